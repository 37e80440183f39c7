//! The running stream on one error model: the history, the IMU times measurements
//! snap to, and the measurements waiting for the IMU to reach them.

use std::collections::VecDeque;

use estim_ins::ImuSample;

use super::history::{EventKey, History, HistoryLimits, NotInserted};
use super::replica::{Event, Replica};
use super::{MeasurementTiming, Refusal, Result, Sensor, StreamError};
use crate::navigator::NavigationModel;

/// A measurement waiting for the IMU to reach its time.
#[derive(Debug, Clone, Copy)]
pub(super) struct Waiting {
    pub(super) sensor: Sensor,
    /// Its stamp minus its sensor's time offset \[s\].
    pub(super) time: f64,
    pub(super) event: Event,
    pub(super) sequence: u64,
}

/// The running stream on one error model.
#[derive(Clone)]
pub(super) struct Engine<E: NavigationModel<N>, const N: usize>
where
    E: Clone,
    E::DvlMemory: Clone,
{
    pub(super) history: History<Replica<E, N>>,
    /// Recent IMU sample times (for the nearest-sample rule).
    pub(super) imu_times: VecDeque<f64>,
    pub(super) first_imu_time: f64,
    pub(super) start_time: f64,
    pub(super) skip_before: Option<f64>,
    pub(super) period: f64,
    pub(super) timing: MeasurementTiming,
    pub(super) waiting: Vec<Waiting>,
}

