use estim_core::nalgebra::{DMatrix, Matrix3x4, SMatrix, Vector3};
use estim_core::WindowedCrossCovariance;
use estim_core::{ErrorStateKalmanFilter, FilterConfig, LearnedMeasurement};
use estim_dvl::BeamGeometry;
use estim_ins::{ImuSpec, InsErrorModel, ATT, ERROR_STATES, VEL};
use estim_learned::{LearnedCrossCovariance, IMU_CHANNELS};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::*;
use crate::study::run::filter_imu_spec;
use crate::study::CrossMatrix;

use super::gyro_stand_in::{gyro_update_inputs, GyroStandIn};

/// A short mission of `grade` (5 DVL epochs).
fn short(grade: &str, seed: u64) -> (Config, Scenario) {
    let config = cell_config(&Config::default(), grade, 5.0);
    let scenario = Scenario::simulated(&config, seed).expect("simulated mission");
    (config, scenario)
}

/// The generic M of the dead-reckoning stand-ins against two references coded
/// apart from it: the forward recursion S <- Phi_j S + G_j,acc q dt α C_{b_k <- b_j}'
/// over the recorded steps (Simon 2006 sec. 7.1 carried over the window; the
/// oracle's form), to rounding; and the closed form of its velocity block,
/// -α q T C_b^n(t_k) (Phi_vv = I over 1 s up to the Earth-rate terms), to 1e-3.
#[test]
fn dead_reckoning_m_equals_the_closed_form() {
    let (config, scenario) = short("akit_observed", 11);
    let error_model = InsErrorModel::new(filter_imu_spec(&scenario.imu_spec).unwrap());
    let q = scenario
        .imu_spec
        .accelerometer()
        .white_noise_density
        .powi(2);
    let dt = scenario.imu_dt;
    let window = 100;
    for kind in [SensorKind::DeadReckoning, SensorKind::HalfDeadReckoning] {
        let alpha = kind.imu_gain();
        let sensor = stand_in_measurements(kind, DvlNoise::Beam, &scenario, &config, 3).unwrap();
        for (k, epoch) in scenario.dvl.iter().enumerate() {
            let end = epoch.imu_index;
            let m = sensor.cross_covariances[k];
            let recording = FilterConfig::builder()
                .window_capacity(window)
                .build()
                .unwrap();
            let mut recorder = ErrorStateKalmanFilter::new(
                error_model,
                scenario.truth[end - window],
                SMatrix::<f64, ERROR_STATES, ERROR_STATES>::identity(),
            )
            .unwrap()
            .with_config(recording);
            for sample in &scenario.imu[end - window..end] {
                recorder.predict(sample, dt).unwrap();
            }
            let c_nb_k = scenario.truth[end]
                .attitude
                .inverse()
                .to_rotation_matrix()
                .into_inner();
            let mut s = CrossMatrix::zeros();
            for (j, step) in recorder.step_window(window).unwrap().iter().enumerate() {
                let c_bn_nominal = step.state.attitude.to_rotation_matrix().into_inner();
                let c_bn_truth = scenario.truth[end - window + j]
                    .attitude
                    .to_rotation_matrix()
                    .into_inner();
                let mut g = CrossMatrix::zeros();
                g.fixed_view_mut::<3, 3>(VEL, 0).copy_from(
                    &(-c_bn_nominal * (c_nb_k * c_bn_truth).transpose() * (q * dt * alpha)),
                );
                s = step.transition * s + g;
            }
            let scale = s.abs().max();
            assert!(scale > 0.0);
            assert!(
                (m - s).abs().max() <= 1e-12 * scale,
                "{kind:?} epoch {k}: generic {m} vs recursion {s}"
            );
            let closed = -c_nb_k.transpose() * (alpha * q * dt * window as f64);
            let velocity_block = m.fixed_view::<3, 3>(VEL, 0).into_owned();
            assert!(
                (velocity_block - closed).abs().max() <= 1e-3 * closed.abs().max(),
                "{kind:?} epoch {k}: {velocity_block} vs {closed}"
            );
        }
    }
}

