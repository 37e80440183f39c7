//! `estim tune`: maximum-likelihood noise parameters of the INS/DVL filter on A-KIT
//! training trajectories, with standard errors and the likelihood-ratio test of M = 0.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context;
use estim::navigator::tune::{TuneOptions, PARAMETER_NAMES, PARAMETER_UNITS};

use crate::study::{tune_akit, Config, TuneReport};

/// Arguments of `estim tune`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Folder holding A-KIT `TrajectoryN/` (or a data root holding `a-kit/`); default
    /// `ESTIM_DATA_DIR`, then `../shared/data`.
    #[arg(long, value_name = "DIR")]
    data: Option<PathBuf>,
    /// A-KIT training trajectories, comma-separated (e.g. `1,2,3`); the test
    /// trajectories 4 and 13 are refused (exit status 2).
    #[arg(long, value_name = "N,N,...", value_delimiter = ',', required = true)]
    trajectories: Vec<u32>,
    /// TOML configuration (as for `estim reproduce`): the IMU error model the IMU is
    /// synthesized with, the DVL lever arm, time offset and beam protocol, the
    /// starting values.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Seed of the synthesized IMU and of the initial error (default: the
    /// configuration's).
    #[arg(long, value_name = "N")]
    seed: Option<u64>,
    /// Linearizations of the filter: the first at the starting values, each next one
    /// at the previous estimate.
    #[arg(long, value_name = "N", default_value_t = 2,
          value_parser = clap::value_parser!(u64).range(1..=10))]
    linearizations: u64,
    /// Machine-readable JSON on stdout instead of the table.
    #[arg(long)]
    json: bool,
}

/// Run it.
pub fn run(args: Args) -> anyhow::Result<()> {
    let config = match &args.config {
        Some(path) => Config::from_file(path)?,
        None => Config::default(),
    };
    let seed = match args.seed {
        Some(seed) => {
            crate::schema::check_seeds("--seed", seed, 0)?;
            seed
        }
        None => config.seed,
    };
    let dir = estim::datasets::data_root(args.data.as_deref()).context(
        "no data folder: pass --data DIR, set ESTIM_DATA_DIR, or place the data at ../shared/data",
    )?;
    let options = TuneOptions {
        linearizations: usize::try_from(args.linearizations)?,
        ..TuneOptions::default()
    };
    let report = tune_akit(&dir, &args.trajectories, &config, seed, &options)?;
    let text = if args.json {
        json(&args, &dir, seed, &report)?
    } else {
        table(&report)
    };
    crate::output::emit(&text)
}

fn json(
    args: &Args,
    dir: &std::path::Path,
    seed: u64,
    report: &TuneReport,
) -> anyhow::Result<String> {
    use crate::schema::{document, path_json};
    let fit = &report.fit;
    let se =
        |i: usize, f: &estim_core::noise::ml::MaximumLikelihood<5>| f.standard_errors.map(|s| s[i]);
    let parameters: Vec<_> = (0..PARAMETER_NAMES.len())
        .map(|i| {
            serde_json::json!({
                "name": PARAMETER_NAMES[i],
                "unit": PARAMETER_UNITS[i],
                "value": fit.full.theta[i],
                "standard_error": fit.standard_errors[i],
                "on_bound": fit.on_bound[i],
                "start": report.start[i],
                "synthesized": report.synthesized_psd.get(i),
                "value_with_m_zero": fit.restricted.theta[i],
                "standard_error_with_m_zero": se(i, &fit.restricted),
            })
        })
        .collect();
    let inputs = serde_json::json!({
        "data": path_json(Some(dir)),
        "config": path_json(args.config.as_deref()),
        "trajectories": report.trajectories,
        "seed": seed,
        "linearizations": args.linearizations,
        "imu": "synthesized from the ground truth with the configured error model",
    });
    let points: Vec<Vec<f64>> = fit.points.iter().map(|p| p.as_slice().to_vec()).collect();
    let doc = document(
        "tune",
        inputs,
        0,
        serde_json::json!({
            "parameters": parameters,
            "log_likelihood": fit.full.log_likelihood,
            "log_likelihood_with_m_zero": fit.restricted.log_likelihood,
            "converged": fit.full.converged,
            "converged_with_m_zero": fit.restricted.converged,
            "iterations": fit.full.iterations,
            "termination": fit.full.termination,
            "gradient": fit.full.gradient.as_slice(),
            "m_scale_bound": fit.rho_bound,
            "likelihood_ratio_test": {
                "null": "m_scale = 0 (M = 0)",
                "statistic": fit.test.statistic,
                "degrees_of_freedom": fit.test.degrees_of_freedom,
                "p_value": fit.test.p_value,
            },
            "epochs": report.epochs,
            "overlapping_epochs_left_out": report.overlapping,
            "linearization_points": points,
        }),
    );
    Ok(format!("{}\n", serde_json::to_string_pretty(&doc)?))
}

fn table(report: &TuneReport) -> String {
    let fit = &report.fit;
    let mut out = String::new();
    let list: Vec<String> = report.trajectories.iter().map(u32::to_string).collect();
    let _ = writeln!(
        out,
        "Maximum likelihood on A-KIT trajectories {} ({} DVL epochs; {} left out as shared \
         with a test trajectory). The IMU is synthesized from the ground truth with the \
         configured error model (column `synthesized`).",
        list.join(", "),
        report.epochs.iter().sum::<usize>(),
        report.overlapping.iter().sum::<usize>(),
    );
    let _ = writeln!(
        out,
        "\n| parameter | unit | estimate | standard error | start | synthesized |\n|---|---|---|---|---|---|"
    );
    for i in 0..PARAMETER_NAMES.len() {
        let se = match (fit.standard_errors[i], fit.on_bound[i]) {
            (Some(s), _) => format!("{s:.4e}"),
            (None, true) => "on its bound".to_string(),
            (None, false) => "n/a".to_string(),
        };
        let synthesized = report
            .synthesized_psd
            .get(i)
            .map_or(String::new(), |v| format!("{v:.4e}"));
        let _ = writeln!(
            out,
            "| {} | {} | {:.4e} | {} | {:.4e} | {} |",
            PARAMETER_NAMES[i],
            PARAMETER_UNITS[i],
            fit.full.theta[i],
            se,
            report.start[i],
            synthesized
        );
    }
    let _ = writeln!(
        out,
        "\nln p = {:.3} (converged: {}); with M = 0: ln p = {:.3} (converged: {}).\n\
         Likelihood-ratio test of m_scale = 0: statistic {:.4}, 1 degree of freedom, p-value {:.4}.\n\
         m_scale is bounded by +-{:.4} (99 % of the largest valid value at the last linearization).",
        fit.full.log_likelihood,
        fit.full.converged,
        fit.restricted.log_likelihood,
        fit.restricted.converged,
        fit.test.statistic,
        fit.test.p_value,
        fit.rho_bound,
    );
    out
}
