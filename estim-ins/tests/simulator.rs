//! The trajectory-driven IMU simulator, the IMU error generator and the mission generator.

use estim_ins::earth::{earth_rate_ned, normal_gravity, radii_of_curvature};
use estim_ins::{
    ImuErrorGenerator, ImuSample, ImuSpec, InsState, Mechanization, Mission, MissionConfig,
    SensorSpec, Trajectory, TrajectorySample,
};
use nalgebra::{UnitQuaternion, Vector3};

fn errors(a: &InsState, b: &InsState) -> (f64, f64, f64) {
    let (rn, re) = radii_of_curvature(b.latitude);
    let d = Vector3::new(
        (a.latitude - b.latitude) * (rn + b.height),
        (a.longitude - b.longitude) * (re + b.height) * b.latitude.cos(),
        b.height - a.height,
    );
    (
        d.norm(),
        (a.velocity_ned - b.velocity_ned).norm(),
        (a.attitude * b.attitude.inverse()).angle().to_degrees(),
    )
}

/// A vehicle turning in place at `rate` rad/s, 20 m under the ellipsoid.
fn spinning(rate: f64) -> Trajectory {
    let samples = (0..=20)
        .map(|k| {
            let t = f64::from(k);
            TrajectorySample {
                time: t,
                latitude: 0.5733,
                longitude: 0.609,
                height: -20.0,
                velocity_ned: Vector3::zeros(),
                attitude: UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3 + rate * t),
            }
        })
        .collect();
    Trajectory::new(samples).unwrap()
}

#[test]
fn imu_of_a_vehicle_turning_in_place_is_gravity_earth_rate_and_yaw_rate() {
    let rate = 0.05;
    let traj = spinning(rate);
    for &t in &[0.0, 3.7, 12.25, 19.99] {
        let k = traj.evaluate(t).unwrap();
        // Independent reference: f^n = -g^n, ω_ib^b = C_n^b ω_ie^n + [0, 0, rate].
        let c_nb = UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3 + rate * t).inverse();
        let f = c_nb * Vector3::new(0.0, 0.0, -normal_gravity(0.5733, -20.0));
        let w = c_nb * earth_rate_ned(0.5733) + Vector3::new(0.0, 0.0, rate);
        assert!(
            (k.specific_force - f).amax() < 1e-12,
            "{}",
            k.specific_force - f
        );
        assert!((k.angular_rate - w).amax() < 1e-15);
        let s = traj.imu_sample(t.min(19.9), 0.01).unwrap();
        assert!((s.angular_rate.z - w.z).abs() < 1e-9);
    }
    assert!(traj.evaluate(20.5).is_err());
    assert!(traj.imu_sample(19.995, 0.01).is_err());
}

#[test]
fn trajectory_passes_through_its_samples_and_rejects_bad_input() {
    let cfg = MissionConfig::builder().duration(60.0).build().unwrap();
    let mission = Mission::generate(&cfg, 1).unwrap();
    let traj = &mission.trajectory;
    for s in traj.samples().iter().take(100).skip(1) {
        let k = traj.evaluate(s.time).unwrap();
        assert!((k.state.latitude - s.latitude).abs() < 1e-15);
        assert!((k.state.height - s.height).abs() < 1e-9);
        assert!((k.state.velocity_ned - s.velocity_ned).amax() < 1e-9);
        assert!((k.state.attitude * s.attitude.inverse()).angle() < 1e-12);
    }
    let mut bad = traj.samples()[..3].to_vec();
    bad[2].time = bad[1].time;
    let e = Trajectory::new(bad.clone()).unwrap_err();
    assert!(e.to_string().contains("sample 2"), "{e}");
    bad[2].time = 10.0;
    bad[1].height = f64::NAN;
    assert!(Trajectory::new(bad)
        .unwrap_err()
        .to_string()
        .contains("sample 1"));
    assert!(Trajectory::new(vec![]).is_err());
}

#[test]
fn default_mission_is_an_auv_and_its_clean_imu_reproduces_the_truth() {
    let cfg = MissionConfig::default();
    let m = Mission::generate(&cfg, 42).unwrap();
    assert_eq!(m.imu.len(), 40_000);
    assert_eq!(m.truth.len(), 40_001);
    assert!((m.truth[40_000].time - m.truth[0].time - 400.0).abs() < 1e-6);
    let mut turned = 0.0f64;
    for s in &m.truth {
        assert!(
            s.height <= -12.0 + 1e-9 && s.height >= -28.0 - 1e-9,
            "{}",
            s.height
        );
        let horizontal = s.velocity_ned.xy().norm();
        assert!(
            (1.5 - 1e-6..=2.0 + 1e-6).contains(&horizontal),
            "{horizontal}"
        );
        turned = turned.max(s.angular_rate.z.abs());
    }
    assert!(turned > 0.02, "the mission turns");
    let mech = Mechanization::new();
    let mut s = m.truth[0];
    s.acc_bias = Vector3::zeros();
    s.gyro_bias = Vector3::zeros();
    for (k, imu) in m.clean_imu.iter().enumerate() {
        s = mech.step(&s, imu, m.imu_dt).unwrap();
        if k % 1000 == 999 {
            let (p, v, a) = errors(&s, &m.truth[k + 1]);
            assert!(
                p < 1.0 && v < 0.01 && a < 0.01,
                "t = {}: {p} m {v} m/s {a} deg",
                s.time
            );
        }
    }
    let (p, v, a) = errors(&s, m.truth.last().unwrap());
    println!("synthetic mission round trip (400 s): {p:.4} m, {v:.2e} m/s, {a:.2e} deg");
    // Seeded: same seed, same IMU; another seed, another mission.
    let again = Mission::generate(&cfg, 42).unwrap();
    assert_eq!(again.imu[1234], m.imu[1234]);
    let other = Mission::generate(&cfg, 43).unwrap();
    assert_ne!(other.imu[1234], m.imu[1234]);
    assert!(MissionConfig::builder().mean_depth(-5.0).build().is_err());
    assert!(MissionConfig::builder()
        .speed_range((2.0, 1.0))
        .build()
        .is_err());
}

