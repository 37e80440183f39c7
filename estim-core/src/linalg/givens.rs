//! Givens triangularisation: the orthogonal transformation of the square-root
//! filter's pre-arrays.
//!
//! **What it computes.** For a matrix W with at most as many rows as columns, an
//! orthogonal Theta (never formed) with W Theta = [L, 0], L lower triangular with a
//! nonnegative diagonal, so L L' = W W' (the QR factorisation of W', Golub & Van
//! Loan, *Matrix Computations*, 4th ed., sec. 5.1.8): row by row, each entry right
//! of the diagonal is rotated into the diagonal one.
//!
//! **Pivot rule and tolerance.** None: no pivoting, and an exact zero is skipped
//! (no rotation). The radius sqrt(x^2 + y^2) is the plain formula, with `hypot`
//! where the squares overflow or both underflow to zero.
//!
//! **Failure.** None (NaN and infinities propagate; callers check the result).

use nalgebra::SMatrix;

use super::cholesky::Blocks;
use crate::scalar::Scalar;

impl<T: Scalar, const R1: usize, const R2: usize, const C1: usize, const C2: usize>
    Blocks<T, R1, R2, C1, C2>
{
    /// Lower-triangularise in place by Givens rotations from the right (an orthogonal
    /// Theta with W Theta = [L, 0], L lower triangular with a nonnegative diagonal,
    /// so L L' = W W'; Golub & Van Loan, *Matrix Computations*, 4th ed., sec. 5.1.8).
    /// Requires R1 + R2 <= C1 + C2.
    #[inline]
    pub(crate) fn lower_triangularize(&mut self) {
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
#[inline]
pub(crate) fn lower_triangularize_pair<
    T: Scalar,
    const R: usize,
    const C1: usize,
    const C2: usize,
>(
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
