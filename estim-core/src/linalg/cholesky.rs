//! The semidefinite Cholesky factorisation: the one factorisation of a covariance
//! (P, Q, a joint [[P, M], [M', R]]) into a lower-triangular square root.
//!
//! **What it computes.** For a symmetric n x n matrix J (only its lower triangle is
//! read), a lower-triangular L with L L' = J, by the left-looking Cholesky
//! algorithm (Golub & Van Loan, *Matrix Computations*, 4th ed., alg. 4.2.1) in
//! column order, *without pivoting* (the order of the rows is the caller's: state,
//! then measurement noise).
//!
//! **Tolerance.** tol = 16 n eps (`PIVOT_TOLERANCE`), with n the size of the whole
//! joint matrix when a leading block is factored alone. Column j's pivot
//! d_j = J_jj - sum_k L_jk^2 is
//!
//! - *positive*: d_j > tol |J_jj|. L_jj = sqrt(d_j), and the column below is
//!   divided by L_jj (computed as sqrt(d_j) (1 / d_j) where 1 / d_j is finite);
//! - *zero to round-off*: |d_j| <= tol |J_jj|. The column is a zero column (L_jj and
//!   the entries below are 0), accepted only if every entry below vanishes to
//!   round-off, v_i^2 <= tol |J_jj| |J_ii| (a positive semidefinite matrix with a
//!   zero pivot has a zero column: |v_i|^2 <= d_j d_i);
//! - *negative*: d_j < -tol |J_jj|, or not finite.
//!
//! So a positive *semi*definite J (a singular Q = G G' q, an M on the validity
//! boundary) factors, with zero columns where it is singular.
//!
//! **Failure.** `false` / `None` when a pivot is negative beyond the tolerance or not
//! finite, or a zero pivot's column does not vanish: J has no square root. Nothing is
//! ever factored around (no shift, no clamping).
//!
//! **Speed.** Columns are first taken by a loop with one test per column
//! (`definite_columns`, the common case of a definite leading part), which hands
//! over to the careful loop at the first pivot that is not clearly positive; both
//! perform the same operations on such a column, so the factor is the same bit for
//! bit. The joint factor of 8 or more states runs a copy compiled for AVX-512F where
//! [`super::dispatch`] allows (no fused operations: the same bits).

use nalgebra::{SMatrix, SVector};

use crate::gaussian::exactly_zero;
use crate::scalar::{lit, Scalar};

/// A matrix made of four static blocks (the joint factor, the pre-arrays of the
/// square-root update, the LDL' certificate's joint matrix) [[A, B], [C, D]] (A: R1 x C1, B: R1 x C2,
/// C: R2 x C1, D: R2 x C2), addressed with global indices. Lets the pre-arrays,
/// whose sizes are sums of const generics (M + N, N + N), stay on the stack without
/// `generic_const_exprs`.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Blocks<
    T: Scalar,
    const R1: usize,
    const R2: usize,
    const C1: usize,
    const C2: usize,
> {
    pub(crate) a: SMatrix<T, R1, C1>,
    pub(crate) b: SMatrix<T, R1, C2>,
    pub(crate) c: SMatrix<T, R2, C1>,
    pub(crate) d: SMatrix<T, R2, C2>,
}

impl<T: Scalar, const R1: usize, const R2: usize, const C1: usize, const C2: usize>
    Blocks<T, R1, R2, C1, C2>
{
    pub(crate) fn zeros() -> Self {
        Self {
            a: SMatrix::zeros(),
            b: SMatrix::zeros(),
            c: SMatrix::zeros(),
            d: SMatrix::zeros(),
        }
    }

    #[inline(always)]
    pub(crate) fn get(&self, i: usize, k: usize) -> T {
        match (i < R1, k < C1) {
            (true, true) => self.a[(i, k)],
            (true, false) => self.b[(i, k - C1)],
            (false, true) => self.c[(i - R1, k)],
            (false, false) => self.d[(i - R1, k - C1)],
        }
    }

    #[inline(always)]
    pub(crate) fn at(&mut self, i: usize, k: usize) -> &mut T {
        match (i < R1, k < C1) {
            (true, true) => &mut self.a[(i, k)],
            (true, false) => &mut self.b[(i, k - C1)],
            (false, true) => &mut self.c[(i - R1, k)],
            (false, false) => &mut self.d[(i - R1, k - C1)],
        }
    }
}

