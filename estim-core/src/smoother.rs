//! Rauch-Tung-Striebel smoothing (fixed interval and fixed lag) over a recorded
//! forward pass, consistent with correlated process and measurement noise.
//!
//! ## Recording
//!
//! A [`ForwardRecorder`] is an [`Observer`]: attach it to any runner
//! ([`crate::KalmanFilter`], [`crate::ExtendedKalmanFilter`],
//! [`crate::ErrorStateKalmanFilter`], [`crate::SquareRootKalmanFilter`],
//! [`crate::UnscentedKalmanFilter`]; for the last, whose events carry the statistical
//! linearisations of its sigma points, the unscented RTS smoother) and it keeps, per *epoch*, the filtered state and
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
//! with the process noise since the previous epoch. A windowed update
//! ([`crate::WindowedCrossCovariance`]) whose window reaches further back, or that
//! follows another update of its epoch, is smoothed with an augmented state (next
//! section). When the recording cannot give the answer exactly,
//! [`ForwardRecorder::smooth`] returns [`Error::SmootherUnsupported`] naming the
//! epoch, never a number:
//!
//! - an update the gate's recovery rule accepted with an inflated prior covariance
//!   ([`crate::GateRecovery::Inflate`]) inside a correlated window over several
//!   epochs (elsewhere such an update is smoothed exactly as the forward pass ran:
//!   its step is the Kalman step of the model with an extra, independent process noise
//!   (lambda - 1) P at that epoch, the smoothed values those of that model);
//! - a one-step correlated update (M != 0 from a [`crate::CrossCovariance`]) that is
//!   not the first accepted update of its epoch (the earlier update made its noise
//!   correlated with e_k), or, with [`RecordAt::EveryStep`], that follows more than
//!   one predict: M = Cov(sum of the interval's noise, v) does not say how v is shared
//!   between the intermediate steps (record with [`RecordAt::Updates`], where M is
//!   exactly the cross-covariance with the composed step, or state the sharing with a
//!   windowed M);
//! - a correlated window that starts before the recording (a recorder attached after
//!   its first step), or a D_j outside the range of its step's Q_j (no valid joint
//!   covariance has those blocks).
//!
//! A windowed update inside its epoch needs no augmentation: with
//! [`RecordAt::Updates`] a window within the interval since the previous update makes
//! the window's C = sum_j Phi(k, j) D_j the cross-covariance with the composed step (no
//! other update lies inside it, so Var(v) = R and E\[v\] = 0); with
//! [`RecordAt::EveryStep`] a one-step window is the textbook Cov(w_{k-1}, v_k), also
//! after unmeasured steps.
//!
//! ## Windows over several epochs
//!
//! A measurement whose noise shares the process noise of L steps, D_j = Cov(G_j w_j,
//! v), decomposes as v = s + v_perp with s = sum_j B_j G_j w_j, B_j = D_j' Q_j^+ (the
//! regression of v on the window's noise; exact when D_j lies in the range of Q_j,
//! which a valid joint covariance guarantees) and v_perp independent of every w. The
//! partial sum s_i over the window's steps up to epoch i is what makes the epochs of
//! the window Markov again: given [e_i; s_i] and Y up to i, the earlier epochs are
//! independent of every later measurement. So inside the window the recorder smooths
//! the augmented state z_i = [e_i; s_i] (e alone at the window's last epoch, after
//! its update, and before the window). The runner hands the window's Phi_j, Q_j, D_j
//! and the other updates inside it (J (I - K H), H' S^-1 H, H' S^-1 nu) with the
//! windowed update ([`crate::UpdateEvent::window`], asked for by
//! [`Observer::wants_window`]); the recorder then fills, epoch by epoch, with
//! C_s = Cov(e, s) and V_s = Var(s):
//!
//! ```text
//! each step j:           C_s <- Phi_j C_s + D_j        V_s <- V_s + D_j' Q_j^+ D_j
//! another update (M=0):  V_s <- V_s - C_s' H'S^-1H C_s  C_s <- J (I - K H) C_s
//! filtered Cov(z_i)    = [[P_i, C_s], [C_s', V_s]]
//! link, before epoch i's updates: Cov(z_{i-1}, e_i) = Cov(z_{i-1}, e_{i-1}) Phi_i',
//!                        Cov(z_{i-1}, s_i) = Cov(z_{i-1}, s_{i-1})
//! ```
//!
//! and conditions each link on its epoch's updates as above, the windowed one with
//! Cov(z_{i-1}, y) = Cov(z_{i-1}, e_i) H' + Cov(z_{i-1}, s_i) (its noise is s + v_perp).
//! The backward pass is the one above in these coordinates, with P^+ (scale-free
//! pseudo-inverse) where s is still zero or determined by e. This equals joint-Gaussian
//! conditioning of the stacked problem for windows over any number of epochs with
//! other updates inside, recorded either way, for the linear filter (plain and square
//! root), the EKF, the error-state filter and the UKF, fixed interval, fixed lag and
//! online (`tests/smoother.rs`,
//! `windows_over_several_epochs_*`, to 1e-9 relative). The cost is L N^3 per
//! windowed update in the forward pass (each step's Q_j^+ from its
//! eigendecomposition, and the runner asks the model for the D_j once more) and
//! (N + M)^3 per augmented epoch in the backward one: at N = 15, M = 3 and windows of
//! 10 steps, the recorded forward pass costs 6.1 times the plain one and smoothing
//! 2,000 epochs 50.8 ms (`cargo bench -p estim-core --bench smoother`). The online
//! [`FixedLagSmoother`] needs no more memory (epochs it no longer holds are only
//! passed through).
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
use crate::window::RecordedWindow;
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
    /// As [`RecordAt::Updates`], and a measurement the gate rejected also ends its
    /// epoch (smoothed values at every measurement epoch, accepted or not, as a
    /// filter reports them).
    Measurements,
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
    /// Number of predicts composed into the epoch (0 for an initial one).
    steps: usize,
    /// Their composed transition Phi (identity for an initial epoch).
    transition: SMatrix<T, N, N>,
    /// Set when the epoch lies in a correlated window that spans several epochs.
    augmented: Option<Augmented<T>>,
}

