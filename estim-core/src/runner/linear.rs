//! The linear Kalman filter: fixed F, Q, H, R; its predict and update run a copy
//! compiled for AVX2 where the dispatch allows.

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

/// Linear Kalman filter x_k = F x_{k-1} + G w, y_k = H x_k + v, with the correlated
/// update.
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
    /// R's block certificate for the joint check (R never changes).
    measurement_certificate: Option<T>,
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
            shared: self.shared.with_observer(observer),
        }
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
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn predict_avx2(&mut self) -> Result<()> {
        self.predict_body()
    }

    #[inline(always)]
    fn predict_body(&mut self) -> Result<()> {
        let f = &self.transition;
        let state = mul_static(f, self.estimate.state());
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
        let f = &self.transition;
        self.shared.record_predict(
            true,
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
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn update_avx2<C, W>(
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
        let windowed = matches!(source, CrossSource::Windowed(_));
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
        /// Those of [`crate::correlated_update`], [`Error::InvalidJointCovariance`] under
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
    }
}
