//! The `estim` binary as a script or a user meets it: one JSON schema across commands,
//! a failing filter variant reported as data (exit 3) while the others complete, a
//! closed stdout, `--out` checks, progress on stderr, `--print-config`.
//!
//! Exit statuses (estim-cli/src/schema.rs): 0 ok, 2 bad input, 3 some filter variant
//! failed, 141 stdout closed by the reader.

use std::io::Read;
use std::path::Path;
use std::process::{Command, Output, Stdio};

use serde_json::Value;

mod common;

/// The page holding the `[faults]` example.
const RESULTS: &str = include_str!("../../docs/results.md");

fn estim(args: &[&str], cwd: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(args)
        .current_dir(cwd)
        .output()
        .expect("run estim")
}

/// The `[faults]` TOML block of docs/results.md (the example a user copies into
/// faults.toml).
fn readme_faults_toml() -> String {
    let start = RESULTS
        .find("```toml\n[faults]")
        .expect("docs/results.md [faults] block")
        + 8;
    let len = RESULTS[start..].find("```").expect("block end");
    RESULTS[start..start + len].to_string()
}

fn json_of(out: &Output) -> Value {
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "not JSON ({e}): stdout {:?}, stderr {}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        )
    })
}

/// A filter id: lower-case words joined by underscores.
fn is_id(v: &Value) -> bool {
    v.as_str().is_some_and(|s| {
        !s.is_empty()
            && s.chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
    })
}

/// The common header of every JSON document, and `id` + `label` on every element of
/// every array of variants found anywhere in it.
fn assert_schema(doc: &Value, command: &str) {
    assert_eq!(doc["schema_version"], 2, "{command}: schema_version");
    assert_eq!(
        doc["estim_version"].as_str(),
        Some(env!("CARGO_PKG_VERSION")),
        "{command}: estim_version"
    );
    assert_eq!(doc["command"].as_str(), Some(command));
    assert!(doc["inputs"].is_object(), "{command}: inputs");
    assert!(
        matches!(doc["status"].as_str(), Some("ok" | "filters_failed")),
        "{command}: status {}",
        doc["status"]
    );
    check_variant_arrays(doc, command, "");
}

/// Arrays named `velocity`, `filters`, `variants`, `failures`, `improvements` hold
/// objects with an `id` and a string `label`; no old key spellings anywhere.
fn check_variant_arrays(v: &Value, command: &str, path: &str) {
    match v {
        Value::Object(o) => {
            for (k, x) in o {
                let here = format!("{path}.{k}");
                // One name per count: the `_epochs` spelling only.
                assert_ne!(k, "covariance_not_positive_definite", "{command}: {here}");
                // An error summary's `rmse` sits under a key that names the unit.
                if k == "rmse" {
                    assert!(
                        ["_m", "_mps", "_deg"].iter().any(|u| path.ends_with(u)),
                        "{command}: {here} without a unit"
                    );
                }
                let variant_list = matches!(
                    k.as_str(),
                    "velocity" | "filters" | "variants" | "failures" | "improvements"
                );
                if let (true, Some(arr)) = (variant_list, x.as_array()) {
                    for (i, e) in arr.iter().enumerate() {
                        assert!(is_id(&e["id"]), "{command}: {here}[{i}].id = {}", e["id"]);
                        assert!(e["label"].is_string(), "{command}: {here}[{i}].label");
                    }
                }
                check_variant_arrays(x, command, &here);
            }
        }
        Value::Array(a) => a
            .iter()
            .enumerate()
            .for_each(|(i, x)| check_variant_arrays(x, command, &format!("{path}[{i}]"))),
        _ => {}
    }
}

fn variant<'a>(list: &'a Value, id: &str) -> &'a Value {
    list.as_array()
        .and_then(|a| a.iter().find(|v| v["id"] == id))
        .unwrap_or_else(|| panic!("no variant {id} in {list}"))
}

