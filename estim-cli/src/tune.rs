//! `estim tune`: maximum-likelihood noise parameters of the INS/DVL filter, with
//! standard errors and the likelihood-ratio test of M = 0, on A-KIT training
//! trajectories (`--trajectories`) or on a survey's own IMU and DVL files (`--imu`).
//! This file runs the survey mode ([`run`]) and prints either mode's fit; the
//! `--trajectories` mode ([`TrajectoryMode`]) is the A-KIT reproduction's code, which
//! `main.rs` runs.

use std::fmt::Write as _;
use std::path::PathBuf;

use crate::imu_choice::ImuChoice;
use estim::navigator::tune::{
    TuneFit, TuneOptions, TuneParameters, M_SCALE, PARAMETER_NAMES, PARAMETER_UNITS,
};

/// Arguments of `estim tune`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Folder holding A-KIT `TrajectoryN/` (or a data root holding `a-kit/`); default
    /// `ESTIM_DATA_DIR`, then `../shared/data`.
    #[arg(long, value_name = "DIR")]
    data: Option<PathBuf>,
    /// A-KIT training trajectories, comma-separated (e.g. `1,2,3`); the test
    /// trajectories 4 and 13 are refused (exit status 2).
    #[arg(
        long,
        value_name = "N,N,...",
        value_delimiter = ',',
        required_unless_present = "imu",
        conflicts_with = "imu"
    )]
    trajectories: Vec<u32>,
    /// Survey mode: the IMU CSV of a survey (as `estim navigate --imu`), with --dvl or
    /// --beams and optionally --vehicle; the likelihood is of its DVL rows.
    #[arg(long, value_name = "FILE", conflicts_with_all = ["data", "config", "seed"])]
    imu: Option<PathBuf>,
    /// Survey mode: DVL velocity CSV (body frame).
    #[arg(long, value_name = "FILE", requires = "imu", conflicts_with = "beams")]
    dvl: Option<PathBuf>,
    /// Survey mode: DVL beams CSV (least squares on 3 or 4 beams).
    #[arg(long, value_name = "FILE", requires = "imu")]
    beams: Option<PathBuf>,
    /// Vehicle configuration TOML (IMU spec, DVL lever arm, time offset, beam geometry
    /// and noise, initial state; as `estim navigate --vehicle`). With `--trajectories`:
    /// the file a recorded IMU is read through (default: the embedded
    /// `vehicles/akit.toml`).
    #[arg(long, value_name = "FILE")]
    vehicle: Option<PathBuf>,
    /// With `--trajectories`: which IMU each trajectory runs on: `auto` (the recorded
    /// IMU where the folder holds `IMU_trajectoryN.csv`, else synthesized), `recorded`
    /// or `synthesized`. All trajectories of one fit must share one.
    #[arg(long = "imu-source", value_enum, default_value_t = ImuChoice::Auto,
          conflicts_with = "imu")]
    imu_source: ImuChoice,
    /// Survey mode: a reference track (as `estim navigate --truth`), used for the
    /// initial state only (`--init-from-truth`, or `[truth] initial_state` in the
    /// vehicle file); the fit itself sees only the IMU and the DVL.
    #[arg(long, value_name = "FILE", requires = "imu")]
    truth: Option<PathBuf>,
    /// Survey mode: start from the truth's state (as `estim navigate --init-from-truth`).
    #[arg(long, requires = "truth")]
    init_from_truth: bool,
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
    /// Hold a parameter at a value instead of fitting it (repeatable), e.g.
    /// `--fix accelerometer_psd=9e-6` (names and units as in the output's table).
    #[arg(long, value_name = "NAME=VALUE", value_parser = parse_fix)]
    fix: Vec<(usize, f64)>,
    /// Machine-readable JSON on stdout instead of the table.
    #[arg(long)]
    json: bool,
}

/// `NAME=VALUE` of `--fix`: the parameter's index and a finite value inside its
/// range (variances >= 0, m_scale any finite value; the fit checks it against the
/// largest valid M).
fn parse_fix(text: &str) -> Result<(usize, f64), String> {
    let (name, value) = text
        .split_once('=')
        .ok_or_else(|| format!("{text:?}: expected NAME=VALUE"))?;
    let index = PARAMETER_NAMES
        .iter()
        .position(|n| *n == name.trim())
        .ok_or_else(|| {
            format!(
                "{name:?} is not a parameter (one of {})",
                PARAMETER_NAMES.join(", ")
            )
        })?;
    let value: f64 = value
        .trim()
        .parse()
        .map_err(|e| format!("{name}: {value:?} is not a number ({e})"))?;
    let valid = value.is_finite() && (index == M_SCALE || value >= 0.0);
    if !valid {
        return Err(format!(
            "{name}: {value} must be finite{}",
            if index == M_SCALE { "" } else { " and >= 0" }
        ));
    }
    Ok((index, value))
}

