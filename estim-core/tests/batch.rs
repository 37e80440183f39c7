//! `KalmanFilter::filter_batch` and `smooth_batch`:
//!
//! - the batch filter equals `step()` in a loop bit for bit (estimates, reports, the
//!   log-likelihood as the sum of the accepted reports' terms, the filter's end state and
//!   its cumulative `log_likelihood()`), also with a gate rejecting some measurements;
//! - the batch smoother equals joint-Gaussian conditioning of the stacked
//!   [x_0; w_1..w_K; v's] on every measurement (`stacked/mod.rs`, dynamic matrices and
//!   LU, not the crate's code), to 1e-9 relative (as `tests/smoother.rs`: covariances
//!   against their largest entry, means against max(|mean|, largest standard deviation)),
//!   for M = 0 with unmeasured steps and for a constant M != 0 at every step; its
//!   log-likelihood equals the stacked measurements' log density;
//! - the smoother leaves the filter untouched, and refuses what it cannot smooth with a
//!   typed error.

mod stacked;

use estim_core::nalgebra::SVector;
use estim_core::{
    Error, FilterConfig, Fixed, Gate, KalmanFilter, StateAndCovariance, UpdateStatus, Zero,
};
use stacked::{dm, dv, make_plan, rel, s, sv, Plan, Shape, Stacked};

const N: usize = 3;
const M: usize = 2;

fn shape(steps: usize, measured: f64, correlated: bool) -> Shape {
    Shape {
        n: N,
        m: M,
        u: 0,
        steps,
        measured,
        correlated,
        one_step_only: false,
        time_varying: false,
    }
}

/// The plan's fixed model, its measurements and its M (the first measured step's).
fn setup(
    plan: &Plan,
) -> (
    KalmanFilter<f64, N, M>,
    Vec<Option<SVector<f64, M>>>,
    Fixed<f64, N, M>,
) {
    let first = &plan.steps[0];
    let meas = plan
        .steps
        .iter()
        .find_map(|s| s.meas.as_ref())
        .expect("a measured step");
    let initial = StateAndCovariance::new(sv(&plan.x0), s(&plan.p0)).expect("initial");
    let kf = KalmanFilter::new(s(&first.f), s(&first.q), s(&meas.h), s(&meas.r), initial)
        .expect("filter");
    let ys = plan
        .steps
        .iter()
        .map(|s| s.meas.as_ref().map(|m| sv::<M>(&m.y)))
        .collect();
    (kf, ys, Fixed(s(&meas.cross)))
}

#[test]
fn batch_filter_equals_step_in_a_loop_bit_for_bit() {
    let gate = FilterConfig::builder()
        .gate(Gate::Nis { probability: 0.7 })
        .build()
        .expect("config");
    for (seed, correlated, config) in [
        (1, false, FilterConfig::default()),
        (2, true, FilterConfig::default()),
        (3, true, gate.clone()),
    ] {
        let measured = if correlated { 1.0 } else { 0.6 };
        let plan = make_plan(shape(60, measured, correlated), seed);
        let (kf, ys, cross) = setup(&plan);
        let (mut batch, mut looped) = (
            kf.clone().with_config(config.clone()),
            kf.with_config(config),
        );
        let out = batch.filter_batch(&ys, &cross).expect("batch");
        let mut log_likelihood = 0.0;
        let mut rejected = 0;
        for (k, y) in ys.iter().enumerate() {
            let report = looped.step(y.as_ref(), &cross).expect("step");
            if let Some(r) = report.as_ref() {
                if r.status == UpdateStatus::Accepted {
                    log_likelihood += r.log_likelihood;
                } else {
                    rejected += 1;
                }
            }
            assert_eq!(&out.estimates[k], looped.estimate());
            assert_eq!(out.reports[k], report);
        }
        assert_eq!(out.estimates.len(), ys.len());
        assert_eq!(out.log_likelihood.to_bits(), log_likelihood.to_bits());
        assert_eq!(batch.estimate(), looped.estimate());
        assert_eq!(
            batch.log_likelihood().to_bits(),
            looped.log_likelihood().to_bits()
        );
        assert_eq!(
            batch.accumulated_process_noise(),
            looped.accumulated_process_noise()
        );
        eprintln!("seed {seed}: {rejected} rejected by the gate");
        if seed == 3 {
            assert!(rejected > 0, "the gate case must reject some updates");
        }
    }
}

