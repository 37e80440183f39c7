//! Scenarios: truth, the IMU the filter integrates, and the DVL epochs (beams).

use std::path::Path;

use estim_core::nalgebra::{Vector3, Vector4};
use estim_dvl::dvl_frame_velocity;
use estim_ins::{ImuSample, ImuSpec, InsState, Mission, MissionConfig};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::{Config, PipelineError, Result};
use crate::experiment::{dvl_epochs, protocol, synthesize_imu, DvlEpoch};
use estim::datasets::{
    check_spans, load_dvl_with, load_gt_with, trajectory_files, DatasetError, SpanCheck,
    SPAN_TIME_OFFSET_ALLOWANCE_S,
};

/// Fewest DVL updates a recorded trajectory must give for its figures to be defined.
pub const MIN_DVL_EPOCHS: usize = 2;

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
    /// Recorded data: the GT and DVL spans as read (before any trimming to the overlap).
    pub span: Option<SpanCheck>,
    /// Which IMU the filter integrates.
    pub imu_source: super::ImuSource,
    /// A recorded IMU's survey: the navigator's settings and inputs the variants run
    /// on ([`super::run_recorded`]).
    pub recorded: Option<std::sync::Arc<super::RecordedSurvey>>,
}

impl Scenario {
    /// The embedded default: a seeded simulated AUV mission.
    pub fn simulated(config: &Config, seed: u64) -> Result<Self> {
        let spec = config.imu_spec()?;
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
            span: None,
            imu_source: super::ImuSource::Synthesized,
            recorded: None,
        })
    }

    /// Recorded data (A-KIT or a user's files), not a simulation.
    pub fn is_recorded(&self) -> bool {
        self.span.is_some() || self.recorded.is_some()
    }

    /// A-KIT trajectory `n` under `dir` (see [`Scenario::recorded`]; the spans must agree).
    ///
    /// # Errors
    /// As [`Scenario::recorded`], and [`DatasetError::Missing`] listing the
    /// trajectories the folder holds.
    pub fn akit(dir: &Path, n: u32, config: &Config, seed: u64) -> Result<Self> {
        Self::akit_with(dir, n, config, seed, false)
    }

    /// [`Scenario::akit`], with `allow_partial` as in [`Scenario::recorded`].
    ///
    /// # Errors
    /// As [`Scenario::akit`].
    pub fn akit_with(
        dir: &Path,
        n: u32,
        config: &Config,
        seed: u64,
        allow_partial: bool,
    ) -> Result<Self> {
        let files = trajectory_files(dir, n)?;
        let mut scenario = Self::recorded(&files.gt, &files.dvl, config, seed, allow_partial)?;
        scenario.name = format!("A-KIT trajectory {n}");
        scenario.trajectory = Some(n);
        Ok(scenario)
    }

    /// A recorded trajectory from a ground-truth and a DVL file (columns by name or by
    /// the configuration's `[columns]` map): truth = GT, IMU synthesized from GT at the
    /// configured rate and corrupted with the configured error model, DVL = the real
    /// DVL velocity (time-shifted by the configured offset), beams by the protocol.
    ///
    /// The two files must cover the same time span (the rule of
    /// [`estim::datasets::SpanCheck`], with an allowance of 1.5 s or the configured
    /// offset's magnitude if larger). With `allow_partial` a mismatch is accepted and
    /// the run covers the overlap only (the caller says so; [`Scenario::span`] holds
    /// both spans).
    ///
    /// # Errors
    /// Every loader error (file and line), [`DatasetError::SpanMismatch`] naming both
    /// files and their spans, [`DatasetError::Unusable`] for a span too long to
    /// synthesize or too short for one IMU step, two DVL rows on one IMU sample, or
    /// fewer than [`MIN_DVL_EPOCHS`] DVL rows inside the GT span.
    pub fn recorded(
        gt_path: &Path,
        dvl_path: &Path,
        config: &Config,
        seed: u64,
        allow_partial: bool,
    ) -> Result<Self> {
        let gt = load_gt_with(gt_path, &config.columns)?;
        let dvl_log = load_dvl_with(dvl_path, &config.columns)?;
        let allowance = SPAN_TIME_OFFSET_ALLOWANCE_S.max(config.dvl.akit_time_offset_s.abs());
        let span = check_spans(gt_path, &gt, dvl_path, &dvl_log, allowance, allow_partial)?;
        // On a mismatch (only with allow_partial) the run covers the overlap.
        let gt: Vec<_> = match span.overlap_s() {
            Some([start, end]) if !span.agrees() => gt
                .into_iter()
                .filter(|g| g.time >= start && g.time <= end)
                .collect(),
            _ => gt,
        };
        let (truth, imu, clean, dt, spec) = synthesize_imu(&gt, gt_path, dvl_path, config, seed)?;
        let t0 = truth.first().map_or(0.0, |s| s.time);
        let dvl: Vec<DvlEpoch> =
            dvl_epochs(&dvl_log, dvl_path, [t0, dt], truth.len(), config, seed)?
                .into_iter()
                .map(|(_, epoch)| epoch)
                .collect();
        // Fewer updates than that give no finite figure to report (a two-row
        // trajectory would end with NaN statistics).
        if dvl.len() < MIN_DVL_EPOCHS {
            return Err(PipelineError::Dataset(DatasetError::Unusable {
                path: dvl_path.to_path_buf(),
                message: format!(
                    "{} DVL rows fall inside the GT span {:.3}-{:.3} s of {} (after the \
                     time offset dvl.akit_time_offset_s = {} s); at least {MIN_DVL_EPOCHS} \
                     are needed",
                    dvl.len(),
                    t0,
                    truth.last().map_or(t0, |s| s.time),
                    gt_path.display(),
                    config.dvl.akit_time_offset_s
                ),
            }));
        }
        Ok(Self {
            name: gt_path.display().to_string(),
            trajectory: None,
            truth,
            imu,
            clean_imu: clean,
            imu_dt: dt,
            imu_spec: spec,
            dvl,
            span: Some(span),
            imu_source: super::ImuSource::Synthesized,
            recorded: None,
        })
    }
}

