//! The three runners (linear KF, EKF, error-state EKF), all built on the one
//! [`crate::correlated_update`], with process-noise accumulation, the innovation gate,
//! the joint-covariance policy and observers.

use nalgebra::{SMatrix, SVector};

use crate::config::JointCheck;
use crate::cross::{check_joint_covariance, joint_validity_margin};
use crate::gaussian::{check_finite, check_symmetric, symmetrize};
use crate::observer::{NoObserver, Observer, PredictEvent, UpdateEvent, UpdateStatus};
use crate::scalar::lit;
use crate::update::{factor_innovation, finish_update, mul_static};
use crate::{
    CrossCovariance, CrossCovarianceContext, Error, ErrorStateModel, FilterConfig,
    MeasurementModel, ProcessModel, Result, Scalar, StateAndCovariance,
};

/// Everything one update attempt produced, accepted or rejected.
#[derive(Debug, Clone, PartialEq)]
pub struct UpdateReport<T: Scalar, const N: usize, const M: usize> {
    /// Accepted, or rejected by the innovation gate (state untouched).
    pub status: UpdateStatus,
    /// Innovation y - h(x).
    pub innovation: SVector<T, M>,
    /// Innovation covariance S = H P H' + H M + M' H' + R.
    pub innovation_covariance: SMatrix<T, M, M>,
    /// Normalised innovation squared, innovation' S^-1 innovation.
    pub nis: T,
    /// The gate's NIS threshold for this measurement size, if a gate is configured.
    pub gate_threshold: Option<T>,
    /// The cross-covariance M_k the [`CrossCovariance`] produced.
    pub cross_covariance: SMatrix<T, N, M>,
    /// Smallest eigenvalue of the correlation matrix of [[Q_acc, M], [M', R]]
    /// (dimensionless; the joint covariance is valid iff it is >= 0, tolerance 1e-9);
    /// `None` with [`JointCheck::Skip`].
    pub joint_min_eigenvalue: Option<T>,
    /// The gain K (`None` if rejected).
    pub gain: Option<SMatrix<T, N, M>>,
    /// The state correction K * innovation (`None` if rejected); for the error-state
    /// filter this is the error injected into the nominal state.
    pub correction: Option<SVector<T, N>>,
}

impl<T: Scalar, const N: usize, const M: usize> UpdateReport<T, N, M> {
    /// Whether the posterior replaced the prior.
    pub fn is_accepted(&self) -> bool {
        self.status == UpdateStatus::Accepted
    }
}

/// Process noise and transition accumulated since the last measurement:
/// Q_acc <- Phi Q_acc Phi' + Q_d and Phi_acc <- Phi Phi_acc.
///
/// The first propagation after a measurement copies (no product), so a filter that
/// updates after every prediction pays nothing for the accumulation.
#[derive(Debug, Clone, PartialEq)]
struct Accumulator<T: Scalar, const N: usize> {
    noise: SMatrix<T, N, N>,
    transition: SMatrix<T, N, N>,
    steps: usize,
}

impl<T: Scalar, const N: usize> Accumulator<T, N> {
    fn new() -> Self {
        Self {
            noise: SMatrix::zeros(),
            transition: SMatrix::identity(),
            steps: 0,
        }
    }

    /// Add one propagation; `propagate` is the model's covariance propagation
    /// (the same structure as P's, so a sparse override speeds up both).
    fn push(
        &mut self,
        transition: &SMatrix<T, N, N>,
        process_noise: &SMatrix<T, N, N>,
        propagate: impl FnOnce(
            &SMatrix<T, N, N>,
            &SMatrix<T, N, N>,
            &SMatrix<T, N, N>,
        ) -> SMatrix<T, N, N>,
    ) {
        if self.steps == 0 {
            self.noise = *process_noise;
            self.transition = *transition;
        } else {
            self.noise = propagate(&self.noise, transition, process_noise);
            self.transition = transition * self.transition;
        }
        self.steps += 1;
    }

    fn reset(&mut self) {
        *self = Self::new();
    }
}

