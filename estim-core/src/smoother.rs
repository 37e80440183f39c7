//! Rauch-Tung-Striebel smoothing (fixed interval and fixed lag) over a recorded
//! forward pass, consistent with correlated process and measurement noise.
//!
//! ## Recording
//!
//! A [`ForwardRecorder`] is an [`Observer`]: attach it to any runner
//! ([`crate::KalmanFilter`], [`crate::ExtendedKalmanFilter`],
//! [`crate::ErrorStateKalmanFilter`], [`crate::SquareRootKalmanFilter`],
//! [`crate::UnscentedKalmanFilter`]; for the last, the linearised smoother around the
//! unscented forward pass, exact on linear models) and it keeps, per *epoch*, the filtered state and
//! covariance and three quantities that link the epoch to the previous one (below). An
//! epoch is a moment of the forward pass: with [`RecordAt::EveryStep`] every predict
//! opens one (the updates that follow belong to it); with [`RecordAt::Updates`] the
//! predicts between two updates are composed into one transition and an epoch ends
//! with its updates (memory: one epoch per update, not per IMU sample).
//!
//! ## The smoother with correlated noise (derivation)
//!
//! Model (error coordinates, `true = estimate + error`): e_{k+1} = Phi e_k + w and,
//! at epoch k+1, updates y = H e_{k+1} + v with M = Cov(w, v) (`M_k = Cov(G w_{k-1},
//! v_k)`, crate docs). The textbook RTS step uses the Markov property
//! p(x_k | x_{k+1}, Y_{1:K}) = p(x_k | x_{k+1}, Y_{1:k}); with M != 0 it fails, because
//! v_{k+1} is correlated with w = x_{k+1} - Phi x_k, so y_{k+1} still tells about x_k
//! once x_{k+1} is known. It holds again one measurement later: given x_{k+1} *and*
//! Y_{1:k+1}, x_k is independent of every later measurement (later noises are
//! independent of x_k, w and v up to k+1). So we smooth the pair (x_k, x_{k+1})
//! augmented over the update of epoch k+1 (the consider/augmented-state form; with
//! M = 0 it reduces to Rauch, Tung & Striebel 1965, Saerkkae 2013 *Bayesian Filtering
//! and Smoothing* th. 8.2). Before the updates of epoch k+1 the joint covariance of
//! (e_k, e_{k+1}, v) is [[P_k, C, 0], [C', P-, M], [0, M', R]] with C = P_k Phi'. Each
//! accepted update (innovation nu, covariance S, gain K, reset J) is joint-Gaussian
//! conditioning of that joint (Simon 2006 sec. 7.1 for the e_{k+1} part):
//!
//! ```text
//! A        = C H' S^-1                     Cov(e_k, y) S^-1, since Cov(e_k, v) = 0
//! shift_k += A nu                          E[e_k | Y_{1:k+1}]   - filtered mean
//! P_k|k+1 -= A H C'                        Cov(e_k | Y_{1:k+1})
//! C       <- C (I - K H)' J'               Cov(e_k, e_{k+1} | Y_{1:k+1}), any gain K
//! ```
//!
//! and the backward pass, with the filtered P_{k+1} = Cov(e_{k+1} | Y_{1:k+1}):
//!
//! ```text
//! G_k  = C P_{k+1}^-1
//! e^s_k = shift_k + G_k e^s_{k+1}
//! P^s_k = P_k|k+1 + G_k (P^s_{k+1} - P_{k+1}) G_k'
//! ```
//!
//! (e^s is the smoothed mean minus the filtered one). This equals joint-Gaussian
//! conditioning of the stacked [x_0; w_1..w_K; v's] on all measurements
//! (`tests/smoother.rs`, to 1e-9 relative). It is equivalent to running the textbook
//! RTS on Simon's decorrelated process (2006, sec. 7.1), but needs no rewriting of the
//! model and reads only what the forward pass reported.
//!
//! ## What it covers, and the typed refusals
//!
//! The step above needs Cov(e_k, v) = 0 for every update of epoch k+1 (conditional on
//! the earlier updates). It holds when each measurement's noise is correlated only
//! with the process noise since the previous epoch. When the recording cannot
//! guarantee it, [`ForwardRecorder::smooth`] returns
//! [`Error::SmootherUnsupported`] naming the epoch, never a number:
//!
//! - a windowed update ([`crate::WindowedCrossCovariance`]) whose window reaches back
//!   past the previous epoch: with [`RecordAt::Updates`], a window longer than the
//!   predicts since the previous update; with [`RecordAt::EveryStep`], a window of more
//!   than one step;
//! - an update the gate's recovery rule accepted with an inflated prior covariance
//!   ([`crate::GateRecovery::Inflate`]): the forward pass then is not a Kalman filter
//!   of the recorded model;
//! - a correlated update (M != 0) that is not the first accepted update of its epoch
//!   (the earlier update made its noise correlated with e_k);
//! - with [`RecordAt::EveryStep`], a one-step correlated update after more than one
//!   predict: M = Cov(sum of the interval's noise, v) does not say how v is shared
//!   between the intermediate steps (record with [`RecordAt::Updates`], where M is
//!   exactly the cross-covariance with the composed step, or state the sharing with a
//!   windowed M).
//!
//! Windowed updates inside these limits are smoothed exactly: with
//! [`RecordAt::Updates`] a window within the interval since the previous update makes
//! the window's C = sum_j Phi(k, j) D_j the cross-covariance with the composed step (no
//! other update lies inside it, so Var(v) = R and E\[v\] = 0); with
//! [`RecordAt::EveryStep`] a one-step window is the textbook Cov(w_{k-1}, v_k), also
//! after unmeasured steps (`tests/smoother.rs`, `windowed_*`, against joint-Gaussian
//! conditioning).
//!
//! ## Error-state convention
//!
//! For the [`crate::ErrorStateKalmanFilter`] the recorded state is the nominal state
//! after the epoch's injections and the smoothed correction e^s_k is the error
//! relative to *that* nominal (`true = nominal + error`); [`Smoothed::injected`]
//! re-injects it with [`ErrorStateModel::inject`]. The smoothed covariance is the
//! error covariance about the recorded nominal (no reset Jacobian is applied to it).
//! Resets J inside the forward pass are carried in C (the event's `reset`).
//!
//! ## Fixed lag
//!
//! The fixed-lag estimate of epoch k with lag L is E[x_k | Y_{1:k+L}]: the backward
//! pass above from epoch min(k+L, last) down to k (exact, cost L N^3 per epoch).
//! [`ForwardRecorder::fixed_lag`] does it over a recording; [`FixedLagSmoother`] does
//! it online with L+2 epochs of memory.

