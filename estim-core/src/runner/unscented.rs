//! The unscented Kalman filter: sigma-point prediction through the nonlinear
//! [`SigmaPointProcess::propagate`] and the sigma-point correlated update
//! ([`crate::sigma_point`]), on the shared runner core. No Jacobian of the model
//! is used anywhere: the bookkeeping's matrices are statistical linearisations.

#[cfg(doc)]
use crate::sigma_point::{unscented_predict, unscented_update, SigmaPointUpdate};
#[cfg(doc)]
use crate::{
    CovarianceUpdate, Error, ExtendedKalmanFilter, GateRecovery, KalmanFilter, MeasurementModel,
    ProcessModel,
};
use nalgebra::{SMatrix, SVector};

use super::batch::{fork_shared, smoothed_estimate};
use super::shared::{bisect_inflation, check_dt, Attempt, CrossSource, GateVerdict, Shared};
use super::{FilteredBatch, SmoothedBatch, UpdateReport};
use crate::gaussian::check_finite;
use crate::linalg::mul_static;
use crate::observer::{NoObserver, Observer};
use crate::sigma_point::{
    measurement_linearisation, predict_with_hooks, sigma_statistics, ModelHooks, UnscentedTransform,
};
use crate::update::innovation_log_likelihood;
use crate::{
    CrossCovariance, FilterConfig, Result, Scalar, SigmaPointMeasurement, SigmaPointProcess,
    StateAndCovariance, WindowedCrossCovariance,
};

