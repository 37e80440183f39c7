//! Observers: what a runner reports at each step (argmin's executor pattern), so
//! CSV writers, progress bars and plots stay out of the numerical code.

use nalgebra::SMatrix;

use crate::window::RecordedWindow;
use crate::{Result, Scalar};

/// Reported after each prediction.
#[derive(Debug, Clone, Copy)]
pub struct PredictEvent<'a, T: Scalar, S, const N: usize> {
    /// Time step (`None` for the linear [`crate::KalmanFilter`], which has no dt).
    pub dt: Option<T>,
    /// The (nominal) state after the prediction.
    pub state: &'a S,
    /// The covariance after the prediction.
    pub covariance: &'a SMatrix<T, N, N>,
    /// Propagations since the last measurement (including this one).
    pub propagations_since_update: usize,
    /// The transition Phi of this step (for smoothers and recorders).
    pub transition: &'a SMatrix<T, N, N>,
    /// The process noise Q_d of this step.
    pub process_noise: &'a SMatrix<T, N, N>,
}

/// Reported when the runner's owner marks the current step ([`Observer::on_mark`]):
/// the estimate there, with no measurement.
#[derive(Debug, Clone, Copy)]
pub struct MarkEvent<'a, T: Scalar, S, const N: usize> {
    /// The (nominal) state at the marked step.
    pub state: &'a S,
    /// The covariance at the marked step.
    pub covariance: &'a SMatrix<T, N, N>,
}

/// Whether an update was applied.
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum UpdateStatus {
    /// The posterior replaced the prior.
    Accepted,
    /// The innovation gate rejected the measurement; the state is untouched.
    RejectedByGate,
}

/// Reported after each update attempt (accepted or rejected).
#[derive(Debug, Clone, Copy)]
pub struct UpdateEvent<'a, T: Scalar, S, const N: usize> {
    /// The (nominal) state after the update (unchanged if rejected).
    pub state: &'a S,
    /// The covariance after the update (unchanged if rejected).
    pub covariance: &'a SMatrix<T, N, N>,
    /// The innovation y - h(x), `measurement_size` values.
    pub innovation: &'a [T],
    /// Size M of the measurement.
    pub measurement_size: usize,
    /// Normalised innovation squared.
    pub nis: T,
    /// The gate threshold, if a gate is configured.
    pub gate_threshold: Option<T>,
    /// Smallest eigenvalue of the correlation matrix of [[Q_acc, M], [M', R]], if the
    /// configuration computes it (valid iff >= 0, tolerance 1e-9).
    pub joint_min_eigenvalue: Option<T>,
    /// The factor lambda the prior covariance was inflated by before an update the
    /// gate would have rejected ([`crate::GateRecovery::Inflate`]); `None` otherwise.
    pub covariance_inflation: Option<T>,
    /// Accepted or rejected.
    pub status: UpdateStatus,
    /// The covariance before the update (the prior of this update).
    pub prior_covariance: &'a SMatrix<T, N, N>,
    /// H (M x N), column-major.
    pub jacobian: &'a [T],
    /// The measurement-noise covariance used (M x M, column-major): R, or the
    /// conditional Var(v | ...) of a windowed update.
    pub noise_covariance: &'a [T],
    /// The cross-covariance M used (N x M, column-major).
    pub cross_covariance: &'a [T],
    /// The innovation covariance S (M x M, column-major).
    pub innovation_covariance: &'a [T],
    /// The gain K (N x M, column-major), `None` if rejected.
    pub gain: Option<&'a [T]>,
    /// Whether the cross-covariance came from a windowed model (exact M over a window
    /// of steps, see [`crate::window`]) rather than a one-step one.
    pub windowed: bool,
    /// The window's length in process steps for a windowed model
    /// ([`crate::WindowedCrossCovariance::window_steps`]), `None` for a one-step one.
    pub window_steps: Option<usize>,
    /// The error-state reset J applied after injection (P <- J P J'), `None` when it
    /// is the identity or the runner has no reset (KF, EKF).
    pub reset: Option<&'a SMatrix<T, N, N>>,
    /// For an accepted windowed update, when the observer asks for it
    /// ([`Observer::wants_window`]): the window's steps (Phi_j, Q_j, D_j) and the other
    /// updates inside it. `None` otherwise.
    pub window: Option<&'a dyn RecordedWindow<T, N>>,
}

