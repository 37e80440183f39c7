use super::*;
use crate::navigator::*;
use estim_core::noise::adaptive::NoiseScale;
use estim_core::{ErrorStateModel, MeasurementModel, ProcessModel, Zero};
use estim_ins::ImuSpec;
use estim_ins::{ErrorMatrix, ImuSample, InsErrorModel, ATT, GYRO_BIAS};
use nalgebra::Matrix3;
use nalgebra::UnitQuaternion;

/// The default simulated mission of `duration` seconds.
fn mission(duration: f64, seed: u64) -> estim_ins::SimulatedMission {
    estim_ins::Mission::generate(
        &estim_ins::MissionConfig::builder()
            .duration(duration)
            .build()
            .unwrap(),
        seed,
    )
    .unwrap()
}

fn state(tau: f64) -> AugmentedState {
    let mut ins = InsState::new(
        0.0,
        0.57,
        0.61,
        -35.0,
        Vector3::new(1.4, -0.6, 0.1),
        UnitQuaternion::from_euler_angles(0.05, -0.08, 2.3),
    );
    ins.angular_rate = Vector3::new(0.01, -0.02, 0.05);
    ins.acc_bias = Vector3::new(0.002, -0.001, 0.003);
    ins.gyro_bias = Vector3::new(1e-5, -2e-5, 3e-5);
    AugmentedState {
        ins,
        dvl: DvlParameters {
            scale_factor_error: 0.003,
            dvl_to_body: Rotation3::new(Vector3::new(0.01, -0.02, 0.03)),
            bias: Vector3::new(0.01, -0.005, 0.002),
            lever_arm: Vector3::new(-1.87, -0.03, 0.2),
            time_offset: tau,
        },
        specific_force: Vector3::new(0.3, -0.2, -9.7),
    }
}

fn model() -> AugmentedErrorModel {
    AugmentedErrorModel::new(
        InsErrorModel::new(ImuSpec::akit_observed()),
        &DvlStatesConfig::default(),
    )
    .unwrap()
}

/// Central differences of h(inject(x, e)) along every error-state axis against
/// the analytic H, for time offsets 0 and 0.8 s.
#[test]
fn dvl_jacobian_matches_finite_differences() {
    let process = model();
    let dvl = AugmentedDvlModel::new(Matrix3::identity() * 4e-4).unwrap();
    for tau in [0.0, 0.8, -1.1] {
        let x = state(tau);
        let h = dvl.jacobian(&x).unwrap();
        for j in 0..AUGMENTED_STATES {
            let step = match j {
                _ if (ATT..ATT + 3).contains(&j) => 1e-6,
                _ if (DVL_MISALIGNMENT..DVL_MISALIGNMENT + 3).contains(&j) => 1e-6,
                DVL_SCALE => 1e-6,
                _ => 1e-3,
            };
            let mut e = AugmentedVector::zeros();
            e[j] = step;
            // The injection leaves the mechanization's bias-corrected rate as it
            // was; the perturbed truth's rate is omega - δb_g.
            let perturbed = |e: &AugmentedVector| {
                let mut y = process.inject(&x, e).unwrap();
                y.ins.angular_rate -= e.fixed_rows::<3>(GYRO_BIAS);
                dvl.predict(&y).unwrap()
            };
            let plus = perturbed(&e);
            let minus = perturbed(&(-e));
            let numeric = (plus - minus) / (2.0 * step);
            for i in 0..3 {
                let tol = 1e-7 * (1.0 + h[(i, j)].abs());
                assert!(
                    (numeric[i] - h[(i, j)]).abs() <= tol,
                    "tau {tau}, row {i}, column {j}: finite difference {} vs Jacobian {}",
                    numeric[i],
                    h[(i, j)]
                );
            }
        }
        // The time-offset column is not trivially zero (the test has motion).
        assert!(h.column(DVL_TIME_OFFSET).norm() > 0.01);
    }
}

/// With tau = 0 and the DVL states at their calibrated values, the prediction is
/// estim-dvl's (lever arm, scale factor, misalignment), plus the bias.
#[test]
fn prediction_without_time_offset_is_the_dvl_crates() {
    let x = state(0.0);
    let reference = estim_dvl::DvlVelocityModel::builder()
        .lever_arm(x.dvl.lever_arm)
        .scale_factor_error(x.dvl.scale_factor_error)
        .mounting_misalignment(x.dvl.mounting_misalignment())
        .noise_std(0.02)
        .build()
        .unwrap();
    let a = AugmentedDvlModel::new(Matrix3::identity())
        .unwrap()
        .predict(&x)
        .unwrap();
    let b = reference.predict(&x.ins).unwrap() + x.dvl.bias;
    assert!((a - b).norm() < 1e-14, "{a} vs {b}");
    // And the INS columns of H equal the DVL crate's at tau = 0.
    let h = AugmentedDvlModel::new(Matrix3::identity())
        .unwrap()
        .jacobian(&x)
        .unwrap();
    let h_ref = reference.jacobian(&x.ins).unwrap();
    let d = (h.fixed_view::<3, ERROR_STATES>(0, 0) - h_ref).abs().max();
    assert!(d < 1e-14, "{d}");
}

