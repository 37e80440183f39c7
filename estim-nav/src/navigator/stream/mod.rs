//! The streaming navigator: records fed in arrival order, each measurement applied at
//! its own time from a bounded history, solutions emitted once final.
//!
//! [`StreamNavigator`] wraps the one [`Navigator`] (the 15-state error model, or the
//! augmented one when the settings hold `[dvl_states]`) in a [`History`]: checkpoints
//! of the whole navigator (nominal, covariance, the accumulated process noise and
//! recorded window the correlated update's M is built from, the adaptive DVL noise
//! level, the health monitor's NIS windows) and the time-ordered log of IMU samples
//! and measurements since. A measurement stamped in the past is inserted at its place
//! and the log replayed from the checkpoint before it (state history with replay: the
//! module docs of [`History`] say why this method), so the result is that of the batch
//! run ([`super::navigate`]) with every record on time, bit for bit.
//!
//! Timing is the batch run's: a measurement stamped t is applied at t minus its
//! sensor's `time_offset_s`, at the nearest IMU sample time
//! ([`MeasurementTiming::NearestImuSample`], as [`super::navigate`] does), or at that
//! exact time with the held IMU sample's interval split there
//! ([`MeasurementTiming::Exact`]). A measurement waits until an IMU sample at or after
//! its time has arrived (its nearest sample is known then).
//!
//! Final: the stream's time is its latest IMU sample's; a solution is final once the
//! stream's time has passed it by the history's length ([`StreamConfig`]). A
//! measurement whose time is before that boundary is refused and counted
//! ([`Refusal::TooOld`]), never applied at another time. Memory is bounded by the
//! history's length (and a cap on its events), not by the stream's.
//!
//! The initial state is the batch run's ([`super::navigate`]): from the configuration,
//! else the first fix and a coarse alignment over `initial.alignment_s`; records are
//! buffered until it can be made (the first fix arrived, the alignment window covered,
//! the first depth arrived or one history length passed without one), up to the
//! history's event cap.

mod engine;
mod history;
mod replica;
#[cfg(test)]
mod tests;
mod types;

use std::sync::Arc;

use estim_ins::{ImuSample, InsErrorModel, ERROR_STATES};

use engine::{Engine, Waiting};
pub use history::{EventKey, History, HistoryLimits, HistoryStats, NotInserted, Replay};
use replica::{Event, Produced, Replica};
pub use types::{
    Admission, FinalSolution, MeasurementTiming, NisSummary, Refusal, Result, Sensor, StreamConfig,
    StreamConfigBuilder, StreamCounts, StreamError,
};

use super::initial::{first_imu_index, imu_period, initial_state};
use super::{
    Alignment, AugmentedErrorModel, AugmentedNavigator, DepthSample, DvlInput, DvlRecord,
    DvlStateSolution, HealthMonitor, NavSolution, Navigator, NavigatorSettings, PositionFix,
    SolutionKind, SurveyInputs, UpdateCounts, AUGMENTED_STATES,
};

/// A record buffered before the initial state is made.
#[derive(Debug, Clone, Copy)]
enum Buffered {
    Imu(ImuSample),
    Dvl(DvlRecord),
    Depth(DepthSample),
    Fix(PositionFix),
}

/// The navigator the settings ask for.
#[derive(Clone)]
enum Running {
    Ins(Box<Engine<InsErrorModel, ERROR_STATES>>),
    Augmented(Box<Engine<AugmentedErrorModel, AUGMENTED_STATES>>),
}

macro_rules! dispatch {
    ($running:expr, $engine:ident => $body:expr) => {
        match $running {
            Running::Ins($engine) => $body,
            Running::Augmented($engine) => $body,
        }
    };
}

