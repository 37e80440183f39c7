//! Square-root form (issue 13.3): `SquareRootKalmanFilter` and the free functions
//! against an independently coded correlated Kalman filter, refusal of an invalid
//! joint covariance (the paper's rho = 0.42), and positive definiteness over a long
//! run.
//!
//! The reference is the covariance-form filter of Simon (2006, sec. 7.1) coded here
//! with dynamic matrices and LU inverses; it shares nothing with the crate's
//! Cholesky / Givens code.

mod common;

use common::*;
use estim_core::nalgebra::{DMatrix, DVector, SMatrix, SVector};
use estim_core::square_root::{covariance_factor, square_root_predict, square_root_update};
use estim_core::{
    CrossCovariance, CrossCovarianceContext, Error, Fixed, KalmanFilter, ScaledCorrelation,
    SquareRootKalmanFilter, StateAndCovariance,
};
use proptest::prelude::*;
use proptest::test_runner::{FileFailurePersistence, RngSeed, TestCaseError};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// Well-conditioned systems (cond(P), cond(S) below ~1e3): 1e-10 relative leaves
/// room for the round-off of two different factorisations.
const TOL: f64 = 1e-10;

fn check_same<const N: usize, const M: usize>(
    what: &str,
    x: &SVector<f64, N>,
    p: &SMatrix<f64, N, N>,
    reference: &(DMatrix<f64>, DMatrix<f64>),
) -> Result<(), TestCaseError> {
    let ex = rel_err(
        &DMatrix::from_column_slice(N, 1, x.as_slice()),
        &reference.0,
    );
    let ep = rel_err(&dm(p), &reference.1);
    prop_assert!(
        ex <= TOL && ep <= TOL,
        "{what}: mean {ex:e}, covariance {ep:e}"
    );
    Ok(())
}

fn equals_standard_form<const N: usize, const M: usize>(
    values: &[f64],
) -> Result<(), TestCaseError> {
    let sys = System::<N, M>::from_entries(values);
    let initial = StateAndCovariance::new(sys.x0, sys.p0).unwrap();
    let mut filter =
        SquareRootKalmanFilter::new(sys.f, sys.qd(), sys.h, sys.r, initial.clone()).unwrap();
    for y in sys.ys.iter().take(3) {
        filter.step(Some(y), &Fixed(sys.m())).unwrap();
        // The factor stays lower triangular with a positive diagonal.
        let s = filter.factor();
        prop_assert!((0..N).all(|j| s[(j, j)] > 0.0 && (j + 1..N).all(|i| s[(j, i)] == 0.0)));
    }
    let est = filter.estimate();
    check_same::<N, M>(
        "filter, 3 steps",
        est.state(),
        est.covariance(),
        &reference(&sys, 3),
    )?;

    // Free functions (what an error-state runner would call), one step, against the
    // same reference.
    let s0 = covariance_factor(&sys.p0, "P0").unwrap();
    let sq = covariance_factor(&sys.qd(), "Q").unwrap();
    let s1 = square_root_predict(&s0, &sys.f, &sq).unwrap();
    let x1 = sys.f * sys.x0;
    let out = square_root_update(
        &x1,
        &s1,
        &(sys.ys[0] - sys.h * x1),
        &sys.h,
        &sys.r,
        &sys.m(),
    )
    .unwrap();
    check_same::<N, M>(
        "free functions, 1 step",
        &out.state,
        &(out.factor * out.factor.transpose()),
        &reference(&sys, 1),
    )?;
    // The gain and the innovation factor against the reference formulas.
    let p1 = dm(&(sys.f * sys.p0 * sys.f.transpose() + sys.qd()));
    let (h, m, r) = (dm(&sys.h), dm(&sys.m()), dm(&sys.r));
    let s = &h * &p1 * h.transpose() + &h * &m + m.transpose() * h.transpose() + &r;
    let k = (&p1 * h.transpose() + &m) * inv(&s);
    let sf = dm(&(out.innovation_factor * out.innovation_factor.transpose()));
    prop_assert!(rel_err(&dm(&out.gain), &k) <= TOL, "gain");
    prop_assert!(rel_err(&sf, &s) <= TOL, "innovation covariance");
    let nu = DVector::from_column_slice(out.innovation.as_slice());
    let nis = (nu.transpose() * inv(&s) * &nu)[(0, 0)];
    prop_assert!(
        (out.nis - nis).abs() <= TOL * nis.max(1.0),
        "NIS {} vs {nis}",
        out.nis
    );
    Ok(())
}

