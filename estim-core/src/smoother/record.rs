//! Recording the forward pass: each predict and update of the runner opens, extends
//! or conditions an epoch ([`RecordAt`]).

use nalgebra::{SMatrix, SVector};

use super::link::{DynamicLink, UpdateTerms};
use super::{Epoch, ForwardRecorder, Link, RecordAt};
use crate::observer::{MarkEvent, Observer, PredictEvent, UpdateEvent};
use crate::{Result, Scalar};

impl<T: Scalar, S: Clone, const N: usize> ForwardRecorder<T, S, N> {
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
        // (An epoch a mark closed starts a new one inside the accumulation interval:
        // its own steps then bound the window, not the predicts since the update.)
        let augment = correlated
            && match (event.window_steps, self.mode) {
                (Some(window), RecordAt::Updates | RecordAt::Measurements) => {
                    window > self.predicts_since_update
                        || window > last.steps
                        || last.accepted_updates > 0
                }
                (Some(window), RecordAt::EveryStep) => window > 1 || last.accepted_updates > 0,
                (None, _) => false,
            };
        if correlated && !augment && last.accepted_updates > 0 {
            self.mark_unsupported(
                "correlated one-step update after another update at the same epoch (its noise is then correlated with the previous epoch's error; state the window with a WindowedCrossCovariance)",
            );
        }
        if correlated && event.window_steps.is_none() && self.marked_since_update {
            self.mark_unsupported(
                "correlated one-step update whose accumulation interval a mark split into two epochs (its noise is then correlated with both; state the window with a WindowedCrossCovariance)",
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
        self.marked_since_update = false;
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

    fn on_mark(&mut self, event: &MarkEvent<'_, T, S, N>) -> Result<()> {
        match self.epochs.back_mut() {
            // The open epoch ends here (its state and covariance are the event's: the
            // last predict's). Every step is an epoch already with RecordAt::EveryStep.
            Some(last) => {
                if !last.closed {
                    last.closed = true;
                    self.marked_since_update = true;
                }
            }
            // Nothing recorded yet: the marked estimate is the first epoch, as with
            // `from_initial_parts`.
            None => self.push_epoch(Epoch::initial(event.state.clone(), *event.covariance)),
        }
        Ok(())
    }

    fn on_rejected(&mut self, _event: &UpdateEvent<'_, T, S, N>) -> Result<()> {
        // Observed nothing; it still closes the filter's accumulation interval, and
        // with RecordAt::Measurements its epoch.
        self.predicts_since_update = 0;
        self.marked_since_update = false;
        if self.mode == RecordAt::Measurements {
            if let Some(last) = self.epochs.back_mut() {
                last.closed = true;
            }
        }
        Ok(())
    }
}
