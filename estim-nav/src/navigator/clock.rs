//! The IMU timing of the navigator: the time the state refers to, the sample in effect
//! and the nominal period.

use estim_ins::ImuSample;

use super::{NavigatorError, Result};

/// Largest relative difference between a timestamp difference and the nominal IMU
/// period for which the nominal period is used as dt (timestamps are a fixed-rate
/// clock written in floating point; this keeps a run independent of their rounding).
pub const IMU_PERIOD_SNAP: f64 = 1e-6;

/// The IMU timing both navigators share: the time the state refers to, the sample in
/// effect and the nominal period. It decides what to integrate; the navigator
/// integrates it and then advances the clock.
#[derive(Debug, Clone, Copy)]
pub(super) struct ImuClock {
    period: f64,
    tolerance: f64,
    clock: f64,
    held: Option<ImuSample>,
}

impl ImuClock {
    /// A clock at `start` for a nominal period `period` \[s\].
    ///
    /// # Errors
    /// [`NavigatorError::InvalidValue`] for a period that is not positive and finite.
    pub(super) fn new(period: f64, start: f64) -> Result<Self> {
        if !(period.is_finite() && period > 0.0) {
            return Err(NavigatorError::invalid(
                "IMU period",
                format!("{period} s is not positive and finite"),
            ));
        }
        Ok(Self {
            period,
            tolerance: IMU_PERIOD_SNAP * period,
            clock: start,
            held: None,
        })
    }

    /// The time the state refers to \[s\].
    pub(super) fn time(&self) -> f64 {
        self.clock
    }

    /// The nominal period \[s\].
    pub(super) fn period(&self) -> f64 {
        self.period
    }

    /// The sample in effect.
    pub(super) fn held(&self) -> Option<&ImuSample> {
        self.held.as_ref()
    }

    /// The step from the clock to `end`: the held sample and dt (the nominal period
    /// when within [`IMU_PERIOD_SNAP`] of it).
    ///
    /// # Errors
    /// [`NavigatorError::NoImu`] before the first sample.
    pub(super) fn step(&self, end: f64) -> Result<(ImuSample, f64)> {
        // Nothing to integrate before the first sample.
        let sample = self.held.ok_or(NavigatorError::NoImu { time: end })?;
        let dt = end - self.clock;
        if (dt - self.period).abs() <= self.tolerance {
            Ok((sample, self.period))
        } else {
            Ok((sample, dt))
        }
    }

    /// Move the clock to `end` (after its step was integrated).
    pub(super) fn advance(&mut self, end: f64) {
        self.clock = end;
    }

    /// Whether `sample` needs a step to its time before it is held.
    ///
    /// # Errors
    /// [`NavigatorError::NonFinite`], [`NavigatorError::TimeOrder`].
    pub(super) fn sample_needs_step(&self, sample: &ImuSample) -> Result<bool> {
        let finite = sample.time.is_finite()
            && sample.specific_force.iter().all(|v| v.is_finite())
            && sample.angular_rate.iter().all(|v| v.is_finite());
        if !finite {
            return Err(NavigatorError::NonFinite {
                what: "IMU sample",
                time: sample.time,
            });
        }
        if self.held.is_none() {
            return Ok(false);
        }
        if sample.time < self.clock - self.tolerance {
            return Err(NavigatorError::TimeOrder {
                what: "IMU sample",
                time: sample.time,
                clock: self.clock,
            });
        }
        Ok(sample.time - self.clock > self.tolerance)
    }

    /// Hold `sample` from the clock on.
    pub(super) fn hold(&mut self, sample: ImuSample) {
        self.held = Some(sample);
    }

    /// Whether a measurement at `time` needs a step to it first.
    ///
    /// # Errors
    /// [`NavigatorError::TimeOrder`] for a time before the clock or not finite.
    pub(super) fn measurement_needs_step(&self, time: f64) -> Result<bool> {
        if !time.is_finite() || time < self.clock - self.tolerance {
            return Err(NavigatorError::TimeOrder {
                what: "measurement",
                time,
                clock: self.clock,
            });
        }
        Ok(time - self.clock > self.tolerance)
    }
}
