//! `estim beamsnet eval`: least squares vs BeamsNet on an A-KIT trajectory or on the
//! embedded simulated mission.

use std::path::PathBuf;

use anyhow::Context;
use estim_dvl::BeamsNetProtocol;
use estim_ins::{Mission, MissionConfig};
use estim_learned::BeamsNet;

use crate::study::{evaluate_beamsnet, filter_label, synthesize, BeamsNetEvaluation, BEAMSNET, LS};

use crate::dataset::{imu_spec, load_akit, TEST_TRAJECTORIES};
use crate::output::emit;
use crate::schema::{document, path_json};

/// Arguments of `estim beamsnet`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, clap::Subcommand)]
enum Command {
    /// Print LS vs BeamsNet accuracy (RMSE, MAE, R^2, VAF on |v|).
    Eval(EvalArgs),
}

#[derive(Debug, clap::Args)]
struct EvalArgs {
    /// Data root (holding a-kit/ or TrajectoryN/). Without it: the simulated mission.
    #[arg(long)]
    data: Option<PathBuf>,
    /// A-KIT trajectory number (with --data).
    #[arg(long, default_value_t = 4)]
    trajectory: u32,
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
    /// ONNX model (its .json metadata beside it); default: the committed models/beamsnet.onnx.
    #[arg(long)]
    model: Option<PathBuf>,
    /// Seed of the IMU errors and beam noise (trajectory n uses seed + n).
    #[arg(long, default_value_t = 7000)]
    seed: u64,
}

/// Run `estim beamsnet`.
pub fn run(args: Args) -> anyhow::Result<()> {
    match args.command {
        Command::Eval(a) => eval(a),
    }
}

fn eval(args: EvalArgs) -> anyhow::Result<()> {
    crate::schema::check_seeds("--seed", args.seed, u64::from(args.trajectory))?;
    let beamsnet = match &args.model {
        Some(path) => BeamsNet::load(path)
            .with_context(|| format!("loading BeamsNet from {}", path.display()))?,
        None => estim::models::beamsnet().context("the embedded BeamsNet model")?,
    };
    let model_json = match &args.model {
        Some(path) => path_json(Some(path)),
        None => serde_json::Value::from(estim::models::BEAMSNET_NAME),
    };
    let protocol = BeamsNetProtocol::v1();
    let seed = match args.data {
        Some(_) => args.seed + u64::from(args.trajectory),
        None => args.seed,
    };
    let (label, trajectory_json, evaluation) = match &args.data {
        Some(dir) => {
            if !TEST_TRAJECTORIES.contains(&args.trajectory) {
                eprintln!(
                    "note: trajectory {} is a training trajectory; the held-out ones are 4 and 13",
                    args.trajectory
                );
            }
            let (trajectory, dvl) = load_akit(dir, args.trajectory)?;
            let run = synthesize(&trajectory, &dvl, &imu_spec(), &protocol, seed)?;
            let e = evaluate_beamsnet(&beamsnet, protocol.geometry(), &run.samples)?;
            (
                format!("A-KIT trajectory {}", args.trajectory),
                serde_json::json!(args.trajectory),
                e,
            )
        }
        None => {
            let e = simulated(&beamsnet, &protocol, seed)?;
            (
                "simulated mission".to_string(),
                serde_json::json!("simulated"),
                e,
            )
        }
    };
    if args.json {
        let metrics = |id: &str, m: &estim_learned::Metrics| {
            serde_json::json!({
                "id": id,
                "label": filter_label(id, f64::NAN),
                "rmse_mps": m.rmse,
                "mae_mps": m.mae,
                "r2": m.r2,
                "vaf_percent": m.vaf,
            })
        };
        let inputs = serde_json::json!({
            "data": path_json(args.data.as_deref()),
            "trajectory": trajectory_json,
            "model": model_json,
            "seed": seed,
            "base_seed": args.seed,
        });
        let doc = document(
            "beamsnet eval",
            inputs,
            0,
            serde_json::json!({
                "trajectory": trajectory_json,
                "windows": evaluation.reference.len(),
                "velocity": [metrics(LS, &evaluation.ls), metrics(BEAMSNET, &evaluation.beamsnet)],
                "rmse_reduction_percent": evaluation.rmse_reduction_percent(),
            }),
        );
        emit(&format!("{}\n", serde_json::to_string_pretty(&doc)?))
    } else {
        emit(&print_table(&label, &evaluation, seed))
    }
}

/// The embedded default: a seeded estim-ins mission (400 s), DVL = true body velocity
/// sampled at 1 Hz, IMU and beams synthesized as for the A-KIT trajectories.
fn simulated(
    beamsnet: &BeamsNet,
    protocol: &BeamsNetProtocol,
    seed: u64,
) -> anyhow::Result<BeamsNetEvaluation> {
    let config = MissionConfig::builder().duration(400.0).build()?;
    let mission = Mission::generate(&config, seed)?;
    let trajectory = &mission.trajectory;
    let mut dvl = Vec::new();
    let mut t = trajectory.start_time() + 1.0;
    while t <= trajectory.end_time() {
        let state = trajectory.evaluate(t)?.state;
        dvl.push((t, state.attitude.inverse() * state.velocity_ned));
        t += 1.0;
    }
    let run = synthesize(trajectory, &dvl, &imu_spec(), protocol, seed)?;
    Ok(evaluate_beamsnet(
        beamsnet,
        protocol.geometry(),
        &run.samples,
    )?)
}

fn print_table(label: &str, e: &BeamsNetEvaluation, seed: u64) -> String {
    let mut out = format!(
        "{label}: {} windows, seed {seed}, metrics on |v|\n",
        e.reference.len()
    );
    out.push_str(&format!(
        "{:<10} {:>12} {:>12} {:>10} {:>11}\n",
        "method", "RMSE [m/s]", "MAE [m/s]", "R^2", "VAF [%]"
    ));
    for (name, m) in [("LS", &e.ls), ("BeamsNet", &e.beamsnet)] {
        out.push_str(&format!(
            "{name:<10} {:>12.6} {:>12.6} {:>10.6} {:>11.6}\n",
            m.rmse, m.mae, m.r2, m.vaf
        ));
    }
    out.push_str(&format!(
        "BeamsNet RMSE is {:.1}% below LS\n",
        e.rmse_reduction_percent()
    ));
    out
}
