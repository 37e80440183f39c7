//! The result tables of docs/results.md, regenerated from seeded runs (`estim report --markdown`).
//!
//! Each table is a named region of docs/results.md between two HTML comments,
//! `<!-- estim-report:NAME begin -->` and `<!-- estim-report:NAME end -->`;
//! [`splice`] replaces exactly those regions and [`region`] reads one back, so a test
//! can compare docs/results.md with a fresh run byte for byte.
//!
//! Sources:
//! - [`results_tables`]: `velocity`, `filters`, `paper-std`, `rho`: the default
//!   configuration on A-KIT trajectories 4 and 13 and the embedded simulated mission
//!   (what `estim reproduce` runs), the paper's heuristic M on both bases
//!   ([`PaperMBasis`]). Needs the A-KIT data.
//! - [`seed_interval_tables`]: `filters-seeds`, `velocity-seeds`, `paper-std-seeds`,
//!   `rho-seeds`: the rows of `filters`, `velocity`, `paper-std` and `rho` over
//!   [`SEED_INTERVAL_SEEDS`] seeds from [`SEED_INTERVAL_FIRST_SEED`] (IMU synthesis,
//!   initial error and beam noise redrawn per seed): mean and 95 % interval (2.5 / 97.5
//!   percentiles, linear interpolation). Needs the A-KIT data.
//! - [`learned_seed_tables`]: `two-beams-seeds`, `outage-seeds`: the A-KIT rows of
//!   `estim reproduce --scenario two-beams|outage` over the same seeds. Needs the A-KIT
//!   data.
//! - [`monte_carlo_table`]: `montecarlo`, [`MONTE_CARLO_RUNS`] simulated missions from
//!   seed [`MONTE_CARLO_FIRST_SEED`] (what `estim montecarlo --runs 20` runs).
//! - [`long_run_tables`]: `fuzz` and `long-mission`, rendered from the committed logs
//!   of the long runs in `results/` (those runs take minutes; their logs carry the
//!   commit they ran on).
//!
//! Rounding (stated once, used everywhere): velocity metrics with 6 decimals (VAF 4;
//! in the seed table RMSE and MAE in mm/s with 3 decimals, the same digits);
//! position errors 2 decimals \[m\], velocity errors 3 decimals \[m/s\]; NEES and NIS
//! averages of filters with 3 significant digits, of the Monte Carlo with 2 decimals;
//! percentages with 1 decimal; rho with 3 decimals; counts exact (their mean over seeds
//! with 1 decimal); learned-scenario tables: NEES and NIS 2 decimals, position error 3,
//! velocity error 4. Log figures are
//! quoted as the log prints them.

use std::path::Path;

mod recorded;
mod seeds;

pub use recorded::recorded_tables;
pub use seeds::{learned_seed_tables, seed_interval_tables};

use super::report::{BEAMSNET, BEAMSNET_NEGLECTED, BEAMSNET_SCALED, BEAMSNET_SENSITIVITY, LS};
use super::{
    analyse, apply_faults, monte_carlo, Config, FilterSummary, Improvement, LearnedInputs,
    LearnedSource, PaperMBasis, PipelineError, Result, Scenario, TrajectoryReport,
    ORACLE_NEGLECTED, ORACLE_SCALED, ORACLE_TRUE_M,
};

/// Missions of the Monte Carlo table.
pub const MONTE_CARLO_RUNS: usize = 20;
/// Seed of its first mission (missions use seeds 1000..1019).
pub const MONTE_CARLO_FIRST_SEED: u64 = 1000;
/// Seeds of the `filters-seeds` table.
pub const SEED_INTERVAL_SEEDS: usize = 20;
/// Its first seed (seeds 2000..2019).
pub const SEED_INTERVAL_FIRST_SEED: u64 = 2000;
/// A-KIT trajectories of the results (the paper's "Trajectory #1" and "#2").
pub const AKIT_TRAJECTORIES: [u32; 2] = [4, 13];

/// One generated region of docs/results.md.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Table {
    /// Region name (`<!-- estim-report:NAME begin -->`).
    pub name: &'static str,
    /// The markdown between the markers, ending with a newline.
    pub markdown: String,
}

/// The begin marker of region `name`.
pub fn begin_marker(name: &str) -> String {
    format!("<!-- estim-report:{name} begin -->")
}

