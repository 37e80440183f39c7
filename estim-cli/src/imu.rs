//! `estim imu calibrate`: an IMU's axis convention, clock scale and offset and initial
//! biases against a reference trajectory (`estim_ins::ImuCalibrator`), printed as the
//! `[imu]` table of a vehicle file.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use estim::datasets::{load_gt, load_times, ImuLog};
use estim_ins::{Error as InsError, Estimate, ImuCalibration, ImuCalibrator, TrajectorySample};

/// Arguments of `estim imu`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, clap::Subcommand)]
enum Command {
    /// Estimate the IMU's axis convention (a signed permutation, IMU -> body x forward,
    /// y right, z down), clock scale s and time offset tau (a sample stamped t is at
    /// reference time s t - tau), initial accelerometer and gyroscope biases and the
    /// gyroscope's scale factor per body axis (on axes the reference turns about)
    /// against a reference trajectory, each with its 1-sigma. Prints the `[imu]` table of a vehicle
    /// file (or `--json`).
    ///
    /// The IMU file is read as `estim navigate --imu` reads it, the reference as
    /// `--truth` (GT_trajectoryN.csv layout); times are relative to the IMU file's first
    /// whole second (0 for A-KIT).
    Calibrate(CalibrateArgs),
}

#[derive(Debug, clap::Args)]
struct CalibrateArgs {
    /// IMU file (specific force and angular rate, or increments; columns by name).
    #[arg(long, value_name = "IMU.csv")]
    imu: PathBuf,
    /// Reference trajectory (`GT_trajectoryN.csv` layout: position, NED velocity, roll,
    /// pitch, yaw).
    #[arg(long, value_name = "GT.csv")]
    truth: PathBuf,
    /// Largest |time offset| searched, in seconds.
    #[arg(long, value_name = "S", default_value_t = 3.0)]
    max_time_offset: f64,
    /// Largest |clock scale - 1| searched.
    #[arg(long, value_name = "FRACTION", default_value_t = 0.01)]
    max_clock_scale_error: f64,
    /// JSON (the schema of every `--json`, see docs/cli.md) instead of the TOML table.
    #[arg(long)]
    json: bool,
}

/// Run `estim imu`.
pub fn run(args: Args) -> anyhow::Result<()> {
    // Printed only on success: a refused input leaves stdout empty.
    let output = match args.command {
        Command::Calibrate(a) => calibrate(&a)?,
    };
    crate::output::emit(&output)
}

fn calibrate(args: &CalibrateArgs) -> anyhow::Result<String> {
    let calibrator = ImuCalibrator::builder()
        .max_time_offset(args.max_time_offset)
        .max_clock_scale_error(args.max_clock_scale_error)
        .build()
        .map_err(|e| match e {
            InsError::InvalidParameter { name, reason } => {
                anyhow::anyhow!("--{}: {reason}", name.replace('_', "-"))
            }
            other => other.into(),
        })?;
    let log = ImuLog::load(&args.imu, None)?;
    let reference = load_reference(&args.truth, log.epoch_s)?;
    let calibration = calibrator
        .calibrate(&log.samples, &reference)
        .map_err(|e| name_files(e, args, &log))?;
    if args.json {
        json(args, &log, &calibration)
    } else {
        Ok(table(args, &log, &calibration))
    }
}

/// The reference epochs with their times read on the IMU file's epoch (as `navigate
/// --truth` reads them).
fn load_reference(path: &Path, epoch_s: f64) -> anyhow::Result<Vec<TrajectorySample>> {
    let gt = load_gt(path)?;
    let times = load_times(path, epoch_s)?;
    anyhow::ensure!(
        times.len() == gt.len(),
        "{}: {} time cells for {} rows",
        path.display(),
        times.len(),
        gt.len()
    );
    Ok(gt
        .iter()
        .zip(&times)
        .map(|(g, &t)| {
            let mut s = g.trajectory_sample();
            s.time = t;
            s
        })
        .collect())
}

/// The calibrator's error with the files named (and the IMU line for a sample error).
fn name_files(e: InsError, args: &CalibrateArgs, log: &ImuLog) -> anyhow::Error {
    let (imu, truth) = (args.imu.display(), args.truth.display());
    match &e {
        InsError::ImuTime { index, reason } => match log.lines.get(*index) {
            Some(line) => anyhow::anyhow!("{imu}:{line}: {reason}"),
            None => anyhow::anyhow!("{imu}: {e}"),
        },
        InsError::Trajectory { .. } => anyhow::anyhow!("{truth}: {e}"),
        _ => anyhow::anyhow!("{imu} against {truth}: {e}"),
    }
}

/// `value` with enough decimals to show the first two digits of `sigma` (at least one
/// decimal, so that TOML reads a float).
fn decimal(value: f64, sigma: f64) -> String {
    let digits = if sigma.is_finite() && sigma > 0.0 {
        (1.0 - sigma.log10().floor()).clamp(1.0, 12.0) as usize
    } else {
        6
    };
    format!("{value:.digits$}")
}

fn triple(e: &[Estimate; 3], part: impl Fn(&Estimate) -> String) -> String {
    format!("[{}, {}, {}]", part(&e[0]), part(&e[1]), part(&e[2]))
}

