//! Cross-covariance models M_k and the validity check of the joint covariance.

use nalgebra::{DMatrix, SMatrix};

use crate::scalar::{lit, to_f64};
use crate::{CrossCovariance, CrossCovarianceContext, Error, Result, Scalar};

/// M = 0: process and measurement noise uncorrelated (the standard filter).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Zero;

impl<T: Scalar, S, const N: usize, const M: usize> CrossCovariance<T, S, N, M> for Zero {
    fn cross_covariance(
        &self,
        _context: &CrossCovarianceContext<'_, T, S, N, M>,
    ) -> Result<SMatrix<T, N, M>> {
        Ok(SMatrix::zeros())
    }
}

/// A fixed, known M.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fixed<T: Scalar, const N: usize, const M: usize>(pub SMatrix<T, N, M>);

impl<T: Scalar, S, const N: usize, const M: usize> CrossCovariance<T, S, N, M> for Fixed<T, N, M> {
    fn cross_covariance(
        &self,
        _context: &CrossCovarianceContext<'_, T, S, N, M>,
    ) -> Result<SMatrix<T, N, M>> {
        Ok(self.0)
    }
}

/// The paper's heuristic M = rho * sqrt(diag Q_acc) * sqrt(diag R)' (full outer product).
///
/// Valid (joint covariance PSD) only when rho^2 * q * m <= 1 for diagonal Q_acc and R,
/// q = nonzero diagonal entries of Q_acc, m = measurement size; see
/// [`ScaledCorrelation::largest_valid_rho`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScaledCorrelation<T: Scalar> {
    /// Correlation coefficient, in [-1, 1].
    pub rho: T,
}

impl<T: Scalar> ScaledCorrelation<T> {
    /// The unscaled outer product sqrt(diag Q) sqrt(diag R)'.
    pub fn unit<const N: usize, const M: usize>(
        accumulated_process_noise: &SMatrix<T, N, N>,
        measurement_noise: &SMatrix<T, M, M>,
    ) -> SMatrix<T, N, M> {
        let q = accumulated_process_noise
            .diagonal()
            .map(|d| d.max(T::zero()).sqrt());
        let r = measurement_noise
            .diagonal()
            .map(|d| d.max(T::zero()).sqrt());
        q * r.transpose()
    }

    /// The largest |rho| for which [[Q, M(rho)], [M(rho)', R]] stays PSD.
    pub fn largest_valid_rho<const N: usize, const M: usize>(
        accumulated_process_noise: &SMatrix<T, N, N>,
        measurement_noise: &SMatrix<T, M, M>,
    ) -> Result<T> {
        largest_valid_scale(
            accumulated_process_noise,
            &Self::unit(accumulated_process_noise, measurement_noise),
            measurement_noise,
        )
    }
}

impl<T: Scalar, S, const N: usize, const M: usize> CrossCovariance<T, S, N, M>
    for ScaledCorrelation<T>
{
    fn cross_covariance(
        &self,
        context: &CrossCovarianceContext<'_, T, S, N, M>,
    ) -> Result<SMatrix<T, N, M>> {
        if !self.rho.is_finite() || self.rho.abs() > T::one() {
            return Err(Error::InvalidParameter {
                name: "rho",
                reason: format!("{} is outside [-1, 1]", to_f64(self.rho)),
            });
        }
        if !context.accumulation_tracked {
            return Err(Error::NotTracked {
                what: "accumulated process noise (for ScaledCorrelation)",
                hint: "FilterConfig::builder().track_accumulated_noise(true)",
            });
        }
        Ok(Self::unit(context.accumulated_process_noise, context.measurement_noise) * self.rho)
    }
}

