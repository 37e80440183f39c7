//! What the history checkpoints and replays: the navigator with everything its later
//! steps depend on (the health monitor's NIS windows, the rate output's schedule),
//! applying events exactly as the batch run's hook does.

use std::sync::Arc;

use estim_core::smoother::{ForwardRecorder, RecordAt};
use estim_core::{Observer, PredictEvent, UpdateEvent, Zero};
use estim_dvl::BeamGeometry;
use estim_ins::ImuSample;

use super::history::{EventKey, Replay};
use super::Sensor;
use crate::navigator::{
    DvlInput, HealthMonitor, InsNominal, NavSolution, NavigationModel, Navigator, NavigatorError,
    PositionFix, SolutionKind,
};

/// One event of the log.
#[derive(Debug, Clone, Copy)]
pub(super) enum Event {
    Imu(ImuSample),
    Dvl(DvlInput),
    Depth(f64),
    Fix(PositionFix),
}

/// What applying an event produces. (Solutions are most of the outputs, so the
/// variants' sizes differing costs little.)
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone)]
pub(super) enum Produced {
    Solution(SolutionKind, NavSolution),
    /// A fixed-lag smoothed solution (`--lag`).
    Lagged(NavSolution),
    /// The recording cannot be smoothed (why: e.g. an update accepted by the gate's
    /// recovery rule): no lagged solution at this epoch.
    LagUnavailable(String),
    Nis(Sensor, f64),
    InsufficientBeams,
}

/// The fixed-lag recording: estim-core's forward recorder, one epoch per update time,
/// holding the last epochs only (`None`: no lag asked for).
#[derive(Debug, Clone)]
pub(super) struct LagRecorder<S: Clone, const N: usize>(Option<ForwardRecorder<f64, S, N>>);

impl<S: Clone, const N: usize> LagRecorder<S, N> {
    /// A recorder holding `epochs` epochs, or none.
    pub(super) fn new(epochs: Option<usize>) -> Self {
        Self(epochs.map(|e| ForwardRecorder::new(RecordAt::Updates).with_capacity(e)))
    }
}

impl<S: Clone, const N: usize> Observer<f64, S, N> for LagRecorder<S, N> {
    fn on_predict(&mut self, event: &PredictEvent<'_, f64, S, N>) -> estim_core::Result<()> {
        self.0.as_mut().map_or(Ok(()), |r| r.on_predict(event))
    }
    fn on_update(&mut self, event: &UpdateEvent<'_, f64, S, N>) -> estim_core::Result<()> {
        self.0.as_mut().map_or(Ok(()), |r| r.on_update(event))
    }
    fn on_rejected(&mut self, event: &UpdateEvent<'_, f64, S, N>) -> estim_core::Result<()> {
        self.0.as_mut().map_or(Ok(()), |r| r.on_rejected(event))
    }
    fn wants_window(&self) -> bool {
        self.0
            .as_ref()
            .is_some_and(Observer::<f64, S, N>::wants_window)
    }
}

/// How far past `now - lag` an epoch still counts as reached \[s\].
const LAG_TOLERANCE_S: f64 = 1e-6;

/// The navigator a replica runs.
pub(super) type LagNavigator<E, const N: usize> =
    Navigator<E, LagRecorder<<E as estim_core::ProcessModel<f64, N>>::State, N>, N>;

/// The navigator and the state of the batch hook's bookkeeping.
pub(super) struct Replica<E: NavigationModel<N>, const N: usize> {
    pub(super) nav: LagNavigator<E, N>,
    health: HealthMonitor,
    /// The lag \[s\] of the smoothed output, and the time of the last epoch emitted.
    lag: Option<(f64, f64)>,
    geometry: Arc<BeamGeometry>,
    /// (first IMU time, output period) of the rate output.
    rate: Option<(f64, f64)>,
    next_output: usize,
}

impl<E: NavigationModel<N> + Clone, const N: usize> Clone for Replica<E, N>
where
    E::DvlMemory: Clone,
{
    fn clone(&self) -> Self {
        Self {
            nav: self.nav.clone(),
            health: self.health.clone(),
            geometry: Arc::clone(&self.geometry),
            lag: self.lag,
            rate: self.rate,
            next_output: self.next_output,
        }
    }
}

impl<E: NavigationModel<N>, const N: usize> Replica<E, N> {
    pub(super) fn new(
        nav: Navigator<E, estim_core::NoObserver, N>,
        health: HealthMonitor,
        geometry: Arc<BeamGeometry>,
        rate: Option<(f64, f64)>,
        lag: Option<(f64, usize)>,
    ) -> Self {
        Self {
            nav: nav.with_observer(LagRecorder::new(lag.map(|(_, epochs)| epochs))),
            health,
            lag: lag.map(|(seconds, _)| (seconds, f64::NEG_INFINITY)),
            geometry,
            rate,
            next_output: 0,
        }
    }