/// The time-offset model against a moving truth: a DVL sample of the motion at
/// t - tau is predicted from the state at t to first order (error O(tau^2)).
#[test]
fn time_offset_term_predicts_the_delayed_velocity() {
    let mission = mission(60.0, 5);
    let dvl = AugmentedDvlModel::new(Matrix3::identity()).unwrap();
    let k = 3000;
    let delay = 20; // IMU steps
    let dt = mission.imu_dt;
    let tau = delay as f64 * dt;
    let truth = mission.truth[k];
    let earlier = mission.truth[k - delay];
    let mut x = AugmentedState {
        ins: truth,
        dvl: DvlParameters::default(),
        specific_force: mission.clean_imu[k - 1].specific_force,
    };
    x.ins.acc_bias = Vector3::zeros();
    x.dvl.time_offset = tau;
    let predicted = dvl.predict(&x).unwrap();
    let delayed = earlier.attitude.inverse() * earlier.velocity_ned;
    let undelayed = truth.attitude.inverse() * truth.velocity_ned;
    let with = (predicted - delayed).norm();
    let without = (undelayed - delayed).norm();
    assert!(
        with < 0.2 * without,
        "first-order delay error {with:e} vs no correction {without:e}"
    );
}

/// The DVL block of Phi and Q against the continuous Gauss-Markov model
/// integrated by Van Loan's formula in closed form, and the structured covariance
/// propagation and transition composition against the dense products.
#[test]
fn process_blocks_match_the_dense_and_continuous_references() {
    let process = model();
    let x = state(0.3);
    let imu = ImuSample::new(
        0.0,
        Vector3::new(0.2, 0.1, -9.8),
        Vector3::new(0.01, 0.0, 0.02),
    );
    let dt = 0.37;
    let (phi, q) = process.transition_and_noise(&x, &imu, dt).unwrap();
    let (sigma, tau) = (0.01, 60.0);
    // Continuous: db/dt = -b/tau + w, PSD 2 sigma^2/tau; exact discrete variance
    // integral_0^dt e^{-2s/tau} 2 sigma^2/tau ds.
    let steps = 20_000;
    let h = dt / steps as f64;
    let integral: f64 = (0..steps)
        .map(|i| (-2.0 * (i as f64 + 0.5) * h / tau).exp() * 2.0 * sigma * sigma / tau * h)
        .sum();
    for i in 0..3 {
        let b = DVL_BIAS + i;
        assert!((phi[(b, b)] - (-dt / tau).exp()).abs() < 1e-15);
        assert!((q[(b, b)] - integral).abs() < 1e-9 * integral);
    }
    // Constant states: identity, no noise.
    for i in [
        DVL_SCALE,
        DVL_MISALIGNMENT,
        DVL_LEVER_ARM + 2,
        DVL_TIME_OFFSET,
    ] {
        assert_eq!(phi[(i, i)], 1.0);
        assert_eq!(q[(i, i)], 0.0);
    }
    // A full random SPD P.
    let a = AugmentedMatrix::from_fn(|i, j| ((i * 7 + j * 13) % 11) as f64 * 0.01 - 0.05);
    let p = a * a.transpose() + AugmentedMatrix::identity() * 0.1;
    let fast = process.propagate_covariance(&p, &phi, &q);
    let dense = phi * p * phi.transpose() + q;
    let d = (fast - dense).abs().max();
    assert!(d < 1e-12 * dense.abs().max(), "{d}");
    let composed = process.compose_transitions(&phi, &phi);
    let dense = phi * phi;
    assert!((composed - dense).abs().max() < 1e-12 * dense.abs().max());
}

#[test]
fn lifted_models_have_zero_dvl_columns() {
    let x = state(0.2);
    let depth = DepthModel::<AugmentedState>::new(Vector3::new(0.3, 0.0, 0.5), 0.1);
    let h = depth.jacobian(&x).unwrap();
    let inner = DepthModel::new(Vector3::new(0.3, 0.0, 0.5), 0.1)
        .jacobian(&x.ins)
        .unwrap();
    assert_eq!(h.fixed_view::<1, ERROR_STATES>(0, 0), inner);
    assert!(h
        .fixed_view::<1, DVL_STATES>(0, ERROR_STATES)
        .iter()
        .all(|v| *v == 0.0));
    assert_eq!(
        depth.predict(&x).unwrap()[0],
        35.0 + (x.ins.attitude * Vector3::new(0.3, 0.0, 0.5))[2]
    );
}