use std::collections::VecDeque;

use nalgebra::{DMatrix, DVector, SMatrix, SVector};

use crate::gaussian::symmetrize;
use crate::observer::{Observer, PredictEvent, UpdateEvent};
use crate::{Error, ErrorStateModel, Result, Scalar};

/// The result of every runner's `smooth_batch` (e.g.
/// [`crate::KalmanFilter::smooth_batch`]; defined with the runners).
pub use crate::runner::SmoothedBatch;

/// When a [`ForwardRecorder`] opens an epoch.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum RecordAt {
    /// Every predict opens an epoch (smoothed values at every step).
    EveryStep,
    /// Predicts between updates are composed; an epoch ends with its updates
    /// (smoothed values at the update epochs and at the last predict).
    #[default]
    Updates,
}

/// The link from an epoch back to the previous one.
#[derive(Debug, Clone, PartialEq)]
struct Link<T: Scalar, const N: usize> {
    /// E[e_{k-1} | Y_{1:k}] minus the filtered mean of epoch k-1.
    shift: SVector<T, N>,
    /// Cov(e_{k-1} | Y_{1:k}).
    previous_covariance: SMatrix<T, N, N>,
    /// Cov(e_{k-1}, e_k | Y_{1:k}).
    cross: SMatrix<T, N, N>,
}

#[derive(Debug, Clone, PartialEq)]
struct Epoch<T: Scalar, S, const N: usize> {
    state: S,
    covariance: SMatrix<T, N, N>,
    link: Option<Link<T, N>>,
    /// No more predicts join this epoch (it has an update, or is the initial one).
    closed: bool,
    accepted_updates: usize,
}

