//! The bounded history of a streaming filter: checkpoints of the filter's whole state
//! and the time-ordered log of the events applied since, so that an event stamped in
//! the past is applied at its own place by rewind and replay.
//!
//! Method: state history with replay (robot_localization's approach), not an exact
//! delayed-state update (e.g. Larsen's extrapolation of the measurement to the
//! present). Replay re-runs the very code of the in-order filter from a copy of its
//! whole state (nominal, covariance, the accumulated process noise and recorded
//! window the correlated update's M is built from, the adaptive noise level, the
//! health monitor's windows), so a delayed measurement gives bit for bit what the
//! filter would have given with it on time, for any error model, nonlinear
//! measurement or gate decision; a delayed-state update is exact only for a linear(ised)
//! model with fixed linearisation points and would have to re-derive the windowed M.
//! The price is replay time, proportional to the delay (measured by `benches/stream.rs`).

use std::cmp::Ordering;
use std::collections::VecDeque;

/// Where an event sorts in the log: by time, then by class (at one time: IMU samples
/// first, then the measurements in the batch run's order), then by arrival.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EventKey {
    /// The time the event is applied at \[s\].
    pub time: f64,
    /// The class (0 sorts first at one time).
    pub class: u8,
    /// The arrival number (ties in time and class keep arrival order).
    pub sequence: u64,
}

impl EventKey {
    /// The log's order.
    pub fn order(&self, other: &Self) -> Ordering {
        self.time
            .total_cmp(&other.time)
            .then(self.class.cmp(&other.class))
            .then(self.sequence.cmp(&other.sequence))
    }
}

/// A filter state that can be copied and fed events: what the [`History`] checkpoints
/// and replays.
///
/// ```
/// use estim_nav::navigator::{EventKey, History, HistoryLimits, Replay};
///
/// /// A running sum: the outputs are the partial sums.
/// #[derive(Clone, Default)]
/// struct Sum(f64);
/// impl Replay for Sum {
///     type Event = f64;
///     type Output = f64;
///     type Error = std::convert::Infallible;
///     fn apply(&mut self, _: &EventKey, x: &f64, out: &mut Vec<f64>) -> Result<(), Self::Error> {
///         self.0 += x;
///         out.push(self.0);
///         Ok(())
///     }
/// }
///
/// let mut history = History::new(Sum::default(), HistoryLimits::new(2, 100));
/// let key = |time: f64, sequence| EventKey { time, class: 0, sequence };
/// history.insert(key(1.0, 0), 1.0)?;
/// history.insert(key(3.0, 1), 3.0)?;
/// history.insert(key(2.0, 2), 2.0)?; // late: rewind, insert, replay
/// history.finalize_before(10.0);
/// let sums: Vec<f64> = history.take_final().map(|(_, s)| s).collect();
/// assert_eq!(sums, [1.0, 3.0, 6.0]);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub trait Replay: Clone {
    /// What the log holds.
    type Event: Clone;
    /// What applying an event produces (e.g. a solution).
    type Output;
    /// A failure of the filter.
    type Error;

    /// Apply `event` (at `key`), pushing what it produces onto `outputs`.
    ///
    /// # Errors
    /// The filter's; the history's state is then that of a partial step.
    fn apply(
        &mut self,
        key: &EventKey,
        event: &Self::Event,
        outputs: &mut Vec<Self::Output>,
    ) -> Result<(), Self::Error>;
}

/// How much a [`History`] keeps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HistoryLimits {
    /// A checkpoint is taken before every this many events (>= 1): a rewind replays at
    /// most this many events more than its delay needs.
    pub checkpoint_every: usize,
    /// The most events the log holds (>= 2). When full, the oldest half is finalized
    /// early (shortening the history); an event that still does not fit is refused.
    pub max_events: usize,
}

impl HistoryLimits {
    /// Limits (each clamped to its minimum).
    pub fn new(checkpoint_every: usize, max_events: usize) -> Self {
        Self {
            checkpoint_every: checkpoint_every.max(1),
            max_events: max_events.max(2),
        }
    }
}

