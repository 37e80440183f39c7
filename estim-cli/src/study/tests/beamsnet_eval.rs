//! BeamsNet vs least squares on the held-out A-KIT trajectories 4 and 13 (as `estim
//! beamsnet eval`), the metrics checked against an independent computation.
//!
//! Data rule: if the data is absent the tests print why and return, unless
//! `ESTIM_REQUIRE_DATA=1`. Run with `--nocapture` to see the table.

use std::path::Path;

use estim::datasets::{load_dvl, load_gt, trajectory_files};
use estim_core::nalgebra::Vector3;
use estim_dvl::BeamsNetProtocol;
use estim_ins::{ImuSpec, Trajectory};
use estim_learned::BeamsNet;

use super::common::data_root;
use crate::study::{evaluate_beamsnet, synthesize};

fn load(root: &Path, n: u32) -> (Trajectory, Vec<(f64, Vector3<f64>)>) {
    let files = trajectory_files(root, n).unwrap();
    let samples = load_gt(&files.gt)
        .unwrap()
        .iter()
        .map(|g| g.trajectory_sample())
        .collect();
    let trajectory = Trajectory::new(samples).unwrap();
    let dvl = load_dvl(&files.dvl)
        .unwrap()
        .iter()
        .filter(|d| d.time <= trajectory.end_time())
        .map(|d| (d.time, Vector3::from(d.velocity_body)))
        .collect();
    (trajectory, dvl)
}

/// RMSE, MAE, R^2, VAF on |v| coded independently of estim_learned::metrics.
fn reference_metrics(truth: &[Vector3<f64>], pred: &[Vector3<f64>]) -> [f64; 4] {
    let y: Vec<f64> = truth
        .iter()
        .map(|v| (v.x * v.x + v.y * v.y + v.z * v.z).sqrt())
        .collect();
    let p: Vec<f64> = pred
        .iter()
        .map(|v| (v.x * v.x + v.y * v.y + v.z * v.z).sqrt())
        .collect();
    let n = y.len() as f64;
    let e: Vec<f64> = y.iter().zip(&p).map(|(a, b)| a - b).collect();
    let ybar = y.iter().sum::<f64>() / n;
    let ebar = e.iter().sum::<f64>() / n;
    let ss_tot: f64 = y.iter().map(|v| (v - ybar).powi(2)).sum();
    let ss_res: f64 = e.iter().map(|v| v * v).sum();
    let ss_e: f64 = e.iter().map(|v| (v - ebar).powi(2)).sum();
    [
        (ss_res / n).sqrt(),
        e.iter().map(|v| v.abs()).sum::<f64>() / n,
        1.0 - ss_res / ss_tot,
        100.0 * (1.0 - ss_e / ss_tot),
    ]
}

#[test]
fn beamsnet_vs_ls_on_held_out_trajectories() {
    let Some(root) = data_root() else { return };
    let beamsnet = BeamsNet::load_default().unwrap();
    let protocol = BeamsNetProtocol::v1();
    println!("traj method     RMSE      MAE       R^2       VAF%");
    for n in [4u32, 13] {
        let (trajectory, dvl) = load(&root, n);
        // Same seed rule as `estim beamsnet eval` (default seed 7000 + n).
        let run = synthesize(
            &trajectory,
            &dvl,
            &ImuSpec::akit_observed(),
            &protocol,
            7000 + u64::from(n),
        )
        .unwrap();
        assert!(run.samples.len() > 350, "{} windows", run.samples.len());
        let e = evaluate_beamsnet(&beamsnet, protocol.geometry(), &run.samples).unwrap();
        for (name, m, pred) in [
            ("LS", e.ls, &e.ls_velocity),
            ("BeamsNet", e.beamsnet, &e.beamsnet_velocity),
        ] {
            let got = [m.rmse, m.mae, m.r2, m.vaf];
            assert!(got.iter().all(|v| v.is_finite()), "{name}: {got:?}");
            let want = reference_metrics(&e.reference, pred);
            for (g, w) in got.iter().zip(want) {
                assert!(
                    (g - w).abs() <= 1e-9 * w.abs().max(1.0),
                    "{name}: {got:?} vs {want:?}"
                );
            }
            println!(
                "{n:>4} {name:<9} {:.6} {:.6} {:.6} {:.4}",
                m.rmse, m.mae, m.r2, m.vaf
            );
        }
        println!(
            "     BeamsNet RMSE {:.1}% below LS",
            e.rmse_reduction_percent()
        );
    }
}
