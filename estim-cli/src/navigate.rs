//! `estim navigate`: the INS/DVL navigator on a survey's own files (no ground truth
//! needed). Writes, through a staged `--out DIR`, `solution.csv` (the input's own
//! time epoch; position, velocity, attitude, IMU biases, a 1-sigma for each),
//! `track.geojson` and `summary.json`; prints the summary (text, or JSON with
//! `--json`). `--truth GT.csv` adds errors against truth and NEES at the DVL epochs.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;
use estim::ins::{ErrorMatrix, InsState};
use estim::navigator::{
    format_heading, navigate, navigate_learned, NavSolution, NavigationObserver, NavigationRun,
    NavigatorConfig, NavigatorError, NavigatorSettings, SolutionKind, SurveyInputs,
};
use estim::truth::{Truth, TruthTimeOffset};
use estim::{Pd0Load, SurveyError};
use serde_json::{json, Value};

use crate::output::StagedDir;
use crate::schema;

/// The survey's input files, shared by `estim navigate` and `estim smooth`.
#[derive(Debug, Clone, Default)]
pub struct SurveyFiles {
    /// IMU CSV.
    pub imu: PathBuf,
    /// DVL velocity CSV.
    pub dvl: Option<PathBuf>,
    /// DVL beams CSV.
    pub beams: Option<PathBuf>,
    /// Teledyne RDI PD0 file.
    pub pd0: Option<PathBuf>,
    /// Depth CSV.
    pub depth: Option<PathBuf>,
    /// Position fixes CSV.
    pub fixes: Option<PathBuf>,
    /// Vehicle TOML.
    pub vehicle: Option<PathBuf>,
    /// Ground truth CSV.
    pub truth: Option<PathBuf>,
    /// Start from the truth's state at the first IMU sample (position, velocity,
    /// attitude), replacing `[initial]`'s.
    pub init_from_truth: bool,
}

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

impl SurveyFiles {
    /// Every input path given (for [`StagedDir::keep_inputs`]).
    pub fn paths(&self) -> impl Iterator<Item = &Path> {
        [
            &self.dvl,
            &self.beams,
            &self.pd0,
            &self.depth,
            &self.fixes,
            &self.vehicle,
            &self.truth,
        ]
        .into_iter()
        .flatten()
        .map(PathBuf::as_path)
        .chain([self.imu.as_path()])
    }
}

impl Args {
    fn files(&self) -> SurveyFiles {
        SurveyFiles {
            imu: self.imu.clone().unwrap_or_default(),
            dvl: self.dvl.clone(),
            beams: self.beams.clone(),
            pd0: self.pd0.clone(),
            depth: self.depth.clone(),
            fixes: self.fixes.clone(),
            vehicle: self.vehicle.clone(),
            truth: self.truth.clone(),
            init_from_truth: self.init_from_truth,
        }
    }
}

/// Read and check a vehicle TOML; errors name the file and line.
pub fn vehicle_config(path: &Path) -> anyhow::Result<NavigatorConfig> {
    Ok(estim::truth::read_vehicle(path)?)
}

/// The reference's clock offset in effect, as the summary gives it (`source`,
/// `offset_s`, and for an estimate its `sigma_s`, `residual_rad`, `intervals`).
pub fn time_offset_json(offset: &TruthTimeOffset) -> Value {
    match offset {
        TruthTimeOffset::Vehicle(tau) => json!({ "source": "vehicle", "offset_s": tau }),
        TruthTimeOffset::Estimated(est) => json!({
            "source": "estimated",
            "offset_s": est.offset_s,
            "sigma_s": est.sigma_s,
            "residual_rad": est.residual_rad,
            "intervals": est.intervals,
        }),
    }
}

