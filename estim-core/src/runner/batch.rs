//! Batch calls: a whole sequence of steps filtered or smoothed in one call, the same
//! as `step()` in a loop, for every runner. One implementation (the loop, the
//! log-likelihood sum, the forward recording and its smoothing) below; each runner's
//! `filter_batch` and `smooth_batch` around it come from one macro
//! (`batch_methods!` in `wrappers.rs`).
//!
//! Convention (as [`KalmanFilter::filter_batch`]): entry k - 1 of the slice is step k,
//! which *predicts first* (x_{k-1} to x_k) and then updates when the step has a
//! measurement; the runner's estimate before the call is x_0. The shape of a step:
//!
//! - the linear runners ([`KalmanFilter`], [`crate::SquareRootKalmanFilter`]), whose
//!   predict takes no argument: `&[Option<y>]`, one measurement (or none) per step;
//! - the runners over a [`crate::ProcessModel`] ([`crate::ExtendedKalmanFilter`],
//!   [`crate::ErrorStateKalmanFilter`], [`crate::UnscentedKalmanFilter`]):
//!   `&[(input, dt, Option<y>)]`, the arguments of one `step`: the process model's
//!   input, the step's dt (so a log with irregular times needs no resampling) and the
//!   measurement, with one [`crate::MeasurementModel`] and one cross-covariance model
//!   for the whole batch. For a measurement model that changes within the batch, loop
//!   over `step` instead.
//!
//! What a batch returns per step is the runner's estimate type `E`:
//! [`StateAndCovariance`] for every runner but the error-state filter, whose estimate
//! is the pair (nominal state, error covariance).

use nalgebra::{SMatrix, SVector};

use super::shared::Shared;
use super::{KalmanFilter, UpdateReport};
use crate::observer::Observer;
use crate::smoother::{ForwardRecorder, RecordAt, Smoothed};
use crate::{CrossCovariance, Error, Result, Scalar, StateAndCovariance};

/// What a runner's `filter_batch` produced, one entry per step (module docs for the
/// shapes). `E` is the runner's estimate: [`StateAndCovariance`] (the default), or
/// `(nominal state, error covariance)` for [`crate::ErrorStateKalmanFilter`].
#[derive(Debug, Clone, PartialEq)]
pub struct FilteredBatch<T: Scalar, const N: usize, const M: usize, E = StateAndCovariance<T, N>> {
    /// The estimate after step k (index k - 1): the posterior when its update was
    /// accepted, else the prediction (no measurement, or rejected by the gate).
    pub estimates: Vec<E>,
    /// Step k's update report, `None` for a step without a measurement.
    pub reports: Vec<Option<UpdateReport<T, N, M>>>,
    /// The sum of this batch's accepted updates' [`UpdateReport::log_likelihood`], in
    /// step order from zero: ln p(y's of the batch | everything the filter saw before).
    pub log_likelihood: T,
}

/// What a runner's `smooth_batch` produced: every estimate given every measurement of
/// the batch (fixed-interval RTS smoothing, see [`crate::smoother`]). `E` as for
/// [`FilteredBatch`]; for [`crate::ErrorStateKalmanFilter`] the smoothed error
/// injected into the recorded nominal state ([`Smoothed::injected`]) and the smoothed
/// error covariance about the recorded nominal ([`Smoothed::covariance`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SmoothedBatch<T: Scalar, const N: usize, E = StateAndCovariance<T, N>> {
    /// The smoothed estimate of x_0, the filter's estimate before the batch.
    pub initial: E,
    /// The smoothed estimate of x_k after step k (index k - 1).
    pub estimates: Vec<E>,
    /// The filter's own estimate after step k (index k - 1), from the same forward
    /// pass: [`FilteredBatch::estimates`] (one call gives both).
    pub filtered: Vec<E>,
    /// As [`FilteredBatch::log_likelihood`] (smoothing does not change it).
    pub log_likelihood: T,
}