/// F P F' + Q for a symmetric P and Q, as two static products in column (axpy)
/// order, which vectorise and carry no long dependency chain; then the upper
/// triangle, plus Q's triangles averaged (as by `symmetrize`), mirrored so the
/// result is exactly symmetric.
#[inline(always)]
fn propagate_symmetric<T: Scalar, const N: usize>(
    transition: &SMatrix<T, N, N>,
    covariance: &SMatrix<T, N, N>,
    process_noise: &SMatrix<T, N, N>,
) -> SMatrix<T, N, N> {
    let fp = mul_static(transition, covariance);
    let mut out = mul_static(&fp, &transition.transpose());
    let half = lit::<T>(0.5);
    for j in 0..N {
        for i in 0..=j {
            let v = out[(i, j)] + (process_noise[(i, j)] + process_noise[(j, i)]) * half;
            out[(i, j)] = v;
            out[(j, i)] = v;
        }
    }
    out
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

/// The update attempt shared by all runners. Returns the report and, if accepted,
/// the posterior. Touches nothing: the caller commits.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn attempt_update<T, S, C, const N: usize, const M: usize>(
    config: &FilterConfig,
    prior: &StateAndCovariance<T, N>,
    state: &S,
    accumulated: &Accumulator<T, N>,
    measurement: &SVector<T, M>,
    innovation: SVector<T, M>,
    jacobian: &SMatrix<T, M, N>,
    measurement_noise: &SMatrix<T, M, M>,
    cross: &C,
) -> Result<(UpdateReport<T, N, M>, Option<StateAndCovariance<T, N>>)>
where
    T: Scalar,
    C: CrossCovariance<T, S, N, M> + ?Sized,
{
    // H, R, M and P are checked by `factor_innovation` (any NaN reaches S); the
    // measurement is checked here so the error names it.
    check_finite(measurement.as_slice(), "measurement")?;
    let context = CrossCovarianceContext {
        accumulated_process_noise: &accumulated.noise,
        accumulated_transition: &accumulated.transition,
        measurement_noise,
        jacobian,
        measurement,
        state,
        covariance: prior.covariance(),
    };
    let cross_covariance = cross.cross_covariance(&context)?;
    let joint_min_eigenvalue = match config.joint_check() {
        JointCheck::Skip => None,
        JointCheck::Report => Some(joint_validity_margin(
            &accumulated.noise,
            &cross_covariance,
            measurement_noise,
        )?),
        JointCheck::Reject => Some(check_joint_covariance(
            &accumulated.noise,
            &cross_covariance,
            measurement_noise,
        )?),
    };
    let factored = factor_innovation(
        prior,
        &innovation,
        jacobian,
        measurement_noise,
        &cross_covariance,
    )?;
    let gate_threshold = config.gate_threshold(M)?.map(lit::<T>);
    let mut report = UpdateReport {
        status: UpdateStatus::Accepted,
        innovation,
        innovation_covariance: factored.covariance,
        nis: factored.nis,
        gate_threshold,
        cross_covariance,
        joint_min_eigenvalue,
        gain: None,
        correction: None,
    };
    if let Some(threshold) = gate_threshold {
        if factored.nis > threshold {
            report.status = UpdateStatus::RejectedByGate;
            return Ok((report, None));
        }
    }
    let outcome = finish_update(
        prior,
        &innovation,
        &cross_covariance,
        config.covariance_update(),
        factored,
    )?;
    report.gain = Some(outcome.gain);
    report.correction = Some(outcome.posterior.state() - prior.state());
    Ok((report, Some(outcome.posterior)))
}

fn notify_update<T, S, O, const N: usize, const M: usize>(
    observer: &mut O,
    report: &UpdateReport<T, N, M>,
    state: &S,
    covariance: &SMatrix<T, N, N>,
) -> Result<()>
where
    T: Scalar,
    O: Observer<T, S, N>,
{
    let event = UpdateEvent {
        state,
        covariance,
        innovation: report.innovation.as_slice(),
        measurement_size: M,
        nis: report.nis,
        gate_threshold: report.gate_threshold,
        joint_min_eigenvalue: report.joint_min_eigenvalue,
        status: report.status,
    };
    match report.status {
        UpdateStatus::Accepted => observer.on_update(&event),
        UpdateStatus::RejectedByGate => observer.on_rejected(&event),
    }
}

