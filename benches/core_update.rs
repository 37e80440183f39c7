//! Predict + update cost of estim's linear Kalman filter (static sizes, the one
//! correlated update) for (states, measurements) = (4, 2), (15, 3), (30, 6), and the
//! peer crate adskalman on the same (4, 2) model in the same run.
//!
//! Run: `cargo bench --bench core_update` (times are the thread's CPU time, see
//! `benches/common`). estim's runner uses its default covariance form (`SquareRoot`)
//! unless the row names another, and is measured without the joint-covariance check
//! (adskalman has no such check) and with the default configuration (check reported:
//! a static LDL' of the joint correlation matrix); adskalman uses its Joseph form, as
//! does the one estim row that says `JosephLike` (the like-for-like form). Four
//! hand-written `floor` rows time the default form's operations alone, and with the
//! checks and report the runner owes (see [`floor`]). Groups `state_size`
//! (N = 6..30) and `single_precision` (f32 vs f64 vs eskf) follow.

use std::hint::black_box;
use std::time::Duration;

mod common;
use common::ThreadCpuTime;

use adskalman::{
    CovarianceUpdateMethod, KalmanFilterNoControl, ObservationModel,
    StateAndCovariance as AdsEstimate, TransitionModelLinearNoControl,
};
use criterion::{criterion_group, criterion_main, Criterion};
use estim_core::nalgebra::{Matrix2, Matrix2x4, Matrix4, Matrix4x2, SMatrix, SVector, U2, U4};
use estim_core::update::correlated_update;
use estim_core::{
    CovarianceUpdate, CrossCovariance, FilterConfig, Fixed, JointCheck, JointCovariance,
    KalmanFilter, StateAndCovariance, Zero,
};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// 2-D constant velocity, dt = 0.1, white-noise acceleration, position measured.
fn constant_velocity() -> (Matrix4<f64>, Matrix4<f64>, Matrix2x4<f64>, Matrix2<f64>) {
    let dt = 0.1;
    let mut f = Matrix4::identity();
    f[(0, 2)] = dt;
    f[(1, 3)] = dt;
    let q_psd = 0.5;
    let (d2, d3) = (dt * dt, dt * dt * dt);
    let mut q = Matrix4::zeros();
    for i in 0..2 {
        q[(i, i)] = d3 / 3.0 * q_psd;
        q[(i, i + 2)] = d2 / 2.0 * q_psd;
        q[(i + 2, i)] = d2 / 2.0 * q_psd;
        q[(i + 2, i + 2)] = dt * q_psd;
    }
    let mut h = Matrix2x4::zeros();
    h[(0, 0)] = 1.0;
    h[(1, 1)] = 1.0;
    (f, q, h, Matrix2::identity() * 0.01)
}

/// A random stable model of N states and M measurements (seeded).
fn random_model<const N: usize, const M: usize>(
    seed: u64,
) -> (
    SMatrix<f64, N, N>,
    SMatrix<f64, N, N>,
    SMatrix<f64, M, N>,
    SMatrix<f64, M, M>,
) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut draw = || rng.random_range(-1.0..1.0);
    let f = SMatrix::<f64, N, N>::identity() + SMatrix::from_fn(|_, _| draw()) * (0.1 / N as f64);
    let g = SMatrix::<f64, N, N>::from_fn(|_, _| draw()) * 0.1;
    let q = g * g.transpose() + SMatrix::identity() * 1e-4;
    let h = SMatrix::<f64, M, N>::from_fn(|_, _| draw());
    let r = SMatrix::<f64, M, M>::identity() * 0.05;
    (f, q, h, r)
}

fn estim_filter<const N: usize, const M: usize>(
    model: (
        SMatrix<f64, N, N>,
        SMatrix<f64, N, N>,
        SMatrix<f64, M, N>,
        SMatrix<f64, M, M>,
    ),
    joint_check: JointCheck,
) -> KalmanFilter<f64, N, M> {
    let (f, q, h, r) = model;
    let config = FilterConfig::builder()
        .joint_check(joint_check)
        .build()
        .expect("config");
    KalmanFilter::new(
        f,
        q,
        h,
        r,
        StateAndCovariance::new(SVector::zeros(), SMatrix::identity()).expect("initial"),
    )
    .expect("filter")
    .with_config(config)
}