/// Receives a runner's events. Every method has a default that does nothing.
///
/// Implemented for `()` / [`NoObserver`] (nothing), `&mut O` (observe while keeping
/// ownership), `(A, B)` (both) and [`NisRecorder`].
///
/// ```
/// use estim_core::{Observer, UpdateEvent, Result};
///
/// /// Counts gate rejections.
/// #[derive(Default)]
/// struct Rejections(usize);
///
/// impl<S, const N: usize> Observer<f64, S, N> for Rejections {
///     fn on_rejected(&mut self, _event: &UpdateEvent<'_, f64, S, N>) -> Result<()> {
///         self.0 += 1;
///         Ok(())
///     }
/// }
/// # let _ = Rejections::default();
/// ```
pub trait Observer<T: Scalar, S, const N: usize> {
    /// After each prediction.
    fn on_predict(&mut self, _event: &PredictEvent<'_, T, S, N>) -> Result<()> {
        Ok(())
    }

    /// After each accepted update.
    fn on_update(&mut self, _event: &UpdateEvent<'_, T, S, N>) -> Result<()> {
        Ok(())
    }

    /// After each update rejected by the innovation gate.
    fn on_rejected(&mut self, _event: &UpdateEvent<'_, T, S, N>) -> Result<()> {
        Ok(())
    }

    /// When the runner's owner marks the current step as one to report (a runner
    /// never calls it itself): e.g. the time of a reference sample between two
    /// measurements. A [`crate::smoother::ForwardRecorder`] closes its epoch there, so
    /// that the smoother gives a value at that step.
    fn on_mark(&mut self, _event: &MarkEvent<'_, T, S, N>) -> Result<()> {
        Ok(())
    }

    /// Whether accepted windowed updates should carry their recorded window
    /// ([`UpdateEvent::window`]). The runner then asks the windowed model for every
    /// step's D_j once more (and keeps them in a buffer); `false` by default. The
    /// smoothers ask for it.
    fn wants_window(&self) -> bool {
        false
    }
}

/// The observer that does nothing (the runners' default).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct NoObserver;

impl<T: Scalar, S, const N: usize> Observer<T, S, N> for NoObserver {}
impl<T: Scalar, S, const N: usize> Observer<T, S, N> for () {}

impl<T: Scalar, S, const N: usize, O: Observer<T, S, N> + ?Sized> Observer<T, S, N> for &mut O {
    fn on_predict(&mut self, event: &PredictEvent<'_, T, S, N>) -> Result<()> {
        (**self).on_predict(event)
    }
    fn on_update(&mut self, event: &UpdateEvent<'_, T, S, N>) -> Result<()> {
        (**self).on_update(event)
    }
    fn on_rejected(&mut self, event: &UpdateEvent<'_, T, S, N>) -> Result<()> {
        (**self).on_rejected(event)
    }
    fn on_mark(&mut self, event: &MarkEvent<'_, T, S, N>) -> Result<()> {
        (**self).on_mark(event)
    }
    fn wants_window(&self) -> bool {
        (**self).wants_window()
    }
}

impl<T: Scalar, S, const N: usize, A: Observer<T, S, N>, B: Observer<T, S, N>> Observer<T, S, N>
    for (A, B)
{
    fn on_predict(&mut self, event: &PredictEvent<'_, T, S, N>) -> Result<()> {
        self.0.on_predict(event)?;
        self.1.on_predict(event)
    }
    fn on_update(&mut self, event: &UpdateEvent<'_, T, S, N>) -> Result<()> {
        self.0.on_update(event)?;
        self.1.on_update(event)
    }
    fn on_rejected(&mut self, event: &UpdateEvent<'_, T, S, N>) -> Result<()> {
        self.0.on_rejected(event)?;
        self.1.on_rejected(event)
    }
    fn on_mark(&mut self, event: &MarkEvent<'_, T, S, N>) -> Result<()> {
        self.0.on_mark(event)?;
        self.1.on_mark(event)
    }
    fn wants_window(&self) -> bool {
        self.0.wants_window() || self.1.wants_window()
    }
}

/// Records the NIS of every update attempt and counts rejections.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct NisRecorder<T> {
    /// (NIS, measurement size, status) of each update attempt, in order.
    pub records: Vec<(T, usize, UpdateStatus)>,
}

impl<T: Scalar> NisRecorder<T> {
    /// Number of accepted updates.
    pub fn accepted(&self) -> usize {
        self.records
            .iter()
            .filter(|r| r.2 == UpdateStatus::Accepted)
            .count()
    }

    /// Number of updates rejected by the gate.
    pub fn rejected(&self) -> usize {
        self.records
            .iter()
            .filter(|r| r.2 == UpdateStatus::RejectedByGate)
            .count()
    }
}

impl<T: Scalar, S, const N: usize> Observer<T, S, N> for NisRecorder<T> {
    fn on_update(&mut self, event: &UpdateEvent<'_, T, S, N>) -> Result<()> {
        self.records
            .push((event.nis, event.measurement_size, event.status));
        Ok(())
    }
    fn on_rejected(&mut self, event: &UpdateEvent<'_, T, S, N>) -> Result<()> {
        self.records
            .push((event.nis, event.measurement_size, event.status));
        Ok(())
    }
}