/// Writes the solution CSV as the run goes, keeps the track and evaluates truth.
pub struct Writer {
    epoch_s: f64,
    /// The solutions scored against the truth: the reference's own epochs
    /// ([`SolutionKind::Epoch`]) or the DVL epochs.
    scored: SolutionKind,
    last: Option<NavSolution>,
    rows: usize,
    csv: Option<std::io::BufWriter<std::fs::File>>,
    /// Where `solution.csv` goes once committed (named in write errors).
    csv_target: PathBuf,
    line: String,
    track: Vec<[f64; 2]>,
    truth: Option<Truth>,
    /// With scoring at the reference's epochs, the same truth scored at the DVL
    /// epochs (interpolated), as `estim reproduce` scores.
    dvl_truth: Option<Truth>,
    plot_rows: Option<Vec<crate::navigate_plots::PlotRow>>,
}

/// The header of `solution.csv` (also the first line of `navigate --stream`).
pub const CSV_HEADER: &str = "time_s,kind,latitude_deg,longitude_deg,depth_m,v_north_mps,v_east_mps,v_down_mps,roll_deg,pitch_deg,heading_deg,acc_bias_x_mps2,acc_bias_y_mps2,acc_bias_z_mps2,gyro_bias_x_radps,gyro_bias_y_radps,gyro_bias_z_radps,sigma_north_m,sigma_east_m,sigma_down_m,sigma_v_north_mps,sigma_v_east_mps,sigma_v_down_mps,sigma_roll_deg,sigma_pitch_deg,sigma_heading_deg,sigma_acc_bias_x_mps2,sigma_acc_bias_y_mps2,sigma_acc_bias_z_mps2,sigma_gyro_bias_x_radps,sigma_gyro_bias_y_radps,sigma_gyro_bias_z_radps\n";

impl NavigationObserver for Writer {
    fn on_solution(
        &mut self,
        kind: SolutionKind,
        s: &NavSolution,
        state: &InsState,
        covariance: &ErrorMatrix,
    ) -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
        if let Some(rows) = &mut self.plot_rows {
            rows.push(crate::navigate_plots::PlotRow::new(kind, s, covariance));
        }
        if matches!(kind, SolutionKind::Dvl | SolutionKind::End) {
            self.track.push([s.longitude_deg, s.latitude_deg]);
        }
        if kind == self.scored {
            if let Some(truth) = &mut self.truth {
                truth
                    .score(s.time, state, covariance)
                    .map_err(|e| e.to_string())?;
            }
        }
        if kind == SolutionKind::Dvl {
            if let Some(truth) = &mut self.dvl_truth {
                truth
                    .score(s.time, state, covariance)
                    .map_err(|e| e.to_string())?;
            }
        }
        if kind == SolutionKind::Epoch {
            // A reference epoch: scored, not a row of the solution.
            return Ok(());
        }
        self.write_row(kind, s)
    }
}

impl Writer {
    fn write_row(
        &mut self,
        kind: SolutionKind,
        s: &NavSolution,
    ) -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
        self.last = Some(*s);
        self.rows += 1;
        if let Some(csv) = &mut self.csv {
            let l = &mut self.line;
            solution_row(l, self.epoch_s, kind.as_str(), s);
            csv.write_all(l.as_bytes())
                .map_err(|e| format!("{}: cannot write: {e}", self.csv_target.display()))?;
        }
        Ok(())
    }
}

/// One line of `solution.csv` (with its newline) into `l`: `s` at `epoch_s + s.time`,
/// `kind` in the `kind` column.
pub fn solution_row(l: &mut String, epoch_s: f64, kind: &str, s: &NavSolution) {
    l.clear();
    let _ = write!(
        l,
        "{},{kind},{:.9},{:.9},{:.4},{:.5},{:.5},{:.5},{:.5},{:.5},{}",
        epoch_s + s.time,
        s.latitude_deg,
        s.longitude_deg,
        s.depth_m,
        s.velocity_ned_mps[0],
        s.velocity_ned_mps[1],
        s.velocity_ned_mps[2],
        s.roll_deg,
        s.pitch_deg,
        format_heading(s.heading_deg, 5)
    );
    for v in s.acc_bias_mps2.iter().chain(&s.gyro_bias_radps) {
        let _ = write!(l, ",{v:.4e}");
    }
    for v in s.position_sigma_m.iter().chain(&s.velocity_sigma_mps) {
        let _ = write!(l, ",{v:.5}");
    }
    for v in &s.attitude_sigma_deg {
        let _ = write!(l, ",{v:.6}");
    }
    for v in s.acc_bias_sigma_mps2.iter().chain(&s.gyro_bias_sigma_radps) {
        let _ = write!(l, ",{v:.4e}");
    }
    l.push('\n');
}

