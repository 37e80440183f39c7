//! The core every runner shares: process-noise accumulation, the recorded window,
//! the update attempt (cross terms, joint check, gate and its recovery, the
//! correlated update), its recording and the observer events.

use nalgebra::{SMatrix, SVector};

use super::UpdateReport;
use crate::config::{GateRecovery, JointCheck};
use crate::cross::{joint_tolerance, joint_validity_margin_reusing};
use crate::gaussian::{all_zero, check_finite, symmetrize};
use crate::linalg::{mul_static, spd_inverse};
use crate::observer::{NoObserver, Observer, PredictEvent, UpdateEvent, UpdateStatus};
use crate::scalar::lit;
use crate::update::{
    factor_innovation, finish_update_into, innovation_log_likelihood, FactoredInnovation,
};
use crate::window::{exact_terms, History};
use crate::{
    CrossCovariance, CrossCovarianceContext, Error, FilterConfig, Result, Scalar,
    StateAndCovariance, WindowedCrossCovariance,
};

/// Process noise and transition accumulated since the last measurement:
/// Q_acc <- Phi Q_acc Phi' + Q_d and Phi_acc <- Phi Phi_acc.
///
/// The first propagation after a measurement copies (no product), so a filter that
/// updates after every prediction pays nothing for the accumulation; for a linear
/// filter (F and Q fixed) not even the copy when the last interval was one step too.
///
/// A reset writes nothing: with no propagation since the last measurement the sums
/// read as their origins 0 and I (kept once), and the next push overwrites them.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Accumulator<T: Scalar, const N: usize> {
    noise: SMatrix<T, N, N>,
    transition: SMatrix<T, N, N>,
    pub(super) steps: usize,
    /// Whether `noise` and `transition` hold a sum since the last reset.
    filled: bool,
    /// Whether `noise` and `transition` hold the one step of a fixed model (the
    /// linear filter's F and Q never change), so that the next first push of that
    /// model finds them in place and copies nothing.
    first_is_fixed: bool,
    /// (0, I): Q_acc and Phi_acc while nothing is filled.
    origin: (SMatrix<T, N, N>, SMatrix<T, N, N>),
}

impl<T: Scalar, const N: usize> Accumulator<T, N> {
    #[inline]
    pub(super) fn new() -> Self {
        Self {
            noise: SMatrix::zeros(),
            transition: SMatrix::identity(),
            steps: 0,
            filled: false,
            first_is_fixed: false,
            origin: (SMatrix::zeros(), SMatrix::identity()),
        }
    }

    /// Q_acc.
    #[inline(always)]
    pub(super) fn noise(&self) -> &SMatrix<T, N, N> {
        if !self.filled {
            &self.origin.0
        } else {
            &self.noise
        }
    }

    /// Phi_acc.
    #[inline(always)]
    pub(super) fn transition(&self) -> &SMatrix<T, N, N> {
        if !self.filled {
            &self.origin.1
        } else {
            &self.transition
        }
    }

    /// Add one propagation; `propagate` is the model's covariance propagation and
    /// `compose` its product of transitions (the same structure as P's, so a sparse
    /// override speeds up both). `fixed`: the caller's transition and noise are the
    /// same on every call (a linear filter's).
    #[inline]
    pub(super) fn push(
        &mut self,
        fixed: bool,
        transition: &SMatrix<T, N, N>,
        process_noise: &SMatrix<T, N, N>,
        propagate: impl FnOnce(
            &SMatrix<T, N, N>,
            &SMatrix<T, N, N>,
            &SMatrix<T, N, N>,
        ) -> SMatrix<T, N, N>,
        compose: impl FnOnce(&SMatrix<T, N, N>, &SMatrix<T, N, N>) -> SMatrix<T, N, N>,
    ) {
        if !self.filled {
            if !(fixed && self.first_is_fixed) {
                self.noise = *process_noise;
                self.transition = *transition;
            }
            self.first_is_fixed = fixed;
        } else {
            self.noise = propagate(&self.noise, transition, process_noise);
            self.transition = compose(transition, &self.transition);
            self.first_is_fixed = false;
        }
        self.steps += 1;
        self.filled = true;
    }