/// With every DVL state off, the augmented navigator's INS states and their
/// covariance equal the 15-state navigator's over a mission with DVL (lever arm,
/// misalignment, scale factor), depth and a fix, to 1e-12; the DVL rows of P stay
/// zero.
#[test]
fn with_no_dvl_state_it_equals_the_15_state_navigator() {
    use crate::navigator::{Navigator, NavigatorConfig};
    let mission = mission(30.0, 11);
    let mut config = NavigatorConfig::default();
    config.dvl.lever_arm_m = [1.2, -0.1, 0.3];
    config.dvl.mounting_misalignment_rad = [0.01, -0.02, 0.03];
    config.dvl.scale_factor = 1.004;
    config.depth.lever_arm_m = [0.5, 0.0, -0.2];
    config.fixes.lever_arm_m = [0.0, 0.0, -1.5];
    let settings = config.check().unwrap();
    let x0 = mission.truth[0];
    let p0 = ErrorMatrix::identity() * 1e-3;
    let dt = mission.imu_dt;
    let mut nav = Navigator::new(&settings, x0, p0, dt).unwrap();
    let mut aug =
        AugmentedNavigator::with_states(&settings, &DvlStatesConfig::none(), x0, p0, dt).unwrap();
    let dvl = settings.dvl_model().clone();
    for k in 0..mission.imu.len() {
        nav.imu(&mission.imu[k]).unwrap();
        aug.imu(&mission.imu[k]).unwrap();
        let truth = &mission.truth[k + 1];
        let t = truth.time;
        if (k + 1) % 100 == 0 {
            let v = dvl.predict(truth).unwrap() + Vector3::new(0.01, -0.02, 0.005);
            let a = nav.dvl_velocity(t, &v, &Zero).unwrap();
            let b = aug.dvl_velocity(t, &v, &Zero).unwrap();
            assert_eq!(a.status, b.status);
            assert!((a.nis - b.nis).abs() <= 1e-9 * a.nis.max(1.0));
        }
        if (k + 1) % 50 == 0 {
            let d = -truth.height + 0.01;
            nav.depth(t, d).unwrap();
            aug.depth(t, d).unwrap();
        }
        if k + 1 == 1500 {
            let (lat, lon) = (truth.latitude.to_degrees(), truth.longitude.to_degrees());
            nav.position_fix(t, lat + 1e-6, lon, 3.0).unwrap();
            aug.position_fix(t, lat + 1e-6, lon, 3.0).unwrap();
        }
    }
    let (a, b) = (nav.nominal(), &aug.nominal().ins);
    let diffs = [
        (a.latitude - b.latitude) * 6.4e6,
        (a.longitude - b.longitude) * 6.4e6,
        a.height - b.height,
        (a.velocity_ned - b.velocity_ned).norm(),
        a.attitude.angle_to(&b.attitude),
        (a.acc_bias - b.acc_bias).norm(),
        (a.gyro_bias - b.gyro_bias).norm(),
    ];
    for (i, d) in diffs.iter().enumerate() {
        assert!(d.abs() <= 1e-12, "nominal part {i} differs by {d}");
    }
    let p = (nav.covariance() - aug.ins_covariance()).abs().max();
    assert!(
        p <= 1e-12 * nav.covariance().abs().max(),
        "P differs by {p}"
    );
    let full = aug.covariance();
    for i in ERROR_STATES..AUGMENTED_STATES {
        assert!(
            full.row(i).iter().all(|v| *v == 0.0),
            "row {i} of P not zero"
        );
    }
    assert_eq!(
        aug.nominal().dvl,
        DvlParameters::from_config(&config.dvl).unwrap()
    );
    assert_eq!(nav.dvl_counts, aug.dvl_counts);
}

