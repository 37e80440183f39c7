//! `ImuCalibrator` on simulated logs with known answers: an IMU log made by the
//! trajectory simulator from a dense (0.25 s) analytic truth, mapped through a known
//! axis convention, clock (s, τ) and biases, with seeded white noise; the calibrator
//! sees only the truth at 1 s epochs (so its reference increments come from its own
//! interpolation, not from the simulator's knots).

use std::f64::consts::TAU;

use estim_ins::{
    AxisMap, Error, ImuCalibration, ImuCalibrator, ImuSample, Trajectory, TrajectorySample,
};
use nalgebra::{UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// Per-sample white noise (about the A-KIT IMU's).
const ACC_NOISE: f64 = 0.02;
const GYRO_NOISE: f64 = 3e-4;
const IMU_STEP: f64 = 0.01;

/// Motion of an AUV: turns, speed changes, roll and pitch oscillation, heave.
#[derive(Clone, Copy)]
enum Motion {
    Manoeuvring,
    /// Straight and level at constant speed: nothing separates the axes.
    Straight,
}

fn attitude_and_velocity(motion: Motion, t: f64) -> (UnitQuaternion<f64>, Vector3<f64>) {
    match motion {
        Motion::Manoeuvring => {
            let yaw = 0.3 + 0.9 * (TAU * t / 70.0).sin() + 0.015 * t;
            let roll = 0.04 * (TAU * t / 11.0).sin() + 0.015 * (TAU * t / 5.3).sin();
            let pitch = 0.05 * (TAU * t / 17.0 + 1.0).sin() + 0.01 * (TAU * t / 4.1).sin();
            let speed = 1.5 + 0.3 * (TAU * t / 23.0).sin();
            let velocity = Vector3::new(
                speed * yaw.cos(),
                speed * yaw.sin(),
                0.1 * (TAU * t / 29.0).sin(),
            );
            (
                UnitQuaternion::from_euler_angles(roll, pitch, yaw),
                velocity,
            )
        }
        Motion::Straight => (
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.7),
            Vector3::new(1.5 * 0.7f64.cos(), 1.5 * 0.7f64.sin(), 0.0),
        ),
    }
}

/// The dense truth over [start, end] (reference clock).
fn truth(motion: Motion, start: f64, end: f64) -> Trajectory {
    let n = ((end - start) / 0.25).round() as usize;
    let samples = (0..=n)
        .map(|k| {
            let t = start + 0.25 * k as f64;
            let (attitude, velocity_ned) = attitude_and_velocity(motion, t);
            TrajectorySample {
                time: t,
                latitude: 0.5734,
                longitude: 0.609,
                height: -15.0,
                velocity_ned,
                attitude,
            }
        })
        .collect();
    Trajectory::velocity_driven(samples).expect("truth")
}

