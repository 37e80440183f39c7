//! `estim tune` on A-KIT: the maximum-likelihood noise parameters of the LS-aided
//! INS/DVL filter ([`estim::navigator::tune`]) on chosen training trajectories.
//!
//! Each trajectory is the study's scenario with the IMU the selection picks
//! ([`ImuSelection`]: the recorded IMU where the folder holds one, by default):
//! - recorded: the IMU as the vehicle file reads it (axes, clock, offsets), the run
//!   starting at the reference's state, the vehicle's IMU spec and DVL model (lever
//!   arm, mounting, scale factor; its DVL error states are not part of the 15-state
//!   fit);
//! - synthesized: the IMU synthesized from the ground truth with the configured error
//!   model and `seed`, a seeded initial error, the configured lever arm and time offset.
//!
//! Both take the real DVL velocity through the BeamsNet beam protocol and least
//! squares, and the configuration's initial covariance. All trajectories of one fit
//! share one IMU source. The test trajectories 4 and 13 are refused, and every DVL
//! epoch whose row also occurs in one of them (the A-KIT segments overlap) is left out
//! of the likelihood: the filter propagates through it without an update.

use std::collections::HashSet;
use std::path::Path;

use estim::datasets::{load_dvl_with, trajectory_files};
use estim::navigator::tune::{tune, TuneModel, TuneOptions, TuneParameters, TuneTrajectory};
use estim::navigator::{DvlConfig, NavigatorConfig};
use estim_core::nalgebra::Vector3;
use estim_ins::InsState;

use crate::tune::TuneReport;

use super::{
    initial_covariance, initial_nominal, least_squares_velocities, Config, ImuSelection, ImuSource,
    PipelineError, Result, Scenario, AKIT_TEST_TRAJECTORIES,
};

fn bits(v: &Vector3<f64>) -> [u64; 3] {
    [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()]
}

/// The trajectories `tune` fits on: at least one, none held out, none twice.
fn check_trajectories(trajectories: &[u32], flag: &str) -> Result<()> {
    if trajectories.is_empty() {
        return Err(PipelineError::Argument {
            flag: flag.into(),
            reason: "no trajectory given".into(),
        });
    }
    for (i, n) in trajectories.iter().enumerate() {
        if AKIT_TEST_TRAJECTORIES.contains(n) {
            return Err(PipelineError::HeldOut {
                flag: flag.into(),
                trajectory: *n,
            });
        }
        if trajectories[..i].contains(n) {
            return Err(PipelineError::Argument {
                flag: flag.into(),
                reason: format!("A-KIT trajectory {n} is given twice"),
            });
        }
    }
    Ok(())
}

/// One trajectory's DVL velocities for the fit: (time of the IMU sample, velocity).
type DvlMeasurements = Vec<(f64, Vector3<f64>)>;

/// Per scenario, the least-squares DVL velocities the fit uses (time of their IMU
/// sample, velocity), and how many rows were left out because a held-out
/// trajectory shares them (`test_rows`, the bits of their velocities).
///
/// # Errors
/// [`PipelineError::DvlEpoch`] for an epoch beyond its scenario's IMU.
fn dvl_measurements(
    scenarios: &[Scenario],
    config: &Config,
    test_rows: &HashSet<[u64; 3]>,
) -> Result<(Vec<DvlMeasurements>, Vec<usize>)> {
    let mut measurements = Vec::with_capacity(scenarios.len());
    let mut overlapping = Vec::with_capacity(scenarios.len());
    for scenario in scenarios {
        let velocities = least_squares_velocities(scenario, config);
        let mut used = Vec::with_capacity(velocities.len());
        let mut left_out = 0;
        for (k, (epoch, v)) in scenario.dvl.iter().zip(velocities).enumerate() {
            if test_rows.contains(&bits(&epoch.reference_velocity)) {
                left_out += 1;
            } else if let Some(v) = v {
                let time = scenario
                    .imu
                    .get(epoch.imu_index)
                    .map(|s| s.time)
                    .ok_or_else(|| PipelineError::DvlEpoch {
                        scenario: scenario.name.clone(),
                        epoch: k,
                        reason: format!("at IMU index {}, beyond the IMU", epoch.imu_index),
                    })?;
                used.push((time, v));
            }
        }
        measurements.push(used);
        overlapping.push(left_out);
    }
    Ok((measurements, overlapping))
}

