//! A reference trajectory (ground truth) on the navigator's clock, and the evaluation
//! of a run against it: errors and NEES at the reference's own epochs.
//!
//! [`Truth::load`] reads a truth CSV with the vehicle file's `[truth]` table: its
//! clock scale, its time offset (estimated against the IMU's angular rate when not
//! given) and its point, carried to the IMU by `truth.lever_arm_m`. A run scores its
//! solutions with [`Truth::score`] and [`Truth::evaluation`] sums them up.
//!
//! A reference's velocity and positions need not agree: [`velocity_bias`] measures the
//! constant velocity by which its positions move apart from its integrated velocity
//! (on the A-KIT data, 45 mm/s west on trajectory 9, at most 12.5 mm/s per axis on the
//! other training trajectories; docs/results.md). It is always reported, and removed from the
//! reference's velocity before scoring when `truth.remove_velocity_bias` says so.

use std::path::{Path, PathBuf};

use estim_ins::{ErrorMatrix, InsState, Trajectory, TrajectorySample, ATT, ERROR_STATES, POS, VEL};
use nalgebra::Vector3;

use crate::datasets::{load_gt_with, load_times_with};
use crate::navigator::{
    error_state, nees_of_block, reference_time_offset, NavigatorConfig, ReferenceOffset,
};
use crate::survey::{LoadedSurvey, Result, SurveyError};
use crate::survey_checks::seconds;

/// The half-width \[s\] of the search for the reference's clock offset.
pub const TRUTH_TIME_OFFSET_SEARCH_S: f64 = 5.0;

/// The half-width \[s\] of the window of IMU samples whose mean angular rate carries
/// the reference's velocity to the IMU's point ([`Truth::kinematics`]).
pub const LEVER_ARM_RATE_HALF_WINDOW_S: f64 = 0.05;

/// True accelerometer and gyroscope biases of one simulated IMU sample.
type TrueBiases = (Vector3<f64>, Vector3<f64>);

/// The reference's clock offset in effect.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TruthTimeOffset {
    /// `truth.time_offset_s` of the vehicle file \[s\].
    Vehicle(f64),
    /// Estimated against the IMU's angular rate.
    Estimated(ReferenceOffset),
}

/// The reference's velocity against its own positions ([`velocity_bias`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VelocityBias {
    /// North, east, down \[m/s\]: the reference's velocity plus this integrates to its
    /// positions' change (least-squares slope of position minus integrated velocity).
    pub bias_mps: [f64; 3],
    /// Its standard error \[m/s\] from the fit's residuals taken as independent: a
    /// lower bound, as those residuals are correlated in time.
    pub sigma_mps: [f64; 3],
    /// RMS of the residual of that fit \[m\] per axis.
    pub residual_rms_m: [f64; 3],
    /// The reference's intervals used.
    pub intervals: usize,
    /// Whether it was removed from the reference's velocity before scoring
    /// (`truth.remove_velocity_bias`).
    pub removed: bool,
}

/// The constant velocity \[m/s\] (north, east, down) by which the positions of the
/// time-ordered `samples` move apart from their integrated velocity: the least-squares
/// slope over time of d(t_k) = (p(t_k) - p(t_0)) - integral of v from t_0 to t_k, the
/// position change taken in the local north, east, down frame of each interval's
/// midpoint and the velocity integrated by the trapezoid rule (exact for a velocity
/// linear over the interval). `None` with fewer than 3 samples, or non-increasing times.
pub fn velocity_bias(samples: &[TrajectorySample]) -> Option<VelocityBias> {
    if samples.len() < 3
        || samples
            .windows(2)
            .any(|w| w[1].time.partial_cmp(&w[0].time) != Some(std::cmp::Ordering::Greater))
    {
        return None;
    }
    let mut d = Vector3::zeros();
    let mut points = vec![(samples[0].time, d)];
    for w in samples.windows(2) {
        d += interval_mismatch(&w[0], &w[1]);
        points.push((w[1].time, d));
    }
    let n = points.len() as f64;
    let t_mean = points.iter().map(|p| p.0).sum::<f64>() / n;
    let d_mean = points.iter().map(|p| p.1).sum::<Vector3<f64>>() / n;
    let stt: f64 = points.iter().map(|p| (p.0 - t_mean).powi(2)).sum();
    let slope = points
        .iter()
        .map(|p| (p.1 - d_mean) * (p.0 - t_mean))
        .sum::<Vector3<f64>>()
        / stt;
    let residual_square = points
        .iter()
        .map(|p| (p.1 - d_mean - slope * (p.0 - t_mean)).map(|r| r * r))
        .sum::<Vector3<f64>>();
    let sigma = residual_square.map(|r| (r / (n - 2.0) / stt).sqrt());
    let rms = residual_square.map(|r| (r / n).sqrt());
    Some(VelocityBias {
        bias_mps: slope.into(),
        sigma_mps: sigma.into(),
        residual_rms_m: rms.into(),
        intervals: samples.len() - 1,
        removed: false,
    })
}

