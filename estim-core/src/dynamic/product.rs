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
    product(c, alpha, (a.into(), Triangle::Full), b.into(), beta, false);
}

/// [`gemm`] where only the upper triangle of C is wanted (a symmetric result, or a
/// term of one, mirrored by the caller): the blocks wholly below the diagonal are
/// skipped (about half the work of a square product), so entries below the diagonal
/// are left unspecified.
///
/// # Panics
/// As [`gemm`].
pub(crate) fn gemm_upper<'a, 'b>(
    c: &mut DMatrix<f64>,
    alpha: f64,
    a: impl Into<Operand<'a>>,
    b: impl Into<Operand<'b>>,
    beta: f64,
) {
    product(c, alpha, (a.into(), Triangle::Full), b.into(), beta, true);
}

/// The structure of A in [`gemm_triangular`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Triangle {
    /// Any A.
    Full,
    /// A_ip = 0 for p > i.
    Lower,
    /// A_ip = 0 for p < i.
    Upper,
}

/// [`gemm`] with a triangular A: each block of rows walks only the part of the shared
/// dimension where A is not zero (half the work of a square product). A's entries on
/// the zero side are not read.
///
/// # Panics
/// As [`gemm`].
pub(crate) fn gemm_triangular<'a, 'b>(
    c: &mut DMatrix<f64>,
    alpha: f64,
    a: impl Into<Operand<'a>>,
    shape: Triangle,
    b: impl Into<Operand<'b>>,
    beta: f64,
) {
    product(c, alpha, (a.into(), shape), b.into(), beta, false);
}

fn product(
    c: &mut DMatrix<f64>,
    alpha: f64,
    (a, shape): (Operand, Triangle),
    b: Operand,
    beta: f64,
    upper: bool,
) {
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
            unsafe { gemm_avx512(c, (m, n, upper, shape), alpha, a, b, beta) };
            return;
        }
        if crate::linalg::dispatch::avx2() {
            // SAFETY: the dispatch checked that the CPU has AVX2.
            unsafe { gemm_avx2(c, (m, n, upper, shape), alpha, a, b, beta) };
            return;
        }
    }
    body::<8>(
        c,
        (m, n, upper, shape),
        alpha,
        a,
        b,
        beta,
        |ad, i0, bcols| block_portable::<8>(ad, m, i0, bcols),
    );
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn gemm_avx512(
    c: &mut [f64],
    (m, n, upper, shape): (usize, usize, bool, Triangle),
    alpha: f64,
    a: Operand,
    b: Operand,
    beta: f64,
) {
    body::<16>(
        c,
        (m, n, upper, shape),
        alpha,
        a,
        b,
        beta,
        |ad, i0, bcols| {
            // A closure inherits its function's target features: safe to call here.
            block_avx512(ad, m, i0, bcols)
        },
    );
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn gemm_avx2(
    c: &mut [f64],
    (m, n, upper, shape): (usize, usize, bool, Triangle),
    alpha: f64,
    a: Operand,
    b: Operand,
    beta: f64,
) {
    body::<8>(
        c,
        (m, n, upper, shape),
        alpha,
        a,
        b,
        beta,
        |ad, i0, bcols| {
            // A closure inherits its function's target features: safe to call here.
            block_avx2(ad, m, i0, bcols)
        },
    );
}

/// A full 16 x 4 block of A B: two 8-lane columns of A times 4 broadcast entries of
/// B per step of the shared dimension, fused multiply-adds, 8 accumulators.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn block_avx512(ad: &[f64], m: usize, i0: usize, bcols: [&[f64]; 4]) -> [[f64; 16]; 4] {
    use std::arch::x86_64::{
        _mm512_fmadd_pd, _mm512_loadu_pd, _mm512_set1_pd, _mm512_setzero_pd, _mm512_storeu_pd,
    };
    let mut acc = [_mm512_setzero_pd(); 8];
    for (p, (((x0, x1), x2), x3)) in bcols[0]
        .iter()
        .zip(bcols[1])
        .zip(bcols[2])
        .zip(bcols[3])
        .enumerate()
    {
        let column = &ad[p * m + i0..p * m + i0 + 16];
        // SAFETY: `column` holds 16 entries: two 8-lane unaligned loads inside it.
        let (a0, a1) = unsafe {
            (
                _mm512_loadu_pd(column.as_ptr()),
                _mm512_loadu_pd(column.as_ptr().add(8)),
            )
        };
        for (jj, x) in [*x0, *x1, *x2, *x3].into_iter().enumerate() {
            let x = _mm512_set1_pd(x);
            acc[2 * jj] = _mm512_fmadd_pd(a0, x, acc[2 * jj]);
            acc[2 * jj + 1] = _mm512_fmadd_pd(a1, x, acc[2 * jj + 1]);
        }
    }
    let mut out = [[0.0; 16]; 4];
    for (jj, block) in out.iter_mut().enumerate() {
        // SAFETY: `block` holds 16 entries: two 8-lane unaligned stores inside it.
        unsafe {
            _mm512_storeu_pd(block.as_mut_ptr(), acc[2 * jj]);
            _mm512_storeu_pd(block.as_mut_ptr().add(8), acc[2 * jj + 1]);
        }
    }
    out
}