/// Unscented Kalman filter over a [`SigmaPointProcess`], updated with any
/// [`SigmaPointMeasurement`] and [`CrossCovariance`] (one-step) or
/// [`WindowedCrossCovariance`] (exact over a window), with the weights and the update
/// form ([`SigmaPointUpdate::Additive`] by default, or
/// [`SigmaPointUpdate::Augmented`]) of its [`UnscentedTransform`]. Neither model needs
/// a Jacobian; every [`ProcessModel`] and [`MeasurementModel`] on `SVector<T, N>` is
/// also one of these (its Jacobian unused).
///
/// - **Predict**: [`unscented_predict`], sigma points of (x, P) through
///   [`SigmaPointProcess::propagate`], plus Q_d, with the process model's
///   [`SigmaPointProcess::residual`] and [`SigmaPointProcess::mean`] (a heading).
/// - **Update**: [`unscented_update`] with R, M from the [`CrossCovariance`] (or, for
///   [`UnscentedKalmanFilter::update_windowed`], Var(v | ...), the exact windowed M and
///   the innovation y - y_hat - E[v | ...]), with the model's
///   [`SigmaPointMeasurement::residual`] and [`SigmaPointMeasurement::mean`] (angles:
///   the innovation and the sigma points' deviations wrapped, their circular mean).
///   The [`UpdateReport`] holds `innovation_covariance` = P_yy, `gain` = P_xy P_yy^-1,
///   `nis` from P_yy, and `correction` = K (y - y_hat - E\[v\]). The posterior
///   covariance is always P - K P_yy K' (the sigma-point form):
///   [`FilterConfig::covariance_update`] does not apply (its forms are written in terms
///   of H).
/// - **Statistical linearisation, only in the bookkeeping**: where the shared core
///   needs a matrix (Q_acc / Phi_acc, the [`crate::CrossCovarianceContext`], the
///   window's carried cross-covariance C <- Phi C + D, C <- (I - K H) C, the
///   observer's events and so the smoother) the filter uses Phi~ = D' P^-1 from the
///   prediction's sigma points (D = Cov(x_{k-1}, f(x_{k-1})) of the points,
///   [`crate::sigma_point::unscented_predict_linearised`]) and H~ = P_xy' P^-1 from
///   2N + 1 sigma points of the prior through h
///   ([`crate::sigma_point::measurement_linearisation`]; the update evaluates h at
///   those points once more for it). The state's mean and covariance never use them.
///   On linear models Phi~ = Phi and H~ = H, and the filter equals [`KalmanFilter`]
///   to round-off, with and without M (tested to 1e-10).
/// - **Smoothing** ([`UnscentedKalmanFilter::smooth_batch`]): the unscented RTS
///   smoother (Saerkkae 2008), through the recorder's RTS pass over Phi~ and H~ (exact:
///   P Phi~' is the sigma points' cross-covariance D).
/// - **Gate recovery** ([`GateRecovery::Inflate`]): P -> lambda P moves the sigma
///   points, so each trial factor recomputes the sigma-point statistics (the NIS is
///   that of y - y_hat(lambda P), not necessarily monotone in lambda: the factor
///   returned passes the gate, the smallest one when the NIS is monotone). The report's
///   `innovation`, `innovation_covariance` and `nis` are those the gate saw, before the
///   inflation.
/// - The joint covariance [[P, M], [M', R]] (or with Var(v)) must have a square root:
///   otherwise the update fails with [`Error::InvalidJointCovariance`] whatever the
///   [`crate::JointCheck`] (the sigma points are drawn from its factor).
///
/// Kept state, the reset rule of Q_acc / Phi_acc and the commit rule: as for
/// [`KalmanFilter`].
///
/// ```
/// use estim_core::nalgebra::{Matrix1, Matrix2, Vector1, Vector2};
/// use estim_core::sigma_point::UnscentedTransform;
/// use estim_core::{
///     Result, SigmaPointMeasurement, SigmaPointProcess, StateAndCovariance,
///     UnscentedKalmanFilter,
/// };
///
/// /// A pendulum's angle and rate, explicit Euler (no Jacobian).
/// #[derive(Clone)]
/// struct Pendulum;
/// impl SigmaPointProcess<f64, 2> for Pendulum {
///     type Input = ();
///     fn propagate(&self, x: &Vector2<f64>, _: &(), dt: f64) -> Result<Vector2<f64>> {
///         Ok(Vector2::new(x[0] + dt * x[1], x[1] - dt * 9.81 * x[0].sin()))
///     }
///     fn process_noise(&self, _: &Vector2<f64>, _: &(), dt: f64) -> Result<Matrix2<f64>> {
///         Ok(Matrix2::new(0.0, 0.0, 0.0, 1e-3 * dt))
///     }
/// }
///
/// /// The horizontal position of the bob, sin(angle).
/// struct Horizontal;
/// impl SigmaPointMeasurement<f64, 2, 1> for Horizontal {
///     fn predict(&self, x: &Vector2<f64>) -> Result<Vector1<f64>> {
///         Ok(Vector1::new(x[0].sin()))
///     }
///     fn noise_covariance(&self, _: &Vector2<f64>) -> Result<Matrix1<f64>> {
///         Ok(Matrix1::new(1e-2))
///     }
/// }
///
/// let initial = StateAndCovariance::new(Vector2::new(0.3, 0.0), Matrix2::identity() * 0.1)?;
/// let mut ukf = UnscentedKalmanFilter::new(Pendulum, UnscentedTransform::default(), initial);
/// let report = ukf.step_uncorrelated(&(), 0.01, &Horizontal, Some(&Vector1::new(0.29)))?;
/// assert!(report.is_some_and(|r| r.is_accepted()));
///
/// // Filtered and smoothed estimates of a series in one call.
/// let steps: Vec<_> = [0.28, 0.26, 0.23].iter().map(|&y| ((), 0.01, Some(Vector1::new(y)))).collect();
/// let both = ukf.smooth_batch(&steps, &Horizontal, &estim_core::Zero)?;
/// assert_eq!((both.filtered.len(), both.estimates.len()), (3, 3));
/// assert_eq!(both.filtered[2], both.estimates[2]); // the last smoothed is the filtered
/// # Ok::<(), estim_core::Error>(())
/// ```
#[derive(Debug, Clone)]
pub struct UnscentedKalmanFilter<T: Scalar, P, const N: usize, O = NoObserver>
where
    P: SigmaPointProcess<T, N>,
{
    process: P,
    transform: UnscentedTransform,
    estimate: StateAndCovariance<T, N>,
    /// The update's posterior covariance buffer; after an accepted update it holds
    /// the prior covariance (swapped, not copied).
    spare: SMatrix<T, N, N>,
    shared: Shared<T, SVector<T, N>, P::Input, N, O>,
}