/// The end marker of region `name`.
pub fn end_marker(name: &str) -> String {
    format!("<!-- estim-report:{name} end -->")
}

impl Table {
    /// The region with its markers, as `estim report --markdown` prints it.
    pub fn with_markers(&self) -> String {
        format!(
            "{}\n{}{}\n",
            begin_marker(self.name),
            self.markdown,
            end_marker(self.name)
        )
    }
}

/// Byte range of the content of region `name` in `text` (between the line of the
/// begin marker and the line of the end marker). Errors when a marker is missing,
/// repeated, or out of order.
fn region_range(text: &str, name: &str) -> Result<std::ops::Range<usize>> {
    let find_line = |marker: &str| -> Result<usize> {
        // A marker is a whole line: text that merely quotes it does not count.
        let line = format!("{marker}\n");
        let mut hits = text
            .match_indices(&line)
            .map(|(i, _)| i)
            .filter(|i| *i == 0 || text.as_bytes()[i - 1] == b'\n');
        let first = hits
            .next()
            .ok_or_else(|| PipelineError::Invalid(format!("marker line {marker:?} not found")))?;
        if hits.next().is_some() {
            return Err(PipelineError::Invalid(format!(
                "marker line {marker:?} appears more than once"
            )));
        }
        Ok(first)
    };
    let begin = find_line(&begin_marker(name))?;
    let end = find_line(&end_marker(name))?;
    let start = begin + begin_marker(name).len() + 1;
    if end < start {
        return Err(PipelineError::Invalid(format!(
            "region {name:?}: end marker before begin marker"
        )));
    }
    Ok(start..end)
}

/// The content of region `name` in `text` (the study's tests compare regions).
///
/// # Errors
/// A missing, repeated or misordered marker.
#[cfg(test)]
pub fn region<'a>(text: &'a str, name: &str) -> Result<&'a str> {
    Ok(&text[region_range(text, name)?])
}

/// `text` with each table's region replaced by its markdown; nothing else changes.
///
/// # Errors
/// A missing, repeated or misordered marker of any table (then nothing is replaced).
pub fn splice(text: &str, tables: &[Table]) -> Result<String> {
    let mut ranges = tables
        .iter()
        .map(|t| Ok((region_range(text, t.name)?, t)))
        .collect::<Result<Vec<_>>>()?;
    ranges.sort_by_key(|(r, _)| r.start);
    let mut out = String::with_capacity(text.len());
    let mut at = 0;
    for (range, table) in ranges {
        if range.start < at {
            return Err(PipelineError::Invalid(format!(
                "region {:?} overlaps another region",
                table.name
            )));
        }
        out.push_str(&text[at..range.start]);
        out.push_str(&table.markdown);
        at = range.end;
    }
    out.push_str(&text[at..]);
    Ok(out)
}

/// `x` with `digits` significant digits, in positional notation ("n/a" if not finite).
pub fn significant(x: f64, digits: usize) -> String {
    if !x.is_finite() {
        return "n/a".into();
    }
    if x == 0.0 {
        return format!("{:.*}", digits.saturating_sub(1), 0.0);
    }
    let magnitude = x.abs().log10().floor() as i64;
    let decimals = (digits as i64 - 1 - magnitude).max(0) as usize;
    // Rounding can carry into the next decade (9.995 -> 10.0): format again.
    let text = format!("{x:.decimals$}");
    let rounded: f64 = text.parse().unwrap_or(x);
    let magnitude_after = rounded.abs().log10().floor() as i64;
    if magnitude_after > magnitude {
        let decimals = (digits as i64 - 1 - magnitude_after).max(0) as usize;
        format!("{rounded:.decimals$}")
    } else {
        text
    }
}

/// `x` with one decimal, without the sign of a value that rounds to zero ("-0.0").
pub fn one_decimal(x: f64) -> String {
    let text = format!("{x:.1}");
    if text == "-0.0" {
        "0.0".into()
    } else {
        text
    }
}

