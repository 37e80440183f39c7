//! The one correlated-noise measurement update used by every filter.
//!
//! With M = Cov(G w_{k-1}, v_k) (Simon, *Optimal State Estimation*, 2006, sec. 7.1):
//!
//! - S = H P H' + H M + M' H' + R
//! - K = (P H' + M) S^-1
//! - short form: P+ = P - K (H P + M')
//! - Joseph-like form, valid for any gain:
//!   P+ = (I-KH) P (I-KH)' + K R K' - (I-KH) M K' - K M' (I-KH)'
//!
//! With M = 0 these are the textbook Kalman update.

use nalgebra::{SMatrix, SVector};

use crate::gaussian::{check_finite, symmetrize};
use crate::{Error, Result, Scalar, StateAndCovariance};

/// How the posterior covariance is computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum CovarianceUpdate {
    /// Joseph-like form, valid for any gain and better conditioned (default).
    #[default]
    JosephLike,
    /// Short form P - K (H P + M'), valid only at the optimal gain.
    Short,
}

/// Everything an update produced.
#[derive(Debug, Clone, PartialEq)]
pub struct UpdateOutcome<T: Scalar, const N: usize, const M: usize> {
    /// Posterior mean and covariance.
    pub posterior: StateAndCovariance<T, N>,
    /// Innovation (residual) y - h(x).
    pub innovation: SVector<T, M>,
    /// Innovation covariance S.
    pub innovation_covariance: SMatrix<T, M, M>,
    /// Gain K.
    pub gain: SMatrix<T, N, M>,
    /// Normalised innovation squared, innovation' S^-1 innovation.
    pub nis: T,
}

/// S = H P H' + H M + M' H' + R (Simon 2006, eq. 7.13).
pub fn innovation_covariance<T: Scalar, const N: usize, const M: usize>(
    covariance: &SMatrix<T, N, N>,
    jacobian: &SMatrix<T, M, N>,
    measurement_noise: &SMatrix<T, M, M>,
    cross_covariance: &SMatrix<T, N, M>,
) -> SMatrix<T, M, M> {
    let hm = jacobian * cross_covariance;
    symmetrize(
        &(jacobian * covariance * jacobian.transpose() + hm + hm.transpose() + measurement_noise),
    )
}

/// Posterior covariance for an arbitrary gain (Joseph-like form).
pub fn joseph_covariance<T: Scalar, const N: usize, const M: usize>(
    covariance: &SMatrix<T, N, N>,
    jacobian: &SMatrix<T, M, N>,
    measurement_noise: &SMatrix<T, M, M>,
    cross_covariance: &SMatrix<T, N, M>,
    gain: &SMatrix<T, N, M>,
) -> SMatrix<T, N, N> {
    let i_kh = SMatrix::<T, N, N>::identity() - gain * jacobian;
    let cross = i_kh * cross_covariance * gain.transpose();
    symmetrize(
        &(i_kh * covariance * i_kh.transpose() + gain * measurement_noise * gain.transpose()
            - cross
            - cross.transpose()),
    )
}

/// The correlated-noise Kalman update of `prior` with innovation `innovation` = y - h(x).
///
/// For an error-state filter the prior mean is the error estimate (usually zero).
/// Errors: [`Error::NonFinite`] for NaN/inf inputs, [`Error::InnovationNotPositiveDefinite`]
/// when S cannot be factorised.
pub fn correlated_update<T: Scalar, const N: usize, const M: usize>(
    prior: &StateAndCovariance<T, N>,
    innovation: &SVector<T, M>,
    jacobian: &SMatrix<T, M, N>,
    measurement_noise: &SMatrix<T, M, M>,
    cross_covariance: &SMatrix<T, N, M>,
    form: CovarianceUpdate,
) -> Result<UpdateOutcome<T, N, M>> {
    check_finite(innovation.as_slice(), "innovation")?;
    check_finite(jacobian.as_slice(), "measurement jacobian")?;
    check_finite(measurement_noise.as_slice(), "measurement noise covariance")?;
    check_finite(cross_covariance.as_slice(), "cross-covariance")?;
    let p = prior.covariance();
    let s = innovation_covariance(p, jacobian, measurement_noise, cross_covariance);
    let chol = s.cholesky().ok_or(Error::InnovationNotPositiveDefinite)?;
    // K = (P H' + M) S^-1, computed as (S^-1 (H P + M'))' since S is symmetric.
    let pht_m = p * jacobian.transpose() + cross_covariance;
    let gain = chol.solve(&pht_m.transpose()).transpose();
    let state = prior.state() + gain * innovation;
    let covariance = match form {
        CovarianceUpdate::JosephLike => {
            joseph_covariance(p, jacobian, measurement_noise, cross_covariance, &gain)
        }
        CovarianceUpdate::Short => symmetrize(&(p - gain * pht_m.transpose())),
    };
    let nis = innovation.dot(&chol.solve(innovation));
    check_finite(state.as_slice(), "posterior state")?;
    check_finite(covariance.as_slice(), "posterior covariance")?;
    Ok(UpdateOutcome {
        posterior: StateAndCovariance::new_unchecked(state, covariance),
        innovation: *innovation,
        innovation_covariance: s,
        gain,
        nis,
    })
}
