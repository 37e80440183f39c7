//! `estim reproduce`: the paper end to end.

use std::path::PathBuf;

use anyhow::Context;
use estim::datasets::data_root;
use estim::pipeline::{analyse, apply_faults, Config, Scenario, TrajectoryReport};

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
    /// BeamsNet ONNX model to use instead of the committed one (metadata JSON beside it).
    #[arg(long, value_name = "FILE")]
    model: Option<PathBuf>,
    /// Write CSV time series and plots (PNG, SVG) into this folder.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Also smooth each trajectory (RTS, LS DVL, M = 0): smoothed vs filtered errors
    /// and NEES (files in `--out DIR/smoothing`).
    #[arg(long)]
    smooth: bool,
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
    let mut scenarios = scenarios;
    for s in &mut scenarios {
        apply_faults(s, &config.faults, config.seed)?;
    }
    let learned = crate::learned::sensor(&config, args.model.as_deref())?;
    let reports: Vec<TrajectoryReport> = scenarios
        .iter()
        .map(|s| -> anyhow::Result<TrajectoryReport> {
            let inputs = match &learned {
                Some(make) => Some(make(s)?),
                None => None,
            };
            Ok(analyse(s, &config, inputs.as_ref(), config.seed)?)
        })
        .collect::<Result<_, _>>()?;
    let smoothed = if args.smooth {
        let cross = estim::pipeline::CrossSource::Zero;
        Some(crate::smooth::smooth_all(&scenarios, &config, &cross)?)
    } else {
        None
    };
    let mut value = serde_json::json!({
        "config": config,
        "trajectories": reports,
    });
    if let Some(s) = &smoothed {
        value["smoothing"] = serde_json::to_value(s)?;
    }
    let json = serde_json::to_string_pretty(&value)?;
    // Outputs first: on failure nothing is printed as if it had succeeded.
    if let Some(dir) = &args.out {
        write_outputs(dir, &reports, &json)?;
        if let Some(s) = &smoothed {
            crate::smooth::write_outputs(&dir.join("smoothing"), s)?;
        }
    }
    if args.json {
        println!("{json}");
    } else {
        for r in &reports {
            print_report(r);
        }
        if let Some(s) = &smoothed {
            crate::smooth::print_reports(s);
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
            "    joint covariance: min eigenvalue {:.3e}, invalid updates {}, largest valid rho (median) {:.3}; P not positive definite at {} epochs",
            f.joint_min_eigenvalue, f.joint_invalid_updates, f.largest_valid_rho, f.covariance_not_positive_definite_epochs
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

/// File-name stem of a report ("simulated", "trajectory4").
fn slug(r: &TrajectoryReport) -> String {
    match r.trajectory {
        Some(n) => format!("trajectory{n}"),
        None => "simulated".to_string(),
    }
}

/// CSV time series and plots of every report into a staged folder.
fn write_outputs(
    dir: &std::path::Path,
    reports: &[TrajectoryReport],
    json: &str,
) -> anyhow::Result<()> {
    use crate::output::StagedDir;
    use crate::plots::{bar_chart, line_chart, LineChart, Series};
    use estim::pipeline::stats::GROUPS;
    use std::io::Write;

    let staged = StagedDir::new(dir)?;
    std::fs::write(staged.path("report.json"), json).context("cannot write report.json")?;
    for r in reports {
        let stem = slug(r);
        // Time series, long format: one row per filter and epoch.
        let path = staged.path(&format!("{stem}_timeseries.csv"));
        let mut w = std::io::BufWriter::new(
            std::fs::File::create(&path)
                .with_context(|| format!("{}: cannot create", path.display()))?,
        );
        let mut header = vec!["filter".to_string(), "time_s".to_string()];
        header.extend(GROUPS.iter().map(|(g, _)| format!("{g}_std_sum")));
        header.extend(
            [
                "position_error_m",
                "velocity_error_mps",
                "attitude_error_deg",
                "nees",
                "north_m",
                "east_m",
            ]
            .map(String::from),
        );
        writeln!(w, "{}", header.join(","))?;
        for run in &r.runs {
            for k in 0..run.time.len() {
                let d = &run.covariance_diagonal[k];
                let stds: Vec<String> = GROUPS
                    .iter()
                    .map(|(_, i)| {
                        format!(
                            "{:e}",
                            (*i..*i + 3).map(|j| d[j].max(0.0).sqrt()).sum::<f64>()
                        )
                    })
                    .collect();
                writeln!(
                    w,
                    "\"{}\",{},{},{},{},{},{},{},{}",
                    run.name,
                    run.time[k],
                    stds.join(","),
                    run.position_error[k],
                    run.velocity_error[k],
                    run.attitude_error_deg[k],
                    run.nees[k],
                    run.north_east[k][0],
                    run.north_east[k][1]
                )?;
            }
        }
        w.flush()?;
        drop(w);
        let plot_err = |e: Box<dyn std::error::Error>| anyhow::anyhow!("plot: {e}");
        // Standard deviation over time per group (paper Figs. 3/4).
        for (g, i) in GROUPS {
            let ys: Vec<Vec<f64>> = r
                .runs
                .iter()
                .map(|run| {
                    run.covariance_diagonal
                        .iter()
                        .map(|d| (i..i + 3).map(|j| d[j].max(0.0).sqrt()).sum::<f64>())
                        .collect()
                })
                .collect();
            let chart = LineChart {
                title: &format!("{}: {g} std (sum over axes)", r.name),
                x_label: "time [s]",
                y_label: "std",
                series: r
                    .runs
                    .iter()
                    .zip(&ys)
                    .map(|(run, y)| Series {
                        name: &run.name,
                        x: &run.time,
                        y,
                    })
                    .collect(),
                hlines: vec![],
                log_y: false,
                equal_axes: false,
            };
            line_chart(&staged.path(&format!("{stem}_std_{g}")), &chart).map_err(plot_err)?;
        }
        // Improvement bars (paper Fig. 5).
        if !r.improvements.is_empty() {
            let groups: Vec<&str> = GROUPS.iter().skip(1).map(|(g, _)| *g).collect();
            let variants: Vec<&str> = r.improvements.iter().map(|i| i.variant.as_str()).collect();
            let values: Vec<Vec<f64>> = r
                .improvements
                .iter()
                .map(|imp| {
                    groups
                        .iter()
                        .map(|g| imp.groups[*g].time_average_percent)
                        .collect()
                })
                .collect();
            bar_chart(
                &staged.path(&format!("{stem}_improvement")),
                &format!("{}: time-averaged std improvement over M neglected", r.name),
                "improvement [%]",
                &groups,
                &variants,
                &values,
            )
            .map_err(plot_err)?;
        }
        // North-east track (paper Fig. 2).
        let east: Vec<Vec<f64>> = std::iter::once(&r.truth_north_east)
            .chain(r.runs.iter().map(|run| &run.north_east))
            .map(|ne| ne.iter().map(|p| p[1]).collect())
            .collect();
        let north: Vec<Vec<f64>> = std::iter::once(&r.truth_north_east)
            .chain(r.runs.iter().map(|run| &run.north_east))
            .map(|ne| ne.iter().map(|p| p[0]).collect())
            .collect();
        let names: Vec<&str> = std::iter::once("truth")
            .chain(r.runs.iter().map(|run| run.name.as_str()))
            .collect();
        let chart = LineChart {
            title: &format!("{}: north-east track", r.name),
            x_label: "east [m]",
            y_label: "north [m]",
            series: names
                .iter()
                .zip(east.iter().zip(&north))
                .map(|(n, (x, y))| Series { name: n, x, y })
                .collect(),
            hlines: vec![],
            log_y: false,
            equal_axes: true,
        };
        line_chart(&staged.path(&format!("{stem}_track")), &chart).map_err(plot_err)?;
        // NEES over time with the per-epoch 95 % band of chi-square(15).
        let band = estim::core::chi_square_band(15, 1, 0.95)?;
        let chart = LineChart {
            title: &format!("{}: NEES (15 states) against truth", r.name),
            x_label: "time [s]",
            y_label: "NEES",
            series: r
                .runs
                .iter()
                .map(|run| Series {
                    name: &run.name,
                    x: &run.time,
                    y: &run.nees,
                })
                .collect(),
            hlines: vec![("95% lower", band.lower), ("95% upper", band.upper)],
            log_y: true,
            equal_axes: false,
        };
        line_chart(&staged.path(&format!("{stem}_nees")), &chart).map_err(plot_err)?;
    }
    staged.commit()
}
