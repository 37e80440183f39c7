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
    fn improvement_and_errors() {
        assert!((improvement_percent(2.0, 1.5) - 25.0).abs() < 1e-12);
        let e = error_summary(&[3.0, 4.0]);
        assert!((e.rmse - (12.5f64).sqrt()).abs() < 1e-12);
        assert_eq!(e.final_value, 4.0);
    }
}