fn bench_estim<const N: usize, const M: usize, C>(
    c: &mut Criterion<ThreadCpuTime>,
    name: &str,
    mut kf: KalmanFilter<f64, N, M>,
    cross: C,
) where
    C: CrossCovariance<f64, SVector<f64, N>, N, M>,
{
    let y = SVector::<f64, M>::from_fn(|i, _| 0.1 * i as f64);
    c.bench_function(name, |b| {
        b.iter(|| {
            kf.predict().expect("predict");
            let report = kf.update(black_box(&y), &cross).expect("update");
            black_box(report.nis)
        })
    });
}

struct AdsMotion {
    f: Matrix4<f64>,
    ft: Matrix4<f64>,
    q: Matrix4<f64>,
}

impl TransitionModelLinearNoControl<f64, U4> for AdsMotion {
    fn F(&self) -> &Matrix4<f64> {
        &self.f
    }
    fn FT(&self) -> &Matrix4<f64> {
        &self.ft
    }
    fn Q(&self) -> &Matrix4<f64> {
        &self.q
    }
}

struct AdsObservation {
    h: Matrix2x4<f64>,
    ht: Matrix4x2<f64>,
    r: Matrix2<f64>,
}

impl ObservationModel<f64, U4, U2> for AdsObservation {
    fn H(&self) -> &Matrix2x4<f64> {
        &self.h
    }
    fn HT(&self) -> &Matrix4x2<f64> {
        &self.ht
    }
    fn R(&self) -> &Matrix2<f64> {
        &self.r
    }
}

/// Reference floors for the (4,2) row: the operations of estim's default update (the
/// square-root form) on the covariance's path from one step to the next, written by
/// hand on local arrays with no check, report, error path or bookkeeping: F P F' + Q,
/// S = H P H' + R and its closed-form inverse, the gain, chol(P), B = [L - K H L, -K
/// L_R] and P+ = B B'. The same step with P = L D L' (square-root free: no square
/// root on the chain of dependent columns) is the second floor. Their checked
/// variants add what the runner must check and report, each check in its cheapest
/// form (`Filter::step_body`). They bound what any implementation of these forms can
/// reach on this machine; `floor_matches_estim` checks before the run that all four
/// compute estim's covariances (and the checked ones its report).
mod floor;

/// The floor filter for estim's model (4, 2) from P = I, x = 0.
fn floor_filter(
    (f, q, h, r): (Matrix4<f64>, Matrix4<f64>, Matrix2x4<f64>, Matrix2<f64>),
) -> floor::Filter<4> {
    let columns = |m: &Matrix4<f64>| -> floor::Square<4> {
        std::array::from_fn(|j| std::array::from_fn(|i| m[(i, j)]))
    };
    let r_factor = r.cholesky().expect("R is positive definite").l();
    let r_pivots = [r_factor[(0, 0)].powi(2), r_factor[(1, 1)].powi(2)];
    floor::Filter {
        f: columns(&f),
        q: columns(&q),
        h: std::array::from_fn(|j| std::array::from_fn(|i| h[(i, j)])),
        r: std::array::from_fn(|j| std::array::from_fn(|i| r[(i, j)])),
        r_factor: std::array::from_fn(|j| std::array::from_fn(|i| r_factor[(i, j)])),
        r_unit: std::array::from_fn(|j| {
            std::array::from_fn(|i| r_factor[(i, j)] / r_factor[(j, j)])
        }),
        r_pivots,
        x: [0.0; 4],
        p: columns(&Matrix4::identity()),
        joint_margin: JointCovariance::new(q, Matrix4x2::zeros(), r)
            .validity_margin()
            .expect("margin"),
    }
}

