//! `estim montecarlo`: consistency over seeded simulated missions.

use std::path::PathBuf;

use estim::pipeline::{monte_carlo, Config};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// Arguments of `estim montecarlo`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Number of simulated missions.
    #[arg(long, default_value_t = 50)]
    runs: usize,
    /// Seed of the first mission (missions use seed, seed+1, ...).
    #[arg(long, default_value_t = 1000)]
    seed: u64,
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
    /// Learned scenario: `two-beams` (beams 1-2 only for 120 s; per-variant
    /// nees_mean, nees_in_band_fraction, position_rmse, velocity_rmse,
    /// output_imu_correlation); `beamsnet` is the standard table; `outage` is not built
    /// yet.
    #[arg(long, value_enum)]
    learned: Option<crate::learned_scenarios::LearnedKind>,
}

/// Run it.
pub fn run(args: Args) -> anyhow::Result<()> {
    if args.runs == 0 {
        anyhow::bail!("--runs must be at least 1");
    }
    let mut config = match &args.config {
        Some(path) => Config::from_file(path)?,
        None => Config::default(),
    };
    if args.faults && config.faults == estim::pipeline::FaultConfig::default() {
        config.faults = estim::pipeline::FaultConfig::standard();
    }
    let bar = ProgressBar::with_draw_target(Some(args.runs as u64), ProgressDrawTarget::stderr());
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} missions ({elapsed})")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    match args.learned {
        None | Some(crate::learned_scenarios::LearnedKind::Beamsnet) => {}
        Some(crate::learned_scenarios::LearnedKind::TwoBeams) => {
            let report = crate::learned_scenarios::monte_carlo_two_beams(
                &config,
                args.runs,
                args.seed,
                &|| bar.inc(1),
            )?;
            bar.finish_and_clear();
            if args.json {
                println!("{}", serde_json::to_string_pretty(&report)?);
            } else {
                crate::learned_scenarios::print_monte_carlo(&report);
            }
            return Ok(());
        }
        Some(crate::learned_scenarios::LearnedKind::Outage) => {
            anyhow::bail!("--learned outage is not built yet (estim issue 12, step 4)")
        }
    }
    let learned = crate::learned::sensor(&config, None)?;
    let report = monte_carlo(&config, args.runs, args.seed, learned.as_deref(), &|| {
        bar.inc(1)
    })?;
    bar.finish_and_clear();
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    println!(
        "Monte Carlo: {} simulated missions (seeds {}..{}), 95% chi-square bands of the run average",
        report.runs,
        report.first_seed,
        report.first_seed + report.runs as u64 - 1
    );
    println!(
        "{:<28} {:>9} {:>17} {:>9} {:>8} {:>17} {:>9} {:>7} {:>9} {:>8}",
        "variant",
        "NEES",
        "band",
        "in band",
        "NIS",
        "band",
        "in band",
        "gated",
        "pos RMSE",
        "P not PD"
    );
    println!("(\"in band\": share of epochs whose run-averaged value lies in the band; \"P not PD\": run-epochs whose covariance lost positive definiteness, excluded from the averages)");
    for (name, v) in &report.variants {
        println!(
            "{:<28} {:>9.2} {:>8.2}-{:<8.2} {:>8.1}% {:>8.2} {:>8.2}-{:<8.2} {:>8.1}% {:>7} {:>8.2}m {:>8}",
            name,
            v.nees_average,
            v.nees_band[0],
            v.nees_band[1],
            v.nees_epochs_in_band_percent,
            v.nis_average,
            v.nis_band[0],
            v.nis_band[1],
            v.nis_epochs_in_band_percent,
            v.updates_rejected,
            v.position_rmse_m,
            v.covariance_not_positive_definite
        );
    }
    Ok(())
}
