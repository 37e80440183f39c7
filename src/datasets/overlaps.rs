//! Rows shared between A-KIT trajectories (GT and DVL rows identical), found from the
//! files themselves.

use std::collections::BTreeSet;
use std::path::Path;

use estim_learned::{row_key, RowKey, RowOverlaps};

use super::{load_dvl, load_gt, trajectory_files, DvlSample, GtSample, Result};

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
    Ok(RowOverlaps::find(&keys)?)
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
    match estim_learned::row_span(gt_times, start, end, WINDOW_MARGIN_ROWS) {
        Some((first, last)) => overlaps.touches(n, first, last, held_out),
        None => true,
    }
}
