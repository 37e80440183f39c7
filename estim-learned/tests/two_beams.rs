//! The two-beams network (IMU window + beams 1 and 2 -> velocity): tract reproduces
//! PyTorch on the exported parity vectors; its M is the generic
//! `LearnedCrossCovariance` over the window an error-state filter recorded, compared
//! with the Monte Carlo M (`Empirical::for_model`: nonlinear mechanization + network on
//! noisy windows) where the network is linear at the noise scale, and at the real noise
//! with the noise-averaged first-order M (Stein's lemma); the input-driven error
//! covariance matches its recursion.

mod common;
use common::{flatten, record};

use estim_core::window::StepWindow;
use estim_core::{ErrorStateKalmanFilter, WindowedCrossCovariance};
use estim_ins::{
    ImuSample, ImuSpec, InsErrorModel, InsState, Mission, MissionConfig, SimulatedMission,
    ERROR_STATES,
};
use estim_learned::{
    driven_error_covariance, CrossMatrix, Empirical, InputNoise, LearnedCrossCovariance,
    OnnxMeasurement, TwoBeamsNet, BEAMSNET_WINDOW, IMU_CHANNELS,
};
use nalgebra::{DMatrix, SMatrix, Vector3, Vector4};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};

#[test]
fn tract_matches_pytorch_within_1e_5() {
    check_parity("two_beams");
}

/// The two-beams network trained on recorded IMU windows (its parity inputs are seeded
/// synthetic ones: no recorded window is committed).
#[test]
fn recorded_tract_matches_pytorch_within_1e_5() {
    check_parity("two_beams_recorded");
}

/// `models/NAME.onnx` run by tract on the cases of `models/NAME_parity.json`, within
/// 1e-5 of PyTorch's outputs.
fn check_parity(name: &str) {
    let dir = common::models_dir();
    let model = OnnxMeasurement::<3>::from_model_path(&dir.join(format!("{name}.onnx"))).unwrap();
    let text = std::fs::read_to_string(dir.join(format!("{name}_parity.json"))).unwrap();
    let parity: serde_json::Value = serde_json::from_str(&text).unwrap();
    let cases = parity["cases"].as_array().unwrap();
    assert!(cases.len() >= 2);
    let mut worst = 0.0f64;
    for case in cases {
        let tensors: Vec<Vec<f32>> = ["acc", "gyro", "beams"]
            .iter()
            .map(|k| flatten(&case[*k]))
            .collect();
        assert_eq!(tensors[2].len(), 2);
        let want = flatten(&case["velocity"]);
        let got = model.run_normalised(1, &tensors).unwrap();
        for (g, w) in got[0].iter().zip(&want) {
            worst = worst.max((g - f64::from(*w)).abs());
        }
    }
    println!("{name}: worst |tract - pytorch| = {worst:e}");
    assert!(worst <= 1e-5, "worst deviation {worst:e}");
}

/// A simulated mission, the start of a window in its middle, and the four beams of the
/// true body velocity at the window's end.
fn mission_window(seed: u64) -> (SimulatedMission, usize, Vector4<f64>) {
    let config = MissionConfig::builder().duration(60.0).build().unwrap();
    let mission = Mission::generate(&config, seed).unwrap();
    let start = 3000;
    let state = mission.truth[start + BEAMSNET_WINDOW];
    let v_body: Vector3<f64> = state.attitude.inverse() * state.velocity_ned;
    let beams = estim_dvl::BeamGeometry::beamsnet().beams(&v_body);
    (mission, start, beams)
}

/// The filter that integrated the window's recorded IMU samples, and the beams.
fn recorded(
    seed: u64,
) -> (
    ErrorStateKalmanFilter<f64, InsErrorModel, ERROR_STATES>,
    Vector4<f64>,
) {
    let (mission, start, beams) = mission_window(seed);
    let filter = record(
        &mission,
        start,
        &mission.imu[start..start + BEAMSNET_WINDOW],
    );
    (filter, beams)
}

