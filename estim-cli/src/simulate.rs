//! `estim simulate`: synthesize sensor files from a recorded trajectory (a
//! simulation, never a default path for user data): `simulate imu --gt GT.csv` writes
//! the synthesized IMU of `estim reproduce` (the estim-ins simulator on the GT spline,
//! corrupted by the configured error model with the configured seed) as an IMU CSV on
//! stdout; `simulate beams --gt GT.csv --dvl DVL.csv` writes its BeamsNet-protocol
//! beams of the DVL velocity, at the DVL's time stamps. With `--vehicle-out V.toml`,
//! `simulate imu` also writes the vehicle configuration of that run (noise, lever arm,
//! A-KIT DVL time offset, gate, the seeded initial state), so that `estim navigate
//! --imu ... --beams ... --vehicle V.toml --truth GT.csv` is `reproduce`'s LS filter.
//! Built on the experiments' layer ([`crate::experiment`]).

use std::fmt::Write as _;
use std::path::PathBuf;

use crate::experiment::{
    dvl_epochs, initial_bias_std, initial_covariance, initial_nominal, synthesize_imu, Config,
};
use anyhow::Context;
use estim::datasets::{check_spans, load_dvl_with, load_gt_with, SPAN_TIME_OFFSET_ALLOWANCE_S};

/// Arguments of `estim simulate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    what: What,
}

#[derive(Debug, clap::Subcommand)]
enum What {
    /// IMU CSV on stdout, synthesized from a ground-truth file.
    Imu(ImuArgs),
    /// BeamsNet-protocol beams CSV on stdout, from a DVL velocity file.
    Beams(BeamsArgs),
}