/// Worst relative errors (means, covariances) of the smoothed batch against the
/// stacked conditioning on every measurement, and of its log-likelihood.
fn smoothing_errors(plan: &Plan) -> (f64, f64, f64) {
    let (kf, ys, cross) = setup(plan);
    let before = kf.clone();
    let out = kf.smooth_batch(&ys, &cross).expect("smooth");
    // The same call's filtered estimates are filter_batch's, bit for bit.
    let filtered = before.clone().filter_batch(&ys, &cross).expect("filter");
    assert_eq!(out.filtered, filtered.estimates);
    assert_eq!(kf.estimate(), before.estimate());
    assert_eq!(kf.log_likelihood(), 0.0);
    assert_eq!(kf.propagations_since_update(), 0);
    let stacked = Stacked::new(plan);
    let last = plan.steps.len();
    let all = std::iter::once(&out.initial).chain(&out.estimates);
    let (mut mean, mut cov) = (0.0_f64, 0.0_f64);
    for (k, estimate) in all.enumerate() {
        let (x, p) = stacked.conditional(k, last);
        let spread = p.diagonal().amax().sqrt();
        mean = mean.max((dv(estimate.state()) - &x).amax() / x.amax().max(spread));
        cov = cov.max(rel(&dm(estimate.covariance()), &p, 0.0));
    }
    let reference = stacked.log_density();
    let ll = (out.log_likelihood - reference).abs() / reference.abs();
    (mean, cov, ll)
}

#[test]
fn batch_smoother_equals_joint_gaussian_conditioning_without_correlation() {
    for seed in [4, 5, 6] {
        let plan = make_plan(shape(30, 0.6, false), seed);
        assert!(plan.steps.iter().any(|s| s.meas.is_none()));
        let (mean, cov, ll) = smoothing_errors(&plan);
        eprintln!("seed {seed}: mean {mean:.2e} cov {cov:.2e} ll {ll:.2e}");
        assert!(mean < 1e-9 && cov < 1e-9 && ll < 1e-9);
    }
}

#[test]
fn batch_smoother_equals_joint_gaussian_conditioning_with_correlated_noise() {
    for seed in [7, 8, 9] {
        let plan = make_plan(shape(30, 1.0, true), seed);
        assert!(plan.steps.iter().all(|s| s.meas.is_some()));
        let (mean, cov, ll) = smoothing_errors(&plan);
        eprintln!("seed {seed}: mean {mean:.2e} cov {cov:.2e} ll {ll:.2e}");
        assert!(mean < 1e-9 && cov < 1e-9 && ll < 1e-9);
    }
}

#[test]
fn batch_smoother_refuses_what_it_cannot_smooth() {
    let plan = make_plan(shape(10, 1.0, true), 10);
    let (kf, mut ys, cross) = setup(&plan);
    // A correlated update after an unmeasured step (two predicts, one epoch each).
    ys[3] = None;
    assert!(matches!(
        kf.smooth_batch(&ys, &cross),
        Err(Error::SmootherUnsupported { .. })
    ));
    // A correlated first update when the filter had already predicted.
    let (mut kf, ys, cross) = setup(&plan);
    kf.predict().expect("predict");
    assert!(matches!(
        kf.smooth_batch(&ys, &cross),
        Err(Error::SmootherUnsupported { epoch: 1, .. })
    ));
    // ... which is fine without correlation.
    assert!(kf.smooth_batch(&ys, &Zero).is_ok());
    // A bad measurement is the filter's typed error.
    let (kf, mut ys, cross) = setup(&plan);
    ys[2] = Some(SVector::from_element(f64::NAN));
    assert!(matches!(
        kf.smooth_batch(&ys, &cross),
        Err(Error::NonFinite { .. })
    ));
    let mut kf = kf;
    assert!(matches!(
        kf.filter_batch(&ys, &cross),
        Err(Error::NonFinite { .. })
    ));
    // The steps before the failing one stay committed, as in a loop.
    assert_eq!(kf.propagations_since_update(), 1);
}
