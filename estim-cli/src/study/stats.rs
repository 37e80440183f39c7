//! Summaries of filter runs: per-group standard deviations (paper Fig. 5), errors
//! against truth, consistency averages.

use serde::Serialize;

/// The state groups the paper reports (position is ours: the paper omits it).
pub const GROUPS: [(&str, usize); 5] = [
    ("position", 0),
    ("velocity", 3),
    ("misalignment", 6),
    ("acc_bias", 9),
    ("gyro_bias", 12),
];

/// Unit of each state group's standard deviation, as a key suffix.
pub const GROUP_UNITS: [(&str, &str); 5] = [
    ("position", "m"),
    ("velocity", "mps"),
    ("misalignment", "rad"),
    ("acc_bias", "mps2"),
    ("gyro_bias", "radps"),
];

/// The group key with its unit (`velocity` -> `velocity_mps`); unknown groups unchanged.
pub fn group_key_with_unit(group: &str) -> String {
    match GROUP_UNITS.iter().find(|(g, _)| *g == group) {
        Some((g, u)) => format!("{g}_{u}"),
        None => group.to_string(),
    }
}

/// Serialise a per-group map with the unit in each key (JSON schema of the reports).
pub fn serialize_groups_with_units<S: serde::Serializer, V: Serialize>(
    map: &std::collections::BTreeMap<String, V>,
    serializer: S,
) -> Result<S::Ok, S::Error> {
    use serde::ser::SerializeMap;
    let mut m = serializer.serialize_map(Some(map.len()))?;
    for (k, v) in map {
        m.serialize_entry(&group_key_with_unit(k), v)?;
    }
    m.end()
}

/// One group's standard deviation summary, summed over its three axes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StdSummary {
    /// Time average of sum_axes sqrt(P_ii(t)).
    pub time_average: f64,
    /// sum_axes sqrt(P_ii) at the final time.
    pub final_value: f64,
}

/// Per-group std summary from a series of covariance diagonals (one `[f64; 15]` per time).
pub fn std_summary(diagonals: &[[f64; 15]], first_index: usize) -> StdSummary {
    let sum_std = |d: &[f64; 15]| {
        (first_index..first_index + 3)
            .map(|i| d[i].max(0.0).sqrt())
            .sum::<f64>()
    };
    let n = diagonals.len().max(1) as f64;
    StdSummary {
        time_average: diagonals.iter().map(sum_std).sum::<f64>() / n,
        final_value: diagonals.last().map_or(f64::NAN, sum_std),
    }
}

/// Whether a group's standard deviations over a run come from covariances that were
/// positive definite at every epoch: the run's Cholesky check of the full P never
/// failed (`not_pd_epochs`, [`super::FilterRun::covariance_not_positive_definite`]) and
/// the group's three variances are finite and > 0 at every time (the std of
/// [`std_summary`] clamps a negative variance to 0, which would hide it).
pub fn group_std_positive_definite(
    not_pd_epochs: usize,
    diagonals: &[[f64; 15]],
    first_index: usize,
) -> bool {
    not_pd_epochs == 0
        && diagonals.iter().all(|d| {
            d[first_index..first_index + 3]
                .iter()
                .all(|v| v.is_finite() && *v > 0.0)
        })
}

/// % improvement of `aware` over `neglected` (positive = smaller std), as the paper's Fig. 5.
pub fn improvement_percent(neglected: f64, aware: f64) -> f64 {
    100.0 * (neglected - aware) / neglected
}

/// Mean of the finite values (NaN if there are none).
pub fn finite_mean(values: &[f64]) -> f64 {
    let (sum, n) = values
        .iter()
        .filter(|v| v.is_finite())
        .fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    if n == 0 {
        f64::NAN
    } else {
        sum / n as f64
    }
}

/// A sum of finite `f64` kept exactly (as non-overlapping partials, Shewchuk 1997,
/// "Adaptive precision floating-point arithmetic", the `msum` of Python's
/// `math.fsum`): [`ExactSum::value`] is the exact sum rounded once to the nearest
/// `f64`, so it does not depend on the order of the additions or on how the values
/// were split into sums that were then merged. Monte Carlo shards carry these, so
/// merged shards give the sums of one run over the union of their seeds, bit for bit.
///
/// Two sums are equal when their exact values are, and serialise alike: as their
/// canonical partials ([`ExactSum::canonical`]).
#[derive(Debug, Clone, Default, Serialize, serde::Deserialize)]
#[serde(try_from = "Vec<f64>", into = "Vec<f64>")]
pub struct ExactSum {
    /// Non-overlapping, increasing in magnitude; their exact sum is the sum.
    partials: Vec<f64>,
}