#[test]
fn every_command_speaks_one_schema() {
    let dir = tempfile::tempdir().expect("tempdir");
    let reproduce = estim(&["reproduce", "--json"], dir.path());
    assert_eq!(reproduce.status.code(), Some(0));
    let doc = json_of(&reproduce);
    assert_schema(&doc, "reproduce");
    assert_eq!(doc["inputs"]["seed"], 7);
    assert!(doc["inputs"]["config"]["filter"]["rho"].is_number());
    let t = &doc["trajectories"][0];
    for f in t["filters"].as_array().expect("filters") {
        assert!(f["position_error_m"]["rmse"].is_number());
        assert!(f["velocity_error_mps"]["rmse"].is_number());
        assert!(f["covariance_not_positive_definite_epochs"].is_u64());
        assert!(f["std"]["velocity_mps"]["time_average"].is_number());
    }
    // The label states the rho used: "(paper)" only for 0.42.
    assert_eq!(
        variant(&t["filters"], "beamsnet_m_rho")["label"],
        "BeamsNet, M = rho 0.42 (paper)"
    );
    std::fs::write(dir.path().join("rho.toml"), "[filter]\nrho = 0.1\n").expect("write");
    let doc = json_of(&estim(
        &["reproduce", "--json", "--config", "rho.toml"],
        dir.path(),
    ));
    assert_eq!(
        variant(&doc["trajectories"][0]["filters"], "beamsnet_m_rho")["label"],
        "BeamsNet, M = rho 0.1"
    );
    assert_eq!(doc["inputs"]["config_file"], "rho.toml");

    std::fs::write(
        dir.path().join("short.toml"),
        "[mission]\nduration_s = 60.0\n",
    )
    .expect("write");
    let mc = estim(
        &[
            "montecarlo",
            "--runs",
            "2",
            "--json",
            "--config",
            "short.toml",
        ],
        dir.path(),
    );
    assert_eq!(
        mc.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&mc.stderr)
    );
    let doc = json_of(&mc);
    assert_schema(&doc, "montecarlo");
    assert_eq!(doc["inputs"]["runs"], 2);
    assert_eq!(doc["inputs"]["first_seed"], 1000);
    for id in ["ls", "oracle_m_neglected", "oracle_m_true", "oracle_m_rho"] {
        let v = variant(&doc["variants"], id);
        assert!(
            v["covariance_not_positive_definite_epochs"].is_u64(),
            "{id}"
        );
        assert!(v["position_rmse_m"]["mean"].is_number(), "{id}");
        assert_eq!(v["runs_completed"], 2, "{id}");
    }

    let eval = estim(&["beamsnet", "eval", "--json"], dir.path());
    assert_eq!(
        eval.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&eval.stderr)
    );
    let doc = json_of(&eval);
    assert_schema(&doc, "beamsnet eval");
    // The same velocity rows (ids, unit-suffixed fields) as `reproduce`.
    for id in ["ls", "beamsnet"] {
        assert!(variant(&doc["velocity"], id)["rmse_mps"].is_number());
    }
    assert!(doc["inputs"]["model"].is_string() && doc["inputs"]["seed"].is_u64());
}

#[test]
fn dvl_calibrate_json_speaks_the_schema() {
    let Some(root) = common::data_root() else {
        return;
    };
    let files = estim::datasets::trajectory_files(&root, 13).expect("trajectory 13");
    let dir = tempfile::tempdir().expect("tempdir");
    let (gt, dvl) = (files.gt.to_string_lossy(), files.dvl.to_string_lossy());
    let out = estim(
        &["dvl", "calibrate", "--gt", &gt, "--dvl", &dvl, "--json"],
        dir.path(),
    );
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let doc = json_of(&out);
    assert_schema(&doc, "dvl calibrate");
    assert_eq!(doc["inputs"]["gt"].as_str(), Some(gt.as_ref()));
    for key in ["lever_arm_m", "mounting_misalignment_rad"] {
        for field in ["estimate", "standard_error"] {
            let values = doc[key][field].as_array().expect(key);
            assert_eq!(values.len(), 3, "{key}.{field}");
            assert!(values
                .iter()
                .all(|v| v.as_f64().is_some_and(f64::is_finite)));
        }
    }
    // One-value estimates are numbers, not one-element lists.
    for key in ["scale_factor_error", "time_offset_s"] {
        for field in ["estimate", "standard_error"] {
            assert!(
                doc[key][field].as_f64().is_some_and(f64::is_finite),
                "{key}.{field}: {}",
                doc[key][field]
            );
        }
    }
    assert!(doc["samples"].as_u64().is_some_and(|n| n > 100));
    assert_eq!(doc["residual_rms_mps"].as_array().map(Vec::len), Some(3));
}

