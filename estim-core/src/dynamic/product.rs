//! The dense product of the run-time-sized filter, C <- alpha A B + beta C on
//! column-major buffers, allocating nothing.
//!
//! Why not nalgebra's `gemm`: for sizes above 5 it calls matrixmultiply, which
//! allocates its packing buffers on every call, and the run-time-sized filter promises
//! no allocation per step. This kernel is register-blocked without packing: a block of
//! `MR` rows by 4 columns of C stays in registers while the shared dimension is
//! walked, reading MR contiguous entries of a column of A and 4 entries of a row of B
//! per step. A strip of A (MR x k) stays in L1 across the column blocks; B streams
//! from L2. Three builds of one body, chosen through the crate's one dispatch
//! (`crate::linalg::dispatch`, `ESTIM_FORCE_PORTABLE=1` forces the first): portable
//! (MR = 8), AVX2 (MR = 8, 4 lanes, separate multiply and add, as the linear
//! runner's build) and AVX-512F (MR = 16, 8 lanes with fused multiply-adds: the same
//! values to round-off).

use nalgebra::DMatrix;

/// A column-major matrix operand: `data[i + j * rows]` is entry (i, j).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Operand<'a> {
    pub(crate) data: &'a [f64],
    pub(crate) rows: usize,
    pub(crate) cols: usize,
}

impl<'a> Operand<'a> {
    /// A slice holding a rows x cols column-major matrix.
    pub(crate) fn new(data: &'a [f64], rows: usize, cols: usize) -> Self {
        assert_eq!(data.len(), rows * cols, "operand buffer size");
        Self { data, rows, cols }
    }
}

impl<'a> From<&'a DMatrix<f64>> for Operand<'a> {
    fn from(m: &'a DMatrix<f64>) -> Self {
        Self {
            data: m.as_slice(),
            rows: m.nrows(),
            cols: m.ncols(),
        }
    }
}