/// With the states on, a DVL with a constant bias and a scale-factor error the
/// configuration does not know: the filter's estimates approach the truth and
/// their errors lie within 3 sigma.
#[test]
fn estimated_dvl_states_converge_on_a_simulated_mission() {
    use crate::navigator::NavigatorConfig;
    let mission = mission(300.0, 3);
    let mut config = NavigatorConfig::default();
    config.dvl.lever_arm_m = [1.0, 0.0, 0.2];
    config.dvl.noise_std_mps = 0.01;
    let settings = config.check().unwrap();
    let mut states = DvlStatesConfig::none();
    states.scale_factor.estimate = true;
    states.bias = BiasConfig {
        estimate: true,
        std_mps: 0.02,
        time_constant_s: 1e5,
    };
    let true_k = 0.004;
    let true_bias = Vector3::new(0.015, -0.01, 0.005);
    let x0 = mission.truth[0];
    let p0 = ErrorMatrix::from_diagonal(&SVector::<f64, ERROR_STATES>::from_iterator([
        1.0, 1.0, 1.0, 1e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-5, 1e-6, 1e-6, 1e-6, 1e-10, 1e-10, 1e-10,
    ]));
    let mut aug =
        AugmentedNavigator::with_states(&settings, &states, x0, p0, mission.imu_dt).unwrap();
    let truth_model = estim_dvl::DvlVelocityModel::builder()
        .lever_arm(Vector3::new(1.0, 0.0, 0.2))
        .scale_factor_error(true_k)
        .noise_std(0.01)
        .build()
        .unwrap();
    for k in 0..mission.imu.len() {
        aug.imu(&mission.imu[k]).unwrap();
        if (k + 1) % 10 == 0 {
            let truth = &mission.truth[k + 1];
            let y = truth_model.predict(truth).unwrap() + true_bias;
            aug.dvl_velocity(truth.time, &y, &Zero).unwrap();
        }
    }
    let s = aug.dvl_states().unwrap();
    let k_err = s.scale_factor_error - true_k;
    assert!(
        k_err.abs() < 3.0 * s.scale_factor_sigma,
        "k error {k_err} sigma {}",
        s.scale_factor_sigma
    );
    for i in 0..3 {
        let e = s.bias_mps[i] - true_bias[i];
        assert!(
            e.abs() < 3.0 * s.bias_sigma_mps[i],
            "bias {i}: error {e}, sigma {}",
            s.bias_sigma_mps[i]
        );
    }
    // The bias sigmas fall below the prior's (the motion separates the bias from
    // the INS velocity error only partly: the forward one is confounded with the
    // scale factor at a nearly constant speed, the lateral one with the velocity
    // error between turns).
    for i in 0..3 {
        assert!(
            s.bias_sigma_mps[i] < 0.02 * 0.6,
            "bias {i} not learned: {}",
            s.bias_sigma_mps[i]
        );
    }
}

#[test]
fn rate_noise_adds_kappa_squared_rate_squared() {
    let x = state(0.0);
    let r = Matrix3::from_diagonal(&Vector3::new(1e-4, 2e-4, 3e-4));
    let model = AugmentedDvlModel::new(r)
        .unwrap()
        .with_rate_noise(0.5)
        .unwrap();
    let w2 = 0.01f64.powi(2) + 0.02f64.powi(2) + 0.05f64.powi(2);
    let expected = r + Matrix3::identity() * (0.25 * w2);
    let got = model.noise_covariance(&x).unwrap();
    assert!((got - expected).abs().max() < 1e-18, "{got} vs {expected}");
    let plain = AugmentedDvlModel::new(r).unwrap();
    assert_eq!(plain.noise_covariance(&x).unwrap(), r);
    for bad in [-0.1, f64::NAN] {
        assert!(AugmentedDvlModel::new(r)
            .unwrap()
            .with_rate_noise(bad)
            .is_err());
    }
    assert!(AugmentedDvlModel::new(-r).is_err());
}

/// `with_noise_scale` multiplies R + κ² |ω|² I by the scale; a bad scale is refused.
#[test]
fn noise_scale_scales_r_and_the_rate_noise() {
    let x = state(0.0);
    let r = Matrix3::from_diagonal(&Vector3::new(1e-4, 2e-4, 3e-4));
    let model = AugmentedDvlModel::new(r)
        .unwrap()
        .with_rate_noise(0.5)
        .unwrap();
    let base = model.noise_covariance(&x).unwrap();
    for scale in [0.01, 0.3, 7.0] {
        let got = model
            .with_noise_scale(scale)
            .unwrap()
            .noise_covariance(&x)
            .unwrap();
        let expected = base * scale;
        assert!(
            (got - expected).abs().max() <= 1e-15 * expected.abs().max(),
            "{got} vs {expected}"
        );
    }
    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        assert!(model.with_noise_scale(bad).is_err());
    }
}