fn stats(values: &[f64]) -> Value {
    let finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if finite.is_empty() {
        return json!({ "count": values.len(), "mean": null, "max": null });
    }
    let mean = finite.iter().sum::<f64>() / finite.len() as f64;
    let max = finite.iter().copied().fold(f64::MIN, f64::max);
    json!({ "count": values.len(), "mean": mean, "max": max })
}

/// A survey read and checked: what `navigate` and `smooth` run on.
pub struct Survey {
    /// The files it came from.
    pub files: SurveyFiles,
    /// The vehicle configuration in effect.
    pub config: NavigatorConfig,
    /// Its checked form (with a PD0 file's beam layout).
    pub settings: NavigatorSettings,
    /// The time-ordered inputs.
    pub inputs: SurveyInputs,
    /// The epoch \[s\] every time is relative to (the IMU file's).
    pub epoch: f64,
    /// Truth for the evaluation, with `--truth`.
    pub truth: Option<Truth>,
    /// What the PD0 reader and conversion did, with `--pd0`.
    pub pd0: Option<Value>,
    /// Warnings about the inputs (each `code`, `file`, `message`), also printed on
    /// stderr: the summary's `warnings`.
    pub warnings: Vec<Value>,
}

/// What the PD0 reader and conversion did, as the summary's `pd0` block.
fn pd0_json(load: &Pd0Load) -> Value {
    let (report, conversion) = (&load.report, &load.conversion);
    let skipped: Vec<Value> = report
        .skipped
        .iter()
        .map(|s| json!({ "offset": s.offset, "length": s.length, "reason": s.issue.to_string() }))
        .collect();
    json!({
        "input_bytes": report.input_bytes,
        "ensembles": report.decoded,
        "with_bottom_track": report.with_bottom_track,
        "warnings": report.skipped.len(),
        "skipped": skipped,
        "coordinate_systems": {
            "beam": conversion.beam,
            "instrument": conversion.instrument,
            "ship": conversion.ship,
            "earth": conversion.earth,
        },
        "without_bottom_track": conversion.without_bottom_track,
        "bad_velocity_values": conversion.bad_velocity_values,
        "beam_angle_deg": load.beam_angle_deg,
        "beam_angle_from": if conversion.beam_angle_deg.is_some() { "fixed_leader" } else { "vehicle" },
        "head": if conversion.convex { "convex" } else { "concave" },
        "earth_frame": "rotated into the body frame with the filter's attitude at each update",
    })
}

/// Read and check every input of a survey (errors name the file and line).
pub fn load_survey(files: SurveyFiles) -> anyhow::Result<Survey> {
    load_survey_with(files, None)
}

/// [`load_survey`] with a `--columns` file whose `[columns]` entries override the
/// vehicle file's.
pub fn load_survey_with(files: SurveyFiles, columns: Option<&Path>) -> anyhow::Result<Survey> {
    let mut config = match &files.vehicle {
        Some(p) => vehicle_config(p)?,
        None => NavigatorConfig::default(),
    };
    if let Some(path) = columns {
        let over = crate::survey_checks::columns_file(path)?;
        config.columns = config.columns.overridden_by(&over).map_err(|e| {
            let vehicle = files.vehicle.as_deref().unwrap_or(Path::new("vehicle"));
            anyhow::anyhow!("{}: {e}", vehicle.display())
        })?;
    }
    load_survey_from(files, config)
}

