//! The crate's error type.

/// Everything that can go wrong in `estim-dvl`.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
#[non_exhaustive]
pub enum Error {
    /// A parameter is outside its valid range (or not finite).
    #[error("invalid parameter {name}: {reason}")]
    InvalidParameter {
        /// The parameter.
        name: &'static str,
        /// Why it was rejected.
        reason: String,
    },
    /// A required builder setting was not given.
    #[error("missing parameter {name}: {hint}")]
    MissingParameter {
        /// The parameter.
        name: &'static str,
        /// How to give it.
        hint: &'static str,
    },
    /// The beam directions do not allow a velocity solution from every set of 3 beams.
    #[error("degenerate beam geometry: {reason}")]
    DegenerateGeometry {
        /// Which beams and why.
        reason: String,
    },
    /// Input data (a trajectory, a DVL log) is unusable.
    #[error("invalid data in {what}: {reason}")]
    InvalidData {
        /// Which input.
        what: &'static str,
        /// What is wrong, naming the sample index where there is one.
        reason: String,
    },
    /// A numerical step failed (singular normal equations, no convergence).
    #[error("numerical failure in {what}: {reason}")]
    Numerical {
        /// Which computation.
        what: &'static str,
        /// What happened.
        reason: String,
    },
    /// A PD0 input has a span that is not a good ensemble (see
    /// [`read_pd0`](crate::read_pd0)'s report, and [`Pd0Read::require_clean`](crate::Pd0Read::require_clean)).
    #[error("PD0 input at byte {offset} ({length} bytes skipped): {issue}")]
    Pd0 {
        /// Byte offset of the span in the input.
        offset: usize,
        /// Bytes in the span.
        length: usize,
        /// Why it is not a good ensemble.
        issue: crate::Pd0Issue,
    },
    /// A file could not be read.
    #[error("cannot read {}: {message}", path.display())]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// The kind of I/O error.
        kind: std::io::ErrorKind,
        /// The operating system's message.
        message: String,
    },
    /// An error from estim-core.
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

pub(crate) fn finite(name: &'static str, x: f64) -> Result<f64> {
    if x.is_finite() {
        Ok(x)
    } else {
        Err(Error::InvalidParameter {
            name,
            reason: format!("{x} is not finite"),
        })
    }
}
