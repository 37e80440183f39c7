//! `estim navigate` end to end: the A-KIT evaluation path (`simulate imu` +
//! `simulate beams` + `navigate --truth`) equals `reproduce`'s LS filter; the same
//! inputs in the Unix epoch give the same figures and a solution in that epoch;
//! lost-lock DVL rows are skipped and counted; the vehicle file's adaptive DVL noise
//! and DVL error states work; bad input exits 2 naming file:line.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;

fn estim(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("run estim")
}

fn ok(out: Output, what: &str) -> Vec<u8> {
    assert_eq!(
        out.status.code(),
        Some(0),
        "{what}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out.stdout
}

fn json(bytes: &[u8]) -> Value {
    serde_json::from_slice(bytes).expect("JSON on stdout")
}

/// The A-KIT trajectory 4 files, or `None` (skipped with a printed reason).
fn trajectory4() -> Option<(PathBuf, PathBuf)> {
    let root = common::data_root()?;
    let files = estim::datasets::trajectory_files(&root, 4).ok()?;
    Some((files.gt, files.dvl))
}

/// IMU, beams and vehicle files of the study's LS run on `gt`/`dvl`, written in `dir`.
fn evaluation_inputs(dir: &Path, gt: &Path, dvl: &Path) {
    let gt_s = gt.to_str().unwrap();
    let imu = ok(
        estim(
            &[
                "simulate",
                "imu",
                "--gt",
                gt_s,
                "--vehicle-out",
                "vehicle.toml",
            ],
            dir,
        ),
        "simulate imu",
    );
    std::fs::write(dir.join("imu.csv"), imu).unwrap();
    let beams = ok(
        estim(
            &[
                "simulate",
                "beams",
                "--gt",
                gt_s,
                "--dvl",
                dvl.to_str().unwrap(),
            ],
            dir,
        ),
        "simulate beams",
    );
    std::fs::write(dir.join("beams.csv"), beams).unwrap();
}

/// A temporary folder with the study's A-KIT 4 inputs (`imu.csv`, `beams.csv`,
/// `vehicle.toml`) and the vehicle file's text, or `None` without the data.
fn akit4_survey() -> Option<(tempfile::TempDir, String)> {
    let (gt, dvl) = trajectory4()?;
    let dir = tempfile::tempdir().unwrap();
    evaluation_inputs(dir.path(), &gt, &dvl);
    let vehicle = std::fs::read_to_string(dir.path().join("vehicle.toml")).unwrap();
    Some((dir, vehicle))
}

/// `estim navigate` on the folder's `imu.csv` and `beams.csv` with the vehicle file
/// `vehicle` and `extra` arguments.
fn navigate_beams(dir: &Path, vehicle: &str, extra: &[&str]) -> Output {
    let mut args = vec![
        "navigate",
        "--imu",
        "imu.csv",
        "--beams",
        "beams.csv",
        "--vehicle",
        vehicle,
    ];
    args.extend_from_slice(extra);
    estim(&args, dir)
}

/// Every time cell of the first column shifted by `shift` whole seconds, on the text
/// (the digits after the point are kept).
fn shift_times(text: &str, shift: u64) -> String {
    let mut out = String::with_capacity(text.len() + text.len() / 10);
    for (i, line) in text.lines().enumerate() {
        if i == 0 || line.trim().is_empty() {
            out.push_str(line);
        } else {
            let (time, rest) = line.split_once(',').unwrap();
            let (whole, fraction) = time.split_once('.').unwrap_or((time, ""));
            let whole: u64 = whole.parse().expect("a non-negative time");
            out.push_str(&format!("{}", whole + shift));
            if !fraction.is_empty() {
                out.push('.');
                out.push_str(fraction);
            }
            out.push(',');
            out.push_str(rest);
        }
        out.push('\n');
    }
    out
}

fn relative(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs().max(1e-300)
}

#[test]
fn akit_evaluation_equals_reproduce_ls_also_in_the_unix_epoch() {
    let Some((gt, dvl)) = trajectory4() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    evaluation_inputs(d, &gt, &dvl);
    let gt_s = gt.to_str().unwrap();
    // The IMU was synthesized from this truth: the clock offset estimated from the
    // IMU's angular rate against the truth's attitude is zero.
    let estimated = json(&ok(
        navigate_beams(d, "vehicle.toml", &["--truth", gt_s, "--json"]),
        "navigate",
    ));
    let offset = &estimated["evaluation"]["truth_time_offset"];
    assert_eq!(offset["source"], "estimated");
    let tau = offset["offset_s"].as_f64().unwrap();
    let sigma = offset["sigma_s"].as_f64().unwrap();
    assert!(
        tau.abs() < 0.005 && sigma < 0.005,
        "offset {tau} +- {sigma} s"
    );
    // With the offset declared, the figures are reproduce's.
    let mut vehicle = std::fs::read_to_string(d.join("vehicle.toml")).unwrap();
    vehicle.push_str("\n[truth]\ntime_offset_s = 0.0\n");
    std::fs::write(d.join("vehicle_declared.toml"), vehicle).unwrap();
    let navigated = json(&ok(
        navigate_beams(d, "vehicle_declared.toml", &["--truth", gt_s, "--json"]),
        "navigate",
    ));
    let reproduced = json(&ok(
        estim(
            &[
                "reproduce",
                "--gt",
                gt_s,
                "--dvl",
                dvl.to_str().unwrap(),
                "--json",
            ],
            d,
        ),
        "reproduce",
    ));
    let ls = reproduced["trajectories"][0]["filters"]
        .as_array()
        .unwrap()
        .iter()
        .find(|f| f["id"] == "ls")
        .expect("the LS filter")
        .clone();
    // reproduce scores at the DVL epochs; navigate's main figures are at the truth's
    // own epochs, and the DVL-epoch ones are kept beside them.
    let e = &navigated["evaluation"]["at_dvl_epochs"];
    assert_eq!(navigated["evaluation"]["scored_at"], "reference_epochs");
    let pairs = [
        (
            e["position_rmse_m"].as_f64().unwrap(),
            ls["position_error_m"]["rmse"].as_f64().unwrap(),
        ),
        (
            e["final_position_error_m"].as_f64().unwrap(),
            ls["position_error_m"]["final_value"].as_f64().unwrap(),
        ),
        (
            e["nees_average"].as_f64().unwrap(),
            ls["nees_average"].as_f64().unwrap(),
        ),
    ];
    for (a, b) in pairs {
        assert!(relative(a, b) <= 1e-9, "navigate {a} vs reproduce {b}");
    }
    assert_eq!(e["nees_states"], 15);
    assert_eq!(
        navigated["updates"]["dvl"]["accepted"],
        ls["updates_accepted"]
    );
    assert_eq!(navigated["updates"]["dvl"]["gated"], ls["updates_rejected"]);

    // The same files in the Unix epoch.
    const SHIFT: u64 = 1_700_000_000;
    for name in ["imu.csv", "beams.csv"] {
        let text = std::fs::read_to_string(d.join(name)).unwrap();
        std::fs::write(d.join(format!("unix_{name}")), shift_times(&text, SHIFT)).unwrap();
    }
    let gt_text = std::fs::read_to_string(&gt).unwrap();
    std::fs::write(d.join("unix_gt.csv"), shift_times(&gt_text, SHIFT)).unwrap();
    let unix = json(&ok(
        estim(
            &[
                "navigate",
                "--imu",
                "unix_imu.csv",
                "--beams",
                "unix_beams.csv",
                "--vehicle",
                "vehicle_declared.toml",
                "--truth",
                "unix_gt.csv",
                "--out",
                "unix",
                "--json",
            ],
            d,
        ),
        "navigate (Unix epoch)",
    ));
    let u = &unix["evaluation"]["at_dvl_epochs"];
    for key in ["position_rmse_m", "final_position_error_m", "nees_average"] {
        let (a, b) = (u[key].as_f64().unwrap(), e[key].as_f64().unwrap());
        assert!(relative(a, b) <= 1e-9, "{key}: Unix epoch {a} vs {b}");
    }
    assert_eq!(unix["epoch_s"], 1.7e9);
    let solution = std::fs::read_to_string(d.join("unix/solution.csv")).unwrap();
    let first: f64 = solution
        .lines()
        .nth(1)
        .unwrap()
        .split(',')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!((first - 1.7e9).abs() < 500.0, "solution time {first}");
    assert!(d.join("unix/track.geojson").is_file() && d.join("unix/summary.json").is_file());
}

#[test]
fn lost_lock_rows_are_skipped_and_counted() {
    let Some((gt, dvl)) = trajectory4() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    evaluation_inputs(d, &gt, &dvl);
    // The recorded DVL velocity with three lost-lock rows: NaN, an empty cell, RDI's
    // marker.
    let text = std::fs::read_to_string(&dvl).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    for (row, cell) in [(50, "nan"), (120, ""), (200, "-32.768")] {
        let mut cells: Vec<String> = lines[row].split(',').map(str::to_string).collect();
        cells[1] = cell.to_string();
        lines[row] = cells.join(",");
    }
    std::fs::write(d.join("dvl.csv"), lines.join("\n") + "\n").unwrap();
    let run = |file: &str| {
        json(&ok(
            estim(
                &[
                    "navigate",
                    "--imu",
                    "imu.csv",
                    "--dvl",
                    file,
                    "--vehicle",
                    "vehicle.toml",
                    "--json",
                ],
                d,
            ),
            "navigate --dvl",
        ))
    };
    std::fs::copy(&dvl, d.join("clean.csv")).unwrap();
    let clean = run("clean.csv");
    let lost = run("dvl.csv");
    assert_eq!(clean["dvl_no_lock_rows"], 0);
    assert_eq!(lost["dvl_no_lock_rows"], 3);
    let used = |v: &Value| {
        v["updates"]["dvl"]["accepted"].as_u64().unwrap()
            + v["updates"]["dvl"]["gated"].as_u64().unwrap()
    };
    assert_eq!(used(&lost) + 3, used(&clean));
    assert_eq!(lost["status"], "ok");
}

/// `dvl.adaptive_noise_window` in the vehicle file: on A-KIT 4 (IMU synthesized,
/// beams by the protocol), whose DVL mismatch is above the vehicle file's R, the
/// final noise scale is above 1 and the mean DVL NIS comes into [0.5, 2] x 3 (it is
/// 13.4 with the fixed R); the summary gives the scale (null when fixed); 0 is
/// refused with exit 2 naming the key.
#[test]
fn adaptive_dvl_noise_from_the_vehicle_file() {
    let Some((dir, vehicle)) = akit4_survey() else {
        return;
    };
    let d = dir.path();
    let with_window =
        |n: &str| vehicle.replace("[dvl]\n", &format!("[dvl]\nadaptive_noise_window = {n}\n"));
    assert_ne!(
        with_window("1"),
        vehicle,
        "the vehicle file has a [dvl] table"
    );
    std::fs::write(d.join("adaptive.toml"), with_window("100")).unwrap();
    std::fs::write(d.join("zero.toml"), with_window("0")).unwrap();
    let run = |file: &str| navigate_beams(d, file, &["--json"]);
    let fixed = json(&ok(run("vehicle.toml"), "navigate, fixed R"));
    let adaptive = json(&ok(run("adaptive.toml"), "navigate, adaptive R"));
    let nis = |v: &Value| v["nis"]["dvl"]["mean"].as_f64().unwrap();
    println!("NIS fixed {}, adaptive {}", nis(&fixed), nis(&adaptive));
    assert!(fixed["dvl_noise_scale"].is_null());
    let scale = adaptive["dvl_noise_scale"].as_f64().unwrap();
    assert!(scale > 1.0, "scale {scale}");
    assert!(nis(&fixed) > 6.0);
    assert!((1.5..=6.0).contains(&nis(&adaptive)));
    let zero = run("zero.toml");
    assert_eq!(zero.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&zero.stderr);
    assert!(
        stderr.contains("zero.toml") && stderr.contains("dvl.adaptive_noise_window"),
        "{stderr}"
    );
}

/// `[dvl_states]` in the vehicle file runs the 26-state filter: with every state held
/// it gives the 15-state run's final solution (to 1e-9); with the misalignment and
/// lever arm estimated the summary reports them with sigmas below their priors; the
/// smoother runs on them (exit 0); BeamsNet and `tune` refuse the table, and a bad
/// prior exits 2 naming its key.
#[test]
fn dvl_states_from_the_vehicle_file() {
    let Some((dir, vehicle)) = akit4_survey() else {
        return;
    };
    let d = dir.path();
    let held = "[dvl_states]\n\
        scale_factor = { estimate = false, prior_std = 0.005 }\n\
        misalignment = { estimate = false, prior_std_rad = 0.01 }\n\
        bias = { estimate = false, std_mps = 0.01, time_constant_s = 60.0 }\n\
        lever_arm = { estimate = false, prior_std_m = 0.1 }\n\
        time_offset = { estimate = false, prior_std_s = 0.5 }\n";
    let estimated = "[dvl_states]\n\
        scale_factor = { estimate = false, prior_std = 0.005 }\n\
        misalignment = { estimate = true, prior_std_rad = 0.01 }\n\
        bias = { estimate = false, std_mps = 0.01, time_constant_s = 60.0 }\n\
        lever_arm = { estimate = true, prior_std_m = 0.1 }\n\
        time_offset = { estimate = false, prior_std_s = 0.5 }\n";
    let bad = "[dvl_states]\nbias = { estimate = true, std_mps = -1.0, time_constant_s = 60.0 }\n";
    for (name, table) in [("held", held), ("estimated", estimated), ("bad", bad)] {
        std::fs::write(
            d.join(format!("{name}.toml")),
            format!("{vehicle}\n{table}"),
        )
        .unwrap();
    }
    let run = |file: &str, extra: &[&str]| navigate_beams(d, file, extra);
    let plain = json(&ok(run("vehicle.toml", &["--json"]), "navigate, 15 states"));
    let same = json(&ok(run("held.toml", &["--json"]), "navigate, states held"));
    assert!(plain["dvl_states"].is_null());
    for key in ["latitude_deg", "longitude_deg", "depth_m"] {
        let (a, b) = (
            plain["final"][key].as_f64().unwrap(),
            same["final"][key].as_f64().unwrap(),
        );
        assert!(
            (a - b).abs() <= 1e-9 * a.abs().max(1.0),
            "{key}: {a} vs {b}"
        );
    }
    assert_eq!(plain["updates"], same["updates"]);
    let states = json(&ok(
        run("estimated.toml", &["--json"]),
        "navigate, states estimated",
    ));
    let s = &states["dvl_states"];
    println!("{s}");
    assert_eq!(s["estimated"]["lever_arm"], true);
    assert_eq!(s["estimated"]["scale_factor"], false);
    assert_eq!(s["scale_factor_sigma"].as_f64(), Some(0.0));
    for i in 0..3 {
        let lever = s["lever_arm_sigma_m"][i].as_f64().unwrap();
        let misalignment = s["mounting_misalignment_sigma_rad"][i].as_f64().unwrap();
        assert!(lever > 0.0 && lever < 0.1, "lever arm sigma {lever}");
        assert!(
            misalignment > 0.0 && misalignment < 0.01,
            "misalignment sigma {misalignment}"
        );
    }
    let text = String::from_utf8(ok(run("estimated.toml", &[]), "navigate, text")).unwrap();
    assert!(text.contains("DVL states:"), "{text}");
    let other = |command: &str| {
        let args = [
            command,
            "--imu",
            "imu.csv",
            "--beams",
            "beams.csv",
            "--vehicle",
            "estimated.toml",
        ];
        estim(&args, d)
    };
    let smooth = other("smooth");
    let learned = run("estimated.toml", &["--learned"]);
    let tune = other("tune");
    let bad = run("bad.toml", &[]);
    assert_eq!(
        smooth.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&smooth.stderr)
    );
    for (what, out, key) in [
        ("--learned", learned, "dvl_states"),
        ("tune", tune, "dvl_states"),
        ("bad prior", bad, "dvl_states.bias.std_mps"),
    ] {
        assert_eq!(out.status.code(), Some(2), "{what}");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            stderr.contains(".toml") && stderr.contains(key),
            "{what}: {stderr}"
        );
    }
}

#[test]
fn bad_input_exits_2_naming_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("imu.csv"),
        "time,ax,ay,az,gx,gy,gz\n0,0,0,-9.8,0,0,0\n0.01,0,0,oops,0,0,0\n",
    )
    .unwrap();
    std::fs::write(d.join("dvl.csv"), "time,vx,vy,vz\n0,1,0,0\n").unwrap();
    let out = estim(
        &[
            "navigate", "--imu", "imu.csv", "--dvl", "dvl.csv", "--out", "o",
        ],
        d,
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("imu.csv:3:"), "{stderr}");
    assert!(out.stdout.is_empty());
    assert!(!d.join("o").exists(), "nothing written");
    // A vehicle file with an unknown key names its line.
    std::fs::write(
        d.join("v.toml"),
        "[dvl]\nlever_arm_m = [0, 0, 0]\nbogus = 1\n",
    )
    .unwrap();
    let out = estim(
        &[
            "navigate",
            "--imu",
            "imu.csv",
            "--dvl",
            "dvl.csv",
            "--vehicle",
            "v.toml",
        ],
        d,
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("v.toml:3:"), "{stderr}");
}