/// Read/write access to a square matrix by global indices.
pub(crate) trait Square<T> {
    /// Entry (i, k).
    fn value(&self, i: usize, k: usize) -> T;
    /// Set entry (i, k) to v.
    fn set(&mut self, i: usize, k: usize, v: T);
}

impl<T: Scalar, const R1: usize, const R2: usize, const C1: usize, const C2: usize> Square<T>
    for Blocks<T, R1, R2, C1, C2>
{
    #[inline(always)]
    fn value(&self, i: usize, k: usize) -> T {
        self.get(i, k)
    }
    #[inline(always)]
    fn set(&mut self, i: usize, k: usize, v: T) {
        *self.at(i, k) = v;
    }
}

impl<T: Scalar, const N: usize> Square<T> for SMatrix<T, N, N> {
    #[inline(always)]
    fn value(&self, i: usize, k: usize) -> T {
        self[(i, k)]
    }
    #[inline(always)]
    fn set(&mut self, i: usize, k: usize, v: T) {
        self[(i, k)] = v;
    }
}

/// Multiple of (size x eps) within which a Cholesky pivot counts as zero (see the
/// module docs).
const PIVOT_TOLERANCE: f64 = 16.0;

/// Left-looking Cholesky (Golub & Van Loan alg. 4.2.1) of the symmetric matrix
/// `joint(i, k)` (i >= k read only) of size `n`, into the lower triangle of `l`,
/// tolerating zero pivots to round-off (positive *semi*definite input).
///
/// The first `given` columns' rows `0..given` already hold a factor of the leading
/// block (`joint` must still return that block's diagonal); only the rows below are
/// computed for them. Returns false if the matrix is not positive semidefinite to
/// round-off: a pivot below -tol J_jj, or a zero pivot whose column does not vanish
/// (for a PSD matrix |v_i|^2 <= d_j d_i <= tol J_jj J_ii), tol = 16 n eps.
#[inline]
pub(crate) fn semidefinite_cholesky<T: Scalar, L: Square<T>>(
    n: usize,
    given: usize,
    joint: impl Fn(usize, usize) -> T,
    l: &mut L,
) -> bool {
    semidefinite_cholesky_sized(n, n, given, joint, l)
}

/// The common case of [`semidefinite_cholesky_sized`] without a given block: columns
/// whose pivot is finite and above its tolerance, with one test per column (the
/// careful loop's three, with their exits, cost about a tenth of a (4, 2) update).
/// The operations are those of the careful loop on such a column (pivot, its square
/// root, 1 / L_jj as sqrt(d) (1 / d), the rows), so the factor is the same bit for
/// bit. Returns the first column it did not factor (n when it factored all): the
/// careful loop takes over there (it reads only the columns before it).
#[inline(always)]
fn definite_columns<T: Scalar, L: Square<T>>(
    n: usize,
    tol: T,
    joint: &impl Fn(usize, usize) -> T,
    l: &mut L,
) -> usize {
    for j in 0..n {
        let jj = joint(j, j);
        let mut pivot = jj;
        for k in 0..j {
            let v = l.value(j, k);
            pivot -= v * v;
        }
        let r = T::one() / pivot;
        // False for a NaN pivot too; an infinite one would give r = 0.
        if !(pivot.is_finite() & (pivot > tol * jj.abs()) & r.is_finite()) {
            return j;
        }
        let ljj = pivot.sqrt();
        l.set(j, j, ljj);
        let inverse = ljj * r;
        for i in j + 1..n {
            let mut v = joint(i, j);
            for k in 0..j {
                v -= l.value(i, k) * l.value(j, k);
            }
            l.set(i, j, v * inverse);
        }
    }
    n
}

/// [`semidefinite_cholesky`] with the tolerance of a matrix of size `tol_size`
/// (>= n: the leading block of a larger joint matrix).
#[inline(always)]
fn semidefinite_cholesky_sized<T: Scalar, L: Square<T>>(
    n: usize,
    tol_size: usize,
    given: usize,
    joint: impl Fn(usize, usize) -> T,
    l: &mut L,
) -> bool {
    let tol = lit::<T>(PIVOT_TOLERANCE * tol_size as f64) * T::default_epsilon();
    let start = if given == 0 {
        definite_columns(n, tol, &joint, l)
    } else {
        0
    };
    careful_columns(start, n, tol, given, &joint, l)
}

