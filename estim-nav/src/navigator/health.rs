//! The navigator's watch over its own result: a solution that breaks a physical bound
//! or whose DVL innovations stay far outside their band stops the run with
//! [`NavigatorError::Diverged`](super::NavigatorError::Diverged), naming the epoch and
//! the reason. A diverged filter is never reported as a solution.
//!
//! Every limit is a key of the vehicle file's `[health]` table ([`HealthConfig`]),
//! with its default documented there.

use std::collections::VecDeque;
use std::fmt;

use serde::{Deserialize, Serialize};

use super::{NavSolution, NavigatorError, Result};

/// Limits of the health checks (`[health]` in the vehicle file).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HealthConfig {
    /// Largest speed over ground \[m/s\] (default 30: no underwater vehicle is faster).
    pub max_speed_mps: f64,
    /// Deepest depth \[m\] (default 11,000: the deepest ocean).
    pub max_depth_m: f64,
    /// Highest point, as a depth \[m\] (default -1,000: 1 km above the sea surface).
    pub min_depth_m: f64,
    /// Largest horizontal position 1-sigma \[m\] (default 100,000).
    pub max_position_sigma_m: f64,
    /// Largest velocity 1-sigma \[m/s\] (default 100).
    pub max_velocity_sigma_mps: f64,
    /// DVL updates over which the NIS's median is taken (default 30; 0 turns the NIS
    /// check off).
    pub nis_window: usize,
    /// The run has diverged when the median NIS of one sensor over `nis_window`
    /// consecutive update attempts (gated ones included; `fix_nis_window` for position
    /// fixes) exceeds this many times the measurement size (default 100: a consistent
    /// filter's median is below 1 times (0.79 for the DVL's 3 components, the chi-square
    /// median), and a mistuned but converged one stays within tens; a filter whose
    /// position or attitude has left the measurements behind reaches thousands). The
    /// median, not the mean: outliers in fewer than half the window (a spike of one DVL
    /// row, a wild fix) are the gate's business and do not stop a run whose other
    /// updates agree with it.
    pub nis_limit: f64,
    /// Position-fix update attempts over which the fix NIS's median is taken (default
    /// 3; 0 turns the check off).
    pub fix_nis_window: usize,
    /// Longest interval between consecutive IMU samples \[s\] (default 1): a longer
    /// hole cannot be integrated and stops the run.
    pub max_imu_gap_s: f64,
}

impl Default for HealthConfig {
    fn default() -> Self {
        Self {
            max_speed_mps: 30.0,
            max_depth_m: 11_000.0,
            min_depth_m: -1_000.0,
            max_position_sigma_m: 1.0e5,
            max_velocity_sigma_mps: 100.0,
            nis_window: 30,
            nis_limit: 100.0,
            fix_nis_window: 3,
            max_imu_gap_s: 1.0,
        }
    }
}

impl HealthConfig {
    /// Validate every limit once.
    ///
    /// # Errors
    /// [`NavigatorError::InvalidValue`] naming the key.
    pub fn check(&self) -> Result<()> {
        let positive = [
            ("health.max_speed_mps", self.max_speed_mps),
            ("health.max_position_sigma_m", self.max_position_sigma_m),
            ("health.max_velocity_sigma_mps", self.max_velocity_sigma_mps),
            ("health.nis_limit", self.nis_limit),
            ("health.max_imu_gap_s", self.max_imu_gap_s),
        ];
        for (key, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(NavigatorError::invalid(
                    key,
                    format!("{value:?} is not a positive finite number"),
                ));
            }
        }
        if !(self.min_depth_m.is_finite()
            && self.max_depth_m.is_finite()
            && self.min_depth_m < self.max_depth_m)
        {
            return Err(NavigatorError::conflict(
                "health.min_depth_m / max_depth_m",
                format!(
                    "[{}, {}] is not an interval",
                    self.min_depth_m, self.max_depth_m
                ),
            ));
        }
        for (key, window) in [
            ("health.nis_window", self.nis_window),
            ("health.fix_nis_window", self.fix_nis_window),
        ] {
            if window > 100_000 {
                return Err(NavigatorError::invalid(
                    key,
                    format!("{window} is not in 0-100000"),
                ));
            }
        }
        Ok(())
    }
}