/// What a simulated log is made with.
#[derive(Clone, Copy)]
struct Case {
    axes: [&'static str; 3],
    scale: f64,
    offset: f64,
    acc_bias: [f64; 3],
    gyro_bias: [f64; 3],
}

/// (IMU log on the IMU clock in IMU axes, 1 Hz reference epochs) over `span` seconds.
fn simulate(
    case: &Case,
    motion: Motion,
    span: f64,
    seed: u64,
) -> (Vec<ImuSample>, Vec<TrajectorySample>) {
    let truth = truth(motion, -10.0, span + 10.0);
    let to_imu = AxisMap::from_labels(&case.axes)
        .expect("axes")
        .matrix()
        .transpose();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut noise = |sigma: f64| {
        Vector3::from_fn(|_, _| {
            let n: f64 = StandardNormal.sample(&mut rng);
            sigma * n
        })
    };
    let (acc_bias, gyro_bias) = (Vector3::from(case.acc_bias), Vector3::from(case.gyro_bias));
    let samples = (span / IMU_STEP).round() as usize;
    let imu = (0..samples)
        .map(|k| {
            let stamp = IMU_STEP * k as f64;
            // The sample covers [s t_k - τ, s t_{k+1} - τ] on the reference clock.
            let clean = truth
                .imu_sample(case.scale * stamp - case.offset, case.scale * IMU_STEP)
                .expect("inside the truth");
            let f = clean.specific_force + acc_bias + noise(ACC_NOISE);
            let w = clean.angular_rate + gyro_bias + noise(GYRO_NOISE);
            ImuSample::new(stamp, to_imu * f, to_imu * w)
        })
        .collect();
    let reference = (0..=span as usize)
        .map(|j| {
            let s = truth.evaluate(j as f64).expect("inside").state;
            TrajectorySample {
                time: s.time,
                latitude: s.latitude,
                longitude: s.longitude,
                height: s.height,
                velocity_ned: s.velocity_ned,
                attitude: s.attitude,
            }
        })
        .collect();
    (imu, reference)
}

/// (estimate - true) / sigma for s, τ, b_a, b_g.
fn normalised_errors(c: &ImuCalibration, case: &Case) -> [f64; 8] {
    let z = |e: estim_ins::Estimate, truth: f64| (e.value - truth) / e.standard_error;
    [
        z(c.clock_scale, case.scale),
        z(c.time_offset_s, case.offset),
        z(c.accelerometer_bias[0], case.acc_bias[0]),
        z(c.accelerometer_bias[1], case.acc_bias[1]),
        z(c.accelerometer_bias[2], case.acc_bias[2]),
        z(c.gyroscope_bias[0], case.gyro_bias[0]),
        z(c.gyroscope_bias[1], case.gyro_bias[1]),
        z(c.gyroscope_bias[2], case.gyro_bias[2]),
    ]
}

const CASES: [Case; 6] = [
    // A-KIT-like: y reversed, stretched clock, stamps late.
    Case {
        axes: ["x", "-y", "z"],
        scale: 1.0025,
        offset: -0.45,
        acc_bias: [0.03, -0.05, 0.08],
        gyro_bias: [2e-3, -1e-3, 5e-4],
    },
    Case {
        axes: ["x", "y", "z"],
        scale: 0.995,
        offset: 1.3,
        acc_bias: [-0.1, 0.02, 0.0],
        gyro_bias: [0.0, 3e-3, -2e-3],
    },
    // Mounted upside down (a rotation about x).
    Case {
        axes: ["x", "-y", "-z"],
        scale: 1.005,
        offset: 0.1,
        acc_bias: [0.0, 0.0, -0.2],
        gyro_bias: [1e-3, 1e-3, 1e-3],
    },
    // x and y swapped (a mirror image).
    Case {
        axes: ["y", "x", "z"],
        scale: 1.0,
        offset: -2.0,
        acc_bias: [0.05, 0.05, 0.05],
        gyro_bias: [-1e-3, 0.0, 4e-3],
    },
    // A cyclic permutation with signs.
    Case {
        axes: ["-z", "x", "-y"],
        scale: 0.998,
        offset: 2.0,
        acc_bias: [0.2, -0.1, 0.0],
        gyro_bias: [0.0, -2e-3, 1e-3],
    },
    Case {
        axes: ["z", "-x", "y"],
        scale: 1.003,
        offset: -0.7,
        acc_bias: [0.0, 0.15, -0.05],
        gyro_bias: [5e-3, 0.0, 0.0],
    },
];

#[test]
fn recovers_axes_clock_and_biases() {
    let calibrator = ImuCalibrator::default();
    for (i, case) in CASES.iter().enumerate() {
        let (imu, reference) = simulate(case, Motion::Manoeuvring, 150.0, 100 + i as u64);
        let c = calibrator.calibrate(&imu, &reference).expect("calibrate");
        let z = normalised_errors(&c, case);
        println!(
            "case {i}: axes {} (runner-up {:?}, ratio {:.1}), s {:.6} ± {:.1e}, τ {:.4} ± {:.1e}, \
             ρ {:.2}, z {z:.2?}",
            c.axes,
            c.runner_up.map(|(a, _)| a.to_string()),
            c.cost_ratio,
            c.clock_scale.value,
            c.clock_scale.standard_error,
            c.time_offset_s.value,
            c.time_offset_s.standard_error,
            c.residual_lag1_autocorrelation,
        );
        assert_eq!(c.axes.labels(), case.axes, "case {i}");
        assert!(c.cost_ratio > 3.0, "case {i}: ratio {}", c.cost_ratio);
        assert!(z.iter().all(|z| z.abs() < 4.5), "case {i}: {z:?}");
        // Precise enough to matter: 2 ms, 2e-5, 5 mm/s^2, 1e-4 rad/s.
        assert!(c.time_offset_s.standard_error < 2e-3, "case {i}");
        assert!(c.clock_scale.standard_error < 2e-5, "case {i}");
        assert!(c.accelerometer_bias.iter().all(|b| b.standard_error < 5e-3));
        assert!(c.gyroscope_bias.iter().all(|b| b.standard_error < 1e-4));
    }
}

#[test]
fn sigmas_are_honest_over_seeds() {
    // Same case, independent noise: the normalised errors of all eight parameters
    // pooled over the seeds have an RMS near 1 (neither optimistic nor inflated).
    let calibrator = ImuCalibrator::default();
    let case = CASES[0];
    let mut pooled = Vec::new();
    for seed in 0..8 {
        let (imu, reference) = simulate(&case, Motion::Manoeuvring, 120.0, 7_000 + seed);
        let c = calibrator.calibrate(&imu, &reference).expect("calibrate");
        assert_eq!(c.axes.labels(), case.axes);
        pooled.extend(normalised_errors(&c, &case));
    }
    let rms = (pooled.iter().map(|z| z * z).sum::<f64>() / pooled.len() as f64).sqrt();
    println!(
        "RMS of (estimate - true) / sigma over {} values: {rms:.2}",
        pooled.len()
    );
    assert!((0.5..=1.6).contains(&rms), "{rms}");
}

#[test]
fn refuses_what_it_cannot_fit() {
    let calibrator = ImuCalibrator::default();
    let case = CASES[0];
    // Too short: 20 s of reference.
    let (imu, reference) = simulate(&case, Motion::Manoeuvring, 20.0, 1);
    assert!(matches!(
        calibrator.calibrate(&imu, &reference),
        Err(Error::CalibrationTooShort { min: 30, .. })
    ));
    // A search grid too large to run: refused before any work.
    let huge = ImuCalibrator::builder()
        .max_time_offset(60.0)
        .time_offset_grid_step(0.001)
        .build()
        .expect("valid settings");
    assert!(matches!(
        huge.calibrate(&imu, &reference),
        Err(Error::InvalidParameter {
            name: "max_time_offset",
            ..
        })
    ));
    // No motion to separate the axes.
    let (imu, reference) = simulate(&case, Motion::Straight, 80.0, 2);
    let e = calibrator.calibrate(&imu, &reference).unwrap_err();
    assert!(
        matches!(
            e,
            Error::CalibrationAmbiguousAxes { .. } | Error::CalibrationNoMotion
        ),
        "{e}"
    );
    // Non-finite and non-increasing IMU samples, named by index.
    let (mut imu, reference) = simulate(&case, Motion::Manoeuvring, 60.0, 3);
    imu[17].angular_rate.y = f64::NAN;
    assert_eq!(
        calibrator.calibrate(&imu, &reference),
        Err(Error::NonFinite {
            what: "IMU sample 17".into()
        })
    );
    imu[17].angular_rate.y = 0.0;
    imu[40].time = imu[39].time;
    assert!(matches!(
        calibrator.calibrate(&imu, &reference),
        Err(Error::ImuTime { index: 40, .. })
    ));
    // Biases beyond any IMU's: no axis convention is admitted.
    let wild = Case {
        acc_bias: [3.0, -3.0, 3.0],
        ..case
    };
    let (imu, reference) = simulate(&wild, Motion::Manoeuvring, 60.0, 4);
    assert!(matches!(
        calibrator.calibrate(&imu, &reference),
        Err(Error::CalibrationNoAxes { .. })
    ));
}

/// A gyroscope that reads 0.25 % high about z and 0.4 % low about x (a manoeuvring
/// vehicle turns and rolls about both): the calibrator recovers both scales within
/// 4.5 sigma, and the biases and the clock stay right beside them. About y (pitch
/// rates of this motion are small) the scale is fitted too, or held at 1 and reported
/// as not fitted; either way the other parameters are unbiased.
#[test]
fn recovers_the_gyroscope_scale() {
    let case = CASES[0];
    let scale = Vector3::new(0.996, 1.0, 1.0025);
    let (mut imu, reference) = simulate(&case, Motion::Manoeuvring, 150.0, 4_242);
    // Re-scale the body rates the simulator produced: in IMU axes the samples are
    // to_imu * w, so scale in body axes and map back.
    let axes = estim_ins::AxisMap::from_labels(&case.axes).expect("axes");
    let to_body = axes.matrix();
    let gyro_bias = Vector3::from(case.gyro_bias);
    for s in &mut imu {
        let body = to_body * s.angular_rate;
        let clean = body - gyro_bias;
        s.angular_rate = to_body.transpose() * (clean.component_mul(&scale) + gyro_bias);
    }
    let c = ImuCalibrator::default()
        .calibrate(&imu, &reference)
        .expect("calibrate");
    for (axis, want) in [(0, scale.x), (2, scale.z)] {
        let got = c.gyroscope_scale[axis].expect("fitted about a turning axis");
        let z = (got.value - want) / got.standard_error;
        println!(
            "axis {axis}: {:.6} ± {:.1e} (z {z:.2})",
            got.value, got.standard_error
        );
        assert!(z.abs() < 4.5, "axis {axis}: {got:?} vs {want}");
        assert!(got.standard_error < 5e-4, "axis {axis}: {got:?}");
    }
    let z = normalised_errors(&c, &case);
    assert!(z.iter().all(|z| z.abs() < 4.5), "{z:?}");
    // Held at 1 when the reference does not turn about any axis enough.
    let never = ImuCalibrator::builder()
        .min_scale_rate(f64::INFINITY)
        .build()
        .expect("settings");
    let fixed = never.calibrate(&imu, &reference).expect("calibrate");
    assert!(fixed.gyroscope_scale.iter().all(Option::is_none));
    assert!(ImuCalibrator::builder()
        .min_scale_rate(0.0)
        .build()
        .is_err());
}
