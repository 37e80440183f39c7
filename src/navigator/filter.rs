//! [`Navigator`]: the 15-state INS error-state filter fed sample by sample.

use estim_core::noise::adaptive::NoiseScale;
use estim_core::{
    CrossCovariance, ErrorStateKalmanFilter, NoObserver, Observer, UpdateReport, Zero,
};
use estim_dvl::DvlVelocityModel;
use estim_ins::{
    ErrorMatrix, ImuSample, InsErrorModel, InsState, ACC_BIAS, ATT, ERROR_STATES, GYRO_BIAS, POS,
    VEL,
};
use nalgebra::{Vector3, Vector4};
use serde::Serialize;

use super::aiding::{DepthModel, PositionFixModel, FIX_MEASUREMENT};
use super::{NavigatorError, NavigatorSettings, Result};

/// Largest relative difference between a timestamp difference and the nominal IMU
/// period for which the nominal period is used as dt (timestamps are a fixed-rate
/// clock written in floating point; this keeps a run independent of their rounding).
pub const IMU_PERIOD_SNAP: f64 = 1e-6;

/// The filter type the navigator owns.
pub type InsFilter<O> = ErrorStateKalmanFilter<f64, InsErrorModel, ERROR_STATES, O>;

/// The DVL update's cross-covariance source (15 x 3).
pub type DvlCross<'a> = dyn CrossCovariance<f64, InsState, ERROR_STATES, 3> + 'a;

/// Counts of what the navigator did with its inputs.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct UpdateCounts {
    /// Updates accepted (including recovered ones).
    pub accepted: usize,
    /// Updates rejected by the innovation gate.
    pub gated: usize,
    /// Updates the gate would have rejected, accepted with P inflated after a run of
    /// rejections (`gate.recovery_after`).
    pub recovered: usize,
}

impl UpdateCounts {
    pub(crate) fn count<const N: usize, const M: usize>(
        &mut self,
        report: &UpdateReport<f64, N, M>,
    ) {
        if report.is_accepted() {
            self.accepted += 1;
            if report.covariance_inflation.is_some() {
                self.recovered += 1;
            }
        } else {
            self.gated += 1;
        }
    }
}

/// The IMU timing both navigators share: the time the state refers to, the sample in
/// effect and the nominal period. It decides what to integrate; the navigator
/// integrates it and then advances the clock.
#[derive(Debug, Clone, Copy)]
pub(super) struct ImuClock {
    period: f64,
    tolerance: f64,
    clock: f64,
    held: Option<ImuSample>,
}

impl ImuClock {
    /// A clock at `start` for a nominal period `period` \[s\].
    ///
    /// # Errors
    /// [`NavigatorError::Config`] for a period that is not positive and finite.
    pub(super) fn new(period: f64, start: f64) -> Result<Self> {
        if !(period.is_finite() && period > 0.0) {
            return Err(NavigatorError::Config(format!(
                "IMU period {period} s is not positive and finite"
            )));
        }
        Ok(Self {
            period,
            tolerance: IMU_PERIOD_SNAP * period,
            clock: start,
            held: None,
        })
    }

    /// The time the state refers to \[s\].
    pub(super) fn time(&self) -> f64 {
        self.clock
    }

    /// The nominal period \[s\].
    pub(super) fn period(&self) -> f64 {
        self.period
    }

    /// The sample in effect.
    pub(super) fn held(&self) -> Option<&ImuSample> {
        self.held.as_ref()
    }

    /// The step from the clock to `end`: the held sample and dt (the nominal period
    /// when within [`IMU_PERIOD_SNAP`] of it).
    ///
    /// # Errors
    /// [`NavigatorError::NoImu`] before the first sample.
    pub(super) fn step(&self, end: f64) -> Result<(ImuSample, f64)> {
        // Nothing to integrate before the first sample.
        let sample = self.held.ok_or(NavigatorError::NoImu { time: end })?;
        let dt = end - self.clock;
        if (dt - self.period).abs() <= self.tolerance {
            Ok((sample, self.period))
        } else {
            Ok((sample, dt))
        }
    }

    /// Move the clock to `end` (after its step was integrated).
    pub(super) fn advance(&mut self, end: f64) {
        self.clock = end;
    }

    /// Whether `sample` needs a step to its time before it is held.
    ///
    /// # Errors
    /// [`NavigatorError::NonFinite`], [`NavigatorError::TimeOrder`].
    pub(super) fn sample_needs_step(&self, sample: &ImuSample) -> Result<bool> {
        let finite = sample.time.is_finite()
            && sample.specific_force.iter().all(|v| v.is_finite())
            && sample.angular_rate.iter().all(|v| v.is_finite());
        if !finite {
            return Err(NavigatorError::NonFinite {
                what: "IMU sample",
                time: sample.time,
            });
        }
        if self.held.is_none() {
            return Ok(false);
        }
        if sample.time < self.clock - self.tolerance {
            return Err(NavigatorError::TimeOrder {
                what: "IMU sample",
                time: sample.time,
                clock: self.clock,
            });
        }
        Ok(sample.time - self.clock > self.tolerance)
    }

