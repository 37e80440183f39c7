//! `estim montecarlo`: consistency over seeded simulated missions.

use std::path::PathBuf;

mod merge;

use std::fmt::Write as _;
use std::io::IsTerminal;
use std::sync::atomic::{AtomicUsize, Ordering};

use crate::study::{monte_carlo, Config, MonteCarloReport};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use crate::output::emit;
use crate::schema::{document, path_json, status_result};

/// Arguments of `estim montecarlo`.
#[derive(Debug, clap::Args)]
#[command(args_conflicts_with_subcommands = true)]
pub struct Args {
    /// `merge`: combine shards (the `--json` outputs of runs over disjoint seeds).
    #[command(subcommand)]
    command: Option<Subcommand>,
    /// Number of simulated missions.
    #[arg(long, default_value_t = 50)]
    runs: usize,
    /// Seed of the first mission (missions use seeds S, S+1, ..., S+runs-1); `--seed`
    /// is the same flag.
    #[arg(
        long = "first-seed",
        visible_alias = "seed",
        value_name = "S",
        default_value_t = 1000
    )]
    first_seed: u64,
    /// TOML configuration (see `estim reproduce --print-config`).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// JSON on stdout.
    #[arg(long)]
    json: bool,
    /// Inject the standard fault scenario (beam dropouts and outliers, a 60 s DVL
    /// outage, IMU gaps; see `FaultConfig::standard`) unless the configuration has its
    /// own `[faults]` section.
    #[arg(long)]
    faults: bool,
    /// Learned scenario: `two-beams` (beams 1-2 only for 120 s) or `outage` (no DVL
    /// for 60 s): per-variant nees_average, nees_epochs_in_band_percent, nis_average,
    /// position_rmse_m, velocity_rmse_mps, output_imu_correlation; `beamsnet` is the
    /// standard table.
    #[arg(long, value_enum)]
    learned: Option<crate::learned_scenarios::LearnedKind>,
    /// With --learned two-beams|outage: Monte Carlo draws of the empirical M per
    /// update (0 leaves that variant out).
    #[arg(long, default_value_t = 100)]
    empirical_realizations: usize,
}

/// Subcommands of `estim montecarlo`.
#[derive(Debug, clap::Subcommand)]
enum Subcommand {
    /// Merge Monte Carlo shards (`estim montecarlo --json` outputs over disjoint seed
    /// ranges, same configuration) into the statistics of one run over all their seeds.
    Merge(merge::Args),
}

/// Without a terminal, a progress line at least every this many missions.
const PROGRESS_EVERY: usize = 100;

/// Progress on stderr: a bar when stderr is a terminal, otherwise one plain line per
/// tenth of the missions and per 100 missions (logs and CI keep a readable trace; stdout stays clean).
struct Progress {
    bar: Option<ProgressBar>,
    total: usize,
    done: AtomicUsize,
    start: std::time::Instant,
}

impl Progress {
    fn new(total: usize) -> Self {
        let bar = std::io::stderr().is_terminal().then(|| {
            let bar =
                ProgressBar::with_draw_target(Some(total as u64), ProgressDrawTarget::stderr());
            bar.set_style(
                ProgressStyle::with_template(
                    "{bar:40} {pos}/{len} missions ({elapsed}, eta {eta})",
                )
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
            );
            bar
        });
        Self {
            bar,
            total,
            done: AtomicUsize::new(0),
            start: std::time::Instant::now(),
        }
    }

    fn tick(&self) {
        let done = self.done.fetch_add(1, Ordering::SeqCst) + 1;
        match &self.bar {
            Some(bar) => bar.inc(1),
            None => {
                // A line when the completed tenth changes, every 100 missions (a long
                // run is never silent for long) and at the end.
                let tenth = |k: usize| k * 10 / self.total;
                if tenth(done) != tenth(done - 1)
                    || done.is_multiple_of(PROGRESS_EVERY)
                    || done == self.total
                {
                    eprintln!(
                        "montecarlo: {done}/{} missions done ({:.1} s)",
                        self.total,
                        self.start.elapsed().as_secs_f64()
                    );
                }
            }
        }
    }

    fn finish(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }
}

