//! The 400 s / 100 Hz default mission with the covariance propagated every step (the
//! loop of the `ins_mission_400s_100hz` bench), as a plain program to run under a
//! profiler, e.g.
//!
//! ```text
//! CARGO_PROFILE_RELEASE_DEBUG=line-tables-only cargo build --release -p estim-ins --example mission_profile
//! valgrind --tool=callgrind --callgrind-out-file=cg.out target/release/examples/mission_profile
//! callgrind_annotate --inclusive=yes cg.out
//! ```

use estim_ins::{ErrorMatrix, ImuSpec, InsErrorModel, Mechanization, Mission, MissionConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mission = Mission::generate(&MissionConfig::default(), 7)?;
    let model = InsErrorModel::new(ImuSpec::akit_observed());
    let mech = Mechanization::new();
    let dt = mission.imu_dt;
    let mut p = ErrorMatrix::from_diagonal(&nalgebra::SVector::<f64, 15>::from_fn(|i, _| {
        [1.0, 1e-2, 1e-6, 1e-6, 1e-10][i / 3]
    }));
    let mut s = mission.truth[0];
    for imu in &mission.imu {
        model.predict_covariance(&s, imu, dt, &mut p);
        s = mech.step_unchecked(&s, imu, dt);
    }
    println!(
        "final 1-sigma: {:?}",
        p.diagonal().map(f64::sqrt).as_slice()
    );
    Ok(())
}
