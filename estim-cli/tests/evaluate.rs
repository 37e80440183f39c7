//! `estim evaluate`: the test trajectories refused for fitting, bad state files
//! refused, and a small run on the real data (two test trajectories, one seed, fitted
//! on two training trajectories to keep CI cheap).

mod common;

use std::process::{Command, Output};

fn estim(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(args)
        .output()
        .expect("run estim")
}

/// `estim reproduce --data ROOT --trajectory N --imu IMU --json` with the study's
/// configuration `seed = SEED` (written into `dir`): exit 0 and the JSON document.
fn reproduce_json(
    root: &str,
    trajectory: &str,
    seed: u64,
    imu: &str,
    dir: &std::path::Path,
) -> serde_json::Value {
    let config = dir.join(format!("seed{seed}.toml"));
    std::fs::write(&config, format!("seed = {seed}\n")).expect("write");
    let out = estim(&[
        "reproduce",
        "--data",
        root,
        "--trajectory",
        trajectory,
        "--imu",
        imu,
        "--config",
        config.to_str().expect("utf-8 path"),
        "--json",
    ]);
    assert_eq!(out.status.code(), Some(0));
    serde_json::from_slice(&out.stdout).expect("JSON")
}

/// `estim evaluate --data ROOT --fit-trajectories 2,7 --imu synthesized ARGS --json`
/// (fitted on two training trajectories to keep CI cheap; the synthesized IMU, whatever
/// IMU files the folders hold): exit 0 and the JSON document.
fn evaluate_json(root: &str, args: &[&str]) -> serde_json::Value {
    let out = estim(
        &[
            &[
                "evaluate",
                "--data",
                root,
                "--fit-trajectories",
                "2,7",
                "--imu",
                "synthesized",
            ][..],
            args,
            &["--json"],
        ]
        .concat(),
    );
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("JSON")
}

