//! The extended Kalman filter over a [`ProcessModel`] whose state is `SVector<T, N>`.

#[cfg(doc)]
use crate::{Error, KalmanFilter};
use nalgebra::{SMatrix, SVector};

use super::batch::{fork_shared, smoothed_estimate};
use super::shared::{check_dt, CrossSource, Shared};
use super::{FilteredBatch, SmoothedBatch, UpdateReport};
use crate::gaussian::check_finite;
use crate::observer::{NoObserver, Observer};
use crate::{
    CrossCovariance, FilterConfig, MeasurementModel, ProcessModel, Result, Scalar,
    StateAndCovariance, WindowedCrossCovariance,
};

/// Extended Kalman filter over a [`ProcessModel`] whose state is `SVector<T, N>`,
/// updated with any [`MeasurementModel`] and [`CrossCovariance`] (one-step) or
/// [`WindowedCrossCovariance`] (exact over a window).
///
/// F and Q_d are evaluated at the state before propagation. Kept state, the reset
/// rule of Q_acc / Phi_acc and the commit rule: as for [`KalmanFilter`].
#[derive(Debug, Clone)]
pub struct ExtendedKalmanFilter<T: Scalar, P, const N: usize, O = NoObserver>
where
    P: ProcessModel<T, N>,
{
    process: P,
    estimate: StateAndCovariance<T, N>,
    /// The update's posterior covariance buffer; after an accepted update it holds
    /// the prior covariance (swapped, not copied).
    spare: SMatrix<T, N, N>,
    shared: Shared<T, SVector<T, N>, P::Input, N, O>,
}

impl<T, P, const N: usize> ExtendedKalmanFilter<T, P, N, NoObserver>
where
    T: Scalar,
    P: ProcessModel<T, N, State = SVector<T, N>>,
{
    /// A filter for `process` starting from `initial`; default configuration.
    pub fn new(process: P, initial: StateAndCovariance<T, N>) -> Self {
        Self {
            process,
            estimate: initial,
            spare: SMatrix::zeros(),
            shared: Shared::new(),
        }
    }
}

impl<T: Scalar, P: ProcessModel<T, N>, const N: usize, O> ExtendedKalmanFilter<T, P, N, O> {
    shared_accessors!(step_window: SVector<T, N>, P::Input);

    /// Replace the observer.
    #[must_use]
    pub fn with_observer<O2>(self, observer: O2) -> ExtendedKalmanFilter<T, P, N, O2> {
        ExtendedKalmanFilter {
            process: self.process,
            estimate: self.estimate,
            spare: self.spare,
            shared: self.shared.with_observer(observer),
        }
    }

    /// A copy of this filter (model, estimate, accumulators, recorded window,
    /// configuration, log-likelihood) with `observer` in place of its own.
    pub(super) fn fork<O2>(&self, observer: O2) -> ExtendedKalmanFilter<T, P, N, O2>
    where
        P: Clone,
        P::Input: Clone,
    {
        ExtendedKalmanFilter {
            process: self.process.clone(),
            estimate: self.estimate.clone(),
            spare: self.spare,
            shared: fork_shared(&self.shared, observer),
        }
    }

    /// The process model.
    pub fn process(&self) -> &P {
        &self.process
    }

    /// The current estimate.
    pub fn estimate(&self) -> &StateAndCovariance<T, N> {
        &self.estimate
    }
}