/// The joint covariance [[Q_acc, M], [M', R]] as a dynamic matrix.
pub fn joint_covariance<T: Scalar, const N: usize, const M: usize>(
    accumulated_process_noise: &SMatrix<T, N, N>,
    cross_covariance: &SMatrix<T, N, M>,
    measurement_noise: &SMatrix<T, M, M>,
) -> DMatrix<T> {
    let mut j = DMatrix::zeros(N + M, N + M);
    j.view_mut((0, 0), (N, N))
        .copy_from(accumulated_process_noise);
    j.view_mut((0, N), (N, M)).copy_from(cross_covariance);
    j.view_mut((N, 0), (M, N))
        .copy_from(&cross_covariance.transpose());
    j.view_mut((N, N), (M, M)).copy_from(measurement_noise);
    j
}

/// Smallest eigenvalue of the (symmetrised) joint covariance; NaN if an entry is not
/// finite.
pub fn joint_min_eigenvalue<T: Scalar, const N: usize, const M: usize>(
    accumulated_process_noise: &SMatrix<T, N, N>,
    cross_covariance: &SMatrix<T, N, M>,
    measurement_noise: &SMatrix<T, M, M>,
) -> T {
    let j = joint_covariance(
        accumulated_process_noise,
        cross_covariance,
        measurement_noise,
    );
    if !j.iter().all(|v| v.is_finite()) {
        return lit(f64::NAN);
    }
    let j = (&j + j.transpose()) * lit::<T>(0.5);
    j.symmetric_eigenvalues().min()
}

/// 1/sqrt(d), or 1 where d <= 0 (a zero variance: its row must then be zero).
fn inverse_sqrt_or_one<T: Scalar>(d: T) -> T {
    if d > T::zero() {
        T::one() / d.sqrt()
    } else {
        T::one()
    }
}

/// Smallest eigenvalue of the joint *correlation* matrix D^-1/2 J D^-1/2,
/// J = [[Q_acc, M], [M', R]], D = diag(J) (entries with zero variance left unscaled).
///
/// Unlike [`joint_min_eigenvalue`] it does not depend on the units of the state and
/// measurement components, so one tolerance serves every scale: PSD iff >= 0.
/// NaN if an entry is not finite.
pub fn joint_min_correlation_eigenvalue<T: Scalar, const N: usize, const M: usize>(
    accumulated_process_noise: &SMatrix<T, N, N>,
    cross_covariance: &SMatrix<T, N, M>,
    measurement_noise: &SMatrix<T, M, M>,
) -> T {
    let j = joint_covariance(
        accumulated_process_noise,
        cross_covariance,
        measurement_noise,
    );
    // The eigen solver on NaN would not converge: report NaN instead.
    if !j.iter().all(|v| v.is_finite()) {
        return lit(f64::NAN);
    }
    let scale: Vec<T> = (0..N + M).map(|i| inverse_sqrt_or_one(j[(i, i)])).collect();
    let c = DMatrix::from_fn(N + M, N + M, |r, k| {
        (j[(r, k)] + j[(k, r)]) * lit::<T>(0.5) * scale[r] * scale[k]
    });
    c.symmetric_eigenvalues().min()
}

/// Tolerance on the smallest eigenvalue of the joint correlation matrix.
const JOINT_TOLERANCE: f64 = 1e-9;

/// Check that [[Q_acc, M], [M', R]] is positive semidefinite: the smallest
/// eigenvalue of its correlation matrix ([`joint_min_correlation_eigenvalue`]) must be
/// at least -1e-9 (scale invariant, so Q_acc and R may be in any units). Returns
/// that eigenvalue on success.
///
/// # Errors
/// [`Error::NonFinite`] for non-finite input, [`Error::InvalidJointCovariance`]
/// otherwise.
pub fn check_joint_covariance<T: Scalar, const N: usize, const M: usize>(
    accumulated_process_noise: &SMatrix<T, N, N>,
    cross_covariance: &SMatrix<T, N, M>,
    measurement_noise: &SMatrix<T, M, M>,
) -> Result<T> {
    crate::gaussian::check_finite(cross_covariance.as_slice(), "cross-covariance")?;
    crate::gaussian::check_finite(
        accumulated_process_noise.as_slice(),
        "accumulated process noise",
    )?;
    crate::gaussian::check_finite(measurement_noise.as_slice(), "measurement noise")?;
    let min = joint_min_correlation_eigenvalue(
        accumulated_process_noise,
        cross_covariance,
        measurement_noise,
    );
    if min >= -lit::<T>(JOINT_TOLERANCE) {
        Ok(min)
    } else {
        Err(Error::InvalidJointCovariance {
            min_eigenvalue: to_f64(min),
        })
    }
}

