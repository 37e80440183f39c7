//! Smoothing a survey: the 15-state INS/DVL error-state filter recorded with
//! [`estim_core::smoother::ForwardRecorder`] (one epoch per DVL update, the IMU predicts between
//! updates composed), smoothed by the RTS smoother of estim-core and re-injected into
//! the recorded nominal trajectory (`true = nominal + error`, estim-ins convention),
//! then compared with the filter against ground truth at the same epochs.

use std::collections::HashMap;

use estim::navigator::{smooth_survey_at, DvlInput, NavSolution, NavigationObserver, SolutionKind};
use estim_core::consistency::nees;
use estim_core::nalgebra::{Matrix3, SMatrix};
use estim_core::smoother::{ForwardRecorder, RecordAt, Smoothed};
use estim_ins::{ErrorMatrix, InsErrorModel, InsState, ATT, ERROR_STATES, POS, VEL};
use serde::Serialize;

use super::stats::{error_summary, finite_mean, ErrorSummary};
use super::{
    error_state, filter_imu_spec, least_squares_velocities, run_filter_with_observer, Config,
    CrossSource, MeasurementSet, PipelineError, Result, Scenario, RECORDED_NEES_STATES,
};

/// Error series of one estimate (filtered or smoothed) at the smoother's epochs.
#[derive(Debug, Clone, Default, Serialize)]
pub struct EstimateSeries {
    /// |position error| \[m\].
    pub position_error: Vec<f64>,
    /// 3 sqrt(trace of the position covariance) \[m\] (the 3-sigma of the error norm's
    /// scale).
    pub position_3sigma: Vec<f64>,
    /// |velocity error| \[m/s\].
    pub velocity_error: Vec<f64>,
    /// |attitude error| \[deg\].
    pub attitude_error_deg: Vec<f64>,
    /// NEES of the 15-state error (NaN where the covariance is not positive definite).
    pub nees: Vec<f64>,
}

/// Summary of an [`EstimateSeries`].
#[derive(Debug, Clone, Copy, Serialize)]
pub struct EstimateSummary {
    /// Position error norm.
    pub position_m: ErrorSummary,
    /// Velocity error norm.
    pub velocity_mps: ErrorSummary,
    /// Attitude error norm.
    pub attitude_deg: ErrorSummary,
    /// Time-averaged NEES (15 for a consistent estimate).
    pub mean_nees: f64,
}

impl EstimateSeries {
    fn summary(&self) -> EstimateSummary {
        EstimateSummary {
            position_m: error_summary(&self.position_error),
            velocity_mps: error_summary(&self.velocity_error),
            attitude_deg: error_summary(&self.attitude_error_deg),
            mean_nees: finite_mean(&self.nees),
        }
    }

    /// Append the errors of `estimate` against `truth`, NEES over the first
    /// `nees_states` error states (15 with the IMU's true biases, 9 without).
    fn push(
        &mut self,
        truth: &InsState,
        estimate: &InsState,
        covariance: &SMatrix<f64, ERROR_STATES, ERROR_STATES>,
        nees_states: usize,
    ) {
        let e = error_state(truth, estimate);
        self.position_error.push(e.fixed_rows::<3>(POS).norm());
        let trace: f64 = (POS..POS + 3).map(|i| covariance[(i, i)]).sum();
        self.position_3sigma.push(3.0 * trace.max(0.0).sqrt());
        self.velocity_error.push(e.fixed_rows::<3>(VEL).norm());
        self.attitude_error_deg
            .push(e.fixed_rows::<3>(ATT).norm().to_degrees());
        let value = if nees_states == ERROR_STATES {
            nees(&e, covariance).ok()
        } else {
            estim::navigator::nees_of_block(&e, covariance, 0, nees_states)
        };
        self.nees.push(value.unwrap_or(f64::NAN));
    }
}

/// Filtered against smoothed on one scenario.
#[derive(Debug, Clone, Serialize)]
pub struct SmoothReport {
    /// Scenario name.
    pub name: String,
    /// A-KIT trajectory number, if any.
    pub trajectory: Option<u32>,
    /// Which IMU the filter integrated.
    pub imu_source: super::ImuSource,
    /// The states NEES is over: 15 on a synthesized IMU (its true biases known), 9 on
    /// a recorded one (position, velocity, attitude).
    pub nees_states: usize,
    /// The cross-covariance used ("M = 0" or "rho = ...").
    pub cross: String,
    /// Time of each epoch since the start \[s\].
    pub time: Vec<f64>,
    /// The filter at each epoch (after its updates).
    pub filtered: EstimateSeries,
    /// The fixed-interval smoother at each epoch.
    pub smoothed: EstimateSeries,
    /// Summary of `filtered`.
    pub filtered_summary: EstimateSummary,
    /// Summary of `smoothed`.
    pub smoothed_summary: EstimateSummary,
}

