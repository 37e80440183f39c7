//! The sensors an experiment synthesizes from a reference: the IMU from the ground
//! truth's spline, corrupted by the configured error model; the beams of the DVL's
//! velocity by the BeamsNet protocol; the seeded initial state and its covariance.
//! Every draw is seeded (the seed and a fixed tag per stream).

use std::path::Path;

use estim::datasets::{DatasetError, DvlSample};
use estim_core::nalgebra::{SMatrix, SVector, Vector3, Vector4};
use estim_dvl::BeamsNetProtocol;
use estim_ins::{
    inject, ImuErrorGenerator, ImuSample, ImuSpec, InsState, Trajectory, ERROR_STATES,
};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use super::{AkitTruth, Config, PipelineError, Result};

/// Most IMU samples synthesized from a recorded trajectory (13.9 h at 100 Hz, about
/// 1.4 GB of states and samples): a longer span is refused before allocating.
pub const MAX_SYNTHESIZED_IMU_SAMPLES: f64 = 5e6;

/// One DVL epoch: what the DVL measured and the beams simulated from it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DvlEpoch {
    /// The update is applied after IMU sample `imu_index - 1`, i.e. at `truth[imu_index]`.
    pub imu_index: usize,
    /// Velocity at the DVL in its frame \[m/s\] (the real DVL's on A-KIT, exact in simulation).
    pub reference_velocity: Vector3<f64>,
    /// Beam velocities from the BeamsNet protocol (NaN for a missing beam).
    pub beams: Vector4<f64>,
}

/// The configured BeamsNet protocol (`dvl.protocol`).
pub fn protocol(config: &Config) -> BeamsNetProtocol {
    if config.dvl.protocol == "v2" {
        BeamsNetProtocol::v2()
    } else {
        BeamsNetProtocol::v1()
    }
}

fn imu_spec(config: &Config) -> Result<ImuSpec> {
    config.imu_spec()
}

/// The IMU synthesized from recorded ground truth: truth at
/// the configured IMU rate from the GT spline, the error-free IMU, and the IMU
/// corrupted by the configured error model with `seed` (truth carries its true
/// biases). Returns (truth, imu, clean imu, dt, spec).
///
/// # Errors
/// [`DatasetError::Unusable`] naming `gt_path` for fewer than 2 rows, a span too long
/// to synthesize or a trajectory the simulator refuses.
#[allow(clippy::type_complexity)]
pub fn synthesize_imu(
    gt: &[estim::datasets::GtSample],
    gt_path: &Path,
    other: &Path,
    config: &Config,
    seed: u64,
) -> Result<(Vec<InsState>, Vec<ImuSample>, Vec<ImuSample>, f64, ImuSpec)> {
    let unusable = |message: String| {
        PipelineError::Dataset(DatasetError::Unusable {
            path: gt_path.to_path_buf(),
            message,
        })
    };
    let dvl_path = other;
    let (first, last) = match (gt.first(), gt.last()) {
        (Some(a), Some(b)) if gt.len() >= 2 => (*a, *b),
        _ => {
            return Err(unusable(format!(
                "fewer than 2 GT rows inside the overlap with {}",
                dvl_path.display()
            )))
        }
    };
    let samples = (last.time - first.time) * config.mission.imu_rate_hz;
    if samples > MAX_SYNTHESIZED_IMU_SAMPLES {
        return Err(unusable(format!(
            "lines {}-{} span {} s, {samples:.0} IMU samples at {} Hz; at most {MAX_SYNTHESIZED_IMU_SAMPLES:.0} are synthesized",
            first.line, last.line, last.time - first.time, config.mission.imu_rate_hz
        )));
    }
    let samples = gt.iter().map(|g| g.trajectory_sample()).collect();
    // The loader checked every value the trajectory checks; an error here still
    // names the file.
    let trajectory = match config.imu.akit_truth {
        AkitTruth::PositionAndVelocity => Trajectory::new(samples),
        AkitTruth::Velocity => Trajectory::velocity_driven(samples),
    }
    .map_err(|e| unusable(e.to_string()))?;
    let (mut truth, clean) = trajectory
        .simulate(config.mission.imu_rate_hz)
        .map_err(|e| {
            unusable(format!(
                "lines {}-{} (span {} s): {e}",
                first.line,
                last.line,
                last.time - first.time
            ))
        })?;
    let dt = 1.0 / config.mission.imu_rate_hz;
    let spec = imu_spec(config)?;
    let mut errors = ImuErrorGenerator::new(spec, seed);
    let mut imu = Vec::with_capacity(clean.len());
    for (k, sample) in clean.iter().enumerate() {
        truth[k].acc_bias = errors.acc_bias();
        truth[k].gyro_bias = errors.gyro_bias();
        imu.push(errors.corrupt(sample, dt));
    }
    if let Some(last) = truth.last_mut() {
        last.acc_bias = errors.acc_bias();
        last.gyro_bias = errors.gyro_bias();
    }
    Ok((truth, imu, clean, dt, spec))
}