/// The position change from `a` to `b` (north, east, down \[m\], in the local frame
/// of the interval's midpoint) less their velocity integrated by the trapezoid rule.
fn interval_mismatch(a: &TrajectorySample, b: &TrajectorySample) -> Vector3<f64> {
    let latitude = 0.5 * (a.latitude + b.latitude);
    let height = 0.5 * (a.height + b.height);
    let (rn, re) = estim_ins::earth::radii_of_curvature(latitude);
    let moved = Vector3::new(
        (b.latitude - a.latitude) * (rn + height),
        (b.longitude - a.longitude) * (re + height) * latitude.cos(),
        -(b.height - a.height),
    );
    moved - 0.5 * (a.velocity_ned + b.velocity_ned) * (b.time - a.time)
}

/// A reference row whose position jumps: it moved from the row before by more than
/// its velocity says ([`position_jumps`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PositionJump {
    /// The row (1 = the first data row).
    pub row: usize,
    /// |position change - integrated velocity| over the interval that ends there \[m\].
    pub mismatch_m: f64,
    /// The median of that figure over the reference's intervals \[m\].
    pub median_m: f64,
}

/// Smallest mismatch \[m\] that [`position_jumps`] reports.
pub const POSITION_JUMP_MIN_M: f64 = 5.0;

/// How many times the median interval's mismatch a jump is at least.
pub const POSITION_JUMP_MEDIANS: f64 = 100.0;

/// The intervals of the time-ordered `samples` over which the position changes by
/// more than the velocity integrates to (trapezoid rule, as in [`velocity_bias`]) by
/// over [`POSITION_JUMP_MIN_M`] and [`POSITION_JUMP_MEDIANS`] times the median interval's
/// mismatch: a jump in the reference's positions, whose errors there are the
/// reference's. (On the A-KIT training references the largest is 1.1 m and 36 times
/// the median.) Empty with fewer than 3 samples.
pub fn position_jumps(samples: &[TrajectorySample]) -> Vec<PositionJump> {
    if samples.len() < 3 {
        return Vec::new();
    }
    let mismatch: Vec<f64> = samples
        .windows(2)
        .map(|w| interval_mismatch(&w[0], &w[1]).norm())
        .collect();
    let mut sorted: Vec<f64> = mismatch.iter().copied().filter(|m| m.is_finite()).collect();
    sorted.sort_by(f64::total_cmp);
    let Some(&median) = sorted.get(sorted.len() / 2) else {
        return Vec::new();
    };
    let limit = POSITION_JUMP_MIN_M.max(POSITION_JUMP_MEDIANS * median);
    mismatch
        .iter()
        .enumerate()
        .filter(|(_, &m)| m > limit)
        .map(|(k, &m)| PositionJump {
            row: k + 2,
            mismatch_m: m,
            median_m: median,
        })
        .collect()
}

/// `state` at the reference's point carried to the IMU's, `lever_arm` (the
/// reference's point seen from the IMU, body frame) behind it: the position less
/// C_b^n l; velocity and attitude as they are.
fn carried(mut state: InsState, lever_arm: &Vector3<f64>) -> InsState {
    let offset = state.attitude * lever_arm;
    let (rn, re) = estim_ins::earth::radii_of_curvature(state.latitude);
    state.latitude -= offset.x / (rn + state.height);
    state.longitude -= offset.y / ((re + state.height) * state.latitude.cos());
    state.height += offset.z;
    state
}

impl TruthTimeOffset {
    /// The offset \[s\]: a reference row stamped t refers to navigator time t - offset.
    pub fn offset_s(&self) -> f64 {
        match self {
            Self::Vehicle(tau) => *tau,
            Self::Estimated(e) => e.offset_s,
        }
    }
}

