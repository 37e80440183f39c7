//! The vehicle configuration of the navigator: IMU and sensor noise, lever arms, DVL
//! mounting, time offsets, the innovation gate and the initial state. Deserialized with
//! serde (unknown keys refused) and checked once by [`NavigatorConfig::check`] into
//! [`NavigatorSettings`], which cannot be invalid.

use estim_core::noise::adaptive::NoiseScaleConfig;
use estim_core::{FilterConfig, Gate, GateRecovery, JointCheck};
use estim_dvl::{BeamGeometry, DvlVelocityModel};
use estim_ins::{ImuSpec, SensorSpec};
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use super::{DvlStatesConfig, HealthConfig, NavigatorError, Result};

mod check;
pub use check::ImuFrame;

/// The whole vehicle configuration (every key optional; defaults documented per field).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NavigatorConfig {
    /// IMU noise model.
    pub imu: ImuConfig,
    /// DVL mounting, geometry, time offset and noise.
    pub dvl: DvlConfig,
    /// Depth (pressure) sensor.
    pub depth: DepthConfig,
    /// Position fixes (GNSS at the surface, USBL).
    pub fixes: FixConfig,
    /// Innovation gate.
    pub gate: GateConfig,
    /// Initial state and its uncertainty.
    pub initial: InitialConfig,
    /// DVL error states estimated online (scale factor, misalignment, Gauss-Markov
    /// velocity bias, lever arm, time offset; [`DvlStatesConfig`]). Unset (default):
    /// the 15-state filter with the `[dvl]` mounting held fixed. A `[dvl_states]`
    /// table runs the 26-state [`super::AugmentedNavigator`]; each group left out
    /// takes its default (estimated), `estimate = false` holds it at the `[dvl]` value.
    pub dvl_states: Option<DvlStatesConfig>,
    /// The reference (ground truth) used by an evaluation (`--truth`): its point and
    /// clock. Never used by the navigator itself.
    pub truth: TruthConfig,
    /// Limits of the navigator's health checks ([`HealthConfig`]).
    pub health: HealthConfig,
    /// The input files' column names and units (`[columns.imu]`, `[columns.dvl]`,
    /// `[columns.beams]`, `[columns.depth]`, `[columns.fixes]`, and `[columns.gt]` for
    /// the reference of an evaluation; keys as in [`crate::datasets::ColumnMap`]).
    /// Empty (default): every column found by name.
    #[serde(skip_serializing_if = "crate::datasets::ColumnMap::is_empty")]
    pub columns: crate::datasets::ColumnMap,
}

/// The reference (truth) track of an evaluation, as it was recorded.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TruthConfig {
    /// Position of the reference's point relative to the IMU in the body frame \[m\]
    /// (default zero): errors compare the truth with the solution carried to that point.
    #[serde(deserialize_with = "super::fixed::three")]
    pub lever_arm_m: [f64; 3],
    /// Clock scale s of the reference's stamps: a row stamped t refers to navigator
    /// time `o + s (t - o) - time_offset_s`, o = `clock_origin_s` (default 1; within
    /// 10 % of 1, as `imu.clock_scale`).
    pub clock_scale: f64,
    /// The stamp o \[s\] about which `clock_scale` acts, on the reference file's own
    /// clock. Unset (default): the reference's first stamp.
    pub clock_origin_s: Option<f64>,
    /// Time offset of the reference's stamps \[s\]; unset (default): estimated by
    /// [`Truth::load`](crate::truth::Truth::load) against the IMU's angular rate
    /// (`evaluation.truth_time_offset_s`).
    pub time_offset_s: Option<f64>,
    /// With a truth, start from its position, velocity and attitude at its first
    /// epoch inside the IMU's span, replacing `[initial]`'s (as `--init-from-truth`;
    /// default false).
    pub initial_state: bool,
    /// Remove from the reference's velocity its constant bias against its own
    /// positions before scoring (default false). The bias is estimated per run by
    /// [`Truth::load`](crate::truth::Truth::load) as the slope of the reference's
    /// positions minus its integrated velocity, and reported
    /// (`evaluation.truth_velocity_bias`) whether it is removed or not.
    pub remove_velocity_bias: bool,
}

