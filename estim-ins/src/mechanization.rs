//! Strapdown inertial navigation in the local NED frame.
//!
//! # Equations (Groves 2013, sec. 5.4 "Local-navigation-frame navigation equations")
//!
//! - attitude: Ċ_b^n = C_b^n [ω_ib^b ×] - [ω_in^n ×] C_b^n, ω_in^n = ω_ie^n + ω_en^n (eq. 5.46);
//! - velocity: v̇^n = C_b^n f^b + g^n - (2 ω_ie^n + ω_en^n) × v^n (eq. 5.53);
//! - position: L̇ = v_N/(R_N+h), λ̇ = v_E/((R_E+h) cos L), ḣ = -v_D (eq. 5.56).
//!
//! # Discretisation (second order in dt, documented replacement for coning/sculling)
//!
//! An [`ImuSample`] holds the *mean* specific force and angular rate over the step
//! (Δv/dt and Δθ/dt, what an integrating IMU delivers). One step is a two-pass
//! midpoint (predictor-corrector) scheme:
//!
//! 1. body rotation over the step: q(Δθ), Δθ = (ω - b_g) dt (exact for a constant rate);
//!    navigation-frame rotation q(-ω_in^n dt) with ω_in^n at the mid-step position and
//!    velocity;
//! 2. specific-force velocity increment Δv^n = C_b^n(t + dt/2) Δv^b: the attitude at
//!    mid-step, C_b^n(t+dt/2) = q(-ω_in dt/2) C_b^n(t) q(Δθ/2), which contains the
//!    rotation compensation ½ Δθ × Δv of the classic velocity update (Savage 1998,
//!    "Strapdown inertial navigation integration algorithm design part 2", eq. 19)
//!    to second order;
//! 3. gravity and Coriolis at the mid-step state; position by the trapezoidal rule on
//!    velocity (Groves eq. 5.56 form).
//!
//! Pass 1 takes the mid-step state equal to the start of the step, pass 2 the average
//! of the start and the end predicted by pass 1. Local error O(dt^3) for smooth
//! motion; multi-sample coning and sculling corrections need sub-interval increments
//! that one sample per step does not carry (their effect is O(dt^3) per step for smooth
//! motion, see the round-trip tests for the measured figure).

use nalgebra::{UnitQuaternion, Vector3};

use crate::earth::{earth_rate_ned, gravity_ned, radii_of_curvature, transport_rate_ned};
use crate::error::{Error, Result};
use crate::InsState;

/// One IMU sample: raw (bias-including) mean specific force and angular rate over the
/// interval [`time`, `time` + dt], body frame (x forward, y right, z down).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuSample {
    /// Start of the interval the sample covers [s].
    pub time: f64,
    /// Specific force f^b [m/s^2] (about [0, 0, -9.8] when level and still).
    pub specific_force: Vector3<f64>,
    /// Angular rate ω_ib^b [rad/s].
    pub angular_rate: Vector3<f64>,
}

impl ImuSample {
    /// A sample from its parts.
    #[must_use]
    pub fn new(time: f64, specific_force: Vector3<f64>, angular_rate: Vector3<f64>) -> Self {
        Self {
            time,
            specific_force,
            angular_rate,
        }
    }
}

/// Continuous-time rates of the navigation equations at one state (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavigationRates {
    /// L̇ [rad/s].
    pub latitude_rate: f64,
    /// λ̇ [rad/s].
    pub longitude_rate: f64,
    /// ḣ [m/s].
    pub height_rate: f64,
    /// v̇^n [m/s^2].
    pub velocity_rate: Vector3<f64>,
    /// Bias-corrected body rate ω_ib^b [rad/s].
    pub body_rate: Vector3<f64>,
    /// Navigation-frame rate ω_in^n = ω_ie^n + ω_en^n [rad/s].
    pub navigation_frame_rate: Vector3<f64>,
    /// Bias-corrected specific force resolved in NED, C_b^n f^b [m/s^2].
    pub specific_force_ned: Vector3<f64>,
}

/// Continuous-time navigation equations (Groves eqs. 5.46, 5.53, 5.56) at `state` with
/// the raw IMU sample `imu` (the state's bias estimates are removed).
pub fn navigation_rates(state: &InsState, imu: &ImuSample) -> NavigationRates {
    let (meridian, transverse) = radii_of_curvature(state.latitude);
    let v = state.velocity_ned;
    let body_rate = imu.angular_rate - state.gyro_bias;
    let specific_force_ned = state.attitude * (imu.specific_force - state.acc_bias);
    let w_ie = earth_rate_ned(state.latitude);
    let w_en = transport_rate_ned(state.latitude, state.height, &v);
    let velocity_rate = specific_force_ned + gravity_ned(state.latitude, state.height)
        - (2.0 * w_ie + w_en).cross(&v);
    NavigationRates {
        latitude_rate: v.x / (meridian + state.height),
        longitude_rate: v.y / ((transverse + state.height) * state.latitude.cos()),
        height_rate: -v.z,
        velocity_rate,
        body_rate,
        navigation_frame_rate: w_ie + w_en,
        specific_force_ned,
    }
}

