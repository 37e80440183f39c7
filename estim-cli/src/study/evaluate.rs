//! `estim evaluate`: the INS/DVL filter with DVL error states
//! ([`estim::navigator::AugmentedNavigator`]) on every A-KIT trajectory, its
//! parameters fitted on training trajectories only.
//!
//! # Fit ([`fit_training`])
//!
//! Only the trajectories given (default: the 11 training ones); 4 and 13 are refused
//! ([`AKIT_TEST_TRAJECTORIES`]), and the DVL rows a training trajectory shares with
//! 4 or 13 (the segments overlap, data README) are left out of every fit.
//!
//! 1. Per training trajectory, `estim_dvl::Calibrator` (lever arm, scale factor,
//!    misalignment, time offset within +-3 s) on its ground truth and DVL log.
//! 2. The DVL model's initial values: the mean of the training calibrations (lever
//!    arm, scale-factor error, misalignment); the time offset's prior mean is the mean
//!    of the training offsets, applied as the shift of the DVL time stamps, and the
//!    online time-offset state estimates what remains. The training offsets fall in
//!    two groups (about -1.48 s and -0.55 s), so the state's prior 1-sigma is the
//!    larger of their RMS deviation from the mean and half the largest deviation:
//!    it covers both groups.
//! 3. The prior 1-sigma of scale factor, misalignment and lever arm: the RMS
//!    deviation of the training calibrations from their mean (largest axis), at least
//!    the mean standard error of the calibrations.
//! 4. The velocity bias: the residual r = y_DVL - h(truth) of each training trajectory
//!    at its own calibration is modelled as a first-order Gauss-Markov process plus
//!    white noise; its autocovariances at lags 1 and 2 (pooled over trajectories and
//!    axes, consecutive DVL epochs only) give e^{-Δ/τ} = c_2 / c_1,
//!    σ_b² = c_1 e^{Δ/τ}, and the white part σ_w² = c_0 - σ_b² (at least 1e-6 m²/s²),
//!    which is added to R in place of `dvl.akit_reference_mismatch_std_mps`. Without
//!    a Gauss-Markov part (c_1 <= 0 or c_2 / c_1 outside (0, 1)) the bias is not
//!    estimated and σ_w² = c_0.
//! 5. Optionally (`estim evaluate --rate-noise`), DVL noise growing with the angular
//!    rate, R + κ² |ω|² I ([`estim::navigator::AugmentedDvlModel::with_rate_noise`]):
//!    step 4 then uses the calm epochs only (|ω| below [`CALM_RATE_RADPS`] at both
//!    ends of a pair), and κ² is the least-squares slope through the origin of
//!    (mean square residual per axis - c_0) on |ω|² over every epoch. On A-KIT the
//!    residual RMS grows from about 0.02 m/s below 0.02 rad/s to about 0.1 m/s
//!    above 0.1 rad/s.
//! 6. Optionally (`estim evaluate --adaptive-noise N`), the DVL noise level
//!    adapted online per run by the navigator (`dvl.adaptive_noise_window` = N,
//!    [`estim::navigator::AugmentedNavigator`]; [`estim_core::noise::adaptive::NoiseScale`],
//!    memory N updates): one scale λ multiplies R, the Gauss-Markov bias variance (its sigma
//!    by √λ) and κ² (κ by √λ); λ is the covariance-matching estimate from the past
//!    innovations of the run, S = S_0 + λ D with D = R + the bias block of the prior
//!    covariance, every update counted (accepted or gated). A-KIT's trajectories
//!    differ in DVL-versus-reference mismatch (residual RMS 0.015-0.076 m/s at each
//!    training trajectory's own calibration), so one fitted level leaves the NIS
//!    out of band on most of them.
//!
//! # Evaluation ([`evaluate`])
//!
//! Per (trajectory, seed): the study's scenario (IMU synthesized from the ground
//! truth with the configured error model and the seed; the real DVL, beams by the
//! BeamsNet protocol), the augmented filter fed the least-squares DVL velocity (`ls`)
//! and BeamsNet's with M neglected (`beamsnet_m_neglected`), gate as configured. Per
//! run: time-averaged NEES of the 15 INS states against truth, time-averaged NIS
//! (3 dof), position RMSE. A trajectory meets the NEES band when its seed-mean NEES
//! is within [0.5, 2] x 15, the NIS band when its NIS is within [0.5, 2] x 3.
//!
//! Each cell also runs the 15-state filter of `estim reproduce --data` (the
//! configuration as given: its `dvl.akit_time_offset_s`, R with the reference
//! mismatch, no DVL states) for both variants on the same seed, hence the same
//! synthesized IMU; per trajectory and variant the position RMSE difference is
//! summarised as a mean paired difference with its 95 % Student t interval over the
//! seeds ([`PairedInterval`]).
//!
//! # On a recorded IMU
//!
//! Where the trajectory's folder holds `IMU_trajectoryN.csv` (`--imu auto`, the
//! default, or `recorded`) the cell is the study's recorded scenario
//! ([`Scenario::akit_selected`]: the IMU read through the vehicle file) and both
//! variants run through the navigator ([`super::run_recorded`]) with the vehicle
//! file's DVL model: its `[dvl_states]` (fitted on the training trajectories by the
//! procedures of docs/results.md, "The A-KIT vehicle file"), its time offset and
//! its adapted R, in place of the fit above, which applies to the synthesized IMU's
//! clock. NEES is over the 9 states with truth at the reference's epochs; the
//! comparison run is the same navigator without DVL error states. A seed redraws only
//! the protocol's beam noise. `--states`, `--rate-noise` and `--adaptive-noise`
//! change the synthesized runs only and are refused with a recorded IMU.