/// Fit on A-KIT `trajectories` under `dir` (module docs), from the configuration's
/// noise values (IMU densities, beam noise of the protocol, the reference mismatch,
/// rho = 0).
///
/// # Errors
/// [`PipelineError::HeldOut`] for a test trajectory, [`PipelineError::Argument`] for
/// a repeated one or none; loader errors (file and line); the fit's errors.
pub fn tune_akit(
    dir: &Path,
    trajectories: &[u32],
    config: &Config,
    seed: u64,
    selection: &ImuSelection,
    options: &TuneOptions,
) -> Result<TuneReport> {
    const FLAG: &str = "--trajectories";
    let no_trajectory = || PipelineError::Argument {
        flag: FLAG.into(),
        reason: "no trajectory given".into(),
    };
    check_trajectories(trajectories, FLAG)?;
    let mut test_rows = HashSet::new();
    for &n in &AKIT_TEST_TRAJECTORIES {
        let files = trajectory_files(dir, n)?;
        for row in load_dvl_with(&files.dvl, &config.columns)? {
            test_rows.insert(bits(&Vector3::from(row.velocity_body)));
        }
    }
    let scenarios = trajectories
        .iter()
        .map(|&n| Scenario::akit_selected(dir, n, config, seed, selection))
        .collect::<Result<Vec<_>>>()?;
    let first = scenarios.first().ok_or_else(no_trajectory)?;
    let source = first.imu_source;
    if let Some(other) = scenarios.iter().find(|s| s.imu_source != source) {
        return Err(PipelineError::Argument {
            flag: "--imu-source".into(),
            reason: format!(
                "{} and {} run on different IMUs (one fit has one model); give \
                 --imu-source synthesized, or trajectories that all have a recorded IMU",
                first.name, other.name
            ),
        });
    }
    let (measurements, overlapping) = dvl_measurements(&scenarios, config, &test_rows)?;
    let mut inputs = Vec::with_capacity(scenarios.len());
    for (scenario, dvl) in scenarios.iter().zip(&measurements) {
        let truth0 = scenario
            .truth
            .first()
            .ok_or_else(|| PipelineError::NoData {
                what: format!("truth samples in {}", scenario.name),
            })?;
        let covariance = initial_covariance(config, &scenario.imu_spec);
        let initial = match &scenario.recorded {
            // The recorded runs start at the reference's state, the biases unknown.
            Some(_) => InsState {
                acc_bias: Vector3::zeros(),
                gyro_bias: Vector3::zeros(),
                ..*truth0
            },
            None => initial_nominal(truth0, &covariance, seed),
        };
        inputs.push(TuneTrajectory {
            imu: &scenario.imu,
            imu_period: scenario.imu_dt,
            dvl,
            initial,
            covariance,
        });
    }
    let spec = first.imu_spec;
    let dvl_model = match &first.recorded {
        Some(recorded) => recorded.settings.dvl_model().clone(),
        None => NavigatorConfig {
            dvl: DvlConfig {
                lever_arm_m: config.dvl.lever_arm_m,
                ..DvlConfig::default()
            },
            ..NavigatorConfig::default()
        }
        .check()?
        .dvl_model()
        .clone(),
    };
    let protocol = if config.dvl.protocol == "v2" {
        estim_dvl::BeamsNetProtocol::v2()
    } else {
        estim_dvl::BeamsNetProtocol::v1()
    };
    let model = TuneModel {
        sensor_spec: spec,
        dvl: dvl_model,
        geometry: protocol.geometry().clone(),
    };
    let psd = [
        spec.accelerometer().white_noise_density.powi(2),
        spec.gyroscope().white_noise_density.powi(2),
    ];
    let start = TuneParameters::from([
        psd[0],
        psd[1],
        protocol.error_model().noise_std().powi(2),
        config.dvl.akit_reference_mismatch_std.powi(2),
        0.0,
    ]);
    let fit = tune(&inputs, &model, &start, options)?;
    Ok(TuneReport {
        trajectories: trajectories.to_vec(),
        epochs: measurements.iter().map(Vec::len).collect(),
        overlapping,
        start,
        synthesized_psd: (source == ImuSource::Synthesized).then_some(psd),
        imu_source: Some(source.as_str()),
        fit,
    })
}