/// Run it. Exit status: see `schema` (3 when a filter variant failed in some run).
pub fn run(args: Args) -> anyhow::Result<()> {
    if let Some(Subcommand::Merge(merge)) = args.command {
        return merge::run(merge);
    }
    crate::schema::check_count("--runs", args.runs, 1, crate::schema::MAX_RUNS)?;
    crate::schema::check_count(
        "--empirical-realizations",
        args.empirical_realizations,
        0,
        crate::schema::MAX_REALIZATIONS,
    )?;
    crate::schema::check_seeds("--first-seed", args.first_seed, args.runs as u64 - 1)?;
    let mut config = match &args.config {
        Some(path) => Config::from_file(path)?,
        None => Config::default(),
    };
    if args.faults && config.faults == crate::study::FaultConfig::default() {
        config.faults = crate::study::FaultConfig::standard();
    }
    match args.learned {
        None | Some(crate::learned_scenarios::LearnedKind::Beamsnet) => {}
        Some(kind) => {
            let outage = kind == crate::learned_scenarios::LearnedKind::Outage;
            let progress = Progress::new(args.runs);
            let report = crate::learned_scenarios::monte_carlo_learned(
                &config,
                outage,
                args.runs,
                args.first_seed,
                args.empirical_realizations,
                &|| progress.tick(),
            );
            progress.finish();
            let report = report?;
            if args.json {
                let inputs = serde_json::json!({
                    "config_file": path_json(args.config.as_deref()),
                    "runs": args.runs,
                    "first_seed": args.first_seed,
                    "seeds": [args.first_seed, args.first_seed + args.runs as u64 - 1],
                    "learned": report.scenario,
                    "empirical_realizations": args.empirical_realizations,
                    "config": config,
                });
                let doc = document("montecarlo", inputs, 0, serde_json::to_value(&report)?);
                emit(&format!("{}\n", serde_json::to_string_pretty(&doc)?))?;
            } else {
                let mut text = String::new();
                crate::learned_scenarios::print_monte_carlo(&mut text, &report)?;
                emit(&text)?;
            }
            return Ok(());
        }
    }
    let learned = crate::learned::sensor(&config, None)?;
    let progress = Progress::new(args.runs);
    let report = monte_carlo(
        &config,
        args.runs,
        args.first_seed,
        learned.as_deref(),
        &|| progress.tick(),
    );
    progress.finish();
    let report = report?;
    let failures = report.failures().count();
    if args.json {
        let inputs = serde_json::json!({
            "config_file": path_json(args.config.as_deref()),
            "runs": args.runs,
            "first_seed": args.first_seed,
            "seeds": [args.first_seed, args.first_seed + args.runs as u64 - 1],
            "faults_flag": args.faults,
            "config": config,
        });
        let doc = document(
            "montecarlo",
            inputs,
            failures,
            serde_json::to_value(&report)?,
        );
        emit(&format!("{}\n", serde_json::to_string_pretty(&doc)?))?;
        return status_result(failures);
    }
    emit(&text_report(&report)?)?;
    status_result(failures)
}

/// The text table of a report (its seeds, then one line per variant, then failures).
pub fn text_report(report: &MonteCarloReport) -> anyhow::Result<String> {
    let mut out = String::new();
    writeln!(
        out,
        "Monte Carlo: {} simulated missions (seeds {}), 95% chi-square bands of the run average",
        report.runs,
        seed_list(&report.seed_ranges)
    )?;
    writeln!(
        out,
        "{:<32} {:>7} {:>9} {:>17} {:>9} {:>8} {:>17} {:>9} {:>7} {:>10} {:>8}",
        "variant",
        "runs ok",
        "NEES",
        "band",
        "in band",
        "NIS",
        "band",
        "in band",
        "gated",
        "pos RMSE",
        "P not PD"
    )?;
    writeln!(out, "(\"in band\": share of epochs whose run-averaged value lies in the band; \"pos RMSE\": mean over the runs of each run's position RMSE over its epochs; \"P not PD\": run-epochs whose covariance lost positive definiteness, excluded from the averages; statistics over the runs that completed)")?;
    for v in report.variants.values() {
        writeln!(
            out,
            "{:<32} {:>7} {:>9.2} {:>8.2}-{:<8.2} {:>8.1}% {:>8.2} {:>8.2}-{:<8.2} {:>8.1}% {:>7} {:>8.2} m {:>8}",
            v.label,
            format!("{}/{}", v.runs_completed, report.runs),
            v.nees_average,
            v.nees_band[0],
            v.nees_band[1],
            v.nees_epochs_in_band_percent,
            v.nis_average,
            v.nis_band[0],
            v.nis_band[1],
            v.nis_epochs_in_band_percent,
            v.updates_rejected,
            v.position_rmse.mean,
            v.covariance_not_positive_definite
        )?;
    }
    for f in report.failures() {
        writeln!(out, "FAILED: {f}")?;
    }
    Ok(out)
}

/// Seed ranges `[a, b)` as text: `1000..1019, 1040..1059` (inclusive ends).
fn seed_list(ranges: &[[u64; 2]]) -> String {
    ranges
        .iter()
        .map(|[a, b]| format!("{a}..{}", b.saturating_sub(1)))
        .collect::<Vec<_>>()
        .join(", ")
}
