//! Loaders for the public A-KIT AUV data (ground truth and DVL CSV files) and the
//! rules for finding the data on disk.
//!
//! Every loader validates the header, the row count, strictly increasing time and
//! finite values; every error names the file and, where there is one, the line.

mod akit;
mod beams;
mod locate;
mod overlaps;

pub use akit::{
    load_dvl, load_gt, parse_dvl, parse_gt, DvlSample, GtSample, DVL_HEADER, GT_HEADER,
};
pub use beams::{load_beams, parse_beams, BeamRow};
pub use locate::{akit_dir, data_root, trajectory_files, TrajectoryFiles, DATA_DIR_ENV};
pub use overlaps::{akit_overlaps, akit_row_keys, touches_held_out, WINDOW_MARGIN_ROWS};

use std::path::PathBuf;

/// Errors of the dataset loaders. Each names the file; parse errors name the line.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DatasetError {
    /// The file could not be opened or read.
    #[error("{}: cannot read: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
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
    #[error("{}:{line}: time {time} does not increase (previous {previous})", path.display())]
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
    /// The data folder or a trajectory's files are missing.
    #[error("{}: {what}", path.display())]
    Missing {
        /// The path looked for.
        path: PathBuf,
        /// What was missing.
        what: String,
    },
}

/// `Result` of the dataset loaders.
pub type Result<T> = std::result::Result<T, DatasetError>;