/// The beams-only stand-in reads the IMU window and ignores it: its M is zero to the
/// bit, at every epoch, for every grade's window.
#[test]
fn beams_only_m_is_zero() {
    for grade in GRADES {
        let (config, scenario) = short(grade, 5);
        let sensor = stand_in_measurements(
            SensorKind::BeamsOnly,
            DvlNoise::Mismatch,
            &scenario,
            &config,
            1,
        )
        .unwrap();
        assert_eq!(
            sensor.velocities.iter().flatten().count(),
            scenario.dvl.len()
        );
        assert!(sensor
            .cross_covariances
            .iter()
            .all(|m| m.iter().all(|v| *v == 0.0)));
    }
}

/// The stand-ins' errors against the truth at the DVL have the R they report: the
/// mean of e' R⁻¹ e over 3 missions x 60 epochs is that of chi-square(3), 3 with
/// standard error sqrt(6 / 180) = 0.18; asserted within 0.75 (4 standard errors).
/// The IMU noise is the A-KIT level with the accelerometer noise x 3, so that the
/// carried IMU noise dominates R where α > 0.
/// The A-KIT IMU level with the accelerometer white noise x 3.
fn noisy_accelerometer(mut config: Config) -> Config {
    let acc = *ImuSpec::akit_observed().accelerometer();
    config.imu.accelerometer = Some(crate::experiment::SensorSection {
        white_noise_density: 3.0 * acc.white_noise_density,
        bias_instability: acc.bias_instability,
        bias_time_constant: acc.bias_time_constant,
        turn_on_bias: acc.turn_on_bias,
        scale_factor: acc.scale_factor,
    });
    config
}

#[test]
fn stand_in_errors_have_the_reported_covariance() {
    for kind in SensorKind::ALL {
        for noise in DvlNoise::ALL {
            let mut sum = 0.0;
            let mut count = 0;
            for seed in 0..3 {
                let config =
                    noisy_accelerometer(cell_config(&Config::default(), "akit_observed", 60.0));
                let scenario = Scenario::simulated(&config, 40 + seed).unwrap();
                let sensor = stand_in_measurements(kind, noise, &scenario, &config, seed).unwrap();
                for (k, epoch) in scenario.dvl.iter().enumerate() {
                    let (Some(y), Some(r)) = (sensor.velocities[k], sensor.noise_covariances[k])
                    else {
                        continue;
                    };
                    let e = y - epoch.reference_velocity;
                    sum += (e.transpose() * r.try_inverse().unwrap() * e)[0];
                    count += 1;
                }
            }
            let mean = sum / count as f64;
            assert_eq!(count, 180);
            assert!(
                (mean - 3.0).abs() < 0.75,
                "{kind:?} {noise:?}: mean e'R^-1 e {mean}"
            );
        }
    }
}

/// Where M matters most (the A-KIT IMU with the accelerometer noise x 3, beam-level
/// DVL noise, the dead-reckoning stand-in: correlation 0.99), 100 missions of 30 s
/// (seeds 500-599): with the exact M the time mean of the run-averaged NEES lies in
/// the 95 % band of one epoch's run-average (13.95-16.09; a consistent filter's
/// time mean varies less than one epoch's) and at least 70 % of the epochs have
/// their average in it (95 % expected; successive epochs are correlated); with M
/// neglected the time mean is above the band. Other seed blocks (set
/// `WHERE_M_FIRST_SEED`, and `WHERE_M_RUNS` / `WHERE_M_DURATION` to vary the cell)
/// measured before committing: first seeds 500 (the default), 0, 100, 200, 300,
/// 400 give exact 14.60, 14.95, 15.57, 14.62, 15.25, 15.37 (100 % of epochs in
/// band) and neglected 16.91, 17.24, 17.84, 16.80, 17.51, 17.63. With 40 missions
/// of 60 s the exact filter's time mean spread wider than that band (it left it in
/// 2 of 5 blocks): the unobservable states keep each run's NEES level, so the time
/// mean averages over runs more than over epochs.
#[test]
fn exact_m_is_consistent_and_neglected_m_is_not_where_m_matters() {
    let env = |name: &str, default: u64| {
        std::env::var(name)
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(default)
    };
    let first_seed = env("WHERE_M_FIRST_SEED", 500);
    let runs = env("WHERE_M_RUNS", 100) as usize;
    let mut base = noisy_accelerometer(Config::default());
    base.mission.duration_s = env("WHERE_M_DURATION", 30) as f64;
    let report = where_m(
        &base,
        &["akit_observed"],
        &[DvlNoise::Beam],
        &[SensorKind::DeadReckoning],
        runs,
        first_seed,
        &|| {},
    )
    .unwrap();
    let cell = &report.cells[0];
    let [lower, upper] = cell.nees_band;
    eprintln!(
        "seeds {first_seed}..: exact {:.2} ({:.0} % in band), neglected {:.2}, band {lower:.2}-{upper:.2}, corr. {:.2}",
        cell.exact.nees_average,
        cell.exact.nees_epochs_in_band_percent,
        cell.neglected.nees_average,
        cell.output_imu_correlation
    );
    assert!(
        (lower..=upper).contains(&cell.exact.nees_average)
            && cell.exact.nees_epochs_in_band_percent >= 70.0,
        "exact M: {:?}",
        cell.exact
    );
    assert!(
        cell.neglected.nees_average > upper,
        "M neglected: {:?}",
        cell.neglected
    );
    // The sign: the exact M raises the velocity std.
    assert!(cell.velocity_std_change > 0.0, "{cell:?}");
}