/// Linear Kalman filter x_k = F x_{k-1} + G w, y_k = H x_k + v, with the correlated
/// update.
///
/// State kept between calls (all readable): the estimate, Q_acc and Phi_acc since
/// the last measurement, the configuration and the observer. Q_acc and Phi_acc are
/// reset after every update attempt, accepted or rejected by the gate (the
/// measurement's noise is correlated with the process noise of the interval that
/// ends at it; a rejected measurement still closes its interval). They are kept
/// when an update fails with an error, and when a step has no measurement (`None`).
#[derive(Debug, Clone)]
pub struct KalmanFilter<T: Scalar, const N: usize, const M: usize, O = NoObserver> {
    transition: SMatrix<T, N, N>,
    process_noise: SMatrix<T, N, N>,
    observation: SMatrix<T, M, N>,
    measurement_noise: SMatrix<T, M, M>,
    estimate: StateAndCovariance<T, N>,
    accumulated: Accumulator<T, N>,
    config: FilterConfig,
    observer: O,
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
            accumulated: Accumulator::new(),
            config: FilterConfig::default(),
            observer: NoObserver,
        })
    }
}

impl<T: Scalar, const N: usize, const M: usize, O> KalmanFilter<T, N, M, O> {
    /// Replace the configuration.
    #[must_use]
    pub fn with_config(self, config: FilterConfig) -> Self {
        Self { config, ..self }
    }

    /// Replace the observer.
    #[must_use]
    pub fn with_observer<O2>(self, observer: O2) -> KalmanFilter<T, N, M, O2> {
        KalmanFilter {
            transition: self.transition,
            process_noise: self.process_noise,
            observation: self.observation,
            measurement_noise: self.measurement_noise,
            estimate: self.estimate,
            accumulated: self.accumulated,
            config: self.config,
            observer,
        }
    }

    /// The current estimate.
    pub fn estimate(&self) -> &StateAndCovariance<T, N> {
        &self.estimate
    }

    /// The configuration.
    pub fn config(&self) -> &FilterConfig {
        &self.config
    }

    /// Q_acc since the last measurement.
    pub fn accumulated_process_noise(&self) -> &SMatrix<T, N, N> {
        &self.accumulated.noise
    }

    /// Phi_acc since the last measurement.
    pub fn accumulated_transition(&self) -> &SMatrix<T, N, N> {
        &self.accumulated.transition
    }

    /// Propagations since the last measurement.
    pub fn propagations_since_update(&self) -> usize {
        self.accumulated.steps
    }

    /// The observer.
    pub fn observer(&self) -> &O {
        &self.observer
    }

    /// The observer, mutably.
    pub fn observer_mut(&mut self) -> &mut O {
        &mut self.observer
    }

    /// Consume the filter, keeping the observer (e.g. to read what it recorded).
    pub fn into_observer(self) -> O {
        self.observer
    }
}

impl<T: Scalar, const N: usize, const M: usize, O: Observer<T, SVector<T, N>, N>>
    KalmanFilter<T, N, M, O>
{
    /// Prior: x <- F x, P <- F P F' + Q.
    ///
    /// # Errors
    /// [`Error::NonFinite`] if the prediction overflows; observer errors.
    pub fn predict(&mut self) -> Result<()> {
        let f = &self.transition;
        let state = mul_static(f, self.estimate.state());
        let covariance = propagate_symmetric(f, self.estimate.covariance(), &self.process_noise);
        check_finite(state.as_slice(), "predicted state")?;
        check_finite(covariance.as_slice(), "predicted covariance")?;
        self.estimate = StateAndCovariance::new_unchecked(state, covariance);
        self.accumulated.push(f, &self.process_noise, |q, phi, qd| {
            propagate_symmetric(phi, q, qd)
        });
        self.observer.on_predict(&PredictEvent {
            dt: None,
            state: self.estimate.state(),
            covariance: self.estimate.covariance(),
            propagations_since_update: self.accumulated.steps,
        })
    }

    /// Update with measurement y and the cross-covariance model `cross`.
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
        let innovation = measurement - self.observation * self.estimate.state();
        let (report, posterior) = attempt_update(
            &self.config,
            &self.estimate,
            self.estimate.state(),
            &self.accumulated,
            measurement,
            innovation,
            &self.observation,
            &self.measurement_noise,
            cross,
        )?;
        if let Some(posterior) = posterior {
            self.estimate = posterior;
        }
        self.accumulated.reset();
        notify_update(
            &mut self.observer,
            &report,
            self.estimate.state(),
            self.estimate.covariance(),
        )?;
        Ok(report)
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
/// updated with any [`MeasurementModel`] and [`CrossCovariance`].
///
/// F and Q_d are evaluated at the state before propagation. Kept state and the
/// reset rule of Q_acc / Phi_acc: as for [`KalmanFilter`].
#[derive(Debug, Clone)]
pub struct ExtendedKalmanFilter<T: Scalar, P, const N: usize, O = NoObserver> {
    process: P,
    estimate: StateAndCovariance<T, N>,
    accumulated: Accumulator<T, N>,
    config: FilterConfig,
    observer: O,
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
            accumulated: Accumulator::new(),
            config: FilterConfig::default(),
            observer: NoObserver,
        }
    }
}

