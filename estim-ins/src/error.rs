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
    /// IMU sample times that do not increase, or leave a gap.
    #[error("IMU sample {index}: {reason}")]
    ImuTime {
        /// The sample (0-based).
        index: usize,
        /// What is wrong.
        reason: String,
    },
    /// IMU calibration: too few reference intervals lie inside the IMU log for every
    /// clock in the searched range.
    #[error(
        "IMU calibration: {intervals} reference intervals lie inside the IMU log for every \
         searched clock, at least {min} needed"
    )]
    CalibrationTooShort {
        /// Intervals usable.
        intervals: usize,
        /// Intervals needed.
        min: usize,
    },
    /// IMU calibration: the reference neither turns nor accelerates.
    #[error("IMU calibration: the reference shows no motion to fit the axes against")]
    CalibrationNoMotion,
    /// IMU calibration: no axis convention keeps the biases within their bounds.
    #[error(
        "IMU calibration: no axis convention keeps the biases within \
         {max_accelerometer_bias} m/s^2 and {max_gyroscope_bias} rad/s"
    )]
    CalibrationNoAxes {
        /// Bound on |accelerometer bias| per axis \[m/s^2\].
        max_accelerometer_bias: f64,
        /// Bound on |gyroscope bias| per axis \[rad/s\].
        max_gyroscope_bias: f64,
    },
    /// IMU calibration: the best two axis conventions fit about equally well.
    #[error(
        "IMU calibration: axes {best} and {runner_up} fit about equally well (cost ratio \
         {cost_ratio:.3} < {min_cost_ratio}): the motion does not separate the axes"
    )]
    CalibrationAmbiguousAxes {
        /// The best convention.
        best: crate::AxisMap,
        /// The next best.
        runner_up: crate::AxisMap,
        /// Runner-up cost / best cost.
        cost_ratio: f64,
        /// The smallest ratio accepted.
        min_cost_ratio: f64,
    },
    /// IMU calibration: the normal equations are singular.
    #[error("IMU calibration: {reason}")]
    CalibrationDegenerate {
        /// What is singular.
        reason: &'static str,
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