/// Run `step` over `steps` (it returns the step's report and the estimate after it)
/// and collect the results: every runner's `filter_batch`.
pub(super) fn filter_steps<T: Scalar, I, E, const N: usize, const M: usize>(
    steps: &[I],
    mut step: impl FnMut(&I) -> Result<(Option<UpdateReport<T, N, M>>, E)>,
) -> Result<FilteredBatch<T, N, M, E>> {
    let mut batch = FilteredBatch {
        estimates: Vec::with_capacity(steps.len()),
        reports: Vec::with_capacity(steps.len()),
        log_likelihood: T::zero(),
    };
    for item in steps {
        let (report, estimate) = step(item)?;
        if let Some(report) = report.as_ref().filter(|r| r.is_accepted()) {
            batch.log_likelihood += report.log_likelihood;
        }
        batch.reports.push(report);
        batch.estimates.push(estimate);
    }
    Ok(batch)
}

/// The smoothed batch of every runner's `smooth_batch`: `forward` runs the batch on a
/// copy of the runner observed by the given recorder (whose epoch 0 is `initial`, the
/// runner's estimate as (state models see, covariance)) and hands both back;
/// `estimate` turns a smoothed epoch into the runner's estimate type.
/// `mid_interval`: the runner had predicted since its last update before the batch
/// (then a correlated first update shares noise from before x_0).
pub(super) fn smooth_steps<T: Scalar, S: Clone, E, const N: usize, const M: usize>(
    initial: (S, SMatrix<T, N, N>),
    mid_interval: bool,
    forward: impl FnOnce(
        ForwardRecorder<T, S, N>,
    ) -> Result<(FilteredBatch<T, N, M, E>, ForwardRecorder<T, S, N>)>,
    mut estimate: impl FnMut(Smoothed<T, S, N>) -> Result<E>,
) -> Result<SmoothedBatch<T, N, E>> {
    let recorder = ForwardRecorder::from_initial_parts(RecordAt::EveryStep, initial.0, initial.1);
    let (filtered, recorder) = forward(recorder)?;
    let first_update = filtered
        .reports
        .iter()
        .enumerate()
        .find_map(|(k, r)| r.as_ref().map(|r| (k, r)));
    if let Some((k, report)) = first_update {
        let correlated = report.cross_covariance.iter().any(|v| !v.is_zero());
        if mid_interval && report.is_accepted() && correlated {
            return Err(Error::SmootherUnsupported {
                epoch: k + 1,
                reason: "correlated first update of a batch that started after predicts \
                         without an update (its noise is correlated with the initial error)",
            });
        }
    }
    let mut smoothed = recorder.smooth()?.into_iter();
    let initial = estimate(smoothed.next().ok_or(Error::SmootherUnsupported {
        epoch: 0,
        reason: "the recording holds no initial epoch",
    })?)?;
    let estimates = smoothed.map(estimate).collect::<Result<Vec<_>>>()?;
    if estimates.len() != filtered.estimates.len() {
        return Err(Error::Dimension {
            what: "smoothed epochs (one per step)",
            expected: filtered.estimates.len(),
            got: estimates.len(),
        });
    }
    Ok(SmoothedBatch {
        initial,
        estimates,
        filtered: filtered.estimates,
        log_likelihood: filtered.log_likelihood,
    })
}

/// A smoothed epoch of a runner whose state is `SVector<T, N>` as its estimate.
pub(super) fn smoothed_estimate<T: Scalar, const N: usize>(
    epoch: Smoothed<T, SVector<T, N>, N>,
) -> Result<StateAndCovariance<T, N>> {
    Ok(StateAndCovariance::new_unchecked(
        epoch.state(),
        epoch.covariance,
    ))
}

/// A copy of a runner's shared core (accumulators, recorded window, configuration,
/// gate state, log-likelihood) with `observer` in place of its own: what
/// `smooth_batch` runs its forward pass on.
pub(super) fn fork_shared<T: Scalar, S: Clone, U: Clone, const N: usize, O, O2>(
    shared: &Shared<T, S, U, N, O>,
    observer: O2,
) -> Shared<T, S, U, N, O2> {
    Shared {
        accumulated: shared.accumulated.clone(),
        history: shared.history.clone(),
        config: shared.config.clone(),
        observer,
        rejections_in_a_row: shared.rejections_in_a_row,
        noise_certificate: shared.noise_certificate,
        log_likelihood: shared.log_likelihood,
        window_cross: Vec::new(),
        window_prepared: None,
    }
}