impl ExactSum {
    /// Add a finite `x` exactly (a non-finite `x` is the caller's to count apart; an
    /// intermediate overflow beyond `f64::MAX` makes the value infinite).
    pub fn add(&mut self, mut x: f64) {
        let mut kept = 0;
        for j in 0..self.partials.len() {
            let mut y = self.partials[j];
            if x.abs() < y.abs() {
                std::mem::swap(&mut x, &mut y);
            }
            // Two-sum (Knuth): hi + lo == x + y exactly.
            let hi = x + y;
            let lo = y - (hi - x);
            if lo != 0.0 {
                self.partials[kept] = lo;
                kept += 1;
            }
            x = hi;
        }
        self.partials.truncate(kept);
        self.partials.push(x);
    }

    /// Add every value of `other` (exactly: the merged sum is the sum of both).
    pub fn merge(&mut self, other: &ExactSum) {
        for &p in &other.partials {
            self.add(p);
        }
    }

    /// The exact sum rounded to the nearest `f64`, ties to even (0 for no values).
    pub fn value(&self) -> f64 {
        let p = &self.partials;
        let Some(mut n) = p.len().checked_sub(1) else {
            return 0.0;
        };
        let mut hi = p[n];
        let mut lo = 0.0;
        while n > 0 {
            let x = hi;
            n -= 1;
            let y = p[n];
            hi = x + y;
            lo = y - (hi - x);
            if lo != 0.0 {
                break;
            }
        }
        // Half-way case: the partials below decide the rounding direction.
        if n > 0 && ((lo < 0.0 && p[n - 1] < 0.0) || (lo > 0.0 && p[n - 1] > 0.0)) {
            let y = 2.0 * lo;
            let x = hi + y;
            if x - hi == y {
                hi = x;
            }
        }
        hi
    }
}

impl ExactSum {
    /// The exact value as `[v1, v2, ...]`, largest first, each the exact remainder
    /// rounded to nearest (v1 = [`ExactSum::value`], v2 = the value of the sum minus
    /// v1, ...): one list per exact value, whatever the additions were.
    pub fn canonical(&self) -> Vec<f64> {
        let mut rest = self.clone();
        let mut out = Vec::new();
        // Each step leaves at most half an ulp of the last term: 64 steps span far
        // more than the f64 exponent range.
        for _ in 0..64 {
            let v = rest.value();
            if v == 0.0 || !v.is_finite() {
                if !v.is_finite() {
                    out.push(v);
                }
                break;
            }
            out.push(v);
            rest.add(-v);
        }
        out
    }
}

impl PartialEq for ExactSum {
    fn eq(&self, other: &Self) -> bool {
        self.canonical() == other.canonical()
    }
}

impl TryFrom<Vec<f64>> for ExactSum {
    type Error = String;

    /// From any finite partials (renormalised, so a hand-edited list still sums
    /// exactly).
    fn try_from(values: Vec<f64>) -> Result<Self, String> {
        let mut sum = ExactSum::default();
        for v in values {
            if !v.is_finite() {
                return Err(format!("partial sum {v} is not finite"));
            }
            sum.add(v);
        }
        Ok(sum)
    }
}

impl From<ExactSum> for Vec<f64> {
    fn from(sum: ExactSum) -> Self {
        sum.canonical()
    }
}

/// Root mean square and final value of a series of error norms.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ErrorSummary {
    /// sqrt(mean(e^2)).
    pub rmse: f64,
    /// Error norm at the final time.
    pub final_value: f64,
}