    /// Hold `sample` from the clock on.
    pub(super) fn hold(&mut self, sample: ImuSample) {
        self.held = Some(sample);
    }

    /// Whether a measurement at `time` needs a step to it first.
    ///
    /// # Errors
    /// [`NavigatorError::TimeOrder`] for a time before the clock or not finite.
    pub(super) fn measurement_needs_step(&self, time: f64) -> Result<bool> {
        if !time.is_finite() || time < self.clock - self.tolerance {
            return Err(NavigatorError::TimeOrder {
                what: "measurement",
                time,
                clock: self.clock,
            });
        }
        Ok(time - self.clock > self.tolerance)
    }
}

/// The navigation solution at one time, with 1-sigma per state (from the diagonal
/// of the error covariance; the error state's own frames: position N, E, D metres,
/// misalignment about N, E, D).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NavSolution {
    /// Time \[s\] on the navigator's clock.
    pub time: f64,
    /// Latitude \[deg\].
    pub latitude_deg: f64,
    /// Longitude \[deg\].
    pub longitude_deg: f64,
    /// Depth \[m\] (positive down: -height).
    pub depth_m: f64,
    /// Velocity N, E, D \[m/s\].
    pub velocity_ned_mps: [f64; 3],
    /// Roll \[deg\].
    pub roll_deg: f64,
    /// Pitch \[deg\].
    pub pitch_deg: f64,
    /// Heading \[deg\] in [0, 360).
    pub heading_deg: f64,
    /// Accelerometer bias estimate \[m/s^2\].
    pub acc_bias_mps2: [f64; 3],
    /// Gyroscope bias estimate \[rad/s\].
    pub gyro_bias_radps: [f64; 3],
    /// 1-sigma of the position error N, E, D \[m\].
    pub position_sigma_m: [f64; 3],
    /// 1-sigma of the velocity error N, E, D \[m/s\].
    pub velocity_sigma_mps: [f64; 3],
    /// 1-sigma of the misalignment about N, E, D \[deg\] (about N and E: level; about
    /// D: heading).
    pub attitude_sigma_deg: [f64; 3],
    /// 1-sigma of the accelerometer bias \[m/s^2\].
    pub acc_bias_sigma_mps2: [f64; 3],
    /// 1-sigma of the gyroscope bias \[rad/s\].
    pub gyro_bias_sigma_radps: [f64; 3],
}

impl NavSolution {
    /// The solution of a nominal state and its error covariance at `time`.
    pub fn from_state(time: f64, state: &InsState, covariance: &ErrorMatrix) -> Self {
        let sigma = |i: usize| covariance[(i, i)].max(0.0).sqrt();
        let group = |start: usize| [sigma(start), sigma(start + 1), sigma(start + 2)];
        let (roll, pitch, yaw) = state.roll_pitch_yaw();
        let heading = wrap_heading_deg(yaw.to_degrees());
        let attitude = group(ATT).map(f64::to_degrees);
        Self {
            time,
            latitude_deg: state.latitude.to_degrees(),
            longitude_deg: state.longitude.to_degrees(),
            depth_m: -state.height,
            velocity_ned_mps: state.velocity_ned.into(),
            roll_deg: roll.to_degrees(),
            pitch_deg: pitch.to_degrees(),
            heading_deg: heading,
            acc_bias_mps2: state.acc_bias.into(),
            gyro_bias_radps: state.gyro_bias.into(),
            position_sigma_m: group(POS),
            velocity_sigma_mps: group(VEL),
            attitude_sigma_deg: attitude,
            acc_bias_sigma_mps2: group(ACC_BIAS),
            gyro_bias_sigma_radps: group(GYRO_BIAS),
        }
    }
}

