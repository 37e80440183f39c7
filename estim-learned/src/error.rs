//! The crate's error type.

use std::path::PathBuf;

/// Everything that can go wrong in `estim-learned`.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A model or metadata file does not exist.
    #[error("{path}: file not found ({what})")]
    MissingFile {
        /// The missing file.
        path: PathBuf,
        /// What the file was supposed to be.
        what: &'static str,
    },
    /// A file exists but could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The ONNX file could not be parsed, typed or optimised.
    #[error("{path}: malformed ONNX model: {reason}")]
    MalformedModel {
        /// The model file.
        path: PathBuf,
        /// What tract reported.
        reason: String,
    },
    /// The metadata file is not valid JSON of the expected shape, or is inconsistent.
    #[error("{path}: malformed model metadata: {reason}")]
    MalformedMetadata {
        /// The metadata file.
        path: PathBuf,
        /// What was wrong.
        reason: String,
    },
    /// The metadata and the ONNX graph disagree about the inputs or the output.
    #[error("{path}: model and metadata disagree: expected (model) {expected}, metadata declares {given}")]
    ModelMetadataMismatch {
        /// The model file.
        path: PathBuf,
        /// What the ONNX graph declares.
        expected: String,
        /// What the metadata declares.
        given: String,
    },
    /// Inputs handed to a model do not match what it declares (names, count, shapes,
    /// dtypes or values).
    #[error("input mismatch: expected {expected}; given {given}")]
    InputMismatch {
        /// What the model declares.
        expected: String,
        /// What was given.
        given: String,
    },
    /// Running the model failed.
    #[error("inference failed: {0}")]
    Inference(String),
    /// Metrics cannot be computed (empty or mismatched series, zero variance).
    #[error("metrics: {0}")]
    Metrics(String),
    /// A simulation or dataset-assembly input is invalid.
    #[error("invalid {what}: {reason}")]
    InvalidInput {
        /// Which input.
        what: &'static str,
        /// Why.
        reason: String,
    },
    /// An error from estim-core (covariance checks, cross-covariance validity).
    #[error(transparent)]
    Core(#[from] estim_core::Error),
}

/// `Result` with this crate's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;

impl From<Error> for estim_core::Error {
    fn from(e: Error) -> Self {
        match e {
            Error::Core(c) => c,
            other => estim_core::Error::Model(other.to_string()),
        }
    }
}