use std::collections::HashSet;
use std::path::Path;

use estim::datasets::{load_dvl_with, load_gt_with, trajectory_files};
use estim::navigator::{
    run_epochs, AugmentedDvlModel, AugmentedErrorModel, AugmentedNavigator, BiasConfig, DvlConfig,
    DvlParameters, DvlStatesConfig, EpochHook, GateConfig, LeverArmState, MisalignmentState,
    NavigatorConfig, NavigatorError, ScaleFactorState, Tail, TimeOffsetState, AUGMENTED_STATES,
};
use estim_core::consistency::nees;
use estim_core::nalgebra::{Matrix3, Rotation3, Vector3};
use estim_core::{NoObserver, Zero};
use estim_dvl::{dvl_frame_velocity, Calibrator, DvlMeasurement, TrajectorySample};
use estim_ins::{InsState, ERROR_STATES, POS};
use rayon::prelude::*;
use serde::Serialize;

use super::paired::{recorded_sets, LEVEL};
use super::stats::{error_summary, finite_mean};
use super::{
    beamsnet_without_sensitivity, error_state, initial_covariance, initial_nominal,
    least_squares_velocities, run_variant, summarise, Config, CrossSource, ImuSelection, ImuSource,
    LearnedSource, PairedInterval, PipelineError, RecordedSurvey, Result, Scenario,
    AKIT_TEST_TRAJECTORIES, BEAMSNET_NEGLECTED, LS,
};

mod recorded;
use recorded::recorded_cell;
mod report;
mod rows;
use rows::evaluation_rows;
mod runs;
#[cfg(test)]
mod tests;

pub use report::markdown;
use runs::{fifteen_state_rmse, Run};

/// The A-KIT training trajectories (all but 4 and 13); the study's tests check
/// `check_fit_trajectories` against them.
#[cfg(test)]
pub const AKIT_TRAINING_TRAJECTORIES: [u32; 11] = [1, 2, 3, 5, 6, 7, 8, 9, 10, 11, 12];

/// The variants evaluated.
pub const EVALUATED_VARIANTS: [&str; 2] = [LS, BEAMSNET_NEGLECTED];

/// Angular rate below which an epoch counts as calm for the Gauss-Markov fit
/// \[rad/s\].
pub const CALM_RATE_RADPS: f64 = 0.02;

/// The NEES and NIS bands: [0.5, 2] x the degrees of freedom.
pub const BAND: [f64; 2] = [0.5, 2.0];

/// A DVL residual against the truth \[m/s\] and the angular rate |ω| \[rad/s\] at
/// its epoch.
type RateResidual = (Vector3<f64>, f64);

