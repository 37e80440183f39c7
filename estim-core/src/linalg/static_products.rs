//! Static products as plain loops, inlined into the caller: A B, A B', and A L for a
//! lower-triangular L.
//!
//! **What they compute.** The textbook products, each entry the sum over k in
//! increasing order with a separately rounded multiply and add, in column (axpy)
//! order: column j of the product accumulates column k of A times one entry of the
//! second factor, which vectorises and carries no long dependency chain.
//!
//! **Why by hand.** nalgebra's product is an out-of-line call, which dominates at the
//! sizes of a measurement update; these loops are inlined and unrolled for the
//! static sizes. The dense products of 8 or more states go through
//! [`super::fused_product`] instead, where the CPU allows.
//!
//! **Failure.** None (IEEE arithmetic: NaN and infinities propagate).

use nalgebra::SMatrix;

use crate::scalar::Scalar;

/// A B' for static sizes as plain loops (see [`mul_static`]).
#[inline(always)]
pub(crate) fn mul_transpose_static<T: Scalar, const R: usize, const K: usize, const C: usize>(
    a: &SMatrix<T, R, K>,
    b: &SMatrix<T, C, K>,
) -> SMatrix<T, R, C> {
    let mut out = SMatrix::<T, R, C>::zeros();
    for j in 0..C {
        for k in 0..K {
            let bjk = b[(j, k)];
            for i in 0..R {
                out[(i, j)] += a[(i, k)] * bjk;
            }
        }
    }
    out
}

/// A L for a lower-triangular L (static sizes, plain loops): column j of the product
/// only reads rows k >= j of L. Equal bit for bit to [`mul_static`] on the same
/// arguments (the skipped terms a * 0 come first, while each sum is still +0).
/// Written into `out`, which must be zero.
#[inline(always)]
pub(crate) fn mul_lower_into<T: Scalar, const R: usize, const K: usize>(
    a: &SMatrix<T, R, K>,
    lower: &SMatrix<T, K, K>,
    out: &mut SMatrix<T, R, K>,
) {
    for j in 0..K {
        for k in j..K {
            let lkj = lower[(k, j)];
            for i in 0..R {
                out[(i, j)] += a[(i, k)] * lkj;
            }
        }
    }
}

/// A B for static sizes as plain loops, inlined into the caller (nalgebra's product
/// is an out-of-line call, which dominates at the sizes of a measurement update).
#[inline(always)]
pub(crate) fn mul_static<T: Scalar, const R: usize, const K: usize, const C: usize>(
    a: &SMatrix<T, R, K>,
    b: &SMatrix<T, K, C>,
) -> SMatrix<T, R, C> {
    let mut out = SMatrix::<T, R, C>::zeros();
    for j in 0..C {
        for k in 0..K {
            let bkj = b[(k, j)];
            for i in 0..R {
                out[(i, j)] += a[(i, k)] * bkj;
            }
        }
    }
    out
}