#[test]
fn beam_inputs_pick_the_two_beams_used() {
    let net = TwoBeamsNet::load_default().unwrap();
    let [a, b] = net.beams_used();
    let beams = Vector4::new(0.1, 0.2, 0.3, 0.4);
    let extra = net.beam_inputs(&beams).unwrap();
    assert_eq!(extra.len(), 1);
    assert_eq!(extra[0].shape(), (2, 1));
    assert_eq!((extra[0][0], extra[0][1]), (beams[a], beams[b]));
    let mut missing = beams;
    missing[a] = f64::NAN;
    assert!(net.beam_inputs(&missing).is_none());
    // A beam the network does not read may be missing.
    let other = (0..4).find(|i| *i != a && *i != b).unwrap();
    let mut unused = beams;
    unused[other] = f64::NAN;
    assert!(net.beam_inputs(&unused).is_some());
}

/// Q_w from the adjoint transport equals the forward recursion
/// C <- Phi_j C Phi_j' + A_j Σ_j A_j' over the recorded steps (coded here).
#[test]
fn driven_error_covariance_matches_its_recursion() {
    let (filter, _) = recorded(21);
    let window = filter.step_window(BEAMSNET_WINDOW).unwrap();
    let process = filter.process();
    let q =
        driven_error_covariance::<f64, _, ERROR_STATES, IMU_CHANNELS>(process, &window).unwrap();
    let mut c = SMatrix::<f64, ERROR_STATES, ERROR_STATES>::zeros();
    for step in window.iter() {
        let dt = step.dt.unwrap();
        let a = process.input_noise_jacobian(step.state, step.input, dt);
        let phi = step.transition;
        c = phi * c * phi.transpose() + a * process.input_noise_covariance(dt) * a.transpose();
    }
    let scale = c.amax();
    assert!(scale > 0.0);
    assert!((q - c).amax() <= 1e-12 * scale, "{q}\nvs\n{c}");
}

fn per_step_sum(
    cross: &impl WindowedCrossCovariance<f64, InsState, ImuSample, ERROR_STATES, 3>,
    window: &StepWindow<'_, f64, InsState, ImuSample, ERROR_STATES>,
) -> CrossMatrix {
    // C <- Phi_j C + D_j, with the recorded transitions.
    let mut c = CrossMatrix::zeros();
    let mut j = 0;
    cross
        .step_cross_covariances(window, &mut |d: &CrossMatrix| {
            c = window.step(j).unwrap().transition * c + d;
            j += 1;
            Ok(())
        })
        .unwrap();
    assert_eq!(j, window.len());
    c
}

/// The adjoint form (15 JVP directions spanning the window) and the per-step form
/// (600 unit directions) of the generic M on a network that uses the IMU. Both are
/// central-difference JVPs (step `DEFAULT_SENSITIVITY_STEP`) of a float32 network with
/// tanh and ReLU units, the per-step form perturbing one sample at a time, the adjoint
/// all samples at once; they differ by the differences' truncation error (curvature,
/// kinks straddled) and float32 rounding. Measured max |adjoint - per step| / max |M|
/// on seeds 11, 12, 13: 3.4e-4, 3.7e-4, 2.7e-4 (max |M| 1.0e-5, 7.8e-6, 6.6e-6); the
/// bound 0.01 (27 times the largest) holds all three.
#[test]
fn adjoint_and_per_step_forms_agree() {
    let net = TwoBeamsNet::load_default().unwrap();
    for seed in [11, 12, 13] {
        let (filter, beams) = recorded(seed);
        let window = filter.step_window(BEAMSNET_WINDOW).unwrap();
        let extra = net.beam_inputs(&beams).unwrap();
        let generic = LearnedCrossCovariance::<f64, _, _, 3, IMU_CHANNELS>::new(
            net.measurement(),
            filter.process(),
            &extra,
        )
        .unwrap();
        let adjoint = generic
            .transported_cross_covariance(&window)
            .unwrap()
            .unwrap();
        let per_step = per_step_sum(&generic, &window);
        let diff = (adjoint - per_step).amax() / adjoint.amax();
        println!(
            "seed {seed}: max |M| {:.3e}, forms differ by {diff:.3e}",
            adjoint.amax()
        );
        // Resolved: far above BeamsNet's float32-level M (1e-8).
        assert!(adjoint.amax() > 1e-6, "seed {seed}: M\n{adjoint}");
        assert!(
            diff <= 0.01,
            "seed {seed}: adjoint\n{adjoint}per step\n{per_step}"
        );
    }
}