impl<T: Scalar, P, const N: usize, O> ExtendedKalmanFilter<T, P, N, O> {
    /// Replace the configuration.
    #[must_use]
    pub fn with_config(self, config: FilterConfig) -> Self {
        Self { config, ..self }
    }

    /// Replace the observer.
    #[must_use]
    pub fn with_observer<O2>(self, observer: O2) -> ExtendedKalmanFilter<T, P, N, O2> {
        ExtendedKalmanFilter {
            process: self.process,
            estimate: self.estimate,
            accumulated: self.accumulated,
            config: self.config,
            observer,
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

    /// The configuration.
    pub fn config(&self) -> &FilterConfig {
        &self.config
    }

    /// Q_acc since the last measurement.
    pub fn accumulated_process_noise(&self) -> &SMatrix<T, N, N> {
        &self.accumulated.noise
    }

    /// Phi_acc since the last measurement.
    pub fn accumulated_transition(&self) -> &SMatrix<T, N, N> {
        &self.accumulated.transition
    }

    /// Propagations since the last measurement.
    pub fn propagations_since_update(&self) -> usize {
        self.accumulated.steps
    }

    /// The observer.
    pub fn observer(&self) -> &O {
        &self.observer
    }

    /// The observer, mutably.
    pub fn observer_mut(&mut self) -> &mut O {
        &mut self.observer
    }

    /// Consume the filter, keeping the observer.
    pub fn into_observer(self) -> O {
        self.observer
    }
}

impl<T, P, const N: usize, O> ExtendedKalmanFilter<T, P, N, O>
where
    T: Scalar,
    P: ProcessModel<T, N, State = SVector<T, N>>,
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
        self.estimate = StateAndCovariance::new_unchecked(state, covariance);
        let process = &self.process;
        self.accumulated.push(&phi, &qd, |q, phi, qd| {
            process.propagate_covariance(q, phi, qd)
        });
        self.observer.on_predict(&PredictEvent {
            dt: Some(dt),
            state: self.estimate.state(),
            covariance: self.estimate.covariance(),
            propagations_since_update: self.accumulated.steps,
        })
    }

    /// Update with `model`, measurement y and the cross-covariance model `cross`.
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
        let x = self.estimate.state();
        let innovation = measurement - model.predict(x)?;
        let jacobian = model.jacobian(x)?;
        let noise = model.noise_covariance(x)?;
        let (report, posterior) = attempt_update(
            &self.config,
            &self.estimate,
            x,
            &self.accumulated,
            measurement,
            innovation,
            &jacobian,
            &noise,
            cross,
        )?;
        if let Some(posterior) = posterior {
            self.estimate = posterior;
        }
        self.accumulated.reset();
        notify_update(
            &mut self.observer,
            &report,
            self.estimate.state(),
            self.estimate.covariance(),
        )?;
        Ok(report)
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
/// error estimate is zero between updates.
///
/// Kept state and the reset rule of Q_acc / Phi_acc: as for [`KalmanFilter`].
#[derive(Debug, Clone)]
pub struct ErrorStateKalmanFilter<T, P, const N: usize, O = NoObserver>
where
    T: Scalar,
    P: ProcessModel<T, N>,
{
    process: P,
    nominal: P::State,
    covariance: SMatrix<T, N, N>,
    accumulated: Accumulator<T, N>,
    config: FilterConfig,
    observer: O,
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
            accumulated: Accumulator::new(),
            config: FilterConfig::default(),
            observer: NoObserver,
        })
    }
}