/// One training trajectory's calibration.
#[derive(Debug, Clone, Serialize)]
pub struct TrajectoryCalibration {
    /// A-KIT trajectory.
    pub trajectory: u32,
    /// DVL rows used (those shared with 4 or 13 left out).
    pub samples: usize,
    /// Lever arm \[m\].
    pub lever_arm_m: [f64; 3],
    /// Scale-factor error.
    pub scale_factor_error: f64,
    /// Mounting misalignment \[rad\].
    pub misalignment_rad: [f64; 3],
    /// Time offset \[s\].
    pub time_offset_s: f64,
    /// Residual RMS per axis at the calibration \[m/s\].
    pub residual_rms_mps: [f64; 3],
}

/// What [`fit_training`] found.
#[derive(Debug, Clone, Serialize)]
pub struct TrainingFit {
    /// The trajectories fitted on.
    pub trajectories: Vec<u32>,
    /// Per trajectory.
    pub calibrations: Vec<TrajectoryCalibration>,
    /// Mean lever arm \[m\].
    pub lever_arm_m: [f64; 3],
    /// Mean scale-factor error.
    pub scale_factor_error: f64,
    /// Mean misalignment \[rad\].
    pub misalignment_rad: [f64; 3],
    /// Prior mean of the time offset (the stamp shift) \[s\].
    pub time_offset_s: f64,
    /// Prior 1-sigma of the time-offset state \[s\].
    pub time_offset_std_s: f64,
    /// Prior 1-sigma of the scale-factor error.
    pub scale_factor_std: f64,
    /// Prior 1-sigma of the misalignment \[rad\].
    pub misalignment_std_rad: f64,
    /// Prior 1-sigma of the lever arm \[m\].
    pub lever_arm_std_m: f64,
    /// Residual epochs used for the Gauss-Markov fit.
    pub residual_samples: usize,
    /// Pooled residual autocovariances at lags 0, 1, 2 \[m^2/s^2\].
    pub autocovariance: [f64; 3],
    /// DVL sample interval Δ \[s\] (median).
    pub dvl_interval_s: f64,
    /// Whether the residuals have a Gauss-Markov part (a positive lag-1
    /// autocovariance and 0 < c_2 / c_1 < 1); if not, the bias is not estimated and
    /// the whole residual is white.
    pub bias_estimated: bool,
    /// Gauss-Markov bias sigma \[m/s\] (0 without a Gauss-Markov part).
    pub bias_std_mps: f64,
    /// Gauss-Markov bias time constant \[s\].
    pub bias_time_constant_s: f64,
    /// White residual std \[m/s\], added to R.
    pub white_std_mps: f64,
    /// Rate-dependent noise κ \[m/s per rad/s\]: R grows by κ² |ω|² I.
    pub rate_noise_mps_per_radps: f64,
}

impl TrainingFit {
    /// The DVL states of this fit (all estimated).
    pub fn states(&self) -> DvlStatesConfig {
        DvlStatesConfig {
            scale_factor: ScaleFactorState {
                estimate: true,
                prior_std: self.scale_factor_std,
            },
            misalignment: MisalignmentState {
                estimate: true,
                prior_std_rad: self.misalignment_std_rad.into(),
            },
            bias: BiasConfig {
                estimate: self.bias_estimated,
                std_mps: self.bias_std_mps,
                time_constant_s: self.bias_time_constant_s,
            },
            lever_arm: LeverArmState {
                estimate: true,
                prior_std_m: self.lever_arm_std_m.into(),
            },
            time_offset: TimeOffsetState {
                estimate: true,
                prior_std_s: self.time_offset_std_s,
            },
        }
    }

    /// The DVL mounting of this fit as the navigator's configuration.
    pub fn dvl_config(&self) -> DvlConfig {
        DvlConfig {
            lever_arm_m: self.lever_arm_m,
            mounting_misalignment_rad: self.misalignment_rad,
            scale_factor: 1.0 + self.scale_factor_error,
            ..DvlConfig::default()
        }
    }
}

/// Refuse the test trajectories, an empty list and repeats.
///
/// # Errors
/// [`PipelineError::HeldOut`] for a test trajectory, [`PipelineError::Argument`] for
/// an empty list or a repeat.
pub fn check_fit_trajectories(trajectories: &[u32]) -> Result<()> {
    const FLAG: &str = "--fit-trajectories";
    let bad = |reason: String| PipelineError::Argument {
        flag: FLAG.into(),
        reason,
    };
    if trajectories.is_empty() {
        return Err(bad("no trajectory to fit on".into()));
    }
    for (i, n) in trajectories.iter().enumerate() {
        if AKIT_TEST_TRAJECTORIES.contains(n) {
            return Err(PipelineError::HeldOut {
                flag: FLAG.into(),
                trajectory: *n,
            });
        }
        if trajectories[..i].contains(n) {
            return Err(bad(format!("trajectory {n} given twice")));
        }
    }
    Ok(())
}