/// The A-KIT IMU error model with its white noise scaled by `scale` (the biases as
/// they are).
fn error_model_scaled(scale: f64) -> InsErrorModel {
    let base = ImuSpec::akit_observed();
    let mut acc = *base.accelerometer();
    let mut gyro = *base.gyroscope();
    acc.white_noise_density *= scale;
    gyro.white_noise_density *= scale;
    InsErrorModel::new(
        ImuSpec::builder()
            .accelerometer(acc)
            .gyroscope(gyro)
            .build()
            .unwrap(),
    )
}

/// The first-order M of the generic piece (adjoint form) on a recorded window.
fn first_order(
    net: &TwoBeamsNet,
    model: &InsErrorModel,
    window: &StepWindow<'_, f64, InsState, ImuSample, ERROR_STATES>,
    extra: &[DMatrix<f64>],
) -> CrossMatrix {
    LearnedCrossCovariance::<f64, _, _, 3, IMU_CHANNELS>::new(net.measurement(), model, extra)
        .unwrap()
        .transported_cross_covariance(window)
        .unwrap()
        .unwrap()
}

/// Largest |first order - Monte Carlo| / (4 se + 10 % |first order|) over the elements
/// (4 se: probability > 0.9999 per element for the Monte Carlo error; 10 %: the
/// first-order INS error and the finite-difference JVPs).
fn worst_ratio(first: &CrossMatrix, mc: &CrossMatrix, se: &CrossMatrix) -> f64 {
    let mut worst = 0.0f64;
    for r in 0..ERROR_STATES {
        for c in 0..3 {
            let d = (first[(r, c)] - mc[(r, c)]).abs();
            let tol = 4.0 * se[(r, c)] + 0.1 * first[(r, c)].abs();
            worst = worst.max(if d == 0.0 { 0.0 } else { d / tol });
        }
    }
    worst
}

/// The first-order M does not depend on the central-difference step around the default
/// (`DEFAULT_SENSITIVITY_STEP`): max |M(step) - M(default)| / max |M(default)| <= 5 %
/// (half the 10 % of |M| the Monte Carlo comparison allows for the first-order
/// approximation) at steps 2e-3, 3e-3 and 5e-3 on seeds 11-13. The wider range is
/// printed: above it the two evaluations straddle more ReLU kinks, below it the float32
/// rounding error grows as 1 / step.
#[test]
fn first_order_m_is_step_insensitive_around_the_default() {
    let net = TwoBeamsNet::load_default().unwrap();
    let model = InsErrorModel::new(ImuSpec::akit_observed());
    for seed in [11, 12, 13] {
        let (filter, beams) = recorded(seed);
        let window = filter.step_window(BEAMSNET_WINDOW).unwrap();
        let extra = net.beam_inputs(&beams).unwrap();
        let at = |step: f64| {
            let measurement = net.measurement().clone().with_sensitivity_step(step);
            LearnedCrossCovariance::<f64, _, _, 3, IMU_CHANNELS>::new(&measurement, &model, &extra)
                .unwrap()
                .transported_cross_covariance(&window)
                .unwrap()
                .unwrap()
        };
        common::assert_m_step_insensitive(&format!("seed {seed}"), at);
    }
}

