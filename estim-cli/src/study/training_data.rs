//! BeamsNet examples synthesized from a recorded trajectory: IMU windows from the
//! estim-ins simulator, beams simulated from the DVL velocities with the BeamsNet
//! protocol, the rows and `.npy` file the training scripts read (`estim dataset
//! beamsnet`), and least squares against BeamsNet on them (`estim beamsnet eval`, the
//! paper's Tables I and II).

use std::io::Write;
use std::path::Path;

use estim_dvl::{BeamGeometry, BeamsNetProtocol};
use estim_ins::{ImuErrorGenerator, ImuSample, ImuSpec, InsState, Trajectory};
use estim_learned::{speed_metrics, BeamsNet, BeamsNetInput, Metrics, BEAMSNET_WINDOW};
use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use super::{PipelineError, Result};

/// Columns of a dataset row (the layout in [`synthesize`]).
pub const DATASET_COLUMNS: usize = 610;

/// IMU rate of the synthesized windows \[Hz\].
pub const IMU_RATE_HZ: f64 = 100.0;

/// One synthesized BeamsNet example.
#[derive(Debug, Clone, PartialEq)]
pub struct BeamsNetSample {
    /// DVL sample time stamp \[s\].
    pub time: f64,
    /// Network input (measured IMU window + beams).
    pub input: BeamsNetInput,
    /// Target: the DVL velocity (body) \[m/s\].
    pub target: Vector3<f64>,
    /// Index one past the window's last IMU sample in [`SynthesizedRun::imu`].
    pub imu_end: usize,
}

/// A whole synthesized run: truth states and IMU at 100 Hz plus the examples.
#[derive(Debug, Clone)]
pub struct SynthesizedRun {
    /// Truth states at the IMU sample times (one more than `imu`).
    pub truth: Vec<InsState>,
    /// Measured (corrupted) IMU samples.
    #[cfg_attr(
        not(test),
        expect(dead_code, reason = "the tests check each window against it")
    )]
    pub imu: Vec<ImuSample>,
    /// The examples, one per DVL sample with a full window.
    pub samples: Vec<BeamsNetSample>,
}

/// How a DVL sample is paired with its IMU window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum WindowAlignment {
    /// The window ends at the DVL time stamp: the [`BEAMSNET_WINDOW`] samples whose
    /// intervals end at or before the stamp t_k (index floor((t_k - t0) / dt)), no time
    /// offset. The alignment of `estim beamsnet eval` and of the committed BeamsNet's
    /// training set.
    EndsAtStamp,
    /// The window the filter feeds the network (the study's `Scenario::recorded` and
    /// its learned measurements): a DVL sample stamped t_k measures the motion at
    /// t_k - `time_offset_s`, its update is applied after IMU sample i - 1 with
    /// i = round((t_k - time_offset_s - t0) / dt), and the window is IMU samples
    /// i - [`BEAMSNET_WINDOW`] .. i - 1. Samples with i outside 1 ..= (number of IMU
    /// samples) are dropped (the filter drops them too), as are those without a full
    /// window.
    Filter {
        /// DVL time offset \[s\] (`dvl.akit_time_offset_s` of the study).
        time_offset_s: f64,
    },
}

impl WindowAlignment {
    /// Index one past the window's last IMU sample for a DVL sample stamped `time`
    /// (trajectory start `t0`, IMU period `dt`, `len` IMU samples); `None` if the
    /// sample gets no full window.
    fn window_end(&self, time: f64, t0: f64, dt: f64, len: usize) -> Option<usize> {
        match *self {
            Self::EndsAtStamp => {
                // Samples whose interval [t0 + j dt, t0 + (j+1) dt] ends at or before `time`.
                let end = ((time - t0) / dt + 1e-6).floor();
                if end < BEAMSNET_WINDOW as f64 {
                    return None;
                }
                let end = (end as usize).min(len);
                (end >= BEAMSNET_WINDOW).then_some(end)
            }
            Self::Filter { time_offset_s } => {
                // The same expression as the study's Scenario::recorded, so that the
                // index is the same to the bit.
                let t = time - time_offset_s;
                let i = ((t - t0) / dt).round();
                if !(1.0..=len as f64).contains(&i) || i < BEAMSNET_WINDOW as f64 {
                    return None;
                }
                Some(i as usize)
            }
        }
    }
}

/// [`synthesize_aligned`] with [`WindowAlignment::EndsAtStamp`].
///
/// # Errors
/// As [`synthesize_aligned`].
pub fn synthesize(
    trajectory: &Trajectory,
    dvl: &[(f64, Vector3<f64>)],
    imu_spec: &ImuSpec,
    protocol: &BeamsNetProtocol,
    seed: u64,
) -> Result<SynthesizedRun> {
    synthesize_aligned(
        trajectory,
        dvl,
        imu_spec,
        protocol,
        seed,
        WindowAlignment::EndsAtStamp,
    )
}