/// `n` with thousands separators (7,703).
pub fn thousands(n: usize) -> String {
    let digits = n.to_string();
    let mut out = String::with_capacity(digits.len() + digits.len() / 3);
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// The committed BeamsNet models as the pipeline's learned sensor, with M from the
/// network's sensitivity, per IMU source ([`crate::study::committed_beamsnet`]: what
/// `estim reproduce` and `estim montecarlo` use).
pub fn default_beamsnet(config: &Config) -> Result<Box<LearnedSource>> {
    crate::study::committed_beamsnet(config)
}

/// One data set of the results tables: the report on the configured basis and the
/// report with the paper's M on the other basis.
struct DataSet {
    label: String,
    accumulated: TrajectoryReport,
    per_step: TrajectoryReport,
}

fn with_basis(config: &Config, basis: PaperMBasis) -> Config {
    let mut c = config.clone();
    c.filter.paper_m_basis = basis;
    c
}

fn data_set(
    label: String,
    scenario: &mut Scenario,
    config: &Config,
    learned: &LearnedSource,
) -> Result<DataSet> {
    apply_faults(scenario, &config.faults, config.seed)?;
    let inputs: LearnedInputs = learned(scenario)?;
    let accumulated = analyse(
        scenario,
        &with_basis(config, PaperMBasis::Accumulated),
        Some(&inputs),
        config.seed,
    )?;
    let per_step = analyse(
        scenario,
        &with_basis(config, PaperMBasis::PerStep),
        Some(&inputs),
        config.seed,
    )?;
    Ok(DataSet {
        label,
        accumulated,
        per_step,
    })
}

fn filter<'a>(report: &'a TrajectoryReport, name: &str) -> Result<&'a FilterSummary> {
    report
        .filters
        .iter()
        .find(|f| f.id == name)
        .ok_or_else(|| PipelineError::Invalid(format!("{}: no filter {name:?}", report.name)))
}

/// The `velocity`, `filters`, `paper-std` and `rho` tables: `config` on A-KIT
/// trajectories 4 and 13 under `data` and on the simulated mission, with `learned`.
///
/// # Errors
/// Missing or bad data files; the pipeline's errors.
pub fn results_tables(config: &Config, data: &Path, learned: &LearnedSource) -> Result<Vec<Table>> {
    let mut sets = Vec::new();
    for n in AKIT_TRAJECTORIES {
        let mut scenario = Scenario::akit(data, n, config, config.seed)?;
        sets.push(data_set(
            format!("A-KIT {n}"),
            &mut scenario,
            config,
            learned,
        )?);
    }
    let mut simulated = Scenario::simulated(config, config.seed)?;
    sets.push(data_set(
        "simulated".into(),
        &mut simulated,
        config,
        learned,
    )?);
    Ok(vec![
        velocity_table(&sets)?,
        filters_table(&sets, config.filter.rho)?,
        paper_std_table(&sets, config.filter.rho)?,
        rho_table(&sets, config.filter.rho)?,
    ])
}

/// The rows of the `velocity` table of one data set: LS, then BeamsNet if present, each
/// with [RMSE, MAE, R^2, VAF, RMSE change against LS in %] (NaN for LS itself).
fn velocity_rows(set: &DataSet) -> Result<Vec<(&'static str, [f64; 5])>> {
    let v = &set.accumulated.velocity;
    let ls = v.get(LS).ok_or_else(|| {
        PipelineError::Invalid(format!("{}: no least-squares velocity", set.label))
    })?;
    let mut rows = Vec::new();
    for (method, m) in [("LS", Some(ls)), ("BeamsNet", v.get(BEAMSNET))] {
        let Some(m) = m else { continue };
        let versus = if method == "LS" {
            f64::NAN
        } else {
            100.0 * (m.rmse - ls.rmse) / ls.rmse
        };
        rows.push((method, [m.rmse, m.mae, m.r2, m.vaf, versus]));
    }
    Ok(rows)
}

fn velocity_table(sets: &[DataSet]) -> Result<Table> {
    let mut s = String::from(
        "| data | method | RMSE [m/s] | MAE [m/s] | R^2 | VAF [%] | RMSE vs LS |\n\
         |---|---|---|---|---|---|---|\n",
    );
    for set in sets {
        for (method, [rmse, mae, r2, vaf, versus]) in velocity_rows(set)? {
            let versus = if versus.is_finite() {
                format!("{} %", one_decimal(versus))
            } else {
                String::new()
            };
            s.push_str(&format!(
                "| {} | {method} | {rmse:.6} | {mae:.6} | {r2:.6} | {vaf:.4} | {versus} |\n",
                set.label
            ));
        }
    }
    Ok(Table {
        name: "velocity",
        markdown: s,
    })
}