/// The INS/DVL navigator: owns the error-state filter (INS mechanization and the
/// 15-state error model of estim-ins) and the sensor models (DVL velocity with lever
/// arm, mounting misalignment and scale factor; depth; position fixes).
///
/// Times are f64 seconds on one clock (the input's own epoch, or relative to it).
/// Feed the IMU and the measurements in time order ([`crate::navigator::navigate`]
/// merges files so):
/// - [`Navigator::imu`] integrates the sample in effect from the clock to the new
///   sample's time (a gap is bridged by holding the last sample), then holds the new
///   one; dt is the nominal period when it differs from it by less than
///   [`IMU_PERIOD_SNAP`] relative.
/// - A measurement at time t first integrates the held sample up to t (cutting its
///   interval), then updates. An IMU sample stamped exactly t goes before it.
///
/// This is the integration of `estim reproduce`'s filter runs, which are built on it.
///
/// ```
/// use estim::navigator::{Navigator, NavigatorConfig};
/// use estim::core::Zero;
/// use estim::ins::{ErrorMatrix, ImuSample, InsState};
/// use estim::core::nalgebra::{UnitQuaternion, Vector3};
///
/// let settings = NavigatorConfig::default().check()?;
/// let start = InsState::new(0.0, 0.57, 0.61, -20.0, Vector3::new(1.0, 0.0, 0.0),
///     UnitQuaternion::identity());
/// let mut nav = Navigator::new(&settings, start, ErrorMatrix::identity() * 1e-4, 0.01)?;
/// let g = estim::ins::earth::normal_gravity(0.57, -20.0);
/// for k in 0..=100 {
///     nav.imu(&ImuSample::new(k as f64 * 0.01, Vector3::new(0.0, 0.0, -g), Vector3::zeros()))?;
/// }
/// let report = nav.dvl_velocity(1.0, &Vector3::new(1.0, 0.0, 0.0), &Zero)?;
/// assert!(report.is_accepted());
/// let solution = nav.solution();
/// assert!(solution.velocity_sigma_mps[0] < 0.05);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub struct Navigator<O = NoObserver> {
    filter: InsFilter<O>,
    dvl: DvlVelocityModel,
    depth: DepthModel,
    fix_lever_arm: Vector3<f64>,
    imu_clock: ImuClock,
    last_step: Option<(ImuSample, f64)>,
    last_learned_velocity: Option<Vector3<f64>>,
    noise_scale: Option<NoiseScale>,
    /// DVL velocity updates.
    pub dvl_counts: UpdateCounts,
    /// Depth updates.
    pub depth_counts: UpdateCounts,
    /// Position-fix updates.
    pub fix_counts: UpdateCounts,
}

impl Navigator<NoObserver> {
    /// A navigator from checked settings, the initial nominal state (its `time` starts
    /// the clock), its error covariance and the nominal IMU period \[s\].
    ///
    /// # Errors
    /// [`NavigatorError::Config`] for a period that is not positive and finite; the
    /// core's for a covariance that is not finite and symmetric.
    pub fn new(
        settings: &NavigatorSettings,
        initial: InsState,
        covariance: ErrorMatrix,
        imu_period_s: f64,
    ) -> Result<Self> {
        let imu_clock = ImuClock::new(imu_period_s, initial.time)?;
        let process = InsErrorModel::new(settings.filter_spec);
        let filter = ErrorStateKalmanFilter::new(process, initial, covariance)?
            .with_config(settings.filter_config.clone());
        let config = &settings.config;
        Ok(Self {
            filter,
            dvl: settings.dvl.clone(),
            depth: DepthModel::new(
                Vector3::from(config.depth.lever_arm_m),
                config.depth.noise_std_m,
            ),
            fix_lever_arm: Vector3::from(config.fixes.lever_arm_m),
            imu_clock,
            last_step: None,
            last_learned_velocity: None,
            noise_scale: settings.dvl_noise_scale.map(NoiseScale::new).transpose()?,
            dvl_counts: UpdateCounts::default(),
            depth_counts: UpdateCounts::default(),
            fix_counts: UpdateCounts::default(),
        })
    }
}

impl<O> Navigator<O> {
    /// Replace the filter's observer (e.g. a `ForwardRecorder` for the smoother).
    #[must_use]
    pub fn with_observer<O2>(self, observer: O2) -> Navigator<O2> {
        Navigator {
            filter: self.filter.with_observer(observer),
            dvl: self.dvl,
            depth: self.depth,
            fix_lever_arm: self.fix_lever_arm,
            imu_clock: self.imu_clock,
            last_step: self.last_step,
            last_learned_velocity: self.last_learned_velocity,
            noise_scale: self.noise_scale,
            dvl_counts: self.dvl_counts,
            depth_counts: self.depth_counts,
            fix_counts: self.fix_counts,
        }
    }

    /// The filter (nominal state, covariance, accumulated process noise, observer).
    pub fn filter(&self) -> &InsFilter<O> {
        &self.filter
    }

    /// The filter, mutably (e.g. to read its observer out).
    pub fn filter_mut(&mut self) -> &mut InsFilter<O> {
        &mut self.filter
    }

    /// The filter, by value (its observer with it).
    pub fn into_filter(self) -> InsFilter<O> {
        self.filter
    }

    /// The nominal state.
    pub fn nominal(&self) -> &InsState {
        self.filter.nominal()
    }

    /// The error covariance.
    pub fn covariance(&self) -> &ErrorMatrix {
        self.filter.covariance()
    }

    /// The time the state refers to \[s\].
    pub fn clock(&self) -> f64 {
        self.imu_clock.time()
    }

    /// The nominal IMU period \[s\].
    pub fn imu_period(&self) -> f64 {
        self.imu_clock.period()
    }

