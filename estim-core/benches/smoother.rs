//! Cost of the RTS smoother beside the filter it records: a 15-state model with a
//! 3-dimensional correlated measurement (M != 0), 200 epochs of
//! (a) one predict + one update, (b) 100 predicts + one update (the INS pattern,
//! recorded at updates).
//!
//! Lines: the forward EKF alone; the forward EKF with a `ForwardRecorder`; the
//! fixed-interval smoother over the recording; fixed lag 10 over the recording; the
//! forward EKF with the online `FixedLagSmoother` (lag 10).
//!
//! (c) 200 x (10 predicts + one windowed update whose noise shares the 10 steps,
//! D_j = Q B' / sqrt(10)), recorded at every step: each window spans 10 epochs, so the
//! recorder augments them (the module docs of `estim_core::smoother`). Lines: the
//! forward EKF alone, with a `ForwardRecorder`, and the smoother over the recording.
//!
//! Run: `cargo bench -p estim-core --bench smoother`.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use estim_core::nalgebra::{SMatrix, SVector};
use estim_core::smoother::{FixedLagSmoother, ForwardRecorder, RecordAt};
use estim_core::window::StepWindow;
use estim_core::{
    ExtendedKalmanFilter, FilterConfig, Fixed, NoObserver, Observer, Result, StateAndCovariance,
    WindowedCrossCovariance,
};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

const EPOCHS: usize = 200;
/// Steps per windowed update (and the window's length) in case (c).
const WINDOW: usize = 10;

/// Every step of the window shares D_j with the measurement.
struct Shared(SMatrix<f64, N, M>);

impl WindowedCrossCovariance<f64, SVector<f64, N>, (), N, M> for Shared {
    fn window_steps(&self) -> usize {
        WINDOW
    }
    fn step_cross_covariances(
        &self,
        window: &StepWindow<'_, f64, SVector<f64, N>, (), N>,
        sink: &mut dyn FnMut(&SMatrix<f64, N, M>) -> Result<()>,
    ) -> Result<()> {
        (0..window.len()).try_for_each(|_| sink(&self.0))
    }
}

/// Case (c): WINDOW predicts, then a windowed update over them.
fn forward_windowed<O: Observer<f64, SVector<f64, N>, N>>(s: &Setup, observer: O) -> O {
    let process = Linear {
        phi: s.process_f,
        q: s.process_q,
    };
    let config = FilterConfig::builder()
        .window_capacity(WINDOW)
        .build()
        .expect("config");
    let mut ekf = ExtendedKalmanFilter::new(process, s.initial.clone())
        .with_config(config)
        .with_observer(observer);
    let shared = Shared(s.step_cross);
    for y in &s.ys {
        for _ in 0..WINDOW {
            ekf.predict(&(), 0.01).expect("predict");
        }
        ekf.update_windowed(&s.measurement, y, &shared)
            .expect("update");
    }
    ekf.into_observer()
}

mod common;
use common::{Dense as Linear, Sensor as Observe, M, N};

struct Setup {
    process_f: SMatrix<f64, N, N>,
    process_q: SMatrix<f64, N, N>,
    measurement: Observe,
    cross: Fixed<f64, N, M>,
    /// D_j of the windowed case: the same v = B w + e shared evenly over the window.
    step_cross: SMatrix<f64, N, M>,
    initial: StateAndCovariance<f64, N>,
    ys: Vec<SVector<f64, M>>,
}

