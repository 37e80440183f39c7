//! `estim reproduce`: the paper end to end.

use std::path::PathBuf;

use anyhow::Context;
use estim::datasets::data_root;
use estim::pipeline::{analyse, Config, Scenario, TrajectoryReport};

/// Arguments of `estim reproduce`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Folder holding A-KIT `TrajectoryN/` (or a data root holding `a-kit/`).
    /// Without it, the embedded simulated mission is used.
    #[arg(long, value_name = "DIR")]
    data: Option<PathBuf>,
    /// A-KIT trajectories to run (repeatable); default 4 and 13.
    #[arg(long = "trajectory", value_name = "N")]
    trajectories: Vec<u32>,
    /// TOML configuration (see --print-config for every key and default).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Print the configuration in effect as TOML and exit.
    #[arg(long)]
    print_config: bool,
    /// Machine-readable JSON on stdout instead of tables.
    #[arg(long)]
    json: bool,
    /// Write CSV time series and plots (PNG, SVG) into this folder.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
}

/// Run it.
pub fn run(args: Args) -> anyhow::Result<()> {
    let config = match &args.config {
        Some(path) => Config::from_file(path)?,
        None => Config::default(),
    };
    if args.print_config {
        print!("{}", config.to_toml());
        return Ok(());
    }
    let scenarios: Vec<Scenario> = match &args.data {
        Some(dir) => {
            let dir = data_root(Some(dir)).context("no data folder")?;
            let list = if args.trajectories.is_empty() {
                vec![4, 13]
            } else {
                args.trajectories.clone()
            };
            list.iter()
                .map(|n| Scenario::akit(&dir, *n, &config, config.seed))
                .collect::<Result<_, _>>()?
        }
        None => vec![Scenario::simulated(&config, config.seed)?],
    };
    let reports: Vec<TrajectoryReport> = scenarios
        .iter()
        .map(|s| analyse(s, &config, None, config.seed))
        .collect::<Result<_, _>>()?;
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({ "trajectories": reports }))?
        );
    } else {
        for r in &reports {
            print_report(r);
        }
    }
    Ok(())
}

fn print_report(r: &TrajectoryReport) {
    println!(
        "== {} ({:.0} s, {} DVL epochs)",
        r.name, r.duration_s, r.dvl_epochs
    );
    println!("velocity norm vs DVL reference (paper Tables I/II):");
    println!(
        "  {:<10} {:>10} {:>10} {:>10} {:>10}",
        "method", "RMSE", "MAE", "R^2", "VAF [%]"
    );
    for (name, m) in &r.velocity {
        println!(
            "  {:<10} {:>10.6} {:>10.6} {:>10.6} {:>10.4}",
            name, m.rmse, m.mae, m.r2, m.vaf
        );
    }
    println!("filters (std = time average / final, summed over axes; errors RMSE / final):");
    for f in &r.filters {
        println!("  {}", f.name);
        for (g, s) in &f.std {
            println!(
                "    std {:<13} {:>12.4e} / {:>12.4e}",
                g, s.time_average, s.final_value
            );
        }
        println!(
            "    error position {:.3} / {:.3} m, velocity {:.4} / {:.4} m/s, attitude {:.4} / {:.4} deg",
            f.position_error_m.rmse,
            f.position_error_m.final_value,
            f.velocity_error_mps.rmse,
            f.velocity_error_mps.final_value,
            f.attitude_error_deg.rmse,
            f.attitude_error_deg.final_value
        );
        println!(
            "    NEES {:.2} (95% band {:.2}-{:.2}), NIS {:.2} (band {:.2}-{:.2}), updates {} accepted / {} gated",
            f.nees_average, f.nees_band[0], f.nees_band[1], f.nis_average, f.nis_band[0], f.nis_band[1],
            f.updates_accepted, f.updates_rejected
        );
        println!(
            "    joint covariance: min eigenvalue {:.3e}, invalid updates {}, largest valid rho (median) {:.3}",
            f.joint_min_eigenvalue, f.joint_invalid_updates, f.largest_valid_rho
        );
    }
    for imp in &r.improvements {
        println!(
            "  improvement of {} over M neglected (time average / final):",
            imp.variant
        );
        for (g, v) in &imp.groups {
            println!(
                "    {:<13} {:>7.2} % / {:>7.2} %",
                g, v.time_average_percent, v.final_percent
            );
        }
    }
}