impl<E: NavigationModel<N>, const N: usize> Engine<E, N>
where
    E: Clone,
    E::DvlMemory: Clone,
{
    pub(super) fn new(
        replica: Replica<E, N>,
        limits: HistoryLimits,
        first_imu_time: f64,
        start_time: f64,
        skip_before: Option<f64>,
        period: f64,
        timing: MeasurementTiming,
    ) -> Self {
        Self {
            history: History::new(replica, limits),
            imu_times: VecDeque::new(),
            first_imu_time,
            start_time,
            skip_before,
            period,
            timing,
            waiting: Vec::new(),
        }
    }

    /// Insert an event; a refusal is pushed onto `refusals`.
    fn insert(
        &mut self,
        sensor: Sensor,
        key: EventKey,
        event: Event,
        refusals: &mut Vec<Refusal>,
    ) -> Result<()> {
        match self.history.insert(key, event)? {
            Ok(()) => {}
            Err(NotInserted::TooOld { boundary }) => refusals.push(Refusal::TooOld {
                sensor,
                time: key.time,
                boundary,
            }),
            Err(NotInserted::Full) if sensor == Sensor::Imu => {
                return Err(StreamError::HistoryFull {
                    time: key.time,
                    events: self.history.limits().max_events,
                })
            }
            Err(NotInserted::Full) => refusals.push(Refusal::HistoryFull {
                sensor,
                time: key.time,
            }),
        }
        Ok(())
    }

    pub(super) fn imu(
        &mut self,
        sample: ImuSample,
        history_s: f64,
        refusals: &mut Vec<Refusal>,
    ) -> Result<()> {
        self.imu_times.push_back(sample.time);
        // Keep the times a waiting or late measurement can snap to.
        let keep_after = sample.time - history_s - 2.0 * self.period;
        while self.imu_times.len() > 2 && self.imu_times[1] < keep_after {
            self.imu_times.pop_front();
        }
        // The sample and the measurements it lets be placed, inserted in the log's
        // order (so that records on time never rewind).
        let mut batch: Vec<(EventKey, Sensor, Event)> = Vec::new();
        if self.skip_before.is_none_or(|t| sample.time >= t) {
            let key = EventKey {
                time: sample.time,
                class: 0,
                sequence: 0,
            };
            batch.push((key, Sensor::Imu, Event::Imu(sample)));
        }
        let reached = self.take_reached(sample.time, false);
        for w in reached {
            match self.key_of(&w, false) {
                Some(key) => batch.push((key, w.sensor, w.event)),
                None => refusals.push(Refusal::OutsideImuSpan {
                    sensor: w.sensor,
                    time: w.time,
                }),
            }
        }
        batch.sort_by(|a, b| a.0.order(&b.0));
        for (key, sensor, event) in batch {
            self.insert(sensor, key, event, refusals)?;
        }
        self.history.finalize_before(sample.time - history_s);
        Ok(())
    }

    /// The waiting measurements the IMU has reached (`up_to`: its latest time;
    /// `at_end`: all of them), in arrival order.
    fn take_reached(&mut self, up_to: f64, at_end: bool) -> Vec<Waiting> {
        let mut now: Vec<Waiting> = Vec::new();
        self.waiting.retain(|w| {
            let reached = at_end || w.time <= up_to;
            if reached {
                now.push(*w);
            }
            !reached
        });
        now.sort_by_key(|w| w.sequence);
        now
    }

    /// The log key of a measurement the IMU has reached (`None`: outside its span).
    fn key_of(&self, w: &Waiting, at_end: bool) -> Option<EventKey> {
        let at = self.applied_time(w.time, at_end)?;
        (at > self.start_time).then_some(EventKey {
            time: at,
            class: w.sensor_class(),
            sequence: w.sequence,
        })
    }

    /// A measurement: applied now if the IMU has reached its time, else it waits.
    pub(super) fn wait(&mut self, waiting: Waiting, refusals: &mut Vec<Refusal>) -> Result<()> {
        let reached = self.imu_times.back().is_some_and(|&t| t >= waiting.time);
        if reached {
            return self.place(waiting, false, refusals);
        }
        if self.waiting.len() >= self.history.limits().max_events {
            refusals.push(Refusal::HistoryFull {
                sensor: waiting.sensor,
                time: waiting.time,
            });
            return Ok(());
        }
        self.waiting.push(waiting);
        Ok(())
    }

    /// Place every waiting measurement, the IMU having ended.
    pub(super) fn resolve_at_end(&mut self, refusals: &mut Vec<Refusal>) -> Result<()> {
        for w in self.take_reached(f64::INFINITY, true) {
            self.place(w, true, refusals)?;
        }
        Ok(())
    }

    /// The time a measurement at `t` is applied at (`None`: outside the IMU's span);
    /// `t` is at or before the last IMU sample unless `at_end`.
    fn applied_time(&self, t: f64, at_end: bool) -> Option<f64> {
        let last = *self.imu_times.back()?;
        let end = last + self.period;
        let half = 0.5 * self.period * (1.0 + 1e-9);
        if t > end + half || (!at_end && t > last) {
            return None;
        }
        if self.timing == MeasurementTiming::Exact {
            return (t >= self.first_imu_time && t <= end).then_some(t);
        }
        // The batch run's rule (`batch::snap`): the nearer of the samples around t (the
        // end of the last one's interval counts as one), the later on a tie.
        let j = self.imu_times.partition_point(|&s| s < t);
        let time_at = |k: usize| self.imu_times.get(k).copied().unwrap_or(end);
        let mut best: Option<(f64, f64)> = None;
        for k in [j.checked_sub(1), Some(j)].into_iter().flatten() {
            let at = time_at(k);
            let d = (at - t).abs();
            if best.is_none_or(|(_, bd)| d <= bd) {
                best = Some((at, d));
            }
        }
        let (at, distance) = best?;
        if at == self.first_imu_time {
            return None;
        }
        Some(if distance <= half { at } else { t })
    }

    /// Insert a measurement whose time the IMU has reached (or, `at_end`, any).
    fn place(&mut self, w: Waiting, at_end: bool, refusals: &mut Vec<Refusal>) -> Result<()> {
        match self.key_of(&w, at_end) {
            Some(key) => self.insert(w.sensor, key, w.event, refusals),
            None => {
                refusals.push(Refusal::OutsideImuSpan {
                    sensor: w.sensor,
                    time: w.time,
                });
                Ok(())
            }
        }
    }
}

impl Waiting {
    /// The batch run's order at one time: DVL, depth, fixes.
    fn sensor_class(&self) -> u8 {
        match self.sensor {
            Sensor::Imu => 0,
            Sensor::Dvl => 1,
            Sensor::Depth => 2,
            Sensor::Fix => 3,
        }
    }
}