    /// The IMU sample in effect (the last one fed).
    pub fn held_sample(&self) -> Option<&ImuSample> {
        self.imu_clock.held()
    }

    /// The last propagation step: the sample integrated and its dt.
    pub fn last_step(&self) -> Option<(&ImuSample, f64)> {
        self.last_step.as_ref().map(|(s, dt)| (s, *dt))
    }

    /// The velocity of the last [`Navigator::dvl_beamsnet`] update (the network's
    /// output) \[m/s\].
    pub fn last_learned_velocity(&self) -> Option<Vector3<f64>> {
        self.last_learned_velocity
    }

    /// The configured DVL velocity model (R before any adaptive scale).
    pub fn dvl_model(&self) -> &DvlVelocityModel {
        &self.dvl
    }

    /// The DVL noise scale λ the next DVL update uses, when the noise level is
    /// adapted (`dvl.adaptive_noise_window`); `None` for a fixed R.
    pub fn dvl_noise_scale(&self) -> Option<f64> {
        self.noise_scale.as_ref().map(NoiseScale::scale)
    }

    /// The state and covariance predicted from the clock to `time` with the held IMU
    /// sample, the filter itself unchanged (the clock, or no sample held yet, gives
    /// the current ones).
    ///
    /// # Errors
    /// [`NavigatorError::Filter`] for a numerical failure of the prediction.
    pub fn predicted(&self, time: f64) -> Result<(InsState, ErrorMatrix)> {
        let nominal = self.filter.nominal();
        let covariance = self.filter.covariance();
        let dt = time - self.imu_clock.time();
        match self.imu_clock.held() {
            Some(sample) if dt > 0.0 => super::reference::predict_copy(
                self.filter.process(),
                nominal,
                covariance,
                sample,
                dt,
            )
            .map_err(|source| NavigatorError::Filter { time, source }),
            _ => Ok((*nominal, *covariance)),
        }
    }

    /// The solution now.
    pub fn solution(&self) -> NavSolution {
        NavSolution::from_state(
            self.imu_clock.time(),
            self.filter.nominal(),
            self.filter.covariance(),
        )
    }
}

impl<O: Observer<f64, InsState, ERROR_STATES>> Navigator<O> {
    /// Integrate the held sample from the clock to `end` in one step.
    fn step_to(&mut self, end: f64) -> Result<()> {
        let (sample, dt) = self.imu_clock.step(end)?;
        self.filter
            .predict(&sample, dt)
            .map_err(|source| NavigatorError::Filter {
                time: self.imu_clock.time(),
                source,
            })?;
        self.last_step = Some((sample, dt));
        self.imu_clock.advance(end);
        Ok(())
    }

    /// Feed one IMU sample: integrate the held sample up to `sample.time` (nothing
    /// when within the snap tolerance of the clock), then hold `sample`. The first
    /// sample is held from the initial state's time.
    ///
    /// # Errors
    /// [`NavigatorError::TimeOrder`] for a sample before the clock,
    /// [`NavigatorError::NonFinite`] for a non-finite value; [`NavigatorError::Filter`] for a numerical failure (with the time).
    pub fn imu(&mut self, sample: &ImuSample) -> Result<()> {
        if self.imu_clock.sample_needs_step(sample)? {
            self.step_to(sample.time)?;
        }
        self.imu_clock.hold(*sample);
        Ok(())
    }

    /// Integrate the held sample up to `time` (a measurement's time).
    ///
    /// # Errors
    /// [`NavigatorError::TimeOrder`] for a time before the clock,
    /// [`NavigatorError::NoImu`] before the first IMU sample, the filter's.
    pub fn propagate_to(&mut self, time: f64) -> Result<()> {
        if self.imu_clock.measurement_needs_step(time)? {
            self.step_to(time)?;
        }
        Ok(())
    }

    /// DVL velocity update at `time`: `velocity` in the DVL frame \[m/s\], with the
    /// configured model and the cross-covariance `cross` (`&Zero` for M = 0). With
    /// `dvl.adaptive_noise_window` set, R is the configured one times the current
    /// noise scale, and the update's innovation (accepted or gated) updates the scale
    /// for the next one.
    ///
    /// # Errors
    /// As [`Navigator::propagate_to`]; [`NavigatorError::Filter`] for a numerical
    /// failure of the update.
    pub fn dvl_velocity(
        &mut self,
        time: f64,
        velocity: &Vector3<f64>,
        cross: &DvlCross<'_>,
    ) -> Result<UpdateReport<f64, ERROR_STATES, 3>> {
        let fail = |source| NavigatorError::Filter { time, source };
        let Some(scale) = self.dvl_noise_scale() else {
            let model = self.dvl.clone();
            return self.dvl_velocity_with(time, velocity, &model, cross);
        };
        let model = self
            .dvl
            .with_noise_scale(scale)
            .map_err(|e| NavigatorError::Config(e.to_string()))?;
        let report = self.dvl_velocity_with(time, velocity, &model, cross)?;
        if let Some(estimate) = &mut self.noise_scale {
            estimate
                .update(
                    &report.innovation,
                    &report.innovation_covariance,
                    &report.noise_covariance,
                )
                .map_err(fail)?;
        }
        Ok(report)
    }