/// The strapdown mechanization (stateless; see the module docs for the scheme).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Mechanization;

impl Mechanization {
    /// A mechanization.
    #[must_use]
    pub fn new() -> Self {
        Self
    }

    /// Propagate `state` over `dt` [s] with the raw IMU sample `imu`. The result keeps
    /// the bias estimates, has `time + dt`, and stores the bias-corrected rate in
    /// [`InsState::angular_rate`].
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] if `dt` is not finite and > 0,
    /// [`Error::NonFinite`] if the sample or the result is not finite.
    pub fn step(&self, state: &InsState, imu: &ImuSample, dt: f64) -> Result<InsState> {
        if !(dt.is_finite() && dt > 0.0) {
            return Err(Error::InvalidParameter {
                name: "dt",
                reason: format!("must be finite and > 0, got {dt}"),
            });
        }
        if !(imu.specific_force.iter().all(|x| x.is_finite())
            && imu.angular_rate.iter().all(|x| x.is_finite()))
        {
            return Err(Error::NonFinite {
                what: format!("IMU sample at t = {}", imu.time),
            });
        }
        let next = self.step_unchecked(state, imu, dt);
        if !(next.latitude.is_finite()
            && next.longitude.is_finite()
            && next.height.is_finite()
            && next.velocity_ned.iter().all(|x| x.is_finite())
            && next.attitude.coords.iter().all(|x| x.is_finite()))
        {
            return Err(Error::NonFinite {
                what: format!("INS state after the step from t = {}", state.time),
            });
        }
        Ok(next)
    }

    /// [`Mechanization::step`] without the input and output checks (for hot loops whose
    /// inputs are known to be valid).
    #[must_use]
    pub fn step_unchecked(&self, state: &InsState, imu: &ImuSample, dt: f64) -> InsState {
        let body_rate = imu.angular_rate - state.gyro_bias;
        let delta_v_body = (imu.specific_force - state.acc_bias) * dt;
        let body_rotation = UnitQuaternion::from_scaled_axis(body_rate * dt);
        let body_half = UnitQuaternion::from_scaled_axis(body_rate * (0.5 * dt));

        let (lat0, h0, v0) = (state.latitude, state.height, state.velocity_ned);
        let (rn0, re0) = radii_of_curvature(lat0);
        let cos0 = lat0.cos();
        // Pass 1: mid-step = start; pass 2: mid-step = mean of start and predicted end.
        let (mut lat_mid, mut h_mid, mut v_mid) = (lat0, h0, v0);
        let mut out = *state;
        for _ in 0..2 {
            let (rn, re) = radii_of_curvature(lat_mid);
            let w_ie = earth_rate_ned(lat_mid);
            let w_en = Vector3::new(
                v_mid.y / (re + h_mid),
                -v_mid.x / (rn + h_mid),
                -v_mid.y * lat_mid.tan() / (re + h_mid),
            );
            let w_in = w_ie + w_en;
            let nav_half = UnitQuaternion::from_scaled_axis(w_in * (-0.5 * dt));
            let attitude_mid = nav_half * state.attitude * body_half;
            let velocity = v0
                + attitude_mid * delta_v_body
                + (gravity_ned(lat_mid, h_mid) - (2.0 * w_ie + w_en).cross(&v_mid)) * dt;
            let height = h0 - 0.5 * (v0.z + velocity.z) * dt;
            let latitude = lat0 + 0.5 * dt * (v0.x / (rn0 + h0) + velocity.x / (rn0 + height));
            let (_, re1) = radii_of_curvature(latitude);
            let longitude = state.longitude
                + 0.5
                    * dt
                    * (v0.y / ((re0 + h0) * cos0) + velocity.y / ((re1 + height) * latitude.cos()));
            let nav_rotation = nav_half * nav_half;
            out.attitude = nav_rotation * state.attitude * body_rotation;
            out.velocity_ned = velocity;
            out.latitude = latitude;
            out.longitude = longitude;
            out.height = height;
            lat_mid = 0.5 * (lat0 + latitude);
            h_mid = 0.5 * (h0 + height);
            v_mid = 0.5 * (v0 + velocity);
        }
        // Renormalise: products of unit quaternions drift from unit norm by rounding.
        out.attitude = UnitQuaternion::new_normalize(out.attitude.into_inner());
        out.time = state.time + dt;
        out.angular_rate = body_rate;
        out
    }
}
