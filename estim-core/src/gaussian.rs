//! A state estimate and its covariance, travelling together.

use nalgebra::{SMatrix, SVector};

use crate::{Error, Result, Scalar};

/// Mean and covariance of a Gaussian state estimate of size `N`.
///
/// Fields are private so the pair stays consistent: the constructor checks that
/// every value is finite and the covariance is a covariance: symmetric entry by entry
/// and positive semidefinite, both to [`crate::numeric::relative_tolerance`] (relative;
/// see [`check_positive_semidefinite`]).
///
/// With the `serde` feature it serializes as `{ "state": [...], "covariance": [...] }`
/// (nalgebra's column-major arrays); deserialization goes through
/// [`StateAndCovariance::new`], so a non-finite, asymmetric or indefinite covariance is
/// refused.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(
        try_from = "UncheckedStateAndCovariance<T, N>",
        bound(
            serialize = "T: serde::Serialize",
            deserialize = "T: serde::Deserialize<'de>"
        )
    )
)]
pub struct StateAndCovariance<T: Scalar, const N: usize> {
    state: SVector<T, N>,
    covariance: SMatrix<T, N, N>,
}

/// The serialized form of [`StateAndCovariance`], checked by `TryFrom`.
#[cfg(feature = "serde")]
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields, bound(deserialize = "T: serde::Deserialize<'de>"))]
struct UncheckedStateAndCovariance<T: Scalar, const N: usize> {
    state: SVector<T, N>,
    covariance: SMatrix<T, N, N>,
}

#[cfg(feature = "serde")]
impl<T: Scalar, const N: usize> TryFrom<UncheckedStateAndCovariance<T, N>>
    for StateAndCovariance<T, N>
{
    type Error = Error;

    fn try_from(u: UncheckedStateAndCovariance<T, N>) -> Result<Self> {
        Self::new(u.state, u.covariance)
    }
}

impl<T: Scalar, const N: usize> StateAndCovariance<T, N> {
    /// Build an estimate, checking that every value is finite and that the covariance is
    /// symmetric ([`check_symmetric`]) and positive semidefinite
    /// ([`check_positive_semidefinite`]), each to a relative 9.3e-10 in f64 (2.2e-5 in
    /// f32).
    ///
    /// ```
    /// use estim_core::nalgebra::{Matrix2, Vector2};
    /// use estim_core::{Error, StateAndCovariance};
    ///
    /// assert!(StateAndCovariance::new(Vector2::zeros(), Matrix2::new(1.0, 0.5, 0.5, 1.0)).is_ok());
    /// // Symmetric with a positive diagonal, but eigenvalues 3 and -1: not a covariance.
    /// assert!(matches!(
    ///     StateAndCovariance::new(Vector2::zeros(), Matrix2::new(1.0, 2.0, 2.0, 1.0)),
    ///     Err(Error::InvalidCovariance { what: "state covariance", .. })
    /// ));
    /// ```
    ///
    /// # Errors
    /// [`Error::NonFinite`] for NaN or infinity in the state or covariance;
    /// [`Error::InvalidCovariance`] for an asymmetric or indefinite covariance.
    pub fn new(state: SVector<T, N>, covariance: SMatrix<T, N, N>) -> Result<Self> {
        check_finite(state.as_slice(), "state")?;
        check_covariance(&covariance, "state covariance")?;
        Ok(Self { state, covariance })
    }

    /// Build from values a filter step computed: finite and symmetric (as
    /// [`StateAndCovariance::new`]) but not re-checked for semidefiniteness, so a step
    /// keeps returning what it returned before (a sigma-point step with negative weights
    /// may produce an indefinite P, which the next factorisation refuses).
    pub(crate) fn from_step(state: SVector<T, N>, covariance: SMatrix<T, N, N>) -> Result<Self> {
        check_finite(state.as_slice(), "state")?;
        check_finite(covariance.as_slice(), "state covariance")?;
        check_symmetric(&covariance, "state covariance")?;
        Ok(Self { state, covariance })
    }

    /// Build without checks; for runners that produced the values themselves.
    pub(crate) fn new_unchecked(state: SVector<T, N>, covariance: SMatrix<T, N, N>) -> Self {
        Self { state, covariance }
    }

    /// Take `state` and the covariance in `covariance`, leaving the old covariance
    /// there (a swap: the runners commit a posterior without copying it).
    pub(crate) fn commit(&mut self, state: SVector<T, N>, covariance: &mut SMatrix<T, N, N>) {
        self.state = state;
        std::mem::swap(&mut self.covariance, covariance);
    }

