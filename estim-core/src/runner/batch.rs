//! Batch calls: a whole sequence of measurements filtered or smoothed in one call
//! (convention: [`KalmanFilter::filter_batch`]).

use nalgebra::SVector;

use super::{KalmanFilter, UpdateReport};
use crate::observer::Observer;
use crate::smoother::{ForwardRecorder, RecordAt};
use crate::{CrossCovariance, Error, Result, Scalar, StateAndCovariance};

/// What [`KalmanFilter::filter_batch`] produced, one entry per step.
#[derive(Debug, Clone, PartialEq)]
pub struct FilteredBatch<T: Scalar, const N: usize, const M: usize> {
    /// The estimate after step k (index k - 1): the posterior when its update was
    /// accepted, else the prediction (no measurement, or rejected by the gate).
    pub estimates: Vec<StateAndCovariance<T, N>>,
    /// Step k's update report, `None` for a step without a measurement.
    pub reports: Vec<Option<UpdateReport<T, N, M>>>,
    /// The sum of this batch's accepted updates' [`UpdateReport::log_likelihood`], in
    /// step order from zero: ln p(y's of the batch | everything the filter saw before).
    pub log_likelihood: T,
}

/// What [`KalmanFilter::smooth_batch`] produced: every estimate given every
/// measurement of the batch (fixed-interval RTS smoothing, see [`crate::smoother`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SmoothedBatch<T: Scalar, const N: usize> {
    /// The smoothed estimate of x_0, the filter's estimate before the batch.
    pub initial: StateAndCovariance<T, N>,
    /// The smoothed estimate of x_k after step k (index k - 1).
    pub estimates: Vec<StateAndCovariance<T, N>>,
    /// As [`FilteredBatch::log_likelihood`] (smoothing does not change it).
    pub log_likelihood: T,
}

/// Run `step` over `measurements` (it returns the step's report and the estimate
/// after it) and collect the results.
fn filter_steps<T: Scalar, const N: usize, const M: usize>(
    measurements: &[Option<SVector<T, M>>],
    mut step: impl FnMut(
        Option<&SVector<T, M>>,
    ) -> Result<(Option<UpdateReport<T, N, M>>, StateAndCovariance<T, N>)>,
) -> Result<FilteredBatch<T, N, M>> {
    let mut batch = FilteredBatch {
        estimates: Vec::with_capacity(measurements.len()),
        reports: Vec::with_capacity(measurements.len()),
        log_likelihood: T::zero(),
    };
    for measurement in measurements {
        let (report, estimate) = step(measurement.as_ref())?;
        if let Some(report) = report.as_ref().filter(|r| r.is_accepted()) {
            batch.log_likelihood += report.log_likelihood;
        }
        batch.reports.push(report);
        batch.estimates.push(estimate);
    }
    Ok(batch)
}

/// The smoothed batch from a forward pass recorded at every step from the initial
/// estimate. `mid_interval`: the filter had predicted since its last update before
/// the batch (then a correlated first update shares noise from before x_0).
fn smoothed_steps<T: Scalar, const N: usize, const M: usize>(
    recorder: &ForwardRecorder<T, SVector<T, N>, N>,
    filtered: &FilteredBatch<T, N, M>,
    mid_interval: bool,
) -> Result<SmoothedBatch<T, N>> {
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
    let mut smoothed = recorder
        .smooth()?
        .into_iter()
        .map(|epoch| StateAndCovariance::new_unchecked(epoch.state(), epoch.covariance));
    let initial = smoothed.next().ok_or(Error::SmootherUnsupported {
        epoch: 0,
        reason: "the recording holds no initial epoch",
    })?;
    let estimates: Vec<_> = smoothed.collect();
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
        log_likelihood: filtered.log_likelihood,
    })
}

impl<T: Scalar, const N: usize, const M: usize, O: Observer<T, SVector<T, N>, N>>
    KalmanFilter<T, N, M, O>
{
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
    pub fn filter_batch<C>(
        &mut self,
        measurements: &[Option<SVector<T, M>>],
        cross: &C,
    ) -> Result<FilteredBatch<T, N, M>>
    where
        C: CrossCovariance<T, SVector<T, N>, N, M> + ?Sized,
    {
        filter_steps(measurements, |y| {
            let report = self.step(y, cross)?;
            Ok((report, self.estimate().clone()))
        })
    }

    /// Smooth `measurements` (convention as [`KalmanFilter::filter_batch`]): every estimate from
    /// x_0 (the current one) to the last step given every measurement of the batch, by
    /// a forward pass on a copy of this filter recorded at every step
    /// ([`ForwardRecorder`] with [`RecordAt::EveryStep`]) and its fixed-interval
    /// smoothing. This filter and its observer are left untouched.
    ///
    /// # Errors
    /// Those of [`KalmanFilter::step`] and [`ForwardRecorder::smooth`]
    /// ([`Error::SmootherUnsupported`] for a correlated update after an unmeasured step,
    /// a windowed or inflated update, or a correlated first update when the filter had
    /// predicted since its last update before the batch).
    pub fn smooth_batch<C>(
        &self,
        measurements: &[Option<SVector<T, M>>],
        cross: &C,
    ) -> Result<SmoothedBatch<T, N>>
    where
        C: CrossCovariance<T, SVector<T, N>, N, M> + ?Sized,
    {
        let recorder = ForwardRecorder::from_initial(RecordAt::EveryStep, self.estimate());
        let mut forward = self.fork(recorder);
        let filtered = forward.filter_batch(measurements, cross)?;
        smoothed_steps(
            forward.observer(),
            &filtered,
            self.propagations_since_update() > 0,
        )
    }
}
