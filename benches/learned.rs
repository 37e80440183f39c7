//! BeamsNet inference latency and the cost of NetworkSensitivity per update (adjoint
//! form over the window an error-state filter recorded).
//!
//! `cargo bench --bench learned`; the ratio sensitivity / inference is the number the
//! estim-learned README reports (goal <= 20). Measured in the benchmark thread's CPU
//! time (`benches/common`; tract runs single-threaded here), so the shared machine's
//! load does not enter the figures.

mod common;

use common::ThreadCpuTime;
use criterion::{criterion_group, criterion_main, Criterion};
use estim_core::nalgebra::{SMatrix, Vector4};
use estim_core::{ErrorStateKalmanFilter, FilterConfig, WindowedCrossCovariance};
use estim_ins::{ImuSpec, InsErrorModel, Mission, MissionConfig, ERROR_STATES};
use estim_learned::{BeamsNet, BeamsNetInput, NetworkSensitivity, BEAMSNET_WINDOW};

fn bench(c: &mut Criterion<ThreadCpuTime>) {
    let config = MissionConfig::builder().duration(5.0).build().unwrap();
    let mission = Mission::generate(&config, 3).unwrap();
    let imu = &mission.imu[..BEAMSNET_WINDOW];
    let beams = Vector4::new(0.7, 0.7, 0.6, 0.6);
    let beamsnet = BeamsNet::load_default().unwrap();
    let force: Vec<_> = imu.iter().map(|s| s.specific_force).collect();
    let rate: Vec<_> = imu.iter().map(|s| s.angular_rate).collect();
    let input = BeamsNetInput::from_samples(&force, &rate, beams);
    c.bench_function("beamsnet_single_inference", |b| {
        b.iter(|| beamsnet.velocity(std::hint::black_box(&input)).unwrap())
    });
    let mut filter = ErrorStateKalmanFilter::new(
        InsErrorModel::new(ImuSpec::akit_observed()),
        mission.truth[0],
        SMatrix::<f64, ERROR_STATES, ERROR_STATES>::identity() * 1e-6,
    )
    .unwrap()
    .with_config(
        FilterConfig::builder()
            .window_capacity(BEAMSNET_WINDOW)
            .build()
            .unwrap(),
    );
    for s in imu {
        filter.predict(s, mission.imu_dt).unwrap();
    }
    let window = filter.step_window(BEAMSNET_WINDOW).unwrap();
    // Built once and kept, as a filter keeps it from one update to the next (its
    // workspace is reused; the beams would be set per update with `set_beams`).
    let sensitivity = NetworkSensitivity::new(&beamsnet, filter.process(), beams).unwrap();
    c.bench_function("network_sensitivity_per_update", |b| {
        b.iter(|| {
            sensitivity
                .transported_cross_covariance(std::hint::black_box(&window))
                .unwrap()
        })
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().with_measurement(ThreadCpuTime);
    targets = bench
}
criterion_main!(benches);
