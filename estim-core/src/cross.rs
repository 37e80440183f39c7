//! Cross-covariance models M_k and the validity check of the joint covariance.

use nalgebra::{DMatrix, SMatrix, SVector};

use crate::gaussian::{all_zero, check_finite};
use crate::linalg::{certify_block, certify_psd};
use crate::scalar::{lit, to_f64};
use crate::{CrossCovariance, CrossCovarianceContext, Error, Result, Scalar};

/// M = 0: process and measurement noise uncorrelated (the standard filter).
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
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
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
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
/// [`ScaledCorrelation::largest_valid_rho`] and [`JointCovariance`].
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
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
    ///
    /// # Errors
    /// [`Error::NonFinite`] if Q or R holds NaN or infinity (checked before the square
    /// roots of [`ScaledCorrelation::unit`], which would clamp a NaN to 0); those of
    /// [`JointCovariance::largest_valid_scale`].
    pub fn largest_valid_rho<const N: usize, const M: usize>(
        accumulated_process_noise: &SMatrix<T, N, N>,
        measurement_noise: &SMatrix<T, M, M>,
    ) -> Result<T> {
        check_finite(
            accumulated_process_noise.as_slice(),
            "accumulated process noise",
        )?;
        check_finite(measurement_noise.as_slice(), "measurement noise")?;
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
pub(crate) fn joint_covariance<T: Scalar, const N: usize, const M: usize>(
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

/// The joint covariance [[Q, M], [M', R]] of a process noise Q (the noise
/// accumulated since the last update, Q_acc, for a runner's one-step update), a
/// cross-covariance M = Cov(G w, v) and a measurement noise R, and the questions
/// about it: is it a covariance at all (positive semidefinite), by how much, and how
/// large a multiple of M would still be one.
///
/// Every check is scale invariant: it works on the correlation matrix
/// C = D^-1/2 J D^-1/2 (D = diag J; zero variances left unscaled), so Q and R may be
/// in any units, and one tolerance ([`JointCovariance::tolerance`]) serves every scale.
///
/// ```
/// use estim_core::nalgebra::{Matrix1, Matrix2, Matrix2x1};
/// use estim_core::{Error, JointCovariance, ScaledCorrelation};
///
/// // The paper's M = rho sqrt(diag Q) sqrt(diag R)' with q = 2 nonzero variances
/// // and m = 1 measurement is valid iff rho^2 q m <= 1: rho <= 0.707.
/// let q = Matrix2::new(0.04, 0.0, 0.0, 0.01);
/// let r = Matrix1::new(0.1);
/// let unit = ScaledCorrelation::<f64>::unit(&q, &r);
/// let scale = JointCovariance::new(q, unit, r).largest_valid_scale()?;
/// assert!((scale - 0.5f64.sqrt()).abs() < 1e-9);
/// assert!(JointCovariance::new(q, unit * 0.42, r).check().is_ok());
/// assert!(matches!(
///     JointCovariance::new(q, unit * 0.9, r).check(),
///     Err(Error::InvalidJointCovariance { .. })
/// ));
/// # Ok::<(), Error>(())
/// ```
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointCovariance<T: Scalar, const N: usize, const M: usize> {
    process_noise: SMatrix<T, N, N>,
    cross_covariance: SMatrix<T, N, M>,
    measurement_noise: SMatrix<T, M, M>,
}

impl<T: Scalar, const N: usize, const M: usize> JointCovariance<T, N, M> {
    /// The joint covariance of Q, M and R (nothing is checked here: every question
    /// below checks what it needs and says what is wrong).
    pub fn new(
        process_noise: SMatrix<T, N, N>,
        cross_covariance: SMatrix<T, N, M>,
        measurement_noise: SMatrix<T, M, M>,
    ) -> Self {
        Self {
            process_noise,
            cross_covariance,
            measurement_noise,
        }
    }

    /// Q (the accumulated process noise block).
    pub fn process_noise(&self) -> &SMatrix<T, N, N> {
        &self.process_noise
    }

    /// M (the cross-covariance block).
    pub fn cross_covariance(&self) -> &SMatrix<T, N, M> {
        &self.cross_covariance
    }

    /// R (the measurement noise block).
    pub fn measurement_noise(&self) -> &SMatrix<T, M, M> {
        &self.measurement_noise
    }

    /// The whole (N+M)-square matrix [[Q, M], [M', R]] (allocates).
    pub fn matrix(&self) -> DMatrix<T> {
        joint_covariance(
            &self.process_noise,
            &self.cross_covariance,
            &self.measurement_noise,
        )
    }

    /// Tolerance on the smallest eigenvalue (and the LDL' pivots) of the correlation
    /// matrix: [`crate::numeric::relative_tolerance`], 9.3e-10 in f64 and 2.2e-5 in
    /// f32. Why the square root of eps: Q_acc and M are products of many steps,
    /// whose rounding (relative ~ steps x eps) moves a zero eigenvalue of a
    /// semidefinite joint covariance (Q_acc is often singular) by far more than a few
    /// eps, while an invalid M (e.g. rho beyond its bound by 1e-6) moves it by orders
    /// of magnitude more.
    pub fn tolerance() -> T {
        joint_tolerance()
    }

    /// Smallest eigenvalue of the (symmetrised) joint covariance, in its units
    /// (allocates: a dynamic eigen decomposition).
    ///
    /// # Errors
    /// [`Error::NonFinite`] if an entry is NaN or infinite; [`Error::Overflow`] if the
    /// eigen decomposition of entries near the scalar's largest value overflows (use
    /// [`JointCovariance::min_correlation_eigenvalue`], scale-free).
    pub fn min_eigenvalue(&self) -> Result<T> {
        joint_min_eigenvalue(
            &self.process_noise,
            &self.cross_covariance,
            &self.measurement_noise,
        )
    }

    /// Smallest eigenvalue of the correlation matrix C (dimensionless; PSD iff >= 0;
    /// allocates).
    ///
    /// # Errors
    /// [`Error::NonFinite`] if an entry is NaN or infinite.
    pub fn min_correlation_eigenvalue(&self) -> Result<T> {
        joint_min_correlation_eigenvalue(
            &self.process_noise,
            &self.cross_covariance,
            &self.measurement_noise,
        )
    }

    /// How valid the joint covariance is, without allocating when it is valid: at
    /// least -[`JointCovariance::tolerance`] iff it is positive semidefinite.
    ///
    /// - Valid (certified by the static LDL' certificate of C): the smallest LDL'
    ///   pivot of C, clamped at 0, so in [0, 1]. An upper bound on the smallest
    ///   eigenvalue of C, 0 exactly when C is singular (to the tolerance); small means
    ///   M is near the edge of what a covariance allows.
    /// - Otherwise: the smallest eigenvalue of C (allocates), or -1 when a zero
    ///   variance of Q or R has a nonzero covariance in M (its correlation is
    ///   unbounded: invalid at any size of M, e.g. M != 0 with Q = 0).
    ///
    /// This is the number every [`crate::UpdateReport::joint_min_eigenvalue`] holds.
    ///
    /// # Errors
    /// [`Error::NonFinite`] if an entry is NaN or infinite.
    pub fn validity_margin(&self) -> Result<T> {
        joint_validity_margin(
            &self.process_noise,
            &self.cross_covariance,
            &self.measurement_noise,
        )
    }

    /// The [`JointCovariance::validity_margin`] if the joint covariance is positive
    /// semidefinite (margin >= -tolerance), else an error.
    ///
    /// # Errors
    /// [`Error::NonFinite`] for non-finite input, [`Error::InvalidJointCovariance`]
    /// otherwise (carrying the smallest eigenvalue of the correlation matrix).
    pub fn check(&self) -> Result<T> {
        check_joint_covariance(
            &self.process_noise,
            &self.cross_covariance,
            &self.measurement_noise,
        )
    }

    /// Read M as a direction U: the largest c >= 0 such that [[Q, c U], [c U', R]] is
    /// PSD, for a PSD Q and a positive definite R.
    ///
    /// PSD iff every column of U lies in range(Q) and
    /// c^2 lambda_max(R^-1/2 U' Q^+ U R^-1/2) <= 1 (Schur complement). 0 if U leaves
    /// range(Q), infinity if U = 0.
    ///
    /// # Errors
    /// [`Error::NonFinite`] for non-finite input; [`Error::InvalidCovariance`] if R
    /// is not positive definite.
    pub fn largest_valid_scale(&self) -> Result<T> {
        largest_valid_scale(
            &self.process_noise,
            &self.cross_covariance,
            &self.measurement_noise,
        )
    }
}

/// Fail with [`Error::NonFinite`] naming the first of Q_acc, M, R that holds NaN or
/// infinity (an eigen decomposition of such a matrix does not converge to anything
/// meaningful).
fn check_joint_finite<T: Scalar, const N: usize, const M: usize>(
    accumulated_process_noise: &SMatrix<T, N, N>,
    cross_covariance: &SMatrix<T, N, M>,
    measurement_noise: &SMatrix<T, M, M>,
) -> Result<()> {
    check_finite(
        accumulated_process_noise.as_slice(),
        "accumulated process noise",
    )?;
    check_finite(cross_covariance.as_slice(), "cross-covariance")?;
    check_finite(measurement_noise.as_slice(), "measurement noise")
}

/// Smallest eigenvalue of the (symmetrised) joint covariance (allocates: a dynamic
/// (N+M)-square eigen decomposition).
///
/// # Errors
/// [`Error::NonFinite`] if an entry is NaN or infinite.
pub(crate) fn joint_min_eigenvalue<T: Scalar, const N: usize, const M: usize>(
    accumulated_process_noise: &SMatrix<T, N, N>,
    cross_covariance: &SMatrix<T, N, M>,
    measurement_noise: &SMatrix<T, M, M>,
) -> Result<T> {
    check_joint_finite(
        accumulated_process_noise,
        cross_covariance,
        measurement_noise,
    )?;
    let j = joint_covariance(
        accumulated_process_noise,
        cross_covariance,
        measurement_noise,
    );
    // Halves first: (a + b) / 2 of two entries near T::MAX would overflow.
    let half = lit::<T>(0.5);
    let j = &j * half + j.transpose() * half;
    let smallest = j.symmetric_eigenvalues().min();
    if smallest.is_finite() {
        Ok(smallest)
    } else {
        Err(Error::Overflow {
            what: "smallest eigenvalue of the joint covariance",
        })
    }
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
/// Allocates (dynamic eigen decomposition); [`joint_validity_margin`] avoids it when the
/// joint covariance is valid.
///
/// # Errors
/// [`Error::NonFinite`] if an entry is NaN or infinite.
pub(crate) fn joint_min_correlation_eigenvalue<T: Scalar, const N: usize, const M: usize>(
    accumulated_process_noise: &SMatrix<T, N, N>,
    cross_covariance: &SMatrix<T, N, M>,
    measurement_noise: &SMatrix<T, M, M>,
) -> Result<T> {
    check_joint_finite(
        accumulated_process_noise,
        cross_covariance,
        measurement_noise,
    )?;
    let j = joint_covariance(
        accumulated_process_noise,
        cross_covariance,
        measurement_noise,
    );
    let scale: Vec<T> = (0..N + M).map(|i| inverse_sqrt_or_one(j[(i, i)])).collect();
    let c = DMatrix::from_fn(N + M, N + M, |r, k| {
        (j[(r, k)] + j[(k, r)]) * lit::<T>(0.5) * scale[r] * scale[k]
    });
    Ok(c.symmetric_eigenvalues().min())
}

/// Tolerance on the smallest eigenvalue (and the LDL' pivots) of the joint correlation
/// matrix: [`crate::numeric::relative_tolerance`], 9.3e-10 in f64 (the former fixed 1e-9) and
/// 2.2e-5 in f32. Why the square root of eps: Q_acc and M are products of many steps,
/// whose rounding (relative ~ steps x eps) moves a zero eigenvalue of a semidefinite
/// joint covariance (Q_acc is often singular) by far more than a few eps, while an
/// invalid M (e.g. rho beyond its bound by 1e-6) moves it by orders of magnitude more.
pub(crate) fn joint_tolerance<T: Scalar>() -> T {
    crate::scalar::relative_tolerance()
}

/// How valid the joint covariance [[Q_acc, M], [M', R]] is, without allocating when it
/// is valid: the number is >= -[`joint_tolerance`] iff the joint covariance is positive
/// semidefinite (to that tolerance, on the correlation matrix C = D^-1/2 J D^-1/2).
///
/// - Valid (certified by a static LDL' of C, the fast path): the smallest LDL' pivot of
///   C, clamped at 0, so in [0, 1]. It is an upper bound on the smallest eigenvalue of C and is 0
///   exactly when C is singular (to the tolerance); small means M is near the edge of
///   what a covariance allows.
/// - Otherwise (a negative or inconclusive pivot): the smallest eigenvalue of C, from
///   [`joint_min_correlation_eigenvalue`] (allocates); -1 when a zero variance of
///   Q_acc or R has a nonzero entry of M in its row (column).
///   ([`zero_variance_correlated`]: invalid whatever the size of M).
///
/// # Errors
/// [`Error::NonFinite`] if an entry is NaN or infinite.
pub(crate) fn joint_validity_margin<T: Scalar, const N: usize, const M: usize>(
    accumulated_process_noise: &SMatrix<T, N, N>,
    cross_covariance: &SMatrix<T, N, M>,
    measurement_noise: &SMatrix<T, M, M>,
) -> Result<T> {
    joint_validity_margin_reusing(
        accumulated_process_noise,
        cross_covariance,
        measurement_noise,
        None,
        None,
    )
    .map(|(margin, _)| margin)
}

/// The unit-diagonal correlation matrix D^-1/2 A D^-1/2 of a symmetric block (its two
/// triangles averaged), upper triangle only (the certificate reads no other entry),
/// and the scaling D^-1/2.
#[inline(always)]
fn correlation_upper<T: Scalar, const K: usize>(
    a: &SMatrix<T, K, K>,
) -> (SMatrix<T, K, K>, SVector<T, K>) {
    let half = lit::<T>(0.5);
    let d = a.diagonal().map(inverse_sqrt_or_one);
    let c = SMatrix::<T, K, K>::from_fn(|i, j| {
        if i <= j {
            (a[(i, j)] + a[(j, i)]) * half * d[i] * d[j]
        } else {
            T::zero()
        }
    });
    (c, d)
}

/// The certificate of one symmetric block of an uncorrelated (M = 0) joint covariance,
/// the LDL' certificate of that block alone: its smallest LDL' pivot
/// (not clamped), or `None` when the block is not certified.
pub(crate) fn block_certificate<T: Scalar, const K: usize>(a: &SMatrix<T, K, K>) -> Option<T> {
    let (mut c, _) = correlation_upper(a);
    let mut smallest = T::one();
    certify_block(&mut c, joint_tolerance::<T>(), &mut smallest).then_some(smallest)
}

/// [`joint_validity_margin`], given the certificate of Q_acc's block when it is already
/// known (`Some(block_certificate(Q_acc))`, e.g. from an earlier update with the same
/// Q_acc), and R's (`Some(block_certificate(R))`, e.g. a linear filter's fixed R).
/// Also returns Q_acc's block certificate when M = 0 (else `None`), for reuse.
///
/// A known certificate vouches for its block's finiteness too (it was computed on a
/// checked block): with M = 0 and both known, nothing is re-checked.
///
/// With M = 0 the joint correlation matrix is block diagonal, and the static LDL' certificate
/// eliminates the two blocks independently (the eliminations through
/// the zero block subtract nothing), so its smallest pivot is the smaller of the two
/// blocks' and it certifies the joint iff it certifies both: the same margin, without
/// forming the joint matrix.
pub(crate) fn joint_validity_margin_reusing<T: Scalar, const N: usize, const M: usize>(
    accumulated_process_noise: &SMatrix<T, N, N>,
    cross_covariance: &SMatrix<T, N, M>,
    measurement_noise: &SMatrix<T, M, M>,
    known_noise_certificate: Option<Option<T>>,
    known_measurement_certificate: Option<Option<T>>,
) -> Result<(T, Option<Option<T>>)> {
    let (q, m, r) = (
        accumulated_process_noise,
        cross_covariance,
        measurement_noise,
    );
    let uncorrelated = all_zero(m.as_slice());
    if !(uncorrelated
        && known_noise_certificate.is_some()
        && known_measurement_certificate.is_some())
    {
        check_joint_finite(q, m, r)?;
    }
    if uncorrelated {
        let noise = known_noise_certificate.unwrap_or_else(|| block_certificate(q));
        let measurement = known_measurement_certificate.unwrap_or_else(|| block_certificate(r));
        let margin = match (noise, measurement) {
            (Some(a), Some(c)) => a.min(c).max(T::zero()),
            _ => joint_min_correlation_eigenvalue(q, m, r)?,
        };
        return Ok((margin, Some(noise)));
    }
    if zero_variance_correlated(q, m, r) {
        return Ok((-T::one(), None));
    }
    let (a, dq) = correlation_upper(q);
    let (c, dr) = correlation_upper(r);
    let b = SMatrix::<T, N, M>::from_fn(|i, j| m[(i, j)] * dq[i] * dr[j]);
    let margin = match certify_psd(a, b, c, joint_tolerance::<T>()) {
        Some(smallest_pivot) => smallest_pivot,
        None => joint_min_correlation_eigenvalue(q, m, r)?,
    };
    Ok((margin, None))
}

/// Whether a variance of Q_acc or R is zero (or negative) while its row of M (column,
/// for R) is not zero: no covariance has that, whatever the size of M (e.g. a
/// correlated update with no predict since the previous one, Q_acc = 0). The
/// correlation matrix leaves zero variances unscaled, so without this rule a small M
/// beside a zero variance would pass within the tolerance.
fn zero_variance_correlated<T: Scalar, const N: usize, const M: usize>(
    q: &SMatrix<T, N, N>,
    m: &SMatrix<T, N, M>,
    r: &SMatrix<T, M, M>,
) -> bool {
    let zero = T::zero();
    (0..N).any(|i| q[(i, i)] <= zero && (0..M).any(|j| m[(i, j)] != zero))
        || (0..M).any(|j| r[(j, j)] <= zero && (0..N).any(|i| m[(i, j)] != zero))
}

/// Check that [[Q_acc, M], [M', R]] is positive semidefinite: [`joint_validity_margin`]
/// must be at least -[`joint_tolerance`] (scale invariant, so Q_acc and R may be in any
/// units). Returns that margin on success (the smallest LDL' pivot of the correlation
/// matrix when the fast static factorisation certifies it, else its smallest eigenvalue).
///
/// # Errors
/// [`Error::NonFinite`] for non-finite input, [`Error::InvalidJointCovariance`]
/// otherwise (carrying the smallest eigenvalue of the correlation matrix).
pub(crate) fn check_joint_covariance<T: Scalar, const N: usize, const M: usize>(
    accumulated_process_noise: &SMatrix<T, N, N>,
    cross_covariance: &SMatrix<T, N, M>,
    measurement_noise: &SMatrix<T, M, M>,
) -> Result<T> {
    let margin = joint_validity_margin(
        accumulated_process_noise,
        cross_covariance,
        measurement_noise,
    )?;
    if margin >= -joint_tolerance::<T>() {
        Ok(margin)
    } else {
        Err(Error::InvalidJointCovariance {
            min_eigenvalue: to_f64(margin),
        })
    }
}

/// The largest c >= 0 such that [[Q, c U], [c U', R]] is PSD, for PSD Q and PD R.
///
/// PSD iff every column of U lies in range(Q) and c^2 lambda_max(R^-1/2 U' Q^+ U R^-1/2) <= 1
/// (Schur complement). Returns 0 if U leaves range(Q), infinity if U = 0.
pub(crate) fn largest_valid_scale<T: Scalar, const N: usize, const M: usize>(
    q: &SMatrix<T, N, N>,
    u: &SMatrix<T, N, M>,
    r: &SMatrix<T, M, M>,
) -> Result<T> {
    check_finite(q.as_slice(), "process noise (largest_valid_scale)")?;
    check_finite(
        u.as_slice(),
        "cross-covariance direction (largest_valid_scale)",
    )?;
    check_finite(r.as_slice(), "measurement noise (largest_valid_scale)")?;
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
    // Null-space threshold: 4096 eps of the largest eigenvalue of the unit-diagonal Q
    // (9.1e-13 in f64, 4.9e-4 in f32), well above the eigen solver's backward error
    // (a small multiple of N eps).
    let tol = T::default_epsilon() * lit::<T>(4096.0) * qmax;
    // Components of U along the eigenvectors of Q.
    let u_dyn = DMatrix::from_column_slice(N, M, u.as_slice());
    let coords = eig.eigenvectors.transpose() * u_dyn;
    let mut w = SMatrix::<T, M, M>::zeros(); // U' Q^+ U
    for (i, lambda) in eig.eigenvalues.iter().enumerate() {
        let row = coords.row(i);
        if *lambda > tol && *lambda > T::zero() {
            let row_t = SMatrix::<T, 1, M>::from_iterator(row.iter().copied());
            w += row_t.transpose() * row_t / *lambda;
        } else if row.amax() > joint_tolerance::<T>() * u.amax() {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::certify_psd_with;
    use nalgebra::{Matrix2, SMatrix};
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// With M = 0 the margin from the two blocks' separate certificates (what the
    /// runners compute, reusing Q_acc's) equals the joint elimination's: the LDL' of the
    /// whole correlation matrix through its zero block (`certify_psd_with(.., true)`),
    /// with the eigenvalue fallback where that does not certify; a given Q certificate
    /// gives the same as a fresh one. Valid, rank-deficient and indefinite Q and R at
    /// (6, 3), seeded (seeds 11, 12, 13 checked: each exercises both outcomes).
    #[test]
    fn uncorrelated_margin_from_the_two_blocks_equals_the_joint_elimination() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let (mut certified, mut refused) = (0, 0);
        for case in 0..300 {
            let g = crate::test_support::rank_deficient_factor::<6>(&mut rng, 1 + case % 6);
            let q_shift = if case % 5 == 0 { -0.05 } else { 0.0 };
            let q = g * g.transpose() + SMatrix::identity() * q_shift;
            let h = SMatrix::<f64, 3, 3>::from_fn(|_, _| rng.random_range(-1.0..1.0));
            let r_shift = if case % 7 == 0 { -0.1 } else { 0.01 };
            let r = h * h.transpose() + SMatrix::identity() * r_shift;
            let m = SMatrix::<f64, 6, 3>::zeros();
            let (a, _) = correlation_upper(&q);
            let (c, _) = correlation_upper(&r);
            let joint = certify_psd_with(a, m, c, joint_tolerance(), true);
            let reference = match joint {
                Some(pivot) => pivot,
                None => joint_min_correlation_eigenvalue(&q, &m, &r).unwrap(),
            };
            let (fresh, certificate) =
                joint_validity_margin_reusing(&q, &m, &r, None, None).unwrap();
            assert_eq!(fresh, reference, "case {case}");
            assert_eq!(certificate, Some(block_certificate(&q)), "case {case}");
            let (reused, _) = joint_validity_margin_reusing(&q, &m, &r, certificate, None).unwrap();
            assert_eq!(reused, reference, "case {case}");
            let known_r = Some(block_certificate(&r));
            let (both, _) =
                joint_validity_margin_reusing(&q, &m, &r, certificate, known_r).unwrap();
            assert_eq!(both, reference, "case {case}");
            match joint {
                Some(_) => certified += 1,
                None => refused += 1,
            }
        }
        assert!(certified > 20 && refused > 20, "{certified} / {refused}");
    }

    /// The M = 0 shortcut of the LDL' certificate (eliminations involving B skipped)
    /// gives exactly what the full elimination gives on B = 0: valid, rank-deficient
    /// and indefinite symmetric blocks, sizes (6, 3), seeded.
    #[test]
    fn certificate_skips_a_zero_cross_block_exactly() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut draw = |n: usize, m: usize| -> SMatrix<f64, 9, 9> {
            // G G' of rank `m` (<= 9) shifted by a diagonal that may make it indefinite.
            let g = SMatrix::<f64, 9, 9>::from_fn(|_, j| {
                if j < m {
                    rng.random_range(-1.0..1.0)
                } else {
                    0.0
                }
            });
            let shift = if n.is_multiple_of(3) { -0.05 } else { 0.0 };
            g * g.transpose() + SMatrix::identity() * shift
        };
        let (mut certified, mut refused) = (0, 0);
        for case in 0..300 {
            let j = draw(case, 1 + case % 9);
            let a = j.fixed_view::<6, 6>(0, 0).into_owned();
            let c = j.fixed_view::<3, 3>(6, 6).into_owned();
            let b = SMatrix::<f64, 6, 3>::zeros();
            let tol = joint_tolerance::<f64>();
            let full = certify_psd_with(a, b, c, tol, true);
            let fast = certify_psd_with(a, b, c, tol, false);
            assert_eq!(full, fast, "case {case}");
            assert_eq!(certify_psd(a, b, c, tol), full, "case {case}");
            match full {
                Some(_) => certified += 1,
                None => refused += 1,
            }
        }
        // Both branches were exercised.
        assert!(certified > 20 && refused > 20, "{certified} / {refused}");
    }

    /// NaN or infinity on the diagonal of a 15x15 Q is a typed error everywhere an eigen
    /// decomposition could be reached (it used to give 0.154 and NaN).
    #[test]
    fn non_finite_joint_input_is_a_typed_error() {
        let r = Matrix2::<f64>::identity() * 0.1;
        let m = SMatrix::<f64, 15, 2>::from_element(1e-3);
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            let mut q = SMatrix::<f64, 15, 15>::identity();
            q[(7, 7)] = bad;
            let non_finite = |e: Error| matches!(e, Error::NonFinite { .. });
            assert!(non_finite(
                ScaledCorrelation::largest_valid_rho(&q, &r).unwrap_err()
            ));
            assert!(non_finite(largest_valid_scale(&q, &m, &r).unwrap_err()));
            assert!(non_finite(
                joint_min_correlation_eigenvalue(&q, &m, &r).unwrap_err()
            ));
            assert!(non_finite(joint_min_eigenvalue(&q, &m, &r).unwrap_err()));
            assert!(non_finite(joint_validity_margin(&q, &m, &r).unwrap_err()));
            assert!(non_finite(check_joint_covariance(&q, &m, &r).unwrap_err()));
            // In M or R too.
            let q = SMatrix::<f64, 15, 15>::identity();
            let mut m_bad = m;
            m_bad[(3, 1)] = bad;
            assert!(non_finite(
                joint_validity_margin(&q, &m_bad, &r).unwrap_err()
            ));
            let mut r_bad = r;
            r_bad[(1, 1)] = bad;
            assert!(non_finite(
                ScaledCorrelation::largest_valid_rho(&q, &r_bad).unwrap_err()
            ));
        }
    }

    /// The static LDL' certificate agrees with the eigen decomposition: on random joint
    /// covariances (singular Q of rank 1..N, M = c U with c on both sides of the largest
    /// valid scale) the fast margin is >= -tol exactly when the smallest eigenvalue of
    /// the correlation matrix is, and a certified margin is never below that
    /// eigenvalue (a pivot bounds it from above).
    #[test]
    fn fast_certificate_agrees_with_the_eigen_decomposition() {
        let mut rng = ChaCha8Rng::seed_from_u64(41);
        let tol = joint_tolerance::<f64>();
        let (mut valid, mut invalid) = (0, 0);
        for case in 0..400 {
            let rank = 1 + case % 6;
            let g = SMatrix::<f64, 6, 6>::from_fn(|_, j| {
                if j < rank {
                    rng.random_range(-1.0..1.0)
                } else {
                    0.0
                }
            });
            let scales = SMatrix::<f64, 6, 1>::from_fn(|i, _| 10f64.powi(i as i32 - 3));
            let g = SMatrix::<f64, 6, 6>::from_fn(|i, j| g[(i, j)] * scales[i]);
            let q = g * g.transpose();
            // U in range(Q) half the time, arbitrary otherwise.
            let coef = SMatrix::<f64, 6, 2>::from_fn(|_, _| rng.random_range(-1.0..1.0));
            let u = if case % 2 == 0 {
                g * coef
            } else {
                SMatrix::<f64, 6, 2>::from_fn(|i, _| rng.random_range(-1.0..1.0) * scales[i])
            };
            let r = Matrix2::new(2.0, 0.3, 0.3, 1.0) * 1e-2;
            let c_max = largest_valid_scale(&q, &u, &r).unwrap();
            let factor = [0.5, 0.999, 1.001, 2.0][case % 4];
            let c = if c_max.is_finite() && c_max > 0.0 {
                c_max * factor
            } else {
                factor
            };
            let m = u * c;
            let eig = joint_min_correlation_eigenvalue(&q, &m, &r).unwrap();
            let margin = joint_validity_margin(&q, &m, &r).unwrap();
            assert_eq!(
                margin >= -tol,
                eig >= -tol,
                "case {case}: margin {margin:e}, eigenvalue {eig:e}"
            );
            if margin >= -tol {
                valid += 1;
                // Up to the tolerance: a pivot accepted as zero may be -tol..0 where the
                // eigenvalue of a singular matrix rounds to 0.
                assert!(margin >= eig - tol, "case {case}: {margin:e} < {eig:e}");
            } else {
                invalid += 1;
            }
        }
        assert!(
            valid > 100 && invalid > 100,
            "{valid} valid, {invalid} invalid"
        );
    }
}
