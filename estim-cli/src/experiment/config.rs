//! The TOML configuration of the experiments (`estim reproduce`, `montecarlo`,
//! `evaluate`, `simulate`, ...).
//!
//! Every field has a default ([`Config::default`]); `estim reproduce --print-config`
//! prints them all as TOML. Unknown keys are rejected.

use std::path::Path;

use estim_ins::{ImuSpec, SensorSpec};
use serde::{Deserialize, Serialize};

use super::{FaultConfig, PipelineError, Result};
use estim::datasets::ColumnMap;

/// The valid values of `imu.preset`.
pub const IMU_PRESETS: [&str; 4] = [
    "akit_observed",
    "tactical_mems",
    "navigation_grade_fog",
    "consumer_mems",
];

/// One line of documentation per TOML key of `--print-config`: `(section, key,
/// "[unit] meaning")`. A key missing here makes `to_commented_toml` fail its test.
const KEY_DOCS: &[(&str, &str, &str)] = &[
    ("", "seed", "[-] seed of every random draw (mission, IMU errors, beams, initial errors, faults)"),
    ("mission", "duration_s", "[s] duration of the embedded simulated mission"),
    ("mission", "imu_rate_hz", "[Hz] IMU rate"),
    ("mission", "dvl_period_s", "[s] DVL / BeamsNet update period"),
    ("imu", "preset", "[-] IMU error model: akit_observed, tactical_mems, navigation_grade_fog, consumer_mems"),
    ("imu", "scale_factor_errors", "[-] keep the preset's scale-factor errors in the simulated IMU (the 15-state filter does not estimate them)"),
    ("imu", "akit_truth", "[-] the trajectory an A-KIT IMU is synthesized from: position_and_velocity (through the recorded positions and velocities) or velocity (through the velocities, positions integrated)"),
    ("imu.accelerometer", "white_noise_density", "[m/s/sqrt(s)] velocity random walk (overrides the preset)"),
    ("imu.accelerometer", "bias_instability", "[m/s^2] Gauss-Markov bias sigma"),
    ("imu.accelerometer", "bias_time_constant_s", "[s] Gauss-Markov correlation time"),
    ("imu.accelerometer", "turn_on_bias", "[m/s^2] turn-on bias sigma"),
    ("imu.accelerometer", "scale_factor", "[-] scale-factor error sigma (1e-6 = 1 ppm)"),
    ("imu.gyroscope", "white_noise_density", "[rad/sqrt(s)] angle random walk (overrides the preset)"),
    ("imu.gyroscope", "bias_instability", "[rad/s] Gauss-Markov bias sigma"),
    ("imu.gyroscope", "bias_time_constant_s", "[s] Gauss-Markov correlation time"),
    ("imu.gyroscope", "turn_on_bias", "[rad/s] turn-on bias sigma"),
    ("imu.gyroscope", "scale_factor", "[-] scale-factor error sigma (1e-6 = 1 ppm)"),
    ("dvl", "lever_arm_m", "[m] lever arm IMU -> DVL in the body frame (x, y, z)"),
    ("dvl", "akit_time_offset_s", "[s] A-KIT DVL time offset (a sample stamped t measures the motion at t - offset)"),
    ("dvl", "protocol", "[-] BeamsNet beam protocol: v1 (bias 0.001 m/s) or v2 (bias 0.0001 m/s)"),
    ("dvl", "ls_noise_std_mps", "[m/s] noise std per axis of the least-squares DVL velocity (was ls_noise_std)"),
    ("dvl", "akit_reference_mismatch_std_mps", "[m/s] std per axis added to R on A-KIT data for the DVL-vs-ground-truth mismatch (was akit_reference_mismatch_std)"),
    ("filter", "initial_position_std_m", "[m] initial position std per axis (N, E, D)"),
    ("filter", "initial_velocity_std_mps", "[m/s] initial velocity std per axis"),
    ("filter", "initial_level_std_deg", "[deg] initial roll / pitch std"),
    ("filter", "initial_heading_std_deg", "[deg] initial heading std"),
    ("filter", "initial_bias_std_scale", "[-] factor on the IMU spec's bias sigma for the initial bias covariance"),
    ("filter", "rho", "[-] rho of the paper's M = rho sqrt(diag Q) sqrt(diag R)' (valid only up to about 0.167 here)"),
    ("filter", "paper_m_basis", "[-] the Q of the paper's M: accumulated (over the update interval, this project's reading) or per_step (one IMU step's Q_k)"),
    ("filter", "gate_probability", "[-] innovation gate probability (chi-square, 3 dof); 0 disables the gate"),
    ("filter", "gate_recovery_after", "[updates] after this many consecutive gate rejections, inflate P so the next measurement passes (estim-core GateRecovery::Inflate); 0 disables; no effect without the gate"),
    ("faults", "beam_dropout_probability", "[-] probability that each beam of each DVL epoch is missing"),
    ("faults", "dvl_outages", "[-] full DVL outages: [[faults.dvl_outages]] tables with start_s [s] and duration_s [s]"),
    ("faults", "beam_outlier_probability", "[-] probability that a DVL epoch has one beam off by an outlier"),
    ("faults", "beam_outlier_magnitude_mps", "[m/s] range of the outlier magnitude (random sign)"),
    ("faults", "imu_gap_rate_per_s", "[1/s] rate of random IMU gaps"),
    ("faults", "imu_gap_samples", "[samples] length of each random IMU gap"),
    ("faults", "imu_gaps", "[-] listed IMU gaps: [[faults.imu_gaps]] tables with start_s [s] and samples"),
    ("faults.dvl_outages", "start_s", "[s] outage start since the first truth sample"),
    ("faults.dvl_outages", "duration_s", "[s] outage length"),
    ("faults.imu_gaps", "start_s", "[s] time of the first removed IMU sample"),
    ("faults.imu_gaps", "samples", "[samples] consecutive IMU samples removed"),
];