/// The least-squares DVL measurement set of `analyse` (sensor noise plus, on A-KIT,
/// the measured DVL/ground-truth mismatch).
pub fn least_squares_measurements(scenario: &Scenario, config: &Config) -> MeasurementSet {
    let mismatch = if scenario.trajectory.is_some() {
        Matrix3::identity() * config.dvl.akit_reference_mismatch_std.powi(2)
    } else {
        Matrix3::zeros()
    };
    MeasurementSet {
        velocities: least_squares_velocities(scenario, config),
        noise_covariance: Matrix3::identity() * config.dvl.ls_noise_std.powi(2) + mismatch,
    }
}

/// Index of the truth sample at `time` (within half an IMU period).
fn truth_at(scenario: &Scenario, time: f64) -> Result<&InsState> {
    let truth = &scenario.truth;
    let i = truth.partition_point(|s| s.time < time);
    let best = [i.checked_sub(1), Some(i)]
        .into_iter()
        .flatten()
        .filter(|&j| j < truth.len())
        .min_by(|&a, &b| {
            (truth[a].time - time)
                .abs()
                .total_cmp(&(truth[b].time - time).abs())
        });
    match best {
        Some(j) if (truth[j].time - time).abs() <= 0.5 * scenario.imu_dt => Ok(&truth[j]),
        _ => Err(PipelineError::Missing {
            within: scenario.name.clone(),
            what: format!("truth sample at the smoother epoch t = {time} s"),
        }),
    }
}

/// Run the LS-aided INS/DVL filter on `scenario` with `cross`, record it, smooth it.
/// On a recorded IMU: [`smooth_recorded`] (M = 0 only).
///
/// # Errors
/// The filter's and the smoother's errors (e.g. [`estim_core::Error::SmootherUnsupported`]);
/// a cross-covariance other than M = 0 on a recorded IMU.
pub fn smooth_scenario(
    scenario: &Scenario,
    config: &Config,
    cross: &CrossSource,
    seed: u64,
) -> Result<SmoothReport> {
    if let Some(recorded) = &scenario.recorded {
        if !matches!(cross, CrossSource::Zero) {
            return Err(PipelineError::Argument {
                flag: "--rho".into(),
                reason: format!(
                    "{}: the recorded IMU is smoothed by the navigator's own pass, whose \
                     DVL updates have M = 0 (leave out --rho, or run on the synthesized \
                     IMU)",
                    scenario.name
                ),
            });
        }
        return smooth_recorded(scenario, recorded, config);
    }
    let measurements = least_squares_measurements(scenario, config);
    let mut recorder = ForwardRecorder::<f64, InsState, ERROR_STATES>::new(RecordAt::Updates);
    run_filter_with_observer(
        "LS",
        scenario,
        config,
        &measurements,
        cross,
        seed,
        &mut recorder,
    )?;
    let smoothed: Vec<Smoothed<f64, InsState, ERROR_STATES>> = recorder.smooth()?;
    let process = InsErrorModel::new(filter_imu_spec(&scenario.imu_spec)?);
    let start = scenario
        .truth
        .first()
        .ok_or_else(|| PipelineError::NoData {
            what: format!("truth samples in {}", scenario.name),
        })?
        .time;
    let mut time = Vec::with_capacity(smoothed.len());
    let mut filtered = EstimateSeries::default();
    let mut smooth = EstimateSeries::default();
    for s in &smoothed {
        let truth = truth_at(scenario, s.filtered_state.time)?;
        time.push(truth.time - start);
        filtered.push(
            truth,
            &s.filtered_state,
            &s.filtered_covariance,
            ERROR_STATES,
        );
        let state = s.injected(&process)?;
        smooth.push(truth, &state, &s.covariance, ERROR_STATES);
    }
    let cross_name = match cross {
        CrossSource::Zero => "M = 0".to_string(),
        CrossSource::Scaled(rho) => format!("rho = {rho}"),
        CrossSource::ScaledPerStep(rho) => format!("rho = {rho} (per-step Q)"),
        CrossSource::PerEpoch(_) => "per-epoch M".to_string(),
    };
    Ok(SmoothReport {
        name: scenario.name.clone(),
        trajectory: scenario.trajectory,
        imu_source: scenario.imu_source,
        nees_states: ERROR_STATES,
        cross: cross_name,
        time,
        filtered_summary: filtered.summary(),
        smoothed_summary: smooth.summary(),
        filtered,
        smoothed: smooth,
    })
}

