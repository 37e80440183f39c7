//! Square-root (Cholesky factor) form of the correlated-noise Kalman filter.
//!
//! The covariance is kept as a lower-triangular factor S with P = S S'. Every
//! covariance the filter produces is a Gram product of a computed matrix, so it is
//! positive semidefinite *by construction*, whatever the round-off.
//!
//! **Predict** (Simon, *Optimal State Estimation*, 2006, sec. 6.3.2): the pre-array
//! [Phi S, S_q] (S_q S_q' = Q_d) is lower-triangularised by an orthogonal
//! transformation from the right (Givens rotations: the QR of its transpose),
//! [Phi S, S_q] Theta = [S-, 0], so S- S-' = Phi P Phi' + Q_d.
//!
//! **Correlated update** (Simon 2006, sec. 6.3.4 array form, adapted to
//! M = Cov(e, v) through the joint factor): the prior error e and the measurement
//! noise v have the joint covariance J = [[P, M], [M', R]]. Its lower-triangular
//! factor is
//!
//! ```text
//! L = [[S, 0], [L21, L22]],   L21 = M' S^-T,   L22 L22' = R - L21 L21'
//! ```
//!
//! (block Cholesky; L22 exists iff J is positive semidefinite). With z = [e; v] =
//! L xi, the innovation nu = H e + v and e itself are
//!
//! ```text
//! [nu; e] = [[L22, H S + L21], [0, S]] [xi_v; xi_e]     (pre-array, (M+N) x (M+N))
//! ```
//!
//! Triangularising the pre-array from the right gives
//! [[S_nu, 0], [Kbar, S+]] with S_nu S_nu' = S (innovation covariance),
//! Kbar = (P H' + M) S_nu^-T and S+ S+' = P - Kbar Kbar' = P+: the gain is
//! K = Kbar S_nu^-1 and the NIS is |S_nu^-1 nu|^2. With M = 0 this is the classical
//! array algorithm (Kailath, Sayed & Hassibi, *Linear Estimation*, 2000, sec. 12.3).
//!
//! **An invalid joint covariance is refused, never factored around.** If J (or, in
//! [`SquareRootKalmanFilter`], [[Q_acc, M], [M', R]]) has a Cholesky pivot below
//! round-off (more negative than 16 (N+M) eps times its diagonal entry, or a zero
//! pivot whose column is not zero to round-off), it has no square root and the
//! update returns [`Error::InvalidJointCovariance`] with the smallest eigenvalue of
//! its correlation matrix. Pivots within round-off of zero (a positive
//! *semi*definite J, e.g. M on the validity boundary) are valid and give a zero
//! column.

use nalgebra::{SMatrix, SVector};

use crate::cross::joint_min_correlation_eigenvalue;
use crate::gaussian::check_finite;
use crate::linalg::{
    joint_factor, joint_factor_from, lower_triangularize_pair, mul_static, semidefinite_cholesky,
    Blocks,
};
use crate::scalar::to_f64;
use crate::update::check_innovation_conditioning;
use crate::{Error, Result, Scalar};

/// Lower-triangular factor S of a covariance, S S' = P (semidefinite Cholesky:
/// zero pivots to round-off allowed, so a singular Q = G G' q factors).
///
/// # Errors
/// [`Error::NonFinite`] for NaN/inf, [`Error::InvalidCovariance`] naming `what` if
/// P is not symmetric positive semidefinite to round-off.
pub fn covariance_factor<T: Scalar, const N: usize>(
    covariance: &SMatrix<T, N, N>,
    what: &'static str,
) -> Result<SMatrix<T, N, N>> {
    check_finite(covariance.as_slice(), what)?;
    crate::gaussian::check_symmetric(covariance, what)?;
    let mut l = SMatrix::<T, N, N>::zeros();
    if semidefinite_cholesky(N, 0, |i, k| covariance[(i, k)], &mut l) {
        Ok(l)
    } else {
        Err(Error::InvalidCovariance {
            what,
            reason: "not positive semidefinite (a Cholesky pivot is negative beyond round-off)"
                .into(),
        })
    }
}