/// Bounds of the numeric keys: `(key, lowest, highest, unit)`. Chosen so that the
/// filter's covariances stay finite and positive definite in f64 (stds squared
/// within 1e-18..1e12) and a run stays within memory and hours, not days.
pub const LIMITS: &[(&str, f64, f64, &str)] = &[
    ("mission.duration_s", 1e-3, 1e6, "s"),
    ("mission.imu_rate_hz", 1.0, 1e4, "Hz"),
    ("mission.dvl_period_s", 1e-3, 3600.0, "s"),
    ("dvl.ls_noise_std_mps", 1e-6, 100.0, "m/s"),
    ("dvl.akit_reference_mismatch_std_mps", 0.0, 100.0, "m/s"),
    ("dvl.akit_time_offset_s", -10.0, 10.0, "s"),
    ("filter.initial_position_std_m", 1e-6, 1e6, "m"),
    ("filter.initial_velocity_std_mps", 1e-6, 1e3, "m/s"),
    ("filter.initial_level_std_deg", 1e-6, 90.0, "deg"),
    ("filter.initial_heading_std_deg", 1e-6, 180.0, "deg"),
    ("filter.initial_bias_std_scale", 1e-6, 1e6, "-"),
    ("filter.rho", -1.0, 1.0, "-"),
    ("filter.gate_probability", 0.0, 0.999_999_999, "-"),
    ("filter.gate_recovery_after", 0.0, 1e6, "updates"),
];

/// Most IMU samples of the simulated mission (`mission.duration_s *
/// mission.imu_rate_hz`), as for a recorded trajectory.
pub const MAX_MISSION_IMU_SAMPLES: f64 = super::synthesis::MAX_SYNTHESIZED_IMU_SAMPLES;

/// Largest seed (`seed`, `--seed`; and `--seed` + runs - 1): 2^53, the largest integer
/// every JSON reader keeps exactly, far from wrapping around u64.
pub const MAX_SEED: u64 = 1 << 53;

/// Largest |component| of `dvl.lever_arm_m` \[m\].
pub const MAX_LEVER_ARM_M: f64 = 100.0;

/// Exactly three numbers: serde's own `[f64; 3]` reads the first three of a longer
/// array and ignores the rest (as `crate::navigator`'s vehicle file refuses them).
fn three_numbers<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> std::result::Result<[f64; 3], D::Error> {
    use serde::de::Error as _;
    let v = Vec::<f64>::deserialize(d)?;
    <[f64; 3]>::try_from(v.as_slice())
        .map_err(|_| D::Error::invalid_length(v.len(), &"an array of 3 numbers"))
}

