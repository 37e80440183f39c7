//! `estim dvl`: beam least squares on a CSV file, Teledyne RDI PD0 files decoded to
//! CSV, and DVL calibration against a reference trajectory.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context;
use estim::datasets::{check_spans, load_dvl, load_gt, BeamFile, SPAN_TIME_OFFSET_ALLOWANCE_S};
use estim_dvl::nalgebra::Vector3;
use estim_dvl::{BeamGeometry, Calibrator, DvlMeasurement, TrajectorySample};

/// Arguments of `estim dvl`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, clap::Subcommand)]
enum Command {
    /// Velocity from DVL beams by least squares (3-beam solutions where one is missing).
    ///
    /// Reads a CSV with a header row (`-` reads stdin); the beam columns are found by
    /// name (`beam1`, `b1`, `beam_1`, `Beam 1 [m/s]`, `beam velocity 1`; any case; unit
    /// m/s, cm/s or mm/s), a time column (`time`, `t`, `timestamp`; s or ms) is kept,
    /// other columns are ignored; an empty or `nan` cell is a missing beam. Writes
    /// `[time_s,]vx,vy,vz,error_velocity,n_beams` [m/s] to stdout, one row per input
    /// row; the error velocity is empty for a 3-beam solution, and the velocity too
    /// when fewer than 3 beams are present.
    Solve(SolveArgs),
    /// Estimate the DVL lever arm, scale factor, mounting misalignment and time offset
    /// against a ground-truth trajectory (GT and DVL CSV files, columns by name as for
    /// `reproduce --gt/--dvl`; both must cover the same time span).
    Calibrate(CalibrateArgs),
    /// Fit `dvl.akit_reference_mismatch_std_mps` on the A-KIT training trajectories:
    /// the residual of the recorded DVL velocity against the filter's DVL model applied
    /// to the ground truth (the configuration's lever arm and time offset), pooled over
    /// epochs and axes as sqrt(mean square). The held-out trajectories (default 4 and
    /// 13) and every epoch whose DVL row also occurs in one of them are left out.
    Mismatch(MismatchArgs),
    /// Decode a Teledyne RDI PD0 binary file (bottom track) to CSV on stdout.
    ///
    /// One row per good ensemble: `time_unix_s` (the ensemble's real-time clock, UTC),
    /// the four bottom-track beam velocities [m/s] and ranges [m] in the file's own
    /// coordinate system (beam, instrument, ship or earth, as its fixed leader
    /// declares; named in the last column), with an empty cell where the instrument
    /// marked a value bad (-32768 mm/s, range 0) and eight empty cells for an ensemble
    /// without bottom track. A truncated or corrupt ensemble (checksum, header) and
    /// bytes between ensembles are skipped, each named on stderr with its byte offset;
    /// every good ensemble is kept. Exit status 2 when the file holds no good ensemble,
    /// or with `--strict` when anything was skipped.
    Pd0(Pd0Args),
}

#[derive(Debug, clap::Args)]
struct Pd0Args {
    /// The PD0 file (e.g. `*.pd0`, `*.000`, VmDas `*.ENR`).
    #[arg(value_name = "FILE")]
    input: PathBuf,
    /// Refuse the file (exit status 2, nothing on stdout) when any span was skipped.
    #[arg(long)]
    strict: bool,
}

/// The flags of `dvl mismatch`.
#[derive(Debug, clap::Args)]
pub struct MismatchArgs {
    /// Folder holding A-KIT `TrajectoryN/` (or a data root holding `a-kit/`); default
    /// `ESTIM_DATA_DIR`, then `../shared/data`.
    #[arg(long, value_name = "DIR")]
    pub data: Option<PathBuf>,
    /// TOML configuration (lever arm, time offset, column names; as for `estim reproduce`).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Trajectories held out of the fit (repeatable); default 4 and 13, the test set.
    #[arg(long = "held-out", value_name = "N")]
    pub held_out: Vec<u32>,
    /// JSON (the schema of every `--json`, see docs/cli.md) instead of CSV.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, clap::Args)]
struct SolveArgs {
    /// Beam angle from the vertical, in degrees (BeamsNet 20, RDI Workhorse Navigator 30).
    #[arg(long, value_name = "DEG")]
    beam_angle: f64,
    /// Azimuth of beam 1 from the x axis, in degrees; beam i at offset + (i-1) 90.
    #[arg(
        long,
        value_name = "DEG",
        default_value_t = 45.0,
        allow_negative_numbers = true
    )]
    azimuth_offset: f64,
    /// Input CSV file, or `-` for stdin.
    #[arg(value_name = "INPUT.csv")]
    input: PathBuf,
}