/// `estim tune` as parsed, by call shape.
pub enum Mode {
    /// `--imu`: a survey's own files, fitted by [`run`].
    Survey(SurveyMode),
    /// `--trajectories`: A-KIT training trajectories, fitted by the A-KIT
    /// reproduction's code.
    Trajectories(TrajectoryMode),
}

/// The survey mode's flags.
pub struct SurveyMode {
    imu: PathBuf,
    dvl: Option<PathBuf>,
    beams: Option<PathBuf>,
    vehicle: Option<PathBuf>,
    truth: Option<PathBuf>,
    init_from_truth: bool,
    linearizations: u64,
    json: bool,
    options: TuneOptions,
}

/// The `--trajectories` mode's flags, as given.
pub struct TrajectoryMode {
    /// `--data`.
    pub data: Option<PathBuf>,
    /// `--trajectories`.
    pub trajectories: Vec<u32>,
    /// `--config`.
    pub config: Option<PathBuf>,
    /// `--seed`.
    pub seed: Option<u64>,
    /// `--linearizations`.
    pub linearizations: u64,
    /// `--json`.
    pub json: bool,
    /// The fit's options (`--linearizations`, `--fix`).
    pub options: TuneOptions,
    /// `--imu-source`.
    pub imu_source: ImuChoice,
    /// `--vehicle`.
    pub vehicle: Option<PathBuf>,
}

impl Args {
    /// The call shape: survey mode with `--imu`, else the trajectories.
    ///
    /// # Errors
    /// A parameter held twice by `--fix`.
    pub fn into_mode(self) -> anyhow::Result<Mode> {
        let mut fixed = [None; PARAMETER_NAMES.len()];
        for &(i, value) in &self.fix {
            anyhow::ensure!(
                fixed[i].replace(value).is_none(),
                "--fix {}: given twice",
                PARAMETER_NAMES[i]
            );
        }
        let options = TuneOptions {
            linearizations: usize::try_from(self.linearizations)?,
            fixed,
            ..TuneOptions::default()
        };
        let Some(imu) = self.imu else {
            return Ok(Mode::Trajectories(TrajectoryMode {
                data: self.data,
                trajectories: self.trajectories,
                config: self.config,
                seed: self.seed,
                linearizations: self.linearizations,
                json: self.json,
                options,
                imu_source: self.imu_source,
                vehicle: self.vehicle,
            }));
        };
        Ok(Mode::Survey(SurveyMode {
            imu,
            dvl: self.dvl,
            beams: self.beams,
            vehicle: self.vehicle,
            truth: self.truth,
            init_from_truth: self.init_from_truth,
            linearizations: self.linearizations,
            json: self.json,
            options,
        }))
    }
}

/// What a fit was fitted on, with the fit.
#[derive(Debug, Clone)]
pub struct TuneReport {
    /// The trajectories, in the order given (none for a survey).
    pub trajectories: Vec<u32>,
    /// DVL epochs used per trajectory.
    pub epochs: Vec<usize>,
    /// DVL epochs left out per trajectory (rows shared with a test trajectory; for a
    /// survey, the rows skipped).
    pub overlapping: Vec<usize>,
    /// The starting point.
    pub start: TuneParameters,
    /// The IMU PSDs the IMU was synthesized with (the values q_a and q_g recover when
    /// the filter's model is right); `None` for a recorded IMU.
    pub synthesized_psd: Option<[f64; 2]>,
    /// With `--trajectories`: the IMU every trajectory ran on (`recorded` or
    /// `synthesized`); `None` for a survey.
    pub imu_source: Option<&'static str>,
    /// The fit.
    pub fit: TuneFit,
}

