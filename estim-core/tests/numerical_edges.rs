//! Numerical edges of the correlated update (issue 8): nearly singular S, M at the
//! validity boundary, scales from 1e-9 to 1e9, non-finite input. The answer is
//! correct or the error is typed; a NaN is never passed on.

mod common;

use common::*;
use estim_core::nalgebra::{
    DMatrix, Matrix1, Matrix2, SMatrix, SVector, Vector1, Vector2, Vector4,
};
use estim_core::update::correlated_update;
use estim_core::{CovarianceUpdate, Error, JointCovariance, ScaledCorrelation, StateAndCovariance};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn is_singular_error(e: &Error) -> bool {
    matches!(
        e,
        Error::InnovationNotPositiveDefinite | Error::InnovationIllConditioned { .. }
    )
}

/// P = I, H = [[1, 0], [1, d]], R = 0: S = H H' has condition ~ 4 / d^2. The exact
/// posterior is x = H^-1 y (the measurement pins the state), P+ = 0.
#[test]
fn nearly_singular_innovation_is_accurate_or_a_typed_error() {
    let y = Vector2::new(1.0, 2.0);
    let mut accepted = Vec::new();
    for k in 1..=10 {
        let d = 10f64.powi(-k);
        let h = Matrix2::new(1.0, 0.0, 1.0, d);
        let prior = StateAndCovariance::new(Vector2::zeros(), Matrix2::identity()).unwrap();
        let s = dm(&(h * h.transpose()));
        let eig = s.symmetric_eigenvalues();
        let cond = eig.max() / eig.min().max(f64::MIN_POSITIVE);
        let out = correlated_update(
            &prior,
            &y,
            &h,
            &Matrix2::zeros(),
            &SMatrix::<f64, 2, 2>::zeros(),
            CovarianceUpdate::JosephLike,
        );
        match out {
            Ok(out) => {
                let exact = Vector2::new(y[0], (y[1] - y[0]) / d);
                let err = (out.posterior.state() - exact).amax() / exact.amax();
                // Backward-stable solve: relative error of order cond(S) * eps; the
                // factor 100 covers the constant of the bound.
                assert!(
                    err <= 100.0 * cond * f64::EPSILON,
                    "d = {d:e}: rel err {err:e}, cond {cond:e}"
                );
                assert!(out.posterior.covariance().iter().all(|v| v.is_finite()));
                accepted.push(k);
            }
            Err(e) => {
                assert!(is_singular_error(&e), "d = {d:e}: {e:?}");
                // Only refused when genuinely near singular.
                assert!(cond > 1e11, "d = {d:e} refused at cond {cond:e}");
            }
        }
    }
    // Mildly ill-conditioned S (cond up to ~4e10) must be solved, and S singular in
    // floating point (1 + d^2 == 1 from d = 1e-8) must be refused.
    assert!((1..=5).all(|k| accepted.contains(&k)), "{accepted:?}");
    assert!(accepted.iter().all(|k| *k < 8), "{accepted:?}");
}

