//! The `fuzz` and `long-mission` tables, rendered from the committed logs of the long
//! runs in `results/` ([`long_run_tables`]).

use std::path::{Path, PathBuf};

use super::{thousands, Table};
use crate::study::{PipelineError, Result};

/// A long-run log: its first line is `<commit> <command>`, the rest the command's output.
#[derive(Debug, Clone)]
struct Log {
    path: PathBuf,
    file: String,
    commit: String,
    command: String,
    lines: Vec<String>,
}

fn read_log(path: &Path) -> Result<Log> {
    let text = std::fs::read_to_string(path).map_err(|source| PipelineError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let first_line = |reason: String| PipelineError::Data {
        path: path.to_path_buf(),
        line: Some(1),
        reason,
    };
    let mut lines = text.lines();
    let first = lines.next().unwrap_or_default();
    let (commit, command) = first
        .split_once(' ')
        .ok_or_else(|| first_line("expected \"<commit> <command>\"".into()))?;
    if commit.len() != 40 || !commit.chars().all(|c| c.is_ascii_hexdigit()) {
        return Err(first_line(format!(
            "{commit:?} is not a 40-digit commit hash"
        )));
    }
    let file = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    Ok(Log {
        path: path.to_path_buf(),
        file,
        commit: commit.to_string(),
        command: command.to_string(),
        lines: lines.map(str::to_string).collect(),
    })
}

impl Log {
    /// What was wrong in this log, at `line` (1-based) where known.
    fn error(&self, line: Option<u64>, reason: &str) -> PipelineError {
        PipelineError::Data {
            path: self.path.clone(),
            line,
            reason: reason.into(),
        }
    }
}

/// The text after `key` in `line`, up to `end` (or the end of the line).
fn after<'a>(line: &'a str, key: &str, end: &str) -> Option<&'a str> {
    let start = line.find(key)? + key.len();
    let rest = &line[start..];
    Some(match rest.find(end) {
        Some(i) if !end.is_empty() => &rest[..i],
        _ => rest,
    })
}

/// The `finished in X s` time and pass/fail of a cargo test log.
fn test_outcome(log: &Log) -> Result<(bool, String)> {
    let line = log
        .lines
        .iter()
        .find(|l| l.starts_with("test result:"))
        .ok_or_else(|| log.error(None, "no \"test result:\" line"))?;
    let passed = line.starts_with("test result: ok.");
    let seconds = after(line, "finished in ", "s")
        .and_then(|s| s.trim().parse::<f64>().ok())
        .ok_or_else(|| log.error(None, "no \"finished in\" time"))?;
    Ok((passed, format!("{seconds:.0} s")))
}

/// Parser and property of a `src/study/tests/fuzz_parsers.rs` property, by its name.
fn fuzz_property(test: &str) -> (usize, String, String) {
    let parsers = [
        ("gt_loader_", "A-KIT GT CSV (`datasets::parse_gt`)"),
        ("dvl_loader_", "A-KIT DVL CSV (`datasets::parse_dvl`)"),
        (
            "beams_parser_",
            "`estim dvl solve` beam CSV (`datasets::parse_beams`)",
        ),
        (
            "config_parser_",
            "TOML configuration (`Config::from_toml` of the study, with its `[faults]` section)",
        ),
        (
            "faults_parser_",
            "Fault configuration (`FaultConfig::from_toml` of the study)",
        ),
    ];
    for (rank, (prefix, parser)) in parsers.iter().enumerate() {
        if let Some(rest) = test.strip_prefix(prefix) {
            let property = match rest {
                "survives_arbitrary_bytes" => "arbitrary bytes".to_string(),
                "survives_mutations" => "mutations of a valid file".to_string(),
                other => format!("`{other}`"),
            };
            return (rank, parser.to_string(), property);
        }
    }
    (parsers.len(), format!("`{test}`"), String::new())
}

