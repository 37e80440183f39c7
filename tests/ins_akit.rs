//! Round trip on the A-KIT ground truth: the error-free IMU simulated from trajectories 4
//! and 13 (1 Hz GT, 100 Hz IMU), integrated by the strapdown mechanization from the GT
//! initial state, must reproduce the trajectory over the 400 s.
//!
//! Needs the data (see shared/data/README.md); without it the test prints why and
//! returns, unless `ESTIM_REQUIRE_DATA=1`.

use std::path::PathBuf;

use estim::datasets::{data_root, load_gt, trajectory_files};
use estim_ins::earth::radii_of_curvature;
use estim_ins::{InsState, Mechanization, Trajectory};
use nalgebra::Vector3;

fn data_dir() -> Option<PathBuf> {
    if let Some(p) = data_root(None).filter(|p| p.is_dir()) {
        return Some(p);
    }
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data");
    p.is_dir().then_some(p)
}

fn require_data(reason: &str) {
    if std::env::var("ESTIM_REQUIRE_DATA").is_ok_and(|v| v == "1") {
        panic!("ESTIM_REQUIRE_DATA=1 but {reason}");
    }
    eprintln!("skipping: {reason}");
}

fn trajectory(n: u32, velocity_driven: bool) -> Option<Trajectory> {
    let Some(root) = data_dir() else {
        require_data("no data folder (set ESTIM_DATA_DIR)");
        return None;
    };
    let files = match trajectory_files(&root, n) {
        Ok(f) => f,
        Err(e) => {
            require_data(&e.to_string());
            return None;
        }
    };
    let gt = load_gt(&files.gt).unwrap();
    let samples = gt.iter().map(|g| g.trajectory_sample()).collect();
    Some(if velocity_driven {
        Trajectory::velocity_driven(samples).unwrap()
    } else {
        Trajectory::new(samples).unwrap()
    })
}

/// (horizontal+vertical position error [m], velocity error [m/s], attitude error [deg]).
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

fn round_trip(n: u32, velocity_driven: bool) {
    let Some(traj) = trajectory(n, velocity_driven) else {
        return;
    };
    let fit = if velocity_driven {
        "velocity spline"
    } else {
        "Hermite"
    };
    let (truth, imu) = traj.simulate(100.0).unwrap();
    // Realism of the simulated IMU (reported, not asserted): horizontal specific force and
    // its jump between consecutive samples (the Hermite fit's acceleration kinks).
    let rms = |f: &dyn Fn(&estim_ins::ImuSample) -> f64| {
        (imu.iter().map(|s| f(s).powi(2)).sum::<f64>() / imu.len() as f64).sqrt()
    };
    let max_jump = imu
        .windows(2)
        .map(|w| (w[1].specific_force - w[0].specific_force).norm())
        .fold(0.0, f64::max);
    println!(
        "trajectory {n} ({fit}) simulated IMU: rms f_x {:.3} f_y {:.3} f_z {:.3} m/s^2, rms gyro z {:.4} rad/s, largest sample-to-sample jump of f {:.3} m/s^2",
        rms(&|s| s.specific_force.x),
        rms(&|s| s.specific_force.y),
        rms(&|s| s.specific_force.z),
        rms(&|s| s.angular_rate.z),
        max_jump
    );
    let mech = Mechanization::new();
    let mut s = truth[0];
    let mut worst = (0.0f64, 0.0f64, 0.0f64);
    for (k, sample) in imu.iter().enumerate() {
        s = mech.step(&s, sample, 0.01).unwrap();
        let e = errors(&s, &truth[k + 1]);
        worst = (worst.0.max(e.0), worst.1.max(e.1), worst.2.max(e.2));
    }
    let last = truth.last().unwrap();
    let (p, v, a) = errors(&s, last);
    // The interpolated truth passes through the GT samples: check that at the last one.
    let gt_last = traj.samples().last().unwrap();
    println!(
        "trajectory {n} ({fit}): {} steps over {:.1} s; final errors: position {p:.4} m, velocity {v:.2e} m/s, attitude {a:.2e} deg; max: {:.4} m, {:.2e} m/s, {:.2e} deg",
        imu.len(),
        last.time - truth[0].time,
        worst.0,
        worst.1,
        worst.2
    );
    // How far the simulated truth is from the GT positions (0 for the Hermite fit at
    // the samples; for the velocity spline it is the data's position/velocity mismatch).
    let at_last_sample = traj.evaluate(gt_last.time).unwrap().state;
    let mut gt_state = at_last_sample;
    gt_state.latitude = gt_last.latitude;
    gt_state.longitude = gt_last.longitude;
    gt_state.height = gt_last.height;
    println!(
        "trajectory {n} ({fit}): simulated truth vs GT position at the last sample {:.3} m",
        errors(&at_last_sample, &gt_state).0
    );
    assert!(last.time - truth[0].time > 390.0);
    assert!(gt_last.time - last.time < 0.01 + 1e-9);
    assert!(p <= 1.0, "final position error {p} m");
    assert!(v <= 0.01, "final velocity error {v} m/s");
    assert!(a <= 0.01, "final attitude error {a} deg");
}

#[test]
fn akit_trajectory_4_round_trip() {
    round_trip(4, false);
}

#[test]
fn akit_trajectory_13_round_trip() {
    round_trip(13, false);
}

#[test]
fn akit_trajectory_4_round_trip_velocity_spline() {
    round_trip(4, true);
}

#[test]
fn akit_trajectory_13_round_trip_velocity_spline() {
    round_trip(13, true);
}