/// The rows of the `filters` table (label, filter id, on the per-step basis).
fn filter_rows(rho: f64) -> [(String, &'static str, bool); 5] {
    [
        ("LS".to_string(), LS, false),
        (
            "BeamsNet, M neglected".to_string(),
            BEAMSNET_NEGLECTED,
            false,
        ),
        (
            format!("BeamsNet, M = rho {rho} (Q accumulated over the interval)"),
            BEAMSNET_SCALED,
            false,
        ),
        (
            format!("BeamsNet, M = rho {rho} (per-step Q_k)"),
            BEAMSNET_SCALED,
            true,
        ),
        (
            "BeamsNet, M from network".to_string(),
            BEAMSNET_SENSITIVITY,
            false,
        ),
    ]
}

fn filters_table(sets: &[DataSet], rho: f64) -> Result<Table> {
    let mut s = String::from(
        "| data | filter | position [m] | velocity [m/s] | NEES (15) | NEES 95 % band | P not PD [epochs] | updates gated |\n\
         |---|---|---|---|---|---|---|---|\n",
    );
    for set in sets {
        let rows = [
            ("LS".to_string(), filter(&set.accumulated, LS)?),
            (
                "BeamsNet, M neglected".to_string(),
                filter(&set.accumulated, BEAMSNET_NEGLECTED)?,
            ),
            (
                format!("BeamsNet, M = rho {rho} (Q accumulated over the interval)"),
                filter(&set.accumulated, BEAMSNET_SCALED)?,
            ),
            (
                format!("BeamsNet, M = rho {rho} (per-step Q_k)"),
                filter(&set.per_step, BEAMSNET_SCALED)?,
            ),
            (
                "BeamsNet, M from network".to_string(),
                filter(&set.accumulated, BEAMSNET_SENSITIVITY)?,
            ),
        ];
        for (name, f) in rows {
            s.push_str(&format!(
                "| {} | {name} | {:.2} / {:.2} | {:.3} / {:.3} | {} | {:.1}-{:.1} | {} | {} / {} |\n",
                set.label,
                f.position_error_m.rmse,
                f.position_error_m.final_value,
                f.velocity_error_mps.rmse,
                f.velocity_error_mps.final_value,
                significant(f.nees_average, 3),
                f.nees_band[0],
                f.nees_band[1],
                thousands(f.covariance_not_positive_definite_epochs),
                f.updates_rejected,
                f.updates_accepted + f.updates_rejected,
            ));
        }
    }
    Ok(Table {
        name: "filters",
        markdown: s,
    })
}

/// Whether a time-averaged improvement meets the paper's "more than 10 %".
fn meets_paper(percent: f64) -> bool {
    percent > 10.0
}

/// The rows of the `paper-std` table of one data set: (M label, its improvement over
/// M neglected).
fn paper_rows(set: &DataSet, rho: f64) -> Result<Vec<(String, Improvement)>> {
    let find = |report: &TrajectoryReport, variant: &str| {
        report
            .improvements
            .iter()
            .find(|i| i.id == variant)
            .cloned()
            .ok_or_else(|| {
                PipelineError::Invalid(format!("{}: no improvement of {variant}", set.label))
            })
    };
    Ok(vec![
        (
            format!("rho {rho}, Q accumulated over the interval"),
            find(&set.accumulated, BEAMSNET_SCALED)?,
        ),
        (
            format!("rho {rho}, per-step Q_k"),
            find(&set.per_step, BEAMSNET_SCALED)?,
        ),
        (
            "from the network's sensitivity".to_string(),
            find(&set.accumulated, BEAMSNET_SENSITIVITY)?,
        ),
    ])
}

/// Improvement of `group` (time average, final) in %.
fn group_improvement(set: &DataSet, imp: &Improvement, group: &str) -> Result<[f64; 2]> {
    let v = imp
        .groups
        .get(group)
        .ok_or_else(|| PipelineError::Invalid(format!("{}: no group {group}", set.label)))?;
    Ok([v.time_average_percent, v.final_percent])
}

/// Whether `imp` meets the paper's claim: > 10 % on the time-averaged velocity and
/// misalignment std.
fn meets_paper_claim(imp: &Improvement) -> bool {
    ["velocity", "misalignment"].iter().all(|g| {
        imp.groups
            .get(*g)
            .is_some_and(|v| meets_paper(v.time_average_percent))
    })
}

fn paper_std_table(sets: &[DataSet], rho: f64) -> Result<Table> {
    let mut s = String::from(
        "| data | M | velocity | misalignment | acc bias | gyro bias | > 10 % on velocity and misalignment |\n\
         |---|---|---|---|---|---|---|\n",
    );
    for set in sets {
        for (name, imp) in paper_rows(set, rho)? {
            let cell = |group: &str| -> Result<String> {
                let [average, last] = group_improvement(set, &imp, group)?;
                Ok(format!(
                    "{} % / {} %",
                    one_decimal(average),
                    one_decimal(last)
                ))
            };
            s.push_str(&format!(
                "| {} | {name} | {} | {} | {} | {} | {} |\n",
                set.label,
                cell("velocity")?,
                cell("misalignment")?,
                cell("acc_bias")?,
                cell("gyro_bias")?,
                if meets_paper_claim(&imp) { "yes" } else { "no" },
            ));
        }
    }
    Ok(Table {
        name: "paper-std",
        markdown: s,
    })
}

/// Median, smallest and largest of the finite values (NaN if none).
pub fn median_min_max(values: &[f64]) -> [f64; 3] {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return [f64::NAN; 3];
    }
    v.sort_by(f64::total_cmp);
    [v[v.len() / 2], v[0], v[v.len() - 1]]
}

