//! What faults a run injects (`[faults]` of the configuration): plain data, every
//! field defaulting to "no fault", checked with the key named; the injection itself is
//! the scenario's.

use serde::{Deserialize, Serialize};

use super::{PipelineError, Result};

/// Largest `beam_outlier_magnitude_mps` \[m/s\] (the loaders' speed limit).
pub const MAX_OUTLIER_MPS: f64 = 1000.0;
/// Largest `imu_gap_rate_per_s` \[1/s\].
pub const MAX_GAP_RATE_PER_S: f64 = 10.0;
/// Largest `imu_gap_samples` and `imu_gaps[].samples`.
pub const MAX_GAP_SAMPLES: usize = 1_000_000;
/// Most entries of `dvl_outages` and of `imu_gaps`.
pub const MAX_LISTED_FAULTS: usize = 10_000;
/// Largest |start_s| and duration_s of a listed fault \[s\].
pub const MAX_FAULT_TIME_S: f64 = 1e7;

/// A full DVL outage: every beam missing from `start_s` for `duration_s`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DvlOutage {
    /// Start, in seconds since the scenario's first truth sample.
    pub start_s: f64,
    /// Length \[s\].
    pub duration_s: f64,
}

impl DvlOutage {
    /// The scripted outage of the outage scenario: no DVL from 200 s for 60 s (inside
    /// the 400 s A-KIT segments and the default simulated mission).
    pub fn scripted() -> Self {
        Self {
            start_s: 200.0,
            duration_s: 60.0,
        }
    }
}

/// A deterministic IMU gap: `samples` consecutive IMU samples removed from `start_s`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImuGap {
    /// Time of the first removed sample, in seconds since the first truth sample.
    pub start_s: f64,
    /// Number of consecutive samples removed (>= 1).
    pub samples: usize,
}

/// What faults to inject. The default injects nothing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FaultConfig {
    /// Probability that each beam of each DVL epoch is missing (independent draws).
    pub beam_dropout_probability: f64,
    /// Full DVL outages.
    pub dvl_outages: Vec<DvlOutage>,
    /// Probability that a DVL epoch has one beam (chosen uniformly) off by an outlier.
    pub beam_outlier_probability: f64,
    /// Range of the outlier's magnitude \[m/s\]; the sign is random.
    pub beam_outlier_magnitude_mps: [f64; 2],
    /// Rate of random IMU gaps \[gaps per second of mission\].
    pub imu_gap_rate_per_s: f64,
    /// Length of each random IMU gap \[samples\].
    pub imu_gap_samples: usize,
    /// Deterministic IMU gaps.
    pub imu_gaps: Vec<ImuGap>,
}

impl Default for FaultConfig {
    fn default() -> Self {
        Self {
            beam_dropout_probability: 0.0,
            dvl_outages: Vec::new(),
            beam_outlier_probability: 0.0,
            beam_outlier_magnitude_mps: [0.5, 2.0],
            imu_gap_rate_per_s: 0.0,
            imu_gap_samples: 10,
            imu_gaps: Vec::new(),
        }
    }
}

impl FaultConfig {
    /// The standard fault scenario of `estim montecarlo --faults`: 5 % beam dropouts,
    /// 2 % beam outliers of 0.5-2 m/s, a 60 s DVL outage from t = 120 s, and one IMU gap
    /// of 10 samples per 100 s on average.
    #[must_use]
    pub fn standard() -> Self {
        Self {
            beam_dropout_probability: 0.05,
            dvl_outages: vec![DvlOutage {
                start_s: 120.0,
                duration_s: 60.0,
            }],
            beam_outlier_probability: 0.02,
            beam_outlier_magnitude_mps: [0.5, 2.0],
            imu_gap_rate_per_s: 0.01,
            imu_gap_samples: 10,
            imu_gaps: Vec::new(),
        }
    }

    /// Validate ranges; the message names the key.
    ///
    /// # Errors
    /// [`PipelineError::Setting`] or [`PipelineError::OutOfRange`] naming the
    /// offending key.
    pub fn check(&self) -> Result<()> {
        let bad = |key: &str, reason: String| {
            Err(PipelineError::Setting {
                key: format!("faults.{key}"),
                reason,
            })
        };
        let outside = |key: &str, value: String, range: String| {
            Err(PipelineError::OutOfRange {
                key: format!("faults.{key}"),
                value,
                range,
            })
        };
        let probability = |name: &str, p: f64| -> Result<()> {
            if (0.0..=1.0).contains(&p) {
                Ok(())
            } else {
                bad(name, format!("must be within [0, 1], got {p}"))
            }
        };
        probability("beam_dropout_probability", self.beam_dropout_probability)?;
        probability("beam_outlier_probability", self.beam_outlier_probability)?;
        let [lo, hi] = self.beam_outlier_magnitude_mps;
        if !(lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo <= hi && hi <= MAX_OUTLIER_MPS) {
            return bad(
                "beam_outlier_magnitude_mps",
                format!(
                    "must be finite with 0 <= low <= high <= {MAX_OUTLIER_MPS} m/s, \
                     got [{lo}, {hi}]"
                ),
            );
        }
        let rate = self.imu_gap_rate_per_s;
        if !(rate.is_finite() && (0.0..=MAX_GAP_RATE_PER_S).contains(&rate)) {
            return outside(
                "imu_gap_rate_per_s",
                rate.to_string(),
                format!("[0, {MAX_GAP_RATE_PER_S}] 1/s"),
            );
        }
        let samples_ok = |n: usize| (1..=MAX_GAP_SAMPLES).contains(&n);
        if !samples_ok(self.imu_gap_samples) {
            return outside(
                "imu_gap_samples",
                self.imu_gap_samples.to_string(),
                format!("[1, {MAX_GAP_SAMPLES}]"),
            );
        }
        for (key, n) in [
            ("dvl_outages", self.dvl_outages.len()),
            ("imu_gaps", self.imu_gaps.len()),
        ] {
            if n > MAX_LISTED_FAULTS {
                return bad(key, format!("{n} entries, at most {MAX_LISTED_FAULTS}"));
            }
        }
        let time_ok = |t: f64| t.is_finite() && t.abs() <= MAX_FAULT_TIME_S;
        for (i, o) in self.dvl_outages.iter().enumerate() {
            if !(time_ok(o.start_s) && time_ok(o.duration_s) && o.duration_s > 0.0) {
                return bad(
                    &format!("dvl_outages[{i}]"),
                    format!(
                        "needs start_s within +-{MAX_FAULT_TIME_S:e} s and \
                         0 < duration_s <= {MAX_FAULT_TIME_S:e} s"
                    ),
                );
            }
        }
        for (i, g) in self.imu_gaps.iter().enumerate() {
            if !(time_ok(g.start_s) && samples_ok(g.samples)) {
                return bad(
                    &format!("imu_gaps[{i}]"),
                    format!(
                        "needs start_s within +-{MAX_FAULT_TIME_S:e} s and \
                         samples in [1, {MAX_GAP_SAMPLES}]"
                    ),
                );
            }
        }
        Ok(())
    }
}