#[test]
fn a_diverging_filter_is_reported_and_the_others_are_kept() {
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::write(dir.path().join("faults.toml"), readme_faults_toml()).expect("write");
    let out = estim(
        &[
            "reproduce",
            "--config",
            "faults.toml",
            "--json",
            "--out",
            "results",
        ],
        dir.path(),
    );
    assert_eq!(
        out.status.code(),
        Some(3),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let doc = json_of(&out);
    assert_schema(&doc, "reproduce");
    assert_eq!(doc["status"], "filters_failed");
    let t = &doc["trajectories"][0];
    let failures = t["failures"].as_array().expect("failures");
    assert_eq!(failures.len(), 1, "{failures:?}");
    let f = &failures[0];
    assert_eq!(f["id"], "beamsnet_m_rho");
    assert_eq!(f["seed"], 7);
    assert!(f["epoch"].is_u64() && f["time_s"].as_f64().is_some_and(|t| t > 0.0));
    assert!(
        f["reason"]
            .as_str()
            .is_some_and(|r| r.contains("not positive definite")),
        "{f}"
    );
    // The other variants completed, with their figures.
    let ids: Vec<&str> = t["filters"]
        .as_array()
        .expect("filters")
        .iter()
        .filter_map(|f| f["id"].as_str())
        .collect();
    assert_eq!(ids, ["ls", "beamsnet_m_neglected", "beamsnet_m_network"]);
    for f in t["filters"].as_array().expect("filters") {
        assert!(f["position_error_m"]["rmse"]
            .as_f64()
            .is_some_and(f64::is_finite));
    }
    // Outputs of the completed filters were written.
    let results = dir.path().join("results");
    assert!(results.join("report.json").is_file());
    assert!(results.join("simulated_track.png").is_file());
    assert!(results.join("simulated_error_velocity_ls.svg").is_file());
    assert!(!results
        .join("simulated_error_velocity_beamsnet_m_rho.svg")
        .exists());

    // Text: the failure named with seed and epoch, the status on stderr.
    let out = estim(&["reproduce", "--config", "faults.toml"], dir.path());
    assert_eq!(out.status.code(), Some(3));
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text
        .lines()
        .find(|l| l.contains("FAILED"))
        .expect("failure line");
    assert!(
        line.contains("beamsnet_m_rho") && line.contains("seed 7") && line.contains("DVL epoch"),
        "{line}"
    );
    assert!(text.contains("LS [ls]"), "{text}");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("filter run(s) failed") && !stderr.contains("panicked"));

    // montecarlo --faults: the rho variants fail in that run, the others complete.
    let out = estim(
        &["montecarlo", "--runs", "1", "--faults", "--json"],
        dir.path(),
    );
    assert_eq!(
        out.status.code(),
        Some(3),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let doc = json_of(&out);
    assert_schema(&doc, "montecarlo");
    for v in doc["variants"].as_array().expect("variants") {
        let failed = v["failures"].as_array().expect("failures").len();
        assert_eq!(
            v["runs_completed"].as_u64().map(|n| n as usize + failed),
            Some(1)
        );
        for f in v["failures"].as_array().expect("failures") {
            assert_eq!(f["seed"], 1000);
            assert!(f["epoch"].is_u64() && f["reason"].is_string());
        }
    }
    assert_eq!(
        variant(&doc["variants"], "oracle_m_true")["runs_completed"],
        1
    );
    assert_eq!(variant(&doc["variants"], "ls")["runs_completed"], 1);
}

/// Spawn `estim args` with its stdout read end closed before it writes (each command
/// used computes for a second or more before its first write).
fn with_closed_stdout(args: &[&str]) -> (Option<i32>, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn");
    drop(child.stdout.take());
    let mut stderr = String::new();
    if let Some(mut e) = child.stderr.take() {
        e.read_to_string(&mut stderr).expect("stderr");
    }
    let status = child.wait().expect("wait");
    (status.code(), stderr)
}

#[test]
fn a_closed_stdout_ends_quietly_with_status_141() {
    for args in [
        &["reproduce"][..],
        &["reproduce", "--json"],
        &["beamsnet", "eval"],
    ] {
        let (code, stderr) = with_closed_stdout(args);
        assert_eq!(code, Some(141), "estim {args:?}: stderr {stderr}");
        assert!(stderr.is_empty(), "estim {args:?}: not quiet: {stderr}");
    }
}

#[test]
fn out_is_checked_before_any_work() {
    let dir = tempfile::tempdir().expect("tempdir");
    // A path no one can create (even root): /proc refuses new folders.
    #[cfg(target_os = "linux")]
    {
        let out = estim(
            &[
                "reproduce",
                "--out",
                "/proc/estim-out",
                "--data",
                "no-such-data",
            ],
            dir.path(),
        );
        assert_eq!(out.status.code(), Some(2));
        let stderr = String::from_utf8_lossy(&out.stderr);
        // The output folder is named, not the data folder: the check came first.
        assert!(
            stderr.contains("/proc/estim-out") && !stderr.contains("no-such-data"),
            "{stderr}"
        );
        assert!(out.stdout.is_empty());
    }
    // --out is a file.
    std::fs::write(dir.path().join("a-file"), "x").expect("write");
    let out = estim(
        &["reproduce", "--out", "a-file", "--data", "no-such-data"],
        dir.path(),
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("a-file"));

    // Permissions: a read-only parent with a writable --out works (files are staged
    // inside the target); a read-only --out fails before work, naming it.
    use std::os::unix::fs::PermissionsExt;
    let parent = dir.path().join("parent");
    let target = parent.join("out");
    std::fs::create_dir_all(&target).expect("mkdir");
    std::fs::set_permissions(&parent, std::fs::Permissions::from_mode(0o555)).expect("chmod");
    let privileged = std::fs::write(parent.join("probe"), "x").is_ok();
    if privileged {
        // Root ignores permission bits; the /proc case above covers the refusal.
        eprintln!("skipped the permission-bit cases: running with privileges that ignore them");
        let _ = std::fs::remove_file(parent.join("probe"));
    } else {
        let out = estim(
            &["reproduce", "--out", target.to_str().expect("utf-8")],
            dir.path(),
        );
        assert_eq!(
            out.status.code(),
            Some(0),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(target.join("report.json").is_file());
        std::fs::set_permissions(&target, std::fs::Permissions::from_mode(0o555)).expect("chmod");
        let out = estim(
            &[
                "reproduce",
                "--out",
                target.to_str().expect("utf-8"),
                "--data",
                "no-such-data",
            ],
            dir.path(),
        );
        assert_eq!(out.status.code(), Some(2));
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.contains(target.to_str().expect("utf-8")), "{stderr}");
        std::fs::set_permissions(&target, std::fs::Permissions::from_mode(0o755)).expect("chmod");
    }
    std::fs::set_permissions(&parent, std::fs::Permissions::from_mode(0o755)).expect("chmod");
    // Staging leaves nothing beside the target, and nothing hidden inside it.
    let out = estim(&["reproduce", "--out", "fresh"], dir.path());
    assert_eq!(out.status.code(), Some(0));
    let beside: Vec<String> = std::fs::read_dir(dir.path())
        .expect("list")
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(beside.is_empty(), "{beside:?}");
    let hidden: Vec<String> = std::fs::read_dir(dir.path().join("fresh"))
        .expect("list")
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(hidden.is_empty(), "{hidden:?}");
    // A failed run removes the target it created.
    let out = estim(
        &["reproduce", "--out", "never", "--data", "no-such-data"],
        dir.path(),
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(!dir.path().join("never").exists());
}

#[test]
fn montecarlo_progress_goes_to_stderr_as_lines() {
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::write(
        dir.path().join("short.toml"),
        "[mission]\nduration_s = 30.0\n",
    )
    .expect("write");
    let out = estim(
        &["montecarlo", "--runs", "3", "--config", "short.toml"],
        dir.path(),
    );
    assert_eq!(out.status.code(), Some(0));
    let stderr = String::from_utf8_lossy(&out.stderr);
    let lines: Vec<&str> = stderr.lines().collect();
    // stderr is a pipe here: one plain line per completed tenth (each mission here).
    assert_eq!(lines.len(), 3, "{stderr}");
    assert!(
        lines[2].starts_with("montecarlo: 3/3 missions done"),
        "{stderr}"
    );
    assert!(!String::from_utf8_lossy(&out.stdout).contains("missions done"));
}

#[test]
fn print_config_and_preset_errors_help_the_user() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = estim(&["reproduce", "--print-config"], dir.path());
    assert_eq!(out.status.code(), Some(0));
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    for needle in [
        "[imu.accelerometer]",
        "[imu.gyroscope]",
        "[faults]",
        "ls_noise_std_mps",
    ] {
        assert!(text.contains(needle), "{needle} missing");
    }
    // What it prints loads back.
    std::fs::write(dir.path().join("printed.toml"), &text).expect("write");
    let back = estim(
        &["reproduce", "--config", "printed.toml", "--print-config"],
        dir.path(),
    );
    assert_eq!(
        back.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&back.stderr)
    );
    assert_eq!(String::from_utf8_lossy(&back.stdout), text);
    std::fs::write(dir.path().join("t.toml"), "[imu]\npreset = \"tactical\"\n").expect("write");
    let out = estim(&["reproduce", "--config", "t.toml"], dir.path());
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    for p in [
        "akit_observed",
        "tactical_mems",
        "navigation_grade_fog",
        "consumer_mems",
    ] {
        assert!(stderr.contains(p), "{stderr}");
    }
}

