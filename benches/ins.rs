//! estim-ins throughput: strapdown mechanization, mechanization + 15x15 covariance
//! propagation, a whole 400 s / 100 Hz mission, and the peer crate `eskf` 0.2 predicting
//! at the same rate (18-state, f32, flat Earth, dense covariance).
//!
//! Run: `cargo bench --bench ins`.
//!
//! Times are the benchmark thread's CPU time (`CLOCK_THREAD_CPUTIME_ID` on Linux, wall
//! clock elsewhere): the shared development machine runs several compilers at once and
//! wall-clock figures there measure the load, not the code.

use std::hint::black_box;
use std::time::Duration;

mod common;
use common::ThreadCpuTime;

use criterion::{criterion_group, criterion_main, Criterion};
use estim_core::ProcessModel;
use estim_ins::{ErrorMatrix, ImuSpec, InsErrorModel, Mechanization, Mission, MissionConfig};

fn benches(c: &mut Criterion<ThreadCpuTime>) {
    let mission = Mission::generate(&MissionConfig::default(), 7).expect("default mission");
    let dt = mission.imu_dt;
    let model = InsErrorModel::new(ImuSpec::akit_observed());
    let mech = Mechanization::new();
    let start = mission.truth[0];
    let p0 = ErrorMatrix::from_diagonal(&nalgebra::SVector::<f64, 15>::from_fn(|i, _| {
        [1.0, 1e-2, 1e-6, 1e-6, 1e-10][i / 3]
    }));
    let n = mission.imu.len();

    let mut g = c.benchmark_group("ins_step");
    g.throughput(criterion::Throughput::Elements(1));
    g.bench_function("mechanization", |b| {
        let mut s = start;
        let mut k = 0;
        b.iter(|| {
            s = mech.step(&s, &mission.imu[k], dt).expect("step");
            k = (k + 1) % n;
            if k == 0 {
                s = start;
            }
            black_box(&s);
        });
    });
    let imu0 = mission.imu[100];
    let s100 = mission.truth[100];
    g.bench_function("transition_and_noise (Phi, Q)", |b| {
        b.iter(|| black_box(model.transition_and_noise(black_box(&s100), &imu0, dt)));
    });
    let (phi, q) = model.transition_and_noise(&s100, &imu0, dt);
    let p_full = {
        let l = ErrorMatrix::from_fn(|i, j| ((i * 7 + j * 3) % 11) as f64 * 0.01);
        l * l.transpose() + p0
    };
    g.bench_function("propagate_covariance (structured)", |b| {
        b.iter(|| black_box(model.propagate_covariance(black_box(&p_full), &phi, &q)));
    });
    g.bench_function("propagate_covariance (dense Phi P Phi' + Q)", |b| {
        b.iter(|| black_box(black_box(phi) * p_full * phi.transpose() + q));
    });
    g.bench_function(
        "predict_covariance (in place: Phi, Q, structured propagation)",
        |b| {
            let mut p = p_full;
            b.iter(|| {
                model.predict_covariance(black_box(&s100), &imu0, dt, &mut p);
                black_box(&p);
            });
        },
    );
    g.bench_function("mechanization+covariance (sparse)", |b| {
        let (mut s, mut p, mut k) = (start, p0, 0);
        b.iter(|| {
            let imu = &mission.imu[k];
            let (phi, q) = model.transition_and_noise(&s, imu, dt);
            p = model.propagate_covariance(&p, &phi, &q);
            s = mech.step(&s, imu, dt).expect("step");
            k = (k + 1) % n;
            if k == 0 {
                (s, p) = (start, p0);
            }
            black_box(&p);
        });
    });
    g.bench_function("mechanization+covariance (dense)", |b| {
        let (mut s, mut p, mut k) = (start, p0, 0);
        b.iter(|| {
            let imu = &mission.imu[k];
            let (phi, q) = model.transition_and_noise(&s, imu, dt);
            p = phi * p * phi.transpose() + q;
            s = mech.step(&s, imu, dt).expect("step");
            k = (k + 1) % n;
            if k == 0 {
                (s, p) = (start, p0);
            }
            black_box(&p);
        });
    });
    g.bench_function("eskf 0.2 predict (peer)", |b| {
        let mut filter = eskf::Builder::new()
            .acceleration_variance(0.03f32 * 0.03)
            .rotation_variance(5e-4f32 * 5e-4)
            .acceleration_bias(1e-6)
            .rotation_bias(1e-8)
            .initial_covariance(1e-3)
            .build();
        let fresh = filter;
        // eskf's own nalgebra 0.25 vectors, taken from its public fields.
        let (mut acc, mut rot) = (filter.velocity, filter.velocity);
        let mut k = 0;
        b.iter(|| {
            let imu = &mission.imu[k];
            acc.x = imu.specific_force.x as f32;
            acc.y = imu.specific_force.y as f32;
            acc.z = imu.specific_force.z as f32;
            rot.x = imu.angular_rate.x as f32;
            rot.y = imu.angular_rate.y as f32;
            rot.z = imu.angular_rate.z as f32;
            filter.predict(acc, rot, Duration::from_millis(10));
            k = (k + 1) % n;
            if k == 0 {
                filter = fresh;
            }
            black_box(&filter);
        });
    });
    g.finish();

    let mut g = c.benchmark_group("ins_mission_400s_100hz");
    g.sample_size(10);
    g.bench_function("mechanization+covariance every step", |b| {
        b.iter(|| {
            let (mut s, mut p) = (start, p0);
            for imu in &mission.imu {
                model.predict_covariance(&s, imu, dt, &mut p);
                s = mech.step_unchecked(&s, imu, dt);
            }
            black_box((s, p))
        });
    });
    // The same through the two trait calls a runner makes (Phi and Q_d returned, P
    // returned by value): bit-for-bit the same P.
    g.bench_function(
        "mechanization+covariance every step (transition_and_noise + propagate_covariance)",
        |b| {
            b.iter(|| {
                let (mut s, mut p) = (start, p0);
                for imu in &mission.imu {
                    let (phi, q) = model.transition_and_noise(&s, imu, dt);
                    p = model.propagate_covariance(&p, &phi, &q);
                    s = mech.step_unchecked(&s, imu, dt);
                }
                black_box((s, p))
            });
        },
    );
    g.bench_function("mechanization 100 Hz + covariance 10 Hz", |b| {
        b.iter(|| {
            let (mut s, mut p) = (start, p0);
            for block in mission.imu.chunks(10) {
                // Phi and Q over the block from its first sample (see README for the cost).
                let span = dt * block.len() as f64;
                let (phi, q) = model.transition_and_noise(&s, &block[0], span);
                p = model.propagate_covariance(&p, &phi, &q);
                for imu in block {
                    s = mech.step_unchecked(&s, imu, dt);
                }
            }
            black_box((s, p))
        });
    });
    g.bench_function("eskf 0.2 predict x 40000 (peer)", |b| {
        let proto = eskf::Builder::new()
            .acceleration_variance(0.03f32 * 0.03)
            .rotation_variance(5e-4f32 * 5e-4)
            .initial_covariance(1e-3)
            .build();
        b.iter(|| {
            let mut filter = proto;
            let (mut acc, mut rot) = (filter.velocity, filter.velocity);
            for imu in &mission.imu {
                acc.x = imu.specific_force.x as f32;
                acc.y = imu.specific_force.y as f32;
                acc.z = imu.specific_force.z as f32;
                rot.x = imu.angular_rate.x as f32;
                rot.y = imu.angular_rate.y as f32;
                rot.z = imu.angular_rate.z as f32;
                filter.predict(acc, rot, Duration::from_millis(10));
            }
            black_box(filter)
        });
    });
    g.finish();
}

criterion_group! {
    name = ins;
    config = Criterion::default()
        .with_measurement(ThreadCpuTime)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3));
    targets = benches
}
criterion_main!(ins);
