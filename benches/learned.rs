//! BeamsNet inference latency and the cost of NetworkSensitivity per update.
//!
//! `cargo bench --bench learned`; the ratio sensitivity / inference is the number the
//! estim-learned README reports (goal <= 20).

use criterion::{criterion_group, criterion_main, Criterion};
use estim_core::nalgebra::Vector4;
use estim_ins::{ImuSpec, InsErrorModel, Mission, MissionConfig};
use estim_learned::{BeamsNet, BeamsNetInput, ImuWindow, NetworkSensitivity};

fn window() -> ImuWindow {
    let config = MissionConfig::builder().duration(5.0).build().unwrap();
    let mission = Mission::generate(&config, 3).unwrap();
    ImuWindow {
        states: mission.truth[..100].to_vec(),
        imu: mission.imu[..100].to_vec(),
        beams: Vector4::new(0.7, 0.7, 0.6, 0.6),
        dt: mission.imu_dt,
    }
}

fn bench(c: &mut Criterion) {
    let beamsnet = BeamsNet::load_default().unwrap();
    let w = window();
    let force: Vec<_> = w.imu.iter().map(|s| s.specific_force).collect();
    let rate: Vec<_> = w.imu.iter().map(|s| s.angular_rate).collect();
    let input = BeamsNetInput::from_samples(&force, &rate, w.beams);
    c.bench_function("beamsnet_single_inference", |b| {
        b.iter(|| beamsnet.velocity(std::hint::black_box(&input)).unwrap())
    });
    let sensitivity = NetworkSensitivity::new(
        beamsnet.clone(),
        InsErrorModel::new(ImuSpec::akit_observed()),
    );
    c.bench_function("network_sensitivity_per_update", |b| {
        b.iter(|| sensitivity.compute(std::hint::black_box(&w)).unwrap())
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
