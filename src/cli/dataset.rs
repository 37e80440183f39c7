//! `estim dataset beamsnet`: the BeamsNet training set from A-KIT trajectories.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use estim::datasets::{
    akit_overlaps, check_spans, data_root, load_dvl, load_gt, touches_held_out, trajectory_files,
    SPAN_TIME_OFFSET_ALLOWANCE_S, WINDOW_MARGIN_ROWS,
};
use estim_core::nalgebra::Vector3;
use estim_dvl::BeamsNetProtocol;
use estim_ins::{ImuSpec, Trajectory};
use estim_learned::{
    dataset_row, synthesize, write_npy, BEAMSNET_WINDOW, DATASET_COLUMNS, IMU_RATE_HZ,
};

/// Trajectories BeamsNet is trained on: A-KIT 1-3 and 5-12 (4 and 13 are held out).
pub const TRAINING_TRAJECTORIES: [u32; 11] = [1, 2, 3, 5, 6, 7, 8, 9, 10, 11, 12];
/// Held-out test trajectories, never used for training.
pub const TEST_TRAJECTORIES: [u32; 2] = [4, 13];

/// Arguments of `estim dataset`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    kind: Kind,
}

#[derive(Debug, clap::Subcommand)]
enum Kind {
    /// BeamsNet windows (IMU synthesized from GT, beams from the real DVL velocity).
    Beamsnet(BeamsnetArgs),
}

#[derive(Debug, clap::Args)]
struct BeamsnetArgs {
    /// Data root (holding a-kit/ or TrajectoryN/); default: $ESTIM_DATA_DIR, ../shared/data.
    #[arg(long)]
    data: Option<PathBuf>,
    /// Output .npy file (a .json description is written beside it).
    #[arg(long)]
    out: PathBuf,
    /// Noise realizations per trajectory (IMU errors and beam noise redrawn each time).
    #[arg(long, default_value_t = 4)]
    realizations: u32,
    /// Base seed; realization r of trajectory n uses seed + 1000 n + r.
    #[arg(long, default_value_t = 2022)]
    seed: u64,
}

/// The A-KIT IMU error model used for synthesis: white noise as observed in the real
/// 100 Hz stream (0.03 m/s^2, 5e-4 rad/s per sample) plus tactical-MEMS biases.
pub fn imu_spec() -> ImuSpec {
    ImuSpec::akit_observed()
}

/// DVL velocities `(time, v_body)`.
pub type DvlVelocities = Vec<(f64, Vector3<f64>)>;

/// Trajectory `n` as an estim-ins [`Trajectory`] plus its DVL velocities.
pub fn load_akit(dir: &Path, n: u32) -> anyhow::Result<(Trajectory, DvlVelocities)> {
    let files = trajectory_files(dir, n)?;
    let gt = load_gt(&files.gt)?;
    let dvl = load_dvl(&files.dvl)?;
    check_spans(
        &files.gt,
        &gt,
        &files.dvl,
        &dvl,
        SPAN_TIME_OFFSET_ALLOWANCE_S,
        false,
    )?;
    let samples = gt.iter().map(|g| g.trajectory_sample()).collect();
    let trajectory = Trajectory::new(samples)
        .with_context(|| format!("{}: not a usable trajectory", files.gt.display()))?;
    let dvl = dvl
        .iter()
        .filter(|d| d.time <= trajectory.end_time())
        .map(|d| (d.time, Vector3::from(d.velocity_body)))
        .collect();
    Ok((trajectory, dvl))
}

/// Run `estim dataset`.
pub fn run(args: Args) -> anyhow::Result<()> {
    match args.kind {
        Kind::Beamsnet(a) => beamsnet(a),
    }
}

