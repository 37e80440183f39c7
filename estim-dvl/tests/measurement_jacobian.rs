//! The DVL measurement Jacobian against central finite differences through the error
//! injection convention pinned in estim-ins/src/state.rs, implemented here independently:
//!
//! - position: lat += dN / (R_N + h), lon += dE / ((R_E + h) cos lat), h -= dD;
//! - velocity: v^n += dv;
//! - misalignment: C_b^n,true = (I + [psi x]) C_b^n (applied as the exact rotation
//!   exp([psi x]), equal to first order);
//! - biases: b += db; the gyro bias also changes the bias-corrected angular rate,
//!   omega = omega_meas - b_g, so omega -= db_g.

use estim_core::MeasurementModel;
use estim_dvl::nalgebra::{SVector, UnitQuaternion, Vector3};
use estim_dvl::DvlVelocityModel;
use estim_ins::InsState;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn inject(x: &InsState, e: &SVector<f64, 15>) -> InsState {
    // WGS-84 radii of curvature (Groves 2013, eqs. 2.105-2.106).
    let a = 6_378_137.0;
    let e2 = 6.694_379_990_14e-3;
    let s2 = x.latitude.sin().powi(2);
    let r_n = a * (1.0 - e2) / (1.0 - e2 * s2).powf(1.5);
    let r_e = a / (1.0 - e2 * s2).sqrt();
    let mut y = *x;
    y.latitude += e[0] / (r_n + x.height);
    y.longitude += e[1] / ((r_e + x.height) * x.latitude.cos());
    y.height -= e[2];
    y.velocity_ned += Vector3::new(e[3], e[4], e[5]);
    let psi = Vector3::new(e[6], e[7], e[8]);
    y.attitude = UnitQuaternion::from_scaled_axis(psi) * x.attitude;
    y.acc_bias += Vector3::new(e[9], e[10], e[11]);
    let dbg = Vector3::new(e[12], e[13], e[14]);
    y.gyro_bias += dbg;
    y.angular_rate -= dbg;
    y
}

fn random_state(rng: &mut ChaCha8Rng) -> InsState {
    let mut v3 = |s: f64| {
        Vector3::new(
            rng.random_range(-s..s),
            rng.random_range(-s..s),
            rng.random_range(-s..s),
        )
    };
    let velocity_ned = v3(3.0);
    let att = v3(3.0);
    let acc_bias = v3(0.01);
    let gyro_bias = v3(0.001);
    let angular_rate = v3(0.3);
    InsState {
        time: 10.0,
        latitude: 0.5733,
        longitude: 0.609,
        height: -20.0,
        velocity_ned,
        attitude: UnitQuaternion::from_scaled_axis(att),
        acc_bias,
        gyro_bias,
        angular_rate,
    }
}

fn check(model: &DvlVelocityModel, rng: &mut ChaCha8Rng) {
    let x = random_state(rng);
    let h = model.jacobian(&x).unwrap();
    let step = 1e-6;
    let scale = h.amax();
    for j in 0..15 {
        let mut e = SVector::<f64, 15>::zeros();
        e[j] = step;
        let plus = model.predict(&inject(&x, &e)).unwrap();
        let minus = model.predict(&inject(&x, &(-e))).unwrap();
        let fd = (plus - minus) / (2.0 * step);
        for i in 0..3 {
            let diff = (fd[i] - h[(i, j)]).abs();
            assert!(
                diff <= 1e-6 * scale,
                "H[{i},{j}] = {} but finite difference {} (scale {scale})",
                h[(i, j)],
                fd[i]
            );
        }
    }
}