/// C <- alpha A B + beta C (beta = 0: C is only written, never read).
///
/// # Panics
/// When the shapes do not agree (a bug of the caller: every caller sizes its buffers
/// from the filter's dimensions).
pub(crate) fn gemm<'a, 'b>(
    c: &mut DMatrix<f64>,
    alpha: f64,
    a: impl Into<Operand<'a>>,
    b: impl Into<Operand<'b>>,
    beta: f64,
) {
    let (a, b) = (a.into(), b.into());
    assert!(
        a.cols == b.rows && c.nrows() == a.rows && c.ncols() == b.cols,
        "gemm shapes: ({}x{}) ({}x{}) into ({}x{})",
        a.rows,
        a.cols,
        b.rows,
        b.cols,
        c.nrows(),
        c.ncols()
    );
    let (m, n) = (c.nrows(), c.ncols());
    let c = c.as_mut_slice();
    #[cfg(target_arch = "x86_64")]
    {
        if crate::linalg::dispatch::avx512f() {
            // SAFETY: the dispatch checked that the CPU has AVX-512F.
            unsafe { gemm_avx512(c, m, n, alpha, a, b, beta) };
            return;
        }
        if crate::linalg::dispatch::avx2() {
            // SAFETY: the dispatch checked that the CPU has AVX2.
            unsafe { gemm_avx2(c, m, n, alpha, a, b, beta) };
            return;
        }
    }
    body::<8>(c, m, n, alpha, a, b, beta);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn gemm_avx512(c: &mut [f64], m: usize, n: usize, alpha: f64, a: Operand, b: Operand, beta: f64) {
    body::<16>(c, m, n, alpha, a, b, beta);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn gemm_avx2(c: &mut [f64], m: usize, n: usize, alpha: f64, a: Operand, b: Operand, beta: f64) {
    body::<8>(c, m, n, alpha, a, b, beta);
}

/// The blocked loops (module docs). Full row blocks take the fixed-size path that
/// the compiler vectorizes; the last partial block of rows and of columns pads with
/// zeros and stores only the valid entries.
#[inline(always)]
fn body<const MR: usize>(
    c: &mut [f64],
    m: usize,
    n: usize,
    alpha: f64,
    a: Operand,
    b: Operand,
    beta: f64,
) {
    let k = a.cols;
    let (ad, bd) = (a.data, b.data);
    let mut i0 = 0;
    while i0 < m {
        let rows = (m - i0).min(MR);
        let mut j0 = 0;
        while j0 < n {
            let cols = (n - j0).min(4);
            let mut acc = [[0.0f64; MR]; 4];
            // Column offsets of B's 4 columns (a missing column repeats the last one:
            // computed, never stored).
            let boff: [usize; 4] = std::array::from_fn(|jj| (j0 + jj.min(cols - 1)) * k);
            if rows == MR {
                for p in 0..k {
                    let column = &ad[p * m + i0..p * m + i0 + MR];
                    let bv: [f64; 4] = std::array::from_fn(|jj| bd[boff[jj] + p]);
                    for jj in 0..4 {
                        for r in 0..MR {
                            acc[jj][r] += column[r] * bv[jj];
                        }
                    }
                }
            } else {
                for p in 0..k {
                    let base = p * m + i0;
                    let column: [f64; MR] =
                        std::array::from_fn(|r| if r < rows { ad[base + r] } else { 0.0 });
                    let bv: [f64; 4] = std::array::from_fn(|jj| bd[boff[jj] + p]);
                    for jj in 0..4 {
                        for r in 0..MR {
                            acc[jj][r] += column[r] * bv[jj];
                        }
                    }
                }
            }
            for (jj, block) in acc.iter().enumerate().take(cols) {
                let out = &mut c[(j0 + jj) * m + i0..(j0 + jj) * m + i0 + rows];
                if beta == 0.0 {
                    for (o, v) in out.iter_mut().zip(block) {
                        *o = alpha * v;
                    }
                } else {
                    for (o, v) in out.iter_mut().zip(block) {
                        *o = alpha * v + beta * *o;
                    }
                }
            }
            j0 += 4;
        }
        i0 += MR;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::dispatch::{with_features, Features};
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Every build equals a naive triple loop (to round-off: the fused build rounds
    /// once per multiply-add) at sizes around the block edges, with beta 0 and not.
    #[test]
    fn every_build_equals_the_naive_product() {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let builds = [
            Features::PORTABLE,
            Features {
                avx2: true,
                avx512f: false,
            },
            crate::linalg::dispatch::cpu(),
        ];
        for (m, k, n) in [
            (1, 1, 1),
            (3, 5, 2),
            (8, 8, 4),
            (9, 17, 5),
            (16, 3, 33),
            (40, 21, 23),
        ] {
            let a = DMatrix::from_fn(m, k, |_, _| rng.random_range(-1.0..1.0));
            let b = DMatrix::from_fn(k, n, |_, _| rng.random_range(-1.0..1.0));
            let c0 = DMatrix::from_fn(m, n, |_, _| rng.random_range(-1.0..1.0));
            for (alpha, beta) in [(1.0, 0.0), (-0.5, 1.0), (2.0, -1.5)] {
                let naive = DMatrix::from_fn(m, n, |i, j| {
                    alpha * (0..k).map(|p| a[(i, p)] * b[(p, j)]).sum::<f64>() + beta * c0[(i, j)]
                });
                for features in builds {
                    if features.avx2 && !crate::linalg::dispatch::cpu().avx2 {
                        continue;
                    }
                    let mut c = if beta == 0.0 {
                        DMatrix::from_element(m, n, f64::NAN)
                    } else {
                        c0.clone()
                    };
                    with_features(features, || gemm(&mut c, alpha, &a, &b, beta));
                    let err = (&c - &naive).amax();
                    assert!(
                        err <= 1e-14 * k as f64,
                        "({m},{k},{n}) {features:?}: {err:e}"
                    );
                }
            }
        }
    }
}