#[test]
fn smooth_json_is_one_document_in_the_schema() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = estim(&["smooth", "--json"], dir.path());
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let doc = json_of(&out);
    assert_schema(&doc, "smooth");
    let reports = doc["reports"].as_array().expect("reports");
    assert_eq!(reports.len(), 1, "the embedded simulated mission");
    assert!(doc["inputs"]["seed"].is_u64());
}

#[test]
fn trajectory_without_data_finds_the_data_through_estim_data_dir() {
    let Some(root) = common::data_root() else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let run = |data_dir: &Path| {
        Command::new(env!("CARGO_BIN_EXE_estim"))
            .args(["reproduce", "--trajectory", "13", "--json"])
            .env("ESTIM_DATA_DIR", data_dir)
            .current_dir(dir.path())
            .output()
            .expect("run estim")
    };
    let out = run(&root);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let doc = json_of(&out);
    let numbers: Vec<u64> = doc["trajectories"]
        .as_array()
        .expect("trajectories")
        .iter()
        .filter_map(|t| t["trajectory"].as_u64())
        .collect();
    assert_eq!(
        numbers,
        [13],
        "--trajectory 13 ran A-KIT 13, not the simulated mission"
    );
    // A data folder without the trajectory: exit 2 naming it, never a silent fallback.
    let out = run(dir.path());
    assert_eq!(out.status.code(), Some(2));
    assert!(out.stdout.is_empty());
}
