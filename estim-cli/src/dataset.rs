//! `estim dataset beamsnet`: the BeamsNet training set from A-KIT trajectories.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use estim::datasets::{
    check_spans, data_root, load_dvl, load_gt, trajectory_files, SPAN_TIME_OFFSET_ALLOWANCE_S,
};
use estim_core::nalgebra::Vector3;
use estim_dvl::BeamsNetProtocol;
use estim_ins::{ImuSpec, Trajectory};
use estim_learned::{BeamsNetInput, BEAMSNET_WINDOW};

use crate::study::{
    akit_overlaps, dataset_row, synthesize_aligned, touches_held_out, write_npy, BeamsNetSample,
    Config, ImuChoice, RowOverlaps, Scenario, WindowAlignment, DATASET_COLUMNS, IMU_RATE_HZ,
    WINDOW_MARGIN_ROWS,
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
    /// BeamsNet windows (IMU synthesized from GT, or recorded with `--imu recorded`;
    /// beams from the real DVL velocity).
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
    /// Noise realizations per trajectory (beam noise, and the IMU errors of a synthesized
    /// IMU, redrawn each time).
    #[arg(long, default_value_t = 4)]
    realizations: u32,
    /// Base seed; realization r of trajectory n uses seed + 1000 n + r.
    #[arg(long, default_value_t = 2022)]
    seed: u64,
    /// The IMU windows: synthesized from the reference with the study's error model, or
    /// the vehicle's recorded IMU (`IMU_trajectoryN.csv` read through
    /// `vehicles/akit.toml`, as the study's filter integrates it).
    #[arg(long, value_enum, default_value_t = ImuWindows::Synthesized)]
    imu: ImuWindows,
}

/// Where `estim dataset beamsnet` takes the IMU windows from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum ImuWindows {
    /// Synthesized from the GT track (IMU errors redrawn per realization).
    Synthesized,
    /// The recorded IMU (only the beam noise is redrawn per realization).
    Recorded,
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
    let spec = config.imu_spec()?;
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

/// One trajectory's examples on its recorded IMU, for one seed.
struct RecordedExamples {
    /// Each example with the span of GT file time it depends on (its IMU window and
    /// its DVL sample).
    examples: Vec<(BeamsNetSample, [f64; 2])>,
    /// The vehicle file the IMU was read with.
    vehicle: String,
    /// The reference's clock offset against the IMU (as `estim navigate` reports it).
    truth_time_offset: serde_json::Value,
}

/// The examples of A-KIT trajectory `n` on its recorded IMU, as the study's filter
/// sees them (`Scenario::akit_choosing` with [`ImuChoice::Recorded`] and the embedded
/// `vehicles/akit.toml`): one per DVL update with a full window, the window being the
/// 100 recorded samples integrated before the update (`imu[imu_index - 100 ..
/// imu_index]`), the beams the scenario drew with `seed`, the target the DVL velocity.
fn recorded_examples(
    root: &Path,
    n: u32,
    config: &Config,
    seed: u64,
) -> anyhow::Result<RecordedExamples> {
    let scenario = Scenario::akit_choosing(root, n, config, seed, false, ImuChoice::Recorded, None)
        .with_context(|| format!("trajectory {n} on its recorded IMU"))?;
    let Some(recorded) = scenario.recorded.as_deref() else {
        bail!("trajectory {n}: the study did not read its recorded IMU");
    };
    // The survey's DVL rows are the scenario's epochs, in order (their stamps).
    anyhow::ensure!(
        recorded.inputs.dvl.len() == scenario.dvl.len(),
        "trajectory {n}: {} DVL rows for {} epochs",
        recorded.inputs.dvl.len(),
        scenario.dvl.len()
    );
    // The navigator's clock is the IMU's; the reference (GT, and the DVL file that
    // shares its time column) runs `offset_s` ahead: GT file time = clock + offset_s.
    let Some(offset) = recorded.truth_time_offset["offset_s"].as_f64() else {
        bail!("trajectory {n}: no reference clock offset");
    };
    let imu = &scenario.imu;
    let examples = scenario
        .dvl
        .iter()
        .zip(&recorded.inputs.dvl)
        .filter(|(epoch, _)| epoch.imu_index >= BEAMSNET_WINDOW && epoch.imu_index < imu.len())
        .map(|(epoch, row)| {
            let i = epoch.imu_index;
            let window = &imu[i - BEAMSNET_WINDOW..i];
            let force: Vec<_> = window.iter().map(|s| s.specific_force).collect();
            let rate: Vec<_> = window.iter().map(|s| s.angular_rate).collect();
            let start = (window[0].time + offset).min(row.time);
            let end = (imu[i].time + offset).max(row.time);
            let sample = BeamsNetSample {
                time: row.time,
                input: BeamsNetInput::from_samples(&force, &rate, epoch.beams),
                target: epoch.reference_velocity,
                imu_end: i,
            };
            (sample, [start, end])
        })
        .collect();
    Ok(RecordedExamples {
        examples,
        vehicle: recorded.vehicle.clone(),
        truth_time_offset: recorded.truth_time_offset.clone(),
    })
}