/// The run the `rho` table reads: BeamsNet with M neglected (R enters the largest
/// valid rho only through its correlations).
fn rho_run(set: &DataSet) -> Result<&super::FilterRun> {
    set.accumulated
        .runs
        .iter()
        .find(|r| r.id == BEAMSNET_NEGLECTED)
        .ok_or_else(|| {
            PipelineError::Invalid(format!("{}: no run {BEAMSNET_NEGLECTED:?}", set.label))
        })
}

fn rho_table(sets: &[DataSet], rho: f64) -> Result<Table> {
    let mut s = format!(
        "| data | updates | largest valid rho, M from Q accumulated: median / min / max | from per-step Q_k: median / min / max | rho = {rho} valid at (accumulated / per-step) |\n\
         |---|---|---|---|---|\n"
    );
    for set in sets {
        let run = rho_run(set)?;
        let acc = median_min_max(&run.largest_valid_rho);
        let step = median_min_max(&run.largest_valid_rho_per_step);
        let valid = |v: &[f64]| v.iter().filter(|x| **x >= rho.abs()).count();
        s.push_str(&format!(
            "| {} | {} | {:.3} / {:.3} / {:.3} | {:.3} / {:.3} / {:.3} | {} / {} |\n",
            set.label,
            run.largest_valid_rho.len(),
            acc[0],
            acc[1],
            acc[2],
            step[0],
            step[1],
            step[2],
            valid(&run.largest_valid_rho),
            valid(&run.largest_valid_rho_per_step),
        ));
    }
    Ok(Table {
        name: "rho",
        markdown: s,
    })
}