/// `with_noise_covariance` replaces R and drops the rate noise: its R is the given
/// one at any angular rate; a matrix that is not a covariance is refused.
#[test]
fn noise_covariance_replaces_r_and_drops_the_rate_noise() {
    let x = state(0.0);
    let model = AugmentedDvlModel::new(Matrix3::identity() * 1e-4)
        .unwrap()
        .with_rate_noise(0.5)
        .unwrap();
    let r = Matrix3::new(4e-4, 1e-5, 0.0, 1e-5, 9e-4, 0.0, 0.0, 0.0, 1e-4);
    let got = model
        .with_noise_covariance(r)
        .unwrap()
        .noise_covariance(&x)
        .unwrap();
    assert_eq!(got, r);
    assert!(model
        .noise_covariance(&x)
        .unwrap()
        .iter()
        .zip(r.iter())
        .any(|(a, b)| a != b));
    let not_symmetric = Matrix3::new(1.0, 0.5, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0);
    for bad in [
        not_symmetric,
        -Matrix3::identity(),
        Matrix3::identity() * f64::NAN,
    ] {
        assert!(model.with_noise_covariance(bad).is_err());
    }
}

/// An update with its R given (`dvl_velocity_with_noise`) equals `dvl_velocity_with`
/// on a model built with that R and no rate noise, to 1e-12; the adapted level stays.
#[test]
fn an_update_with_a_given_r_equals_the_model_built_with_it() {
    use crate::navigator::NavigatorConfig;
    let mission = mission(30.0, 6);
    let mut config = NavigatorConfig::default();
    config.dvl.noise_std_mps = 0.01;
    config.dvl.adaptive_noise_window = Some(20);
    config.gate.probability = 0.0;
    let settings = config.check().unwrap();
    let states = DvlStatesConfig {
        bias: BiasConfig {
            estimate: true,
            std_mps: 0.01,
            time_constant_s: 30.0,
        },
        ..DvlStatesConfig::default()
    };
    let x0 = mission.truth[0];
    let p0 = ErrorMatrix::identity() * 1e-3;
    let dt = mission.imu_dt;
    let mut given = AugmentedNavigator::with_states(&settings, &states, x0, p0, dt).unwrap();
    let mut built = AugmentedNavigator::with_states(&settings, &states, x0, p0, dt).unwrap();
    let r = Matrix3::from_diagonal(&Vector3::new(2.5e-5, 1.6e-3, 1e-4));
    let model = AugmentedDvlModel::new(r).unwrap();
    for k in 0..mission.imu.len() {
        given.imu(&mission.imu[k]).unwrap();
        built.imu(&mission.imu[k]).unwrap();
        if (k + 1) % 100 != 0 {
            continue;
        }
        let truth = &mission.truth[k + 1];
        let y = truth.attitude.inverse() * truth.velocity_ned + Vector3::new(0.01, -0.02, 0.0);
        let a = given
            .dvl_velocity_with_noise(truth.time, &y, &r, &Zero)
            .unwrap();
        let b = built
            .dvl_velocity_with(truth.time, &y, &model, &Zero)
            .unwrap();
        assert!((a.nis - b.nis).abs() <= 1e-12 * b.nis.max(1.0));
        assert_eq!(given.dvl_noise_scale(), Some(1.0));
    }
    let d = (given.covariance() - built.covariance()).abs().max();
    assert!(
        d <= 1e-12 * built.covariance().abs().max(),
        "P differs by {d}"
    );
}