/// The streaming INS/DVL navigator (module docs).
///
/// ```
/// use estim_nav::navigator::{
///     DvlInput, DvlRecord, NavigatorConfig, StreamConfig, StreamNavigator,
/// };
/// use estim_ins::ImuSample;
/// use estim_core::nalgebra::Vector3;
///
/// let mut config = NavigatorConfig::default();
/// config.initial.latitude_deg = Some(32.0);
/// config.initial.longitude_deg = Some(34.0);
/// config.initial.attitude_deg = Some([0.0, 0.0, 0.0]);
/// config.initial.depth_m = Some(0.0);
/// config.imu.rate_hz = Some(100.0);
/// let stream = StreamConfig::builder().history_s(2.0).build()?;
/// let mut nav = StreamNavigator::new(config.check()?, stream);
/// let g = estim_ins::earth::normal_gravity(32f64.to_radians(), 0.0);
/// for k in 0..300 {
///     let t = k as f64 * 0.01;
///     nav.push_imu(ImuSample::new(t, Vector3::new(0.0, 0.0, -g), Vector3::zeros()))?;
///     if k == 250 {
///         // The DVL row stamped 1.0 s arrives 1.5 s late: applied at 1.0 s.
///         nav.push_dvl(DvlRecord { time: 1.0, input: DvlInput::Velocity(Vector3::zeros()) })?;
///     }
/// }
/// nav.finish()?;
/// let solutions = nav.take_final();
/// assert_eq!(solutions.len(), 1);
/// assert_eq!(solutions[0].solution.time, 1.0);
/// assert_eq!(nav.counts().rewinds, 1);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone)]
pub struct StreamNavigator {
    settings: Arc<NavigatorSettings>,
    /// Checks the IMU's gaps as the samples arrive (`health.max_imu_gap_s`).
    gaps: HealthMonitor,
    config: StreamConfig,
    startup: Vec<Buffered>,
    running: Option<Running>,
    alignment: Option<Alignment>,
    last_imu_time: Option<f64>,
    sequence: u64,
    counts: StreamCounts,
    ready: Vec<FinalSolution>,
    lag_failure: Option<String>,
    finished: bool,
}

impl StreamNavigator {
    /// A streaming navigator on checked vehicle settings (the 15-state filter, or the
    /// augmented one when they hold `[dvl_states]`).
    pub fn new(settings: NavigatorSettings, config: StreamConfig) -> Self {
        Self {
            gaps: HealthMonitor::new(settings.config.health.clone()),
            settings: Arc::new(settings),
            config,
            startup: Vec::new(),
            running: None,
            alignment: None,
            last_imu_time: None,
            sequence: 0,
            counts: StreamCounts::default(),
            ready: Vec::new(),
            lag_failure: None,
            finished: false,
        }
    }

    /// The stream's settings.
    pub fn config(&self) -> &StreamConfig {
        &self.config
    }

    /// What the stream did so far.
    pub fn counts(&self) -> StreamCounts {
        let mut counts = self.counts;
        if let Some(running) = &self.running {
            let stats = dispatch!(running, e => e.history.stats());
            counts.rewinds = stats.rewinds;
            counts.replayed_events = stats.replayed;
            counts.max_history_events = stats.max_events;
            counts.max_checkpoints = stats.max_checkpoints;
        }
        counts
    }

    /// Events in the history now (IMU samples and measurements not yet dropped).
    pub fn history_events(&self) -> usize {
        self.running
            .as_ref()
            .map_or(self.startup.len(), |r| dispatch!(r, e => e.history.len()))
    }

    /// Checkpoints held now.
    pub fn history_checkpoints(&self) -> usize {
        self.running
            .as_ref()
            .map_or(0, |r| dispatch!(r, e => e.history.checkpoints()))
    }

    /// The initial state's sources, once it is made.
    pub fn alignment(&self) -> Option<&Alignment> {
        self.alignment.as_ref()
    }

    /// The nominal IMU period in use \[s\], once running.
    pub fn imu_period(&self) -> Option<f64> {
        self.running.as_ref().map(|r| dispatch!(r, e => e.period))
    }

    /// The final boundary \[s\]: solutions before it are final, measurements before
    /// it refused.
    pub fn boundary(&self) -> f64 {
        self.running.as_ref().map_or(
            f64::NEG_INFINITY,
            |r| dispatch!(r, e => e.history.boundary()),
        )
    }

