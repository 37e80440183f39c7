//! The linear Kalman filter with a control input and per-step F, B, H, Q, R (setters,
//! `predict_with_input`, `predict_with` / `update_with`) against independent references
//! (`stacked/mod.rs`, dynamic matrices and plain formulas): the textbook correlated
//! filter over 200 seeded steps (some unmeasured), with M = 0 and with a `Fixed` M per
//! step; the log-likelihood against the sum of the reference's ln N(nu; 0, S) and
//! against the Gaussian log density of the stacked measurements (joint-Gaussian
//! conditioning of [x_0; w_1..w_K; v's]) over a short horizon; Q_acc against the
//! reference accumulation; the observer's Phi and Q_d; and the setters' typed refusals.
//!
//! Tolerance 1e-10 relative over 200 steps (covariances against their largest entry,
//! states against max(|x|, 1)): the reference uses P - K (H P + M') and LU inverses,
//! the filter its square-root form and Cholesky, so they differ by round-off only;
//! the models are well conditioned (F near 0.9 I, noise eigenvalues >= 0.05).

mod stacked;

use estim_core::nalgebra::{DMatrix, Matrix2, Matrix4, SMatrix, Vector2};
use estim_core::{
    Error, FilterConfig, Fixed, JointCheck, KalmanFilter, Observer, PredictEvent, Result,
    StateAndCovariance, Zero,
};
use stacked::{dm, dv, make_plan, rel, s, sv, textbook, Plan, Shape, Stacked};

const N: usize = 4;
const M: usize = 2;
const U: usize = 2;
const TOL: f64 = 1e-10;

fn shape(steps: usize, correlated: bool) -> Shape {
    Shape {
        n: N,
        m: M,
        u: U,
        steps,
        measured: 0.7,
        correlated,
        one_step_only: false,
        time_varying: true,
    }
}

/// A filter at the plan's x_0 with placeholder matrices (every step sets its own).
fn filter(plan: &Plan) -> KalmanFilter<f64, N, M> {
    let initial = StateAndCovariance::new(sv(&plan.x0), s(&plan.p0)).expect("initial");
    KalmanFilter::new(
        Matrix4::identity(),
        Matrix4::identity(),
        SMatrix::zeros(),
        Matrix2::identity(),
        initial,
    )
    .expect("filter")
}

/// Worst relative errors (state, covariance, Q_acc) of `kf` run over the plan (with
/// the setters, or with `predict_with` / `update_with`)
/// against the textbook reference, step by step.
fn compare<O: Observer<f64, estim_core::nalgebra::SVector<f64, N>, N>>(
    plan: &Plan,
    kf: &mut KalmanFilter<f64, N, M, O>,
    setters: bool,
) -> (f64, f64, f64) {
    let reference = textbook(plan);
    let (mut state, mut cov, mut acc) = (0.0_f64, 0.0_f64, 0.0_f64);
    for (k, step) in plan.steps.iter().enumerate() {
        let (b, u) = (s::<N, U>(&step.b), sv::<U>(&step.u));
        if setters {
            kf.set_transition(s(&step.f)).expect("F");
            kf.set_process_noise(s(&step.q)).expect("Q");
            kf.predict_with_input(&b, &u).expect("predict");
        } else {
            kf.predict_with(s(&step.f), s(&step.q), Some((&b, &u)))
                .expect("predict");
        }
        acc = acc.max(rel(
            &dm(kf.accumulated_process_noise()),
            &reference.accumulated[k],
            0.0,
        ));
        if let Some(meas) = &step.meas {
            let cross = Fixed(s::<N, M>(&meas.cross));
            let y = sv::<M>(&meas.y);
            if setters {
                kf.set_observation(s(&meas.h)).expect("H");
                kf.set_measurement_noise(s(&meas.r)).expect("R");
                kf.update(&y, &cross).expect("update");
            } else {
                kf.update_with(s(&meas.h), s(&meas.r), &y, &cross)
                    .expect("update");
            }
        }
        let x = &reference.states[k];
        state = state.max((dv(kf.estimate().state()) - x).amax() / x.amax().max(1.0));
        cov = cov.max(rel(
            &dm(kf.estimate().covariance()),
            &reference.covariances[k],
            0.0,
        ));
    }
    (state, cov, acc)
}

