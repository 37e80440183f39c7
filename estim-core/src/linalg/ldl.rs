//! The LDL' certificate: a proof, without an eigen decomposition and without
//! allocating, that a symmetric matrix with unit diagonal (a correlation matrix) is
//! positive semidefinite to a tolerance.
//!
//! **What it computes.** The LDL' elimination of a symmetric n x n matrix C (upper
//! triangle read and overwritten), in static storage, *without pivoting* (rows in
//! the caller's order), and its smallest pivot. C = L D L' + E with D >= 0 and
//! |E| <= tol entrywise when it certifies.
//!
//! **Pivot rule.** Column k's pivot d_k (the diagonal entry after the eliminations
//! of the columns before it) is
//!
//! - *positive*: d_k > tol. Row k is eliminated from the rows below it;
//! - *zero to round-off*: |d_k| <= tol. Accepted as a zero variance only if the rest
//!   of row k is within tol too (a semidefinite matrix with a zero pivot has a zero
//!   row); nothing is eliminated;
//! - *negative*: d_k < -tol.
//!
//! **Tolerance.** The caller's (the joint check's `joint_tolerance`, the square root
//! of eps: 9.3e-10 in f64), absolute, which is meaningful because C has a unit
//! diagonal.
//!
//! **Failure.** `None` / `false` when it does not certify: a negative pivot, or a zero
//! pivot with a nonzero row (invalid, or too close to call without an eigen
//! decomposition, which is then the caller's fallback).

use nalgebra::SMatrix;

use super::cholesky::{Blocks, Square};
use crate::gaussian::all_zero;
use crate::scalar::Scalar;

/// The elimination of the module docs on the upper triangle of `u` (n x n), in
/// place; `smallest` takes every pivot. Rows `0..coupled` are eliminated only from
/// the rows below them up to `coupled` when `decoupled` (the block [[A, 0], [0, C]]
/// of an uncorrelated joint matrix: the eliminations through the zero block would
/// subtract only zero products, so skipping them gives the same bits). False when
/// it does not certify.
#[inline(always)]
fn eliminate<T: Scalar, U: Square<T>>(
    u: &mut U,
    n: usize,
    coupled: usize,
    decoupled: bool,
    tol: T,
    smallest: &mut T,
) -> bool {
    for k in 0..n {
        let d = u.value(k, k);
        *smallest = smallest.min(d);
        if d > tol {
            let inv = T::one() / d;
            let end = if decoupled && k < coupled { coupled } else { n };
            for j in (k + 1)..end {
                let f = u.value(k, j) * inv;
                for i in (k + 1)..=j {
                    let v = u.value(k, i) * f;
                    u.set(i, j, u.value(i, j) - v);
                }
            }
        } else if d < -tol || ((k + 1)..n).any(|j| u.value(k, j).abs() > tol) {
            return false;
        }
    }
    true
}

/// Certify [[A, B], [B', C]] (already scaled to unit diagonal; upper triangles of A
/// and C read) positive semidefinite: its smallest LDL' pivot, clamped at 0, or
/// `None` when the elimination does not certify it.
#[inline]
pub(crate) fn certify_psd<T: Scalar, const N: usize, const M: usize>(
    a: SMatrix<T, N, N>,
    b: SMatrix<T, N, M>,
    c: SMatrix<T, M, M>,
    tol: T,
) -> Option<T> {
    let correlated = !all_zero(b.as_slice());
    certify_psd_with(a, b, c, tol, correlated)
}

/// [`certify_psd`]; `correlated` false skips the eliminations involving B (only
/// valid when B = 0; the same result bit for bit, up to the sign of exact zeros).
#[inline(always)]
pub(crate) fn certify_psd_with<T: Scalar, const N: usize, const M: usize>(
    a: SMatrix<T, N, N>,
    b: SMatrix<T, N, M>,
    c: SMatrix<T, M, M>,
    tol: T,
    correlated: bool,
) -> Option<T> {
    let mut joint = Blocks::<T, N, M, N, M> {
        a,
        b,
        c: SMatrix::zeros(),
        d: c,
    };
    let mut smallest = T::one();
    if !eliminate(&mut joint, N + M, N, !correlated, tol, &mut smallest) {
        return None;
    }
    // A pivot accepted as zero may be a round-off -tol..0: certified means >= 0.
    Some(smallest.max(T::zero()))
}

/// The elimination of one symmetric block alone (upper triangle, in place):
/// `smallest` takes its pivots; false when it does not certify.
#[inline(always)]
pub(crate) fn certify_block<T: Scalar, const K: usize>(
    c: &mut SMatrix<T, K, K>,
    tol: T,
    smallest: &mut T,
) -> bool {
    eliminate(c, K, K, false, tol, smallest)
}