    /// The solution after every record so far (not final), once running.
    pub fn solution(&self) -> Option<NavSolution> {
        self.running
            .as_ref()
            .map(|r| dispatch!(r, e => e.history.current().nav.solution()))
    }

    /// DVL, depth and fix update counts of the filter now.
    pub fn update_counts(&self) -> Option<[UpdateCounts; 3]> {
        self.running.as_ref().map(|r| {
            dispatch!(r, e => {
                let nav = &e.history.current().nav;
                [nav.dvl_counts, nav.depth_counts, nav.fix_counts]
            })
        })
    }

    /// The DVL error states now, when the settings hold them.
    pub fn dvl_states(&self) -> Option<DvlStateSolution> {
        self.running
            .as_ref()
            .and_then(|r| dispatch!(r, e => e.history.current().nav.dvl_states()))
    }

    /// The DVL noise scale now, when adapted.
    pub fn dvl_noise_scale(&self) -> Option<f64> {
        self.running
            .as_ref()
            .and_then(|r| dispatch!(r, e => e.history.current().nav.dvl_noise_scale()))
    }

    /// Why an update epoch had no fixed-lag smoothed solution, the first time it
    /// happened (the count is [`StreamCounts::lag_unavailable`]).
    pub fn lag_failure(&self) -> Option<&str> {
        self.lag_failure.as_deref()
    }

    /// The solutions made final since the last call, in time order.
    pub fn take_final(&mut self) -> Vec<FinalSolution> {
        std::mem::take(&mut self.ready)
    }

    /// Feed one IMU sample (on the navigator's clock, body frame), after the previous
    /// one. Makes final what the stream's new time allows.
    ///
    /// # Errors
    /// [`StreamError::ImuTimeOrder`], [`StreamError::NonFinite`],
    /// [`StreamError::HistoryFull`]; the navigator's (a failure, a divergence, an IMU
    /// gap above `health.max_imu_gap_s`).
    pub fn push_imu(&mut self, sample: ImuSample) -> Result<Admission> {
        let finite = sample.time.is_finite()
            && sample.specific_force.iter().all(|v| v.is_finite())
            && sample.angular_rate.iter().all(|v| v.is_finite());
        if !finite {
            return Err(StreamError::NonFinite {
                sensor: Sensor::Imu,
                time: sample.time,
            });
        }
        if let Some(previous) = self.last_imu_time {
            if sample.time <= previous {
                return Err(StreamError::ImuTimeOrder {
                    time: sample.time,
                    previous,
                });
            }
            self.gaps.check_imu_times([previous, sample.time])?;
        }
        self.last_imu_time = Some(sample.time);
        self.counts.imu_samples += 1;
        if self.running.is_none() {
            self.startup.push(Buffered::Imu(sample));
            self.try_start()?;
            return Ok(Admission::Taken);
        }
        self.imu(sample)?;
        Ok(Admission::Taken)
    }

    /// Feed one DVL row (its stamp before `dvl.time_offset_s`).
    ///
    /// # Errors
    /// [`StreamError::NonFinite`] for a non-finite time; the navigator's.
    pub fn push_dvl(&mut self, record: DvlRecord) -> Result<Admission> {
        self.counts.measurements += 1;
        if record.input == DvlInput::NoLock {
            self.counts.dvl_no_lock += 1;
            return Ok(Admission::NoLock);
        }
        self.measurement(Buffered::Dvl(record))
    }

    /// Feed one depth sample (its stamp before `depth.time_offset_s`).
    ///
    /// # Errors
    /// As [`StreamNavigator::push_dvl`].
    pub fn push_depth(&mut self, sample: DepthSample) -> Result<Admission> {
        self.counts.measurements += 1;
        self.measurement(Buffered::Depth(sample))
    }

    /// Feed one position fix (its stamp before `fixes.time_offset_s`).
    ///
    /// # Errors
    /// As [`StreamNavigator::push_dvl`].
    pub fn push_fix(&mut self, fix: PositionFix) -> Result<Admission> {
        self.counts.measurements += 1;
        self.measurement(Buffered::Fix(fix))
    }

