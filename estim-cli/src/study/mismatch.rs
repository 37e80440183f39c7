//! The DVL-vs-ground-truth mismatch on A-KIT, fitted on the training trajectories.
//!
//! On A-KIT the filter's DVL model (lever arm and time offset of the configuration,
//! no scale factor or misalignment) does not reproduce the recorded DVL velocity from
//! the ground truth exactly; `dvl.akit_reference_mismatch_std_mps` adds that residual
//! to R. It is fitted here, never on the test trajectories 4 and 13: the residual
//! r = y_DVL - h(truth) at every DVL epoch of the training trajectories, the epochs
//! whose DVL row also occurs in a held-out trajectory left out (the A-KIT segments
//! overlap, data README), pooled over the epochs and the three axes:
//! std = sqrt(mean of r_i^2). The mean square, not the variance: R stands for the
//! whole residual the filter sees, its mean included.

use std::collections::HashSet;
use std::path::Path;

use estim_core::nalgebra::{Matrix3, Vector3};
use estim_core::MeasurementModel;
use estim_dvl::DvlVelocityModel;

use super::{Config, PipelineError, Result, Scenario};
use estim::datasets::{akit_dir, load_dvl_with, trajectories_in, trajectory_files};

/// Median of the chi-square distribution with one degree of freedom.
pub const CHI_SQUARE_1_MEDIAN: f64 = 0.454_936_423_119_572_8;

/// The A-KIT test trajectories (data README): never used to fit anything.
pub const AKIT_TEST_TRAJECTORIES: [u32; 2] = [4, 13];

/// Residual statistics of one trajectory.
#[derive(Debug, Clone, PartialEq)]
pub struct TrajectoryMismatch {
    /// A-KIT trajectory number.
    pub trajectory: u32,
    /// Epochs used.
    pub samples: usize,
    /// Epochs left out because their DVL row occurs in a held-out trajectory.
    pub overlapping: usize,
    /// Mean residual per axis \[m/s\].
    pub mean: Vector3<f64>,
    /// RMS residual per axis \[m/s\].
    pub rms: Vector3<f64>,
}

/// The fit over the training trajectories.
#[derive(Debug, Clone, PartialEq)]
pub struct MismatchFit {
    /// Per trajectory, in the order fitted.
    pub trajectories: Vec<TrajectoryMismatch>,
    /// Held-out trajectories whose rows were excluded.
    pub held_out: Vec<u32>,
    /// Epochs used in all.
    pub samples: usize,
    /// Mean residual per axis over all epochs \[m/s\].
    pub mean: Vector3<f64>,
    /// RMS residual per axis over all epochs \[m/s\].
    pub rms: Vector3<f64>,
    /// sqrt of the mean square over epochs and axes \[m/s\].
    pub rms_all: f64,
    /// The robust counterpart: sqrt(median of r_i^2 over epochs and axes / 0.45494),
    /// 0.45494 being the median of chi-square(1), so that it equals the std for
    /// Gaussian residuals and ignores the heavy tail \[m/s\].
    pub robust_std: f64,
}

fn bits(v: &Vector3<f64>) -> [u64; 3] {
    [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()]
}

/// Fit the mismatch std on the A-KIT trajectories under `dir`: every trajectory the
/// folder holds except `held_out` (default use: [`AKIT_TEST_TRAJECTORIES`]), with the
/// epochs whose DVL row (its three velocity values, bit for bit) occurs in a held-out
/// trajectory left out.
///
/// # Errors
/// Loader errors (file and line), a held-out trajectory missing from the folder, and
/// [`PipelineError::Data`] when no training trajectory is left,
/// [`PipelineError::DvlEpoch`] when a residual is not finite.
pub fn fit_reference_mismatch(
    dir: &Path,
    config: &Config,
    held_out: &[u32],
) -> Result<MismatchFit> {
    let akit = akit_dir(dir)?;
    let mut test_rows = HashSet::new();
    for &n in held_out {
        let files = trajectory_files(dir, n)?;
        for row in load_dvl_with(&files.dvl, &config.columns)? {
            test_rows.insert(bits(&Vector3::from(row.velocity_body)));
        }
    }
    let model = DvlVelocityModel::builder()
        .lever_arm(Vector3::from(config.dvl.lever_arm_m))
        // R plays no part in the prediction; the builder requires one.
        .noise_covariance(Matrix3::identity() * config.dvl.ls_noise_std.powi(2))
        .build()?;
    let mut fit = MismatchFit {
        trajectories: Vec::new(),
        held_out: held_out.to_vec(),
        samples: 0,
        mean: Vector3::zeros(),
        rms: Vector3::zeros(),
        rms_all: f64::NAN,
        robust_std: f64::NAN,
    };
    let mut squares = Vec::new();
    let (mut sum, mut sum_sq) = (Vector3::zeros(), Vector3::zeros());
    for n in trajectories_in(&akit) {
        if held_out.contains(&n) {
            continue;
        }
        let scenario = Scenario::akit(dir, n, config, config.seed)?;
        let (mut s, mut s2, mut used, mut overlapping) =
            (Vector3::zeros(), Vector3::zeros(), 0usize, 0usize);
        for (k, epoch) in scenario.dvl.iter().enumerate() {
            if test_rows.contains(&bits(&epoch.reference_velocity)) {
                overlapping += 1;
                continue;
            }
            let bad = |reason: String| PipelineError::DvlEpoch {
                scenario: scenario.name.clone(),
                epoch: k,
                reason,
            };
            let truth = scenario.truth.get(epoch.imu_index).ok_or_else(|| {
                bad(format!(
                    "at IMU index {}, beyond the truth",
                    epoch.imu_index
                ))
            })?;
            let r = epoch.reference_velocity - model.predict(truth)?;
            if !r.iter().all(|x| x.is_finite()) {
                return Err(bad(format!(
                    "non-finite DVL residual at t = {:.3} s",
                    truth.time
                )));
            }
            s += r;
            s2 += r.component_mul(&r);
            squares.extend(r.iter().map(|x| x * x));
            used += 1;
        }
        if used == 0 {
            continue;
        }
        sum += s;
        sum_sq += s2;
        fit.samples += used;
        let k = used as f64;
        fit.trajectories.push(TrajectoryMismatch {
            trajectory: n,
            samples: used,
            overlapping,
            mean: s / k,
            rms: (s2 / k).map(f64::sqrt),
        });
    }
    if fit.samples == 0 {
        return Err(PipelineError::Data {
            path: akit,
            line: None,
            reason: format!("no A-KIT training trajectory (all held out: {held_out:?})"),
        });
    }
    let k = fit.samples as f64;
    fit.mean = sum / k;
    fit.rms = (sum_sq / k).map(f64::sqrt);
    fit.rms_all = (sum_sq.sum() / (3.0 * k)).sqrt();
    squares.sort_by(f64::total_cmp);
    let n = squares.len();
    let median = if n % 2 == 1 {
        squares[n / 2]
    } else {
        0.5 * (squares[n / 2 - 1] + squares[n / 2])
    };
    fit.robust_std = (median / CHI_SQUARE_1_MEDIAN).sqrt();
    Ok(fit)
}
