//! [`Navigator`]: the INS error-state filter fed sample by sample, generic over its
//! error model ([`NavigationModel`]): the 15 INS states of estim-ins
//! ([`InsErrorModel`], the default), or those and the DVL error states
//! ([`super::AugmentedErrorModel`], [`super::AugmentedNavigator`]).

use std::borrow::Cow;

use estim_core::noise::adaptive::NoiseScale;
use estim_core::{
    CrossCovariance, ErrorStateKalmanFilter, ErrorStateModel, MarkEvent, MeasurementModel,
    NoObserver, Observer, UpdateReport, Zero,
};
use estim_dvl::DvlVelocityModel;
use estim_ins::{ErrorMatrix, ImuSample, InsErrorModel, InsState, ERROR_STATES};
use nalgebra::{Matrix3, SMatrix, Vector3, Vector4};

use super::aiding::{DepthModel, InsNominal, PositionFixModel, FIX_MEASUREMENT};
use super::clock::ImuClock;
use super::{
    DvlStateSolution, NavSolution, NavigatorError, NavigatorSettings, Result, UpdateCounts,
};

#[cfg(test)]
mod tests;

/// The filter type the navigator owns.
pub type InsFilter<O, E = InsErrorModel, const N: usize = ERROR_STATES> =
    ErrorStateKalmanFilter<f64, E, N, O>;

/// The DVL update's cross-covariance source (N x 3; 15 x 3 by default).
pub type DvlCross<'a, S = InsState, const N: usize = ERROR_STATES> =
    dyn CrossCovariance<f64, S, N, 3> + 'a;

/// An error model the [`Navigator`] runs on: an error-state model over `N` states whose
/// first 15 are estim-ins' INS error states, driven by IMU samples, with a DVL
/// velocity measurement of its own. The navigator owns the timing, the updates and
/// the adaptive DVL noise level; the model says what differs with its states.
///
/// ```
/// use estim_nav::navigator::{AugmentedErrorModel, NavigationModel, AUGMENTED_STATES};
/// use estim_ins::{InsErrorModel, ERROR_STATES};
///
/// fn states<E: NavigationModel<N>, const N: usize>() -> usize { N }
/// assert_eq!(states::<InsErrorModel, ERROR_STATES>(), 15);
/// assert_eq!(states::<AugmentedErrorModel, AUGMENTED_STATES>(), 26);
/// ```
pub trait NavigationModel<const N: usize>:
    ErrorStateModel<f64, N, Input = ImuSample, State: InsNominal<N>>
{
    /// The DVL velocity measurement on this error state.
    type Dvl: MeasurementModel<f64, N, 3, State = Self::State> + Clone;
    /// What the navigator keeps for the DVL between updates (nothing for 15 states;
    /// the time-offset window of body accelerations for the DVL error states).
    type DvlMemory: Default;

    /// The 15 x 15 covariance of the INS states.
    fn ins_covariance(covariance: &SMatrix<f64, N, N>) -> ErrorMatrix;

    /// `model` with its noise scaled by `scale` (the adaptive DVL noise level).
    ///
    /// # Errors
    /// [`NavigatorError::InvalidValue`] for a scale that is not finite and positive.
    fn scale_dvl_noise(model: &Self::Dvl, scale: f64) -> Result<Self::Dvl>;

    /// `model` with its noise covariance replaced by `r` (the noise of a velocity that
    /// is not the DVL's own, e.g. a learned sensor's).
    ///
    /// # Errors
    /// [`NavigatorError::InvalidValue`] for an `r` that is not finite, symmetric and
    /// positive definite.
    fn replace_dvl_noise(model: &Self::Dvl, r: Matrix3<f64>) -> Result<Self::Dvl>;

    /// After a propagation step of length `dt` ending at `end`, at the new nominal.
    fn after_step(
        &self,
        _memory: &mut Self::DvlMemory,
        _nominal: &Self::State,
        _end: f64,
        _dt: f64,
    ) {
    }

    /// The DVL model of an update at `time` (by default `model` itself).
    fn dvl_model_at<'a>(
        &self,
        _memory: &Self::DvlMemory,
        _nominal: &Self::State,
        _time: f64,
        model: &'a Self::Dvl,
    ) -> Cow<'a, Self::Dvl> {
        Cow::Borrowed(model)
    }

    /// A prior covariance added to R in the adaptive noise level's D (`None`: none).
    fn adaptive_noise_prior(_covariance: &SMatrix<f64, N, N>) -> Option<Matrix3<f64>> {
        None
    }

    /// The adaptive noise level moved to `scale` (by default nothing else follows).
    ///
    /// # Errors
    /// The model's, for a scale it cannot take.
    fn on_noise_scale(&mut self, _scale: f64) -> Result<()> {
        Ok(())
    }

    /// The DVL error states with their 1-sigma, when the model has them.
    fn dvl_states(
        _nominal: &Self::State,
        _covariance: &SMatrix<f64, N, N>,
    ) -> Option<DvlStateSolution> {
        None
    }
}