/// The whole configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// Seed of every random draw (simulated mission, IMU errors, beams, initial errors).
    pub seed: u64,
    /// The embedded simulated mission.
    pub mission: MissionSection,
    /// The IMU error model used to synthesize the IMU and by the filter.
    pub imu: ImuSection,
    /// DVL geometry, beam protocol, lever arm, time offset.
    pub dvl: DvlSection,
    /// Filter settings.
    pub filter: FilterSection,
    /// Sensor faults injected into every scenario (default: none).
    pub faults: FaultConfig,
    /// Column map for recorded GT and DVL files (default: columns found by name).
    #[serde(skip_serializing_if = "ColumnMap::is_empty")]
    pub columns: ColumnMap,
}

/// The embedded simulated mission.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MissionSection {
    /// Duration \[s\].
    pub duration_s: f64,
    /// IMU rate \[Hz\].
    pub imu_rate_hz: f64,
    /// DVL / BeamsNet update period \[s\].
    pub dvl_period_s: f64,
}

/// IMU error model: a preset with optional per-sensor overrides.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ImuSection {
    /// `akit_observed` (default), `tactical_mems`, `navigation_grade_fog`, `consumer_mems`.
    pub preset: String,
    /// Accelerometer overrides (SI units, see estim_ins::SensorSpec).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub accelerometer: Option<SensorSection>,
    /// Gyroscope overrides.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gyroscope: Option<SensorSection>,
    /// Keep the preset's scale-factor errors in the simulated IMU (default false).
    /// The 15-state filter does not estimate scale factors: with the tactical
    /// preset's 500 ppm the filter is inconsistent (measured average NEES 91 instead
    /// of 15 on the default simulated mission), so they are off unless asked for.
    pub scale_factor_errors: bool,
    /// The trajectory an A-KIT IMU is synthesized from (and the truth it is scored
    /// against): [`AkitTruth::PositionAndVelocity`] (default) or
    /// [`AkitTruth::Velocity`].
    pub akit_truth: AkitTruth,
}

/// How recorded ground truth (A-KIT) becomes the smooth trajectory the synthesized IMU is
/// synthesized from ([`estim_ins::Trajectory`]).
///
/// A-KIT's recorded positions and velocities disagree (on trajectory 4, 6.6 cm per
/// 1 s step RMS). A curve through both puts the disagreement into the synthesized
/// specific force: spurious accelerations between the samples that a real IMU
/// would not sense and the recorded DVL does not see. A curve through the velocities
/// alone has no such accelerations; its positions are the integral of the recorded
/// velocities and drift from the recorded positions by the data's own
/// inconsistency.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AkitTruth {
    /// Cubic Hermite through every recorded position and velocity
    /// ([`estim_ins::Trajectory::new`]).
    #[default]
    PositionAndVelocity,
    /// Natural cubic spline through the recorded velocities, position integrated
    /// from the first sample ([`estim_ins::Trajectory::velocity_driven`]).
    Velocity,
}

/// One sensor triad's error parameters (SI units).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorSection {
    /// White-noise density [m/s/√s or rad/√s].
    pub white_noise_density: f64,
    /// Gauss-Markov bias instability σ [m/s^2 or rad/s].
    pub bias_instability: f64,
    /// Gauss-Markov correlation time \[s\]. TOML key `bias_time_constant_s` (the old
    /// `bias_time_constant` is still accepted).
    #[serde(rename = "bias_time_constant_s", alias = "bias_time_constant")]
    pub bias_time_constant: f64,
    /// Turn-on bias σ [m/s^2 or rad/s].
    pub turn_on_bias: f64,
    /// Scale-factor error σ (dimensionless).
    pub scale_factor: f64,
}