/// A full 8 x 4 block of A B: two 4-lane columns of A times 4 broadcast entries of B
/// per step, separate multiply and add (as the linear runner's AVX2 build).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn block_avx2(ad: &[f64], m: usize, i0: usize, bcols: [&[f64]; 4]) -> [[f64; 8]; 4] {
    use std::arch::x86_64::{
        _mm256_add_pd, _mm256_loadu_pd, _mm256_mul_pd, _mm256_set1_pd, _mm256_setzero_pd,
        _mm256_storeu_pd,
    };
    let mut acc = [_mm256_setzero_pd(); 8];
    for (p, (((x0, x1), x2), x3)) in bcols[0]
        .iter()
        .zip(bcols[1])
        .zip(bcols[2])
        .zip(bcols[3])
        .enumerate()
    {
        let column = &ad[p * m + i0..p * m + i0 + 8];
        // SAFETY: `column` holds 8 entries: two 4-lane unaligned loads inside it.
        let (a0, a1) = unsafe {
            (
                _mm256_loadu_pd(column.as_ptr()),
                _mm256_loadu_pd(column.as_ptr().add(4)),
            )
        };
        for (jj, x) in [*x0, *x1, *x2, *x3].into_iter().enumerate() {
            let x = _mm256_set1_pd(x);
            acc[2 * jj] = _mm256_add_pd(acc[2 * jj], _mm256_mul_pd(a0, x));
            acc[2 * jj + 1] = _mm256_add_pd(acc[2 * jj + 1], _mm256_mul_pd(a1, x));
        }
    }
    let mut out = [[0.0; 8]; 4];
    for (jj, block) in out.iter_mut().enumerate() {
        // SAFETY: `block` holds 8 entries: two 4-lane unaligned stores inside it.
        unsafe {
            _mm256_storeu_pd(block.as_mut_ptr(), acc[2 * jj]);
            _mm256_storeu_pd(block.as_mut_ptr().add(4), acc[2 * jj + 1]);
        }
    }
    out
}

/// The portable full block: the same sums in plain loops.
fn block_portable<const MR: usize>(
    ad: &[f64],
    m: usize,
    i0: usize,
    bcols: [&[f64]; 4],
) -> [[f64; MR]; 4] {
    let mut acc = [[0.0f64; MR]; 4];
    for p in 0..bcols[0].len() {
        let column = &ad[p * m + i0..p * m + i0 + MR];
        for (jj, block) in acc.iter_mut().enumerate() {
            let x = bcols[jj][p];
            for (v, a) in block.iter_mut().zip(column) {
                *v += a * x;
            }
        }
    }
    acc
}

/// Below this many multiply-adds (a 16-cube) the blocking costs more than it saves:
/// plain column (axpy) loops instead.
const SMALL: usize = 4096;

/// C <- alpha A B + beta C as column axpys: column j of C gets column p of A times
/// alpha B_pj, no index and no bounds check in the loops.
#[inline(always)]
fn small(c: &mut [f64], m: usize, alpha: f64, ad: &[f64], bd: &[f64], k: usize, beta: f64) {
    if m == 0 {
        return;
    }
    if k == 0 {
        c.iter_mut()
            .for_each(|v| *v = if beta == 0.0 { 0.0 } else { beta * *v });
        return;
    }
    for (cj, bj) in c.chunks_exact_mut(m).zip(bd.chunks_exact(k)) {
        if beta == 0.0 {
            cj.fill(0.0);
        } else if beta != 1.0 {
            cj.iter_mut().for_each(|v| *v *= beta);
        }
        for (ap, &x) in ad.chunks_exact(m).zip(bj) {
            let s = alpha * x;
            for (v, a) in cj.iter_mut().zip(ap) {
                *v += a * s;
            }
        }
    }
}

