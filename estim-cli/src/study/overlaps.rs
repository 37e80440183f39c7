//! Rows shared between recorded trajectories, found in the A-KIT files themselves, and
//! the rule that keeps anything touching a held-out trajectory out of training and
//! validation (`estim dataset beamsnet`).

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::Path;

use estim::datasets::{load_dvl, load_gt, trajectory_files, DvlSample, GtSample};

use super::{PipelineError, Result};

/// The exact bit patterns of one row's values (the time stamp excluded).
pub type RowKey = Vec<u64>;

/// Fingerprint of a row: the IEEE-754 bit patterns of its values, with -0.0 and 0.0
/// made equal (a copy written by another tool may flip the sign of a zero).
pub fn row_key(values: &[f64]) -> RowKey {
    values
        .iter()
        .map(|v| if *v == 0.0 { 0 } else { v.to_bits() })
        .collect()
}

/// Rows shared between trajectories.
///
/// Public datasets cut from one long recording can share rows: in A-KIT, trajectory 13's
/// first 101 rows (GT and DVL) are trajectory 10's last 101 rows, and trajectories 1
/// and 8 share 102 rows. A training window built from such rows is test data seen during
/// training. [`RowOverlaps::find`] finds the shared rows from exact value fingerprints
/// (time stamps excluded: the copies carry each file's own clock), and
/// [`RowOverlaps::touches`] tells whether a window's row span reaches a row shared with
/// a held-out trajectory. [`RowOverlaps::groups`] gives the trajectories linked by shared
/// rows, which a train / validation split must not separate.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RowOverlaps {
    /// Per trajectory: row index -> the other trajectories holding an identical row.
    shared: BTreeMap<u32, BTreeMap<usize, BTreeSet<u32>>>,
}

impl RowOverlaps {
    /// Find the rows that occur (identical fingerprint) in more than one trajectory.
    ///
    /// # Errors
    /// A trajectory number given twice.
    pub fn find(trajectories: &[(u32, Vec<RowKey>)]) -> Result<Self> {
        let mut seen = BTreeSet::new();
        let mut index: HashMap<&RowKey, Vec<(u32, usize)>> = HashMap::new();
        for (n, rows) in trajectories {
            if !seen.insert(*n) {
                return Err(PipelineError::Argument {
                    flag: "trajectories".into(),
                    reason: format!("trajectory {n} given twice"),
                });
            }
            for (i, key) in rows.iter().enumerate() {
                index.entry(key).or_default().push((*n, i));
            }
        }
        let mut shared: BTreeMap<u32, BTreeMap<usize, BTreeSet<u32>>> = BTreeMap::new();
        for holders in index.values() {
            let owners: BTreeSet<u32> = holders.iter().map(|(n, _)| *n).collect();
            if owners.len() < 2 {
                continue;
            }
            for (n, i) in holders {
                let others = owners.iter().copied().filter(|m| m != n);
                shared
                    .entry(*n)
                    .or_default()
                    .entry(*i)
                    .or_default()
                    .extend(others);
            }
        }
        Ok(Self { shared })
    }

    /// Rows of trajectory `n` also found in trajectory `other`, increasing.
    pub fn rows_shared_with(&self, n: u32, other: u32) -> Vec<usize> {
        self.shared.get(&n).map_or_else(Vec::new, |rows| {
            rows.iter()
                .filter(|(_, o)| o.contains(&other))
                .map(|(i, _)| *i)
                .collect()
        })
    }

    /// Pairs `(a, b)`, `a < b`, sharing at least one row, with the shared row count
    /// (counted in `a`).
    pub fn pairs(&self) -> Vec<(u32, u32, usize)> {
        let mut out = Vec::new();
        for (&a, rows) in &self.shared {
            let partners: BTreeSet<u32> = rows.values().flatten().copied().collect();
            for b in partners.into_iter().filter(|&b| b > a) {
                out.push((a, b, self.rows_shared_with(a, b).len()));
            }
        }
        out
    }