    /// The end of the stream: the waiting measurements are applied with the IMU's end
    /// (its last sample's interval) known, and every solution is made final.
    ///
    /// # Errors
    /// [`StreamError::NotInitialized`] when the initial state could never be made; the
    /// navigator's.
    pub fn finish(&mut self) -> Result<()> {
        if self.finished {
            return Ok(());
        }
        self.finished = true;
        if self.running.is_none() {
            self.start(true)?;
        }
        let mut refusals = Vec::new();
        let mut tail = Vec::new();
        if let Some(running) = &mut self.running {
            dispatch!(running, e => {
                e.resolve_at_end(&mut refusals)?;
                e.history.finalize_all();
                tail = e.history.current().lagged_tail();
            });
        }
        self.count_refusals(&refusals);
        self.collect();
        for output in tail {
            absorb(
                &mut self.counts,
                &mut self.ready,
                &mut self.lag_failure,
                output,
            );
        }
        Ok(())
    }

    fn count_refusals(&mut self, refusals: &[Refusal]) {
        for r in refusals {
            match r {
                Refusal::TooOld { .. } => self.counts.refused_too_old += 1,
                Refusal::OutsideImuSpan { .. } => self.counts.outside_imu_span += 1,
                Refusal::HistoryFull { .. } => self.counts.refused_history_full += 1,
            }
        }
    }

    /// A measurement: buffered before the start, else queued.
    fn measurement(&mut self, record: Buffered) -> Result<Admission> {
        let (sensor, time) = match &record {
            Buffered::Dvl(d) => (Sensor::Dvl, d.time),
            Buffered::Depth(d) => (Sensor::Depth, d.time),
            Buffered::Fix(f) => (Sensor::Fix, f.time),
            Buffered::Imu(s) => (Sensor::Imu, s.time),
        };
        let finite = time.is_finite()
            && match &record {
                Buffered::Dvl(d) => match d.input {
                    DvlInput::Velocity(v) | DvlInput::EarthVelocity(v) => {
                        v.iter().all(|x| x.is_finite())
                    }
                    _ => true,
                },
                Buffered::Depth(d) => d.depth_m.is_finite(),
                Buffered::Fix(f) => [f.latitude_deg, f.longitude_deg, f.sigma_m]
                    .iter()
                    .all(|x| x.is_finite()),
                Buffered::Imu(_) => true,
            };
        if !finite {
            return Err(StreamError::NonFinite { sensor, time });
        }
        if self.running.is_none() {
            self.startup.push(record);
            self.try_start()?;
            return Ok(Admission::Taken);
        }
        let admission = self.queue(record)?;
        self.collect();
        Ok(admission)
    }

    /// Queue a measurement on the running engine.
    fn queue(&mut self, record: Buffered) -> Result<Admission> {
        self.sequence += 1;
        let sequence = self.sequence;
        let config = &self.settings.config;
        let waiting = match record {
            Buffered::Dvl(d) => Waiting {
                sensor: Sensor::Dvl,
                time: d.time - config.dvl.time_offset_s,
                event: Event::Dvl(d.input),
                sequence,
            },
            Buffered::Depth(d) => Waiting {
                sensor: Sensor::Depth,
                time: d.time - config.depth.time_offset_s,
                event: Event::Depth(d.depth_m),
                sequence,
            },
            Buffered::Fix(f) => Waiting {
                sensor: Sensor::Fix,
                time: f.time - config.fixes.time_offset_s,
                event: Event::Fix(f),
                sequence,
            },
            Buffered::Imu(s) => {
                self.imu(s)?;
                return Ok(Admission::Taken);
            }
        };
        let Some(running) = &mut self.running else {
            return Ok(Admission::Taken);
        };
        let mut refusals = Vec::new();
        dispatch!(running, e => e.wait(waiting, &mut refusals)?);
        self.count_refusals(&refusals);
        Ok(refusals
            .first()
            .map_or(Admission::Taken, |r| Admission::Refused(*r)))
    }

