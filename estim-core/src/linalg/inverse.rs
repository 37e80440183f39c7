//! The inverse of a small symmetric positive definite matrix (the innovation
//! covariance S of a measurement update).
//!
//! **What it computes.** S^-1, exactly symmetric, for a static M x M matrix S of
//! which only the lower triangle is read.
//!
//! **Method.** One and two rows: the closed forms 1 / s and adj(S) / det(S) (one
//! division instead of a chain of square roots and divisions: the latency of a small
//! update), when det(S) is a positive normal number and its reciprocal is finite.
//! Otherwise, and for three or more rows: the Cholesky factor S = L L' without
//! pivoting (Golub & Van Loan, *Matrix Computations*, 4th ed., alg. 4.2.1), W = L^-1
//! by forward substitution, S^-1 = W' W (upper triangle, mirrored).
//!
//! **Tolerance.** None: a pivot must be strictly positive and finite. Whether S is
//! numerically singular is the caller's separate test (the update's reciprocal
//! condition number of the correlation matrix).
//!
//! **Log-determinant.** [`spd_inverse_log_det`] also returns ln det S from the same
//! factorization (the closed form's determinant, or the Cholesky pivots), for the
//! Gaussian log-likelihood of an innovation.
//!
//! **Failure.** `None` when a pivot is zero, negative or not finite (S is not
//! positive definite in floating point).

use nalgebra::SMatrix;

use crate::scalar::{lit, Scalar};

/// Whether `x` is a finite positive normal number (at least 4 / MAX, the smallest
/// normal of IEEE binary formats; positive and finite for a type without a maximum):
/// where a closed form keeps full precision.
#[inline(always)]
pub(crate) fn positive_normal<T: Scalar>(x: T) -> bool {
    x.is_finite()
        && match T::max_value() {
            Some(max) => x >= lit::<T>(4.0) / max,
            None => x > T::zero(),
        }
}

/// Inverse of a symmetric positive definite matrix through its Cholesky factor
/// S = L L', S^-1 = L^-T L^-1 (Golub & Van Loan, *Matrix Computations*, 4th ed.,
/// alg. 4.2.1); exactly symmetric. `None` if a pivot is not positive.
///
/// Written out for static sizes: for the small S of a measurement update it is
/// several times faster than the generic `nalgebra` Cholesky + inverse.
///
/// One and two measurements take the closed forms 1 / s and adj(S) / det(S) (one
/// division instead of a chain of square roots and divisions: the latency of a small
/// update), where det(S) is a normal positive number; anything else (a pivot or
/// determinant not positive, extreme scales) goes through the factor.
#[inline]
pub(crate) fn spd_inverse<T: Scalar, const M: usize>(
    s: &SMatrix<T, M, M>,
) -> Option<SMatrix<T, M, M>> {
    // The unused logarithm is dead code once inlined (a pure intrinsic).
    spd_inverse_log_det(s).map(|(inverse, _)| inverse)
}

/// [`spd_inverse`] and ln det S from the same factorization: ln of the closed form's
/// determinant for one or two rows, else ln prod d_j over the Cholesky pivots
/// d_j = L_jj^2 (det S = prod L_jj^2, Golub & Van Loan, 4th ed., sec. 4.2.1): no
/// second factorization, and one logarithm where the product is a positive normal
/// number, else (extreme scales, where it would overflow or underflow) the sum
/// 2 sum ln L_jj.
#[inline(always)]
pub(crate) fn spd_inverse_log_det<T: Scalar, const M: usize>(
    s: &SMatrix<T, M, M>,
) -> Option<(SMatrix<T, M, M>, T)> {
    if M == 1 || M == 2 {
        let a = s[(0, 0)];
        let (b, d) = if M == 2 {
            (s[(M - 1, 0)], s[(M - 1, M - 1)])
        } else {
            (T::zero(), T::one())
        };
        let det = a * d - b * b;
        if a > T::zero() && positive_normal(det) {
            let r = T::one() / det;
            if r.is_finite() {
                let mut inv = SMatrix::<T, M, M>::zeros();
                if M == 2 {
                    inv[(0, 0)] = d * r;
                    inv[(M - 1, 0)] = -b * r;
                    inv[(0, M - 1)] = -b * r;
                    inv[(M - 1, M - 1)] = a * r;
                } else {
                    inv[(0, 0)] = r;
                }
                return Some((inv, det.ln()));
            }
        }
    }
    // One division per column (1 / L_jj, also W's diagonal), none per entry: square
    // roots and divisions queue on one unit, the bottleneck of a small update.
    let mut l = SMatrix::<T, M, M>::zeros();
    let mut w = SMatrix::<T, M, M>::zeros();
    let mut det = T::one();
    for j in 0..M {
        let mut d = s[(j, j)];
        for k in 0..j {
            d -= l[(j, k)] * l[(j, k)];
        }
        // `d` is finite (S was checked); also refuses NaN from round-off.
        if d <= T::zero() || !d.is_finite() {
            return None;
        }
        det *= d;
        let ljj = d.sqrt();
        let inverse = T::one() / ljj;
        l[(j, j)] = ljj;
        w[(j, j)] = inverse;
        for i in (j + 1)..M {
            let mut v = s[(i, j)];
            for k in 0..j {
                v -= l[(i, k)] * l[(j, k)];
            }
            l[(i, j)] = v * inverse;
        }
    }
    // W = L^-1 (lower triangular), by forward substitution.
    for j in 0..M {
        for i in (j + 1)..M {
            let mut v = T::zero();
            for k in j..i {
                v -= l[(i, k)] * w[(k, j)];
            }
            w[(i, j)] = v * w[(i, i)];
        }
    }
    // S^-1 = W' W, upper triangle then mirrored.
    let mut inv = SMatrix::<T, M, M>::zeros();
    for j in 0..M {
        for i in 0..=j {
            let mut v = T::zero();
            for k in j..M {
                v += w[(k, i)] * w[(k, j)];
            }
            inv[(i, j)] = v;
            inv[(j, i)] = v;
        }
    }
    let log_det = if positive_normal(det) {
        det.ln()
    } else {
        (0..M).fold(T::zero(), |sum, j| sum + l[(j, j)].ln()) * lit::<T>(2.0)
    };
    Some((inv, log_det))
}