/// One smoothed epoch.
#[derive(Debug, Clone, PartialEq)]
pub struct Smoothed<T: Scalar, S, const N: usize> {
    /// Index of the epoch in the recording (0 = first recorded).
    pub epoch: usize,
    /// The filtered state (for the error-state filter, the nominal state).
    pub filtered_state: S,
    /// The filtered covariance.
    pub filtered_covariance: SMatrix<T, N, N>,
    /// Smoothed mean minus filtered mean (the smoothed error about the nominal for
    /// the error-state filter).
    pub correction: SVector<T, N>,
    /// The smoothed covariance.
    pub covariance: SMatrix<T, N, N>,
}

impl<T: Scalar, const N: usize> Smoothed<T, SVector<T, N>, N> {
    /// The smoothed state (KF, EKF): filtered + correction.
    pub fn state(&self) -> SVector<T, N> {
        self.filtered_state + self.correction
    }
}

impl<T: Scalar, S, const N: usize> Smoothed<T, S, N> {
    /// The smoothed state of an error-state filter: the correction injected into the
    /// recorded nominal state.
    ///
    /// # Errors
    /// The model's injection errors.
    pub fn injected<P>(&self, model: &P) -> Result<S>
    where
        P: ErrorStateModel<T, N, State = S> + ?Sized,
    {
        model.inject(&self.filtered_state, &self.correction)
    }
}

/// Records the forward pass of a runner for smoothing (see the module docs).
///
/// ```
/// use estim_core::nalgebra::{Matrix1, Matrix1x2, Matrix2, Vector1, Vector2};
/// use estim_core::{KalmanFilter, StateAndCovariance, Zero};
/// use estim_core::smoother::{ForwardRecorder, RecordAt};
///
/// let f = Matrix2::new(1.0, 1.0, 0.0, 1.0);
/// let initial = StateAndCovariance::new(Vector2::zeros(), Matrix2::identity())?;
/// let recorder = ForwardRecorder::from_initial(RecordAt::EveryStep, &initial);
/// let mut kf = KalmanFilter::new(f, Matrix2::identity() * 0.01, Matrix1x2::new(1.0, 0.0),
///     Matrix1::new(0.1), initial)?.with_observer(recorder);
/// for y in [Some(1.0), None, Some(3.1), Some(3.9)] {
///     kf.step(y.map(Vector1::new).as_ref(), &Zero)?;
/// }
/// let smoothed = kf.into_observer().smooth()?;
/// assert_eq!(smoothed.len(), 5); // the initial epoch and four steps
/// // The last epoch's smoothed estimate is the filtered one.
/// assert_eq!(smoothed[4].correction, Vector2::zeros());
/// // Smoothing never increases the variance.
/// assert!(smoothed[1].covariance[(0, 0)] <= smoothed[1].filtered_covariance[(0, 0)]);
/// # Ok::<(), estim_core::Error>(())
/// ```
#[derive(Debug, Clone)]
pub struct ForwardRecorder<T: Scalar, S, const N: usize> {
    mode: RecordAt,
    /// Keep at most this many epochs (oldest dropped); `None` keeps all.
    capacity: Option<usize>,
    epochs: VecDeque<Epoch<T, S, N>>,
    /// Index (in the whole recording) of `epochs[0]`.
    first_index: usize,
    predicts_since_update: usize,
    unsupported: Option<(usize, &'static str)>,
}

impl<T: Scalar, S: Clone, const N: usize> ForwardRecorder<T, S, N> {
    /// A recorder whose first epoch is the first event it sees (the filter's initial
    /// estimate is not smoothed).
    pub fn new(mode: RecordAt) -> Self {
        Self {
            mode,
            capacity: None,
            epochs: VecDeque::new(),
            first_index: 0,
            predicts_since_update: 0,
            unsupported: None,
        }
    }

    /// Keep only the last `epochs` epochs (at least 2); for online fixed-lag use.
    #[must_use]
    pub fn with_capacity(mut self, epochs: usize) -> Self {
        self.capacity = Some(epochs.max(2));
        self
    }

