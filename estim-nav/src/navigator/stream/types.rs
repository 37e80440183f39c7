//! The streaming navigator's settings, errors and reports.

use super::history::HistoryLimits;
use crate::navigator::{NavSolution, NavigatorError, SolutionKind};

/// Where a measurement is applied on the IMU's timeline.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum MeasurementTiming {
    /// At the IMU sample time nearest to its time (within half a period; its own time
    /// inside an IMU gap): the batch run's rule ([`navigate`](crate::navigator::navigate)), so that a stream
    /// equals the batch run of the same records.
    #[default]
    NearestImuSample,
    /// At its own time: the held sample is integrated up to it, splitting the IMU
    /// interval.
    Exact,
}

/// A sensor of the stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Sensor {
    /// IMU samples.
    Imu,
    /// DVL velocity or beams.
    Dvl,
    /// Depth.
    Depth,
    /// Position fixes.
    Fix,
}

impl Sensor {
    /// Its name in records and messages (`imu`, `dvl`, `depth`, `fix`).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Imu => "imu",
            Self::Dvl => "dvl",
            Self::Depth => "depth",
            Self::Fix => "fix",
        }
    }
}

impl std::fmt::Display for Sensor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Errors of the streaming navigator.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StreamError {
    /// An invalid stream setting (the key and why).
    #[error("stream setting {key}: {reason}")]
    Config {
        /// The setting.
        key: &'static str,
        /// Why it was refused.
        reason: String,
    },
    /// An IMU sample not after the previous one.
    #[error("IMU sample at t = {time} s is not after the previous one at t = {previous} s")]
    ImuTimeOrder {
        /// Its time \[s\].
        time: f64,
        /// The previous sample's \[s\].
        previous: f64,
    },
    /// A record with a value that is not finite.
    #[error("{sensor} record at t = {time} s: a value is not finite")]
    NonFinite {
        /// Its sensor.
        sensor: Sensor,
        /// Its time \[s\].
        time: f64,
    },
    /// The initial state could not be made before the buffer filled.
    #[error("no initial state after {records} records: {reason}")]
    NotInitialized {
        /// Records buffered.
        records: usize,
        /// What was missing.
        reason: String,
    },
    /// An IMU sample that the history cannot hold (full of later events).
    #[error("IMU sample at t = {time} s: the history is full ({events} events)")]
    HistoryFull {
        /// Its time \[s\].
        time: f64,
        /// The history's cap.
        events: usize,
    },
    /// The navigator (a numerical failure, a divergence, inputs it cannot use).
    #[error(transparent)]
    Navigator(#[from] NavigatorError),
}

/// `Result` of the streaming navigator.
pub type Result<T> = std::result::Result<T, StreamError>;

/// The streaming navigator's settings, checked by [`StreamConfigBuilder::build`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StreamConfig {
    history_s: f64,
    timing: MeasurementTiming,
    output_rate_hz: Option<f64>,
    lag_s: Option<f64>,
    limits: HistoryLimits,
}

impl StreamConfig {
    /// A builder with the defaults: 10 s of history, the batch run's timing, no rate
    /// output, a checkpoint every 10 events, at most 65,536 events.
    pub fn builder() -> StreamConfigBuilder {
        StreamConfigBuilder::default()
    }

    /// The history's length \[s\]: the largest delay a measurement may have, and the
    /// delay of the final solutions.
    pub fn history_s(&self) -> f64 {
        self.history_s
    }

    /// Where measurements are applied.
    pub fn timing(&self) -> MeasurementTiming {
        self.timing
    }

    /// The rate of the `rate` solutions \[Hz\], if any.
    pub fn output_rate_hz(&self) -> Option<f64> {
        self.output_rate_hz
    }

    /// The lag of the fixed-lag smoothed solutions \[s\], if any.
    pub fn lag_s(&self) -> Option<f64> {
        self.lag_s
    }

    /// The update epochs the fixed-lag recording holds: 8 a second of lag, and 2.
    pub fn lag_epochs(&self) -> Option<usize> {
        self.lag_s.map(|lag| 2 + 8 * lag.ceil() as usize)
    }

    /// The history's checkpoint interval and event cap.
    pub fn limits(&self) -> HistoryLimits {
        self.limits
    }
}

impl Default for StreamConfig {
    fn default() -> Self {
        Self {
            history_s: 10.0,
            timing: MeasurementTiming::NearestImuSample,
            output_rate_hz: None,
            lag_s: None,
            limits: HistoryLimits::new(10, 65_536),
        }
    }
}

/// Builds a [`StreamConfig`] (consuming setters, checked once by
/// [`StreamConfigBuilder::build`]).
///
/// ```
/// use estim_nav::navigator::{MeasurementTiming, StreamConfig};
/// let config = StreamConfig::builder().history_s(5.0).timing(MeasurementTiming::Exact).build()?;
/// assert_eq!(config.history_s(), 5.0);
/// assert!(StreamConfig::builder().history_s(-1.0).build().is_err());
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StreamConfigBuilder(StreamConfig);

impl StreamConfigBuilder {
    /// The history's length \[s\] (0 < h <= 3600).
    #[must_use]
    pub fn history_s(mut self, seconds: f64) -> Self {
        self.0.history_s = seconds;
        self
    }

    /// Where measurements are applied.
    #[must_use]
    pub fn timing(mut self, timing: MeasurementTiming) -> Self {
        self.0.timing = timing;
        self
    }

    /// Also emit a solution at this rate \[Hz\] (after the first IMU sample at or after
    /// each multiple of 1 / rate from the first sample, as the batch run does).
    #[must_use]
    pub fn output_rate_hz(mut self, rate: Option<f64>) -> Self {
        self.0.output_rate_hz = rate;
        self
    }

