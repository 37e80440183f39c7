//! What the history checkpoints and replays: the navigator with everything its later
//! steps depend on (the health monitor's NIS windows, the rate output's schedule),
//! applying events exactly as the batch run's hook does.

use std::sync::Arc;

use estim_core::Zero;
use estim_dvl::BeamGeometry;
use estim_ins::ImuSample;

use super::history::{EventKey, Replay};
use super::Sensor;
use crate::navigator::{
    DvlInput, HealthMonitor, NavSolution, NavigationModel, Navigator, NavigatorError, PositionFix,
    SolutionKind,
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
#[derive(Debug, Clone, Copy)]
pub(super) enum Produced {
    Solution(SolutionKind, NavSolution),
    Nis(Sensor, f64),
    InsufficientBeams,
}

/// The navigator and the state of the batch hook's bookkeeping.
pub(super) struct Replica<E: NavigationModel<N>, const N: usize> {
    pub(super) nav: Navigator<E, estim_core::NoObserver, N>,
    health: HealthMonitor,
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
    ) -> Self {
        Self {
            nav,
            health,
            geometry,
            rate,
            next_output: 0,
        }
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
