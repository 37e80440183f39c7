//! `estim montecarlo --learned two-beams|outage --json` and `estim reproduce --scenario
//! outage --json`: the common schema header, the five variants with their stable ids,
//! and the per-variant fields the issue asks for (small run counts: CI time).

use std::process::Command;

fn run(args: &[&str]) -> serde_json::Value {
    let out = Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

fn check_monte_carlo(kind: &str, prefix: &str, ins_only: &str) {
    let doc = run(&[
        "montecarlo",
        "--learned",
        kind,
        "--runs",
        "2",
        "--empirical-realizations",
        "20",
        "--json",
    ]);
    assert_eq!(doc["schema_version"], 2);
    assert_eq!(doc["command"], "montecarlo");
    assert_eq!(doc["status"], "ok");
    assert_eq!(doc["scenario"], kind);
    assert_eq!(doc["runs"], 2);
    let variants = doc["variants"].as_array().unwrap();
    let ids: Vec<&str> = variants.iter().map(|v| v["id"].as_str().unwrap()).collect();
    assert_eq!(
        ids,
        [
            format!("{prefix}_m_network"),
            format!("{prefix}_m_empirical"),
            format!("{prefix}_m_neglected"),
            format!("{prefix}_m_rho"),
            ins_only.to_string()
        ]
    );
    for v in variants {
        let mean = v["nees_average"].as_f64().unwrap();
        assert!(mean > 0.0, "{v}");
        let f = v["nees_epochs_in_band_percent"].as_f64().unwrap();
        assert!((0.0..=100.0).contains(&f));
        for key in ["position_rmse_m", "velocity_rmse_mps"] {
            let (m, lo, hi) = (
                v[key]["mean"].as_f64().unwrap(),
                v[key]["lo"].as_f64().unwrap(),
                v[key]["hi"].as_f64().unwrap(),
            );
            assert!(lo <= m && m <= hi && lo > 0.0, "{key}: {v}");
        }
        // The network variants report the correlation; INS only has none (null).
        if v["id"] == ins_only {
            assert!(v["output_imu_correlation"].is_null());
        } else {
            let c = v["output_imu_correlation"].as_f64().unwrap();
            assert!(c > 0.0 && c < 1.0, "{v}");
        }
    }
}

#[test]
fn montecarlo_two_beams_json_has_the_variant_fields() {
    check_monte_carlo("two-beams", "two_beams", "ins_only_during_loss");
}

#[test]
fn montecarlo_outage_json_has_the_variant_fields() {
    check_monte_carlo("outage", "outage", "ins_only_during_outage");
}

#[test]
fn reproduce_outage_json_on_the_simulated_mission() {
    let doc = run(&["reproduce", "--scenario", "outage", "--json"]);
    assert_eq!(doc["command"], "reproduce");
    let studies = doc["studies"].as_array().unwrap();
    assert_eq!(studies.len(), 1);
    let s = &studies[0];
    assert_eq!(s["event"], "outage");
    // 60 s at 1 Hz, all within the network's trained range.
    assert_eq!(s["loss_epochs"], 60);
    assert_eq!(s["filters"].as_array().unwrap().len(), 5);
}
