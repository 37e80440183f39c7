//! The batch run: IMU, DVL, depth and fixes merged by time through one [`Navigator`]
//! (on the 15-state error model, or the augmented one when the settings hold DVL
//! error states), by the one loop of [`super::run_epochs`].

use estim_core::{NoObserver, Observer, Zero};
#[cfg(feature = "learned")]
use estim_ins::InsErrorModel;
use estim_ins::{ErrorMatrix, ImuSample, InsState, ERROR_STATES};
#[cfg(feature = "learned")]
use nalgebra::Vector3;
use nalgebra::Vector4;
use serde::Serialize;

use super::initial::{first_imu_index, imu_period, initial_state};
use super::run::{run_epochs, EpochHook, Tail};
use super::{
    Alignment, AugmentedNavigator, DvlInput, DvlStateSolution, HealthMonitor, NavSolution,
    NavigationModel, NavigationObserver, Navigator, NavigatorError, NavigatorSettings, PositionFix,
    Result, SolutionKind, SurveyInputs, UpdateCounts,
};

#[cfg(test)]
mod tests;

/// What [`navigate`] did.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NavigationRun {
    /// The initial state's sources.
    pub alignment: Alignment,
    /// The nominal IMU period used \[s\].
    pub imu_period_s: f64,
    /// First and last IMU times \[s\].
    pub span_s: [f64; 2],
    /// IMU samples integrated.
    pub imu_samples: usize,
    /// DVL velocity (or beam) updates.
    pub dvl: UpdateCounts,
    /// Depth updates.
    pub depth: UpdateCounts,
    /// Position-fix updates.
    pub fixes: UpdateCounts,
    /// DVL rows without bottom lock, skipped.
    pub dvl_no_lock: usize,
    /// DVL beam rows with fewer than 3 beams, skipped.
    pub dvl_insufficient_beams: usize,
    /// Measurements outside the IMU's span (before its first interval or after its
    /// end), skipped.
    pub outside_imu_span: usize,
    /// Gaps between consecutive DVL updates longer than twice the median DVL
    /// interval, coasted on the INS alone.
    pub dvl_gaps_coasted: usize,
    /// The longest interval between consecutive DVL updates \[s\].
    pub longest_dvl_gap_s: f64,
    /// The final DVL noise scale λ when the noise level is adapted
    /// (`dvl.adaptive_noise_window`), else `None`.
    pub dvl_noise_scale: Option<f64>,
    /// NIS of every DVL update attempt.
    pub dvl_nis: Vec<f64>,
    /// Time of each entry of `dvl_nis` \[s\].
    pub dvl_nis_times: Vec<f64>,
    /// Times of the accepted DVL updates \[s\], increasing.
    pub dvl_update_times: Vec<f64>,
    /// What the BeamsNet sensor did ([`navigate_learned`] only).
    pub learned: Option<LearnedCounts>,
    /// NIS of every depth update attempt.
    pub depth_nis: Vec<f64>,
    /// NIS of every fix update attempt.
    pub fix_nis: Vec<f64>,
    /// Solutions emitted.
    pub solutions: usize,
    /// The last solution.
    pub final_solution: NavSolution,
    /// The final DVL error states with their 1-sigma, when estimated (`[dvl_states]`).
    pub dvl_states: Option<DvlStateSolution>,
    /// Each output epoch ([`SurveyInputs::output_epochs`]) as the run met it, in
    /// order; the filter's observer was told of it with a mark (a smoother's recorder
    /// closes its epoch there: [`estim_core::Observer::on_mark`]). Not serialized.
    #[serde(skip)]
    pub output_marks: Vec<OutputMark>,
    /// Time of each depth and fix update attempt \[s\], in order (accepted or
    /// gated). Not serialized.
    #[serde(skip)]
    pub aiding_times: Vec<f64>,
}

/// An output epoch of a batch run: the estimate there is the filter's at `at`
/// predicted over `time - at` with `sample` ([`Navigator::predicted`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OutputMark {
    /// The output epoch \[s\].
    pub time: f64,
    /// The navigator's time then \[s\] (at or before `time`).
    pub at: f64,
    /// The IMU sample it held (`None` before the first).
    pub sample: Option<ImuSample>,
}