/// Scalar model, Cov(G w) = q, R = r: the joint covariance is PSD iff |M| <= sqrt(q r).
#[test]
fn m_at_the_validity_boundary() {
    let (q, r): (f64, f64) = (0.5, 2.0);
    let boundary = (q * r).sqrt();
    let qm = Matrix1::new(q);
    let rm = Matrix1::new(r);
    assert!(JointCovariance::new(qm, Matrix1::new(boundary), rm)
        .check()
        .is_ok());
    assert!(JointCovariance::new(qm, Matrix1::new(-boundary), rm)
        .check()
        .is_ok());
    assert!(matches!(
        JointCovariance::new(qm, Matrix1::new(boundary * (1.0 + 1e-6)), rm).check(),
        Err(Error::InvalidJointCovariance { .. })
    ));
    let c = JointCovariance::new(qm, Matrix1::new(1.0), rm)
        .largest_valid_scale()
        .unwrap();
    assert!(
        (c - boundary).abs() <= 1e-14 * boundary,
        "{c} vs {boundary}"
    );

    // Update at the boundary (v = (M/q) w exactly) against the scalar formulas.
    let (p_prior, h, innovation): (f64, f64, f64) = (0.3 + q, 1.5, 0.7);
    for m in [boundary, -boundary] {
        let prior = StateAndCovariance::new(Vector1::new(0.2), Matrix1::new(p_prior)).unwrap();
        let out = correlated_update(
            &prior,
            &Vector1::new(innovation),
            &Matrix1::new(h),
            &rm,
            &Matrix1::new(m),
            CovarianceUpdate::JosephLike,
        )
        .unwrap();
        let s = h * h * p_prior + 2.0 * h * m + r;
        let k = (p_prior * h + m) / s;
        let p_post = p_prior - k * (h * p_prior + m);
        assert!((out.posterior.state()[0] - (0.2 + k * innovation)).abs() < 1e-14);
        assert!((out.posterior.covariance()[(0, 0)] - p_post).abs() < 1e-14);
        assert!(p_post >= 0.0);
    }

    // At the boundary with rho = -1, h = 1, q = r = 0.5 and a prior uncertainty made
    // of the process noise only (P- = q), the measurement noise cancels the process
    // noise: S = P- + 2 M + R = 0.5 - 1.0 + 0.5 = 0 exactly.
    let prior = StateAndCovariance::new(Vector1::new(0.0), Matrix1::new(0.5)).unwrap();
    let err = correlated_update(
        &prior,
        &Vector1::new(0.1),
        &Matrix1::new(1.0),
        &Matrix1::new(0.5),
        &Matrix1::new(-0.5),
        CovarianceUpdate::JosephLike,
    );
    assert!(is_singular_error(&err.unwrap_err()));
}

/// ScaledCorrelation (M = rho sqrt(diag Q) sqrt(diag R)') with diagonal Q (q nonzero
/// entries) and R (m entries) is valid iff rho^2 q m <= 1 (DESIGN.md).
#[test]
fn scaled_correlation_bound_is_one_over_sqrt_qm() {
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    for q_count in 1..=15usize {
        for m_count in 1..=4usize {
            let mut qd = SMatrix::<f64, 15, 15>::zeros();
            for i in 0..q_count {
                qd[(i, i)] = 10f64.powf(rng.random_range(-6.0..0.0));
            }
            let mut r = SMatrix::<f64, 4, 4>::identity();
            for i in 0..m_count {
                r[(i, i)] = 10f64.powf(rng.random_range(-4.0..0.0));
            }
            // Only the first m_count measurement components are used: model m by
            // zeroing the unit columns beyond it through a separate R block.
            let rho_max = match m_count {
                1 => rho_for::<1>(&qd, &r),
                2 => rho_for::<2>(&qd, &r),
                3 => rho_for::<3>(&qd, &r),
                _ => rho_for::<4>(&qd, &r),
            };
            let expected = 1.0 / ((q_count * m_count) as f64).sqrt();
            assert!(
                (rho_max - expected).abs() <= 1e-9 * expected,
                "q {q_count}, m {m_count}: {rho_max} vs {expected}"
            );
            // rho = 0.42 (the paper's value) is valid iff q m <= 1 / 0.42^2 = 5.67.
            assert_eq!(0.42 <= rho_max, q_count * m_count <= 5);
        }
    }
}

fn rho_for<const M: usize>(qd: &SMatrix<f64, 15, 15>, r: &SMatrix<f64, 4, 4>) -> f64 {
    let r = SMatrix::<f64, M, M>::from_fn(|i, j| r[(i, j)]);
    let rho = ScaledCorrelation::<f64>::largest_valid_rho(qd, &r).unwrap();
    // Cross-check against eigenvalues of the joint covariance computed here.
    let unit = ScaledCorrelation::<f64>::unit(qd, &r);
    let joint = |c: f64| {
        let mut j = DMatrix::zeros(15 + M, 15 + M);
        j.view_mut((0, 0), (15, 15)).copy_from(&dm(qd));
        j.view_mut((0, 15), (15, M)).copy_from(&(dm(&unit) * c));
        j.view_mut((15, 0), (M, 15))
            .copy_from(&(dm(&unit).transpose() * c));
        j.view_mut((15, 15), (M, M)).copy_from(&dm(&r));
        j
    };
    let scale = qd.amax().max(r.amax());
    assert!(min_eig(&joint(rho * 0.999)) >= -1e-12 * scale);
    assert!(min_eig(&joint(rho * 1.01)) < 0.0);
    rho
}

fn random_system(seed: u64) -> System<4, 2> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let values: Vec<f64> = (0..entries_len(4, 2))
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    System::from_entries(&values)
}

