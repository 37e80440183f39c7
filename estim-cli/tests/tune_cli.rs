//! `estim tune`: the test trajectories refused, and the JSON document on real data.

mod common;

use std::process::{Command, Output};

fn estim(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(args)
        .output()
        .expect("run estim")
}

#[test]
fn test_trajectories_are_refused_with_exit_2() {
    // Refused before any file is read: no data needed.
    for list in ["1,4", "13", "2,13,3"] {
        let out = estim(&["tune", "--data", "/nonexistent", "--trajectories", list]);
        assert_eq!(out.status.code(), Some(2), "{list}");
        assert!(out.stdout.is_empty(), "{list}: nothing on stdout");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("held-out test trajectory"), "{list}: {err}");
    }
    let out = estim(&["tune", "--data", "/nonexistent", "--trajectories", "2,2"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("given twice"));
    // Missing --trajectories is a usage error.
    assert_eq!(estim(&["tune"]).status.code(), Some(2));
}

#[test]
fn json_gives_every_parameter_a_standard_error_and_the_test_a_p_value() {
    let Some(root) = common::data_root() else {
        return;
    };
    let root = root.to_string_lossy().into_owned();
    let out = estim(&[
        "tune",
        "--data",
        &root,
        "--trajectories",
        "2",
        "--imu-source",
        "synthesized",
        "--linearizations",
        "1",
        "--json",
    ]);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    assert_eq!(doc["command"], "tune");
    assert_eq!(
        doc["inputs"]["imu_source"], "synthesized",
        "{}",
        doc["inputs"]
    );
    let parameters = doc["parameters"].as_array().expect("parameters");
    assert_eq!(parameters.len(), 5);
    for p in parameters {
        assert!(p["value"].is_f64(), "{p}");
        let on_bound = p["on_bound"].as_bool().expect("on_bound");
        // A number, or null exactly for a parameter on its bound.
        assert!(
            p["standard_error"].as_f64().is_some_and(|s| s > 0.0) || on_bound,
            "{p}"
        );
    }
    let test = &doc["likelihood_ratio_test"];
    let p_value = test["p_value"].as_f64().expect("p_value");
    assert!((0.0..=1.0).contains(&p_value));
    assert!(test["statistic"].as_f64().expect("statistic") >= 0.0);
    assert!(
        doc["epochs"][0].as_u64().is_some_and(|n| n > 300),
        "{}",
        doc["epochs"]
    );
}

#[test]
fn trajectories_run_on_the_recorded_imu_where_it_exists() {
    // Trajectory 2's folder holds its recorded IMU: the default reads it through the
    // embedded vehicle file and says so. A fit that cannot be used (on trajectory 2 the
    // accelerometer's density goes to 0: degenerate) is reported with its figures and
    // exit status 3, a usable one with 0.
    let Some(root) = common::data_root() else {
        return;
    };
    let root = root.to_string_lossy().into_owned();
    let out = estim(&[
        "tune",
        "--data",
        &root,
        "--trajectories",
        "2",
        "--linearizations",
        "1",
        "--json",
    ]);
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    assert_eq!(doc["inputs"]["imu_source"], "recorded", "{}", doc["inputs"]);
    assert_eq!(doc["inputs"]["vehicle"], "vehicles/akit.toml (embedded)");
    let usable = doc["fit_status"] == "converged" || doc["fit_status"] == "converged_on_bound";
    assert_eq!(
        out.status.code(),
        Some(if usable { 0 } else { 3 }),
        "{}",
        doc["fit_status"]
    );
    assert!(
        doc["epochs"][0].as_u64().is_some_and(|n| n > 300),
        "{}",
        doc["epochs"]
    );
    // No synthesized densities to compare with.
    for p in doc["parameters"].as_array().expect("parameters") {
        assert!(p["synthesized"].is_null(), "{p}");
    }
}

fn tune_json(args: &[&str]) -> serde_json::Value {
    let out = estim(args);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("JSON")
}

#[test]
fn survey_files_give_the_fit_of_the_study_trajectory() {
    // The study's trajectory 2 written as a survey (`estim simulate`: the synthesized
    // IMU, the protocol's beams, the vehicle file of the study's filter), tuned from
    // the files, against `--trajectories 2`.
    let Some(root) = common::data_root() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let files = estim::datasets::trajectory_files(&root, 2).unwrap();
    let (gt, dvl) = (files.gt.to_string_lossy(), files.dvl.to_string_lossy());
    let vehicle = dir.path().join("v.toml");
    let imu = estim(&[
        "simulate",
        "imu",
        "--gt",
        &gt,
        "--vehicle-out",
        &vehicle.to_string_lossy(),
    ]);
    assert_eq!(imu.status.code(), Some(0));
    let beams = estim(&["simulate", "beams", "--gt", &gt, "--dvl", &dvl]);
    assert_eq!(beams.status.code(), Some(0));
    let (imu_path, beams_path) = (dir.path().join("imu.csv"), dir.path().join("beams.csv"));
    std::fs::write(&imu_path, imu.stdout).unwrap();
    std::fs::write(&beams_path, beams.stdout).unwrap();
    let survey = tune_json(&[
        "tune",
        "--imu",
        &imu_path.to_string_lossy(),
        "--beams",
        &beams_path.to_string_lossy(),
        "--vehicle",
        &vehicle.to_string_lossy(),
        "--linearizations",
        "1",
        "--json",
    ]);
    let root = root.to_string_lossy().into_owned();
    let study = tune_json(&[
        "tune",
        "--data",
        &root,
        "--trajectories",
        "2",
        "--imu-source",
        "synthesized",
        "--linearizations",
        "1",
        "--json",
    ]);
    assert_eq!(study["inputs"]["imu_source"], "synthesized");
    assert_eq!(survey["epochs"], study["epochs"]);
    let (a, b) = (
        survey["parameters"].as_array().unwrap(),
        study["parameters"].as_array().unwrap(),
    );
    for (x, y) in a.iter().zip(b) {
        let Some(se) = y["standard_error"].as_f64() else {
            assert!(x["on_bound"].as_bool().unwrap() && y["on_bound"].as_bool().unwrap());
            continue;
        };
        let z = (x["value"].as_f64().unwrap() - y["value"].as_f64().unwrap()) / se;
        // The two start from different values (the vehicle file's DVL noise, the
        // configuration's), so one linearization is made at different points: measured
        // 0.006 standard errors apart at most.
        assert!(z.abs() < 0.05, "{}: {z} standard errors apart", y["name"]);
    }
}