/// The evaluation of a run against the truth (every mean over the finite values).
#[derive(Debug, Clone, PartialEq)]
pub struct Evaluation {
    /// Epochs scored.
    pub epochs: usize,
    /// Solutions outside the reference's span (not scored).
    pub epochs_outside_truth: usize,
    /// RMS of the 3-D position error \[m\] (`None` with no epoch scored).
    pub position_rmse_m: Option<f64>,
    /// RMS of the horizontal position error \[m\].
    pub horizontal_position_rmse_m: Option<f64>,
    /// The last scored 3-D position error \[m\].
    pub final_position_error_m: Option<f64>,
    /// Mean NEES over [`Evaluation::nees_states`] states.
    pub nees_average: Option<f64>,
    /// The states with truth: 15 with a simulated IMU's true biases, else 9 (position,
    /// velocity, attitude).
    pub nees_states: usize,
    /// Mean NEES of the position, velocity and attitude blocks (3 states each).
    pub nees_per_group: [Option<f64>; 3],
    /// Epochs whose covariance block was not positive definite (NEES not defined).
    pub covariance_not_positive_definite_epochs: usize,
}

/// The truth for an evaluation: the reference's spline on the navigator's clock
/// through the reference's own point (carried to the IMU's point where it is
/// evaluated), and (for a simulated IMU) the true biases; it keeps the scores of the
/// solutions passed to [`Truth::score`].
#[derive(Clone)]
pub struct Truth {
    path: PathBuf,
    trajectory: Trajectory,
    /// The reference's point relative to the IMU, body frame \[m\].
    lever_arm: Vector3<f64>,
    /// The IMU's samples (navigator clock, body-frame angular rate \[rad/s\]).
    rates: Vec<(f64, Vector3<f64>)>,
    epochs: Vec<f64>,
    span: [f64; 2],
    biases: Option<(Vec<f64>, Vec<TrueBiases>)>,
    time_offset: TruthTimeOffset,
    velocity_bias: Option<VelocityBias>,
    jumps: Vec<PositionJump>,
    position_error: Vec<f64>,
    horizontal_error: Vec<f64>,
    nees: Vec<f64>,
    group_nees: [Vec<f64>; 3],
    rows: Vec<[f64; 19]>,
    not_positive_definite: usize,
    outside: usize,
}

impl std::fmt::Debug for Truth {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Truth")
            .field("path", &self.path)
            .field("epochs", &self.epochs.len())
            .field("span", &self.span)
            .field("time_offset", &self.time_offset)
            .field("scored", &self.position_error.len())
            .finish_non_exhaustive()
    }
}