macro_rules! for_every_size {
    ($($name:ident: $n:literal, $m:literal;)*) => {
        proptest! {
            #![proptest_config(ProptestConfig {
                cases: 32,
                rng_seed: RngSeed::Fixed(20_261_130),
                failure_persistence: Some(Box::new(FileFailurePersistence::WithSource(
                    "proptest-regressions",
                ))),
                ..ProptestConfig::default()
            })]
            $(
                #[test]
                fn $name(values in proptest::collection::vec(-1.0f64..1.0, entries_len($n, $m))) {
                    equals_standard_form::<$n, $m>(&values)?;
                }
            )*
        }
    };
}

for_every_size! {
    n1_m1: 1, 1; n1_m2: 1, 2; n1_m3: 1, 3; n1_m4: 1, 4;
    n2_m1: 2, 1; n2_m2: 2, 2; n2_m3: 2, 3; n2_m4: 2, 4;
    n3_m1: 3, 1; n3_m2: 3, 2; n3_m3: 3, 3; n3_m4: 3, 4;
    n4_m1: 4, 1; n4_m2: 4, 2; n4_m3: 4, 3; n4_m4: 4, 4;
    n5_m1: 5, 1; n5_m2: 5, 2; n5_m3: 5, 3; n5_m4: 5, 4;
    n6_m1: 6, 1; n6_m2: 6, 2; n6_m3: 6, 3; n6_m4: 6, 4;
    n7_m1: 7, 1; n7_m2: 7, 2; n7_m3: 7, 3; n7_m4: 7, 4;
    n8_m1: 8, 1; n8_m2: 8, 2; n8_m3: 8, 3; n8_m4: 8, 4;
    n9_m1: 9, 1; n9_m2: 9, 2; n9_m3: 9, 3; n9_m4: 9, 4;
}

/// The paper's M = rho sqrt(diag Q_acc) sqrt(diag R)' with rho = 0.42, a 6-state
/// diagonal Q_acc and a 3-axis measurement: rho^2 q m = 0.1764 x 18 = 3.2 > 1, the
/// joint covariance is indefinite (smallest correlation eigenvalue
/// 1 - rho sqrt(q m) = -0.78) and has no square root. The update is refused with the
/// typed error and the filter is untouched. At rho = 1/sqrt(q m) (the boundary: PSD,
/// singular) it is accepted; just above it, refused.
#[test]
fn paper_rho_is_refused_never_factored_around() {
    const N: usize = 6;
    const M: usize = 3;
    let q =
        SMatrix::<f64, N, N>::from_diagonal(&SVector::from([1e-4, 2e-4, 3e-4, 1e-6, 2e-6, 5e-6]));
    let r = SMatrix::<f64, M, M>::from_diagonal(&SVector::from([0.01, 0.02, 0.04]));
    let f = SMatrix::<f64, N, N>::identity();
    let h = SMatrix::<f64, M, N>::from_fn(|i, k| if k == i { 1.0 } else { 0.0 });
    let initial =
        StateAndCovariance::new(SVector::<f64, N>::zeros(), SMatrix::<f64, N, N>::identity())
            .unwrap();
    let y = SVector::<f64, M>::from([0.1, -0.2, 0.05]);
    let boundary = 1.0 / ((N * M) as f64).sqrt();
    for (rho, valid) in [
        (0.42, false),
        (-0.42, false),
        (boundary * (1.0 + 1e-6), false),
        (boundary, true),
        (boundary * 0.999, true),
        (0.0, true),
    ] {
        let mut filter = SquareRootKalmanFilter::new(f, q, h, r, initial.clone()).unwrap();
        filter.predict().unwrap();
        let before = (
            *filter.state(),
            *filter.factor(),
            *filter.accumulated_process_noise(),
        );
        match filter.update(&y, &ScaledCorrelation { rho }) {
            Ok(report) => {
                assert!(valid, "rho = {rho} accepted");
                assert!(report.is_accepted());
                assert!(filter.factor().iter().all(|v| v.is_finite()));
            }
            Err(Error::InvalidJointCovariance { min_eigenvalue }) => {
                assert!(!valid, "rho = {rho} refused");
                // Independent: the correlation matrix [[I, rho 1 1'], [rho 1 1', I]]
                // has smallest eigenvalue 1 - |rho| sqrt(q m).
                let expected = 1.0 - rho.abs() * ((N * M) as f64).sqrt();
                assert!(
                    (min_eigenvalue - expected).abs() < 1e-9,
                    "{min_eigenvalue} vs {expected}"
                );
                let after = (
                    *filter.state(),
                    *filter.factor(),
                    *filter.accumulated_process_noise(),
                );
                assert_eq!(before, after, "state changed on a refused update");
            }
            Err(e) => panic!("rho = {rho}: unexpected error {e}"),
        }
    }
    // The free update refuses an indefinite [[P, M], [M', R]] the same way.
    let s = covariance_factor(&q, "Q").unwrap();
    let m = ScaledCorrelation::unit(&q, &r) * 0.42;
    let e = square_root_update(&SVector::zeros(), &s, &y, &h, &r, &m).unwrap_err();
    assert!(matches!(e, Error::InvalidJointCovariance { .. }), "{e}");
}