    /// [`Navigator::dvl_velocity`] with another DVL model (e.g. another R for a
    /// learned sensor at this epoch).
    ///
    /// # Errors
    /// As [`Navigator::dvl_velocity`].
    pub fn dvl_velocity_with(
        &mut self,
        time: f64,
        velocity: &Vector3<f64>,
        model: &DvlVelocityModel,
        cross: &DvlCross<'_>,
    ) -> Result<UpdateReport<f64, ERROR_STATES, 3>> {
        self.propagate_to(time)?;
        let report = self
            .filter
            .update(model, velocity, cross)
            .map_err(|source| NavigatorError::Filter { time, source })?;
        self.dvl_counts.count(&report);
        Ok(report)
    }

    /// DVL beam update at `time`: the least-squares velocity of the beams present
    /// (4, or 3 with the 3-beam solution; `None` or non-finite = missing), with the
    /// configured DVL noise. Fewer than 3 beams: `Ok(None)`, nothing done but the
    /// propagation.
    ///
    /// # Errors
    /// As [`Navigator::dvl_velocity`].
    pub fn dvl_beams(
        &mut self,
        time: f64,
        beams: &[Option<f64>; 4],
        geometry: &estim_dvl::BeamGeometry,
        cross: &DvlCross<'_>,
    ) -> Result<Option<UpdateReport<f64, ERROR_STATES, 3>>> {
        match geometry.solve(beams).velocity() {
            Some(v) => self.dvl_velocity(time, &v, cross).map(Some),
            None => {
                self.propagate_to(time)?;
                Ok(None)
            }
        }
    }

    /// BeamsNet update at `time`: the embedded network's velocity on the last
    /// [`estim_learned::BEAMSNET_WINDOW`] IMU steps the filter integrated and the four
    /// `beams`, fused with `model` (the network's R) and M from the network's own
    /// sensitivity ([`estim_learned::NetworkSensitivity`] over the filter's recorded
    /// window; the filter must record at least that many steps,
    /// `FilterConfigBuilder::window_capacity`). `Ok(None)` when fewer steps than the
    /// window were integrated (nothing done but the propagation).
    ///
    /// # Errors
    /// As [`Navigator::dvl_velocity`]; the network's errors as [`NavigatorError::Filter`].
    pub fn dvl_beamsnet(
        &mut self,
        time: f64,
        beams: &Vector4<f64>,
        network: &estim_learned::BeamsNet,
        error_model: &InsErrorModel,
        model: &DvlVelocityModel,
    ) -> Result<Option<UpdateReport<f64, ERROR_STATES, 3>>> {
        self.propagate_to(time)?;
        let fail = |source| NavigatorError::Filter { time, source };
        let sensitivity =
            estim_learned::NetworkSensitivity::new(network, error_model, *beams).map_err(fail)?;
        let velocity = match self.filter.step_window(estim_learned::BEAMSNET_WINDOW) {
            Ok(window) => sensitivity.measure(&window).map_err(fail)?,
            Err(estim_core::Error::WindowUnavailable { .. }) => return Ok(None),
            Err(e) => return Err(fail(e)),
        };
        let report = self
            .filter
            .update_windowed(model, &velocity, &sensitivity)
            .map_err(fail)?;
        self.dvl_counts.count(&report);
        self.last_learned_velocity = Some(velocity);
        Ok(Some(report))
    }

    /// Depth update at `time` (`depth_m` positive down).
    ///
    /// # Errors
    /// As [`Navigator::dvl_velocity`].
    pub fn depth(&mut self, time: f64, depth_m: f64) -> Result<UpdateReport<f64, ERROR_STATES, 1>> {
        self.propagate_to(time)?;
        let y = nalgebra::Vector1::new(depth_m);
        let model = self.depth.clone();
        let report = self
            .filter
            .update(&model, &y, &Zero)
            .map_err(|source| NavigatorError::Filter { time, source })?;
        self.depth_counts.count(&report);
        Ok(report)
    }