/// The forward pass's state and covariance at each reference epoch, by time.
#[derive(Default)]
struct ForwardEpochs(HashMap<u64, (InsState, ErrorMatrix)>);

impl NavigationObserver for ForwardEpochs {
    fn on_solution(
        &mut self,
        kind: SolutionKind,
        solution: &NavSolution,
        state: &InsState,
        covariance: &ErrorMatrix,
    ) -> std::result::Result<(), Box<dyn std::error::Error + Send + Sync>> {
        if kind == SolutionKind::Epoch {
            self.0
                .insert(solution.time.to_bits(), (*state, *covariance));
        }
        Ok(())
    }
}

/// [`smooth_scenario`] on a recorded IMU: the navigator's own forward pass on the
/// survey as the vehicle file describes it (its DVL model and error states, the least
/// squares velocities of the protocol's beams as DVL rows, M = 0), smoothed over its
/// measurement epochs and the reference's ([`estim::navigator::smooth_survey_at`], as
/// `estim smooth --imu --truth` does), the filtered and smoothed solutions scored
/// against the reference at its own epochs, NEES over the 9 states with truth.
///
/// # Errors
/// The navigator's and the smoother's errors; a smoothed epoch without a forward
/// solution or a truth sample.
pub fn smooth_recorded(
    scenario: &Scenario,
    recorded: &super::RecordedSurvey,
    config: &Config,
) -> Result<SmoothReport> {
    let mut inputs = recorded.inputs.clone();
    inputs.output_epochs = recorded.truth_epochs.iter().map(|(t, _)| *t).collect();
    let velocities = least_squares_velocities(scenario, config);
    for (row, v) in inputs.dvl.iter_mut().zip(&velocities) {
        row.input = match v {
            Some(v) => DvlInput::Velocity(*v),
            None => DvlInput::NoLock,
        };
    }
    let mut forward = ForwardEpochs::default();
    let run = smooth_survey_at(
        &inputs,
        &recorded.settings,
        None,
        &mut forward,
        RecordAt::Measurements,
    )?;
    let start = recorded
        .truth_epochs
        .first()
        .ok_or_else(|| PipelineError::NoData {
            what: format!("reference epochs in {}", scenario.name),
        })?
        .0;
    let truth: HashMap<u64, &InsState> = recorded
        .truth_epochs
        .iter()
        .map(|(t, s)| (t.to_bits(), s))
        .collect();
    let mut time = Vec::with_capacity(run.smoothed.len());
    let mut filtered = EstimateSeries::default();
    let mut smooth = EstimateSeries::default();
    for s in run
        .smoothed
        .iter()
        .filter(|s| s.kind == SolutionKind::Epoch)
    {
        let t = s.solution.time;
        let (state, covariance) =
            forward
                .0
                .get(&t.to_bits())
                .ok_or_else(|| PipelineError::Missing {
                    within: scenario.name.clone(),
                    what: format!("forward solution at the smoothed epoch t = {t} s"),
                })?;
        let truth = truth
            .get(&t.to_bits())
            .ok_or_else(|| PipelineError::Missing {
                within: scenario.name.clone(),
                what: format!("reference sample at the smoothed epoch t = {t} s"),
            })?;
        time.push(t - start);
        filtered.push(truth, state, covariance, RECORDED_NEES_STATES);
        smooth.push(truth, &s.state, &s.covariance, RECORDED_NEES_STATES);
    }
    Ok(SmoothReport {
        name: scenario.name.clone(),
        trajectory: scenario.trajectory,
        imu_source: scenario.imu_source,
        nees_states: RECORDED_NEES_STATES,
        cross: "M = 0".to_string(),
        time,
        filtered_summary: filtered.summary(),
        smoothed_summary: smooth.summary(),
        filtered,
        smoothed: smooth,
    })
}