/// An epoch inside a correlated window that spans several epochs: its Markov state
/// is e augmented with s, the part of the window's measurement noise shared so far
/// (module docs, "Windows over several epochs").
#[derive(Debug, Clone, PartialEq)]
struct Augmented<T: Scalar> {
    /// Cov([e; s] | Y up to the epoch); `None`: the state is e alone (the epoch of
    /// the windowed update itself).
    covariance: Option<DMatrix<T>>,
    /// The link back to the previous epoch in these coordinates (`None` when the
    /// previous epoch is not held).
    link: Option<DynamicLink<T>>,
}

/// [`Link`] in augmented (dynamic) coordinates.
#[derive(Debug, Clone, PartialEq)]
struct DynamicLink<T: Scalar> {
    shift: DVector<T>,
    previous_covariance: DMatrix<T>,
    cross: DMatrix<T>,
}

impl<T: Scalar> DynamicLink<T> {
    fn from_static<const N: usize>(link: &Link<T, N>) -> Self {
        Self {
            shift: DVector::from_column_slice(link.shift.as_slice()),
            previous_covariance: DMatrix::from_column_slice(
                N,
                N,
                link.previous_covariance.as_slice(),
            ),
            cross: DMatrix::from_column_slice(N, N, link.cross.as_slice()),
        }
    }

