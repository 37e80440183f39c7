//! Cost of the exact windowed cross-covariance: 15 states, 100 predicts + 1 update
//! (3 measurements), with a 100-step window, against the same cycle without it.
//!
//! `cargo bench -p estim-core --bench windowed`

use criterion::{criterion_group, criterion_main, Criterion};
use estim_core::nalgebra::{SMatrix, SVector};
use estim_core::window::StepWindow;
use estim_core::{
    ExtendedKalmanFilter, FilterConfig, JointCheck, Result, StateAndCovariance,
    WindowedCrossCovariance, Zero,
};
use std::hint::black_box;

const STEPS: usize = 100;

mod common;
use common::{Dense, Sensor, M, N};

struct PerStep(SMatrix<f64, N, M>);

impl WindowedCrossCovariance<f64, SVector<f64, N>, (), N, M> for PerStep {
    fn window_steps(&self) -> usize {
        STEPS
    }
    fn step_cross_covariances(
        &self,
        window: &StepWindow<'_, f64, SVector<f64, N>, (), N>,
        sink: &mut dyn FnMut(&SMatrix<f64, N, M>) -> Result<()>,
    ) -> Result<()> {
        for _ in 0..window.len() {
            sink(&self.0)?;
        }
        Ok(())
    }
}

fn setup() -> (Dense, Sensor, PerStep, StateAndCovariance<f64, N>) {
    let phi = SMatrix::<f64, N, N>::from_fn(|i, j| {
        if i == j {
            1.0
        } else {
            1e-3 * ((i * 7 + j * 3) % 11) as f64 / 11.0
        }
    });
    let q = SMatrix::<f64, N, N>::identity() * 1e-6;
    let h = SMatrix::<f64, M, N>::from_fn(|i, j| if j == i + 3 { 1.0 } else { 0.0 });
    let r = SMatrix::<f64, M, M>::identity() * 1e-2;
    // A small per-step D (valid: |D| << sqrt(q r) / STEPS).
    let d = SMatrix::<f64, N, M>::from_fn(|i, j| if i == j + 3 { 1e-7 } else { 0.0 });
    let initial =
        StateAndCovariance::new(SVector::zeros(), SMatrix::identity() * 0.1).expect("initial");
    (Dense { phi, q }, Sensor { h, r }, PerStep(d), initial)
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("windowed_15x3_100_predicts_1_update");
    let y = SVector::<f64, M>::new(0.01, -0.02, 0.005);
    for (name, capacity, accumulate, windowed) in [
        ("no window, Q_acc tracked, M = 0 (before)", 0, true, false),
        ("no window, no Q_acc, M = 0", 0, false, false),
        ("exact M over a 100-step window", STEPS, false, true),
    ] {
        let (process, sensor, cross, initial) = setup();
        let config = FilterConfig::builder()
            .window_capacity(capacity)
            .track_accumulated_noise(accumulate)
            .joint_check(JointCheck::Skip)
            .build()
            .expect("config");
        let mut ekf = ExtendedKalmanFilter::new(process, initial.clone()).with_config(config);
        group.bench_function(name, |b| {
            b.iter(|| {
                for _ in 0..STEPS {
                    ekf.predict(&(), 0.01).expect("predict");
                }
                let report = if windowed {
                    ekf.update_windowed(&sensor, &y, &cross)
                } else {
                    ekf.update(&sensor, &y, &Zero)
                };
                black_box(report.expect("update"));
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
