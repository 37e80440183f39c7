//! What the navigator reports: its solution, update counts, headings as printed.

use estim_core::UpdateReport;
use estim_ins::{ErrorMatrix, InsState, ACC_BIAS, ATT, GYRO_BIAS, POS, VEL};
use serde::Serialize;

/// Counts of what the navigator did with its inputs.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct UpdateCounts {
    /// Updates accepted (including recovered ones).
    pub accepted: usize,
    /// Updates rejected by the innovation gate.
    pub gated: usize,
    /// Updates the gate would have rejected, accepted with P inflated after a run of
    /// rejections (`gate.recovery_after`).
    pub recovered: usize,
}

impl UpdateCounts {
    pub(crate) fn count<const N: usize, const M: usize>(
        &mut self,
        report: &UpdateReport<f64, N, M>,
    ) {
        if report.is_accepted() {
            self.accepted += 1;
            if report.covariance_inflation.is_some() {
                self.recovered += 1;
            }
        } else {
            self.gated += 1;
        }
    }
}

/// The navigation solution at one time, with 1-sigma per state (from the diagonal
/// of the error covariance; the error state's own frames: position N, E, D metres,
/// misalignment about N, E, D).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NavSolution {
    /// Time \[s\] on the navigator's clock.
    pub time: f64,
    /// Latitude \[deg\].
    pub latitude_deg: f64,
    /// Longitude \[deg\].
    pub longitude_deg: f64,
    /// Depth \[m\] (positive down: -height).
    pub depth_m: f64,
    /// Velocity N, E, D \[m/s\].
    pub velocity_ned_mps: [f64; 3],
    /// Roll \[deg\].
    pub roll_deg: f64,
    /// Pitch \[deg\].
    pub pitch_deg: f64,
    /// Heading \[deg\] in [0, 360).
    pub heading_deg: f64,
    /// Accelerometer bias estimate \[m/s^2\].
    pub acc_bias_mps2: [f64; 3],
    /// Gyroscope bias estimate \[rad/s\].
    pub gyro_bias_radps: [f64; 3],
    /// 1-sigma of the position error N, E, D \[m\].
    pub position_sigma_m: [f64; 3],
    /// 1-sigma of the velocity error N, E, D \[m/s\].
    pub velocity_sigma_mps: [f64; 3],
    /// 1-sigma of the misalignment about N, E, D \[deg\] (about N and E: level; about
    /// D: heading).
    pub attitude_sigma_deg: [f64; 3],
    /// 1-sigma of the accelerometer bias \[m/s^2\].
    pub acc_bias_sigma_mps2: [f64; 3],
    /// 1-sigma of the gyroscope bias \[rad/s\].
    pub gyro_bias_sigma_radps: [f64; 3],
}

impl NavSolution {
    /// The solution of a nominal state and its error covariance at `time`.
    pub fn from_state(time: f64, state: &InsState, covariance: &ErrorMatrix) -> Self {
        let sigma = |i: usize| covariance[(i, i)].max(0.0).sqrt();
        let group = |start: usize| [sigma(start), sigma(start + 1), sigma(start + 2)];
        let (roll, pitch, yaw) = state.roll_pitch_yaw();
        let heading = wrap_heading_deg(yaw.to_degrees());
        let attitude = group(ATT).map(f64::to_degrees);
        Self {
            time,
            latitude_deg: state.latitude.to_degrees(),
            longitude_deg: state.longitude.to_degrees(),
            depth_m: -state.height,
            velocity_ned_mps: state.velocity_ned.into(),
            roll_deg: roll.to_degrees(),
            pitch_deg: pitch.to_degrees(),
            heading_deg: heading,
            acc_bias_mps2: state.acc_bias.into(),
            gyro_bias_radps: state.gyro_bias.into(),
            position_sigma_m: group(POS),
            velocity_sigma_mps: group(VEL),
            attitude_sigma_deg: attitude,
            acc_bias_sigma_mps2: group(ACC_BIAS),
            gyro_bias_sigma_radps: group(GYRO_BIAS),
        }
    }
}

/// A heading \[deg\] wrapped into [0, 360).
///
/// `f64::rem_euclid` alone is not enough: it returns -0.0 for -0.0 (printed `-0`), and
/// for a negative value smaller in magnitude than half an ulp of 360 (e.g. -1e-15) the
/// sum `x + 360` rounds to 360.0 exactly. Both are mapped to +0.0.
pub fn wrap_heading_deg(deg: f64) -> f64 {
    let wrapped = deg.rem_euclid(360.0);
    if wrapped >= 360.0 {
        0.0
    } else {
        // -0.0 + 0.0 is +0.0 (IEEE 754, round to nearest).
        wrapped + 0.0
    }
}

/// A heading as text with `decimals` decimals, in [0, 360) as printed: a heading
/// that rounds up to 360 at that precision (359.9999996 with 5 decimals) is printed
/// as 0.
pub fn format_heading(deg: f64, decimals: usize) -> String {
    let text = format!("{:.decimals$}", wrap_heading_deg(deg));
    if text.starts_with("360") {
        format!("{:.decimals$}", 0.0)
    } else {
        text
    }
}
