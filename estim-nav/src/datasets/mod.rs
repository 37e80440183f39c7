//! Loaders for ground-truth and DVL CSV files (the public A-KIT AUV data, or a
//! user's own files), the beam files of `estim dvl solve`, and the rules for finding
//! the data on disk.
//!
//! Columns are found by name in any order, with the units the header states, or
//! through a [`ColumnMap`]. Every loader validates the header, the row count, a
//! complete last line, strictly increasing time and finite, in-range values; every
//! error names the file and, where there is one, the line.

mod akit;
mod beams;
mod columns;
mod dvl_log;
mod fixes;
mod imu;
mod input;
mod locate;
mod span;
mod table;

pub use akit::{
    load_dvl, load_dvl_with, load_gt, load_gt_with, parse_dvl, parse_gt, DvlSample, GtSample,
    DVL_HEADER, GT_HEADER, MAX_ABS_ALTITUDE_M, MAX_ABS_ANGLE_RAD, MAX_ABS_LATITUDE_RAD,
    MAX_ABS_LONGITUDE_RAD, MAX_ABS_SPEED_MPS, MAX_ABS_TIME_S,
};
pub use beams::{load_beams, parse_beams, BeamFile, BeamRow};
pub use columns::ColumnMap;
pub use dvl_log::{DvlLog, RDI_BAD_VELOCITY_MPS};
pub use fixes::{
    load_depth, load_depth_with, load_fixes, load_fixes_with, parse_depth, parse_depth_with,
    parse_fixes, parse_fixes_with,
};
pub use imu::{
    ImuLog, IMPLAUSIBLE_RATE_DURATION_S, MAX_ABS_ANGULAR_RATE_RADPS, MAX_ABS_SPECIFIC_FORCE_MPS2,
    PLAUSIBLE_ANGULAR_RATE_RADPS,
};
pub use input::{read_input, read_limited, read_pd0_input, read_text_file, MAX_INPUT_BYTES};
pub use locate::{
    akit_dir, data_root, trajectories_in, trajectory_files, TrajectoryFiles, DATA_DIR_ENV,
};
pub use span::{check_spans, span_tolerance, SpanCheck, SPAN_TIME_OFFSET_ALLOWANCE_S};
pub use table::{load_times, load_times_with};

use std::path::PathBuf;

