//! The INS/DVL navigator: the 15-state error-state filter assembled from estim-ins
//! (mechanization, error model) and estim-dvl (the DVL velocity model), with optional
//! depth and position fixes, fed with real logs and producing a navigation solution
//! with its uncertainty. No ground truth is needed.
//!
//! - [`NavigatorConfig`]: the vehicle configuration (serde; unknown keys refused),
//!   checked once by [`NavigatorConfig::check`] into [`NavigatorSettings`];
//! - [`Navigator`]: feed IMU samples and measurements in time order, read
//!   [`NavSolution`]s (state and 1-sigma per state group). One navigator, generic over
//!   its error model ([`NavigationModel`]): `Navigator` is `Navigator<InsErrorModel,
//!   NoObserver, 15>` (the 15 INS states, static sizes, no per-step allocation);
//!   [`AugmentedNavigator`] is `Navigator<AugmentedErrorModel, O, 26>`, the same code
//!   with optional DVL error states (scale factor, mounting misalignment, Gauss-Markov
//!   velocity bias, lever arm, time offset; [`DvlStatesConfig`]), built by
//!   [`AugmentedNavigator::with_states`], its DVL states read by
//!   [`Navigator::dvl_states`];
//! - [`run_epochs`]: the one loop that feeds an IMU stream and time-ordered measurement
//!   epochs into a navigator, with a per-epoch hook ([`EpochHook`]: it applies each
//!   epoch's measurements, sees every IMU sample, and can stop the run with its own
//!   typed error); [`navigate`], the smoother and the study's runs are hooks on it;
//! - [`navigate`]: the batch run over time-merged inputs ([`SurveyInputs`]), with the
//!   initial state from the configuration, the first fix and a coarse alignment; on
//!   the augmented error model when the configuration has `dvl_states`;
//! - [`tune`]: maximum-likelihood noise parameters (IMU white-noise densities, DVL
//!   beam noise and mismatch, the scale of the paper's M) with standard errors and a
//!   likelihood-ratio test of M = 0, on A-KIT scenarios or a survey's inputs
//!   ([`tune::survey_measurements`]);
//! - [`StreamNavigator`]: records fed in arrival order, a measurement stamped in the
//!   past applied at its own time by rewind and replay from a bounded [`History`],
//!   solutions emitted once final; equal to [`navigate`] on the same records.
//!
//! Conventions (estim-ins): NED, body x forward y right z down, true = nominal +
//! error, misalignment in NED. A sensor's time offset tau means a sample stamped t
//! measures the motion at t - tau.

mod aiding;
mod augmented;
mod batch;
mod clock;
mod config;
mod filter;
mod fixed;
mod health;
mod initial;
mod inputs;
mod pd0;
mod reference;
mod run;
mod smooth;
mod solution;
mod stream;
pub mod tune;

pub use aiding::{DepthModel, InsNominal, PositionFixModel};
pub use augmented::{
    AccelerationWindow, AugmentedDvlModel, AugmentedErrorModel, AugmentedFilter, AugmentedMatrix,
    AugmentedNavigator, AugmentedState, AugmentedVector, AxisSigma, BiasConfig, DvlParameters,
    DvlStateSolution, DvlStatesConfig, LeverArmState, MisalignmentState, ScaleFactorState,
    TimeOffsetState, ACCELERATION_HISTORY_S, AUGMENTED_STATES, DVL_BIAS, DVL_LEVER_ARM,
    DVL_MISALIGNMENT, DVL_SCALE, DVL_STATES, DVL_TIME_OFFSET,
};
#[cfg(feature = "learned")]
pub use batch::navigate_learned;
pub use batch::{
    navigate, navigate_beams_with, navigate_with, BeamUpdate, LearnedCounts, NavigationRun,
    OutputMark,
};
pub use clock::IMU_PERIOD_SNAP;
pub use config::{
    filter_config, filter_imu_spec, imu_preset, DepthConfig, DvlConfig, FixConfig, GateConfig,
    ImuConfig, ImuFrame, InitialConfig, NavigatorConfig, NavigatorSettings, SensorConfig,
    TruthConfig, FILTER_BIAS_TIME_CONSTANT, IMU_PRESETS,
};
pub use filter::{beams_from_nan, DvlCross, InsFilter, NavigationModel, Navigator};
pub use health::{Divergence, HealthConfig, HealthMonitor};
pub(crate) use initial::median_interval;
pub use initial::{coarse_alignment, nominal_imu_period, Alignment, InitialAttitude};
pub use inputs::{
    DepthSample, DvlInput, DvlRecord, NavigationObserver, PositionFix, SolutionKind, SurveyInputs,
};
pub use pd0::{pd0_records, rdi_beam_geometry, Pd0Conversion};
pub use reference::{
    error_state, nees_of_block, reference_time_offset, ReferenceOffset, MIN_REFERENCE_INTERVALS,
};
pub use run::{run_epochs, EpochHook, Tail};
pub use smooth::{smooth_survey, smooth_survey_at, SmoothedSolution, SmoothingRun};
pub use solution::{format_heading, wrap_heading_deg, NavSolution, UpdateCounts};
pub use stream::{
    solutions_agree, Admission, EventKey, FinalSolution, History, HistoryLimits, HistoryStats,
    MeasurementTiming, NisSummary, NotInserted, Refusal, Replay, Sensor, StreamConfig,
    StreamConfigBuilder, StreamCounts, StreamError, StreamNavigator,
};

