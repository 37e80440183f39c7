//! NetworkSensitivity (first-order, finite-difference JVPs, linear error model) agrees
//! with Empirical (Monte Carlo: nonlinear mechanization + network on noisy windows),
//! both read from the window an error-state filter recorded; and the adjoint and
//! per-step forms of NetworkSensitivity agree.

use estim_core::window::StepWindow;
use estim_core::{ErrorStateKalmanFilter, FilterConfig, WindowedCrossCovariance};
use estim_ins::{
    ImuSample, ImuSpec, InsErrorModel, InsState, Mission, MissionConfig, ERROR_STATES,
};
use estim_learned::{
    default_model_path, BeamsNet, CrossMatrix, Empirical, LearnedCrossCovariance,
    NetworkSensitivity, OnnxMeasurement, BEAMSNET_WINDOW,
};
use nalgebra::{DMatrix, SMatrix, Vector3, Vector4};

/// A filter that integrated the 100 IMU samples of a window in the middle of a
/// mission, and the beams of the true body velocity at its end.
fn recorded(
    seed: u64,
) -> (
    ErrorStateKalmanFilter<f64, InsErrorModel, ERROR_STATES>,
    Vector4<f64>,
) {
    let config = MissionConfig::builder().duration(60.0).build().unwrap();
    let mission = Mission::generate(&config, seed).unwrap();
    let start = 3000;
    let state = mission.truth[start + BEAMSNET_WINDOW];
    let v_body: Vector3<f64> = state.attitude.inverse() * state.velocity_ned;
    let beams = estim_dvl::BeamGeometry::beamsnet().beams(&v_body);
    let model = InsErrorModel::new(ImuSpec::akit_observed());
    let mut filter = ErrorStateKalmanFilter::new(
        model,
        mission.truth[start],
        SMatrix::<f64, ERROR_STATES, ERROR_STATES>::identity() * 1e-6,
    )
    .unwrap()
    .with_config(
        FilterConfig::builder()
            .window_capacity(BEAMSNET_WINDOW)
            .build()
            .unwrap(),
    );
    for imu in &mission.imu[start..start + BEAMSNET_WINDOW] {
        filter.predict(imu, mission.imu_dt).unwrap();
    }
    (filter, beams)
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

#[test]
fn network_sensitivity_matches_monte_carlo() {
    let beamsnet = BeamsNet::load_default().unwrap();
    let (filter, beams) = recorded(11);
    let window = filter.step_window(BEAMSNET_WINDOW).unwrap();
    let analytic = NetworkSensitivity::new(&beamsnet, filter.process(), beams)
        .unwrap()
        .transported_cross_covariance(&window)
        .unwrap()
        .unwrap();
    let realizations = 4000;
    let mc = Empirical::new(&beamsnet, filter.process(), beams, realizations, 99)
        .estimate(&window)
        .unwrap();
    println!(
        "NetworkSensitivity M (rows vel, att):\n{}",
        analytic.fixed_rows::<6>(3)
    );
    println!("Empirical M:\n{}", mc.cross_covariance.fixed_rows::<6>(3));
    println!(
        "Empirical standard error:\n{}",
        mc.standard_error.fixed_rows::<6>(3)
    );
    // Tolerance: the Monte Carlo estimate of each element has standard error se (sample
    // standard deviation of δx_r (y_c - ȳ_c) over sqrt(N)); 4 se bounds the MC error
    // with probability > 0.9999 per element. On top, 10% of |M| for the first-order
    // (linearised INS error, finite-difference JVP) approximation.
    let mut worst = 0.0f64;
    for r in 0..ERROR_STATES {
        for c in 0..3 {
            let d = (analytic[(r, c)] - mc.cross_covariance[(r, c)]).abs();
            let tol = 4.0 * mc.standard_error[(r, c)] + 0.1 * analytic[(r, c)].abs();
            worst = worst.max(d / tol.max(f64::MIN_POSITIVE));
            assert!(
                d <= tol,
                "M[{r},{c}]: analytic {:e}, Monte Carlo {:e} ± {:e}",
                analytic[(r, c)],
                mc.cross_covariance[(r, c)],
                mc.standard_error[(r, c)]
            );
        }
    }
    println!("worst |difference| / tolerance = {worst:.3}");
    // The velocity block is where the correlation lives: it must be resolved (not
    // within the Monte Carlo noise of zero), or the agreement above would be empty.
    let vel = analytic.fixed_rows::<3>(3);
    let se = mc.standard_error.fixed_rows::<3>(3);
    assert!(vel.amax() > 10.0 * se.amax(), "M_vel {vel} vs se {se}");
}

/// The adjoint form (15 JVP directions, each spanning the window) and the per-step
/// form (600 unit directions, one IMU channel of one sample each) of BeamsNet's M.
///
/// BeamsNet retrained under the beam protocol (estim issue 12) does not use the IMU:
/// both forms give an M at the float32 resolution of the network's output (measured
/// on this window at the default step: max |M| 1.1e-8 adjoint; the forms differ by
/// 0.31 of that, 0.06 at step 1e-2: round-off, not signal). What is checked here is
/// that both forms say so, far below the resolved M of a network that does use the
/// IMU (two-beams network, 2e-6 to 1e-5 on simulated windows, `tests/two_beams.rs`,
/// where the two forms are compared). The threshold 1e-7 is 9x the measured value.
#[test]
fn adjoint_and_per_step_forms_agree() {
    let (filter, beams) = recorded(12);
    let window = filter.step_window(BEAMSNET_WINDOW).unwrap();
    let extra = [DMatrix::from_column_slice(4, 1, beams.as_slice())];
    let model = OnnxMeasurement::<3>::from_model_path(&default_model_path()).unwrap();
    let generic = LearnedCrossCovariance::new(&model, filter.process(), &extra).unwrap();
    let adjoint = generic
        .transported_cross_covariance(&window)
        .unwrap()
        .unwrap();
    let per_step = per_step_sum(&generic, &window);
    println!(
        "max |M|: adjoint {:.3e}, per step {:.3e}",
        adjoint.amax(),
        per_step.amax()
    );
    assert!(adjoint.amax() < 1e-7, "adjoint M\n{adjoint}");
    assert!(per_step.amax() < 1e-7, "per-step M\n{per_step}");
    let beamsnet = BeamsNet::load_default().unwrap();
    let ns = NetworkSensitivity::new(&beamsnet, filter.process(), beams).unwrap();
    // The network reads exactly the samples the filter integrated.
    let force: Vec<Vector3<f64>> = window.iter().map(|s| s.input.specific_force).collect();
    let rate: Vec<Vector3<f64>> = window.iter().map(|s| s.input.angular_rate).collect();
    let direct = beamsnet
        .velocity(&estim_learned::BeamsNetInput::from_samples(
            &force, &rate, beams,
        ))
        .unwrap();
    assert_eq!(ns.measure(&window).unwrap(), direct);
}

#[test]
fn a_window_of_the_wrong_length_is_a_typed_error() {
    let beamsnet = BeamsNet::load_default().unwrap();
    let (filter, beams) = recorded(13);
    let short = filter.step_window(BEAMSNET_WINDOW - 1).unwrap();
    let ns = NetworkSensitivity::new(&beamsnet, filter.process(), beams).unwrap();
    assert!(ns.transported_cross_covariance(&short).is_err());
    assert!(Empirical::new(&beamsnet, filter.process(), beams, 10, 1)
        .estimate(&short)
        .is_err());
    assert!(Empirical::new(&beamsnet, filter.process(), beams, 1, 1)
        .estimate(&filter.step_window(BEAMSNET_WINDOW).unwrap())
        .is_err());
}
