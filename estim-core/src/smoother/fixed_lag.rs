//! Online fixed-lag smoothing over a bounded recording.

use super::{ForwardRecorder, RecordAt, Smoothed};
use crate::observer::{Observer, PredictEvent, UpdateEvent};
use crate::{Error, Result, Scalar};

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
