//! `estim montecarlo merge`: shards over disjoint seeds into one report.
//!
//! A shard is the `--json` document of `estim montecarlo` (or of an earlier merge):
//! its `sufficient_statistics` (counts, exact sums, per-run figures) add up, and every
//! statistic is recomputed from the union, so the merged report equals one run over
//! all the seeds.

use std::path::{Path, PathBuf};

use serde_json::Value;

use crate::output::emit;
use crate::schema::{document, status_result, SCHEMA_VERSION};
use crate::study::{MergeError, MonteCarloReport, MonteCarloSums};

/// Arguments of `estim montecarlo merge`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Shard files: `estim montecarlo --json` outputs (or merges) over disjoint seed
    /// ranges with the same configuration.
    #[arg(required = true, value_name = "SHARD.json")]
    files: Vec<PathBuf>,
    /// JSON on stdout (itself a shard: merges can be merged again).
    #[arg(long)]
    json: bool,
}

/// Why shards were refused; each names its file(s) (exit status 2).
#[derive(Debug, thiserror::Error)]
pub enum ShardError {
    /// The file could not be read.
    #[error("{path}: cannot read: {reason}")]
    Read {
        /// The file.
        path: String,
        /// What failed.
        reason: String,
    },
    /// Not JSON, or a key is missing or of the wrong type.
    #[error("{path}:{line}:{column}: {message}")]
    Malformed {
        /// The file.
        path: String,
        /// Line (1-based) where the parser stopped.
        line: usize,
        /// Column (1-based).
        column: usize,
        /// What was wrong there.
        message: String,
    },
    /// A key holds a value a shard cannot have.
    #[error("{path}: key `{key}`: {message}")]
    Key {
        /// The file.
        path: String,
        /// The key (dotted path).
        key: String,
        /// What is wrong with it.
        message: String,
    },
    /// Two shards cannot be merged (overlapping seeds, different variants).
    #[error("{first} and {second}: {reason}")]
    Merge {
        /// One file.
        first: String,
        /// The other.
        second: String,
        /// Why.
        reason: MergeError,
    },
    /// Two shards ran different configurations.
    #[error(
        "{first} and {second}: different configurations: `{key}` is {first_value} in the \
         first and {second_value} in the second"
    )]
    Config {
        /// One file.
        first: String,
        /// The other.
        second: String,
        /// The first key (dotted path) that differs.
        key: String,
        /// Its value in `first`.
        first_value: String,
        /// Its value in `second`.
        second_value: String,
    },
}

/// One shard read from its file.
struct Shard {
    path: String,
    /// `inputs.config`: the whole configuration in effect.
    config: Value,
    estim_version: Value,
    sums: MonteCarloSums,
}

/// The part of a shard document that is read as typed data (errors carry a line).
#[derive(serde::Deserialize)]
struct ShardDocument {
    sufficient_statistics: MonteCarloSums,
}

fn display(path: &Path) -> String {
    path.display().to_string()
}

/// Read and check one shard.
fn read_shard(path: &Path) -> Result<Shard, ShardError> {
    let name = display(path);
    let bytes = std::fs::File::open(path)
        .map_err(|e| e.to_string())
        .and_then(|f| estim::datasets::read_input(f, path).map_err(|e| e.to_string()))
        .map_err(|reason| ShardError::Read {
            path: name.clone(),
            reason,
        })?;
    let text = String::from_utf8(bytes).map_err(|e| ShardError::Read {
        path: name.clone(),
        reason: format!("not UTF-8 text: {e}"),
    })?;
    let malformed = |e: serde_json::Error, context: &str| {
        // The position is in the error's own fields; keep the message without it.
        let text = e.to_string();
        let suffix = format!(" at line {} column {}", e.line(), e.column());
        ShardError::Malformed {
            path: name.clone(),
            line: e.line(),
            column: e.column(),
            message: format!("{context}{}", text.strip_suffix(&suffix).unwrap_or(&text)),
        }
    };
    let doc: Value = serde_json::from_str(&text).map_err(|e| malformed(e, "not JSON: "))?;
    let key = |key: &str, message: String| ShardError::Key {
        path: name.clone(),
        key: key.to_string(),
        message,
    };
    if doc["command"] != "montecarlo" {
        return Err(key(
            "command",
            format!("{} is not \"montecarlo\"", doc["command"]),
        ));
    }
    if doc["schema_version"] != SCHEMA_VERSION {
        return Err(key(
            "schema_version",
            format!("{} is not {SCHEMA_VERSION}", doc["schema_version"]),
        ));
    }
    if doc["inputs"].get("learned").is_some() {
        return Err(key(
            "inputs.learned",
            "a `montecarlo --learned` document carries no sufficient statistics; only \
             the standard Monte Carlo merges"
                .into(),
        ));
    }
    let config = doc["inputs"]
        .get("config")
        .filter(|c| c.is_object())
        .cloned()
        .ok_or_else(|| key("inputs.config", "missing or not an object".into()))?;
    let typed: ShardDocument =
        serde_json::from_str(&text).map_err(|e| malformed(e, "key `sufficient_statistics`: "))?;
    typed
        .sufficient_statistics
        .check()
        .map_err(|e| key("sufficient_statistics", e.to_string()))?;
    check_against_inputs(&doc, &typed.sufficient_statistics).map_err(|(k, m)| key(k, m))?;
    Ok(Shard {
        path: name,
        config,
        estim_version: doc["estim_version"].clone(),
        sums: typed.sufficient_statistics,
    })
}

