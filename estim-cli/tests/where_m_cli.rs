//! `estim where-m` as a user meets it: the common JSON header, one cell per (IMU grade,
//! DVL noise, sensor), and bad input refused with exit status 2 and one line on stderr.

use std::process::{Command, Output};

use serde_json::Value;

fn estim(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(args)
        .output()
        .expect("run estim")
}

#[test]
fn one_mission_per_grade_gives_every_cell() {
    let out = estim(&["where-m", "--runs", "1", "--first-seed", "3", "--json"]);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let doc: Value = serde_json::from_slice(&out.stdout).expect("JSON on stdout");
    assert_eq!(doc["command"], "where-m");
    assert_eq!(doc["status"], "ok");
    assert_eq!(doc["schema_version"], 2);
    assert_eq!(doc["inputs"]["seeds"], serde_json::json!([3, 3]));
    let cells = doc["cells"].as_array().expect("cells");
    // 4 IMU grades x 2 DVL noise levels x 4 sensors.
    assert_eq!(cells.len(), 32);
    for cell in cells {
        for filter in ["exact", "neglected"] {
            let nees = cell[filter]["nees_average"].as_f64().expect("nees_average");
            assert!(nees.is_finite() && nees > 0.0, "{cell}");
            assert!(cell[filter]["velocity_std_mps"].as_f64().expect("std") > 0.0);
        }
        // The beams-only sensor has M = 0: both filters are one filter.
        if cell["sensor"] == "beams_only" {
            assert_eq!(cell["exact"], cell["neglected"], "{cell}");
            assert_eq!(cell["m_matters"], false);
        }
    }
}

/// Our own checks print one line; clap's parse error (a non-number) its usage too, still
/// with exit status 2 and starting with `error`.
#[test]
fn bad_counts_and_seeds_exit_2_with_one_line() {
    for (args, one_line) in [
        (&["where-m", "--runs", "0"][..], true),
        (
            &["where-m", "--runs", "2", "--first-seed", "9007199254740992"][..],
            true,
        ),
        (&["where-m", "--runs", "x"][..], false),
    ] {
        let out = estim(args);
        assert_eq!(out.status.code(), Some(2), "{args:?}");
        assert!(out.stdout.is_empty(), "{args:?}");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.starts_with("error"), "{args:?}: {stderr}");
        if one_line {
            assert_eq!(stderr.lines().count(), 1, "{args:?}: {stderr}");
        }
    }
}