impl<T: Scalar, const N: usize, const M: usize, O: Observer<T, SVector<T, N>, N>>
    KalmanFilter<T, N, M, O>
{
    batch_methods! {
        steps: measurements: Option<SVector<T, M>>,
        step: |y| [] y.as_ref(),
        model: [],
        size: [],
        state: SVector<T, N>,
        estimate: [] |filter| filter.estimate().clone(),
        initial: (*filter.estimate().state(), *filter.estimate().covariance()),
        smoothed: |epoch| smoothed_estimate(epoch),
        smooth_where: [],
        /// Filter `measurements`, one entry per step: predict, then update with the one-step
        /// cross-covariance model `cross` when the entry is `Some`. The same as
        /// [`KalmanFilter::step`] in a loop, bit for bit: the filter advances and its
        /// observer sees every event.
        ///
        /// Convention (filterpy's `KalmanFilter.batch_filter`): entry k - 1 of the slice is
        /// step k of [`KalmanFilter`]'s time index, which *predicts first* (x_{k-1} to x_k)
        /// and then updates; the filter's estimate before the call is x_0, the time before
        /// the first entry. pykalman's `KalmanFilter.filter` instead takes the first
        /// observation at the initial time: to get that, [`KalmanFilter::update`] with the
        /// first observation, then pass the rest.
        ///
        /// Every runner has this pair: [`crate::SquareRootKalmanFilter::filter_batch`] takes
        /// the same slice; the runners over a [`crate::ProcessModel`]
        /// ([`crate::ExtendedKalmanFilter::filter_batch`],
        /// [`crate::ErrorStateKalmanFilter::filter_batch`],
        /// [`crate::UnscentedKalmanFilter::filter_batch`]) take `(input, dt, measurement)`
        /// per step, the arguments of their `step`, and one measurement model.
        ///
        /// ```
        /// use estim_core::nalgebra::{Matrix1, Matrix1x2, Matrix2, Vector1, Vector2};
        /// use estim_core::{KalmanFilter, StateAndCovariance, Zero};
        ///
        /// let initial = StateAndCovariance::new(Vector2::zeros(), Matrix2::identity())?;
        /// let mut kf = KalmanFilter::new(Matrix2::new(1.0, 1.0, 0.0, 1.0),
        ///     Matrix2::identity() * 0.01, Matrix1x2::new(1.0, 0.0), Matrix1::new(0.1), initial)?;
        /// let ys = [Some(1.0), None, Some(3.1), Some(3.9)].map(|y| y.map(Vector1::new));
        /// let smoothed = kf.smooth_batch(&ys, &Zero)?; // on a copy: kf is untouched
        /// let filtered = kf.filter_batch(&ys, &Zero)?;
        /// assert_eq!(filtered.estimates.len(), 4);
        /// assert_eq!(kf.log_likelihood(), filtered.log_likelihood);
        /// // The last smoothed estimate is the filtered one.
        /// assert_eq!(smoothed.estimates[3], filtered.estimates[3]);
        /// # Ok::<(), estim_core::Error>(())
        /// ```
        ///
        /// For a time-varying model, loop over [`KalmanFilter::predict_with`] and
        /// [`KalmanFilter::update_with`] instead.
        ///
        /// # Errors
        /// Those of [`KalmanFilter::step`]; the steps before the failing one stay committed
        /// (as in a loop).
        filter_batch;
        /// Smooth `measurements` (convention as [`KalmanFilter::filter_batch`]): every estimate from
        /// x_0 (the current one) to the last step given every measurement of the batch, by
        /// a forward pass on a copy of this filter recorded at every step
        /// ([`ForwardRecorder`] with [`RecordAt::EveryStep`]) and its fixed-interval
        /// smoothing. This filter and its observer are left untouched.
        ///
        /// # Errors
        /// Those of [`KalmanFilter::step`] and [`ForwardRecorder::smooth`]
        /// ([`Error::SmootherUnsupported`] for a correlated update after an unmeasured step,
        /// an inflated update, or a correlated first update when the filter had predicted
        /// since its last update before the batch).
        smooth_batch;
    }
}
