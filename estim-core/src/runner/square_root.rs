//! The linear Kalman filter in square-root form, on the shared runner core: the
//! covariance is kept as a lower-triangular factor (array algorithms of
//! [`crate::square_root`]).

#[cfg(doc)]
use crate::{GateRecovery, JointCheck, KalmanFilter};
use nalgebra::{SMatrix, SVector};

use super::batch::{fork_shared, smoothed_estimate};
use super::shared::{
    bisect_inflation, propagate_symmetric, Attempt, CrossSource, GateVerdict, Shared,
};
use super::{FilteredBatch, SmoothedBatch, UpdateReport};
use crate::gaussian::{all_zero, check_finite, symmetrize};
use crate::linalg::{mul_static, spd_inverse};
use crate::observer::{NoObserver, Observer};
use crate::scalar::lit;
use crate::square_root::{
    check_joint_factor, covariance_factor, square_root_predict, square_root_update,
};
use crate::update::innovation_log_likelihood;
use crate::{
    CrossCovariance, Error, FilterConfig, Result, Scalar, StateAndCovariance,
    WindowedCrossCovariance,
};

/// Linear Kalman filter in square-root form, x_k = F x_{k-1} + G w, y_k = H x_k + v,
/// with the correlated update; the same configuration, gate (and its recovery),
/// observer events, [`UpdateReport`] and `predict` / `update` / `update_windowed` /
/// `step` as [`KalmanFilter`].
///
/// Holds the state and a lower-triangular factor S of P: predict triangularises
/// [F S, S_q], update runs the array algorithm of
/// [`crate::square_root::square_root_update`], so every covariance is a Gram product,
/// positive semidefinite by construction. P = S S' is formed after each commit (for
/// [`SquareRootKalmanFilter::estimate`], the cross-covariance context and the
/// observer), never propagated. [`FilterConfig::covariance_update`] does not apply
/// (the form is the array algorithm).
///
/// The square-root form's definition of an invalid M: before every one-step update
/// with M != 0, [[Q_acc, M], [M', R]] must have a square root, whatever the
/// [`JointCheck`] (which still decides what is reported): otherwise the update is
/// refused with [`Error::InvalidJointCovariance`] and nothing changes (never factored
/// around); with `track_accumulated_noise(false)` such an update is
/// [`Error::NotTracked`]. A windowed update needs a square root of
/// [[P, M], [M', Var(v)]] (the update's own joint factor).
///
/// Gate recovery ([`GateRecovery::Inflate`]): P -> lambda P is S -> sqrt(lambda) S, the
/// factor found as for [`KalmanFilter`]. Kept state, the reset rule of Q_acc /
/// Phi_acc and the commit rule: as for [`KalmanFilter`].
#[derive(Debug, Clone)]
pub struct SquareRootKalmanFilter<T: Scalar, const N: usize, const M: usize, O = NoObserver> {
    transition: SMatrix<T, N, N>,
    process_noise: SMatrix<T, N, N>,
    noise_factor: SMatrix<T, N, N>,
    observation: SMatrix<T, M, N>,
    measurement_noise: SMatrix<T, M, M>,
    /// R's block certificate for the joint check (recomputed when R is replaced).
    measurement_certificate: Option<T>,
    /// No setter replaced F or Q since the last predict (lets a one-step interval keep
    /// F and Q in Q_acc / Phi_acc as they are).
    model_unchanged: bool,
    factor: SMatrix<T, N, N>,
    /// The state and P = S S' (formed from `factor` after each commit).
    estimate: StateAndCovariance<T, N>,
    shared: Shared<T, SVector<T, N>, (), N, O>,
}

/// S S' of a lower-triangular S, exactly symmetric.
fn gram_lower<T: Scalar, const N: usize>(factor: &SMatrix<T, N, N>) -> SMatrix<T, N, N> {
    let mut p = SMatrix::<T, N, N>::zeros();
    for j in 0..N {
        for i in j..N {
            let mut v = T::zero();
            for k in 0..=j {
                v += factor[(i, k)] * factor[(j, k)];
            }
            p[(i, j)] = v;
            p[(j, i)] = v;
        }
    }
    p
}