impl Truth {
    /// Read the truth CSV `path` onto the clock of `survey` (times relative to its
    /// epoch), scaled by `truth.clock_scale`, shifted by `truth.time_offset_s` (else by
    /// the offset estimated against the IMU's angular rate within
    /// +-[`TRUTH_TIME_OFFSET_SEARCH_S`]), its positions carried from the reference's
    /// point to the IMU by `truth.lever_arm_m`; its velocity's bias against its positions
    /// ([`velocity_bias`]) is measured, and removed when `truth.remove_velocity_bias`.
    ///
    /// # Errors
    /// The reader's errors (file and line); [`SurveyError::Truth`] when its clock cannot
    /// be aligned to the IMU's or its rows do not make a trajectory.
    pub fn load(path: &Path, survey: &LoadedSurvey, config: &NavigatorConfig) -> Result<Self> {
        let (epoch, imu) = (survey.epoch, &survey.inputs.imu);
        let fail = |reason: String| SurveyError::Truth {
            path: path.to_path_buf(),
            reason,
        };
        let gt = load_gt_with(path, &config.columns)?;
        // The GT times on the navigator's clock, read on their digits.
        let times = load_times_with(path, epoch, &config.columns)?;
        if times.len() != gt.len() {
            return Err(fail(format!(
                "{} time cells for {} rows",
                times.len(),
                gt.len()
            )));
        }
        let c = &config.truth;
        // The stamp the clock scale acts about, on the navigator's clock.
        let t0 = c
            .clock_origin_s
            .map_or(times.first().copied().unwrap_or(0.0), |o| o - epoch);
        let lever = Vector3::from(c.lever_arm_m);
        let mut samples: Vec<TrajectorySample> = gt
            .iter()
            .zip(&times)
            .map(|(g, &t)| {
                // The spline runs through the reference's own point, to which both its
                // positions and its velocities refer; [`Truth::kinematics`] carries it
                // to the IMU.
                let mut s = g.trajectory_sample();
                s.time = t0 + c.clock_scale * (t - t0);
                s
            })
            .collect();
        let broken = samples.iter().zip(&times).enumerate().find(|(k, (s, &t))| {
            !s.time.is_finite() || (*k > 0 && t > times[k - 1] && s.time <= samples[k - 1].time)
        });
        if let Some((k, (s, &t))) = broken {
            return Err(fail(format!(
                "truth.clock_origin_s: with clock_scale {} about stamp {:e} the data row {} \
                 stamped {} s maps to {:e} s, not after the row before it or not finite: the \
                 origin is too far from the reference's stamps",
                c.clock_scale,
                t0 + epoch,
                k + 1,
                t + epoch,
                s.time + epoch
            )));
        }
        let jumps = position_jumps(&samples);
        let mut velocity_bias = velocity_bias(&samples);
        if let Some(b) = velocity_bias.as_mut().filter(|_| c.remove_velocity_bias) {
            let bias = Vector3::from(b.bias_mps);
            for s in &mut samples {
                s.velocity_ned += bias;
            }
            b.removed = true;
        }
        let time_offset = match c.time_offset_s {
            Some(tau) => TruthTimeOffset::Vehicle(tau),
            None => TruthTimeOffset::Estimated(
                reference_time_offset(imu, &samples, TRUTH_TIME_OFFSET_SEARCH_S)
                    .map_err(|e| fail(format!("cannot align its clock to the IMU's: {e}")))?,
            ),
        };
        let tau = time_offset.offset_s();
        for s in &mut samples {
            s.time -= tau;
        }
        let span = [
            samples.first().map_or(0.0, |s| s.time),
            samples.last().map_or(0.0, |s| s.time),
        ];
        // A configured offset that moves the reference off the IMU's span, or so far
        // that its stamps no longer increase, is refused naming the key.
        let shifted_apart = samples
            .iter()
            .enumerate()
            .any(|(k, s)| !s.time.is_finite() || (k > 0 && s.time <= samples[k - 1].time));
        let imu_span = [
            imu.first().map_or(0.0, |s| s.time),
            imu.last().map_or(0.0, |s| s.time),
        ];
        if let TruthTimeOffset::Vehicle(tau) = time_offset {
            if shifted_apart || span[1] < imu_span[0] || span[0] > imu_span[1] {
                return Err(fail(format!(
                    "truth.time_offset_s = {} s puts the reference at {}..{} s, outside \
                     the IMU's span {}..{} s",
                    seconds(tau),
                    seconds(span[0] + epoch),
                    seconds(span[1] + epoch),
                    seconds(imu_span[0] + epoch),
                    seconds(imu_span[1] + epoch)
                )));
            }
        }
        let epochs = samples.iter().map(|s| s.time).collect();
        let trajectory = Trajectory::new(samples).map_err(|e| fail(e.to_string()))?;
        let biases = survey
            .true_biases
            .clone()
            .map(|b| (imu.iter().map(|s| s.time).collect(), b));
        Ok(Self {
            path: path.to_path_buf(),
            trajectory,
            lever_arm: lever,
            rates: imu.iter().map(|s| (s.time, s.angular_rate)).collect(),
            epochs,
            span,
            biases,
            time_offset,
            velocity_bias,
            jumps,
            position_error: Vec::new(),
            horizontal_error: Vec::new(),
            nees: Vec::new(),
            group_nees: [Vec::new(), Vec::new(), Vec::new()],
            rows: Vec::new(),
            not_positive_definite: 0,
            outside: 0,
        })
    }

    /// The file it was read from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The reference's own epochs on the navigator's clock.
    pub fn epochs(&self) -> &[f64] {
        &self.epochs
    }

    /// The reference's first and last epoch on the navigator's clock.
    pub fn span(&self) -> [f64; 2] {
        self.span
    }

    /// The reference's clock offset in effect.
    pub fn time_offset(&self) -> &TruthTimeOffset {
        &self.time_offset
    }

    /// The reference's velocity bias against its positions (`None` with fewer than 3
    /// rows).
    pub fn velocity_bias(&self) -> Option<&VelocityBias> {
        self.velocity_bias.as_ref()
    }

    /// The rows where the reference's position jumps against its velocity
    /// ([`position_jumps`]): the evaluation there scores the reference's error.
    pub fn position_jumps(&self) -> &[PositionJump] {
        &self.jumps
    }

    /// The states the truth has: 15 with a simulated IMU's true biases, else 9.
    pub fn nees_states(&self) -> usize {
        if self.biases.is_some() {
            ERROR_STATES
        } else {
            9
        }
    }

    /// The IMU's mean angular rate over its samples within
    /// +-[`LEVER_ARM_RATE_HALF_WINDOW_S`] of `time` (`None` where it has none).
    fn measured_rate(&self, time: f64) -> Option<Vector3<f64>> {
        let h = LEVER_ARM_RATE_HALF_WINDOW_S;
        let lo = self.rates.partition_point(|r| r.0 < time - h);
        let hi = self.rates.partition_point(|r| r.0 <= time + h);
        let window = self.rates.get(lo..hi).filter(|w| !w.is_empty())?;
        let sum: Vector3<f64> = window.iter().map(|r| r.1).sum();
        Some(sum / window.len() as f64)
    }

