//! What propagating the covariance at a lower rate than the IMU costs: 400 s of the
//! default synthetic mission, covariance at 100 Hz (every IMU step) against 10 Hz (Phi and
//! Q over 0.1 s from the first sample of each block of 10).

use estim_core::ProcessModel;
use estim_ins::{ErrorMatrix, ImuSpec, InsErrorModel, Mechanization, Mission, MissionConfig};
use nalgebra::SVector;

fn final_sigmas(decimation: usize) -> SVector<f64, 15> {
    let mission = Mission::generate(&MissionConfig::default(), 11).unwrap();
    let model = InsErrorModel::new(ImuSpec::akit_observed());
    let mech = Mechanization::new();
    let dt = mission.imu_dt;
    let mut s = mission.truth[0];
    let mut p = ErrorMatrix::from_diagonal(&SVector::<f64, 15>::from_fn(|i, _| {
        [1.0, 1e-2, 1e-6, 1e-6, 1e-10][i / 3]
    }));
    for block in mission.clean_imu.chunks(decimation) {
        let span = dt * block.len() as f64;
        let (phi, q) = model.transition_and_noise(&s, &block[0], span);
        p = model.propagate_covariance(&p, &phi, &q);
        for imu in block {
            s = mech.step(&s, imu, dt).unwrap();
        }
    }
    p.diagonal().map(f64::sqrt)
}

#[test]
fn covariance_at_10_hz_stays_within_a_tenth_of_a_percent_of_100_hz() {
    let full = final_sigmas(1);
    let low = final_sigmas(10);
    let rel = (low - full).component_div(&full);
    println!(
        "final 1-sigma at 100 Hz: {}",
        full.as_slice()
            .iter()
            .map(|x| format!("{x:.3e}"))
            .collect::<Vec<_>>()
            .join(" ")
    );
    println!(
        "relative change at 10 Hz: {}",
        rel.as_slice()
            .iter()
            .map(|x| format!("{x:.2e}"))
            .collect::<Vec<_>>()
            .join(" ")
    );
    let worst = rel.amax();
    println!("largest relative change of a final sigma: {worst:e}");
    // The 10 Hz transition holds the attitude (and so C_b^n, [f^n x]) of the block's
    // first sample for 0.1 s; over a turning mission that averages out to a small bias.
    assert!(worst < 1e-3, "{worst}");
}