    /// An IMU sample on the running engine.
    fn imu(&mut self, sample: ImuSample) -> Result<()> {
        let history_s = self.config.history_s();
        let mut refusals = Vec::new();
        if let Some(running) = &mut self.running {
            dispatch!(running, e => e.imu(sample, history_s, &mut refusals)?);
        }
        self.count_refusals(&refusals);
        self.collect();
        Ok(())
    }

    /// Move the final outputs out of the history.
    fn collect(&mut self) {
        let Some(running) = &mut self.running else {
            return;
        };
        let counts = &mut self.counts;
        let ready = &mut self.ready;
        let lag_failure = &mut self.lag_failure;
        dispatch!(running, e => {
            for (_, output) in e.history.take_final() {
                absorb(counts, ready, lag_failure, output);
            }
        });
    }

    /// Start when the initial state can be made from what is buffered.
    fn try_start(&mut self) -> Result<()> {
        if self.ready_to_start()? {
            self.start(false)?;
        } else {
            self.check_buffer("the initial state's inputs are not all in yet")?;
        }
        Ok(())
    }

    /// Whether the buffer holds what the initial state needs (module docs).
    fn ready_to_start(&self) -> Result<bool> {
        let c = &self.settings.config;
        let imu: Vec<f64> = self
            .startup
            .iter()
            .filter_map(|b| match b {
                Buffered::Imu(s) => Some(s.time),
                _ => None,
            })
            .collect();
        let (Some(&first), Some(&last)) = (imu.first(), imu.last()) else {
            return self.check_buffer("no IMU sample yet");
        };
        let start = match c.initial.time_s {
            Some(t) if last < t => return self.check_buffer("no IMU sample at initial.time_s yet"),
            Some(t) => imu.iter().copied().find(|&s| s >= t).unwrap_or(last),
            None => first,
        };
        let has = |f: fn(&Buffered) -> bool| self.startup.iter().any(f);
        let configured = c.initial.latitude_deg.is_some() && c.initial.longitude_deg.is_some();
        if !configured && !has(|b| matches!(b, Buffered::Fix(_))) {
            return self.check_buffer("no initial position and no fix yet");
        }
        if c.initial.attitude_deg.is_none() && last < start + c.initial.alignment_s {
            return self.check_buffer("the alignment window is not covered yet");
        }
        if c.imu.rate_hz.is_none() && imu.len() < 2 {
            return Ok(false);
        }
        if c.initial.depth_m.is_none()
            && !has(|b| matches!(b, Buffered::Depth(_)))
            && last < first + self.config.history_s()
        {
            return Ok(false);
        }
        Ok(true)
    }

    fn check_buffer(&self, reason: &str) -> Result<bool> {
        if self.startup.len() >= self.config.limits().max_events {
            return Err(StreamError::NotInitialized {
                records: self.startup.len(),
                reason: reason.to_string(),
            });
        }
        Ok(false)
    }