/// The largest c >= 0 such that [[Q, c U], [c U', R]] is PSD, for PSD Q and PD R.
///
/// PSD iff every column of U lies in range(Q) and c^2 lambda_max(R^-1/2 U' Q^+ U R^-1/2) <= 1
/// (Schur complement). Returns 0 if U leaves range(Q), infinity if U = 0.
pub fn largest_valid_scale<T: Scalar, const N: usize, const M: usize>(
    q: &SMatrix<T, N, N>,
    u: &SMatrix<T, N, M>,
    r: &SMatrix<T, M, M>,
) -> Result<T> {
    // c is invariant under diagonal scaling (congruence keeps PSD-ness): work on
    // D_q^-1/2 Q D_q^-1/2, D_q^-1/2 U D_r^-1/2, D_r^-1/2 R D_r^-1/2 so that mixed units
    // (e.g. 1e-16 and 1e-2 variances in one Q) do not fall below the null-space
    // tolerance.
    let dq = q.diagonal().map(inverse_sqrt_or_one);
    let dr = r.diagonal().map(inverse_sqrt_or_one);
    let q = &SMatrix::<T, N, N>::from_fn(|i, j| q[(i, j)] * dq[i] * dq[j]);
    let u = &SMatrix::<T, N, M>::from_fn(|i, j| u[(i, j)] * dq[i] * dr[j]);
    let r = &SMatrix::<T, M, M>::from_fn(|i, j| r[(i, j)] * dr[i] * dr[j]);
    // Static-size symmetric eigen needs extra dimension bounds; go dynamic (cold path).
    let q_dyn = DMatrix::from_column_slice(N, N, crate::gaussian::symmetrize(q).as_slice());
    let eig = q_dyn.symmetric_eigen();
    let qmax = eig.eigenvalues.amax();
    let tol = lit::<T>(1e-12) * qmax;
    // Components of U along the eigenvectors of Q.
    let u_dyn = DMatrix::from_column_slice(N, M, u.as_slice());
    let coords = eig.eigenvectors.transpose() * u_dyn;
    let mut w = SMatrix::<T, M, M>::zeros(); // U' Q^+ U
    for (i, lambda) in eig.eigenvalues.iter().enumerate() {
        let row = coords.row(i);
        if *lambda > tol && *lambda > T::zero() {
            let row_t = SMatrix::<T, 1, M>::from_iterator(row.iter().copied());
            w += row_t.transpose() * row_t / *lambda;
        } else if row.amax() > lit::<T>(1e-9) * u.amax() {
            return Ok(T::zero());
        }
    }
    let chol =
        crate::gaussian::symmetrize(r)
            .cholesky()
            .ok_or_else(|| Error::InvalidCovariance {
                what: "measurement noise",
                reason: "not positive definite".into(),
            })?;
    let l_inv = chol
        .l()
        .try_inverse()
        .ok_or_else(|| Error::InvalidCovariance {
            what: "measurement noise",
            reason: "singular Cholesky factor".into(),
        })?;
    let sym = crate::gaussian::symmetrize(&(l_inv * w * l_inv.transpose()));
    let lmax = DMatrix::from_column_slice(M, M, sym.as_slice())
        .symmetric_eigenvalues()
        .max();
    if lmax <= T::zero() {
        Ok(T::max_value().unwrap_or_else(|| lit(f64::MAX)))
    } else {
        Ok(T::one() / lmax.sqrt())
    }
}