    /// Joint-Gaussian conditioning of the link on one accepted update (innovation nu,
    /// covariance S, gain K, reset J) whose noise has covariance `noise_cross` with
    /// the previous epoch's state (`None`: zero):
    ///
    /// ```text
    /// Cov(z_prev, y) = C H' + X        A = Cov(z_prev, y) S^-1
    /// shift += A nu     P_prev -= A Cov(z_prev, y)'     C <- (C - Cov(z_prev, y) K') J'
    /// ```
    fn condition(
        &mut self,
        update: &UpdateTerms<T>,
        noise_cross: Option<&DMatrix<T>>,
    ) -> Result<()> {
        let mut cov_prev_y = &self.cross * update.jacobian.transpose();
        if let Some(x) = noise_cross {
            cov_prev_y += x;
        }
        let a =
            solve_spd(update.innovation_covariance.clone(), cov_prev_y.transpose())?.transpose();
        self.shift += &a * &update.innovation;
        self.previous_covariance -= &a * cov_prev_y.transpose();
        self.previous_covariance = symmetrize_dynamic(&self.previous_covariance);
        let mut cross = &self.cross - &cov_prev_y * update.gain.transpose();
        if let Some(reset) = update.reset.as_ref() {
            cross *= reset.transpose();
        }
        self.cross = cross;
        Ok(())
    }
}

/// One accepted update's terms, in dynamic matrices.
struct UpdateTerms<T: Scalar> {
    jacobian: DMatrix<T>,
    innovation_covariance: DMatrix<T>,
    innovation: DVector<T>,
    gain: DMatrix<T>,
    reset: Option<DMatrix<T>>,
}

impl<T: Scalar> UpdateTerms<T> {
    /// The terms of an update the gate's recovery rule accepted with its prior
    /// covariance P scaled by `lambda`: the filter's step is then the Kalman step of a
    /// model with an extra, independent process noise (lambda - 1) P at this epoch, so
    /// the innovation covariance the gain used is S + (lambda - 1) H P H' (the report
    /// carries the S before the inflation; the link's cross-covariance with the
    /// previous epoch is unchanged by an independent noise).
    fn inflate<const N: usize>(&mut self, prior: &SMatrix<T, N, N>, lambda: T) {
        let p = DMatrix::from_column_slice(N, N, prior.as_slice());
        let extra = &self.jacobian * p * self.jacobian.transpose() * (lambda - T::one());
        self.innovation_covariance += extra;
    }

    fn new<S, const N: usize>(event: &UpdateEvent<'_, T, S, N>, gain: &[T]) -> Self {
        let m = event.measurement_size;
        Self {
            jacobian: DMatrix::from_column_slice(m, N, event.jacobian),
            innovation_covariance: DMatrix::from_column_slice(m, m, event.innovation_covariance),
            innovation: DVector::from_column_slice(event.innovation),
            gain: DMatrix::from_column_slice(N, m, gain),
            reset: event
                .reset
                .map(|j| DMatrix::from_column_slice(N, N, j.as_slice())),
        }
    }
}

