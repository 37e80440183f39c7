//! The three runners (linear KF, EKF, error-state EKF), all built on the one
//! [`crate::correlated_update`]. What they share lives in one place, [`Shared`]:
//! process-noise accumulation (one-step cross-covariances), the window of recorded
//! steps and updates (exact windowed cross-covariances, see [`crate::window`]), the
//! configuration, the innovation gate, the joint-covariance policy and the observer.
//!
//! Commit rule, the same for every runner: a predict or an update either fails with
//! an error before touching anything, or commits its result (state, covariance,
//! accumulators, recorded history) and *then* notifies the observer. If the observer
//! returns an error, that error is returned and the committed result stays.

use nalgebra::{SMatrix, SVector};

use crate::config::{GateRecovery, JointCheck};
use crate::cross::{joint_tolerance, joint_validity_margin_reusing};
use crate::gaussian::{all_zero, check_finite, check_symmetric, symmetrize};
use crate::observer::{NoObserver, Observer, PredictEvent, UpdateEvent, UpdateStatus};
use crate::scalar::lit;
use crate::update::{
    factor_innovation, finish_update_into, mul_static, spd_inverse, FactoredInnovation,
};
use crate::window::{exact_terms, History};
use crate::{
    CrossCovariance, CrossCovarianceContext, Error, ErrorStateModel, FilterConfig,
    MeasurementModel, ProcessModel, Result, Scalar, StateAndCovariance, WindowedCrossCovariance,
};

/// Everything one update attempt produced, accepted or rejected.
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[derive(Debug, Clone, PartialEq)]
pub struct UpdateReport<T: Scalar, const N: usize, const M: usize> {
    /// Accepted, or rejected by the innovation gate (state untouched).
    pub status: UpdateStatus,
    /// Innovation y - h(x) - E\[v\] (E\[v\] = [`UpdateReport::noise_mean`], zero unless
    /// other updates inside a windowed measurement's window observed part of v).
    pub innovation: SVector<T, M>,
    /// Innovation covariance S = H P H' + H M + M' H' + R.
    pub innovation_covariance: SMatrix<T, M, M>,
    /// Normalised innovation squared, innovation' S^-1 innovation.
    pub nis: T,
    /// The gate's NIS threshold for this measurement size, if a gate is configured.
    pub gate_threshold: Option<T>,
    /// The cross-covariance M_k used (from the [`CrossCovariance`], or the exact
    /// windowed one).
    pub cross_covariance: SMatrix<T, N, M>,
    /// The measurement-noise covariance used: R, or for a windowed update
    /// Var(v | other updates in the window) <= R.
    pub noise_covariance: SMatrix<T, M, M>,
    /// The measurement-noise mean used: zero, or for a windowed update
    /// E[v | other updates in the window].
    pub noise_mean: SVector<T, M>,
    /// Validity margin of the joint covariance, dimensionless, valid iff >= 0 (see
    /// [`crate::joint_validity_margin`]: for a valid joint covariance the smallest
    /// pivot of a static LDL' of its correlation matrix, clamped to [0, 1]; for an
    /// invalid one the smallest eigenvalue of that matrix): [[Q_acc, M], [M', R]] for a
    /// one-step update, [[P, M], [M', Var(v)]] (the covariance of the error state
    /// augmented with v) for a windowed one. `None` with [`JointCheck::Skip`], or when
    /// a one-step update has M != 0 but Q_acc is not tracked.
    pub joint_min_eigenvalue: Option<T>,
    /// The factor lambda >= 1 the prior covariance was inflated by before this update,
    /// which the gate would otherwise have rejected ([`GateRecovery::Inflate`] after a
    /// run of rejections); `None` for an ordinary update or a rejection. `nis` and
    /// `innovation_covariance` are those the gate saw, before the inflation.
    pub covariance_inflation: Option<T>,
    /// The gain K (`None` if rejected).
    pub gain: Option<SMatrix<T, N, M>>,
    /// The state correction K * innovation (`None` if rejected); for the error-state
    /// filter this is the error injected into the nominal state.
    pub correction: Option<SVector<T, N>>,
}

impl<T: Scalar, const N: usize, const M: usize> UpdateReport<T, N, M> {
    /// An accepted report of zeros, for an update attempt to fill in place.
    fn blank() -> Self {
        Self {
            status: UpdateStatus::Accepted,
            innovation: SVector::zeros(),
            innovation_covariance: SMatrix::zeros(),
            nis: T::zero(),
            gate_threshold: None,
            cross_covariance: SMatrix::zeros(),
            noise_covariance: SMatrix::zeros(),
            noise_mean: SVector::zeros(),
            joint_min_eigenvalue: None,
            covariance_inflation: None,
            gain: None,
            correction: None,
        }
    }