/// With `dvl.adaptive_noise_window`, `dvl_velocity` equals a loop coded here
/// again: update with the model at λ, feed the innovation, S and λR + the bias
/// block of the prior P to a `NoiseScale`, then set the bias sigma to σ √λ. The
/// DVL noise is 3x the configured std, so λ moves well away from 1.
#[test]
fn adaptive_noise_equals_the_loop_coded_again() {
    use crate::navigator::NavigatorConfig;
    use estim_core::noise::adaptive::NoiseScaleConfig;
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    let mission = mission(120.0, 5);
    let mut config = NavigatorConfig::default();
    config.dvl.noise_std_mps = 0.01;
    config.gate.probability = 0.0;
    let fixed = config.check().unwrap();
    config.dvl.adaptive_noise_window = Some(50);
    let adaptive = config.check().unwrap();
    let states = DvlStatesConfig {
        bias: BiasConfig {
            estimate: true,
            std_mps: 0.01,
            time_constant_s: 30.0,
        },
        ..DvlStatesConfig::default()
    };
    let x0 = mission.truth[0];
    let p0 = ErrorMatrix::from_diagonal(&SVector::<f64, ERROR_STATES>::from_iterator([
        1.0, 1.0, 1.0, 1e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-5, 1e-6, 1e-6, 1e-6, 1e-10, 1e-10, 1e-10,
    ]));
    let dt = mission.imu_dt;
    let mut nav = AugmentedNavigator::with_states(&adaptive, &states, x0, p0, dt).unwrap();
    let mut reference = AugmentedNavigator::with_states(&fixed, &states, x0, p0, dt).unwrap();
    let r = Matrix3::identity() * 1e-4;
    let mut estimate = NoiseScale::new(NoiseScaleConfig {
        window: 50,
        ..NoiseScaleConfig::default()
    })
    .unwrap();
    let truth_model = estim_dvl::DvlVelocityModel::builder()
        .noise_std(0.01)
        .build()
        .unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let mut lambda = 1.0;
    for k in 0..mission.imu.len() {
        nav.imu(&mission.imu[k]).unwrap();
        reference.imu(&mission.imu[k]).unwrap();
        if (k + 1) % 100 != 0 {
            continue;
        }
        let truth = &mission.truth[k + 1];
        let noise = Vector3::from_fn(|_, _| {
            let z: f64 = StandardNormal.sample(&mut rng);
            0.03 * z
        });
        let y = truth_model.predict(truth).unwrap() + noise;
        assert_eq!(nav.dvl_noise_scale(), Some(lambda));
        let a = nav.dvl_velocity(truth.time, &y, &Zero).unwrap();
        reference.propagate_to(truth.time).unwrap();
        let bias_prior = reference
            .covariance()
            .fixed_view::<3, 3>(DVL_BIAS, DVL_BIAS)
            .into_owned();
        let model = AugmentedDvlModel::new(r * lambda).unwrap();
        let b = reference
            .dvl_velocity_with(truth.time, &y, &model, &Zero)
            .unwrap();
        assert!((a.nis - b.nis).abs() <= 1e-9 * b.nis.max(1.0));
        lambda = estimate
            .update(
                &b.innovation,
                &b.innovation_covariance,
                &(r * lambda + bias_prior),
            )
            .unwrap();
        reference.set_bias_std(0.01 * lambda.sqrt()).unwrap();
    }
    assert!(lambda > 3.0, "scale {lambda}");
    let d = (nav.covariance() - reference.covariance()).abs().max();
    assert!(
        d <= 1e-9 * reference.covariance().abs().max(),
        "P differs by {d}"
    );
    let (a, b) = (nav.solution(), reference.solution());
    let (dvl_a, dvl_b) = (nav.dvl_states().unwrap(), reference.dvl_states().unwrap());
    assert!((dvl_a.bias_mps[0] - dvl_b.bias_mps[0]).abs() < 1e-12);
    assert!((a.latitude_deg - b.latitude_deg).abs() < 1e-12);
}

/// With the time offset estimated, the navigator's DVL prediction at t is the
/// nominal body velocity at t - τ (τ = 0.35 s, every other DVL state zero),
/// interpolated in the nominal's own history recorded here, with the mission's
/// noisy IMU (0.03 m/s^2 per sample): within 1e-3 m/s (neglected Coriolis and
/// transport rate, below 3e-4 m/s^2; the worst epoch is 1.5e-4 to 2.4e-4 m/s
/// over mission seeds 3, 4, 5 and 7, checked once). The model without the window
/// (the last sample's a_b) misses by 0.034-0.041 m/s at its worst epoch: τ times
/// one sample's noise.
#[test]
fn time_offset_prediction_is_the_nominal_velocity_tau_earlier() {
    use crate::navigator::NavigatorConfig;
    let tau = 0.35;
    let mission = mission(60.0, 3);
    let mut config = NavigatorConfig::default();
    config.gate.probability = 0.0;
    let settings = config.check().unwrap();
    let mut states = DvlStatesConfig::none();
    states.time_offset.estimate = true;
    let dvl0 = DvlParameters {
        scale_factor_error: 0.0,
        dvl_to_body: Rotation3::identity(),
        bias: Vector3::zeros(),
        lever_arm: Vector3::zeros(),
        time_offset: tau,
    };
    let x0 = mission.truth[0];
    let p0 = ErrorMatrix::identity() * 1e-6;
    let mut nav =
        AugmentedNavigator::with_dvl(&settings, &states, x0, dvl0, p0, mission.imu_dt).unwrap();
    let body_velocity = |x: &AugmentedState| x.ins.attitude.inverse() * x.ins.velocity_ned;
    let mut history: Vec<(f64, Vector3<f64>)> = Vec::new();
    let (mut worst, mut worst_raw) = (0.0_f64, 0.0_f64);
    for k in 0..mission.imu.len() {
        nav.imu(&mission.imu[k]).unwrap();
        let x = nav.nominal();
        history.push((x.ins.time, body_velocity(x)));
        if (k + 1) % 100 != 0 || k < 200 {
            continue;
        }
        let t = mission.truth[k + 1].time;
        nav.propagate_to(t).unwrap();
        let x = *nav.nominal();
        history.push((x.ins.time, body_velocity(&x)));
        let target = t - x.dvl.time_offset;
        let i = history.partition_point(|(time, _)| *time < target);
        let ((t0, v0), (t1, v1)) = (history[i - 1], history[i]);
        let reference = v0 + (v1 - v0) * ((target - t0) / (t1 - t0));
        let raw = AugmentedDvlModel::new(Matrix3::identity() * 1e-4)
            .unwrap()
            .predict(&x)
            .unwrap();
        let report = nav.dvl_velocity(t, &reference, &Zero).unwrap();
        worst = worst.max(report.innovation.norm());
        worst_raw = worst_raw.max((reference - raw).norm());
    }
    assert!(worst < 1e-3, "prediction misses by {worst} m/s");
    assert!(worst_raw > 3e-3, "without the window: {worst_raw} m/s");
}

