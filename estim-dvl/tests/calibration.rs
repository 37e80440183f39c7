//! Calibration recovers a known lever arm, scale factor, mounting misalignment and time
//! offset from simulated data, within its reported standard errors.

use estim_dvl::nalgebra::{Rotation3, Vector3};
use estim_dvl::{Calibrator, DvlMeasurement, TrajectorySample};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

const TAU: f64 = std::f64::consts::TAU;

/// Analytic AUV motion: Euler angles and their rates, body velocity.
fn euler(t: f64) -> (Vector3<f64>, Vector3<f64>) {
    let yaw = 0.6 * (TAU * t / 80.0).sin() + 0.3 * (TAU * t / 37.0).sin() + 0.002 * t;
    let yaw_rate = 0.6 * TAU / 80.0 * (TAU * t / 80.0).cos()
        + 0.3 * TAU / 37.0 * (TAU * t / 37.0).cos()
        + 0.002;
    let pitch = 0.05 * (TAU * t / 23.0).sin();
    let pitch_rate = 0.05 * TAU / 23.0 * (TAU * t / 23.0).cos();
    let roll = 0.04 * (TAU * t / 29.0).sin();
    let roll_rate = 0.04 * TAU / 29.0 * (TAU * t / 29.0).cos();
    (
        Vector3::new(roll, pitch, yaw),
        Vector3::new(roll_rate, pitch_rate, yaw_rate),
    )
}

/// omega_nb^b from Euler angles and rates (Titterton & Weston 2004, eq. 3.47 inverted).
fn body_rate(t: f64) -> Vector3<f64> {
    let (a, d) = euler(t);
    let (r, p) = (a.x, a.y);
    Vector3::new(
        d.x - d.z * p.sin(),
        d.y * r.cos() + d.z * r.sin() * p.cos(),
        -d.y * r.sin() + d.z * r.cos() * p.cos(),
    )
}

fn body_velocity(t: f64) -> Vector3<f64> {
    Vector3::new(
        2.0 + 0.3 * (TAU * t / 50.0).sin(),
        0.05 * (TAU * t / 31.0).sin(),
        0.03 * (TAU * t / 19.0).sin(),
    )
}

struct Truth {
    lever_arm: Vector3<f64>,
    scale_factor_error: f64,
    misalignment: Vector3<f64>,
    time_offset: f64,
}

fn simulate(truth: &Truth, noise: f64, seed: u64) -> (Vec<TrajectorySample>, Vec<DvlMeasurement>) {
    let dt = 1.0025;
    let n = 400;
    let gt = (0..n)
        .map(|i| {
            let t = i as f64 * dt;
            let (a, _) = euler(t);
            let c = Rotation3::from_euler_angles(a.x, a.y, a.z);
            TrajectorySample {
                time: t,
                velocity_ned: c * body_velocity(t),
                roll_pitch_yaw: a,
            }
        })
        .collect();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let normal = Normal::new(0.0, noise).unwrap();
    // Measurement model written out independently of the crate:
    // y = (1 + k) Rot(mu)^T (v_b + omega x l), evaluated at the true time t - tau.
    let dvl = (0..n)
        .map(|i| {
            let stamp = i as f64 * dt;
            let t = stamp - truth.time_offset;
            let v = body_velocity(t) + body_rate(t).cross(&truth.lever_arm);
            let y = Rotation3::new(truth.misalignment).transpose()
                * v
                * (1.0 + truth.scale_factor_error);
            DvlMeasurement {
                time: stamp,
                velocity: y + Vector3::from_fn(|_, _| normal.sample(&mut rng)),
            }
        })
        .collect();
    (gt, dvl)
}

#[test]
fn calibration_recovers_known_parameters_within_three_sigma() {
    let truth = Truth {
        lever_arm: Vector3::new(1.5, -0.2, 0.3),
        scale_factor_error: 0.004,
        misalignment: Vector3::new(0.01, -0.02, 0.015),
        time_offset: 0.8,
    };
    let (gt, dvl) = simulate(&truth, 0.01, 5);
    let c = Calibrator::builder()
        .build()
        .unwrap()
        .calibrate(&gt, &dvl)
        .unwrap();
    let expected = [
        ("lever x", truth.lever_arm.x, c.lever_arm[0]),
        ("lever y", truth.lever_arm.y, c.lever_arm[1]),
        ("lever z", truth.lever_arm.z, c.lever_arm[2]),
        ("scale", truth.scale_factor_error, c.scale_factor_error),
        ("mis x", truth.misalignment.x, c.mounting_misalignment[0]),
        ("mis y", truth.misalignment.y, c.mounting_misalignment[1]),
        ("mis z", truth.misalignment.z, c.mounting_misalignment[2]),
        ("offset", truth.time_offset, c.time_offset),
    ];
    for (name, t, e) in expected {
        println!(
            "{name:8} truth {t:+.5}  estimate {:+.5} +- {:.5}  ({:+.2} sigma)",
            e.value,
            e.standard_error,
            (e.value - t) / e.standard_error
        );
        assert!(e.standard_error > 0.0 && e.standard_error.is_finite());
        assert!(
            (e.value - t).abs() <= 3.0 * e.standard_error,
            "{name}: estimate {} +- {} vs truth {t}",
            e.value,
            e.standard_error
        );
    }
    // The residual is the injected white noise.
    for a in 0..3 {
        assert!(
            (c.residual_rms[a] / 0.01 - 1.0).abs() < 0.1,
            "{}",
            c.residual_rms
        );
    }
}