/// M = c Q_acc H': the measurement noise is v = c H e_acc + e, e_acc the process
/// noise accumulated since the last update (state space), so
/// Cov(e_acc, v) = c Q_acc H' exactly, whatever the transitions.
struct SharedAccumulatedNoise {
    c: f64,
}

impl<S, const N: usize, const M: usize> CrossCovariance<f64, S, N, M> for SharedAccumulatedNoise {
    fn cross_covariance(
        &self,
        context: &CrossCovarianceContext<f64, S, N, M>,
    ) -> estim_core::Result<SMatrix<f64, N, M>> {
        Ok(context.accumulated_process_noise * context.jacobian.transpose() * self.c)
    }
}

/// A long simulated linear mission: 3-D constant velocity (6 states), 100 predicts
/// (dt = 0.01 s) per position fix whose noise shares the interval's accumulated
/// process noise (v = c H e_acc + e, c = -0.5), 1 hour = 360,000 predicts and
/// 3,600 correlated updates. The square-root filter's factor keeps a positive
/// diagonal throughout (P = S S' positive definite by construction), and its mean
/// and covariance match the covariance-form KalmanFilter (default form) to 1e-8
/// relative at every update. Measurements from a seeded simulation of the model.
#[test]
fn positive_definite_over_a_long_mission() {
    const N: usize = 6;
    const M: usize = 3;
    let dt = 0.01;
    let sigma_a = 0.05;
    let c = -0.5;
    let mut f = SMatrix::<f64, N, N>::identity();
    let mut g = SMatrix::<f64, N, M>::zeros();
    for i in 0..3 {
        f[(i, i + 3)] = dt;
        g[(i, i)] = 0.5 * dt * dt;
        g[(i + 3, i)] = dt;
    }
    let qd = g * g.transpose() * (sigma_a * sigma_a);
    let h = SMatrix::<f64, M, N>::from_fn(|i, k| if k == i { 1.0 } else { 0.0 });
    let mut q_acc = SMatrix::<f64, N, N>::zeros();
    for _ in 0..100 {
        q_acc = f * q_acc * f.transpose() + qd;
    }
    let r_e = 1e-4;
    let r = h * q_acc * h.transpose() * (c * c) + SMatrix::<f64, M, M>::identity() * r_e;
    let initial = StateAndCovariance::new(
        SVector::<f64, N>::zeros(),
        SMatrix::<f64, N, N>::from_diagonal(&SVector::from([1.0, 1.0, 1.0, 0.1, 0.1, 0.1])),
    )
    .unwrap();
    let cross = SharedAccumulatedNoise { c };
    let mut sqrt_filter = SquareRootKalmanFilter::new(f, qd, h, r, initial.clone()).unwrap();
    let mut kf = KalmanFilter::new(f, qd, h, r, initial).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(13);
    let mut truth = SVector::<f64, N>::zeros();
    for update in 0..3600 {
        let mut e_acc = SVector::<f64, N>::zeros();
        for _ in 0..100 {
            let w = SVector::<f64, M>::from_fn(|_, _| {
                sigma_a * Distribution::<f64>::sample(&StandardNormal, &mut rng)
            });
            truth = f * truth + g * w;
            e_acc = f * e_acc + g * w;
            sqrt_filter.predict().unwrap();
            kf.predict().unwrap();
        }
        let e = SVector::<f64, M>::from_fn(|_, _| {
            r_e.sqrt() * Distribution::<f64>::sample(&StandardNormal, &mut rng)
        });
        let y = h * truth + h * e_acc * c + e;
        sqrt_filter.update(&y, &cross).unwrap();
        let report = kf.update(&y, &cross).unwrap();
        assert!(report.cross_covariance.amax() > 0.0);
        let s = sqrt_filter.factor();
        assert!(
            (0..N).all(|j| s[(j, j)] > 0.0),
            "update {update}: factor {s}"
        );
        let p = sqrt_filter.estimate();
        let reference = kf.estimate();
        let err = rel_err(&dm(p.covariance()), &dm(reference.covariance()));
        assert!(err <= 1e-8, "update {update}: covariance rel err {err:e}");
        let ex = (p.state() - reference.state()).amax();
        assert!(ex <= 1e-8, "update {update}: state diff {ex:e}");
    }
}