/// Why a run was stopped as diverged.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "check")]
#[non_exhaustive]
pub enum Divergence {
    /// A state or covariance entry that is not a finite number.
    NonFinite,
    /// Latitude beyond +-90 deg.
    Latitude {
        /// The latitude \[deg\].
        latitude_deg: f64,
    },
    /// Depth outside `[health.min_depth_m, health.max_depth_m]`.
    Depth {
        /// The depth \[m\].
        depth_m: f64,
    },
    /// Speed above `health.max_speed_mps`.
    Speed {
        /// The speed \[m/s\].
        speed_mps: f64,
    },
    /// Horizontal position 1-sigma above `health.max_position_sigma_m`.
    PositionSigma {
        /// The larger of the north and east 1-sigma \[m\].
        sigma_m: f64,
    },
    /// Velocity 1-sigma above `health.max_velocity_sigma_mps`.
    VelocitySigma {
        /// The largest velocity 1-sigma \[m/s\].
        sigma_mps: f64,
    },
    /// Median NIS of one sensor over its window above `health.nis_limit` times the
    /// measurement size.
    Nis {
        /// The sensor (`dvl`, `depth`, `fixes`).
        sensor: &'static str,
        /// The median NIS over the window.
        median: f64,
        /// Updates in the window.
        window: usize,
    },
    /// An IMU hole longer than `health.max_imu_gap_s`.
    ImuGap {
        /// The hole \[s\].
        gap_s: f64,
    },
}

impl fmt::Display for Divergence {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::NonFinite => write!(f, "a state or covariance entry is not finite"),
            Self::Latitude { latitude_deg } => {
                write!(f, "latitude {latitude_deg:.3} deg is beyond +-90 deg")
            }
            Self::Depth { depth_m } => write!(
                f,
                "depth {depth_m:.1} m is outside [health.min_depth_m, health.max_depth_m]"
            ),
            Self::Speed { speed_mps } => {
                write!(f, "speed {speed_mps:.1} m/s is above health.max_speed_mps")
            }
            Self::PositionSigma { sigma_m } => write!(
                f,
                "horizontal position 1-sigma {sigma_m:.3e} m is above health.max_position_sigma_m"
            ),
            Self::VelocitySigma { sigma_mps } => write!(
                f,
                "velocity 1-sigma {sigma_mps:.3e} m/s is above health.max_velocity_sigma_mps"
            ),
            Self::Nis {
                sensor,
                median,
                window,
            } => write!(
                f,
                "the median {sensor} NIS over the last {window} updates is {median:.3e}, \
                 above health.nis_limit times the measurement size"
            ),
            Self::ImuGap { gap_s } => write!(
                f,
                "the IMU has a hole of {gap_s:.3} s, longer than health.max_imu_gap_s"
            ),
        }
    }
}

/// The NIS of one sensor's last update attempts.
#[derive(Debug, Clone, Default)]
struct NisWindow {
    values: VecDeque<f64>,
}

impl NisWindow {
    /// Push a NIS; the window's median once it holds `length` values (the mean of the
    /// two middle values for an even length).
    fn push(&mut self, nis: f64, length: usize) -> Option<f64> {
        // A non-finite NIS counts as the largest value (it is not a number to sort).
        let nis = if nis.is_finite() { nis } else { f64::MAX };
        self.values.push_back(nis);
        while self.values.len() > length {
            self.values.pop_front();
        }
        if self.values.len() != length {
            return None;
        }
        let mut sorted: Vec<f64> = self.values.iter().copied().collect();
        sorted.sort_by(f64::total_cmp);
        let mid = length / 2;
        Some(if length % 2 == 1 {
            sorted[mid]
        } else {
            0.5 * sorted[mid - 1] + 0.5 * sorted[mid]
        })
    }
}

/// Watches the solutions and the NIS of each sensor of one run.
#[derive(Debug, Clone)]
pub struct HealthMonitor {
    config: HealthConfig,
    dvl: NisWindow,
    depth: NisWindow,
    fixes: NisWindow,
}

impl HealthMonitor {
    /// A monitor with these limits (checked by [`HealthConfig::check`]).
    pub fn new(config: HealthConfig) -> Self {
        Self {
            config,
            dvl: NisWindow::default(),
            depth: NisWindow::default(),
            fixes: NisWindow::default(),
        }
    }

    /// The limits.
    pub fn config(&self) -> &HealthConfig {
        &self.config
    }

    fn stop(time: f64, reason: Divergence) -> Result<()> {
        Err(NavigatorError::Diverged { time, reason })
    }