#[test]
fn setters_and_control_input_match_the_textbook_filter_over_200_steps() {
    for seed in [1, 2, 3] {
        let plan = make_plan(shape(200, false), seed);
        assert!(plan.steps.iter().any(|s| s.meas.is_none()));
        let mut kf = filter(&plan);
        let (state, cov, acc) = compare(&plan, &mut kf, true);
        let reference = textbook(&plan).log_likelihood;
        let ll = (kf.log_likelihood() - reference).abs() / reference.abs();
        eprintln!("seed {seed}: state {state:.2e} cov {cov:.2e} Q_acc {acc:.2e} ll {ll:.2e}");
        assert!(state < TOL && cov < TOL && acc < TOL && ll < TOL);
    }
}

#[test]
fn predict_with_update_with_and_fixed_cross_covariance_match_the_textbook_filter() {
    let config = FilterConfig::builder()
        .joint_check(JointCheck::Reject)
        .build()
        .expect("config");
    for seed in [4, 5, 6] {
        let plan = make_plan(shape(200, true), seed);
        assert!(plan.steps.iter().any(|s| s.meas.is_none()));
        let mut kf = filter(&plan).with_config(config.clone());
        let (state, cov, acc) = compare(&plan, &mut kf, false);
        let reference = textbook(&plan).log_likelihood;
        let ll = (kf.log_likelihood() - reference).abs() / reference.abs();
        eprintln!("seed {seed}: state {state:.2e} cov {cov:.2e} Q_acc {acc:.2e} ll {ll:.2e}");
        assert!(state < TOL && cov < TOL && acc < TOL && ll < TOL);
    }
}

/// Over 8 steps: the log-likelihood is the stacked measurements' log density and the
/// last estimate their joint-Gaussian conditioning, with and without M.
#[test]
fn short_horizon_equals_joint_gaussian_conditioning() {
    for (seed, correlated) in [(7, false), (8, true), (9, true)] {
        let plan = make_plan(shape(8, correlated), seed);
        let mut kf = filter(&plan);
        compare(&plan, &mut kf, false);
        let stacked = Stacked::new(&plan);
        let reference = stacked.log_density();
        let ll = (kf.log_likelihood() - reference).abs() / reference.abs();
        let (x, p) = stacked.conditional(8, 8);
        let state = (dv(kf.estimate().state()) - &x).amax() / x.amax().max(1.0);
        let cov = rel(&dm(kf.estimate().covariance()), &p, 0.0);
        eprintln!("seed {seed}: ll {ll:.2e} state {state:.2e} cov {cov:.2e}");
        assert!(ll < 1e-10 && state < 1e-10 && cov < 1e-10);
    }
}

/// Records each predict's Phi and Q_d.
#[derive(Default)]
struct Models(Vec<(DMatrix<f64>, DMatrix<f64>)>);

impl<S> Observer<f64, S, N> for Models {
    fn on_predict(&mut self, event: &PredictEvent<'_, f64, S, N>) -> Result<()> {
        self.0.push((dm(event.transition), dm(event.process_noise)));
        Ok(())
    }
}

#[test]
fn the_predict_event_carries_each_steps_transition_and_noise() {
    let plan = make_plan(shape(20, false), 10);
    let mut kf = filter(&plan).with_observer(Models::default());
    compare(&plan, &mut kf, false);
    let seen = kf.into_observer().0;
    assert_eq!(seen.len(), plan.steps.len());
    for ((phi, qd), step) in seen.iter().zip(&plan.steps) {
        assert_eq!(phi, &step.f);
        assert_eq!(qd, &step.q);
    }
}

/// After a one-step interval of a fixed model, a new Q must reach Q_acc (the
/// accumulator keeps the fixed model's first step across updates).
#[test]
fn a_replaced_process_noise_reaches_the_accumulated_noise() {
    let plan = make_plan(shape(1, false), 11);
    let mut kf = filter(&plan);
    let y = Vector2::new(0.1, -0.2);
    kf.set_observation(SMatrix::from_fn(|r, c| if r == c { 1.0 } else { 0.0 }))
        .expect("H");
    for _ in 0..2 {
        kf.predict().expect("predict");
        kf.update(&y, &Zero).expect("update");
    }
    let q2 = Matrix4::identity() * 0.5;
    kf.set_process_noise(q2).expect("Q");
    kf.predict().expect("predict");
    assert_eq!(kf.accumulated_process_noise(), &q2);
    let f2 = Matrix4::identity() * 0.7;
    kf.update(&y, &Zero).expect("update");
    kf.set_transition(f2).expect("F");
    kf.predict().expect("predict");
    assert_eq!(kf.accumulated_transition(), &f2);
    assert_eq!(kf.accumulated_process_noise(), &q2);
}