impl Default for TruthConfig {
    fn default() -> Self {
        Self {
            lever_arm_m: [0.0; 3],
            clock_scale: 1.0,
            clock_origin_s: None,
            time_offset_s: None,
            initial_state: false,
            remove_velocity_bias: false,
        }
    }
}

/// IMU noise model: a preset, optionally with per-sensor densities replacing it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ImuConfig {
    /// `akit_observed` (default), `tactical_mems`, `navigation_grade_fog`, `consumer_mems`.
    pub preset: String,
    /// Accelerometer error parameters (SI units, see [`estim_ins::SensorSpec`]),
    /// replacing the preset's.
    pub accelerometer: Option<SensorConfig>,
    /// Gyroscope error parameters, replacing the preset's.
    pub gyroscope: Option<SensorConfig>,
    /// Nominal IMU rate \[Hz\]: a time step within the timestamps' rounding of 1 / rate
    /// is taken as exactly 1 / rate. `None`: from the median interval of the IMU file.
    pub rate_hz: Option<f64>,
    /// The IMU's axes as mounted: the signed IMU axis along body x, y and z (body x
    /// forward, y right, z down), e.g. `["x", "-y", "z"]` for an IMU whose y axis
    /// points left. Applied to the accelerometer and the gyroscope alike. Default
    /// `["x", "y", "z"]`.
    #[serde(default = "identity_axes")]
    pub axes: [String; 3],
    /// A further small mounting rotation from the (re-signed) IMU axes to the body
    /// frame: roll, pitch, yaw \[deg\] (default zero).
    #[serde(deserialize_with = "super::fixed::three")]
    pub mounting_rpy_deg: [f64; 3],
    /// Clock scale s of the IMU's time stamps: a sample stamped t was taken at
    /// navigator time `o + s (t - o) - time_offset_s`, o = `clock_origin_s` (default 1).
    pub clock_scale: f64,
    /// The stamp o \[s\] about which `clock_scale` acts, on the IMU file's own clock.
    /// Unset (default): the IMU's first stamp. Give it when the clock's relation holds
    /// from a fixed stamp (for example 0 of a time column), so that a log cut to start
    /// later keeps the same timing.
    pub clock_origin_s: Option<f64>,
    /// Time offset tau of the IMU's stamps \[s\] (see `clock_scale`; default 0).
    pub time_offset_s: f64,
    /// Initial accelerometer bias in body axes \[m/s^2\] (the filter's starting
    /// estimate, e.g. from `estim imu calibrate`; default zero).
    #[serde(deserialize_with = "super::fixed::three")]
    pub accelerometer_bias: [f64; 3],
    /// Initial gyroscope bias in body axes \[rad/s\] (default zero).
    #[serde(deserialize_with = "super::fixed::three")]
    pub gyroscope_bias: [f64; 3],
    /// Gyroscope scale factor per body axis (dimensionless, default `[1, 1, 1]`): the
    /// gyroscope reads this many times the true rate, and the navigator divides each
    /// body-axis rate by it before anything else sees the sample (`estim imu
    /// calibrate`'s `gyroscope_scale`).
    #[serde(deserialize_with = "super::fixed::three")]
    pub gyroscope_scale: [f64; 3],
}

fn identity_axes() -> [String; 3] {
    ["x".into(), "y".into(), "z".into()]
}

impl Default for ImuConfig {
    fn default() -> Self {
        Self {
            preset: "akit_observed".into(),
            accelerometer: None,
            gyroscope: None,
            rate_hz: None,
            axes: identity_axes(),
            mounting_rpy_deg: [0.0; 3],
            clock_scale: 1.0,
            clock_origin_s: None,
            time_offset_s: 0.0,
            accelerometer_bias: [0.0; 3],
            gyroscope_bias: [0.0; 3],
            gyroscope_scale: [1.0; 3],
        }
    }
}