    /// Also emit, at each update epoch, its fixed-lag smoothed solution given the
    /// measurements up to `lag` seconds after it (0 < lag <= 600; estim-core's
    /// Rauch-Tung-Striebel recursion over the recorded update epochs, holding
    /// [`StreamConfig::lag_epochs`] of them).
    #[must_use]
    pub fn lag_s(mut self, lag: Option<f64>) -> Self {
        self.0.lag_s = lag;
        self
    }

    /// A checkpoint before every `events` events (1-10,000).
    #[must_use]
    pub fn checkpoint_every(mut self, events: usize) -> Self {
        self.0.limits.checkpoint_every = events;
        self
    }

    /// At most `events` events in the history (16-100,000,000).
    #[must_use]
    pub fn max_events(mut self, events: usize) -> Self {
        self.0.limits.max_events = events;
        self
    }

    /// The checked settings.
    ///
    /// # Errors
    /// [`StreamError::Config`] naming the setting out of its range.
    pub fn build(self) -> Result<StreamConfig> {
        let c = self.0;
        let bad = |key, reason: String| Err(StreamError::Config { key, reason });
        if !(c.history_s.is_finite() && c.history_s > 0.0 && c.history_s <= 3600.0) {
            return bad(
                "history_s",
                format!("{} s is not in (0, 3600]", c.history_s),
            );
        }
        if let Some(rate) = c.output_rate_hz {
            if !(rate.is_finite() && rate > 0.0) {
                return bad("output_rate_hz", format!("{rate} Hz is not positive"));
            }
        }
        if let Some(lag) = c.lag_s {
            if !(lag.is_finite() && lag > 0.0 && lag <= 600.0) {
                return bad("lag_s", format!("{lag} s is not in (0, 600]"));
            }
        }
        if !(1..=10_000).contains(&c.limits.checkpoint_every) {
            return bad(
                "checkpoint_every",
                format!("{} is not in 1-10000", c.limits.checkpoint_every),
            );
        }
        if !(16..=100_000_000).contains(&c.limits.max_events) {
            return bad(
                "max_events",
                format!("{} is not in 16-100000000", c.limits.max_events),
            );
        }
        Ok(c)
    }
}

/// Why a record was not used.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case", tag = "reason")]
pub enum Refusal {
    /// Its time is before the final boundary: older than the history.
    TooOld {
        /// Its sensor.
        sensor: Sensor,
        /// The time it would be applied at \[s\].
        time: f64,
        /// The boundary \[s\] (the stream's time minus the history's length).
        boundary: f64,
    },
    /// Outside the IMU's span (before the initial state or its first sample, after
    /// the end of its last).
    OutsideImuSpan {
        /// Its sensor.
        sensor: Sensor,
        /// The time it would be applied at \[s\].
        time: f64,
    },
    /// The history is full of later events.
    HistoryFull {
        /// Its sensor.
        sensor: Sensor,
        /// Its time \[s\].
        time: f64,
    },
}

/// What became of a record pushed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Admission {
    /// Taken: applied, waiting for the IMU to reach its time, or buffered until the
    /// initial state is made (a waiting measurement can still be refused later; the
    /// counts say so).
    Taken,
    /// A DVL row without bottom lock: skipped and counted, as in a batch run.
    NoLock,
    /// Refused (and counted).
    Refused(Refusal),
}

/// A solution made final.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FinalSolution {
    /// Why it was emitted (`dvl` after each DVL row, `rate`; for a smoothed solution,
    /// `dvl`).
    pub kind: SolutionKind,
    /// The solution.
    pub solution: NavSolution,
    /// A fixed-lag smoothed solution ([`StreamConfigBuilder::lag_s`]) of an update
    /// epoch, not the filter's.
    pub smoothed: bool,
}

/// Count, mean and largest NIS of one sensor's update attempts (final ones).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct NisSummary {
    /// Update attempts.
    pub count: usize,
    /// Their mean NIS (0 without any).
    pub mean: f64,
    /// Their largest NIS.
    pub max: f64,
}

impl NisSummary {
    pub(super) fn add(&mut self, nis: f64) {
        self.count += 1;
        self.mean += (nis - self.mean) / self.count as f64;
        self.max = self.max.max(nis);
    }
}

/// What the stream did so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct StreamCounts {
    /// IMU samples received.
    pub imu_samples: usize,
    /// Measurements received (DVL, depth, fixes).
    pub measurements: usize,
    /// DVL rows without bottom lock, skipped.
    pub dvl_no_lock: usize,
    /// Measurements refused as older than the history.
    pub refused_too_old: usize,
    /// Measurements outside the IMU's span.
    pub outside_imu_span: usize,
    /// Measurements refused because the history was full.
    pub refused_history_full: usize,
    /// Measurements applied before later events (each a rewind).
    pub rewinds: usize,
    /// Events re-applied by the rewinds.
    pub replayed_events: usize,
    /// The most events the history held.
    pub max_history_events: usize,
    /// The most checkpoints it held.
    pub max_checkpoints: usize,
    /// Final solutions emitted.
    pub solutions: usize,
    /// Fixed-lag smoothed solutions emitted.
    pub lagged_solutions: usize,
    /// Epochs without a smoothed solution: the recording could not be smoothed
    /// exactly (an update accepted by the gate's recovery rule).
    pub lag_unavailable: usize,
    /// DVL beam rows with fewer than 3 beams (final ones).
    pub dvl_insufficient_beams: usize,
    /// NIS of the final DVL update attempts.
    pub dvl_nis: NisSummary,
    /// NIS of the final depth updates.
    pub depth_nis: NisSummary,
    /// NIS of the final fix updates.
    pub fix_nis: NisSummary,
}