impl<T: Scalar, P: ProcessModel<T, N>, const N: usize, O> ErrorStateKalmanFilter<T, P, N, O> {
    /// Replace the configuration.
    #[must_use]
    pub fn with_config(self, config: FilterConfig) -> Self {
        Self { config, ..self }
    }

    /// Replace the observer.
    #[must_use]
    pub fn with_observer<O2>(self, observer: O2) -> ErrorStateKalmanFilter<T, P, N, O2> {
        ErrorStateKalmanFilter {
            process: self.process,
            nominal: self.nominal,
            covariance: self.covariance,
            accumulated: self.accumulated,
            config: self.config,
            observer,
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

    /// The configuration.
    pub fn config(&self) -> &FilterConfig {
        &self.config
    }

    /// Q_acc since the last measurement.
    pub fn accumulated_process_noise(&self) -> &SMatrix<T, N, N> {
        &self.accumulated.noise
    }

    /// Phi_acc since the last measurement.
    pub fn accumulated_transition(&self) -> &SMatrix<T, N, N> {
        &self.accumulated.transition
    }

    /// Propagations since the last measurement.
    pub fn propagations_since_update(&self) -> usize {
        self.accumulated.steps
    }

    /// The observer.
    pub fn observer(&self) -> &O {
        &self.observer
    }

    /// The observer, mutably.
    pub fn observer_mut(&mut self) -> &mut O {
        &mut self.observer
    }

    /// Consume the filter, keeping the observer.
    pub fn into_observer(self) -> O {
        self.observer
    }
}

impl<T, P, const N: usize, O> ErrorStateKalmanFilter<T, P, N, O>
where
    T: Scalar,
    P: ErrorStateModel<T, N>,
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
        self.nominal = nominal;
        self.covariance = covariance;
        let process = &self.process;
        self.accumulated.push(&phi, &qd, |q, phi, qd| {
            process.propagate_covariance(q, phi, qd)
        });
        self.observer.on_predict(&PredictEvent {
            dt: Some(dt),
            state: &self.nominal,
            covariance: &self.covariance,
            propagations_since_update: self.accumulated.steps,
        })
    }

    /// Estimate the error from measurement y (prior error zero), inject it into the
    /// nominal state, reset the covariance.
    ///
    /// # Errors
    /// As [`ExtendedKalmanFilter::update`], plus the injection's errors; on any error
    /// the filter is left untouched.
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
        let innovation = measurement - model.predict(&self.nominal)?;
        let jacobian = model.jacobian(&self.nominal)?;
        let noise = model.noise_covariance(&self.nominal)?;
        let prior = StateAndCovariance::new_unchecked(SVector::zeros(), self.covariance);
        let (report, posterior) = attempt_update(
            &self.config,
            &prior,
            &self.nominal,
            &self.accumulated,
            measurement,
            innovation,
            &jacobian,
            &noise,
            cross,
        )?;
        if let Some(posterior) = posterior {
            let (error, covariance) = posterior.into_parts();
            let reset = self.process.reset_jacobian(&self.nominal, &error);
            check_finite(reset.as_slice(), "reset jacobian")?;
            let nominal = self.process.inject(&self.nominal, &error)?;
            let covariance = if reset == SMatrix::<T, N, N>::identity() {
                covariance
            } else {
                symmetrize(&(reset * covariance * reset.transpose()))
            };
            self.nominal = nominal;
            self.covariance = covariance;
        }
        self.accumulated.reset();
        notify_update(&mut self.observer, &report, &self.nominal, &self.covariance)?;
        Ok(report)
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

    fn cv_filter() -> KalmanFilter<f64, 2, 1> {
        let f = Matrix2::new(1.0, 1.0, 0.0, 1.0);
        let g = Matrix2x1::new(0.5, 1.0);
        let q = g * g.transpose() * 0.04;
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
        let f = Matrix2::new(1.0, 1.0, 0.0, 1.0);
        let g = Matrix2x1::new(0.5, 1.0);
        let q = g * g.transpose() * 0.04;
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
