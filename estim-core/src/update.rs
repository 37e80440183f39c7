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

use nalgebra::{Cholesky, Const, SMatrix, SVector};

use crate::gaussian::{check_finite, symmetrize};
use crate::scalar::{lit, to_f64};
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

/// S factorised once: used for the NIS, the gate and the gain.
pub(crate) struct FactoredInnovation<T: Scalar, const N: usize, const M: usize> {
    pub(crate) covariance: SMatrix<T, M, M>,
    pub(crate) cholesky: Cholesky<T, Const<M>>,
    /// P H' + M.
    pub(crate) pht_m: SMatrix<T, N, M>,
    pub(crate) nis: T,
    /// Whether M is nonzero (skips the cross terms when it is zero).
    pub(crate) correlated: bool,
}

/// Form and factorise S, compute the NIS. Checks finiteness of every input and the
/// conditioning of S.
pub(crate) fn factor_innovation<T: Scalar, const N: usize, const M: usize>(
    prior: &StateAndCovariance<T, N>,
    innovation: &SVector<T, M>,
    jacobian: &SMatrix<T, M, N>,
    measurement_noise: &SMatrix<T, M, M>,
    cross_covariance: &SMatrix<T, N, M>,
) -> Result<FactoredInnovation<T, N, M>> {
    check_finite(innovation.as_slice(), "innovation")?;
    check_finite(jacobian.as_slice(), "measurement jacobian")?;
    check_finite(measurement_noise.as_slice(), "measurement noise covariance")?;
    check_finite(cross_covariance.as_slice(), "cross-covariance")?;
    check_finite(prior.covariance().as_slice(), "prior covariance")?;
    let p = prior.covariance();
    let correlated = cross_covariance.iter().any(|v| !v.is_zero());
    let pht = p * jacobian.transpose();
    let s = if correlated {
        innovation_covariance(p, jacobian, measurement_noise, cross_covariance)
    } else {
        // M = 0: skip the zero products H M (same value as innovation_covariance).
        symmetrize(&(jacobian * pht + measurement_noise))
    };
    let cholesky = s.cholesky().ok_or(Error::InnovationNotPositiveDefinite)?;
    // Reciprocal condition estimate of S from its Cholesky factor: cond(S) >=
    // (max L_ii / min L_ii)^2. Below machine precision the gain is round-off.
    let (mut lmin, mut lmax) = (T::max_value().unwrap_or_else(|| lit(f64::MAX)), T::zero());
    for i in 0..M {
        let d = cholesky.l_dirty()[(i, i)].abs();
        lmin = lmin.min(d);
        lmax = lmax.max(d);
    }
    let rcond = if lmax > T::zero() {
        (lmin / lmax) * (lmin / lmax)
    } else {
        T::zero()
    };
    // rcond is NaN-free here (finite S); `<=` also catches rcond = 0.
    if rcond <= T::default_epsilon() * lit::<T>(M as f64) || !rcond.is_finite() {
        return Err(Error::InnovationIllConditioned {
            reciprocal_condition: to_f64(rcond),
        });
    }
    let nis = innovation.dot(&cholesky.solve(innovation));
    if !nis.is_finite() {
        return Err(Error::NonFinite {
            what: "normalised innovation squared",
        });
    }
    let pht_m = if correlated {
        pht + cross_covariance
    } else {
        pht
    };
    Ok(FactoredInnovation {
        covariance: s,
        cholesky,
        pht_m,
        nis,
        correlated,
    })
}

/// Gain, posterior mean and covariance from a factored S.
pub(crate) fn finish_update<T: Scalar, const N: usize, const M: usize>(
    prior: &StateAndCovariance<T, N>,
    innovation: &SVector<T, M>,
    jacobian: &SMatrix<T, M, N>,
    measurement_noise: &SMatrix<T, M, M>,
    cross_covariance: &SMatrix<T, N, M>,
    form: CovarianceUpdate,
    factored: FactoredInnovation<T, N, M>,
) -> Result<UpdateOutcome<T, N, M>> {
    let p = prior.covariance();
    // K = (P H' + M) S^-1, computed as (S^-1 (H P + M'))' since S is symmetric.
    let gain = factored
        .cholesky
        .solve(&factored.pht_m.transpose())
        .transpose();
    let state = prior.state() + gain * innovation;
    let covariance = match form {
        CovarianceUpdate::JosephLike if factored.correlated => {
            joseph_covariance(p, jacobian, measurement_noise, cross_covariance, &gain)
        }
        CovarianceUpdate::JosephLike => {
            // M = 0: the cross terms vanish (textbook Joseph form).
            let i_kh = SMatrix::<T, N, N>::identity() - gain * jacobian;
            symmetrize(&(i_kh * p * i_kh.transpose() + gain * measurement_noise * gain.transpose()))
        }
        CovarianceUpdate::Short => symmetrize(&(p - gain * factored.pht_m.transpose())),
    };
    check_finite(state.as_slice(), "posterior state")?;
    check_finite(covariance.as_slice(), "posterior covariance")?;
    Ok(UpdateOutcome {
        posterior: StateAndCovariance::new_unchecked(state, covariance),
        innovation: *innovation,
        innovation_covariance: factored.covariance,
        gain,
        nis: factored.nis,
    })
}

/// The correlated-noise Kalman update of `prior` with innovation `innovation` = y - h(x).
///
/// For an error-state filter the prior mean is the error estimate (usually zero).
///
/// # Errors
/// [`Error::NonFinite`] for NaN/inf inputs (or a non-finite result),
/// [`Error::InnovationNotPositiveDefinite`] when S cannot be factorised,
/// [`Error::InnovationIllConditioned`] when S is numerically singular (reciprocal
/// condition estimate below M times machine epsilon).
pub fn correlated_update<T: Scalar, const N: usize, const M: usize>(
    prior: &StateAndCovariance<T, N>,
    innovation: &SVector<T, M>,
    jacobian: &SMatrix<T, M, N>,
    measurement_noise: &SMatrix<T, M, M>,
    cross_covariance: &SMatrix<T, N, M>,
    form: CovarianceUpdate,
) -> Result<UpdateOutcome<T, N, M>> {
    let factored = factor_innovation(
        prior,
        innovation,
        jacobian,
        measurement_noise,
        cross_covariance,
    )?;
    finish_update(
        prior,
        innovation,
        jacobian,
        measurement_noise,
        cross_covariance,
        form,
        factored,
    )
}
