//! `estim montecarlo --first-seed S --runs N` in shards and `estim montecarlo merge`
//! (issue 31): shards [S, S+1) and [S+1, S+3) merged equal one run [S, S+3) exactly;
//! overlapping seeds, another configuration and malformed shard files are refused with
//! exit status 2, an error naming the file(s) and nothing on stdout.

use std::path::Path;
use std::process::{Command, Output};

use serde_json::Value;

/// The arguments as `&str`.
fn strs(v: &[String]) -> Vec<&str> {
    v.iter().map(String::as_str).collect()
}

fn estim(args: &[&str], cwd: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(args)
        .current_dir(cwd)
        .output()
        .expect("estim runs")
}

/// Run, expect exit 0, write stdout to `file`, return the document.
fn shard(args: &[&str], cwd: &Path, file: &str) -> Value {
    let out = estim(args, cwd);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    std::fs::write(cwd.join(file), &out.stdout).unwrap();
    serde_json::from_slice(&out.stdout).unwrap()
}

/// Expect exit 2, an empty stdout and every `needle` in stderr.
fn refused(args: &[&str], cwd: &Path, needles: &[&str]) {
    let out = estim(args, cwd);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
    assert!(out.stdout.is_empty(), "{args:?}: stdout not empty");
    for n in needles {
        assert!(stderr.contains(n), "{args:?}: {n:?} not in {stderr}");
    }
    println!("{args:?}: {}", stderr.trim());
}