#[test]
fn jacobian_matches_finite_differences() {
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    for _ in 0..50 {
        let lever = Vector3::new(
            rng.random_range(-2.0..2.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        let model = DvlVelocityModel::builder()
            .lever_arm(lever)
            .noise_std(0.02)
            .build()
            .unwrap();
        check(&model, &mut rng);
    }
}

#[test]
fn jacobian_with_scale_factor_and_misalignment_matches_finite_differences() {
    let mut rng = ChaCha8Rng::seed_from_u64(22);
    for _ in 0..50 {
        let model = DvlVelocityModel::builder()
            .lever_arm(Vector3::new(1.5, 0.1, -0.3))
            .scale_factor_error(rng.random_range(-0.02..0.02))
            .mounting_misalignment(Vector3::new(
                rng.random_range(-0.05..0.05),
                rng.random_range(-0.05..0.05),
                rng.random_range(-0.05..0.05),
            ))
            .noise_std(0.02)
            .build()
            .unwrap();
        check(&model, &mut rng);
    }
}

#[test]
fn jacobian_blocks_have_the_pinned_signs() {
    // A hand-worked case, independent of finite differences: level, heading north,
    // v^n = (2, 0, 0), lever arm (1.5, 0, 0), no scale factor or misalignment.
    let model = DvlVelocityModel::builder()
        .lever_arm(Vector3::new(1.5, 0.0, 0.0))
        .noise_std(0.02)
        .build()
        .unwrap();
    let x = InsState {
        time: 0.0,
        latitude: 0.5,
        longitude: 0.6,
        height: -20.0,
        velocity_ned: Vector3::new(2.0, 0.0, 0.0),
        attitude: UnitQuaternion::identity(),
        acc_bias: Vector3::zeros(),
        gyro_bias: Vector3::zeros(),
        angular_rate: Vector3::new(0.0, 0.0, 0.1),
    };
    let h = model.jacobian(&x).unwrap();
    // a yaw error psi_D > 0 rotates the true body clockwise seen from above: the body
    // then sees the northward velocity to its left, v_y = -2 psi_D.
    assert!((h[(1, 8)] + 2.0).abs() < 1e-15);
    // a gyro bias error db_z > 0 lowers the true yaw rate: v_y = (r - db) * 1.5.
    assert!((h[(1, 14)] + 1.5).abs() < 1e-15);
    // velocity block = C_n^b = I here
    assert!((h[(0, 3)] - 1.0).abs() < 1e-15 && h[(0, 4)].abs() < 1e-15);
}

#[test]
fn builder_validates() {
    assert!(DvlVelocityModel::builder().build().is_err());
    assert!(DvlVelocityModel::builder()
        .noise_covariance(estim_dvl::nalgebra::Matrix3::new(
            1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0
        ))
        .build()
        .is_err());
    assert!(DvlVelocityModel::builder()
        .noise_std(0.02)
        .scale_factor_error(0.7)
        .build()
        .is_err());
    assert!(DvlVelocityModel::builder()
        .noise_std(0.02)
        .lever_arm(Vector3::new(f64::NAN, 0.0, 0.0))
        .build()
        .is_err());
}

/// `with_noise_scale` multiplies R and nothing else; a scale that is not finite and
/// positive is refused.
#[test]
fn noise_scale_multiplies_r_only() {
    let r = estim_dvl::nalgebra::Matrix3::new(4e-4, 1e-5, 0.0, 1e-5, 4e-4, 0.0, 0.0, 0.0, 1e-4);
    let model = DvlVelocityModel::builder()
        .lever_arm(Vector3::new(1.2, -0.1, 0.3))
        .scale_factor_error(0.002)
        .noise_covariance(r)
        .build()
        .unwrap();
    let state = InsState::new(
        0.0,
        0.57,
        0.61,
        -20.0,
        Vector3::new(1.5, -0.2, 0.1),
        UnitQuaternion::from_euler_angles(0.02, -0.03, 1.1),
    );
    let scaled = model.with_noise_scale(2.5).unwrap();
    assert_eq!(scaled.noise_covariance(&state).unwrap(), r * 2.5);
    assert_eq!(
        scaled.predict(&state).unwrap(),
        model.predict(&state).unwrap()
    );
    assert_eq!(
        scaled.jacobian(&state).unwrap(),
        model.jacobian(&state).unwrap()
    );
    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        assert!(model.with_noise_scale(bad).is_err(), "{bad}");
    }
}