/// The gyro stand-in (mismatch-level DVL noise) on one epoch of a short consumer-MEMS
/// mission: its inputs and the
/// recorded window of an error-state filter started from the truth.
fn gyro_epoch() -> (GyroStandIn, Vec<DMatrix<f64>>, [f64; 2], Scenario, usize) {
    let (config, scenario) = short("consumer_mems", 21);
    let geometry = BeamGeometry::beamsnet();
    let model = GyroStandIn::new(100, scenario.imu_dt, &geometry, DvlNoise::Mismatch);
    let psd = [
        scenario
            .imu_spec
            .accelerometer()
            .white_noise_density
            .powi(2),
        scenario.imu_spec.gyroscope().white_noise_density.powi(2),
    ];
    let end = scenario.dvl[2].imu_index;
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let lever_arm = Vector3::from(config.dvl.lever_arm_m);
    let (extra, _) = gyro_update_inputs(
        &model,
        &scenario,
        &lever_arm,
        &geometry,
        psd,
        DvlNoise::Mismatch,
        end,
        &mut rng,
    )
    .unwrap();
    let mut imu = DMatrix::zeros(IMU_CHANNELS, 100);
    for (column, sample) in scenario.imu[end - 100..end].iter().enumerate() {
        for r in 0..3 {
            imu[(r, column)] = sample.specific_force[r];
            imu[(3 + r, column)] = sample.angular_rate[r];
        }
    }
    let inputs = std::iter::once(imu).chain(extra).collect();
    (model, inputs, psd, scenario, end)
}

/// One unit direction (stream `stream`, element (row, column)) in the model's shapes.
fn unit(inputs: &[DMatrix<f64>], stream: usize, row: usize, column: usize) -> Vec<DMatrix<f64>> {
    let mut d: Vec<DMatrix<f64>> = inputs
        .iter()
        .map(|m| DMatrix::zeros(m.nrows(), m.ncols()))
        .collect();
    d[stream][(row, column)] = 1.0;
    d
}