impl<T: Scalar, const N: usize, const M: usize> SquareRootKalmanFilter<T, N, M, NoObserver> {
    /// A filter with transition F, process noise Cov(G w) = Q, observation matrix H,
    /// measurement noise R and the initial estimate (P is factored once); default
    /// configuration.
    ///
    /// # Errors
    /// [`Error::NonFinite`]; [`Error::InvalidCovariance`] if Q or P is not positive
    /// semidefinite or R is not positive definite.
    pub fn new(
        transition: SMatrix<T, N, N>,
        process_noise: SMatrix<T, N, N>,
        observation: SMatrix<T, M, N>,
        measurement_noise: SMatrix<T, M, M>,
        initial: StateAndCovariance<T, N>,
    ) -> Result<Self> {
        check_finite(transition.as_slice(), "transition")?;
        check_finite(observation.as_slice(), "observation matrix")?;
        let noise_factor = covariance_factor(&process_noise, "process noise")?;
        let r_factor = covariance_factor(&measurement_noise, "measurement noise")?;
        if (0..M).any(|i| r_factor[(i, i)] <= T::zero()) {
            return Err(Error::InvalidCovariance {
                what: "measurement noise",
                reason: "not positive definite".into(),
            });
        }
        let factor = covariance_factor(initial.covariance(), "initial covariance")?;
        Ok(Self {
            transition,
            process_noise,
            noise_factor,
            observation,
            measurement_noise,
            measurement_certificate: crate::cross::block_certificate(&measurement_noise),
            model_unchanged: true,
            estimate: StateAndCovariance::new_unchecked(*initial.state(), gram_lower(&factor)),
            factor,
            shared: Shared::new(),
        })
    }
}

impl<T: Scalar, const N: usize, const M: usize, O> SquareRootKalmanFilter<T, N, M, O> {
    shared_accessors!();

    /// Replace the observer.
    #[must_use]
    pub fn with_observer<O2>(self, observer: O2) -> SquareRootKalmanFilter<T, N, M, O2> {
        SquareRootKalmanFilter {
            transition: self.transition,
            process_noise: self.process_noise,
            noise_factor: self.noise_factor,
            observation: self.observation,
            measurement_noise: self.measurement_noise,
            measurement_certificate: self.measurement_certificate,
            model_unchanged: self.model_unchanged,
            factor: self.factor,
            estimate: self.estimate,
            shared: self.shared.with_observer(observer),
        }
    }

    /// A copy of this filter (model, estimate, accumulators, recorded window,
    /// configuration, log-likelihood) with `observer` in place of its own.
    pub(super) fn fork<O2>(&self, observer: O2) -> SquareRootKalmanFilter<T, N, M, O2> {
        SquareRootKalmanFilter {
            transition: self.transition,
            process_noise: self.process_noise,
            noise_factor: self.noise_factor,
            observation: self.observation,
            measurement_noise: self.measurement_noise,
            measurement_certificate: self.measurement_certificate,
            model_unchanged: self.model_unchanged,
            factor: self.factor,
            estimate: self.estimate.clone(),
            shared: fork_shared(&self.shared, observer),
        }
    }

    /// Current mean.
    pub fn state(&self) -> &SVector<T, N> {
        self.estimate.state()
    }

    /// Lower-triangular factor S of the covariance, P = S S'.
    pub fn factor(&self) -> &SMatrix<T, N, N> {
        &self.factor
    }

    /// Mean and covariance P = S S' (exactly symmetric, formed at each commit).
    pub fn estimate(&self) -> &StateAndCovariance<T, N> {
        &self.estimate
    }

    linear_model_accessors!();

    /// Replace Q = Cov(G w) for the following predicts (its factor is recomputed).
    ///
    /// # Errors
    /// As [`SquareRootKalmanFilter::new`] for Q: [`Error::NonFinite`], or
    /// [`Error::InvalidCovariance`]; the filter is then unchanged.
    pub fn set_process_noise(&mut self, process_noise: SMatrix<T, N, N>) -> Result<()> {
        let noise_factor = covariance_factor(&process_noise, "process noise")?;
        self.process_noise = process_noise;
        self.noise_factor = noise_factor;
        self.model_unchanged = false;
        Ok(())
    }