/// Synthesize BeamsNet examples from a trajectory and DVL velocities `(time stamp,
/// v_body)`, each DVL sample paired with the IMU window given by `alignment`.
///
/// Seeds: the IMU errors use `seed`, the beam noise `seed + 1_000_003` (independent
/// ChaCha8 streams).
///
/// # Synthesis
///
/// 1. The trajectory (e.g. A-KIT ground truth at 1 Hz) is interpolated and inverted by
///    the estim-ins simulator into error-free 100 Hz IMU samples
///    ([`estim_ins::Trajectory::simulate`]).
/// 2. A seeded [`estim_ins::ImuErrorGenerator`] corrupts them (white noise, turn-on
///    bias, Gauss-Markov drift, scale factor of the given [`estim_ins::ImuSpec`]),
///    one draw per sample in time order, as the study synthesizes the IMU of a
///    recorded trajectory: the same trajectory, spec and seed give the same samples.
/// 3. For each DVL sample, the window is the 100 IMU samples given by `alignment`
///    ([`WindowAlignment`]); samples without a full window are skipped.
/// 4. Beams = the BeamsNet protocol applied to the DVL velocity
///    ([`estim_dvl::BeamsNetProtocol::beams`]); target = the DVL velocity.
///
/// # File format (`.npy` + `.json` sidecar)
///
/// `FILE.npy`: NumPy format 1.0, little-endian `float64`, C order, shape
/// `(N, DATASET_COLUMNS)`; row layout:
///
/// | columns | content |
/// |---|---|
/// | 0..300 | specific force, channel-major: x[0..100], y[0..100], z[0..100] (m/s^2) |
/// | 300..600 | angular rate, same layout (rad/s) |
/// | 600..604 | beams 1..4 (m/s) |
/// | 604..607 | target DVL velocity x, y, z (body, m/s) |
/// | 607 | trajectory number |
/// | 608 | DVL sample time stamp (s) |
/// | 609 | realization index (IMU / beam noise draw) |
///
/// `FILE.json` (same stem) records the column count, the window alignment, the IMU
/// error model, the beam protocol and geometry, the trajectories and seeds (written by
/// `estim dataset beamsnet`).
///
/// # Errors
/// [`PipelineError::Trajectory`] for a trajectory the simulator refuses,
/// [`PipelineError::DvlEpoch`] for a non-finite DVL sample and
/// [`PipelineError::Setting`] for a non-finite time offset.
pub fn synthesize_aligned(
    trajectory: &Trajectory,
    dvl: &[(f64, Vector3<f64>)],
    imu_spec: &ImuSpec,
    protocol: &BeamsNetProtocol,
    seed: u64,
    alignment: WindowAlignment,
) -> Result<SynthesizedRun> {
    if let WindowAlignment::Filter { time_offset_s } = alignment {
        if !time_offset_s.is_finite() {
            return Err(PipelineError::Setting {
                key: "dvl.akit_time_offset_s".into(),
                reason: format!("invalid DVL time offset: {time_offset_s} is not finite"),
            });
        }
    }
    let (truth, imu_clean) = trajectory
        .simulate(IMU_RATE_HZ)
        .map_err(PipelineError::Trajectory)?;
    let dt = 1.0 / IMU_RATE_HZ;
    let mut generator = ImuErrorGenerator::new(*imu_spec, seed);
    let imu: Vec<ImuSample> = imu_clean.iter().map(|s| generator.corrupt(s, dt)).collect();
    let mut beam_rng = ChaCha8Rng::seed_from_u64(seed.wrapping_add(1_000_003));
    let t0 = trajectory.start_time();
    let mut samples = Vec::with_capacity(dvl.len());
    for (k, &(time, velocity)) in dvl.iter().enumerate() {
        if !time.is_finite() || velocity.iter().any(|v| !v.is_finite()) {
            return Err(PipelineError::DvlEpoch {
                scenario: "the DVL log".into(),
                epoch: k,
                reason: format!("invalid DVL sample: non-finite value at time {time}"),
            });
        }
        let Some(end) = alignment.window_end(time, t0, dt, imu.len()) else {
            continue;
        };
        let window = &imu[end - BEAMSNET_WINDOW..end];
        let force: Vec<Vector3<f64>> = window.iter().map(|s| s.specific_force).collect();
        let rate: Vec<Vector3<f64>> = window.iter().map(|s| s.angular_rate).collect();
        let beams = protocol.beams(&velocity, &mut beam_rng);
        samples.push(BeamsNetSample {
            time,
            input: BeamsNetInput::from_samples(&force, &rate, beams),
            target: velocity,
            imu_end: end,
        });
    }
    Ok(SynthesizedRun {
        truth,
        imu,
        samples,
    })
}