    /// The truth at `time` with its error-free specific force at the IMU (`None`
    /// outside the reference's span).
    ///
    /// The reference's velocity is its point's; the IMU's lacks C_b^n (omega x l).
    /// omega is the IMU's own measured angular rate about `time`: a reference sampled
    /// at 1 Hz does not resolve the vehicle's rotation above 0.5 Hz (waves near the
    /// surface), and with l about 2 m its spline's rate would carry that error, times
    /// 2 m, into the velocity there. The spline's rate stands in where the IMU has no
    /// sample.
    ///
    /// # Errors
    /// The spline's error for a time it cannot evaluate.
    pub fn kinematics(
        &self,
        time: f64,
    ) -> std::result::Result<Option<(InsState, Vector3<f64>)>, estim_ins::Error> {
        if !(time >= self.span[0] && time <= self.span[1]) {
            return Ok(None);
        }
        let kinematics = self.trajectory.evaluate(time)?;
        let w = kinematics.angular_rate;
        let mut state = carried(kinematics.state, &self.lever_arm);
        let measured = self.measured_rate(time).unwrap_or(w);
        state.velocity_ned -= state.attitude * measured.cross(&self.lever_arm);
        if let Some((times, biases)) = &self.biases {
            let i = times
                .partition_point(|&t| t < time)
                .min(biases.len().saturating_sub(1));
            if let Some(b) = biases.get(i) {
                state.acc_bias = b.0;
                state.gyro_bias = b.1;
            }
        }
        // The specific force at the IMU: the reference point's less the lever arm's
        // centripetal term (the angular acceleration's term is below the spline's
        // resolution at 1 Hz and left out).
        let force = kinematics.specific_force - w.cross(&w.cross(&self.lever_arm));
        Ok(Some((state, force)))
    }

    /// The truth at `time` (`None` outside the reference's span).
    ///
    /// # Errors
    /// As [`Truth::kinematics`].
    pub fn at(&self, time: f64) -> std::result::Result<Option<InsState>, estim_ins::Error> {
        Ok(self.kinematics(time)?.map(|(state, _)| state))
    }

    /// The reference's track: latitude, longitude \[deg\] (at the IMU's point) at its
    /// own epochs within `[from, to]` (the navigator's clock).
    pub fn track_deg(&self, from: f64, to: f64) -> Vec<[f64; 2]> {
        self.epochs
            .iter()
            .filter(|&&t| t >= from && t <= to)
            .filter_map(|&t| self.trajectory.evaluate(t).ok())
            .map(|k| carried(k.state, &self.lever_arm))
            .map(|s| [s.latitude.to_degrees(), s.longitude.to_degrees()])
            .collect()
    }

    /// Score a solution (nominal `state`, error `covariance`) at `time`; counted apart
    /// when outside the reference's span.
    ///
    /// # Errors
    /// As [`Truth::kinematics`].
    pub fn score(
        &mut self,
        time: f64,
        state: &InsState,
        covariance: &ErrorMatrix,
    ) -> std::result::Result<(), estim_ins::Error> {
        let Some(t) = self.at(time)? else {
            self.outside += 1;
            return Ok(());
        };
        let e = error_state(&t, state);
        self.position_error.push(e.fixed_rows::<3>(POS).norm());
        self.horizontal_error.push(e.fixed_rows::<2>(POS).norm());
        match nees_of_block(&e, covariance, 0, self.nees_states()) {
            Some(v) => self.nees.push(v),
            None => {
                self.nees.push(f64::NAN);
                self.not_positive_definite += 1;
            }
        }
        let mut row = [0.0; 19];
        row[0] = time;
        for i in 0..9 {
            let degrees = if i >= ATT {
                180.0 / std::f64::consts::PI
            } else {
                1.0
            };
            row[1 + i] = e[i] * degrees;
            row[10 + i] = covariance[(i, i)].max(0.0).sqrt() * degrees;
        }
        self.rows.push(row);
        for (g, start) in [POS, VEL, ATT].into_iter().enumerate() {
            let v = nees_of_block(&e, covariance, start, 3);
            self.group_nees[g].push(v.unwrap_or(f64::NAN));
        }
        Ok(())
    }

    /// Per scored epoch: the time, the 9 errors (position N, E, D \[m\], velocity
    /// N, E, D \[m/s\], misalignment about N, E, D \[deg\]) and their 9 1-sigmas.
    pub fn rows(&self) -> &[[f64; 19]] {
        &self.rows
    }

