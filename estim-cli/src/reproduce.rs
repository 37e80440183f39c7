//! `estim reproduce`: the paper end to end.

use std::path::PathBuf;

use std::fmt::Write as _;

use crate::study::{analyse, apply_faults, filter_label, Config, Scenario, TrajectoryReport};
use anyhow::Context;
use estim::datasets::data_root;

use crate::output::{emit, StagedDir};
use crate::schema::{document, path_json, status_result};

/// Arguments of `estim reproduce`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Folder holding A-KIT `TrajectoryN/` (or a data root holding `a-kit/`).
    /// Without it, the embedded simulated mission is used.
    #[arg(long, value_name = "DIR")]
    data: Option<PathBuf>,
    /// A-KIT trajectories to run (repeatable); default 4 and 13. Without --data the
    /// data is found through `ESTIM_DATA_DIR`, then `../shared/data`.
    #[arg(long = "trajectory", value_name = "N")]
    trajectories: Vec<u32>,
    /// A ground-truth CSV file at any path (one trajectory; with --dvl). Columns are
    /// found by name in any order, with units from the header (docs/cli.md, "Your own data").
    #[arg(long, value_name = "FILE", requires = "dvl", conflicts_with_all = ["data", "trajectories"])]
    gt: Option<PathBuf>,
    /// The DVL velocity CSV file of that trajectory (with --gt).
    #[arg(long, value_name = "FILE", requires = "gt")]
    dvl: Option<PathBuf>,
    /// Run on the common time span when GT and DVL do not cover the same span
    /// (otherwise an error); the choice is printed on stderr.
    #[arg(long)]
    allow_partial: bool,
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
    /// Scenario: `paper` (default), `two-beams` (beams 1-2 only for 120 s, the
    /// two-beams network), `outage` (no DVL for 60 s, the outage network).
    #[arg(long, value_enum, default_value = "paper")]
    scenario: crate::learned_scenarios::ScenarioKind,
    /// Which IMU an A-KIT trajectory uses: `auto` (the recorded `IMU_trajectoryN.csv`
    /// where the folder holds one, else synthesized from the reference), `recorded`
    /// (an error where there is none) or `synthesized`. `--scenario two-beams` and
    /// `outage` always synthesize (`recorded` is refused with them).
    #[arg(long = "imu", value_enum, default_value = "auto")]
    imu: crate::study::ImuChoice,
    /// Vehicle file a recorded IMU is read with (axes, clocks, offsets, lever arms);
    /// default: the A-KIT vehicle, `vehicles/akit.toml`, embedded in the binary.
    #[arg(long, value_name = "FILE")]
    vehicle: Option<PathBuf>,
    /// Also smooth each trajectory (RTS, LS DVL, M = 0): smoothed vs filtered errors
    /// and NEES (files in `--out DIR/smoothing`).
    #[arg(long)]
    smooth: bool,
}