/// Sign convention, window alignment and transport of the generic M, checked where the
/// first-order model is exact: with the IMU white noise scaled by 0.1 the network is
/// linear at the noise scale and the first-order M (which scales as 0.01, the noise
/// variance) must match the Monte Carlo M within 4 se + 10 % per element. Measured
/// worst ratio to that tolerance on seeds 11, 12, 13 is printed: 0.58 / 0.38 / 0.63,
/// with max |M - M_MC| / max |M| at 0.17, 0.13, 0.072 and the Monte Carlo's own
/// se / max |M| at 0.078, 0.077, 0.065 (4000 draws): agreement at the Monte Carlo's
/// resolution. Re-run with Monte Carlo seeds 3-9 on each of the three windows: worst
/// ratio at most 0.49 / 0.73 / 0.75. On a second block (mission seeds 14-16, MC seeds
/// 5, 6, 8): 0.39 / 0.24 / 0.46, where the window of mission 16 has a velocity block
/// (1.1e-8) below 5 se (1.4e-8), unresolved, which the last assertion refuses.
#[test]
fn first_order_m_matches_monte_carlo_where_the_network_is_linear() {
    let net = TwoBeamsNet::load_default().unwrap();
    let model = error_model_scaled(0.1);
    for (mission_seed, mc_seed) in [(11, 99), (12, 7), (13, 2024)] {
        let (filter, beams) = recorded(mission_seed);
        let window = filter.step_window(BEAMSNET_WINDOW).unwrap();
        let extra = net.beam_inputs(&beams).unwrap();
        let first = first_order(&net, &model, &window, &extra);
        let mc = Empirical::for_model(net.measurement(), &model, extra, 4000, mc_seed)
            .estimate(&window)
            .unwrap();
        let worst = worst_ratio(&first, &mc.cross_covariance, &mc.standard_error);
        println!("seed {mission_seed}: worst |difference| / tolerance = {worst:.3}");
        assert!(
            worst <= 1.0,
            "seed {mission_seed}: first order\n{first}Monte Carlo\n{}± {}",
            mc.cross_covariance,
            mc.standard_error
        );
        // Resolved: the velocity block is well above the Monte Carlo noise.
        assert!(first.fixed_rows::<3>(3).amax() > 5.0 * mc.standard_error.amax());
    }
}

