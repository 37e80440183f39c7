//! `estim smooth`, two call shapes told apart by `--imu`:
//!
//! - on a survey's own files (`--imu` with `--dvl`, `--beams` or `--pd0`, and the other
//!   inputs of `estim navigate`): the navigator's forward pass smoothed (RTS over its
//!   update epochs), written as `navigate` writes its solution (`solution.csv`,
//!   `track.geojson`, `summary.json`);
//! - on the study's scenarios (no `--imu`; also `estim reproduce --smooth`): the
//!   15-state INS/DVL filter on the simulated mission and A-KIT trajectories, recorded
//!   and smoothed (exact with correlated noise), smoothed against filtered errors
//!   versus ground truth, plus NEES.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::study::{apply_faults, smooth_scenario, Config, CrossSource, Scenario, SmoothReport};
use anyhow::Context;
use estim::datasets::data_root;
use rayon::prelude::*;

/// Arguments of `estim smooth`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Survey mode: the IMU CSV of a survey (as `estim navigate --imu`); with it, one
    /// of --dvl, --beams, --pd0 and optionally --depth, --fixes, --vehicle, --truth.
    #[arg(long, value_name = "FILE", conflicts_with_all = ["data", "trajectories", "config", "rho"])]
    imu: Option<PathBuf>,
    /// Survey mode: DVL velocity CSV.
    #[arg(long, value_name = "FILE", requires = "imu", conflicts_with_all = ["beams", "pd0"])]
    dvl: Option<PathBuf>,
    /// Survey mode: DVL beams CSV.
    #[arg(long, value_name = "FILE", requires = "imu", conflicts_with = "pd0")]
    beams: Option<PathBuf>,
    /// Survey mode: Teledyne RDI PD0 file.
    #[arg(long, value_name = "FILE", requires = "imu")]
    pd0: Option<PathBuf>,
    /// Survey mode: depth CSV.
    #[arg(long, value_name = "FILE", requires = "imu")]
    depth: Option<PathBuf>,
    /// Survey mode: position fixes CSV.
    #[arg(long, value_name = "FILE", requires = "imu")]
    fixes: Option<PathBuf>,
    /// Survey mode: vehicle configuration TOML.
    #[arg(long, value_name = "FILE", requires = "imu")]
    vehicle: Option<PathBuf>,
    /// Survey mode: TOML with a `[columns]` table overriding the vehicle file's.
    #[arg(long, value_name = "FILE", requires = "imu")]
    columns: Option<PathBuf>,
    /// Survey mode: ground truth CSV (errors and NEES of the filtered and smoothed
    /// solutions at the DVL epochs).
    #[arg(long, value_name = "FILE", requires = "imu")]
    truth: Option<PathBuf>,
    /// Survey mode, with --truth: start from the truth's state at the first IMU sample.
    #[arg(long, requires = "truth")]
    init_from_truth: bool,
    /// Survey mode: `all` smooths at every measurement epoch, accepted or gated (the
    /// epochs `navigate` reports), `accepted` only at those with an accepted update
    /// (the smoothed values there are the same).
    #[arg(long, value_name = "WHICH", requires = "imu", default_value = "all",
          value_parser = ["all", "accepted"])]
    epochs: String,
    /// Survey mode: also draw the smoothed track with 3-sigma ellipses, the 1-sigma
    /// per state group and the forward filter's DVL NIS (PNG and SVG into --out).
    #[arg(long, requires = "imu", requires = "out")]
    plots: bool,
    /// Folder holding A-KIT `TrajectoryN/` (or a data root holding `a-kit/`); its
    /// trajectories are smoothed besides the embedded simulated mission.
    #[arg(long, value_name = "DIR")]
    data: Option<PathBuf>,
    /// A-KIT trajectories to run (repeatable); default 4 and 13 with --data. Without
    /// --data the data is found through `ESTIM_DATA_DIR`, then `../shared/data`.
    #[arg(long = "trajectory", value_name = "N")]
    trajectories: Vec<u32>,
    /// TOML configuration (as for `estim reproduce`).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Correlate the DVL noise with the process noise by the paper's heuristic
    /// M = rho sqrt(diag Q_acc) sqrt(diag R)'; default M = 0.
    #[arg(long, value_name = "RHO")]
    rho: Option<f64>,
    /// Machine-readable JSON on stdout instead of tables.
    #[arg(long)]
    json: bool,
    /// Write CSV time series and plots (PNG, SVG) into this folder.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
}

