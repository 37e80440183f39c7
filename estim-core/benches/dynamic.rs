//! The run-time-sized filter (`estim_core::dynamic::DynKalmanFilter`) at the sizes of
//! issue 47: n = 50 states with m = 10 measurements and n = 200 with m = 20, over a
//! series of 100 steps, every step measured. Lines: `filter_series` (the filter alone)
//! and `filter_and_smooth` (filter + RTS smoother, both results from one call); the
//! time per step is the reported time / 100. Single threaded.
//!
//! Run: `cargo bench -p estim-core --bench dynamic`.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use estim_core::dynamic::{DynKalmanFilter, MeasurementSeries};
use estim_core::nalgebra::{DMatrix, DVector};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

const STEPS: usize = 100;

/// A random stable model of n states and m measurements, seeded, and its series.
fn problem(n: usize, m: usize) -> (DynKalmanFilter, Vec<f64>) {
    let mut rng = ChaCha8Rng::seed_from_u64(47);
    let f = DMatrix::from_fn(n, n, |i, j| {
        if i == j {
            0.97
        } else {
            rng.random_range(-0.01..0.01)
        }
    });
    let g = DMatrix::from_fn(n, n, |_, _| rng.random_range(-0.1..0.1));
    let q = &g * g.transpose() + DMatrix::identity(n, n) * 1e-3;
    let h = DMatrix::from_fn(m, n, |_, _| rng.random_range(-1.0..1.0));
    let r = DMatrix::identity(m, m) * 0.5;
    let ys: Vec<f64> = (0..STEPS * m)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let kf = DynKalmanFilter::new(f, q, h, r, DVector::zeros(n), DMatrix::identity(n, n))
        .expect("valid model");
    (kf, ys)
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("dynamic");
    group
        .measurement_time(Duration::from_secs(5))
        .sample_size(10);
    for (n, m) in [(50, 10), (200, 20)] {
        let (kf, ys) = problem(n, m);
        let series = MeasurementSeries::new(&ys, m).expect("whole rows");
        group.bench_function(format!("filter_series n{n} m{m} x{STEPS}"), |b| {
            b.iter(|| {
                let mut f = kf.clone();
                black_box(f.filter_series(&series, None).expect("filters"))
            })
        });
        group.bench_function(format!("filter_and_smooth n{n} m{m} x{STEPS}"), |b| {
            b.iter(|| black_box(kf.filter_and_smooth(&series, None).expect("smooths")))
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
