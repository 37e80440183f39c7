//! The crate's error type.

/// Everything that can go wrong in `estim-ins`.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
#[non_exhaustive]
pub enum Error {
    /// A parameter (IMU spec, mission configuration, time step) is outside its valid range.
    #[error("invalid parameter {name}: {reason}")]
    InvalidParameter {
        /// The parameter.
        name: &'static str,
        /// Why it was rejected.
        reason: String,
    },
    /// An input (state, IMU sample, trajectory sample) holds NaN or infinity.
    #[error("non-finite value in {what}")]
    NonFinite {
        /// Which quantity.
        what: String,
    },
    /// Trajectory samples are too few or their times do not strictly increase.
    #[error("invalid trajectory: {reason}")]
    Trajectory {
        /// What is wrong, naming the sample index.
        reason: String,
    },
}

/// `Result` with this crate's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;

impl From<Error> for estim_core::Error {
    fn from(e: Error) -> Self {
        match e {
            Error::InvalidParameter { name, reason } => {
                estim_core::Error::InvalidParameter { name, reason }
            }
            other => estim_core::Error::Model(other.to_string()),
        }
    }
}

/// `Err(InvalidParameter)` unless `value` is finite and strictly positive.
pub(crate) fn positive(name: &'static str, value: f64) -> Result<f64> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(Error::InvalidParameter {
            name,
            reason: format!("must be finite and > 0, got {value}"),
        })
    }
}