/// The DVL rows of `dvl_log` (from `dvl_path`) as epochs of a synthesized truth
/// starting at `t0` with IMU period `dt` and `samples` truth samples: each row stamped t
/// measures the motion at t - `dvl.akit_time_offset_s`, applied at the nearest IMU
/// sample after the first and inside the truth; its beams by the configured protocol
/// (seeded with `seed`). Returns each kept row's stamp with its epoch.
///
/// # Errors
/// [`DatasetError::Unusable`] naming `dvl_path` for two rows on one IMU sample.
pub fn dvl_epochs(
    dvl_log: &[DvlSample],
    dvl_path: &Path,
    [t0, dt]: [f64; 2],
    samples: usize,
    config: &Config,
    seed: u64,
) -> Result<Vec<(f64, DvlEpoch)>> {
    let protocol = protocol(config);
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xD71);
    let mut dvl: Vec<(f64, DvlEpoch)> = Vec::with_capacity(dvl_log.len());
    let mut previous_line: Option<u64> = None;
    for d in dvl_log {
        // A sample stamped t measures the motion at t - tau.
        let t = d.time - config.dvl.akit_time_offset_s;
        let i = ((t - t0) / dt).round();
        if i < 1.0 || i >= samples as f64 {
            continue;
        }
        // Two DVL rows on one IMU sample would be applied twice at one instant.
        if let (Some((_, last)), Some(line)) = (dvl.last(), previous_line) {
            if last.imu_index == i as usize {
                return Err(PipelineError::Dataset(DatasetError::Unusable {
                    path: dvl_path.to_path_buf(),
                    message: format!(
                        "lines {line} and {} fall on the same IMU sample at \
                         mission.imu_rate_hz = {} (DVL rows must be at least one IMU \
                         period apart; refused, not merged)",
                        d.line, config.mission.imu_rate_hz
                    ),
                }));
            }
        }
        previous_line = Some(d.line);
        let reference = Vector3::from(d.velocity_body);
        dvl.push((
            d.time,
            DvlEpoch {
                imu_index: i as usize,
                reference_velocity: reference,
                beams: protocol.beams(&reference, &mut rng),
            },
        ));
    }
    Ok(dvl)
}

/// The initial 1-sigma of the accelerometer and the gyroscope biases: the configured
/// `filter.initial_bias_std_scale` times the root sum square of each sensor's turn-on
/// bias and bias instability.
pub fn initial_bias_std(config: &Config, spec: &ImuSpec) -> (f64, f64) {
    let scale = config.filter.initial_bias_std_scale;
    let (a, g) = (spec.accelerometer(), spec.gyroscope());
    (
        scale * (a.turn_on_bias.powi(2) + a.bias_instability.powi(2)).sqrt(),
        scale * (g.turn_on_bias.powi(2) + g.bias_instability.powi(2)).sqrt(),
    )
}

/// Initial covariance from the configuration and the IMU spec.
pub fn initial_covariance(
    config: &Config,
    spec: &ImuSpec,
) -> SMatrix<f64, ERROR_STATES, ERROR_STATES> {
    let f = &config.filter;
    let (acc, gyro) = initial_bias_std(config, spec);
    let level = f.initial_level_std_deg.to_radians();
    let heading = f.initial_heading_std_deg.to_radians();
    let std = [
        f.initial_position_std_m,
        f.initial_position_std_m,
        f.initial_position_std_m,
        f.initial_velocity_std_mps,
        f.initial_velocity_std_mps,
        f.initial_velocity_std_mps,
        level,
        level,
        heading,
        acc.max(1e-9),
        acc.max(1e-9),
        acc.max(1e-9),
        gyro.max(1e-12),
        gyro.max(1e-12),
        gyro.max(1e-12),
    ];
    SMatrix::from_diagonal(&SVector::from_iterator(std.iter().map(|s| s * s)))
}

/// The initial nominal state: truth minus an error drawn from the initial covariance
/// (position, velocity, attitude; the bias estimates start at zero, so their initial
/// error is the true bias).
pub fn initial_nominal(
    truth: &InsState,
    p0: &SMatrix<f64, ERROR_STATES, ERROR_STATES>,
    seed: u64,
) -> InsState {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x1417);
    let mut e = SVector::<f64, ERROR_STATES>::zeros();
    for i in 0..9 {
        let n: f64 = StandardNormal.sample(&mut rng);
        e[i] = n * p0[(i, i)].sqrt();
    }
    let mut nominal = inject(truth, &(-e));
    nominal.acc_bias = Vector3::zeros();
    nominal.gyro_bias = Vector3::zeros();
    nominal
}
