//! A survey's input files, read and checked into a [`Survey`]: what `navigate`,
//! `smooth` and `tune` run on.

use std::path::{Path, PathBuf};

use anyhow::Context;
use estim::navigator::{NavigatorConfig, NavigatorSettings, SurveyInputs};
use estim::truth::Truth;
use estim::{Pd0Load, SurveyError};
use serde_json::{json, Value};

/// The survey's input files, shared by `estim navigate` and `estim smooth`: the
/// library's sensor files and the evaluation's truth.
#[derive(Debug, Clone, Default)]
pub struct SurveyFiles {
    /// The sensors' files and the vehicle file (read by [`estim::SurveyFiles::read`]).
    pub sensors: estim::SurveyFiles,
    /// Ground truth CSV.
    pub truth: Option<PathBuf>,
    /// Start from the truth's state at the first IMU sample (position, velocity,
    /// attitude), replacing `[initial]`'s.
    pub init_from_truth: bool,
}

impl SurveyFiles {
    /// Every input path given (for
    /// [`StagedDir::keep_inputs`](crate::output::StagedDir::keep_inputs)).
    pub fn paths(&self) -> impl Iterator<Item = &Path> {
        let s = &self.sensors;
        [
            &s.dvl,
            &s.beams,
            &s.pd0,
            &s.depth,
            &s.fixes,
            &s.vehicle,
            &self.truth,
        ]
        .into_iter()
        .flatten()
        .map(PathBuf::as_path)
        .chain([s.imu.as_path()])
    }
}

/// Read and check a vehicle TOML; errors name the file and line.
pub fn vehicle_config(path: &Path) -> anyhow::Result<NavigatorConfig> {
    Ok(estim::truth::read_vehicle(path)?)
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
    let mut config = match &files.sensors.vehicle {
        Some(p) => vehicle_config(p)?,
        None => NavigatorConfig::default(),
    };
    if let Some(path) = columns {
        let over = crate::survey_checks::columns_file(path)?;
        config.columns = config.columns.overridden_by(&over).map_err(|e| {
            let vehicle = files
                .sensors
                .vehicle
                .as_deref()
                .unwrap_or(Path::new("vehicle"));
            anyhow::anyhow!("{}: {e}", vehicle.display())
        })?;
    }
    load_survey_from(files, config)
}

/// [`load_survey`] with the vehicle configuration already read (`files.sensors.vehicle` only
/// names it in messages), e.g. a vehicle embedded in the binary.
pub fn load_survey_from(files: SurveyFiles, config: NavigatorConfig) -> anyhow::Result<Survey> {
    // Skipped PD0 spans are warned about on stderr with their byte offsets as they are
    // found, and listed in the summary's `pd0` block.
    let mut loaded = files
        .sensors
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
    let mut warnings: Vec<Value> = estim::check_survey(&files.sensors, &config, &inputs, epoch)?
        .into_iter()
        .map(|w| {
            eprintln!("warning: {}", w.message);
            serde_json::json!({
                "code": w.code,
                "file": w.file.display().to_string(),
                "message": w.message,
            })
        })
        .collect();
    if let Some(truth) = &truth {
        warnings.extend(truth.position_jumps().iter().map(|j| {
            let file = truth.path().display().to_string();
            let message = format!(
                "{file}: data rows {} to {}: the reference's position change differs by \
                 {:.1} m from what its velocity integrates to (median over its intervals \
                 {:.3} m): the errors and NEES there score the reference",
                j.row - 1,
                j.row,
                j.mismatch_m,
                j.median_m
            );
            eprintln!("warning: {message}");
            serde_json::json!({
                "code": "truth_position_jump",
                "file": file,
                "message": message,
            })
        }));
    }
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

/// Refuse a run that takes the 15-state filter only (`what`) when the vehicle file
/// asks for DVL error states, naming the file and the table.
pub fn refuse_dvl_states(survey: &Survey, what: &str) -> anyhow::Result<()> {
    if survey.config.dvl_states.is_none() {
        return Ok(());
    }
    let file = survey.files.sensors.vehicle.as_deref().map_or_else(
        || "vehicle configuration".to_string(),
        |p| p.display().to_string(),
    );
    anyhow::bail!(
        "{file}: dvl_states: {what} runs the 15-state filter; remove the [dvl_states] table"
    )
}
