//! The crate's error type.

/// Everything that can go wrong in `estim-core`.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
#[non_exhaustive]
pub enum Error {
    /// An input (state, covariance, measurement, ...) holds NaN or infinity.
    #[error("non-finite value in {what}")]
    NonFinite {
        /// Which quantity held the non-finite value.
        what: &'static str,
    },
    /// A number computed from finite inputs is not finite: it overflows the scalar type
    /// (or meets 0 / 0 or infinity - infinity on the way), e.g. Q_d of a step dt = 1e300,
    /// or a NEES of an error 1e200 under a covariance 1e-200. Every public function
    /// that returns a number returns a finite one or an error.
    #[error("{what} is not representable in the scalar type (overflow)")]
    Overflow {
        /// Which result.
        what: &'static str,
    },
    /// The innovation covariance S = H P H' + H M + M' H' + R could not be inverted
    /// (Cholesky failed): it is not positive definite.
    #[error("innovation covariance is not positive definite")]
    InnovationNotPositiveDefinite,
    /// The innovation covariance S factorises but is numerically singular: the
    /// reciprocal 1-norm condition number of its correlation matrix
    /// diag(S)^-1/2 S diag(S)^-1/2 is below 1000 machine epsilons, so the gain would
    /// be mostly round-off.
    #[error("innovation covariance is numerically singular (reciprocal condition estimate {reciprocal_condition:e})")]
    InnovationIllConditioned {
        /// 1 / (||C||_1 ||C^-1||_1), C the correlation matrix of S (1 for a diagonal S).
        reciprocal_condition: f64,
    },
    /// An observer failed (e.g. could not write its output).
    #[error("observer failed: {0}")]
    Observer(String),
    /// The joint covariance [[Q_acc, M], [M', R]] is not positive semidefinite:
    /// the cross-covariance M is not a possible covariance of (G w, v).
    #[error("joint covariance [[Q_acc, M], [M', R]] is not positive semidefinite (smallest eigenvalue of its correlation matrix {min_eigenvalue:e})")]
    InvalidJointCovariance {
        /// Smallest eigenvalue of the joint correlation matrix
        /// diag(J)^-1/2 J diag(J)^-1/2 (below -[`crate::JointCovariance::tolerance`], 9.3e-10 in f64);
        /// -1 when a zero variance of Q_acc or R has a nonzero entry of M (e.g. M != 0
        /// with no predict since the previous update, Q_acc = 0).
        min_eigenvalue: f64,
    },
    /// A covariance matrix that must be positive (semi)definite is not.
    #[error("{what} is not a valid covariance: {reason}")]
    InvalidCovariance {
        /// Which covariance.
        what: &'static str,
        /// Why it was rejected.
        reason: String,
    },
    /// Sizes that the type system cannot check disagree.
    #[error("dimension mismatch in {what}: expected {expected}, got {got}")]
    Dimension {
        /// Which quantity.
        what: &'static str,
        /// Expected size.
        expected: usize,
        /// Size given.
        got: usize,
    },
    /// A parameter is outside its valid range.
    #[error("invalid parameter {name}: {reason}")]
    InvalidParameter {
        /// The parameter.
        name: &'static str,
        /// Why it was rejected.
        reason: String,
    },
    /// A quantity the runner was configured not to track was needed (e.g. Q_acc with
    /// `track_accumulated_noise(false)`).
    #[error("{what} is not tracked by this filter's configuration ({hint})")]
    NotTracked {
        /// The quantity.
        what: &'static str,
        /// The configuration setting that enables it.
        hint: &'static str,
    },
    /// A windowed cross-covariance needs more recorded process steps than the filter
    /// holds (its capacity, or the steps predicted so far).
    #[error("windowed cross-covariance needs the last {needed} process steps, the filter holds {available} (capacity {capacity}; set FilterConfig window_capacity)")]
    WindowUnavailable {
        /// Window length asked for.
        needed: usize,
        /// Steps recorded and available.
        available: usize,
        /// Configured capacity.
        capacity: usize,
    },
    /// Another update whose measurement noise is itself correlated with the process
    /// noise lies inside a windowed measurement's window: the two measurement noises
    /// may be correlated with each other (coloured noise), which the exact
    /// consider-state bookkeeping does not represent. Refused, never approximated.
    #[error("coloured measurement noise: a correlated update {steps_before_end} steps before the end of this measurement's {window}-step window (stack both measurements into one, or shorten the window to the update interval)")]
    ColouredMeasurementNoise {
        /// Window length of the measurement being updated.
        window: usize,
        /// Where the earlier correlated update lies, in steps before the window's end.
        steps_before_end: usize,
    },
    /// The recorded forward pass is outside what the smoother handles exactly (see
    /// `estim_core::smoother::ForwardRecorder`); nothing was smoothed.
    #[error("the smoother does not cover this recording: {reason} (epoch {epoch})")]
    SmootherUnsupported {
        /// The first epoch (index in the recording) where it happened.
        epoch: usize,
        /// What the forward pass did.
        reason: &'static str,
    },
    /// A [`crate::ProcessModel`] speed hook (`transition_and_noise`,
    /// `propagate_covariance`, `compose_transitions`) does not equal its default
    /// (found by `estim_core::testing::check_speed_hooks`).
    #[error("ProcessModel::{hook} differs from its default by {difference:e} relative (tolerance {tolerance:e})")]
    SpeedHookMismatch {
        /// The hook.
        hook: &'static str,
        /// Largest entrywise difference, relative to the largest entry of the default.
        difference: f64,
        /// The tolerance it exceeded.
        tolerance: f64,
    },
    /// A model (process, measurement or learned) failed to evaluate.
    #[error("model evaluation failed: {0}")]
    Model(String),
}

/// `Result` with this crate's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;