#[derive(Debug, clap::Args)]
struct CalibrateArgs {
    /// Ground-truth file (`GT_trajectoryN.csv` layout).
    #[arg(long, value_name = "GT.csv")]
    gt: PathBuf,
    /// DVL file (`DVL_trajectoryN.csv` layout).
    #[arg(long, value_name = "DVL.csv")]
    dvl: PathBuf,
    /// Largest |time offset| searched, in seconds.
    #[arg(long, value_name = "S", default_value_t = 3.0)]
    max_time_offset: f64,
    /// Hold the time offset at zero instead of estimating it.
    #[arg(long)]
    no_time_offset: bool,
    /// JSON (the schema of every `--json`, see docs/cli.md) instead of CSV.
    #[arg(long)]
    json: bool,
}

/// `estim dvl` as parsed, by subcommand.
pub enum Mode {
    /// `dvl solve`, `dvl calibrate`, `dvl pd0`: run by [`run`].
    Tool(Tool),
    /// `dvl mismatch`: a fit on the A-KIT reproduction's training trajectories, with
    /// its configuration; that code runs it.
    Mismatch(MismatchArgs),
}

/// A subcommand that [`run`] runs.
pub struct Tool(ToolCommand);

enum ToolCommand {
    Solve(SolveArgs),
    Calibrate(CalibrateArgs),
    Pd0(Pd0Args),
}

impl Args {
    /// The subcommand, as [`Mode`] sorts it.
    pub fn into_mode(self) -> Mode {
        match self.command {
            Command::Solve(a) => Mode::Tool(Tool(ToolCommand::Solve(a))),
            Command::Calibrate(a) => Mode::Tool(Tool(ToolCommand::Calibrate(a))),
            Command::Mismatch(a) => Mode::Mismatch(a),
            Command::Pd0(a) => Mode::Tool(Tool(ToolCommand::Pd0(a))),
        }
    }
}

/// Run `estim dvl`'s own subcommands.
pub fn run(tool: Tool) -> anyhow::Result<()> {
    // Everything is written to a buffer and printed only on success, so that a
    // malformed input leaves stdout empty.
    let output = match tool.0 {
        ToolCommand::Solve(a) => solve(&a)?,
        ToolCommand::Calibrate(a) => calibrate(&a)?,
        ToolCommand::Pd0(a) => pd0(&a)?,
    };
    crate::output::emit(&output)
}

/// Largest `dvl calibrate --max-time-offset` \[s\].
const MAX_TIME_OFFSET_S: f64 = 60.0;

fn solve(args: &SolveArgs) -> anyhow::Result<String> {
    // The beam angle is checked by the geometry builder (naming `beam_angle`).
    let azimuth = args.azimuth_offset;
    if !(azimuth.is_finite() && azimuth.abs() <= 360.0) {
        anyhow::bail!("--azimuth-offset {azimuth} is outside [-360, 360] deg");
    }
    let geometry = BeamGeometry::janus(args.beam_angle)
        .azimuth_offset(args.azimuth_offset)
        .build()
        .context("beam geometry")?;
    let file = if args.input.as_os_str() == "-" {
        let stdin = std::path::Path::new("<stdin>");
        // At most MAX_INPUT_BYTES, binary streams refused after one block.
        let bytes = estim::datasets::read_input(std::io::stdin().lock(), stdin)?;
        BeamFile::parse(&bytes, stdin)?
    } else {
        BeamFile::load(&args.input)?
    };
    let mut out = String::new();
    if file.times.is_some() {
        out.push_str("time_s,");
    }
    out.push_str("vx,vy,vz,error_velocity,n_beams\n");
    for (k, beams) in file.rows.iter().enumerate() {
        if let Some(t) = file.times.as_ref().and_then(|times| times.get(k)) {
            let _ = write!(out, "{t},");
        }
        let solution = geometry.solve(beams);
        match solution.velocity() {
            Some(v) => {
                let _ = write!(out, "{},{},{},", v.x, v.y, v.z);
            }
            None => out.push_str(",,,"),
        }
        if let Some(e) = solution.error_velocity() {
            let _ = write!(out, "{e}");
        }
        let _ = writeln!(out, ",{}", solution.beams_used());
    }
    Ok(out)
}

fn pd0(args: &Pd0Args) -> anyhow::Result<String> {
    let name = args.input.display();
    // Binary input, read up to the input-size limit of every loader (an endless
    // stream such as /dev/zero stops there).
    let read = estim::datasets::read_pd0_input(&args.input, estim::datasets::MAX_INPUT_BYTES)?;
    for skip in &read.report.skipped {
        eprintln!("warning: {name}: {skip}");
    }
    if read.ensembles.is_empty() {
        anyhow::bail!(
            "{name}: no good PD0 ensemble in {} bytes ({} spans skipped)",
            read.report.input_bytes,
            read.report.skipped.len()
        );
    }
    if args.strict {
        if let Some(skip) = read.report.skipped.first() {
            anyhow::bail!("{name}: {skip} (--strict)");
        }
    }
    eprintln!(
        "{name}: {} ensembles decoded ({} with bottom track), {} spans skipped ({} bytes)",
        read.report.decoded,
        read.report.with_bottom_track,
        read.report.skipped.len(),
        read.report.skipped_bytes()
    );
    let mut out = Vec::new();
    estim_dvl::write_pd0_csv(&read.ensembles, &mut out)?;
    Ok(String::from_utf8(out)?)
}