    /// The mean.
    pub fn state(&self) -> &SVector<T, N> {
        &self.state
    }

    /// The covariance.
    pub fn covariance(&self) -> &SMatrix<T, N, N> {
        &self.covariance
    }

    /// Split into (mean, covariance).
    pub fn into_parts(self) -> (SVector<T, N>, SMatrix<T, N, N>) {
        (self.state, self.covariance)
    }

    /// Replace the mean, keeping the covariance (checked for finiteness).
    pub fn with_state(self, state: SVector<T, N>) -> Result<Self> {
        check_finite(state.as_slice(), "state")?;
        Ok(Self { state, ..self })
    }
}

/// Whether every value is finite: a branch-free fold (it vectorises; `all` stops at
/// the first failure and does not, which cost more than the check on matrices).
#[inline(always)]
pub(crate) fn all_finite<T: Scalar>(values: &[T]) -> bool {
    values.iter().fold(true, |ok, v| ok & v.is_finite())
}

/// Whether every value is zero (branch-free, as [`all_finite`]).
#[inline(always)]
pub(crate) fn all_zero<T: Scalar>(values: &[T]) -> bool {
    values.iter().fold(true, |ok, v| ok & v.is_zero())
}

/// Whether every value is exactly zero, derivatives included: the test that lets the
/// update skip the terms of M = 0. [`all_zero`] for `f64` and `f32`, whose `is_zero`
/// is exact; other scalars answer `false`, so the general formulas run (with M = 0 they
/// give the same values). A dual number's `is_zero` (num-dual) reads its value only,
/// and an M whose value is 0 but whose derivative is not (d M / d rho at rho = 0) would
/// otherwise lose that derivative.
#[inline(always)]
pub(crate) fn exactly_zero<T: Scalar>(values: &[T]) -> bool {
    use core::any::TypeId;
    let exact =
        TypeId::of::<T>() == TypeId::of::<f64>() || TypeId::of::<T>() == TypeId::of::<f32>();
    exact && all_zero(values)
}

/// Fail with [`Error::NonFinite`] if any value is NaN or infinite.
#[inline(always)]
pub fn check_finite<T: Scalar>(values: &[T], what: &'static str) -> Result<()> {
    if all_finite(values) {
        Ok(())
    } else {
        Err(Error::NonFinite { what })
    }
}

/// Fail with [`Error::InvalidCovariance`] unless `m` is symmetric entry by entry:
/// |m_ij - m_ji| <= tol s_ij with s_ij = max(sqrt|m_ii| sqrt|m_jj|, |m_ij|, |m_ji|)
/// and tol = [`crate::numeric::relative_tolerance`] (9.3e-10 in f64, 2.2e-5 in f32).
///
/// s_ij is the scale of entry (i, j) itself (for a covariance |m_ij| <= sqrt(m_ii
/// m_jj)), so the check does not depend on the units of the other components: a
/// large variance elsewhere does not hide an asymmetric pair.
pub fn check_symmetric<T: Scalar, const N: usize>(
    m: &SMatrix<T, N, N>,
    what: &'static str,
) -> Result<()> {
    check_symmetric_entries(N, |i, j| m[(i, j)], what)
}

/// [`check_symmetric`] for any square matrix of size `n` read through `entry(i, j)`.
pub(crate) fn check_symmetric_entries<T: Scalar>(
    n: usize,
    entry: impl Fn(usize, usize) -> T,
    what: &'static str,
) -> Result<()> {
    let m = |i, j| entry(i, j);
    let tol = crate::scalar::relative_tolerance::<T>();
    for i in 0..n {
        for j in (i + 1)..n {
            let (upper, lower) = (m(i, j), m(j, i));
            let scale = (m(i, i).abs().sqrt() * m(j, j).abs().sqrt())
                .max(upper.abs())
                .max(lower.abs());
            if (upper - lower).abs() > tol * scale {
                return Err(Error::InvalidCovariance {
                    what,
                    reason: format!("not symmetric at ({i}, {j})"),
                });
            }
        }
    }
    Ok(())
}