fn bits(v: &[f64; 3]) -> [u64; 3] {
    v.map(f64::to_bits)
}

fn mean3(values: impl Iterator<Item = [f64; 3]>) -> [f64; 3] {
    let (mut sum, mut n) = ([0.0; 3], 0.0);
    for v in values {
        for i in 0..3 {
            sum[i] += v[i];
        }
        n += 1.0;
    }
    sum.map(|s| s / n)
}

/// RMS deviation from the mean, largest axis.
fn spread3(values: &[[f64; 3]]) -> f64 {
    let m = mean3(values.iter().copied());
    (0..3)
        .map(|i| {
            (values.iter().map(|v| (v[i] - m[i]).powi(2)).sum::<f64>() / values.len() as f64).sqrt()
        })
        .fold(0.0, f64::max)
}

/// The calibration of training trajectory `n` (its rows shared with a test
/// trajectory left out) and the largest standard errors of its scale factor,
/// misalignment and lever arm.
fn calibrate(
    dir: &Path,
    config: &Config,
    n: u32,
    calibrator: &Calibrator,
    test_rows: &HashSet<[u64; 3]>,
) -> Result<(TrajectoryCalibration, [f64; 3])> {
    let files = trajectory_files(dir, n)?;
    let gt = load_gt_with(&files.gt, &config.columns)?;
    let dvl = load_dvl_with(&files.dvl, &config.columns)?;
    let reference: Vec<TrajectorySample> = gt
        .iter()
        .map(|s| TrajectorySample {
            time: s.time,
            velocity_ned: Vector3::from(s.velocity_ned),
            roll_pitch_yaw: Vector3::from(s.roll_pitch_yaw),
        })
        .collect();
    let log: Vec<DvlMeasurement> = dvl
        .iter()
        .filter(|s| !test_rows.contains(&bits(&s.velocity_body)))
        .map(|s| DvlMeasurement {
            time: s.time,
            velocity: Vector3::from(s.velocity_body),
        })
        .collect();
    let c = calibrator
        .calibrate(&reference, &log)
        .map_err(|error| PipelineError::Calibration {
            trajectory: n,
            error,
        })?;
    let standard_errors = [
        c.scale_factor_error.standard_error,
        c.mounting_misalignment
            .iter()
            .map(|e| e.standard_error)
            .fold(0.0, f64::max),
        c.lever_arm
            .iter()
            .map(|e| e.standard_error)
            .fold(0.0, f64::max),
    ];
    Ok((
        TrajectoryCalibration {
            trajectory: n,
            samples: c.samples,
            lever_arm_m: c.lever_arm_vector().into(),
            scale_factor_error: c.scale_factor_error.value,
            misalignment_rad: c.mounting_misalignment_vector().into(),
            time_offset_s: c.time_offset.value,
            residual_rms_mps: c.residual_rms.into(),
        },
        standard_errors,
    ))
}

/// The residuals of a trajectory at its own calibration, with the angular rate, for
/// the Gauss-Markov fit (`None` for an epoch shared with a test trajectory).
fn calibration_residuals(
    dir: &Path,
    config: &Config,
    c: &TrajectoryCalibration,
    test_rows: &HashSet<[u64; 3]>,
) -> Result<Vec<Option<RateResidual>>> {
    let mut cfg = config.clone();
    cfg.dvl.akit_time_offset_s = c.time_offset_s;
    let scenario = Scenario::akit(dir, c.trajectory, &cfg, cfg.seed)?;
    let mut out = Vec::with_capacity(scenario.dvl.len());
    for (k, epoch) in scenario.dvl.iter().enumerate() {
        if test_rows.contains(&bits(&epoch.reference_velocity.into())) {
            out.push(None);
            continue;
        }
        let truth = scenario
            .truth
            .get(epoch.imu_index)
            .ok_or_else(|| PipelineError::DvlEpoch {
                scenario: scenario.name.clone(),
                epoch: k,
                reason: "beyond the truth".into(),
            })?;
        let predicted = dvl_frame_velocity(
            &(truth.attitude.inverse() * truth.velocity_ned),
            &truth.angular_rate,
            &Vector3::from(c.lever_arm_m),
            c.scale_factor_error,
            &Vector3::from(c.misalignment_rad),
        );
        let rr = epoch.reference_velocity - predicted;
        out.push(Some((rr, truth.angular_rate.norm())));
    }
    Ok(out)
}