/// Run it: survey mode with `--imu`, else the study's scenarios.
pub fn run(args: Args) -> anyhow::Result<()> {
    if let Some(imu) = &args.imu {
        let files = crate::navigate::SurveyFiles {
            imu: imu.clone(),
            dvl: args.dvl.clone(),
            beams: args.beams.clone(),
            pd0: args.pd0.clone(),
            depth: args.depth.clone(),
            fixes: args.fixes.clone(),
            vehicle: args.vehicle.clone(),
            truth: args.truth.clone(),
            init_from_truth: args.init_from_truth,
        };
        anyhow::ensure!(
            files.dvl.is_some() || files.beams.is_some() || files.pd0.is_some(),
            "estim smooth --imu: give --dvl, --beams or --pd0"
        );
        let epochs = if args.epochs == "accepted" {
            estim::core::smoother::RecordAt::Updates
        } else {
            estim::core::smoother::RecordAt::Measurements
        };
        return smooth_survey_files(
            files,
            args.columns.as_deref(),
            args.out.as_deref(),
            args.json,
            args.plots,
            epochs,
        );
    }
    let config = match &args.config {
        Some(path) => Config::from_file(path)?,
        None => Config::default(),
    };
    let cross = match args.rho {
        None => CrossSource::Zero,
        Some(rho) if rho.is_finite() && (-1.0..=1.0).contains(&rho) => CrossSource::Scaled(rho),
        Some(rho) => anyhow::bail!("--rho {rho}: a correlation must be finite and in [-1, 1]"),
    };
    // Checked before any work: an unwritable --out fails now, naming the folder.
    let mut staged = match &args.out {
        Some(dir) => Some(crate::output::StagedDir::new(dir)?),
        None => None,
    };
    if let Some(dir) = &mut staged {
        dir.keep_inputs(
            [&args.config, &args.data]
                .into_iter()
                .flatten()
                .map(PathBuf::as_path),
        );
    }
    let mut scenarios = vec![Scenario::simulated(&config, config.seed)?];
    if args.data.is_some() || !args.trajectories.is_empty() {
        let dir = data_root(args.data.as_deref()).context(
            "--trajectory needs the A-KIT data: pass --data DIR, set ESTIM_DATA_DIR, \
             or place it at ../shared/data",
        )?;
        let list = if args.trajectories.is_empty() {
            vec![4, 13]
        } else {
            args.trajectories.clone()
        };
        for n in list {
            scenarios.push(Scenario::akit(&dir, n, &config, config.seed)?);
        }
    }
    for s in &mut scenarios {
        apply_faults(s, &config.faults, config.seed)?;
    }
    let reports = smooth_all(&scenarios, &config, &cross)?;
    if let Some(staged) = staged {
        write_files(&staged.path(""), &reports)?;
        staged.commit()?;
    }
    let mut text = String::new();
    if args.json {
        use crate::schema::{document, path_json};
        let inputs = serde_json::json!({
            "data": path_json(args.data.as_deref()),
            "trajectories": args.trajectories,
            "config_file": path_json(args.config.as_deref()),
            "rho": args.rho,
            "out": path_json(args.out.as_deref()),
            "seed": config.seed,
            // The study's smoother runs on an IMU synthesized from the ground truth.
            "imu_source": "synthesized",
            "config": config,
        });
        let doc = document(
            "smooth",
            inputs,
            0,
            serde_json::json!({ "reports": reports }),
        );
        writeln!(text, "{}", serde_json::to_string_pretty(&doc)?)?;
    } else {
        print_reports(&mut text, &reports)?;
    }
    crate::output::emit(&text)
}