impl<T, P, const N: usize> UnscentedKalmanFilter<T, P, N, NoObserver>
where
    T: Scalar,
    P: SigmaPointProcess<T, N>,
{
    /// A filter for `process` with the sigma points of `transform`, starting from
    /// `initial`; default configuration.
    pub fn new(
        process: P,
        transform: UnscentedTransform,
        initial: StateAndCovariance<T, N>,
    ) -> Self {
        Self {
            process,
            transform,
            estimate: initial,
            spare: SMatrix::zeros(),
            shared: Shared::new(),
        }
    }
}

impl<T: Scalar, P: SigmaPointProcess<T, N>, const N: usize, O> UnscentedKalmanFilter<T, P, N, O> {
    shared_accessors!(step_window: SVector<T, N>, P::Input);

    /// Replace the observer.
    #[must_use]
    pub fn with_observer<O2>(self, observer: O2) -> UnscentedKalmanFilter<T, P, N, O2> {
        UnscentedKalmanFilter {
            process: self.process,
            transform: self.transform,
            estimate: self.estimate,
            spare: self.spare,
            shared: self.shared.with_observer(observer),
        }
    }

    /// A copy of this filter (model, estimate, accumulators, recorded window,
    /// configuration, log-likelihood) with `observer` in place of its own.
    pub(super) fn fork<O2>(&self, observer: O2) -> UnscentedKalmanFilter<T, P, N, O2>
    where
        P: Clone,
        P::Input: Clone,
    {
        UnscentedKalmanFilter {
            process: self.process.clone(),
            transform: self.transform,
            estimate: self.estimate.clone(),
            spare: self.spare,
            shared: fork_shared(&self.shared, observer),
        }
    }

    /// The process model.
    pub fn process(&self) -> &P {
        &self.process
    }

    /// The unscented transform (weights and update form).
    pub fn transform(&self) -> &UnscentedTransform {
        &self.transform
    }

    /// The current estimate.
    pub fn estimate(&self) -> &StateAndCovariance<T, N> {
        &self.estimate
    }
}

