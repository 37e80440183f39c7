//! Fixed-interval smoothing of a survey: the navigator's forward pass recorded at its
//! measurement epochs (estim-core's `ForwardRecorder`, `RecordAt::Measurements`: the
//! predicts between two measurements are composed into one transition) and smoothed backwards (the
//! Rauch-Tung-Striebel recursion of estim-core's smoother, exact with correlated noise;
//! the navigator's updates here have M = 0).

use estim_core::nalgebra::SMatrix;
use estim_core::smoother::{ForwardRecorder, RecordAt};
use estim_ins::{ErrorMatrix, InsErrorModel, InsState, ERROR_STATES};

use super::aiding::InsNominal;
use super::batch::navigate_augmented_with;
use super::reference::predict_copy;
use super::{
    navigate_with, AugmentedErrorModel, AugmentedState, DvlStateSolution, NavSolution,
    NavigationModel, NavigationObserver, NavigationRun, NavigatorError, NavigatorSettings, Result,
    SolutionKind, SurveyInputs, AUGMENTED_STATES,
};

/// One smoothed epoch.
#[derive(Debug, Clone, PartialEq)]
pub struct SmoothedSolution {
    /// [`SolutionKind::Dvl`] at a DVL epoch (accepted or gated), [`SolutionKind::Aiding`]
    /// at an epoch whose updates are depth or fixes only, [`SolutionKind::Epoch`] at one
    /// of [`SurveyInputs::output_epochs`], [`SolutionKind::End`] for the last
    /// propagation after the last update.
    pub kind: SolutionKind,
    /// The smoothed solution (1-sigma from the smoothed covariance).
    pub solution: NavSolution,
    /// The smoothed state: the smoothed error injected into the recorded nominal.
    pub state: InsState,
    /// The smoothed error covariance of the INS states (about the recorded nominal).
    pub covariance: ErrorMatrix,
    /// The smoothed DVL error states with their 1-sigma, when the run estimates them
    /// (`dvl_states` in the configuration).
    pub dvl_states: Option<DvlStateSolution>,
}

/// What [`smooth_survey`] did: the forward run and the smoothed epochs, oldest first.
#[derive(Debug, Clone, PartialEq)]
pub struct SmoothingRun {
    /// The forward (filter) pass.
    pub forward: NavigationRun,
    /// The smoothed epochs.
    pub smoothed: Vec<SmoothedSolution>,
}

/// Navigate a survey forward as [`super::navigate`] does (the forward solutions go to
/// `observer`; on the DVL error states when the configuration has `dvl_states`), then
/// smooth it: one smoothed solution per measurement epoch, accepted or gated (the
/// epochs the forward pass reports; estim-core's `RecordAt::Measurements`), one at
/// each of the inputs' output epochs (the forward pass marks the IMU sample before
/// each, and the smoothed estimate there is predicted over the rest of the interval,
/// as the forward pass predicts its own), and one for the last propagation. An update
/// the gate's recovery rule accepted with an inflated covariance is smoothed as the
/// forward pass ran it (estim-core's smoother: the model with an extra process noise
/// at that epoch).
///
/// # Errors
/// As [`super::navigate`]; [`NavigatorError::Smoother`] when the recording cannot be
/// smoothed exactly, or a filtered covariance is not positive definite.
pub fn smooth_survey(
    inputs: &SurveyInputs,
    settings: &NavigatorSettings,
    output_rate_hz: Option<f64>,
    observer: &mut dyn NavigationObserver,
) -> Result<SmoothingRun> {
    smooth_survey_at(
        inputs,
        settings,
        output_rate_hz,
        observer,
        RecordAt::Measurements,
    )
}