/// Run it. Exit status: see `schema` (3 when a filter variant failed).
pub fn run(args: Args) -> anyhow::Result<()> {
    let config = match &args.config {
        Some(path) => Config::from_file(path)?,
        None => Config::default(),
    };
    if args.print_config {
        return crate::output::emit(&config.to_commented_toml());
    }
    // Checked before any work: an unwritable --out fails now, naming the folder.
    let mut staged = match &args.out {
        Some(dir) => Some(crate::output::StagedDir::new(dir)?),
        None => None,
    };
    if let Some(dir) = &mut staged {
        dir.keep_inputs(
            [&args.config, &args.data, &args.gt, &args.dvl]
                .into_iter()
                .flatten()
                .map(std::path::PathBuf::as_path),
        );
    }
    // The two-beams and outage studies run the study's own 15-state filter, which is
    // not defined on a recorded IMU: they keep the synthesized one.
    let learned_event = args.scenario != crate::learned_scenarios::ScenarioKind::Paper;
    let imu = match (learned_event, args.imu) {
        (true, crate::study::ImuChoice::Recorded) => anyhow::bail!(
            "--imu recorded: --scenario two-beams and outage run on the IMU synthesized \
             from the reference only (use --imu synthesized or auto)"
        ),
        (true, _) => crate::study::ImuChoice::Synthesized,
        (false, choice) => choice,
    };
    let (scenarios, trajectories): (Vec<Scenario>, Option<Vec<u32>>) =
        match (&args.data, &args.gt, &args.dvl) {
            (_, Some(gt), Some(dvl)) => (
                vec![Scenario::recorded(
                    gt,
                    dvl,
                    &config,
                    config.seed,
                    args.allow_partial,
                )?],
                None,
            ),
            (Some(_), _, _) | (None, None, None)
                if args.data.is_some() || !args.trajectories.is_empty() =>
            {
                let dir = data_root(args.data.as_deref()).context(
                    "--trajectory needs the A-KIT data: pass --data DIR, set ESTIM_DATA_DIR, \
                     or place it at ../shared/data",
                )?;
                let list = if args.trajectories.is_empty() {
                    vec![4, 13]
                } else {
                    args.trajectories.clone()
                };
                let s = list
                    .iter()
                    .map(|n| {
                        Scenario::akit_choosing(
                            &dir,
                            *n,
                            &config,
                            config.seed,
                            args.allow_partial,
                            imu,
                            args.vehicle.as_deref(),
                        )
                    })
                    .collect::<Result<_, _>>()?;
                (s, Some(list))
            }
            _ => (vec![Scenario::simulated(&config, config.seed)?], None),
        };
    for s in &scenarios {
        if let Some(span) = s.span.filter(|span| !span.agrees()) {
            let [a, b] = span.overlap_s().unwrap_or(span.gt_s);
            eprintln!(
                "warning: --allow-partial: {}: {}; running on the overlap {a:.3}-{b:.3} s only",
                s.name,
                span.describe()
            );
        }
    }
    let mut scenarios = scenarios;
    for s in &mut scenarios {
        apply_faults(s, &config.faults, config.seed)?;
    }
    match args.scenario {
        crate::learned_scenarios::ScenarioKind::Paper => {}
        kind => {
            let outage = kind == crate::learned_scenarios::ScenarioKind::Outage;
            let studies = crate::learned_scenarios::reproduce_learned(&scenarios, &config, outage)?;
            if args.json {
                let inputs = serde_json::json!({
                    "data": path_json(args.data.as_deref()),
                    "trajectories": trajectories,
                    "config_file": path_json(args.config.as_deref()),
                    "scenario": if outage { "outage" } else { "two-beams" },
                    "seed": config.seed,
                    "config": config,
                });
                let payload = serde_json::json!({ "studies": studies });
                let doc = document("reproduce", inputs, 0, payload);
                emit(&format!("{}\n", serde_json::to_string_pretty(&doc)?))?;
            } else {
                let mut text = String::new();
                for s in &studies {
                    crate::learned_scenarios::print_study(&mut text, s)?;
                }
                emit(&text)?;
            }
            return Ok(());
        }
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
    let failures: usize = reports.iter().map(|r| r.failures.len()).sum();
    let inputs = serde_json::json!({
        "data": path_json(args.data.as_deref()),
        "trajectories": trajectories,
        "config_file": path_json(args.config.as_deref()),
        "model": match &args.model {
            Some(path) => path_json(Some(path)),
            None => serde_json::Value::from(estim::models::BEAMSNET_NAME),
        },
        // On a recorded IMU without --model: the network trained on recorded windows.
        "model_recorded_imu": match &args.model {
            Some(path) => path_json(Some(path)),
            None => serde_json::Value::from(estim::models::BEAMSNET_RECORDED_NAME),
        },
        "out": path_json(args.out.as_deref()),
        "seed": config.seed,
        "config": config,
    });
    let smoothed = if args.smooth {
        let cross = crate::study::CrossSource::Zero;
        Some(crate::study::cli::smooth::smooth_all(
            &scenarios, &config, &cross,
        )?)
    } else {
        None
    };
    let mut payload = serde_json::json!({ "trajectories": reports });
    if let Some(s) = &smoothed {
        payload["smoothing"] = serde_json::to_value(s)?;
    }
    let json = serde_json::to_string_pretty(&document("reproduce", inputs, failures, payload))?;
    // Outputs first: on failure nothing is printed as if it had succeeded.
    // Everything, the smoothing files included, in one commit.
    if let Some(staged) = staged {
        if let Some(s) = &smoothed {
            let dir = staged.path("smoothing");
            std::fs::create_dir(&dir)
                .with_context(|| format!("{}: cannot create", dir.display()))?;
            crate::study::cli::smooth::write_files(&dir, s)?;
        }
        write_outputs(staged, &reports, &json)?;
    }
    if args.json {
        emit(&format!("{json}\n"))?;
    } else {
        let mut text = String::new();
        for r in &reports {
            print_report(&mut text, r)?;
        }
        if let Some(s) = &smoothed {
            crate::study::cli::smooth::print_reports(&mut text, s)?;
        }
        emit(&text)?;
    }
    status_result(failures)
}

fn print_report(out: &mut String, r: &TrajectoryReport) -> std::fmt::Result {
    writeln!(
        out,
        "== {} ({:.0} s, {} DVL epochs, IMU {})",
        r.name,
        r.duration_s,
        r.dvl_epochs,
        r.imu_source.as_str()
    )?;
    if let Some(recorded) = &r.recorded {
        writeln!(
            out,
            "recorded IMU read with {}; reference clock offset {} s; errors and NEES (over \
             {} states with truth) at the reference's epochs",
            recorded["vehicle"].as_str().unwrap_or("?"),
            recorded["truth_time_offset"]["offset_s"],
            recorded["nees_states"]
        )?;
    }
    writeln!(out, "velocity norm vs DVL reference (paper Tables I/II):")?;
    writeln!(
        out,
        "  {:<10} {:>10} {:>10} {:>10} {:>10}",
        "method", "RMSE [m/s]", "MAE [m/s]", "R^2", "VAF [%]"
    )?;
    // LS first, then the learned sources.
    let mut rows: Vec<_> = r.velocity.iter().collect();
    rows.sort_by_key(|(id, _)| (id.as_str() != crate::study::LS, id.as_str()));
    for (id, m) in rows {
        writeln!(
            out,
            "  {:<10} {:>10.6} {:>10.6} {:>10.6} {:>10.4}",
            filter_label(id, f64::NAN),
            m.rmse,
            m.mae,
            m.r2,
            m.vaf
        )?;
    }
    writeln!(
        out,
        "filters (std = time average / final, summed over axes; errors RMSE / final):"
    )?;
    for f in &r.filters {
        writeln!(out, "  {} [{}]", f.name, f.id)?;
        for (g, s) in &f.std {
            writeln!(
                out,
                "    std {:<17} {:>12.4e} / {:>12.4e}",
                format!("{g} [{}]", group_unit(g)),
                s.time_average,
                s.final_value
            )?;
        }
        writeln!(
            out,
            "    error position {:.3} / {:.3} m (horizontal {:.3} / {:.3} m), velocity {:.4} / {:.4} m/s, attitude {:.4} / {:.4} deg",
            f.position_error_m.rmse,
            f.position_error_m.final_value,
            f.horizontal_position_error_m.rmse,
            f.horizontal_position_error_m.final_value,
            f.velocity_error_mps.rmse,
            f.velocity_error_mps.final_value,
            f.attitude_error_deg.rmse,
            f.attitude_error_deg.final_value
        )?;
        writeln!(
            out,
            "    NEES {:.2} (95% band {:.2}-{:.2}), NIS {:.2} (band {:.2}-{:.2}), updates {} accepted / {} gated",
            f.nees_average, f.nees_band[0], f.nees_band[1], f.nis_average, f.nis_band[0], f.nis_band[1],
            f.updates_accepted, f.updates_rejected
        )?;
        writeln!(
            out,
            "    joint covariance: min eigenvalue {:.3e}, invalid updates {}, largest valid rho (median) {:.3}; P not positive definite at {} epochs",
            f.joint_min_eigenvalue, f.joint_invalid_updates, f.largest_valid_rho, f.covariance_not_positive_definite_epochs
        )?;
    }
    for failure in &r.failures {
        writeln!(out, "  FAILED: {failure}")?;
    }
    for imp in &r.improvements {
        writeln!(
            out,
            "  improvement of {} over M neglected (time average / final):",
            imp.variant
        )?;
        for (g, v) in &imp.groups {
            writeln!(
                out,
                "    {:<13} {:>7.2} % / {:>7.2} %",
                g, v.time_average_percent, v.final_percent
            )?;
        }
    }
    Ok(())
}

/// Unit of a state group's std.
fn group_unit(group: &str) -> &'static str {
    match group {
        "position" => "m",
        "velocity" => "m/s",
        "misalignment" => "rad",
        "acc_bias" => "m/s^2",
        "gyro_bias" => "rad/s",
        _ => "?",
    }
}