/// A scripted beam loss: from `start_s` (after the scenario's start) for `duration_s`,
/// only the beams `kept` (0-based) are received; the others are NaN.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BeamLoss {
    /// Start, seconds after the first truth sample.
    pub start_s: f64,
    /// Duration \[s\].
    pub duration_s: f64,
    /// The beams still received (0-based, distinct, < 4).
    pub kept: [usize; 2],
}

impl BeamLoss {
    /// The two-beams scenario: beams 1 and 2 only, for 120 s from 200 s (inside the
    /// 400 s A-KIT segments and the default simulated mission).
    pub fn two_beams() -> Self {
        Self {
            start_s: 200.0,
            duration_s: 120.0,
            kept: [0, 1],
        }
    }
}

impl Scenario {
    /// Apply a scripted beam loss; returns the indices of the DVL epochs affected.
    ///
    /// # Errors
    /// Non-finite or negative times, or `kept` not two distinct beams below 4.
    pub fn lose_beams(&mut self, loss: &BeamLoss) -> Result<Vec<usize>> {
        let [a, b] = loss.kept;
        if !(loss.start_s.is_finite() && loss.duration_s.is_finite())
            || loss.start_s < 0.0
            || loss.duration_s < 0.0
            || a == b
            || a > 3
            || b > 3
        {
            return Err(PipelineError::Event {
                event: format!("beam loss {loss:?}"),
            });
        }
        let t0 = self.truth.first().map_or(0.0, |s| s.time);
        let mut affected = Vec::new();
        for (k, epoch) in self.dvl.iter_mut().enumerate() {
            let Some(t) = self.truth.get(epoch.imu_index).map(|s| s.time - t0) else {
                continue;
            };
            if t >= loss.start_s && t < loss.start_s + loss.duration_s {
                for i in 0..4 {
                    if i != a && i != b {
                        epoch.beams[i] = f64::NAN;
                    }
                }
                affected.push(k);
            }
        }
        Ok(affected)
    }