/// Why [`History::insert`] did not take an event.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum NotInserted {
    /// Its time is before the final boundary \[s\]: what it would change is final.
    TooOld {
        /// The boundary \[s\].
        boundary: f64,
    },
    /// The log is full of events at or after the boundary.
    Full,
}

/// What a rewind cost, and the largest size the history reached.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct HistoryStats {
    /// Events inserted before the end of the log (each a rewind).
    pub rewinds: usize,
    /// Events re-applied by the rewinds.
    pub replayed: usize,
    /// The most events the log held at once.
    pub max_events: usize,
    /// The most checkpoints held at once.
    pub max_checkpoints: usize,
}

/// A log entry and the outputs it produced.
#[derive(Debug, Clone)]
struct Entry<E> {
    key: EventKey,
    event: E,
}

/// The bounded history: the current state, checkpoints (copies of the state before
/// a log index), the time-ordered log since the oldest checkpoint, and the outputs
/// not yet final. See the module docs for the method.
#[derive(Debug, Clone)]
pub struct History<S: Replay> {
    current: S,
    log: VecDeque<Entry<S::Event>>,
    /// (log index, the state before that entry), increasing.
    checkpoints: VecDeque<(usize, S)>,
    /// (log index of the producing entry, its key, output), in log order.
    pending: VecDeque<(usize, EventKey, S::Output)>,
    ready: VecDeque<(EventKey, S::Output)>,
    limits: HistoryLimits,
    boundary: f64,
    stats: HistoryStats,
    scratch: Vec<S::Output>,
}

impl<S: Replay> History<S> {
    /// A history starting from `initial`.
    pub fn new(initial: S, limits: HistoryLimits) -> Self {
        let mut checkpoints = VecDeque::new();
        checkpoints.push_back((0, initial.clone()));
        Self {
            current: initial,
            log: VecDeque::new(),
            checkpoints,
            pending: VecDeque::new(),
            ready: VecDeque::new(),
            limits,
            boundary: f64::NEG_INFINITY,
            stats: HistoryStats::default(),
            scratch: Vec::new(),
        }
    }

    /// The state after every event of the log.
    pub fn current(&self) -> &S {
        &self.current
    }

    /// Events in the log.
    pub fn len(&self) -> usize {
        self.log.len()
    }

    /// Whether the log is empty.
    pub fn is_empty(&self) -> bool {
        self.log.is_empty()
    }

    /// Checkpoints held.
    pub fn checkpoints(&self) -> usize {
        self.checkpoints.len()
    }

    /// Outputs produced and not yet final.
    pub fn pending_outputs(&self) -> usize {
        self.pending.len()
    }

    /// The final boundary \[s\]: outputs before it are final, events before it refused.
    pub fn boundary(&self) -> f64 {
        self.boundary
    }

    /// What the rewinds cost and the largest sizes reached.
    pub fn stats(&self) -> HistoryStats {
        self.stats
    }

    /// The limits.
    pub fn limits(&self) -> HistoryLimits {
        self.limits
    }

    /// The time of the last event in the log (`None` when empty).
    pub fn last_time(&self) -> Option<f64> {
        self.log.back().map(|e| e.key.time)
    }