/// Columns `start..n` of [`semidefinite_cholesky_sized`], each pivot tested: negative
/// beyond round-off or not finite (false), zero to round-off (a zero column, false
/// unless the column vanishes), or positive.
#[inline(always)]
fn careful_columns<T: Scalar, L: Square<T>>(
    start: usize,
    n: usize,
    tol: T,
    given: usize,
    joint: &impl Fn(usize, usize) -> T,
    l: &mut L,
) -> bool {
    for j in start..n {
        let jj = joint(j, j);
        let tol_j = tol * jj.abs();
        let pivot = if j < given {
            let v = l.value(j, j);
            v * v
        } else {
            let mut d = jj;
            for k in 0..j {
                let v = l.value(j, k);
                d -= v * v;
            }
            d
        };
        if !pivot.is_finite() || pivot < -tol_j {
            return false;
        }
        let first = if j < given { given } else { j + 1 };
        if pivot <= tol_j {
            if j >= given {
                l.set(j, j, T::zero());
            }
            for i in first..n {
                let mut v = joint(i, j);
                for k in 0..j {
                    v -= l.value(i, k) * l.value(j, k);
                }
                if v * v > tol_j * joint(i, i).abs() {
                    return false;
                }
                l.set(i, j, T::zero());
            }
            continue;
        }
        let ljj = if j < given {
            l.value(j, j)
        } else {
            let s = pivot.sqrt();
            l.set(j, j, s);
            s
        };
        // One division per column, not per entry; 1 / L_jj as sqrt(d) (1 / d), the
        // square root and the division side by side instead of one after the other
        // (this chain of columns is the latency of a small update), unless 1 / d
        // overflows.
        let inverse = {
            let r = T::one() / pivot;
            if j >= given && r.is_finite() {
                ljj * r
            } else {
                T::one() / ljj
            }
        };
        for i in first..n {
            let mut v = joint(i, j);
            for k in 0..j {
                v -= l.value(i, k) * l.value(j, k);
            }
            l.set(i, j, v * inverse);
        }
    }
    true
}

/// Lower-triangular factor of the joint covariance [[P, M], [M', R]] as blocks
/// (L11 = a, L21 = c, L22 = d; b = 0), or `None` if it is not positive
/// semidefinite to round-off. Reads the lower triangles of P and R only.
///
/// For 8 or more states it runs a copy compiled for AVX-512 where the CPU has it
/// (no FMA: the same bits; 7 % of the (15,3) predict + update).
#[inline]
pub(crate) fn joint_factor<T: Scalar, const N: usize, const M: usize>(
    covariance: &SMatrix<T, N, N>,
    cross_covariance: &SMatrix<T, N, M>,
    measurement_noise: &SMatrix<T, M, M>,
) -> Option<Blocks<T, N, M, N, M>> {
    let mut l = Blocks::zeros();
    joint_factor_into(covariance, cross_covariance, measurement_noise, &mut l).then_some(l)
}

/// [`joint_factor`] into `l`, which must be zero (only the lower triangle is
/// written): the update's caller keeps the factor where it is used instead of
/// moving it out of a return value. False if the joint has no square root.
#[inline(always)]
pub(crate) fn joint_factor_into<T: Scalar, const N: usize, const M: usize>(
    covariance: &SMatrix<T, N, N>,
    cross_covariance: &SMatrix<T, N, M>,
    measurement_noise: &SMatrix<T, M, M>,
    l: &mut Blocks<T, N, M, N, M>,
) -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        if N >= 8 && super::dispatch::avx512f() {
            // SAFETY: the CPU has AVX-512F (the dispatch checked it on the line above).
            return unsafe {
                joint_factor_avx512(covariance, cross_covariance, measurement_noise, l)
            };
        }
    }
    joint_factor_body(covariance, cross_covariance, measurement_noise, l)
}

/// [`joint_factor_body`] compiled for AVX-512F (wider registers for the loops; no
/// fused operations, so the same bits). Safe to call where AVX-512F is enabled; other
/// callers need an `unsafe` block that justifies the CPU has it.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn joint_factor_avx512<T: Scalar, const N: usize, const M: usize>(
    covariance: &SMatrix<T, N, N>,
    cross_covariance: &SMatrix<T, N, M>,
    measurement_noise: &SMatrix<T, M, M>,
    l: &mut Blocks<T, N, M, N, M>,
) -> bool {
    joint_factor_body(covariance, cross_covariance, measurement_noise, l)
}