/// Fail with [`Error::InvalidCovariance`] unless `m` is positive semidefinite to a
/// relative tolerance: the correlation matrix C = D^-1/2 m D^-1/2 (D = |diag m|, zero
/// variances left unscaled, the two triangles averaged) has no eigenvalue below
/// -[`crate::numeric::relative_tolerance`] (9.3e-10 in f64, 2.2e-5 in f32). Scale
/// invariant, so one tolerance serves every unit. A negative variance shows as -1 on
/// C's diagonal and is always refused. Certified first by a static LDL' of C (no
/// allocation); only a matrix that does not certify gets an eigen decomposition
/// (allocates). Does not check finiteness or symmetry ([`check_covariance`] does all
/// three).
///
/// ```
/// use estim_core::nalgebra::Matrix2;
/// use estim_core::numeric::check_positive_semidefinite;
///
/// assert!(check_positive_semidefinite(&Matrix2::new(4.0, 2.0, 2.0, 1.0), "P").is_ok()); // singular
/// assert!(check_positive_semidefinite(&Matrix2::new(1.0, 2.0, 2.0, 1.0), "P").is_err());
/// assert!(check_positive_semidefinite(&Matrix2::new(-1e-30, 0.0, 0.0, 1.0), "P").is_err());
/// ```
pub fn check_positive_semidefinite<T: Scalar, const N: usize>(
    m: &SMatrix<T, N, N>,
    what: &'static str,
) -> Result<()> {
    let half = crate::scalar::lit::<T>(0.5);
    let scale = m.diagonal().map(|d| {
        let d = d.abs();
        if d > T::zero() {
            T::one() / d.sqrt()
        } else {
            T::one()
        }
    });
    let correlation =
        SMatrix::<T, N, N>::from_fn(|i, j| (m[(i, j)] + m[(j, i)]) * half * scale[i] * scale[j]);
    let tol = crate::scalar::relative_tolerance::<T>();
    let mut certified = correlation;
    let mut smallest = T::one();
    if crate::linalg::certify_block(&mut certified, tol, &mut smallest) {
        return Ok(());
    }
    let eigenvalue = nalgebra::DMatrix::from_column_slice(N, N, correlation.as_slice())
        .symmetric_eigenvalues()
        .min();
    if eigenvalue >= -tol {
        Ok(())
    } else {
        Err(Error::InvalidCovariance {
            what,
            reason: format!(
                "not positive semidefinite (smallest eigenvalue of its correlation matrix {:e}, tolerance -{:e})",
                crate::scalar::to_f64(eigenvalue),
                crate::scalar::to_f64(tol)
            ),
        })
    }
}

/// Finite ([`check_finite`]), symmetric ([`check_symmetric`]) and positive
/// semidefinite ([`check_positive_semidefinite`]): what a covariance must be.
///
/// # Errors
/// [`Error::NonFinite`] or [`Error::InvalidCovariance`] naming `what`.
pub fn check_covariance<T: Scalar, const N: usize>(
    m: &SMatrix<T, N, N>,
    what: &'static str,
) -> Result<()> {
    check_finite(m.as_slice(), what)?;
    check_symmetric(m, what)?;
    check_positive_semidefinite(m, what)
}

/// The symmetric part (A + A') / 2, used to remove round-off asymmetry.
#[inline]
pub fn symmetrize<T: Scalar, const N: usize>(m: &SMatrix<T, N, N>) -> SMatrix<T, N, N> {
    (m + m.transpose()) * crate::scalar::lit::<T>(0.5)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix4;

    /// The symmetry check is per entry: an asymmetric pair of unit-scale entries is
    /// refused beside a variance of 1e12 (a check relative to the largest entry let
    /// it pass), and round-off asymmetry at every scale is accepted.
    #[test]
    fn symmetry_is_checked_entry_by_entry() {
        let mut p = Matrix4::<f64>::identity();
        p[(3, 3)] = 1e12;
        p[(0, 1)] = 0.5;
        p[(1, 0)] = -0.5;
        assert!(matches!(
            check_symmetric(&p, "P"),
            Err(Error::InvalidCovariance { what: "P", .. })
        ));
        assert!(StateAndCovariance::new(SVector::zeros(), p).is_err());
        for scale in [1e-200, 1e-8, 1.0, 1e12, 1e200] {
            let mut q = Matrix4::<f64>::identity() * scale;
            q[(0, 1)] = 0.5 * scale;
            q[(1, 0)] = 0.5 * scale * (1.0 + 4.0 * f64::EPSILON);
            q[(3, 3)] = 1e12 * scale;
            q[(2, 3)] = 1e5 * scale;
            q[(3, 2)] = 1e5 * scale * (1.0 - 4.0 * f64::EPSILON);
            assert!(check_symmetric(&q, "Q").is_ok(), "{scale:e}");
        }
    }
}