    /// A recorder whose epoch 0 is the filter's initial estimate (then smoothed too).
    /// For the error-state filter pass the nominal state and its error covariance.
    pub fn from_initial_parts(mode: RecordAt, state: S, covariance: SMatrix<T, N, N>) -> Self {
        let mut recorder = Self::new(mode);
        recorder.epochs.push_back(Epoch {
            state,
            covariance,
            link: None,
            closed: true,
            accepted_updates: 0,
        });
        recorder
    }

    /// Number of epochs recorded (held, when a capacity is set).
    pub fn len(&self) -> usize {
        self.epochs.len()
    }

    /// Whether nothing was recorded.
    pub fn is_empty(&self) -> bool {
        self.epochs.is_empty()
    }

    /// Index of the newest epoch in the whole recording, if any.
    pub fn newest_epoch(&self) -> Option<usize> {
        (!self.epochs.is_empty()).then(|| self.first_index + self.epochs.len() - 1)
    }

    /// The first reason the recording cannot be smoothed exactly, if any.
    pub fn unsupported(&self) -> Option<Error> {
        self.unsupported
            .map(|(epoch, reason)| Error::SmootherUnsupported { epoch, reason })
    }

    fn check(&self) -> Result<()> {
        self.unsupported().map_or(Ok(()), Err)
    }

    fn mark_unsupported(&mut self, reason: &'static str) {
        if self.unsupported.is_none() {
            let epoch = self.newest_epoch().unwrap_or(0);
            self.unsupported = Some((epoch, reason));
        }
    }

    fn push_epoch(&mut self, epoch: Epoch<T, S, N>) {
        self.epochs.push_back(epoch);
        if let Some(capacity) = self.capacity {
            while self.epochs.len() > capacity {
                self.epochs.pop_front();
                self.first_index += 1;
            }
        }
    }

    fn record_predict(
        &mut self,
        state: &S,
        covariance: &SMatrix<T, N, N>,
        transition: &SMatrix<T, N, N>,
    ) {
        self.predicts_since_update += 1;
        let extend =
            self.mode == RecordAt::Updates && self.epochs.back().is_some_and(|epoch| !epoch.closed);
        if extend {
            if let Some(last) = self.epochs.back_mut() {
                // Compose the step: Cov(e_prev, Phi e + w) = C Phi'.
                if let Some(link) = last.link.as_mut() {
                    link.cross *= transition.transpose();
                }
                last.state = state.clone();
                last.covariance = *covariance;
            }
            return;
        }
        let link = self.epochs.back().map(|previous| Link {
            shift: SVector::zeros(),
            previous_covariance: previous.covariance,
            cross: previous.covariance * transition.transpose(),
        });
        self.push_epoch(Epoch {
            state: state.clone(),
            covariance: *covariance,
            link,
            closed: self.mode == RecordAt::EveryStep,
            accepted_updates: 0,
        });
    }