/// The bias block of Q after `set_bias_std` is sigma² (1 - e^{-2 dt / tau}) with
/// the new sigma (the exact Gauss-Markov discretisation, coded here again); a
/// model without a bias, or a bad sigma, is refused.
#[test]
fn set_bias_std_changes_the_bias_process_noise() {
    let mut states = DvlStatesConfig {
        bias: BiasConfig {
            estimate: true,
            std_mps: 0.04,
            time_constant_s: 1.5,
        },
        ..DvlStatesConfig::default()
    };
    let mut m =
        AugmentedErrorModel::new(InsErrorModel::new(ImuSpec::akit_observed()), &states).unwrap();
    m.set_bias_std(0.01).unwrap();
    assert_eq!(m.bias(), Some((0.01, 1.5)));
    let x = state(0.0);
    let sample = ImuSample {
        time: 0.01,
        specific_force: x.specific_force,
        angular_rate: x.ins.angular_rate,
    };
    let dt = 0.01;
    let (_, q) = m.transition_and_noise(&x, &sample, dt).unwrap();
    let expected = 0.01f64.powi(2) * (1.0 - (-2.0 * dt / 1.5f64).exp());
    for i in 0..3 {
        let got = q[(DVL_BIAS + i, DVL_BIAS + i)];
        // 1 - phi² against 1 - e^{-2 dt/tau}: the subtraction amplifies the
        // rounding of e^x by 1 / (1 - phi²) (about 75 here), hence 1e-12.
        assert!(
            (got - expected).abs() <= 1e-12 * expected,
            "{got} vs {expected}"
        );
    }
    for bad in [0.0, -0.1, f64::NAN] {
        assert!(m.set_bias_std(bad).is_err());
    }
    assert_eq!(m.bias(), Some((0.01, 1.5)));
    states.bias.estimate = false;
    let mut without =
        AugmentedErrorModel::new(InsErrorModel::new(ImuSpec::akit_observed()), &states).unwrap();
    assert!(without.set_bias_std(0.01).is_err());
}