/// One sensor triad's error parameters (SI units; the fields of
/// [`estim_ins::SensorSpec`]). Each key may be given alone: the others keep the
/// preset's value.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensorConfig {
    /// White-noise density [m/s/sqrt(s) or rad/sqrt(s)].
    pub white_noise_density: Option<f64>,
    /// Gauss-Markov bias instability sigma [m/s^2 or rad/s].
    pub bias_instability: Option<f64>,
    /// Gauss-Markov correlation time \[s\].
    pub bias_time_constant_s: Option<f64>,
    /// Turn-on bias sigma [m/s^2 or rad/s].
    pub turn_on_bias: Option<f64>,
    /// Scale-factor error sigma (dimensionless; the filter does not estimate it).
    pub scale_factor: Option<f64>,
}

impl SensorConfig {
    /// The preset's spec with the keys given here replacing its values.
    pub fn over(&self, preset: &SensorSpec) -> SensorSpec {
        SensorSpec {
            white_noise_density: self
                .white_noise_density
                .unwrap_or(preset.white_noise_density),
            bias_instability: self.bias_instability.unwrap_or(preset.bias_instability),
            bias_time_constant: self
                .bias_time_constant_s
                .unwrap_or(preset.bias_time_constant),
            turn_on_bias: self.turn_on_bias.unwrap_or(preset.turn_on_bias),
            scale_factor: self.scale_factor.unwrap_or(preset.scale_factor),
        }
    }
}

/// DVL mounting and noise.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DvlConfig {
    /// Lever arm IMU -> DVL in the body frame \[m\] (default zero).
    #[serde(deserialize_with = "super::fixed::three")]
    pub lever_arm_m: [f64; 3],
    /// Mounting misalignment, rotation vector DVL -> body \[rad\] (roll, pitch, yaw
    /// axes; default zero), as `estim dvl calibrate` estimates it.
    #[serde(deserialize_with = "super::fixed::three")]
    pub mounting_misalignment_rad: [f64; 3],
    /// Scale factor 1 + s of the DVL velocity (default 1).
    pub scale_factor: f64,
    /// Beam angle from the z axis \[deg\] (default 30, a Teledyne RDI Workhorse Navigator).
    pub beam_angle_deg: f64,
    /// Azimuth of beam 1 \[deg\]; beams i = 1..4 at `beam1_azimuth_deg + (i-1) 90`
    /// (default 45).
    pub beam1_azimuth_deg: f64,
    /// Time offset tau \[s\]: a sample stamped t measures the motion at t - tau
    /// (default 0; A-KIT's DVL is -1.48 s, which is never applied unless configured).
    pub time_offset_s: f64,
    /// Measurement noise std per axis of the DVL velocity \[m/s\] (default 0.02).
    pub noise_std_mps: f64,
    /// Adapt the DVL noise level online: R = λ diag(`noise_std_mps`²), λ estimated
    /// from the past DVL innovations with a memory of this many updates (1-100000;
    /// `estim_core::noise::adaptive::NoiseScale`, λ in [0.01, 100]; an innovation
    /// whose NIS is above `health.nis_limit` x 3 counts shrunk onto that NIS). Unset
    /// (default): R fixed. BeamsNet updates keep the network's R.
    pub adaptive_noise_window: Option<usize>,
}

impl Default for DvlConfig {
    fn default() -> Self {
        Self {
            lever_arm_m: [0.0; 3],
            mounting_misalignment_rad: [0.0; 3],
            scale_factor: 1.0,
            beam_angle_deg: 30.0,
            beam1_azimuth_deg: 45.0,
            time_offset_s: 0.0,
            noise_std_mps: 0.02,
            adaptive_noise_window: None,
        }
    }
}