#[test]
fn shards_merge_exactly_and_bad_shards_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let cwd = dir.path();
    // Short missions keep the test quick; every shard uses the same file.
    std::fs::write(cwd.join("short.toml"), "[mission]\nduration_s = 60.0\n").unwrap();
    std::fs::write(
        cwd.join("other.toml"),
        "[mission]\nduration_s = 60.0\n[filter]\nrho = 0.1\n",
    )
    .unwrap();
    let mc = |first: &str, runs: &str, config: &str| {
        vec![
            "montecarlo",
            "--config",
            config,
            "--first-seed",
            first,
            "--runs",
            runs,
            "--json",
        ]
        .into_iter()
        .map(String::from)
        .collect::<Vec<_>>()
    };
    let whole = shard(&strs(&mc("5000", "3", "short.toml")), cwd, "whole.json");
    // `--seed` is the same flag as `--first-seed`.
    let mut a_args = mc("5000", "1", "short.toml");
    a_args[3] = "--seed".into();
    shard(&strs(&a_args), cwd, "a.json");
    shard(&strs(&mc("5001", "2", "short.toml")), cwd, "b.json");

    let merged = shard(
        &["montecarlo", "merge", "b.json", "a.json", "--json"],
        cwd,
        "merged.json",
    );
    for key in [
        "runs",
        "first_seed",
        "seed_ranges",
        "epochs",
        "variants",
        "sufficient_statistics",
        "status",
    ] {
        assert_eq!(merged[key], whole[key], "{key}");
    }
    assert_eq!(merged["inputs"]["config"], whole["inputs"]["config"]);
    assert_eq!(
        merged["inputs"]["shards"],
        serde_json::json!(["b.json", "a.json"])
    );
    assert_eq!(merged["seed_ranges"], serde_json::json!([[5000, 5003]]));
    let ls = &merged["variants"][0];
    println!(
        "merged {} variants over 3 runs; {}: NEES {} position RMSE {} m",
        merged["variants"].as_array().unwrap().len(),
        ls["id"],
        ls["nees_average"],
        ls["position_rmse_m"]["mean"]
    );
    // The text table of the merge is that of the whole run.
    let text_whole = estim(
        &[
            "montecarlo",
            "--config",
            "short.toml",
            "--first-seed",
            "5000",
            "--runs",
            "3",
        ],
        cwd,
    );
    let text_merged = estim(&["montecarlo", "merge", "a.json", "b.json"], cwd);
    assert_eq!(text_merged.status.code(), Some(0));
    assert_eq!(text_merged.stdout, text_whole.stdout);
    // A merge is a shard again.
    shard(&strs(&mc("5003", "1", "short.toml")), cwd, "c.json");
    let again = shard(
        &["montecarlo", "merge", "merged.json", "c.json", "--json"],
        cwd,
        "again.json",
    );
    assert_eq!(again["runs"], 4);

    // Overlapping seeds: [5000, 5003) and [5001, 5003).
    refused(
        &["montecarlo", "merge", "whole.json", "b.json"],
        cwd,
        &[
            "whole.json and b.json",
            "seed ranges [5000, 5003) and [5001, 5003) overlap",
        ],
    );
    // Another configuration.
    shard(&strs(&mc("5010", "1", "other.toml")), cwd, "other.json");
    refused(
        &["montecarlo", "merge", "a.json", "other.json"],
        cwd,
        &[
            "a.json and other.json",
            "different configurations",
            "`config.filter.rho`",
        ],
    );
    // A truncated shard: its path and the line where it stops.
    let text = std::fs::read_to_string(cwd.join("a.json")).unwrap();
    let cut = &text[..text.len() / 2];
    std::fs::write(cwd.join("cut.json"), cut).unwrap();
    let line = cut.lines().count();
    refused(
        &["montecarlo", "merge", "a.json", "cut.json"],
        cwd,
        &[&format!("cut.json:{line}:"), "not JSON"],
    );
    // A shard without its sufficient statistics, or with a wrong value in them.
    let mut doc: Value = serde_json::from_str(&text).unwrap();
    doc.as_object_mut().unwrap().remove("sufficient_statistics");
    std::fs::write(cwd.join("bare.json"), doc.to_string()).unwrap();
    refused(
        &["montecarlo", "merge", "bare.json", "b.json"],
        cwd,
        &["bare.json:", "key `sufficient_statistics`", "missing field"],
    );
    let mut doc: Value = serde_json::from_str(&text).unwrap();
    doc["sufficient_statistics"]["variants"][0]["runs"][0]["seed"] = serde_json::json!(9);
    std::fs::write(cwd.join("seed.json"), doc.to_string()).unwrap();
    refused(
        &["montecarlo", "merge", "seed.json", "b.json"],
        cwd,
        &["seed.json: key `sufficient_statistics`: variant ls: seed 9 is outside the seed ranges [[5000, 5001]]"],
    );
    // Internally inconsistent: the document announces other seeds than its
    // statistics hold, or "ok" beside failures (issue 46): refused, not merged.
    let mut doc: Value = serde_json::from_str(&text).unwrap();
    doc["inputs"]["runs"] = serde_json::json!(2);
    std::fs::write(cwd.join("runs.json"), doc.to_string()).unwrap();
    refused(
        &["montecarlo", "merge", "runs.json", "b.json"],
        cwd,
        &[
            "runs.json: key `inputs.runs`",
            "[[5000, 5002]]",
            "[[5000, 5001]]",
        ],
    );
    // "ok" beside a failure: variant ls's run moved to its failures, status kept.
    let mut doc: Value = serde_json::from_str(&text).unwrap();
    assert_eq!(doc["status"], "ok");
    let ls = &mut doc["sufficient_statistics"]["variants"][0];
    let run = ls["runs"].as_array_mut().unwrap().remove(0);
    ls["failures"] = serde_json::json!([{
        "id": ls["id"].clone(),
        "label": ls["label"].clone(),
        "seed": run["seed"].clone(),
        "epoch": 3,
        "time_s": 3.0,
        "reason": "diverged",
    }]);
    std::fs::write(cwd.join("ok.json"), doc.to_string()).unwrap();
    refused(
        &["montecarlo", "merge", "ok.json", "b.json"],
        cwd,
        &["ok.json: key `status`", "\"ok\" with 1 filter failures"],
    );
    refused(
        &["montecarlo", "merge", "missing.json"],
        cwd,
        &["missing.json: cannot read"],
    );
}