/// The shared runner shape: with a gate, its recovery and an observer, the
/// square-root filter makes the KalmanFilter's decisions (rejections, the inflation
/// factor after two rejections in a row), its observer sees the same events, and
/// every report field agrees (S, gain, NIS, M, correction) to 1e-10 relative.
#[test]
fn gate_recovery_observer_and_reports_match_the_kalman_filter() {
    use estim_core::{FilterConfig, Gate, GateRecovery, NisRecorder, UpdateStatus, Zero};
    let f = SMatrix::<f64, 2, 2>::new(1.0, 1.0, 0.0, 1.0);
    let qd = SMatrix::<f64, 2, 2>::new(0.25, 0.5, 0.5, 1.0) * 0.01;
    let h = SMatrix::<f64, 1, 2>::new(1.0, 0.0);
    let r = SMatrix::<f64, 1, 1>::new(0.1);
    let initial =
        StateAndCovariance::new(SVector::<f64, 2>::new(0.0, 1.0), SMatrix::identity() * 0.1)
            .unwrap();
    let config = FilterConfig::builder()
        .gate(Gate::NisThreshold(9.0))
        .gate_recovery(GateRecovery::Inflate { after: 2 })
        .build()
        .unwrap();
    let mut kf = KalmanFilter::new(f, qd, h, r, initial.clone())
        .unwrap()
        .with_config(config.clone())
        .with_observer(NisRecorder::default());
    let mut sr = SquareRootKalmanFilter::new(f, qd, h, r, initial)
        .unwrap()
        .with_config(config)
        .with_observer(NisRecorder::default());
    let mut inflations = 0;
    for (k, y) in [1.0, 2.1, 30.0, 31.2, 32.1, 33.0].iter().enumerate() {
        let y = SVector::<f64, 1>::new(*y);
        let a = kf.step(Some(&y), &Zero).unwrap().unwrap();
        let b = sr.step(Some(&y), &Zero).unwrap().unwrap();
        assert_eq!(a.status, b.status, "step {k}");
        assert_eq!(a.gate_threshold, b.gate_threshold);
        assert!((a.nis - b.nis).abs() <= 1e-10 * a.nis, "step {k}");
        assert!(rel_err(&dm(&a.innovation_covariance), &dm(&b.innovation_covariance)) <= TOL);
        match (a.covariance_inflation, b.covariance_inflation) {
            (None, None) => {}
            (Some(la), Some(lb)) => {
                inflations += 1;
                assert!((la - lb).abs() <= 1e-9 * la, "{la} vs {lb}");
            }
            other => panic!("step {k}: {other:?}"),
        }
        if a.status == UpdateStatus::Accepted {
            assert!(rel_err(&dm(a.gain.as_ref().unwrap()), &dm(b.gain.as_ref().unwrap())) <= TOL);
            let (ca, cb) = (a.correction.unwrap(), b.correction.unwrap());
            assert!(rel_err(&dm(&ca), &dm(&cb)) <= TOL);
        } else {
            assert!(b.gain.is_none() && b.correction.is_none());
        }
        let (ea, eb) = (kf.estimate(), sr.estimate());
        assert!(
            rel_err(&dm(ea.covariance()), &dm(eb.covariance())) <= TOL,
            "step {k}"
        );
        assert!(rel_err(&dm(ea.state()), &dm(eb.state())) <= TOL, "step {k}");
    }
    assert_eq!(inflations, 1);
    let (a, b) = (kf.observer(), sr.observer());
    assert_eq!((a.accepted(), a.rejected()), (b.accepted(), b.rejected()));
    assert_eq!(b.rejected(), 3);
}

