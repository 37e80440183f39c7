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
    dataset_row, synthesize_aligned, write_npy, WindowAlignment, DATASET_COLUMNS, IMU_RATE_HZ,
};

use crate::study::Config;

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

/// The IMU error model of `estim beamsnet eval` and of the committed BeamsNet's
/// training set: white noise as observed in the real 100 Hz stream (0.03 m/s^2, 5e-4
/// rad/s per sample) plus tactical-MEMS biases and 500 ppm scale factors.
pub fn imu_spec() -> ImuSpec {
    ImuSpec::akit_observed()
}

/// How `estim dataset beamsnet` synthesizes an example as the study's filter sees it
/// under `config`: the IMU error model of the test scenarios (`config.imu_spec()`:
/// `imu.preset`, without scale factors unless `imu.scale_factor_errors`) and the window
/// the filter feeds the network (DVL stamps shifted by `dvl.akit_time_offset_s`).
///
/// # Errors
/// An invalid IMU section, or an IMU rate other than the networks' 100 Hz.
pub fn filter_synthesis(config: &Config) -> anyhow::Result<(ImuSpec, WindowAlignment)> {
    let spec = config.imu_spec().map_err(anyhow::Error::msg)?;
    if config.mission.imu_rate_hz != IMU_RATE_HZ {
        bail!(
            "mission.imu_rate_hz = {}: the networks' windows are {IMU_RATE_HZ} Hz",
            config.mission.imu_rate_hz
        );
    }
    Ok((
        spec,
        WindowAlignment::Filter {
            time_offset_s: config.dvl.akit_time_offset_s,
        },
    ))
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
    let config = Config::default();
    let (spec, alignment) = filter_synthesis(&config)?;
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
            let run = synthesize_aligned(&trajectory, &dvl, &spec, &protocol, seed, alignment)
                .with_context(|| format!("trajectory {n}"))?;
            for s in &run.samples {
                // The GT rows the example depends on: its IMU window and its DVL row.
                let window = [
                    run.truth[s.imu_end - estim_learned::BEAMSNET_WINDOW].time,
                    run.truth[s.imu_end].time,
                ];
                let start = window[0].min(s.time);
                let end = window[1].max(s.time);
                if touches_held_out(&overlaps, n, &gt_times, start, end, &TEST_TRAJECTORIES) {
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
        "format": "estim-beamsnet-dataset/2",
        "columns": DATASET_COLUMNS,
        "rows": data.len() / DATASET_COLUMNS,
        "layout": {
            "acc": [0, 300], "gyro": [300, 600], "beams": [600, 604], "target": [604, 607],
            "trajectory": 607, "time": 608, "realization": 609,
            "window_order": "channel-major: x[0..100], y[0..100], z[0..100], oldest sample first"
        },
        "imu_rate_hz": IMU_RATE_HZ,
        "dvl_rate_hz": 1.0 / 1.0025,
        "window_alignment": {
            "rule": "filter",
            "time_offset_s": config.dvl.akit_time_offset_s,
            "description": "as the study's filter: a DVL sample stamped t measures the motion at t - time_offset_s; \
                its update follows IMU sample i - 1, i = round((t - time_offset_s - t0) / dt); the window is IMU \
                samples i - 100 .. i - 1 (t0: first GT time, dt = 0.01 s); column 608 holds the stamp t"
        },
        "imu_error_model": {
            "name": format!(
                "study default configuration: imu.preset = {}, imu.scale_factor_errors = {}",
                config.imu.preset, config.imu.scale_factor_errors
            ),
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

// The data lookup shared with the integration tests (one copy; the study's tests load
// it too, privately to the study).
#[cfg(test)]
#[allow(clippy::duplicate_mod)]
#[path = "../../tests/common/mod.rs"]
mod common;

#[cfg(test)]
mod tests {
    //! The dataset's windows are the windows the study's filter feeds the networks.
    //! Data rule: without the A-KIT data the data tests print why and return, unless
    //! `ESTIM_REQUIRE_DATA=1`.

    use super::common;
    use super::*;
    use crate::study::{two_beams_measurements, Scenario};
    use estim_core::nalgebra::DMatrix;
    use estim_learned::{synthesize, BeamsNetSample, BEAMSNET_WINDOW};

    /// Whether every example is the window, target and update the study builds for the
    /// same trajectory and seed, and every study epoch with a full window has one.
    fn check_windows(samples: &[BeamsNetSample], scenario: &Scenario) -> Result<(), String> {
        let n = BEAMSNET_WINDOW;
        let full = scenario.dvl.iter().filter(|e| e.imu_index >= n).count();
        if full != samples.len() {
            return Err(format!("{} examples, {full} study epochs", samples.len()));
        }
        for s in samples {
            let Some(epoch) = scenario.dvl.iter().find(|e| e.imu_index == s.imu_end) else {
                return Err(format!(
                    "stamp {}: no study update at IMU sample {}",
                    s.time, s.imu_end
                ));
            };
            if epoch.reference_velocity != s.target {
                return Err(format!("stamp {}: another DVL row at that update", s.time));
            }
            for (j, imu) in scenario.imu[s.imu_end - n..s.imu_end].iter().enumerate() {
                for r in 0..3 {
                    if s.input.acc[(r, j)] != imu.specific_force[r]
                        || s.input.gyro[(r, j)] != imu.angular_rate[r]
                    {
                        return Err(format!("stamp {}: window sample {j} differs", s.time));
                    }
                }
            }
        }
        Ok(())
    }

    #[test]
    fn dataset_windows_are_the_windows_the_filter_feeds() {
        let Some(root) = common::data_root() else {
            return;
        };
        let config = Config::default();
        let (spec, alignment) = filter_synthesis(&config).unwrap();
        let protocol = BeamsNetProtocol::v1();
        for (n, seed) in [(2, 4321), (12, 98)] {
            let (trajectory, dvl) = load_akit(&root, n).unwrap();
            let scenario = Scenario::akit(&root, n, &config, seed).unwrap();
            let run =
                synthesize_aligned(&trajectory, &dvl, &spec, &protocol, seed, alignment).unwrap();
            assert!(run.samples.len() > 350, "{} examples", run.samples.len());
            check_windows(&run.samples, &scenario).unwrap();
            // The former dataset (window ending at the stamp, 500 ppm scale factors)
            // and each of its two differences alone fail the check.
            let old = synthesize(&trajectory, &dvl, &imu_spec(), &protocol, seed).unwrap();
            assert!(check_windows(&old.samples, &scenario).is_err());
            let unshifted = synthesize(&trajectory, &dvl, &spec, &protocol, seed).unwrap();
            assert!(check_windows(&unshifted.samples, &scenario).is_err());
            let scaled =
                synthesize_aligned(&trajectory, &dvl, &imu_spec(), &protocol, seed, alignment)
                    .unwrap();
            assert!(check_windows(&scaled.samples, &scenario).is_err());

            // What the study's two-beams measurement computes at an update equals the
            // network run on the dataset's window with the study's beams.
            let net = estim::models::two_beams().unwrap();
            let picks: Vec<usize> = [50, 200, 300]
                .iter()
                .map(|&i| run.samples[i].imu_end)
                .filter_map(|end| scenario.dvl.iter().position(|e| e.imu_index == end))
                .collect();
            assert_eq!(picks.len(), 3);
            let study = two_beams_measurements(&net, &scenario, &picks, 0, seed).unwrap();
            for &k in &picks {
                let epoch = &scenario.dvl[k];
                let s = run
                    .samples
                    .iter()
                    .find(|s| s.imu_end == epoch.imu_index)
                    .unwrap();
                let mut inputs = vec![
                    DMatrix::from_fn(3, BEAMSNET_WINDOW, |r, c| s.input.acc[(r, c)]),
                    DMatrix::from_fn(3, BEAMSNET_WINDOW, |r, c| s.input.gyro[(r, c)]),
                ];
                inputs.extend(net.beam_inputs(&epoch.beams).unwrap());
                let direct = net.measurement().measure_batch(&[inputs]).unwrap()[0];
                let via_study = study.velocities[k].unwrap();
                assert!(
                    (direct - via_study).amax() < 1e-6,
                    "epoch {k}: {direct} vs {via_study}"
                );
            }
        }
    }

    /// The committed two-beams network's dataset was aligned as the filter feeds it,
    /// with the test scenarios' IMU error model. (The committed outage network was not
    /// retrained: training/README.md says why.)
    #[test]
    fn committed_two_beams_network_was_trained_as_the_filter_uses_it() {
        let config = Config::default();
        let (spec, _) = filter_synthesis(&config).unwrap();
        for (name, json) in [("two_beams", include_str!("../../models/two_beams.json"))] {
            let meta: serde_json::Value = serde_json::from_str(json).unwrap();
            let data = &meta["training"]["dataset_metadata"];
            assert_eq!(data["window_alignment"]["rule"], "filter", "{name}");
            assert_eq!(
                data["window_alignment"]["time_offset_s"].as_f64(),
                Some(config.dvl.akit_time_offset_s),
                "{name}"
            );
            let model = &data["imu_error_model"];
            for (sensor, s) in [
                ("accelerometer", spec.accelerometer()),
                ("gyroscope", spec.gyroscope()),
            ] {
                for (key, value) in [
                    ("white_noise_density", s.white_noise_density),
                    ("bias_instability", s.bias_instability),
                    ("bias_time_constant", s.bias_time_constant),
                    ("turn_on_bias", s.turn_on_bias),
                    ("scale_factor", s.scale_factor),
                ] {
                    assert_eq!(
                        model[sensor][key].as_f64(),
                        Some(value),
                        "{name} {sensor} {key}"
                    );
                }
            }
        }
    }
}