/// Summarise a series of error norms.
pub fn error_summary(norms: &[f64]) -> ErrorSummary {
    let n = norms.len().max(1) as f64;
    ErrorSummary {
        rmse: (norms.iter().map(|e| e * e).sum::<f64>() / n).sqrt(),
        final_value: norms.last().copied().unwrap_or(f64::NAN),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn std_summary_sums_axes_and_averages_time() {
        let mut a = [0.0; 15];
        let mut b = [0.0; 15];
        // velocity block: variances 1, 4, 9 then 4, 16, 36 -> std sums 6 and 12.
        a[3..6].copy_from_slice(&[1.0, 4.0, 9.0]);
        b[3..6].copy_from_slice(&[4.0, 16.0, 36.0]);
        let s = std_summary(&[a, b], 3);
        assert_eq!(s.time_average, 9.0);
        assert_eq!(s.final_value, 12.0);
    }

    #[test]
    fn positive_definite_check_sees_the_run_and_the_group() {
        let mut d = [1.0; 15];
        assert!(group_std_positive_definite(0, &[d, d], 9));
        // The run's Cholesky check failed once: not PD whatever the diagonal says.
        assert!(!group_std_positive_definite(1, &[d, d], 9));
        // A negative, zero or NaN variance in the group (std_summary would clamp it).
        for bad in [-1e-30, 0.0, f64::NAN] {
            d[10] = bad;
            assert!(!group_std_positive_definite(0, &[[1.0; 15], d], 9), "{bad}");
            // Outside the group it does not matter here.
            assert!(group_std_positive_definite(0, &[[1.0; 15], d], 12), "{bad}");
        }
    }

    #[test]
    fn exact_sum_is_the_exactly_rounded_sum_whatever_the_order_or_split() {
        let mut s = ExactSum::default();
        assert_eq!(s.value(), 0.0);
        for x in [1e16, 1.0, -1e16] {
            s.add(x);
        }
        // The naive sum gives 0.
        assert_eq!(((1e16 + 1.0) - 1e16), 0.0);
        assert_eq!(s.value(), 1.0);
        // Independent reference: multiples of 2^-30 below 2^20 in magnitude sum exactly
        // in i128; the i128 -> f64 cast rounds to nearest, ties to even, and the scaling
        // by 2^-30 is exact.
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut next = || {
            // xorshift64*: deterministic, no dependency.
            state ^= state >> 12;
            state ^= state << 25;
            state ^= state >> 27;
            state.wrapping_mul(0x2545_f491_4f6c_dd1d)
        };
        let scale = 2f64.powi(-30);
        for trial in 0..200 {
            let n = 1 + trial % 37;
            let ints: Vec<i128> = (0..n)
                .map(|_| (next() >> 14) as i128 - (1i128 << 49))
                .collect();
            let values: Vec<f64> = ints.iter().map(|i| *i as f64 * scale).collect();
            let exact = ints.iter().sum::<i128>() as f64 * scale;
            let mut whole = ExactSum::default();
            values.iter().for_each(|v| whole.add(*v));
            assert_eq!(whole.value().to_bits(), exact.to_bits(), "trial {trial}");
            // Reversed, and split in two sums then merged (through JSON): same bits.
            let mut reversed = ExactSum::default();
            values.iter().rev().for_each(|v| reversed.add(*v));
            let k = n / 3;
            let (mut a, mut b) = (ExactSum::default(), ExactSum::default());
            values[..k].iter().for_each(|v| a.add(*v));
            values[k..].iter().for_each(|v| b.add(*v));
            let b: ExactSum = serde_json::from_str(&serde_json::to_string(&b).unwrap()).unwrap();
            a.merge(&b);
            assert_eq!(reversed.value().to_bits(), exact.to_bits());
            assert_eq!(a.value().to_bits(), exact.to_bits());
        }
        // Ties round to even: 2^53 + 1 is half-way between 2^53 and 2^53 + 2.
        let mut t = ExactSum::default();
        for x in [2f64.powi(53), 1.0] {
            t.add(x);
        }
        assert_eq!(t.value(), 2f64.powi(53));
        t.add(1e-300);
        assert_eq!(t.value(), 2f64.powi(53) + 2.0);
        assert!(serde_json::from_str::<ExactSum>("[1.0, null]").is_err());
        // One canonical form per exact value: 1 + 2^-60 reached two ways.
        let (mut p, mut q) = (ExactSum::default(), ExactSum::default());
        for x in [0.5, 2f64.powi(-61), 0.5, 2f64.powi(-61)] {
            p.add(x);
        }
        for x in [2f64.powi(-60), 3.0, -2.0] {
            q.add(x);
        }
        assert_eq!(p.canonical(), vec![1.0, 2f64.powi(-60)]);
        assert_eq!(p, q);
        assert_eq!(
            serde_json::to_string(&p).unwrap(),
            serde_json::to_string(&q).unwrap()
        );
        assert!(ExactSum::default().canonical().is_empty());
    }

    #[test]
    fn improvement_and_errors() {
        assert!((improvement_percent(2.0, 1.5) - 25.0).abs() < 1e-12);
        let e = error_summary(&[3.0, 4.0]);
        assert!((e.rmse - (12.5f64).sqrt()).abs() < 1e-12);
        assert_eq!(e.final_value, 4.0);
    }
}