/// D_j = c Q_d H' over the last 3 predicts (v = c H sum_j G w_j + e).
struct SharesWindow<const N: usize, const M: usize> {
    d: SMatrix<f64, N, M>,
}

impl<const N: usize, const M: usize>
    estim_core::WindowedCrossCovariance<f64, SVector<f64, N>, (), N, M> for SharesWindow<N, M>
{
    fn window_steps(&self) -> usize {
        3
    }
    fn step_cross_covariances(
        &self,
        window: &estim_core::window::StepWindow<'_, f64, SVector<f64, N>, (), N>,
        sink: &mut dyn FnMut(&SMatrix<f64, N, M>) -> estim_core::Result<()>,
    ) -> estim_core::Result<()> {
        for _ in window.iter() {
            sink(&self.d)?;
        }
        Ok(())
    }
}

/// Windowed exact M in square-root form equals the KalmanFilter's windowed update
/// (itself tested against stacked joint-Gaussian conditioning in tests/windowed.rs),
/// with an interleaved uncorrelated update of the same sensor inside the window, so
/// that Var(v) < R and E[v] != 0.
#[test]
fn windowed_update_matches_the_kalman_filter() {
    use estim_core::{FilterConfig, Zero};
    const N: usize = 4;
    const M: usize = 2;
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let values: Vec<f64> = (0..entries_len(N, M))
        .map(|_| rand::RngExt::random_range(&mut rng, -1.0..1.0))
        .collect();
    let sys = System::<N, M>::from_entries(&values);
    let c = 0.3;
    let r = sys.r + sys.h * sys.qd() * sys.h.transpose() * (c * c * 3.0);
    let window = SharesWindow::<N, M> {
        d: sys.qd() * sys.h.transpose() * c,
    };
    let config = FilterConfig::builder().window_capacity(8).build().unwrap();
    let initial = StateAndCovariance::new(sys.x0, sys.p0).unwrap();
    let mut kf = KalmanFilter::new(sys.f, sys.qd(), sys.h, r, initial.clone())
        .unwrap()
        .with_config(config.clone());
    let mut sr = SquareRootKalmanFilter::new(sys.f, sys.qd(), sys.h, r, initial)
        .unwrap()
        .with_config(config);
    for epoch in 0..3 {
        for k in 0..4 {
            kf.predict().unwrap();
            sr.predict().unwrap();
            if k == 1 {
                let y = sys.ys[3] * 0.5;
                kf.update(&y, &Zero).unwrap();
                sr.update(&y, &Zero).unwrap();
            }
        }
        let a = kf.update_windowed(&sys.ys[epoch], &window).unwrap();
        let b = sr.update_windowed(&sys.ys[epoch], &window).unwrap();
        assert!(a.noise_mean.amax() > 0.0);
        for (what, x, y) in [
            ("M", dm(&a.cross_covariance), dm(&b.cross_covariance)),
            ("Var(v)", dm(&a.noise_covariance), dm(&b.noise_covariance)),
            ("E[v]", dm(&a.noise_mean), dm(&b.noise_mean)),
            (
                "P",
                dm(kf.estimate().covariance()),
                dm(sr.estimate().covariance()),
            ),
            ("x", dm(kf.estimate().state()), dm(sr.estimate().state())),
        ] {
            let e = rel_err(&x, &y);
            assert!(e <= TOL, "epoch {epoch} {what}: {e:e}");
        }
    }
}
