//! NetworkSensitivity (first-order, finite-difference JVPs, linear error model) agrees
//! with Empirical (Monte Carlo: nonlinear mechanization + network on noisy windows).

use estim_core::{check_joint_covariance, CrossCovariance, CrossCovarianceContext};
use estim_ins::{ImuSpec, InsErrorModel, Mission, MissionConfig, ERROR_STATES};
use estim_learned::{BeamsNet, Empirical, ImuWindow, NetworkSensitivity};
use nalgebra::{SMatrix, Vector3, Vector4};

fn window(seed: u64) -> ImuWindow {
    let config = MissionConfig::builder().duration(60.0).build().unwrap();
    let mission = Mission::generate(&config, seed).unwrap();
    // A window in the middle of the mission, beams from the true body velocity.
    let start = 3000;
    let state = mission.truth[start + 100];
    let v_body: Vector3<f64> = state.attitude.inverse() * state.velocity_ned;
    let geometry = estim_dvl::BeamGeometry::beamsnet();
    let beams: Vector4<f64> = geometry.beams(&v_body);
    ImuWindow {
        states: mission.truth[start..start + 100].to_vec(),
        imu: mission.imu[start..start + 100].to_vec(),
        beams,
        dt: mission.imu_dt,
    }
}

#[test]
fn network_sensitivity_matches_monte_carlo() {
    let beamsnet = BeamsNet::load_default().unwrap();
    let model = InsErrorModel::new(ImuSpec::akit_observed());
    let w = window(11);
    let analytic = NetworkSensitivity::new(beamsnet.clone(), model)
        .compute(&w)
        .unwrap();
    let realizations = 4000;
    let mc = Empirical::new(beamsnet, model, realizations, 99)
        .estimate(&w)
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
}

#[test]
fn cross_covariance_trait_checks_the_joint_covariance() {
    let beamsnet = BeamsNet::load_default().unwrap();
    let model = InsErrorModel::new(ImuSpec::akit_observed());
    let w = window(12);
    let mut ns = NetworkSensitivity::new(beamsnet.clone(), model);
    let q = SMatrix::<f64, ERROR_STATES, ERROR_STATES>::identity() * 1e-4;
    let r = beamsnet.noise_covariance();
    let h = SMatrix::<f64, 3, ERROR_STATES>::zeros();
    let y = Vector3::zeros();
    let p = SMatrix::<f64, ERROR_STATES, ERROR_STATES>::identity();
    let ctx = CrossCovarianceContext {
        accumulated_process_noise: &q,
        accumulated_transition: &p,
        accumulation_tracked: true,
        measurement_noise: &r,
        jacobian: &h,
        measurement: &y,
        state: &w.states[99],
        covariance: &p,
    };
    // No window set: a clear error, not a panic.
    assert!(ns.cross_covariance(&ctx).is_err());
    ns.set_window(w.clone()).unwrap();
    let m = ns.cross_covariance(&ctx).unwrap();
    assert!(check_joint_covariance(&q, &m, &r).is_ok());
    // Mismatched window lengths are a typed error.
    let mut bad = w;
    bad.states.pop();
    assert!(ns.set_window(bad).is_err());
}