/// DVL settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DvlSection {
    /// Lever arm IMU -> DVL in the body frame \[m\]. Default: the mean of the
    /// calibration on A-KIT training trajectories (estim-dvl/README.md).
    #[serde(deserialize_with = "three_numbers")]
    pub lever_arm_m: [f64; 3],
    /// A-KIT DVL time offset tau \[s\] (a sample stamped t measures the motion at t - tau).
    pub akit_time_offset_s: f64,
    /// `v1` (bias 0.001 m/s) or `v2` (bias 0.0001 m/s) BeamsNet beam protocol.
    pub protocol: String,
    /// Measurement noise std of the least-squares DVL velocity per axis \[m/s\].
    /// TOML key `ls_noise_std_mps` (the old `ls_noise_std` is still accepted).
    #[serde(rename = "ls_noise_std_mps", alias = "ls_noise_std")]
    pub ls_noise_std: f64,
    /// Extra std per axis added (in quadrature) to R on A-KIT data \[m/s\]: the real DVL
    /// and the ground truth disagree beyond the sensor noise even after lever arm and
    /// time offset. Default 0.017: the robust std of that residual on the A-KIT
    /// training trajectories (`estim dvl mismatch`, 0.0169; trajectories 4 and 13 and
    /// the rows they share with others held out). The robust std, not the RMS
    /// (0.068, a heavy tail on turns and on trajectory 11), because the innovation gate
    /// removes the tail and R models the bulk.
    /// TOML key `akit_reference_mismatch_std_mps` (the old name is still accepted).
    #[serde(
        rename = "akit_reference_mismatch_std_mps",
        alias = "akit_reference_mismatch_std"
    )]
    pub akit_reference_mismatch_std: f64,
}

/// Filter settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FilterSection {
    /// Initial position std per axis (N, E, D) \[m\].
    pub initial_position_std_m: f64,
    /// Initial velocity std per axis \[m/s\].
    pub initial_velocity_std_mps: f64,
    /// Initial roll/pitch std \[deg\].
    pub initial_level_std_deg: f64,
    /// Initial heading std \[deg\].
    pub initial_heading_std_deg: f64,
    /// Scale factor on the IMU spec's bias σ for the initial bias covariance.
    pub initial_bias_std_scale: f64,
    /// rho of the paper's heuristic M (ScaledCorrelation).
    pub rho: f64,
    /// Which process noise the paper's M = rho sqrt(diag Q) sqrt(diag R)' is built
    /// from: `accumulated` (default; Q accumulated over the update interval, this
    /// project's reading of the paper) or `per_step` (the last IMU step's Q_k, as the
    /// paper writes E[w_k v_j'] = rho sqrt(diag Q_k) sqrt(diag R_k)').
    pub paper_m_basis: PaperMBasis,
    /// Innovation gate probability (chi-square, 3 dof); `0` disables the gate.
    pub gate_probability: f64,
    /// After this many consecutive gate rejections, the next measurement the gate
    /// would reject is accepted with P inflated onto the gate boundary
    /// (`estim_core::GateRecovery::Inflate`); `0` disables the rule, which has no
    /// effect when the gate is off (`gate_probability = 0`).
    ///
    /// Default 25, chosen on the A-KIT training trajectories (1-3, 5-12; seeds
    /// 2000-2004; docs/results.md "Filters"): without the rule a filter whose P fell below its
    /// error stays locked out (mean position RMSE 25.1 m for BeamsNet, 60.6 m for LS,
    /// worst 301 / 1125 m); with 20, 25 or 30 the means are 4.7-5.5 m and the worst
    /// 21-36 m; below 20 the rule also accepts the long runs of bad DVL data on
    /// trajectory 11 and the filter diverges (5: worst 2e8 m).
    pub gate_recovery_after: usize,
}

/// The process noise the paper's heuristic M is scaled from (`filter.paper_m_basis`).
///
/// The paper writes E[w_k v_j'] = rho sqrt(diag Q_k) sqrt(diag R_k)' with Q_k the
/// process noise of one propagation step. With a 100 Hz IMU and a 1 Hz velocity the
/// measurement noise meets the noise of 100 steps; building M from the noise
/// accumulated over the update interval is a reading of the paper, not its letter.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum PaperMBasis {
    /// Q_acc, accumulated since the previous update (the core's `ScaledCorrelation`).
    #[default]
    Accumulated,
    /// Q_k of the last IMU step before the update.
    PerStep,
}

// The tests name the basis by its configuration value; the binary does not.
#[cfg(test)]
impl PaperMBasis {
    /// The configuration value (`accumulated`, `per_step`).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Accumulated => "accumulated",
            Self::PerStep => "per_step",
        }
    }
}

