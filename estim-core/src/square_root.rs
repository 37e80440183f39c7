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
use crate::gaussian::{all_zero, check_finite};
use crate::scalar::{lit, to_f64};
use crate::update::{check_innovation_conditioning, mul_static};
use crate::{CrossCovariance, CrossCovarianceContext, Error, Result, Scalar, StateAndCovariance};

/// A matrix made of four static blocks [[A, B], [C, D]] (A: R1 x C1, B: R1 x C2,
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
    fn get(&self, i: usize, k: usize) -> T {
        match (i < R1, k < C1) {
            (true, true) => self.a[(i, k)],
            (true, false) => self.b[(i, k - C1)],
            (false, true) => self.c[(i - R1, k)],
            (false, false) => self.d[(i - R1, k - C1)],
        }
    }

    #[inline(always)]
    fn at(&mut self, i: usize, k: usize) -> &mut T {
        match (i < R1, k < C1) {
            (true, true) => &mut self.a[(i, k)],
            (true, false) => &mut self.b[(i, k - C1)],
            (false, true) => &mut self.c[(i - R1, k)],
            (false, false) => &mut self.d[(i - R1, k - C1)],
        }
    }

    /// Lower-triangularise in place by Givens rotations from the right (an orthogonal
    /// Theta with W Theta = [L, 0], L lower triangular with a nonnegative diagonal,
    /// so L L' = W W'; Golub & Van Loan, *Matrix Computations*, 4th ed., sec. 5.1.8).
    /// Requires R1 + R2 <= C1 + C2.
    fn lower_triangularize(&mut self) {
        let rows = R1 + R2;
        let cols = C1 + C2;
        for i in 0..rows.min(cols) {
            for j in (i + 1)..cols {
                let b = self.get(i, j);
                if b.is_zero() {
                    continue;
                }
                let a = self.get(i, i);
                let r = radius(a, b);
                let (c, s) = (a / r, b / r);
                // Rows above i are zero in columns i and j (> their own index).
                for k in i..rows {
                    let x = self.get(k, i);
                    let y = self.get(k, j);
                    *self.at(k, i) = c * x + s * y;
                    *self.at(k, j) = c * y - s * x;
                }
                *self.at(i, j) = T::zero();
            }
            if self.get(i, i) < T::zero() {
                for k in i..rows {
                    let x = self.get(k, i);
                    *self.at(k, i) = -x;
                }
            }
        }
    }
}