/// [`load_survey`] with the vehicle configuration already read (`files.vehicle` only
/// names it in messages), e.g. a vehicle embedded in the binary.
pub fn load_survey_from(files: SurveyFiles, config: NavigatorConfig) -> anyhow::Result<Survey> {
    let sensors = estim::SurveyFiles {
        imu: files.imu.clone(),
        dvl: files.dvl.clone(),
        beams: files.beams.clone(),
        pd0: files.pd0.clone(),
        depth: files.depth.clone(),
        fixes: files.fixes.clone(),
        vehicle: files.vehicle.clone(),
    };
    // Skipped PD0 spans are warned about on stderr with their byte offsets as they are
    // found, and listed in the summary's `pd0` block.
    let mut loaded = sensors
        .read(&config, &mut |path, skip| {
            eprintln!("warning: {}: {skip}", path.display());
        })
        .map_err(|e| match e {
            SurveyError::NoDvl => anyhow::anyhow!("give --dvl, --beams or --pd0"),
            e => e.into(),
        })?;
    let epoch = loaded.epoch;
    let truth = match &files.truth {
        Some(p) => Some(Truth::load(p, &loaded, &config)?),
        None => None,
    };
    let mut config = config;
    if files.init_from_truth || (config.truth.initial_state && truth.is_some()) {
        let truth = truth.as_ref().context("--init-from-truth needs --truth")?;
        // The run starts at the first of the truth's own epochs inside the IMU's span
        // (the truth is exact there, interpolated between).
        truth.set_initial(&loaded, &mut config)?;
    }
    // `initial.time_s` is in the inputs' own time; the navigator's clock runs from the
    // IMU file's epoch.
    loaded.settle_initial(&config)?;
    let pd0 = loaded.pd0.as_ref().map(pd0_json);
    let (settings, inputs) = (loaded.settings, loaded.inputs);
    crate::aiding_span::check_survey(&files, &config, &inputs, epoch)?;
    let warnings = crate::survey_checks::check_dvl_lock(&files, &inputs)?;
    Ok(Survey {
        files,
        config,
        settings,
        inputs,
        epoch,
        truth,
        pd0,
        warnings,
    })
}

impl Writer {
    /// A writer of `solution.csv` in `dir` (none without a folder), evaluating `truth`.
    pub fn new(
        dir: Option<&StagedDir>,
        epoch_s: f64,
        truth: Option<Truth>,
    ) -> anyhow::Result<Self> {
        let csv_target = dir.map_or_else(PathBuf::new, |d| d.target().join("solution.csv"));
        let csv = match dir {
            Some(dir) => {
                let path = dir.path("solution.csv");
                let file = std::fs::File::create(&path)
                    .with_context(|| format!("{}: cannot create", csv_target.display()))?;
                let mut w = std::io::BufWriter::new(file);
                w.write_all(CSV_HEADER.as_bytes())
                    .with_context(|| format!("{}: cannot write", csv_target.display()))?;
                Some(w)
            }
            None => None,
        };
        Ok(Self {
            epoch_s,
            scored: SolutionKind::Dvl,
            last: None,
            rows: 0,
            csv,
            csv_target,
            line: String::new(),
            track: Vec::new(),
            truth,
            dvl_truth: None,
            plot_rows: None,
        })
    }

    /// Score the truth at the reference's own epochs (the run's
    /// [`SurveyInputs::output_epochs`] must be the truth's epochs).
    #[must_use]
    pub fn scored_at_reference_epochs(mut self) -> Self {
        self.scored = SolutionKind::Epoch;
        self.dvl_truth = self.truth.clone();
        self
    }

    /// The evaluation at the DVL epochs, when the main one is at the reference's.
    pub fn dvl_epoch_truth(&self) -> Option<&Truth> {
        self.dvl_truth.as_ref()
    }

    /// Keep every solution for the plots.
    #[must_use]
    pub fn with_plot_rows(mut self, keep: bool) -> Self {
        self.plot_rows = keep.then(Vec::new);
        self
    }