fn setup() -> Setup {
    let mut rng = ChaCha8Rng::seed_from_u64(15);
    let mut draw = || rng.random_range(-1.0..1.0);
    let f = SMatrix::<f64, N, N>::identity() + SMatrix::from_fn(|_, _| draw()) * (0.1 / N as f64);
    let g = SMatrix::<f64, N, N>::from_fn(|_, _| draw()) * 0.1;
    let q = g * g.transpose() + SMatrix::identity() * 1e-4;
    let h = SMatrix::<f64, M, N>::from_fn(|_, _| draw());
    // v = B w + e: a valid joint covariance with M = Q B'.
    let b = SMatrix::<f64, M, N>::from_fn(|_, _| draw()) * 0.2;
    let r = b * q * b.transpose() + SMatrix::identity() * 0.01;
    let ys = (0..EPOCHS)
        .map(|_| SVector::from_fn(|_, _| draw()))
        .collect();
    Setup {
        process_f: f,
        process_q: q,
        measurement: Observe { h, r },
        cross: Fixed(q * b.transpose()),
        step_cross: q * b.transpose() / (WINDOW as f64).sqrt(),
        initial: StateAndCovariance::new(SVector::zeros(), SMatrix::identity()).expect("initial"),
        ys,
    }
}

fn forward<O: Observer<f64, SVector<f64, N>, N>>(s: &Setup, predicts: usize, observer: O) -> O {
    let process = Linear {
        phi: s.process_f,
        q: s.process_q,
    };
    let mut ekf = ExtendedKalmanFilter::new(process, s.initial.clone()).with_observer(observer);
    for y in &s.ys {
        for _ in 0..predicts {
            ekf.predict(&(), 0.01).expect("predict");
        }
        ekf.update(&s.measurement, y, &s.cross).expect("update");
    }
    ekf.into_observer()
}

fn bench(c: &mut Criterion) {
    let s = setup();
    for (predicts, label) in [(1usize, "1 predict"), (100, "100 predicts")] {
        let mode = if predicts == 1 {
            RecordAt::EveryStep
        } else {
            RecordAt::Updates
        };
        c.bench_function(
            &format!("EKF (15,3) forward, 200 x ({label} + 1 update)"),
            |b| b.iter(|| black_box(forward(&s, predicts, NoObserver))),
        );
        c.bench_function(
            &format!("EKF (15,3) forward + ForwardRecorder, 200 x ({label} + 1 update)"),
            |b| b.iter(|| black_box(forward(&s, predicts, ForwardRecorder::new(mode)).len())),
        );
        let recorder = forward(&s, predicts, ForwardRecorder::new(mode));
        c.bench_function(
            &format!("RTS smooth (15,3), 200 epochs ({label} per update)"),
            |b| b.iter(|| black_box(recorder.smooth().expect("smooth").len())),
        );
        c.bench_function(
            &format!("fixed lag 10 over the recording (15,3), 200 epochs ({label} per update)"),
            |b| b.iter(|| black_box(recorder.fixed_lag(10).expect("lag").len())),
        );
        c.bench_function(
            &format!("EKF (15,3) forward + online FixedLagSmoother lag 10 ({label} + 1 update)"),
            |b| {
                b.iter(|| {
                    let online =
                        forward(&s, predicts, FixedLagSmoother::new(mode, 10).expect("lag"));
                    black_box(online.finish().expect("finish").len())
                })
            },
        );
    }
    let label = "200 x (10 predicts + 1 windowed update over them)";
    c.bench_function(&format!("EKF (15,3) forward, {label}"), |b| {
        b.iter(|| black_box(forward_windowed(&s, NoObserver)))
    });
    c.bench_function(
        &format!("EKF (15,3) forward + ForwardRecorder, {label}"),
        |b| {
            b.iter(|| {
                black_box(forward_windowed(&s, ForwardRecorder::new(RecordAt::EveryStep)).len())
            })
        },
    );
    let recorder = forward_windowed(&s, ForwardRecorder::new(RecordAt::EveryStep));
    c.bench_function(&format!("RTS smooth (15,3), 2000 epochs, {label}"), |b| {
        b.iter(|| black_box(recorder.smooth().expect("smooth").len()))
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .measurement_time(Duration::from_secs(2))
        .warm_up_time(Duration::from_millis(500))
        .sample_size(20);
    targets = bench
}
criterion_main!(benches);
