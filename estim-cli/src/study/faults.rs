//! Seeded sensor-fault injection into a [`Scenario`]: DVL beam dropouts, full DVL
//! outages, beam outliers and IMU sample gaps.
//!
//! A [`FaultConfig`] is plain data (TOML / serde, unknown keys rejected, every field
//! defaulting to "no fault"); [`apply_faults`] edits a scenario in place with a seeded
//! generator and returns a [`FaultLog`] counting what it injected, so a test can
//! compare the filter's reaction (gate rejections, fallbacks) with the faults.
//!
//! What the filter does with each fault (see [`super::run_filter`]):
//! - a dropped beam is NaN in [`DvlEpoch::beams`]; the least-squares path then uses
//!   the 3-beam solution, or no update when fewer than 3 beams remain;
//! - an outage makes every beam of the epochs inside it NaN: no DVL update, the INS
//!   runs free and its covariance grows;
//! - an outlier (one beam off by a random 0.5-2 m/s of random sign) goes through the
//!   least squares into the velocity; the innovation gate rejects it;
//! - an IMU gap removes samples: the runner takes dt from the IMU timestamps and holds
//!   the last sample over the gap (zero-order hold).

#[cfg(test)]
use std::path::Path;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

#[cfg(test)]
use super::PipelineError;
use super::{FaultConfig, Result, Scenario};

/// What [`apply_faults`] injected.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct FaultLog {
    /// Beams made NaN by random dropout (outside outages).
    pub beams_dropped: usize,
    /// DVL epochs inside an outage (all beams NaN).
    pub epochs_in_outage: usize,
    /// DVL epochs left with fewer than 3 beams by dropouts alone (no LS velocity).
    pub epochs_without_velocity: usize,
    /// DVL epochs with one beam shifted by an outlier (on a beam that is present).
    pub outliers: usize,
    /// Index into `Scenario::dvl` of each epoch with an outlier, increasing.
    pub outlier_epochs: Vec<usize>,
    /// IMU gaps injected (random and listed; overlapping gaps count once each).
    pub imu_gaps: usize,
    /// IMU samples removed.
    pub imu_samples_removed: usize,
}

impl FaultConfig {
    /// Parse and validate TOML text (a `[faults]`-less file of these keys); `path`
    /// names the source in errors. The study's tests (and fuzzing) only: the binary reads
    /// `[faults]` inside a study configuration.
    ///
    /// # Errors
    /// [`PipelineError::Config`] naming the file (and line for a syntax error).
    #[cfg(test)]
    pub fn from_toml(text: &str, path: &Path) -> Result<Self> {
        let config: FaultConfig = toml::from_str(text).map_err(|e| {
            let line = e.span().map(|s| {
                text.as_bytes()[..s.start.min(text.len())]
                    .iter()
                    .filter(|&&c| c == b'\n')
                    .count()
                    + 1
            });
            PipelineError::Config {
                path: path.to_path_buf(),
                message: match line {
                    Some(l) => format!("line {l}: {}", e.message()),
                    None => e.message().to_string(),
                },
            }
        })?;
        config.check().map_err(|e| PipelineError::Config {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        Ok(config)
    }
}

/// Inject the faults of `config` into `scenario`, drawing from a generator seeded
/// with `seed`. The draws per DVL epoch (4 dropout draws, then the outlier's
/// occurrence, beam, magnitude and sign) are made whether or not they apply, so
/// changing one fault's setting does not move the others.
///
/// IMU gaps never remove the first IMU sample.
///
/// # Errors
/// [`PipelineError::Setting`] for an invalid configuration.
pub fn apply_faults(scenario: &mut Scenario, config: &FaultConfig, seed: u64) -> Result<FaultLog> {
    config.check()?;
    let mut log = FaultLog::default();
    let t0 = scenario.truth.first().map_or(0.0, |s| s.time);
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xFA17_5EED);
    let [lo, hi] = config.beam_outlier_magnitude_mps;
    for (index, epoch) in scenario.dvl.iter_mut().enumerate() {
        let dropped: [bool; 4] =
            std::array::from_fn(|_| rng.random::<f64>() < config.beam_dropout_probability);
        let outlier = rng.random::<f64>() < config.beam_outlier_probability;
        let beam = rng.random_range(0..4usize);
        let magnitude = lo + (hi - lo) * rng.random::<f64>();
        let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
        let t = scenario
            .truth
            .get(epoch.imu_index)
            .map_or(f64::NAN, |s| s.time - t0);
        if config
            .dvl_outages
            .iter()
            .any(|o| t >= o.start_s && t < o.start_s + o.duration_s)
        {
            epoch.beams.fill(f64::NAN);
            log.epochs_in_outage += 1;
            continue;
        }
        for (b, &drop) in dropped.iter().enumerate() {
            if drop && !epoch.beams[b].is_nan() {
                epoch.beams[b] = f64::NAN;
                log.beams_dropped += 1;
            }
        }
        let present = epoch.beams.iter().filter(|b| !b.is_nan()).count();
        if present < 3 {
            log.epochs_without_velocity += 1;
            continue;
        }
        if outlier && !epoch.beams[beam].is_nan() {
            epoch.beams[beam] += sign * magnitude;
            log.outliers += 1;
            log.outlier_epochs.push(index);
        }
    }

    let n = scenario.imu.len();
    if n > 1 {
        let mut removed = vec![false; n];
        let index_at = |t: f64| {
            scenario
                .imu
                .partition_point(|s| s.time - t0 < t - 1e-9 * scenario.imu_dt.abs())
        };
        let mut mark = |start: usize, samples: usize, log: &mut FaultLog| {
            let start = start.max(1);
            if start >= n {
                return;
            }
            log.imu_gaps += 1;
            for r in removed.iter_mut().skip(start).take(samples) {
                *r = true;
            }
        };
        for g in &config.imu_gaps {
            mark(index_at(g.start_s), g.samples, &mut log);
        }
        if config.imu_gap_rate_per_s > 0.0 {
            // Bernoulli per sample with p = rate * dt (a Poisson process, discretised).
            let p = (config.imu_gap_rate_per_s * scenario.imu_dt).min(1.0);
            let mut gap_rng = ChaCha8Rng::seed_from_u64(seed ^ 0x1A9_5EED);
            for k in 1..n {
                if gap_rng.random::<f64>() < p {
                    mark(k, config.imu_gap_samples, &mut log);
                }
            }
        }
        log.imu_samples_removed = removed.iter().filter(|&&r| r).count();
        let mut k = 0;
        scenario.imu.retain(|_| {
            let keep = !removed[k];
            k += 1;
            keep
        });
    }
    Ok(log)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_inject_nothing_and_reject_unknown_keys() {
        let c = FaultConfig::from_toml("", Path::new("f.toml")).unwrap();
        assert_eq!(c, FaultConfig::default());
        let e = FaultConfig::from_toml("beam_dropout = 0.1\n", Path::new("f.toml")).unwrap_err();
        assert!(e.to_string().contains("f.toml") && e.to_string().contains("line 1"));
        let e = FaultConfig::from_toml("beam_outlier_probability = 1.5\n", Path::new("f.toml"))
            .unwrap_err();
        assert!(e.to_string().contains("beam_outlier_probability"), "{e}");
        let c = FaultConfig::from_toml(
            "[[dvl_outages]]\nstart_s = 100.0\nduration_s = 60.0\n",
            Path::new("f.toml"),
        )
        .unwrap();
        assert_eq!(
            c.dvl_outages,
            vec![super::super::DvlOutage {
                start_s: 100.0,
                duration_s: 60.0
            }]
        );
    }
}