impl NavigationModel<ERROR_STATES> for InsErrorModel {
    type Dvl = DvlVelocityModel;
    type DvlMemory = ();

    fn ins_covariance(covariance: &ErrorMatrix) -> ErrorMatrix {
        *covariance
    }

    fn scale_dvl_noise(model: &DvlVelocityModel, scale: f64) -> Result<DvlVelocityModel> {
        model.with_noise_scale(scale).map_err(|_| {
            NavigatorError::invalid(
                "DVL noise scale",
                format!("{scale} is not finite and positive"),
            )
        })
    }

    fn replace_dvl_noise(model: &DvlVelocityModel, r: Matrix3<f64>) -> Result<DvlVelocityModel> {
        model.with_noise_covariance(r).map_err(|_| {
            NavigatorError::invalid(
                "DVL noise covariance",
                format!("{r} is not symmetric positive definite"),
            )
        })
    }
}

/// The INS/DVL navigator: owns the error-state filter (INS mechanization and the
/// error model `E` over `N` states: by default the 15-state model of estim-ins, or
/// [`super::AugmentedErrorModel`] with the DVL error states, [`super::AugmentedNavigator`])
/// and the sensor models (DVL velocity with lever arm, mounting misalignment and scale
/// factor; depth; position fixes). `O` is an estim-core observer on the filter.
///
/// Times are f64 seconds on one clock (the input's own epoch, or relative to it).
/// Feed the IMU and the measurements in time order ([`crate::navigator::navigate`]
/// merges files so):
/// - [`Navigator::imu`] integrates the sample in effect from the clock to the new
///   sample's time (a gap is bridged by holding the last sample), then holds the new
///   one; dt is the nominal period when it differs from it by less than
///   [`IMU_PERIOD_SNAP`](crate::navigator::IMU_PERIOD_SNAP) relative.
/// - A measurement at time t first integrates the held sample up to t (cutting its
///   interval), then updates. An IMU sample stamped exactly t goes before it.
///
/// This is the integration of `estim reproduce`'s filter runs, which are built on it.
///
/// ```
/// use estim_nav::navigator::{Navigator, NavigatorConfig};
/// use estim_core::Zero;
/// use estim_ins::{ErrorMatrix, ImuSample, InsState};
/// use estim_core::nalgebra::{UnitQuaternion, Vector3};
///
/// let settings = NavigatorConfig::default().check()?;
/// let start = InsState::new(0.0, 0.57, 0.61, -20.0, Vector3::new(1.0, 0.0, 0.0),
///     UnitQuaternion::identity());
/// let mut nav = Navigator::new(&settings, start, ErrorMatrix::identity() * 1e-4, 0.01)?;
/// let g = estim_ins::earth::normal_gravity(0.57, -20.0);
/// for k in 0..=100 {
///     nav.imu(&ImuSample::new(k as f64 * 0.01, Vector3::new(0.0, 0.0, -g), Vector3::zeros()))?;
/// }
/// let report = nav.dvl_velocity(1.0, &Vector3::new(1.0, 0.0, 0.0), &Zero)?;
/// assert!(report.is_accepted());
/// let solution = nav.solution();
/// assert!(solution.velocity_sigma_mps[0] < 0.05);
/// # Ok::<(), Box<dyn std::error::Error>>(())
pub struct Navigator<E = InsErrorModel, O = NoObserver, const N: usize = ERROR_STATES>
where
    E: NavigationModel<N>,
{
    filter: InsFilter<O, E, N>,
    dvl: E::Dvl,
    dvl_memory: E::DvlMemory,
    depth: DepthModel<E::State>,
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

/// A copy of the whole navigator (filter, accumulated process noise, recorded window,
/// adaptive noise level, DVL memory, counts): what the streaming navigator keeps as a
/// checkpoint ([`super::StreamNavigator`]), so that a rewind restores every quantity a
/// later update depends on.
impl<E, O, const N: usize> Clone for Navigator<E, O, N>
where
    E: NavigationModel<N> + Clone,
    E::State: Clone,
    E::DvlMemory: Clone,
    O: Clone,
{
    fn clone(&self) -> Self {
        Self {
            filter: self.filter.clone(),
            dvl: self.dvl.clone(),
            dvl_memory: self.dvl_memory.clone(),
            depth: self.depth.clone(),
            fix_lever_arm: self.fix_lever_arm,
            imu_clock: self.imu_clock,
            last_step: self.last_step,
            last_learned_velocity: self.last_learned_velocity,
            noise_scale: self.noise_scale.clone(),
            dvl_counts: self.dvl_counts,
            depth_counts: self.depth_counts,
            fix_counts: self.fix_counts,
        }
    }
}

impl Navigator {
    /// A navigator from checked settings, the initial nominal state (its `time` starts
    /// the clock), its error covariance and the nominal IMU period \[s\].
    ///
    /// # Errors
    /// [`NavigatorError::InvalidValue`] for a period that is not positive and finite; the
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
        Self::assemble(filter, settings.dvl.clone(), settings, imu_clock)
    }
}

