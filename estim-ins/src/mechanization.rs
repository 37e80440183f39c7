//! Strapdown inertial navigation in the local NED frame.

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use crate::earth::{
    earth_rate_ned, gravity_ned, height_factor, inverse_root_of_prime_vertical_factor,
    latitude_sin_cos, radii_of_curvature, transport_rate_ned, EARTH_RATE, ECCENTRICITY_SQUARED,
    GRAVITY_EQUATOR, SEMI_MAJOR_AXIS, SOMIGLIANA_K,
};
use crate::error::{Error, Result};
use crate::kernel::{hand_tuned, MultiplyAdd};
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

/// Continuous-time rates of the navigation equations at one state (the equations of [`Mechanization`]).
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

/// The strapdown mechanization (stateless; the scheme below).
///
/// # Equations (Groves 2013, sec. 5.4 "Local-navigation-frame navigation equations")
///
/// - attitude: Ċ_b^n = C_b^n \[ω_ib^b ×\] - \[ω_in^n ×\] C_b^n, ω_in^n = ω_ie^n + ω_en^n (eq. 5.46);
/// - velocity: v̇^n = C_b^n f^b + g^n - (2 ω_ie^n + ω_en^n) × v^n (eq. 5.53);
/// - position: L̇ = v_N/(R_N+h), λ̇ = v_E/((R_E+h) cos L), ḣ = -v_D (eq. 5.56).
///
/// # Discretisation (second order in dt, documented replacement for coning/sculling)
///
/// An [`ImuSample`] holds the *mean* specific force and angular rate over the step
/// (Δv/dt and Δθ/dt, what an integrating IMU delivers). One step is a two-pass
/// midpoint (predictor-corrector) scheme:
///
/// 1. body rotation over the step: q(Δθ), Δθ = (ω - b_g) dt (exact for a constant rate);
///    navigation-frame rotation q(-ω_in^n dt) with ω_in^n at the mid-step position and
///    velocity;
/// 2. specific-force velocity increment Δv^n = C_b^n(t + dt/2) Δv^b: the attitude at
///    mid-step, C_b^n(t+dt/2) = q(-ω_in dt/2) C_b^n(t) q(Δθ/2), which contains the
///    rotation compensation ½ Δθ × Δv of the classic velocity update (Savage 1998,
///    "Strapdown inertial navigation integration algorithm design part 2", eq. 19)
///    to second order;
/// 3. gravity and Coriolis at the mid-step state; position by the trapezoidal rule on
///    velocity (Groves eq. 5.56 form).
///
/// Pass 1 takes the mid-step state equal to the start of the step, pass 2 the average
/// of the start and the end predicted by pass 1. Local error O(dt^3) for smooth
/// motion; multi-sample coning and sculling corrections need sub-interval increments
/// that one sample per step does not carry (their effect is O(dt^3) per step for smooth
/// motion, see the round-trip tests for the measured figure).
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
    ///
    /// On a CPU with FMA (x86-64 with AVX2 or AVX-512) the step runs a build compiled with
    /// fused multiply-adds, chosen at run time as the covariance kernels are; elsewhere the
    /// portable build rounds each product and sum separately. The two differ by rounding
    /// only (`tests::both_builds_agree_to_rounding`).
    #[must_use]
    pub fn step_unchecked(&self, state: &InsState, imu: &ImuSample, dt: f64) -> InsState {
        step_dispatched(state, imu, dt)
    }
}

hand_tuned! {
    /// [`Mechanization::step_unchecked`]: the build compiled with FMA (and AVX2's
    /// three-operand forms) where the dispatch allows it (AVX-512 CPUs run it too), else
    /// the portable one.
    fn step_dispatched(state: &InsState, imu: &ImuSample, dt: f64) -> InsState
        = step_body in [avx2_fma];
}

/// A vector's components (the body works on plain arrays so that every multiply-add is
/// written out, and fused in the FMA build).
type Components = [f64; 3];
/// A quaternion's components, scalar first: \[w, x, y, z\].
type QuaternionComponents = [f64; 4];