    #[inline]
    pub(super) fn reset(&mut self) {
        self.steps = 0;
        self.filled = false;
    }
}

/// F P F' + Q for a symmetric P and Q, as two products (`crate::linalg::fused_product`:
/// the fused AVX-512 loop for 8 or more states where the CPU has it, else static loops in
/// column (axpy) order, which vectorise and carry no long dependency chain); then the upper
/// triangle, plus Q's triangles averaged (as by `symmetrize`), mirrored so the
/// result is exactly symmetric. (An upper-triangle-only (F P) F', same values,
/// measured slower at (4,2), (15,3) and (30,6): its inner loops have a variable
/// length.)
#[inline(always)]
pub(super) fn propagate_symmetric<T: Scalar, const N: usize>(
    transition: &SMatrix<T, N, N>,
    covariance: &SMatrix<T, N, N>,
    process_noise: &SMatrix<T, N, N>,
) -> SMatrix<T, N, N> {
    let mut work = SMatrix::zeros();
    let mut out = SMatrix::zeros();
    propagate_symmetric_into(transition, covariance, process_noise, &mut work, &mut out);
    out
}

/// [`propagate_symmetric`] written into `out` (every entry), with F P in `work`:
/// buffers the caller keeps, so that nothing is zeroed or copied on the way (at
/// N = 15 the zeroing and the copies of the returned matrices were a third of the
/// time of the products).
#[inline(always)]
pub(super) fn propagate_symmetric_into<T: Scalar, const N: usize>(
    transition: &SMatrix<T, N, N>,
    covariance: &SMatrix<T, N, N>,
    process_noise: &SMatrix<T, N, N>,
    work: &mut SMatrix<T, N, N>,
    out: &mut SMatrix<T, N, N>,
) {
    crate::linalg::product_into(transition, covariance, work);
    crate::linalg::product_transposed_into(work, transition, out);
    let half = lit::<T>(0.5);
    for j in 0..N {
        for i in 0..=j {
            let v = out[(i, j)] + (process_noise[(i, j)] + process_noise[(j, i)]) * half;
            out[(i, j)] = v;
            out[(j, i)] = v;
        }
    }
}

#[inline]
pub(super) fn check_dt<T: Scalar>(dt: T) -> Result<()> {
    if dt.is_finite() && dt > T::zero() {
        Ok(())
    } else {
        Err(Error::InvalidParameter {
            name: "dt",
            reason: format!(
                "{} is not a positive finite time step",
                crate::numeric::to_f64(dt)
            ),
        })
    }
}

