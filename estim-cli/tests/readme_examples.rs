//! Every `estim` command in the ```sh blocks of README.md and the user docs
//! (docs/cli.md, docs/results.md), run as written.
//!
//! The pages are read at compile time of this test, so a changed example is re-tested. A command is a
//! line (or a `&&`-separated part of one) that starts with `estim` or `cargo run
//! [--release] [--example NAME] --`; everything else (`cargo test`, `git clone`) is
//! not an `estim` example and is skipped by kind. A trailing `# ...` comment may state
//! the expected exit status as `exit N` (default 0). Commands run in a temporary
//! folder holding `faults.toml` (the `[faults]` TOML block of docs/results.md, as
//! that page tells the user to save it); the A-KIT paths of the README (`../shared/data`,
//! `A-KIT/Data`) are replaced by the test data root, and such commands are skipped
//! with a printed reason when the data is absent (a failure with ESTIM_REQUIRE_DATA=1).

use std::path::{Path, PathBuf};
use std::process::Command;

mod common;

/// The pages whose examples run, with their text.
const PAGES: &[(&str, &str)] = &[
    ("README.md", include_str!("../../README.md")),
    ("docs/cli.md", include_str!("../../docs/cli.md")),
    ("docs/results.md", include_str!("../../docs/results.md")),
];

/// Commands not run here, each with its reason (matched as a substring).
const SKIPPED: &[(&str, &str)] = &[
    (
        "montecarlo --runs 20",
        "20 missions take about 25 s on 2 cores; the same code path runs in this file with \
         --runs 1 and in tests/cli_manners.rs",
    ),
    (
        "navigate --imu imu.csv",
        "needs a survey's own files (none are committed); tests/navigate.rs runs navigate \
         on files in these shapes made from A-KIT",
    ),
];

/// The ```sh blocks of a Markdown text, as lists of lines.
fn sh_blocks(text: &str) -> Vec<Vec<String>> {
    let mut blocks = Vec::new();
    let mut current: Option<Vec<String>> = None;
    for line in text.lines() {
        let t = line.trim();
        match &mut current {
            None if t == "```sh" || t == "```bash" || t == "```shell" => current = Some(Vec::new()),
            Some(lines) if t.starts_with("```") => {
                blocks.push(std::mem::take(lines));
                current = None;
            }
            Some(lines) => lines.push(line.to_string()),
            None => {}
        }
    }
    blocks
}

/// The body of the README's ```toml block that holds `[faults]`.
fn faults_toml(text: &str) -> String {
    let mut in_block = false;
    let mut body = String::new();
    for line in text.lines() {
        if !in_block && line.trim() == "```toml" {
            in_block = true;
            body.clear();
        } else if in_block && line.trim().starts_with("```") {
            if body.contains("[faults]") {
                return body;
            }
            in_block = false;
        } else if in_block {
            body.push_str(line);
            body.push('\n');
        }
    }
    panic!("docs/results.md has no ```toml block with [faults]");
}

/// An `estim` invocation found in the README.
#[derive(Debug)]
struct Example {
    line: String,
    args: Vec<String>,
    expected_status: i32,
    needs_data: bool,
}

/// Split a README command line into `estim` invocations.
fn examples(line: &str) -> Vec<Example> {
    let (command, comment) = match line.split_once(" #") {
        Some((c, k)) => (c, k),
        None => (line, ""),
    };
    let expected_status = comment
        .split("exit ")
        .nth(1)
        .and_then(|t| t.split(|c: char| !c.is_ascii_digit()).next())
        .and_then(|n| n.parse().ok())
        .unwrap_or(0);
    let mut out = Vec::new();
    for part in command.split("&&") {
        let words: Vec<&str> = part.split_whitespace().collect();
        let args: Vec<&str> = match words.as_slice() {
            ["estim", rest @ ..] => rest.to_vec(),
            ["cargo", "run", rest @ ..] => match rest.iter().position(|w| *w == "--") {
                Some(i) if !rest[..i].contains(&"--example") => rest[i + 1..].to_vec(),
                _ => continue,
            },
            _ => continue,
        };
        assert!(
            !part.contains(['|', '>', '<', '"', '\'', '$', '`']),
            "README command {part:?} uses shell syntax this test does not run; keep examples plain"
        );
        let needs_data = args
            .iter()
            .any(|a| *a == "../shared/data" || *a == "A-KIT/Data");
        out.push(Example {
            line: line.trim().to_string(),
            args: args.iter().map(|s| s.to_string()).collect(),
            expected_status,
            needs_data,
        });
    }
    out
}

fn run(example: &Example, dir: &Path, data: Option<&PathBuf>) {
    let args: Vec<String> = example
        .args
        .iter()
        .map(|a| match (a.as_str(), data) {
            ("../shared/data" | "A-KIT/Data", Some(d)) => d.to_string_lossy().into_owned(),
            _ => a.clone(),
        })
        .collect();
    let out = Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(&args)
        .current_dir(dir)
        .output()
        .expect("run estim");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(
        out.status.code(),
        Some(example.expected_status),
        "README example `{}` (run as estim {args:?}): stderr {stderr}",
        example.line
    );
    assert!(!stderr.contains("panicked"), "{}: {stderr}", example.line);
    if example.expected_status == 0 || example.expected_status == 3 {
        assert!(!out.stdout.is_empty(), "{}: no output", example.line);
    }
}

#[test]
fn every_readme_estim_example_runs_as_documented() {
    let all: Vec<Example> = PAGES
        .iter()
        .flat_map(|(_, text)| sh_blocks(text))
        .flatten()
        .flat_map(|l| examples(&l))
        .collect();
    assert!(
        all.len() >= 3,
        "expected the README's estim examples, found {all:?}"
    );
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::write(dir.path().join("faults.toml"), faults_toml(PAGES[2].1)).expect("write");
    let data = if all.iter().any(|e| e.needs_data) {
        common::data_root()
    } else {
        None
    };
    let mut ran = 0;
    for example in &all {
        if let Some((_, reason)) = SKIPPED.iter().find(|(p, _)| example.line.contains(p)) {
            eprintln!("skipped `{}`: {reason}", example.line);
            continue;
        }
        if example.needs_data && data.is_none() {
            eprintln!("skipped `{}`: A-KIT data not found", example.line);
            continue;
        }
        eprintln!("running `{}`", example.line);
        run(example, dir.path(), data.as_ref());
        ran += 1;
    }
    assert!(ran >= 2, "ran only {ran} README examples");
}

#[test]
fn the_parser_finds_commands_and_statuses() {
    let e = examples("cargo run --release -- reproduce --config faults.toml   # exit 3: rho fails");
    assert_eq!(e.len(), 1);
    assert_eq!(e[0].args, ["reproduce", "--config", "faults.toml"]);
    assert_eq!(e[0].expected_status, 3);
    let e =
        examples("git clone https://x/A-KIT && cargo run --release -- reproduce --data A-KIT/Data");
    assert_eq!(e.len(), 1);
    assert!(e[0].needs_data);
    assert!(examples("cargo test --workspace --release     # the tests").is_empty());
    assert!(examples("cargo run --release --example correlated_tracker").is_empty());
    let e = examples("estim montecarlo --runs 1 --faults   # exit 3");
    assert_eq!(e[0].args, ["montecarlo", "--runs", "1", "--faults"]);
    assert_eq!(
        sh_blocks("a\n```sh\nx\ny\n```\n```toml\nz\n```\n"),
        vec![vec!["x", "y"]]
    );
}