/// The floors, unchecked and checked, compute estim's covariance and NIS (to
/// round-off) over 200 steps of the (4,2) model, and the checked ones its report
/// (innovation, S, joint margin, gain, correction): so that they time the same
/// operations, not a shortcut.
fn floor_matches_estim(cv: (Matrix4<f64>, Matrix4<f64>, Matrix2x4<f64>, Matrix2<f64>)) {
    for (ldl, checked) in [(false, false), (true, false), (false, true), (true, true)] {
        let mut kf = estim_filter(cv, JointCheck::Report);
        let mut reference = floor_filter(cv);
        for step in 0..200 {
            let y = SVector::<f64, 2>::new((step as f64 * 0.3).sin(), 0.1);
            kf.predict().expect("predict");
            let report = kf.update(&y, &Zero).expect("update");
            let nis = report.nis;
            let yy = [y[0], y[1]];
            let mut floor_report = floor::Report::zeros();
            let floor_nis = match (ldl, checked) {
                (false, false) => Ok(reference.step::<false>(&yy)),
                (true, false) => Ok(reference.step::<true>(&yy)),
                (false, true) => reference.checked_step::<false>(&yy, &mut floor_report),
                (true, true) => reference.checked_step::<true>(&yy, &mut floor_report),
            }
            .expect("floor step");
            if checked {
                let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * a.abs().max(1.0);
                let gain = report.gain.expect("accepted");
                let correction = report.correction.expect("accepted");
                for i in 0..2 {
                    assert!(close(report.innovation[i], floor_report.innovation[i]));
                    for j in 0..2 {
                        assert!(close(
                            report.innovation_covariance[(i, j)],
                            floor_report.innovation_covariance[j][i]
                        ));
                    }
                    for r in 0..4 {
                        assert!(close(gain[(r, i)], floor_report.gain[i][r]), "gain");
                    }
                }
                for r in 0..4 {
                    assert!(
                        close(correction[r], floor_report.correction[r]),
                        "correction"
                    );
                }
                assert!(close(nis, floor_report.nis), "NIS reported");
                assert_eq!(report.joint_min_eigenvalue, Some(floor_report.joint_margin));
            }
            let p = kf.estimate().covariance();
            let scale = p.amax();
            for j in 0..4 {
                for i in 0..4 {
                    let gap = (p[(i, j)] - reference.p[j][i]).abs();
                    assert!(
                        gap <= 1e-12 * scale,
                        "floor (ldl: {ldl}, checked: {checked}) left estim at step {step}: \
                         P({i},{j}) off by {gap:e}"
                    );
                }
            }
            assert!((nis - floor_nis).abs() <= 1e-9 * nis.abs().max(1.0), "NIS");
        }
    }
}

/// A checked floor step per iteration (`LDL`: P = L D L' instead of chol(P)).
fn bench_checked_floor<const LDL: bool>(
    c: &mut Criterion<ThreadCpuTime>,
    name: &str,
    cv: (Matrix4<f64>, Matrix4<f64>, Matrix2x4<f64>, Matrix2<f64>),
) {
    let y = [0.0, 0.1];
    let mut reference = floor_filter(cv);
    let mut report = floor::Report::zeros();
    c.bench_function(name, |b| {
        b.iter(|| {
            let nis = reference
                .checked_step::<LDL>(black_box(&y), &mut report)
                .expect("checked floor step");
            black_box((nis, &report));
        })
    });
}

fn predict_update(c: &mut Criterion<ThreadCpuTime>) {
    let cv = constant_velocity();
    bench_estim(
        c,
        "estim KalmanFilter (4,2) predict+update",
        estim_filter(cv, JointCheck::Skip),
        Zero,
    );
    {
        let mut kf = estim_filter(cv, JointCheck::Skip);
        let y = SVector::<f64, 2>::new(0.0, 0.1);
        kf.update(&y, &Zero).expect("update");
        c.bench_function("estim KalmanFilter (4,2) predict only", |b| {
            b.iter(|| {
                kf.predict().expect("predict");
                black_box(kf.estimate().state()[0])
            })
        });
    }
    bench_estim(
        c,
        "estim KalmanFilter (4,2) predict+update, joint check reported",
        estim_filter(cv, JointCheck::Report),
        Zero,
    );
    {
        let (f, q, h, r) = cv;
        let config = FilterConfig::builder()
            .covariance_update(CovarianceUpdate::JosephLike)
            .build()
            .expect("config");
        let kf = KalmanFilter::new(
            f,
            q,
            h,
            r,
            StateAndCovariance::new(SVector::zeros(), SMatrix::identity()).expect("initial"),
        )
        .expect("filter")
        .with_config(config);
        bench_estim(
            c,
            "estim KalmanFilter (4,2) predict+update, JosephLike form, joint check reported",
            kf,
            Zero,
        );
    }
    bare_update_and_peer(c, cv);
    floor_references(c, cv);
    bench_estim(
        c,
        "estim KalmanFilter (15,3) predict+update",
        estim_filter(random_model::<15, 3>(15), JointCheck::Skip),
        Zero,
    );
    // The same with a nonzero M (the correlated path).
    let model = random_model::<15, 3>(15);
    // Valid: M' Q^-1 M <= 1e-6 / 1e-4 = 0.01 < R = 0.05.
    let m = SMatrix::<f64, 15, 3>::from_fn(|i, j| if i == j { 1e-3 } else { 0.0 });
    bench_estim(
        c,
        "estim KalmanFilter (15,3) predict+update, correlated (Fixed M)",
        estim_filter(model, JointCheck::Skip),
        Fixed(m),
    );
    bench_estim(
        c,
        "estim KalmanFilter (30,6) predict+update",
        estim_filter(random_model::<30, 6>(30), JointCheck::Skip),
        Zero,
    );
}