    fn record_update(&mut self, event: &UpdateEvent<'_, T, S, N>) -> Result<()> {
        let correlated = event.cross_covariance.iter().any(|v| !v.is_zero());
        match (event.window_steps, self.mode) {
            (Some(window), RecordAt::Updates) if window > self.predicts_since_update => {
                self.mark_unsupported(
                    "windowed update whose window reaches back past the previous update (recorded at updates, its noise is then correlated with the previous epoch's error)",
                );
            }
            (Some(window), RecordAt::EveryStep) if window > 1 => {
                self.mark_unsupported(
                    "windowed update over more than one step recorded at every step (its noise is correlated with several epochs; record with RecordAt::Updates)",
                );
            }
            _ => {}
        }
        if event.covariance_inflation.is_some() {
            self.mark_unsupported(
                "update accepted by the gate's recovery rule with an inflated prior covariance \
                 (not a Kalman step of the recorded model; GateRecovery::None to smooth)",
            );
        }
        let Some(last) = self.epochs.back() else {
            // An update before any predict: the epoch starts at its posterior.
            self.predicts_since_update = 0;
            self.push_epoch(Epoch {
                state: event.state.clone(),
                covariance: *event.covariance,
                link: None,
                closed: true,
                accepted_updates: 1,
            });
            return Ok(());
        };
        if correlated && last.accepted_updates > 0 {
            self.mark_unsupported(
                "correlated update after another update at the same epoch (its noise is then correlated with the previous epoch's error)",
            );
        }
        // A one-step M after several predicts does not say which of them v shares; a
        // windowed M over one step does (the last one).
        if correlated
            && event.window_steps.is_none()
            && self.mode == RecordAt::EveryStep
            && self.predicts_since_update > 1
        {
            self.mark_unsupported(
                "correlated update after several predicts recorded at every step (how v shares the interval's noise is unknown; record with RecordAt::Updates)",
            );
        }
        self.predicts_since_update = 0;
        let m = event.measurement_size;
        let gain = match event.gain {
            Some(gain) => gain,
            None => return Ok(()),
        };
        let Some(last) = self.epochs.back_mut() else {
            return Ok(());
        };
        if let Some(link) = last.link.as_mut() {
            let jacobian = DMatrix::from_column_slice(m, N, event.jacobian);
            let innovation_covariance =
                DMatrix::from_column_slice(m, m, event.innovation_covariance);
            let innovation = DVector::from_column_slice(event.innovation);
            let gain = DMatrix::from_column_slice(N, m, gain);
            let cross = DMatrix::from_column_slice(N, N, link.cross.as_slice());
            // Cov(e_k, y) = C H'; A = C H' S^-1 = (S^-1 H C')'.
            let cov_prev_y = &cross * jacobian.transpose();
            let solved = solve_spd(innovation_covariance, cov_prev_y.transpose())?;
            let a = solved.transpose();
            let shift = &a * innovation;
            let reduction = &a * cov_prev_y.transpose();
            let mut transform = DMatrix::<T>::identity(N, N) - &gain * &jacobian;
            if let Some(reset) = event.reset {
                transform = DMatrix::from_column_slice(N, N, reset.as_slice()) * transform;
            }
            let new_cross = cross * transform.transpose();
            for i in 0..N {
                link.shift[i] += shift[i];
                for j in 0..N {
                    link.previous_covariance[(i, j)] -= reduction[(i, j)];
                    link.cross[(i, j)] = new_cross[(i, j)];
                }
            }
            link.previous_covariance = symmetrize(&link.previous_covariance);
        }
        last.state = event.state.clone();
        last.covariance = *event.covariance;
        last.closed = true;
        last.accepted_updates += 1;
        Ok(())
    }

    /// Backward pass over the held epochs with positions `from..=to` (positions in
    /// `self.epochs`), returning them oldest first.
    fn backward(&self, from: usize, to: usize) -> Result<Vec<Smoothed<T, S, N>>> {
        let mut out = Vec::with_capacity(to + 1 - from);
        let newest = &self.epochs[to];
        let mut correction = SVector::<T, N>::zeros();
        let mut covariance = newest.covariance;
        out.push(self.smoothed(to, correction, covariance));
        for k in (from..to).rev() {
            let next = &self.epochs[k + 1];
            let Some(link) = next.link.as_ref() else {
                return Err(Error::SmootherUnsupported {
                    epoch: self.first_index + k,
                    reason: "no link to this epoch was recorded",
                });
            };
            // G = C P_{k+1}^-1, i.e. G' = P_{k+1}^-1 C'.
            let gain = next
                .covariance
                .cholesky()
                .map(|c| c.solve(&link.cross.transpose()).transpose())
                .ok_or_else(|| Error::InvalidCovariance {
                    what: "filtered covariance (smoother gain)",
                    reason: format!(
                        "not positive definite at epoch {}",
                        self.first_index + k + 1
                    ),
                })?;
            correction = link.shift + gain * correction;
            covariance = symmetrize(
                &(link.previous_covariance
                    + gain * (covariance - next.covariance) * gain.transpose()),
            );
            if correction.iter().any(|v| !v.is_finite())
                || covariance.iter().any(|v| !v.is_finite())
            {
                return Err(Error::NonFinite {
                    what: "smoothed estimate",
                });
            }
            out.push(self.smoothed(k, correction, covariance));
        }
        out.reverse();
        Ok(out)
    }

