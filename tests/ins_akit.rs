//! Round trip on the A-KIT ground truth: the error-free IMU simulated from trajectories 4
//! and 13 (1 Hz GT, 100 Hz IMU), integrated by the strapdown mechanization from the GT
//! initial state, must reproduce the trajectory over the 400 s.
//!
//! Needs the data (see shared/data/README.md); without it the test prints why and
//! returns, unless `ESTIM_REQUIRE_DATA=1`.

use std::path::PathBuf;

use estim::datasets::{data_root, load_gt, trajectory_files};
use estim_ins::earth::radii_of_curvature;
use estim_ins::{InsState, Mechanization, Trajectory, TrajectorySample};
use nalgebra::{UnitQuaternion, Vector3};

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

fn trajectory(n: u32) -> Option<Trajectory> {
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
    let samples = gt
        .iter()
        .map(|g| TrajectorySample {
            time: g.time,
            latitude: g.latitude,
            longitude: g.longitude,
            height: g.altitude,
            velocity_ned: Vector3::from(g.velocity_ned),
            attitude: UnitQuaternion::from_euler_angles(
                g.roll_pitch_yaw[0],
                g.roll_pitch_yaw[1],
                g.roll_pitch_yaw[2],
            ),
        })
        .collect();
    Some(Trajectory::new(samples).unwrap())
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

fn round_trip(n: u32) {
    let Some(traj) = trajectory(n) else { return };
    let (truth, imu) = traj.simulate(100.0).unwrap();
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
        "trajectory {n}: {} steps over {:.1} s; final errors: position {p:.4} m, velocity {v:.2e} m/s, attitude {a:.2e} deg; max: {:.4} m, {:.2e} m/s, {:.2e} deg",
        imu.len(),
        last.time - truth[0].time,
        worst.0,
        worst.1,
        worst.2
    );
    assert!(last.time - truth[0].time > 390.0);
    assert!(gt_last.time - last.time < 0.01 + 1e-9);
    assert!(p <= 1.0, "final position error {p} m");
    assert!(v <= 0.01, "final velocity error {v} m/s");
    assert!(a <= 0.01, "final attitude error {a} deg");
}

#[test]
fn akit_trajectory_4_round_trip() {
    round_trip(4);
}

#[test]
fn akit_trajectory_13_round_trip() {
    round_trip(13);
}
