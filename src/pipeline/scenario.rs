//! Scenarios: truth, the IMU the filter integrates, and the DVL epochs (beams).

use std::path::Path;

use estim_core::nalgebra::{Vector3, Vector4};
use estim_dvl::{dvl_frame_velocity, BeamsNetProtocol};
use estim_ins::{
    ImuErrorGenerator, ImuSample, ImuSpec, InsState, Mission, MissionConfig, Trajectory,
};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::{Config, PipelineError, Result};
use crate::datasets::{load_dvl, load_gt, trajectory_files};

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

/// Everything a filter run needs.
#[derive(Debug, Clone)]
pub struct Scenario {
    /// Human name ("simulated mission", "A-KIT trajectory 4").
    pub name: String,
    /// A-KIT trajectory number, if any.
    pub trajectory: Option<u32>,
    /// Truth at t_k (k = 0..=N), with the IMU's true biases and angular rate.
    pub truth: Vec<InsState>,
    /// The IMU the filter integrates (N samples; sample k covers [t_k, t_k+1]).
    pub imu: Vec<ImuSample>,
    /// The error-free IMU (N samples), for oracle measurements and noise analysis.
    pub clean_imu: Vec<ImuSample>,
    /// IMU period \[s\].
    pub imu_dt: f64,
    /// The IMU error model the samples were corrupted with (also the filter's model).
    pub imu_spec: ImuSpec,
    /// DVL epochs, increasing `imu_index`.
    pub dvl: Vec<DvlEpoch>,
}

fn protocol(config: &Config) -> BeamsNetProtocol {
    if config.dvl.protocol == "v2" {
        BeamsNetProtocol::v2()
    } else {
        BeamsNetProtocol::v1()
    }
}

fn imu_spec(config: &Config) -> Result<ImuSpec> {
    config.imu_spec().map_err(PipelineError::Invalid)
}

impl Scenario {
    /// The embedded default: a seeded simulated AUV mission.
    pub fn simulated(config: &Config, seed: u64) -> Result<Self> {
        let spec = imu_spec(config)?;
        let mission_config = MissionConfig::builder()
            .duration(config.mission.duration_s)
            .imu_rate_hz(config.mission.imu_rate_hz)
            .imu_spec(spec)
            .build()?;
        let mission = Mission::generate(&mission_config, seed)?;
        let lever_arm = Vector3::from(config.dvl.lever_arm_m);
        let protocol = protocol(config);
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xD71);
        let every = (config.mission.dvl_period_s / mission.imu_dt)
            .round()
            .max(1.0) as usize;
        let dvl = (1..)
            .map(|k| k * every)
            .take_while(|&i| i < mission.truth.len())
            .map(|i| {
                let s = &mission.truth[i];
                let v_body = s.attitude.inverse() * s.velocity_ned;
                let reference = dvl_frame_velocity(
                    &v_body,
                    &s.angular_rate,
                    &lever_arm,
                    0.0,
                    &Vector3::zeros(),
                );
                DvlEpoch {
                    imu_index: i,
                    reference_velocity: reference,
                    beams: protocol.beams(&reference, &mut rng),
                }
            })
            .collect();
        Ok(Self {
            name: "simulated mission".into(),
            trajectory: None,
            truth: mission.truth,
            imu: mission.imu,
            clean_imu: mission.clean_imu,
            imu_dt: mission.imu_dt,
            imu_spec: spec,
            dvl,
        })
    }

    /// A-KIT trajectory `n` under `dir`: truth = GT, IMU synthesized from GT at the
    /// configured rate and corrupted with the configured error model, DVL = the real
    /// DVL velocity (time-shifted by the configured offset), beams by the protocol.
    pub fn akit(dir: &Path, n: u32, config: &Config, seed: u64) -> Result<Self> {
        let files = trajectory_files(dir, n)?;
        let gt = load_gt(&files.gt)?;
        let dvl_log = load_dvl(&files.dvl)?;
        let samples = gt.iter().map(|g| g.trajectory_sample()).collect();
        let trajectory = Trajectory::new(samples)?;
        let (mut truth, clean) = trajectory.simulate(config.mission.imu_rate_hz)?;
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
        let protocol = protocol(config);
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xD71);
        let t0 = truth.first().map_or(0.0, |s| s.time);
        let mut dvl = Vec::with_capacity(dvl_log.len());
        for d in &dvl_log {
            // A sample stamped t measures the motion at t - tau.
            let t = d.time - config.dvl.akit_time_offset_s;
            let i = ((t - t0) / dt).round();
            if i < 1.0 || i >= truth.len() as f64 {
                continue;
            }
            let reference = Vector3::from(d.velocity_body);
            dvl.push(DvlEpoch {
                imu_index: i as usize,
                reference_velocity: reference,
                beams: protocol.beams(&reference, &mut rng),
            });
        }
        Ok(Self {
            name: format!("A-KIT trajectory {n}"),
            trajectory: Some(n),
            truth,
            imu,
            clean_imu: clean,
            imu_dt: dt,
            imu_spec: spec,
            dvl,
        })
    }
}