#[derive(Debug, clap::Args)]
struct ImuArgs {
    /// Ground-truth CSV (columns by name, as for `estim reproduce --gt`).
    #[arg(long, value_name = "FILE")]
    gt: PathBuf,
    /// TOML configuration of the experiments (IMU preset, rate, seed; see `estim
    /// reproduce --print-config`).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Also write the vehicle configuration of `reproduce`'s LS run for `estim
    /// navigate --vehicle`.
    #[arg(long, value_name = "FILE")]
    vehicle_out: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
struct BeamsArgs {
    /// Ground-truth CSV (the span `reproduce` keeps).
    #[arg(long, value_name = "FILE")]
    gt: PathBuf,
    /// DVL velocity CSV.
    #[arg(long, value_name = "FILE")]
    dvl: PathBuf,
    /// TOML configuration of the experiments.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
}

/// Run it.
pub fn run(args: Args) -> anyhow::Result<()> {
    match args.what {
        What::Imu(a) => imu(a),
        What::Beams(a) => beams(a),
    }
}

fn config(path: &Option<PathBuf>) -> anyhow::Result<Config> {
    Ok(match path {
        Some(p) => Config::from_file(p)?,
        None => Config::default(),
    })
}

fn imu(args: ImuArgs) -> anyhow::Result<()> {
    if let Some(out) = &args.vehicle_out {
        crate::output::refuse_input_as_output(
            out,
            [Some(&args.gt), args.config.as_ref()].into_iter().flatten(),
        )?;
    }
    let config = config(&args.config)?;
    let gt = load_gt_with(&args.gt, &config.columns)?;
    let (truth, imu, _, _, spec) = synthesize_imu(&gt, &args.gt, &args.gt, &config, config.seed)?;
    if let Some(path) = &args.vehicle_out {
        let text = vehicle_toml(&config, &truth, &spec)?;
        std::fs::write(path, text).with_context(|| format!("{}: cannot write", path.display()))?;
    }
    let mut out = String::with_capacity(imu.len() * 200);
    out.push_str(
        "time_s,acc_x_mps2,acc_y_mps2,acc_z_mps2,gyro_x_radps,gyro_y_radps,gyro_z_radps,\
         true_acc_bias_x_mps2,true_acc_bias_y_mps2,true_acc_bias_z_mps2,\
         true_gyro_bias_x_radps,true_gyro_bias_y_radps,true_gyro_bias_z_radps\n",
    );
    for (s, t) in imu.iter().zip(&truth) {
        let (f, w, a, g) = (s.specific_force, s.angular_rate, t.acc_bias, t.gyro_bias);
        // `{}` is the shortest text that reads back as the same f64.
        let _ = writeln!(
            out,
            "{},{},{},{},{},{},{},{},{},{},{},{},{}",
            s.time, f.x, f.y, f.z, w.x, w.y, w.z, a.x, a.y, a.z, g.x, g.y, g.z
        );
    }
    crate::output::emit(&out)
}

/// The vehicle TOML of `reproduce`'s LS filter run on this trajectory.
fn vehicle_toml(
    config: &Config,
    truth: &[estim::ins::InsState],
    spec: &estim::ins::ImuSpec,
) -> anyhow::Result<String> {
    let truth0 = truth.first().context("no truth")?;
    let p0 = initial_covariance(config, spec);
    let x0 = initial_nominal(truth0, &p0, config.seed);
    let (r, p, y) = x0.attitude.euler_angles();
    let f = &config.filter;
    let (acc, gyro) = initial_bias_std(config, spec);
    let noise =
        (config.dvl.ls_noise_std.powi(2) + config.dvl.akit_reference_mismatch_std.powi(2)).sqrt();
    let l = config.dvl.lever_arm_m;
    let v = x0.velocity_ned;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# estim reproduce's LS filter (estim simulate imu --vehicle-out)."
    );
    let _ = writeln!(
        s,
        "[imu]\npreset = \"{}\"\nrate_hz = {:?}",
        config.imu.preset, config.mission.imu_rate_hz
    );
    let _ = writeln!(
        s,
        "\n[dvl]\nlever_arm_m = [{:?}, {:?}, {:?}]\ntime_offset_s = {:?}\nnoise_std_mps = {:?}\nbeam_angle_deg = 20.0\nbeam1_azimuth_deg = 45.0",
        l[0], l[1], l[2], config.dvl.akit_time_offset_s, noise
    );
    let _ = writeln!(
        s,
        "\n[gate]\nprobability = {:?}\nrecovery_after = {}",
        f.gate_probability, f.gate_recovery_after
    );
    let _ = writeln!(
        s,
        "\n[initial]\nlatitude_deg = {:?}\nlongitude_deg = {:?}\ndepth_m = {:?}\nvelocity_ned_mps = [{:?}, {:?}, {:?}]\nattitude_deg = [{:?}, {:?}, {:?}]",
        x0.latitude.to_degrees(),
        x0.longitude.to_degrees(),
        -x0.height,
        v.x,
        v.y,
        v.z,
        r.to_degrees(),
        p.to_degrees(),
        y.to_degrees()
    );
    let _ = writeln!(
        s,
        "position_std_m = {:?}\nvelocity_std_mps = {:?}\nlevel_std_deg = {:?}\nheading_std_deg = {:?}\nacc_bias_std_mps2 = {:?}\ngyro_bias_std_radps = {:?}",
        f.initial_position_std_m,
        f.initial_velocity_std_mps,
        f.initial_level_std_deg,
        f.initial_heading_std_deg,
        acc,
        gyro
    );
    Ok(s)
}

fn beams(args: BeamsArgs) -> anyhow::Result<()> {
    let config = config(&args.config)?;
    let gt = load_gt_with(&args.gt, &config.columns)?;
    let dvl = load_dvl_with(&args.dvl, &config.columns)?;
    // The two files must cover the same span (as `reproduce --gt --dvl` reads them).
    let allowance = SPAN_TIME_OFFSET_ALLOWANCE_S.max(config.dvl.akit_time_offset_s.abs());
    check_spans(&args.gt, &gt, &args.dvl, &dvl, allowance, false)?;
    let (truth, _, _, dt, _) = synthesize_imu(&gt, &args.gt, &args.dvl, &config, config.seed)?;
    let t0 = truth.first().map_or(0.0, |s| s.time);
    // The rows kept, in order: the offset-corrected time rounds to an IMU sample after
    // the first and within the truth.
    let epochs = dvl_epochs(&dvl, &args.dvl, [t0, dt], truth.len(), &config, config.seed)?;
    let mut out = String::from("time_s,beam1_mps,beam2_mps,beam3_mps,beam4_mps\n");
    for (time, epoch) in &epochs {
        let b = epoch.beams;
        let cell = |x: f64| {
            if x.is_finite() {
                format!("{x}")
            } else {
                String::new()
            }
        };
        let _ = writeln!(
            out,
            "{time},{},{},{},{}",
            cell(b[0]),
            cell(b[1]),
            cell(b[2]),
            cell(b[3])
        );
    }
    crate::output::emit(&out)
}