fn fuzz_table(logs: &[Log]) -> Result<Table> {
    let mut rows = Vec::new();
    for log in logs {
        let cases = after(&log.command, "ESTIM_FUZZ_CASES=", " ")
            .and_then(|c| c.parse::<usize>().ok())
            .ok_or_else(|| log.error(Some(1), "no ESTIM_FUZZ_CASES=N"))?;
        let (passed, time) = test_outcome(log)?;
        for line in &log.lines {
            let Some(rest) = line.strip_prefix("test ") else {
                continue;
            };
            let Some((name, status)) = rest.split_once(" ... ") else {
                continue;
            };
            let (rank, parser, property) = fuzz_property(name);
            let result = if status == "ok" {
                "0".to_string()
            } else {
                format!("failed ({status})")
            };
            rows.push((
                rank,
                name.to_string(),
                parser,
                property,
                cases,
                result,
                time.clone(),
                log,
            ));
        }
        if !passed
            && !log
                .lines
                .iter()
                .any(|l| l.starts_with("test ") && l.contains(" ... "))
        {
            return Err(log.error(None, "failed without a test line"));
        }
    }
    rows.sort_by(|a, b| (a.0, &a.1).cmp(&(b.0, &b.1)));
    let mut s = String::from(
        "| Parser | Property | Cases | Panics | Time | Log (commit) |\n|---|---|---|---|---|---|\n",
    );
    for (_, _, parser, property, cases, result, time, log) in rows {
        s.push_str(&format!(
            "| {parser} | {property} | {} | {result} | {time} | [{}](../results/{}) (`{}`) |\n",
            thousands(cases),
            log.file,
            log.file,
            &log.commit[..10],
        ));
    }
    Ok(Table {
        name: "fuzz",
        markdown: s,
    })
}

/// docs/results.md wording of a cross-covariance model named in `estim-cli/src/study/tests/long_mission.rs`.
fn long_mission_model(name: &str) -> String {
    match name {
        "Zero" => "`Zero` (M neglected)".into(),
        "Fixed(valid M)" => {
            "`Fixed(M)`, a valid M (half the largest valid scaled correlation)".into()
        }
        "ScaledCorrelation{0.42}" => "`ScaledCorrelation { rho: 0.42 }` (the paper)".into(),
        "SquareRoot Fixed(valid M)" => {
            "the same valid `Fixed(M)`, square-root form (Cholesky factor held; estim-cli/src/study/tests/square_root_ins.rs; run time includes the covariance-form filter run beside it)".into()
        }
        other => format!("`{other}`"),
    }
}