    /// Position-fix update at `time`: latitude, longitude \[deg\] with horizontal
    /// 1-sigma `sigma_m` \[m\] (> 0).
    ///
    /// # Errors
    /// [`NavigatorError::Config`] for a sigma that is not positive and finite; as
    /// [`Navigator::dvl_velocity`].
    pub fn position_fix(
        &mut self,
        time: f64,
        latitude_deg: f64,
        longitude_deg: f64,
        sigma_m: f64,
    ) -> Result<UpdateReport<f64, ERROR_STATES, 2>> {
        if !(sigma_m.is_finite() && sigma_m > 0.0) {
            return Err(NavigatorError::Config(format!(
                "position fix at t = {time}: sigma {sigma_m} m is not positive and finite"
            )));
        }
        self.propagate_to(time)?;
        let model = PositionFixModel::new(
            latitude_deg.to_radians(),
            longitude_deg.to_radians(),
            sigma_m,
            self.fix_lever_arm,
        );
        let report = self
            .filter
            .update(&model, &FIX_MEASUREMENT, &Zero)
            .map_err(|source| NavigatorError::Filter { time, source })?;
        self.fix_counts.count(&report);
        Ok(report)
    }
}

/// A heading \[deg\] wrapped into [0, 360).
///
/// `f64::rem_euclid` alone is not enough: it returns -0.0 for -0.0 (printed `-0`), and
/// for a negative value smaller in magnitude than half an ulp of 360 (e.g. -1e-15) the
/// sum `x + 360` rounds to 360.0 exactly. Both are mapped to +0.0.
pub fn wrap_heading_deg(deg: f64) -> f64 {
    let wrapped = deg.rem_euclid(360.0);
    if wrapped >= 360.0 {
        0.0
    } else {
        // -0.0 + 0.0 is +0.0 (IEEE 754, round to nearest).
        wrapped + 0.0
    }
}

/// A heading as text with `decimals` decimals, in [0, 360) as printed: a heading
/// that rounds up to 360 at that precision (359.9999996 with 5 decimals) is printed
/// as 0.
pub fn format_heading(deg: f64, decimals: usize) -> String {
    let text = format!("{:.decimals$}", wrap_heading_deg(deg));
    if text.starts_with("360") {
        format!("{:.decimals$}", 0.0)
    } else {
        text
    }
}