    /// Insert `event` at `key`: appended and applied when it sorts last; otherwise the
    /// state is restored from the last checkpoint before it, the event inserted and the
    /// log replayed from there (outputs after the checkpoint are produced again).
    ///
    /// # Errors
    /// `Ok(Err(..))` when the event is not taken ([`NotInserted`]); `Err` for the
    /// filter's failure while applying or replaying.
    #[allow(clippy::type_complexity)]
    pub fn insert(
        &mut self,
        key: EventKey,
        event: S::Event,
    ) -> Result<Result<(), NotInserted>, S::Error> {
        if key.time < self.boundary {
            return Ok(Err(NotInserted::TooOld {
                boundary: self.boundary,
            }));
        }
        if self.log.len() >= self.limits.max_events {
            let middle = self.log[self.log.len() / 2].key.time;
            self.finalize_before(middle);
            if key.time < self.boundary {
                return Ok(Err(NotInserted::TooOld {
                    boundary: self.boundary,
                }));
            }
            if self.log.len() >= self.limits.max_events {
                return Ok(Err(NotInserted::Full));
            }
        }
        let at = self
            .log
            .partition_point(|e| e.key.order(&key) != Ordering::Greater);
        self.log.insert(at, Entry { key, event });
        self.stats.max_events = self.stats.max_events.max(self.log.len());
        let applied = self.log.len() - 1;
        if at == applied {
            self.apply_from(applied)?;
            return Ok(Ok(()));
        }
        // Rewind: the last checkpoint at or before `at` holds the state before it.
        let k = self.checkpoints.partition_point(|(i, _)| *i <= at);
        // The first checkpoint is at the log's start, which no insertion precedes
        // (events before the boundary are refused and the boundary is never past it).
        let k = k.max(1);
        self.checkpoints.truncate(k);
        let (start, state) = &self.checkpoints[k - 1];
        let start = *start;
        self.current = state.clone();
        while self.pending.back().is_some_and(|(i, _, _)| *i >= start) {
            self.pending.pop_back();
        }
        self.stats.rewinds += 1;
        self.stats.replayed += self.log.len() - start;
        self.apply_from(start)?;
        Ok(Ok(()))
    }

    /// Apply the log from index `from` to its end, taking checkpoints on the way.
    fn apply_from(&mut self, from: usize) -> Result<(), S::Error> {
        for i in from..self.log.len() {
            let last = self.checkpoints.back().map_or(0, |(j, _)| *j);
            if i >= last + self.limits.checkpoint_every {
                self.checkpoints.push_back((i, self.current.clone()));
                self.stats.max_checkpoints = self.stats.max_checkpoints.max(self.checkpoints.len());
            }
            let entry = &self.log[i];
            self.scratch.clear();
            self.current
                .apply(&entry.key, &entry.event, &mut self.scratch)?;
            let key = entry.key;
            self.pending
                .extend(self.scratch.drain(..).map(|o| (i, key, o)));
        }
        Ok(())
    }

    /// Make final every output produced by an event before `boundary` \[s\] (they move
    /// to [`History::take_final`]), refuse events before it from now on, and drop the
    /// checkpoints and log entries no later event can need. The boundary never moves
    /// back.
    pub fn finalize_before(&mut self, boundary: f64) {
        if boundary <= self.boundary {
            return;
        }
        self.boundary = boundary;
        while self
            .pending
            .front()
            .is_some_and(|(_, key, _)| key.time < boundary)
        {
            if let Some((_, key, output)) = self.pending.pop_front() {
                self.ready.push_back((key, output));
            }
        }
        // Any later event sorts at or after `first`: keep the last checkpoint there or
        // before, and the log from it.
        let first = self.log.partition_point(|e| e.key.time < boundary);
        let k = self
            .checkpoints
            .partition_point(|(i, _)| *i <= first)
            .max(1);
        self.checkpoints.drain(..k - 1);
        let drop = self.checkpoints.front().map_or(0, |(i, _)| *i);
        if drop > 0 {
            self.log.drain(..drop);
            for (i, _) in &mut self.checkpoints {
                *i -= drop;
            }
            for (i, _, _) in &mut self.pending {
                *i -= drop;
            }
        }
    }

    /// Make every output final (the end of the stream).
    pub fn finalize_all(&mut self) {
        self.finalize_before(f64::INFINITY);
    }

    /// The outputs made final so far, in log order, each with its event's key.
    pub fn take_final(&mut self) -> impl Iterator<Item = (EventKey, S::Output)> + '_ {
        self.ready.drain(..)
    }
}