impl<E: NavigationModel<N>, const N: usize> Navigator<E, NoObserver, N> {
    /// The navigator around a filter, with the DVL model `dvl` and the depth, fix and
    /// adaptive-noise settings of `settings`.
    pub(super) fn assemble(
        filter: InsFilter<NoObserver, E, N>,
        dvl: E::Dvl,
        settings: &NavigatorSettings,
        imu_clock: ImuClock,
    ) -> Result<Self> {
        let config = &settings.config;
        Ok(Self {
            filter,
            dvl,
            dvl_memory: E::DvlMemory::default(),
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

impl<E: NavigationModel<N>, O, const N: usize> Navigator<E, O, N> {
    /// Replace the filter's observer (e.g. a `ForwardRecorder` for the smoother).
    #[must_use]
    pub fn with_observer<O2>(self, observer: O2) -> Navigator<E, O2, N> {
        Navigator {
            filter: self.filter.with_observer(observer),
            dvl: self.dvl,
            dvl_memory: self.dvl_memory,
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

    /// Replace the DVL model of [`Navigator::dvl_velocity`] (e.g. with rate noise).
    #[must_use]
    pub fn with_dvl_model(mut self, model: E::Dvl) -> Self {
        self.dvl = model;
        self
    }

    /// The filter (nominal state, covariance, accumulated process noise, observer).
    pub fn filter(&self) -> &InsFilter<O, E, N> {
        &self.filter
    }

    /// The filter, mutably (e.g. to read its observer out).
    pub fn filter_mut(&mut self) -> &mut InsFilter<O, E, N> {
        &mut self.filter
    }

    /// The filter, by value (its observer with it).
    pub fn into_filter(self) -> InsFilter<O, E, N> {
        self.filter
    }

    /// The nominal state.
    pub fn nominal(&self) -> &E::State {
        self.filter.nominal()
    }

    /// The INS part of the nominal state.
    pub fn ins(&self) -> &InsState {
        self.filter.nominal().ins()
    }

    /// The error covariance (N x N).
    pub fn covariance(&self) -> &SMatrix<f64, N, N> {
        self.filter.covariance()
    }

    /// The 15 x 15 covariance of the INS states.
    pub fn ins_covariance(&self) -> ErrorMatrix {
        E::ins_covariance(self.filter.covariance())
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
    pub fn dvl_model(&self) -> &E::Dvl {
        &self.dvl
    }

    /// The DVL noise scale λ the next DVL update uses, when the noise level is
    /// adapted (`dvl.adaptive_noise_window`); `None` for a fixed R.
    pub fn dvl_noise_scale(&self) -> Option<f64> {
        self.noise_scale.as_ref().map(NoiseScale::scale)
    }

    /// The INS state and its covariance predicted from the clock to `time` with the
    /// held IMU sample, the filter itself unchanged (the clock, or no sample held yet,
    /// gives the current ones).
    ///
    /// # Errors
    /// [`NavigatorError::Filter`] for a numerical failure of the prediction.
    pub fn predicted(&self, time: f64) -> Result<(InsState, ErrorMatrix)> {
        let nominal = self.filter.nominal();
        let covariance = self.filter.covariance();
        let dt = time - self.imu_clock.time();
        match self.imu_clock.held() {
            Some(sample) if dt > 0.0 => {
                let (state, p) = super::reference::predict_copy(
                    self.filter.process(),
                    nominal,
                    covariance,
                    sample,
                    dt,
                )
                .map_err(|source| NavigatorError::Filter { time, source })?;
                Ok((*state.ins(), E::ins_covariance(&p)))
            }
            _ => Ok((*nominal.ins(), E::ins_covariance(covariance))),
        }
    }

    /// The solution now (the INS states).
    pub fn solution(&self) -> NavSolution {
        NavSolution::from_state(self.imu_clock.time(), self.ins(), &self.ins_covariance())
    }

    /// The DVL error states with their 1-sigma, when the error model has them.
    pub fn dvl_states(&self) -> Option<DvlStateSolution> {
        E::dvl_states(self.filter.nominal(), self.filter.covariance())
    }
}

impl<E: NavigationModel<N>, O: Observer<f64, E::State, N>, const N: usize> Navigator<E, O, N> {
    /// Tell the filter's observer that the current step is one to report
    /// ([`Observer::on_mark`]): a smoother's recorder closes its epoch here, so the
    /// smoother gives a value at this step (a batch run marks each output epoch).
    ///
    /// # Errors
    /// [`NavigatorError::Filter`] when the observer fails.
    pub fn mark(&mut self) -> Result<()> {
        let state = self.filter.nominal().clone();
        let covariance = *self.filter.covariance();
        let time = self.imu_clock.time();
        self.filter
            .observer_mut()
            .on_mark(&MarkEvent {
                state: &state,
                covariance: &covariance,
            })
            .map_err(|source| NavigatorError::Filter { time, source })
    }

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
        self.filter
            .process()
            .after_step(&mut self.dvl_memory, self.filter.nominal(), end, dt);
        Ok(())
    }

    /// Feed one IMU sample: integrate the held sample up to `sample.time` (nothing
    /// when within the snap tolerance of the clock), then hold `sample`. The first
    /// sample is held from the initial state's time.
    ///
    /// # Errors
    /// [`NavigatorError::TimeOrder`] for a sample before the clock,
    /// [`NavigatorError::NonFinite`] for a non-finite value; [`NavigatorError::Filter`]
    /// for a numerical failure (with the time).
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
    /// for the next one (with D = λR plus the model's
    /// [`NavigationModel::adaptive_noise_prior`]).
    ///
    /// # Errors
    /// As [`Navigator::propagate_to`]; [`NavigatorError::Filter`] for a numerical
    /// failure of the update.
    pub fn dvl_velocity(
        &mut self,
        time: f64,
        velocity: &Vector3<f64>,
        cross: &DvlCross<'_, E::State, N>,
    ) -> Result<UpdateReport<f64, N, 3>> {
        let Some(scale) = self.dvl_noise_scale() else {
            let model = self.dvl.clone();
            return self.dvl_velocity_with(time, velocity, &model, cross);
        };
        let model = E::scale_dvl_noise(&self.dvl, scale)?;
        self.propagate_to(time)?;
        let prior = E::adaptive_noise_prior(self.filter.covariance());
        let report = self.dvl_velocity_with(time, velocity, &model, cross)?;
        if let Some(estimate) = &mut self.noise_scale {
            let noise = match prior {
                Some(prior) => report.noise_covariance + prior,
                None => report.noise_covariance,
            };
            let next = estimate
                .update(&report.innovation, &report.innovation_covariance, &noise)
                .map_err(|source| NavigatorError::Filter { time, source })?;
            if next != scale {
                self.filter.process_mut().on_noise_scale(next)?;
            }
        }
        Ok(report)
    }

    /// DVL velocity update at `time` with the noise covariance `r` in place of the
    /// configured R and its adapted level (e.g. a learned sensor's R for a velocity the
    /// network gave); the adapted level is neither used nor updated.
    ///
    /// # Errors
    /// As [`Navigator::dvl_velocity`]; [`NavigatorError::InvalidValue`] for an `r` that
    /// is not finite, symmetric and positive definite.
    pub fn dvl_velocity_with_noise(
        &mut self,
        time: f64,
        velocity: &Vector3<f64>,
        r: &Matrix3<f64>,
        cross: &DvlCross<'_, E::State, N>,
    ) -> Result<UpdateReport<f64, N, 3>> {
        let model = E::replace_dvl_noise(&self.dvl, *r)?;
        self.dvl_velocity_with(time, velocity, &model, cross)
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
        model: &E::Dvl,
        cross: &DvlCross<'_, E::State, N>,
    ) -> Result<UpdateReport<f64, N, 3>> {
        self.propagate_to(time)?;
        let model = self.filter.process().dvl_model_at(
            &self.dvl_memory,
            self.filter.nominal(),
            time,
            model,
        );
        let report = self
            .filter
            .update(model.as_ref(), velocity, cross)
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
        cross: &DvlCross<'_, E::State, N>,
    ) -> Result<Option<UpdateReport<f64, N, 3>>> {
        match geometry.solve(beams).velocity() {
            Some(v) => self.dvl_velocity(time, &v, cross).map(Some),
            None => {
                self.propagate_to(time)?;
                Ok(None)
            }
        }
    }

    /// Depth update at `time` (`depth_m` positive down).
    ///
    /// # Errors
    /// As [`Navigator::dvl_velocity`].
    pub fn depth(&mut self, time: f64, depth_m: f64) -> Result<UpdateReport<f64, N, 1>> {
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
    /// [`NavigatorError::InvalidValue`] for a sigma that is not positive and finite; as
    /// [`Navigator::dvl_velocity`].
    pub fn position_fix(
        &mut self,
        time: f64,
        latitude_deg: f64,
        longitude_deg: f64,
        sigma_m: f64,
    ) -> Result<UpdateReport<f64, N, 2>> {
        if !(sigma_m.is_finite() && sigma_m > 0.0) {
            return Err(NavigatorError::invalid(
                format!("position fix sigma at t = {time}"),
                format!("{sigma_m} m is not positive and finite"),
            ));
        }
        self.propagate_to(time)?;
        let model = PositionFixModel::<E::State>::new(
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

#[cfg(feature = "learned")]
impl<O: Observer<f64, InsState, ERROR_STATES>> Navigator<InsErrorModel, O, ERROR_STATES> {
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
}

/// Beams as the least-squares solver takes them (`NaN` = missing).
pub fn beams_from_nan(beams: &Vector4<f64>) -> [Option<f64>; 4] {
    std::array::from_fn(|i| Some(beams[i]).filter(|b| b.is_finite()))
}