#[inline(always)]
fn joint_factor_body<T: Scalar, const N: usize, const M: usize>(
    covariance: &SMatrix<T, N, N>,
    cross_covariance: &SMatrix<T, N, M>,
    measurement_noise: &SMatrix<T, M, M>,
    l: &mut Blocks<T, N, M, N, M>,
) -> bool {
    // Leading block on a plain static matrix (the hot part, no block addressing),
    // with the tolerance of the whole joint's size, then the rows of [M' R]. Factored
    // in place in the result's block (no copy of an N x N factor).
    let tol_size = N + M;
    if !semidefinite_cholesky_sized(N, tol_size, 0, |i, k| covariance[(i, k)], &mut l.a) {
        return false;
    }
    if exactly_zero(cross_covariance.as_slice()) {
        // M = 0: the joint is block diagonal, L21 = 0 and L22 = chol(R). The general
        // elimination below would subtract only zero products from R's entries
        // (R_ij - 0 = R_ij exactly) before the same operations in the same order, and
        // its zero-pivot test on the rows of M' reads zeros, so this gives the same
        // factor (bit for bit, up to the sign of exact zeros in L21) without touching
        // the zero block.
        return semidefinite_cholesky_sized(
            M,
            tol_size,
            0,
            |i, k| measurement_noise[(i, k)],
            &mut l.d,
        );
    }
    factor_rest(l, cross_covariance, measurement_noise)
}

/// [`joint_factor`] without the block-diagonal shortcut for M = 0 (the reference the
/// shortcut is tested against).
#[cfg(test)]
pub(crate) fn joint_factor_general<T: Scalar, const N: usize, const M: usize>(
    covariance: &SMatrix<T, N, N>,
    cross_covariance: &SMatrix<T, N, M>,
    measurement_noise: &SMatrix<T, M, M>,
) -> Option<Blocks<T, N, M, N, M>> {
    let mut l11 = SMatrix::<T, N, N>::zeros();
    if !semidefinite_cholesky_sized(N, N + M, 0, |i, k| covariance[(i, k)], &mut l11) {
        return None;
    }
    joint_factor_from(&l11, cross_covariance, measurement_noise)
}

/// The joint factor of [[S S', M], [M', R]] for a given lower-triangular S (the
/// leading block is not refactored): L21 = M' S^-T, L22 L22' = R - L21 L21'.
#[inline]
pub(crate) fn joint_factor_from<T: Scalar, const N: usize, const M: usize>(
    factor: &SMatrix<T, N, N>,
    cross_covariance: &SMatrix<T, N, M>,
    measurement_noise: &SMatrix<T, M, M>,
) -> Option<Blocks<T, N, M, N, M>> {
    let mut l = Blocks::<T, N, M, N, M>::zeros();
    l.a = *factor;
    factor_rest(&mut l, cross_covariance, measurement_noise).then_some(l)
}

/// The rows of [M' R] of the joint factor, given its leading block `l.a` (lower
/// triangular); false if the joint has no square root.
#[inline]
fn factor_rest<T: Scalar, const N: usize, const M: usize>(
    l: &mut Blocks<T, N, M, N, M>,
    cross_covariance: &SMatrix<T, N, M>,
    measurement_noise: &SMatrix<T, M, M>,
) -> bool {
    let factor = &l.a;
    let diag: SVector<T, N> = SVector::from_fn(|j, _| {
        (0..N).fold(T::zero(), |acc, k| acc + factor[(j, k)] * factor[(j, k)])
    });
    let joint = |i: usize, k: usize| -> T {
        match (i < N, k < N) {
            // Only the diagonal of the given block is read (tolerances).
            (true, true) => diag[i],
            (false, true) => cross_covariance[(k, i - N)],
            (false, false) => measurement_noise[(i - N, k - N)],
            (true, false) => cross_covariance[(i, k - N)],
        }
    };
    semidefinite_cholesky(N + M, N, joint, l)
}

#[cfg(test)]
#[path = "cholesky_tests.rs"]
mod tests;
