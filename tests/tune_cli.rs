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
