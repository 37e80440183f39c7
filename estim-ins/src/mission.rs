//! Seeded synthetic AUV missions: straight legs, turns and depth changes, with the
//! truth at IMU rate and the simulated (error-free and corrupted) IMU.

use nalgebra::{UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::earth::radii_of_curvature;
use crate::error::{positive, Error, Result};
use crate::imu_spec::ImuSpec;
use crate::mechanization::ImuSample;
use crate::simulator::{ImuErrorGenerator, Trajectory, TrajectorySample};
use crate::InsState;

const G0: f64 = 9.806_65;

/// A checked mission configuration (build with [`MissionConfig::builder`]).
///
/// With the `serde` feature it serializes as its fields (angles in rad, as the
/// builder's setters) and deserializes through [`MissionConfigBuilder::build`].
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(try_from = "UncheckedMissionConfig")
)]
pub struct MissionConfig {
    duration: f64,
    imu_rate_hz: f64,
    start_latitude: f64,
    start_longitude: f64,
    mean_depth: f64,
    depth_excursion: f64,
    speed_range: (f64, f64),
    leg_duration_range: (f64, f64),
    max_turn_rate: f64,
    max_vertical_speed: f64,
    imu_spec: ImuSpec,
}

/// The serialized form of [`MissionConfig`], checked by `TryFrom`.
#[cfg(feature = "serde")]
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct UncheckedMissionConfig {
    duration: f64,
    imu_rate_hz: f64,
    start_latitude: f64,
    start_longitude: f64,
    mean_depth: f64,
    depth_excursion: f64,
    speed_range: (f64, f64),
    leg_duration_range: (f64, f64),
    max_turn_rate: f64,
    max_vertical_speed: f64,
    imu_spec: ImuSpec,
}

#[cfg(feature = "serde")]
impl TryFrom<UncheckedMissionConfig> for MissionConfig {
    type Error = Error;

    fn try_from(u: UncheckedMissionConfig) -> Result<Self> {
        MissionConfigBuilder {
            config: MissionConfig {
                duration: u.duration,
                imu_rate_hz: u.imu_rate_hz,
                start_latitude: u.start_latitude,
                start_longitude: u.start_longitude,
                mean_depth: u.mean_depth,
                depth_excursion: u.depth_excursion,
                speed_range: u.speed_range,
                leg_duration_range: u.leg_duration_range,
                max_turn_rate: u.max_turn_rate,
                max_vertical_speed: u.max_vertical_speed,
                imu_spec: u.imu_spec,
            },
        }
        .build()
    }
}

/// Builder of [`MissionConfig`]; defaults: 400 s at 100 Hz off Haifa (32.85° N, 34.89° E),
/// 20 m mean depth (height -20 m) ± 8 m, speed 1.5-2.0 m/s, legs 40-100 s, turns up to
/// 3 °/s, climb/dive up to 0.2 m/s, IMU [`ImuSpec::akit_observed`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MissionConfigBuilder {
    config: MissionConfig,
}