/// Beams as the least-squares solver takes them (`NaN` = missing).
pub fn beams_from_nan(beams: &Vector4<f64>) -> [Option<f64>; 4] {
    std::array::from_fn(|i| Some(beams[i]).filter(|b| b.is_finite()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::navigator::{filter_config, filter_imu_spec, NavigatorConfig};
    use estim_core::ScaledCorrelation;
    use estim_dvl::dvl_frame_velocity;
    use estim_ins::{Mission, MissionConfig};
    use nalgebra::Vector1;

    /// A navigator run equals the same steps on a hand-assembled
    /// `ErrorStateKalmanFilter` (IMU predicts at the period, DVL with a lever arm,
    /// misalignment and scale factor, depth and a fix), to 1e-12.
    #[test]
    fn navigator_equals_a_hand_assembled_filter() {
        let mission = Mission::generate(
            &MissionConfig::builder().duration(30.0).build().unwrap(),
            11,
        )
        .unwrap();
        let mut config = NavigatorConfig::default();
        config.dvl.lever_arm_m = [1.2, -0.1, 0.3];
        config.dvl.mounting_misalignment_rad = [0.01, -0.02, 0.03];
        config.dvl.scale_factor = 1.004;
        config.depth.lever_arm_m = [0.5, 0.0, -0.2];
        config.fixes.lever_arm_m = [0.0, 0.0, -1.5];
        let settings = config.check().unwrap();
        let spec = *settings.sensor_spec();
        let x0 = mission.truth[0];
        let p0 = ErrorMatrix::identity() * 1e-3;
        let dt = mission.imu_dt;
        let mut nav = Navigator::new(&settings, x0, p0, dt).unwrap();
        let mut reference = ErrorStateKalmanFilter::new(
            InsErrorModel::new(filter_imu_spec(&spec).unwrap()),
            x0,
            p0,
        )
        .unwrap()
        .with_config(filter_config(0.9999, 25).unwrap());
        let dvl = estim_dvl::DvlVelocityModel::builder()
            .lever_arm(Vector3::new(1.2, -0.1, 0.3))
            .mounting_misalignment(Vector3::new(0.01, -0.02, 0.03))
            .scale_factor_error(1.004 - 1.0)
            .noise_std(0.02)
            .build()
            .unwrap();
        let depth = DepthModel::new(Vector3::new(0.5, 0.0, -0.2), 0.1);
        let rho = ScaledCorrelation { rho: 0.2 };
        nav.imu(&mission.imu[0]).unwrap();
        for k in 0..mission.imu.len() {
            reference.predict(&mission.imu[k], dt).unwrap();
            let t = mission.truth[k + 1].time;
            match mission.imu.get(k + 1) {
                Some(next) => nav.imu(next).unwrap(),
                None => nav.propagate_to(t).unwrap(),
            }
            let truth = &mission.truth[k + 1];
            if (k + 1) % 100 == 0 {
                let v = dvl_frame_velocity(
                    &(truth.attitude.inverse() * truth.velocity_ned),
                    &truth.angular_rate,
                    dvl.lever_arm(),
                    dvl.scale_factor_error(),
                    dvl.mounting_misalignment(),
                );
                let a = nav.dvl_velocity(t, &v, &rho).unwrap();
                let b = reference.update(&dvl, &v, &rho).unwrap();
                assert_eq!(a.status, b.status);
            }
            if (k + 1) % 50 == 0 {
                let d = -truth.height + 0.01;
                nav.depth(t, d).unwrap();
                reference.update(&depth, &Vector1::new(d), &Zero).unwrap();
            }
            if k + 1 == 1500 {
                let (lat, lon) = (truth.latitude.to_degrees(), truth.longitude.to_degrees());
                nav.position_fix(t, lat, lon, 3.0).unwrap();
                let fix = PositionFixModel::new(
                    lat.to_radians(),
                    lon.to_radians(),
                    3.0,
                    Vector3::new(0.0, 0.0, -1.5),
                );
                reference.update(&fix, &FIX_MEASUREMENT, &Zero).unwrap();
            }
        }
        let (a, b) = (nav.nominal(), reference.nominal());
        let diffs = [
            (a.latitude - b.latitude) * 6.4e6,
            (a.longitude - b.longitude) * 6.4e6,
            a.height - b.height,
            (a.velocity_ned - b.velocity_ned).norm(),
            a.attitude.angle_to(&b.attitude),
            (a.acc_bias - b.acc_bias).norm(),
            (a.gyro_bias - b.gyro_bias).norm(),
            a.time - b.time,
        ];
        for (i, d) in diffs.iter().enumerate() {
            assert!(d.abs() <= 1e-12, "nominal part {i} differs by {d}");
        }
        let p = (nav.covariance() - reference.covariance()).abs().max();
        assert!(
            p <= 1e-12 * reference.covariance().abs().max(),
            "P differs by {p}"
        );
        assert_eq!(nav.dvl_counts.accepted + nav.dvl_counts.gated, 30);
        assert_eq!(nav.fix_counts.accepted + nav.fix_counts.gated, 1);
        assert!((nav.clock() - mission.truth.last().unwrap().time).abs() < 1e-9);
    }

    /// DVL velocities of a simulated mission with noise `true_std` per axis, fed to a
    /// navigator configured with `noise_std_mps = 0.02` and the given adaptive memory;
    /// returns (mean noise scale used over the second half, mean NIS over it).
    fn adaptive_run(true_std: f64, window: Option<usize>, seed: u64) -> (Option<f64>, f64) {
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let mission = Mission::generate(
            &MissionConfig::builder().duration(600.0).build().unwrap(),
            seed,
        )
        .unwrap();
        let mut config = NavigatorConfig::default();
        config.dvl.adaptive_noise_window = window;
        config.gate.probability = 0.0;
        let settings = config.check().unwrap();
        let x0 = mission.truth[0];
        let p0 = ErrorMatrix::from_diagonal(&nalgebra::SVector::<f64, 15>::from_column_slice(&[
            1.0, 1.0, 1.0, 0.01, 0.01, 0.01, 1e-6, 1e-6, 1e-5, 1e-6, 1e-6, 1e-6, 1e-10, 1e-10,
            1e-10,
        ]));
        let mut nav = Navigator::new(&settings, x0, p0, mission.imu_dt).unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed + 100);
        let (mut nis, mut scale, mut n) = (0.0, 0.0, 0);
        nav.imu(&mission.imu[0]).unwrap();
        let updates = mission.imu.len() / 100;
        for k in 0..mission.imu.len() {
            let t = mission.truth[k + 1].time;
            match mission.imu.get(k + 1) {
                Some(next) => nav.imu(next).unwrap(),
                None => nav.propagate_to(t).unwrap(),
            }
            if (k + 1) % 100 == 0 {
                let truth = &mission.truth[k + 1];
                let noise = Vector3::from_fn(|_, _| {
                    let z: f64 = StandardNormal.sample(&mut rng);
                    z * true_std
                });
                let v = truth.attitude.inverse() * truth.velocity_ned + noise;
                let used = nav.dvl_noise_scale();
                let report = nav.dvl_velocity(t, &v, &Zero).unwrap();
                if (k + 1) / 100 > updates / 2 {
                    nis += report.nis;
                    scale += used.unwrap_or(f64::NAN);
                    n += 1;
                }
            }
        }
        let scale = nav.dvl_noise_scale().map(|_| scale / f64::from(n));
        (scale, nis / f64::from(n))
    }

    /// With `dvl.adaptive_noise_window`, R follows the DVL's true noise: at 3x and
    /// 0.5x the configured std the final scale is near 9 and 0.25 and the NIS near
    /// 3, while the fixed R gives NIS near 27 and 0.75. Over seeds 1-20 (run once
    /// with `for seed in 1..=20`) the mean scale of the second half is within 9 % of
    /// 9 and 0.25 and the NIS within 2.87-3.22; the bounds (15 %, [2.5, 3.5]) hold
    /// with room.
    #[test]
    fn adaptive_dvl_noise_follows_the_true_level() {
        for seed in 1..=3 {
            for (true_std, expected) in [(0.06, 9.0), (0.01, 0.25)] {
                let (scale, nis) = adaptive_run(true_std, Some(100), seed);
                let scale = scale.unwrap();
                println!("seed {seed}, true std {true_std}: scale {scale:.3}, NIS {nis:.2}");
                assert!((scale / expected - 1.0).abs() < 0.15, "scale {scale}");
                assert!((2.5..3.5).contains(&nis), "NIS {nis}");
                let (fixed, nis_fixed) = adaptive_run(true_std, None, seed);
                assert_eq!(fixed, None);
                assert!(
                    (nis_fixed / (3.0 * expected) - 1.0).abs() < 0.35,
                    "fixed NIS {nis_fixed}"
                );
            }
        }
        let mut config = NavigatorConfig::default();
        config.dvl.adaptive_noise_window = Some(0);
        let e = config.check().unwrap_err().to_string();
        assert!(e.contains("dvl.adaptive_noise_window"), "{e}");
    }

    /// Headings in [0, 360) for the values that `rem_euclid` alone gets wrong, in the
    /// solution and as printed.
    #[test]
    fn headings_are_in_0_360() {
        for (deg, expected) in [
            (-0.0, 0.0),
            (-1e-15, 0.0),
            (-1e-13, 360.0 - 1e-13),
            (360.0, 0.0),
            (720.0, 0.0),
            (-90.0, 270.0),
            (359.5, 359.5),
        ] {
            let h = wrap_heading_deg(deg);
            assert!((0.0..360.0).contains(&h), "{deg} -> {h}");
            assert_eq!(h.to_bits(), f64::to_bits(expected), "{deg} -> {h}");
        }
        assert_eq!(format_heading(-0.0, 5), "0.00000");
        assert_eq!(format_heading(-1e-9, 5), "0.00000");
        assert_eq!(format_heading(359.999_999_6, 5), "0.00000");
        assert_eq!(format_heading(359.999_99, 5), "359.99999");
        assert_eq!(format_heading(359.996, 2), "0.00");
        assert_eq!(format_heading(12.345, 2), "12.35");
        // A state whose yaw is -0.0 rad (north, from a quaternion with a negative-zero
        // z component) gives heading +0.0.
        let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            1.0, 0.0, 0.0, -0.0,
        ));
        let state = InsState::new(0.0, 0.5, 0.6, -10.0, Vector3::zeros(), q);
        let (_, _, yaw) = state.roll_pitch_yaw();
        let s = NavSolution::from_state(0.0, &state, &ErrorMatrix::identity());
        assert_eq!(s.heading_deg.to_bits(), 0.0f64.to_bits(), "yaw {yaw:e}");
        let tiny = InsState::new(
            0.0,
            0.5,
            0.6,
            -10.0,
            Vector3::zeros(),
            nalgebra::UnitQuaternion::from_euler_angles(0.0, 0.0, -1e-17),
        );
        let s = NavSolution::from_state(0.0, &tiny, &ErrorMatrix::identity());
        assert!(
            s.heading_deg < 360.0 && s.heading_deg >= 0.0,
            "{}",
            s.heading_deg
        );
    }

    #[test]
    fn out_of_order_and_early_inputs_are_typed_errors() {
        let settings = NavigatorConfig::default().check().unwrap();
        let x0 = InsState::new(
            5.0,
            0.5,
            0.6,
            -10.0,
            Vector3::zeros(),
            nalgebra::UnitQuaternion::identity(),
        );
        let mut nav = Navigator::new(&settings, x0, ErrorMatrix::identity(), 0.01).unwrap();
        let e = nav.depth(5.5, 10.0).unwrap_err();
        assert!(matches!(e, NavigatorError::NoImu { .. }), "{e}");
        let sample = ImuSample::new(5.0, Vector3::new(0.0, 0.0, -9.8), Vector3::zeros());
        nav.imu(&sample).unwrap();
        nav.imu(&ImuSample {
            time: 5.01,
            ..sample
        })
        .unwrap();
        let e = nav
            .imu(&ImuSample {
                time: 4.0,
                ..sample
            })
            .unwrap_err();
        assert!(matches!(e, NavigatorError::TimeOrder { .. }), "{e}");
        let e = nav
            .imu(&ImuSample {
                time: f64::NAN,
                ..sample
            })
            .unwrap_err();
        assert!(matches!(e, NavigatorError::NonFinite { .. }), "{e}");
        assert!(nav.position_fix(5.02, 30.0, 30.0, 0.0).is_err());
        assert!(Navigator::new(&settings, x0, ErrorMatrix::identity(), 0.0).is_err());
    }
}