    /// Write the plots of the kept solutions (and the truth's track over their span)
    /// into `dir`: the summary's `plots` block, or `None` when no plot was asked for.
    pub fn write_plots(
        &self,
        dir: &StagedDir,
        command: &str,
        solution_label: &str,
        nis: (&[f64], &[f64]),
        stopped: Option<&str>,
    ) -> Option<Value> {
        let rows = self.plot_rows.as_deref()?;
        let truth = match (self.truth.as_ref(), rows.first(), rows.last()) {
            (Some(t), Some(a), Some(b)) => t.track_deg(a.time, b.time),
            _ => Vec::new(),
        };
        Some(crate::navigate_plots::write_plots_or_warn(
            &dir.path(""),
            &crate::navigate_plots::PlotData {
                command,
                solution_label,
                rows,
                nis_times: nis.0,
                nis: nis.1,
                truth: &truth,
                stopped,
            },
        ))
    }

    /// The evaluation against truth, if any.
    pub fn truth(&self) -> Option<&Truth> {
        self.truth.as_ref()
    }

    /// Flush the CSV and write `track.geojson` and `summary.json` into `dir` (the
    /// caller commits the staged folder).
    pub fn finish(
        &mut self,
        dir: &StagedDir,
        track_name: &str,
        summary: &Value,
    ) -> anyhow::Result<()> {
        // Write errors name the file as it will be in --out (a full disk).
        let write = |name: &str, text: &[u8]| {
            std::fs::write(dir.path(name), text)
                .with_context(|| format!("{}: cannot write", dir.target().join(name).display()))
        };
        if let Some(mut csv) = self.csv.take() {
            csv.flush()
                .with_context(|| format!("{}: cannot write", self.csv_target.display()))?;
        }
        if let Some(truth) = &self.truth {
            let mut text = String::from(
                "time_s,error_north_m,error_east_m,error_down_m,error_v_north_mps,error_v_east_mps,error_v_down_mps,error_roll_axis_deg,error_pitch_axis_deg,error_heading_deg,sigma_north_m,sigma_east_m,sigma_down_m,sigma_v_north_mps,sigma_v_east_mps,sigma_v_down_mps,sigma_roll_axis_deg,sigma_pitch_axis_deg,sigma_heading_deg\n",
            );
            for row in truth.rows() {
                let _ = write!(text, "{}", self.epoch_s + row[0]);
                for v in &row[1..] {
                    let _ = write!(text, ",{v:.6e}");
                }
                text.push('\n');
            }
            write("errors.csv", text.as_bytes())?;
        }
        let track = json!({
            "type": "FeatureCollection",
            "features": [{
                "type": "Feature",
                "properties": { "name": track_name },
                "geometry": { "type": "LineString", "coordinates": self.track },
            }],
        });
        write("track.geojson", serde_json::to_string(&track)?.as_bytes())?;
        write(
            "summary.json",
            serde_json::to_string_pretty(summary)?.as_bytes(),
        )?;
        Ok(())
    }
}

/// The evaluation block of the summary (position RMSE, final error, NEES at the DVL
/// epochs).
pub fn evaluation_json(truth: Option<&Truth>) -> Value {
    let Some(t) = truth else { return Value::Null };
    let e = t.evaluation();
    // No epoch scored: every figure is null, with the reason (never an RMSE of 0).
    let not_scored = (e.epochs == 0).then(|| {
        format!(
            "no solution epoch was scored against the truth ({} outside its span); scored at \
             the DVL epochs, a run without a DVL update has none",
            e.epochs_outside_truth
        )
    });
    json!({
        "horizontal_position_rmse_m": e.horizontal_position_rmse_m,
        "nees_per_group": {
            "position": e.nees_per_group[0],
            "velocity": e.nees_per_group[1],
            "attitude": e.nees_per_group[2],
        },
        "epochs": e.epochs,
        "epochs_outside_truth": e.epochs_outside_truth,
        "truth_time_offset_s": t.time_offset().offset_s(),
        "truth_time_offset": time_offset_json(t.time_offset()),
        "truth_velocity_bias": t.velocity_bias().map(|b| json!({
            "bias_mps": b.bias_mps,
            "sigma_mps": b.sigma_mps,
            "residual_rms_m": b.residual_rms_m,
            "intervals": b.intervals,
            "removed": b.removed,
        })),
        "position_rmse_m": e.position_rmse_m,
        "final_position_error_m": e.final_position_error_m,
        "nees_average": e.nees_average,
        "nees_states": e.nees_states,
        "covariance_not_positive_definite_epochs": e.covariance_not_positive_definite_epochs,
        "not_scored_reason": not_scored,
    })
}