/// Change of units: state scaled by s, measurement by t. The posterior in the new
/// units is the old one scaled, for s, t from 1e-9 to 1e9; the joint-covariance check
/// gives the same verdict at every scale.
#[test]
fn scales_from_1e_minus_9_to_1e9() {
    let sys = random_system(7);
    let prior_x = sys.f * sys.x0;
    let prior_p = sys.f * sys.p0 * sys.f.transpose() + sys.qd();
    let innovation = sys.ys[0] - sys.h * prior_x;
    let base = correlated_update(
        &StateAndCovariance::new(prior_x, prior_p).unwrap(),
        &innovation,
        &sys.h,
        &sys.r,
        &sys.m(),
        CovarianceUpdate::JosephLike,
    )
    .unwrap();
    let c_max = JointCovariance::new(sys.qd(), sys.m(), sys.r)
        .largest_valid_scale()
        .unwrap();
    let exps = [-9, -6, -3, 0, 3, 6, 9];
    for es in exps {
        for et in exps {
            let (s, t) = (10f64.powi(es), 10f64.powi(et));
            let prior = StateAndCovariance::new(prior_x * s, prior_p * (s * s)).unwrap();
            let h = sys.h * (t / s);
            let r = sys.r * (t * t);
            let m = sys.m() * (s * t);
            for form in [CovarianceUpdate::JosephLike, CovarianceUpdate::Short] {
                let out = correlated_update(&prior, &(innovation * t), &h, &r, &m, form)
                    .unwrap_or_else(|e| panic!("s {s:e}, t {t:e}: {e}"));
                let ex = (out.posterior.state() / s - base.posterior.state()).amax()
                    / base.posterior.state().amax();
                let ep = (out.posterior.covariance() / (s * s) - base.posterior.covariance())
                    .amax()
                    / base.posterior.covariance().amax();
                assert!(ex < 1e-12 && ep < 1e-12, "s {s:e}, t {t:e}: {ex:e} {ep:e}");
                let nis_rel = (out.nis - base.nis).abs() / base.nis;
                assert!(nis_rel < 1e-12, "nis at s {s:e}, t {t:e}");
            }
            let qd = sys.qd() * (s * s);
            assert!(
                JointCovariance::new(qd, m, r).check().is_ok(),
                "s {s:e} t {t:e}"
            );
            assert!(matches!(
                JointCovariance::new(qd, m * (c_max * 1.01), r).check(),
                Err(Error::InvalidJointCovariance { .. })
            ));
        }
    }
}

/// NaN or infinity anywhere in the input, or overflow inside, is a typed error.
#[test]
fn non_finite_input_or_overflow_is_a_typed_error() {
    let sys = random_system(3);
    let prior = StateAndCovariance::new(sys.x0, sys.p0).unwrap();
    let y = sys.ys[0];
    let ok = |h: &SMatrix<f64, 2, 4>,
              r: &SMatrix<f64, 2, 2>,
              m: &SMatrix<f64, 4, 2>,
              y: &SVector<f64, 2>| {
        correlated_update(&prior, y, h, r, m, CovarianceUpdate::JosephLike)
    };
    let (h, r, m) = (sys.h, sys.r, sys.m());
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let mut hb = h;
        hb[(1, 2)] = bad;
        let mut rb = r;
        rb[(0, 0)] = bad;
        let mut mb = m;
        mb[(3, 1)] = bad;
        let mut yb = y;
        yb[0] = bad;
        for res in [
            ok(&hb, &r, &m, &y),
            ok(&h, &rb, &m, &y),
            ok(&h, &r, &mb, &y),
            ok(&h, &r, &m, &yb),
        ] {
            assert!(matches!(res, Err(Error::NonFinite { .. })), "{res:?}");
        }
        let mut pb = sys.p0;
        pb[(2, 2)] = bad;
        assert!(matches!(
            StateAndCovariance::new(sys.x0, pb),
            Err(Error::NonFinite { .. })
        ));
    }
    // Overflow: H P H' exceeds f64::MAX.
    let huge = StateAndCovariance::new(Vector4::zeros(), SMatrix::identity() * 1e300).unwrap();
    let res = correlated_update(&huge, &y, &(h * 1e10), &r, &m, CovarianceUpdate::JosephLike);
    assert!(matches!(res, Err(Error::NonFinite { .. })), "{res:?}");
}
