//! Strapdown inertial navigation in the local NED frame.
//!
//! # Equations (Groves 2013, sec. 5.4 "Local-navigation-frame navigation equations")
//!
//! - attitude: Ċ_b^n = C_b^n \[ω_ib^b ×\] - \[ω_in^n ×\] C_b^n, ω_in^n = ω_ie^n + ω_en^n (eq. 5.46);
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

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use crate::earth::{
    earth_rate_ned, gravity_ned, height_factor, radii_of_curvature, transport_rate_ned, EARTH_RATE,
    ECCENTRICITY_SQUARED, GRAVITY_EQUATOR, SEMI_MAJOR_AXIS, SOMIGLIANA_K,
};
use crate::error::{Error, Result};
use crate::InsState;

/// One IMU sample: raw (bias-including) mean specific force and angular rate over the
/// interval [`time`, `time` + dt], body frame (x forward, y right, z down).
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuSample {
    /// Start of the interval the sample covers \[s\].
    pub time: f64,
    /// Specific force f^b \[m/s^2\] (about \[0, 0, -9.8\] when level and still).
    pub specific_force: Vector3<f64>,
    /// Angular rate ω_ib^b \[rad/s\].
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
    /// L̇ \[rad/s\].
    pub latitude_rate: f64,
    /// λ̇ \[rad/s\].
    pub longitude_rate: f64,
    /// ḣ \[m/s\].
    pub height_rate: f64,
    /// v̇^n \[m/s^2\].
    pub velocity_rate: Vector3<f64>,
    /// Bias-corrected body rate ω_ib^b \[rad/s\].
    pub body_rate: Vector3<f64>,
    /// Navigation-frame rate ω_in^n = ω_ie^n + ω_en^n \[rad/s\].
    pub navigation_frame_rate: Vector3<f64>,
    /// Bias-corrected specific force resolved in NED, C_b^n f^b \[m/s^2\].
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

    /// Propagate `state` over `dt` \[s\] with the raw IMU sample `imu`. The result keeps
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
        let body_half = small_rotation(&(body_rate * (0.5 * dt)));
        // C_b^n(t) q(Δθ/2) and the specific-force increment resolved by it: neither depends
        // on the navigation-frame rotation, so both passes share them, and each pass only
        // rotates the increment by its small q(-ω_in dt/2) (C_b^n(t+dt/2) Δv^b =
        // q(-ω_in dt/2) [C_b^n(t) q(Δθ/2) Δv^b], step 2 of the module docs).
        let attitude_body = state.attitude * body_half;
        let delta_v_body = attitude_body * ((imu.specific_force - state.acc_bias) * dt);

        let (lat0, h0, v0) = (state.latitude, state.height, state.velocity_ned);
        let (sin0, cos0) = lat0.sin_cos();
        let earth0 = LocalEarth::new(sin0, cos0);
        let half_dt = 0.5 * dt;
        // The start-of-step halves of the trapezoidal position rule (the same in both passes).
        let north_rate0 = v0.x / (earth0.meridian + h0);
        let east_rate0 = v0.y / ((earth0.transverse + h0) * cos0);
        let end_of_pass = |earth_mid: &LocalEarth, h_mid: f64, v_mid: &Vector3<f64>| {
            let w_ie = Vector3::new(EARTH_RATE * earth_mid.cos, 0.0, -EARTH_RATE * earth_mid.sin);
            let re = earth_mid.transverse + h_mid;
            let w_en = Vector3::new(
                v_mid.y / re,
                -v_mid.x / (earth_mid.meridian + h_mid),
                -v_mid.y * earth_mid.sin / (earth_mid.cos * re),
            );
            let nav_half = small_rotation(&((w_ie + w_en) * (-half_dt)));
            let gravity = Vector3::new(0.0, 0.0, earth_mid.gravity(h_mid));
            let velocity =
                v0 + nav_half * delta_v_body + (gravity - (2.0 * w_ie + w_en).cross(v_mid)) * dt;
            let height = h0 - 0.5 * (v0.z + velocity.z) * dt;
            let delta_lat = half_dt * (north_rate0 + velocity.x / (earth0.meridian + height));
            (nav_half, velocity, height, delta_lat)
        };
        // Pass 1: mid-step = start; pass 2: mid-step = mean of start and predicted end.
        // Pass 1 only predicts the end velocity, height and latitude that pass 2 needs.
        let (_, velocity, height, delta_lat) = end_of_pass(&earth0, h0, &v0);
        let (nav_half, velocity, height, delta_lat) = end_of_pass(
            &earth0.moved(0.5 * delta_lat, lat0),
            0.5 * (h0 + height),
            &(0.5 * (v0 + velocity)),
        );
        let earth1 = earth0.moved(delta_lat, lat0);
        let longitude = state.longitude
            + half_dt * (east_rate0 + velocity.y / ((earth1.transverse + height) * earth1.cos));
        // C_b^n(t+dt) = q(-ω_in dt/2)² C_b^n(t) q(Δθ/2)², then renormalised: products of
        // unit quaternions drift from unit norm by rounding.
        let attitude =
            (nav_half * nav_half * state.attitude * (body_half * body_half)).into_inner();
        InsState {
            time: state.time + dt,
            latitude: lat0 + delta_lat,
            longitude,
            height,
            velocity_ned: velocity,
            attitude: renormalise(attitude),
            acc_bias: state.acc_bias,
            gyro_bias: state.gyro_bias,
            angular_rate: body_rate,
        }
    }
}