/// Which DVL sensor a run used, for the summary.
pub fn dvl_source(files: &SurveyFiles) -> &'static str {
    match (&files.dvl, &files.beams, &files.pd0) {
        (Some(_), _, _) => "velocity_csv",
        (None, Some(_), _) => "beams_csv",
        _ => "pd0",
    }
}

/// The summary document of a survey run (`command` = `navigate` or `smooth`):
/// `inputs`, the run's counts and NIS, the final solution of `last` (the filter's, or
/// the smoother's), the evaluation, and the `extra` fields merged at the top level.
pub fn summary_json(
    command: &str,
    survey: &Survey,
    run: &NavigationRun,
    last: &NavSolution,
    rate: Option<f64>,
    evaluation: Value,
    extra: Value,
) -> Value {
    let files = &survey.files;
    let epoch = survey.epoch;
    let counts = |c: &estim::navigator::UpdateCounts| json!({ "accepted": c.accepted, "gated": c.gated, "recovered": c.recovered });
    let f = last;
    let mut body = json!({
        "epoch_s": epoch,
        "time_span_s": [epoch + run.span_s[0], epoch + run.span_s[1]],
        "imu_samples": run.imu_samples,
        "imu_period_s": run.imu_period_s,
        "initial": run.alignment,
        "dvl_source": dvl_source(files),
        "updates": {
            "dvl": counts(&run.dvl),
            "depth": counts(&run.depth),
            "fixes": counts(&run.fixes),
        },
        "dvl_no_lock_rows": run.dvl_no_lock,
        "dvl_insufficient_beam_rows": run.dvl_insufficient_beams,
        "outside_imu_span": run.outside_imu_span,
        "dvl_gaps_coasted": run.dvl_gaps_coasted,
        "longest_dvl_gap_s": run.longest_dvl_gap_s,
        "dvl_noise_scale": run.dvl_noise_scale,
        "dvl_states": dvl_states_json(run, &survey.config),
        "nis": {
            "dvl": stats(&run.dvl_nis),
            "depth": stats(&run.depth_nis),
            "fixes": stats(&run.fix_nis),
        },
        "pd0": survey.pd0,
        "warnings": survey.warnings,
        "solutions": run.solutions,
        "final": {
            "time_s": epoch + f.time,
            "latitude_deg": f.latitude_deg,
            "longitude_deg": f.longitude_deg,
            "depth_m": f.depth_m,
            "position_sigma_m": f.position_sigma_m,
            "heading_deg": f.heading_deg,
            "heading_sigma_deg": f.attitude_sigma_deg[2],
        },
        "evaluation": evaluation,
    });
    if let (Some(b), Value::Object(e)) = (body.as_object_mut(), extra) {
        b.extend(e);
    }
    schema::document(command, inputs_json(survey, rate), 0, body)
}

/// The summary's `inputs` block of a survey run (`navigate`, `smooth`; a completed or
/// a stopped run): every input path, the rate and the configuration in effect.
pub fn inputs_json(survey: &Survey, rate: Option<f64>) -> Value {
    let files = &survey.files;
    json!({
        "imu": schema::path_json(Some(&files.imu)),
        "dvl": schema::path_json(files.dvl.as_deref()),
        "beams": schema::path_json(files.beams.as_deref()),
        "pd0": schema::path_json(files.pd0.as_deref()),
        "depth": schema::path_json(files.depth.as_deref()),
        "fixes": schema::path_json(files.fixes.as_deref()),
        "vehicle": schema::path_json(files.vehicle.as_deref()),
        "truth": schema::path_json(files.truth.as_deref()),
        "rate_hz": rate,
        "configuration": survey.config,
    })
}