/// Run the survey mode: the navigator's inputs and arithmetic, the likelihood of its DVL
/// rows.
pub fn run(args: SurveyMode) -> anyhow::Result<()> {
    use estim::navigator::tune::{survey_measurements, tune, TuneModel};
    if args.dvl.is_none() && args.beams.is_none() {
        anyhow::bail!("--imu needs --dvl or --beams");
    }
    let files = crate::navigate::SurveyFiles {
        sensors: estim::SurveyFiles {
            imu: args.imu.clone(),
            dvl: args.dvl.clone(),
            beams: args.beams.clone(),
            vehicle: args.vehicle.clone(),
            ..Default::default()
        },
        truth: args.truth.clone(),
        init_from_truth: args.init_from_truth,
    };
    let loaded = crate::navigate::load_survey(files)?;
    crate::navigate::refuse_dvl_states(&loaded, "estim tune")?;
    let measurements = survey_measurements(&loaded.inputs, &loaded.settings)?;
    let model = TuneModel::from_settings(&loaded.settings);
    let start = model.start(loaded.config.dvl.noise_std_mps);
    let trajectory = measurements.trajectory(&loaded.inputs.imu);
    let fit = tune(&[trajectory], &model, &start, &args.options)?;
    let report = TuneReport {
        trajectories: Vec::new(),
        epochs: vec![measurements.dvl.len()],
        overlapping: vec![measurements.skipped],
        start,
        synthesized_psd: None,
        imu_source: None,
        fit,
    };
    let text = if args.json {
        use crate::schema::path_json;
        let inputs = serde_json::json!({
            "imu_file": path_json(Some(&loaded.files.sensors.imu)),
            "dvl_file": path_json(loaded.files.sensors.dvl.as_deref()),
            "beams_file": path_json(loaded.files.sensors.beams.as_deref()),
            "vehicle": path_json(loaded.files.sensors.vehicle.as_deref()),
            "linearizations": args.linearizations,
            "dvl_rows_skipped": measurements.skipped,
        });
        json(inputs, &report)?
    } else {
        let head = format!(
            "Maximum likelihood on the survey {} ({} DVL epochs; {} rows skipped: no \
             bottom lock, fewer than 3 beams, or outside the IMU's span).",
            loaded.files.sensors.imu.display(),
            measurements.dvl.len(),
            measurements.skipped,
        );
        table(&head, &report)
    };
    finish(&text, &report)
}

/// Print the report; a fit that cannot be used as it stands (degenerate, not
/// converged) exits 3 naming why, after its figures were printed.
pub fn finish(text: &str, report: &TuneReport) -> anyhow::Result<()> {
    crate::output::emit(text)?;
    let status = &report.fit.status;
    if status.is_usable() {
        Ok(())
    } else {
        Err(crate::schema::RunStopped {
            message: format!("tune: {status}; the figures above are not a usable fit"),
        }
        .into())
    }
}

/// The JSON document of a fit, with the inputs named by `inputs`.
pub fn json(inputs: serde_json::Value, report: &TuneReport) -> anyhow::Result<String> {
    use crate::schema::document;
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
                "fixed": report.fit.fixed[i],
                "start": report.start[i],
                "synthesized": report.synthesized_psd.and_then(|p| p.get(i).copied()),
                "value_with_m_zero": fit.restricted.theta[i],
                "standard_error_with_m_zero": se(i, &fit.restricted),
            })
        })
        .collect();
    let points: Vec<Vec<f64>> = fit.points.iter().map(|p| p.as_slice().to_vec()).collect();
    let doc = document(
        "tune",
        inputs,
        usize::from(!fit.status.is_usable()),
        serde_json::json!({
            "fit_status": fit.status.as_str(),
            "fit_status_reason": fit.status.to_string(),
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

/// The table of a fit under the line `head`.
pub fn table(head: &str, report: &TuneReport) -> String {
    let fit = &report.fit;
    let mut out = String::new();
    let _ = writeln!(out, "{head}");
    let _ = writeln!(
        out,
        "\n| parameter | unit | estimate | standard error | start | synthesized |\n|---|---|---|---|---|---|"
    );
    for i in 0..PARAMETER_NAMES.len() {
        let se = match (report.fit.fixed[i], fit.standard_errors[i], fit.on_bound[i]) {
            (Some(_), _, _) => "held (--fix)".to_string(),
            (None, Some(s), _) => format!("{s:.4e}"),
            (None, None, true) => "on its bound".to_string(),
            (None, None, false) => "n/a".to_string(),
        };
        let synthesized = report
            .synthesized_psd
            .and_then(|p| p.get(i).copied())
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
        "\nFit: {}.\nln p = {:.3} (converged: {}); with M = 0: ln p = {:.3} (converged: {}).\n\
         Likelihood-ratio test of m_scale = 0: statistic {:.4}, 1 degree of freedom, p-value {:.4}.\n\
         m_scale is bounded by +-{:.4} (99 % of the largest valid value at the last linearization).",
        fit.status,
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