/// Fit the DVL model and its error states on `trajectories` (see the module docs).
///
/// # Errors
/// A test trajectory (4, 13) or a repeat in `trajectories`; loader errors (file and
/// line); a calibration failure (naming the trajectory). Residuals without a
/// Gauss-Markov part are not an error: the bias is then not estimated
/// ([`TrainingFit::bias_estimated`]).
pub fn fit_training(
    dir: &Path,
    config: &Config,
    trajectories: &[u32],
    rate_noise: bool,
) -> Result<TrainingFit> {
    let calm = if rate_noise {
        CALM_RATE_RADPS
    } else {
        f64::INFINITY
    };
    check_fit_trajectories(trajectories)?;
    let mut test_rows = HashSet::new();
    for &n in &AKIT_TEST_TRAJECTORIES {
        let files = trajectory_files(dir, n)?;
        for row in load_dvl_with(&files.dvl, &config.columns)? {
            test_rows.insert(bits(&row.velocity_body));
        }
    }
    let calibrator = Calibrator::builder().build()?;
    let calibrations: Vec<(TrajectoryCalibration, [f64; 3])> = trajectories
        .par_iter()
        .map(|&n| calibrate(dir, config, n, &calibrator, &test_rows))
        .collect::<Result<_>>()?;
    let k = calibrations.len() as f64;
    let se = mean3(calibrations.iter().map(|(_, s)| *s));
    let cals: Vec<TrajectoryCalibration> = calibrations.into_iter().map(|(c, _)| c).collect();
    let lever: Vec<[f64; 3]> = cals.iter().map(|c| c.lever_arm_m).collect();
    let mis: Vec<[f64; 3]> = cals.iter().map(|c| c.misalignment_rad).collect();
    let scale: Vec<[f64; 3]> = cals.iter().map(|c| [c.scale_factor_error; 3]).collect();
    let offsets: Vec<f64> = cals.iter().map(|c| c.time_offset_s).collect();
    let offset_mean = offsets.iter().sum::<f64>() / k;
    let offset_rms = (offsets
        .iter()
        .map(|t| (t - offset_mean).powi(2))
        .sum::<f64>()
        / k)
        .sqrt();
    let offset_max = offsets
        .iter()
        .map(|t| (t - offset_mean).abs())
        .fold(0.0, f64::max);
    // The residuals at each trajectory's own calibration, for the Gauss-Markov fit.
    let residuals: Vec<Vec<Option<RateResidual>>> = cals
        .par_iter()
        .map(|c| calibration_residuals(dir, config, c, &test_rows))
        .collect::<Result<_>>()?;
    // With the rate-dependent noise: the Gauss-Markov part from the calm epochs (both
    // ends of a pair below CALM_RATE_RADPS), the rate-dependent part from all epochs.
    // Without: the Gauss-Markov part from all epochs.
    let mut sums = [0.0; 3];
    let mut counts = [0usize; 3];
    for series in &residuals {
        for (i, r) in series.iter().enumerate() {
            let Some((r, w)) = r else { continue };
            if *w >= calm {
                continue;
            }
            for (lag, (sum, count)) in sums.iter_mut().zip(counts.iter_mut()).enumerate() {
                if let Some(Some((s, ws))) = series.get(i + lag) {
                    if *ws < calm {
                        *sum += r.dot(s);
                        *count += 3;
                    }
                }
            }
        }
    }
    let c: [f64; 3] = std::array::from_fn(|i| sums[i] / counts[i].max(1) as f64);
    // kappa^2: least squares through the origin of (mean square per axis - c_0) on
    // |omega|^2 over every epoch.
    let (mut num, mut den) = (0.0, 0.0);
    for (r, w) in residuals.iter().flatten().flatten() {
        let w2 = w * w;
        num += (r.norm_squared() / 3.0 - c[0]) * w2;
        den += w2 * w2;
    }
    let rate_noise = if rate_noise && den > 0.0 {
        (num / den).max(0.0).sqrt()
    } else {
        0.0
    };
    let interval = dvl_interval(dir, config, trajectories)?;
    let gm = gauss_markov_from_autocovariance(c, interval);
    Ok(TrainingFit {
        trajectories: trajectories.to_vec(),
        lever_arm_m: mean3(lever.iter().copied()),
        scale_factor_error: scale.iter().map(|s| s[0]).sum::<f64>() / k,
        misalignment_rad: mean3(mis.iter().copied()),
        time_offset_s: offset_mean,
        time_offset_std_s: offset_rms.max(offset_max / 2.0),
        scale_factor_std: spread3(&scale).max(se[0]),
        misalignment_std_rad: spread3(&mis).max(se[1]),
        lever_arm_std_m: spread3(&lever).max(se[2]),
        residual_samples: counts[0] / 3,
        autocovariance: c,
        dvl_interval_s: interval,
        bias_estimated: gm.is_some(),
        bias_std_mps: gm.map_or(0.0, |g| g.0),
        bias_time_constant_s: gm.map_or(0.0, |g| g.1),
        white_std_mps: (c[0] - gm.map_or(0.0, |g| g.0 * g.0)).max(1e-6).sqrt(),
        rate_noise_mps_per_radps: rate_noise,
        calibrations: cals,
    })
}

