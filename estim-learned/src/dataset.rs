//! BeamsNet training data: IMU windows synthesized from a trajectory, beams simulated
//! from DVL velocities with the BeamsNet protocol, and the file format the training
//! script reads.

use std::io::Write;
use std::path::Path;

use estim_dvl::BeamsNetProtocol;
use estim_ins::{ImuErrorGenerator, ImuSample, ImuSpec, InsState, Trajectory};
use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::beamsnet::{BeamsNetInput, BEAMSNET_WINDOW};
use crate::{Error, Result};

/// Columns of a dataset row (the layout in [`synthesize`]).
pub const DATASET_COLUMNS: usize = 610;

/// IMU rate of the synthesized windows \[Hz\].
pub const IMU_RATE_HZ: f64 = 100.0;

/// One synthesized BeamsNet example.
#[derive(Debug, Clone, PartialEq)]
pub struct BeamsNetSample {
    /// DVL sample time \[s\].
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
    /// Error-free IMU samples.
    pub imu_clean: Vec<ImuSample>,
    /// Measured (corrupted) IMU samples.
    pub imu: Vec<ImuSample>,
    /// The examples, one per DVL sample with a full window.
    pub samples: Vec<BeamsNetSample>,
}

/// Synthesize BeamsNet examples from a trajectory and DVL velocities `(time, v_body)`.
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
///    bias, Gauss-Markov drift, scale factor of the given [`estim_ins::ImuSpec`]).
/// 3. For each DVL sample at time t_k, the window is the 100 IMU samples whose
///    intervals end at or before t_k (the second preceding the DVL sample); samples
///    without a full window are skipped.
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
/// | 608 | DVL sample time (s) |
/// | 609 | realization index (IMU / beam noise draw) |
///
/// `FILE.json` (same stem) records the column count, the IMU error model, the beam
/// protocol and geometry, the trajectories and seeds (written by `estim dataset beamsnet`).
pub fn synthesize(
    trajectory: &Trajectory,
    dvl: &[(f64, Vector3<f64>)],
    imu_spec: &ImuSpec,
    protocol: &BeamsNetProtocol,
    seed: u64,
) -> Result<SynthesizedRun> {
    let ins_err = |e: estim_ins::Error| Error::InvalidInput {
        what: "trajectory",
        reason: e.to_string(),
    };
    let (truth, imu_clean) = trajectory.simulate(IMU_RATE_HZ).map_err(ins_err)?;
    let dt = 1.0 / IMU_RATE_HZ;
    let mut generator = ImuErrorGenerator::new(*imu_spec, seed);
    let imu: Vec<ImuSample> = imu_clean.iter().map(|s| generator.corrupt(s, dt)).collect();
    let mut beam_rng = ChaCha8Rng::seed_from_u64(seed.wrapping_add(1_000_003));
    let t0 = trajectory.start_time();
    let mut samples = Vec::with_capacity(dvl.len());
    for &(time, velocity) in dvl {
        if !time.is_finite() || velocity.iter().any(|v| !v.is_finite()) {
            return Err(Error::InvalidInput {
                what: "DVL sample",
                reason: format!("non-finite value at time {time}"),
            });
        }
        // Samples whose interval [t0 + j dt, t0 + (j+1) dt] ends at or before `time`.
        let end = ((time - t0) / dt + 1e-6).floor();
        if end < BEAMSNET_WINDOW as f64 {
            continue;
        }
        let end = (end as usize).min(imu.len());
        if end < BEAMSNET_WINDOW {
            continue;
        }
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
        imu_clean,
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
        return Err(Error::InvalidInput {
            what: "npy array",
            reason: format!("{} values do not fill rows of {columns}", data.len()),
        });
    }
    let rows = data.len() / columns;
    let mut header =
        format!("{{'descr': '<f8', 'fortran_order': False, 'shape': ({rows}, {columns}), }}");
    // Magic (6) + version (2) + header length (2) + header, padded to 64 with '\n' last.
    let unpadded = 10 + header.len() + 1;
    header.push_str(&" ".repeat((64 - unpadded % 64) % 64));
    header.push('\n');
    let io = |source| Error::Io {
        path: path.to_path_buf(),
        source,
    };
    let file = std::fs::File::create(path).map_err(io)?;
    let mut w = std::io::BufWriter::new(file);
    w.write_all(b"\x93NUMPY\x01\x00").map_err(io)?;
    let len = u16::try_from(header.len()).map_err(|_| Error::InvalidInput {
        what: "npy header",
        reason: "too long".into(),
    })?;
    w.write_all(&len.to_le_bytes()).map_err(io)?;
    w.write_all(header.as_bytes()).map_err(io)?;
    for v in data {
        w.write_all(&v.to_le_bytes()).map_err(io)?;
    }
    w.flush().map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;

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
