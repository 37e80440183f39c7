//! The INS nominal state and the 15-state error-state conventions.

use nalgebra::{UnitQuaternion, Vector3};

/// Size of the INS error state.
pub const ERROR_STATES: usize = 15;
/// Index of the position error (N, E, D metres) in the error state.
pub const POS: usize = 0;
/// Index of the velocity error (NED m/s).
pub const VEL: usize = 3;
/// Index of the misalignment ψ (NED rad).
pub const ATT: usize = 6;
/// Index of the accelerometer bias error (m/s^2).
pub const ACC_BIAS: usize = 9;
/// Index of the gyroscope bias error (rad/s).
pub const GYRO_BIAS: usize = 12;

/// The INS nominal (whole) state.
///
/// # Conventions (pinned; every Jacobian in estim-ins and estim-dvl follows them)
///
/// - Navigation frame: local NED. Body frame: x forward, y right, z down.
/// - `attitude` is the rotation body -> NED, C_b^n.
/// - The error state is `true = nominal + error` ("true = nominal ⊕ error"):
///   - position error δp in metres along N, E, D: lat_true = lat + δp_N / (R_N + h),
///     lon_true = lon + δp_E / ((R_E + h) cos lat), h_true = h - δp_D;
///   - velocity error δv^n = v_true - v_nominal (NED);
///   - misalignment ψ (NED frame, small angle): C_b^n,true = (I + [ψ×]) C_b^n,nominal;
///   - accelerometer / gyroscope bias errors δb = b_true - b_nominal.
/// - IMU measurements: f_meas = f_true + b_a + noise, ω_meas = ω_true + b_g + noise;
///   the mechanization uses f = f_meas - b_a,nominal, ω = ω_meas - b_g,nominal.
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InsState {
    /// Time \[s\].
    pub time: f64,
    /// Geodetic latitude \[rad\].
    pub latitude: f64,
    /// Geodetic longitude \[rad\].
    pub longitude: f64,
    /// Height above the WGS-84 ellipsoid \[m\]; negative under water, never abs()'d.
    pub height: f64,
    /// Velocity in NED \[m/s\].
    pub velocity_ned: Vector3<f64>,
    /// Attitude, rotation body -> NED (C_b^n).
    pub attitude: UnitQuaternion<f64>,
    /// Estimated accelerometer bias [m/s^2].
    pub acc_bias: Vector3<f64>,
    /// Estimated gyroscope bias \[rad/s\].
    pub gyro_bias: Vector3<f64>,
    /// Latest bias-corrected angular rate ω_ib^b \[rad/s\], kept by the mechanization for
    /// lever-arm terms of aiding measurements.
    pub angular_rate: Vector3<f64>,
}

impl InsState {
    /// A state with zero bias estimates and zero angular rate.
    #[must_use]
    pub fn new(
        time: f64,
        latitude: f64,
        longitude: f64,
        height: f64,
        velocity_ned: Vector3<f64>,
        attitude: UnitQuaternion<f64>,
    ) -> Self {
        Self {
            time,
            latitude,
            longitude,
            height,
            velocity_ned,
            attitude,
            acc_bias: Vector3::zeros(),
            gyro_bias: Vector3::zeros(),
            angular_rate: Vector3::zeros(),
        }
    }

    /// Attitude as (roll, pitch, yaw) \[rad\], ZYX Euler angles of C_b^n.
    #[must_use]
    pub fn roll_pitch_yaw(&self) -> (f64, f64, f64) {
        self.attitude.euler_angles()
    }
}