/// Trajectory 7's recorded IMU and DVL as a survey, with the A-KIT vehicle file
/// without its DVL states (tune fits the 15-state filter); `None` without data.
fn recorded_survey(n: u32) -> Option<(tempfile::TempDir, [String; 4])> {
    let root = common::data_root()?;
    let files = estim::datasets::trajectory_files(&root, n).unwrap();
    let folder = files.gt.parent().unwrap();
    let imu = folder.join(format!("IMU_trajectory{n}.csv"));
    let dir = tempfile::tempdir().unwrap();
    let vehicle = dir.path().join("akit15.toml");
    let text = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../vehicles/akit.toml"),
    )
    .unwrap();
    let (head, tail) = text.split_once("[dvl_states]").unwrap();
    let (_, rest) = tail.split_once("\n[").unwrap();
    std::fs::write(&vehicle, format!("{head}\n[{rest}")).unwrap();
    let paths = [imu, files.dvl, files.gt, vehicle].map(|p| p.to_string_lossy().into_owned());
    Some((dir, paths))
}

#[test]
fn a_degenerate_optimum_exits_3_and_a_held_parameter_lets_the_fit_converge() {
    let Some((_dir, [imu, dvl, gt, vehicle])) = recorded_survey(7) else {
        return;
    };
    let base = [
        "tune",
        "--imu",
        &imu,
        "--dvl",
        &dvl,
        "--truth",
        &gt,
        "--vehicle",
        &vehicle,
        "--json",
    ];
    // Free: the accelerometer density and the mismatch variance go to zero.
    let out = estim(&base);
    assert_eq!(
        out.status.code(),
        Some(3),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    assert_ne!(doc["status"], "ok");
    assert_eq!(doc["fit_status"], "degenerate");
    let reason = doc["fit_status_reason"].as_str().unwrap();
    assert!(reason.contains("accelerometer_psd"), "{reason}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("degenerate optimum") && err.contains("--fix"),
        "{err}"
    );
    // Held at data-sheet values: the rest converges inside its bounds, each free
    // parameter with a standard error, each held one marked. The gyroscope density is
    // held too: with the gyroscope's scale corrected (vehicles/akit.toml) nothing is
    // left for it to explain on this trajectory, and alone it goes to zero as well
    // (the same degenerate stop).
    let mut args = base.to_vec();
    args.extend([
        "--fix",
        "accelerometer_psd=9e-6",
        "--fix",
        "dvl_mismatch_variance=1e-5",
        "--fix",
        "m_scale=0",
        "--fix",
        "gyroscope_psd=2.5e-9",
    ]);
    let doc = tune_json(&args);
    assert_eq!(
        doc["fit_status"], "converged",
        "{}",
        doc["fit_status_reason"]
    );
    assert_eq!(doc["converged"], true);
    for p in doc["parameters"].as_array().unwrap() {
        let held = !p["fixed"].is_null();
        assert_eq!(p["standard_error"].is_null(), held, "{p}");
        if held {
            assert_eq!(p["value"], p["fixed"], "{p}");
        } else {
            let (v, se) = (
                p["value"].as_f64().unwrap(),
                p["standard_error"].as_f64().unwrap(),
            );
            assert!(v > 0.0 && se > 0.0 && se < v, "{p}");
        }
    }
}

#[test]
fn a_held_m_scale_beyond_the_valid_range_is_refused() {
    let Some((_dir, [imu, dvl, gt, vehicle])) = recorded_survey(7) else {
        return;
    };
    let out = estim(&[
        "tune",
        "--imu",
        &imu,
        "--dvl",
        &dvl,
        "--truth",
        &gt,
        "--vehicle",
        &vehicle,
        "--fix",
        "m_scale=0.9",
    ]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("m_scale held at 0.9 is beyond"), "{err}");
}

#[test]
fn fix_names_a_parameter_and_a_valid_value() {
    for (fix, says) in [
        ("gyro=1e-9", "is not a parameter"),
        ("gyroscope_psd=-1", "must be finite and >= 0"),
        ("gyroscope_psd=nan", "must be finite"),
        ("gyroscope_psd", "expected NAME=VALUE"),
    ] {
        let out = estim(&[
            "tune",
            "--imu",
            "/nonexistent.csv",
            "--dvl",
            "/x.csv",
            "--fix",
            fix,
        ]);
        assert_eq!(out.status.code(), Some(2), "{fix}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(says), "{fix}: {err}");
    }
}