impl<T, P, const N: usize, O> ExtendedKalmanFilter<T, P, N, O>
where
    T: Scalar,
    P: ProcessModel<T, N, State = SVector<T, N>>,
    P::Input: Clone,
    O: Observer<T, SVector<T, N>, N>,
{
    /// Prior over `dt`: x <- f(x, u), P <- Phi P Phi' + Q_d (via
    /// [`ProcessModel::propagate_covariance`]).
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for dt not positive and finite, the model's errors,
    /// [`Error::NonFinite`] if the prediction is not finite; observer errors.
    pub fn predict(&mut self, input: &P::Input, dt: T) -> Result<()> {
        check_dt(dt)?;
        let x = self.estimate.state();
        let (phi, qd) = self.process.transition_and_noise(x, input, dt)?;
        check_finite(phi.as_slice(), "transition matrix")?;
        check_finite(qd.as_slice(), "process noise covariance")?;
        let state = self.process.propagate(x, input, dt)?;
        let covariance = self
            .process
            .propagate_covariance(self.estimate.covariance(), &phi, &qd);
        check_finite(state.as_slice(), "predicted state")?;
        check_finite(covariance.as_slice(), "predicted covariance")?;
        let before = std::mem::replace(
            &mut self.estimate,
            StateAndCovariance::new_unchecked(state, covariance),
        );
        let process = &self.process;
        self.shared.record_predict(
            false,
            before.state(),
            input,
            Some(dt),
            &phi,
            &qd,
            |q, phi, qd| process.propagate_covariance(q, phi, qd),
            |later, earlier| process.compose_transitions(later, earlier),
        );
        self.shared.notify_predict(
            Some(dt),
            self.estimate.state(),
            self.estimate.covariance(),
            &phi,
            &qd,
        )
    }

    fn update_from<Mm, C, W, const M: usize>(
        &mut self,
        model: &Mm,
        measurement: &SVector<T, M>,
        source: CrossSource<'_, C, W>,
    ) -> Result<UpdateReport<T, N, M>>
    where
        Mm: MeasurementModel<T, N, M, State = SVector<T, N>> + ?Sized,
        C: CrossCovariance<T, SVector<T, N>, N, M> + ?Sized,
        W: WindowedCrossCovariance<T, SVector<T, N>, P::Input, N, M> + ?Sized,
    {
        let x = self.estimate.state();
        let predicted = model.predict(x)?;
        let jacobian = model.jacobian(x)?;
        let noise = model.noise_covariance(x)?;
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
            &self.estimate,
            x,
            measurement,
            predicted,
            &jacobian,
            &noise,
            None,
            &mut self.spare,
            &mut report,
        )?;
        self.shared.prepare_window(window_model, &report);
        self.shared
            .record_update(&attempt, &report, &jacobian, None);
        let prior_covariance = match attempt.posterior {
            Some(state) => {
                self.estimate.commit(state, &mut self.spare);
                &self.spare
            }
            None => self.estimate.covariance(),
        };
        self.shared.notify_update(
            &report,
            self.estimate.state(),
            self.estimate.covariance(),
            prior_covariance,
            &jacobian,
            windowed,
            None,
        )?;
        Ok(report)
    }

    batch_methods! {
        steps: steps: (P::Input, T, Option<SVector<T, M>>),
        step: |(input, dt, y)| [input, *dt] y.as_ref(),
        model: [model: Mm: MeasurementModel<T, N, M, State = SVector<T, N>>],
        size: [M],
        state: SVector<T, N>,
        estimate: [] |filter| filter.estimate.clone(),
        initial: (*filter.estimate.state(), *filter.estimate.covariance()),
        smoothed: |epoch| smoothed_estimate(epoch),
        smooth_where: [P: Clone,],
        /// Filter a batch of steps, each `(input, dt, measurement)`: the arguments of one
        /// [`ExtendedKalmanFilter::step`] (the process model's input, dt in the model's time
        /// unit, the measurement or `None`), updated with `model` and the one-step
        /// cross-covariance model `cross`. The same as `step` in a loop, bit for bit: the
        /// filter advances and its observer sees every event. Time index as
        /// [`KalmanFilter::filter_batch`]: entry k - 1 is step k, which predicts first.
        ///
        /// ```
        /// use estim_core::nalgebra::{Matrix1, Vector1};
        /// use estim_core::{
        ///     ExtendedKalmanFilter, MeasurementModel, ProcessModel, Result, StateAndCovariance, Zero,
        /// };
        ///
        /// /// A position driven by a measured velocity u: x <- x + u dt.
        /// #[derive(Clone)]
        /// struct Odometry;
        /// impl ProcessModel<f64, 1> for Odometry {
        ///     type State = Vector1<f64>;
        ///     type Input = f64;
        ///     fn propagate(&self, x: &Vector1<f64>, u: &f64, dt: f64) -> Result<Vector1<f64>> {
        ///         Ok(x.add_scalar(u * dt))
        ///     }
        ///     fn transition(&self, _: &Vector1<f64>, _: &f64, _: f64) -> Result<Matrix1<f64>> {
        ///         Ok(Matrix1::identity())
        ///     }
        ///     fn process_noise(&self, _: &Vector1<f64>, _: &f64, dt: f64) -> Result<Matrix1<f64>> {
        ///         Ok(Matrix1::new(0.01 * dt))
        ///     }
        /// }
        ///
        /// /// A position fix.
        /// struct Fix;
        /// impl MeasurementModel<f64, 1, 1> for Fix {
        ///     type State = Vector1<f64>;
        ///     fn predict(&self, x: &Vector1<f64>) -> Result<Vector1<f64>> {
        ///         Ok(*x)
        ///     }
        ///     fn jacobian(&self, _: &Vector1<f64>) -> Result<Matrix1<f64>> {
        ///         Ok(Matrix1::identity())
        ///     }
        ///     fn noise_covariance(&self, _: &Vector1<f64>) -> Result<Matrix1<f64>> {
        ///         Ok(Matrix1::new(0.1))
        ///     }
        /// }
        ///
        /// let initial = StateAndCovariance::new(Vector1::zeros(), Matrix1::identity())?;
        /// let mut ekf = ExtendedKalmanFilter::new(Odometry, initial);
        /// // (input, dt, measurement) per step: irregular times, the first step unmeasured.
        /// let steps = [
        ///     (1.0, 0.1, None),
        ///     (1.0, 0.2, Some(Vector1::new(0.31))),
        ///     (0.5, 0.1, Some(Vector1::new(0.33))),
        /// ];
        /// let smoothed = ekf.smooth_batch(&steps, &Fix, &Zero)?; // on a copy: ekf is untouched
        /// let filtered = ekf.filter_batch(&steps, &Fix, &Zero)?;
        /// assert!(filtered.reports[0].is_none());
        /// assert_eq!(ekf.log_likelihood(), filtered.log_likelihood);
        /// // The last smoothed estimate is the filtered one.
        /// assert_eq!(smoothed.estimates[2], filtered.estimates[2]);
        /// # Ok::<(), estim_core::Error>(())
        /// ```
        ///
        /// # Errors
        /// Those of [`ExtendedKalmanFilter::step`]; the steps before the failing one stay
        /// committed (as in a loop).
        #[allow(clippy::type_complexity)] // the step tuple, spelled out for the reader
        filter_batch;
        /// Smooth a batch of steps (shape as [`ExtendedKalmanFilter::filter_batch`]): every
        /// estimate from x_0 (the current one) to the last step given every measurement of
        /// the batch, by a forward pass on a copy of this filter recorded at every step
        /// ([`crate::smoother::ForwardRecorder`] with
        /// [`crate::smoother::RecordAt::EveryStep`]) and its fixed-interval smoothing with
        /// the reported Phi and H (the linearised RTS smoother; exact on a linear model).
        /// This filter and its observer are left untouched; the copy needs a `Clone` process
        /// model.
        ///
        /// # Errors
        /// As [`KalmanFilter::smooth_batch`], with the errors of
        /// [`ExtendedKalmanFilter::step`].
        #[allow(clippy::type_complexity)] // the step tuple, spelled out for the reader
        smooth_batch;
    }

    update_methods! {
        state: SVector<T, N>,
        input: P::Input,
        model: [model: Mm: MeasurementModel<T, N, M, State = SVector<T, N>>],
        size: [M],
        predict: [input: &P::Input, dt: T],
        /// Update with `model`, measurement y and the one-step cross-covariance `cross`.
        ///
        /// # Errors
        /// As [`KalmanFilter::update`], plus the measurement model's errors.
        update;
        /// Update with a measurement whose noise shares a window of recorded process
        /// steps: exact M, Var(v | ...) and E[v | ...] (see [`crate::window`]).
        ///
        /// # Errors
        /// As [`KalmanFilter::update_windowed`], plus the measurement model's errors.
        update_windowed;
        /// One time step: predict over `dt`, then update if a measurement is present.
        ///
        /// # Errors
        /// Those of [`ExtendedKalmanFilter::predict`] and [`ExtendedKalmanFilter::update`].
        step;
        /// Update with `model` and measurement y whose noise is uncorrelated with the
        /// process noise (M = 0): [`ExtendedKalmanFilter::update`] with
        /// [`crate::Zero`], the textbook EKF update.
        ///
        /// # Errors
        /// As [`ExtendedKalmanFilter::update`].
        update_uncorrelated;
    }
}
