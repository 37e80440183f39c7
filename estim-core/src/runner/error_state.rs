//! The error-state Kalman filter: a nominal state propagated by the model, an error
//! covariance, updates that inject the estimated error and reset the covariance.

#[cfg(doc)]
use crate::{Error, ExtendedKalmanFilter, KalmanFilter};
use nalgebra::{SMatrix, SVector};

use super::batch::fork_shared;
use super::shared::{check_dt, CrossSource, Shared};
use super::{FilteredBatch, SmoothedBatch, UpdateReport};
use crate::gaussian::{check_finite, check_symmetric, symmetrize};
use crate::observer::{NoObserver, Observer};
use crate::{
    CrossCovariance, ErrorStateModel, FilterConfig, MeasurementModel, ProcessModel, Result, Scalar,
    StateAndCovariance, WindowedCrossCovariance,
};

/// Error-state Kalman filter: a nominal state propagated by the [`ErrorStateModel`],
/// an N-dimensional error covariance, updates that estimate the error, inject it into
/// the nominal state and reset the covariance (P <- J P J', J = `reset_jacobian`
/// evaluated at the nominal state before injection and the injected error). The
/// error estimate is zero between updates; the windowed bookkeeping applies J to the
/// carried cross-covariance too.
///
/// Kept state, the reset rule of Q_acc / Phi_acc and the commit rule: as for
/// [`KalmanFilter`].
#[derive(Debug, Clone)]
pub struct ErrorStateKalmanFilter<T, P, const N: usize, O = NoObserver>
where
    T: Scalar,
    P: ProcessModel<T, N>,
{
    process: P,
    nominal: P::State,
    covariance: SMatrix<T, N, N>,
    /// The update's posterior covariance buffer; after an accepted update it holds
    /// the prior covariance (swapped, not copied).
    spare: SMatrix<T, N, N>,
    shared: Shared<T, P::State, P::Input, N, O>,
}

impl<T, P, const N: usize> ErrorStateKalmanFilter<T, P, N, NoObserver>
where
    T: Scalar,
    P: ErrorStateModel<T, N>,
{
    /// A filter for `process` from a nominal state and its error covariance.
    ///
    /// # Errors
    /// [`Error::NonFinite`] / [`Error::InvalidCovariance`] for a bad covariance.
    pub fn new(process: P, nominal: P::State, covariance: SMatrix<T, N, N>) -> Result<Self> {
        check_finite(covariance.as_slice(), "error covariance")?;
        check_symmetric(&covariance, "error covariance")?;
        Ok(Self {
            process,
            nominal,
            covariance,
            spare: SMatrix::zeros(),
            shared: Shared::new(),
        })
    }
}

impl<T: Scalar, P: ProcessModel<T, N>, const N: usize, O> ErrorStateKalmanFilter<T, P, N, O> {
    shared_accessors!(step_window: P::State, P::Input);

    /// Replace the observer.
    #[must_use]
    pub fn with_observer<O2>(self, observer: O2) -> ErrorStateKalmanFilter<T, P, N, O2> {
        ErrorStateKalmanFilter {
            process: self.process,
            nominal: self.nominal,
            covariance: self.covariance,
            spare: self.spare,
            shared: self.shared.with_observer(observer),
        }
    }

    /// A copy of this filter (model, estimate, accumulators, recorded window,
    /// configuration, log-likelihood) with `observer` in place of its own.
    pub(super) fn fork<O2>(&self, observer: O2) -> ErrorStateKalmanFilter<T, P, N, O2>
    where
        P: Clone,
        P::Input: Clone,
    {
        ErrorStateKalmanFilter {
            process: self.process.clone(),
            nominal: self.nominal.clone(),
            covariance: self.covariance,
            spare: self.spare,
            shared: fork_shared(&self.shared, observer),
        }
    }

    /// The process model.
    pub fn process(&self) -> &P {
        &self.process
    }

    /// The process model, mutable: a change (e.g. an adapted noise level) takes
    /// effect from the next prediction; steps already recorded keep the model they
    /// were predicted with.
    pub fn process_mut(&mut self) -> &mut P {
        &mut self.process
    }