/// Depth sensor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DepthConfig {
    /// Lever arm IMU -> pressure sensor in the body frame \[m\].
    #[serde(deserialize_with = "super::fixed::three")]
    pub lever_arm_m: [f64; 3],
    /// Noise std \[m\] (default 0.1).
    pub noise_std_m: f64,
    /// Time offset \[s\] (as for the DVL; default 0).
    pub time_offset_s: f64,
}

impl Default for DepthConfig {
    fn default() -> Self {
        Self {
            lever_arm_m: [0.0; 3],
            noise_std_m: 0.1,
            time_offset_s: 0.0,
        }
    }
}

/// Position fixes; each fix carries its own 1-sigma.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FixConfig {
    /// Lever arm IMU -> antenna / transponder in the body frame \[m\].
    #[serde(deserialize_with = "super::fixed::three")]
    pub lever_arm_m: [f64; 3],
    /// Time offset \[s\] (default 0).
    pub time_offset_s: f64,
}

/// The innovation gate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GateConfig {
    /// Chi-square probability of the NIS gate (default 0.9999); 0 disables it.
    pub probability: f64,
    /// After this many consecutive rejections the next measurement the gate would
    /// reject is accepted with P inflated onto the gate boundary (default 25; 0 = never).
    pub recovery_after: usize,
}

impl Default for GateConfig {
    fn default() -> Self {
        Self {
            probability: 0.9999,
            recovery_after: 25,
        }
    }
}

/// Initial state: what is not given is found from the data (position from the first
/// fix, attitude by coarse alignment).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InitialConfig {
    /// Time of the initial state \[s\], in the inputs' own time (the IMU file's
    /// clock; the library reads it on the navigator's clock, relative to the survey's
    /// epoch); IMU samples before it are not used. `None`: the first IMU sample.
    pub time_s: Option<f64>,
    /// Latitude \[deg\] (with `longitude_deg`); `None`: the first position fix.
    pub latitude_deg: Option<f64>,
    /// Longitude \[deg\].
    pub longitude_deg: Option<f64>,
    /// Depth \[m\] (positive down); `None`: the first depth sample, else 0.
    pub depth_m: Option<f64>,
    /// Velocity NED \[m/s\] (default zero).
    #[serde(deserialize_with = "super::fixed::three")]
    pub velocity_ned_mps: [f64; 3],
    /// Roll, pitch, heading \[deg\]; `None`: coarse alignment (levelling from the mean
    /// specific force over the first `alignment_s`, heading = `heading_deg`).
    #[serde(default, deserialize_with = "super::fixed::three_opt")]
    pub attitude_deg: Option<[f64; 3]>,
    /// Heading for the coarse alignment \[deg\] (default 0).
    pub heading_deg: f64,
    /// Length of the coarse alignment window \[s\] (default 10).
    pub alignment_s: f64,
    /// Position 1-sigma per axis \[m\] (default 1).
    pub position_std_m: f64,
    /// Velocity 1-sigma per axis \[m/s\] (default 0.05).
    pub velocity_std_mps: f64,
    /// Roll and pitch 1-sigma \[deg\] (default 0.05).
    pub level_std_deg: f64,
    /// Heading 1-sigma \[deg\] (default 0.2).
    pub heading_std_deg: f64,
    /// Accelerometer bias 1-sigma \[m/s^2\]; `None`: from the IMU spec
    /// (sqrt(turn-on^2 + instability^2)).
    pub acc_bias_std_mps2: Option<f64>,
    /// Gyroscope bias 1-sigma \[rad/s\]; `None`: from the IMU spec.
    pub gyro_bias_std_radps: Option<f64>,
}

