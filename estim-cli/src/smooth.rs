//! `estim smooth`, two call shapes told apart by `--imu`:
//!
//! - on a survey's own files (`--imu` with `--dvl`, `--beams` or `--pd0`, and the other
//!   inputs of `estim navigate`): the navigator's forward pass smoothed (RTS over its
//!   update epochs), written as `navigate` writes its solution (`solution.csv`,
//!   `track.geojson`, `summary.json`);
//! - on the A-KIT reproduction's scenarios (no `--imu`; also `estim reproduce
//!   --smooth`): the 15-state INS/DVL filter on the simulated mission and A-KIT
//!   trajectories, recorded and smoothed, against ground truth. That mode is the
//!   reproduction's code: this file parses its flags ([`ScenarioMode`]) and `main.rs`
//!   hands them to it; the survey mode is [`run`].

use std::path::{Path, PathBuf};

use anyhow::Context;

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
    /// Which IMU an A-KIT trajectory uses: `auto` (the recorded `IMU_trajectoryN.csv`
    /// where the folder holds one, read through the embedded `vehicles/akit.toml` and
    /// smoothed by the navigator's own pass; else synthesized from the reference),
    /// `recorded` (an error where there is none) or `synthesized`.
    #[arg(
        long = "imu-source",
        value_name = "WHICH",
        value_enum,
        default_value = "auto",
        conflicts_with = "imu"
    )]
    imu_source: crate::imu_choice::ImuChoice,
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

/// `estim smooth` as parsed, by call shape.
pub enum Mode {
    /// `--imu`: a survey's own files, smoothed by [`run`].
    Survey(SurveyMode),
    /// No `--imu`: the A-KIT reproduction's scenarios.
    Scenarios(ScenarioMode),
}

/// The survey mode's inputs.
pub struct SurveyMode {
    files: crate::navigate::SurveyFiles,
    columns: Option<PathBuf>,
    out: Option<PathBuf>,
    json: bool,
    plots: bool,
    epochs: estim::core::smoother::RecordAt,
}

/// The scenario mode's flags (no `--imu`), as given.
#[derive(Debug)]
pub struct ScenarioMode {
    /// `--data`.
    pub data: Option<PathBuf>,
    /// `--trajectory` (repeatable).
    pub trajectories: Vec<u32>,
    /// `--imu-source`.
    pub imu_source: crate::imu_choice::ImuChoice,
    /// `--config`.
    pub config: Option<PathBuf>,
    /// `--rho`.
    pub rho: Option<f64>,
    /// `--json`.
    pub json: bool,
    /// `--out`.
    pub out: Option<PathBuf>,
}

impl Args {
    /// The call shape: survey mode with `--imu`, else the scenarios.
    pub fn into_mode(self) -> Mode {
        let Some(imu) = self.imu else {
            return Mode::Scenarios(ScenarioMode {
                data: self.data,
                trajectories: self.trajectories,
                imu_source: self.imu_source,
                config: self.config,
                rho: self.rho,
                json: self.json,
                out: self.out,
            });
        };
        let epochs = if self.epochs == "accepted" {
            estim::core::smoother::RecordAt::Updates
        } else {
            estim::core::smoother::RecordAt::Measurements
        };
        Mode::Survey(SurveyMode {
            files: crate::navigate::SurveyFiles {
                sensors: estim::SurveyFiles {
                    imu,
                    dvl: self.dvl,
                    beams: self.beams,
                    pd0: self.pd0,
                    depth: self.depth,
                    fixes: self.fixes,
                    vehicle: self.vehicle,
                },
                truth: self.truth,
                init_from_truth: self.init_from_truth,
            },
            columns: self.columns,
            out: self.out,
            json: self.json,
            plots: self.plots,
            epochs,
        })
    }
}

/// Run the survey mode.
pub fn run(survey: SurveyMode) -> anyhow::Result<()> {
    let files = &survey.files;
    anyhow::ensure!(
        files.sensors.dvl.is_some() || files.sensors.beams.is_some() || files.sensors.pd0.is_some(),
        "estim smooth --imu: give --dvl, --beams or --pd0"
    );
    smooth_survey_files(
        survey.files,
        survey.columns.as_deref(),
        survey.out.as_deref(),
        survey.json,
        survey.plots,
        survey.epochs,
    )
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
    use crate::navigate::{load_survey_with, summary_json, summary_text, Writer};
    use estim::navigator::{smooth_survey_at, NavigationObserver, NavigatorError};

    let mut staged = out.map(crate::output::StagedDir::new).transpose()?;
    if let Some(dir) = &mut staged {
        dir.keep_inputs(files.paths().chain(columns));
    }
    let mut survey = load_survey_with(files, columns)?;
    let truth = survey.truth.take();
    // Both passes are scored at the reference's own epochs, as `navigate` scores: the
    // forward pass marks them, so the smoother gives a value there too.
    if let Some(truth) = &truth {
        survey.inputs.output_epochs = truth.epochs().to_vec();
    }
    let mut forward = Writer::new(None, survey.epoch, truth.clone())?.scored_at_reference_epochs();
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
    let mut writer = Writer::new(staged.as_ref(), survey.epoch, truth)?
        .with_plot_rows(plots)
        .scored_at_reference_epochs();
    for s in &run.smoothed {
        writer
            .on_solution(s.kind, &s.solution, &s.state, &s.covariance)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    let f = &run.forward.final_solution;
    let extra = serde_json::json!({
        "dvl_sensor": "least_squares",
        "smoother": {
            "method": if run.forward.output_marks.is_empty() {
                "Rauch-Tung-Striebel over the measurement epochs, accepted or gated (estim-core ForwardRecorder, RecordAt::Measurements)"
            } else {
                "Rauch-Tung-Striebel over the measurement epochs, accepted or gated, and the reference's epochs (estim-core ForwardRecorder, RecordAt::Measurements, marked output epochs)"
            },
            "epochs": run.smoothed.len(),
            "forward_final": {
                "time_s": survey.epoch + f.time,
                "latitude_deg": f.latitude_deg,
                "longitude_deg": f.longitude_deg,
                "depth_m": f.depth_m,
                "position_sigma_m": f.position_sigma_m,
            },
            "forward_evaluation": crate::navigate::reference_epochs_evaluation_json(&forward),
        },
    });
    let mut summary = summary_json(
        "smooth",
        &survey,
        &run.forward,
        &last,
        None,
        crate::navigate::reference_epochs_evaluation_json(&writer),
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