impl Default for Config {
    fn default() -> Self {
        Self {
            seed: 7,
            mission: MissionSection::default(),
            imu: ImuSection::default(),
            dvl: DvlSection::default(),
            filter: FilterSection::default(),
            faults: FaultConfig::default(),
            columns: ColumnMap::default(),
        }
    }
}

impl Default for MissionSection {
    fn default() -> Self {
        Self {
            duration_s: 400.0,
            imu_rate_hz: 100.0,
            dvl_period_s: 1.0,
        }
    }
}

impl Default for ImuSection {
    fn default() -> Self {
        Self {
            preset: "akit_observed".into(),
            accelerometer: None,
            gyroscope: None,
            scale_factor_errors: false,
            akit_truth: AkitTruth::default(),
        }
    }
}

impl Default for DvlSection {
    fn default() -> Self {
        Self {
            lever_arm_m: [-1.87, -0.03, 0.2],
            akit_time_offset_s: -1.48,
            protocol: "v1".into(),
            ls_noise_std: 0.015,
            akit_reference_mismatch_std: 0.017,
        }
    }
}

impl Default for FilterSection {
    fn default() -> Self {
        Self {
            initial_position_std_m: 1.0,
            initial_velocity_std_mps: 0.05,
            initial_level_std_deg: 0.05,
            initial_heading_std_deg: 0.2,
            initial_bias_std_scale: 1.0,
            rho: 0.42,
            paper_m_basis: PaperMBasis::default(),
            gate_probability: 0.9999,
            gate_recovery_after: 25,
        }
    }
}

impl From<SensorSection> for SensorSpec {
    fn from(s: SensorSection) -> Self {
        SensorSpec {
            white_noise_density: s.white_noise_density,
            bias_instability: s.bias_instability,
            bias_time_constant: s.bias_time_constant,
            turn_on_bias: s.turn_on_bias,
            scale_factor: s.scale_factor,
        }
    }
}

impl Config {
    /// Read and validate a TOML file.
    pub fn from_file(path: &Path) -> Result<Self> {
        let text = estim::datasets::read_text_file(path)?;
        Self::from_toml(&text, path)
    }

