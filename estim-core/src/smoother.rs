//! Rauch-Tung-Striebel smoothing (fixed interval and fixed lag) over a recorded
//! forward pass, consistent with correlated process and measurement noise.
//!
//! ## Recording
//!
//! A [`ForwardRecorder`] is an [`Observer`](crate::Observer): attach it to any runner
//! ([`crate::KalmanFilter`], [`crate::ExtendedKalmanFilter`],
//! [`crate::ErrorStateKalmanFilter`], [`crate::SquareRootKalmanFilter`],
//! [`crate::UnscentedKalmanFilter`]; for the last, whose events carry the statistical
//! linearisations of its sigma points, the unscented RTS smoother) and it keeps, per *epoch*, the filtered state and
//! covariance and three quantities that link the epoch to the previous one (below). An
//! epoch is a moment of the forward pass: with [`RecordAt::EveryStep`] every predict
//! opens one (the updates that follow belong to it); with [`RecordAt::Updates`] the
//! predicts between two updates are composed into one transition and an epoch ends
//! with its updates (memory: one epoch per update, not per IMU sample). The runner's
//! owner can also end an epoch at a step with no measurement
//! ([`Observer::on_mark`](crate::Observer::on_mark), e.g. at the epochs of a reference
//! to score against): the smoother then gives a value at that step, the same as a
//! recording at every step gives there (`tests/smoother.rs`, uncorrelated updates). A
//! one-step correlated update whose interval a mark split is refused
//! ([`crate::Error::SmootherUnsupported`]).
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
//! [`Observer::wants_window`](crate::Observer::wants_window)); the recorder then
//! fills, epoch by epoch, with C_s = Cov(e, s) and V_s = Var(s):
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

mod backward;
mod fixed_lag;
mod link;
mod record;
mod window;

use std::collections::VecDeque;

use nalgebra::{DMatrix, SMatrix, SVector};

use crate::{Error, ErrorStateModel, Result, Scalar};
use link::DynamicLink;

pub use fixed_lag::FixedLagSmoother;

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

impl<T: Scalar, S, const N: usize> Epoch<T, S, N> {
    /// A first epoch: an estimate with no link back, no step and no update.
    fn initial(state: S, covariance: SMatrix<T, N, N>) -> Self {
        Self {
            state,
            covariance,
            link: None,
            closed: true,
            accepted_updates: 0,
            steps: 0,
            transition: SMatrix::identity(),
            augmented: None,
        }
    }
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
    /// A mark closed an epoch since the last measurement (its accumulation interval
    /// then spans two epochs).
    marked_since_update: bool,
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
            marked_since_update: false,
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
        recorder.epochs.push_back(Epoch::initial(state, covariance));
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