/// Errors of the dataset loaders. Each names the file; parse errors name the line.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DatasetError {
    /// The file could not be opened or read.
    #[error("{}: cannot read: {error}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error (in the message, not chained as a source, so that a
        /// report of the whole chain names it once).
        error: std::io::Error,
    },
    /// The input is larger than the limit (an endless stream, or not a log file).
    #[error("{}: larger than {limit} bytes, the most an input file may hold (MAX_INPUT_BYTES); not read further", path.display())]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// The limit \[bytes\].
        limit: u64,
    },
    /// The bytes are not UTF-8 text with LF or CRLF line ends: UTF-16 or UTF-32, CR-only
    /// line ends, binary data.
    #[error("{}{}: {what}", path.display(), line.map_or(String::new(), |l| format!(":{l}")))]
    NotText {
        /// The file.
        path: PathBuf,
        /// 1-based line of the first offending byte, where one is named.
        line: Option<u64>,
        /// What the file is (encoding or kind, with the offset and line where known).
        what: String,
    },
    /// Two rows closer in time than the file's rate makes plausible (a duplicated row,
    /// a stamp in the wrong unit).
    #[error("{}:{line}: time {time} is {interval:.3e} s after line {previous_line}, less than {fraction} of the file's typical interval {reference:.6} s (upper quartile of its intervals): a duplicated or misstamped row? rows that close are refused, never merged", path.display(), fraction = MIN_INTERVAL_FRACTION)]
    ImplausibleInterval {
        /// The file.
        path: PathBuf,
        /// 1-based line of the later row.
        line: u64,
        /// 1-based line of the earlier row.
        previous_line: u64,
        /// Time on this line \[s\].
        time: f64,
        /// Interval to the previous row \[s\].
        interval: f64,
        /// The file's typical interval: the upper quartile of its intervals \[s\].
        reference: f64,
    },
    /// The last line does not end with a newline: the file was cut (a partial write).
    #[error("{}:{line}: truncated: the last line has no newline at its end", path.display())]
    Truncated {
        /// The file.
        path: PathBuf,
        /// 1-based number of the cut line.
        line: u64,
    },
    /// No header column holds a quantity the loader needs.
    #[error("{}:1: no column for {column} (names accepted: {accepted}; header found: `{found}`)", path.display())]
    MissingColumn {
        /// The file.
        path: PathBuf,
        /// The quantity looked for.
        column: String,
        /// The names that would have matched.
        accepted: String,
        /// The header found.
        found: String,
    },
    /// Several header columns could hold one quantity.
    #[error("{}:1: {column}: more than one column matches ({candidates}); name one in the [columns] map", path.display())]
    AmbiguousColumn {
        /// The file.
        path: PathBuf,
        /// The quantity.
        column: String,
        /// The matching header cells.
        candidates: String,
    },
    /// A header states a unit the quantity cannot be read in.
    #[error("{}:1: column `{column}`: unit `{unit}` not accepted (accepted: {accepted})", path.display())]
    Unit {
        /// The file.
        path: PathBuf,
        /// The header cell.
        column: String,
        /// The unit it states.
        unit: String,
        /// The units accepted for that quantity.
        accepted: String,
    },
    /// The column map of the configuration is invalid for this file.
    #[error("{}: column map: {message}", path.display())]
    ColumnMap {
        /// The file the map was applied to.
        path: PathBuf,
        /// What is wrong, naming the key.
        message: String,
    },
    /// A value outside the range the navigator models.
    #[error("{}:{line}: column `{column}`: {value:?} {unit} is outside +-{limit:?} {unit}{}", path.display(), range_hint(unit))]
    OutOfRange {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: u64,
        /// The header cell.
        column: String,
        /// The value, converted to `unit`.
        value: f64,
        /// The largest magnitude accepted.
        limit: f64,
        /// SI unit of `value` and `limit`.
        unit: &'static str,
    },
    /// Ground truth and DVL do not cover the same time span.
    #[error("{} and {} do not cover the same time span: {}; --allow-partial runs on the overlap", gt.display(), dvl.display(), span.describe())]
    SpanMismatch {
        /// The ground-truth file.
        gt: PathBuf,
        /// The DVL file.
        dvl: PathBuf,
        /// Both spans, the overlap and the tolerance (boxed: the error stays small).
        span: Box<SpanCheck>,
    },
    /// A file whose values are valid one by one but cannot be used as a whole.
    #[error("{}: {message}", path.display())]
    Unusable {
        /// The file.
        path: PathBuf,
        /// Why (with the lines involved).
        message: String,
    },
    /// The CSV layer failed (bad quoting, invalid UTF-8, ragged row).
    #[error("{}:{line}: malformed CSV: {message}", path.display())]
    Csv {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: u64,
        /// What the CSV reader said.
        message: String,
    },
    /// The header is not the expected one.
    #[error("{}:1: unexpected header: expected `{expected}`, found `{found}`", path.display())]
    Header {
        /// The file.
        path: PathBuf,
        /// The header the loader expects.
        expected: String,
        /// The header found.
        found: String,
    },
    /// A row has the wrong number of fields.
    #[error("{}:{line}: expected {expected} fields, found {found}", path.display())]
    FieldCount {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: u64,
        /// Expected number of fields.
        expected: usize,
        /// Fields found.
        found: usize,
    },
    /// A cell is not a number.
    #[error("{}:{line}: column `{column}`: `{value}` is not a number", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: u64,
        /// Column name.
        column: String,
        /// The offending text.
        value: String,
    },
    /// A cell is NaN or infinite.
    #[error("{}:{line}: column `{column}`: non-finite value", path.display())]
    NonFinite {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: u64,
        /// Column name.
        column: String,
    },
    /// Time does not strictly increase.
    #[error("{}:{line}: time {time:?} does not increase (previous {previous:?})", path.display())]
    TimeNotIncreasing {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: u64,
        /// Time on this line.
        time: f64,
        /// Time on the previous data line.
        previous: f64,
    },
    /// Too few data rows.
    #[error("{}: {found} data rows, at least {min} needed", path.display())]
    TooFewRows {
        /// The file.
        path: PathBuf,
        /// Rows found.
        found: usize,
        /// Rows needed.
        min: usize,
    },
    /// A column whose header states no unit holds values implausible in the unit
    /// assumed (a gyroscope logged in deg/s read as rad/s).
    #[error("{}:{line}: column `{column}` states no unit and reads {value:.3} {unit}, above the {limit} {unit} a vehicle sustains, for {seconds:.2} s from this line: is it logged in another unit? state it in the header (e.g. `{column} [deg/s]`, or `[rad/s]` to keep it)", path.display())]
    UnitUnreadable {
        /// The file.
        path: PathBuf,
        /// 1-based line where the implausible stretch starts.
        line: u64,
        /// The header cell.
        column: String,
        /// The largest value of that column in the stretch, in `unit`.
        value: f64,
        /// The plausibility limit, in `unit`.
        limit: f64,
        /// The unit assumed.
        unit: &'static str,
        /// How long the values stay above the limit \[s\].
        seconds: f64,
    },
    /// The data folder or a trajectory's files are missing.
    #[error("{}: {what}", path.display())]
    Missing {
        /// The path looked for.
        path: PathBuf,
        /// What was missing.
        what: String,
    },
}

/// Rows of a GT or DVL file closer in time than this fraction of the file's typical
/// interval (the upper quartile of its intervals) are refused ([`DatasetError::ImplausibleInterval`]).
pub const MIN_INTERVAL_FRACTION: f64 = 0.1;

/// A hint for an angle out of range: degrees read as radians.
fn range_hint(unit: &str) -> &'static str {
    if unit == "rad" {
        " (degrees read as radians? state the unit in the header, e.g. `Latitude [deg]`)"
    } else {
        ""
    }
}

/// `Result` of the dataset loaders.
pub type Result<T> = std::result::Result<T, DatasetError>;