/// One step (the scheme of [`Mechanization`]). Products of two terms summed are
/// written as multiply-adds in pairs (a b + c d as mad(a, b, c d): one multiply, then one
/// multiply-add, instead of a chain through every term), each separately rounded in the
/// portable build, fused in the FMA one.
#[inline(always)]
fn step_body<M: MultiplyAdd>(state: &InsState, imu: &ImuSample, dt: f64) -> InsState {
    let mad = M::multiply_add;
    let gyro_bias = [state.gyro_bias.x, state.gyro_bias.y, state.gyro_bias.z];
    let body_rate = [
        imu.angular_rate.x - gyro_bias[0],
        imu.angular_rate.y - gyro_bias[1],
        imu.angular_rate.z - gyro_bias[2],
    ];
    let half_dt = 0.5 * dt;
    let body_half = small_rotation::<M>(&scaled(&body_rate, half_dt));
    let q = state.attitude.quaternion();
    let attitude0 = [q.w, q.i, q.j, q.k];
    // C_b^n(t) q(Δθ/2) and the specific-force increment resolved by it: neither depends
    // on the navigation-frame rotation, so both passes share them, and each pass only
    // rotates the increment by its small q(-ω_in dt/2) (C_b^n(t+dt/2) Δv^b =
    // q(-ω_in dt/2) [C_b^n(t) q(Δθ/2) Δv^b], step 2 of the scheme in [`Mechanization`]).
    let attitude_body = product::<M>(&attitude0, &body_half);
    let delta_v_body = rotate::<M>(
        &attitude_body,
        &[
            (imu.specific_force.x - state.acc_bias.x) * dt,
            (imu.specific_force.y - state.acc_bias.y) * dt,
            (imu.specific_force.z - state.acc_bias.z) * dt,
        ],
    );

    let (lat0, h0) = (state.latitude, state.height);
    let v0 = [
        state.velocity_ned.x,
        state.velocity_ned.y,
        state.velocity_ned.z,
    ];
    let (sin0, cos0) = latitude_sin_cos::<M>(lat0);
    let earth0 = LocalEarth::new::<M>(sin0, cos0);
    // The start-of-step halves of the trapezoidal position rule (the same in both passes).
    let north_rate0 = v0[0] / (earth0.meridian + h0);
    let east_rate0 = v0[1] / ((earth0.transverse + h0) * cos0);
    // A function, not a closure: closures do not inherit the FMA build's target features.
    let start = StepStart {
        dt,
        v0,
        h0,
        north_rate0,
        meridian0: earth0.meridian,
        delta_v_body,
    };
    // Pass 1: mid-step = start; pass 2: mid-step = mean of start and predicted end.
    // Pass 1 only predicts the end velocity, height and latitude that pass 2 needs.
    let (_, velocity, height, delta_lat) = end_of_pass::<M>(&start, &earth0, h0, &v0);
    let (nav_half, velocity, height, delta_lat) = end_of_pass::<M>(
        &start,
        &earth0.moved::<M>(0.5 * delta_lat, lat0),
        0.5 * (h0 + height),
        &[
            0.5 * (v0[0] + velocity[0]),
            0.5 * (v0[1] + velocity[1]),
            0.5 * (v0[2] + velocity[2]),
        ],
    );
    let earth1 = earth0.moved::<M>(delta_lat, lat0);
    let longitude = mad(
        half_dt,
        east_rate0 + velocity[1] / ((earth1.transverse + height) * earth1.cos),
        state.longitude,
    );
    // C_b^n(t+dt) = q(-ω_in dt/2)² C_b^n(t) q(Δθ/2)², then renormalised: products of
    // unit quaternions drift from unit norm by rounding. The product order is the one
    // the 1 h stationary test measured best (README: a reordered product drifted 100 x
    // more).
    // Through nalgebra's product (no fused multiply-add: Rust does not contract a * b + c,
    // so both builds round these products alike): the fused pairs measured a 160 x larger
    // attitude drift in the 1 h stationary test (3.6e-11 rad against 2.2e-13; there every
    // step repeats the same rounding, which adds up linearly unless it cancels).
    let nav_half = Quaternion::new(nav_half[0], nav_half[1], nav_half[2], nav_half[3]);
    let body_half = Quaternion::new(body_half[0], body_half[1], body_half[2], body_half[3]);
    let attitude = nav_half * nav_half * state.attitude.quaternion() * (body_half * body_half);
    InsState {
        time: state.time + dt,
        latitude: lat0 + delta_lat,
        longitude,
        height,
        velocity_ned: Vector3::from(velocity),
        attitude: renormalise::<M>(&[attitude.w, attitude.i, attitude.j, attitude.k]),
        acc_bias: state.acc_bias,
        gyro_bias: state.gyro_bias,
        angular_rate: Vector3::from(body_rate),
    }
}