/// A shard's statistics must be those its own document announces: the seeds of
/// `inputs.seed_ranges` (a merge), else of `inputs.first_seed` and `inputs.runs`,
/// and `status` "ok" only without a filter failure. A shard edited by hand, or two
/// documents spliced, is refused naming the key rather than merged.
fn check_against_inputs(
    doc: &Value,
    sums: &crate::study::MonteCarloSums,
) -> Result<(), (&'static str, String)> {
    let inputs = &doc["inputs"];
    // A merged document announces its seed ranges; a run, its first seed and count.
    let announced: Option<Vec<[u64; 2]>> = match (
        serde_json::from_value::<Vec<[u64; 2]>>(inputs["seed_ranges"].clone()),
        inputs["first_seed"].as_u64(),
        inputs["runs"].as_u64(),
    ) {
        (Ok(ranges), _, _) => Some(ranges),
        (Err(_), Some(first), Some(runs)) => Some(vec![[first, first.saturating_add(runs)]]),
        _ => None,
    };
    if let Some(expected) = announced.filter(|a| *a != sums.seed_ranges) {
        return Err((
            "inputs.runs",
            format!(
                "the document announces the seeds {expected:?}, its sufficient statistics \
                 hold {:?}",
                sums.seed_ranges
            ),
        ));
    }
    let failures: usize = sums.variants.iter().map(|v| v.failures.len()).sum();
    if doc["status"] == "ok" && failures > 0 {
        return Err((
            "status",
            format!("\"ok\" with {failures} filter failures in the sufficient statistics"),
        ));
    }
    Ok(())
}

/// The first key (dotted path) at which `a` and `b` differ, with both values.
fn first_difference(a: &Value, b: &Value, at: &str) -> Option<(String, String, String)> {
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
            keys.sort();
            keys.dedup();
            keys.into_iter().find_map(|k| {
                let here = if at.is_empty() {
                    k.clone()
                } else {
                    format!("{at}.{k}")
                };
                match (x.get(k), y.get(k)) {
                    (Some(p), Some(q)) => first_difference(p, q, &here),
                    (p, q) => Some((
                        here,
                        p.map_or("absent".into(), Value::to_string),
                        q.map_or("absent".into(), Value::to_string),
                    )),
                }
            })
        }
        _ if a == b => None,
        _ => Some((at.to_string(), a.to_string(), b.to_string())),
    }
}

/// Merge the shards of `paths` (in any order) into one report; errors name the files.
pub fn merge_files(paths: &[PathBuf]) -> Result<(MonteCarloReport, Value), ShardError> {
    let shards: Vec<Shard> = paths
        .iter()
        .map(|p| read_shard(p))
        .collect::<Result<_, _>>()?;
    let Some((first, rest)) = shards.split_first() else {
        return Err(ShardError::Read {
            path: "(none)".into(),
            reason: "no shard file given".into(),
        });
    };
    for (i, a) in shards.iter().enumerate() {
        for b in &shards[i + 1..] {
            let version = first_difference(&a.estim_version, &b.estim_version, "estim_version");
            if let Some((key, first_value, second_value)) =
                version.or_else(|| first_difference(&a.config, &b.config, "config"))
            {
                return Err(ShardError::Config {
                    first: a.path.clone(),
                    second: b.path.clone(),
                    key,
                    first_value,
                    second_value,
                });
            }
            for ra in &a.sums.seed_ranges {
                for rb in &b.sums.seed_ranges {
                    if ra[0] < rb[1] && rb[0] < ra[1] {
                        return Err(ShardError::Merge {
                            first: a.path.clone(),
                            second: b.path.clone(),
                            reason: MergeError::Overlap(*ra, *rb),
                        });
                    }
                }
            }
        }
    }
    let mut sums = first.sums.clone();
    for s in rest {
        sums.merge(&s.sums).map_err(|reason| ShardError::Merge {
            first: first.path.clone(),
            second: s.path.clone(),
            reason,
        })?;
    }
    let report = MonteCarloReport::from_sums(sums).map_err(|e| ShardError::Key {
        path: first.path.clone(),
        key: "sufficient_statistics".into(),
        message: e.to_string(),
    })?;
    Ok((report, first.config.clone()))
}

/// Run it: the merged report as `estim montecarlo` prints it (exit 3 when a filter
/// variant failed in some run of some shard).
pub fn run(args: Args) -> anyhow::Result<()> {
    let (report, config) = merge_files(&args.files)?;
    let failures = report.failures().count();
    if args.json {
        let inputs = serde_json::json!({
            "shards": args.files.iter().map(|p| p.to_string_lossy()).collect::<Vec<_>>(),
            "runs": report.runs,
            "first_seed": report.first_seed,
            "seed_ranges": report.seed_ranges,
            "config": config,
        });
        let doc = document(
            "montecarlo",
            inputs,
            failures,
            serde_json::to_value(&report)?,
        );
        emit(&format!("{}\n", serde_json::to_string_pretty(&doc)?))?;
    } else {
        emit(&super::text_report(&report)?)?;
    }
    status_result(failures)
}
