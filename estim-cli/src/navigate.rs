//! `estim navigate`: the INS/DVL navigator on a survey's own files (no ground truth
//! needed). Writes, through a staged `--out DIR`, `solution.csv` (the input's own
//! time epoch; position, velocity, attitude, IMU biases, a 1-sigma for each),
//! `track.geojson` and `summary.json`; prints the summary (text, or JSON with
//! `--json`). `--truth GT.csv` adds errors against truth and NEES at the truth's own
//! epochs.
//!
//! The survey's files are read in `survey`, the run's observer is `writer`, the
//! summary is built in `summary`, and a run that stops early is reported by `stop`;
//! `smooth`, `tune` and `stream` share them.

use std::path::PathBuf;

use estim::navigator::{navigate, navigate_learned, NavigationRun, NavigatorError};
use serde_json::{json, Value};

use crate::output::StagedDir;

mod stop;
mod summary;
mod survey;
mod writer;

pub use stop::{stop_json, stopped};
pub use summary::{
    evaluation_json, inputs_json, reference_epochs_evaluation_json, summary_json, summary_text,
    time_offset_json,
};
pub use survey::{
    load_survey, load_survey_from, load_survey_with, refuse_dvl_states, vehicle_config, Survey,
    SurveyFiles,
};
pub use writer::{solution_row, Writer, CSV_HEADER};

/// Arguments of `estim navigate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// IMU CSV (specific force and angular rate, or increments; any rate).
    #[arg(long, value_name = "FILE", required_unless_present = "stream")]
    imu: Option<PathBuf>,
    /// DVL velocity CSV (body frame; lost-lock rows are skipped and counted).
    #[arg(
        long,
        value_name = "FILE",
        conflicts_with_all = ["beams", "pd0", "learned"],
        required_unless_present_any = ["beams", "pd0", "stream"]
    )]
    dvl: Option<PathBuf>,
    /// DVL beams CSV (beam1..beam4; least squares on the beams present).
    #[arg(long, value_name = "FILE", conflicts_with = "pd0")]
    beams: Option<PathBuf>,
    /// With --beams: the embedded BeamsNet on the beams and the IMU windows, with M
    /// from the network's sensitivity, instead of least squares (rows with 3 beams and
    /// the first second stay least squares).
    #[arg(long)]
    learned: bool,
    /// Also draw the track with 3-sigma ellipses, the 1-sigma per state group and the
    /// DVL NIS (PNG and SVG into --out).
    #[arg(long, requires = "out")]
    plots: bool,
    /// Teledyne RDI PD0 binary file: bottom track in the coordinates its fixed leader
    /// declares (beam: least squares; instrument, ship, earth: transformed to the
    /// body frame). Corrupt or truncated ensembles are skipped and reported.
    #[arg(long, value_name = "FILE")]
    pd0: Option<PathBuf>,
    /// Depth CSV (time, depth in m).
    #[arg(long, value_name = "FILE")]
    depth: Option<PathBuf>,
    /// Position fixes CSV (time, lat, lon, sigma).
    #[arg(long, value_name = "FILE")]
    fixes: Option<PathBuf>,
    /// Vehicle configuration TOML (lever arms, noise, time offsets, initial state).
    #[arg(long, value_name = "FILE")]
    vehicle: Option<PathBuf>,
    /// TOML with a `[columns]` table (the input files' column names and units); its
    /// entries override the vehicle file's `[columns]`, quantity by quantity.
    #[arg(long, value_name = "FILE")]
    columns: Option<PathBuf>,
    /// Ground truth CSV: adds errors and NEES at the truth's own epochs (evaluation).
    /// Its clock is aligned to the IMU's (`[truth]` in the vehicle file, else
    /// estimated) and its point carried by `truth.lever_arm_m`.
    #[arg(long, value_name = "FILE")]
    truth: Option<PathBuf>,
    /// With --truth: start from the truth's position, velocity and attitude at the
    /// first IMU sample (after aligning its clock), instead of `[initial]`.
    #[arg(long, requires = "truth")]
    init_from_truth: bool,
    /// Also write a solution at this rate \[Hz\] (besides every DVL epoch).
    #[arg(long, value_name = "HZ")]
    rate: Option<f64>,
    /// Output folder (solution.csv, track.geojson, summary.json).
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Print the summary as JSON on stdout.
    #[arg(long)]
    json: bool,
    /// Read sensor records as JSON lines from stdin in arrival order and write each
    /// solution line (solution.csv's columns, header first) to stdout once final.
    #[arg(
        long,
        conflicts_with_all = ["imu", "dvl", "beams", "pd0", "depth", "fixes", "truth", "learned", "plots"]
    )]
    stream: bool,
    /// With --stream: read the records from FILE, still being written, instead of stdin
    /// (ends when FILE has not grown for --idle-timeout seconds).
    #[arg(long, value_name = "FILE", requires = "stream")]
    follow: Option<PathBuf>,
    /// With --follow: seconds without new data after which the stream ends.
    #[arg(long, value_name = "S", default_value_t = 10.0, requires = "follow")]
    idle_timeout: f64,
    /// With --stream: the history's length [s]: the largest delay a measurement may
    /// have, and the delay of each solution line.
    #[arg(long, value_name = "S", default_value_t = 10.0, requires = "stream")]
    history: f64,
    /// With --stream: also read Water Linked DVL velocity reports (JSON over TCP) from
    /// this address (e.g. 127.0.0.1:16171).
    #[arg(long, value_name = "ADDR", requires = "stream")]
    dvl_tcp: Option<String>,
    /// With --stream: also write, for each update epoch, its fixed-lag smoothed
    /// solution given the measurements up to S seconds after it (rows of kind `lag`).
    #[arg(long, value_name = "S", requires = "stream")]
    lag: Option<f64>,
    /// With --stream: apply each measurement at its own time, splitting the IMU
    /// interval, instead of at the nearest IMU sample (the batch run's rule).
    #[arg(long, requires = "stream")]
    exact_times: bool,
}