/// What both passes of a step share: dt, the start velocity and height, the start half
/// of the latitude rule, R_N at the start and the resolved specific-force increment.
struct StepStart {
    dt: f64,
    v0: Components,
    h0: f64,
    north_rate0: f64,
    meridian0: f64,
    delta_v_body: Components,
}

/// One pass of the step with the mid-step Earth terms, height and velocity: the
/// navigation-frame half rotation q(-ω_in dt/2), and the end velocity, height and latitude
/// change.
#[inline(always)]
fn end_of_pass<M: MultiplyAdd>(
    start: &StepStart,
    earth_mid: &LocalEarth,
    h_mid: f64,
    v_mid: &Components,
) -> (QuaternionComponents, Components, f64, f64) {
    let mad = M::multiply_add;
    let StepStart {
        dt,
        v0,
        h0,
        north_rate0,
        meridian0,
        delta_v_body,
    } = *start;
    let half_dt = 0.5 * dt;
    let w_ie = [EARTH_RATE * earth_mid.cos, 0.0, -EARTH_RATE * earth_mid.sin];
    let re = earth_mid.transverse + h_mid;
    let w_en = [
        v_mid[1] / re,
        -v_mid[0] / (earth_mid.meridian + h_mid),
        -v_mid[1] * earth_mid.sin / (earth_mid.cos * re),
    ];
    let nav_half = small_rotation::<M>(&[
        (w_ie[0] + w_en[0]) * -half_dt,
        (w_ie[1] + w_en[1]) * -half_dt,
        (w_ie[2] + w_en[2]) * -half_dt,
    ]);
    let gravity = earth_mid.gravity(h_mid);
    let rotated = rotate::<M>(&nav_half, &delta_v_body);
    let coriolis = cross::<M>(
        &[
            mad(2.0, w_ie[0], w_en[0]),
            mad(2.0, w_ie[1], w_en[1]),
            mad(2.0, w_ie[2], w_en[2]),
        ],
        v_mid,
    );
    let velocity = [
        mad(-coriolis[0], dt, v0[0] + rotated[0]),
        mad(-coriolis[1], dt, v0[1] + rotated[1]),
        mad(gravity - coriolis[2], dt, v0[2] + rotated[2]),
    ];
    let height = mad(-half_dt, v0[2] + velocity[2], h0);
    let delta_lat = half_dt * (north_rate0 + velocity[0] / (meridian0 + height));
    (nav_half, velocity, height, delta_lat)
}

/// v s.
#[inline(always)]
fn scaled(v: &Components, s: f64) -> Components {
    [v[0] * s, v[1] * s, v[2] * s]
}

/// a × b, each component as mad(a_i, b_j, -(a_j b_i)).
#[inline(always)]
fn cross<M: MultiplyAdd>(a: &Components, b: &Components) -> Components {
    let mad = M::multiply_add;
    [
        mad(a[1], b[2], -(a[2] * b[1])),
        mad(a[2], b[0], -(a[0] * b[2])),
        mad(a[0], b[1], -(a[1] * b[0])),
    ]
}

/// The Hamilton product a b, each component two multiply-add pairs.
#[inline(always)]
fn product<M: MultiplyAdd>(
    a: &QuaternionComponents,
    b: &QuaternionComponents,
) -> QuaternionComponents {
    let mad = M::multiply_add;
    [
        mad(a[0], b[0], -(a[1] * b[1])) - mad(a[2], b[2], a[3] * b[3]),
        mad(a[0], b[1], a[1] * b[0]) + mad(a[2], b[3], -(a[3] * b[2])),
        mad(a[0], b[2], -(a[1] * b[3])) + mad(a[2], b[0], a[3] * b[1]),
        mad(a[0], b[3], a[1] * b[2]) + mad(a[3], b[0], -(a[2] * b[1])),
    ]
}