    /// Apply a scripted full DVL outage (every beam NaN from `start_s` for
    /// `duration_s`); returns the indices of the DVL epochs affected.
    ///
    /// # Errors
    /// Non-finite or negative times.
    pub fn lose_dvl(&mut self, outage: &super::DvlOutage) -> Result<Vec<usize>> {
        if !(outage.start_s.is_finite() && outage.duration_s.is_finite())
            || outage.start_s < 0.0
            || outage.duration_s < 0.0
        {
            return Err(PipelineError::Event {
                event: format!("DVL outage {outage:?}"),
            });
        }
        let t0 = self.truth.first().map_or(0.0, |s| s.time);
        let mut affected = Vec::new();
        for (k, epoch) in self.dvl.iter_mut().enumerate() {
            let Some(t) = self.truth.get(epoch.imu_index).map(|s| s.time - t0) else {
                continue;
            };
            if t >= outage.start_s && t < outage.start_s + outage.duration_s {
                epoch.beams = Vector4::from_element(f64::NAN);
                affected.push(k);
            }
        }
        Ok(affected)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::experiment::AkitTruth;

    /// A vehicle at a constant 1.5 m/s north, level, whose recorded positions step
    /// 1.6 m per second (positions and velocities disagree, as A-KIT's do). Through
    /// positions and velocities the synthesized specific force swings north between
    /// the samples; through the velocities alone it is the constant-velocity one:
    /// north and east within 1e-3 m/s^2 of zero (Coriolis and transport rate are
    /// below 3e-4 m/s^2 here), and the integrated truth moves 1.5 m per second.
    #[test]
    fn velocity_truth_has_no_spurious_acceleration() {
        let latitude = 0.57_f64;
        let metres = 1.0 / 6.37e6;
        let gt: Vec<estim::datasets::GtSample> = (0..21)
            .map(|i| estim::datasets::GtSample {
                line: i + 2,
                time: i as f64,
                longitude: 0.6,
                latitude: latitude + 1.6 * i as f64 * metres,
                altitude: -20.0,
                velocity_ned: [1.5, 0.0, 0.0],
                roll_pitch_yaw: [0.0, 0.0, 0.0],
            })
            .collect();
        let path = Path::new("gt.csv");
        let north = |truth: AkitTruth| {
            let mut config = Config::default();
            config.imu.akit_truth = truth;
            let (states, _, clean, _, _) = synthesize_imu(&gt, path, path, &config, 1).unwrap();
            let peak = clean
                .iter()
                .map(|s| s.specific_force.x.abs().max(s.specific_force.y.abs()))
                .fold(0.0, f64::max);
            let (first, last) = (states[0], states[states.len() - 1]);
            let (rn, _) = estim_ins::earth::radii_of_curvature(first.latitude);
            let travelled = (last.latitude - first.latitude) * (rn + first.height);
            (peak, travelled / (last.time - first.time))
        };
        let (both, _) = north(AkitTruth::PositionAndVelocity);
        let (velocity, speed) = north(AkitTruth::Velocity);
        println!("peak horizontal specific force: {both:.4} (positions and velocities), {velocity:.2e} (velocities)");
        assert!(both > 0.1, "{both}");
        assert!(velocity < 1e-3, "{velocity}");
        assert!((speed - 1.5).abs() < 2e-3, "{speed}");
    }

    /// `imu.akit_truth` takes the two documented values and refuses others.
    #[test]
    fn akit_truth_key() {
        let parse = |v: &str| toml::from_str::<Config>(&format!("[imu]\nakit_truth = \"{v}\"\n"));
        assert_eq!(
            parse("velocity").unwrap().imu.akit_truth,
            AkitTruth::Velocity
        );
        assert_eq!(
            parse("position_and_velocity").unwrap().imu.akit_truth,
            AkitTruth::PositionAndVelocity
        );
        assert_eq!(
            Config::default().imu.akit_truth,
            AkitTruth::PositionAndVelocity
        );
        let e = parse("spline").unwrap_err().to_string();
        assert!(e.contains("akit_truth") || e.contains("spline"), "{e}");
    }
}