    /// The NEES of each scored epoch over [`Truth::nees_states`] states (`NaN` where
    /// the covariance block was not positive definite).
    pub fn nees(&self) -> &[f64] {
        &self.nees
    }

    /// The scores so far, summed up.
    pub fn evaluation(&self) -> Evaluation {
        let rms = |values: &[f64]| {
            (!values.is_empty())
                .then(|| (values.iter().map(|e| e * e).sum::<f64>() / values.len() as f64).sqrt())
        };
        let mean = |values: &[f64]| {
            let finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
            (!finite.is_empty()).then(|| finite.iter().sum::<f64>() / finite.len() as f64)
        };
        Evaluation {
            epochs: self.position_error.len(),
            epochs_outside_truth: self.outside,
            position_rmse_m: rms(&self.position_error),
            horizontal_position_rmse_m: rms(&self.horizontal_error),
            final_position_error_m: self.position_error.last().copied(),
            nees_average: mean(&self.nees),
            nees_states: self.nees_states(),
            nees_per_group: [
                mean(&self.group_nees[0]),
                mean(&self.group_nees[1]),
                mean(&self.group_nees[2]),
            ],
            covariance_not_positive_definite_epochs: self.not_positive_definite,
        }
    }

    /// The state of the truth at its first epoch inside the IMU's span of `survey`
    /// (the truth is exact there, interpolated between), written into `config`'s
    /// `[initial]` (time in the inputs' own time, position, velocity, attitude).
    ///
    /// # Errors
    /// [`SurveyError::Truth`] when the first IMU sample is outside the truth's span.
    pub fn set_initial(&self, survey: &LoadedSurvey, config: &mut NavigatorConfig) -> Result<()> {
        let epoch = survey.epoch;
        let imu_start = survey.inputs.imu.first().map_or(0.0, |s| s.time);
        let first = self
            .epochs
            .iter()
            .copied()
            .find(|&t| t >= imu_start)
            .unwrap_or(imu_start);
        let outside = || SurveyError::Truth {
            path: self.path.clone(),
            reason: format!(
                "cannot set the initial state: the first IMU sample (t = {:.3} s) is outside \
                 the truth's span ({:.3}..{:.3} s)",
                epoch + first,
                epoch + self.span[0],
                epoch + self.span[1]
            ),
        };
        let state = self
            .at(first)
            .map_err(|e| SurveyError::Truth {
                path: self.path.clone(),
                reason: e.to_string(),
            })?
            .ok_or_else(outside)?;
        let (roll, pitch, yaw) = state.roll_pitch_yaw();
        let i = &mut config.initial;
        i.time_s = Some(epoch + first);
        i.latitude_deg = Some(state.latitude.to_degrees());
        i.longitude_deg = Some(state.longitude.to_degrees());
        i.depth_m = Some(-state.height);
        i.velocity_ned_mps = state.velocity_ned.into();
        i.attitude_deg = Some([roll, pitch, yaw].map(f64::to_degrees));
        Ok(())
    }
}