/// Errors of the navigator.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum NavigatorError {
    /// A configuration value out of its valid range, or an argument of the API that
    /// is.
    #[error("configuration: {key}: {reason}")]
    InvalidValue {
        /// The key as the vehicle file spells it (`dvl.beam_angle_deg`,
        /// `health.max_speed_mps`), or what the argument is (`DVL noise scale`, `tune`
        /// for the tuner's inputs).
        key: String,
        /// Why the value is not valid (it is quoted).
        reason: String,
    },
    /// A name that is not one of the valid ones.
    #[error("configuration: {key}: unknown {what} `{name}` (valid: {valid})")]
    UnknownName {
        /// The key (`imu.preset`).
        key: String,
        /// What the name names (`preset`).
        what: &'static str,
        /// The name given.
        name: String,
        /// The valid names, comma-separated.
        valid: String,
    },
    /// A `[columns.*]` table that cannot be used: the message of
    /// [`crate::datasets::ColumnMap::check`], which names the section and key.
    #[error("configuration: {0}")]
    ColumnMap(String),
    /// Values that are valid alone but not together (or not with the run asked for).
    #[error("configuration: {keys}: {reason}")]
    Conflict {
        /// The keys (`health.min_depth_m / max_depth_m`, `dvl_states`).
        keys: String,
        /// What does not go together, and what to do.
        reason: String,
    },
    /// A non-finite value (time, specific force or angular rate) in an input.
    #[error("non-finite value in {what} at t = {time} s")]
    NonFinite {
        /// What was fed.
        what: &'static str,
        /// Its time \[s\].
        time: f64,
    },
    /// An input out of time order.
    #[error("{what} at t = {time} s is before the navigator's time {clock} s or not finite")]
    TimeOrder {
        /// What was fed.
        what: &'static str,
        /// Its time \[s\].
        time: f64,
        /// The navigator's clock \[s\].
        clock: f64,
    },
    /// A measurement before the first IMU sample.
    #[error("a measurement at t = {time} s came before the first IMU sample")]
    NoImu {
        /// Its time \[s\].
        time: f64,
    },
    /// A PD0 ensemble that cannot be used (its byte offset in the file).
    #[error("PD0 ensemble at byte {offset}: {reason}")]
    Pd0 {
        /// Byte offset of the ensemble's header.
        offset: usize,
        /// Why.
        reason: String,
    },
    /// Inputs that cannot be navigated as a whole (the message says why).
    #[error("{0}")]
    Inputs(String),
    /// The navigator stopped its own run: the solution at `time` broke a health limit
    /// (`[health]` in the vehicle file), so it is not a navigation solution.
    #[error("diverged at t = {time} s: {reason}")]
    Diverged {
        /// Time of the solution that broke the limit \[s\].
        time: f64,
        /// Which check, with the value that broke it.
        reason: health::Divergence,
    },
    /// A numerical failure of the filter (e.g. an innovation covariance that is not
    /// positive definite), with the time of the step that failed.
    #[error("t = {time} s: {source}")]
    Filter {
        /// Time of the step \[s\] (the start of a propagation, or the measurement's).
        time: f64,
        /// What the filter core reported.
        #[source]
        source: estim_core::Error,
    },
    /// The smoother (a recording it cannot smooth exactly, a covariance that is not
    /// positive definite).
    #[error("smoother: {0}")]
    Smoother(#[source] estim_core::Error),
    /// The filter core, outside a step (construction).
    #[error(transparent)]
    Core(#[from] estim_core::Error),
    /// The INS crate.
    #[error(transparent)]
    Ins(#[from] estim_ins::Error),
    /// The DVL crate.
    #[error(transparent)]
    Dvl(#[from] estim_dvl::Error),
    /// A [`NavigationObserver`] failed (e.g. a writer).
    #[error("observer: {0}")]
    Observer(Box<dyn std::error::Error + Send + Sync>),
}

/// `Result` of the navigator.
pub type Result<T> = std::result::Result<T, NavigatorError>;

impl NavigatorError {
    /// [`NavigatorError::InvalidValue`].
    pub(crate) fn invalid(key: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::InvalidValue {
            key: key.into(),
            reason: reason.into(),
        }
    }

    /// [`NavigatorError::Conflict`].
    pub(crate) fn conflict(keys: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::Conflict {
            keys: keys.into(),
            reason: reason.into(),
        }
    }
}