/// The `[imu]` table with the fit's summary as comments.
fn table(args: &CalibrateArgs, log: &ImuLog, c: &ImuCalibration) -> String {
    let mut out = String::new();
    let v = |v: &nalgebra::Vector3<f64>| format!("{:.1e} {:.1e} {:.1e}", v.x, v.y, v.z);
    let _ = writeln!(
        out,
        "# estim imu calibrate: {} against {} ({} reference intervals; times from the IMU \
         file's epoch {} s)",
        args.imu.display(),
        args.truth.display(),
        c.intervals,
        log.epoch_s
    );
    match c.runner_up {
        Some((axes, cost)) => {
            let _ = writeln!(
                out,
                "# axes: cost {:.4} ({}); runner-up {axes} cost {cost:.4}, {:.1} x worse",
                c.cost,
                if c.axes.is_proper() {
                    "a rotation"
                } else {
                    "a mirror image"
                },
                c.cost_ratio
            );
        }
        None => {
            let _ = writeln!(
                out,
                "# axes: cost {:.4}; no other convention admitted",
                c.cost
            );
        }
    }
    let _ = writeln!(
        out,
        "# residual RMS per interval: accelerometer {} m/s^2, gyroscope {} rad/s; lag-1 \
         autocorrelation {:.2} (sigmas up to {:.2} x those of white residuals)",
        v(&c.residual_rms_accelerometer),
        v(&c.residual_rms_gyroscope),
        c.residual_lag1_autocorrelation,
        c.max_variance_ratio.sqrt()
    );
    let (s, tau) = (&c.clock_scale, &c.time_offset_s);
    let sigma = |e: &Estimate| format!("{:.1e}", e.standard_error);
    let value = |e: &Estimate| decimal(e.value, e.standard_error);
    out.push_str("[imu]\n");
    let _ = writeln!(out, "axes = {}", c.axes);
    let _ = writeln!(out, "clock_scale = {}    # 1-sigma {}", value(s), sigma(s));
    let _ = writeln!(
        out,
        "clock_origin_s = {:?}    # the scale acts about the IMU file's epoch",
        log.epoch_s
    );
    let _ = writeln!(
        out,
        "time_offset_s = {}    # 1-sigma {}",
        value(tau),
        sigma(tau)
    );
    let _ = writeln!(
        out,
        "accelerometer_bias = {}    # m/s^2, 1-sigma {}",
        triple(&c.accelerometer_bias, value),
        triple(&c.accelerometer_bias, sigma)
    );
    let _ = writeln!(
        out,
        "gyroscope_bias = {}    # rad/s, 1-sigma {}",
        triple(&c.gyroscope_bias, value),
        triple(&c.gyroscope_bias, sigma)
    );
    // A scale the motion did not excite is written as 1 (not fitted).
    let scale_value = |e: &Option<Estimate>| e.as_ref().map_or("1.0".into(), value);
    let scale_sigma = |e: &Option<Estimate>| e.as_ref().map_or("not fitted".into(), sigma);
    let _ = writeln!(
        out,
        "gyroscope_scale = [{}, {}, {}]    # 1-sigma [{}, {}, {}]",
        scale_value(&c.gyroscope_scale[0]),
        scale_value(&c.gyroscope_scale[1]),
        scale_value(&c.gyroscope_scale[2]),
        scale_sigma(&c.gyroscope_scale[0]),
        scale_sigma(&c.gyroscope_scale[1]),
        scale_sigma(&c.gyroscope_scale[2]),
    );
    out
}

/// `imu calibrate --json`: the common header, then each estimate with its 1-sigma
/// under a key naming its unit.
fn json(args: &CalibrateArgs, log: &ImuLog, c: &ImuCalibration) -> anyhow::Result<String> {
    use crate::schema::{document, path_json};
    use serde_json::{json, Value};
    let scalar = |e: &Estimate| json!({ "estimate": e.value, "standard_error": e.standard_error });
    let vector = |e: &[Estimate; 3]| {
        json!({
            "estimate": e.iter().map(|x| x.value).collect::<Vec<_>>(),
            "standard_error": e.iter().map(|x| x.standard_error).collect::<Vec<_>>(),
        })
    };
    // Not fitted (the motion does not excite that axis): null.
    let scale = json!({
        "estimate": c.gyroscope_scale.iter().map(|e| e.map(|x| x.value)).collect::<Vec<_>>(),
        "standard_error": c
            .gyroscope_scale
            .iter()
            .map(|e| e.map(|x| x.standard_error))
            .collect::<Vec<_>>(),
    });
    let runner_up = c.runner_up.map_or(
        Value::Null,
        |(axes, cost)| json!({ "axes": axes.labels(), "cost": cost }),
    );
    let inputs = json!({
        "imu": path_json(Some(&args.imu)),
        "truth": path_json(Some(&args.truth)),
        "max_time_offset_s": args.max_time_offset,
        "max_clock_scale_error": args.max_clock_scale_error,
    });
    let r = &c.residual_rms_accelerometer;
    let g = &c.residual_rms_gyroscope;
    let doc = document(
        "imu calibrate",
        inputs,
        0,
        json!({
            "epoch_s": log.epoch_s,
            "axes": c.axes.labels(),
            "axes_proper": c.axes.is_proper(),
            "clock_scale": scalar(&c.clock_scale),
            "time_offset_s": scalar(&c.time_offset_s),
            "accelerometer_bias_mps2": vector(&c.accelerometer_bias),
            "gyroscope_bias_radps": vector(&c.gyroscope_bias),
            "gyroscope_scale": scale,
            "cost": c.cost,
            "runner_up": runner_up,
            "cost_ratio": c.cost_ratio.is_finite().then_some(c.cost_ratio),
            "intervals": c.intervals,
            "iterations": c.iterations,
            "residual_rms_accelerometer_mps2": [r.x, r.y, r.z],
            "residual_rms_gyroscope_radps": [g.x, g.y, g.z],
            "residual_lag1_autocorrelation": c.residual_lag1_autocorrelation,
            "max_variance_ratio": c.max_variance_ratio,
        }),
    );
    Ok(format!("{}\n", serde_json::to_string_pretty(&doc)?))
}