/// One dataset row (the layout in [`synthesize`]).
pub fn dataset_row(sample: &BeamsNetSample, trajectory: u32, realization: u32) -> Vec<f64> {
    let mut row = Vec::with_capacity(DATASET_COLUMNS);
    for m in [&sample.input.acc, &sample.input.gyro] {
        for r in 0..3 {
            row.extend(m.row(r).iter().copied());
        }
    }
    row.extend(sample.input.beams.iter().copied());
    row.extend(sample.target.iter().copied());
    row.push(f64::from(trajectory));
    row.push(sample.time);
    row.push(f64::from(realization));
    row
}

/// Write a 2-D little-endian `float64` C-order array in NumPy `.npy` format 1.0.
pub fn write_npy(path: &Path, columns: usize, data: &[f64]) -> Result<()> {
    if columns == 0 || !data.len().is_multiple_of(columns) {
        return Err(PipelineError::Data {
            path: path.to_path_buf(),
            line: None,
            reason: format!(
                "invalid npy array: {} values do not fill rows of {columns}",
                data.len()
            ),
        });
    }
    let rows = data.len() / columns;
    let mut header =
        format!("{{'descr': '<f8', 'fortran_order': False, 'shape': ({rows}, {columns}), }}");
    // Magic (6) + version (2) + header length (2) + header, padded to 64 with '\n' last.
    let unpadded = 10 + header.len() + 1;
    header.push_str(&" ".repeat((64 - unpadded % 64) % 64));
    header.push('\n');
    let io = |source| PipelineError::Io {
        path: path.to_path_buf(),
        source,
    };
    let file = std::fs::File::create(path).map_err(io)?;
    let mut w = std::io::BufWriter::new(file);
    w.write_all(b"\x93NUMPY\x01\x00").map_err(io)?;
    let len = u16::try_from(header.len()).map_err(|_| PipelineError::Data {
        path: path.to_path_buf(),
        line: None,
        reason: "invalid npy header: too long".into(),
    })?;
    w.write_all(&len.to_le_bytes()).map_err(io)?;
    w.write_all(header.as_bytes()).map_err(io)?;
    for v in data {
        w.write_all(&v.to_le_bytes()).map_err(io)?;
    }
    w.flush().map_err(io)
}

/// Predictions and metrics of least squares and BeamsNet on the same examples.
#[derive(Debug, Clone, Serialize)]
pub struct BeamsNetEvaluation {
    /// Metrics of the least-squares velocity of the beams.
    pub ls: Metrics,
    /// Metrics of BeamsNet.
    pub beamsnet: Metrics,
    /// Reference (target) velocities.
    #[serde(skip)]
    pub reference: Vec<Vector3<f64>>,
    /// Least-squares velocities.
    #[serde(skip)]
    #[cfg_attr(
        not(test),
        expect(dead_code, reason = "the tests check the metrics against them")
    )]
    pub ls_velocity: Vec<Vector3<f64>>,
    /// BeamsNet velocities.
    #[serde(skip)]
    #[cfg_attr(
        not(test),
        expect(dead_code, reason = "the tests check the metrics against them")
    )]
    pub beamsnet_velocity: Vec<Vector3<f64>>,
}

impl BeamsNetEvaluation {
    /// How much lower BeamsNet's RMSE is than LS's, in percent.
    pub fn rmse_reduction_percent(&self) -> f64 {
        100.0 * (1.0 - self.beamsnet.rmse / self.ls.rmse)
    }
}

