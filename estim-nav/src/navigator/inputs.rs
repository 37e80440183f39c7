//! What a survey provides and what a batch run reports to its observer.

use estim_ins::{ErrorMatrix, ImuSample, InsState};
use nalgebra::Vector3;
use serde::Serialize;

use super::NavSolution;

/// One DVL row: a velocity, beams, or a row without bottom lock.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DvlInput {
    /// Velocity in the DVL frame \[m/s\].
    Velocity(Vector3<f64>),
    /// Beam velocities \[m/s\] (`None` = missing beam).
    Beams([Option<f64>; 4]),
    /// The vehicle's velocity N, E, D \[m/s\] (a DVL in earth coordinates): rotated
    /// into the body frame with the filter's attitude at the update time and used as
    /// a DVL-frame velocity (the attitude error it carries is not modelled).
    EarthVelocity(Vector3<f64>),
    /// No bottom lock (NaN, empty, the -32.768 marker or a validity flag): skipped
    /// and counted, never used.
    NoLock,
}

/// A DVL row at its stamped time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DvlRecord {
    /// Time stamp \[s\] (before the configured time offset).
    pub time: f64,
    /// What the row holds.
    pub input: DvlInput,
}

/// A depth sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthSample {
    /// Time stamp \[s\].
    pub time: f64,
    /// Depth \[m\], positive down.
    pub depth_m: f64,
}

/// A position fix.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PositionFix {
    /// Time stamp \[s\].
    pub time: f64,
    /// Latitude \[deg\].
    pub latitude_deg: f64,
    /// Longitude \[deg\].
    pub longitude_deg: f64,
    /// Horizontal 1-sigma \[m\].
    pub sigma_m: f64,
}

/// Everything a survey provides, each series in time order on one clock.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SurveyInputs {
    /// IMU samples (sample k covers [t_k, t_k+1]).
    pub imu: Vec<ImuSample>,
    /// DVL rows.
    pub dvl: Vec<DvlRecord>,
    /// Depth samples.
    pub depth: Vec<DepthSample>,
    /// Position fixes.
    pub fixes: Vec<PositionFix>,
    /// Times at which to emit a [`SolutionKind::Epoch`] solution besides the others
    /// (an evaluation's reference epochs), in time order: a copy of the estimate is
    /// predicted to each exactly with the IMU sample in effect; the filter's own steps
    /// are those of a run without them.
    pub output_epochs: Vec<f64>,
}

/// Why a solution was emitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SolutionKind {
    /// After a DVL epoch (used or not); for the smoother, an accepted DVL update.
    Dvl,
    /// At the output rate.
    Rate,
    /// A smoothed epoch whose updates are depth or fixes only.
    Aiding,
    /// The smoother's last epoch: the propagation after the last update.
    End,
    /// At one of [`SurveyInputs::output_epochs`].
    Epoch,
}

impl SolutionKind {
    /// The name written in `solution.csv` (`dvl`, `rate`, `aiding`, `end`).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Dvl => "dvl",
            Self::Rate => "rate",
            Self::Aiding => "aiding",
            Self::End => "end",
            Self::Epoch => "epoch",
        }
    }
}

/// Receives every solution of [`super::navigate`] (writers and evaluators are observers).
pub trait NavigationObserver {
    /// One solution; `state` and `covariance` are the filter's at that time.
    ///
    /// # Errors
    /// Whatever the observer reports; the run stops with [`NavigatorError::Observer`](crate::navigator::NavigatorError::Observer).
    fn on_solution(
        &mut self,
        kind: SolutionKind,
        solution: &NavSolution,
        state: &InsState,
        covariance: &ErrorMatrix,
    ) -> std::result::Result<(), Box<dyn std::error::Error + Send + Sync>>;
}

impl NavigationObserver for () {
    fn on_solution(
        &mut self,
        _: SolutionKind,
        _: &NavSolution,
        _: &InsState,
        _: &ErrorMatrix,
    ) -> std::result::Result<(), Box<dyn std::error::Error + Send + Sync>> {
        Ok(())
    }
}