    fn smoothed(
        &self,
        position: usize,
        correction: SVector<T, N>,
        covariance: SMatrix<T, N, N>,
    ) -> Smoothed<T, S, N> {
        let epoch = &self.epochs[position];
        Smoothed {
            epoch: self.first_index + position,
            filtered_state: epoch.state.clone(),
            filtered_covariance: epoch.covariance,
            correction,
            covariance,
        }
    }

    /// Fixed-interval smoothing: every held epoch given every recorded measurement.
    ///
    /// # Errors
    /// [`Error::SmootherUnsupported`] (module docs), [`Error::InvalidCovariance`] if a
    /// filtered covariance is not positive definite, [`Error::NonFinite`].
    pub fn smooth(&self) -> Result<Vec<Smoothed<T, S, N>>> {
        self.check()?;
        if self.epochs.is_empty() {
            return Ok(Vec::new());
        }
        self.backward(0, self.epochs.len() - 1)
    }

    /// Fixed-lag smoothing: epoch k given the measurements up to epoch k + `lag`
    /// (or the last), for every held epoch. `lag = 0` gives the filtered estimates.
    ///
    /// # Errors
    /// As [`ForwardRecorder::smooth`].
    pub fn fixed_lag(&self, lag: usize) -> Result<Vec<Smoothed<T, S, N>>> {
        self.check()?;
        let len = self.epochs.len();
        let mut out = Vec::with_capacity(len);
        for k in 0..len {
            let to = (k + lag).min(len - 1);
            let mut window = self.backward(k, to)?;
            out.push(window.swap_remove(0));
        }
        Ok(out)
    }
}

impl<T: Scalar, S: Clone, const N: usize> ForwardRecorder<T, S, N> {
    /// A recorder whose epoch 0 is a KF/EKF initial estimate.
    pub fn from_initial(mode: RecordAt, initial: &crate::StateAndCovariance<T, N>) -> Self
    where
        S: From<SVector<T, N>>,
    {
        Self::from_initial_parts(mode, S::from(*initial.state()), *initial.covariance())
    }
}

/// x = S^-1 b for a symmetric positive definite S (Cholesky, LU as a fallback for a
/// numerically semidefinite one the forward pass accepted).
fn solve_spd<T: Scalar>(s: DMatrix<T>, b: DMatrix<T>) -> Result<DMatrix<T>> {
    if let Some(chol) = s.clone().cholesky() {
        return Ok(chol.solve(&b));
    }
    s.lu().solve(&b).ok_or(Error::InnovationNotPositiveDefinite)
}

impl<T: Scalar, S: Clone, const N: usize> Observer<T, S, N> for ForwardRecorder<T, S, N> {
    fn on_predict(&mut self, event: &PredictEvent<'_, T, S, N>) -> Result<()> {
        self.record_predict(event.state, event.covariance, event.transition);
        Ok(())
    }

    fn on_update(&mut self, event: &UpdateEvent<'_, T, S, N>) -> Result<()> {
        if let Err(error) = self.record_update(event) {
            // Keep the forward pass running; the smoother reports it.
            let _ = error;
            self.mark_unsupported("an update's innovation covariance could not be factored");
        }
        Ok(())
    }

