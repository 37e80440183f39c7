//! End-to-end: `estim reproduce --json` on the embedded default and on A-KIT, and the
//! Monte Carlo consistency of the filter fed the true cross-covariance.

use std::path::Path;
use std::process::Command;

use serde_json::Value;

mod common;
use common::data_root as data_dir;

fn reproduce_json(extra: &[&str]) -> Value {
    let out = Command::new(env!("CARGO_BIN_EXE_estim"))
        .arg("reproduce")
        .arg("--json")
        .args(extra)
        .output()
        .expect("run estim");
    assert!(
        out.status.success(),
        "estim failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("valid JSON")
}

/// Every number in `v` is finite (JSON has no NaN: serde writes null for it).
fn assert_all_finite(v: &Value, path: &str) {
    match v {
        Value::Null => panic!("{path} is null (non-finite)"),
        Value::Number(n) => assert!(n.as_f64().is_some_and(f64::is_finite), "{path} = {n}"),
        Value::Array(a) => a
            .iter()
            .enumerate()
            .for_each(|(i, x)| assert_all_finite(x, &format!("{path}[{i}]"))),
        Value::Object(o) => o
            .iter()
            .for_each(|(k, x)| assert_all_finite(x, &format!("{path}.{k}"))),
        _ => {}
    }
}

fn check_trajectory(t: &Value, expect_learned: bool) {
    let name = t["name"].as_str().unwrap_or("?");
    let velocity = t["velocity"].as_array().expect("velocity table");
    let has = |id: &str| velocity.iter().any(|m| m["id"] == id);
    assert!(has("ls"), "{name}: LS row");
    for m in velocity {
        for key in ["rmse_mps", "mae_mps", "r2", "vaf_percent"] {
            assert!(m[key].is_number(), "{name}: velocity.{key}");
        }
    }
    assert!(
        t["failures"].as_array().is_some_and(Vec::is_empty),
        "{name}: no filter fails on the default configuration"
    );
    let filters = t["filters"].as_array().expect("filters");
    assert!(!filters.is_empty());
    for f in filters {
        for group in [
            "position_m",
            "velocity_mps",
            "misalignment_rad",
            "acc_bias_mps2",
            "gyro_bias_radps",
        ] {
            assert!(
                f["std"][group]["time_average"].is_number(),
                "{name}: std.{group}"
            );
            assert!(
                f["std"][group]["final_value"].is_number(),
                "{name}: std.{group}"
            );
        }
        for key in [
            "position_error_m",
            "velocity_error_mps",
            "attitude_error_deg",
        ] {
            assert!(
                f[key]["rmse"].is_number() && f[key]["final_value"].is_number(),
                "{name}: {key}"
            );
        }
        for key in [
            "nees_average",
            "nis_average",
            "joint_min_eigenvalue",
            "largest_valid_rho",
        ] {
            assert!(f[key].is_number(), "{name}: {key}");
        }
        assert!(f["joint_valid"].is_boolean(), "{name}: joint_valid");
        assert!(f["nees_band"][1].as_f64() > f["nees_band"][0].as_f64());
    }
    if expect_learned {
        assert!(has("beamsnet"), "{name}: BeamsNet row");
        assert!(filters.len() >= 3, "{name}: LS + BeamsNet variants");
        assert!(!t["improvements"]
            .as_array()
            .expect("improvements")
            .is_empty());
    }
    assert_all_finite(t, name);
}

fn learned_available() -> bool {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../models/beamsnet.onnx")
        .is_file()
}

#[test]
fn reproduce_default_json_has_every_field_finite() {
    let v = reproduce_json(&[]);
    let t = v["trajectories"].as_array().expect("trajectories");
    assert_eq!(t.len(), 1);
    check_trajectory(&t[0], learned_available());
}

#[test]
fn reproduce_akit_json_has_every_field_finite() {
    let Some(dir) = data_dir() else { return };
    let v = reproduce_json(&["--data", dir.to_str().expect("utf-8 path")]);
    let t = v["trajectories"].as_array().expect("trajectories");
    let numbers: Vec<u64> = t.iter().filter_map(|x| x["trajectory"].as_u64()).collect();
    assert_eq!(numbers, [4, 13]);
    for x in t {
        check_trajectory(x, learned_available());
    }
}

/// A trajectory whose folder holds `IMU_trajectoryN.csv` runs on the recorded IMU
/// (read with the embedded vehicles/akit.toml, NEES over the 9 states with truth),
/// `--imu synthesized` keeps the synthesized one, and a folder without the file
/// falls back to it under `--imu auto` and is an error naming the file under
/// `--imu recorded`.
#[test]
fn reproduce_uses_the_recorded_imu_where_there_is_one() {
    let Some(dir) = data_dir() else { return };
    let d = dir.to_str().expect("utf-8 path");
    let v = reproduce_json(&["--data", d, "--trajectory", "2"]);
    let t = &v["trajectories"][0];
    assert_eq!(t["imu_source"], "recorded");
    assert_eq!(t["recorded"]["nees_states"], 9);
    assert_eq!(t["recorded"]["scored_at"], "reference_epochs");
    assert!(t["recorded"]["vehicle"]
        .as_str()
        .is_some_and(|s| s.contains("akit.toml")));
    check_trajectory(t, learned_available());
    for f in t["filters"].as_array().expect("filters") {
        assert_eq!(f["nees_states"], 9, "{}", f["id"]);
        let band = f["nees_band"].as_array().expect("band");
        assert!(band[0].as_f64() < Some(9.0) && band[1].as_f64() > Some(9.0));
    }
    let s = reproduce_json(&["--data", d, "--trajectory", "2", "--imu", "synthesized"]);
    let t = &s["trajectories"][0];
    assert_eq!(t["imu_source"], "synthesized");
    assert!(t.get("recorded").is_none());
    assert_eq!(t["filters"][0]["nees_states"], 15);

    // The same trajectory without its IMU file.
    let root = tempfile::tempdir().expect("temp dir");
    let folder = root.path().join("a-kit/Trajectory2");
    std::fs::create_dir_all(&folder).expect("folder");
    let source = if dir.join("a-kit").is_dir() {
        dir.join("a-kit/Trajectory2")
    } else {
        dir.join("Trajectory2")
    };
    for file in ["GT_trajectory2.csv", "DVL_trajectory2.csv"] {
        std::fs::copy(source.join(file), folder.join(file)).expect("copy");
    }
    let r = root.path().to_str().expect("utf-8 path");
    let auto = reproduce_json(&["--data", r, "--trajectory", "2"]);
    assert_eq!(auto["trajectories"][0]["imu_source"], "synthesized");
    let out = Command::new(env!("CARGO_BIN_EXE_estim"))
        .args([
            "reproduce",
            "--data",
            r,
            "--trajectory",
            "2",
            "--imu",
            "recorded",
        ])
        .output()
        .expect("run estim");
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("IMU_trajectory2.csv"), "{stderr}");

    // The two-beams study on the recorded IMU: the networks trained on recorded
    // windows, NEES over the 9 states with truth, the five variants.
    let doc = reproduce_json(&["--data", d, "--trajectory", "2", "--scenario", "two-beams"]);
    let study = &doc["studies"][0];
    assert_eq!(study["imu_source"], "recorded");
    assert_eq!(study["nees_states"], 9);
    assert_eq!(study["event"], "two-beams");
    assert!(
        study["loss_epochs"].as_u64() > Some(100),
        "{}",
        study["loss_epochs"]
    );
    let filters = study["filters"].as_array().expect("filters");
    let windows = study["loss_window"].as_array().expect("loss window");
    assert_eq!(filters.len(), 5);
    assert_eq!(windows.len(), 5);
    for (f, w) in filters.iter().zip(windows) {
        assert_eq!(f["nees_states"], 9, "{}", f["id"]);
        for key in ["nees_mean", "position_rmse_m", "velocity_rmse_mps"] {
            assert!(w[key].as_f64().is_some_and(f64::is_finite), "{key}: {w}");
        }
    }

    // --smooth smooths the recorded trajectory with the navigator's own pass (M = 0),
    // NEES over the 9 states with truth.
    let out = Command::new(env!("CARGO_BIN_EXE_estim"))
        .args([
            "reproduce",
            "--data",
            d,
            "--trajectory",
            "2",
            "--smooth",
            "--json",
        ])
        .output()
        .expect("run estim");
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let doc: Value = serde_json::from_slice(&out.stdout).expect("valid JSON");
    let smoothing = &doc["smoothing"][0];
    assert_eq!(smoothing["imu_source"], "recorded");
    assert_eq!(smoothing["nees_states"], 9);
    assert_eq!(smoothing["cross"], "M = 0");
}