#[test]
fn test_trajectories_in_the_fit_set_are_refused_with_exit_2() {
    // Refused before any file is read: no data needed.
    for list in ["1,4", "13", "2,13,3"] {
        let out = estim(&[
            "evaluate",
            "--data",
            "/nonexistent",
            "--fit-trajectories",
            list,
        ]);
        assert_eq!(out.status.code(), Some(2), "{list}");
        assert!(out.stdout.is_empty(), "{list}: nothing on stdout");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("never used for fitting"), "{list}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "one line: {err}");
    }
    let out = estim(&[
        "evaluate",
        "--data",
        "/nonexistent",
        "--fit-trajectories",
        "2,2",
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("given twice"));
}

#[test]
fn bad_state_files_are_refused_naming_the_key() {
    let dir = tempfile::tempdir().expect("temp dir");
    for (text, key) in [
        (
            "[bias]\nestimate = true\nstd = 0.01\ntime_constant_s = 10\n",
            "std",
        ),
        (
            "[bias]\nestimate = true\nstd_mps = 0.01\ntime_constant_s = -1\n",
            "dvl_states.bias.time_constant_s",
        ),
        (
            "[time_offset]\nestimate = true\nprior_std_s = 0\n",
            "dvl_states.time_offset.prior_std_s",
        ),
        (
            "[misalignment]\nestimate = true\nprior_std_rad = [0.01, -0.01, 0]\n",
            "dvl_states.misalignment.prior_std_rad",
        ),
        (
            "[lever_arm]\nestimate = true\nprior_std_m = [0, 0, 0]\n",
            "dvl_states.lever_arm.prior_std_m",
        ),
        (
            "[lever_arm]\nestimate = true\nprior_std_m = [0.1, 0.1]\n",
            "states.toml: line 3: a number or an array of 3 numbers",
        ),
    ] {
        let path = dir.path().join("states.toml");
        std::fs::write(&path, text).expect("write");
        let out = estim(&[
            "evaluate",
            "--data",
            "/nonexistent",
            "--states",
            path.to_str().expect("utf-8 path"),
        ]);
        assert_eq!(out.status.code(), Some(2), "{text}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(key), "{text}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "one line: {err}");
    }
}

#[test]
fn evaluation_on_the_test_trajectories_reports_every_run() {
    let Some(root) = common::data_root() else {
        return;
    };
    let root = root.to_string_lossy().into_owned();
    let args = ["--trajectory", "4", "--trajectory", "13", "--seeds", "1"];
    let doc = evaluate_json(&root, &args);
    assert_eq!(doc["command"], "evaluate");
    let e = &doc["evaluation"];
    let fitted: Vec<u64> = e["fit"]["calibrations"]
        .as_array()
        .expect("calibrations")
        .iter()
        .map(|c| c["trajectory"].as_u64().expect("trajectory"))
        .collect();
    assert_eq!(fitted, [2, 7], "fitted on exactly the training set given");
    // The lever arm the calibrations find is the known one (docs/results.md: about
    // -1.87, -0.03, 0.2 m).
    let lever = &e["fit"]["lever_arm_m"];
    assert!(
        (lever[0].as_f64().expect("x") + 1.87).abs() < 0.1,
        "{lever}"
    );
    let rows = e["rows"].as_array().expect("rows");
    assert_eq!(rows.len(), 4, "2 trajectories x 2 variants");
    for row in rows {
        let nees = row["nees"].as_f64().expect("nees");
        let nis = row["nis"].as_f64().expect("nis");
        assert!(nees.is_finite() && nees > 0.0, "{row}");
        assert!(nis.is_finite() && nis > 0.0, "{row}");
        assert!(row["position_rmse_m"].as_f64().expect("rmse") > 0.0);
        // The band flags follow the documented bands.
        assert_eq!(
            row["nees_in_band"].as_bool(),
            Some((7.5..=30.0).contains(&nees))
        );
        assert_eq!(
            row["nis_in_band"].as_bool(),
            Some((1.5..=6.0).contains(&nis))
        );
    }
    for count in e["counts"].as_array().expect("counts") {
        let id = count["id"].as_str().expect("id");
        let mine: Vec<_> = rows.iter().filter(|r| r["id"] == id).collect();
        let in_band = mine.iter().filter(|r| r["nees_in_band"] == true).count();
        assert_eq!(count["nees_in_band"].as_u64(), Some(in_band as u64));
    }
    let text = estim(
        &[
            &["evaluate", "--data", &root, "--fit-trajectories", "2,7"][..],
            &args,
        ]
        .concat(),
    );
    assert_eq!(text.status.code(), Some(0));
    let text = String::from_utf8_lossy(&text.stdout);
    assert!(
        text.contains("Synthesized IMU: from the ground truth"),
        "{text}"
    );
    assert!(text.contains("| 4 (test) |") && text.contains("| 13 (test) |"));
}

/// The `--states` example of docs/cli.md parses and passes the checks: the command
/// gets as far as looking for the data.
#[test]
fn the_documented_states_file_is_accepted() {
    let page = include_str!("../../docs/cli.md");
    let section = &page[page
        .find("## Evaluate the DVL error states")
        .expect("docs/cli.md section")..];
    let start = section.find("```toml").expect("a toml block") + "```toml".len();
    let block = &section[start..];
    let block = &block[..block.find("```").expect("block end")];
    let toml: String = block
        .lines()
        .map(|l| l.strip_prefix("  ").unwrap_or(l).to_string() + "\n")
        .collect();
    assert!(toml.contains("[bias]") && toml.contains("time_constant_s"));
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("states.toml");
    std::fs::write(&path, toml).expect("write");
    let out = estim(&[
        "evaluate",
        "--data",
        "/nonexistent",
        "--states",
        path.to_str().expect("utf-8 path"),
    ]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("/nonexistent") && !err.contains("states.toml"),
        "{err}"
    );
}

/// `--adaptive-noise`: a zero memory is refused with exit 2; on A-KIT 13, whose DVL
/// mismatch is below the training level, the adapted scale falls below 1 and the
/// NIS comes into its band for both variants (it is 0.2 with the fitted level).
#[test]
fn adaptive_noise_scale_is_checked_and_brings_the_nis_into_band_on_13() {
    let out = estim(&["evaluate", "--adaptive-noise", "0"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--adaptive-noise 0"));
    let Some(root) = common::data_root() else {
        return;
    };
    let root = root.to_string_lossy().into_owned();
    let doc = evaluate_json(
        &root,
        &[
            "--trajectory",
            "13",
            "--seeds",
            "1",
            "--adaptive-noise",
            "100",
        ],
    );
    let e = &doc["evaluation"];
    assert_eq!(e["adaptive_noise_window"].as_u64(), Some(100));
    for row in e["rows"].as_array().expect("rows") {
        let scale = row["noise_scale"].as_f64().expect("noise_scale");
        let nis = row["nis"].as_f64().expect("nis");
        println!("{}: scale {scale:.3}, NIS {nis:.2}", row["id"]);
        assert!(scale > 0.0 && scale < 1.0, "{row}");
        assert!((1.5..=6.0).contains(&nis), "{row}");
    }
}

/// The 15-state comparison runs are `estim reproduce --data`'s runs (same seed, same
/// variant: position RMSE equal to 1e-12), and each row's paired difference is the
/// mean of (this filter - 15-state) over the seeds with the Student t interval,
/// recomputed here (t_{0.975, 1} = 12.7062, a published constant).
#[test]
fn the_fifteen_state_comparison_is_reproduce_paired_by_seed() {
    let Some(root) = common::data_root() else {
        return;
    };
    let root = root.to_string_lossy().into_owned();
    let doc = evaluate_json(
        &root,
        &["--trajectory", "13", "--seeds", "2", "--first-seed", "31"],
    );
    let e = &doc["evaluation"];
    assert_eq!(e["fifteen_state_time_offset_s"].as_f64(), Some(-1.48));
    let dir = tempfile::tempdir().expect("temp dir");
    let runs = e["runs"].as_array().expect("runs");
    assert_eq!(runs.len(), 4, "2 seeds x 2 variants");
    for seed in [31u64, 32] {
        // evaluate's runs are on the synthesized IMU, whatever IMU files exist.
        let doc = reproduce_json(&root, "13", seed, "synthesized", dir.path());
        let filters = doc["trajectories"][0]["filters"]
            .as_array()
            .expect("filters");
        for id in ["ls", "beamsnet_m_neglected"] {
            let expected = filters.iter().find(|f| f["id"] == id).expect("filter")
                ["position_error_m"]["rmse"]
                .as_f64()
                .expect("rmse");
            let run = runs
                .iter()
                .find(|r| r["id"] == id && r["seed"].as_u64() == Some(seed))
                .expect("run");
            let got = run["fifteen_state_position_rmse_m"].as_f64().expect("rmse");
            assert!(
                (got - expected).abs() <= 1e-12,
                "{id} seed {seed}: {got} vs {expected}"
            );
        }
    }
    for row in e["rows"].as_array().expect("rows") {
        let d: Vec<f64> = runs
            .iter()
            .filter(|r| r["id"] == row["id"])
            .map(|r| {
                r["position_rmse_m"].as_f64().expect("rmse")
                    - r["fifteen_state_position_rmse_m"].as_f64().expect("rmse")
            })
            .collect();
        let mean = (d[0] + d[1]) / 2.0;
        let half = 12.7062 * (d[0] - d[1]).abs() / 2f64.sqrt() / 2f64.sqrt();
        let i = &row["position_rmse_difference_m"];
        let near = |key: &str, v: f64| {
            let got = i[key].as_f64().expect(key);
            assert!(
                (got - v).abs() <= 1e-4 * v.abs().max(1e-3),
                "{key}: {got} vs {v}"
            );
        };
        near("mean", mean);
        near("lo", mean - half);
        near("hi", mean + half);
    }
}

/// On a recorded IMU (the default `--imu auto` where the folder holds one) a cell is
/// `estim reproduce --data`'s recorded run: the same seed gives the same NEES (over the
/// 9 states with truth), NIS and position RMSE to 1e-12 for both variants; options
/// that change the synthesized runs only are refused with exit 2.
#[test]
fn a_recorded_cell_is_the_recorded_reproduce_run() {
    let Some(root) = common::data_root() else {
        return;
    };
    let root = root.to_string_lossy().into_owned();
    let out = estim(&[
        "evaluate",
        "--data",
        &root,
        "--trajectory",
        "2",
        "--first-seed",
        "7",
        "--seeds",
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
    let runs = doc["evaluation"]["runs"].as_array().expect("runs");
    assert_eq!(runs.len(), 2);
    let dir = tempfile::tempdir().expect("temp dir");
    let reproduced = reproduce_json(&root, "2", 7, "auto", dir.path());
    let t = &reproduced["trajectories"][0];
    assert_eq!(t["imu_source"], "recorded");
    let filters = t["filters"].as_array().expect("filters");
    for run in runs {
        assert_eq!(run["imu_source"], "recorded");
        assert_eq!(run["nees_states"], 9);
        let f = filters
            .iter()
            .find(|f| f["id"] == run["id"])
            .expect("the same variant");
        for (mine, theirs) in [
            (&run["nees"], &f["nees_average"]),
            (&run["nis"], &f["nis_average"]),
            (&run["position_rmse_m"], &f["position_error_m"]["rmse"]),
        ] {
            let (a, b) = (
                mine.as_f64().expect("number"),
                theirs.as_f64().expect("number"),
            );
            assert!(
                (a - b).abs() <= 1e-12 * b.abs().max(1.0),
                "{}: {a} vs {b}",
                run["id"]
            );
        }
        let comparison = run["fifteen_state_position_rmse_m"].as_f64().expect("rmse");
        assert!(comparison.is_finite() && comparison > 0.0, "{run}");
    }
    let rows = doc["evaluation"]["rows"].as_array().expect("rows");
    assert!(rows
        .iter()
        .all(|r| r["imu_source"] == "recorded" && r["nees_states"] == 9));
    let out = estim(&[
        "evaluate",
        "--data",
        &root,
        "--trajectory",
        "2",
        "--seeds",
        "1",
        "--adaptive-noise",
        "50",
    ]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--imu synthesized") && err.contains("trajectory 2"),
        "{err}"
    );
}
