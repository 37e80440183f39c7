//! The initial state of a batch run: the IMU period, the position, a coarse
//! alignment and the initial covariance.

use estim_ins::{ErrorMatrix, ImuSample, InsState, ERROR_STATES};
use nalgebra::{SMatrix, SVector, UnitQuaternion, Vector3};
use serde::Serialize;

use super::{NavigatorError, NavigatorSettings, Result, SurveyInputs};

/// Which initial attitude was used.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "method")]
pub enum InitialAttitude {
    /// From the configuration (`initial.attitude_deg`).
    Configured,
    /// Coarse alignment: roll and pitch from the mean specific force over the first
    /// `window_s` seconds (`samples` IMU samples), heading as configured.
    CoarseAlignment {
        /// Length of the window \[s\].
        window_s: f64,
        /// IMU samples averaged.
        samples: usize,
    },
}

/// The initial state [`super::navigate`] started from.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Alignment {
    /// The attitude's source.
    pub attitude: InitialAttitude,
    /// `configured` or `first_fix`.
    pub position: &'static str,
    /// Roll, pitch, heading \[deg\].
    pub attitude_deg: [f64; 3],
}

/// Roll and pitch \[rad\] from a mean specific force in the body frame (levelling:
/// f = -C_n^b g, so roll = atan2(-f_y, -f_z), pitch = atan2(f_x, sqrt(f_y^2 + f_z^2))).
pub fn coarse_alignment(mean_specific_force: &Vector3<f64>) -> (f64, f64) {
    let f = mean_specific_force;
    let roll = (-f.y).atan2(-f.z);
    let pitch = f.x.atan2((f.y * f.y + f.z * f.z).sqrt());
    (roll, pitch)
}

/// The nominal IMU period a run on `settings` uses: 1 / `imu.rate_hz`, else the median
/// interval of `imu`'s samples.
///
/// # Errors
/// [`NavigatorError::Inputs`] without a rate and fewer than 2 increasing samples.
pub fn nominal_imu_period(imu: &[ImuSample], settings: &NavigatorSettings) -> Result<f64> {
    imu_period(imu, settings)
}

/// The nominal IMU period: 1 / `imu.rate_hz`, else the median sample interval.
pub(super) fn imu_period(imu: &[ImuSample], settings: &NavigatorSettings) -> Result<f64> {
    if let Some(rate) = settings.config.imu.rate_hz {
        return Ok(1.0 / rate);
    }
    median_interval(imu).ok_or_else(|| {
        NavigatorError::Inputs("the IMU needs at least 2 samples with increasing times".into())
    })
}

/// The median interval between consecutive samples of `imu` \[s\], when positive and
/// finite.
pub(crate) fn median_interval(imu: &[ImuSample]) -> Option<f64> {
    let mut dts: Vec<f64> = imu.windows(2).map(|w| w[1].time - w[0].time).collect();
    dts.sort_by(f64::total_cmp);
    dts.get(dts.len() / 2)
        .copied()
        .filter(|dt| dt.is_finite() && *dt > 0.0)
}

/// The index of the first IMU sample the run uses: the first one, or the first at or
/// after `initial.time_s` (which must fall within one IMU gap limit of it).
pub(super) fn first_imu_index(
    inputs: &SurveyInputs,
    settings: &NavigatorSettings,
) -> Result<usize> {
    if inputs.imu.is_empty() {
        return Err(NavigatorError::Inputs("no IMU samples".into()));
    }
    let Some(t) = settings.config.initial.time_s else {
        return Ok(0);
    };
    let k = inputs.imu.partition_point(|s| s.time < t);
    match inputs.imu.get(k) {
        Some(s) if s.time - t <= settings.config.health.max_imu_gap_s => Ok(k),
        _ => Err(NavigatorError::Inputs(format!(
            "initial.time_s: no IMU sample within health.max_imu_gap_s after t = {t} s"
        ))),
    }
}