/// Evaluate LS (with `geometry`) and BeamsNet on `samples` (one batched inference): the
/// paper's Tables I and II.
///
/// # Errors
/// The network's inference; metrics of an empty or degenerate set.
pub fn evaluate_beamsnet(
    beamsnet: &BeamsNet,
    geometry: &BeamGeometry,
    samples: &[BeamsNetSample],
) -> Result<BeamsNetEvaluation> {
    let reference: Vec<Vector3<f64>> = samples.iter().map(|s| s.target).collect();
    let ls_velocity: Vec<Vector3<f64>> = samples
        .iter()
        .map(|s| geometry.least_squares(&s.input.beams))
        .collect();
    let inputs: Vec<_> = samples.iter().map(|s| s.input.clone()).collect();
    let beamsnet_velocity = beamsnet.velocities(&inputs)?;
    Ok(BeamsNetEvaluation {
        ls: speed_metrics(&reference, &ls_velocity)?,
        beamsnet: speed_metrics(&reference, &beamsnet_velocity)?,
        reference,
        ls_velocity,
        beamsnet_velocity,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The index of the IMU sample whose interval ends nearest to `t` (linear search
    /// over the samples' own time stamps: an independent recomputation).
    fn nearest_interval_end(imu: &[ImuSample], dt: f64, t: f64) -> usize {
        (0..imu.len())
            .min_by(|&a, &b| {
                let da = (imu[a].time + dt - t).abs();
                let db = (imu[b].time + dt - t).abs();
                da.total_cmp(&db)
            })
            .unwrap()
    }

    #[test]
    fn filter_alignment_pairs_the_sample_with_the_window_before_its_shifted_time() {
        use estim_ins::{Mission, MissionConfig};
        let mission = Mission::generate(
            &MissionConfig::builder().duration(20.0).build().unwrap(),
            11,
        )
        .unwrap();
        let trajectory = &mission.trajectory;
        let t0 = trajectory.start_time();
        let end = trajectory.end_time();
        // Stamps off the IMU grid, from before the first full window to past the end.
        let dvl: Vec<(f64, Vector3<f64>)> = (0..25)
            .map(|k| {
                (
                    t0 - 0.7 + 1.0025 * f64::from(k) + 0.0031,
                    Vector3::new(1.0, 0.1, 0.0),
                )
            })
            .collect();
        let spec = ImuSpec::akit_observed();
        let protocol = BeamsNetProtocol::v1();
        let dt = 1.0 / IMU_RATE_HZ;
        for offset in [-1.48, 0.0, 0.73] {
            let run = synthesize_aligned(
                trajectory,
                &dvl,
                &spec,
                &protocol,
                3,
                WindowAlignment::Filter {
                    time_offset_s: offset,
                },
            )
            .unwrap();
            let mut expected = 0;
            for &(stamp, _) in &dvl {
                let motion = stamp - offset;
                // A full window before the motion instant, inside the simulated span.
                let full = motion - t0 >= BEAMSNET_WINDOW as f64 * dt - dt / 2.0
                    && motion <= run.truth.last().unwrap().time + dt / 2.0;
                let found = run.samples.iter().find(|s| s.time == stamp);
                assert_eq!(found.is_some(), full, "offset {offset}, stamp {stamp}");
                let Some(sample) = found else { continue };
                expected += 1;
                let last = nearest_interval_end(&run.imu, dt, motion);
                assert_eq!(sample.imu_end, last + 1, "offset {offset}, stamp {stamp}");
                for (col, j) in [(0, last + 1 - BEAMSNET_WINDOW), (BEAMSNET_WINDOW - 1, last)] {
                    for r in 0..3 {
                        assert_eq!(sample.input.acc[(r, col)], run.imu[j].specific_force[r]);
                        assert_eq!(sample.input.gyro[(r, col)], run.imu[j].angular_rate[r]);
                    }
                }
            }
            assert!(expected > 10 && expected < dvl.len(), "{expected} windows");
            assert!(run.truth.last().unwrap().time <= end);
        }
    }

    #[test]
    fn ends_at_stamp_alignment_is_the_second_before_the_stamp() {
        use estim_ins::{Mission, MissionConfig};
        let mission = Mission::generate(
            &MissionConfig::builder().duration(10.0).build().unwrap(),
            12,
        )
        .unwrap();
        let trajectory = &mission.trajectory;
        let t0 = trajectory.start_time();
        let dvl: Vec<(f64, Vector3<f64>)> = (1..9)
            .map(|k| (t0 + 1.0025 * f64::from(k) + 0.004, Vector3::zeros()))
            .collect();
        let protocol = BeamsNetProtocol::v1();
        let dt = 1.0 / IMU_RATE_HZ;
        let run = synthesize(trajectory, &dvl, &ImuSpec::akit_observed(), &protocol, 4).unwrap();
        assert_eq!(run.samples.len(), dvl.len());
        for s in &run.samples {
            // The last sample's interval ends at or before the stamp, within one period.
            let last_end = run.imu[s.imu_end - 1].time + dt;
            assert!(last_end <= s.time + 1e-9 && s.time - last_end < dt, "{s:?}");
        }
        let bad = WindowAlignment::Filter {
            time_offset_s: f64::NAN,
        };
        assert!(synthesize_aligned(
            trajectory,
            &dvl,
            &ImuSpec::akit_observed(),
            &protocol,
            4,
            bad
        )
        .is_err());
    }

    #[test]
    fn npy_header_is_aligned_and_data_follows() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.npy");
        write_npy(&p, 2, &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00");
        let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        assert_eq!((10 + hlen) % 64, 0);
        let header = std::str::from_utf8(&bytes[10..10 + hlen]).unwrap();
        assert!(header.contains("'shape': (3, 2)"), "{header}");
        assert!(header.ends_with('\n'));
        let data = &bytes[10 + hlen..];
        assert_eq!(data.len(), 48);
        assert_eq!(f64::from_le_bytes(data[40..48].try_into().unwrap()), 6.0);
        assert!(write_npy(&p, 4, &[1.0, 2.0]).is_err());
    }
}