/// The final DVL error states of a run with `[dvl_states]` (null without): each
/// state's value and 1-sigma, and the time offset in total (the configured stamp
/// shift plus the estimated rest), in the units of the `[dvl]` keys they refine.
fn dvl_states_json(run: &NavigationRun, config: &NavigatorConfig) -> Value {
    let (Some(s), Some(states)) = (&run.dvl_states, &config.dvl_states) else {
        return Value::Null;
    };
    json!({
        "estimated": {
            "scale_factor": states.scale_factor.estimate,
            "misalignment": states.misalignment.estimate,
            "bias": states.bias.estimate,
            "lever_arm": states.lever_arm.estimate,
            "time_offset": states.time_offset.estimate,
        },
        "scale_factor": 1.0 + s.scale_factor_error,
        "scale_factor_sigma": s.scale_factor_sigma,
        "mounting_misalignment_rad": s.misalignment_rad,
        "mounting_misalignment_sigma_rad": s.misalignment_sigma_rad,
        "bias_mps": s.bias_mps,
        "bias_sigma_mps": s.bias_sigma_mps,
        "lever_arm_m": s.lever_arm_m,
        "lever_arm_sigma_m": s.lever_arm_sigma_m,
        "time_offset_s": config.dvl.time_offset_s + s.time_offset_s,
        "time_offset_sigma_s": s.time_offset_sigma_s,
    })
}

/// Refuse a run that takes the 15-state filter only (`what`) when the vehicle file
/// asks for DVL error states, naming the file and the table.
pub fn refuse_dvl_states(survey: &Survey, what: &str) -> anyhow::Result<()> {
    if survey.config.dvl_states.is_none() {
        return Ok(());
    }
    let file = survey.files.vehicle.as_deref().map_or_else(
        || "vehicle configuration".to_string(),
        |p| p.display().to_string(),
    );
    anyhow::bail!(
        "{file}: dvl_states: {what} runs the 15-state filter; remove the [dvl_states] table"
    )
}