/// What [`navigate_learned`] did with the beam rows.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct LearnedCounts {
    /// Updates with BeamsNet's velocity (and M from its sensitivity).
    pub beamsnet_updates: usize,
    /// Rows with 3 beams: least squares on them (M = 0, the vehicle's DVL noise);
    /// BeamsNet takes 4 beams and no beam is filled in.
    pub least_squares_three_beams: usize,
    /// Rows before a full IMU window (the first second): least squares.
    pub least_squares_window_not_full: usize,
    /// Time \[s\] and network velocity \[m/s\] of the first BeamsNet update.
    pub first_update: Option<(f64, [f64; 3])>,
}

/// What one update did, for the run's NIS and counts.
#[derive(Debug, Clone, Copy)]
struct Applied {
    nis: f64,
    accepted: bool,
}

impl<const N: usize, const M: usize> From<estim_core::UpdateReport<f64, N, M>> for Applied {
    fn from(r: estim_core::UpdateReport<f64, N, M>) -> Self {
        Self {
            nis: r.nis,
            accepted: r.is_accepted(),
        }
    }
}

/// A learned DVL update of a batch run on 4 beams at a time (`Ok(None)` before a
/// full window): BeamsNet on the 15-state navigator.
type LearnedUpdate<'a, E, O, const N: usize> =
    dyn FnMut(&mut Navigator<E, O, N>, f64, &Vector4<f64>) -> Result<Option<Applied>> + 'a;

/// The error for a run that cannot take the DVL error states.
fn dvl_states_unsupported(what: &str) -> NavigatorError {
    NavigatorError::conflict(
        "dvl_states",
        format!(
            "{what} runs the 15-state filter; remove the [dvl_states] table from the \
             vehicle configuration"
        ),
    )
}

/// One measurement of a batch run.
#[derive(Debug, Clone, Copy)]
enum Event {
    /// One of [`SurveyInputs::output_epochs`]: a solution predicted on a copy.
    Output,
    Dvl(DvlInput),
    Depth(f64),
    Fix(PositionFix),
}

/// The time a measurement is applied at: the IMU sample time nearest to `t` (the
/// end of the last sample's interval counts as one), when within half a period; `t`
/// itself inside an IMU gap; `None` before the first sample's end or after the
/// IMU's end.
pub(super) fn snap(imu: &[ImuSample], period: f64, t: f64) -> Option<f64> {
    let last = imu.last()?;
    let end = last.time + period;
    let time_at = |j: usize| imu.get(j).map_or(end, |s| s.time);
    let j = imu.partition_point(|s| s.time < t);
    let candidates = [j.checked_sub(1), Some(j)];
    let (best, distance) = candidates
        .into_iter()
        .flatten()
        .filter(|&k| k <= imu.len())
        .map(|k| (k, (time_at(k) - t).abs()))
        .min_by(|a, b| a.1.total_cmp(&b.1).then(b.0.cmp(&a.0)))?;
    let half = 0.5 * period * (1.0 + 1e-9);
    if best == 0 || t > end + half {
        return None;
    }
    if distance <= half {
        Some(time_at(best))
    } else {
        Some(t)
    }
}

/// Navigate a survey: initial state from the configuration (else the first fix and a
/// coarse alignment), then the IMU and the measurements merged by time, each
/// measurement at its stamp minus its sensor's time offset, applied at the nearest
/// IMU sample time (see [`Navigator`] for the integration). Emits a solution to
/// `observer` after every DVL row and, with `output_rate_hz`, at that rate (at the
/// first IMU sample at or after each multiple of 1 / rate from the start).
///
/// DVL rows without lock and beam rows with fewer than 3 beams are skipped and
/// counted; measurements outside the IMU's span are skipped and counted.
///
/// # Errors
/// [`NavigatorError::Inputs`] for unusable inputs (no IMU, no initial position);
/// the navigator's errors; [`NavigatorError::Observer`].
pub fn navigate(
    inputs: &SurveyInputs,
    settings: &NavigatorSettings,
    output_rate_hz: Option<f64>,
    observer: &mut dyn NavigationObserver,
) -> Result<NavigationRun> {
    let Some(states) = settings.dvl_states().copied() else {
        return navigate_with(inputs, settings, output_rate_hz, observer, NoObserver)
            .map(|(run, _)| run);
    };
    run_batch(
        inputs,
        settings,
        output_rate_hz,
        observer,
        None,
        |state, covariance, period| {
            AugmentedNavigator::with_states(settings, &states, state, covariance, period)
        },
    )
    .map(|(run, _)| run)
}

