//! The value of `--imu` (`reproduce`, `compare`) and `--imu-source` (`smooth`'s
//! A-KIT mode): which IMU an A-KIT trajectory is run on.

use serde::Serialize;

/// Which IMU an A-KIT trajectory is run on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ImuChoice {
    /// The recorded IMU where the trajectory's folder holds one, else synthesized.
    #[default]
    Auto,
    /// The recorded IMU; a trajectory without one is an error.
    Recorded,
    /// The IMU synthesized from the reference, everywhere.
    Synthesized,
}
