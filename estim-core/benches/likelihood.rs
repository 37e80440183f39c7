//! Cost of one maximum-likelihood evaluation (`noise::ml`) on the 4-state model of
//! `tests/noise_ml.rs`: a position fix every 4 steps sharing the accelerations of a
//! 3-step window (windowed M), 300 fixes (1,200 predicts), theta = [q_x, q_y, r, c].
//!
//! Lines: the log-likelihood in `f64` (one filter pass); value and gradient (4
//! `Dual64` passes); the observed information (10 `HyperDual64` passes); one whole fit
//! from a distant start (L-BFGS and Newton steps, standard errors).
//!
//! Run: `cargo bench -p estim-core --bench likelihood`.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use estim_core::nalgebra::SVector;
use estim_core::noise::ml::{
    gradient, maximize, observed_information, Bounds, FitOptions, LogLikelihood,
};

#[path = "../tests/common/shared_noise.rs"]
mod shared_noise;
use shared_noise::{Dataset, Setup};

fn bench(c: &mut Criterion) {
    let data = Dataset::simulate(Setup::default(), [0.5, 0.2, 0.0025, 0.6], 1000);
    let theta = SVector::from([0.5, 0.2, 0.0025, 0.6]);
    let free = [false; 4];
    c.bench_function("log-likelihood, 4 states, 300 windowed fixes (f64)", |b| {
        b.iter(|| data.log_likelihood(black_box(&theta)))
    });
    c.bench_function("log-likelihood + gradient (4 dual passes)", |b| {
        b.iter(|| gradient(&data, black_box(&theta), &free))
    });
    c.bench_function("observed information (10 hyper-dual passes)", |b| {
        b.iter(|| observed_information(&data, black_box(&theta), &free))
    });
    let bounds = Bounds::new(
        SVector::from([0.0, 0.0, 0.0, -10.0]),
        SVector::from([f64::INFINITY, f64::INFINITY, f64::INFINITY, 10.0]),
    )
    .expect("bounds");
    let start = SVector::from([1.0, 1.0, 0.01, 0.1]);
    let mut group = c.benchmark_group("fit");
    group.sample_size(10);
    group.bench_function(
        "maximize from [1, 1, 0.01, 0.1] with standard errors",
        |b| b.iter(|| maximize(&data, black_box(&start), &bounds, &FitOptions::default())),
    );
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