/// [`navigate`] on the 15-state filter with an estim-core observer on it (e.g. a
/// `ForwardRecorder` for the smoother), returned with the run.
///
/// # Errors
/// As [`navigate`]; [`NavigatorError::Conflict`] naming `dvl_states` when the settings
/// hold DVL error states.
pub fn navigate_with<F: Observer<f64, InsState, ERROR_STATES>>(
    inputs: &SurveyInputs,
    settings: &NavigatorSettings,
    output_rate_hz: Option<f64>,
    observer: &mut dyn NavigationObserver,
    filter_observer: F,
) -> Result<(NavigationRun, F)> {
    if settings.dvl_states().is_some() {
        return Err(dvl_states_unsupported(
            "a run with a filter observer (the smoother)",
        ));
    }
    run_batch(
        inputs,
        settings,
        output_rate_hz,
        observer,
        None,
        |state, covariance, period| {
            Ok(Navigator::new(settings, state, covariance, period)?.with_observer(filter_observer))
        },
    )
    .map(|(run, nav)| (run, nav.into_filter().into_observer()))
}

/// [`navigate`] on the DVL error states of `states` with an estim-core observer on
/// the filter (the smoother's recorder), returned with the run.
///
/// # Errors
/// As [`navigate`].
pub(super) fn navigate_augmented_with<
    F: Observer<f64, super::AugmentedState, { super::AUGMENTED_STATES }>,
>(
    inputs: &SurveyInputs,
    settings: &NavigatorSettings,
    states: &super::DvlStatesConfig,
    output_rate_hz: Option<f64>,
    observer: &mut dyn NavigationObserver,
    filter_observer: F,
) -> Result<(NavigationRun, F)> {
    run_batch(
        inputs,
        settings,
        output_rate_hz,
        observer,
        None,
        |state, covariance, period| {
            Ok(
                AugmentedNavigator::with_states(settings, states, state, covariance, period)?
                    .with_observer(filter_observer),
            )
        },
    )
    .map(|(run, nav)| (run, nav.into_filter().into_observer()))
}

