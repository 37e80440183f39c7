//! Fixed-interval smoothing of a survey: the navigator's forward pass recorded at its
//! update epochs (estim-core's `ForwardRecorder`, `RecordAt::Updates`: the predicts
//! between two updates are composed into one transition) and smoothed backwards (the
//! Rauch-Tung-Striebel recursion of estim-core's smoother, exact with correlated noise;
//! the navigator's updates here have M = 0).

use estim_core::smoother::{ForwardRecorder, RecordAt};
use estim_ins::{ErrorMatrix, InsErrorModel, InsState, ERROR_STATES};

use super::{
    navigate_with, NavSolution, NavigationObserver, NavigationRun, NavigatorError,
    NavigatorSettings, Result, SolutionKind, SurveyInputs,
};

/// One smoothed epoch.
#[derive(Debug, Clone, PartialEq)]
pub struct SmoothedSolution {
    /// [`SolutionKind::Dvl`] at an accepted DVL update, [`SolutionKind::Aiding`] at an
    /// epoch whose updates are depth or fixes only, [`SolutionKind::End`] for the last
    /// propagation after the last update.
    pub kind: SolutionKind,
    /// The smoothed solution (1-sigma from the smoothed covariance).
    pub solution: NavSolution,
    /// The smoothed state: the smoothed error injected into the recorded nominal.
    pub state: InsState,
    /// The smoothed error covariance (about the recorded nominal).
    pub covariance: ErrorMatrix,
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
/// `observer`), then smooth it: one smoothed solution per epoch that ended with an
/// accepted update, and one for the last propagation.
///
/// # Errors
/// As [`super::navigate`]; [`NavigatorError::Smoother`] when the recording cannot be
/// smoothed exactly (an update accepted by the gate's recovery rule with an inflated
/// covariance is not a Kalman step: set `gate.recovery_after = 0`), or a filtered
/// covariance is not positive definite.
pub fn smooth_survey(
    inputs: &SurveyInputs,
    settings: &NavigatorSettings,
    output_rate_hz: Option<f64>,
    observer: &mut dyn NavigationObserver,
) -> Result<SmoothingRun> {
    let recorder = ForwardRecorder::<f64, InsState, ERROR_STATES>::new(RecordAt::Updates);
    let (forward, recorder) = navigate_with(inputs, settings, output_rate_hz, observer, recorder)?;
    let epochs = recorder.smooth().map_err(NavigatorError::Smoother)?;
    let process = InsErrorModel::new(settings.filter_spec);
    let last = epochs.len().saturating_sub(1);
    let mut smoothed = Vec::with_capacity(epochs.len());
    for (k, epoch) in epochs.iter().enumerate() {
        let state = epoch.injected(&process).map_err(NavigatorError::Smoother)?;
        // The DVL update this epoch ended with, if any (its time as the navigator
        // stamped it; the nominal's own time is the same sum of steps up to rounding).
        let tolerance = 1e-6 * forward.imu_period_s;
        let dvl = forward
            .dvl_update_times
            .get(
                forward
                    .dvl_update_times
                    .partition_point(|&t| t < state.time - tolerance),
            )
            .copied()
            .filter(|t| (t - state.time).abs() <= tolerance);
        let end = forward.final_solution.time;
        let (kind, time) = match dvl {
            Some(t) => (SolutionKind::Dvl, t),
            None if k == last && (state.time - end).abs() <= tolerance => (SolutionKind::End, end),
            None => (SolutionKind::Aiding, state.time),
        };
        smoothed.push(SmoothedSolution {
            kind,
            solution: NavSolution::from_state(time, &state, &epoch.covariance),
            state,
            covariance: epoch.covariance,
        });
    }
    Ok(SmoothingRun { forward, smoothed })
}