    /// Replace R for the following updates (its block certificate for the joint check
    /// is recomputed).
    ///
    /// # Errors
    /// As [`SquareRootKalmanFilter::new`] for R: [`Error::NonFinite`], or
    /// [`Error::InvalidCovariance`] if R is not positive definite; the filter is then
    /// unchanged.
    pub fn set_measurement_noise(&mut self, measurement_noise: SMatrix<T, M, M>) -> Result<()> {
        let r_factor = covariance_factor(&measurement_noise, "measurement noise")?;
        if (0..M).any(|i| r_factor[(i, i)] <= T::zero()) {
            return Err(Error::InvalidCovariance {
                what: "measurement noise",
                reason: "not positive definite".into(),
            });
        }
        self.measurement_noise = measurement_noise;
        self.measurement_certificate = crate::cross::block_certificate(&measurement_noise);
        Ok(())
    }
}

impl<T: Scalar, const N: usize, const M: usize, O: Observer<T, SVector<T, N>, N>>
    SquareRootKalmanFilter<T, N, M, O>
{
    /// Prior: x <- F x, S <- tria([F S, S_q]) ([`square_root_predict`]); Q_acc and
    /// Phi_acc accumulate as for [`KalmanFilter::predict`].
    ///
    /// # Errors
    /// [`Error::NonFinite`] if the prediction overflows (nothing changes then);
    /// observer errors.
    pub fn predict(&mut self) -> Result<()> {
        let f = &self.transition;
        let state = mul_static(f, self.estimate.state());
        check_finite(state.as_slice(), "predicted state")?;
        let factor = square_root_predict(&self.factor, f, &self.noise_factor)?;
        let before = *self.estimate.state();
        self.estimate = StateAndCovariance::new_unchecked(state, gram_lower(&factor));
        self.factor = factor;
        let fixed = std::mem::replace(&mut self.model_unchanged, true);
        self.shared.record_predict(
            fixed,
            &before,
            &(),
            None,
            &self.transition,
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

    /// A nonzero one-step M needs [[Q_acc, M], [M', R]] positive semidefinite, checked
    /// on the tracked accumulated process noise.
    fn check_one_step_cross(&self, cross: &SMatrix<T, N, M>) -> Result<()> {
        if all_zero(cross.as_slice()) {
            return Ok(());
        }
        if !self.shared.config.track_accumulated_noise() {
            return Err(Error::NotTracked {
                what: "accumulated process noise (the square-root filter's joint check)",
                hint: "FilterConfig::builder().track_accumulated_noise(true)",
            });
        }
        check_joint_factor(
            self.shared.accumulated.noise(),
            cross,
            &self.measurement_noise,
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
        check_finite(measurement.as_slice(), "measurement")?;
        let window_model = match source {
            CrossSource::Windowed(w) => Some(w),
            CrossSource::OneStep(_) => None,
        };
        let windowed = window_model.map(|w| w.window_steps());
        let x = *self.estimate.state();
        let h = &self.observation;
        let mut report = UpdateReport::blank();
        let certificate = self.shared.cross_terms(
            source,
            &self.estimate,
            &x,
            measurement,
            h,
            &self.measurement_noise,
            Some(self.measurement_certificate),
            &mut report,
        )?;
        if windowed.is_none() {
            self.check_one_step_cross(&report.cross_covariance)?;
        }
        report.innovation = measurement - mul_static(h, &x) - report.noise_mean;
        let update = |factor: &SMatrix<T, N, N>| {
            square_root_update(
                &x,
                factor,
                &report.innovation,
                h,
                &report.noise_covariance,
                &report.cross_covariance,
            )
        };
        let outcome = update(&self.factor)?;
        let innovation_covariance = gram_lower(&outcome.innovation_factor);
        // H P H', for the NIS under P -> lambda P (as the KalmanFilter's recovery).
        let hph = symmetrize(&mul_static(
            &mul_static(h, self.estimate.covariance()),
            &h.transpose(),
        ));
        let innovation = report.innovation;
        let (threshold, verdict) = self.shared.gate::<M>(outcome.nis, |threshold| {
            bisect_inflation(threshold, |lambda| {
                let s = innovation_covariance + hph * (lambda - T::one());
                let inverse = spd_inverse(&s)?;
                Some(innovation.dot(&mul_static(&inverse, &innovation)))
            })
        })?;
        let accepted = match verdict {
            GateVerdict::Reject => None,
            GateVerdict::Pass => Some(outcome.clone()),
            GateVerdict::Inflate(lambda) => Some(update(&(self.factor * lambda.sqrt()))?),
        };
        report.innovation_covariance = innovation_covariance;
        report.nis = outcome.nis;
        // ln det S = 2 sum ln diag(S_nu) from the triangular factor S_nu S_nu' = S,
        // whose diagonal `square_root_update` checked positive.
        let log_det = (0..M).fold(T::zero(), |sum, j| {
            sum + outcome.innovation_factor[(j, j)].ln()
        }) * lit::<T>(2.0);
        report.log_likelihood = innovation_log_likelihood::<T, M>(log_det, outcome.nis);
        report.gate_threshold = threshold;
        verdict.record(&mut report.status, &mut report.covariance_inflation);
        let mut attempt = Attempt {
            posterior: None,
            innovation_inverse: None,
            noise_certificate: certificate,
        };
        if let Some(used) = accepted.as_ref() {
            report.gain = Some(used.gain);
            report.correction = Some(used.state - x);
            attempt.posterior = Some(used.state);
            if self.shared.history.is_enabled() {
                let s = gram_lower(&used.innovation_factor);
                attempt.innovation_inverse =
                    Some(spd_inverse(&s).ok_or(Error::InnovationNotPositiveDefinite)?);
            }
        }
        self.shared.prepare_window(window_model, &report);
        self.shared.record_update(&attempt, &report, h, None);
        let prior = match accepted {
            Some(used) => {
                self.factor = used.factor;
                let posterior =
                    StateAndCovariance::new_unchecked(used.state, gram_lower(&used.factor));
                Some(std::mem::replace(&mut self.estimate, posterior))
            }
            None => None,
        };
        let prior_covariance = prior
            .as_ref()
            .map_or(self.estimate.covariance(), |p| p.covariance());
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
        /// [`SquareRootKalmanFilter::step`] in a loop, bit for bit: the filter advances and
        /// its observer sees every event. Shape and time index as
        /// [`KalmanFilter::filter_batch`] (this filter's predict takes no argument either):
        /// entry k - 1 is step k, which predicts first.
        ///
        /// # Errors
        /// Those of [`SquareRootKalmanFilter::step`]; the steps before the failing one stay
        /// committed (as in a loop).
        filter_batch;
        /// Smooth `measurements` (shape as [`SquareRootKalmanFilter::filter_batch`]): every
        /// estimate from x_0 (the current one) to the last step given every measurement of
        /// the batch, by a forward pass on a copy of this filter recorded at every step
        /// ([`crate::smoother::ForwardRecorder`] with
        /// [`crate::smoother::RecordAt::EveryStep`]; the events carry F, H, the gain and
        /// S = S_nu S_nu') and its fixed-interval smoothing, in covariance form (the
        /// backward pass is not a square-root one). This filter and its observer are left
        /// untouched.
        ///
        /// # Errors
        /// As [`KalmanFilter::smooth_batch`], with the errors of
        /// [`SquareRootKalmanFilter::step`].
        smooth_batch;
    }

    update_methods! {
        state: SVector<T, N>,
        input: (),
        model: [],
        size: [],
        predict: [],
        /// Update with measurement y and the one-step cross-covariance model `cross`
        /// (array algorithm, see the struct docs for the joint-covariance rule).
        ///
        /// # Errors
        /// [`Error::InvalidJointCovariance`] if [[Q_acc, M], [M', R]] has no square
        /// root; those of [`square_root_update`], of the cross-covariance model and of
        /// the observer; as [`KalmanFilter::update`] otherwise. Nothing changes on an
        /// error other than the observer's.
        update;
        /// Update with measurement y whose noise shares the process noise of a window of
        /// recorded steps: exact M, Var(v | ...) and E[v | ...] (see [`crate::window`]),
        /// in the array algorithm.
        ///
        /// # Errors
        /// As [`KalmanFilter::update_windowed`]; [`Error::InvalidJointCovariance`] if
        /// [[P, M], [M', Var(v)]] has no square root.
        update_windowed;
        /// One time step: predict, then update if a measurement is present.
        ///
        /// # Errors
        /// Those of [`SquareRootKalmanFilter::predict`] and
        /// [`SquareRootKalmanFilter::update`].
        step;
        /// Update with measurement y whose noise is uncorrelated with the process
        /// noise (M = 0): [`SquareRootKalmanFilter::update`] with [`crate::Zero`].
        ///
        /// # Errors
        /// As [`SquareRootKalmanFilter::update`].
        update_uncorrelated;
    }
}