/// [`navigate`] with the embedded BeamsNet (`estim::models::beamsnet`) as the DVL
/// sensor: each row with 4 beams is an update with the network's velocity on the
/// [`estim_learned::BEAMSNET_WINDOW`] IMU samples the filter integrated before it and
/// those beams, with the network's R and M from its own sensitivity
/// ([`Navigator::dvl_beamsnet`]). Rows with 3 beams, and rows before a full window, are
/// least-squares updates (M = 0), counted in [`LearnedCounts`]; no beam is ever
/// synthesized or filled in.
///
/// # Errors
/// [`NavigatorError::Inputs`] for DVL rows that are not beams, or beams whose geometry
/// (`dvl.beam_angle_deg`, `dvl.beam1_azimuth_deg`) is not the one the network was
/// trained on; [`NavigatorError::Conflict`] for an IMU period other than the network's
/// 0.01 s, or settings with DVL error states (`dvl_states`); as [`navigate`].
#[cfg(feature = "learned")]
pub fn navigate_learned(
    inputs: &SurveyInputs,
    settings: &NavigatorSettings,
    output_rate_hz: Option<f64>,
    observer: &mut dyn NavigationObserver,
    network: &estim_learned::BeamsNet,
) -> Result<NavigationRun> {
    if settings.dvl_states().is_some() {
        return Err(dvl_states_unsupported("BeamsNet"));
    }
    if inputs
        .dvl
        .iter()
        .any(|d| !matches!(d.input, DvlInput::Beams(_) | DvlInput::NoLock))
    {
        return Err(NavigatorError::Inputs(
            "BeamsNet takes DVL beams (a beams CSV or a beam-coordinate PD0 file), not \
             velocities"
                .into(),
        ));
    }
    let metadata = network.measurement().metadata();
    if let Some(g) = &metadata.beam_geometry {
        let theta = g.theta_deg.to_radians();
        let trained: Vec<Vector3<f64>> = g
            .psi_deg
            .iter()
            .map(|psi| {
                let psi = psi.to_radians();
                Vector3::new(
                    psi.cos() * theta.sin(),
                    psi.sin() * theta.sin(),
                    theta.cos(),
                )
            })
            .collect();
        let ours = settings.geometry.matrix();
        let same = trained.len() == 4
            && (0..4).all(|i| (0..3).all(|j| (ours[(i, j)] - trained[i][j]).abs() <= 1e-9));
        if !same {
            return Err(NavigatorError::Inputs(format!(
                "BeamsNet was trained on beams {} deg from the z axis at azimuths {:?} deg; \
                 this survey's beam geometry differs (set dvl.beam_angle_deg and \
                 dvl.beam1_azimuth_deg, or use least squares)",
                g.theta_deg, g.psi_deg
            )));
        }
    }
    let period = imu_period(&inputs.imu, settings)?;
    let window_period = 1.0 / 100.0;
    if (period - window_period).abs() > super::IMU_PERIOD_SNAP * window_period {
        return Err(NavigatorError::conflict(
            "IMU period",
            format!(
                "BeamsNet takes {} IMU samples at 100 Hz; this IMU's period is {period} s",
                estim_learned::BEAMSNET_WINDOW
            ),
        ));
    }
    let mut recording = settings.clone();
    recording.filter_config = estim_core::FilterConfigBuilder::from(settings.filter_config.clone())
        .window_capacity(estim_learned::BEAMSNET_WINDOW)
        .build()?;

    let error_model = InsErrorModel::new(settings.filter_spec);
    let model = settings.dvl_model_with_noise(network.noise_covariance())?;
    let mut beamsnet = |nav: &mut Navigator, time: f64, beams: &Vector4<f64>| {
        Ok(nav
            .dvl_beamsnet(time, beams, network, &error_model, &model)?
            .map(Applied::from))
    };
    run_batch(
        inputs,
        &recording,
        output_rate_hz,
        observer,
        Some(&mut beamsnet),
        |state, covariance, period| Navigator::new(&recording, state, covariance, period),
    )
    .map(|(run, _)| run)
}

/// A caller's DVL update on the 4-beam rows of a batch run ([`navigate_beams_with`]):
/// given the navigator (not yet propagated to the row), the row's time on the
/// navigator's clock (snapped to the IMU) and its four beams, it applies an update
/// and returns its report, or `Ok(None)` to leave the row to least squares.
pub type BeamUpdate<'a, E, O, const N: usize> = dyn FnMut(
        &mut Navigator<E, O, N>,
        f64,
        &Vector4<f64>,
    ) -> Result<Option<estim_core::UpdateReport<f64, N, 3>>>
    + 'a;

/// [`navigate`] on the navigator `make` builds (from the initial state, its 15 x 15
/// covariance and the IMU period), with the caller's `update` on every DVL row with 4
/// beams (another velocity source, another R or a cross-covariance M). Everything
/// else is [`navigate`]'s: the same events, timing, health checks and counts (the
/// caller's updates are counted as `learned.beamsnet_updates`). The study's
/// recorded-IMU runs are this loop with the study's velocity and M.
///
/// # Errors
/// As [`navigate`].
pub fn navigate_beams_with<E, const N: usize>(
    inputs: &SurveyInputs,
    settings: &NavigatorSettings,
    output_rate_hz: Option<f64>,
    observer: &mut dyn NavigationObserver,
    update: &mut BeamUpdate<'_, E, NoObserver, N>,
    make: impl FnOnce(InsState, ErrorMatrix, f64) -> Result<Navigator<E, NoObserver, N>>,
) -> Result<NavigationRun>
where
    E: NavigationModel<N>,
{
    let mut applied = |nav: &mut Navigator<E, NoObserver, N>, time: f64, beams: &Vector4<f64>| {
        Ok(update(nav, time, beams)?.map(Applied::from))
    };
    run_batch(
        inputs,
        settings,
        output_rate_hz,
        observer,
        Some(&mut applied),
        make,
    )
    .map(|(run, _)| run)
}

