//! The error of the experiments' pipeline: every failure names the file and line, the
//! configuration key, the flag or the run it came from.

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
    /// A survey's files as `estim navigate` reads them (its loader's message names the
    /// file, and the line or key).
    #[error("{0:#}")]
    Survey(anyhow::Error),
    /// A configuration key or its value (`imu.preset`, `faults.imu_gap_samples`).
    #[error("{key}: {reason}")]
    Setting {
        /// The key, dotted from the table (`faults.imu_gaps[0]`).
        key: String,
        /// What was wrong with it.
        reason: String,
    },
    /// A configuration key's value outside its bounds.
    #[error("{key} = {value} is outside {range}")]
    OutOfRange {
        /// The key, dotted from the table (`faults.imu_gap_samples`).
        key: String,
        /// The value given.
        value: String,
        /// The bounds, with their unit.
        range: String,
    },
    /// A command-line flag's value, or the list it gives (an entry given twice, an
    /// empty list).
    #[error("{flag}: {reason}")]
    Argument {
        /// The flag (`--fit-trajectories`), or the command when the list is its own.
        flag: String,
        /// What was wrong with its value.
        reason: String,
    },
    /// An A-KIT test trajectory (4 or 13) asked for where something is fitted.
    #[error(
        "{flag}: A-KIT trajectory {trajectory} is a held-out test trajectory \
         (4 and 13 are never used for fitting)"
    )]
    HeldOut {
        /// The flag or command that asked for it.
        flag: String,
        /// The trajectory.
        trajectory: u32,
    },
    /// A data file's content: a log, a results folder, an array to be written.
    #[error("{}{}: {reason}", path.display(), line.map(|l| format!(":{l}")).unwrap_or_default())]
    Data {
        /// The file or folder.
        path: PathBuf,
        /// The line (1-based), where known.
        line: Option<u64>,
        /// What was wrong.
        reason: String,
    },
    /// An IMU sample of a scenario that cannot be used (a non-finite, repeated or
    /// backward time stamp).
    #[error("{scenario}: IMU sample {index}: {reason}")]
    ImuSample {
        /// The scenario's name ("A-KIT trajectory 4").
        scenario: String,
        /// Index of the sample (0-based).
        index: usize,
        /// What was wrong.
        reason: String,
    },
    /// A DVL epoch of a scenario that cannot be used (beyond the truth or the IMU,
    /// out of time order, a non-finite residual).
    #[error("{scenario}: DVL epoch {epoch}: {reason}")]
    DvlEpoch {
        /// The scenario's name ("A-KIT trajectory 4").
        scenario: String,
        /// Index of the epoch (0-based).
        epoch: usize,
        /// What was wrong.
        reason: String,
    },
    /// A scripted event (a beam loss, a DVL outage) with non-finite or negative times
    /// or beams that do not exist.
    #[error("invalid {event}")]
    Event {
        /// The event as scripted.
        event: String,
    },
    /// A run that synthesizes its IMU from the reference, given a scenario with a
    /// recorded IMU (those run through the navigator: `run_recorded`).
    #[error(
        "{scenario}: this run takes an IMU synthesized from the reference; on a \
         recorded IMU the variants run through the navigator (run_recorded)"
    )]
    RecordedImu {
        /// The scenario's name.
        scenario: String,
    },
    /// The navigator refused a DVL epoch for another reason than a numerical failure
    /// (those are `FilterStopped`).
    #[error("DVL epoch {epoch}: {error}")]
    NavigatorAt {
        /// Index of the DVL epoch (0-based).
        epoch: usize,
        /// What the navigator reported (in this error's message, not as its source:
        /// a chain would print it twice).
        error: estim::navigator::NavigatorError,
    },
    /// Nothing to work on: an empty scenario, no training trajectory left.
    #[error("no {what}")]
    NoData {
        /// What is missing ("IMU samples in simulated mission").
        what: String,
    },
    /// A result built here lacks an entry that a table needs (a filter variant, an
    /// improvement group): an inconsistency of the pipeline, not the input's.
    #[error("{within}: no {what}")]
    Missing {
        /// The result searched (a data set's label, "Monte Carlo").
        within: String,
        /// The entry missing from it.
        what: String,
    },
    /// Per-seed results whose rows do not line up into one table.
    #[error("{table}: {reason}")]
    Table {
        /// The table (or data set) being assembled.
        table: String,
        /// How the rows disagree.
        reason: String,
    },
    /// A region of a generated document: its begin and end marker lines.
    #[error("region {region:?}: {reason}")]
    Region {
        /// The region's name (`velocity`, `fuzz`).
        region: String,
        /// What was wrong with its markers.
        reason: String,
    },
    /// A simulated trajectory the INS simulator refuses.
    #[error("invalid trajectory: {0}")]
    Trajectory(estim_ins::Error),
    /// The DVL calibration of an A-KIT trajectory.
    #[error("calibration of A-KIT trajectory {trajectory}: {error}")]
    Calibration {
        /// The trajectory.
        trajectory: u32,
        /// What the calibration reported (in the message, not as the source).
        error: estim_dvl::Error,
    },
    /// A network's sensitivity gave no cross-covariance M.
    #[error("{network} gave no M")]
    NoCrossCovariance {
        /// The network ("network sensitivity", "stand-in network").
        network: &'static str,
    },
    /// One run of a larger set failed; names the run (data set, seed, noise).
    #[error("{run}: {error}")]
    Run {
        /// The run.
        run: String,
        /// Why it failed (in the message, not as the source).
        error: Box<PipelineError>,
    },
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
    /// A file or folder could not be read or written.
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