/// The rotation of `v` by the unit quaternion `q`: v + w t + u × t with t = 2 u × v,
/// u = (x, y, z) (the form nalgebra uses).
#[inline(always)]
fn rotate<M: MultiplyAdd>(q: &QuaternionComponents, v: &Components) -> Components {
    let u = [q[1], q[2], q[3]];
    let t = scaled(&cross::<M>(&u, v), 2.0);
    let c = cross::<M>(&u, &t);
    let mad = M::multiply_add;
    [
        mad(q[0], t[0], c[0]) + v[0],
        mad(q[0], t[1], c[1]) + v[1],
        mad(q[0], t[2], c[2]) + v[2],
    ]
}

/// The unit quaternion of `q` (a product of unit quaternions, off unit norm by rounding).
/// With |q|² = 1 + δ, 1/|q| = 1 - δ/2 + 3δ²/8 - ..., so for |δ| < 1e-8 the first-order
/// correction q (1 - |q|²)/2 is exact to 4e-17 relative (below one rounding) and costs no
/// square root or division (added as a small term, not as a factor 1 + δ/2 rounded to the
/// spacing of 1, which measured a 3 x larger attitude drift in the 1 h stationary test);
/// anything further off is normalised exactly.
#[inline(always)]
fn renormalise<M: MultiplyAdd>(q: &QuaternionComponents) -> UnitQuaternion<f64> {
    let mad = M::multiply_add;
    let n2 = mad(q[0], q[0], q[1] * q[1]) + mad(q[2], q[2], q[3] * q[3]);
    let quaternion = Quaternion::new(q[0], q[1], q[2], q[3]);
    if (n2 - 1.0).abs() < 1e-8 {
        // q + q (1 - |q|²)/2: the small correction added last, rounded once.
        let k = 0.5 * (1.0 - n2);
        UnitQuaternion::new_unchecked(Quaternion::new(
            mad(q[0], k, q[0]),
            mad(q[1], k, q[1]),
            mad(q[2], k, q[2]),
            mad(q[3], k, q[3]),
        ))
    } else {
        UnitQuaternion::new_normalize(quaternion)
    }
}

/// Rotation quaternion of a rotation vector; below 0.01 rad by the Taylor series of
/// cos(θ/2) and sin(θ/2)/θ to θ⁴ (remainder < 3e-17), else the exact formula.
#[inline(always)]
fn small_rotation<M: MultiplyAdd>(v: &Components) -> QuaternionComponents {
    let mad = M::multiply_add;
    let t2 = mad(v[0], v[0], mad(v[1], v[1], v[2] * v[2]));
    if t2 < 1e-4 {
        // Multiplications by the reciprocal coefficients (a division by 48 is not exact in
        // binary, so the compiler keeps it a 13-cycle divide): the terms are below 1e-8
        // of the sum, so their own rounding does not reach the result's.
        let t4 = t2 * t2;
        let w = mad(t4, 1.0 / 384.0, mad(t2, -0.125, 1.0));
        let s = mad(t4, 1.0 / 3840.0, mad(t2, -1.0 / 48.0, 0.5));
        [w, s * v[0], s * v[1], s * v[2]]
    } else {
        let q = UnitQuaternion::from_scaled_axis(Vector3::from(*v)).into_inner();
        [q.w, q.i, q.j, q.k]
    }
}