/// File-name stem of a report ("simulated", "trajectory4").
fn slug(r: &TrajectoryReport) -> String {
    match r.trajectory {
        Some(n) => format!("trajectory{n}"),
        None if r.name == "simulated mission" => "simulated".to_string(),
        None => "trajectory".to_string(),
    }
}

/// CSV time series and plots of every report into the staged folder, then commit.
fn write_outputs(
    staged: StagedDir,
    reports: &[TrajectoryReport],
    json: &str,
) -> anyhow::Result<()> {
    use crate::plots::{
        bar_chart, error_chart, line_chart, line_chart_captioned, plot_unit, BarChart, ErrorPanel,
        LineChart, Series,
    };
    use crate::study::stats::group_std_positive_definite;
    use crate::study::stats::GROUPS;
    use std::io::Write;

    let target = staged.target().to_path_buf();
    std::fs::write(staged.path("report.json"), json)
        .with_context(|| format!("{}: cannot write", target.join("report.json").display()))?;
    for r in reports {
        let stem = slug(r);
        // Time series, long format: one row per filter and epoch.
        let name = format!("{stem}_timeseries.csv");
        let path = staged.path(&name);
        // A write error (a full disk) names the file as it will be in --out.
        let named = |e: std::io::Error| {
            anyhow::anyhow!("{}: cannot write: {e}", target.join(&name).display())
        };
        let mut w = std::io::BufWriter::new(
            std::fs::File::create(&path)
                .with_context(|| format!("{}: cannot create", target.join(&name).display()))?,
        );
        let mut header = vec!["filter_id".to_string(), "time_s".to_string()];
        header.extend(
            GROUPS
                .iter()
                .map(|(g, _)| format!("{}_std_sum", crate::study::stats::group_key_with_unit(g))),
        );
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
        writeln!(w, "{}", header.join(",")).map_err(named)?;
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
                    "{},{},{},{},{},{},{},{},{}",
                    run.id,
                    run.time[k],
                    stds.join(","),
                    run.position_error[k],
                    run.velocity_error[k],
                    run.attitude_error_deg[k],
                    run.nees[k],
                    run.north_east[k][0],
                    run.north_east[k][1]
                )
                .map_err(named)?;
            }
        }
        w.flush().map_err(named)?;
        drop(w);
        let plot_err = |e: Box<dyn std::error::Error>| anyhow::anyhow!("plot: {e}");
        // Standard deviation over time per group (paper Figs. 3/4), in a unit whose
        // ticks read (biases in deg/h and mg or µg).
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
            let (unit, scale) = plot_unit(g, ys.iter().flatten().copied());
            let ys: Vec<Vec<f64>> = ys
                .into_iter()
                .map(|y| y.into_iter().map(|v| v * scale).collect())
                .collect();
            let chart = LineChart {
                title: &format!("{}: {g} std (sum over axes)", r.name),
                x_label: "time [s]",
                y_label: &format!("{g} std, sum over axes [{unit}]"),
                series: r
                    .runs
                    .iter()
                    .zip(&ys)
                    .map(|(run, y)| Series {
                        id: &run.id,
                        label: &run.name,
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
            let variants: Vec<(&str, &str)> = r
                .improvements
                .iter()
                .map(|i| (i.id.as_str(), i.variant.as_str()))
                .collect();
            let values: Vec<Vec<f64>> = r
                .improvements
                .iter()
                .map(|imp| {
                    groups
                        .iter()
                        .map(|g| {
                            imp.groups
                                .get(*g)
                                .map_or(f64::NAN, |v| v.time_average_percent)
                        })
                        .collect()
                })
                .collect();
            // A bar is PD when both the aware run and the M-neglected run kept P
            // positive definite throughout in that group.
            let pd = |id: &str, g: &str| {
                let first = GROUPS.iter().find(|(name, _)| *name == g).map(|(_, i)| *i);
                r.runs.iter().find(|run| run.id == id).is_some_and(|run| {
                    first.is_some_and(|i| {
                        group_std_positive_definite(
                            run.covariance_not_positive_definite,
                            &run.covariance_diagonal,
                            i,
                        )
                    })
                })
            };
            let positive_definite: Vec<Vec<bool>> = r
                .improvements
                .iter()
                .map(|imp| {
                    groups
                        .iter()
                        .map(|g| pd(&imp.id, g) && pd(crate::study::BEAMSNET_NEGLECTED, g))
                        .collect()
                })
                .collect();
            bar_chart(
                &staged.path(&format!("{stem}_improvement")),
                &BarChart {
                    title: &format!("{}: time-averaged std improvement over M neglected", r.name),
                    y_label: "improvement of the time-averaged std [%]",
                    groups: &groups,
                    variants: &variants,
                    values: &values,
                    positive_definite: &positive_definite,
                },
            )
            .map_err(plot_err)?;
        }
        // North-east track (paper Fig. 2), equal metres per pixel.
        let tracks: Vec<(&str, &str, &Vec<[f64; 2]>)> =
            std::iter::once(("truth", "truth", &r.truth_north_east))
                .chain(
                    r.runs
                        .iter()
                        .map(|run| (run.id.as_str(), run.name.as_str(), &run.north_east)),
                )
                .collect();
        let east: Vec<Vec<f64>> = tracks
            .iter()
            .map(|t| t.2.iter().map(|p| p[1]).collect())
            .collect();
        let north: Vec<Vec<f64>> = tracks
            .iter()
            .map(|t| t.2.iter().map(|p| p[0]).collect())
            .collect();
        let chart = LineChart {
            title: &format!("{}: north-east track", r.name),
            x_label: "east [m]",
            y_label: "north [m]",
            series: tracks
                .iter()
                .zip(east.iter().zip(&north))
                .map(|(t, (x, y))| Series {
                    id: t.0,
                    label: t.1,
                    x,
                    y,
                })
                .collect(),
            hlines: vec![],
            log_y: false,
            equal_axes: true,
        };
        line_chart(&staged.path(&format!("{stem}_track")), &chart).map_err(plot_err)?;
        // NEES over time with the per-epoch 95 % band of chi-square(15); the line
        // breaks where P was not positive definite (NEES undefined). The band printed
        // with the average NEES is that of a time average: the caption says so.
        let band = estim::core::consistency::chi_square_band(15, 1, 0.95)?;
        let epochs = r.runs.iter().map(|run| run.nees.len()).max().unwrap_or(0);
        let averaged = estim::core::consistency::chi_square_band(15, epochs.max(1), 0.95)?;
        let caption = crate::plots::nees_band_caption(
            [band.lower, band.upper],
            epochs,
            [averaged.lower, averaged.upper],
        );
        let chart = LineChart {
            title: &format!("{}: NEES (15 states) against truth", r.name),
            x_label: "time [s]",
            y_label: "NEES [-] (log scale)",
            series: r
                .runs
                .iter()
                .map(|run| Series {
                    id: &run.id,
                    label: &run.name,
                    x: &run.time,
                    y: &run.nees,
                })
                .collect(),
            hlines: vec![
                ("95% per-epoch band, lower", band.lower),
                ("95% per-epoch band, upper", band.upper),
            ],
            log_y: true,
            equal_axes: false,
        };
        line_chart_captioned(&staged.path(&format!("{stem}_nees")), &chart, &caption)
            .map_err(plot_err)?;
        // Per-axis error against truth with the filter's +-3 sigma, per filter.
        const AXES: [&str; 3] = ["north", "east", "down"];
        for run in &r.runs {
            for (group, first, unit, scale) in [
                ("position", 0, "m", 1.0),
                ("velocity", 3, "m/s", 1.0),
                ("misalignment", 6, "deg", 180.0 / std::f64::consts::PI),
            ] {
                let labels: Vec<String> = AXES
                    .iter()
                    .map(|a| format!("{a} {group} error [{unit}]"))
                    .collect();
                let panels: Vec<ErrorPanel<'_>> = (0..3)
                    .map(|a| ErrorPanel {
                        y_label: &labels[a],
                        error: run
                            .axis_error
                            .iter()
                            .map(|e| e[first + a] * scale)
                            .collect(),
                        three_sigma: run
                            .covariance_diagonal
                            .iter()
                            .map(|d| {
                                let v = d[first + a];
                                // Undefined where the variance is not positive.
                                if v > 0.0 {
                                    3.0 * v.sqrt() * scale
                                } else {
                                    f64::NAN
                                }
                            })
                            .collect(),
                    })
                    .collect();
                error_chart(
                    &staged.path(&format!("{stem}_error_{group}_{}", run.id)),
                    &format!("{}: {} {group} error vs truth, +-3 sigma", r.name, run.name),
                    &run.id,
                    &run.time,
                    &panels,
                )
                .map_err(plot_err)?;
            }
        }
    }
    staged.commit()
}