/// The bare update function on a fixed prior, and adskalman's step (the peer).
fn bare_update_and_peer(
    c: &mut Criterion<ThreadCpuTime>,
    cv: (Matrix4<f64>, Matrix4<f64>, Matrix2x4<f64>, Matrix2<f64>),
) {
    {
        // The bare update function on a fixed prior (no runner, no prediction).
        let (f, q, h, r) = cv;
        let prior = StateAndCovariance::new(SVector::<f64, 4>::zeros(), f * f.transpose() + q)
            .expect("prior");
        let y = SVector::<f64, 2>::new(0.0, 0.1);
        let m = SMatrix::<f64, 4, 2>::zeros();
        c.bench_function("estim correlated_update (4,2) alone", |b| {
            b.iter(|| {
                let out = correlated_update(
                    black_box(&prior),
                    black_box(&y),
                    &h,
                    &r,
                    &m,
                    CovarianceUpdate::JosephLike,
                )
                .expect("update");
                black_box(out.nis)
            })
        });
    }
    {
        let (f, q, h, r) = cv;
        let motion = AdsMotion {
            f,
            ft: f.transpose(),
            q,
        };
        let observation = AdsObservation {
            h,
            ht: h.transpose(),
            r,
        };
        let kf = KalmanFilterNoControl::new(&motion, &observation);
        let mut estimate = AdsEstimate::new(SVector::<f64, 4>::zeros(), Matrix4::identity());
        let y = SVector::<f64, 2>::new(0.0, 0.1);
        c.bench_function(
            "adskalman KalmanFilterNoControl (4,2) predict+update",
            |b| {
                b.iter(|| {
                    estimate = kf
                        .step_with_options(
                            &estimate,
                            black_box(&y),
                            CovarianceUpdateMethod::JosephForm,
                        )
                        .expect("adskalman step");
                    black_box(estimate.state()[0])
                })
            },
        );
    }
}

/// The hand-written (4,2) floors (checked against estim first).
fn floor_references(
    c: &mut Criterion<ThreadCpuTime>,
    cv: (Matrix4<f64>, Matrix4<f64>, Matrix2x4<f64>, Matrix2<f64>),
) {
    floor_matches_estim(cv);
    let y = [0.0, 0.1];
    let mut reference = floor_filter(cv);
    c.bench_function(
        "floor: hand-written (4,2) square-root step, chol(P), no checks (reference)",
        |b| b.iter(|| black_box(reference.step::<false>(black_box(&y)))),
    );
    let mut reference = floor_filter(cv);
    c.bench_function(
        "floor: hand-written (4,2) square-root-free step, LDL'(P), no checks (reference)",
        |b| b.iter(|| black_box(reference.step::<true>(black_box(&y)))),
    );
    bench_checked_floor::<false>(
        c,
        "floor: hand-written (4,2) square-root step, chol(P), with the runner's checks and report (reference)",
        cv,
    );
    bench_checked_floor::<true>(
        c,
        "floor: hand-written (4,2) square-root-free step, LDL'(P), with the runner's checks and report (reference)",
        cv,
    );
}