impl Default for InitialConfig {
    fn default() -> Self {
        Self {
            time_s: None,
            latitude_deg: None,
            longitude_deg: None,
            depth_m: None,
            velocity_ned_mps: [0.0; 3],
            attitude_deg: None,
            heading_deg: 0.0,
            alignment_s: 10.0,
            position_std_m: 1.0,
            velocity_std_mps: 0.05,
            level_std_deg: 0.05,
            heading_std_deg: 0.2,
            acc_bias_std_mps2: None,
            gyro_bias_std_radps: None,
        }
    }
}

/// The IMU presets by name.
pub const IMU_PRESETS: [&str; 4] = [
    "akit_observed",
    "tactical_mems",
    "navigation_grade_fog",
    "consumer_mems",
];

/// The IMU spec of a preset name.
///
/// # Errors
/// [`NavigatorError::UnknownName`] for an unknown name, listing the valid ones.
pub fn imu_preset(name: &str) -> Result<ImuSpec> {
    match name {
        "akit_observed" => Ok(ImuSpec::akit_observed()),
        "tactical_mems" => Ok(ImuSpec::tactical_mems()),
        "navigation_grade_fog" => Ok(ImuSpec::navigation_grade_fog()),
        "consumer_mems" => Ok(ImuSpec::consumer_mems()),
        other => Err(NavigatorError::UnknownName {
            key: "imu.preset".into(),
            what: "preset",
            name: other.into(),
            valid: IMU_PRESETS.join(", "),
        }),
    }
}

/// Correlation time the filter gives the bias states \[s\]: long enough that the
/// turn-on bias (a random constant) is not forgotten.
pub const FILTER_BIAS_TIME_CONSTANT: f64 = 1.0e6;

/// The IMU model the filter uses for a sensor spec: each bias modelled as a
/// Gauss-Markov process of correlation time [`FILTER_BIAS_TIME_CONSTANT`] with the
/// same driving-noise PSD 2 sigma^2 / tau as the sensor's drift.
///
/// A sensor bias is a random constant (turn-on) plus a first-order Gauss-Markov
/// drift. A filter bias state with the drift's own tau would pull the turn-on bias
/// towards zero over a few tau and report a bias covariance far smaller than the error
/// (measured: NEES of the accelerometer-bias block near 100 instead of 3 on the
/// simulated mission). Keeping the driving PSD and removing the decay represents both
/// components (a random walk on top of the turn-on bias) to first order over a mission.
///
/// # Errors
/// The spec builder's (not reachable from a valid spec).
pub fn filter_imu_spec(spec: &ImuSpec) -> Result<ImuSpec> {
    let slow = |s: &SensorSpec| {
        let mut out = *s;
        if s.bias_time_constant.is_finite() {
            out.bias_time_constant = FILTER_BIAS_TIME_CONSTANT;
            out.bias_instability =
                s.bias_instability * (FILTER_BIAS_TIME_CONSTANT / s.bias_time_constant).sqrt();
        }
        out
    };
    Ok(ImuSpec::builder()
        .accelerometer(slow(spec.accelerometer()))
        .gyroscope(slow(spec.gyroscope()))
        .build()?)
}

/// A checked configuration: the models the navigator is assembled from.
#[derive(Debug, Clone)]
pub struct NavigatorSettings {
    pub(crate) config: NavigatorConfig,
    pub(crate) sensor_spec: ImuSpec,
    pub(crate) filter_spec: ImuSpec,
    pub(crate) filter_config: FilterConfig,
    pub(crate) dvl: DvlVelocityModel,
    pub(crate) geometry: BeamGeometry,
    pub(crate) dvl_noise_scale: Option<NoiseScaleConfig>,
}

impl NavigatorSettings {
    /// The configuration it was checked from.
    pub fn config(&self) -> &NavigatorConfig {
        &self.config
    }

    /// The DVL error states to estimate, if any (`[dvl_states]`).
    pub fn dvl_states(&self) -> Option<&DvlStatesConfig> {
        self.config.dvl_states.as_ref()
    }