/// [`smooth_survey`] with the epochs chosen: `RecordAt::Measurements` (every
/// measurement epoch, as the forward pass reports them), `RecordAt::Updates` (the
/// epochs with an accepted update only; the values there are the same) or
/// `RecordAt::EveryStep` (every IMU step: memory grows with N^2 per step).
///
/// # Errors
/// As [`smooth_survey`].
pub fn smooth_survey_at(
    inputs: &SurveyInputs,
    settings: &NavigatorSettings,
    output_rate_hz: Option<f64>,
    observer: &mut dyn NavigationObserver,
    epochs: RecordAt,
) -> Result<SmoothingRun> {
    let Some(states) = settings.dvl_states().copied() else {
        let recorder = ForwardRecorder::<f64, InsState, ERROR_STATES>::new(epochs);
        let (forward, recorder) =
            navigate_with(inputs, settings, output_rate_hz, observer, recorder)?;
        let process = InsErrorModel::new(settings.filter_spec);
        return smoothed(forward, &recorder, &process);
    };
    let recorder = ForwardRecorder::<f64, AugmentedState, AUGMENTED_STATES>::new(epochs);
    let (forward, recorder) = navigate_augmented_with(
        inputs,
        settings,
        &states,
        output_rate_hz,
        observer,
        recorder,
    )?;
    let process = AugmentedErrorModel::new(InsErrorModel::new(settings.filter_spec), &states)?;
    smoothed(forward, &recorder, &process)
}

/// The entry of the increasing `times` within `tolerance` of `time`, if any.
fn time_in(times: &[f64], time: f64, tolerance: f64) -> Option<f64> {
    times
        .get(times.partition_point(|&t| t < time - tolerance))
        .copied()
        .filter(|t| (t - time).abs() <= tolerance)
}

/// The smoothed epochs of `recorder` (the forward pass `forward` on `process`).
fn smoothed<E: NavigationModel<N>, const N: usize>(
    forward: NavigationRun,
    recorder: &ForwardRecorder<f64, E::State, N>,
    process: &E,
) -> Result<SmoothingRun>
where
    E::State: Clone,
{
    let epochs = recorder.smooth().map_err(NavigatorError::Smoother)?;
    let last = epochs.len().saturating_sub(1);
    let mut smoothed = Vec::with_capacity(epochs.len() + forward.output_marks.len());
    let mut marks = forward.output_marks.iter().peekable();
    for (k, epoch) in epochs.iter().enumerate() {
        let nominal = epoch.injected(process).map_err(NavigatorError::Smoother)?;
        let state = *nominal.ins();
        let covariance: &SMatrix<f64, N, N> = &epoch.covariance;
        let ins_covariance = E::ins_covariance(covariance);
        // The DVL epoch this epoch ended with, if any, accepted or gated (its time as
        // the navigator stamped it; the nominal's own time is the same sum of steps up
        // to rounding).
        let tolerance = 1e-6 * forward.imu_period_s;
        let dvl = time_in(&forward.dvl_nis_times, state.time, tolerance);
        let end = forward.final_solution.time;
        // An epoch a mark ended with no measurement is not a solution of its own: it
        // gives the output epochs' solutions below.
        let kind = match dvl {
            Some(t) => Some((SolutionKind::Dvl, t)),
            None if k == last && (state.time - end).abs() <= tolerance => {
                Some((SolutionKind::End, end))
            }
            None if time_in(&forward.aiding_times, state.time, tolerance).is_some() => {
                Some((SolutionKind::Aiding, state.time))
            }
            None => None,
        };
        if let Some((kind, time)) = kind {
            smoothed.push(SmoothedSolution {
                kind,
                solution: NavSolution::from_state(time, &state, &ins_covariance),
                state,
                covariance: ins_covariance,
                dvl_states: E::dvl_states(&nominal, covariance),
            });
        }
        // The output epochs met at this epoch's time (the forward pass marked them, so
        // an epoch ends there): the smoothed estimate predicted over the rest of the
        // IMU interval, as the forward pass predicts its own there.
        while let Some(mark) = marks.next_if(|m| m.at <= state.time + tolerance) {
            if (mark.at - state.time).abs() > tolerance {
                continue;
            }
            let (at_mark, p) = match (&mark.sample, mark.time - mark.at) {
                (Some(sample), dt) if dt > 0.0 => {
                    predict_copy(process, &nominal, covariance, sample, dt).map_err(|source| {
                        NavigatorError::Filter {
                            time: mark.time,
                            source,
                        }
                    })?
                }
                _ => (nominal.clone(), *covariance),
            };
            let ins = *at_mark.ins();
            let ins_p = E::ins_covariance(&p);
            smoothed.push(SmoothedSolution {
                kind: SolutionKind::Epoch,
                solution: NavSolution::from_state(mark.time, &ins, &ins_p),
                state: ins,
                covariance: ins_p,
                dvl_states: E::dvl_states(&at_mark, &p),
            });
        }
    }
    Ok(SmoothingRun { forward, smoothed })
}