/// At the A-KIT IMU noise the first-order M and the Monte Carlo M differ by more than
/// the Monte Carlo error (measured on seed 11: 34 % of max |M|, 6 se): the network is
/// not linear at the noise scale (0.03 m/s^2 per sample is 0.2 of the z-accelerometer
/// normalisation). By Stein's lemma the Monte Carlo measures Cov(n, y(x + n)) =
/// Σ E_n[J(x + n)]: the Jacobian averaged over the noise, where the first-order M uses
/// J at the window's samples. So the reference for the Monte Carlo is the first-order M
/// averaged over noisy copies of the window (each re-recorded by the filter), coded
/// here independently of `Empirical`: it must agree within 4 (se_MC + se_avg) + 10 %
/// per element. And since the recorded samples already carry one noise draw, J at them
/// is itself one draw of J(x + n): the network-derived M is an unbiased but noisy
/// estimate of E[J] per update (the spread is printed).
///
/// Measured (seeds 11-13): local vs Monte Carlo 0.36 / 1.17 / 0.16 of max |M|;
/// averaged vs Monte Carlo worst ratio to the tolerance 0.51 / 0.44 / 0.50; per-draw
/// spread (std) of the first-order M 0.25 / 3.49 / 0.26 of max |E M|. Second block
/// (mission seeds 14-16, MC seeds 5, 6, 8): worst ratio 0.37 / 0.25 / 0.40.
#[test]
fn monte_carlo_m_is_the_noise_averaged_first_order_m() {
    let net = TwoBeamsNet::load_default().unwrap();
    let model = InsErrorModel::new(ImuSpec::akit_observed());
    let draws = 400;
    for (mission_seed, mc_seed) in [(11, 99), (12, 7), (13, 2024)] {
        let (mission, start, beams) = mission_window(mission_seed);
        let extra = net.beam_inputs(&beams).unwrap();
        let filter = record(
            &mission,
            start,
            &mission.imu[start..start + BEAMSNET_WINDOW],
        );
        let window = filter.step_window(BEAMSNET_WINDOW).unwrap();
        let local = first_order(&net, &model, &window, &extra);
        let mc = Empirical::for_model(net.measurement(), &model, extra.clone(), 4000, mc_seed)
            .estimate(&window)
            .unwrap();
        // Noise-averaged first-order M (seeded draws with the per-sample covariance).
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(mc_seed + 1);
        let sigma = model
            .input_noise_covariance(mission.imu_dt)
            .diagonal()
            .map(f64::sqrt);
        let mut sum = CrossMatrix::zeros();
        let mut sum_sq = CrossMatrix::zeros();
        for _ in 0..draws {
            let noisy: Vec<ImuSample> = mission.imu[start..start + BEAMSNET_WINDOW]
                .iter()
                .map(|s| {
                    let mut s = *s;
                    for i in 0..3 {
                        let a: f64 = StandardNormal.sample(&mut rng);
                        let g: f64 = StandardNormal.sample(&mut rng);
                        s.specific_force[i] += a * sigma[i];
                        s.angular_rate[i] += g * sigma[3 + i];
                    }
                    s
                })
                .collect();
            let f = record(&mission, start, &noisy);
            let m = first_order(
                &net,
                &model,
                &f.step_window(BEAMSNET_WINDOW).unwrap(),
                &extra,
            );
            sum += m;
            sum_sq += m.component_mul(&m);
        }
        let n = draws as f64;
        let mean = sum / n;
        let se_avg =
            ((sum_sq / n - mean.component_mul(&mean)).map(|v| v.max(0.0)) / n).map(f64::sqrt);
        let spread = (se_avg * n.sqrt()).amax() / mean.amax();
        let mut worst = 0.0f64;
        for r in 0..ERROR_STATES {
            for c in 0..3 {
                let d = (mean[(r, c)] - mc.cross_covariance[(r, c)]).abs();
                let tol =
                    4.0 * (mc.standard_error[(r, c)] + se_avg[(r, c)]) + 0.1 * mean[(r, c)].abs();
                worst = worst.max(if d == 0.0 { 0.0 } else { d / tol });
            }
        }
        println!(
            "seed {mission_seed}: local vs MC {:.3} of max |M|; averaged vs MC worst ratio {worst:.3}; \
             per-draw spread of the first-order M {spread:.2} of max |E M|",
            (local - mc.cross_covariance).amax() / local.amax()
        );
        assert!(
            worst <= 1.0,
            "seed {mission_seed}: averaged\n{mean}Monte Carlo\n{}",
            mc.cross_covariance
        );
    }
}

#[test]
fn wrong_layouts_are_typed_errors() {
    let net = TwoBeamsNet::load_default().unwrap();
    let (filter, beams) = recorded(11);
    let extra = net.beam_inputs(&beams).unwrap();
    let generic = LearnedCrossCovariance::<f64, _, _, 3, IMU_CHANNELS>::new(
        net.measurement(),
        filter.process(),
        &extra,
    )
    .unwrap();
    let short = filter.step_window(BEAMSNET_WINDOW - 1).unwrap();
    assert!(generic.transported_cross_covariance(&short).is_err());
    // No per-update input, or four beams where the network reads two.
    assert!(LearnedCrossCovariance::<f64, _, _, 3, IMU_CHANNELS>::new(
        net.measurement(),
        filter.process(),
        &[],
    )
    .is_err());
    let four = [DMatrix::from_column_slice(4, 1, beams.as_slice())];
    assert!(LearnedCrossCovariance::<f64, _, _, 3, IMU_CHANNELS>::new(
        net.measurement(),
        filter.process(),
        &four,
    )
    .is_err());
    let full = filter.step_window(BEAMSNET_WINDOW).unwrap();
    assert!(
        Empirical::for_model(net.measurement(), filter.process(), four.to_vec(), 10, 1)
            .estimate(&full)
            .is_err()
    );
    assert!(
        Empirical::for_model(net.measurement(), filter.process(), extra.clone(), 10, 1)
            .estimate(&short)
            .is_err()
    );
}