/// Where an update's cross-covariance comes from.
pub(super) enum CrossSource<'c, C: ?Sized, W: ?Sized> {
    /// A one-step [`CrossCovariance`] (reads Q_acc, Phi_acc from the context).
    OneStep(&'c C),
    /// An exact [`WindowedCrossCovariance`].
    Windowed(&'c W),
}

/// The update attempt's result before the runner commits it.
pub(super) struct Attempt<T: Scalar, const N: usize, const M: usize> {
    /// The posterior mean when accepted; its covariance is in the runner's buffer.
    pub(super) posterior: Option<SVector<T, N>>,
    /// S^-1 of the accepted update when the history records updates (for
    /// H' S^-1 H and H' S^-1 nu, formed when recorded).
    pub(super) innovation_inverse: Option<SMatrix<T, M, M>>,
    /// Q_acc's block certificate, when an uncorrelated joint check computed it afresh.
    pub(super) noise_certificate: Option<Option<T>>,
}

/// What the innovation gate decided ([`Shared::gate`]).
pub(super) enum GateVerdict<T> {
    /// Within the gate (or no gate).
    Pass,
    /// Rejected: the state stays untouched.
    Reject,
    /// Accepted after inflating the prior covariance by this factor.
    Inflate(T),
}

impl<T: Copy> GateVerdict<T> {
    /// Into a report's `status` and `covariance_inflation`.
    #[inline(always)]
    pub(super) fn record(&self, status: &mut UpdateStatus, inflation: &mut Option<T>) {
        match self {
            GateVerdict::Pass => {}
            GateVerdict::Reject => *status = UpdateStatus::RejectedByGate,
            GateVerdict::Inflate(lambda) => *inflation = Some(*lambda),
        }
    }
}

/// The bookkeeping every runner shares: accumulation, recorded window, configuration,
/// observer. `S` is the state models see, `U` the process input.
#[derive(Debug, Clone)]
pub(super) struct Shared<T: Scalar, S, U, const N: usize, O> {
    pub(super) accumulated: Accumulator<T, N>,
    pub(super) history: History<T, S, U, N>,
    pub(super) config: FilterConfig,
    pub(super) observer: O,
    /// Gate rejections since the last accepted update (for [`GateRecovery`]).
    pub(super) rejections_in_a_row: usize,
    /// The last uncorrelated joint check's certificate of Q_acc's block, with that
    /// Q_acc: reused while Q_acc is the same (a time-invariant model with one predict
    /// per update checks its Q once).
    pub(super) noise_certificate: Option<(SMatrix<T, N, N>, Option<T>)>,
    /// Sum of the accepted updates' `UpdateReport::log_likelihood` since construction.
    pub(super) log_likelihood: T,
    /// D_j of the window of the update being reported, for an observer that wants it
    /// ([`Observer::wants_window`]; allocated on first use).
    pub(super) window_cross: Vec<T>,
    /// (steps, end of its updates in the history, measurement size) of that window.
    pub(super) window_prepared: Option<(usize, usize, usize)>,
}

impl<T: Scalar, S, U, const N: usize> Shared<T, S, U, N, NoObserver> {
    pub(super) fn new() -> Self {
        let config = FilterConfig::default();
        Self {
            accumulated: Accumulator::new(),
            history: History::new(config.window_capacity()),
            config,
            observer: NoObserver,
            rejections_in_a_row: 0,
            noise_certificate: None,
            log_likelihood: T::zero(),
            window_cross: Vec::new(),
            window_prepared: None,
        }
    }
}

impl<T: Scalar, S, U, const N: usize, O> Shared<T, S, U, N, O> {
    /// New configuration; the recorded window restarts with its capacity.
    #[inline]
    pub(super) fn set_config(&mut self, config: FilterConfig) {
        self.history = History::new(config.window_capacity());
        self.config = config;
        self.rejections_in_a_row = 0;
    }

    #[inline]
    pub(super) fn with_observer<O2>(self, observer: O2) -> Shared<T, S, U, N, O2> {
        Shared {
            accumulated: self.accumulated,
            history: self.history,
            config: self.config,
            observer,
            rejections_in_a_row: self.rejections_in_a_row,
            noise_certificate: self.noise_certificate,
            log_likelihood: self.log_likelihood,
            window_cross: self.window_cross,
            window_prepared: None,
        }
    }

    /// Record a committed predict: accumulation (if tracked) and window (if kept).
    /// `fixed`: as for [`Accumulator::push`].
    #[allow(clippy::too_many_arguments)]
    #[inline]
    pub(super) fn record_predict(
        &mut self,
        fixed: bool,
        state_before: &S,
        input: &U,
        dt: Option<T>,
        transition: &SMatrix<T, N, N>,
        process_noise: &SMatrix<T, N, N>,
        propagate: impl FnOnce(
            &SMatrix<T, N, N>,
            &SMatrix<T, N, N>,
            &SMatrix<T, N, N>,
        ) -> SMatrix<T, N, N>,
        compose: impl FnOnce(&SMatrix<T, N, N>, &SMatrix<T, N, N>) -> SMatrix<T, N, N>,
    ) where
        S: Clone,
        U: Clone,
    {
        if self.config.track_accumulated_noise() {
            self.accumulated
                .push(fixed, transition, process_noise, propagate, compose);
        } else {
            self.accumulated.steps += 1;
        }
        self.history
            .push_step(state_before, input, dt, transition, process_noise);
    }

    /// Before an accepted windowed update is recorded: when the observer wants the
    /// window ([`Observer::wants_window`]), collect every step's D_j from `model` for
    /// [`Shared::notify_update`]. A model that fails here leaves the event without its
    /// window (the smoother then reports it); the update itself is not affected.
    pub(super) fn prepare_window<W, const M: usize>(
        &mut self,
        model: Option<&W>,
        report: &UpdateReport<T, N, M>,
    ) where
        O: Observer<T, S, N>,
        W: WindowedCrossCovariance<T, S, U, N, M> + ?Sized,
    {
        self.window_prepared = None;
        let Some(model) = model else {
            return;
        };
        if !report.is_accepted() || !self.observer.wants_window() {
            return;
        }
        let steps = model.window_steps();
        let Shared {
            history,
            window_cross,
            ..
        } = self;
        let Ok(window) = history.window(steps) else {
            return;
        };
        window_cross.clear();
        let collected = model.step_cross_covariances(&window, &mut |d: &SMatrix<T, N, M>| {
            window_cross.extend_from_slice(d.as_slice());
            Ok(())
        });
        if collected.is_ok() && window_cross.len() == steps * N * M {
            self.window_prepared = Some((steps, self.history.recorded_updates(), M));
        }
    }

    /// Cross-covariance, noise covariance, noise mean and joint eigenvalue for an
    /// update, written into `report` (in place: no matrix moves through a return
    /// value); returns Q_acc's block certificate when the joint check computed one.
    /// Fails before anything but `report` is touched.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(super) fn cross_terms<C, W, const M: usize>(
        &self,
        source: CrossSource<'_, C, W>,
        prior: &StateAndCovariance<T, N>,
        state: &S,
        measurement: &SVector<T, M>,
        jacobian: &SMatrix<T, M, N>,
        measurement_noise: &SMatrix<T, M, M>,
        measurement_certificate: Option<Option<T>>,
        report: &mut UpdateReport<T, N, M>,
    ) -> Result<Option<Option<T>>>
    where
        C: CrossCovariance<T, S, N, M> + ?Sized,
        W: WindowedCrossCovariance<T, S, U, N, M> + ?Sized,
    {
        match source {
            CrossSource::OneStep(model) => {
                let tracked = self.config.track_accumulated_noise();
                let context = CrossCovarianceContext {
                    accumulated_process_noise: self.accumulated.noise(),
                    accumulated_transition: self.accumulated.transition(),
                    accumulation_tracked: tracked,
                    measurement_noise,
                    jacobian,
                    measurement,
                    state,
                    covariance: prior.covariance(),
                };
                report.cross_covariance = model.cross_covariance(&context)?;
                let cross = &report.cross_covariance;
                let correlated = !all_zero(cross.as_slice());
                let (joint, certificate) = match self.config.joint_check() {
                    JointCheck::Skip => (None, None),
                    _ if !tracked && correlated => {
                        if self.config.joint_check() == JointCheck::Reject {
                            return Err(Error::NotTracked {
                                what: "accumulated process noise (for the joint check)",
                                hint: "FilterConfig::builder().track_accumulated_noise(true)",
                            });
                        }
                        (None, None)
                    }
                    check => {
                        let noise = self.accumulated.noise();
                        let known = match &self.noise_certificate {
                            Some((checked, certificate))
                                if checked.as_slice() == noise.as_slice() =>
                            {
                                Some(*certificate)
                            }
                            _ => None,
                        };
                        let (margin, certificate) = joint_eigenvalue(
                            check,
                            noise,
                            cross,
                            measurement_noise,
                            known,
                            measurement_certificate,
                        )?;
                        // A reused certificate is already stored with its Q_acc.
                        (Some(margin), certificate.filter(|_| known.is_none()))
                    }
                };
                report.noise_covariance = *measurement_noise;
                report.noise_mean = SVector::zeros();
                report.joint_min_eigenvalue = joint;
                Ok(certificate)
            }
            CrossSource::Windowed(model) => {
                let terms = exact_terms(&self.history, model, measurement_noise)?;
                let joint = match self.config.joint_check() {
                    JointCheck::Skip => None,
                    check => Some(
                        joint_eigenvalue(
                            check,
                            prior.covariance(),
                            &terms.cross,
                            &terms.noise_covariance,
                            None,
                            None,
                        )?
                        .0,
                    ),
                };
                report.cross_covariance = terms.cross;
                report.noise_covariance = terms.noise_covariance;
                report.noise_mean = terms.noise_mean;
                report.joint_min_eigenvalue = joint;
                Ok(None)
            }
        }
    }

    /// The update attempt shared by all runners. Touches nothing but the runner's
    /// posterior buffer `posterior_covariance` (P+ when accepted, unspecified
    /// otherwise): the caller commits.
    /// Inlined, so that the linear runner's AVX2 build (`simd_dispatch!`) covers it
    /// (measured 8 % faster at (15,3) and 13 % at (4,2) than an out-of-line call).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(super) fn attempt<C, W, const M: usize>(
        &self,
        source: CrossSource<'_, C, W>,
        prior: &StateAndCovariance<T, N>,
        state: &S,
        measurement: &SVector<T, M>,
        predicted: SVector<T, M>,
        jacobian: &SMatrix<T, M, N>,
        measurement_noise: &SMatrix<T, M, M>,
        measurement_certificate: Option<Option<T>>,
        posterior_covariance: &mut SMatrix<T, N, N>,
        report: &mut UpdateReport<T, N, M>,
    ) -> Result<Attempt<T, N, M>>
    where
        C: CrossCovariance<T, S, N, M> + ?Sized,
        W: WindowedCrossCovariance<T, S, U, N, M> + ?Sized,
    {
        // H, R, M and P are checked by `factor_innovation` (any NaN reaches S); the
        // measurement is checked here so the error names it.
        check_finite(measurement.as_slice(), "measurement")?;
        check_finite(predicted.as_slice(), "predicted measurement")?;
        let certificate = self.cross_terms(
            source,
            prior,
            state,
            measurement,
            jacobian,
            measurement_noise,
            measurement_certificate,
            report,
        )?;
        report.innovation = measurement - predicted - report.noise_mean;
        let factored = factor_innovation(
            prior,
            &report.innovation,
            jacobian,
            &report.noise_covariance,
            &report.cross_covariance,
        )?;
        report.innovation_covariance = factored.covariance;
        report.nis = factored.nis;
        report.log_likelihood = innovation_log_likelihood::<T, M>(factored.log_det, factored.nis);
        let mut inflated_prior = None;
        let (threshold, verdict) = self.gate::<M>(factored.nis, |threshold| {
            recovery_inflation(&factored, &report.innovation, threshold)
        })?;
        report.gate_threshold = threshold;
        verdict.record(&mut report.status, &mut report.covariance_inflation);
        match verdict {
            GateVerdict::Pass => {}
            GateVerdict::Reject => {
                return Ok(Attempt {
                    posterior: None,
                    innovation_inverse: None,
                    noise_certificate: certificate,
                })
            }
            GateVerdict::Inflate(lambda) => {
                inflated_prior = Some(StateAndCovariance::new_unchecked(
                    *prior.state(),
                    prior.covariance() * lambda,
                ));
            }
        }
        let (prior, factored) = match inflated_prior.as_ref() {
            Some(inflated) => (
                inflated,
                factor_innovation(
                    inflated,
                    &report.innovation,
                    jacobian,
                    &report.noise_covariance,
                    &report.cross_covariance,
                )?,
            ),
            None => (prior, factored),
        };
        let gain = report.gain.insert(SMatrix::zeros());
        let finished = finish_update_into(
            prior,
            &report.innovation,
            &report.cross_covariance,
            self.config.covariance_update(),
            &factored,
            gain,
            posterior_covariance,
        )?;
        report.correction = Some(SVector::from_fn(|i, _| {
            finished.state[i] - prior.state()[i]
        }));
        Ok(Attempt {
            innovation_inverse: self.history.is_enabled().then_some(factored.inverse),
            posterior: Some(finished.state),
            noise_certificate: certificate,
        })
    }

    /// The innovation gate and its recovery on `nis` for a measurement of size `M`:
    /// the gate's threshold and its verdict (`inflation(threshold)`: the factor that
    /// brings the NIS onto the threshold under [`GateRecovery::Inflate`], or `None`).
    /// The caller writes both into its report ([`GateVerdict::record`]).
    #[inline(always)]
    pub(super) fn gate<const M: usize>(
        &self,
        nis: T,
        inflation: impl FnOnce(T) -> Option<T>,
    ) -> Result<(Option<T>, GateVerdict<T>)> {
        let threshold = self.config.gate_threshold(M)?.map(lit::<T>);
        let Some(limit) = threshold else {
            return Ok((None, GateVerdict::Pass));
        };
        if nis <= limit {
            return Ok((threshold, GateVerdict::Pass));
        }
        let lambda = match self.config.gate_recovery() {
            GateRecovery::Inflate { after } if self.rejections_in_a_row >= after => {
                inflation(limit)
            }
            _ => None,
        };
        Ok((
            threshold,
            lambda.map_or(GateVerdict::Reject, GateVerdict::Inflate),
        ))
    }

    /// After the runner committed an attempt: record it for later windows (with the
    /// reset Jacobian J of an error-state filter), add an accepted update's
    /// log-likelihood to the sum, close the accumulation interval.
    #[inline]
    pub(super) fn record_update<const M: usize>(
        &mut self,
        attempt: &Attempt<T, N, M>,
        report: &UpdateReport<T, N, M>,
        jacobian: &SMatrix<T, M, N>,
        reset: Option<&SMatrix<T, N, N>>,
    ) {
        if let (Some(gain), Some(inverse)) =
            (report.gain.as_ref(), attempt.innovation_inverse.as_ref())
        {
            // H' S^-1 H and H' S^-1 nu: what a later windowed update needs of this one.
            let hs = mul_static(&jacobian.transpose(), inverse);
            let information = symmetrize(&mul_static(&hs, jacobian));
            let weighted = mul_static(&hs, &report.innovation);
            let mut transform = SMatrix::<T, N, N>::identity() - mul_static(gain, jacobian);
            if let Some(j) = reset {
                transform = mul_static(j, &transform);
            }
            let correlated = !all_zero(report.cross_covariance.as_slice());
            self.history
                .push_update(transform, information, weighted, correlated);
        }
        if let Some(certificate) = attempt.noise_certificate {
            self.noise_certificate = Some((*self.accumulated.noise(), certificate));
        }
        if report.is_accepted() {
            self.rejections_in_a_row = 0;
            self.log_likelihood += report.log_likelihood;
        } else {
            self.rejections_in_a_row += 1;
        }
        self.accumulated.reset();
    }

    #[inline]
    pub(super) fn notify_predict(
        &mut self,
        dt: Option<T>,
        state: &S,
        covariance: &SMatrix<T, N, N>,
        transition: &SMatrix<T, N, N>,
        process_noise: &SMatrix<T, N, N>,
    ) -> Result<()>
    where
        O: Observer<T, S, N>,
    {
        self.observer.on_predict(&PredictEvent {
            dt,
            state,
            covariance,
            propagations_since_update: self.accumulated.steps,
            transition,
            process_noise,
        })
    }

    #[allow(clippy::too_many_arguments)]
    #[inline]
    pub(super) fn notify_update<const M: usize>(
        &mut self,
        report: &UpdateReport<T, N, M>,
        state: &S,
        covariance: &SMatrix<T, N, N>,
        prior_covariance: &SMatrix<T, N, N>,
        jacobian: &SMatrix<T, M, N>,
        window_steps: Option<usize>,
        reset: Option<&SMatrix<T, N, N>>,
    ) -> Result<()>
    where
        O: Observer<T, S, N>,
    {
        let view = self
            .window_prepared
            .take()
            .and_then(|(steps, end_update, size)| {
                self.history
                    .recorded_window(steps, end_update, &self.window_cross, size)
            });
        let event = UpdateEvent {
            window: view
                .as_ref()
                .map(|v| v as &dyn crate::window::RecordedWindow<T, N>),
            windowed: window_steps.is_some(),
            window_steps,
            reset,
            prior_covariance,
            jacobian: jacobian.as_slice(),
            noise_covariance: report.noise_covariance.as_slice(),
            cross_covariance: report.cross_covariance.as_slice(),
            innovation_covariance: report.innovation_covariance.as_slice(),
            gain: report.gain.as_ref().map(|g| g.as_slice()),
            state,
            covariance,
            innovation: report.innovation.as_slice(),
            measurement_size: M,
            nis: report.nis,
            gate_threshold: report.gate_threshold,
            joint_min_eigenvalue: report.joint_min_eigenvalue,
            covariance_inflation: report.covariance_inflation,
            status: report.status,
        };
        match report.status {
            UpdateStatus::Accepted => self.observer.on_update(&event),
            UpdateStatus::RejectedByGate => self.observer.on_rejected(&event),
        }
    }
}

