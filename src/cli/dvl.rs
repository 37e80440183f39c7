//! `estim dvl`: beam least squares on a CSV file, and DVL calibration against a
//! reference trajectory.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context;
use estim::datasets::{load_beams, load_dvl, load_gt};
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
    /// Reads a CSV with a header row; the beam columns are found by name (`beam1`..`beam4`
    /// or `beam 1`..`beam 4`, any case), other columns are ignored; an empty or `nan`
    /// cell is a missing beam. Writes `vx,vy,vz,error_velocity,n_beams` to stdout, one
    /// row per input row; the error velocity is empty for a 3-beam solution, and the
    /// velocity too when fewer than 3 beams are present.
    Solve(SolveArgs),
    /// Estimate the DVL lever arm, scale factor, mounting misalignment and time offset
    /// against a ground-truth trajectory (A-KIT CSV files).
    Calibrate(CalibrateArgs),
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
    /// Input CSV file.
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
}

/// Run `estim dvl`.
pub fn run(args: Args) -> anyhow::Result<()> {
    // Everything is written to a buffer and printed only on success, so that a
    // malformed input leaves stdout empty.
    let output = match args.command {
        Command::Solve(a) => solve(&a)?,
        Command::Calibrate(a) => calibrate(&a)?,
    };
    print!("{output}");
    Ok(())
}

fn solve(args: &SolveArgs) -> anyhow::Result<String> {
    let geometry = BeamGeometry::janus(args.beam_angle)
        .azimuth_offset(args.azimuth_offset)
        .build()
        .context("beam geometry")?;
    let rows = load_beams(&args.input)?;
    let mut out = String::from("vx,vy,vz,error_velocity,n_beams\n");
    for beams in rows {
        let solution = geometry.solve(&beams);
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

fn calibrate(args: &CalibrateArgs) -> anyhow::Result<String> {
    let gt = load_gt(&args.gt)?;
    let dvl = load_dvl(&args.dvl)?;
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
