//! `estim compare`: paired comparisons of filter variants on A-KIT, gate off.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context;
use estim::datasets::data_root;

use crate::output::emit;
use crate::schema::{document, path_json, status_result};
use crate::study::{
    beamsnet_without_sensitivity, paired_study, Config, Gate, ImuSelection, ImuSource, MAX_SEED,
};

/// Arguments of `estim compare`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Folder holding A-KIT `TrajectoryN/` (or a data root holding `a-kit/`); else
    /// `ESTIM_DATA_DIR`, then `../shared/data`.
    #[arg(long, value_name = "DIR")]
    data: Option<PathBuf>,
    /// A-KIT trajectories (repeatable); default all 13.
    #[arg(long = "trajectory", value_name = "N")]
    trajectories: Vec<u32>,
    /// First seed; the seeds are S, S+1, ..., S+seeds-1.
    #[arg(long = "first-seed", value_name = "S", default_value_t = 2000)]
    first_seed: u64,
    /// Number of seeds per trajectory (1-1000).
    #[arg(long, value_name = "N", default_value_t = 5)]
    seeds: u64,
    /// TOML configuration (see `estim reproduce --print-config`); the gate is turned
    /// off whatever it says.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Common gate decisions instead of the gate off: each variant first runs with the
    /// configured gate, then all run on the updates that all of them accepted.
    #[arg(long)]
    common_gate: bool,
    /// Which IMU a trajectory uses: `auto` (the recorded `IMU_trajectoryN.csv` where
    /// the folder holds one, else synthesized from the reference), `recorded` (an
    /// error where there is none) or `synthesized`.
    #[arg(long = "imu", value_enum, default_value = "auto")]
    imu: crate::study::ImuChoice,
    /// Vehicle file a recorded IMU is read with (axes, clocks, offsets, lever arms);
    /// default: the A-KIT vehicle, `vehicles/akit.toml`, embedded in the binary.
    #[arg(long, value_name = "FILE")]
    vehicle: Option<PathBuf>,
    /// JSON on stdout.
    #[arg(long)]
    json: bool,
}

/// Run it. Exit status 3 when some variant failed on some cell (the others are
/// reported, the failed cells left out of the pairs).
pub fn run(args: Args) -> anyhow::Result<()> {
    let config = match &args.config {
        Some(path) => Config::from_file(path)?,
        None => Config::default(),
    };
    if !(1..=1000).contains(&args.seeds) {
        anyhow::bail!("--seeds {} is outside 1-1000", args.seeds);
    }
    let last = args
        .first_seed
        .checked_add(args.seeds - 1)
        .filter(|s| *s <= MAX_SEED)
        .with_context(|| format!("--first-seed plus --seeds exceeds {MAX_SEED}"))?;
    let dir = data_root(args.data.as_deref()).context(
        "compare needs the A-KIT data: pass --data DIR, set ESTIM_DATA_DIR, \
         or place it at ../shared/data",
    )?;
    let trajectories = if args.trajectories.is_empty() {
        (1..=13).collect()
    } else {
        args.trajectories.clone()
    };
    let seeds: Vec<u64> = (args.first_seed..=last).collect();
    let learned = beamsnet_without_sensitivity(&config)?;
    let gate = if args.common_gate {
        Gate::Common
    } else {
        Gate::Off
    };
    let imu = ImuSelection {
        choice: args.imu,
        vehicle: args.vehicle.clone(),
    };
    let study = paired_study(
        &config,
        &dir,
        &trajectories,
        &seeds,
        gate,
        learned.as_ref(),
        &imu,
    )?;
    let failures = study.failures.len();
    if args.json {
        let inputs = serde_json::json!({
            "data": path_json(args.data.as_deref()),
            "trajectories": trajectories,
            "seeds": seeds,
            "common_gate": args.common_gate,
            "imu": args.imu,
            "vehicle": path_json(args.vehicle.as_deref()),
            "config_file": path_json(args.config.as_deref()),
            "config": config,
        });
        let body = serde_json::json!({ "paired": study, "failures": study.failures });
        let doc = document("compare", inputs, failures, body);
        emit(&format!("{}\n", serde_json::to_string_pretty(&doc)?))?;
    } else {
        let mut text = String::new();
        writeln!(
            text,
            "Paired comparison, {}; {} trajectories x {} seeds ({}-{}).\n\
             IMU per trajectory: {}. A recorded IMU is read through the vehicle file ({}); a \
             synthesized one uses the error model `{}`. Beams by the BeamsNet protocol from \
             the real DVL (A-KIT has no beam data); the seeds redraw only the synthetic \
             noise. NEES is per state with truth (15 synthesized, 9 recorded).\n\
             Intervals: 95 % Student t confidence intervals of the mean paired difference \
             (minuend - subtrahend); over trajectories = each trajectory's seed mean is one \
             sample (the real sample); over cells = every (trajectory, seed) is one sample.\n",
            match gate {
                Gate::Off => "innovation gate off".to_string(),
                Gate::Common => format!(
                    "common gate decisions (the updates all variants accepted with the gate at \
                     probability {})",
                    config.filter.gate_probability
                ),
            },
            trajectories.len(),
            seeds.len(),
            args.first_seed,
            last,
            study
                .imu_sources
                .iter()
                .map(|(n, source)| format!("{n} {}", source.as_str()))
                .collect::<Vec<_>>()
                .join(", "),
            match (
                &args.vehicle,
                study
                    .imu_sources
                    .values()
                    .any(|s| *s == ImuSource::Recorded)
            ) {
                (_, false) => "none recorded".to_string(),
                (Some(path), true) => path.display().to_string(),
                (None, true) => "vehicles/akit.toml, embedded".to_string(),
            },
            config.imu.preset,
        )?;
        text.push_str(&crate::study::paired_markdown(&study));
        for f in &study.failures {
            writeln!(text, "FAILED: trajectory cell left out: {f}")?;
        }
        emit(&text)?;
    }
    status_result(failures)
}