/// The events of a batch run: each measurement at its stamp minus its sensor's time
/// offset, snapped to the IMU ([`snap`]), and the output epochs inside the run's span,
/// in time order (stable: DVL before depth before fixes before outputs at one time,
/// each in file order); with the rows without lock and the measurements outside the
/// IMU's span or at or before the start time.
struct Events {
    events: Vec<(f64, Event)>,
    no_lock: usize,
    outside: usize,
}

impl Events {
    fn new(
        inputs: &SurveyInputs,
        settings: &NavigatorSettings,
        period: f64,
        start_time: f64,
    ) -> Self {
        let imu = &inputs.imu;
        let config = &settings.config;
        let mut out = Self {
            events: Vec::new(),
            no_lock: 0,
            outside: 0,
        };
        let push = |t: f64, event: Event, out: &mut Self| match snap(imu, period, t) {
            Some(at) if at > start_time => out.events.push((at, event)),
            _ => out.outside += 1,
        };
        for d in &inputs.dvl {
            if d.input == DvlInput::NoLock {
                out.no_lock += 1;
                continue;
            }
            push(
                d.time - config.dvl.time_offset_s,
                Event::Dvl(d.input),
                &mut out,
            );
        }
        for d in &inputs.depth {
            let t = d.time - config.depth.time_offset_s;
            push(t, Event::Depth(d.depth_m), &mut out);
        }
        for f in &inputs.fixes {
            push(
                f.time - config.fixes.time_offset_s,
                Event::Fix(*f),
                &mut out,
            );
        }
        let (first, end) = (
            imu.first().map_or(0.0, |s| s.time),
            imu.last().map_or(0.0, |s| s.time + period),
        );
        for &t in &inputs.output_epochs {
            if t >= first.max(start_time) && t <= end {
                out.events.push((t, Event::Output));
            }
        }
        out.events.sort_by(|a, b| a.0.total_cmp(&b.0));
        out
    }
}

/// The per-epoch hook of a batch run: applies each event, keeps the NIS and the
/// counts, and emits the solutions to the run's observer (after every DVL event, at
/// the output rate after the IMU sample that reaches it, and predicted at each output
/// epoch); its health monitor checks every solution emitted and each sensor's NIS,
/// and stops the run with [`NavigatorError::Diverged`].
struct BatchHook<'a, 'l, E: NavigationModel<N>, O, const N: usize> {
    settings: &'a NavigatorSettings,
    observer: &'a mut dyn NavigationObserver,
    health: HealthMonitor,
    learned: Option<&'a mut LearnedUpdate<'l, E, O, N>>,
    learned_counts: Option<LearnedCounts>,
    start: f64,
    step: Option<f64>,
    next_output: usize,
    solutions: usize,
    dvl_nis: Vec<f64>,
    dvl_nis_times: Vec<f64>,
    dvl_times: Vec<f64>,
    depth_nis: Vec<f64>,
    fix_nis: Vec<f64>,
    insufficient: usize,
    marks: Vec<OutputMark>,
    aiding_times: Vec<f64>,
}