/// The gyro stand-in's JVPs against central finite differences of its `measure`
/// (every input stream, a sample of elements; step 1e-4 of max(|element|, 1),
/// agreement to 1e-6 relative: the model is a polynomial, linear in all but the
/// gyroscope samples and the attitude, of low curvature at that step), and its closed-form R against the R assembled from JVP columns
/// (G σ_v² G' + J_b σ_b² J_b' + Σ_j J_j Σ_j J_j', to 1e-9 relative).
#[test]
fn gyro_stand_in_jvps_and_r_match_independent_references() {
    let (model, inputs, psd, _, _) = gyro_epoch();
    let elements = [
        (0, 0, 0),
        (0, 2, 50),
        (0, 3, 0),
        (0, 4, 37),
        (0, 5, 99),
        (1, 1, 0),
        (2, 4, 0),
        (3, 2, 0),
        (4, 0, 0),
    ];
    for (stream, row, column) in elements {
        let d = unit(&inputs, stream, row, column);
        let mut product = [Vector3::zeros()];
        model.sensitivity(&inputs, &d, &mut product).unwrap();
        let h = 1e-4 * inputs[stream][(row, column)].abs().max(1.0);
        let shifted = |sign: f64| {
            let mut x = inputs.clone();
            x[stream][(row, column)] += sign * h;
            model.measure(&x).unwrap()
        };
        let fd = (shifted(1.0) - shifted(-1.0)) / (2.0 * h);
        assert!(
            (product[0] - fd).norm() <= 1e-6 * fd.norm().max(1e-9),
            "stream {stream} ({row}, {column}): jvp {} fd {}",
            product[0],
            fd
        );
    }
    // R from JVP columns.
    let dt = 0.01;
    let column_of = |stream, row, column| {
        let mut p = [Vector3::zeros()];
        model
            .sensitivity(&inputs, &unit(&inputs, stream, row, column), &mut p)
            .unwrap();
        p[0]
    };
    let j_beams = Matrix3x4::from_columns(&[
        column_of(1, 0, 0),
        column_of(1, 1, 0),
        column_of(1, 2, 0),
        column_of(1, 3, 0),
    ]);
    let g = j_beams * BeamGeometry::beamsnet().matrix();
    let mut reference = g * g.transpose() * MISMATCH_STD.powi(2)
        + j_beams * j_beams.transpose() * BEAM_NOISE_STD.powi(2);
    for j in 0..100 {
        for c in 0..6 {
            let col = column_of(0, c, j);
            let variance = if c < 3 { psd[0] } else { psd[1] } / dt;
            reference += col * col.transpose() * variance;
        }
    }
    let r = model.noise_covariance_at(&inputs, psd).unwrap();
    assert!(
        (r - reference).abs().max() <= 1e-9 * reference.abs().max(),
        "closed form {r} vs JVP columns {reference}"
    );
}

/// The generic (adjoint) M of the gyro stand-in against the forward recursion
/// S <- Phi_j S + A_j Σ_j J_j' with J_j from per-sample JVPs, over the recorded
/// steps, to 1e-9 relative; the attitude rows are non-zero (the gyroscope noise is
/// shared).
#[test]
fn gyro_stand_in_m_equals_the_forward_recursion() {
    let (model, inputs, _, scenario, end) = gyro_epoch();
    let error_model = InsErrorModel::new(filter_imu_spec(&scenario.imu_spec).unwrap());
    let recording = FilterConfig::builder()
        .window_capacity(100)
        .build()
        .unwrap();
    let mut recorder = ErrorStateKalmanFilter::new(
        error_model,
        scenario.truth[end - 100],
        SMatrix::<f64, ERROR_STATES, ERROR_STATES>::identity(),
    )
    .unwrap()
    .with_config(recording);
    for sample in &scenario.imu[end - 100..end] {
        recorder.predict(sample, scenario.imu_dt).unwrap();
    }
    let steps = recorder.step_window(100).unwrap();
    let cross = LearnedCrossCovariance::<f64, _, _, 3, IMU_CHANNELS>::new(
        &model,
        &error_model,
        &inputs[1..],
    )
    .unwrap();
    let m = cross.transported_cross_covariance(&steps).unwrap().unwrap();
    let mut s = CrossMatrix::zeros();
    for step in steps.iter() {
        let dt = step.dt.unwrap();
        let mut jt = SMatrix::<f64, IMU_CHANNELS, 3>::zeros();
        for c in 0..IMU_CHANNELS {
            let mut p = [Vector3::zeros()];
            model
                .sensitivity(&inputs, &unit(&inputs, 0, c, step.position), &mut p)
                .unwrap();
            jt.set_row(c, &p[0].transpose());
        }
        let a = estim_learned::InputNoise::input_noise_jacobian(
            &error_model,
            step.state,
            step.input,
            dt,
        );
        let sigma =
            estim_learned::InputNoise::<f64, ERROR_STATES, IMU_CHANNELS>::input_noise_covariance(
                &error_model,
                dt,
            );
        s = step.transition * s + a * sigma * jt;
    }
    assert!(
        (m - s).abs().max() <= 1e-9 * s.abs().max(),
        "adjoint {m} vs forward {s}"
    );
    assert!(m.fixed_view::<3, 3>(ATT, 0).abs().max() > 0.0);
}