/// The blocked loops (module docs): full MR x 4 blocks through `full` (the build's
/// kernel), the last partial block of rows or columns through plain loops that pad
/// with zeros and store only the valid entries.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn body<const MR: usize>(
    c: &mut [f64],
    (m, n, upper, shape): (usize, usize, bool, Triangle),
    alpha: f64,
    a: Operand,
    b: Operand,
    beta: f64,
    full: impl Fn(&[f64], usize, [&[f64]; 4]) -> [[f64; MR]; 4],
) {
    let k = a.cols;
    let (ad, bd) = (a.data, b.data);
    if m * n * k <= SMALL {
        small(c, m, alpha, ad, bd, k, beta);
        return;
    }
    let mut i0 = 0;
    while i0 < m {
        let rows = (m - i0).min(MR);
        let mut j0 = 0;
        while j0 < n {
            if upper && j0 + 3 < i0 {
                j0 += 4; // wholly below the diagonal
                continue;
            }
            let cols = (n - j0).min(4);
            // The shared dimension's range where A's rows i0.. are not zero.
            let (p0, p1) = match shape {
                Triangle::Full => (0, k),
                Triangle::Lower => (0, (i0 + rows).min(k)),
                Triangle::Upper => (i0.min(k), k),
            };
            let ad = &ad[p0 * m..];
            // B's 4 columns over that range (a missing column repeats the last one:
            // computed, never stored).
            let bcols: [&[f64]; 4] = std::array::from_fn(|jj| {
                let start = (j0 + jj.min(cols - 1)) * k;
                &bd[start + p0..start + p1]
            });
            let acc = if rows == MR {
                full(ad, i0, bcols)
            } else {
                let mut acc = [[0.0f64; MR]; 4];
                for p in 0..p1 - p0 {
                    let column = &ad[p * m + i0..p * m + i0 + rows];
                    for (jj, block) in acc.iter_mut().enumerate() {
                        let x = bcols[jj][p];
                        for (v, a) in block.iter_mut().zip(column) {
                            *v += a * x;
                        }
                    }
                }
                acc
            };
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
    /// Timing against nalgebra's gemm (matrixmultiply); `--ignored --nocapture`.
    #[test]
    #[ignore]
    fn timing_against_nalgebra() {
        for n in [50, 200] {
            let a = DMatrix::from_fn(n, n, |i, j| ((i * 7 + j) as f64).sin());
            let b = DMatrix::from_fn(n, n, |i, j| ((i + 3 * j) as f64).cos());
            let mut c = DMatrix::zeros(n, n);
            let reps = 20_000_000 / (n * n * n) + 1;
            let t = std::time::Instant::now();
            for _ in 0..reps {
                gemm(&mut c, 1.0, &a, &b, 0.0);
            }
            let ours = t.elapsed().as_secs_f64() / reps as f64;
            let t = std::time::Instant::now();
            for _ in 0..reps {
                c.gemm(1.0, &a, &b, 0.0);
            }
            let theirs = t.elapsed().as_secs_f64() / reps as f64;
            let gflops = |s: f64| 2.0 * (n * n * n) as f64 / s / 1e9;
            eprintln!(
                "n {n}: ours {:.1} GFLOP/s, nalgebra {:.1}",
                gflops(ours),
                gflops(theirs)
            );
        }
    }

    use super::*;
    use crate::linalg::dispatch::{with_features, Features};
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The upper-triangle product equals the full one on and above the diagonal, for
    /// every build, at sizes past the small-size switch with partial blocks.
    #[test]
    fn upper_product_equals_the_full_one_above_the_diagonal() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for (m, k) in [(20, 30), (37, 37), (64, 5)] {
            let a = DMatrix::from_fn(m, k, |_, _| rng.random_range(-1.0..1.0));
            let b = DMatrix::from_fn(k, m, |_, _| rng.random_range(-1.0..1.0));
            let c0 = DMatrix::from_fn(m, m, |_, _| rng.random_range(-1.0..1.0));
            for features in [Features::PORTABLE, crate::linalg::dispatch::cpu()] {
                let (mut full, mut upper) = (c0.clone(), c0.clone());
                with_features(features, || {
                    gemm(&mut full, -0.5, &a, &b, 1.0);
                    gemm_upper(&mut upper, -0.5, &a, &b, 1.0);
                });
                for j in 0..m {
                    for i in 0..=j {
                        assert_eq!(upper[(i, j)], full[(i, j)], "({m},{k}) {features:?}");
                    }
                }
            }
        }
    }

    /// The triangular products equal the full ones exactly (the skipped terms are
    /// exact zeros), every build, lower and upper A, partial blocks.
    #[test]
    fn triangular_products_equal_the_full_ones() {
        let mut rng = ChaCha8Rng::seed_from_u64(10);
        for (m, n) in [(20, 20), (37, 11), (64, 64)] {
            let b = DMatrix::from_fn(m, n, |_, _| rng.random_range(-1.0..1.0));
            let lower = DMatrix::from_fn(m, m, |i, p| {
                if p <= i {
                    rng.random_range(-1.0..1.0)
                } else {
                    0.0
                }
            });
            let upper = lower.transpose();
            for features in [Features::PORTABLE, crate::linalg::dispatch::cpu()] {
                for (a, shape) in [(&lower, Triangle::Lower), (&upper, Triangle::Upper)] {
                    let (mut full, mut tri) = (DMatrix::zeros(m, n), DMatrix::zeros(m, n));
                    with_features(features, || {
                        gemm(&mut full, 1.0, a, &b, 0.0);
                        gemm_triangular(&mut tri, 1.0, a, shape, &b, 0.0);
                    });
                    assert_eq!(tri, full, "({m},{n}) {shape:?} {features:?}");
                }
            }
        }
    }

    /// Every build equals a naive triple loop (to round-off: the fused build rounds
    /// once per multiply-add) at sizes around the block edges, on both sides of the
    /// small-size switch and with an empty shared dimension, with beta 0 and not.
    #[test]
    fn every_build_equals_the_naive_product() {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let builds = [
            Features::PORTABLE,
            Features {
                avx2: true,
                avx512f: false,
                fma: false,
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