impl<E, O, const N: usize> BatchHook<'_, '_, E, O, N>
where
    E: NavigationModel<N>,
    O: Observer<f64, E::State, N>,
{
    fn emit(&mut self, nav: &Navigator<E, O, N>, kind: SolutionKind) -> Result<()> {
        let solution = nav.solution();
        self.health.check_solution(&solution)?;
        self.solutions += 1;
        self.observer
            .on_solution(kind, &solution, nav.ins(), &nav.ins_covariance())
            .map_err(NavigatorError::Observer)
    }

    /// An output epoch at `time`: a copy of the estimate predicted there, emitted.
    fn output(&mut self, nav: &Navigator<E, O, N>, time: f64) -> Result<()> {
        let (state, covariance) = nav.predicted(time)?;
        let solution = NavSolution::from_state(time, &state, &covariance);
        self.health.check_solution(&solution)?;
        self.observer
            .on_solution(SolutionKind::Epoch, &solution, &state, &covariance)
            .map_err(NavigatorError::Observer)
    }

    /// A DVL row at `time` (the navigator is there): the update it made, if any.
    fn dvl(
        &mut self,
        nav: &mut Navigator<E, O, N>,
        time: f64,
        input: DvlInput,
    ) -> Result<Option<Applied>> {
        let beams = match input {
            DvlInput::Velocity(v) => return Ok(Some(nav.dvl_velocity(time, &v, &Zero)?.into())),
            DvlInput::EarthVelocity(v_ned) => {
                nav.propagate_to(time)?;
                let body = nav.ins().attitude.inverse() * v_ned;
                return Ok(Some(nav.dvl_velocity(time, &body, &Zero)?.into()));
            }
            DvlInput::NoLock => return Ok(None),
            DvlInput::Beams(b) => b,
        };
        let mut report = None;
        if let (Some(learned), Some(counts)) = (self.learned.as_mut(), self.learned_counts.as_mut())
        {
            let present = beams.iter().flatten().filter(|v| v.is_finite()).count();
            if present == 4 {
                let four = Vector4::from_fn(|i, _| beams[i].unwrap_or(f64::NAN));
                report = learned(nav, time, &four)?;
                match report {
                    Some(_) => {
                        counts.beamsnet_updates += 1;
                        if counts.first_update.is_none() {
                            counts.first_update =
                                nav.last_learned_velocity().map(|v| (time, v.into()));
                        }
                    }
                    None => counts.least_squares_window_not_full += 1,
                }
            } else if present == 3 {
                counts.least_squares_three_beams += 1;
            }
        }
        if report.is_some() {
            return Ok(report);
        }
        match self.settings.geometry.solve(&beams).velocity() {
            Some(v) => Ok(Some(nav.dvl_velocity(time, &v, &Zero)?.into())),
            None => {
                nav.propagate_to(time)?;
                self.insufficient += 1;
                Ok(None)
            }
        }
    }
}

impl<E, O, const N: usize> EpochHook<E, O, N> for BatchHook<'_, '_, E, O, N>
where
    E: NavigationModel<N>,
    O: Observer<f64, E::State, N>,
{
    type Measurement = Event;
    type Error = NavigatorError;

    fn propagates(&self, event: &Event) -> bool {
        !matches!(event, Event::Output)
    }

    fn on_sample(&mut self, nav: &Navigator<E, O, N>, sample: &ImuSample) -> Result<()> {
        if let Some(step) = self.step {
            let since = sample.time - self.start;
            if since >= self.next_output as f64 * step {
                self.emit(nav, SolutionKind::Rate)?;
                self.next_output = (since / step).floor() as usize + 1;
            }
        }
        Ok(())
    }

    fn on_epoch(&mut self, nav: &mut Navigator<E, O, N>, t: f64, event: Event) -> Result<()> {
        match event {
            Event::Output => {
                nav.mark()?;
                self.marks.push(OutputMark {
                    time: t,
                    at: nav.clock(),
                    sample: nav.held_sample().copied(),
                });
                self.output(nav, t)?;
            }
            Event::Dvl(input) => {
                if let Some(r) = self.dvl(nav, t, input)? {
                    self.health.record_nis("dvl", t, r.nis, 3)?;
                    self.dvl_nis.push(r.nis);
                    self.dvl_nis_times.push(t);
                    if r.accepted {
                        self.dvl_times.push(t);
                    }
                }
                self.emit(nav, SolutionKind::Dvl)?;
            }
            Event::Depth(d) => {
                let nis = nav.depth(t, d)?.nis;
                self.health.record_nis("depth", t, nis, 1)?;
                self.depth_nis.push(nis);
                self.aiding_times.push(t);
            }
            Event::Fix(f) => {
                let nis = nav
                    .position_fix(t, f.latitude_deg, f.longitude_deg, f.sigma_m)?
                    .nis;
                self.health.record_nis("fixes", t, nis, 2)?;
                self.fix_nis.push(nis);
                self.aiding_times.push(t);
            }
        }
        Ok(())
    }
}