/// The text summary of a survey run.
pub fn summary_text(
    verb: &str,
    run: &NavigationRun,
    last: &NavSolution,
    summary: &Value,
) -> String {
    let f = last;
    let mut text = String::new();
    let _ = writeln!(
        text,
        "{verb} {} IMU samples ({:.1} s); DVL updates {} accepted, {} gated, {} recovered; {} rows without lock skipped; {} gaps coasted",
        run.imu_samples,
        run.span_s[1] - run.span_s[0],
        run.dvl.accepted,
        run.dvl.gated,
        run.dvl.recovered,
        run.dvl_no_lock,
        run.dvl_gaps_coasted
    );
    let _ = writeln!(
        text,
        "final: lat {:.7} deg, lon {:.7} deg, depth {:.2} m, heading {} deg; 1-sigma N/E {:.2}/{:.2} m",
        f.latitude_deg,
        f.longitude_deg,
        f.depth_m,
        format_heading(f.heading_deg, 2),
        f.position_sigma_m[0],
        f.position_sigma_m[1]
    );
    if let Some(d) = &run.dvl_states {
        let mrad =
            |v: &[f64; 3]| format!("[{:.2}, {:.2}, {:.2}]", v[0] * 1e3, v[1] * 1e3, v[2] * 1e3);
        let _ = writeln!(
            text,
            "DVL states: scale factor {:.5} +- {:.5}, misalignment {} +- {} mrad, lever arm [{:.3}, {:.3}, {:.3}] m, time offset {:.3} +- {:.3} s",
            summary["dvl_states"]["scale_factor"].as_f64().unwrap_or(f64::NAN),
            d.scale_factor_sigma,
            mrad(&d.misalignment_rad),
            mrad(&d.misalignment_sigma_rad),
            d.lever_arm_m[0],
            d.lever_arm_m[1],
            d.lever_arm_m[2],
            summary["dvl_states"]["time_offset_s"].as_f64().unwrap_or(f64::NAN),
            d.time_offset_sigma_s
        );
    }
    let evaluation = summary.get("evaluation").filter(|v| !v.is_null());
    if let Some(reason) = evaluation.and_then(|e| e["not_scored_reason"].as_str()) {
        let _ = writeln!(text, "against truth: not scored: {reason}");
    } else if let Some(e) = evaluation {
        let _ = writeln!(
            text,
            "against truth: position RMSE {} m, average NEES {} ({} states)",
            e["position_rmse_m"], e["nees_average"], e["nees_states"]
        );
    }
    text
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

/// The `stop` block of a run that ended early: its status, time and reason.
pub fn stop_json(epoch: f64, error: &NavigatorError) -> (&'static str, Value) {
    match error {
        NavigatorError::Diverged { time, reason } => (
            "diverged",
            json!({
                "time_s": epoch + time,
                "time_since_epoch_s": time,
                "reason": reason.to_string(),
                "check": reason,
            }),
        ),
        NavigatorError::Filter { time, source } => (
            "failed",
            json!({
                "time_s": epoch + time,
                "time_since_epoch_s": time,
                "reason": source.to_string(),
            }),
        ),
        other => ("failed", json!({ "reason": other.to_string() })),
    }
}

/// A run stopped by divergence or a numerical failure: the solution rows before the
/// stop, the track and a summary marked `partial` are committed to `--out` (exit 3);
/// nothing of the stopped run is reported as a solution.
pub fn stopped(
    command: &str,
    survey: &Survey,
    writer: &mut Writer,
    staged: Option<StagedDir>,
    error: &NavigatorError,
    rate: Option<f64>,
    json_out: bool,
) -> anyhow::Result<()> {
    let (status, stop) = stop_json(survey.epoch, error);
    let mut summary = schema::document(
        command,
        inputs_json(survey, rate),
        0,
        json!({
            "epoch_s": survey.epoch,
            "partial": true,
            "stop": stop,
            "solution_rows_before_stop": writer.rows,
            "last_solution_before_stop": writer.last.map(|f| json!({
                "time_s": survey.epoch + f.time,
                "latitude_deg": f.latitude_deg,
                "longitude_deg": f.longitude_deg,
                "depth_m": f.depth_m,
                "position_sigma_m": f.position_sigma_m,
            })),
            "evaluation_before_stop": evaluation_json(writer.truth()),
            "warnings": survey.warnings,
        }),
    );
    summary["status"] = json!(status);
    let kept = match staged {
        Some(dir) => {
            // The plots of the solutions before the stop (their axes bounded by the
            // valid part, see navigate_plots); the NIS were not kept.
            let note = format!(
                "{status} at t = {:.1} s",
                stop["time_since_epoch_s"].as_f64().unwrap_or(f64::NAN)
            );
            if let Some(plots) =
                writer.write_plots(&dir, command, "filter", (&[], &[]), Some(&note))
            {
                summary["plots"] = plots;
            }
            writer.finish(
                &dir,
                &format!("estim {command} track before the stop (partial)"),
                &summary,
            )?;
            let path = dir.target().to_path_buf();
            dir.commit()?;
            format!(
                "the {} solution rows before the stop are in {} (summary.json: \"partial\": true)",
                writer.rows,
                path.display()
            )
        }
        None => "nothing was written (no --out)".to_string(),
    };
    if json_out {
        crate::output::emit(&format!("{}\n", serde_json::to_string_pretty(&summary)?))?;
    }
    Err(schema::RunStopped {
        message: format!(
            "{command} {status} at t = {} s: {}; {kept}",
            stop["time_s"],
            stop["reason"].as_str().unwrap_or("")
        ),
    }
    .into())
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
            survey.files.beams.is_some(),
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
    let mut evaluation = evaluation_json(writer.truth());
    if let (Some(e), Some(dvl)) = (evaluation.as_object_mut(), writer.dvl_epoch_truth()) {
        e.insert("scored_at".into(), json!("reference_epochs"));
        e.insert("at_dvl_epochs".into(), evaluation_json(Some(dvl)));
    }
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