    /// Make the initial state from the buffer and replay it into the engine (`at_end`:
    /// the stream ended, start with what there is).
    fn start(&mut self, at_end: bool) -> Result<()> {
        let buffered = std::mem::take(&mut self.startup);
        let mut inputs = SurveyInputs::default();
        for b in &buffered {
            match b {
                Buffered::Imu(s) => inputs.imu.push(*s),
                Buffered::Fix(f) => inputs.fixes.push(*f),
                Buffered::Depth(d) => inputs.depth.push(*d),
                Buffered::Dvl(_) => {}
            }
        }
        // The batch run uses the first fix and depth of its files (the earliest).
        inputs.fixes.sort_by(|a, b| a.time.total_cmp(&b.time));
        inputs.depth.sort_by(|a, b| a.time.total_cmp(&b.time));
        if inputs.imu.is_empty() && at_end {
            return Err(StreamError::NotInitialized {
                records: buffered.len(),
                reason: "the stream ended before any IMU sample".into(),
            });
        }
        let period = imu_period(&inputs.imu, &self.settings)?;
        // As the batch run: an `initial.time_s` with no IMU sample near it is refused.
        first_imu_index(&inputs, &self.settings)?;
        let (state, covariance, alignment) = initial_state(&inputs, &self.settings)?;
        let first_imu_time = inputs.imu[0].time;
        let skip_before = self.settings.config.initial.time_s;
        let start_time = state.time;
        let geometry = Arc::new(self.settings.geometry.clone());
        let health = HealthMonitor::new(self.settings.config.health.clone());
        let lag = self.config.lag_s().zip(self.config.lag_epochs());
        if lag.is_some() && self.settings.dvl_states().is_some() {
            return Err(StreamError::Config {
                key: "lag_s",
                reason: "the fixed-lag smoother runs the 15-state filter (held DVL states \
                         make the covariance singular); remove the [dvl_states] table"
                    .into(),
            });
        }
        let rate = self
            .config
            .output_rate_hz()
            .map(|r| (first_imu_time, 1.0 / r));
        let running = match self.settings.dvl_states().copied() {
            None => {
                let nav = Navigator::new(&self.settings, state, covariance, period)?;
                Running::Ins(Box::new(Engine::new(
                    Replica::new(nav, health, geometry, rate, lag),
                    self.config.limits(),
                    first_imu_time,
                    start_time,
                    skip_before,
                    period,
                    self.config.timing(),
                )))
            }
            Some(states) => {
                let nav = AugmentedNavigator::with_states(
                    &self.settings,
                    &states,
                    state,
                    covariance,
                    period,
                )?;
                Running::Augmented(Box::new(Engine::new(
                    Replica::new(nav, health, geometry, rate, lag),
                    self.config.limits(),
                    first_imu_time,
                    start_time,
                    skip_before,
                    period,
                    self.config.timing(),
                )))
            }
        };
        self.running = Some(running);
        self.alignment = Some(alignment);
        for b in buffered {
            match b {
                Buffered::Imu(s) => self.imu(s)?,
                other => {
                    self.queue(other)?;
                }
            }
        }
        self.collect();
        Ok(())
    }
}

/// Count an output made final, and keep it when it is a solution.
fn absorb(
    counts: &mut StreamCounts,
    ready: &mut Vec<FinalSolution>,
    lag_failure: &mut Option<String>,
    output: Produced,
) {
    match output {
        Produced::Solution(kind, solution) => {
            counts.solutions += 1;
            ready.push(FinalSolution {
                kind,
                solution,
                smoothed: false,
            });
        }
        Produced::Lagged(solution) => {
            counts.lagged_solutions += 1;
            ready.push(FinalSolution {
                kind: SolutionKind::Dvl,
                solution,
                smoothed: true,
            });
        }
        Produced::LagUnavailable(reason) => {
            counts.lag_unavailable += 1;
            lag_failure.get_or_insert(reason);
        }
        Produced::Nis(Sensor::Dvl, nis) => counts.dvl_nis.add(nis),
        Produced::Nis(Sensor::Depth, nis) => counts.depth_nis.add(nis),
        Produced::Nis(_, nis) => counts.fix_nis.add(nis),
        Produced::InsufficientBeams => counts.dvl_insufficient_beams += 1,
    }
}

/// Whether two solutions agree to `relative` (each value against the larger of its
/// two magnitudes and 1): the comparison the stream's tests make against a batch run.
pub fn solutions_agree(a: &NavSolution, b: &NavSolution, relative: f64) -> bool {
    let values = |s: &NavSolution| {
        let mut v = vec![
            s.time,
            s.latitude_deg,
            s.longitude_deg,
            s.depth_m,
            s.roll_deg,
            s.pitch_deg,
        ];
        v.extend(s.velocity_ned_mps);
        v.extend(s.position_sigma_m);
        v.extend(s.velocity_sigma_mps);
        v.extend(s.attitude_sigma_deg);
        v.extend(s.acc_bias_mps2);
        v.extend(s.gyro_bias_radps);
        v
    };
    let heading = (a.heading_deg - b.heading_deg + 180.0).rem_euclid(360.0) - 180.0;
    heading.abs() <= relative * a.heading_deg.abs().max(1.0)
        && values(a)
            .iter()
            .zip(values(b))
            .all(|(x, y)| (x - y).abs() <= relative * x.abs().max(y.abs()).max(1.0))
}
