//! Tests of the semidefinite Cholesky factorisation and the joint factor.

use super::*;
use crate::linalg::dispatch::{with_features, Features};
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
        // The dispatched build with every feature the CPU has (whatever
        // ESTIM_FORCE_PORTABLE says for the rest of the suite).
        let all = Features {
            avx2: true,
            avx512f: true,
            fma: false,
        };
        let vector = with_features(all, || joint_factor(&p, &m, &r));
        if same_factor(vector, portable, case) {
            factored += 1;
        } else {
            refused += 1;
        }
    }
    assert!(factored > 50 && refused > 20, "{factored} / {refused}");
}
