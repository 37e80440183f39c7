//! The linear Kalman filter: F, Q, H, R held by the filter (replaceable per step), an
//! optional control input B u; its predict and update run a copy compiled for AVX2
//! where the dispatch allows.

#[cfg(doc)]
use crate::{Error, JointCheck};
use nalgebra::{SMatrix, SVector};

use super::shared::{propagate_symmetric, propagate_symmetric_into, CrossSource, Shared};
use super::UpdateReport;
use crate::gaussian::check_finite;
use crate::linalg::mul_static;
use crate::observer::{NoObserver, Observer};
use crate::square_root::covariance_factor;
use crate::{
    CrossCovariance, FilterConfig, Result, Scalar, StateAndCovariance, WindowedCrossCovariance,
};

/// Linear Kalman filter x_k = F_k x_{k-1} + B_k u_k + G w_{k-1}, y_k = H_k x_k + v_k,
/// with the correlated update.
///
/// ## Time index and the time-varying model
///
/// Step k (k = 1, 2, ...) is one predict, then at most one update (as [`Self::step`]).
/// The predict of step k maps x_{k-1} to x_k with the F and Q the filter holds at that
/// moment: F_k and Q_k = Cov(G w_{k-1}), plus B_k u_k with
/// [`Self::predict_with_input`]; the update of step k uses the H and R it holds: H_k
/// and R_k, and the cross-covariance model's M_k = Cov(G w_{k-1}, v_k) (accumulated
/// over the interval, below). A time-varying model replaces the matrices before each
/// call with the setters ([`Self::set_transition`], [`Self::set_process_noise`],
/// [`Self::set_observation`], [`Self::set_measurement_noise`]) or with
/// [`Self::predict_with`] / [`Self::update_with`], which set and run in one call; the
/// matrices stay in force until replaced. Between two updates each predict adds its own
/// step: Q_acc <- F_k Q_acc F_k' + Q_k and Phi_acc <- F_k Phi_acc (the first predict
/// after an update sets Q_acc = Q_k, Phi_acc = F_k), so Q_acc = Cov of the process
/// noise accumulated over the interval and Phi_acc its transition, whatever F and Q
/// each step used. B u is deterministic: it moves the mean only, and the observer's
/// [`crate::PredictEvent`] carries Phi = F_k and Q_d = Q_k of the step.
///
/// A whole sequence of measurements of the fixed model is filtered or smoothed in one
/// call by [`Self::filter_batch`] and [`Self::smooth_batch`].
///
/// State kept between calls (all readable): the estimate, Q_acc and Phi_acc since
/// the last measurement, the recorded window (if configured), the configuration and
/// the observer. Q_acc and Phi_acc are reset after every update attempt, accepted or
/// rejected by the gate (the measurement's noise is correlated with the process noise
/// of the interval that ends at it; a rejected measurement still closes its
/// interval). They are kept when an update fails with an error, and when a step has
/// no measurement (`None`). On an observer error, see the module docs' commit rule.
#[derive(Debug, Clone)]
pub struct KalmanFilter<T: Scalar, const N: usize, const M: usize, O = NoObserver> {
    transition: SMatrix<T, N, N>,
    process_noise: SMatrix<T, N, N>,
    observation: SMatrix<T, M, N>,
    measurement_noise: SMatrix<T, M, M>,
    estimate: StateAndCovariance<T, N>,
    /// The predicted or posterior covariance buffer; after a predict or an accepted
    /// update it holds the covariance before (swapped, not copied).
    spare: SMatrix<T, N, N>,
    /// F P during a predict.
    work: SMatrix<T, N, N>,
    /// R's block certificate for the joint check (recomputed when R is replaced).
    measurement_certificate: Option<T>,
    /// False after F or Q was replaced, until the next predict: the accumulator's kept
    /// first step (see `Accumulator::push`) is then not this model's and is copied.
    model_unchanged: bool,
    shared: Shared<T, SVector<T, N>, (), N, O>,
}