/// The `montecarlo` table: [`MONTE_CARLO_RUNS`] simulated missions from
/// [`MONTE_CARLO_FIRST_SEED`] with `config`, the oracle sensor and `learned`.
///
/// # Errors
/// The pipeline's errors.
pub fn monte_carlo_table(config: &Config, learned: &LearnedSource) -> Result<Table> {
    let report = monte_carlo(
        config,
        MONTE_CARLO_RUNS,
        MONTE_CARLO_FIRST_SEED,
        Some(learned),
        &|| {},
    )?;
    let rho = config.filter.rho;
    let any = report
        .variants
        .values()
        .next()
        .ok_or_else(|| PipelineError::Invalid("Monte Carlo: no variant".into()))?;
    let mut s = format!(
        "| variant | average NEES (band {:.1}-{:.1}) | epochs in band | NIS (band {:.2}-{:.2}) | P not PD [run-epochs] |\n\
         |---|---|---|---|---|\n",
        any.nees_band[0], any.nees_band[1], any.nis_band[0], any.nis_band[1]
    );
    let rows = [
        (ORACLE_TRUE_M, "oracle, true M".to_string()),
        (ORACLE_NEGLECTED, "oracle, M neglected".to_string()),
        (ORACLE_SCALED, format!("oracle, M = rho {rho}")),
        (BEAMSNET_SENSITIVITY, "BeamsNet, M from network".to_string()),
        (BEAMSNET_NEGLECTED, "BeamsNet, M neglected".to_string()),
        (BEAMSNET_SCALED, format!("BeamsNet, M = rho {rho}")),
        (LS, "LS".to_string()),
    ];
    let total = report.runs * report.epochs;
    for (key, label) in rows {
        let v = report
            .variants
            .get(key)
            .ok_or_else(|| PipelineError::Invalid(format!("Monte Carlo: no variant {key:?}")))?;
        let nees = if v.covariance_not_positive_definite > 0 {
            format!("{:.2} (over the epochs where P stayed PD)", v.nees_average)
        } else {
            format!("{:.2}", v.nees_average)
        };
        s.push_str(&format!(
            "| {label} | {nees} | {:.1} % | {:.2} | {} of {} |\n",
            v.nees_epochs_in_band_percent,
            v.nis_average,
            thousands(v.covariance_not_positive_definite),
            thousands(total),
        ));
    }
    Ok(Table {
        name: "montecarlo",
        markdown: s,
    })
}

/// A long-run log: its first line is `<commit> <command>`, the rest the command's output.
#[derive(Debug, Clone)]
struct Log {
    file: String,
    commit: String,
    command: String,
    lines: Vec<String>,
}