#[test]
fn imu_error_generator_has_the_specified_statistics() {
    let white = SensorSpec {
        white_noise_density: 0.003,
        bias_instability: 0.0,
        bias_time_constant: f64::INFINITY,
        turn_on_bias: 0.01,
        scale_factor: 1e-3,
    };
    let spec = ImuSpec::builder()
        .accelerometer(white)
        .gyroscope(white)
        .build()
        .unwrap();
    let mut generator = ImuErrorGenerator::new(spec, 9);
    let bias = generator.acc_bias();
    let (scale, _) = generator.scale_factors();
    let dt = 0.01;
    let n = 100_000;
    let input = ImuSample::new(0.0, Vector3::new(10.0, 0.0, 0.0), Vector3::zeros());
    let mut sum = Vector3::zeros();
    let mut sum_sq = Vector3::zeros();
    for _ in 0..n {
        let out = generator.corrupt(&input, dt);
        let e = out.specific_force - input.specific_force;
        sum += e;
        sum_sq += e.component_mul(&e);
    }
    let mean = sum / n as f64;
    let var = sum_sq / n as f64 - mean.component_mul(&mean);
    let sigma = 0.003 / dt.sqrt();
    // Mean = bias + scale ∘ input within 5 standard errors (σ/√n).
    let expected = bias + scale.component_mul(&input.specific_force);
    assert!((mean - expected).amax() < 5.0 * sigma / (n as f64).sqrt());
    // Standard deviation within 1 % (its relative standard error is 1/√(2n) = 0.22 %).
    for i in 0..3 {
        assert!(
            (var[i].sqrt() / sigma - 1.0).abs() < 0.01,
            "{}",
            var[i].sqrt()
        );
    }
    // Gauss-Markov drift: stationary with variance σ_b² (ensemble over seeds).
    let gm = SensorSpec {
        white_noise_density: 0.0,
        bias_instability: 0.02,
        bias_time_constant: 5.0,
        turn_on_bias: 0.0,
        scale_factor: 0.0,
    };
    let spec = ImuSpec::builder().gyroscope(gm).build().unwrap();
    let mut sum_sq = 0.0;
    let runs = 4000;
    for seed in 0..runs {
        let mut g = ImuErrorGenerator::new(spec, seed);
        for _ in 0..200 {
            let _ = g.corrupt(&input, 0.05);
        }
        sum_sq += g.gyro_bias().x.powi(2);
    }
    let var = sum_sq / runs as f64;
    // Variance estimate of a Gaussian: relative standard error √(2/runs) = 2.2 %; 5 of them.
    assert!((var / 0.0004 - 1.0).abs() < 0.11, "{var}");
}

/// Halving the step divides the round-trip error by about four: the mechanization (with
/// the IMU samples as interval means) is second order.
#[test]
fn mechanization_error_shrinks_as_dt_squared() {
    let cfg = MissionConfig::builder()
        .duration(120.0)
        .max_turn_rate(8f64.to_radians())
        .build()
        .unwrap();
    let m = Mission::generate(&cfg, 5).unwrap();
    let mech = Mechanization::new();
    let final_error = |rate: f64| {
        let (truth, imu) = m.trajectory.simulate(rate).unwrap();
        let mut s = truth[0];
        for sample in &imu {
            s = mech.step(&s, sample, 1.0 / rate).unwrap();
        }
        let (p, v, a) = errors(&s, truth.last().unwrap());
        println!("{rate} Hz: {p:.3e} m, {v:.3e} m/s, {a:.3e} deg");
        (p, v)
    };
    let coarse = final_error(5.0);
    let fine = final_error(10.0);
    let ratio = (coarse.0 / fine.0, coarse.1 / fine.1);
    println!(
        "error ratio for dt/2: position {:.2}, velocity {:.2}",
        ratio.0, ratio.1
    );
    assert!(ratio.0 > 3.0 && ratio.1 > 3.0, "{ratio:?}");
}