fn calibrate(args: &CalibrateArgs) -> anyhow::Result<String> {
    let offset = args.max_time_offset;
    if !(offset.is_finite() && offset > 0.0 && offset <= MAX_TIME_OFFSET_S) {
        anyhow::bail!("--max-time-offset {offset} is outside (0, {MAX_TIME_OFFSET_S}] s");
    }
    let gt = load_gt(&args.gt)?;
    let dvl = load_dvl(&args.dvl)?;
    // The span rule of `reproduce`, with the searched time offset as the allowance.
    check_spans(
        &args.gt,
        &gt,
        &args.dvl,
        &dvl,
        SPAN_TIME_OFFSET_ALLOWANCE_S.max(args.max_time_offset.abs()),
        false,
    )?;
    let trajectory: Vec<TrajectorySample> = gt
        .iter()
        .map(|s| TrajectorySample {
            time: s.time,
            velocity_ned: Vector3::from(s.velocity_ned),
            roll_pitch_yaw: Vector3::from(s.roll_pitch_yaw),
        })
        .collect();
    let log: Vec<DvlMeasurement> = dvl
        .iter()
        .map(|s| DvlMeasurement {
            time: s.time,
            velocity: Vector3::from(s.velocity_body),
        })
        .collect();
    let calibrator = Calibrator::builder()
        .max_time_offset(args.max_time_offset)
        .estimate_time_offset(!args.no_time_offset)
        .build()?;
    let c = calibrator.calibrate(&trajectory, &log)?;
    if args.json {
        return calibration_json(args, &c);
    }
    let mut out = String::from("parameter,estimate,standard_error,unit\n");
    let rows = [
        ("lever_arm_x", c.lever_arm[0], "m"),
        ("lever_arm_y", c.lever_arm[1], "m"),
        ("lever_arm_z", c.lever_arm[2], "m"),
        ("scale_factor_error", c.scale_factor_error, "1"),
        ("misalignment_x", c.mounting_misalignment[0], "rad"),
        ("misalignment_y", c.mounting_misalignment[1], "rad"),
        ("misalignment_z", c.mounting_misalignment[2], "rad"),
        ("time_offset", c.time_offset, "s"),
    ];
    for (name, e, unit) in rows {
        let _ = writeln!(out, "{name},{:.6},{:.6},{unit}", e.value, e.standard_error);
    }
    let r = |v: &Vector3<f64>| format!("{:.4} {:.4} {:.4}", v.x, v.y, v.z);
    let _ = writeln!(
        out,
        "# samples {}; residual RMS x y z [m/s]: uncalibrated {}, calibrated {}; lag-1 autocorrelation {}",
        c.samples,
        r(&c.residual_rms_uncalibrated),
        r(&c.residual_rms),
        r(&c.residual_lag1_autocorrelation)
    );
    let _ = writeln!(
        out,
        "# standard errors assume white residuals; a lag-1 autocorrelation well above 0 makes them optimistic"
    );
    Ok(out)
}

/// `dvl calibrate --json`: the common header, then each estimate with its standard
/// error under a key naming its unit.
fn calibration_json(args: &CalibrateArgs, c: &estim_dvl::Calibration) -> anyhow::Result<String> {
    use crate::schema::{document, path_json};
    // Vectors (lever arm, misalignment) as arrays, scalars as numbers.
    let estimate = |e: &[&estim_dvl::Estimate]| {
        serde_json::json!({
            "estimate": e.iter().map(|x| x.value).collect::<Vec<_>>(),
            "standard_error": e.iter().map(|x| x.standard_error).collect::<Vec<_>>(),
        })
    };
    let scalar = |e: &estim_dvl::Estimate| serde_json::json!({ "estimate": e.value, "standard_error": e.standard_error });
    let v = |v: &Vector3<f64>| [v.x, v.y, v.z];
    let inputs = serde_json::json!({
        "gt": path_json(Some(&args.gt)),
        "dvl": path_json(Some(&args.dvl)),
        "max_time_offset_s": args.max_time_offset,
        "estimate_time_offset": !args.no_time_offset,
    });
    let doc = document(
        "dvl calibrate",
        inputs,
        0,
        serde_json::json!({
            "lever_arm_m": estimate(&[&c.lever_arm[0], &c.lever_arm[1], &c.lever_arm[2]]),
            "scale_factor_error": scalar(&c.scale_factor_error),
            "mounting_misalignment_rad": estimate(&[
                &c.mounting_misalignment[0],
                &c.mounting_misalignment[1],
                &c.mounting_misalignment[2],
            ]),
            "time_offset_s": scalar(&c.time_offset),
            "samples": c.samples,
            "residual_rms_uncalibrated_mps": v(&c.residual_rms_uncalibrated),
            "residual_rms_mps": v(&c.residual_rms),
            "residual_lag1_autocorrelation": v(&c.residual_lag1_autocorrelation),
        }),
    );
    Ok(format!("{}\n", serde_json::to_string_pretty(&doc)?))
}