/// Survey mode: forward pass, smoothing, and the smoothed solution written as
/// `estim navigate` writes its own (the summary adds the forward pass's figures).
fn smooth_survey_files(
    files: crate::navigate::SurveyFiles,
    columns: Option<&Path>,
    out: Option<&Path>,
    json: bool,
    plots: bool,
    epochs: estim::core::smoother::RecordAt,
) -> anyhow::Result<()> {
    use crate::navigate::{evaluation_json, load_survey_with, summary_json, summary_text, Writer};
    use estim::navigator::{smooth_survey_at, NavigationObserver, NavigatorError};

    let mut staged = out.map(crate::output::StagedDir::new).transpose()?;
    if let Some(dir) = &mut staged {
        dir.keep_inputs(files.paths().chain(columns));
    }
    let mut survey = load_survey_with(files, columns)?;
    let truth = survey.truth.take();
    let mut forward = Writer::new(None, survey.epoch, truth.clone())?;
    let run = match smooth_survey_at(&survey.inputs, &survey.settings, None, &mut forward, epochs) {
        Ok(run) => run,
        Err(e @ (NavigatorError::Filter { .. } | NavigatorError::Diverged { .. })) => {
            return forward_stopped(&survey, staged, &e, plots, json);
        }
        Err(NavigatorError::Smoother(e)) => {
            anyhow::bail!("{e}; nothing was smoothed, nothing written")
        }
        Err(e) => return Err(e.into()),
    };
    let last = run
        .smoothed
        .last()
        .map_or(run.forward.final_solution, |s| s.solution);
    let mut writer = Writer::new(staged.as_ref(), survey.epoch, truth)?.with_plot_rows(plots);
    for s in &run.smoothed {
        writer
            .on_solution(s.kind, &s.solution, &s.state, &s.covariance)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    let f = &run.forward.final_solution;
    let extra = serde_json::json!({
        "dvl_sensor": "least_squares",
        "smoother": {
            "method": "Rauch-Tung-Striebel over the measurement epochs, accepted or gated (estim-core ForwardRecorder, RecordAt::Measurements)",
            "epochs": run.smoothed.len(),
            "forward_final": {
                "time_s": survey.epoch + f.time,
                "latitude_deg": f.latitude_deg,
                "longitude_deg": f.longitude_deg,
                "depth_m": f.depth_m,
                "position_sigma_m": f.position_sigma_m,
            },
            "forward_evaluation": evaluation_json(forward.truth()),
        },
    });
    let mut summary = summary_json(
        "smooth",
        &survey,
        &run.forward,
        &last,
        None,
        evaluation_json(writer.truth()),
        extra,
    );
    if let Some(dir) = staged {
        // Optional: a plot that cannot be drawn is warned about, not the run lost.
        let nis = (&run.forward.dvl_nis_times[..], &run.forward.dvl_nis[..]);
        if let Some(plots) = writer.write_plots(&dir, "smooth", "smoothed", nis, None) {
            summary["plots"] = plots;
        }
        writer.finish(&dir, "estim smooth track (smoothed, DVL epochs)", &summary)?;
        dir.commit()?;
    }
    if json {
        return crate::output::emit(&format!("{}\n", serde_json::to_string_pretty(&summary)?));
    }
    crate::output::emit(&summary_text("smoothed", &run.forward, &last, &summary))
}

/// The forward pass stopped (divergence or a numerical failure): nothing was
/// smoothed, so no solution is kept. With `--out`, only `summary.json` is committed,
/// marked `partial`, with the stop and `"smoothed_epochs": 0`; exit 3 says so. With
/// `--plots`, no plot is drawn and the summary's `plots` block says why.
fn forward_stopped(
    survey: &crate::navigate::Survey,
    staged: Option<crate::output::StagedDir>,
    error: &estim::navigator::NavigatorError,
    plots: bool,
    json: bool,
) -> anyhow::Result<()> {
    let (status, stop) = crate::navigate::stop_json(survey.epoch, error);
    let mut summary = crate::schema::document(
        "smooth",
        crate::navigate::inputs_json(survey, None),
        0,
        serde_json::json!({
            "epoch_s": survey.epoch,
            "partial": true,
            "stop": stop,
            "smoothed_epochs": 0,
            "kept": "nothing: the forward pass stopped before smoothing, no solution is written",
        }),
    );
    summary["status"] = serde_json::json!(status);
    if plots {
        summary["plots"] = serde_json::json!({
            "written": false,
            "reason": "the forward pass stopped: nothing was smoothed, nothing to draw",
        });
    }
    let kept = match staged {
        Some(dir) => {
            let path = dir.target().join("summary.json");
            std::fs::write(
                dir.path("summary.json"),
                serde_json::to_string_pretty(&summary)?,
            )
            .with_context(|| format!("{}: cannot write", path.display()))?;
            dir.commit()?;
            format!(
                "nothing was smoothed and no solution is kept; {} records the stop",
                path.display()
            )
        }
        None => "nothing was smoothed and nothing written".to_string(),
    };
    if json {
        crate::output::emit(&format!("{}\n", serde_json::to_string_pretty(&summary)?))?;
    }
    Err(crate::schema::RunStopped {
        message: format!(
            "smooth: the forward pass {status} at t = {} s: {}; {kept}",
            stop["time_s"],
            stop["reason"].as_str().unwrap_or("")
        ),
    }
    .into())
}

/// Smooth every scenario (in parallel), M = 0 or the given cross-covariance.
pub fn smooth_all(
    scenarios: &[Scenario],
    config: &Config,
    cross: &CrossSource,
) -> anyhow::Result<Vec<SmoothReport>> {
    scenarios
        .par_iter()
        .map(|s| {
            smooth_scenario(s, config, cross, config.seed)
                .with_context(|| format!("smoothing {}", s.name))
        })
        .collect()
}

/// The filtered-against-smoothed tables.
pub fn print_reports(out: &mut String, reports: &[SmoothReport]) -> std::fmt::Result {
    for r in reports {
        writeln!(
            out,
            "== {} (IMU synthesized from the ground truth, LS DVL, {}, {} epochs): filtered \
             vs smoothed against ground truth",
            r.name,
            r.cross,
            r.time.len()
        )?;
        writeln!(
            out,
            "{:<10} {:>12} {:>12} {:>14} {:>14} {:>10}",
            "", "pos RMSE m", "pos final m", "vel RMSE m/s", "att RMSE deg", "mean NEES"
        )?;
        for (name, s) in [
            ("filtered", &r.filtered_summary),
            ("smoothed", &r.smoothed_summary),
        ] {
            writeln!(
                out,
                "{:<10} {:>12.3} {:>12.3} {:>14.4} {:>14.4} {:>10.2}",
                name,
                s.position_m.rmse,
                s.position_m.final_value,
                s.velocity_mps.rmse,
                s.attitude_deg.rmse,
                s.mean_nees
            )?;
        }
        writeln!(
            out,
            "(NEES of the 15-state error; 15 for a consistent estimate)\n"
        )?;
    }
    Ok(())
}

/// File-name stem of a report.
fn slug(r: &SmoothReport) -> String {
    match r.trajectory {
        Some(n) => format!("trajectory{n}"),
        None => "simulated".to_string(),
    }
}

/// CSV time series and the position-error plot of every report, into `dir` (a
/// folder inside a staging folder: the caller commits it with its other outputs).
pub fn write_files(dir: &Path, reports: &[SmoothReport]) -> anyhow::Result<()> {
    use crate::plots::{line_chart, LineChart, Series};
    use std::io::Write;

    let file = |name: &str| dir.join(name);
    std::fs::write(
        file("smoothing.json"),
        serde_json::to_string_pretty(reports)?,
    )
    .with_context(|| format!("{}: cannot write", file("smoothing.json").display()))?;
    for r in reports {
        let stem = slug(r);
        let path = file(&format!("{stem}_smoothing.csv"));
        // A write error (a full disk) names the file.
        let named = |e: std::io::Error| anyhow::anyhow!("{}: cannot write: {e}", path.display());
        let mut w = std::io::BufWriter::new(
            std::fs::File::create(&path)
                .with_context(|| format!("{}: cannot create", path.display()))?,
        );
        writeln!(
            w,
            "time_s,filtered_position_error_m,filtered_position_3sigma_m,smoothed_position_error_m,smoothed_position_3sigma_m,filtered_velocity_error_mps,smoothed_velocity_error_mps,filtered_attitude_error_deg,smoothed_attitude_error_deg,filtered_nees,smoothed_nees"
        )
        .map_err(named)?;
        let (f, s) = (&r.filtered, &r.smoothed);
        for k in 0..r.time.len() {
            writeln!(
                w,
                "{},{},{},{},{},{},{},{},{},{},{}",
                r.time[k],
                f.position_error[k],
                f.position_3sigma[k],
                s.position_error[k],
                s.position_3sigma[k],
                f.velocity_error[k],
                s.velocity_error[k],
                f.attitude_error_deg[k],
                s.attitude_error_deg[k],
                f.nees[k],
                s.nees[k]
            )
            .map_err(named)?;
        }
        w.flush().map_err(named)?;
        drop(w);
        let chart = LineChart {
            title: &format!("{}: position error, filtered and smoothed", r.name),
            x_label: "time [s]",
            y_label: "|position error| and 3 sqrt(trace P_pos) [m]",
            series: vec![
                Series {
                    id: "smooth_filtered",
                    label: "filtered error",
                    x: &r.time,
                    y: &f.position_error,
                },
                Series {
                    id: "smooth_filtered_3sigma",
                    label: "filtered 3-sigma",
                    x: &r.time,
                    y: &f.position_3sigma,
                },
                Series {
                    id: "smooth_smoothed",
                    label: "smoothed error",
                    x: &r.time,
                    y: &s.position_error,
                },
                Series {
                    id: "smooth_smoothed_3sigma",
                    label: "smoothed 3-sigma",
                    x: &r.time,
                    y: &s.position_3sigma,
                },
            ],
            hlines: vec![],
            log_y: false,
            equal_axes: false,
        };
        line_chart(&file(&format!("{stem}_smoothed_position")), &chart)
            .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
    }
    Ok(())
}