/// A first-order Gauss-Markov process (sigma, tau) plus white noise from the
/// autocovariances `c` at lags 0, 1, 2 of a series sampled every `interval`:
/// e^{-interval/tau} = c_2 / c_1, sigma² = c_1 e^{interval/tau}. `None` when the
/// series has no such part (c_1 <= 0, or c_2 / c_1 outside (0, 1)).
pub fn gauss_markov_from_autocovariance(c: [f64; 3], interval: f64) -> Option<(f64, f64)> {
    let decay = c[2] / c[1];
    (c[1] > 0.0 && decay > 0.0 && decay < 1.0)
        .then(|| ((c[1] / decay).sqrt(), -interval / decay.ln()))
}

/// Median DVL interval over the trajectories \[s\].
fn dvl_interval(dir: &Path, config: &Config, trajectories: &[u32]) -> Result<f64> {
    let mut dts = Vec::new();
    for &n in trajectories {
        let files = trajectory_files(dir, n)?;
        let log = load_dvl_with(&files.dvl, &config.columns)?;
        dts.extend(log.windows(2).map(|w| w[1].time - w[0].time));
    }
    dts.sort_by(f64::total_cmp);
    dts.get(dts.len() / 2)
        .copied()
        .filter(|d| *d > 0.0)
        .ok_or_else(|| PipelineError::NoData {
            what: "DVL interval in the training logs".into(),
        })
}

/// The numbers of one run.
#[derive(Debug, Clone, Serialize)]
pub struct EvaluationRun {
    /// A-KIT trajectory.
    pub trajectory: u32,
    /// Seed.
    pub seed: u64,
    /// Variant id.
    pub id: String,
    /// The IMU the run integrated.
    pub imu_source: ImuSource,
    /// The states with truth NEES is over (15 on a synthesized IMU, 9 on a recorded
    /// one).
    pub nees_states: usize,
    /// Time-averaged NEES over `nees_states` INS states.
    pub nees: f64,
    /// Time-averaged NIS (3 dof).
    pub nis: f64,
    /// Position RMSE \[m\].
    pub position_rmse_m: f64,
    /// DVL updates accepted / rejected by the gate.
    pub accepted: usize,
    /// Rejected.
    pub rejected: usize,
    /// The DVL stamp shift applied \[s\]: the fit's on a synthesized IMU, the vehicle
    /// file's (on the IMU's clock) on a recorded one.
    pub applied_time_offset_s: f64,
    /// Final time-offset estimate beyond the stamp shift \[s\] and its 1-sigma.
    pub time_offset_s: [f64; 2],
    /// Final scale-factor error and its 1-sigma.
    pub scale_factor_error: [f64; 2],
    /// Final DVL noise scale λ (1 without `--adaptive-noise`).
    pub noise_scale: f64,
    /// Position RMSE \[m\] of the 15-state filter of `estim reproduce --data` (no DVL
    /// states, fixed R, the configured time offset) with the same variant and seed:
    /// the same synthesized IMU. NaN when that run stopped.
    pub fifteen_state_position_rmse_m: f64,
}