fn beamsnet(args: BeamsnetArgs) -> anyhow::Result<()> {
    crate::schema::check_count(
        "--realizations",
        args.realizations as usize,
        1,
        crate::schema::MAX_REALIZATIONS,
    )?;
    // The largest seed: trajectory 13, the last realization, the beam-noise offset.
    crate::schema::check_seeds(
        "--seed",
        args.seed,
        1000 * 13 + u64::from(args.realizations) + 1_000_003,
    )?;
    // Checked before any work: the folder of --out is created, locked and written to
    // now; the .npy and its .json appear together at the end, or neither does.
    let (Some(npy_name), Some(json_name)) = (
        args.out.file_name(),
        args.out
            .with_extension("json")
            .file_name()
            .map(ToOwned::to_owned),
    ) else {
        bail!("--out {}: not a file name", args.out.display());
    };
    let folder = match args.out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let staged = crate::output::StagedDir::for_files(&folder)?;
    let npy_path = staged.path(&npy_name.to_string_lossy());
    let staged_meta = staged.path(&json_name.to_string_lossy());
    let Some(root) = data_root(args.data.as_deref()) else {
        bail!("no data folder: pass --data DIR or set ESTIM_DATA_DIR");
    };
    let protocol = BeamsNetProtocol::v1();
    let spec = imu_spec();
    // Rows shared between trajectories (identical GT and DVL values): every example
    // whose window touches a row shared with a held-out trajectory is left out, and the
    // groups of trajectories linked by shared rows are recorded so that the training
    // script keeps each group on one side of its train / validation split.
    let all: Vec<u32> = TRAINING_TRAJECTORIES
        .iter()
        .chain(&TEST_TRAJECTORIES)
        .copied()
        .collect();
    let overlaps = akit_overlaps(&root, &all)
        .context("finding rows shared with the held-out trajectories (all 13 are needed)")?;
    let window_s = BEAMSNET_WINDOW as f64 / IMU_RATE_HZ;
    let mut data = Vec::new();
    let mut counts = Vec::new();
    for n in TRAINING_TRAJECTORIES {
        let (trajectory, dvl) = load_akit(&root, n)?;
        let gt_times: Vec<f64> = load_gt(&trajectory_files(&root, n)?.gt)?
            .iter()
            .map(|g| g.time)
            .collect();
        let mut rows = 0;
        let mut excluded = 0;
        for r in 0..args.realizations {
            let seed = args.seed + 1000 * u64::from(n) + u64::from(r);
            let run = synthesize(&trajectory, &dvl, &spec, &protocol, seed)
                .with_context(|| format!("trajectory {n}"))?;
            for s in &run.samples {
                let start = s.time - window_s;
                if touches_held_out(&overlaps, n, &gt_times, start, s.time, &TEST_TRAJECTORIES) {
                    excluded += 1;
                    continue;
                }
                data.extend(dataset_row(s, n, r));
                rows += 1;
            }
        }
        counts.push(serde_json::json!({
            "trajectory": n, "rows": rows, "excluded_touching_held_out": excluded
        }));
        eprintln!("trajectory {n}: {rows} rows ({excluded} left out: they touch rows of a held-out trajectory)");
    }
    let shared_pairs: Vec<serde_json::Value> = overlaps
        .pairs()
        .iter()
        .map(|&(a, b, count)| {
            let span = |x: u32, y: u32| {
                let rows = overlaps.rows_shared_with(x, y);
                serde_json::json!([rows.first(), rows.last()])
            };
            serde_json::json!({
                "trajectories": [a, b], "rows": count,
                "rows_of_first": span(a, b), "rows_of_second": span(b, a)
            })
        })
        .collect();
    write_npy(&npy_path, DATASET_COLUMNS, &data)?;
    let geometry = protocol.geometry();
    let a = spec.accelerometer();
    let g = spec.gyroscope();
    let meta = serde_json::json!({
        "format": "estim-beamsnet-dataset/1",
        "columns": DATASET_COLUMNS,
        "rows": data.len() / DATASET_COLUMNS,
        "layout": {
            "acc": [0, 300], "gyro": [300, 600], "beams": [600, 604], "target": [604, 607],
            "trajectory": 607, "time": 608, "realization": 609,
            "window_order": "channel-major: x[0..100], y[0..100], z[0..100], oldest sample first"
        },
        "imu_rate_hz": IMU_RATE_HZ,
        "dvl_rate_hz": 1.0 / 1.0025,
        "imu_error_model": {
            "name": "ImuSpec::akit_observed (estim-ins)",
            "accelerometer": {
                "white_noise_density": a.white_noise_density,
                "per_sample_std_at_100hz": a.white_noise_density * IMU_RATE_HZ.sqrt(),
                "bias_instability": a.bias_instability,
                "bias_time_constant": a.bias_time_constant,
                "turn_on_bias": a.turn_on_bias,
                "scale_factor": a.scale_factor
            },
            "gyroscope": {
                "white_noise_density": g.white_noise_density,
                "per_sample_std_at_100hz": g.white_noise_density * IMU_RATE_HZ.sqrt(),
                "bias_instability": g.bias_instability,
                "bias_time_constant": g.bias_time_constant,
                "turn_on_bias": g.turn_on_bias,
                "scale_factor": g.scale_factor
            }
        },
        "beam_geometry": {
            "theta_deg": geometry.beam_angle_deg(),
            "psi_deg": [45.0, 135.0, 225.0, 315.0]
        },
        "beam_protocol": {
            "name": "BeamsNet V1 scripts",
            "formula": "beams = A v (1 + 0.007) + 0.042^2 n + 0.001, n ~ N(0, I4)",
            "scale_factor_error": BeamsNetProtocol::SCALE_FACTOR_ERROR,
            "noise_std": BeamsNetProtocol::NOISE_STD,
            "bias": BeamsNetProtocol::BIAS_V1
        },
        "trajectories": counts,
        "held_out_trajectories": TEST_TRAJECTORIES,
        "shared_rows": shared_pairs,
        "overlap_groups": overlaps.groups(),
        "overlap_rule": format!(
            "rows identical (GT and DVL values, time excluded) across trajectories are found in the files; \
             an example whose GT row span (IMU window + DVL sample, widened by {WINDOW_MARGIN_ROWS} rows each side) \
             touches a row shared with a held-out trajectory is left out; a validation split must keep \
             each overlap group on one side"
        ),
        "realizations": args.realizations,
        "seed": args.seed,
        "seed_rule": "IMU errors: seed + 1000 n + r; beam noise: that + 1000003",
        "source": "A-KIT GT_trajectoryN.csv (IMU synthesized) and DVL_trajectoryN.csv (target, beams)",
        "command": std::env::args().collect::<Vec<_>>().join(" ")
    });
    let meta_path = args.out.with_extension("json");
    std::fs::write(&staged_meta, serde_json::to_string_pretty(&meta)?)
        .with_context(|| format!("writing {}", meta_path.display()))?;
    staged.commit()?;
    eprintln!(
        "wrote {} rows to {} and {}",
        data.len() / DATASET_COLUMNS,
        args.out.display(),
        meta_path.display()
    );
    Ok(())
}
