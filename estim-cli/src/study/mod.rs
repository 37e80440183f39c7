//! The paper study behind `estim reproduce`, `estim montecarlo` and `estim report`:
//! scenarios (simulated or A-KIT), filter variants, their summaries and the result
//! tables of docs/results.md. Private to the binary (docs/design.md): not library API.

pub mod cli;
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

pub use crate::experiment::{
    initial_covariance, initial_nominal, Config, DvlEpoch, DvlOutage, FaultConfig, PaperMBasis,
    PipelineError, Result, MAX_SEED,
};
pub use evaluate::{
    check_fit_trajectories, evaluate, fit_training, markdown as evaluation_markdown, Evaluation,
};
pub use faults::apply_faults;
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
pub use overlaps::{akit_overlaps, touches_held_out, RowOverlaps, WINDOW_MARGIN_ROWS};
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
    error_state, filter_imu_spec, run_filter, run_filter_per_epoch_noise, run_filter_with_observer,
    CrossMatrix, CrossSource, FilterRun, MeasurementSet,
};
pub use scenario::{BeamLoss, Scenario};
pub use smooth::{smooth_scenario, SmoothReport};
pub use training_data::{
    dataset_row, evaluate_beamsnet, synthesize, synthesize_aligned, write_npy, BeamsNetEvaluation,
    BeamsNetSample, WindowAlignment, DATASET_COLUMNS, IMU_RATE_HZ,
};
pub use tune::tune_akit;
pub use where_m::{GRADES, MISSION_DURATION_S};

// Names only the study's tests use (the tests, and dataset.rs's, import them from here).
#[cfg(test)]
pub use crate::experiment::ImuGap;
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