#[test]
fn standard_errors_are_calibrated_over_seeds() {
    // Over 20 seeded runs, the normalised errors (estimate - truth) / se of all 8
    // parameters should have a mean square near 1 (chi-square with 160 degrees of
    // freedom: 1 +- 0.11 at one sigma); accept [0.6, 1.5].
    let truth = Truth {
        lever_arm: Vector3::new(1.4, 0.1, -0.2),
        scale_factor_error: -0.003,
        misalignment: Vector3::new(-0.01, 0.02, 0.005),
        time_offset: -0.6,
    };
    let calibrator = Calibrator::builder().build().unwrap();
    let mut sum = 0.0;
    let mut count = 0;
    for seed in 0..20 {
        let (gt, dvl) = simulate(&truth, 0.02, 100 + seed);
        let c = calibrator.calibrate(&gt, &dvl).unwrap();
        let t = [
            truth.lever_arm.x,
            truth.lever_arm.y,
            truth.lever_arm.z,
            truth.scale_factor_error,
            truth.misalignment.x,
            truth.misalignment.y,
            truth.misalignment.z,
            truth.time_offset,
        ];
        let p = c.parameters();
        for k in 0..8 {
            let z = (p[k] - t[k]) / c.covariance[(k, k)].sqrt();
            sum += z * z;
            count += 1;
        }
    }
    let mean_square = sum / count as f64;
    println!("mean square normalised error over 20 runs: {mean_square:.3}");
    assert!((0.6..1.5).contains(&mean_square), "{mean_square}");
}

#[test]
fn bad_input_is_a_typed_error() {
    let truth = Truth {
        lever_arm: Vector3::zeros(),
        scale_factor_error: 0.0,
        misalignment: Vector3::zeros(),
        time_offset: 0.0,
    };
    let (gt, mut dvl) = simulate(&truth, 0.01, 1);
    let cal = Calibrator::builder().build().unwrap();
    assert!(cal.calibrate(&gt[..3], &dvl).is_err());
    assert!(cal.calibrate(&gt, &dvl[..5]).is_err());
    dvl[10].velocity.x = f64::NAN;
    let e = cal.calibrate(&gt, &dvl).unwrap_err();
    assert!(e.to_string().contains("sample 10"), "{e}");
    assert!(Calibrator::builder().max_time_offset(-1.0).build().is_err());
    assert!(Calibrator::builder().max_iterations(0).build().is_err());
}

#[test]
fn unexcited_parameters_are_a_numerical_error() {
    // Straight line at constant velocity, no rotation: the lever arm and the time
    // offset leave no trace in the data, the normal equations are singular.
    let gt: Vec<TrajectorySample> = (0..100)
        .map(|i| TrajectorySample {
            time: i as f64,
            velocity_ned: Vector3::new(2.0, 0.0, 0.0),
            roll_pitch_yaw: Vector3::zeros(),
        })
        .collect();
    let dvl: Vec<DvlMeasurement> = gt
        .iter()
        .map(|s| DvlMeasurement {
            time: s.time,
            velocity: Vector3::new(2.0, 0.0, 0.0),
        })
        .collect();
    let e = Calibrator::builder()
        .build()
        .unwrap()
        .calibrate(&gt, &dvl)
        .unwrap_err();
    assert!(matches!(e, estim_dvl::Error::Numerical { .. }), "{e}");
}

#[test]
fn measurement_model_takes_the_calibration() {
    let truth = Truth {
        lever_arm: Vector3::new(-1.8, 0.05, 0.2),
        scale_factor_error: 0.003,
        misalignment: Vector3::new(0.0, -0.001, 0.004),
        time_offset: 0.0,
    };
    let (gt, dvl) = simulate(&truth, 0.005, 9);
    let c = Calibrator::builder()
        .estimate_time_offset(false)
        .build()
        .unwrap()
        .calibrate(&gt, &dvl)
        .unwrap();
    assert_eq!(c.time_offset.standard_error, 0.0);
    let model = estim_dvl::DvlVelocityModel::builder()
        .calibration(&c)
        .noise_std(0.005)
        .build()
        .unwrap();
    assert_eq!(*model.lever_arm(), c.lever_arm_vector());
    assert_eq!(model.scale_factor_error(), c.scale_factor_error.value);
    assert!((model.lever_arm() - truth.lever_arm).amax() < 0.05);
}