impl<T, P, const N: usize, O> UnscentedKalmanFilter<T, P, N, O>
where
    T: Scalar,
    P: SigmaPointProcess<T, N>,
    P::Input: Clone,
    O: Observer<T, SVector<T, N>, N>,
{
    /// Prior over `dt` by [`unscented_predict`]: sigma points of (x, P) through
    /// [`SigmaPointProcess::propagate`], plus Q_d. The statistical linearisation
    /// Phi~ = D' P^-1 of the same sigma points
    /// ([`crate::sigma_point::unscented_predict_linearised`]) goes only to
    /// Q_acc / Phi_acc, the recorded window and the observer (the event's
    /// `transition`).
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for dt not positive and finite (or N + kappa <= 0),
    /// the model's errors, [`Error::InvalidCovariance`] if P has no square root,
    /// [`Error::NonFinite`] if the prediction is not finite; observer errors.
    pub fn predict(&mut self, input: &P::Input, dt: T) -> Result<()> {
        check_dt(dt)?;
        let x = self.estimate.state();
        let qd = self.process.process_noise(x, input, dt)?;
        check_finite(qd.as_slice(), "process noise covariance")?;
        let process = &self.process;
        let (predicted, phi) = predict_with_hooks(
            &self.transform,
            &self.estimate,
            |s| process.propagate(s, input, dt),
            |a, b| process.residual(a, b),
            |points| process.mean(points),
            &qd,
        )?;
        let before = std::mem::replace(&mut self.estimate, predicted);
        self.shared.record_predict(
            false,
            before.state(),
            input,
            Some(dt),
            &phi,
            &qd,
            |q, phi, qd| phi * q * phi.transpose() + qd,
            |later, earlier| mul_static(later, earlier),
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
        Mm: SigmaPointMeasurement<T, N, M> + ?Sized,
        C: CrossCovariance<T, SVector<T, N>, N, M> + ?Sized,
        W: WindowedCrossCovariance<T, SVector<T, N>, P::Input, N, M> + ?Sized,
    {
        check_finite(measurement.as_slice(), "measurement")?;
        let prior = &self.estimate;
        let x = prior.state();
        let jacobian = measurement_linearisation(&self.transform, prior, model)?;
        let noise = model.noise_covariance(x)?;
        let window_model = match source {
            CrossSource::Windowed(w) => Some(w),
            CrossSource::OneStep(_) => None,
        };
        let windowed = window_model.map(|w| w.window_steps());
        let mut report = UpdateReport::blank();
        let certificate = self.shared.cross_terms(
            source,
            prior,
            x,
            measurement,
            &jacobian,
            &noise,
            None,
            &mut report,
        )?;
        let transform = &self.transform;
        let hooks = ModelHooks(model);
        let (noise_covariance, cross, noise_mean) = (
            report.noise_covariance,
            report.cross_covariance,
            report.noise_mean,
        );
        // The sigma-point statistics of a prior, its innovation y - y_hat - E[v], P_yy^-1
        // and the NIS.
        let statistics = |prior: &StateAndCovariance<T, N>| {
            let stats = sigma_statistics(transform, prior, &hooks, &noise_covariance, &cross)?;
            let innovation = model.residual(measurement, &stats.predicted) - noise_mean;
            let (inverse, nis, log_det) = stats.factor(&innovation)?;
            Ok::<_, crate::Error>((stats, innovation, inverse, nis, log_det))
        };
        let (stats, innovation, inverse, nis, log_det) = statistics(prior)?;
        report.innovation = innovation;
        report.innovation_covariance = stats.innovation_covariance;
        report.nis = nis;
        report.log_likelihood = innovation_log_likelihood::<T, M>(log_det, nis);
        let (threshold, verdict) = self.shared.gate::<M>(nis, |threshold| {
            bisect_inflation(threshold, |lambda| {
                let inflated = StateAndCovariance::new_unchecked(*x, prior.covariance() * lambda);
                statistics(&inflated).ok().map(|(.., nis, _)| nis)
            })
        })?;
        report.gate_threshold = threshold;
        verdict.record(&mut report.status, &mut report.covariance_inflation);
        let mut attempt = Attempt {
            posterior: None,
            innovation_inverse: None,
            noise_certificate: certificate,
        };
        let accepted = match verdict {
            GateVerdict::Reject => None,
            GateVerdict::Pass => Some((None, stats, innovation, inverse)),
            GateVerdict::Inflate(lambda) => {
                let inflated = StateAndCovariance::new_unchecked(*x, prior.covariance() * lambda);
                let (stats, innovation, inverse, ..) = statistics(&inflated)?;
                Some((Some(inflated), stats, innovation, inverse))
            }
        };
        if let Some((inflated, stats, innovation, inverse)) = accepted {
            let used = inflated.as_ref().unwrap_or(prior);
            let gain = report.gain.insert(SMatrix::zeros());
            let state = stats.posterior(used, &innovation, &inverse, gain, &mut self.spare)?;
            report.correction = Some(state - x);
            attempt.posterior = Some(state);
            attempt.innovation_inverse = self.shared.history.is_enabled().then_some(inverse);
        }
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
        model: [model: Mm: SigmaPointMeasurement<T, N, M>],
        size: [M],
        state: SVector<T, N>,
        estimate: [] |filter| filter.estimate.clone(),
        initial: (*filter.estimate.state(), *filter.estimate.covariance()),
        smoothed: |epoch| smoothed_estimate(epoch),
        smooth_where: [P: Clone,],
        /// Filter a batch of steps, each `(input, dt, measurement)`: the arguments of one
        /// [`UnscentedKalmanFilter::step`] (the process model's input, dt in the model's time
        /// unit, the measurement or `None`), updated with `model` and the one-step
        /// cross-covariance model `cross`. The same as `step` in a loop, bit for bit: the
        /// filter advances and its observer sees every event. Time index as
        /// [`KalmanFilter::filter_batch`]: entry k - 1 is step k, which predicts first.
        ///
        /// # Errors
        /// Those of [`UnscentedKalmanFilter::step`]; the steps before the failing one stay
        /// committed (as in a loop).
        #[allow(clippy::type_complexity)] // the step tuple, spelled out for the reader
        filter_batch;
        /// Smooth a batch of steps (shape as [`UnscentedKalmanFilter::filter_batch`]): every
        /// estimate from x_0 (the current one) to the last step given every measurement of
        /// the batch, by a forward pass on a copy of this filter recorded at every step
        /// ([`crate::smoother::ForwardRecorder`] with
        /// [`crate::smoother::RecordAt::EveryStep`]) and its fixed-interval smoothing.
        ///
        /// It is the unscented RTS smoother (Saerkkae, "Unscented Rauch-Tung-Striebel
        /// smoother", IEEE TAC 53(3), 2008; *Bayesian Filtering and Smoothing*, 2013,
        /// alg. 9.6):
        ///
        /// ```text
        /// D_{k+1} = sum Wc_i (X_i,k - m_k)(f(X_i,k) - m-_{k+1})'    (prediction's points)
        /// G_k = D_{k+1} (P-_{k+1})^-1
        /// m^s_k = m_k + G_k (m^s_{k+1} - m-_{k+1}),  P^s_k = P_k + G_k (P^s_{k+1} - P-_{k+1}) G_k'
        /// ```
        ///
        /// The smoother reads what the forward pass reported: the sigma-point gain, P_yy
        /// and the innovation, and the statistical linearisations Phi~ and H~ (struct
        /// docs), never a Jacobian of the model. With P_k Phi~' = D_{k+1} and, for an
        /// update, P+ = (I - K H~) P-, its RTS step over Phi~ and H~ is the one above
        /// (tested against a separately written URTS to 1e-10). On a linear model it equals
        /// the [`KalmanFilter`]'s. The returned [`SmoothedBatch`] also holds the filtered
        /// estimates of the same forward pass ([`SmoothedBatch::filtered`]).
        /// This filter and its observer are left untouched; the copy needs a `Clone` process
        /// model.
        ///
        /// # Errors
        /// As [`KalmanFilter::smooth_batch`], with the errors of
        /// [`UnscentedKalmanFilter::step`].
        #[allow(clippy::type_complexity)] // the step tuple, spelled out for the reader
        smooth_batch;
    }

    update_methods! {
        state: SVector<T, N>,
        input: P::Input,
        model: [model: Mm: SigmaPointMeasurement<T, N, M>],
        size: [M],
        predict: [input: &P::Input, dt: T],
        /// Update with `model`, measurement y and the one-step cross-covariance `cross`:
        /// the sigma-point update of the transform's form (struct docs).
        ///
        /// # Errors
        /// As [`ExtendedKalmanFilter::update`] (but the joint covariance
        /// [[P, M], [M', R]] must always have a square root:
        /// [`Error::InvalidJointCovariance`]), plus [`Error::InvalidParameter`] if
        /// L + kappa <= 0.
        update;
        /// Update with a measurement whose noise shares a window of recorded process
        /// steps: the sigma-point update with the exact windowed M, Var(v | ...) in place
        /// of R and the innovation y - y_hat - E[v | ...] (see [`crate::window`]).
        ///
        /// # Errors
        /// As [`UnscentedKalmanFilter::update`], plus [`Error::NotTracked`] (no window
        /// kept), [`Error::WindowUnavailable`], [`Error::ColouredMeasurementNoise`].
        update_windowed;
        /// One time step: predict over `dt`, then update if a measurement is present.
        ///
        /// # Errors
        /// Those of [`UnscentedKalmanFilter::predict`] and [`UnscentedKalmanFilter::update`].
        step;
        /// Update with `model` and measurement y whose noise is uncorrelated with the
        /// process noise (M = 0): [`UnscentedKalmanFilter::update`] with
        /// [`crate::Zero`], the textbook UKF update (filterpy's `update(z)`).
        ///
        /// # Errors
        /// As [`UnscentedKalmanFilter::update`].
        update_uncorrelated;
    }
}
