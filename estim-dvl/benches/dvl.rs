//! Speed of the beam solutions, the DVL measurement Jacobian and a calibration.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use estim_core::MeasurementModel;
use estim_dvl::nalgebra::{Rotation3, UnitQuaternion, Vector3, Vector4};
use estim_dvl::{BeamGeometry, Calibrator, DvlMeasurement, DvlVelocityModel, TrajectorySample};
use estim_ins::InsState;

fn beams(c: &mut Criterion) {
    let g = BeamGeometry::rdi_workhorse_navigator();
    let b = g.beams(&Vector3::new(1.9, -0.2, 0.05));
    c.bench_function("solve 4 beams", |bench| {
        bench.iter(|| g.solve(black_box(&[Some(b[0]), Some(b[1]), Some(b[2]), Some(b[3])])))
    });
    c.bench_function("solve 3 beams", |bench| {
        bench.iter(|| g.solve_nan(black_box(&Vector4::new(b[0], f64::NAN, b[2], b[3]))))
    });
}

fn measurement(c: &mut Criterion) {
    let model = DvlVelocityModel::builder()
        .lever_arm(Vector3::new(-1.85, 0.0, 0.2))
        .noise_std(0.02)
        .build()
        .unwrap();
    let state = InsState {
        time: 0.0,
        latitude: 0.57,
        longitude: 0.61,
        height: -20.0,
        velocity_ned: Vector3::new(1.5, -0.8, 0.02),
        attitude: UnitQuaternion::from_euler_angles(0.01, -0.02, 2.0),
        acc_bias: Vector3::zeros(),
        gyro_bias: Vector3::zeros(),
        angular_rate: Vector3::new(0.001, 0.002, 0.05),
    };
    c.bench_function("DVL predict + jacobian", |bench| {
        bench.iter(|| {
            (
                model.predict(black_box(&state)).unwrap(),
                model.jacobian(black_box(&state)).unwrap(),
            )
        })
    });
}

fn calibration(c: &mut Criterion) {
    let n = 400;
    let yaw = |t: f64| 0.6 * (t / 13.0).sin();
    let gt: Vec<TrajectorySample> = (0..n)
        .map(|i| {
            let t = i as f64;
            let rpy = Vector3::new(0.02 * (t / 5.0).sin(), 0.03 * (t / 7.0).cos(), yaw(t));
            TrajectorySample {
                time: t,
                velocity_ned: Rotation3::from_euler_angles(rpy.x, rpy.y, rpy.z)
                    * Vector3::new(2.0 + 0.2 * (t / 9.0).sin(), 0.05, 0.01),
                roll_pitch_yaw: rpy,
            }
        })
        .collect();
    let dvl: Vec<DvlMeasurement> = (0..n)
        .map(|i| {
            let t = i as f64;
            let r = 0.6 / 13.0 * (t / 13.0).cos();
            DvlMeasurement {
                time: t,
                velocity: Vector3::new(2.0 + 0.2 * (t / 9.0).sin(), 0.05 - 1.5 * r, 0.01),
            }
        })
        .collect();
    let calibrator = Calibrator::builder().build().unwrap();
    let mut group = c.benchmark_group("calibration");
    group.sample_size(10);
    group.bench_function("400 samples, 8 parameters", |bench| {
        bench.iter(|| {
            calibrator
                .calibrate(black_box(&gt), black_box(&dvl))
                .unwrap()
        })
    });
    group.finish();
}

criterion_group!(benches, beams, measurement, calibration);
criterion_main!(benches);
