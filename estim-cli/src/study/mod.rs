//! The paper study behind `estim reproduce`, `estim montecarlo` and `estim report`:
//! scenarios (simulated or A-KIT), filter variants, their summaries and the result
//! tables of docs/results.md. Private to the binary (docs/design.md): not library API.

pub mod cli;
mod config;
mod evaluate;
mod faults;
mod learned;
mod learned_scenarios;
pub mod markdown;
mod mismatch;
mod montecarlo;
mod oracle;
mod overlaps;
mod paired;
mod recorded;
mod report;
mod run;
mod scenario;
mod smooth;
pub mod stats;
mod training_data;
mod tune;
pub mod where_m;

pub use config::{AkitTruth, Config, PaperMBasis, MAX_SEED};
pub use evaluate::{
    check_fit_trajectories, evaluate, fit_training, markdown as evaluation_markdown,
};
pub use faults::{apply_faults, DvlOutage, FaultConfig};
pub use learned::{beamsnet_inputs, committed_beamsnet};
pub use learned_scenarios::{
    learned_monte_carlo, learned_study, max_correlation, LearnedEvent, LearnedMonteCarlo,
    LearnedStudy, MeanInterval, STUDY_EMPIRICAL_REALIZATIONS,
};
pub use mismatch::{fit_reference_mismatch, AKIT_TEST_TRAJECTORIES};
pub use montecarlo::{
    monte_carlo, LearnedSource, MergeError, MonteCarloReport, MonteCarloSums, ORACLE_NEGLECTED,
    ORACLE_SCALED, ORACLE_TRUE_M,
};
pub use oracle::{oracle_measurements, OracleSensor};
pub use overlaps::{akit_overlaps, touches_held_out, WINDOW_MARGIN_ROWS};
pub use paired::{
    beamsnet_without_sensitivity, markdown as paired_markdown, paired_study, Gate, PairedInterval,
};
pub use recorded::{
    run_recorded, ImuChoice, ImuSelection, ImuSource, RecordedSurvey, AKIT_VEHICLE,
    RECORDED_NEES_STATES,
};
pub use report::{
    analyse, filter_label, least_squares_velocities, run_variant, summarise, FilterSummary,
    Improvement, LearnedInputs, TrajectoryReport, BEAMSNET, BEAMSNET_NEGLECTED, BEAMSNET_SCALED,
    BEAMSNET_SENSITIVITY, LS,
};
pub use run::{
    error_state, filter_imu_spec, initial_covariance, initial_nominal, run_filter,
    run_filter_per_epoch_noise, run_filter_with_observer, CrossMatrix, CrossSource, FilterRun,
    MeasurementSet,
};
pub use scenario::{synthesize_imu, BeamLoss, DvlEpoch, Scenario};
pub use smooth::{smooth_scenario, SmoothReport};
pub use training_data::{
    dataset_row, evaluate_beamsnet, synthesize, synthesize_aligned, write_npy, BeamsNetEvaluation,
    BeamsNetSample, WindowAlignment, DATASET_COLUMNS, IMU_RATE_HZ,
};
pub use tune::tune_akit;
pub use where_m::{GRADES, MISSION_DURATION_S};

use std::path::PathBuf;

/// Errors of the pipeline; each names what was wrong.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PipelineError {
    /// A dataset file or folder.
    #[error(transparent)]
    Dataset(#[from] estim::datasets::DatasetError),
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
    /// The navigator (its configuration; numerical failures are `FilterStopped`).
    #[error(transparent)]
    Navigator(#[from] estim::navigator::NavigatorError),
    /// A file could not be written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The learned-measurement crate (model files, inference).
    #[error(transparent)]
    Learned(#[from] estim_learned::Error),
}

/// `Result` of the pipeline.
pub type Result<T> = std::result::Result<T, PipelineError>;

// Names only the study's tests use (the tests, and dataset.rs's, import them from here).
#[cfg(test)]
pub use faults::ImuGap;
#[cfg(test)]
pub use learned_scenarios::two_beams_measurements;
#[cfg(test)]
pub use mismatch::CHI_SQUARE_1_MEDIAN;
#[cfg(test)]
pub use paired::{CellRun, PairedStudy, BEAMSNET_PER_STEP};
#[cfg(test)]
pub use smooth::least_squares_measurements;

#[cfg(test)]
mod tests;