/// The held-out trajectories take the recorded-IMU path as soon as their folders hold
/// an IMU file, as they do where this project is evaluated: in a data folder whose
/// trajectories 4 and 13 are stand-ins (trajectory 2's and 12's three files under the
/// held-out names; nothing of 4 or 13 is read), `estim reproduce --data DIR --json`
/// (4 and 13 by default) says `imu_source: recorded` for both and gives, filter by
/// filter, the figures of `--trajectory 2` and `--trajectory 12` on the real folder.
#[test]
fn held_out_trajectories_with_an_imu_file_run_on_it() {
    let Some(dir) = data_dir() else { return };
    let akit = if dir.join("a-kit").is_dir() {
        dir.join("a-kit")
    } else {
        dir.clone()
    };
    let root = tempfile::tempdir().expect("temp dir");
    for (held_out, stand_in) in [(4, 2), (13, 12)] {
        let folder = root.path().join(format!("a-kit/Trajectory{held_out}"));
        std::fs::create_dir_all(&folder).expect("folder");
        for kind in ["GT", "DVL", "IMU"] {
            std::fs::copy(
                akit.join(format!(
                    "Trajectory{stand_in}/{kind}_trajectory{stand_in}.csv"
                )),
                folder.join(format!("{kind}_trajectory{held_out}.csv")),
            )
            .expect("copy");
        }
    }
    let r = root.path().to_str().expect("utf-8 path");
    let held = reproduce_json(&["--data", r]);
    let d = dir.to_str().expect("utf-8 path");
    let runs = held["trajectories"].as_array().expect("trajectories");
    assert_eq!(runs.len(), 2);
    for (t, stand_in) in runs.iter().zip(["2", "12"]) {
        assert_eq!(t["imu_source"], "recorded", "{}", t["name"]);
        check_trajectory(t, learned_available());
        let own = reproduce_json(&["--data", d, "--trajectory", stand_in]);
        let own = &own["trajectories"][0];
        assert_eq!(own["imu_source"], "recorded");
        let filters = t["filters"].as_array().expect("filters");
        let own_filters = own["filters"].as_array().expect("filters");
        assert_eq!(filters.len(), own_filters.len());
        for (f, g) in filters.iter().zip(own_filters) {
            assert_eq!(f["id"], g["id"]);
            for key in ["nees_average", "nis_average", "updates_rejected"] {
                assert_eq!(f[key], g[key], "{stand_in} {}: {key}", f["id"]);
            }
            assert_eq!(
                f["horizontal_position_error_m"]["rmse"], g["horizontal_position_error_m"]["rmse"],
                "{stand_in} {}",
                f["id"]
            );
        }
    }
}