/// Per trajectory and variant, means over the seeds.
#[derive(Debug, Clone, Serialize)]
pub struct EvaluationRow {
    /// A-KIT trajectory.
    pub trajectory: u32,
    /// Variant id.
    pub id: String,
    /// The IMU its runs integrated (`None` when none completed).
    pub imu_source: Option<ImuSource>,
    /// The states with truth NEES is over.
    pub nees_states: usize,
    /// Runs that completed.
    pub runs: usize,
    /// Mean NEES.
    pub nees: f64,
    /// Mean NIS.
    pub nis: f64,
    /// Mean position RMSE \[m\].
    pub position_rmse_m: f64,
    /// NEES within the band.
    pub nees_in_band: bool,
    /// NIS within the band.
    pub nis_in_band: bool,
    /// Mean final time offset (stamp shift plus state) \[s\].
    pub time_offset_s: f64,
    /// Mean final DVL noise scale λ.
    pub noise_scale: f64,
    /// Mean position RMSE of the 15-state filter on the same seeds \[m\].
    pub fifteen_state_position_rmse_m: f64,
    /// Position RMSE minus the 15-state filter's, paired by seed: the mean and its
    /// 95 % Student t interval over the seeds (the seeds redraw synthetic noise only).
    pub position_rmse_difference_m: PairedInterval,
}

/// Per variant, how many trajectories meet the bands.
#[derive(Debug, Clone, Serialize)]
pub struct EvaluationCount {
    /// Variant id.
    pub id: String,
    /// Trajectories evaluated.
    pub trajectories: usize,
    /// Within [0.5, 2] x the states with truth (NEES).
    pub nees_in_band: usize,
    /// Within [0.5, 2] x 3 (NIS).
    pub nis_in_band: usize,
}

/// The whole evaluation.
#[derive(Debug, Clone, Serialize)]
pub struct Evaluation {
    /// The fit it used.
    pub fit: TrainingFit,
    /// The DVL states (the fit's, or the given ones).
    pub states: DvlStatesConfig,
    /// Memory N of the adaptive DVL noise scale, if adapted.
    pub adaptive_noise_window: Option<usize>,
    /// Seeds.
    pub seeds: Vec<u64>,
    /// Every completed run.
    pub runs: Vec<EvaluationRun>,
    /// Runs that stopped, as text.
    pub failures: Vec<String>,
    /// The DVL time offset of the 15-state comparison runs (`dvl.akit_time_offset_s`)
    /// \[s\].
    pub fifteen_state_time_offset_s: f64,
    /// Per trajectory and variant.
    pub rows: Vec<EvaluationRow>,
    /// Per variant.
    pub counts: Vec<EvaluationCount>,
}

fn in_band(value: f64, dof: f64) -> bool {
    value >= BAND[0] * dof && value <= BAND[1] * dof
}