#[test]
fn bad_state_settings_are_typed_errors_naming_the_key() {
    let mut c = DvlStatesConfig::default();
    c.bias.time_constant_s = 0.0;
    let e = c.check().unwrap_err().to_string();
    assert!(e.contains("dvl_states.bias.time_constant_s"), "{e}");
    let mut c = DvlStatesConfig::default();
    c.time_offset.prior_std_s = f64::NAN;
    let e = c.check().unwrap_err().to_string();
    assert!(e.contains("dvl_states.time_offset.prior_std_s"), "{e}");
    let mut c = DvlStatesConfig::default();
    c.lever_arm.prior_std_m = AxisSigma::All(11.0);
    let e = c.check().unwrap_err().to_string();
    assert!(e.contains("dvl_states.lever_arm.prior_std_m"), "{e}");
    // Per axis: 0 holds an axis, but not every axis, and no value out of range.
    for bad in [
        [0.0; 3],
        [0.01, -0.01, 0.01],
        [0.01, f64::NAN, 0.0],
        [0.2, 0.0, 0.0],
    ] {
        let mut c = DvlStatesConfig::default();
        c.misalignment.prior_std_rad = AxisSigma::PerAxis(bad);
        let e = c.check().unwrap_err().to_string();
        assert!(e.contains("dvl_states.misalignment.prior_std_rad"), "{e}");
    }
    let mut c = DvlStatesConfig::default();
    c.misalignment.prior_std_rad = AxisSigma::All(0.0);
    assert!(c.check().is_err());
    c.misalignment.prior_std_rad = AxisSigma::PerAxis([0.01, 0.0, 0.02]);
    assert!(c.check().is_ok());
    // Not estimated: its values are not used and not checked.
    let mut c = DvlStatesConfig::none();
    c.time_offset.prior_std_s = -1.0;
    assert!(c.check().is_ok());
    {
        let e = toml::from_str::<DvlStatesConfig>("[bias]\nestimate = true\nstd = 1\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("std"), "{e}");
        let e = toml::from_str::<DvlStatesConfig>(
            "[misalignment]\nestimate = true\nprior_std_rad = [0.01, 0.0]\n",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("prior_std_rad"), "{e}");
        assert!(e.contains("a number or an array of 3 numbers"), "{e}");
    }
}

/// A per-axis prior: the variances are the squares of each axis's sigma, a held
/// axis's is 0, and a number applies to every axis.
#[test]
fn per_axis_priors_give_per_axis_variances() {
    let mut c = DvlStatesConfig::none();
    c.misalignment.estimate = true;
    c.misalignment.prior_std_rad = AxisSigma::PerAxis([0.002, 0.0, 0.003]);
    c.lever_arm.estimate = true;
    c.lever_arm.prior_std_m = AxisSigma::All(0.5);
    c.check().unwrap();
    let v = c.prior_variances();
    let expected = [0.0, 4e-6, 0.0, 9e-6, 0.0, 0.0, 0.0, 0.25, 0.25, 0.25, 0.0];
    for (i, e) in expected.iter().enumerate() {
        assert!((v[i] - e).abs() <= 1e-18, "state {i}: {} vs {e}", v[i]);
    }
    {
        let parsed: DvlStatesConfig = toml::from_str(
            "[misalignment]\nestimate = true\nprior_std_rad = [0.002, 0, 0.003]\n\
             [lever_arm]\nestimate = true\nprior_std_m = 0.5\n\
             [scale_factor]\nestimate = false\nprior_std = 0.005\n\
             [bias]\nestimate = false\nstd_mps = 0.01\ntime_constant_s = 60\n\
             [time_offset]\nestimate = false\nprior_std_s = 0.5\n",
        )
        .unwrap();
        assert_eq!(parsed, c);
    }
}

/// A held axis stays held through a run: its rows of P stay exactly zero and a
/// held lever-arm axis keeps its configured value, while the estimated axes move.
#[test]
fn a_held_axis_stays_at_its_initial_value() {
    use crate::navigator::NavigatorConfig;
    let mission = mission(60.0, 5);
    let mut config = NavigatorConfig::default();
    config.dvl.lever_arm_m = [1.0, 0.0, 0.2];
    config.dvl.noise_std_mps = 0.01;
    let settings = config.check().unwrap();
    let mut states = DvlStatesConfig::none();
    states.misalignment.estimate = true;
    states.misalignment.prior_std_rad = AxisSigma::PerAxis([0.01, 0.0, 0.01]);
    states.lever_arm.estimate = true;
    states.lever_arm.prior_std_m = AxisSigma::PerAxis([0.1, 0.1, 0.0]);
    let x0 = mission.truth[0];
    let p0 = ErrorMatrix::identity() * 1e-4;
    let mut aug =
        AugmentedNavigator::with_states(&settings, &states, x0, p0, mission.imu_dt).unwrap();
    // The DVL is mounted 5 mrad off in yaw and its lever arm is 0.3 m further aft
    // than configured: the estimated axes have something to find.
    let mut truth_config = config.clone();
    truth_config.dvl.mounting_misalignment_rad = [0.0, 0.0, 0.005];
    truth_config.dvl.lever_arm_m = [0.7, 0.0, 0.2];
    let dvl = truth_config.check().unwrap().dvl_model().clone();
    for k in 0..mission.imu.len() {
        aug.imu(&mission.imu[k]).unwrap();
        if (k + 1) % 20 == 0 {
            let truth = &mission.truth[k + 1];
            let v = dvl.predict(truth).unwrap();
            aug.dvl_velocity(truth.time, &v, &Zero).unwrap();
        }
    }
    let p = aug.covariance();
    for i in [DVL_MISALIGNMENT + 1, DVL_LEVER_ARM + 2] {
        assert!(p.row(i).iter().all(|v| *v == 0.0), "row {i} of P not zero");
        assert!(
            p.column(i).iter().all(|v| *v == 0.0),
            "column {i} of P not zero"
        );
    }
    let dvl_state = aug.nominal().dvl;
    assert_eq!(dvl_state.lever_arm[2], 0.2);
    assert!(dvl_state.lever_arm[0] != 1.0, "lever arm x did not move");
    let mu = dvl_state.mounting_misalignment();
    assert!(mu[2] != 0.0, "yaw misalignment did not move");
    // The estimated axes were updated: their variances fell below the priors.
    assert!(p[(DVL_MISALIGNMENT + 2, DVL_MISALIGNMENT + 2)] < 0.01f64.powi(2));
    assert!(p[(DVL_LEVER_ARM, DVL_LEVER_ARM)] < 0.1f64.powi(2));
}