/// The batch run on the navigator `make` builds from the initial state, its
/// covariance and the IMU period, with the learned DVL update `learned` on 4-beam
/// rows if given; returns the run and the navigator.
fn run_batch<E, O, const N: usize>(
    inputs: &SurveyInputs,
    settings: &NavigatorSettings,
    output_rate_hz: Option<f64>,
    observer: &mut dyn NavigationObserver,
    learned: Option<&mut LearnedUpdate<'_, E, O, N>>,
    make: impl FnOnce(InsState, ErrorMatrix, f64) -> Result<Navigator<E, O, N>>,
) -> Result<(NavigationRun, Navigator<E, O, N>)>
where
    E: NavigationModel<N>,
    O: Observer<f64, E::State, N>,
{
    if let Some(rate) = output_rate_hz {
        if !(rate.is_finite() && rate > 0.0) {
            return Err(NavigatorError::invalid(
                "output rate",
                format!("{rate} Hz is not positive and finite"),
            ));
        }
    }
    let imu = &inputs.imu;
    let period = imu_period(imu, settings)?;
    let (state, covariance, alignment) = initial_state(inputs, settings)?;
    let start_time = state.time;
    let mut nav = make(state, covariance, period)?;
    let events = Events::new(inputs, settings, period, start_time);
    let start = imu.first().map_or(0.0, |s| s.time);
    let skipped = first_imu_index(inputs, settings)?;
    let health = HealthMonitor::new(settings.config.health.clone());
    health.check_imu_times(imu.iter().map(|s| s.time))?;
    let mut hook = BatchHook {
        settings,
        observer,
        health,
        learned_counts: learned.as_ref().map(|_| LearnedCounts::default()),
        learned,
        start,
        step: output_rate_hz.map(|r| 1.0 / r),
        next_output: 0,
        solutions: 0,
        dvl_nis: Vec::new(),
        dvl_nis_times: Vec::new(),
        dvl_times: Vec::new(),
        depth_nis: Vec::new(),
        fix_nis: Vec::new(),
        insufficient: 0,
        marks: Vec::new(),
        aiding_times: Vec::new(),
    };
    // The samples before the start are skipped but counted as fed, as the run's
    // `imu_samples` counts the IMU's samples up to the last one fed.
    let fed = skipped
        + run_epochs(
            &mut nav,
            &imu[skipped..],
            events.events,
            &mut hook,
            Tail::FeedRest,
        )?;
    let dvl_times = hook.dvl_times;
    let mut gaps: Vec<f64> = dvl_times.windows(2).map(|w| w[1] - w[0]).collect();
    let longest = gaps.iter().copied().fold(0.0, f64::max);
    gaps.sort_by(f64::total_cmp);
    let median = gaps.get(gaps.len() / 2).copied().unwrap_or(f64::INFINITY);
    let coasted = gaps.iter().filter(|&&g| g > 2.0 * median).count();
    let run = NavigationRun {
        alignment,
        imu_period_s: period,
        span_s: [start, imu.last().map_or(start, |s| s.time)],
        imu_samples: fed,
        dvl: nav.dvl_counts,
        depth: nav.depth_counts,
        fixes: nav.fix_counts,
        dvl_no_lock: events.no_lock,
        dvl_insufficient_beams: hook.insufficient,
        outside_imu_span: events.outside,
        dvl_gaps_coasted: coasted,
        longest_dvl_gap_s: longest,
        dvl_noise_scale: nav.dvl_noise_scale(),
        dvl_nis: hook.dvl_nis,
        dvl_nis_times: hook.dvl_nis_times,
        dvl_update_times: dvl_times,
        learned: hook.learned_counts,
        depth_nis: hook.depth_nis,
        fix_nis: hook.fix_nis,
        solutions: hook.solutions,
        final_solution: nav.solution(),
        dvl_states: nav.dvl_states(),
        output_marks: hook.marks,
        aiding_times: hook.aiding_times,
    };
    Ok((run, nav))
}