    /// Trajectories linked (directly or through others) by shared rows: the connected
    /// components with more than one member, each increasing, ordered by first member.
    pub fn groups(&self) -> Vec<Vec<u32>> {
        let mut left: BTreeSet<u32> = self.shared.keys().copied().collect();
        let mut groups = Vec::new();
        while let Some(start) = left.pop_first() {
            let mut group = BTreeSet::from([start]);
            let mut stack = vec![start];
            while let Some(a) = stack.pop() {
                let partners = self.shared.get(&a).into_iter().flat_map(|r| r.values());
                for b in partners.flatten() {
                    if left.remove(b) {
                        group.insert(*b);
                        stack.push(*b);
                    }
                }
            }
            groups.push(group.into_iter().collect());
        }
        groups
    }

    /// Whether rows `first..=last` of trajectory `n` hold a row shared with any
    /// trajectory in `held_out` (or `n` itself is held out).
    pub fn touches(&self, n: u32, first: usize, last: usize, held_out: &[u32]) -> bool {
        if held_out.contains(&n) {
            return true;
        }
        self.shared.get(&n).is_some_and(|rows| {
            rows.range(first..=last)
                .any(|(_, others)| others.iter().any(|o| held_out.contains(o)))
        })
    }

    /// Check that a validation set does not split a group: for every group, its members
    /// present in `dataset` (trajectories with examples) are all in `validation` or
    /// none is. The training scripts apply this rule to the groups `estim dataset`
    /// records (training/); here it is the tests' statement of it.
    ///
    /// # Errors
    /// [`PipelineError::Argument`] naming the group.
    #[cfg(test)]
    pub fn check_split(&self, dataset: &[u32], validation: &[u32]) -> Result<()> {
        for group in self.groups() {
            let present: Vec<u32> = group
                .iter()
                .copied()
                .filter(|n| dataset.contains(n))
                .collect();
            let in_val = present.iter().filter(|n| validation.contains(n)).count();
            if in_val != 0 && in_val != present.len() {
                return Err(PipelineError::Argument {
                    flag: "validation split".into(),
                    reason: format!(
                        "trajectories {present:?} share rows; validation {validation:?} \
                         splits them"
                    ),
                });
            }
        }
        Ok(())
    }
}

/// Rows of a 1-D time grid (`times` increasing) that an example spanning `[start, end]`
/// depends on, widened by `margin` rows on each side: from the last row at or before
/// `start` to the first row at or after `end`, then `margin` more. Clamped to the grid.
///
/// The margin accounts for interpolation: the IMU synthesized over `[start, end]` comes
/// from splines through the neighbouring rows too.
pub fn row_span(times: &[f64], start: f64, end: f64, margin: usize) -> Option<(usize, usize)> {
    if times.is_empty() || !(start.is_finite() && end.is_finite()) || end < start {
        return None;
    }
    let first = times.partition_point(|&t| t <= start).saturating_sub(1);
    let last = times.partition_point(|&t| t < end).min(times.len() - 1);
    Some((
        first.saturating_sub(margin),
        (last + margin).min(times.len() - 1),
    ))
}

/// Fingerprint of each row: the GT values and the DVL values of the same row, time
/// stamps excluded (the copies carry each file's own clock). Rows beyond the shorter
/// file use the values of the longer one alone.
pub fn akit_row_keys(gt: &[GtSample], dvl: &[DvlSample]) -> Vec<RowKey> {
    (0..gt.len().max(dvl.len()))
        .map(|i| {
            let mut values = Vec::with_capacity(12);
            if let Some(g) = gt.get(i) {
                values.extend([g.longitude, g.latitude, g.altitude]);
                values.extend(g.velocity_ned);
                values.extend(g.roll_pitch_yaw);
            }
            if let Some(d) = dvl.get(i) {
                values.extend(d.velocity_body);
            }
            row_key(&values)
        })
        .collect()
}

/// The rows shared between the given A-KIT trajectories under `dir` (a data root or an
/// A-KIT folder); a trajectory listed twice counts once.
///
/// # Errors
/// A missing or malformed file (named).
pub fn akit_overlaps(dir: &Path, trajectories: &[u32]) -> Result<RowOverlaps> {
    let list: BTreeSet<u32> = trajectories.iter().copied().collect();
    let mut keys = Vec::with_capacity(list.len());
    for n in list {
        let files = trajectory_files(dir, n)?;
        let gt = load_gt(&files.gt)?;
        let dvl = load_dvl(&files.dvl)?;
        keys.push((n, akit_row_keys(&gt, &dvl)));
    }
    RowOverlaps::find(&keys)
}

