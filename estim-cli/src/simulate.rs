//! `estim simulate`: synthesize sensor files from a recorded trajectory (a
//! simulation, never a default path for user data): `simulate imu --gt GT.csv` writes
//! the study's IMU (the estim-ins simulator on the GT spline, corrupted by the
//! configured error model with the configured seed) as an IMU CSV on stdout;
//! `simulate beams --gt GT.csv --dvl DVL.csv` writes the study's BeamsNet-protocol
//! beams of the DVL velocity, at the DVL's time stamps. With `--vehicle-out V.toml`,
//! `simulate imu` also writes the vehicle configuration of the study's run (noise,
//! lever arm, A-KIT DVL time offset, gate, the seeded initial state), so that `estim
//! navigate --imu ... --beams ... --vehicle V.toml --truth GT.csv` is the study's LS
//! filter.

use std::fmt::Write as _;
use std::path::PathBuf;

use crate::study::{
    initial_covariance, initial_nominal, synthesize_imu, Config, ImuSource, Scenario,
};
use anyhow::Context;
use estim::datasets::{load_dvl_with, load_gt_with};

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
    /// TOML configuration of the study (IMU preset, rate, seed; see `estim reproduce
    /// --print-config`).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Also write the study's vehicle configuration for `estim navigate --vehicle`.
    #[arg(long, value_name = "FILE")]
    vehicle_out: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
struct BeamsArgs {
    /// Ground-truth CSV (the span the study keeps).
    #[arg(long, value_name = "FILE")]
    gt: PathBuf,
    /// DVL velocity CSV.
    #[arg(long, value_name = "FILE")]
    dvl: PathBuf,
    /// TOML configuration of the study.
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

/// The vehicle TOML of the study's LS filter run on this trajectory.
fn vehicle_toml(
    config: &Config,
    truth: &[estim::ins::InsState],
    spec: &estim::ins::ImuSpec,
) -> anyhow::Result<String> {
    let truth0 = truth.first().context("no truth")?;
    let scenario = Scenario {
        name: String::new(),
        trajectory: Some(0),
        truth: vec![*truth0],
        imu: Vec::new(),
        clean_imu: Vec::new(),
        imu_dt: 1.0 / config.mission.imu_rate_hz,
        imu_spec: *spec,
        dvl: Vec::new(),
        span: None,
        imu_source: ImuSource::Synthesized,
        recorded: None,
    };
    let p0 = initial_covariance(config, &scenario);
    let x0 = initial_nominal(truth0, &p0, config.seed);
    let (r, p, y) = x0.attitude.euler_angles();
    let f = &config.filter;
    let (a, g) = (spec.accelerometer(), spec.gyroscope());
    let acc =
        f.initial_bias_std_scale * (a.turn_on_bias.powi(2) + a.bias_instability.powi(2)).sqrt();
    let gyro =
        f.initial_bias_std_scale * (g.turn_on_bias.powi(2) + g.bias_instability.powi(2)).sqrt();
    let noise =
        (config.dvl.ls_noise_std.powi(2) + config.dvl.akit_reference_mismatch_std.powi(2)).sqrt();
    let l = config.dvl.lever_arm_m;
    let v = x0.velocity_ned;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# The study's LS filter (estim simulate imu --vehicle-out)."
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
    let scenario = Scenario::recorded(&args.gt, &args.dvl, &config, config.seed, false)?;
    // The rows the study kept, in order (its rule: the offset-corrected time rounds
    // to an IMU sample after the first and within the truth).
    let dvl = load_dvl_with(&args.dvl, &config.columns)?;
    let t0 = scenario.truth.first().map_or(0.0, |s| s.time);
    let dt = scenario.imu_dt;
    let kept: Vec<f64> = dvl
        .iter()
        .map(|d| d.time)
        .filter(|&time| {
            let i = ((time - config.dvl.akit_time_offset_s - t0) / dt).round();
            i >= 1.0 && i < scenario.truth.len() as f64
        })
        .collect();
    anyhow::ensure!(
        kept.len() == scenario.dvl.len(),
        "internal: {} DVL rows kept, {} epochs",
        kept.len(),
        scenario.dvl.len()
    );
    let mut out = String::from("time_s,beam1_mps,beam2_mps,beam3_mps,beam4_mps\n");
    for (time, epoch) in kept.iter().zip(&scenario.dvl) {
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