    /// Whether the posterior replaced the prior.
    pub fn is_accepted(&self) -> bool {
        self.status == UpdateStatus::Accepted
    }
}

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
struct Accumulator<T: Scalar, const N: usize> {
    noise: SMatrix<T, N, N>,
    transition: SMatrix<T, N, N>,
    steps: usize,
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
    fn new() -> Self {
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
    fn noise(&self) -> &SMatrix<T, N, N> {
        if !self.filled {
            &self.origin.0
        } else {
            &self.noise
        }
    }

    /// Phi_acc.
    #[inline(always)]
    fn transition(&self) -> &SMatrix<T, N, N> {
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
    fn push(
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

    fn reset(&mut self) {
        self.steps = 0;
        self.filled = false;
    }
}

/// F P F' + Q for a symmetric P and Q, as two products (`crate::kernel`: the fused
/// AVX-512 kernel for 8 or more states where the CPU has it, else static loops in
/// column (axpy) order, which vectorise and carry no long dependency chain); then the upper
/// triangle, plus Q's triangles averaged (as by `symmetrize`), mirrored so the
/// result is exactly symmetric. (An upper-triangle-only (F P) F', same values,
/// measured slower at (4,2), (15,3) and (30,6): its inner loops have a variable
/// length.)
#[inline(always)]
fn propagate_symmetric<T: Scalar, const N: usize>(
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
fn propagate_symmetric_into<T: Scalar, const N: usize>(
    transition: &SMatrix<T, N, N>,
    covariance: &SMatrix<T, N, N>,
    process_noise: &SMatrix<T, N, N>,
    work: &mut SMatrix<T, N, N>,
    out: &mut SMatrix<T, N, N>,
) {
    crate::kernel::product_into(transition, covariance, work);
    crate::kernel::product_transposed_into(work, transition, out);
    let half = lit::<T>(0.5);
    for j in 0..N {
        for i in 0..=j {
            let v = out[(i, j)] + (process_noise[(i, j)] + process_noise[(j, i)]) * half;
            out[(i, j)] = v;
            out[(j, i)] = v;
        }
    }
}

fn check_dt<T: Scalar>(dt: T) -> Result<()> {
    if dt.is_finite() && dt > T::zero() {
        Ok(())
    } else {
        Err(Error::InvalidParameter {
            name: "dt",
            reason: format!("{} is not a positive finite time step", crate::to_f64(dt)),
        })
    }
}

/// `$this.$body`, run through its copy `$avx2` compiled for AVX2 when the CPU has it
/// (4 lanes instead of SSE2's 2). No FMA in this build itself: its loops do the same
/// separately rounded multiply and add as the portable build. The large dense
/// products (N >= 8) go through [`crate::kernel`], which fuses them on AVX-512 CPUs:
/// there the results differ from the portable build's by round-off. (An AVX-512 copy
/// of the whole runner measured no faster at (15,3) and 10 % slower at (4,2).)
macro_rules! simd_dispatch {
    ($this:ident . $body:ident ( $($arg:expr),* ) via $avx2:ident) => {{
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: a `target_feature` function only requires that the CPU has
                // the feature, checked on the line above.
                return unsafe { $this.$avx2($($arg),*) };
            }
        }
        $this.$body($($arg),*)
    }};
}

/// Where an update's cross-covariance comes from.
enum CrossSource<'c, C: ?Sized, W: ?Sized> {
    /// A one-step [`CrossCovariance`] (reads Q_acc, Phi_acc from the context).
    OneStep(&'c C),
    /// An exact [`WindowedCrossCovariance`].
    Windowed(&'c W),
}

/// The update attempt's result before the runner commits it.
struct Attempt<T: Scalar, const N: usize, const M: usize> {
    /// The posterior mean when accepted; its covariance is in the runner's buffer.
    posterior: Option<SVector<T, N>>,
    /// S^-1 of the accepted update when the history records updates (for
    /// H' S^-1 H and H' S^-1 nu, formed when recorded).
    innovation_inverse: Option<SMatrix<T, M, M>>,
    /// Q_acc's block certificate, when an uncorrelated joint check computed it afresh.
    noise_certificate: Option<Option<T>>,
}

/// The bookkeeping every runner shares: accumulation, recorded window, configuration,
/// observer. `S` is the state models see, `U` the process input.
#[derive(Debug, Clone)]
struct Shared<T: Scalar, S, U, const N: usize, O> {
    accumulated: Accumulator<T, N>,
    history: History<T, S, U, N>,
    config: FilterConfig,
    observer: O,
    /// Gate rejections since the last accepted update (for [`GateRecovery`]).
    rejections_in_a_row: usize,
    /// The last uncorrelated joint check's certificate of Q_acc's block, with that
    /// Q_acc: reused while Q_acc is the same (a time-invariant model with one predict
    /// per update checks its Q once).
    noise_certificate: Option<(SMatrix<T, N, N>, Option<T>)>,
}

impl<T: Scalar, S, U, const N: usize> Shared<T, S, U, N, NoObserver> {
    fn new() -> Self {
        let config = FilterConfig::default();
        Self {
            accumulated: Accumulator::new(),
            history: History::new(config.window_capacity()),
            config,
            observer: NoObserver,
            rejections_in_a_row: 0,
            noise_certificate: None,
        }
    }
}

impl<T: Scalar, S, U, const N: usize, O> Shared<T, S, U, N, O> {
    /// New configuration; the recorded window restarts with its capacity.
    fn set_config(&mut self, config: FilterConfig) {
        self.history = History::new(config.window_capacity());
        self.config = config;
        self.rejections_in_a_row = 0;
    }

    fn with_observer<O2>(self, observer: O2) -> Shared<T, S, U, N, O2> {
        Shared {
            accumulated: self.accumulated,
            history: self.history,
            config: self.config,
            observer,
            rejections_in_a_row: self.rejections_in_a_row,
            noise_certificate: self.noise_certificate,
        }
    }

    /// Record a committed predict: accumulation (if tracked) and window (if kept).
    /// `fixed`: as for [`Accumulator::push`].
    #[allow(clippy::too_many_arguments)]
    fn record_predict(
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
        self.history.push_step(state_before, input, dt, transition);
    }

    /// Cross-covariance, noise covariance, noise mean and joint eigenvalue for an
    /// update, written into `report` (in place: no matrix moves through a return
    /// value); returns Q_acc's block certificate when the joint check computed one.
    /// Fails before anything but `report` is touched.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn cross_terms<C, W, const M: usize>(
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
    fn attempt<C, W, const M: usize>(
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
        report.gate_threshold = self.config.gate_threshold(M)?.map(lit::<T>);
        report.innovation_covariance = factored.covariance;
        report.nis = factored.nis;
        let mut inflated_prior = None;
        if let Some(threshold) = report.gate_threshold {
            if factored.nis > threshold {
                let inflation = match self.config.gate_recovery() {
                    GateRecovery::Inflate { after } if self.rejections_in_a_row >= after => {
                        recovery_inflation(&factored, &report.innovation, threshold)
                    }
                    _ => None,
                };
                let Some(lambda) = inflation else {
                    report.status = UpdateStatus::RejectedByGate;
                    return Ok(Attempt {
                        posterior: None,
                        innovation_inverse: None,
                        noise_certificate: certificate,
                    });
                };
                report.covariance_inflation = Some(lambda);
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

    /// After the runner committed an attempt: record it for later windows (with the
    /// reset Jacobian J of an error-state filter), close the accumulation interval.
    fn record_update<const M: usize>(
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
        } else {
            self.rejections_in_a_row += 1;
        }
        self.accumulated.reset();
    }

    fn notify_predict(
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
    fn notify_update<const M: usize>(
        &mut self,
        report: &UpdateReport<T, N, M>,
        state: &S,
        covariance: &SMatrix<T, N, N>,
        prior_covariance: &SMatrix<T, N, N>,
        jacobian: &SMatrix<T, M, N>,
        windowed: bool,
        reset: Option<&SMatrix<T, N, N>>,
    ) -> Result<()>
    where
        O: Observer<T, S, N>,
    {
        let event = UpdateEvent {
            windowed,
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
fn recovery_inflation<T: Scalar, const N: usize, const M: usize>(
    factored: &FactoredInnovation<'_, T, N, M>,
    innovation: &SVector<T, M>,
    threshold: T,
) -> Option<T> {
    let hph = symmetrize(&mul_static(factored.jacobian, &factored.pht));
    let nis = |lambda: T| -> Option<T> {
        let s = factored.covariance + hph * (lambda - T::one());
        let inverse = spd_inverse(&s)?;
        Some(innovation.dot(&mul_static(&inverse, innovation)))
    };
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
fn joint_eigenvalue<T: Scalar, const N: usize, const M: usize>(
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

/// The accessors every runner has, over its `shared` field (one definition).
macro_rules! shared_accessors {
    () => {
        /// The configuration.
        pub fn config(&self) -> &FilterConfig {
            &self.shared.config
        }

        /// Q_acc since the last measurement (zero when not tracked, see
        /// [`FilterConfig::track_accumulated_noise`]).
        pub fn accumulated_process_noise(&self) -> &SMatrix<T, N, N> {
            self.shared.accumulated.noise()
        }

        /// Phi_acc since the last measurement (identity when not tracked).
        pub fn accumulated_transition(&self) -> &SMatrix<T, N, N> {
            self.shared.accumulated.transition()
        }

        /// Propagations since the last measurement.
        pub fn propagations_since_update(&self) -> usize {
            self.shared.accumulated.steps
        }

        /// Process steps currently recorded for windowed cross-covariances (at most
        /// [`FilterConfig::window_capacity`]).
        pub fn recorded_steps(&self) -> usize {
            self.shared.history.len()
        }

        /// The observer.
        pub fn observer(&self) -> &O {
            &self.shared.observer
        }

        /// The observer, mutably.
        pub fn observer_mut(&mut self) -> &mut O {
            &mut self.shared.observer
        }

        /// Consume the filter, keeping the observer (e.g. to read what it recorded).
        pub fn into_observer(self) -> O {
            self.shared.observer
        }

        /// Replace the configuration. The recorded window (if any) restarts empty
        /// with the new capacity; Q_acc is kept.
        #[must_use]
        pub fn with_config(mut self, config: FilterConfig) -> Self {
            self.shared.set_config(config);
            self
        }
    };
}

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
    /// [`Error::NonFinite`] or [`Error::InvalidCovariance`] (Q or R not symmetric).
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
        check_symmetric(&process_noise, "process noise covariance")?;
        check_symmetric(&measurement_noise, "measurement noise covariance")?;
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
    /// through the fused AVX-512 product kernel on CPUs that have it (same values to
    /// round-off).
    ///
    /// # Errors
    /// [`Error::NonFinite`] if the prediction overflows; observer errors.
    pub fn predict(&mut self) -> Result<()> {
        simd_dispatch!(self.predict_body() via predict_avx2)
    }

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
            |later, earlier| crate::kernel::product(later, earlier),
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

    /// Update with measurement y and the one-step cross-covariance model `cross`.
    ///
    /// # Errors
    /// Those of [`crate::correlated_update`], [`Error::InvalidJointCovariance`] under
    /// [`JointCheck::Reject`], the cross-covariance model's and the observer's.
    pub fn update<C>(
        &mut self,
        measurement: &SVector<T, M>,
        cross: &C,
    ) -> Result<UpdateReport<T, N, M>>
    where
        C: CrossCovariance<T, SVector<T, N>, N, M> + ?Sized,
    {
        self.update_from::<C, dyn WindowedCrossCovariance<T, SVector<T, N>, (), N, M>>(
            measurement,
            CrossSource::OneStep(cross),
        )
    }

    /// Update with measurement y whose noise shares the process noise of a window of
    /// recorded steps: exact M, Var(v | ...) and E[v | ...] (see [`crate::window`]).
    ///
    /// # Errors
    /// As [`KalmanFilter::update`], plus [`Error::NotTracked`] (no window kept),
    /// [`Error::WindowUnavailable`], [`Error::ColouredMeasurementNoise`].
    pub fn update_windowed<W>(
        &mut self,
        measurement: &SVector<T, M>,
        cross: &W,
    ) -> Result<UpdateReport<T, N, M>>
    where
        W: WindowedCrossCovariance<T, SVector<T, N>, (), N, M> + ?Sized,
    {
        self.update_from::<crate::Zero, W>(measurement, CrossSource::Windowed(cross))
    }

    /// One time step: predict, then update if a measurement is present.
    ///
    /// # Errors
    /// Those of [`KalmanFilter::predict`] and [`KalmanFilter::update`].
    pub fn step<C>(
        &mut self,
        measurement: Option<&SVector<T, M>>,
        cross: &C,
    ) -> Result<Option<UpdateReport<T, N, M>>>
    where
        C: CrossCovariance<T, SVector<T, N>, N, M> + ?Sized,
    {
        self.predict()?;
        measurement.map(|y| self.update(y, cross)).transpose()
    }
}

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
    shared_accessors!();

    /// The last `steps` recorded process steps (states before propagation, inputs,
    /// dt, transitions), e.g. to build a learned measurement's input window from the
    /// samples the filter itself consumed (the runner is the ring buffer of its
    /// input stream).
    ///
    /// # Errors
    /// [`Error::WindowUnavailable`] if fewer steps are recorded (or `steps` is 0).
    pub fn step_window(
        &self,
        steps: usize,
    ) -> Result<crate::StepWindow<'_, T, SVector<T, N>, P::Input, N>> {
        self.shared.history.window(steps)
    }

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
        let windowed = matches!(source, CrossSource::Windowed(_));
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

    /// Update with `model`, measurement y and the one-step cross-covariance `cross`.
    ///
    /// # Errors
    /// As [`KalmanFilter::update`], plus the measurement model's errors.
    pub fn update<Mm, C, const M: usize>(
        &mut self,
        model: &Mm,
        measurement: &SVector<T, M>,
        cross: &C,
    ) -> Result<UpdateReport<T, N, M>>
    where
        Mm: MeasurementModel<T, N, M, State = SVector<T, N>> + ?Sized,
        C: CrossCovariance<T, SVector<T, N>, N, M> + ?Sized,
    {
        self.update_from::<Mm, C, dyn WindowedCrossCovariance<T, SVector<T, N>, P::Input, N, M>, M>(
            model,
            measurement,
            CrossSource::OneStep(cross),
        )
    }

    /// Update with a measurement whose noise shares a window of recorded process
    /// steps: exact M, Var(v | ...) and E[v | ...] (see [`crate::window`]).
    ///
    /// # Errors
    /// As [`KalmanFilter::update_windowed`], plus the measurement model's errors.
    pub fn update_windowed<Mm, W, const M: usize>(
        &mut self,
        model: &Mm,
        measurement: &SVector<T, M>,
        cross: &W,
    ) -> Result<UpdateReport<T, N, M>>
    where
        Mm: MeasurementModel<T, N, M, State = SVector<T, N>> + ?Sized,
        W: WindowedCrossCovariance<T, SVector<T, N>, P::Input, N, M> + ?Sized,
    {
        self.update_from::<Mm, crate::Zero, W, M>(model, measurement, CrossSource::Windowed(cross))
    }

    /// One time step: predict over `dt`, then update if a measurement is present.
    ///
    /// # Errors
    /// Those of [`ExtendedKalmanFilter::predict`] and [`ExtendedKalmanFilter::update`].
    pub fn step<Mm, C, const M: usize>(
        &mut self,
        input: &P::Input,
        dt: T,
        model: &Mm,
        measurement: Option<&SVector<T, M>>,
        cross: &C,
    ) -> Result<Option<UpdateReport<T, N, M>>>
    where
        Mm: MeasurementModel<T, N, M, State = SVector<T, N>> + ?Sized,
        C: CrossCovariance<T, SVector<T, N>, N, M> + ?Sized,
    {
        self.predict(input, dt)?;
        measurement
            .map(|y| self.update(model, y, cross))
            .transpose()
    }
}

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
    shared_accessors!();

    /// The last `steps` recorded process steps (states before propagation, inputs,
    /// dt, transitions), e.g. to build a learned measurement's input window from the
    /// samples the filter itself consumed (the runner is the ring buffer of its
    /// input stream).
    ///
    /// # Errors
    /// [`Error::WindowUnavailable`] if fewer steps are recorded (or `steps` is 0).
    pub fn step_window(
        &self,
        steps: usize,
    ) -> Result<crate::StepWindow<'_, T, P::State, P::Input, N>> {
        self.shared.history.window(steps)
    }

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

    /// The process model.
    pub fn process(&self) -> &P {
        &self.process
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
        let windowed = matches!(source, CrossSource::Windowed(_));
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

    /// Estimate the error from measurement y (prior error zero), inject it into the
    /// nominal state, reset the covariance.
    ///
    /// # Errors
    /// As [`ExtendedKalmanFilter::update`], plus the injection's errors; on any error
    /// other than the observer's the filter is left untouched.
    pub fn update<Mm, C, const M: usize>(
        &mut self,
        model: &Mm,
        measurement: &SVector<T, M>,
        cross: &C,
    ) -> Result<UpdateReport<T, N, M>>
    where
        Mm: MeasurementModel<T, N, M, State = P::State> + ?Sized,
        C: CrossCovariance<T, P::State, N, M> + ?Sized,
    {
        self.update_from::<Mm, C, dyn WindowedCrossCovariance<T, P::State, P::Input, N, M>, M>(
            model,
            measurement,
            CrossSource::OneStep(cross),
        )
    }

    /// Windowed update (exact M, Var(v | ...), E[v | ...]; see [`crate::window`]),
    /// then injection and reset as [`ErrorStateKalmanFilter::update`].
    ///
    /// # Errors
    /// As [`ExtendedKalmanFilter::update_windowed`], plus the injection's errors.
    pub fn update_windowed<Mm, W, const M: usize>(
        &mut self,
        model: &Mm,
        measurement: &SVector<T, M>,
        cross: &W,
    ) -> Result<UpdateReport<T, N, M>>
    where
        Mm: MeasurementModel<T, N, M, State = P::State> + ?Sized,
        W: WindowedCrossCovariance<T, P::State, P::Input, N, M> + ?Sized,
    {
        self.update_from::<Mm, crate::Zero, W, M>(model, measurement, CrossSource::Windowed(cross))
    }

    /// One time step: predict over `dt`, then update if a measurement is present.
    ///
    /// # Errors
    /// Those of [`ErrorStateKalmanFilter::predict`] and [`ErrorStateKalmanFilter::update`].
    pub fn step<Mm, C, const M: usize>(
        &mut self,
        input: &P::Input,
        dt: T,
        model: &Mm,
        measurement: Option<&SVector<T, M>>,
        cross: &C,
    ) -> Result<Option<UpdateReport<T, N, M>>>
    where
        Mm: MeasurementModel<T, N, M, State = P::State> + ?Sized,
        C: CrossCovariance<T, P::State, N, M> + ?Sized,
    {
        self.predict(input, dt)?;
        measurement
            .map(|y| self.update(model, y, cross))
            .transpose()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Fixed, Gate, Zero};
    use nalgebra::{Matrix2, Matrix2x1, Vector1, Vector2};

    /// F and Q of the constant-velocity model of [`cv_filter`].
    fn cv_model() -> (Matrix2<f64>, Matrix2<f64>) {
        let g = Matrix2x1::new(0.5, 1.0);
        (Matrix2::new(1.0, 1.0, 0.0, 1.0), g * g.transpose() * 0.04)
    }

    fn cv_filter() -> KalmanFilter<f64, 2, 1> {
        let (f, q) = cv_model();
        KalmanFilter::new(
            f,
            q,
            nalgebra::Matrix1x2::new(1.0, 0.0),
            nalgebra::Matrix1::new(0.1),
            StateAndCovariance::new(Vector2::zeros(), Matrix2::identity()).unwrap(),
        )
        .unwrap()
    }

    #[test]
    fn accumulation_matches_explicit_sum_and_resets() {
        let mut kf = cv_filter();
        let (f, q) = cv_model();
        for _ in 0..3 {
            kf.predict().unwrap();
        }
        // Independent: sum_{j=0}^{2} F^j Q F'^j and F^3.
        let expected = q + f * q * f.transpose() + f * f * q * (f * f).transpose();
        assert!((kf.accumulated_process_noise() - expected).amax() < 1e-15);
        assert!((kf.accumulated_transition() - f * f * f).amax() < 1e-15);
        assert_eq!(kf.propagations_since_update(), 3);
        kf.update(&Vector1::new(0.3), &Zero).unwrap();
        assert_eq!(kf.propagations_since_update(), 0);
        assert_eq!(*kf.accumulated_process_noise(), Matrix2::zeros());
    }

    /// The linear filter's first push of an interval reuses F and Q left in place by
    /// the last one-step interval: Q_acc and Phi_acc still equal the explicit sums
    /// after every predict, whatever mix of one-step and longer intervals came before.
    #[test]
    fn accumulation_is_exact_across_intervals_of_any_length() {
        let mut kf = cv_filter();
        let (f, q) = cv_model();
        for steps in [1, 1, 3, 1, 2, 1, 1, 4] {
            let (mut expected_q, mut expected_f) = (Matrix2::zeros(), Matrix2::identity());
            for step in 1..=steps {
                kf.predict().unwrap();
                // Independent: Q_acc <- F Q_acc F' + Q and Phi_acc <- F Phi_acc by
                // nalgebra's products.
                expected_q = f * expected_q * f.transpose() + q;
                expected_f = f * expected_f;
                assert!((kf.accumulated_process_noise() - expected_q).amax() < 1e-15);
                assert_eq!(*kf.accumulated_transition(), expected_f);
                assert_eq!(kf.propagations_since_update(), step);
            }
            kf.update(&Vector1::new(0.3), &Zero).unwrap();
            assert_eq!(*kf.accumulated_process_noise(), Matrix2::zeros());
            assert_eq!(*kf.accumulated_transition(), Matrix2::identity());
        }
    }

    #[test]
    fn gate_rejects_outlier_and_leaves_state_untouched() {
        let config = FilterConfig::builder()
            .gate(Gate::Nis { probability: 0.99 })
            .build()
            .unwrap();
        let mut kf = cv_filter()
            .with_config(config)
            .with_observer(crate::NisRecorder::default());
        kf.predict().unwrap();
        let before = kf.estimate().clone();
        let report = kf.update(&Vector1::new(100.0), &Zero).unwrap();
        assert_eq!(report.status, UpdateStatus::RejectedByGate);
        assert!(report.nis > 6.63, "nis {}", report.nis);
        assert_eq!(*kf.estimate(), before);
        assert_eq!(kf.propagations_since_update(), 0);
        kf.predict().unwrap();
        let ok = kf.update(&Vector1::new(0.1), &Zero).unwrap();
        assert!(ok.is_accepted());
        let rec = kf.into_observer();
        assert_eq!((rec.accepted(), rec.rejected()), (1, 1));
    }

    /// A filter that a far measurement locks out: x = 0, P = I, gate at NIS 9.
    fn locked_out(after: Option<usize>) -> KalmanFilter<f64, 2, 1> {
        let mut builder = FilterConfig::builder().gate(Gate::NisThreshold(9.0));
        if let Some(after) = after {
            builder = builder.gate_recovery(GateRecovery::Inflate { after });
        }
        cv_filter().with_config(builder.build().unwrap())
    }

    #[test]
    fn gate_recovery_inflates_p_onto_the_gate_boundary_after_a_run_of_rejections() {
        let mut kf = locked_out(Some(3));
        let y = Vector1::new(100.0);
        for _ in 0..3 {
            kf.predict().unwrap();
            let before = kf.estimate().clone();
            let report = kf.update(&y, &Zero).unwrap();
            assert_eq!(report.status, UpdateStatus::RejectedByGate);
            assert_eq!(report.covariance_inflation, None);
            assert_eq!(*kf.estimate(), before);
        }
        kf.predict().unwrap();
        let prior = kf.estimate().clone();
        let report = kf.update(&y, &Zero).unwrap();
        assert!(report.is_accepted());
        let lambda = report.covariance_inflation.unwrap();
        // Independent reference, scalar measurement of the first state (H = [1 0],
        // R = 0.1): nu^2 / (lambda P00 + R) = 9 gives lambda = (nu^2 / 9 - R) / P00.
        let p = prior.covariance();
        let nu = 100.0 - prior.state()[0];
        let expected = (nu * nu / 9.0 - 0.1) / p[(0, 0)];
        assert!(expected > 1.0);
        assert!(
            (lambda - expected).abs() <= 1e-12 * expected,
            "{lambda} vs {expected}"
        );
        // The NIS the gate saw is the uninflated one.
        assert!((report.nis - nu * nu / (p[(0, 0)] + 0.1)).abs() < 1e-9 * report.nis);
        // The posterior is the textbook update of the prior with P -> lambda P.
        let pl = p * lambda;
        let s = pl[(0, 0)] + 0.1;
        let k = Vector2::new(pl[(0, 0)] / s, pl[(1, 0)] / s);
        let x = prior.state() + k * nu;
        let h = nalgebra::Matrix1x2::new(1.0, 0.0);
        let posterior = (Matrix2::identity() - k * h) * pl;
        assert!((kf.estimate().state() - x).norm() < 1e-12 * x.norm());
        assert!((kf.estimate().covariance() - posterior).norm() < 1e-12 * posterior.norm());
        // The run is over: the next gated measurement is rejected again.
        kf.predict().unwrap();
        let far = Vector1::new(kf.estimate().state()[0] + 50.0);
        assert_eq!(
            kf.update(&far, &Zero).unwrap().status,
            UpdateStatus::RejectedByGate
        );
    }

    #[test]
    fn without_recovery_a_locked_out_filter_stays_locked_out() {
        let mut kf = locked_out(None);
        for _ in 0..50 {
            kf.predict().unwrap();
            let report = kf.update(&Vector1::new(1e4), &Zero).unwrap();
            assert_eq!(report.status, UpdateStatus::RejectedByGate);
        }
        // With the rule, the same sequence is accepted at the 4th attempt.
        let mut kf = locked_out(Some(3));
        let statuses: Vec<_> = (0..5)
            .map(|_| {
                kf.predict().unwrap();
                kf.update(&Vector1::new(1e4), &Zero).unwrap().status
            })
            .collect();
        assert_eq!(statuses[..3], [UpdateStatus::RejectedByGate; 3]);
        assert_eq!(statuses[3], UpdateStatus::Accepted);
    }

    #[test]
    fn gate_recovery_leaves_rejected_what_no_inflation_can_explain() {
        // State 2 is known exactly (zero variance, no process noise) and measured
        // directly: an innovation there is not explained by any lambda P.
        let config = FilterConfig::builder()
            .gate(Gate::NisThreshold(9.0))
            .gate_recovery(GateRecovery::Inflate { after: 1 })
            .build()
            .unwrap();
        let mut kf = KalmanFilter::<f64, 2, 2>::new(
            Matrix2::identity(),
            Matrix2::new(0.01, 0.0, 0.0, 0.0),
            Matrix2::identity(),
            Matrix2::identity() * 0.01,
            StateAndCovariance::new(Vector2::zeros(), Matrix2::new(1.0, 0.0, 0.0, 0.0)).unwrap(),
        )
        .unwrap()
        .with_config(config);
        for _ in 0..4 {
            kf.predict().unwrap();
            let report = kf.update(&Vector2::new(0.0, 5.0), &Zero).unwrap();
            assert_eq!(report.status, UpdateStatus::RejectedByGate);
            assert_eq!(report.covariance_inflation, None);
        }
    }

    #[test]
    fn reject_policy_returns_typed_error_without_touching_state() {
        let config = FilterConfig::builder()
            .joint_check(JointCheck::Reject)
            .build()
            .unwrap();
        let mut kf = cv_filter().with_config(config);
        kf.predict().unwrap();
        let before = kf.estimate().clone();
        // |M| far beyond sqrt(Q_acc R): not a covariance.
        let err = kf
            .update(&Vector1::new(0.1), &Fixed(Matrix2x1::new(5.0, 5.0)))
            .unwrap_err();
        assert!(matches!(err, Error::InvalidJointCovariance { .. }));
        assert_eq!(*kf.estimate(), before);
        assert_eq!(kf.propagations_since_update(), 1);
    }

    /// The commit rule: an observer's error is returned after the predict or update
    /// was committed (module docs).
    #[test]
    fn observer_error_leaves_the_committed_result() {
        struct Fails;
        impl<S, const N: usize> Observer<f64, S, N> for Fails {
            fn on_predict(&mut self, _: &PredictEvent<'_, f64, S, N>) -> Result<()> {
                Err(Error::Observer("disk full".into()))
            }
            fn on_update(&mut self, _: &UpdateEvent<'_, f64, S, N>) -> Result<()> {
                Err(Error::Observer("disk full".into()))
            }
        }
        let mut reference = cv_filter();
        let mut kf = cv_filter().with_observer(Fails);
        reference.predict().unwrap();
        assert!(matches!(kf.predict(), Err(Error::Observer(_))));
        assert_eq!(kf.estimate(), reference.estimate());
        assert_eq!(kf.propagations_since_update(), 1);
        reference.update(&Vector1::new(0.4), &Zero).unwrap();
        assert!(matches!(
            kf.update(&Vector1::new(0.4), &Zero),
            Err(Error::Observer(_))
        ));
        assert_eq!(kf.estimate(), reference.estimate());
        assert_eq!(kf.propagations_since_update(), 0);
    }

    /// With accumulation off, a model that needs Q_acc fails with a typed error and
    /// Zero / Fixed still work.
    #[test]
    fn untracked_accumulation_is_refused_where_needed() {
        let config = FilterConfig::builder()
            .track_accumulated_noise(false)
            .build()
            .unwrap();
        let mut kf = cv_filter().with_config(config);
        kf.predict().unwrap();
        kf.predict().unwrap();
        assert_eq!(*kf.accumulated_process_noise(), Matrix2::zeros());
        assert_eq!(kf.propagations_since_update(), 2);
        let err = kf
            .update(&Vector1::new(0.1), &crate::ScaledCorrelation { rho: 0.1 })
            .unwrap_err();
        assert!(matches!(err, Error::NotTracked { .. }), "{err}");
        let report = kf
            .update(&Vector1::new(0.1), &Fixed(Matrix2x1::new(0.001, 0.002)))
            .unwrap();
        assert_eq!(report.joint_min_eigenvalue, None);
        let reject = FilterConfig::builder()
            .track_accumulated_noise(false)
            .joint_check(JointCheck::Reject)
            .build()
            .unwrap();
        let mut kf = cv_filter().with_config(reject);
        kf.predict().unwrap();
        assert!(kf.update(&Vector1::new(0.1), &Zero).is_ok());
        assert!(matches!(
            kf.update(&Vector1::new(0.1), &Fixed(Matrix2x1::new(0.001, 0.002))),
            Err(Error::NotTracked { .. })
        ));
    }

    /// The joint check reuses Q_acc's block certificate only while Q_acc is the same:
    /// with 1, 2, 1, 3, 1 predicts per update (Q_acc = Q, F Q F' + Q, ...), every
    /// reported margin equals a fresh `joint_validity_margin` of Q_acc (formed here by
    /// the recursion, dense), for a valid Q and for an indefinite one (whose margins,
    /// negative, come from the eigenvalue fallback and differ between the intervals).
    /// 1e-12: the runner's Q_acc (symmetric propagation) and the dense one here differ
    /// by rounding; a stale certificate is off by more than 1e-3.
    #[test]
    fn joint_check_reuses_the_noise_certificate_only_while_q_acc_is_unchanged() {
        use crate::cross::joint_validity_margin;
        for q in [
            Matrix2::<f64>::new(0.01, 0.02, 0.02, 0.04),
            Matrix2::new(0.04, 0.01, 0.01, -0.01),
        ] {
            let f = Matrix2::new(1.0, 1.0, 0.0, 1.0);
            let r = nalgebra::Matrix1::new(0.1);
            let mut kf = KalmanFilter::new(
                f,
                q,
                nalgebra::Matrix1x2::new(1.0, 0.0),
                r,
                StateAndCovariance::new(Vector2::zeros(), Matrix2::identity()).unwrap(),
            )
            .unwrap();
            let mut margins: Vec<f64> = Vec::new();
            for predicts in [1, 2, 1, 3, 1] {
                let mut q_acc = Matrix2::zeros();
                for _ in 0..predicts {
                    kf.predict().unwrap();
                    q_acc = f * q_acc * f.transpose() + q;
                }
                let report = kf.update(&Vector1::new(0.1), &Zero).unwrap();
                let margin: f64 = report.joint_min_eigenvalue.unwrap();
                let fresh = joint_validity_margin(&q_acc, &Matrix2x1::zeros(), &r).unwrap();
                assert!(
                    (margin - fresh).abs() <= 1e-12,
                    "{predicts}: {margin} vs {fresh}"
                );
                margins.push(margin);
            }
            // The intervals' Q_acc differ enough that a stale certificate would show.
            assert!((margins[0] - margins[1]).abs() > 1e-3, "{margins:?}");
        }
    }

    #[test]
    fn report_policy_exposes_negative_eigenvalue() {
        let mut kf = cv_filter();
        kf.predict().unwrap();
        let report = kf
            .update(&Vector1::new(0.1), &Fixed(Matrix2x1::new(0.3, 0.3)))
            .unwrap();
        assert!(report.joint_min_eigenvalue.unwrap() < 0.0);
    }

    #[test]
    fn bad_dt_is_a_typed_error() {
        struct Walk;
        impl ProcessModel<f64, 1> for Walk {
            type State = SVector<f64, 1>;
            type Input = ();
            fn propagate(&self, s: &Self::State, _: &(), _: f64) -> Result<Self::State> {
                Ok(*s)
            }
            fn transition(&self, _: &Self::State, _: &(), _: f64) -> Result<SMatrix<f64, 1, 1>> {
                Ok(SMatrix::identity())
            }
            fn process_noise(
                &self,
                _: &Self::State,
                _: &(),
                dt: f64,
            ) -> Result<SMatrix<f64, 1, 1>> {
                Ok(SMatrix::identity() * dt)
            }
        }
        let mut ekf = ExtendedKalmanFilter::new(
            Walk,
            StateAndCovariance::new(Vector1::zeros(), nalgebra::Matrix1::identity()).unwrap(),
        );
        for dt in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(matches!(
                ekf.predict(&(), dt),
                Err(Error::InvalidParameter { name: "dt", .. })
            ));
        }
        ekf.predict(&(), 0.5).unwrap();
        assert_eq!(ekf.estimate().covariance()[(0, 0)], 1.5);
    }

    /// A model whose Phi and Q_d come only from `transition_and_noise` (the separate
    /// methods fail): the runners must ask for both at once.
    struct OnlyJoint;
    impl ProcessModel<f64, 1> for OnlyJoint {
        type State = SVector<f64, 1>;
        type Input = ();
        fn propagate(&self, s: &Self::State, _: &(), _: f64) -> Result<Self::State> {
            Ok(*s)
        }
        fn transition(&self, _: &Self::State, _: &(), _: f64) -> Result<SMatrix<f64, 1, 1>> {
            Err(Error::InvalidParameter {
                name: "transition",
                reason: "not to be called".into(),
            })
        }
        fn process_noise(&self, _: &Self::State, _: &(), _: f64) -> Result<SMatrix<f64, 1, 1>> {
            Err(Error::InvalidParameter {
                name: "process_noise",
                reason: "not to be called".into(),
            })
        }
        fn transition_and_noise(
            &self,
            _: &Self::State,
            _: &(),
            dt: f64,
        ) -> Result<(SMatrix<f64, 1, 1>, SMatrix<f64, 1, 1>)> {
            Ok((SMatrix::identity() * 2.0, SMatrix::identity() * dt))
        }
    }
    impl ErrorStateModel<f64, 1> for OnlyJoint {
        fn inject(&self, nominal: &Self::State, error: &SVector<f64, 1>) -> Result<Self::State> {
            Ok(nominal + error)
        }
    }

    #[test]
    fn runners_take_transition_and_noise_together() {
        let initial = StateAndCovariance::new(Vector1::zeros(), nalgebra::Matrix1::new(0.5));
        let mut ekf = ExtendedKalmanFilter::new(OnlyJoint, initial.unwrap());
        ekf.predict(&(), 0.25).unwrap();
        // 2 * 0.5 * 2 + 0.25
        assert_eq!(ekf.estimate().covariance()[(0, 0)], 2.25);
        let mut eskf =
            ErrorStateKalmanFilter::new(OnlyJoint, Vector1::zeros(), nalgebra::Matrix1::new(0.5))
                .unwrap();
        eskf.predict(&(), 0.25).unwrap();
        assert_eq!(eskf.covariance()[(0, 0)], 2.25);
        // The default pairs the two separate methods.
        assert!(matches!(
            ScalarNominal.transition_and_noise(&1.0, &0.0, 0.5),
            Ok((phi, qd)) if phi[(0, 0)] == 1.0 && qd[(0, 0)] == 0.05
        ));
    }

    /// Scalar error-state model with a non-identity reset (like the attitude reset of
    /// Sola 2017, eq. 287: J = 1 - e/2), checked against scalar formulas.
    struct ScalarNominal;
    impl ProcessModel<f64, 1> for ScalarNominal {
        type State = f64;
        type Input = f64;
        fn propagate(&self, x: &f64, u: &f64, dt: f64) -> Result<f64> {
            Ok(x + u * dt)
        }
        fn transition(&self, _: &f64, _: &f64, _: f64) -> Result<SMatrix<f64, 1, 1>> {
            Ok(SMatrix::identity())
        }
        fn process_noise(&self, _: &f64, _: &f64, dt: f64) -> Result<SMatrix<f64, 1, 1>> {
            Ok(SMatrix::identity() * 0.1 * dt)
        }
    }
    impl ErrorStateModel<f64, 1> for ScalarNominal {
        fn inject(&self, nominal: &f64, error: &SVector<f64, 1>) -> Result<f64> {
            Ok(nominal + error[0])
        }
        fn reset_jacobian(&self, _: &f64, error: &SVector<f64, 1>) -> SMatrix<f64, 1, 1> {
            SMatrix::identity() * (1.0 - 0.5 * error[0])
        }
    }
    struct Direct;
    impl MeasurementModel<f64, 1, 1> for Direct {
        type State = f64;
        fn predict(&self, x: &f64) -> Result<SVector<f64, 1>> {
            Ok(Vector1::new(*x))
        }
        fn jacobian(&self, _: &f64) -> Result<SMatrix<f64, 1, 1>> {
            Ok(SMatrix::identity())
        }
        fn noise_covariance(&self, _: &f64) -> Result<SMatrix<f64, 1, 1>> {
            Ok(SMatrix::identity() * 0.2)
        }
    }

    #[test]
    fn error_state_injects_and_resets() {
        let mut eskf =
            ErrorStateKalmanFilter::new(ScalarNominal, 1.0, nalgebra::Matrix1::new(0.3)).unwrap();
        eskf.predict(&2.0, 0.5).unwrap(); // nominal 2.0, P = 0.3 + 0.05
        let (p, r, y) = (0.35, 0.2, 2.4);
        let report = eskf.update(&Direct, &Vector1::new(y), &Zero).unwrap();
        let k = p / (p + r);
        let e = k * (y - 2.0);
        let j = 1.0 - 0.5 * e;
        assert!((report.correction.unwrap()[0] - e).abs() < 1e-15);
        assert!((eskf.nominal() - (2.0 + e)).abs() < 1e-15);
        assert!((eskf.covariance()[(0, 0)] - j * (1.0 - k) * p * j).abs() < 1e-15);
    }
}