fn long_mission_table(logs: &[Log]) -> Result<Table> {
    let mut s = String::from(
        "| Mission | Cross-covariance | Checks | Cholesky failures | Non-finite | Max asymmetry | Smallest eigenvalue of P | Of its correlation matrix | Joint covariance validity margin (valid: smallest LDL' pivot of its correlation matrix; invalid: its smallest eigenvalue) | Run time | Final position error |\n\
         |---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let mut notes = Vec::new();
    for log in logs {
        // `lines` starts after the log's first line, and lines count from 1.
        let bad = |line: usize, what: &str| log.error(Some(line as u64 + 2), what);
        let mut mission = None;
        let (passed, total) = test_outcome(log)?;
        let mut i = 0;
        while i < log.lines.len() {
            let line = &log.lines[i];
            if let Some((hours, _)) = line.split_once(" h mission: ") {
                let generated = after(line, "generated in ", " s")
                    .ok_or_else(|| bad(i, "no \"generated in\" time"))?;
                mission = Some(format!("{hours} h"));
                notes.push(format!(
                    "[{}](../results/{}): {hours} h mission generated in {generated} s, commit `{}`, test {}, {total} in all",
                    log.file,
                    log.file,
                    &log.commit[..10],
                    if passed { "passed" } else { "FAILED" },
                ));
            } else if let Some((name, rest)) = line
                .split_once(" run ")
                .filter(|(_, rest)| rest.contains(" checks, Cholesky failures "))
            {
                let name = name.trim();
                let field = |key: &str, end: &str| {
                    after(rest, key, end)
                        .map(str::trim)
                        .ok_or_else(|| bad(i, &format!("no {key:?}")))
                };
                let run_time = field("", " s;")?;
                let checks = field("; ", " checks")?;
                let cholesky = field("Cholesky failures ", ",")?;
                let non_finite = field("non-finite ", ",")?;
                let asymmetry = field("max asymmetry ", ",")?;
                let min_p = field("min eigenvalue of P ", ",")?;
                let min_corr = field("of its correlation matrix ", "")?;
                let next = log.lines.get(i + 1).map(String::as_str).unwrap_or_default();
                let (joint, final_error) = if next.contains("stopped by a typed error") {
                    ("n/a".to_string(), "stopped (typed error)".to_string())
                } else {
                    let joint = after(next, "joint covariance min eigenvalue ", ";")
                        .ok_or_else(|| bad(i + 1, "no joint covariance eigenvalue"))?;
                    let error = after(next, "final position error ", " m")
                        .ok_or_else(|| bad(i + 1, "no final position error"))?;
                    (joint.trim().to_string(), format!("{} m", error.trim()))
                };
                let checks_n: usize = checks
                    .parse()
                    .map_err(|_| bad(i, "checks is not a count"))?;
                let cholesky_n: usize = cholesky
                    .parse()
                    .map_err(|_| bad(i, "Cholesky failures is not a count"))?;
                let cholesky_cell = if cholesky_n > 0 && checks_n > 0 {
                    format!(
                        "{} ({:.0} %)",
                        thousands(cholesky_n),
                        100.0 * cholesky_n as f64 / checks_n as f64
                    )
                } else {
                    thousands(cholesky_n)
                };
                s.push_str(&format!(
                    "| {} | {} | {} | {cholesky_cell} | {non_finite} | {asymmetry} | {min_p} | {min_corr} | {joint} | {run_time} s | {final_error} |\n",
                    mission.as_deref().ok_or_else(|| bad(i, "model line before the mission line"))?,
                    long_mission_model(name),
                    thousands(checks_n),
                ));
            }
            i += 1;
        }
    }
    s.push('\n');
    for note in notes {
        s.push_str(&format!("- {note}\n"));
    }
    Ok(Table {
        name: "long-mission",
        markdown: s,
    })
}

/// The `fuzz` and `long-mission` tables from the logs in `results`:
/// `fuzz_parsers-*.log` (one per property) and `long_mission-*.log`.
///
/// # Errors
/// A missing folder, a log that cannot be read or parsed (file and line named).
pub fn long_run_tables(results: &Path) -> Result<Vec<Table>> {
    let io = |source| PipelineError::Io {
        path: results.to_path_buf(),
        source,
    };
    let entries = std::fs::read_dir(results).map_err(io)?;
    let mut names = Vec::new();
    for entry in entries {
        let entry = entry.map_err(io)?;
        names.push(entry.file_name().to_string_lossy().into_owned());
    }
    names.sort();
    let logs = |prefix: &str| -> Result<Vec<Log>> {
        names
            .iter()
            .filter(|n| n.starts_with(prefix) && n.ends_with(".log"))
            .map(|n| read_log(&results.join(n)))
            .collect()
    };
    let fuzz = logs("fuzz_parsers-")?;
    let long = logs("long_mission-")?;
    if fuzz.is_empty() || long.is_empty() {
        return Err(PipelineError::Data {
            path: results.to_path_buf(),
            line: None,
            reason: "expected fuzz_parsers-*.log and long_mission-*.log".into(),
        });
    }
    Ok(vec![fuzz_table(&fuzz)?, long_mission_table(&long)?])
}