/// The smallest lambda in [1, [`GateRecovery::MAX_INFLATION`]] with
/// nu' (S + (lambda - 1) H P H')^-1 nu <= `threshold` (S = H P H' + H M + M' H' + R,
/// so the bracket is S with P -> lambda P), or `None` when even the largest factor
/// leaves the NIS above the threshold. The NIS is non-increasing in lambda (H P H' is
/// positive semidefinite), so bisection on log lambda brackets the boundary; the upper
/// end of the final bracket is returned, so the inflated update passes the gate.
#[inline]
pub(super) fn recovery_inflation<T: Scalar, const N: usize, const M: usize>(
    factored: &FactoredInnovation<'_, T, N, M>,
    innovation: &SVector<T, M>,
    threshold: T,
) -> Option<T> {
    let hph = symmetrize(&mul_static(factored.jacobian, &factored.pht));
    bisect_inflation(threshold, |lambda| {
        let s = factored.covariance + hph * (lambda - T::one());
        let inverse = spd_inverse(&s)?;
        Some(innovation.dot(&mul_static(&inverse, innovation)))
    })
}

/// The smallest lambda in [1, [`GateRecovery::MAX_INFLATION`]] with
/// `nis(lambda)` <= `threshold`, by bisection on log lambda, for a NIS non-increasing
/// in lambda; `None` when even the largest factor leaves it above. The upper end of
/// the final bracket is returned, so the inflated update passes the gate whatever
/// `nis` is (for a NIS that is not monotone, a factor that passes, not necessarily the
/// smallest).
#[inline]
pub(super) fn bisect_inflation<T: Scalar>(threshold: T, nis: impl Fn(T) -> Option<T>) -> Option<T> {
    let mut low = T::one();
    let mut high = lit::<T>(GateRecovery::MAX_INFLATION);
    if nis(high)? > threshold {
        return None;
    }
    // 64 halvings of the log-bracket (width ln 1e6 = 13.8) leave it below 1e-18:
    // the returned factor is the boundary to the scalar's precision.
    for _ in 0..64 {
        let middle = (low * high).sqrt();
        if middle <= low || middle >= high {
            break;
        }
        match nis(middle) {
            Some(v) if v <= threshold => high = middle,
            _ => low = middle,
        }
    }
    Some(high)
}

/// The joint check of `config` on [[A, M], [M', B]], given A's and B's block
/// certificates when known; also returns A's block certificate when it was computed or
/// used (M = 0).
#[inline(always)]
pub(super) fn joint_eigenvalue<T: Scalar, const N: usize, const M: usize>(
    check: JointCheck,
    a: &SMatrix<T, N, N>,
    cross: &SMatrix<T, N, M>,
    b: &SMatrix<T, M, M>,
    known: Option<Option<T>>,
    known_b: Option<Option<T>>,
) -> Result<(T, Option<Option<T>>)> {
    // Certified without allocation when valid (smallest LDL' pivot, clamped to
    // [0, 1]); the smallest eigenvalue of the correlation matrix when invalid.
    let (margin, certificate) = joint_validity_margin_reusing(a, cross, b, known, known_b)?;
    if check == JointCheck::Reject && margin < -joint_tolerance::<T>() {
        // As check_joint_covariance.
        return Err(Error::InvalidJointCovariance {
            min_eigenvalue: crate::scalar::to_f64(margin),
        });
    }
    Ok((margin, certificate))
}
