//! The fused product: the dense products of the runners' hot loops (F P F', Phi_acc,
//! the square-root update's Gram product) through a register-blocked AVX-512 loop
//! with fused multiply-adds, for `f64` (8 lanes) and `f32` (16 lanes) on CPUs that
//! have AVX-512F ([`super::dispatch::avx512f`]); everywhere else (other CPUs, small
//! products, `ESTIM_FORCE_PORTABLE=1`) the plain loops of [`mul_static`].
//!
//! **What it computes.** `out = start + A B` or `start + A X'` (`start` zero, `out`
//! itself, or another matrix), column-major static matrices.
//!
//! **Why by hand.** At the sizes of a filter (N = 8..30) the loops of `mul_static`,
//! even compiled for AVX-512, run at 12-15 multiply-adds per ns on the Zen 5 machine
//! the benches run on, and the crates that do products well (matrixmultiply, gemm)
//! pack their operands, which costs more than the product at these sizes (14 and 11
//! per ns at N = 15, measured in the same session). The loop keeps a panel of up to
//! 24 rows by 4 columns of the product in 24 registers and streams A's columns
//! through them: 28 per ns at N = 15, 35 at N = 30 (F P F' + Q 566 -> 241 ns at
//! N = 15).
//!
//! **Results.** Each entry is the sum over k in increasing order, as in `mul_static`,
//! but with every multiply-add rounded once (fused) instead of twice; so the two
//! paths differ by round-off, within the error bound of a product (Higham,
//! *Accuracy and Stability of Numerical Algorithms*, 2nd ed., eq. 3.5; tested below
//! against a separately coded product, and against the portable path). A A'
//! computed here is exactly symmetric: entry (i, j) and (j, i) run the same fused
//! operations on the same products (a b = b a exactly).
//!
//! **Failure.** None: every function either runs the fused loop or the portable one;
//! the `*_into` functions that report which (`gram_pair_into`) leave `out` untouched
//! when they do not run.

use nalgebra::SMatrix;

use super::static_products::{mul_static, mul_transpose_static};
use crate::scalar::Scalar;

/// Products with fewer multiply-adds than this use `mul_static`: the fused loop's masked
/// panels do not pay below about N = 8 (F P F' + Q at N = 6: 41 ns by the fused loop, 29
/// ns by the loops; N = 8: 48 against 100 ns).
const FUSED_MIN_WORK: usize = 512;

/// What the product is added to.
#[derive(Clone, Copy, Debug)]
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
enum Start<'a, T> {
    /// Nothing: `out` = A B.
    Zero,
    /// `out` itself: `out` += A B.
    Out,
    /// Another matrix of `out`'s shape: `out` = C + A B.
    Matrix(&'a [T]),
}

/// How the second factor is read.
#[derive(Clone, Copy, Debug)]
enum Second {
    /// B itself (column-major K x C).
    Plain,
    /// X' for a column-major C x K matrix X.
    Transposed,
}

/// A B.
#[inline(always)]
pub(crate) fn product<T: Scalar, const R: usize, const K: usize, const C: usize>(
    a: &SMatrix<T, R, K>,
    b: &SMatrix<T, K, C>,
) -> SMatrix<T, R, C> {
    let mut out = SMatrix::<T, R, C>::zeros();
    product_into(a, b, &mut out);
    out
}

/// `out` = A B (every entry written; no zeroing first when the fused loop runs).
#[inline(always)]
pub(crate) fn product_into<T: Scalar, const R: usize, const K: usize, const C: usize>(
    a: &SMatrix<T, R, K>,
    b: &SMatrix<T, K, C>,
    out: &mut SMatrix<T, R, C>,
) {
    if !fused(
        out.as_mut_slice(),
        a.as_slice(),
        b.as_slice(),
        (R, K, C),
        Second::Plain,
        Start::Zero,
    ) {
        *out = mul_static(a, b);
    }
}