    /// Push the smoothed solutions of the update epochs whose lag is reached at `now`
    /// (`--lag`), from the recording's epochs given everything recorded up to now.
    fn lagged(&mut self, now: f64, out: &mut Vec<Produced>) {
        if let Some((lag, last)) = self.lag {
            // An epoch exactly `lag` before now counts as reached (stamps are sums of
            // rounded steps).
            let newest = self.lagged_until(now - lag + LAG_TOLERANCE_S, last, out);
            self.lag = Some((lag, newest));
        }
    }

    /// The smoothed solutions of the epochs not emitted yet (the end of the stream).
    pub(super) fn lagged_tail(&self) -> Vec<Produced> {
        let mut out = Vec::new();
        if let Some((_, last)) = self.lag {
            self.lagged_until(f64::INFINITY, last, &mut out);
        }
        out
    }

    /// Push the smoothed solutions of the held epochs in (`last`, `until`]; the time of
    /// the newest pushed (`last` if none).
    fn lagged_until(&self, until: f64, last: f64, out: &mut Vec<Produced>) -> f64 {
        let Some(recorder) = &self.nav.filter().observer().0 else {
            return last;
        };
        let smoothed = match recorder.smooth() {
            Ok(s) => s,
            Err(e) => {
                out.push(Produced::LagUnavailable(e.to_string()));
                return last;
            }
        };
        let process = self.nav.filter().process();
        let mut newest = last;
        for epoch in &smoothed {
            let time = epoch.filtered_state.ins().time;
            if time <= last || time > until {
                continue;
            }
            match epoch.injected(process) {
                Ok(state) => {
                    let covariance = E::ins_covariance(&epoch.covariance);
                    out.push(Produced::Lagged(NavSolution::from_state(
                        time,
                        state.ins(),
                        &covariance,
                    )));
                }
                Err(e) => out.push(Produced::LagUnavailable(e.to_string())),
            }
            newest = time;
        }
        newest
    }

    fn emit(&self, kind: SolutionKind, out: &mut Vec<Produced>) -> Result<(), NavigatorError> {
        let solution = self.nav.solution();
        self.health.check_solution(&solution)?;
        out.push(Produced::Solution(kind, solution));
        Ok(())
    }

    /// A DVL row at `time` (as the batch hook's): the NIS of its update, if any.
    fn dvl(
        &mut self,
        time: f64,
        input: DvlInput,
        out: &mut Vec<Produced>,
    ) -> Result<Option<f64>, NavigatorError> {
        let nav = &mut self.nav;
        match input {
            DvlInput::Velocity(v) => Ok(Some(nav.dvl_velocity(time, &v, &Zero)?.nis)),
            DvlInput::EarthVelocity(v_ned) => {
                nav.propagate_to(time)?;
                let body = nav.ins().attitude.inverse() * v_ned;
                Ok(Some(nav.dvl_velocity(time, &body, &Zero)?.nis))
            }
            DvlInput::NoLock => Ok(None),
            DvlInput::Beams(beams) => match self.geometry.solve(&beams).velocity() {
                Some(v) => Ok(Some(nav.dvl_velocity(time, &v, &Zero)?.nis)),
                None => {
                    nav.propagate_to(time)?;
                    out.push(Produced::InsufficientBeams);
                    Ok(None)
                }
            },
        }
    }
}

impl<E: NavigationModel<N> + Clone, const N: usize> Replay for Replica<E, N>
where
    E::DvlMemory: Clone,
{
    type Event = Event;
    type Output = Produced;
    type Error = NavigatorError;

    fn apply(
        &mut self,
        key: &EventKey,
        event: &Event,
        out: &mut Vec<Produced>,
    ) -> Result<(), NavigatorError> {
        let t = key.time;
        match *event {
            Event::Imu(sample) => {
                self.nav.imu(&sample)?;
                if let Some((start, step)) = self.rate {
                    let since = sample.time - start;
                    if since >= self.next_output as f64 * step {
                        self.emit(SolutionKind::Rate, out)?;
                        self.next_output = (since / step).floor() as usize + 1;
                    }
                }
            }
            Event::Dvl(input) => {
                self.nav.propagate_to(t)?;
                if let Some(nis) = self.dvl(t, input, out)? {
                    self.health.record_nis("dvl", t, nis, 3)?;
                    out.push(Produced::Nis(Sensor::Dvl, nis));
                }
                self.emit(SolutionKind::Dvl, out)?;
                self.lagged(t, out);
            }
            Event::Depth(d) => {
                self.nav.propagate_to(t)?;
                let nis = self.nav.depth(t, d)?.nis;
                self.health.record_nis("depth", t, nis, 1)?;
                out.push(Produced::Nis(Sensor::Depth, nis));
            }
            Event::Fix(f) => {
                self.nav.propagate_to(t)?;
                let nis = self
                    .nav
                    .position_fix(t, f.latitude_deg, f.longitude_deg, f.sigma_m)?
                    .nis;
                self.health.record_nis("fixes", t, nis, 2)?;
                out.push(Produced::Nis(Sensor::Fix, nis));
            }
        }
        Ok(())
    }
}