/// GT rows on each side of an example's time span that count as part of it: the IMU
/// synthesized over the span comes from a cubic Hermite position curve (the two rows
/// around each instant) and a natural cubic spline of the attitude (every row, with an
/// influence that decays by 2 - sqrt(3) = 0.27 per row). Two rows each side keep the
/// influence of any excluded row below 0.27^2 = 7 %.
pub const WINDOW_MARGIN_ROWS: usize = 2;

/// Whether an example of trajectory `n` spanning `[start, end]` (its IMU window and
/// its DVL sample) touches a row shared with a trajectory in `held_out` (GT times
/// `gt_times`, margin [`WINDOW_MARGIN_ROWS`]). An example whose span is empty or not
/// finite counts as touching (it is kept out).
pub fn touches_held_out(
    overlaps: &RowOverlaps,
    n: u32,
    gt_times: &[f64],
    start: f64,
    end: f64,
    held_out: &[u32],
) -> bool {
    match row_span(gt_times, start, end, WINDOW_MARGIN_ROWS) {
        Some((first, last)) => overlaps.touches(n, first, last, held_out),
        None => true,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn keys(values: &[f64]) -> Vec<RowKey> {
        values.iter().map(|v| row_key(&[*v, 2.0 * v])).collect()
    }

    #[test]
    fn finds_a_shared_tail_and_groups_it() {
        // a: 0..10, b: 7..15 (shares 7, 8, 9 with a), c: 100..105 (alone),
        // d: 14..17 shares 14 with b (so a, b, d form one group through b).
        let a: Vec<f64> = (0..10).map(f64::from).collect();
        let b: Vec<f64> = (7..15).map(f64::from).collect();
        let c: Vec<f64> = (100..105).map(f64::from).collect();
        let d: Vec<f64> = (14..17).map(f64::from).collect();
        let o = RowOverlaps::find(&[(1, keys(&a)), (2, keys(&b)), (3, keys(&c)), (4, keys(&d))])
            .unwrap();
        assert_eq!(o.rows_shared_with(1, 2), vec![7, 8, 9]);
        assert_eq!(o.rows_shared_with(2, 1), vec![0, 1, 2]);
        assert_eq!(o.rows_shared_with(2, 4), vec![7]);
        assert_eq!(o.pairs(), vec![(1, 2, 3), (2, 4, 1)]);
        assert_eq!(o.groups(), vec![vec![1, 2, 4]]);
        assert!(o.touches(1, 5, 7, &[2]));
        assert!(!o.touches(1, 0, 6, &[2]));
        assert!(!o.touches(1, 5, 9, &[4]));
        assert!(o.touches(4, 0, 0, &[4]));
        assert!(o.check_split(&[1, 2, 3], &[3]).is_ok());
        assert!(o.check_split(&[1, 2, 3], &[1, 2]).is_ok());
        assert!(o.check_split(&[1, 2, 3], &[2]).is_err());
        // 4 absent from the dataset: {1, 2} decide.
        assert!(o.check_split(&[1, 2, 3], &[1, 2, 3]).is_ok());
        assert!(RowOverlaps::find(&[(1, keys(&a)), (1, keys(&b))]).is_err());
    }

    #[test]
    fn signed_zero_is_one_value_and_time_span_is_widened() {
        assert_eq!(row_key(&[0.0, 1.0]), row_key(&[-0.0, 1.0]));
        assert_ne!(row_key(&[1.0]), row_key(&[1.0 + f64::EPSILON]));
        let t: Vec<f64> = (0..10).map(|i| f64::from(i) * 1.0025).collect();
        // [2.5, 3.5]: last row at or before 2.5 is 2 (2.005), first at or after 3.5 is 4.
        assert_eq!(row_span(&t, 2.5, 3.5, 0), Some((2, 4)));
        assert_eq!(row_span(&t, 2.5, 3.5, 2), Some((0, 6)));
        assert_eq!(row_span(&t, t[3], t[3], 0), Some((3, 3)));
        assert_eq!(row_span(&t, 8.0, 100.0, 3), Some((4, 9)));
        assert_eq!(row_span(&t, 3.0, 2.0, 0), None);
        assert_eq!(row_span(&[], 0.0, 1.0, 0), None);
    }
}