/// `out` = A X' (X is C x K; every entry written, as [`product_into`]).
#[inline(always)]
pub(crate) fn product_transposed_into<T: Scalar, const R: usize, const K: usize, const C: usize>(
    a: &SMatrix<T, R, K>,
    x: &SMatrix<T, C, K>,
    out: &mut SMatrix<T, R, C>,
) {
    if !fused(
        out.as_mut_slice(),
        a.as_slice(),
        x.as_slice(),
        (R, K, C),
        Second::Transposed,
        Start::Zero,
    ) {
        *out = mul_transpose_static(a, x);
    }
}

/// A X' (X is C x K).
#[inline(always)]
pub(crate) fn product_transposed<T: Scalar, const R: usize, const K: usize, const C: usize>(
    a: &SMatrix<T, R, K>,
    x: &SMatrix<T, C, K>,
) -> SMatrix<T, R, C> {
    let mut out = SMatrix::<T, R, C>::zeros();
    product_transposed_into(a, x, &mut out);
    out
}

/// C - A B.
#[cfg(test)]
pub(crate) fn minus_product<T: Scalar, const R: usize, const K: usize, const C: usize>(
    c: &SMatrix<T, R, C>,
    a: &SMatrix<T, R, K>,
    b: &SMatrix<T, K, C>,
) -> SMatrix<T, R, C> {
    let mut out = SMatrix::<T, R, C>::zeros();
    minus_product_into(c, a, b, &mut out);
    out
}

/// `out` = C - A B (every entry written; no zeroing first when the fused loop runs).
#[inline(always)]
pub(crate) fn minus_product_into<T: Scalar, const R: usize, const K: usize, const C: usize>(
    c: &SMatrix<T, R, C>,
    a: &SMatrix<T, R, K>,
    b: &SMatrix<T, K, C>,
    out: &mut SMatrix<T, R, C>,
) {
    let negated = -a;
    if !fused(
        out.as_mut_slice(),
        negated.as_slice(),
        b.as_slice(),
        (R, K, C),
        Second::Plain,
        Start::Matrix(c.as_slice()),
    ) {
        *out = c - mul_static(a, b);
    }
}

/// `out` = A A' + B B' (A is N x K, B is N x L), exactly symmetric, when the fused loop
/// runs (f64 or f32, AVX-512F, large enough); false, with `out` untouched, otherwise (the
/// caller's own loops then).
#[inline(always)]
pub(crate) fn gram_pair_into<T: Scalar, const N: usize, const K: usize, const L: usize>(
    a: &SMatrix<T, N, K>,
    b: &SMatrix<T, N, L>,
    out: &mut SMatrix<T, N, N>,
) -> bool {
    if N * (K + L) * N < FUSED_MIN_WORK
        || !fused_any_size(
            out.as_mut_slice(),
            a.as_slice(),
            a.as_slice(),
            (N, K, N),
            Second::Transposed,
            Start::Zero,
        )
    {
        return false;
    }
    // The first call ran the fused loop, so this one does too (same scalar, same CPU).
    L == 0
        || fused_any_size(
            out.as_mut_slice(),
            b.as_slice(),
            b.as_slice(),
            (N, L, N),
            Second::Transposed,
            Start::Out,
        )
}

/// Whether the fused loop runs (for `f64` and `f32`): the CPU has AVX-512F and the
/// portable path is not forced ([`super::dispatch`]).
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
#[inline(always)]
pub(crate) fn available() -> bool {
    cfg!(target_arch = "x86_64") && super::dispatch::avx512f()
}

/// `out` (R x C) = `start` + A B through the fused loop when it applies
/// (f64 or f32, the CPU, at least [`FUSED_MIN_WORK`]); false (nothing written) when
/// not.
#[inline(always)]
fn fused<T: Scalar>(
    out: &mut [T],
    a: &[T],
    b: &[T],
    (r, k, c): (usize, usize, usize),
    second: Second,
    start: Start<'_, T>,
) -> bool {
    r * k * c >= FUSED_MIN_WORK && fused_any_size(out, a, b, (r, k, c), second, start)
}