/// Run the augmented filter on `trajectories` x `seeds` with the fit (and `states`
/// in place of the fitted DVL states when given), with the DVL noise level adapted
/// online when `adaptive_noise` gives its memory in updates (module docs, step 6),
/// on the IMU `imu` selects (module docs, "On a recorded IMU").
///
/// # Errors
/// An empty or repeated trajectory or seed list, a zero memory; `states`, a rate
/// noise or `adaptive_noise` with a recorded IMU; loader and settings errors (a run's
/// numerical failure is recorded in [`Evaluation::failures`]).
#[allow(clippy::too_many_arguments)]
pub fn evaluate(
    dir: &Path,
    config: &Config,
    fit: TrainingFit,
    states: Option<DvlStatesConfig>,
    adaptive_noise: Option<usize>,
    trajectories: &[u32],
    seeds: &[u64],
    imu: &ImuSelection,
) -> Result<Evaluation> {
    let synthesized_only =
        states.is_some() || adaptive_noise.is_some() || fit.rate_noise_mps_per_radps != 0.0;
    check_lists(trajectories, seeds)?;
    let states = states.unwrap_or_else(|| fit.states());
    states.check()?;
    if let Some(window) = adaptive_noise {
        if !(1..=100_000).contains(&window) {
            return Err(PipelineError::Argument {
                flag: "--adaptive-noise".into(),
                reason: format!("{window} is not in 1-100000"),
            });
        }
    }
    let learned = beamsnet_without_sensitivity(config)?;
    let cells: Vec<(u32, u64)> = trajectories
        .iter()
        .flat_map(|t| seeds.iter().map(move |s| (*t, *s)))
        .collect();
    let outcomes: Vec<Vec<std::result::Result<EvaluationRun, String>>> = cells
        .par_iter()
        .map(|&(n, seed)| {
            let mut cfg = Config {
                seed,
                ..config.clone()
            };
            cfg.dvl.akit_time_offset_s = fit.time_offset_s;
            let scenario = Scenario::akit_selected(dir, n, &cfg, seed, imu)?;
            if let Some(recorded) = &scenario.recorded {
                if synthesized_only {
                    return Err(PipelineError::Argument {
                        flag: "--imu".into(),
                        reason: format!(
                            "trajectory {n} runs on its recorded IMU, with the vehicle file's DVL \
                             model: --states, --rate-noise and --adaptive-noise change the \
                             synthesized runs only (give --imu synthesized)"
                        ),
                    });
                }
                return recorded_cell(n, seed, &scenario, recorded, &cfg, learned.as_ref());
            }
            let white = Matrix3::identity() * fit.white_std_mps.powi(2);
            let ls = least_squares_velocities(&scenario, &cfg);
            let ls_r = Matrix3::identity() * cfg.dvl.ls_noise_std.powi(2) + white;
            let net = learned(&scenario)?;
            let net_r = net.noise_covariance + white;
            let baseline = fifteen_state_rmse(dir, n, config, seed, &learned)?;
            let jobs = [(LS, ls, ls_r), (BEAMSNET_NEGLECTED, net.velocities, net_r)];
            jobs.iter()
                .zip(baseline)
                .map(|((id, velocities, r), baseline)| {
                    let run = Run {
                        scenario: &scenario,
                        config: &cfg,
                        fit: &fit,
                        states: &states,
                        adaptive_noise,
                    };
                    run.run(velocities, *r, seed).map(|m| {
                        m.map(|m| EvaluationRun {
                            trajectory: n,
                            seed,
                            id: id.to_string(),
                            fifteen_state_position_rmse_m: baseline,
                            ..m
                        })
                        .map_err(|e| format!("trajectory {n}, seed {seed}, {id}: {e}"))
                    })
                })
                .collect::<Result<Vec<_>>>()
        })
        .collect::<Result<_>>()?;
    let mut runs = Vec::new();
    let mut failures = Vec::new();
    for outcome in outcomes.into_iter().flatten() {
        match outcome {
            Ok(r) => runs.push(r),
            Err(f) => failures.push(f),
        }
    }
    let rows = evaluation_rows(trajectories, &runs, &fit);
    let counts = EVALUATED_VARIANTS
        .iter()
        .map(|id| {
            let mine: Vec<&EvaluationRow> = rows.iter().filter(|r| r.id == *id).collect();
            EvaluationCount {
                id: id.to_string(),
                trajectories: mine.len(),
                nees_in_band: mine.iter().filter(|r| r.nees_in_band).count(),
                nis_in_band: mine.iter().filter(|r| r.nis_in_band).count(),
            }
        })
        .collect();
    Ok(Evaluation {
        fit,
        states,
        adaptive_noise_window: adaptive_noise,
        seeds: seeds.to_vec(),
        runs,
        failures,
        fifteen_state_time_offset_s: config.dvl.akit_time_offset_s,
        rows,
        counts,
    })
}

/// Refuse an empty or repeated trajectory (`--trajectory`) or seed (`--seeds`) list.
fn check_lists(trajectories: &[u32], seeds: &[u64]) -> Result<()> {
    let bad = |flag: &str, reason: String| PipelineError::Argument {
        flag: flag.into(),
        reason,
    };
    let needs = "an evaluation needs at least one trajectory and one seed";
    if trajectories.is_empty() {
        return Err(bad("--trajectory", needs.into()));
    }
    if seeds.is_empty() {
        return Err(bad("--seeds", needs.into()));
    }
    for (i, t) in trajectories.iter().enumerate() {
        if trajectories[..i].contains(t) {
            return Err(bad("--trajectory", format!("trajectory {t} given twice")));
        }
    }
    for (i, s) in seeds.iter().enumerate() {
        if seeds[..i].contains(s) {
            return Err(bad("--seeds", format!("seed {s} given twice")));
        }
    }
    Ok(())
}