    /// Check one solution.
    ///
    /// # Errors
    /// [`NavigatorError::Diverged`] with the solution's time and the broken limit.
    pub fn check_solution(&self, s: &NavSolution) -> Result<()> {
        let c = &self.config;
        let values = [s.latitude_deg, s.longitude_deg, s.depth_m, s.heading_deg]
            .into_iter()
            .chain(s.velocity_ned_mps)
            .chain(s.position_sigma_m)
            .chain(s.velocity_sigma_mps)
            .chain(s.attitude_sigma_deg)
            .chain(s.acc_bias_mps2)
            .chain(s.gyro_bias_radps);
        if values.into_iter().any(|v| !v.is_finite()) {
            return Self::stop(s.time, Divergence::NonFinite);
        }
        if s.latitude_deg.abs() > 90.0 {
            return Self::stop(
                s.time,
                Divergence::Latitude {
                    latitude_deg: s.latitude_deg,
                },
            );
        }
        if s.depth_m < c.min_depth_m || s.depth_m > c.max_depth_m {
            return Self::stop(s.time, Divergence::Depth { depth_m: s.depth_m });
        }
        let v = s.velocity_ned_mps;
        let speed = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if speed > c.max_speed_mps {
            return Self::stop(s.time, Divergence::Speed { speed_mps: speed });
        }
        let sigma = s.position_sigma_m[0].max(s.position_sigma_m[1]);
        if sigma > c.max_position_sigma_m {
            return Self::stop(s.time, Divergence::PositionSigma { sigma_m: sigma });
        }
        let sigma = s.velocity_sigma_mps.into_iter().fold(0.0, f64::max);
        if sigma > c.max_velocity_sigma_mps {
            return Self::stop(s.time, Divergence::VelocitySigma { sigma_mps: sigma });
        }
        Ok(())
    }

    /// Record the NIS of an update attempt of `sensor` (`dvl`, `depth` or `fixes`)
    /// of size `dimension` at `time`.
    ///
    /// # Errors
    /// [`NavigatorError::Diverged`] when the sensor's window is full and its median NIS
    /// is above `nis_limit` times the size.
    pub fn record_nis(
        &mut self,
        sensor: &'static str,
        time: f64,
        nis: f64,
        dimension: usize,
    ) -> Result<()> {
        let (window, length) = match sensor {
            "fixes" => (&mut self.fixes, self.config.fix_nis_window),
            "depth" => (&mut self.depth, self.config.nis_window),
            _ => (&mut self.dvl, self.config.nis_window),
        };
        if length == 0 {
            return Ok(());
        }
        match window.push(nis, length) {
            Some(median) if median > self.config.nis_limit * dimension as f64 => Self::stop(
                time,
                Divergence::Nis {
                    sensor,
                    median,
                    window: length,
                },
            ),
            _ => Ok(()),
        }
    }