    fn on_rejected(&mut self, _event: &UpdateEvent<'_, T, S, N>) -> Result<()> {
        // Observed nothing; it still closes the filter's accumulation interval.
        self.predicts_since_update = 0;
        Ok(())
    }
}

/// Online fixed-lag smoother: an [`Observer`] that holds the last `lag + 2` epochs
/// and, each time an epoch is complete (the next one opens), emits the estimate of
/// the epoch `lag` before it given everything up to it.
///
/// ```
/// use estim_core::nalgebra::{Matrix1, Matrix1x2, Matrix2, Vector1, Vector2};
/// use estim_core::smoother::FixedLagSmoother;
/// use estim_core::{KalmanFilter, StateAndCovariance, Zero};
/// use estim_core::smoother::RecordAt;
///
/// let initial = StateAndCovariance::new(Vector2::zeros(), Matrix2::identity())?;
/// let mut kf = KalmanFilter::new(Matrix2::new(1.0, 1.0, 0.0, 1.0),
///     Matrix2::identity() * 0.01, Matrix1x2::new(1.0, 0.0), Matrix1::new(0.1), initial)?
///     .with_observer(FixedLagSmoother::new(RecordAt::EveryStep, 2));
/// for k in 0..10 {
///     kf.step(Some(&Vector1::new(k as f64)), &Zero)?;
/// }
/// let lagged = kf.into_observer().finish()?;
/// assert_eq!(lagged.len(), 10);
/// assert_eq!(lagged[3].epoch, 3);
/// # Ok::<(), estim_core::Error>(())
/// ```
#[derive(Debug, Clone)]
pub struct FixedLagSmoother<T: Scalar, S, const N: usize> {
    recorder: ForwardRecorder<T, S, N>,
    lag: usize,
    emitted: Vec<Smoothed<T, S, N>>,
    /// Next epoch index to emit.
    next: usize,
}

impl<T: Scalar, S: Clone, const N: usize> FixedLagSmoother<T, S, N> {
    /// A fixed-lag smoother with `lag` epochs, recording as `mode`.
    pub fn new(mode: RecordAt, lag: usize) -> Self {
        Self::from_recorder(ForwardRecorder::new(mode), lag)
    }

    /// From a recorder (e.g. [`ForwardRecorder::from_initial_parts`]); its capacity
    /// is set to `lag + 2` epochs.
    pub fn from_recorder(recorder: ForwardRecorder<T, S, N>, lag: usize) -> Self {
        Self {
            recorder: recorder.with_capacity(lag + 2),
            lag,
            emitted: Vec::new(),
            next: 0,
        }
    }

    /// The estimates emitted so far, oldest first.
    pub fn emitted(&self) -> &[Smoothed<T, S, N>] {
        &self.emitted
    }

    /// Emit the estimate of every complete epoch whose lag is reached, where
    /// `complete` is the index of the newest complete epoch.
    fn emit_up_to(&mut self, complete: usize, final_pass: bool) -> Result<()> {
        let first = self.recorder.first_index;
        while self.next <= complete && (final_pass || self.next + self.lag <= complete) {
            let to = (self.next + self.lag).min(complete);
            let mut window = self.recorder.backward(self.next - first, to - first)?;
            self.emitted.push(window.swap_remove(0));
            self.next += 1;
        }
        Ok(())
    }

    /// Smooth the epochs still waiting for their lag with what was recorded and
    /// return every estimate, oldest first.
    ///
    /// # Errors
    /// As [`ForwardRecorder::smooth`].
    pub fn finish(mut self) -> Result<Vec<Smoothed<T, S, N>>> {
        self.recorder.check()?;
        if let Some(newest) = self.recorder.newest_epoch() {
            self.emit_up_to(newest, true)?;
        }
        Ok(self.emitted)
    }
}

impl<T: Scalar, S: Clone, const N: usize> Observer<T, S, N> for FixedLagSmoother<T, S, N> {
    fn on_predict(&mut self, event: &PredictEvent<'_, T, S, N>) -> Result<()> {
        let before = self.recorder.newest_epoch();
        self.recorder.on_predict(event)?;
        let after = self.recorder.newest_epoch();
        if let (Some(complete), true) = (before, after != before) {
            if self.recorder.unsupported.is_none() {
                // An error here (a covariance that is not positive definite) is kept
                // for `finish`; the forward pass goes on.
                if let Err(error) = self.emit_up_to(complete, false) {
                    let _ = error;
                    self.recorder
                        .mark_unsupported("a filtered covariance was not positive definite");
                }
            }
        }
        Ok(())
    }

    fn on_update(&mut self, event: &UpdateEvent<'_, T, S, N>) -> Result<()> {
        self.recorder.on_update(event)
    }

    fn on_rejected(&mut self, event: &UpdateEvent<'_, T, S, N>) -> Result<()> {
        self.recorder.on_rejected(event)
    }
}