impl<T: Scalar, const N: usize, const M: usize> KalmanFilter<T, N, M, NoObserver> {
    /// A filter with transition F, process noise Cov(G w) = Q, observation matrix H,
    /// measurement noise R and the initial estimate; default configuration.
    ///
    /// # Errors
    /// [`crate::Error::NonFinite`] or [`crate::Error::InvalidCovariance`] (Q or R not
    /// symmetric, or not positive semidefinite to round-off: see
    /// [`crate::square_root::covariance_factor`]).
    pub fn new(
        transition: SMatrix<T, N, N>,
        process_noise: SMatrix<T, N, N>,
        observation: SMatrix<T, M, N>,
        measurement_noise: SMatrix<T, M, M>,
        initial: StateAndCovariance<T, N>,
    ) -> Result<Self> {
        check_finite(transition.as_slice(), "transition matrix")?;
        check_finite(process_noise.as_slice(), "process noise covariance")?;
        check_finite(observation.as_slice(), "observation matrix")?;
        check_finite(measurement_noise.as_slice(), "measurement noise covariance")?;
        // Symmetric and positive semidefinite to round-off (the semidefinite
        // Cholesky of `crate::linalg::cholesky`; the factors are not kept).
        covariance_factor(&process_noise, "process noise covariance")?;
        covariance_factor(&measurement_noise, "measurement noise covariance")?;
        Ok(Self {
            transition,
            process_noise,
            observation,
            measurement_noise,
            estimate: initial,
            spare: SMatrix::zeros(),
            work: SMatrix::zeros(),
            measurement_certificate: crate::cross::block_certificate(&measurement_noise),
            model_unchanged: true,
            shared: Shared::new(),
        })
    }
}

impl<T: Scalar, const N: usize, const M: usize, O> KalmanFilter<T, N, M, O> {
    shared_accessors!();

    /// Replace the observer.
    #[must_use]
    pub fn with_observer<O2>(self, observer: O2) -> KalmanFilter<T, N, M, O2> {
        KalmanFilter {
            transition: self.transition,
            process_noise: self.process_noise,
            observation: self.observation,
            measurement_noise: self.measurement_noise,
            estimate: self.estimate,
            spare: self.spare,
            work: self.work,
            measurement_certificate: self.measurement_certificate,
            model_unchanged: self.model_unchanged,
            shared: self.shared.with_observer(observer),
        }
    }

    /// A copy of this filter (model, estimate, accumulators, recorded window,
    /// configuration, log-likelihood) with `observer` in place of its own.
    pub(super) fn fork<O2>(&self, observer: O2) -> KalmanFilter<T, N, M, O2> {
        KalmanFilter {
            transition: self.transition,
            process_noise: self.process_noise,
            observation: self.observation,
            measurement_noise: self.measurement_noise,
            estimate: self.estimate.clone(),
            spare: self.spare,
            work: self.work,
            measurement_certificate: self.measurement_certificate,
            model_unchanged: self.model_unchanged,
            shared: super::batch::fork_shared(&self.shared, observer),
        }
    }

    linear_model_accessors!();

    /// Replace Q = Cov(G w) for the following predicts.
    ///
    /// # Errors
    /// As [`KalmanFilter::new`] for Q: [`Error::NonFinite`], or
    /// [`Error::InvalidCovariance`] (not symmetric, or not positive semidefinite to
    /// round-off); the filter is then unchanged.
    pub fn set_process_noise(&mut self, process_noise: SMatrix<T, N, N>) -> Result<()> {
        check_finite(process_noise.as_slice(), "process noise covariance")?;
        covariance_factor(&process_noise, "process noise covariance")?;
        self.process_noise = process_noise;
        self.model_unchanged = false;
        Ok(())
    }

    /// Replace R for the following updates (its block certificate for the joint check
    /// is recomputed).
    ///
    /// # Errors
    /// As [`KalmanFilter::new`] for R: [`Error::NonFinite`], or
    /// [`Error::InvalidCovariance`]; the filter is then unchanged.
    pub fn set_measurement_noise(&mut self, measurement_noise: SMatrix<T, M, M>) -> Result<()> {
        check_finite(measurement_noise.as_slice(), "measurement noise covariance")?;
        covariance_factor(&measurement_noise, "measurement noise covariance")?;
        self.measurement_noise = measurement_noise;
        self.measurement_certificate = crate::cross::block_certificate(&measurement_noise);
        Ok(())
    }

    /// The current estimate.
    pub fn estimate(&self) -> &StateAndCovariance<T, N> {
        &self.estimate
    }
}