/// The INS pattern: 100 propagations (with Q_acc / Phi_acc accumulation) per update.
fn hundred_predictions_per_update(c: &mut Criterion<ThreadCpuTime>) {
    let mut kf = estim_filter(random_model::<15, 3>(15), JointCheck::Skip);
    let y = SVector::<f64, 3>::zeros();
    c.bench_function("estim KalmanFilter (15,3) 100 predicts + 1 update", |b| {
        b.iter(|| {
            for _ in 0..100 {
                kf.predict().expect("predict");
            }
            black_box(kf.update(&y, &Zero).expect("update").nis)
        })
    });
}

/// Per-step cost against state size: predict + update of a random (N, 3) model with the
/// default configuration (square-root form, joint covariance reported), N = 6, 9, 15,
/// 21, 30. The dense multiply-add count of each size is in estim-ins/README.md.
fn state_size(c: &mut Criterion<ThreadCpuTime>) {
    fn one<const N: usize>(c: &mut Criterion<ThreadCpuTime>) {
        let mut kf = estim_filter(random_model::<N, 3>(N as u64), JointCheck::default());
        let y = SVector::<f64, 3>::new(0.1, -0.2, 0.05);
        c.bench_function(
            &format!("state_size/({N},3) predict+update, default configuration"),
            |b| {
                b.iter(|| {
                    kf.predict().expect("predict");
                    black_box(kf.update(black_box(&y), &Zero).expect("update").nis)
                })
            },
        );
    }
    one::<6>(c);
    one::<9>(c);
    one::<15>(c);
    one::<21>(c);
    one::<30>(c);
}

/// f32 against f64 and the peer: an 18-state linear predict (dense F P F' + Q, the size
/// of eskf's covariance) in f32 and f64, beside eskf 0.2's predict (f32, 18 states,
/// with its own nominal-state kinematics) in the same run.
fn single_precision(c: &mut Criterion<ThreadCpuTime>) {
    fn predict_only<T: estim_core::Scalar>(c: &mut Criterion<ThreadCpuTime>, name: &str) {
        let (f, q, h, r) = random_model::<18, 3>(18);
        let cast = |x: f64| -> T { estim_core::numeric::lit(x) };
        let mut kf = KalmanFilter::new(
            f.map(cast),
            q.map(cast),
            h.map(cast),
            r.map(cast),
            StateAndCovariance::new(SVector::<T, 18>::zeros(), SMatrix::identity())
                .expect("initial"),
        )
        .expect("filter");
        let y = SVector::<T, 3>::zeros();
        c.bench_function(name, |b| {
            let mut k = 0u32;
            b.iter(|| {
                kf.predict().expect("predict");
                // Keep the covariance bounded: one update every 100 predicts.
                k += 1;
                if k.is_multiple_of(100) {
                    kf.update(&y, &Zero).expect("update");
                }
                black_box(kf.estimate().covariance()[(0, 0)])
            })
        });
    }
    predict_only::<f32>(c, "single_precision/estim KalmanFilter<f32, 18, 3> predict");
    predict_only::<f64>(c, "single_precision/estim KalmanFilter<f64, 18, 3> predict");
    c.bench_function(
        "single_precision/eskf 0.2 predict (peer, f32, 18 states)",
        |b| {
            let mut filter = eskf::Builder::new()
                .acceleration_variance(0.03f32 * 0.03)
                .rotation_variance(5e-4f32 * 5e-4)
                .initial_covariance(1e-3)
                .build();
            let fresh = filter;
            let (mut acc, mut rot) = (filter.velocity, filter.velocity);
            acc.z = -9.81;
            rot.z = 0.01;
            let mut k = 0u32;
            b.iter(|| {
                filter.predict(black_box(acc), black_box(rot), Duration::from_millis(10));
                k += 1;
                if k.is_multiple_of(40_000) {
                    filter = fresh;
                }
                black_box(&filter);
            })
        },
    );
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .with_measurement(ThreadCpuTime)
        .measurement_time(Duration::from_secs(2))
        .warm_up_time(Duration::from_millis(500))
        .sample_size(30);
    targets = predict_update, hundred_predictions_per_update, state_size, single_precision
}
criterion_main!(benches);
