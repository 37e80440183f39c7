//! estim-ins throughput: strapdown mechanization, mechanization + 15x15 covariance
//! propagation, a whole 400 s / 100 Hz mission, and the peer crate `eskf` 0.2 predicting
//! at the same rate (18-state, f32, flat Earth, dense covariance). Then the same mission
//! through the error-state filter with a learned-style DVL velocity update every second:
//! M = 0 (default configuration, and without the Q_acc / Phi_acc accumulation) and the
//! exact windowed M over the last 100 predicts.
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
use estim_core::nalgebra::SMatrix;
use estim_core::window::StepWindow;
use estim_core::{
    ErrorStateKalmanFilter, FilterConfig, MeasurementModel, ProcessModel, WindowedCrossCovariance,
    Zero,
};
use estim_dvl::DvlVelocityModel;
use estim_ins::{
    ErrorMatrix, ImuSample, ImuSpec, InsErrorModel, InsState, Mechanization, Mission,
    MissionConfig, SimulatedMission, ERROR_STATES,
};

/// Predicts per learned-style update (1 Hz against the 100 Hz IMU) and the window its
/// noise shares with the process noise.
const WINDOW: usize = 100;

/// A learned-style body-velocity measurement whose error contains β times the mean
/// accelerometer noise of the last `WINDOW` IMU samples it was computed from (as a
/// network fed with the raw IMU window would): v = β/L Σ_j w_a,j + independent part.
/// The velocity error of step j gains -C_b^n,j w_a,j dt, and w_a,j has per-sample
/// covariance q_a/dt I, so D_j = Cov(G_j w_j, v) = -(β q_a / L) C_b^n,j in the velocity
/// rows (state recorded by the filter before step j).
struct SharedAccelerometerNoise {
    /// β q_a / L.
    weight: f64,
}

impl WindowedCrossCovariance<f64, InsState, ImuSample, ERROR_STATES, 3>
    for SharedAccelerometerNoise
{
    fn window_steps(&self) -> usize {
        WINDOW
    }

    fn step_cross_covariances(
        &self,
        window: &StepWindow<'_, f64, InsState, ImuSample, ERROR_STATES>,
        sink: &mut dyn FnMut(&SMatrix<f64, ERROR_STATES, 3>) -> estim_core::Result<()>,
    ) -> estim_core::Result<()> {
        for step in window.iter() {
            let c_bn = step.state.attitude.to_rotation_matrix().into_inner();
            let mut d = SMatrix::<f64, ERROR_STATES, 3>::zeros();
            d.fixed_view_mut::<3, 3>(3, 0)
                .copy_from(&(c_bn * -self.weight));
            sink(&d)?;
        }
        Ok(())
    }
}

/// The default 400 s mission and the filter's start, shared by the groups.
struct Setup {
    mission: SimulatedMission,
    dt: f64,
    model: InsErrorModel,
    mech: Mechanization,
    start: InsState,
    p0: ErrorMatrix,
    n: usize,
}

impl Setup {
    fn new() -> Self {
        let mission = Mission::generate(&MissionConfig::default(), 7).expect("default mission");
        let p0 = ErrorMatrix::from_diagonal(&nalgebra::SVector::<f64, 15>::from_fn(|i, _| {
            [1.0, 1e-2, 1e-6, 1e-6, 1e-10][i / 3]
        }));
        Self {
            dt: mission.imu_dt,
            model: InsErrorModel::new(ImuSpec::akit_observed()),
            mech: Mechanization::new(),
            start: mission.truth[0],
            n: mission.imu.len(),
            p0,
            mission,
        }
    }
}

fn benches(c: &mut Criterion<ThreadCpuTime>) {
    let setup = Setup::new();
    step_benches(c, &setup);
    mission_benches(c, &setup);
    filter_benches(c, &setup);
}

/// One IMU step's parts, and the peer's predict.
fn step_benches(c: &mut Criterion<ThreadCpuTime>, setup: &Setup) {
    let (mission, model, mech) = (&setup.mission, &setup.model, &setup.mech);
    let (dt, start, p0, n) = (setup.dt, setup.start, setup.p0, setup.n);
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
}

/// The whole 400 s mission, and the peer's.
fn mission_benches(c: &mut Criterion<ThreadCpuTime>, setup: &Setup) {
    let (mission, model, mech) = (&setup.mission, &setup.model, &setup.mech);
    let (dt, start, p0) = (setup.dt, setup.start, setup.p0);
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

/// The error-state filter over the same mission with a learned-style DVL velocity
/// update every second (WINDOW predicts), without and with the exact windowed M.
fn filter_benches(c: &mut Criterion<ThreadCpuTime>, setup: &Setup) {
    let mission = &setup.mission;
    let (dt, start, p0, n) = (setup.dt, setup.start, setup.p0, setup.n);
    let spec = ImuSpec::akit_observed();
    let dvl = DvlVelocityModel::builder()
        .lever_arm(nalgebra::Vector3::new(0.5, 0.0, 0.3))
        .noise_std(0.02)
        .build()
        .expect("DVL model");
    // β = 1: the whole mean accelerometer noise of the window (variance q_a/(L dt) =
    // 9e-6 (m/s)^2, inside R = 4e-4, so the joint covariance is valid).
    let cross = SharedAccelerometerNoise {
        weight: spec.continuous_noise_psd()[0] / WINDOW as f64,
    };
    let measurements: Vec<_> = (1..=n / WINDOW)
        .map(|u| dvl.predict(&mission.truth[u * WINDOW]).expect("DVL"))
        .collect();
    let filter = |config: FilterConfig| {
        ErrorStateKalmanFilter::new(InsErrorModel::new(spec), start, p0)
            .expect("filter")
            .with_config(config)
    };
    let mut g = c.benchmark_group("ins_filter_mission_400s_100hz_dvl_1hz");
    g.sample_size(10);
    for (name, config, windowed) in [
        ("default config, M = 0", FilterConfig::default(), false),
        (
            "no accumulation, M = 0",
            FilterConfig::builder()
                .track_accumulated_noise(false)
                .build()
                .expect("config"),
            false,
        ),
        (
            "exact windowed M (100-sample window)",
            FilterConfig::builder()
                .track_accumulated_noise(false)
                .window_capacity(WINDOW)
                .build()
                .expect("config"),
            true,
        ),
    ] {
        let proto = filter(config);
        g.bench_function(name, |b| {
            b.iter(|| {
                let mut f = proto.clone();
                for (k, imu) in mission.imu.iter().enumerate() {
                    f.predict(imu, dt).expect("predict");
                    if (k + 1) % WINDOW == 0 {
                        let y = &measurements[k / WINDOW];
                        let report = if windowed {
                            f.update_windowed(&dvl, y, &cross)
                        } else {
                            f.update(&dvl, y, &Zero)
                        };
                        black_box(report.expect("update"));
                    }
                }
                black_box(f.covariance()[(0, 0)])
            });
        });
    }
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