    /// The IMU error spec of the sensor (preset or given).
    pub fn sensor_spec(&self) -> &ImuSpec {
        &self.sensor_spec
    }

    /// The IMU model the filter propagates with ([`filter_imu_spec`] of the sensor's).
    pub fn filter_spec(&self) -> &ImuSpec {
        &self.filter_spec
    }

    /// Gate and recovery rule of the filter.
    pub fn filter_config(&self) -> &FilterConfig {
        &self.filter_config
    }

    /// The DVL velocity model (lever arm, misalignment, scale factor, R).
    pub fn dvl_model(&self) -> &DvlVelocityModel {
        &self.dvl
    }

    /// The DVL beam geometry.
    pub fn beam_geometry(&self) -> &BeamGeometry {
        &self.geometry
    }

    /// The same settings with another sensor IMU spec (the filter's model follows by
    /// [`filter_imu_spec`]).
    ///
    /// # Errors
    /// Not reachable from a valid spec (the spec builder's).
    pub fn with_sensor_spec(mut self, spec: ImuSpec) -> Result<Self> {
        self.filter_spec = filter_imu_spec(&spec)?;
        self.sensor_spec = spec;
        Ok(self)
    }

    /// The configured DVL model with another measurement-noise covariance R.
    ///
    /// # Errors
    /// [`NavigatorError::Dvl`] for an R that is not symmetric positive definite.
    pub fn dvl_model_with_noise(&self, r: Matrix3<f64>) -> Result<DvlVelocityModel> {
        dvl_model(&self.config.dvl, r)
    }

    /// The same settings with another beam geometry (e.g. a PD0 file's RDI layout,
    /// [`super::rdi_beam_geometry`]).
    #[must_use]
    pub fn with_beam_geometry(mut self, geometry: BeamGeometry) -> Self {
        self.geometry = geometry;
        self
    }

    /// The same settings with another DVL measurement-noise covariance R (e.g. a
    /// learned sensor's).
    ///
    /// # Errors
    /// [`NavigatorError::Dvl`] for an R that is not symmetric positive definite.
    pub fn with_dvl_noise_covariance(mut self, r: Matrix3<f64>) -> Result<Self> {
        self.dvl = dvl_model(&self.config.dvl, r)?;
        Ok(self)
    }
}

fn vector(v: [f64; 3]) -> Vector3<f64> {
    Vector3::from(v)
}

pub(crate) fn dvl_model(dvl: &DvlConfig, r: Matrix3<f64>) -> Result<DvlVelocityModel> {
    Ok(DvlVelocityModel::builder()
        .lever_arm(vector(dvl.lever_arm_m))
        .mounting_misalignment(vector(dvl.mounting_misalignment_rad))
        .scale_factor_error(dvl.scale_factor - 1.0)
        .noise_covariance(r)
        .build()?)
}

/// The filter configuration of a gate probability (0 = off) and a recovery rule
/// (0 = none; no effect without a gate).
///
/// The joint covariance of each update is reported, not refused
/// ([`JointCheck::Report`], an explicit opt-in since estim-core refuses an invalid one
/// by default): the navigator runs the paper's `ScaledCorrelation { rho: 0.42 }`, an
/// invalid M, and counts its invalid updates rather than stopping.
///
/// # Errors
/// The core's, for a probability outside (0, 1).
pub fn filter_config(probability: f64, recovery_after: usize) -> Result<FilterConfig> {
    let gate = if probability > 0.0 {
        Gate::Nis { probability }
    } else {
        Gate::None
    };
    // The rule acts on the gate's rejections: nothing to recover from without a gate.
    let recovery = match recovery_after {
        after if after > 0 && probability > 0.0 => GateRecovery::Inflate { after },
        _ => GateRecovery::None,
    };
    Ok(FilterConfig::builder()
        .gate(gate)
        .gate_recovery(recovery)
        .joint_check(JointCheck::Report)
        .build()?)
}