/// Predicted factor: lower-triangular S- with S- S-' = Phi S S' Phi' + S_q S_q', by
/// Givens triangularisation of the pre-array [Phi S, S_q] (Simon 2006, sec. 6.3.2).
///
/// `factor` and `noise_factor` may be any square roots (triangular or not).
///
/// # Errors
/// [`Error::NonFinite`] if an input or the result is not finite.
pub fn square_root_predict<T: Scalar, const N: usize>(
    factor: &SMatrix<T, N, N>,
    transition: &SMatrix<T, N, N>,
    noise_factor: &SMatrix<T, N, N>,
) -> Result<SMatrix<T, N, N>> {
    let mut a = mul_static(transition, factor);
    let mut b = *noise_factor;
    if !a.iter().chain(b.iter()).all(|v| v.is_finite()) {
        check_finite(transition.as_slice(), "transition")?;
        check_finite(factor.as_slice(), "covariance factor")?;
        check_finite(noise_factor.as_slice(), "process noise factor")?;
        return Err(Error::NonFinite {
            what: "predicted covariance factor (overflow)",
        });
    }
    lower_triangularize_pair(&mut a, &mut b);
    check_finite(a.as_slice(), "predicted covariance factor")?;
    Ok(a)
}

/// Everything a square-root update produced.
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[derive(Debug, Clone, PartialEq)]
pub struct SquareRootOutcome<T: Scalar, const N: usize, const M: usize> {
    /// Posterior mean.
    pub state: SVector<T, N>,
    /// Lower-triangular factor S+ of the posterior covariance (P+ = S+ S+').
    pub factor: SMatrix<T, N, N>,
    /// Innovation y - h(x).
    pub innovation: SVector<T, M>,
    /// Lower-triangular factor of the innovation covariance S = H P H' + H M + M' H' + R.
    pub innovation_factor: SMatrix<T, M, M>,
    /// Gain K = (P H' + M) S^-1.
    pub gain: SMatrix<T, N, M>,
    /// Normalised innovation squared.
    pub nis: T,
}

/// Cold path of a failed joint factorisation: the error with the smallest eigenvalue
/// of the joint correlation matrix (dynamic eigen decomposition).
fn invalid_joint<T: Scalar, const N: usize, const M: usize>(
    block: &SMatrix<T, N, N>,
    cross_covariance: &SMatrix<T, N, M>,
    measurement_noise: &SMatrix<T, M, M>,
) -> Error {
    match joint_min_correlation_eigenvalue(block, cross_covariance, measurement_noise) {
        Ok(min) => Error::InvalidJointCovariance {
            min_eigenvalue: to_f64(min),
        },
        // Non-finite input: say so rather than report a made-up eigenvalue.
        Err(e) => e,
    }
}

/// Check that [[Q, M], [M', R]] has a square root (positive semidefinite to
/// round-off, see the module docs) without building the filter.
///
/// # Errors
/// [`Error::NonFinite`], or [`Error::InvalidJointCovariance`] with the smallest
/// eigenvalue of its correlation matrix.
pub fn check_joint_factor<T: Scalar, const N: usize, const M: usize>(
    block: &SMatrix<T, N, N>,
    cross_covariance: &SMatrix<T, N, M>,
    measurement_noise: &SMatrix<T, M, M>,
) -> Result<()> {
    check_finite(block.as_slice(), "accumulated process noise")?;
    check_finite(cross_covariance.as_slice(), "cross-covariance")?;
    check_finite(measurement_noise.as_slice(), "measurement noise covariance")?;
    match joint_factor(block, cross_covariance, measurement_noise) {
        Some(_) => Ok(()),
        None => Err(invalid_joint(block, cross_covariance, measurement_noise)),
    }
}