    /// Check the IMU's sample times for holes longer than `max_imu_gap_s`.
    ///
    /// # Errors
    /// [`NavigatorError::Diverged`] at the start of the first such hole.
    pub fn check_imu_times(&self, times: impl IntoIterator<Item = f64>) -> Result<()> {
        let mut last: Option<f64> = None;
        for t in times {
            if let Some(prev) = last {
                let gap = t - prev;
                if gap > self.config.max_imu_gap_s {
                    return Self::stop(prev, Divergence::ImuGap { gap_s: gap });
                }
            }
            last = Some(t);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn solution() -> NavSolution {
        NavSolution {
            time: 10.0,
            latitude_deg: 32.0,
            longitude_deg: 34.0,
            depth_m: 20.0,
            velocity_ned_mps: [1.5, 0.2, 0.0],
            roll_deg: 0.0,
            pitch_deg: 0.0,
            heading_deg: 10.0,
            acc_bias_mps2: [0.0; 3],
            gyro_bias_radps: [0.0; 3],
            position_sigma_m: [1.0; 3],
            velocity_sigma_mps: [0.01; 3],
            attitude_sigma_deg: [0.1; 3],
            acc_bias_sigma_mps2: [1e-3; 3],
            gyro_bias_sigma_radps: [1e-5; 3],
        }
    }

    fn check(s: &NavSolution) -> Option<Divergence> {
        match HealthMonitor::new(HealthConfig::default()).check_solution(s) {
            Ok(()) => None,
            Err(NavigatorError::Diverged { time, reason }) => {
                assert_eq!(time, s.time);
                Some(reason)
            }
            Err(e) => panic!("{e}"),
        }
    }

    #[test]
    fn each_bound_names_its_check() {
        assert_eq!(check(&solution()), None);
        let mut s = solution();
        s.latitude_deg = -5238.0;
        assert!(matches!(check(&s), Some(Divergence::Latitude { .. })));
        let mut s = solution();
        s.depth_m = -341_798.0;
        assert!(matches!(check(&s), Some(Divergence::Depth { .. })));
        let mut s = solution();
        s.velocity_ned_mps = [30.0, 5.0, 0.0];
        assert!(matches!(check(&s), Some(Divergence::Speed { .. })));
        let mut s = solution();
        s.position_sigma_m = [2e5, 1.0, 1.0];
        assert!(matches!(check(&s), Some(Divergence::PositionSigma { .. })));
        let mut s = solution();
        s.velocity_sigma_mps = [0.01, 150.0, 0.01];
        assert!(matches!(check(&s), Some(Divergence::VelocitySigma { .. })));
        let mut s = solution();
        s.gyro_bias_radps = [f64::NAN, 0.0, 0.0];
        assert_eq!(check(&s), Some(Divergence::NonFinite));
    }

    #[test]
    fn the_nis_window_stops_only_when_full_and_far_out() {
        let config = HealthConfig {
            nis_window: 5,
            ..HealthConfig::default()
        };
        let mut m = HealthMonitor::new(config);
        // Four huge values do not fill the window.
        for k in 0..4 {
            m.record_nis("dvl", f64::from(k), 1e6, 3).unwrap();
        }
        // The fifth fills it: median 1e6 > 100 * 3.
        let err = m.record_nis("dvl", 4.0, 1e6, 3).unwrap_err();
        assert!(matches!(
            err,
            NavigatorError::Diverged {
                time,
                reason: Divergence::Nis { sensor: "dvl", window: 5, .. }
            } if time == 4.0
        ));
        // A consistent sensor never stops, and the fixes have their own window.
        let mut m = HealthMonitor::new(HealthConfig::default());
        for k in 0..1000 {
            m.record_nis("dvl", f64::from(k), 3.0 + f64::from(k % 7), 3)
                .unwrap();
        }
        m.record_nis("fixes", 0.0, 1e8, 2).unwrap();
        m.record_nis("fixes", 1.0, 1e8, 2).unwrap();
        assert!(m.record_nis("fixes", 2.0, 1e8, 2).is_err());
    }

    #[test]
    fn outliers_in_fewer_than_half_the_window_do_not_stop_a_run() {
        let config = HealthConfig {
            nis_window: 7,
            ..HealthConfig::default()
        };
        let nis = |m: &mut HealthMonitor, k: usize, v: f64| m.record_nis("dvl", k as f64, v, 3);
        // Three wild rows (one not even a number) among seven: the median is the
        // largest of the four ordinary values, 5.
        let mut m = HealthMonitor::new(config.clone());
        for (k, v) in [2.0, 1e9, 3.0, f64::INFINITY, 4.0, 1e12, 5.0]
            .into_iter()
            .enumerate()
        {
            nis(&mut m, k, v).unwrap();
        }
        // A fourth takes the median to the smallest wild value, 1e9: diverged, and the
        // reason carries it.
        let err = nis(&mut m, 7, 1e10).unwrap_err();
        assert!(matches!(
            err,
            NavigatorError::Diverged {
                reason: Divergence::Nis { median, window: 7, .. },
                ..
            } if median == 1e9
        ));
        // An even window takes the mean of its two middle values: [1, 2, 700, 900]
        // has median 351: below 100 x 4 for size 4, above 100 x 3 for size 3.
        let mut m = HealthMonitor::new(HealthConfig {
            nis_window: 4,
            ..HealthConfig::default()
        });
        for (k, v) in [1.0, 700.0, 2.0].into_iter().enumerate() {
            m.record_nis("depth", k as f64, v, 4).unwrap();
        }
        m.record_nis("depth", 3.0, 900.0, 4).unwrap();
        let mut m = HealthMonitor::new(HealthConfig {
            nis_window: 4,
            ..HealthConfig::default()
        });
        for (k, v) in [1.0, 700.0, 2.0].into_iter().enumerate() {
            m.record_nis("depth", k as f64, v, 3).unwrap();
        }
        assert!(m.record_nis("depth", 3.0, 900.0, 3).is_err());
    }

    #[test]
    fn an_imu_hole_is_found_and_limits_are_checked() {
        let m = HealthMonitor::new(HealthConfig::default());
        let times = (0..100).map(|k| f64::from(k) * 0.01).chain([61.0, 61.01]);
        assert!(matches!(
            m.check_imu_times(times),
            Err(NavigatorError::Diverged {
                reason: Divergence::ImuGap { .. },
                ..
            })
        ));
        let bad = HealthConfig {
            max_speed_mps: -1.0,
            ..HealthConfig::default()
        };
        assert!(
            matches!(bad.check(), Err(NavigatorError::InvalidValue { key, .. }) if key == "health.max_speed_mps")
        );
        let bad = HealthConfig {
            min_depth_m: 10.0,
            max_depth_m: 5.0,
            ..HealthConfig::default()
        };
        assert!(bad.check().is_err());
    }
}