/// The dataset description's IMU part for synthesized windows.
fn synthesized_description(config: &Config, spec: &ImuSpec) -> serde_json::Value {
    let a = spec.accelerometer();
    let g = spec.gyroscope();
    serde_json::json!({
        "imu_source": "synthesized",
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
        "seed_rule": "IMU errors: seed + 1000 n + r; beam noise: that + 1000003",
        "source": "A-KIT GT_trajectoryN.csv (IMU synthesized) and DVL_trajectoryN.csv (target, beams)"
    })
}

/// The dataset description's IMU part for recorded windows read with `vehicle`.
///
/// # Errors
/// The embedded vehicle file does not parse.
fn recorded_description(vehicle: &str) -> anyhow::Result<serde_json::Value> {
    let nav: estim::navigator::NavigatorConfig =
        toml::from_str(crate::study::AKIT_VEHICLE).context("the embedded vehicles/akit.toml")?;
    Ok(serde_json::json!({
        "imu_source": "recorded",
        "vehicle": vehicle,
        "vehicle_toml": crate::study::AKIT_VEHICLE,
        "window_alignment": {
            "rule": "filter",
            "imu": "recorded",
            "time_offset_s": nav.dvl.time_offset_s,
            "description": "as the study's filter on the recorded IMU (Scenario::akit_choosing, ImuChoice::Recorded): \
                IMU_trajectoryN.csv read through the vehicle file (axes, clock scale) onto the navigator's clock, \
                the run from the reference's first epoch in the IMU's span to its last; a DVL row stamped t is \
                applied at the IMU sample i nearest t - time_offset_s (within half a period), after integrating \
                samples i - 100 .. i - 1, which are the window; column 608 holds the stamp t (DVL file time); \
                per trajectory, reference_time_offset is the reference's clock offset against the IMU, \
                estimated from the IMU's angular rate (GT file time = navigator time + offset_s), used only \
                to place each example on the GT rows for the overlap rule"
        },
        "imu_error_model": null,
        "seed_rule": "the recorded IMU is the same in every realization; beam noise: ChaCha8 seeded with \
            (seed + 1000 n + r) XOR 0xD71, one draw per DVL row of the run in time order, as the study draws it",
        "source": "A-KIT IMU_trajectoryN.csv (recorded IMU windows), GT_trajectoryN.csv (clock offset, overlap \
            rows) and DVL_trajectoryN.csv (target, beams)"
    }))
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
    let (staged, npy_path, staged_meta) = staged_outputs(&args.out)?;
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
    // What the recorded IMU was read with (the same for every trajectory).
    let mut vehicle = None;
    for n in TRAINING_TRAJECTORIES {
        let gt_times: Vec<f64> = load_gt(&trajectory_files(&root, n)?.gt)?
            .iter()
            .map(|g| g.time)
            .collect();
        let synthesized = match args.imu {
            ImuWindows::Synthesized => Some(load_akit(&root, n)?),
            ImuWindows::Recorded => None,
        };
        let mut rows = 0;
        let mut excluded = 0;
        let mut truth_time_offset = serde_json::Value::Null;
        for r in 0..args.realizations {
            let seed = args.seed + 1000 * u64::from(n) + u64::from(r);
            // Each example with the span of GT file time it depends on: its IMU window
            // and its DVL sample.
            let examples: Vec<(BeamsNetSample, [f64; 2])> = match &synthesized {
                Some((trajectory, dvl)) => {
                    let run =
                        synthesize_aligned(trajectory, dvl, &spec, &protocol, seed, alignment)
                            .with_context(|| format!("trajectory {n}"))?;
                    let truth = &run.truth;
                    run.samples
                        .into_iter()
                        .map(|s| {
                            let start = truth[s.imu_end - BEAMSNET_WINDOW].time.min(s.time);
                            let end = truth[s.imu_end].time.max(s.time);
                            (s, [start, end])
                        })
                        .collect()
                }
                None => {
                    let recorded = recorded_examples(&root, n, &config, seed)?;
                    truth_time_offset = recorded.truth_time_offset;
                    vehicle = Some(recorded.vehicle);
                    recorded.examples
                }
            };
            for (s, [start, end]) in &examples {
                if touches_held_out(&overlaps, n, &gt_times, *start, *end, &TEST_TRAJECTORIES) {
                    excluded += 1;
                    continue;
                }
                data.extend(dataset_row(s, n, r));
                rows += 1;
            }
        }
        let mut count = serde_json::json!({
            "trajectory": n, "rows": rows, "excluded_touching_held_out": excluded
        });
        if args.imu == ImuWindows::Recorded {
            count["reference_time_offset"] = truth_time_offset;
        }
        counts.push(count);
        eprintln!("trajectory {n}: {rows} rows ({excluded} left out: they touch rows of a held-out trajectory)");
    }
    write_npy(&npy_path, DATASET_COLUMNS, &data)?;
    let imu = match (args.imu, vehicle) {
        (ImuWindows::Synthesized, _) => synthesized_description(&config, &spec),
        (ImuWindows::Recorded, Some(vehicle)) => recorded_description(&vehicle)?,
        (ImuWindows::Recorded, None) => bail!("no trajectory was read"),
    };
    let meta = metadata(
        &args,
        data.len() / DATASET_COLUMNS,
        &protocol,
        counts,
        &overlaps,
        imu,
    );
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

/// The staged folder of `--out` (created and locked now) and the staged paths of the
/// `.npy` and its `.json`.
fn staged_outputs(out: &Path) -> anyhow::Result<(crate::output::StagedDir, PathBuf, PathBuf)> {
    let (Some(npy_name), Some(json_name)) = (
        out.file_name(),
        out.with_extension("json")
            .file_name()
            .map(ToOwned::to_owned),
    ) else {
        bail!("--out {}: not a file name", out.display());
    };
    let folder = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let staged = crate::output::StagedDir::for_files(&folder)?;
    let npy_path = staged.path(&npy_name.to_string_lossy());
    let staged_meta = staged.path(&json_name.to_string_lossy());
    Ok((staged, npy_path, staged_meta))
}

/// The dataset's `.json` description: layout, rates, beam protocol, the rows per
/// trajectory (`counts`), the rows shared between trajectories and the rule that left
/// examples out, and the IMU's description (`imu`, merged in).
fn metadata(
    args: &BeamsnetArgs,
    rows: usize,
    protocol: &BeamsNetProtocol,
    counts: Vec<serde_json::Value>,
    overlaps: &RowOverlaps,
    imu: serde_json::Value,
) -> serde_json::Value {
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
    let geometry = protocol.geometry();
    let mut meta = serde_json::json!({
        "format": "estim-beamsnet-dataset/2",
        "columns": DATASET_COLUMNS,
        "rows": rows,
        "layout": {
            "acc": [0, 300], "gyro": [300, 600], "beams": [600, 604], "target": [604, 607],
            "trajectory": 607, "time": 608, "realization": 609,
            "window_order": "channel-major: x[0..100], y[0..100], z[0..100], oldest sample first"
        },
        "imu_rate_hz": IMU_RATE_HZ,
        "dvl_rate_hz": 1.0 / 1.0025,
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
        "command": std::env::args().collect::<Vec<_>>().join(" ")
    });
    if let (Some(meta), serde_json::Value::Object(imu)) = (meta.as_object_mut(), imu) {
        meta.extend(imu);
    }
    meta
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
    use crate::study::{synthesize, two_beams_measurements, BeamsNetSample, Scenario};
    use estim_core::nalgebra::DMatrix;
    use estim_learned::BEAMSNET_WINDOW;

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

    /// `--imu recorded`: every row of trajectory 2 is the study's recorded scenario at
    /// the row's DVL stamp (the window is the scenario's `imu` slice before the update,
    /// the beams and target its epoch's), realizations differ only in the beam noise,
    /// and no row touches a row shared with trajectory 4 or 13.
    #[test]
    fn recorded_dataset_rows_are_the_recorded_scenarios_windows() {
        let Some(root) = common::data_root() else {
            return;
        };
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("recorded.npy");
        let seed = 2022;
        beamsnet(BeamsnetArgs {
            data: Some(root.clone()),
            out: out.clone(),
            realizations: 2,
            seed,
            imu: ImuWindows::Recorded,
        })
        .unwrap();
        let bytes = std::fs::read(&out).unwrap();
        let header = usize::from(u16::from_le_bytes([bytes[8], bytes[9]]));
        let values: Vec<f64> = bytes[10 + header..]
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect();
        let rows: Vec<&[f64]> = values.chunks_exact(DATASET_COLUMNS).collect();
        let meta: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.with_extension("json")).unwrap()).unwrap();
        assert_eq!(meta["imu_source"], "recorded");
        assert_eq!(meta["rows"].as_u64(), Some(rows.len() as u64));
        assert_eq!(meta["window_alignment"]["rule"], "filter");

        let config = Config::default();
        let scenario = |n: u32, r: u32| {
            let seed = seed + 1000 * u64::from(n) + u64::from(r);
            Scenario::akit_choosing(&root, n, &config, seed, false, ImuChoice::Recorded, None)
                .unwrap()
        };
        let n = BEAMSNET_WINDOW;
        for r in 0..2 {
            let study = scenario(2, r);
            let recorded = study.recorded.as_deref().unwrap();
            let of2: Vec<&[f64]> = rows
                .iter()
                .copied()
                .filter(|row| row[607] == 2.0 && row[609] == f64::from(r))
                .collect();
            let full = study.dvl.iter().filter(|e| e.imu_index >= n).count();
            assert!(of2.len() > 350 && of2.len() == full, "{} rows", of2.len());
            for row in of2 {
                let k = recorded
                    .inputs
                    .dvl
                    .iter()
                    .position(|d| d.time == row[608])
                    .unwrap();
                let epoch = &study.dvl[k];
                let i = epoch.imu_index;
                for (j, s) in study.imu[i - n..i].iter().enumerate() {
                    for c in 0..3 {
                        assert_eq!(row[c * n + j], s.specific_force[c], "stamp {}", row[608]);
                        assert_eq!(row[3 * n + c * n + j], s.angular_rate[c]);
                    }
                }
                assert_eq!(&row[600..604], epoch.beams.as_slice());
                assert_eq!(&row[604..607], epoch.reference_velocity.as_slice());
            }
        }
        // The two realizations: the same windows, other beam noise.
        let first = |r: f64| {
            rows.iter()
                .find(|row| row[607] == 2.0 && row[609] == r)
                .unwrap()
        };
        assert_eq!(&first(0.0)[..604 - 4], &first(1.0)[..604 - 4]);
        assert_ne!(&first(0.0)[600..604], &first(1.0)[600..604]);

        // Nothing of 4 or 13; every row of 10 ends (IMU window and DVL stamp, on the GT
        // file's clock) more than 2 rows before the first row 10 shares with 13.
        assert!(rows.iter().all(|row| row[607] != 4.0 && row[607] != 13.0));
        let all: Vec<u32> = (1..=13).collect();
        let overlaps = akit_overlaps(&root, &all).unwrap();
        let first_shared = overlaps.rows_shared_with(10, 13)[0];
        let gt10 = load_gt(&trajectory_files(&root, 10).unwrap().gt).unwrap();
        let study = scenario(10, 0);
        let recorded = study.recorded.as_deref().unwrap();
        let offset = recorded.truth_time_offset["offset_s"].as_f64().unwrap();
        let mut kept = 0;
        for row in rows
            .iter()
            .filter(|row| row[607] == 10.0 && row[609] == 0.0)
        {
            let k = recorded
                .inputs
                .dvl
                .iter()
                .position(|d| d.time == row[608])
                .unwrap();
            let end = (study.imu[study.dvl[k].imu_index].time + offset).max(row[608]);
            assert!(
                end < gt10[first_shared - 2].time,
                "a row of 10 ends at {end} s"
            );
            kept += 1;
        }
        assert!(kept > 250, "{kept} rows of 10");
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