macro_rules! setter {
    ($(#[$doc:meta])* $name:ident: $ty:ty) => {
        $(#[$doc])*
        #[must_use]
        pub fn $name(mut self, value: $ty) -> Self {
            self.config.$name = value;
            self
        }
    };
}

impl MissionConfigBuilder {
    setter!(/// Mission duration \[s\].
        duration: f64);
    setter!(/// IMU (and truth) rate \[Hz\].
        imu_rate_hz: f64);
    setter!(/// Start latitude \[rad\].
        start_latitude: f64);
    setter!(/// Start longitude \[rad\].
        start_longitude: f64);
    setter!(/// Mean depth below the ellipsoid \[m\], positive down (height = -depth).
        mean_depth: f64);
    setter!(/// Largest depth change from the mean \[m\].
        depth_excursion: f64);
    setter!(/// (min, max) forward speed \[m/s\].
        speed_range: (f64, f64));
    setter!(/// (min, max) duration of a straight leg \[s\].
        leg_duration_range: (f64, f64));
    setter!(/// Largest yaw rate in turns \[rad/s\].
        max_turn_rate: f64);
    setter!(/// Largest climb or dive rate \[m/s\].
        max_vertical_speed: f64);
    setter!(/// IMU error specification.
        imu_spec: ImuSpec);

    /// Validate the configuration.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming the first invalid field.
    pub fn build(self) -> Result<MissionConfig> {
        let c = self.config;
        positive("duration", c.duration)?;
        positive("imu_rate_hz", c.imu_rate_hz)?;
        positive("max_turn_rate", c.max_turn_rate)?;
        positive("max_vertical_speed", c.max_vertical_speed)?;
        if !(c.start_latitude.is_finite() && c.start_latitude.abs() < 1.4) {
            return Err(invalid("start_latitude", "must be finite, |lat| < 1.4 rad"));
        }
        if !c.start_longitude.is_finite() {
            return Err(invalid("start_longitude", "must be finite"));
        }
        if !(c.mean_depth.is_finite()
            && c.depth_excursion.is_finite()
            && c.depth_excursion >= 0.0
            && c.mean_depth - c.depth_excursion >= 0.0)
        {
            return Err(invalid(
                "depth_excursion",
                "depths must be finite and mean_depth - depth_excursion >= 0 (submerged)",
            ));
        }
        let (lo, hi) = c.speed_range;
        if !(lo.is_finite() && hi.is_finite() && lo > 0.0 && hi >= lo) {
            return Err(invalid("speed_range", "need 0 < min <= max"));
        }
        let (lo, hi) = c.leg_duration_range;
        if !(lo.is_finite() && hi.is_finite() && lo > 0.0 && hi >= lo) {
            return Err(invalid("leg_duration_range", "need 0 < min <= max"));
        }
        Ok(c)
    }
}

fn invalid(name: &'static str, reason: &str) -> Error {
    Error::InvalidParameter {
        name,
        reason: reason.to_string(),
    }
}

impl Default for MissionConfig {
    fn default() -> Self {
        Self {
            duration: 400.0,
            imu_rate_hz: 100.0,
            start_latitude: 32.85_f64.to_radians(),
            start_longitude: 34.89_f64.to_radians(),
            mean_depth: 20.0,
            depth_excursion: 8.0,
            speed_range: (1.5, 2.0),
            leg_duration_range: (40.0, 100.0),
            max_turn_rate: 3_f64.to_radians(),
            max_vertical_speed: 0.2,
            imu_spec: ImuSpec::akit_observed(),
        }
    }
}

impl MissionConfig {
    /// A builder starting from the defaults.
    #[must_use]
    pub fn builder() -> MissionConfigBuilder {
        MissionConfigBuilder {
            config: Self::default(),
        }
    }

    /// Mission duration \[s\].
    #[must_use]
    pub fn duration(&self) -> f64 {
        self.duration
    }

    /// IMU rate \[Hz\].
    #[must_use]
    pub fn imu_rate_hz(&self) -> f64 {
        self.imu_rate_hz
    }

    /// IMU error specification.
    #[must_use]
    pub fn imu_spec(&self) -> &ImuSpec {
        &self.imu_spec
    }
}

/// A generated mission.
#[derive(Debug, Clone)]
pub struct SimulatedMission {
    /// Truth at t_k = k dt, k = 0..=N; `acc_bias`/`gyro_bias` hold the IMU's true total
    /// biases and `angular_rate` the true ω_ib^b.
    pub truth: Vec<InsState>,
    /// Corrupted IMU samples (N), sample k covering \[t_k, t_k+1\].
    pub imu: Vec<ImuSample>,
    /// Error-free IMU samples (N).
    pub clean_imu: Vec<ImuSample>,
    /// IMU period dt \[s\].
    pub imu_dt: f64,
    /// The smooth trajectory (2 Hz knots) the truth and IMU were simulated from.
    pub trajectory: Trajectory,
}

/// Smooth 0 -> 1 ramp with zero slope at both ends: s - sin(2πs)/(2π); returns (value, slope).
fn ramp(s: f64) -> (f64, f64) {
    let tau = std::f64::consts::TAU;
    (s - (tau * s).sin() / tau, 1.0 - (tau * s).cos())
}

/// One manoeuvre of a schedule: from `start` for `length` seconds, change by `delta`.
#[derive(Debug, Clone, Copy)]
struct Manoeuvre {
    start: f64,
    length: f64,
    delta: f64,
}

/// Value and rate of a schedule of smooth ramps starting from `initial`.
fn schedule(initial: f64, manoeuvres: &[Manoeuvre], t: f64) -> (f64, f64) {
    let mut value = initial;
    let mut rate = 0.0;
    for m in manoeuvres {
        if t >= m.start + m.length {
            value += m.delta;
        } else if t > m.start {
            let (v, r) = ramp((t - m.start) / m.length);
            value += m.delta * v;
            rate += m.delta * r / m.length;
        }
    }
    (value, rate)
}

/// Synthetic AUV missions.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Mission;

impl Mission {
    /// Generate a mission: a random sequence of straight legs and smooth turns
    /// (45-180°), independent smooth depth changes, slowly varying speed; body x along
    /// the velocity (no side-slip), pitch along the flight path, coordinated-turn roll.
    /// Knots every 0.5 s (position integrated at 1 kHz) are interpolated by
    /// [`Trajectory`] and sampled at the IMU rate; the IMU is corrupted by an
    /// [`ImuErrorGenerator`] seeded with `seed`.
    ///
    /// # Errors
    /// Propagates [`Trajectory`] errors (none for a valid configuration).
    pub fn generate(config: &MissionConfig, seed: u64) -> Result<SimulatedMission> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let c = *config;
        let total = c.duration + 2.0;
        // Heading schedule: legs then turns.
        let mut turns = Vec::new();
        let mut t = 0.0;
        while t < total {
            t += rng.random_range(c.leg_duration_range.0..=c.leg_duration_range.1);
            let angle = rng.random_range(45f64.to_radians()..=180f64.to_radians())
                * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            // Peak rate of the ramp is 2 angle / length.
            let length = (2.0 * angle.abs() / c.max_turn_rate).max(10.0);
            turns.push(Manoeuvre {
                start: t,
                length,
                delta: angle,
            });
            t += length;
        }
        // Depth schedule, independent of the legs.
        let mut dives = Vec::new();
        let mut depth = c.mean_depth;
        let mut t = rng.random_range(10.0..=40.0);
        while t < total {
            let target = c.mean_depth + rng.random_range(-1.0..=1.0) * c.depth_excursion;
            let length = (2.0 * (target - depth).abs() / c.max_vertical_speed).max(20.0);
            dives.push(Manoeuvre {
                start: t,
                length,
                delta: target - depth,
            });
            depth = target;
            t += length + rng.random_range(20.0..=80.0);
        }
        let heading0 = rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
        let speed_mid = 0.5 * (c.speed_range.0 + c.speed_range.1);
        let speed_amp = 0.5 * (c.speed_range.1 - c.speed_range.0);
        let speed_phase = rng.random_range(0.0..std::f64::consts::TAU);
        let speed_period = 180.0;
        let kinematics = |t: f64| {
            let (heading, heading_rate) = schedule(heading0, &turns, t);
            let (depth, depth_rate) = schedule(c.mean_depth, &dives, t);
            let speed = speed_mid
                + speed_amp * (std::f64::consts::TAU * t / speed_period + speed_phase).sin();
            let velocity = Vector3::new(speed * heading.cos(), speed * heading.sin(), depth_rate);
            let pitch = (-depth_rate).atan2(speed);
            let roll = (speed * heading_rate / G0).atan();
            (
                velocity,
                UnitQuaternion::from_euler_angles(roll, pitch, heading),
                -depth,
            )
        };
        // Knots at 2 Hz; latitude/longitude integrated by the trapezoidal rule at 1 kHz.
        let knot_dt = 0.5;
        let sub = 500;
        let h = knot_dt / f64::from(sub);
        let (mut lat, mut lon) = (c.start_latitude, c.start_longitude);
        let knots_n = (total / knot_dt).ceil() as usize + 1;
        let mut knots = Vec::with_capacity(knots_n);
        let rates = |lat: f64, t: f64| {
            let (v, _, height) = kinematics(t);
            let (rn, re) = radii_of_curvature(lat);
            (v.x / (rn + height), v.y / ((re + height) * lat.cos()))
        };
        for k in 0..knots_n {
            let t = k as f64 * knot_dt;
            let (velocity, attitude, height) = kinematics(t);
            knots.push(TrajectorySample {
                time: t,
                latitude: lat,
                longitude: lon,
                height,
                velocity_ned: velocity,
                attitude,
            });
            for j in 0..sub {
                let ts = t + f64::from(j) * h;
                let (dl0, dn0) = rates(lat, ts);
                let (dl1, dn1) = rates(lat + h * dl0, ts + h);
                lat += 0.5 * h * (dl0 + dl1);
                lon += 0.5 * h * (dn0 + dn1);
            }
        }
        let trajectory = Trajectory::new(knots)?;
        let (truth_all, clean_all) = trajectory.simulate(c.imu_rate_hz)?;
        let steps = ((c.duration * c.imu_rate_hz).round() as usize).min(clean_all.len());
        let dt = 1.0 / c.imu_rate_hz;
        let mut generator = ImuErrorGenerator::new(c.imu_spec, seed ^ 0x5eed_1b0b);
        let mut truth = Vec::with_capacity(steps + 1);
        let mut imu = Vec::with_capacity(steps);
        for k in 0..=steps {
            let mut s = truth_all[k];
            s.acc_bias = generator.acc_bias();
            s.gyro_bias = generator.gyro_bias();
            truth.push(s);
            if k < steps {
                imu.push(generator.corrupt(&clean_all[k], dt));
            }
        }
        let clean_imu = clean_all[..steps].to_vec();
        Ok(SimulatedMission {
            truth,
            imu,
            clean_imu,
            imu_dt: dt,
            trajectory,
        })
    }
}
