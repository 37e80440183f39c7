//! The INS/DVL + BeamsNet pipeline behind `estim reproduce` and `estim montecarlo`:
//! scenarios (simulated or A-KIT), filter variants, and their summaries.

mod config;
mod faults;
mod learned;
mod learned_scenarios;
pub mod markdown;
mod mismatch;
mod montecarlo;
mod oracle;
mod report;
mod run;
mod scenario;
mod smooth;
pub mod stats;

pub use config::{
    Config, DvlSection, FilterSection, ImuSection, MissionSection, PaperMBasis, SensorSection,
};
pub use faults::{apply_faults, DvlOutage, FaultConfig, FaultLog, ImuGap};
pub use learned::{beamsnet_inputs, complete_beams};
pub use learned_scenarios::{
    learned_filter_label, learned_measurements, learned_monte_carlo, learned_study,
    max_correlation, outage_extras, two_beams_measurements, two_beams_study, LearnedEvent,
    LearnedMeasurements, LearnedMonteCarlo, LearnedStudy, LearnedVariant, LossWindowSummary,
    MeanInterval, INS_ONLY_DURING_LOSS, INS_ONLY_DURING_OUTAGE, OUTAGE_EMPIRICAL, OUTAGE_NEGLECTED,
    OUTAGE_NETWORK, OUTAGE_SCALED, STUDY_EMPIRICAL_REALIZATIONS, TWO_BEAMS_EMPIRICAL,
    TWO_BEAMS_NEGLECTED, TWO_BEAMS_NETWORK, TWO_BEAMS_SCALED,
};
pub use mismatch::{
    fit_reference_mismatch, MismatchFit, TrajectoryMismatch, AKIT_TEST_TRAJECTORIES,
    CHI_SQUARE_1_MEDIAN,
};
pub use montecarlo::{
    monte_carlo, LearnedSource, MonteCarloReport, VariantConsistency, ORACLE_NEGLECTED,
    ORACLE_SCALED, ORACLE_TRUE_M,
};
pub use oracle::{oracle_measurements, OracleSensor};
pub use report::{
    analyse, filter_label, least_squares_velocities, run_variant, summarise, velocity_metrics,
    FilterFailure, FilterSummary, Improvement, ImprovementValues, LearnedInputs, TrajectoryReport,
    VelocityMetrics, BEAMSNET, BEAMSNET_NEGLECTED, BEAMSNET_SCALED, BEAMSNET_SENSITIVITY, LS,
    PAPER_RHO,
};
pub use run::{
    error_state, filter_imu_spec, initial_covariance, initial_nominal, run_filter,
    run_filter_per_epoch_noise, run_filter_with_observer, CrossMatrix, CrossSource, FilterRun,
    MeasurementSet, FILTER_BIAS_TIME_CONSTANT,
};
pub use scenario::{BeamLoss, DvlEpoch, Scenario};
pub use smooth::{
    least_squares_measurements, smooth_scenario, EstimateSeries, EstimateSummary, SmoothReport,
};

use std::path::PathBuf;

/// Errors of the pipeline; each names what was wrong.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PipelineError {
    /// A dataset file or folder.
    #[error(transparent)]
    Dataset(#[from] crate::datasets::DatasetError),
    /// The configuration file.
    #[error("{}: {message}", path.display())]
    Config {
        /// The file.
        path: PathBuf,
        /// What was wrong (with the line where known).
        message: String,
    },
    /// An invalid setting or input.
    #[error("{0}")]
    Invalid(String),
    /// The filter core.
    #[error(transparent)]
    Core(#[from] estim_core::Error),
    /// A filter run stopped on a numerical failure (e.g. an innovation covariance
    /// that is not positive definite after P lost positive definiteness). This is a
    /// property of the filter variant, not of the input: the pipeline reports it as a
    /// [`FilterFailure`] and keeps the other variants' results.
    #[error("DVL epoch {epoch} (t = {time_s:.2} s): {source}")]
    FilterStopped {
        /// Index of the DVL epoch being processed (0-based).
        epoch: usize,
        /// Time since the start of the scenario \[s\].
        time_s: f64,
        /// What the filter core reported.
        #[source]
        source: estim_core::Error,
    },
    /// The INS crate.
    #[error(transparent)]
    Ins(#[from] estim_ins::Error),
    /// The DVL crate.
    #[error(transparent)]
    Dvl(#[from] estim_dvl::Error),
    /// The learned-measurement crate (model files, inference).
    #[error(transparent)]
    Learned(#[from] estim_learned::Error),
}

/// `Result` of the pipeline.
pub type Result<T> = std::result::Result<T, PipelineError>;