/// The initial nominal state and covariance from the configuration and the data.
pub(super) fn initial_state(
    inputs: &SurveyInputs,
    settings: &NavigatorSettings,
) -> Result<(InsState, ErrorMatrix, Alignment)> {
    let c = &settings.config.initial;
    let skipped = first_imu_index(inputs, settings)?;
    let first = &inputs.imu[skipped];
    let start_time = c.time_s.unwrap_or(first.time);
    let (latitude, longitude, position) = match (c.latitude_deg, c.longitude_deg) {
        (Some(lat), Some(lon)) => (lat.to_radians(), lon.to_radians(), "configured"),
        _ => match inputs.fixes.first() {
            Some(f) => (
                f.latitude_deg.to_radians(),
                f.longitude_deg.to_radians(),
                "first_fix",
            ),
            None => {
                return Err(NavigatorError::Inputs(
                    "no initial position: set initial.latitude_deg / longitude_deg in the \
                     vehicle configuration or give position fixes"
                        .into(),
                ))
            }
        },
    };
    let depth = c
        .depth_m
        .or_else(|| inputs.depth.first().map(|d| d.depth_m))
        .unwrap_or(0.0);
    let (attitude, source) = match c.attitude_deg {
        Some([r, p, y]) => (
            UnitQuaternion::from_euler_angles(r.to_radians(), p.to_radians(), y.to_radians()),
            InitialAttitude::Configured,
        ),
        None => {
            let end = start_time + c.alignment_s;
            let window: Vec<&ImuSample> = inputs.imu[skipped..]
                .iter()
                .take_while(|s| s.time < end)
                .collect();
            let n = window.len().max(1);
            let mean = window
                .iter()
                .fold(Vector3::zeros(), |a, s| a + s.specific_force)
                / n as f64;
            let (roll, pitch) = coarse_alignment(&mean);
            (
                UnitQuaternion::from_euler_angles(roll, pitch, c.heading_deg.to_radians()),
                InitialAttitude::CoarseAlignment {
                    window_s: c.alignment_s,
                    samples: window.len(),
                },
            )
        }
    };
    let mut state = InsState::new(
        start_time,
        latitude,
        longitude,
        -depth,
        Vector3::from(c.velocity_ned_mps),
        attitude,
    );
    state.acc_bias = Vector3::from(settings.config.imu.accelerometer_bias);
    state.gyro_bias = Vector3::from(settings.config.imu.gyroscope_bias);
    let (a, g) = (
        settings.sensor_spec.accelerometer(),
        settings.sensor_spec.gyroscope(),
    );
    let acc = c
        .acc_bias_std_mps2
        .unwrap_or_else(|| (a.turn_on_bias.powi(2) + a.bias_instability.powi(2)).sqrt());
    let gyro = c
        .gyro_bias_std_radps
        .unwrap_or_else(|| (g.turn_on_bias.powi(2) + g.bias_instability.powi(2)).sqrt());
    let covariance = initial_covariance(
        c.position_std_m,
        c.velocity_std_mps,
        c.level_std_deg,
        c.heading_std_deg,
        acc,
        gyro,
    );
    let (r, p, y) = attitude.euler_angles();
    let alignment = Alignment {
        attitude: source,
        position,
        attitude_deg: [
            r.to_degrees(),
            p.to_degrees(),
            super::wrap_heading_deg(y.to_degrees()),
        ],
    };
    Ok((state, covariance, alignment))
}

/// The diagonal initial covariance of 1-sigmas per group (angles in degrees; bias
/// sigmas floored at 1e-9 m/s^2 and 1e-12 rad/s so that P stays positive definite).
pub(crate) fn initial_covariance(
    position_m: f64,
    velocity_mps: f64,
    level_deg: f64,
    heading_deg: f64,
    acc_bias: f64,
    gyro_bias: f64,
) -> ErrorMatrix {
    let level = level_deg.to_radians();
    let heading = heading_deg.to_radians();
    let std = [
        position_m,
        position_m,
        position_m,
        velocity_mps,
        velocity_mps,
        velocity_mps,
        level,
        level,
        heading,
        acc_bias.max(1e-9),
        acc_bias.max(1e-9),
        acc_bias.max(1e-9),
        gyro_bias.max(1e-12),
        gyro_bias.max(1e-12),
        gyro_bias.max(1e-12),
    ];
    SMatrix::from_diagonal(&SVector::<f64, ERROR_STATES>::from_iterator(
        std.iter().map(|s| s * s),
    ))
}