/// R's block certificate is recomputed: the joint check after `set_measurement_noise`
/// equals that of a filter built with the new R.
#[test]
fn a_replaced_measurement_noise_is_checked_as_a_new_one() {
    let plan = make_plan(shape(1, false), 12);
    let config = FilterConfig::builder()
        .joint_check(JointCheck::Report)
        .build()
        .expect("config");
    let (q, h) = (Matrix4::identity(), SMatrix::<f64, M, N>::identity());
    let cross = Fixed(SMatrix::<f64, N, M>::identity() * 0.9);
    let (r_big, r_small) = (Matrix2::identity() * 4.0, Matrix2::identity() * 0.5);
    let initial = StateAndCovariance::new(sv(&plan.x0), s(&plan.p0)).expect("initial");
    let build = |r| {
        KalmanFilter::new(Matrix4::identity(), q, h, r, initial.clone())
            .expect("filter")
            .with_config(config.clone())
    };
    let mut replaced = build(r_big);
    let y = Vector2::new(0.3, 0.1);
    replaced.step(Some(&y), &cross).expect("step");
    replaced.set_measurement_noise(r_small).expect("R");
    let mut fresh = build(r_small);
    fresh.step(Some(&y), &cross).expect("step");
    let (a, b) = (
        replaced.step(Some(&y), &cross),
        fresh.step(Some(&y), &cross),
    );
    let margin = |r: Result<Option<estim_core::UpdateReport<f64, N, M>>>| {
        r.expect("update").expect("measured").joint_min_eigenvalue
    };
    let (a, b) = (margin(a), margin(b));
    // 0.9^2 > 1 * 0.5: [[I, 0.9 I], [0.9 I, 0.5 I]] is indefinite.
    assert!(b.expect("checked") < 0.0);
    assert_eq!(a, b);
}

#[test]
fn setters_refuse_bad_input_and_leave_the_filter_unchanged() {
    let plan = make_plan(shape(3, false), 13);
    let mut kf = filter(&plan);
    kf.predict().expect("predict");
    let before = kf.clone();
    let same = |kf: &KalmanFilter<f64, N, M>| {
        kf.transition() == before.transition()
            && kf.process_noise() == before.process_noise()
            && kf.observation() == before.observation()
            && kf.measurement_noise() == before.measurement_noise()
            && kf.estimate() == before.estimate()
            && kf.accumulated_process_noise() == before.accumulated_process_noise()
    };
    let mut nan4 = Matrix4::identity();
    nan4[(1, 2)] = f64::NAN;
    let mut asymmetric = Matrix4::identity();
    asymmetric[(0, 1)] = 0.3;
    let indefinite = Matrix2::new(1.0, 2.0, 2.0, 1.0);
    let mut nan2 = SMatrix::<f64, M, N>::identity();
    nan2[(0, 3)] = f64::INFINITY;
    let non_finite = |r: Result<()>| matches!(r, Err(Error::NonFinite { .. }));
    let invalid = |r: Result<()>| matches!(r, Err(Error::InvalidCovariance { .. }));
    assert!(non_finite(kf.set_transition(nan4)));
    assert!(non_finite(kf.set_process_noise(nan4)));
    assert!(invalid(kf.set_process_noise(asymmetric)));
    assert!(invalid(kf.set_process_noise(-Matrix4::identity())));
    assert!(non_finite(kf.set_observation(nan2)));
    assert!(invalid(kf.set_measurement_noise(indefinite)));
    assert!(non_finite(kf.set_measurement_noise(Matrix2::new(
        1.0,
        0.0,
        0.0,
        f64::NAN
    ))));
    // The combined calls check everything before replacing anything.
    let b = SMatrix::<f64, N, U>::identity();
    let u = Vector2::new(f64::NAN, 0.0);
    assert!(kf
        .predict_with(
            Matrix4::identity() * 0.5,
            asymmetric,
            None::<(&_, &Vector2<f64>)>
        )
        .is_err());
    assert!(kf
        .predict_with(
            Matrix4::identity() * 0.5,
            Matrix4::identity(),
            Some((&b, &u))
        )
        .is_err());
    assert!(kf.predict_with_input(&b, &u).is_err());
    let y = Vector2::new(0.0, 1.0);
    assert!(kf
        .update_with(SMatrix::identity(), indefinite, &y, &Zero)
        .is_err());
    assert!(kf
        .update_with(nan2, Matrix2::identity(), &y, &Zero)
        .is_err());
    assert!(same(&kf));
    assert_eq!(kf.propagations_since_update(), 1);
    // And the filter still runs as before.
    let mut reference = before.clone();
    kf.predict().expect("predict");
    reference.predict().expect("predict");
    assert_eq!(kf.estimate(), reference.estimate());
}