impl Args {
    fn files(&self) -> SurveyFiles {
        SurveyFiles {
            sensors: estim::SurveyFiles {
                imu: self.imu.clone().unwrap_or_default(),
                dvl: self.dvl.clone(),
                beams: self.beams.clone(),
                pd0: self.pd0.clone(),
                depth: self.depth.clone(),
                fixes: self.fixes.clone(),
                vehicle: self.vehicle.clone(),
            },
            truth: self.truth.clone(),
            init_from_truth: self.init_from_truth,
        }
    }
}

/// `dvl_sensor` and, for BeamsNet, what it did (times on the navigator's clock,
/// relative to `epoch_s`).
fn learned_json(run: &NavigationRun) -> Value {
    match &run.learned {
        None => json!({ "dvl_sensor": "least_squares" }),
        Some(l) => json!({
            "dvl_sensor": "beamsnet",
            "learned": {
                "model": estim::models::BEAMSNET_NAME,
                "cross_covariance": "network sensitivity (NetworkSensitivity over the filter's recorded IMU window)",
                "beamsnet_updates": l.beamsnet_updates,
                "least_squares_three_beams": l.least_squares_three_beams,
                "least_squares_window_not_full": l.least_squares_window_not_full,
                "first_update": l.first_update.map(|(t, v)| json!({ "time_since_epoch_s": t, "velocity_mps": v })),
            },
        }),
    }
}

/// Run it.
pub fn run(args: Args) -> anyhow::Result<()> {
    if args.stream {
        return crate::stream::run(crate::stream::Options {
            vehicle: args.vehicle,
            history_s: args.history,
            follow: args.follow,
            idle_timeout_s: args.idle_timeout,
            dvl_tcp: args.dvl_tcp,
            exact_times: args.exact_times,
            lag_s: args.lag,
            rate: args.rate,
            out: args.out,
            json: args.json,
        });
    }
    if let Some(rate) = args.rate {
        anyhow::ensure!(
            rate.is_finite() && rate > 0.0,
            "--rate {rate}: not a positive rate"
        );
    }
    let mut staged = args.out.as_deref().map(StagedDir::new).transpose()?;
    if let Some(dir) = &mut staged {
        dir.keep_inputs(args.files().paths().chain(args.columns.as_deref()));
    }
    let mut survey = load_survey_with(args.files(), args.columns.as_deref())?;
    if let Some(truth) = &survey.truth {
        survey.inputs.output_epochs = truth.epochs().to_vec();
    }
    let mut writer = Writer::new(staged.as_ref(), survey.epoch, survey.truth.take())?
        .with_plot_rows(args.plots)
        .scored_at_reference_epochs();
    let network = if args.learned {
        refuse_dvl_states(&survey, "--learned (BeamsNet)")?;
        anyhow::ensure!(
            survey.files.sensors.beams.is_some(),
            "--learned takes a DVL beams CSV (--beams) in the network's beam geometry"
        );
        Some(estim::models::beamsnet()?)
    } else {
        None
    };
    let result = match &network {
        Some(net) => navigate_learned(
            &survey.inputs,
            &survey.settings,
            args.rate,
            &mut writer,
            net,
        ),
        None => navigate(&survey.inputs, &survey.settings, args.rate, &mut writer),
    };
    let run = match result {
        Ok(run) => run,
        Err(e @ (NavigatorError::Filter { .. } | NavigatorError::Diverged { .. })) => {
            return stopped(
                "navigate",
                &survey,
                &mut writer,
                staged,
                &e,
                args.rate,
                args.json,
            );
        }
        Err(e) => return Err(e.into()),
    };
    let evaluation = reference_epochs_evaluation_json(&writer);
    let mut summary = summary_json(
        "navigate",
        &survey,
        &run,
        &run.final_solution,
        args.rate,
        evaluation,
        learned_json(&run),
    );
    if let Some(dir) = staged {
        // Optional: a plot that cannot be drawn is warned about, not the run lost.
        let nis = (&run.dvl_nis_times[..], &run.dvl_nis[..]);
        if let Some(plots) = writer.write_plots(&dir, "navigate", "filter", nis, None) {
            summary["plots"] = plots;
        }
        writer.finish(&dir, "estim navigate track (DVL epochs)", &summary)?;
        dir.commit()?;
    }
    if args.json {
        return crate::output::emit(&format!("{}\n", serde_json::to_string_pretty(&summary)?));
    }
    crate::output::emit(&summary_text(
        "navigated",
        &run,
        &run.final_solution,
        &summary,
    ))
}