fn read_log(path: &Path) -> Result<Log> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| PipelineError::Invalid(format!("{}: cannot read: {e}", path.display())))?;
    let mut lines = text.lines();
    let first = lines.next().unwrap_or_default();
    let (commit, command) = first.split_once(' ').ok_or_else(|| {
        PipelineError::Invalid(format!(
            "{}:1: expected \"<commit> <command>\"",
            path.display()
        ))
    })?;
    if commit.len() != 40 || !commit.chars().all(|c| c.is_ascii_hexdigit()) {
        return Err(PipelineError::Invalid(format!(
            "{}:1: {commit:?} is not a 40-digit commit hash",
            path.display()
        )));
    }
    let file = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    Ok(Log {
        file,
        commit: commit.to_string(),
        command: command.to_string(),
        lines: lines.map(str::to_string).collect(),
    })
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
        .ok_or_else(|| PipelineError::Invalid(format!("{}: no \"test result:\" line", log.file)))?;
    let passed = line.starts_with("test result: ok.");
    let seconds = after(line, "finished in ", "s")
        .and_then(|s| s.trim().parse::<f64>().ok())
        .ok_or_else(|| PipelineError::Invalid(format!("{}: no \"finished in\" time", log.file)))?;
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
            .ok_or_else(|| {
                PipelineError::Invalid(format!("{}:1: no ESTIM_FUZZ_CASES=N", log.file))
            })?;
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
            return Err(PipelineError::Invalid(format!(
                "{}: failed without a test line",
                log.file
            )));
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
        let bad = |line: usize, what: &str| {
            PipelineError::Invalid(format!("{}:{}: {what}", log.file, line + 2))
        };
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
    let entries = std::fs::read_dir(results)
        .map_err(|e| PipelineError::Invalid(format!("{}: cannot list: {e}", results.display())))?;
    let mut names = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| {
            PipelineError::Invalid(format!("{}: cannot list: {e}", results.display()))
        })?;
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
        return Err(PipelineError::Invalid(format!(
            "{}: expected fuzz_parsers-*.log and long_mission-*.log",
            results.display()
        )));
    }
    Ok(vec![fuzz_table(&fuzz)?, long_mission_table(&long)?])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splice_replaces_only_the_regions() {
        let text = "a\n<!-- estim-report:x begin -->\nold\n<!-- estim-report:x end -->\nb\n\
                    <!-- estim-report:y begin -->\n<!-- estim-report:y end -->\nc";
        let tables = [
            Table {
                name: "y",
                markdown: "Y\n".into(),
            },
            Table {
                name: "x",
                markdown: "X1\nX2\n".into(),
            },
        ];
        let out = splice(text, &tables).expect("markers present");
        assert_eq!(
            out,
            "a\n<!-- estim-report:x begin -->\nX1\nX2\n<!-- estim-report:x end -->\nb\n\
             <!-- estim-report:y begin -->\nY\n<!-- estim-report:y end -->\nc"
        );
        assert_eq!(region(&out, "x").expect("present"), "X1\nX2\n");
        // Splicing the same tables again changes nothing.
        assert_eq!(splice(&out, &tables).expect("present"), out);
    }

    #[test]
    fn splice_refuses_missing_repeated_or_misordered_markers() {
        let t = [Table {
            name: "x",
            markdown: String::new(),
        }];
        assert!(splice("no markers\n", &t).is_err());
        let twice = "<!-- estim-report:x begin -->\n<!-- estim-report:x begin -->\n<!-- estim-report:x end -->\n";
        assert!(splice(twice, &t).is_err());
        let reversed = "<!-- estim-report:x end -->\n<!-- estim-report:x begin -->\n";
        assert!(splice(reversed, &t).is_err());
    }

    #[test]
    fn number_formats() {
        assert_eq!(significant(42.63, 3), "42.6");
        assert_eq!(significant(473.2, 3), "473");
        assert_eq!(significant(12.0, 3), "12.0");
        assert_eq!(significant(9.996, 3), "10.0");
        assert_eq!(significant(0.0123456, 3), "0.0123");
        assert_eq!(significant(f64::NAN, 3), "n/a");
        assert_eq!(one_decimal(-0.04), "0.0");
        assert_eq!(one_decimal(-0.05), "-0.1");
        assert_eq!(thousands(0), "0");
        assert_eq!(thousands(999), "999");
        assert_eq!(thousands(7703), "7,703");
        assert_eq!(thousands(3_636_000), "3,636,000");
        assert_eq!(median_min_max(&[3.0, f64::NAN, 1.0, 2.0]), [2.0, 1.0, 3.0]);
    }

    #[test]
    fn logs_render_and_bad_logs_name_file_and_line() {
        let dir = std::env::temp_dir().join(format!("estim-md-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let hash = "0123456789abcdef0123456789abcdef01234567";
        std::fs::write(
            dir.join("fuzz_parsers-gt_loader_survives_mutations.log"),
            format!(
                "{hash} ESTIM_FUZZ_CASES=1000000 cargo test --release --bin estim study::tests::fuzz_parsers\n\
                 running 1 test\ntest gt_loader_survives_mutations ... ok\n\n\
                 test result: ok. 1 passed; 0 failed; 0 ignored; 0 measured; 11 filtered out; finished in 58.71s\n"
            ),
        )
        .expect("write");
        std::fs::write(
            dir.join("long_mission-10h.log"),
            format!(
                "{hash} cargo test --release --bin estim study::tests::long_mission -- --ignored --nocapture\n\
                 test ten_hour ... ignored, 10-hour mission: about 75 s; run with --ignored\n\
                 10 h mission: 3600001 IMU steps, 36000 DVL epochs, generated in 70.2 s\n\
                 Zero                     run   25.1 s; 3636000 checks, Cholesky failures 0, non-finite 0, max asymmetry 1.1e-14, min eigenvalue of P 4.230e-12, of its correlation matrix 8.000e-3\n\
                 {:<24} updates 36000 accepted / 0 gated; joint covariance min eigenvalue 1.330e-1; final position error 43.5 m\n\
                 test result: ok. 1 passed; 0 failed; 0 ignored; 0 measured; 1 filtered out; finished in 120.00s\n",
                ""
            ),
        )
        .expect("write");
        let tables = long_run_tables(&dir).expect("valid logs");
        assert!(tables[0].markdown.contains(
            "| A-KIT GT CSV (`datasets::parse_gt`) | mutations of a valid file | 1,000,000 | 0 | 59 s |"
        ));
        assert!(tables[1].markdown.contains(
            "| 10 h | `Zero` (M neglected) | 3,636,000 | 0 | 0 | 1.1e-14 | 4.230e-12 | 8.000e-3 | 1.330e-1 | 25.1 s | 43.5 m |"
        ));
        std::fs::write(dir.join("long_mission-1h.log"), "not a hash\n").expect("write");
        let e = long_run_tables(&dir).unwrap_err().to_string();
        assert!(e.contains("long_mission-1h.log:1"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