    /// The nominal state.
    pub fn nominal(&self) -> &P::State {
        &self.nominal
    }

    /// The error covariance.
    pub fn covariance(&self) -> &SMatrix<T, N, N> {
        &self.covariance
    }
}

impl<T, P, const N: usize, O> ErrorStateKalmanFilter<T, P, N, O>
where
    T: Scalar,
    P: ErrorStateModel<T, N>,
    P::Input: Clone,
    O: Observer<T, P::State, N>,
{
    /// Propagate the nominal state with [`ProcessModel::propagate`] and the error
    /// covariance with [`ProcessModel::propagate_covariance`] (Phi and Q_d evaluated
    /// at the nominal state before propagation).
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for dt not positive and finite, the model's errors,
    /// [`Error::NonFinite`] if the covariance is not finite; observer errors.
    pub fn predict(&mut self, input: &P::Input, dt: T) -> Result<()> {
        check_dt(dt)?;
        let (phi, qd) = self
            .process
            .transition_and_noise(&self.nominal, input, dt)?;
        check_finite(phi.as_slice(), "transition matrix")?;
        check_finite(qd.as_slice(), "process noise covariance")?;
        let nominal = self.process.propagate(&self.nominal, input, dt)?;
        let covariance = self
            .process
            .propagate_covariance(&self.covariance, &phi, &qd);
        check_finite(covariance.as_slice(), "predicted covariance")?;
        let before = std::mem::replace(&mut self.nominal, nominal);
        self.covariance = covariance;
        let process = &self.process;
        self.shared.record_predict(
            false,
            &before,
            input,
            Some(dt),
            &phi,
            &qd,
            |q, phi, qd| process.propagate_covariance(q, phi, qd),
            |later, earlier| process.compose_transitions(later, earlier),
        );
        self.shared
            .notify_predict(Some(dt), &self.nominal, &self.covariance, &phi, &qd)
    }

    fn update_from<Mm, C, W, const M: usize>(
        &mut self,
        model: &Mm,
        measurement: &SVector<T, M>,
        source: CrossSource<'_, C, W>,
    ) -> Result<UpdateReport<T, N, M>>
    where
        Mm: MeasurementModel<T, N, M, State = P::State> + ?Sized,
        C: CrossCovariance<T, P::State, N, M> + ?Sized,
        W: WindowedCrossCovariance<T, P::State, P::Input, N, M> + ?Sized,
    {
        let predicted = model.predict(&self.nominal)?;
        let jacobian = model.jacobian(&self.nominal)?;
        let noise = model.noise_covariance(&self.nominal)?;
        let prior = StateAndCovariance::new_unchecked(SVector::zeros(), self.covariance);
        let window_model = match source {
            CrossSource::Windowed(w) => Some(w),
            CrossSource::OneStep(_) => None,
        };
        let windowed = window_model.map(|w| w.window_steps());
        // Filled in place by the attempt (the copies of returned matrices were a
        // tenth of an update at N = 15).
        let mut report = UpdateReport::blank();
        let attempt = self.shared.attempt(
            source,
            &prior,
            &self.nominal,
            measurement,
            predicted,
            &jacobian,
            &noise,
            None,
            &mut self.spare,
            &mut report,
        )?;
        // Everything that can fail happens before the commit; the posterior
        // covariance (reset when J != I) is in `spare`.
        let mut committed = None;
        let mut reset = None;
        if let Some(error) = attempt.posterior.as_ref() {
            let j = self.process.reset_jacobian(&self.nominal, error);
            check_finite(j.as_slice(), "reset jacobian")?;
            let nominal = self.process.inject(&self.nominal, error)?;
            if j != SMatrix::<T, N, N>::identity() {
                self.spare = symmetrize(&(j * self.spare * j.transpose()));
                reset = Some(j);
            }
            committed = Some(nominal);
        }
        self.shared.prepare_window(window_model, &report);
        self.shared
            .record_update(&attempt, &report, &jacobian, reset.as_ref());
        let prior_covariance = match committed {
            Some(nominal) => {
                self.nominal = nominal;
                std::mem::swap(&mut self.covariance, &mut self.spare);
                &self.spare
            }
            None => &self.covariance,
        };
        self.shared.notify_update(
            &report,
            &self.nominal,
            &self.covariance,
            prior_covariance,
            &jacobian,
            windowed,
            reset.as_ref(),
        )?;
        Ok(report)
    }

    batch_methods! {
        steps: steps: (P::Input, T, Option<SVector<T, M>>),
        step: |(input, dt, y)| [input, *dt] y.as_ref(),
        model: [model: Mm: MeasurementModel<T, N, M, State = P::State>],
        size: [M],
        state: P::State,
        estimate: [(P::State, SMatrix<T, N, N>)] |filter| (filter.nominal.clone(), filter.covariance),
        initial: (filter.nominal.clone(), filter.covariance),
        smoothed: |epoch| Ok((epoch.injected(&filter.process)?, epoch.covariance)),
        smooth_where: [P: Clone,],
        /// Filter a batch of steps, each `(input, dt, measurement)`: the arguments of one
        /// [`ErrorStateKalmanFilter::step`] (the process model's input, dt in the model's
        /// time unit, the measurement or `None`), updated with `model` and the one-step
        /// cross-covariance model `cross`. The same as `step` in a loop, bit for bit: the
        /// filter advances and its observer sees every event. Time index as
        /// [`KalmanFilter::filter_batch`]: entry k - 1 is step k, which predicts first. The
        /// estimate after each step is the pair (nominal state, error covariance).
        ///
        /// # Errors
        /// Those of [`ErrorStateKalmanFilter::step`]; the steps before the failing one stay
        /// committed (as in a loop).
        #[allow(clippy::type_complexity)] // the step tuple and the estimate pair, spelled out
        filter_batch;
        /// Smooth a batch of steps (shape as [`ErrorStateKalmanFilter::filter_batch`]):
        /// every estimate from x_0 (the current nominal state and error covariance) to the
        /// last step given every measurement of the batch, by a forward pass on a copy of
        /// this filter recorded at every step ([`crate::smoother::ForwardRecorder`] with
        /// [`crate::smoother::RecordAt::EveryStep`]) and its fixed-interval smoothing (the
        /// linearised RTS smoother with the resets carried, see the smoother's error-state
        /// convention; exact on a linear model with additive injection). Each smoothed
        /// estimate is (the smoothed error injected into the recorded nominal state with
        /// [`ErrorStateModel::inject`], the smoothed error covariance about that recorded
        /// nominal). This filter and its observer are left untouched; the copy needs a
        /// `Clone` process model.
        ///
        /// # Errors
        /// As [`KalmanFilter::smooth_batch`], with the errors of
        /// [`ErrorStateKalmanFilter::step`] and of the injection.
        #[allow(clippy::type_complexity)] // the step tuple and the estimate pair, spelled out
        smooth_batch;
    }

    update_methods! {
        state: P::State,
        input: P::Input,
        model: [model: Mm: MeasurementModel<T, N, M, State = P::State>],
        size: [M],
        predict: [input: &P::Input, dt: T],
        /// Estimate the error from measurement y (prior error zero), inject it into the
        /// nominal state, reset the covariance.
        ///
        /// # Errors
        /// As [`ExtendedKalmanFilter::update`], plus the injection's errors; on any error
        /// other than the observer's the filter is left untouched.
        update;
        /// Windowed update (exact M, Var(v | ...), E[v | ...]; see [`crate::window`]),
        /// then injection and reset as [`ErrorStateKalmanFilter::update`].
        ///
        /// # Errors
        /// As [`ExtendedKalmanFilter::update_windowed`], plus the injection's errors.
        update_windowed;
        /// One time step: predict over `dt`, then update if a measurement is present.
        ///
        /// # Errors
        /// Those of [`ErrorStateKalmanFilter::predict`] and [`ErrorStateKalmanFilter::update`].
        step;
        /// Update with `model` and measurement y whose noise is uncorrelated with the
        /// process noise (M = 0): [`ErrorStateKalmanFilter::update`] with
        /// [`crate::Zero`].
        ///
        /// # Errors
        /// As [`ErrorStateKalmanFilter::update`].
        update_uncorrelated;
    }
}