/// The fused loop on slices of `T` read as `E`, when `T` is `E`; false (nothing
/// written) when it is not.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn run_as<T: Scalar, E: avx512::Lanes>(
    out: &mut [T],
    a: &[T],
    b: &[T],
    dims: (usize, usize, usize),
    strides: (usize, usize),
    start: Start<'_, T>,
) -> bool {
    use std::any::TypeId;
    if TypeId::of::<T>() != TypeId::of::<E>() {
        return false;
    }
    // SAFETY: T is E (checked above), so the memory holds E values of the same lengths.
    let cast = |s: &[T]| unsafe { std::slice::from_raw_parts(s.as_ptr().cast::<E>(), s.len()) };
    // SAFETY: as above; `out` is borrowed mutably for the lifetime of the cast.
    let out = unsafe { std::slice::from_raw_parts_mut(out.as_mut_ptr().cast::<E>(), out.len()) };
    let start = match start {
        Start::Zero => avx512::Start::Zero,
        Start::Out => avx512::Start::Out,
        Start::Matrix(initial) => avx512::Start::Matrix(cast(initial)),
    };
    avx512::product(out, cast(a), cast(b), dims, strides, start);
    true
}

/// [`fused`] whatever the size.
#[inline(always)]
fn fused_any_size<T: Scalar>(
    out: &mut [T],
    a: &[T],
    b: &[T],
    (r, k, c): (usize, usize, usize),
    second: Second,
    start: Start<'_, T>,
) -> bool {
    if r * c == 0 {
        return false;
    }
    #[cfg(target_arch = "x86_64")]
    {
        let strides = match second {
            Second::Plain => (1, k),
            Second::Transposed => (c, 1),
        };
        if available()
            && (run_as::<T, f64>(out, a, b, (r, k, c), strides, start)
                || run_as::<T, f32>(out, a, b, (r, k, c), strides, start))
        {
            return true;
        }
    }
    // Other architectures and scalars: the callers' loops (the arguments are used above
    // only).
    let _ = (out, a, b, k, second, start);
    false
}

#[cfg(target_arch = "x86_64")]
mod avx512 {
    use std::arch::x86_64::{
        __m512, __m512d, __mmask16, __mmask8, _mm512_fmadd_pd, _mm512_fmadd_ps,
        _mm512_mask_storeu_pd, _mm512_mask_storeu_ps, _mm512_maskz_loadu_pd, _mm512_maskz_loadu_ps,
        _mm512_set1_pd, _mm512_set1_ps, _mm512_setzero_pd, _mm512_setzero_ps,
    };

    /// Proof that the CPU itself has AVX-512F (its FMA is part of AVX-512F), whatever
    /// the dispatch decided. Made only by [`Avx512::detect`], so holding one is the
    /// safety argument of every intrinsic [`Lanes`] calls.
    #[derive(Clone, Copy)]
    pub(super) struct Avx512(());

    impl Avx512 {
        /// The proof, if the CPU has AVX-512F.
        #[inline(always)]
        fn detect() -> Option<Self> {
            std::arch::is_x86_feature_detected!("avx512f").then_some(Self(()))
        }
    }

