//! `estim::navigator::tune` on a simulated 400 s / 100 Hz INS mission with a DVL update
//! every second (400 epochs): one log-likelihood plus its gradient over the five noise
//! parameters (f64 value, five dual-number passes), the log-likelihood alone, and the
//! linearization (the error-state filter run once, with Q_d split into its parts).
//!
//! Run: `cargo bench --bench tune`. Times are the benchmark thread's CPU time (see
//! benches/common).

use std::hint::black_box;
use std::time::Duration;

mod common;
use common::ThreadCpuTime;

#[path = "../tests/tune_mission/mod.rs"]
mod tune_mission;

use criterion::{criterion_group, criterion_main, Criterion};
use estim::navigator::tune::{linearize, InsDvlLikelihood, M_SCALE};
use estim_core::noise::ml::{gradient, LogLikelihood};

fn benches(c: &mut Criterion<ThreadCpuTime>) {
    let m = tune_mission::mission(400.0, 7);
    let mut theta = m.truth;
    let first = linearize(&m.trajectory(), &m.model, &theta).expect("linearization");
    theta[M_SCALE] = 0.3 * first.largest_valid_rho;
    let linearizations = [linearize(&m.trajectory(), &m.model, &theta).expect("linearization")];
    let likelihood = InsDvlLikelihood {
        beam_covariance: m.model.beam_covariance(),
        trajectories: &linearizations,
    };
    let mut g = c.benchmark_group("tune_400s_mission");
    g.sample_size(10);
    g.bench_function("log_likelihood_and_gradient", |b| {
        b.iter(|| {
            black_box(gradient(&likelihood, black_box(&theta), &[false; 5]).expect("gradient"))
        })
    });
    g.bench_function("log_likelihood", |b| {
        b.iter(|| black_box(likelihood.log_likelihood(black_box(&theta)).expect("value")))
    });
    g.bench_function("linearize", |b| {
        b.iter(|| black_box(linearize(&m.trajectory(), &m.model, black_box(&theta)).expect("run")))
    });
    g.finish();
}

criterion_group! {
    name = tune;
    config = Criterion::default()
        .with_measurement(ThreadCpuTime)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3));
    targets = benches
}
criterion_main!(tune);