fn symmetrize_dynamic<T: Scalar>(m: &DMatrix<T>) -> DMatrix<T> {
    (m + m.transpose()) * crate::scalar::lit::<T>(0.5)
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
            steps: 0,
            transition: SMatrix::identity(),
            augmented: None,
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
        let extend = self.mode != RecordAt::EveryStep
            && self.epochs.back().is_some_and(|epoch| !epoch.closed);
        if extend {
            if let Some(last) = self.epochs.back_mut() {
                // Compose the step: Cov(e_prev, Phi e + w) = C Phi'.
                if let Some(link) = last.link.as_mut() {
                    link.cross *= transition.transpose();
                }
                last.transition = transition * last.transition;
                last.steps += 1;
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
            steps: 1,
            transition: *transition,
            augmented: None,
        });
    }

    fn record_update(&mut self, event: &UpdateEvent<'_, T, S, N>) -> Result<()> {
        let correlated = event.cross_covariance.iter().any(|v| !v.is_zero());
        let Some(last) = self.epochs.back() else {
            // An update before any predict: the epoch starts at its posterior.
            self.predicts_since_update = 0;
            self.push_epoch(Epoch {
                state: event.state.clone(),
                covariance: *event.covariance,
                link: None,
                closed: true,
                accepted_updates: 1,
                steps: 0,
                transition: SMatrix::identity(),
                augmented: None,
            });
            return Ok(());
        };
        // A correlated window that reaches back past this epoch's start, or follows
        // another update of the epoch: smoothed with the augmented state.
        let augment = correlated
            && match (event.window_steps, self.mode) {
                (Some(window), RecordAt::Updates | RecordAt::Measurements) => {
                    window > self.predicts_since_update || last.accepted_updates > 0
                }
                (Some(window), RecordAt::EveryStep) => window > 1 || last.accepted_updates > 0,
                (None, _) => false,
            };
        if correlated && !augment && last.accepted_updates > 0 {
            self.mark_unsupported(
                "correlated one-step update after another update at the same epoch (its noise is then correlated with the previous epoch's error; state the window with a WindowedCrossCovariance)",
            );
        }
        // A one-step M after several predicts does not say which of them v shares; a
        // windowed M does.
        if correlated
            && event.window_steps.is_none()
            && self.mode == RecordAt::EveryStep
            && self.predicts_since_update > 1
        {
            self.mark_unsupported(
                "correlated one-step update after several predicts recorded at every step (how v shares the interval's noise is unknown; record with RecordAt::Updates, or state the window with a WindowedCrossCovariance)",
            );
        }
        self.predicts_since_update = 0;
        let Some(gain) = event.gain else {
            return Ok(());
        };
        let mut terms = UpdateTerms::new(event, gain);
        if let Some(lambda) = event.covariance_inflation {
            if augment {
                self.mark_unsupported(
                    "update accepted by the gate's recovery rule with an inflated prior \
                     covariance inside a correlated window over several epochs",
                );
            }
            terms.inflate(event.prior_covariance, lambda);
        }
        if augment {
            match event.window {
                Some(window) => {
                    if let Err(reason) = self.augment_window(window, &terms) {
                        self.mark_unsupported(reason);
                    }
                }
                None => self.mark_unsupported(
                    "windowed update over several epochs without its recorded window (an observer wrapper that does not forward Observer::wants_window)",
                ),
            }
        } else if let Some(last) = self.epochs.back_mut() {
            if let Some(link) = last.augmented.as_mut().and_then(|a| a.link.as_mut()) {
                link.condition(&terms, None)?;
            }
            if let Some(link) = last.link.as_mut() {
                let mut dynamic = DynamicLink::from_static(link);
                dynamic.condition(&terms, None)?;
                link.shift = SVector::from_column_slice(dynamic.shift.as_slice());
                link.previous_covariance =
                    SMatrix::from_column_slice(dynamic.previous_covariance.as_slice());
                link.cross = SMatrix::from_column_slice(dynamic.cross.as_slice());
            }
        }
        let Some(last) = self.epochs.back_mut() else {
            return Ok(());
        };
        last.state = event.state.clone();
        last.covariance = *event.covariance;
        last.closed = true;
        last.accepted_updates += 1;
        Ok(())
    }

    /// The augmented links and covariances of the epochs a correlated window spans
    /// (module docs, "Windows over several epochs"), ending with the windowed update
    /// `update` itself on the newest epoch. Writes nothing unless all of it succeeds.
    fn augment_window(
        &mut self,
        window: &dyn RecordedWindow<T, N>,
        update: &UpdateTerms<T>,
    ) -> std::result::Result<(), &'static str> {
        const NOT_RECORDED: &str = "a windowed update's recorded window is incomplete";
        let m = update.innovation.len();
        let length = window.steps();
        // The window's steps on the held epochs, newest first: (epoch, first, last).
        let mut segments: Vec<(Option<usize>, usize, usize)> = Vec::new();
        let mut remaining = length;
        let mut position = self.epochs.len();
        while remaining > 0 {
            if position == 0 {
                if self.first_index == 0 {
                    return Err("a windowed update's window starts before the recording");
                }
                segments.push((None, 0, remaining - 1));
                break;
            }
            position -= 1;
            let steps = self.epochs[position].steps;
            if steps == 0 {
                return Err("a windowed update's window starts before the recording");
            }
            let first = remaining.saturating_sub(steps);
            segments.push((Some(position), first, remaining - 1));
            remaining = first;
        }
        segments.reverse();
        if segments.last().map(|s| s.0) != Some(Some(self.epochs.len() - 1)) {
            return Err(NOT_RECORDED);
        }
        let mut cs = DMatrix::<T>::zeros(N, m);
        let mut vs = DMatrix::<T>::zeros(m, m);
        let mut next_update = 0;
        let mut results: Vec<(usize, Augmented<T>)> = Vec::with_capacity(segments.len());
        for (i, &(epoch, first, last)) in segments.iter().enumerate() {
            let newest = i + 1 == segments.len();
            // The link needs the previous epoch; before the window's first epoch its
            // state is e alone (nothing of the window shared yet).
            let shared_before = if i > 0 { m } else { 0 };
            let mut link = match epoch {
                Some(q) if q > 0 => {
                    let previous = &self.epochs[q - 1];
                    let dim = N + shared_before;
                    let mut prior = DMatrix::<T>::zeros(dim, dim);
                    prior
                        .view_mut((0, 0), (N, N))
                        .copy_from_slice(previous.covariance.as_slice());
                    if shared_before > 0 {
                        prior.view_mut((0, N), (N, m)).copy_from(&cs);
                        prior.view_mut((N, 0), (m, N)).copy_from(&cs.transpose());
                        prior.view_mut((N, N), (m, m)).copy_from(&vs);
                    }
                    let phi =
                        DMatrix::from_column_slice(N, N, self.epochs[q].transition.as_slice());
                    // Cov(z_prev, e) = Cov(z_prev, e_prev) Phi' and Cov(z_prev, s) =
                    // Cov(z_prev, s_prev) before the epoch's updates.
                    let cross_e = prior.columns(0, N) * phi.transpose();
                    let cross_s = if shared_before > 0 {
                        prior.columns(N, m).into_owned()
                    } else {
                        DMatrix::zeros(dim, m)
                    };
                    Some((
                        DynamicLink {
                            shift: DVector::zeros(dim),
                            previous_covariance: prior,
                            cross: cross_e,
                        },
                        cross_s,
                    ))
                }
                _ => None,
            };
            for p in first..=last {
                let phi = window.transition(p).ok_or(NOT_RECORDED)?;
                let q = window.process_noise(p).ok_or(NOT_RECORDED)?;
                let d = window.step_cross_covariance(p).ok_or(NOT_RECORDED)?;
                let d = DMatrix::from_column_slice(N, m, d);
                let phi = DMatrix::from_column_slice(N, N, phi.as_slice());
                let q = DMatrix::from_column_slice(N, N, q.as_slice());
                vs += shared_noise_increment(&q, &d).ok_or(
                    "a window step's D_j is not in the range of its process noise (the joint covariance of the window is not valid)",
                )?;
                cs = phi * cs + d;
                while let Some(u) = window.update(next_update).filter(|u| u.after_step == p) {
                    if link.is_some() && p != last {
                        return Err("an update inside an epoch's composed steps");
                    }
                    let transform = DMatrix::from_column_slice(N, N, u.transform.as_slice());
                    let information = DMatrix::from_column_slice(N, N, u.information.as_slice());
                    let weighted = DVector::from_column_slice(u.weighted_innovation.as_slice());
                    if let Some((link, cross_s)) = link.as_mut() {
                        let xi = &link.cross * &information;
                        link.shift += &link.cross * &weighted;
                        link.previous_covariance -= &xi * link.cross.transpose();
                        *cross_s -= &xi * &cs;
                        link.cross = &link.cross * transform.transpose();
                    }
                    vs -= cs.transpose() * &information * &cs;
                    cs = transform * cs;
                    next_update += 1;
                }
            }
            let Some(q) = epoch else {
                continue;
            };
            if newest {
                let link = match link {
                    Some((mut link, cross_s)) => {
                        link.condition(update, Some(&cross_s)).map_err(|_| {
                            "a windowed update's innovation covariance could not be factored"
                        })?;
                        Some(link)
                    }
                    None => None,
                };
                results.push((
                    q,
                    Augmented {
                        covariance: None,
                        link,
                    },
                ));
            } else {
                let dim = N + m;
                let mut covariance = DMatrix::<T>::zeros(dim, dim);
                covariance
                    .view_mut((0, 0), (N, N))
                    .copy_from_slice(self.epochs[q].covariance.as_slice());
                covariance.view_mut((0, N), (N, m)).copy_from(&cs);
                covariance
                    .view_mut((N, 0), (m, N))
                    .copy_from(&cs.transpose());
                covariance
                    .view_mut((N, N), (m, m))
                    .copy_from(&symmetrize_dynamic(&vs));
                let link = link.map(|(mut link, cross_s)| {
                    let rows = link.cross.nrows();
                    let mut cross = DMatrix::<T>::zeros(rows, dim);
                    cross.columns_mut(0, N).copy_from(&link.cross);
                    cross.columns_mut(N, m).copy_from(&cross_s);
                    link.cross = cross;
                    link.previous_covariance = symmetrize_dynamic(&link.previous_covariance);
                    link
                });
                results.push((
                    q,
                    Augmented {
                        covariance: Some(covariance),
                        link,
                    },
                ));
            }
        }
        if next_update != window.updates() {
            return Err(NOT_RECORDED);
        }
        if results
            .iter()
            .any(|(q, _)| self.epochs[*q].augmented.is_some())
        {
            return Err("correlated windows that overlap on an epoch");
        }
        for (q, augmented) in results {
            self.epochs[q].augmented = Some(augmented);
        }
        Ok(())
    }

    /// Backward pass over the held epochs with positions `from..=to` (positions in
    /// `self.epochs`), returning them oldest first.
    fn backward(&self, from: usize, to: usize) -> Result<Vec<Smoothed<T, S, N>>> {
        if self.epochs.range(from..=to).any(|e| e.augmented.is_some()) {
            self.backward_augmented(from, to)
        } else {
            self.backward_static(from, to)
        }
    }

    /// The epoch's Markov-state covariance (augmented inside a window).
    fn markov_covariance(&self, position: usize) -> DMatrix<T> {
        let epoch = &self.epochs[position];
        match epoch.augmented.as_ref().and_then(|a| a.covariance.as_ref()) {
            Some(covariance) => covariance.clone(),
            None => DMatrix::from_column_slice(N, N, epoch.covariance.as_slice()),
        }
    }

    /// [`ForwardRecorder::backward_static`] in the epochs' Markov coordinates, e
    /// augmented with s inside a correlated window (module docs).
    fn backward_augmented(&self, from: usize, to: usize) -> Result<Vec<Smoothed<T, S, N>>> {
        let head = |c: &DVector<T>, p: &DMatrix<T>| {
            (
                SVector::<T, N>::from_fn(|i, _| c[i]),
                SMatrix::<T, N, N>::from_fn(|i, j| p[(i, j)]),
            )
        };
        let mut out = Vec::with_capacity(to + 1 - from);
        let mut covariance = self.markov_covariance(to);
        let mut correction = DVector::<T>::zeros(covariance.nrows());
        let (c, p) = head(&correction, &covariance);
        out.push(self.smoothed(to, c, p));
        for k in (from..to).rev() {
            let unsupported = |reason| Error::SmootherUnsupported {
                epoch: self.first_index + k,
                reason,
            };
            let next = &self.epochs[k + 1];
            let link = match (
                next.augmented.as_ref().and_then(|a| a.link.as_ref()),
                next.link.as_ref(),
            ) {
                (Some(link), _) => link.clone(),
                (None, Some(link)) => DynamicLink::from_static(link),
                (None, None) => return Err(unsupported("no link to this epoch was recorded")),
            };
            let next_covariance = self.markov_covariance(k + 1);
            if link.cross.ncols() != next_covariance.nrows()
                || correction.len() != next_covariance.nrows()
                || link.cross.nrows() != link.shift.len()
            {
                return Err(unsupported("inconsistent augmented link"));
            }
            // G = C P_{k+1}^+ (a pseudo-inverse where a shared part is still zero).
            let gain = psd_solve(&next_covariance, &link.cross.transpose())
                .ok_or_else(|| Error::InvalidCovariance {
                    what: "filtered covariance (smoother gain)",
                    reason: format!(
                        "not positive semidefinite at epoch {}",
                        self.first_index + k + 1
                    ),
                })?
                .transpose();
            correction = &link.shift + &gain * &correction;
            covariance = symmetrize_dynamic(
                &(&link.previous_covariance
                    + &gain * (&covariance - &next_covariance) * gain.transpose()),
            );
            if correction.iter().any(|v| !v.is_finite())
                || covariance.iter().any(|v| !v.is_finite())
            {
                return Err(Error::NonFinite {
                    what: "smoothed estimate",
                });
            }
            let (c, p) = head(&correction, &covariance);
            out.push(self.smoothed(k, c, p));
        }
        out.reverse();
        Ok(out)
    }

    fn backward_static(&self, from: usize, to: usize) -> Result<Vec<Smoothed<T, S, N>>> {
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
            // G = C P_{k+1}^-1, i.e. G' = P_{k+1}^-1 C'; a pseudo-inverse where P_{k+1}
            // is only semidefinite (states held at their value: zero rows and columns,
            // zero in C too).
            let gain = match next.covariance.cholesky() {
                Some(c) => Some(c.solve(&link.cross.transpose()).transpose()),
                None => psd_solve(
                    &DMatrix::from_column_slice(N, N, next.covariance.as_slice()),
                    &DMatrix::from_column_slice(N, N, link.cross.transpose().as_slice()),
                )
                .map(|g| SMatrix::<T, N, N>::from_column_slice(g.transpose().as_slice())),
            }
            .ok_or_else(|| Error::InvalidCovariance {
                what: "filtered covariance (smoother gain)",
                reason: format!(
                    "not positive semidefinite at epoch {}",
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
            // Saturating: a lag beyond the recording is the whole rest of it.
            let to = k.saturating_add(lag).min(len - 1);
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

/// D' Q^+ D: the variance a window step adds to the shared part s of the measurement
/// noise (v = sum_j D_j' Q_j^+ G_j w_j + an independent rest), or `None` when D is not
/// in the range of Q (then no valid joint covariance has these blocks). Q^+ from the
/// symmetric eigendecomposition, eigenvalues below 1e-12 of the largest taken as zero.
fn shared_noise_increment<T: Scalar>(q: &DMatrix<T>, d: &DMatrix<T>) -> Option<DMatrix<T>> {
    use crate::scalar::lit;
    let eigen = symmetrize_dynamic(q).symmetric_eigen();
    let largest = eigen
        .eigenvalues
        .iter()
        .fold(T::zero(), |a, &b| if b.abs() > a { b.abs() } else { a });
    let floor = largest * lit::<T>(1e-12);
    let vectors = &eigen.eigenvectors;
    let projected = vectors.transpose() * d;
    let mut scaled = projected.clone();
    let mut residual = T::zero();
    for (i, &lambda) in eigen.eigenvalues.iter().enumerate() {
        for j in 0..d.ncols() {
            if lambda > floor {
                scaled[(i, j)] = projected[(i, j)] / lambda;
            } else {
                let r = projected[(i, j)].abs();
                residual = if r > residual { r } else { residual };
                scaled[(i, j)] = T::zero();
            }
        }
    }
    let size = d
        .iter()
        .fold(T::zero(), |a, &b| if b.abs() > a { b.abs() } else { a });
    if residual > lit::<T>(1e-6) * size + T::default_epsilon() {
        return None;
    }
    Some(symmetrize_dynamic(&(projected.transpose() * scaled)))
}

/// x = P^+ b for a symmetric positive semidefinite P, scale-free: the
/// eigendecomposition of the correlation matrix, eigenvalues below 1e-10 taken as zero
/// (an augmented state [e; s] is singular where s is still fully determined by e's
/// noise, e.g. a window's first step with fewer noise components than M); rows and
/// columns of zero variance are left out. `None` if P has a negative variance or a
/// clearly negative eigenvalue.
fn psd_solve<T: Scalar>(p: &DMatrix<T>, b: &DMatrix<T>) -> Option<DMatrix<T>> {
    use crate::scalar::lit;
    if (0..p.nrows()).any(|i| p[(i, i)] < T::zero()) {
        return None;
    }
    let kept: Vec<usize> = (0..p.nrows()).filter(|&i| p[(i, i)] > T::zero()).collect();
    let scale: Vec<T> = kept.iter().map(|&i| p[(i, i)].sqrt()).collect();
    let k = kept.len();
    let correlation = symmetrize_dynamic(&DMatrix::from_fn(k, k, |i, j| {
        p[(kept[i], kept[j])] / (scale[i] * scale[j])
    }));
    let rhs = DMatrix::from_fn(k, b.ncols(), |i, j| b[(kept[i], j)] / scale[i]);
    let eigen = correlation.symmetric_eigen();
    let mut projected = eigen.eigenvectors.transpose() * &rhs;
    for (i, &lambda) in eigen.eigenvalues.iter().enumerate() {
        if lambda < -lit::<T>(1e-8) {
            return None;
        }
        let inverse = if lambda > lit::<T>(1e-10) {
            T::one() / lambda
        } else {
            T::zero()
        };
        for j in 0..rhs.ncols() {
            projected[(i, j)] *= inverse;
        }
    }
    let solved = &eigen.eigenvectors * projected;
    let mut x = DMatrix::<T>::zeros(p.nrows(), b.ncols());
    for (i, &row) in kept.iter().enumerate() {
        for j in 0..b.ncols() {
            x[(row, j)] = solved[(i, j)] / scale[i];
        }
    }
    Some(x)
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
    fn wants_window(&self) -> bool {
        true
    }

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
        // Observed nothing; it still closes the filter's accumulation interval, and
        // with RecordAt::Measurements its epoch.
        self.predicts_since_update = 0;
        if self.mode == RecordAt::Measurements {
            if let Some(last) = self.epochs.back_mut() {
                last.closed = true;
            }
        }
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
///     .with_observer(FixedLagSmoother::new(RecordAt::EveryStep, 2)?);
/// for k in 0..10 {
///     kf.step(Some(&Vector1::new(k as f64)), &Zero)?;
/// }
/// let lagged = kf.into_observer().finish()?;
/// assert_eq!(lagged.len(), 10);
/// assert_eq!(lagged[3].epoch, 3);
/// // A lag beyond FixedLagSmoother::MAX_LAG is refused, not a panic.
/// assert!(FixedLagSmoother::<f64, Vector2<f64>, 2>::new(RecordAt::EveryStep, usize::MAX).is_err());
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
    /// The largest lag: 2^24 epochs (46 hours of 100 Hz steps). The smoother holds up
    /// to `lag + 2` epochs (each an N x N covariance and more); a longer lag is a
    /// whole-recording smoothing ([`ForwardRecorder::smooth`]).
    pub const MAX_LAG: usize = 1 << 24;

    /// A fixed-lag smoother with `lag` epochs, recording as `mode`.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] (`name: "lag"`) for a lag above
    /// [`FixedLagSmoother::MAX_LAG`].
    pub fn new(mode: RecordAt, lag: usize) -> Result<Self> {
        Self::from_recorder(ForwardRecorder::new(mode), lag)
    }

    /// From a recorder (e.g. [`ForwardRecorder::from_initial_parts`]); its capacity
    /// is set to `lag + 2` epochs.
    ///
    /// # Errors
    /// As [`FixedLagSmoother::new`].
    pub fn from_recorder(recorder: ForwardRecorder<T, S, N>, lag: usize) -> Result<Self> {
        if lag > Self::MAX_LAG {
            return Err(Error::InvalidParameter {
                name: "lag",
                reason: format!(
                    "{lag} epochs is above FixedLagSmoother::MAX_LAG = {}",
                    Self::MAX_LAG
                ),
            });
        }
        Ok(Self {
            recorder: recorder.with_capacity(lag + 2),
            lag,
            emitted: Vec::new(),
            next: 0,
        })
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
    fn wants_window(&self) -> bool {
        true
    }

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
