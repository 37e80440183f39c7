//! The five runners (linear KF, EKF, error-state EKF, square-root KF, unscented KF).
//! The first three call the one [`crate::update::correlated_update`]; the square-root filter
//! runs its array form ([`crate::square_root`]) and the unscented filter its
//! sigma-point form ([`crate::sigma_point`]). What they share lives in one place,
//! `Shared` (module `shared`): process-noise accumulation (one-step cross-covariances),
//! the window of recorded steps and updates (exact windowed cross-covariances, see
//! [`crate::window`]), the configuration, the innovation gate and its recovery, the
//! joint-covariance policy and the observer. Their `update` / `update_windowed` /
//! `step` wrappers and accessors are generated once (module `wrappers`); each
//! runner file holds only what is its own: how it predicts, and how it evaluates
//! the measurement model and commits an update.
//!
//! Commit rule, the same for every runner: a predict or an update either fails with
//! an error before touching anything, or commits its result (state, covariance,
//! accumulators, recorded history) and *then* notifies the observer. If the observer
//! returns an error, that error is returned and the committed result stays.

#[cfg(doc)]
use crate::{CrossCovariance, GateRecovery, JointCheck};
use nalgebra::{SMatrix, SVector};

use crate::observer::UpdateStatus;
use crate::Scalar;

#[macro_use]
mod wrappers;
mod batch;
mod error_state;
mod extended;
mod linear;
mod shared;
mod square_root;
#[cfg(test)]
mod tests;
mod unscented;

pub use batch::{FilteredBatch, SmoothedBatch};
pub use error_state::ErrorStateKalmanFilter;
pub use extended::ExtendedKalmanFilter;
pub use linear::KalmanFilter;
pub use square_root::SquareRootKalmanFilter;
pub use unscented::UnscentedKalmanFilter;

/// Everything one update attempt produced, accepted or rejected. The accepted
/// reports' `log_likelihood` terms sum to the runner's `log_likelihood()`.
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[derive(Debug, Clone, PartialEq)]
pub struct UpdateReport<T: Scalar, const N: usize, const M: usize> {
    /// Accepted, or rejected by the innovation gate (state untouched).
    pub status: UpdateStatus,
    /// Innovation y - h(x) - E\[v\] (E\[v\] = [`UpdateReport::noise_mean`], zero unless
    /// other updates inside a windowed measurement's window observed part of v).
    pub innovation: SVector<T, M>,
    /// Innovation covariance S = H P H' + H M + M' H' + R (for a windowed update with
    /// Var(v | ...) in place of R; for the unscented filter P_yy).
    pub innovation_covariance: SMatrix<T, M, M>,
    /// Normalised innovation squared, innovation' S^-1 innovation.
    pub nis: T,
    /// Gaussian log density of the innovation, ln N(innovation; 0, S) =
    /// -(m ln(2 pi) + ln det S + nis) / 2 for a measurement of size m: this
    /// measurement's term of the log-likelihood (prediction-error decomposition).
    ///
    /// It is for the innovation and S the gate saw, the same as `innovation`,
    /// `innovation_covariance` and `nis` here: the correlated S of a one-step update,
    /// Var(v | ...) and E\[v | ...\] for a windowed one, P_yy for the unscented filter,
    /// always before any gate-recovery inflation ([`GateRecovery::Inflate`]). It is
    /// present for a rejected update too (where it says how unlikely the measurement
    /// was); the runners' cumulative `log_likelihood()` adds only accepted ones.
    /// ln det S comes from the factorization the update already does (the Cholesky
    /// pivots or closed form of S^-1; for the square-root filter its innovation
    /// factor).
    pub log_likelihood: T,
    /// The gate's NIS threshold for this measurement size, if a gate is configured.
    pub gate_threshold: Option<T>,
    /// The cross-covariance M_k used (from the [`CrossCovariance`], or the exact
    /// windowed one).
    pub cross_covariance: SMatrix<T, N, M>,
    /// The measurement-noise covariance used: R, or for a windowed update
    /// Var(v | other updates in the window) <= R.
    pub noise_covariance: SMatrix<T, M, M>,
    /// The measurement-noise mean used: zero, or for a windowed update
    /// E[v | other updates in the window].
    pub noise_mean: SVector<T, M>,
    /// Validity margin of the joint covariance, dimensionless, valid iff >= 0 (see
    /// [`crate::JointCovariance::validity_margin`]: for a valid joint covariance the smallest
    /// pivot of a static LDL' of its correlation matrix, clamped to [0, 1]; for an
    /// invalid one the smallest eigenvalue of that matrix): [[Q_acc, M], [M', R]] for a
    /// one-step update, [[P, M], [M', Var(v)]] (the covariance of the error state
    /// augmented with v) for a windowed one. `None` with [`JointCheck::Skip`], or when
    /// a one-step update has M != 0 but Q_acc is not tracked.
    pub joint_min_eigenvalue: Option<T>,
    /// The factor lambda >= 1 the prior covariance was inflated by before this update,
    /// which the gate would otherwise have rejected ([`GateRecovery::Inflate`] after a
    /// run of rejections); `None` for an ordinary update or a rejection. `nis` and
    /// `innovation_covariance` are those the gate saw, before the inflation.
    pub covariance_inflation: Option<T>,
    /// The gain K (`None` if rejected).
    pub gain: Option<SMatrix<T, N, M>>,
    /// The state correction K * innovation (`None` if rejected); for the error-state
    /// filter this is the error injected into the nominal state.
    pub correction: Option<SVector<T, N>>,
}

impl<T: Scalar, const N: usize, const M: usize> UpdateReport<T, N, M> {
    /// An accepted report of zeros, for an update attempt to fill in place.
    fn blank() -> Self {
        Self {
            status: UpdateStatus::Accepted,
            innovation: SVector::zeros(),
            innovation_covariance: SMatrix::zeros(),
            nis: T::zero(),
            log_likelihood: T::zero(),
            gate_threshold: None,
            cross_covariance: SMatrix::zeros(),
            noise_covariance: SMatrix::zeros(),
            noise_mean: SVector::zeros(),
            joint_min_eigenvalue: None,
            covariance_inflation: None,
            gain: None,
            correction: None,
        }
    }

    /// Whether the posterior replaced the prior.
    pub fn is_accepted(&self) -> bool {
        self.status == UpdateStatus::Accepted
    }
}