impl<T: Scalar, const N: usize, const M: usize, O: Observer<T, SVector<T, N>, N>>
    KalmanFilter<T, N, M, O>
{
    /// Prior: x <- F x, P <- F P F' + Q. Runs a copy compiled for AVX2 when the CPU
    /// has it (as does [`KalmanFilter::update`]); F P F' of 8 or more states runs
    /// through the fused AVX-512 product on CPUs that have it (same values to
    /// round-off).
    ///
    /// # Errors
    /// [`Error::NonFinite`] if the prediction overflows; observer errors.
    pub fn predict(&mut self) -> Result<()> {
        simd_dispatch!(self.predict_body() via predict_avx2)
    }

    /// [`KalmanFilter::predict`]'s body compiled for AVX2.
    /// (A safe `#[target_feature]` function: callers without AVX2 enabled need an
    /// `unsafe` block that justifies the CPU has it.)
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn predict_avx2(&mut self) -> Result<()> {
        self.predict_body()
    }

    #[inline(always)]
    fn predict_body(&mut self) -> Result<()> {
        let state = mul_static(&self.transition, self.estimate.state());
        self.commit_predict(state)
    }

    /// Prior with a control input: x <- F x + B u, P <- F P F' + Q (B u moves the
    /// mean only; the observer sees Phi = F and Q_d = Q). Dispatched as
    /// [`KalmanFilter::predict`].
    ///
    /// # Errors
    /// [`Error::NonFinite`] if B or u is not finite (the filter is then unchanged) or
    /// the prediction overflows; observer errors.
    pub fn predict_with_input<const U: usize>(
        &mut self,
        control: &SMatrix<T, N, U>,
        input: &SVector<T, U>,
    ) -> Result<()> {
        check_finite(control.as_slice(), "control matrix")?;
        check_finite(input.as_slice(), "control input")?;
        simd_dispatch!(self.predict_input_body(control, input) via predict_input_avx2)
    }

    /// [`KalmanFilter::predict_with_input`]'s body compiled for AVX2.
    /// (A safe `#[target_feature]` function: callers without AVX2 enabled need an
    /// `unsafe` block that justifies the CPU has it.)
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn predict_input_avx2<const U: usize>(
        &mut self,
        control: &SMatrix<T, N, U>,
        input: &SVector<T, U>,
    ) -> Result<()> {
        self.predict_input_body(control, input)
    }

    #[inline(always)]
    fn predict_input_body<const U: usize>(
        &mut self,
        control: &SMatrix<T, N, U>,
        input: &SVector<T, U>,
    ) -> Result<()> {
        let state =
            mul_static(&self.transition, self.estimate.state()) + mul_static(control, input);
        self.commit_predict(state)
    }

    /// One predict of a time-varying model: F and Q replaced (as by
    /// [`KalmanFilter::set_transition`] and [`KalmanFilter::set_process_noise`], and
    /// kept for the following predicts), then [`KalmanFilter::predict`], or
    /// [`KalmanFilter::predict_with_input`] when `control` = (B, u) is given.
    ///
    /// # Errors
    /// The setters' errors (checked before anything is replaced: the filter is then
    /// unchanged), then those of the predict.
    pub fn predict_with<const U: usize>(
        &mut self,
        transition: SMatrix<T, N, N>,
        process_noise: SMatrix<T, N, N>,
        control: Option<(&SMatrix<T, N, U>, &SVector<T, U>)>,
    ) -> Result<()> {
        check_finite(transition.as_slice(), "transition matrix")?;
        if let Some((b, u)) = control {
            check_finite(b.as_slice(), "control matrix")?;
            check_finite(u.as_slice(), "control input")?;
        }
        self.set_process_noise(process_noise)?;
        self.set_transition(transition)?;
        match control {
            Some((b, u)) => self.predict_with_input(b, u),
            None => self.predict(),
        }
    }

    /// P <- F P F' + Q into `spare`, checks, commits `state` and the covariance, records
    /// and notifies: the predict after the mean.
    #[inline(always)]
    fn commit_predict(&mut self, state: SVector<T, N>) -> Result<()> {
        let f = &self.transition;
        propagate_symmetric_into(
            f,
            self.estimate.covariance(),
            &self.process_noise,
            &mut self.work,
            &mut self.spare,
        );
        check_finite(state.as_slice(), "predicted state")?;
        check_finite(self.spare.as_slice(), "predicted covariance")?;
        // Only the state before is kept (for the recorded window), not the whole
        // estimate: the covariance is written once, into `spare`, and swapped in.
        let before = *self.estimate.state();
        self.estimate.commit(state, &mut self.spare);
        let fixed = std::mem::replace(&mut self.model_unchanged, true);
        let f = &self.transition;
        self.shared.record_predict(
            fixed,
            &before,
            &(),
            None,
            f,
            &self.process_noise,
            |q, phi, qd| propagate_symmetric(phi, q, qd),
            |later, earlier| crate::linalg::product(later, earlier),
        );
        self.shared.notify_predict(
            None,
            self.estimate.state(),
            self.estimate.covariance(),
            &self.transition,
            &self.process_noise,
        )
    }

    /// One update of a time-varying model: H and R replaced (as by
    /// [`KalmanFilter::set_observation`] and [`KalmanFilter::set_measurement_noise`],
    /// and kept for the following updates), then [`KalmanFilter::update`].
    ///
    /// # Errors
    /// The setters' errors (checked before anything is replaced: the filter is then
    /// unchanged), then those of the update.
    pub fn update_with<C>(
        &mut self,
        observation: SMatrix<T, M, N>,
        measurement_noise: SMatrix<T, M, M>,
        measurement: &SVector<T, M>,
        cross: &C,
    ) -> Result<UpdateReport<T, N, M>>
    where
        C: CrossCovariance<T, SVector<T, N>, N, M> + ?Sized,
    {
        check_finite(observation.as_slice(), "observation matrix")?;
        self.set_measurement_noise(measurement_noise)?;
        self.set_observation(observation)?;
        self.update(measurement, cross)
    }

    fn update_from<C, W>(
        &mut self,
        measurement: &SVector<T, M>,
        source: CrossSource<'_, C, W>,
    ) -> Result<UpdateReport<T, N, M>>
    where
        C: CrossCovariance<T, SVector<T, N>, N, M> + ?Sized,
        W: WindowedCrossCovariance<T, SVector<T, N>, (), N, M> + ?Sized,
    {
        simd_dispatch!(self.update_body(measurement, source) via update_avx2)
    }

    /// The update's body compiled for AVX2.
    /// (A safe `#[target_feature]` function: callers without AVX2 enabled need an
    /// `unsafe` block that justifies the CPU has it.)
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn update_avx2<C, W>(
        &mut self,
        measurement: &SVector<T, M>,
        source: CrossSource<'_, C, W>,
    ) -> Result<UpdateReport<T, N, M>>
    where
        C: CrossCovariance<T, SVector<T, N>, N, M> + ?Sized,
        W: WindowedCrossCovariance<T, SVector<T, N>, (), N, M> + ?Sized,
    {
        self.update_body(measurement, source)
    }

    #[inline(always)]
    fn update_body<C, W>(
        &mut self,
        measurement: &SVector<T, M>,
        source: CrossSource<'_, C, W>,
    ) -> Result<UpdateReport<T, N, M>>
    where
        C: CrossCovariance<T, SVector<T, N>, N, M> + ?Sized,
        W: WindowedCrossCovariance<T, SVector<T, N>, (), N, M> + ?Sized,
    {
        let predicted = mul_static(&self.observation, self.estimate.state());
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
            self.estimate.state(),
            measurement,
            predicted,
            &self.observation,
            &self.measurement_noise,
            Some(self.measurement_certificate),
            &mut self.spare,
            &mut report,
        )?;
        self.shared.prepare_window(window_model, &report);
        self.shared
            .record_update(&attempt, &report, &self.observation, None);
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
            &self.observation,
            windowed,
            None,
        )?;
        Ok(report)
    }

    update_methods! {
        state: SVector<T, N>,
        input: (),
        model: [],
        size: [],
        predict: [],
        /// Update with measurement y and the one-step cross-covariance model `cross`.
        ///
        /// # Errors
        /// Those of [`crate::update::correlated_update`], [`Error::InvalidJointCovariance`] under
        /// [`JointCheck::Reject`], the cross-covariance model's and the observer's.
        update;
        /// Update with measurement y whose noise shares the process noise of a window of
        /// recorded steps: exact M, Var(v | ...) and E[v | ...] (see [`crate::window`]).
        ///
        /// # Errors
        /// As [`KalmanFilter::update`], plus [`Error::NotTracked`] (no window kept),
        /// [`Error::WindowUnavailable`], [`Error::ColouredMeasurementNoise`].
        update_windowed;
        /// One time step: predict, then update if a measurement is present.
        ///
        /// # Errors
        /// Those of [`KalmanFilter::predict`] and [`KalmanFilter::update`].
        step;
        /// Update with measurement y whose noise is uncorrelated with the process
        /// noise (M = 0): [`KalmanFilter::update`] with [`crate::Zero`], the textbook
        /// Kalman update.
        ///
        /// ```
        /// use estim_core::nalgebra::{Matrix1, Matrix1x2, Matrix2, Vector1, Vector2};
        /// use estim_core::{KalmanFilter, StateAndCovariance};
        ///
        /// let initial = StateAndCovariance::new(Vector2::zeros(), Matrix2::identity())?;
        /// let mut kf = KalmanFilter::new(Matrix2::new(1.0, 1.0, 0.0, 1.0),
        ///     Matrix2::identity() * 0.01, Matrix1x2::new(1.0, 0.0), Matrix1::new(1.0), initial)?;
        /// let report = kf.update_uncorrelated(&Vector1::new(2.0))?;
        /// // P = I, H = [1 0], R = 1: S = 2, K = [1/2, 0]'.
        /// assert_eq!(report.innovation_covariance[0], 2.0);
        /// assert_eq!(kf.estimate().state()[0], 1.0);
        /// kf.step_uncorrelated(None)?; // predict only
        /// # Ok::<(), estim_core::Error>(())
        /// ```
        ///
        /// # Errors
        /// As [`KalmanFilter::update`].
        update_uncorrelated;
    }
}