    /// A scalar with its 512-bit register: 8 f64 or 16 f32 lanes. The methods are
    /// AVX-512F intrinsics, only called (inlined) inside `product_avx512`, which is
    /// compiled for AVX-512F; the [`Avx512`] they take proves the CPU has it. Loads
    /// and stores take slices and touch the first `min(len, LANES)` lanes only (the
    /// others masked off), so they stay inside them.
    pub(super) trait Lanes: Copy + 'static {
        type Vector: Copy;
        const LANES: usize;
        /// All lanes zero.
        fn zero(cpu: Avx512) -> Self::Vector;
        /// The first `min(from.len(), LANES)` lanes read from `from`, the others zero.
        fn load(cpu: Avx512, from: &[Self]) -> Self::Vector;
        /// `value` in every lane.
        fn splat(cpu: Avx512, value: Self) -> Self::Vector;
        /// a b + c, rounded once per lane.
        fn multiply_add(
            cpu: Avx512,
            a: Self::Vector,
            b: Self::Vector,
            c: Self::Vector,
        ) -> Self::Vector;
        /// The first `min(to.len(), LANES)` lanes of `value` written to `to`, the rest
        /// of `to` untouched.
        fn store(cpu: Avx512, to: &mut [Self], value: Self::Vector);
    }

    /// The mask of the first `n` of 8 lanes (all for `n >= 8`).
    #[inline(always)]
    fn mask8(n: usize) -> __mmask8 {
        if n >= 8 {
            0xff
        } else {
            ((1u16 << n) - 1) as __mmask8
        }
    }

    /// The mask of the first `n` of 16 lanes (all for `n >= 16`).
    #[inline(always)]
    fn mask16(n: usize) -> __mmask16 {
        if n >= 16 {
            0xffff
        } else {
            ((1u32 << n) - 1) as __mmask16
        }
    }

    impl Lanes for f64 {
        type Vector = __m512d;
        const LANES: usize = 8;
        #[inline(always)]
        fn zero(_: Avx512) -> __m512d {
            // SAFETY: the CPU has AVX-512F (the token proves it).
            unsafe { _mm512_setzero_pd() }
        }
        #[inline(always)]
        fn load(_: Avx512, from: &[f64]) -> __m512d {
            // SAFETY: the CPU has AVX-512F (the token proves it); the mask selects the
            // first min(len, 8) lanes, all inside `from` (masked-off lanes are not read).
            unsafe { _mm512_maskz_loadu_pd(mask8(from.len()), from.as_ptr()) }
        }
        #[inline(always)]
        fn splat(_: Avx512, value: f64) -> __m512d {
            // SAFETY: the CPU has AVX-512F (the token proves it).
            unsafe { _mm512_set1_pd(value) }
        }
        #[inline(always)]
        fn multiply_add(_: Avx512, a: __m512d, b: __m512d, c: __m512d) -> __m512d {
            // SAFETY: the CPU has AVX-512F (the token proves it).
            unsafe { _mm512_fmadd_pd(a, b, c) }
        }
        #[inline(always)]
        fn store(_: Avx512, to: &mut [f64], value: __m512d) {
            // SAFETY: the CPU has AVX-512F (the token proves it); the mask selects the
            // first min(len, 8) lanes, all inside `to` (masked-off lanes are not written).
            unsafe { _mm512_mask_storeu_pd(to.as_mut_ptr(), mask8(to.len()), value) }
        }
    }

    impl Lanes for f32 {
        type Vector = __m512;
        const LANES: usize = 16;
        #[inline(always)]
        fn zero(_: Avx512) -> __m512 {
            // SAFETY: the CPU has AVX-512F (the token proves it).
            unsafe { _mm512_setzero_ps() }
        }
        #[inline(always)]
        fn load(_: Avx512, from: &[f32]) -> __m512 {
            // SAFETY: the CPU has AVX-512F (the token proves it); the mask selects the
            // first min(len, 16) lanes, all inside `from` (masked-off lanes are not read).
            unsafe { _mm512_maskz_loadu_ps(mask16(from.len()), from.as_ptr()) }
        }
        #[inline(always)]
        fn splat(_: Avx512, value: f32) -> __m512 {
            // SAFETY: the CPU has AVX-512F (the token proves it).
            unsafe { _mm512_set1_ps(value) }
        }
        #[inline(always)]
        fn multiply_add(_: Avx512, a: __m512, b: __m512, c: __m512) -> __m512 {
            // SAFETY: the CPU has AVX-512F (the token proves it).
            unsafe { _mm512_fmadd_ps(a, b, c) }
        }
        #[inline(always)]
        fn store(_: Avx512, to: &mut [f32], value: __m512) {
            // SAFETY: the CPU has AVX-512F (the token proves it); the mask selects the
            // first min(len, 16) lanes, all inside `to` (masked-off lanes are not
            // written).
            unsafe { _mm512_mask_storeu_ps(to.as_mut_ptr(), mask16(to.len()), value) }
        }
    }

    /// What the product is added to (as the outer `Start`, for one scalar).
    #[derive(Clone, Copy)]
    pub(super) enum Start<'a, E> {
        Zero,
        Out,
        Matrix(&'a [E]),
    }

    /// `out` (column-major r x c) = `start` + A B, A column-major r x k,
    /// B(kk, j) = b[kk * strides.0 + j * strides.1].
    ///
    /// # Panics
    /// If the CPU lacks AVX-512F (the callers asked the dispatch first), or a slice is
    /// shorter than the sizes say (never for the callers' static sizes).
    pub(super) fn product<E: Lanes>(
        out: &mut [E],
        a: &[E],
        b: &[E],
        dims: (usize, usize, usize),
        strides: (usize, usize),
        start: Start<'_, E>,
    ) {
        let cpu = Avx512::detect().expect("the fused product runs on CPUs with AVX-512F");
        // SAFETY: the CPU has AVX-512F (detected on the line above).
        unsafe { product_avx512(cpu, out, a, b, dims, strides, start) }
    }

    /// The panels of [`product`], compiled for AVX-512F.
    ///
    /// # Panics
    /// As [`product`], for the slices' lengths.
    #[target_feature(enable = "avx512f")]
    fn product_avx512<E: Lanes>(
        cpu: Avx512,
        out: &mut [E],
        a: &[E],
        b: &[E],
        (r, k, c): (usize, usize, usize),
        strides: (usize, usize),
        start: Start<'_, E>,
    ) {
        // Every panel's reads and writes are inside the slices (the invariant of
        // `Panel`): the loop over k of `Panel::run` relies on it, unchecked (a bounds
        // check each costs about a fifth of the product's time at N = 15).
        let product_len = end(0, r, c, 0);
        assert!(out.len() >= product_len && a.len() >= end(0, r, k, 0));
        if k > 0 && c > 0 {
            assert!(b.len() >= end(end(0, c - 1, strides.1, 0), k - 1, strides.0, 1));
        }
        if let Start::Matrix(initial) = start {
            assert!(initial.len() >= product_len);
        }
        let lanes = E::LANES;
        let mut i0 = 0;
        while i0 < r {
            // Panels of one, two or three registers of rows; the rows past r are
            // masked off.
            let rows = (r - i0).min(3 * lanes);
            let mut j0 = 0;
            while j0 < c {
                let width = (c - j0).min(4);
                let job = Panel {
                    cpu,
                    k,
                    rows,
                    a,
                    a_first: i0,
                    lda: r,
                    b,
                    b_first: j0 * strides.1,
                    strides,
                    out: &mut *out,
                    out_first: i0 + j0 * r,
                    ldo: r,
                    start,
                };
                match (rows.div_ceil(lanes), width) {
                    (1, 1) => job.run::<1, 1>(),
                    (1, 2) => job.run::<1, 2>(),
                    (1, 3) => job.run::<1, 3>(),
                    (1, _) => job.run::<1, 4>(),
                    (2, 1) => job.run::<2, 1>(),
                    (2, 2) => job.run::<2, 2>(),
                    (2, 3) => job.run::<2, 3>(),
                    (2, _) => job.run::<2, 4>(),
                    (_, 1) => job.run::<3, 1>(),
                    (_, 2) => job.run::<3, 2>(),
                    (_, 3) => job.run::<3, 3>(),
                    (_, _) => job.run::<3, 4>(),
                }
                j0 += width;
            }
            i0 += rows;
        }
    }

    /// One panel of the product: `rows` rows from i0 (H registers of lanes) by W
    /// columns from j0. Entry (i, w) of the panel is `out[out_first + i + w * ldo]`,
    /// A(i0 + i, kk) is `a[a_first + i + kk * lda]`, B(kk, j0 + w) is
    /// `b[b_first + kk * strides.0 + w * strides.1]`, and the initial values (unless
    /// `Start::Zero`) are laid out as `out`.
    ///
    /// Invariant: built only by `product_avx512`, whose assertions put every one of
    /// these indices (i < rows, kk < k, w < W) inside its slice.
    struct Panel<'s, E: Lanes> {
        cpu: Avx512,
        k: usize,
        rows: usize,
        a: &'s [E],
        a_first: usize,
        lda: usize,
        b: &'s [E],
        b_first: usize,
        strides: (usize, usize),
        out: &'s mut [E],
        out_first: usize,
        ldo: usize,
        start: Start<'s, E>,
    }

    impl<E: Lanes> Panel<'_, E> {
        /// Inlined into `product_avx512`, whose AVX-512 code it becomes. Register h of
        /// a column holds its rows h lanes.. of the panel; the loads and stores take
        /// the column's slice from there on, so the lanes past `rows` are masked off.
        ///
        /// # Panics
        /// If the panel reaches past `out` or the start (never: see the invariant).
        #[inline(always)]
        fn run<const H: usize, const W: usize>(self) {
            let (cpu, lanes, rows, k) = (self.cpu, E::LANES, self.rows, self.k);
            let ((down, across), lda) = (self.strides, self.lda);
            // H registers hold `rows`, each at least one of them.
            debug_assert!(W >= 1 && lanes * (H - 1) < rows && rows <= lanes * H);
            // acc[w][h]: column w of the panel, rows h lanes.. (h + 1) lanes.
            let mut acc = [[E::zero(cpu); H]; W];
            let initial = match self.start {
                Start::Zero => None,
                Start::Out => Some(&*self.out),
                Start::Matrix(initial) => Some(initial),
            };
            if let Some(initial) = initial {
                for (w, column) in acc.iter_mut().enumerate() {
                    let first = self.out_first + w * self.ldo;
                    let from = &initial[first..first + rows];
                    for (h, vector) in column.iter_mut().enumerate() {
                        *vector = E::load(cpu, &from[lanes * h..]);
                    }
                }
            }
            for kk in 0..k {
                let first = self.a_first + kk * lda;
                // SAFETY: rows first.. of column kk < k of A, inside `a` by the
                // struct's invariant.
                let from = unsafe { self.a.get_unchecked(first..first + rows) };
                let mut av = [E::zero(cpu); H];
                for (h, vector) in av.iter_mut().enumerate() {
                    *vector = E::load(cpu, &from[lanes * h..]);
                }
                let row = self.b_first + kk * down;
                for (w, column) in acc.iter_mut().enumerate() {
                    // SAFETY: B(kk, j0 + w) for kk < k and w < W, inside `b` by the
                    // struct's invariant.
                    let bb = E::splat(cpu, unsafe { *self.b.get_unchecked(row + w * across) });
                    for (vector, a) in column.iter_mut().zip(&av) {
                        *vector = E::multiply_add(cpu, *a, bb, *vector);
                    }
                }
            }
            for (w, column) in acc.iter().enumerate() {
                let first = self.out_first + w * self.ldo;
                let to = &mut self.out[first..first + rows];
                for (h, vector) in column.iter().enumerate() {
                    E::store(cpu, &mut to[lanes * h..], *vector);
                }
            }
        }
    }

    /// `first + steps * stride + len`, the end of the last of `steps + 1` runs of `len`
    /// values `stride` apart.
    ///
    /// # Panics
    /// If it overflows.
    #[inline(always)]
    fn end(first: usize, steps: usize, stride: usize, len: usize) -> usize {
        steps
            .checked_mul(stride)
            .and_then(|n| n.checked_add(first))
            .and_then(|n| n.checked_add(len))
            .expect("the panel's indices fit in usize")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scalar::{lit, to_f64};
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The product entry by entry in the textbook order (in f64), with the error
    /// bound of a product computed in a scalar of unit round-off `eps`:
    /// k eps sum |a_il| |b_lj| (Higham, *Accuracy and Stability*, 2nd ed., eq. 3.5),
    /// doubled.
    fn reference(
        a: &[f64],
        b: impl Fn(usize, usize) -> f64,
        (r, k, c): (usize, usize, usize),
        eps: f64,
    ) -> (Vec<f64>, Vec<f64>) {
        let mut value = vec![0.0; r * c];
        let mut bound = vec![0.0; r * c];
        for j in 0..c {
            for i in 0..r {
                let (mut v, mut s) = (0.0, 0.0);
                for l in 0..k {
                    v += a[i + l * r] * b(l, j);
                    s += (a[i + l * r] * b(l, j)).abs();
                }
                value[i + j * r] = v;
                bound[i + j * r] = 2.0 * (k as f64 + 1.0) * eps * s;
            }
        }
        (value, bound)
    }

    /// Every row count 1..=50 (panels of one, two, three registers and a remainder:
    /// 8/16/24 rows in f64, 16/32/48 in f32), inner and column counts around the
    /// panel edges, both orientations, the three starts; the fused loop runs where the
    /// CPU has AVX-512F, otherwise the test checks the fallback's refusal. Inputs are
    /// drawn in `T`, the reference is computed in f64 from the same values.
    fn every_shape<T: Scalar>(seed: u64) {
        let eps = to_f64(T::default_epsilon());
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut draw = |n: usize| -> Vec<T> {
            (0..n)
                .map(|_| lit::<T>(rng.random_range(-1.0..1.0)))
                .collect()
        };
        let wide = |v: &[T]| -> Vec<f64> { v.iter().map(|&x| to_f64(x)).collect() };
        let mut ran_any = false;
        for r in 1..=50 {
            for (k, c) in [(1, 1), (3, 4), (9, 5), (17, 7), (30, 31), (24, 3)] {
                let (a, b, start) = (draw(r * k), draw(k * c), draw(r * c));
                let (a64, b64, start64) = (wide(&a), wide(&b), wide(&start));
                // 0: out = A B; 1: out += A B; 2: out = C + A B (C = `start`, out NaN).
                for (second, mode) in [
                    (Second::Plain, 0),
                    (Second::Transposed, 0),
                    (Second::Plain, 1),
                    (Second::Transposed, 2),
                ] {
                    let read = |l: usize, j: usize| match second {
                        Second::Plain => b64[l + j * k],
                        Second::Transposed => b64[j + l * c],
                    };
                    let (mut want, mut bound) = reference(&a64, read, (r, k, c), eps);
                    if mode > 0 {
                        for i in 0..r * c {
                            want[i] += start64[i];
                            bound[i] += 2.0 * eps * start64[i].abs();
                        }
                    }
                    let mut got = if mode == 1 {
                        start.clone()
                    } else {
                        vec![lit::<T>(f64::NAN); r * c]
                    };
                    // One more column of room: the fused loop must not write past r x c.
                    got.push(lit::<T>(7.0));
                    let from = match mode {
                        0 => Start::Zero,
                        1 => Start::Out,
                        _ => Start::Matrix(&start),
                    };
                    let ran = fused(&mut got, &a, &b, (r, k, c), second, from);
                    assert_eq!(to_f64(got[r * c]), 7.0, "wrote past the product");
                    if !ran {
                        assert!(r * k * c < FUSED_MIN_WORK || !available());
                        continue;
                    }
                    ran_any = true;
                    for i in 0..r * c {
                        let g = to_f64(got[i]);
                        assert!(
                            (g - want[i]).abs() <= bound[i],
                            "({r}, {k}, {c}) {second:?} mode {mode}: entry {i} {g} vs {}",
                            want[i]
                        );
                    }
                }
            }
        }
        assert!(ran_any || !available());
    }

    #[test]
    fn fused_products_equal_the_textbook_product_for_every_shape() {
        every_shape::<f64>(71);
        every_shape::<f32>(73);
    }

    #[test]
    fn static_products_and_the_gram_pair_match_the_plain_loops() {
        let mut rng = ChaCha8Rng::seed_from_u64(72);
        let a = SMatrix::<f64, 15, 15>::from_fn(|_, _| rng.random_range(-1.0..1.0));
        let x = SMatrix::<f64, 15, 15>::from_fn(|_, _| rng.random_range(-1.0..1.0));
        let b = SMatrix::<f64, 15, 3>::from_fn(|_, _| rng.random_range(-1.0..1.0));
        let tol = 1e-13;
        assert!((product(&a, &x) - a * x).amax() < tol);
        assert!((product_transposed(&a, &x) - a * x.transpose()).amax() < tol);
        let want = a * a.transpose() + b * b.transpose();
        let mut got = SMatrix::<f64, 15, 15>::zeros();
        if gram_pair_into(&a, &b, &mut got) {
            assert!((got - want).amax() < tol);
            assert_eq!(
                got,
                got.transpose(),
                "the fused loop's Gram product is exactly symmetric"
            );
        } else {
            assert!(!available());
        }
        assert!((minus_product(&want, &a, &x) - (want - a * x)).amax() < tol * 10.0);
        // Small sizes never take the fused loop.
        let mut small = SMatrix::<f64, 4, 4>::identity();
        let zeros = SMatrix::<f64, 4, 2>::zeros();
        assert!(!gram_pair_into(&small.clone(), &zeros, &mut small));
    }

    /// The fused path against the portable one, in the same process: where the CPU has
    /// AVX-512F the products differ by round-off within the bound of a product
    /// (Higham eq. 3.5, doubled, as `every_shape`), the Gram pair is exactly symmetric
    /// on both; with the portable path forced, `product` is `mul_static` bit for bit
    /// and `gram_pair_into` declines.
    #[test]
    fn fused_and_portable_paths_agree() {
        use crate::linalg::dispatch::{with_features, Features};
        let mut rng = ChaCha8Rng::seed_from_u64(74);
        let a = SMatrix::<f64, 15, 15>::from_fn(|_, _| rng.random_range(-1.0..1.0));
        let x = SMatrix::<f64, 15, 15>::from_fn(|_, _| rng.random_range(-1.0..1.0));
        let b = SMatrix::<f64, 15, 3>::from_fn(|_, _| rng.random_range(-1.0..1.0));
        let portable = with_features(Features::PORTABLE, || {
            let mut gram = SMatrix::<f64, 15, 15>::zeros();
            assert!(!gram_pair_into(&a, &b, &mut gram));
            (product(&a, &x), product_transposed(&a, &x))
        });
        assert_eq!(portable.0, mul_static(&a, &x));
        assert_eq!(portable.1, mul_transpose_static(&a, &x));
        let all = Features {
            avx2: true,
            avx512f: true,
            fma: false,
        };
        let (fused_ax, fused_axt, gram) = with_features(all, || {
            let mut gram = SMatrix::<f64, 15, 15>::zeros();
            let ran = gram_pair_into(&a, &b, &mut gram);
            assert_eq!(ran, crate::linalg::dispatch::cpu().avx512f);
            (
                product(&a, &x),
                product_transposed(&a, &x),
                ran.then_some(gram),
            )
        });
        let bound = |i: usize, j: usize, transposed: bool| {
            let s: f64 = (0..15)
                .map(|k| (a[(i, k)] * if transposed { x[(j, k)] } else { x[(k, j)] }).abs())
                .sum();
            2.0 * 16.0 * f64::EPSILON * s
        };
        for i in 0..15 {
            for j in 0..15 {
                assert!((fused_ax[(i, j)] - portable.0[(i, j)]).abs() <= bound(i, j, false));
                assert!((fused_axt[(i, j)] - portable.1[(i, j)]).abs() <= bound(i, j, true));
            }
        }
        if let Some(gram) = gram {
            assert_eq!(gram, gram.transpose());
            assert!((gram - (a * a.transpose() + b * b.transpose())).amax() < 1e-13);
        }
    }
}