/// Latitude-dependent Earth quantities from sin L and cos L (no square root or division:
/// 1/sqrt(1 - e² sin² L) by its series, `inverse_root_of_prime_vertical_factor`).
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
    #[inline(always)]
    fn new<M: MultiplyAdd>(sin: f64, cos: f64) -> Self {
        let s2 = sin * sin;
        // R_E = a / sqrt(d), R_N = R_E (1 - e²) / d, g_0 ∝ 1 / sqrt(d), d = 1 - e² sin² L.
        let inverse_root = inverse_root_of_prime_vertical_factor::<M>(s2);
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
    #[inline(always)]
    fn moved<M: MultiplyAdd>(&self, delta: f64, latitude: f64) -> Self {
        let mad = M::multiply_add;
        if delta.abs() < 1e-3 {
            let d2 = delta * delta;
            let c = mad(d2 * d2, 1.0 / 24.0, mad(d2, -0.5, 1.0));
            let s = delta * mad(d2, -1.0 / 6.0, 1.0);
            Self::new::<M>(
                mad(self.sin, c, self.cos * s),
                mad(self.cos, c, -(self.sin * s)),
            )
        } else {
            let (s, c) = latitude_sin_cos::<M>(latitude + delta);
            Self::new::<M>(s, c)
        }
    }

    /// Normal gravity at `height` (Groves eq. 2.139).
    #[inline]
    fn gravity(&self, height: f64) -> f64 {
        self.surface_gravity * height_factor(height)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernel::{Fused, Separate};
    use crate::{Mission, MissionConfig};
    use estim_core::dispatch::{cpu, with_features, Features};

    /// Largest differences (position \[m\], velocity \[m/s\], attitude \[rad\]) between two
    /// states.
    fn difference(a: &InsState, b: &InsState) -> (f64, f64, f64) {
        let (meridian, transverse) = radii_of_curvature(a.latitude);
        let north = (a.latitude - b.latitude) * (meridian + a.height);
        let east = (a.longitude - b.longitude) * (transverse + a.height) * a.latitude.cos();
        let position = north.abs().max(east.abs()).max((a.height - b.height).abs());
        let velocity = (a.velocity_ned - b.velocity_ned).amax();
        let attitude = a.attitude.angle_to(&b.attitude);
        (position, velocity, attitude)
    }

    #[test]
    fn both_builds_agree_to_rounding() {
        // The portable build (products and sums rounded separately) and the FMA build's
        // code (`f64::mul_add`, exact on any CPU, a library call where FMA is missing)
        // over the 400 s default mission (noisy IMU), started from the truth: they may
        // differ by rounding only. Rounding differences of 1e-16 relative per step grow
        // through the Schuler loop and the unstable vertical channel; 40,000 steps of them
        // stay far below a micrometre (the bounds), while any formula difference between
        // the builds (a wrong sign or term) moves the state by millimetres or more.
        let mission = Mission::generate(&MissionConfig::default(), 7).expect("mission");
        let dt = mission.imu_dt;
        let (mut portable, mut fused) = (mission.truth[0], mission.truth[0]);
        let mut worst = (0.0f64, 0.0f64, 0.0f64);
        for imu in &mission.imu {
            portable = step_body::<Separate>(&portable, imu, dt);
            fused = step_body::<Fused>(&fused, imu, dt);
            let (p, v, a) = difference(&portable, &fused);
            worst = (worst.0.max(p), worst.1.max(v), worst.2.max(a));
        }
        println!(
            "portable against fused over {} steps: worst {:e} m, {:e} m/s, {:e} rad",
            mission.imu.len(),
            worst.0,
            worst.1,
            worst.2
        );
        assert!(
            worst.0 < 1e-6 && worst.1 < 1e-8 && worst.2 < 1e-10,
            "{worst:?}"
        );
        // And the dispatched step is one of the two, to the last bit.
        let s = mission.truth[0];
        let next = Mechanization::new().step_unchecked(&s, &mission.imu[0], dt);
        assert!(
            next == step_body::<Separate>(&s, &mission.imu[0], dt)
                || next == step_body::<Fused>(&s, &mission.imu[0], dt)
        );
    }

    /// The dispatched step in one process under the portable path and under the
    /// builds this CPU has (estim-core's override): the portable path is the portable
    /// build to the last bit, and the CPU's path is the FMA build where the CPU has AVX2
    /// and FMA (the portable build elsewhere).
    #[test]
    fn the_dispatch_runs_the_build_it_reports() {
        let mission = Mission::generate(&MissionConfig::default(), 7).expect("mission");
        let (s, imu, dt) = (mission.truth[0], mission.imu[0], mission.imu_dt);
        let mechanization = Mechanization::new();
        let portable = step_body::<Separate>(&s, &imu, dt);
        let on_portable = with_features(Features::PORTABLE, || {
            mechanization.step_unchecked(&s, &imu, dt)
        });
        assert!(on_portable == portable);
        let on_cpu = with_features(cpu(), || mechanization.step_unchecked(&s, &imu, dt));
        let fma = cfg!(target_arch = "x86_64") && cpu().avx2 && cpu().fma;
        assert!(
            on_cpu
                == if fma {
                    step_body::<Fused>(&s, &imu, dt)
                } else {
                    portable
                }
        );
    }
}