    /// Parse and validate TOML text; `path` names the source in errors.
    pub fn from_toml(text: &str, path: &Path) -> Result<Self> {
        let config: Config = toml::from_str(text).map_err(|e| {
            let line = e
                .span()
                .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1);
            PipelineError::Config {
                path: path.to_path_buf(),
                message: match line {
                    // The key on that line, when it holds one (`lever_arm_m = [...]`).
                    Some(l) => match text
                        .lines()
                        .nth(l - 1)
                        .and_then(|t| t.split_once('='))
                        .map(|(key, _)| key.trim())
                        .filter(|key| !key.is_empty() && !key.starts_with('['))
                    {
                        Some(key) => format!("line {l}: {key}: {}", e.message()),
                        None => format!("line {l}: {}", e.message()),
                    },
                    None => e.message().to_string(),
                },
            }
        })?;
        config.check().map_err(|message| PipelineError::Config {
            path: path.to_path_buf(),
            message,
        })?;
        Ok(config)
    }

    /// The configuration as TOML.
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_default()
    }

    /// The configuration as TOML for `--print-config`: every section, including the
    /// accelerometer and gyroscope ones (filled with the preset's values when not
    /// overridden, which loads back to the same IMU model), and a comment with the
    /// unit and meaning above every key. Loads back to an equivalent configuration.
    pub fn to_commented_toml(&self) -> String {
        let mut full = self.clone();
        if let Ok(spec) = self.preset_spec() {
            let section = |s: &SensorSpec| SensorSection {
                white_noise_density: s.white_noise_density,
                bias_instability: s.bias_instability,
                bias_time_constant: s.bias_time_constant,
                turn_on_bias: s.turn_on_bias,
                scale_factor: s.scale_factor,
            };
            full.imu.accelerometer = Some(
                self.imu
                    .accelerometer
                    .unwrap_or_else(|| section(spec.accelerometer())),
            );
            full.imu.gyroscope = Some(
                self.imu
                    .gyroscope
                    .unwrap_or_else(|| section(spec.gyroscope())),
            );
        }
        let plain = full.to_toml();
        let mut out = String::from(
            "# estim configuration (estim reproduce --config FILE, estim montecarlo --config FILE).\n\
             # Every key is optional; missing keys take the values shown here.\n\
             # Units are in brackets ([-] = dimensionless).\n\n",
        );
        let mut section = String::new();
        for line in plain.lines() {
            let trimmed = line.trim();
            if let Some(name) = trimmed
                .strip_prefix("[[")
                .and_then(|t| t.strip_suffix("]]"))
                .or_else(|| trimmed.strip_prefix('[').and_then(|t| t.strip_suffix(']')))
            {
                section = name.trim().to_string();
            } else if let Some((key, _)) = trimmed.split_once(" = ") {
                if !line.starts_with(' ') {
                    if let Some((_, _, doc)) = KEY_DOCS
                        .iter()
                        .find(|(s, k, _)| *s == section && *k == key.trim())
                    {
                        out.push_str("# ");
                        out.push_str(doc);
                        out.push('\n');
                    }
                }
            }
            out.push_str(line);
            out.push('\n');
        }
        out
    }

    /// Validate ranges; the message names the key and its bounds. Every value is
    /// bounded (see [`LIMITS`]), so that a configuration is refused here, naming the
    /// key, instead of failing later inside the filter (a std of 1e200 squares to
    /// infinity, one of 1e-200 to zero) or allocating without end.
    pub fn check(&self) -> std::result::Result<(), String> {
        for &(key, lo, hi, unit) in LIMITS {
            let Some(v) = self.limited_value(key) else {
                continue;
            };
            if !(v.is_finite() && v >= lo && v <= hi) {
                return Err(format!("{key} = {v} is outside [{lo:e}, {hi:e}] {unit}"));
            }
        }
        let m = &self.mission;
        if m.dvl_period_s * m.imu_rate_hz < 1.0 {
            return Err("mission.dvl_period_s must span at least one IMU sample".into());
        }
        if m.duration_s < 2.0 * m.dvl_period_s {
            return Err("mission.duration_s must hold at least two DVL periods".into());
        }
        let samples = m.duration_s * m.imu_rate_hz;
        if samples > MAX_MISSION_IMU_SAMPLES {
            return Err(format!(
                "mission.duration_s * mission.imu_rate_hz = {samples:.3e} IMU samples, more \
                 than {MAX_MISSION_IMU_SAMPLES:e} (13.9 h at 100 Hz)"
            ));
        }
        if self.seed > MAX_SEED {
            return Err(format!(
                "seed = {} is above {MAX_SEED} (2^53, the largest integer a JSON reader \
                 keeps exactly)",
                self.seed
            ));
        }
        for (i, x) in self.dvl.lever_arm_m.iter().enumerate() {
            if !(x.is_finite() && x.abs() <= MAX_LEVER_ARM_M) {
                return Err(format!(
                    "dvl.lever_arm_m[{i}] = {x} is outside [-{MAX_LEVER_ARM_M:e}, {MAX_LEVER_ARM_M:e}] m"
                ));
            }
        }
        for (name, sensor) in [
            ("imu.accelerometer", &self.imu.accelerometer),
            ("imu.gyroscope", &self.imu.gyroscope),
        ] {
            let Some(s) = sensor else { continue };
            for (key, v, lo, hi) in [
                ("white_noise_density", s.white_noise_density, 1e-9, 1.0),
                ("bias_instability", s.bias_instability, 0.0, 1.0),
                ("bias_time_constant_s", s.bias_time_constant, 1e-2, 1e7),
                ("turn_on_bias", s.turn_on_bias, 0.0, 1.0),
                ("scale_factor", s.scale_factor, 0.0, 0.1),
            ] {
                if !(v.is_finite() && v >= lo && v <= hi) {
                    return Err(format!("{name}.{key} = {v} is outside [{lo:e}, {hi:e}]"));
                }
            }
        }
        if !matches!(self.dvl.protocol.as_str(), "v1" | "v2") {
            return Err(format!(
                "dvl.protocol must be \"v1\" or \"v2\", got {:?}",
                self.dvl.protocol
            ));
        }
        self.faults.check().map_err(|e| e.to_string())?;
        self.columns.check_used(&["gt", "dvl"])?;
        self.imu_spec().map(|_| ()).map_err(|e| e.to_string())
    }

    /// The value of a key of [`LIMITS`].
    fn limited_value(&self, key: &str) -> Option<f64> {
        Some(match key {
            "mission.duration_s" => self.mission.duration_s,
            "mission.imu_rate_hz" => self.mission.imu_rate_hz,
            "mission.dvl_period_s" => self.mission.dvl_period_s,
            "dvl.ls_noise_std_mps" => self.dvl.ls_noise_std,
            "dvl.akit_reference_mismatch_std_mps" => self.dvl.akit_reference_mismatch_std,
            "dvl.akit_time_offset_s" => self.dvl.akit_time_offset_s,
            "filter.initial_position_std_m" => self.filter.initial_position_std_m,
            "filter.initial_velocity_std_mps" => self.filter.initial_velocity_std_mps,
            "filter.initial_level_std_deg" => self.filter.initial_level_std_deg,
            "filter.initial_heading_std_deg" => self.filter.initial_heading_std_deg,
            "filter.initial_bias_std_scale" => self.filter.initial_bias_std_scale,
            "filter.rho" => self.filter.rho,
            "filter.gate_probability" => self.filter.gate_probability,
            "filter.gate_recovery_after" => self.filter.gate_recovery_after as f64,
            _ => return None,
        })
    }

    /// The preset named by `imu.preset`, without overrides.
    fn preset_spec(&self) -> Result<ImuSpec> {
        Ok(match self.imu.preset.as_str() {
            "akit_observed" => ImuSpec::akit_observed(),
            "tactical_mems" => ImuSpec::tactical_mems(),
            "navigation_grade_fog" => ImuSpec::navigation_grade_fog(),
            "consumer_mems" => ImuSpec::consumer_mems(),
            other => {
                return Err(PipelineError::Setting {
                    key: "imu.preset".into(),
                    reason: format!(
                        "unknown preset {other:?}; valid presets: {}",
                        IMU_PRESETS.join(", ")
                    ),
                })
            }
        })
    }

    /// The IMU spec: preset plus overrides, validated.
    ///
    /// # Errors
    /// [`PipelineError::Setting`] for an unknown `imu.preset` or overrides the spec
    /// builder refuses.
    pub fn imu_spec(&self) -> Result<ImuSpec> {
        let preset = self.preset_spec()?;
        let mut acc = self
            .imu
            .accelerometer
            .map_or(*preset.accelerometer(), SensorSpec::from);
        let mut gyro = self
            .imu
            .gyroscope
            .map_or(*preset.gyroscope(), SensorSpec::from);
        if !self.imu.scale_factor_errors {
            acc.scale_factor = 0.0;
            gyro.scale_factor = 0.0;
        }
        ImuSpec::builder()
            .accelerometer(acc)
            .gyroscope(gyro)
            .build()
            .map_err(|e| PipelineError::Setting {
                key: "imu".into(),
                reason: e.to_string(),
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_round_trip_through_toml() {
        let c = Config::default();
        let back = Config::from_toml(&c.to_toml(), Path::new("x.toml")).expect("valid");
        assert_eq!(back, c);
    }

    #[test]
    fn bad_values_name_key_and_line() {
        let e =
            Config::from_toml("seed = 1\n[filter]\nrho = 2.0\n", Path::new("c.toml")).unwrap_err();
        assert!(e.to_string().contains("filter.rho"), "{e}");
        let e =
            Config::from_toml("seed = 1\n[filter]\nrhoo = 0.1\n", Path::new("c.toml")).unwrap_err();
        assert!(
            e.to_string().contains("c.toml") && e.to_string().contains("line 3"),
            "{e}"
        );
        let e = Config::from_toml("[imu]\npreset = \"x\"\n", Path::new("c.toml")).unwrap_err();
        assert!(e.to_string().contains("imu.preset"), "{e}");
        let e = Config::from_toml("[filter]\ngate_recovery_after = -1\n", Path::new("c.toml"))
            .unwrap_err();
        assert!(e.to_string().contains("c.toml"), "{e}");
        // The default rule with the gate off: valid, the rule has nothing to act on.
        let off = Config::from_toml("[filter]\ngate_probability = 0.0\n", Path::new("c.toml"))
            .expect("no gate is valid with the default recovery");
        assert_eq!(off.filter.gate_recovery_after, 25);
    }

    #[test]
    fn print_config_comments_every_key_and_loads_back() {
        let c = Config::default();
        let text = c.to_commented_toml();
        for section in [
            "[mission]",
            "[imu]",
            "[imu.accelerometer]",
            "[imu.gyroscope]",
            "[dvl]",
            "[filter]",
            "[faults]",
        ] {
            assert!(text.contains(section), "{section} missing:\n{text}");
        }
        let lines: Vec<&str> = text.lines().collect();
        for (i, line) in lines.iter().enumerate() {
            if line.contains(" = ") && !line.starts_with(' ') && !line.starts_with('#') {
                let above = lines[i - 1];
                assert!(
                    above.starts_with("# [") && above.contains(']'),
                    "key without a unit comment: {line:?} (above: {above:?})"
                );
            }
        }
        // Loads back: the same IMU model and everything else unchanged.
        let back = Config::from_toml(&text, Path::new("printed.toml")).expect("valid");
        assert_eq!(back.imu_spec().ok(), c.imu_spec().ok());
        let mut without_imu = back.clone();
        without_imu.imu = c.imu.clone();
        assert_eq!(without_imu, c);
        // With listed outages and gaps, their tables are commented too.
        let mut c = Config::default();
        c.faults.dvl_outages.push(super::super::faults::DvlOutage {
            start_s: 1.0,
            duration_s: 2.0,
        });
        let text = c.to_commented_toml();
        assert!(text.contains("# [s] outage start"), "{text}");
    }

    #[test]
    fn old_key_names_still_load() {
        let c = Config::from_toml(
            "[dvl]\nls_noise_std = 0.02\nakit_reference_mismatch_std = 0.01\n\
             [imu.gyroscope]\nwhite_noise_density = 1e-4\nbias_instability = 1e-6\n\
             bias_time_constant = 300.0\nturn_on_bias = 1e-5\nscale_factor = 0.0\n",
            Path::new("old.toml"),
        )
        .expect("old names accepted");
        assert_eq!(c.dvl.ls_noise_std, 0.02);
        assert_eq!(c.dvl.akit_reference_mismatch_std, 0.01);
        assert_eq!(c.imu.gyroscope.map(|g| g.bias_time_constant), Some(300.0));
        let c = Config::from_toml(
            "[dvl]\nls_noise_std_mps = 0.03\nakit_reference_mismatch_std_mps = 0.0\n",
            Path::new("new.toml"),
        )
        .expect("new names");
        assert_eq!(c.dvl.ls_noise_std, 0.03);
        assert!(c.to_toml().contains("ls_noise_std_mps = 0.03"));
    }

    #[test]
    fn unknown_preset_lists_the_valid_ones() {
        let e = Config::from_toml("[imu]\npreset = \"tactical\"\n", Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        for p in IMU_PRESETS {
            assert!(e.contains(p), "{e}");
        }
        for p in IMU_PRESETS {
            let c = Config::from_toml(&format!("[imu]\npreset = \"{p}\"\n"), Path::new("c"));
            assert!(c.is_ok(), "{p}: {c:?}");
        }
    }

    #[test]
    fn partial_file_keeps_other_defaults() {
        let c =
            Config::from_toml("[dvl]\nls_noise_std = 0.02\n", Path::new("c.toml")).expect("valid");
        assert_eq!(c.dvl.ls_noise_std, 0.02);
        assert_eq!(c.filter.rho, 0.42);
        assert_eq!(c.filter.paper_m_basis, PaperMBasis::Accumulated);
    }

    #[test]
    fn paper_m_basis_values() {
        let c = Config::from_toml(
            "[filter]\npaper_m_basis = \"per_step\"\n",
            Path::new("c.toml"),
        )
        .expect("valid");
        assert_eq!(c.filter.paper_m_basis, PaperMBasis::PerStep);
        let e = Config::from_toml("[filter]\npaper_m_basis = \"daily\"\n", Path::new("c.toml"))
            .unwrap_err();
        assert!(e.to_string().contains("line 2"), "{e}");
    }
}
