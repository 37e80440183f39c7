//! The `estim beamsnet eval --json` output shape (BeamsNet vs least squares on the
//! held-out A-KIT trajectories 4 and 13 with independent metrics: the study's
//! `estim-cli/src/study/tests/beamsnet_eval.rs`).
//!
//! Data rule: if the data is absent the tests print why and return, unless
//! `ESTIM_REQUIRE_DATA=1`. Run with `--nocapture` to see the table.

mod common;
use common::data_root;

#[test]
fn eval_cli_json_shape() {
    let Some(root) = data_root() else { return };
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(["beamsnet", "eval", "--trajectory", "13", "--json", "--data"])
        .arg(&root)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["trajectory"], 13);
    let rows = v["velocity"].as_array().expect("velocity array");
    let ids: Vec<&str> = rows.iter().filter_map(|r| r["id"].as_str()).collect();
    assert_eq!(ids, ["ls", "beamsnet"]);
    for row in rows {
        for key in ["rmse_mps", "mae_mps", "r2", "vaf_percent"] {
            assert!(
                row[key].as_f64().is_some_and(f64::is_finite),
                "{}.{key}: {v}",
                row["id"]
            );
        }
    }
}