/// Read/write access to a square matrix by global indices.
trait Square<T> {
    fn value(&self, i: usize, k: usize) -> T;
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

/// sqrt(x^2 + y^2) for a Givens rotation: the plain formula (several times faster
/// than `hypot`), with `hypot` where the squares overflow or both underflow to zero
/// (entries beyond ~1e+-154 in f64; precision is kept down to ~1e-160, where the
/// squares are subnormal).
#[inline(always)]
fn radius<T: Scalar>(x: T, y: T) -> T {
    let r = (x * x + y * y).sqrt();
    if r.is_finite() && r > T::zero() {
        r
    } else {
        x.hypot(y)
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
fn semidefinite_cholesky<T: Scalar, L: Square<T>>(
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
        if N >= 8 && std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has the feature (checked on the line above).
            return unsafe {
                joint_factor_avx512(covariance, cross_covariance, measurement_noise, l)
            };
        }
    }
    joint_factor_body(covariance, cross_covariance, measurement_noise, l)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn joint_factor_avx512<T: Scalar, const N: usize, const M: usize>(
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
    if all_zero(cross_covariance.as_slice()) {
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
fn joint_factor_from<T: Scalar, const N: usize, const M: usize>(
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

/// Givens rotation of columns (i of `a`, j of `b`) over rows `from..`, chosen to zero
/// `b[(row, j)]` against `a[(row, i)]`.
#[inline(always)]
fn rotate_columns<T: Scalar, const R: usize, const C1: usize, const C2: usize>(
    a: &mut SMatrix<T, R, C1>,
    i: usize,
    b: &mut SMatrix<T, R, C2>,
    j: usize,
    row: usize,
) {
    let y = b[(row, j)];
    if y.is_zero() {
        return;
    }
    let x = a[(row, i)];
    let r = radius(x, y);
    let (c, s) = (x / r, y / r);
    let (mut ca, mut cb) = (a.column_mut(i), b.column_mut(j));
    for (u, v) in ca.iter_mut().zip(cb.iter_mut()).skip(row) {
        let (p, q) = (*u, *v);
        *u = c * p + s * q;
        *v = c * q - s * p;
    }
    b[(row, j)] = T::zero();
}

/// [a, b] Theta = [L, 0] for two column blocks (R <= C1), L lower triangular with a
/// nonnegative diagonal, by Givens rotations on contiguous columns (same algorithm
/// as [`Blocks::lower_triangularize`], specialised to one row block).
fn lower_triangularize_pair<T: Scalar, const R: usize, const C1: usize, const C2: usize>(
    a: &mut SMatrix<T, R, C1>,
    b: &mut SMatrix<T, R, C2>,
) {
    for i in 0..R.min(C1) {
        for j in (i + 1)..C1 {
            let y = a[(i, j)];
            if y.is_zero() {
                continue;
            }
            let x = a[(i, i)];
            let r = radius(x, y);
            let (c, s) = (x / r, y / r);
            for k in i..R {
                let (p, q) = (a[(k, i)], a[(k, j)]);
                a[(k, i)] = c * p + s * q;
                a[(k, j)] = c * q - s * p;
            }
            a[(i, j)] = T::zero();
        }
        for j in 0..C2 {
            rotate_columns(a, i, b, j, i);
        }
        if a[(i, i)] < T::zero() {
            for k in i..R {
                a[(k, i)] = -a[(k, i)];
            }
        }
    }
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
/// [`Error::InnovationIllConditioned`] as for [`crate::correlated_update`].
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

/// Linear Kalman filter in square-root form, x_k = F x_{k-1} + G w, y_k = H x_k + v,
/// with the correlated update; same `predict` / `update` / `step` shape as
/// [`crate::KalmanFilter`].
///
/// Holds the state, a lower-triangular factor S of P (never P itself), and Q_acc /
/// Phi_acc since the last measurement (for the [`CrossCovariance`] context and the
/// validity check). Before every update the joint covariance
/// [[Q_acc, M], [M', R]] must have a square root: otherwise the update is refused
/// with [`Error::InvalidJointCovariance`] and nothing changes (this is the
/// square-root form's definition of an invalid M; it is never factored around).
/// Q_acc and Phi_acc are reset after a successful update and kept on an error.
#[derive(Debug, Clone)]
pub struct SquareRootKalmanFilter<T: Scalar, const N: usize, const M: usize> {
    transition: SMatrix<T, N, N>,
    process_noise: SMatrix<T, N, N>,
    noise_factor: SMatrix<T, N, N>,
    observation: SMatrix<T, M, N>,
    measurement_noise: SMatrix<T, M, M>,
    state: SVector<T, N>,
    factor: SMatrix<T, N, N>,
    accumulated_noise: SMatrix<T, N, N>,
    accumulated_transition: SMatrix<T, N, N>,
    steps: usize,
}

impl<T: Scalar, const N: usize, const M: usize> SquareRootKalmanFilter<T, N, M> {
    /// A filter with transition F, process noise Cov(G w) = Q, observation matrix H,
    /// measurement noise R and the initial estimate (P is factored once).
    ///
    /// # Errors
    /// [`Error::NonFinite`]; [`Error::InvalidCovariance`] if Q or P is not positive
    /// semidefinite or R is not positive definite.
    pub fn new(
        transition: SMatrix<T, N, N>,
        process_noise: SMatrix<T, N, N>,
        observation: SMatrix<T, M, N>,
        measurement_noise: SMatrix<T, M, M>,
        initial: StateAndCovariance<T, N>,
    ) -> Result<Self> {
        check_finite(transition.as_slice(), "transition")?;
        check_finite(observation.as_slice(), "observation matrix")?;
        let noise_factor = covariance_factor(&process_noise, "process noise")?;
        let r_factor = covariance_factor(&measurement_noise, "measurement noise")?;
        if (0..M).any(|i| r_factor[(i, i)] <= T::zero()) {
            return Err(Error::InvalidCovariance {
                what: "measurement noise",
                reason: "not positive definite".into(),
            });
        }
        let factor = covariance_factor(initial.covariance(), "initial covariance")?;
        Ok(Self {
            transition,
            process_noise,
            noise_factor,
            observation,
            measurement_noise,
            state: *initial.state(),
            factor,
            accumulated_noise: SMatrix::zeros(),
            accumulated_transition: SMatrix::identity(),
            steps: 0,
        })
    }

    /// Current mean.
    pub fn state(&self) -> &SVector<T, N> {
        &self.state
    }

    /// Lower-triangular factor S of the covariance, P = S S'.
    pub fn factor(&self) -> &SMatrix<T, N, N> {
        &self.factor
    }

    /// Mean and covariance P = S S' (formed on demand, exactly symmetric).
    pub fn estimate(&self) -> StateAndCovariance<T, N> {
        let mut p = SMatrix::<T, N, N>::zeros();
        for j in 0..N {
            for i in j..N {
                let mut v = T::zero();
                for k in 0..=j {
                    v += self.factor[(i, k)] * self.factor[(j, k)];
                }
                p[(i, j)] = v;
                p[(j, i)] = v;
            }
        }
        StateAndCovariance::new_unchecked(self.state, p)
    }

    /// Q_acc: process noise accumulated since the last update.
    pub fn accumulated_process_noise(&self) -> &SMatrix<T, N, N> {
        &self.accumulated_noise
    }

    /// Phi_acc: product of the transitions since the last update.
    pub fn accumulated_transition(&self) -> &SMatrix<T, N, N> {
        &self.accumulated_transition
    }

    /// Number of predictions since the last update.
    pub fn propagations_since_update(&self) -> usize {
        self.steps
    }

    /// Prior: x <- F x, S <- tria([F S, S_q]); Q_acc <- F Q_acc F' + Q,
    /// Phi_acc <- F Phi_acc.
    ///
    /// # Errors
    /// [`Error::NonFinite`] if the prediction overflows (nothing changes then).
    pub fn predict(&mut self) -> Result<()> {
        let f = &self.transition;
        let state = mul_static(f, &self.state);
        check_finite(state.as_slice(), "predicted state")?;
        let factor = square_root_predict(&self.factor, f, &self.noise_factor)?;
        let fq = mul_static(f, &self.accumulated_noise);
        let mut q = mul_static(&fq, &f.transpose()) + self.process_noise;
        q = (q + q.transpose()) * lit::<T>(0.5);
        let phi = mul_static(f, &self.accumulated_transition);
        check_finite(q.as_slice(), "accumulated process noise")?;
        self.state = state;
        self.factor = factor;
        self.accumulated_noise = q;
        self.accumulated_transition = phi;
        self.steps += 1;
        Ok(())
    }

    /// Update with measurement y and the cross-covariance model `cross`.
    ///
    /// # Errors
    /// [`Error::InvalidJointCovariance`] if [[Q_acc, M], [M', R]] (or
    /// [[P, M], [M', R]]) has no square root; those of [`square_root_update`] and of
    /// the cross-covariance model. Nothing changes on an error.
    pub fn update<C>(
        &mut self,
        measurement: &SVector<T, M>,
        cross: &C,
    ) -> Result<SquareRootOutcome<T, N, M>>
    where
        C: CrossCovariance<T, SVector<T, N>, N, M> + ?Sized,
    {
        check_finite(measurement.as_slice(), "measurement")?;
        let prior = self.estimate();
        let context = CrossCovarianceContext {
            accumulated_process_noise: &self.accumulated_noise,
            accumulated_transition: &self.accumulated_transition,
            accumulation_tracked: true,
            measurement_noise: &self.measurement_noise,
            jacobian: &self.observation,
            measurement,
            state: &self.state,
            covariance: prior.covariance(),
        };
        let cross_covariance = cross.cross_covariance(&context)?;
        check_joint_factor(
            &self.accumulated_noise,
            &cross_covariance,
            &self.measurement_noise,
        )?;
        let innovation = measurement - mul_static(&self.observation, &self.state);
        let outcome = square_root_update(
            &self.state,
            &self.factor,
            &innovation,
            &self.observation,
            &self.measurement_noise,
            &cross_covariance,
        )?;
        self.state = outcome.state;
        self.factor = outcome.factor;
        self.accumulated_noise = SMatrix::zeros();
        self.accumulated_transition = SMatrix::identity();
        self.steps = 0;
        Ok(outcome)
    }

    /// One time step: predict, then update if a measurement is present.
    ///
    /// # Errors
    /// Those of [`SquareRootKalmanFilter::predict`] and
    /// [`SquareRootKalmanFilter::update`].
    pub fn step<C>(
        &mut self,
        measurement: Option<&SVector<T, M>>,
        cross: &C,
    ) -> Result<Option<SquareRootOutcome<T, N, M>>>
    where
        C: CrossCovariance<T, SVector<T, N>, N, M> + ?Sized,
    {
        self.predict()?;
        measurement.map(|y| self.update(y, cross)).transpose()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A symmetric N x N matrix G G' (rank `rank`) plus `shift` I (indefinite when
    /// `shift` < 0), seeded.
    fn gram<const N: usize>(rng: &mut ChaCha8Rng, rank: usize, shift: f64) -> SMatrix<f64, N, N> {
        let g = SMatrix::<f64, N, N>::from_fn(|_, j| {
            if j < rank {
                rng.random_range(-1.0..1.0)
            } else {
                0.0
            }
        });
        g * g.transpose() + SMatrix::identity() * shift
    }

    /// Asserts that two joint factorisations agree: both refused (false) or both
    /// factored with equal blocks (true; == : only the sign of exact zeros is free).
    fn same_factor<const N: usize, const M: usize>(
        one: Option<Blocks<f64, N, M, N, M>>,
        other: Option<Blocks<f64, N, M, N, M>>,
        case: usize,
    ) -> bool {
        match (one, other) {
            (Some(f), Some(g)) => {
                assert_eq!(f.a, g.a, "case {case}");
                assert_eq!(f.c, g.c, "case {case}");
                assert_eq!(f.d, g.d, "case {case}");
                true
            }
            (None, None) => false,
            (f, g) => panic!("case {case}: {:?} vs {:?}", f.is_some(), g.is_some()),
        }
    }

    /// The untested columns of a positive definite matrix, then the careful loop from
    /// the first column whose pivot is not clearly positive, give the careful loop's
    /// own factor bit for bit, and the same verdict: on positive definite matrices,
    /// on rank-deficient ones (the first zero pivot anywhere from the first column
    /// to the last), on indefinite ones, at subnormal scale (1 / pivot overflows) and
    /// with a NaN; every size from 1 to 8, f64 and f32, static and block storage,
    /// seeded (seeds 1, 2, 3 and 99 pass as well, coverage counts included).
    #[test]
    fn definite_columns_then_careful_ones_equal_the_careful_loop() {
        /// (verdict, first column handed over) of the two-stage factorisation, after
        /// asserting it equals the careful loop alone, in `L`'s storage.
        fn compare<T: Scalar, L: Square<T> + PartialEq + std::fmt::Debug>(
            n: usize,
            joint: &impl Fn(usize, usize) -> T,
            zeros: impl Fn() -> L,
            label: &str,
        ) -> (bool, usize) {
            let tol = lit::<T>(PIVOT_TOLERANCE * n as f64) * T::default_epsilon();
            let mut reference = zeros();
            let expected = careful_columns(0, n, tol, 0, joint, &mut reference);
            let mut fast = zeros();
            let start = definite_columns(n, tol, joint, &mut fast);
            let verdict = careful_columns(start, n, tol, 0, joint, &mut fast);
            assert_eq!(verdict, expected, "{label}");
            let mut through = zeros();
            assert_eq!(semidefinite_cholesky(n, 0, joint, &mut through), expected);
            if expected {
                assert_eq!(fast, reference, "{label}");
                assert_eq!(through, reference, "{label}");
            }
            (expected, start)
        }
        fn check<const N: usize>(rng: &mut ChaCha8Rng, saw: &mut [usize; 3]) {
            for case in 0..50 {
                let (rank, shift) = match case % 5 {
                    0 | 4 => (N, 0.0),
                    1 => (rng.random_range(0..N), 0.0),
                    2 => (N, -rng.random_range(0.01..0.5)),
                    _ => (N, 1e-3),
                };
                let mut p = gram::<N>(rng, rank, shift);
                if case % 5 == 4 {
                    // Subnormal entries: 1 / pivot overflows in both types.
                    p *= 1e-310;
                }
                if case == 49 {
                    p[(N - 1, N - 1)] = f64::NAN;
                }
                let label = format!("N = {N}, case {case}");
                let joint = |i: usize, k: usize| p[(i, k)];
                let (expected, start) = compare(N, &joint, SMatrix::<f64, N, N>::zeros, &label);
                let blocks = compare(N, &joint, Blocks::<f64, N, 2, N, 2>::zeros, &label);
                assert_eq!(blocks, (expected, start), "{label}, blocks");
                let single = p.map(|v| if case % 5 == 4 { v * 1e270 } else { v } as f32);
                let joint32 = |i: usize, k: usize| single[(i, k)];
                compare(N, &joint32, SMatrix::<f32, N, N>::zeros, &label);
                compare(N, &joint32, Blocks::<f32, N, 2, N, 2>::zeros, &label);
                saw[usize::from(start < N) + usize::from(expected && start < N)] += 1;
            }
        }
        let mut rng = ChaCha8Rng::seed_from_u64(41);
        // [all columns untested, handed over and refused, handed over and factored]
        let mut saw = [0; 3];
        check::<1>(&mut rng, &mut saw);
        check::<2>(&mut rng, &mut saw);
        check::<3>(&mut rng, &mut saw);
        check::<4>(&mut rng, &mut saw);
        check::<5>(&mut rng, &mut saw);
        check::<6>(&mut rng, &mut saw);
        check::<7>(&mut rng, &mut saw);
        check::<8>(&mut rng, &mut saw);
        assert!(saw.iter().all(|&count| count >= 20), "{saw:?}");
    }

    /// The joint factor is homogeneous: factor(s J) = sqrt(s) factor(J), down to
    /// subnormal scales where 1 / pivot overflows (the column's reciprocal then comes
    /// from the square root) and up to 1e300: entry by entry against sqrt(s) L, within
    /// 1e-10 of sqrt(s) (subnormal entries near 1e-310 keep about 44 bits); seeded (three
    /// other seeds checked).
    #[test]
    fn joint_factor_scales_with_the_joint_down_to_subnormal_entries() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for case in 0..50 {
            let p = gram::<4>(&mut rng, 4, 0.1);
            let r = gram::<2>(&mut rng, 2, 0.1);
            let m = SMatrix::<f64, 4, 2>::from_fn(|i, j| 0.01 * p[(i, j)]);
            let base = joint_factor(&p, &m, &r).expect("valid joint");
            for scale in [1e300, 1e-300, 1e-306, 1e-310] {
                let scaled = joint_factor(&(p * scale), &(m * scale), &(r * scale))
                    .unwrap_or_else(|| panic!("case {case} scale {scale:e}: refused"));
                let root = scale.sqrt();
                for (ours, want) in [
                    (scaled.a.as_slice(), (base.a * root).as_slice().to_vec()),
                    (scaled.c.as_slice(), (base.c * root).as_slice().to_vec()),
                    (scaled.d.as_slice(), (base.d * root).as_slice().to_vec()),
                ] {
                    for (x, y) in ours.iter().zip(&want) {
                        assert!(
                            (x - y).abs() <= 1e-10 * root,
                            "case {case} scale {scale:e}: {x:e} vs {y:e}"
                        );
                    }
                }
            }
        }
    }

    /// The block-diagonal shortcut of `joint_factor` for M = 0 equals the general
    /// elimination entry for entry (== : only the sign of exact zeros is free), and
    /// refuses exactly what it refuses: full-rank, rank-deficient (zero pivots) and
    /// indefinite P and R, sizes (7, 3), seeded.
    #[test]
    fn zero_cross_covariance_factor_equals_the_general_elimination() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (mut factored, mut refused) = (0, 0);
        for case in 0..400 {
            let shift = |c: usize| if c.is_multiple_of(5) { -1e-3 } else { 0.0 };
            let p = gram::<7>(&mut rng, 1 + case % 7, shift(case));
            let r = gram::<3>(&mut rng, 1 + case % 3, shift(case / 2)) * 0.1;
            let m = SMatrix::<f64, 7, 3>::zeros();
            let fast = joint_factor(&p, &m, &r);
            let general = joint_factor_general(&p, &m, &r);
            if same_factor(fast, general, case) {
                factored += 1;
            } else {
                refused += 1;
            }
        }
        assert!(factored > 50 && refused > 50, "{factored} / {refused}");
    }

    /// From 8 states `joint_factor` runs its AVX-512 build where the CPU has one: the
    /// same factor bit for bit as the portable build (no fused operations), and the
    /// same refusals, at (15, 3) with M = 0 and M != 0, seeded.
    #[test]
    fn the_vector_build_of_the_joint_factor_equals_the_portable_one() {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let (mut factored, mut refused) = (0, 0);
        for case in 0..200 {
            let shift = if case % 7 == 3 { -1e-3 } else { 0.0 };
            let p = gram::<15>(&mut rng, 1 + case % 15, shift);
            let r = gram::<3>(&mut rng, 3, 0.01) * 0.1;
            let m = if case % 2 == 0 {
                SMatrix::<f64, 15, 3>::zeros()
            } else {
                SMatrix::<f64, 15, 3>::from_fn(|_, _| rng.random_range(-1.0..1.0)) * 0.01
            };
            let mut portable = Blocks::zeros();
            let portable = joint_factor_body(&p, &m, &r, &mut portable).then_some(portable);
            if same_factor(joint_factor(&p, &m, &r), portable, case) {
                factored += 1;
            } else {
                refused += 1;
            }
        }
        assert!(factored > 50 && refused > 20, "{factored} / {refused}");
    }
}