/// Read a vehicle TOML into a [`NavigatorConfig`]; errors name the file and line.
///
/// # Errors
/// [`SurveyError::Dataset`] when the file cannot be read; [`SurveyError::Vehicle`] for
/// TOML that is not a vehicle configuration (an unknown key, a wrong type).
pub fn read_vehicle(path: &Path) -> Result<NavigatorConfig> {
    let text = crate::datasets::read_text_file(path)?;
    toml::from_str::<NavigatorConfig>(&text).map_err(|e| SurveyError::Vehicle {
        path: path.to_path_buf(),
        line: e
            .span()
            .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1),
        message: e.message().to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    /// A vehicle turning on a circle (radius 40 m, 2 m/s) while it climbs and dives,
    /// sampled at 1 Hz for 600 s: positions from the closed-form path, the velocity its
    /// derivative plus `bias` (north, east, down).
    fn circle(bias: Vector3<f64>) -> Vec<TrajectorySample> {
        let (latitude0, longitude0, height0) = (0.57_f64, 0.61_f64, -20.0);
        let (rn, re) = estim_ins::earth::radii_of_curvature(latitude0);
        let (radius, omega) = (40.0, 0.05);
        (0..=600)
            .map(|k| {
                let t = f64::from(k);
                let north = radius * (omega * t).sin();
                let east = radius * (1.0 - (omega * t).cos());
                let down = 3.0 * (0.02 * t).sin();
                let height = height0 - down;
                let latitude = latitude0 + north / (rn + height);
                let longitude = longitude0 + east / ((re + height) * latitude.cos());
                let velocity = Vector3::new(
                    radius * omega * (omega * t).cos(),
                    radius * omega * (omega * t).sin(),
                    0.06 * (0.02 * t).cos(),
                );
                TrajectorySample {
                    time: 100.0 + t,
                    latitude,
                    longitude,
                    height,
                    velocity_ned: velocity + bias,
                    attitude: UnitQuaternion::identity(),
                }
            })
            .collect()
    }

    /// A row moved 12 m north is found on both of its intervals with a mismatch of
    /// 12 m (to the trapezoid rule's centimetres on this circle); 3 m (under the 5 m
    /// floor) and the clean circle, at 1 Hz or at 0.1 Hz, give none.
    #[test]
    fn a_jump_in_the_references_positions_is_found_on_its_rows() {
        assert!(position_jumps(&circle(Vector3::zeros())).is_empty());
        let coarse: Vec<TrajectorySample> =
            circle(Vector3::zeros()).into_iter().step_by(10).collect();
        assert!(position_jumps(&coarse).is_empty());
        let moved = |metres: f64| {
            let mut samples = circle(Vector3::zeros());
            let s = &mut samples[300];
            let (rn, _) = estim_ins::earth::radii_of_curvature(s.latitude);
            s.latitude += metres / (rn + s.height);
            samples
        };
        let jumps = position_jumps(&moved(12.0));
        assert_eq!(jumps.len(), 2, "{jumps:?}");
        // Sample 300 is data row 301; the intervals into and out of it.
        assert_eq!((jumps[0].row, jumps[1].row), (301, 302));
        for j in &jumps {
            assert!((j.mismatch_m - 12.0).abs() < 0.1, "{j:?}");
            assert!(j.median_m < 0.1, "{j:?}");
        }
        assert!(position_jumps(&moved(3.0)).is_empty());
        assert!(position_jumps(&circle(Vector3::zeros())[..2]).is_empty());
    }

    #[test]
    fn a_velocity_consistent_with_the_positions_has_no_bias() {
        let b = velocity_bias(&circle(Vector3::zeros())).unwrap();
        assert_eq!(b.intervals, 600);
        for axis in 0..3 {
            // The trapezoid rule's error on this path (v'' = omega^2 v) and the
            // curvature radii's change over 80 m keep it under 0.2 mm/s.
            assert!(b.bias_mps[axis].abs() < 2e-4, "{:?}", b.bias_mps);
            assert!(b.residual_rms_m[axis] < 0.05, "{:?}", b.residual_rms_m);
        }
    }

    #[test]
    fn a_constant_velocity_error_is_recovered_with_its_sign() {
        let injected = Vector3::new(-0.025, 0.045, 0.003);
        let b = velocity_bias(&circle(injected)).unwrap();
        // The reference's velocity plus the bias follows its positions.
        for axis in 0..3 {
            assert!(
                (b.bias_mps[axis] + injected[axis]).abs() < 2e-4,
                "{:?} against {injected:?}",
                b.bias_mps
            );
        }
        assert!(!b.removed);
    }

    /// The reference's velocity is carried to the IMU with the IMU's measured angular
    /// rate, which the 1 Hz reference cannot resolve: a pitch oscillation at exactly
    /// 1 Hz is at the same phase at every reference epoch, so the reference is level
    /// throughout and its spline's rate is zero.
    #[test]
    fn the_velocity_is_carried_with_the_imus_measured_rate() {
        let dir = tempfile::tempdir().unwrap();
        let gt = dir.path().join("gt.csv");
        let (latitude0, speed) = (0.57_f64, 1.5);
        let mut text = String::from(
            "Time [s],Longitude [rad],Latitude [rad],Altitude [m],V North [m/s],\
             V East [m/s],V Down [m/s],Roll [rad],Pitch [rad],Yaw [rad]\n",
        );
        for k in 0..=60 {
            let t = f64::from(k);
            let latitude = latitude0 + speed * t / 6_378_137.0;
            text.push_str(&format!("{t},0.61,{latitude},-20,{speed},0,0,0,0,0\n"));
        }
        std::fs::write(&gt, text).unwrap();
        let amplitude = 0.2;
        let rate = |t: f64| amplitude * (2.0 * std::f64::consts::PI * t).cos();
        let imu: Vec<estim_ins::ImuSample> = (0..6000)
            .map(|j| {
                // Stamps half a period off the reference's, clear of the window's edges.
                let t = f64::from(j) * 0.01 + 0.005;
                estim_ins::ImuSample::new(
                    t,
                    Vector3::new(0.0, 0.0, -9.8),
                    Vector3::new(0.0, rate(t), 0.0),
                )
            })
            .collect();
        let mut config = NavigatorConfig::default();
        config.truth.lever_arm_m = [2.0, 0.0, 0.5];
        config.truth.time_offset_s = Some(0.0);
        let truth = Truth::load(&gt, &survey(imu, &config), &config).unwrap();
        for k in [10, 30, 45] {
            let t = f64::from(k);
            // The samples within 0.05 s of t: t + 0.005 + j / 100, j = -5..=4.
            let mean = (-5..=4)
                .map(|j| rate(t + 0.005 + f64::from(j) * 0.01))
                .sum::<f64>()
                / 10.0;
            // omega x l with omega = (0, w, 0), l = (2, 0, 0.5): (0.5 w, 0, -2 w).
            let expected = Vector3::new(speed - 0.5 * mean, 0.0, 2.0 * mean);
            let v = truth.at(t).unwrap().unwrap().velocity_ned;
            assert!(
                (v - expected).norm() < 1e-9,
                "t = {t}: {v:?} against {expected:?}"
            );
            assert!(mean > 0.19, "{mean}");
        }
    }

    /// A survey of `imu` alone on epoch 0.
    fn survey(imu: Vec<estim_ins::ImuSample>, config: &NavigatorConfig) -> LoadedSurvey {
        LoadedSurvey {
            inputs: crate::navigator::SurveyInputs {
                imu,
                dvl: Vec::new(),
                depth: Vec::new(),
                fixes: Vec::new(),
                output_epochs: Vec::new(),
            },
            settings: config.check().unwrap(),
            epoch: 0.0,
            true_biases: None,
            pd0: None,
        }
    }

    /// A reference cut to start at 20 s, on a clock that runs 1.01 times the
    /// navigator's from stamp 0: with `clock_origin_s = 0` its epochs are 1.01 t - tau;
    /// without, the scale acts about its first stamp, 20 + 1.01 (t - 20) - tau.
    #[test]
    fn the_reference_clock_scale_acts_about_its_origin() {
        let dir = tempfile::tempdir().unwrap();
        let gt = dir.path().join("gt.csv");
        let mut text = String::from(
            "Time [s],Longitude [rad],Latitude [rad],Altitude [m],V North [m/s],\
             V East [m/s],V Down [m/s],Roll [rad],Pitch [rad],Yaw [rad]\n",
        );
        for k in 20..=40 {
            let latitude = 0.57 + f64::from(k) / 6_378_137.0;
            text.push_str(&format!("{k},0.61,{latitude},-20,1,0,0,0,0,0\n"));
        }
        std::fs::write(&gt, text).unwrap();
        let imu = (0..6000)
            .map(|j| {
                let (f, w) = (Vector3::new(0.0, 0.0, -9.8), Vector3::zeros());
                estim_ins::ImuSample::new(f64::from(j) * 0.01, f, w)
            })
            .collect::<Vec<_>>();
        let mut config = NavigatorConfig::default();
        config.truth.clock_scale = 1.01;
        config.truth.time_offset_s = Some(0.3);
        let about_first = Truth::load(&gt, &survey(imu.clone(), &config), &config).unwrap();
        config.truth.clock_origin_s = Some(0.0);
        let about_zero = Truth::load(&gt, &survey(imu, &config), &config).unwrap();
        for (k, (a, z)) in about_first
            .epochs()
            .iter()
            .zip(about_zero.epochs())
            .enumerate()
        {
            let t = 20.0 + k as f64;
            assert!(
                (a - (20.0 + 1.01 * (t - 20.0) - 0.3)).abs() < 1e-9,
                "{t}: {a}"
            );
            assert!((z - (1.01 * t - 0.3)).abs() < 1e-9, "{t}: {z}");
        }
        assert_eq!(about_zero.epochs().len(), 21);
        // An origin that loses the stamps' digits is refused, naming the key.
        config.truth.clock_origin_s = Some(1e300);
        let imu = (0..100)
            .map(|j| {
                let (f, w) = (Vector3::new(0.0, 0.0, -9.8), Vector3::zeros());
                estim_ins::ImuSample::new(f64::from(j) * 0.01, f, w)
            })
            .collect::<Vec<_>>();
        let error = Truth::load(&gt, &survey(imu, &config), &config)
            .unwrap_err()
            .to_string();
        assert!(error.contains("truth.clock_origin_s"), "{error}");
    }

    #[test]
    fn too_few_or_unordered_samples_have_no_bias() {
        let samples = circle(Vector3::zeros());
        assert!(velocity_bias(&samples[..2]).is_none());
        let mut unordered = samples[..10].to_vec();
        unordered.swap(3, 4);
        assert!(velocity_bias(&unordered).is_none());
    }
}