/// The correlated update in square-root form (array algorithm of the module docs).
///
/// `factor` is a lower-triangular S with P = S S' (as [`covariance_factor`] and
/// [`square_root_predict`] return); `cross_covariance` is M = Cov(e, v) of the prior
/// error and the measurement noise. For an error-state filter `state` is the error
/// estimate (usually zero).
///
/// # Errors
/// [`Error::NonFinite`]; [`Error::InvalidParameter`] if `factor` is not lower
/// triangular; [`Error::InvalidJointCovariance`] if [[S S', M], [M', R]] has no
/// square root (never factored around); [`Error::InnovationNotPositiveDefinite`] /
/// [`Error::InnovationIllConditioned`] as for [`crate::update::correlated_update`].
pub fn square_root_update<T: Scalar, const N: usize, const M: usize>(
    state: &SVector<T, N>,
    factor: &SMatrix<T, N, N>,
    innovation: &SVector<T, M>,
    jacobian: &SMatrix<T, M, N>,
    measurement_noise: &SMatrix<T, M, M>,
    cross_covariance: &SMatrix<T, N, M>,
) -> Result<SquareRootOutcome<T, N, M>> {
    check_finite(state.as_slice(), "prior state")?;
    check_finite(factor.as_slice(), "covariance factor")?;
    check_finite(innovation.as_slice(), "innovation")?;
    check_finite(jacobian.as_slice(), "measurement jacobian")?;
    check_finite(measurement_noise.as_slice(), "measurement noise covariance")?;
    check_finite(cross_covariance.as_slice(), "cross-covariance")?;
    if (0..N).any(|j| ((j + 1)..N).any(|i| !factor[(j, i)].is_zero())) {
        return Err(Error::InvalidParameter {
            name: "factor",
            reason: "the covariance factor must be lower triangular".into(),
        });
    }
    let l = joint_factor_from(factor, cross_covariance, measurement_noise).ok_or_else(|| {
        invalid_joint(
            &mul_static(factor, &factor.transpose()),
            cross_covariance,
            measurement_noise,
        )
    })?;
    // Pre-array [[L22, H S + L21], [0, S]] (rows nu, e; columns xi_v, xi_e).
    let mut pre = Blocks::<T, M, N, M, N> {
        a: l.d,
        b: mul_static(jacobian, factor) + l.c,
        c: SMatrix::zeros(),
        d: *factor,
    };
    pre.lower_triangularize();
    let s_nu = pre.a;
    let kbar = pre.c;
    let posterior_factor = pre.d;
    if (0..M).any(|j| s_nu[(j, j)] <= T::zero()) {
        return Err(Error::InnovationNotPositiveDefinite);
    }
    // W = S_nu^-1 (lower triangular) by forward substitution.
    let mut w = SMatrix::<T, M, M>::zeros();
    for j in 0..M {
        w[(j, j)] = T::one() / s_nu[(j, j)];
        for i in (j + 1)..M {
            let mut v = T::zero();
            for k in j..i {
                v -= s_nu[(i, k)] * w[(k, j)];
            }
            w[(i, j)] = v / s_nu[(i, i)];
        }
    }
    let s = mul_static(&s_nu, &s_nu.transpose());
    let inverse = mul_static(&w.transpose(), &w);
    check_innovation_conditioning(&s, &inverse)?;
    let whitened = mul_static(&w, innovation);
    let nis = whitened.dot(&whitened);
    let gain = mul_static(&kbar, &w);
    let posterior = state + mul_static(&kbar, &whitened);
    check_finite(posterior.as_slice(), "posterior state")?;
    check_finite(posterior_factor.as_slice(), "posterior covariance factor")?;
    if !nis.is_finite() {
        return Err(Error::NonFinite {
            what: "normalised innovation squared",
        });
    }
    Ok(SquareRootOutcome {
        state: posterior,
        factor: posterior_factor,
        innovation: *innovation,
        innovation_factor: s_nu,
        gain,
        nis,
    })
}

pub use crate::runner::SquareRootKalmanFilter;
