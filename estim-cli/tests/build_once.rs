//! The README's two commands compile every dependency once.
//!
//! `cargo run --release -- reproduce` at the root resolves the features of the `estim`
//! binary's package (estim-cli, whose binary `cargo run` picks) alone; `cargo test
//! --workspace --release` adds every dev-dependency of the workspace and the default
//! features of every member, which turns on more features in some shared dependencies
//! (serde in nalgebra, say). A dependency whose features differ between the two is
//! compiled twice, and with it everything that depends on it (tract included). The
//! estim-cli feature `build-once` turns those features on for the binary too
//! (estim-cli/Cargo.toml); this test fails when a change of dependencies makes the two
//! sets drift apart again.

use std::collections::{BTreeMap, BTreeSet};
use std::process::Command;

/// `cargo tree` lines `name version features...` as a map.
fn features(args: &[&str]) -> BTreeMap<String, BTreeSet<String>> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .args([
            "tree",
            "--locked",
            "--offline",
            "--prefix",
            "none",
            "-f",
            "{p}|{f}",
        ])
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("run cargo tree");
    assert!(
        out.status.success(),
        "cargo tree {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut map: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for line in String::from_utf8_lossy(&out.stdout).lines() {
        let line = line.trim_end_matches(" (*)");
        let Some((package, feats)) = line.split_once('|') else {
            continue;
        };
        // "name v1.2.3 (path or proc-macro)": name and version identify the build.
        let mut words = package.split_whitespace();
        let (Some(name), Some(version)) = (words.next(), words.next()) else {
            continue;
        };
        map.entry(format!("{name} {version}"))
            .or_default()
            .extend(feats.split(',').filter(|f| !f.is_empty()).map(String::from));
    }
    map
}

#[test]
fn run_and_test_commands_resolve_the_same_features() {
    let run = features(&["-p", "estim-cli", "-e", "normal,build"]);
    let test = features(&["--workspace", "-e", "normal,build,dev"]);
    assert!(
        run.keys().any(|k| k.starts_with("tract-onnx ")),
        "the binary uses tract"
    );
    let differing: Vec<String> = run
        .iter()
        .filter_map(|(package, f)| {
            let t = test.get(package)?;
            (t != f).then(|| {
                let extra: Vec<&String> = t.difference(f).collect();
                format!("{package}: the tests add {extra:?}")
            })
        })
        .collect();
    assert!(
        differing.is_empty(),
        "dependencies compiled twice by the README's two commands (add the features to \
         `build-once` in estim-cli/Cargo.toml):\n{}",
        differing.join("\n")
    );
}
