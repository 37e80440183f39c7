//! `estim dvl`: beam least squares on a CSV file, and DVL calibration against a
//! reference trajectory.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context};
use estim::datasets::{load_dvl, load_gt};
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
    /// Beam angle from the vertical [deg] (BeamsNet 20, RDI Workhorse Navigator 30).
    #[arg(long, value_name = "DEG")]
    beam_angle: f64,
    /// Azimuth of beam 1 from the x axis [deg]; beam i at offset + (i-1) 90.
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
    /// Largest |time offset| searched [s].
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
    let rows = read_beams(&args.input)?;
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

/// Column indices of beams 1..4 from a header row.
fn beam_columns(path: &Path, header: &csv::StringRecord) -> anyhow::Result<[usize; 4]> {
    let mut found: [Option<usize>; 4] = [None; 4];
    for (index, name) in header.iter().enumerate() {
        let key: String = name
            .trim_start_matches('\u{feff}')
            .chars()
            .filter(|c| !c.is_whitespace())
            .collect::<String>()
            .to_ascii_lowercase();
        let beam = match key.as_str() {
            "beam1" => 0,
            "beam2" => 1,
            "beam3" => 2,
            "beam4" => 3,
            _ => continue,
        };
        if found[beam].is_some() {
            bail!(
                "{}:1: column for beam {} appears twice in the header",
                path.display(),
                beam + 1
            );
        }
        found[beam] = Some(index);
    }
    let missing: Vec<String> = (0..4)
        .filter(|&b| found[b].is_none())
        .map(|b| format!("beam{}", b + 1))
        .collect();
    if !missing.is_empty() {
        bail!(
            "{}:1: missing beam column(s) {} (expected beam1..beam4 or \"beam 1\"..\"beam 4\")",
            path.display(),
            missing.join(", ")
        );
    }
    Ok(found.map(|c| c.unwrap_or(0)))
}

/// Read the beams of every data row; a missing beam is `None`.
fn read_beams(path: &Path) -> anyhow::Result<Vec<[Option<f64>; 4]>> {
    let bytes = std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
    // Line numbers from byte offsets (the csv crate's own line counter skips blank
    // lines, and a record's offset may point at the blank lines before it).
    let line_at = |byte: u64| {
        let mut start = usize::try_from(byte).unwrap_or(usize::MAX).min(bytes.len());
        while start < bytes.len() && matches!(bytes[start], b'\n' | b'\r') {
            start += 1;
        }
        1 + bytes[..start].iter().filter(|&&c| c == b'\n').count()
    };
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .from_reader(&bytes[..]);
    let csv_error = |e: csv::Error| {
        let line = e.position().map_or(0, |p| line_at(p.byte()));
        anyhow!("{}:{line}: malformed CSV: {e}", path.display())
    };
    let mut records = reader.records();
    let header = match records.next() {
        Some(r) => r.map_err(csv_error)?,
        None => bail!("{}:1: empty file, a header row is required", path.display()),
    };
    let columns = beam_columns(path, &header)?;
    let mut rows = Vec::new();
    for record in records {
        let record = record.map_err(csv_error)?;
        let line = record.position().map_or(0, |p| line_at(p.byte()));
        if record.iter().all(|c| c.trim().is_empty()) && record.len() <= 1 {
            continue; // blank line
        }
        let mut beams = [None; 4];
        for (b, &col) in columns.iter().enumerate() {
            let Some(cell) = record.get(col) else {
                bail!(
                    "{}:{line}: {} fields, the beam{} column is field {}",
                    path.display(),
                    record.len(),
                    b + 1,
                    col + 1
                );
            };
            let cell = cell.trim();
            if cell.is_empty() || cell.eq_ignore_ascii_case("nan") {
                continue;
            }
            match cell.parse::<f64>() {
                Ok(x) if x.is_finite() => beams[b] = Some(x),
                _ => bail!(
                    "{}:{line}: column beam{}: `{}` is not a finite number",
                    path.display(),
                    b + 1,
                    cell.chars().take(40).collect::<String>()
                ),
            }
        }
        rows.push(beams);
    }
    Ok(rows)
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