/// The unit quaternion of `q` (a product of unit quaternions, off unit norm by rounding).
/// With |q|² = 1 + δ, 1/|q| = 1 - δ/2 + 3δ²/8 - ..., so for |δ| < 1e-8 the first-order
/// correction q (1 - |q|²)/2 is exact to 4e-17 relative (below one rounding) and costs no
/// square root or division (added as a small term, not as a factor 1 + δ/2 rounded to the
/// spacing of 1, which measured a 3 x larger attitude drift in the 1 h stationary test);
/// anything further off is normalised exactly.
#[inline]
fn renormalise(q: Quaternion<f64>) -> UnitQuaternion<f64> {
    let n2 = q.norm_squared();
    if (n2 - 1.0).abs() < 1e-8 {
        // q + q (1 - |q|²)/2: the small correction added last, rounded once.
        UnitQuaternion::new_unchecked(q + q * (0.5 * (1.0 - n2)))
    } else {
        UnitQuaternion::new_normalize(q)
    }
}

/// Rotation quaternion of a rotation vector; below 0.01 rad by the Taylor series of
/// cos(θ/2) and sin(θ/2)/θ to θ⁴ (remainder < 3e-17), else the exact formula.
#[inline]
fn small_rotation(v: &Vector3<f64>) -> UnitQuaternion<f64> {
    let t2 = v.norm_squared();
    if t2 < 1e-4 {
        // Multiplications by the reciprocal coefficients (a division by 48 is not exact in
        // binary, so the compiler keeps it a 13-cycle divide): the terms are below 1e-8
        // of the sum, so their own rounding does not reach the result's.
        let w = 1.0 - t2 * 0.125 + t2 * t2 * (1.0 / 384.0);
        let s = 0.5 - t2 * (1.0 / 48.0) + t2 * t2 * (1.0 / 3840.0);
        UnitQuaternion::new_unchecked(Quaternion::new(w, s * v.x, s * v.y, s * v.z))
    } else {
        UnitQuaternion::from_scaled_axis(*v)
    }
}

/// Latitude-dependent Earth quantities from sin L and cos L (one square root).
#[derive(Debug, Clone, Copy)]
struct LocalEarth {
    sin: f64,
    cos: f64,
    meridian: f64,
    transverse: f64,
    /// Somigliana normal gravity on the ellipsoid, g_0(L) (Groves eq. 2.134).
    surface_gravity: f64,
}

impl LocalEarth {
    #[inline]
    fn new(sin: f64, cos: f64) -> Self {
        let s2 = sin * sin;
        let d = 1.0 - ECCENTRICITY_SQUARED * s2;
        // One division: R_E = a / sqrt(d), R_N = R_E (1 - e²) / d, g_0 ∝ 1 / sqrt(d).
        let inverse_root = 1.0 / d.sqrt();
        let transverse = SEMI_MAJOR_AXIS * inverse_root;
        Self {
            sin,
            cos,
            meridian: transverse * (1.0 - ECCENTRICITY_SQUARED) * (inverse_root * inverse_root),
            transverse,
            surface_gravity: GRAVITY_EQUATOR * (1.0 + SOMIGLIANA_K * s2) * inverse_root,
        }
    }

    /// The quantities at latitude L + delta (series for |delta| < 1e-3 rad, remainder
    /// below delta^5/120 < 1e-17; exact trigonometry beyond).
    #[inline]
    fn moved(&self, delta: f64, latitude: f64) -> Self {
        if delta.abs() < 1e-3 {
            let d2 = delta * delta;
            let c = 1.0 - d2 * 0.5 + d2 * d2 * (1.0 / 24.0);
            let s = delta * (1.0 - d2 * (1.0 / 6.0));
            Self::new(self.sin * c + self.cos * s, self.cos * c - self.sin * s)
        } else {
            let (s, c) = (latitude + delta).sin_cos();
            Self::new(s, c)
        }
    }

    /// Normal gravity at `height` (Groves eq. 2.139).
    #[inline]
    fn gravity(&self, height: f64) -> f64 {
        self.surface_gravity * height_factor(height)
    }
}
