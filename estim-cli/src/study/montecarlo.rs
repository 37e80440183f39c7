//! Monte Carlo consistency: N seeded simulated missions with known truth; per filter
//! variant the run-averaged NEES / NIS against their 95 % chi-square bands.

use std::collections::BTreeMap;

use estim_core::consistency::chi_square_band;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::learned_scenarios::MeanInterval;
use super::report::{
    filter_label, least_squares_velocities, run_variant, FilterFailure, LearnedInputs,
    BEAMSNET_NEGLECTED, BEAMSNET_SCALED, BEAMSNET_SENSITIVITY, LS,
};
use super::stats::{finite_mean, ExactSum};
use super::{
    apply_faults, oracle_measurements, Config, CrossSource, FilterRun, MeasurementSet,
    OracleSensor, Result, Scenario,
};
use estim_core::nalgebra::Matrix3;

/// Produces a learned sensor's measurements (and optionally M) for a scenario.
pub type LearnedSource = dyn Fn(&Scenario) -> Result<LearnedInputs> + Sync;

/// Filter id: oracle sensor, M neglected.
pub const ORACLE_NEGLECTED: &str = "oracle_m_neglected";
/// Filter id: oracle sensor, true M.
pub const ORACLE_TRUE_M: &str = "oracle_m_true";
/// Filter id: oracle sensor, the paper's M = rho.
pub const ORACLE_SCALED: &str = "oracle_m_rho";

/// Consistency of one variant over the runs that completed.
#[derive(Debug, Clone, Serialize)]
pub struct VariantConsistency {
    /// Stable filter id.
    pub id: String,
    /// Human label, stating the rho used.
    pub label: String,
    /// Runs of this variant that completed (the statistics are over these).
    pub runs_completed: usize,
    /// Runs of this variant that stopped, with seed, epoch and reason.
    pub failures: Vec<FilterFailure>,
    /// NEES (15 states) averaged over the completed runs at each DVL epoch, then over
    /// the epochs where that run-average is defined (an epoch at which some run's P was
    /// not positive definite has none) \[-\].
    pub nees_average: f64,
    /// 95 % band of a run-average of chi-square(15) at one epoch.
    pub nees_band: [f64; 2],
    /// Percentage of DVL epochs whose run-averaged NEES lies in `nees_band` (95
    /// expected; an epoch without a run-average counts as outside) \[%\].
    pub nees_epochs_in_band_percent: f64,
    /// NIS (3 dof) averaged over the completed runs at each update, then over the
    /// updates \[-\].
    pub nis_average: f64,
    /// 95 % band of a run-average of chi-square(3).
    pub nis_band: [f64; 2],
    /// Percentage of updates whose run-averaged NIS lies in `nis_band` \[%\].
    pub nis_epochs_in_band_percent: f64,
    /// Run-epochs at which P was not positive definite (excluded from the averages).
    #[serde(rename = "covariance_not_positive_definite_epochs")]
    pub covariance_not_positive_definite: usize,
    /// Updates rejected by the gate, all runs.
    pub updates_rejected: usize,
    /// Position error: per completed run, the RMSE over its DVL epochs of |position
    /// error|; `mean` over the runs and `lo` / `hi` the 2.5 / 97.5 percentiles over the
    /// runs (a spread, not a confidence interval) \[m\].
    #[serde(rename = "position_rmse_m")]
    pub position_rmse: MeanInterval,
    /// Velocity error, as `position_rmse` with |velocity error| \[m/s\].
    #[serde(rename = "velocity_rmse_mps")]
    pub velocity_rmse: MeanInterval,
    /// For the learned (BeamsNet) variants, when the network's sensitivity is computed:
    /// the mean over runs and epochs of the largest output / IMU-error correlation
    /// coefficient (see [`LearnedInputs::output_imu_correlation`]); `None` otherwise.
    pub output_imu_correlation: Option<f64>,
}

/// The Monte Carlo report.
#[derive(Debug, Clone, Serialize)]
pub struct MonteCarloReport {
    /// Missions run (seeds in `seed_ranges`).
    pub runs: usize,
    /// The smallest seed.
    pub first_seed: u64,
    /// The seeds used, as sorted disjoint ranges `[first, end)` (one range for one
    /// run; merged shards may leave gaps).
    pub seed_ranges: Vec<[u64; 2]>,
    /// DVL epochs per mission (of the first completed run; every mission has the same length).
    pub epochs: usize,
    /// Per variant, keyed by filter id; serialised as an array (each entry has its id).
    #[serde(serialize_with = "variants_as_array")]
    pub variants: BTreeMap<String, VariantConsistency>,
    /// What the statistics are computed from, so that shards merge exactly
    /// ([`MonteCarloSums`]).
    pub sufficient_statistics: MonteCarloSums,
}

impl MonteCarloReport {
    /// Every failure of every variant.
    pub fn failures(&self) -> impl Iterator<Item = &FilterFailure> {
        self.variants.values().flat_map(|v| v.failures.iter())
    }
}

fn variants_as_array<S: serde::Serializer>(
    map: &BTreeMap<String, VariantConsistency>,
    serializer: S,
) -> std::result::Result<S::Ok, S::Error> {
    serializer.collect_seq(map.values())
}

/// The outcome of one variant on one mission.
type Outcome = (String, std::result::Result<FilterRun, FilterFailure>);

/// One mission's outcomes and, with a learned sensor's sensitivity, the mean of its
/// output / IMU-error correlation over the epochs.
type Mission = (Vec<Outcome>, Option<f64>);

/// One mission's runs of every variant.
fn one_mission(config: &Config, seed: u64, learned: Option<&LearnedSource>) -> Result<Mission> {
    let mut scenario = Scenario::simulated(config, seed)?;
    apply_faults(&mut scenario, &config.faults, seed)?;
    let ls = MeasurementSet {
        velocities: least_squares_velocities(&scenario, config),
        noise_covariance: Matrix3::identity() * config.dvl.ls_noise_std.powi(2),
    };
    let (oracle, true_m) = oracle_measurements(&scenario, config, OracleSensor::default(), seed)?;
    let mut jobs: Vec<(&str, MeasurementSet, CrossSource)> = vec![
        (LS, ls, CrossSource::Zero),
        (ORACLE_NEGLECTED, oracle.clone(), CrossSource::Zero),
        (ORACLE_TRUE_M, oracle.clone(), CrossSource::PerEpoch(true_m)),
        (
            ORACLE_SCALED,
            oracle,
            CrossSource::paper(config.filter.rho, config.filter.paper_m_basis),
        ),
    ];
    let mut correlation = None;
    if let Some(make) = learned {
        let l = make(&scenario)?;
        correlation = l
            .output_imu_correlation
            .as_deref()
            .map(finite_mean)
            .filter(|c| c.is_finite());
        let set = MeasurementSet {
            velocities: l.velocities,
            noise_covariance: l.noise_covariance,
        };
        jobs.push((BEAMSNET_NEGLECTED, set.clone(), CrossSource::Zero));
        jobs.push((
            BEAMSNET_SCALED,
            set.clone(),
            CrossSource::paper(config.filter.rho, config.filter.paper_m_basis),
        ));
        if let Some(m) = l.sensitivity {
            jobs.push((BEAMSNET_SENSITIVITY, set, CrossSource::PerEpoch(m)));
        }
    }
    let outcomes = jobs
        .iter()
        .map(|(id, set, cross)| {
            run_variant(id, &scenario, config, set, cross, seed).map(|r| (id.to_string(), r))
        })
        .collect::<Result<_>>()?;
    Ok((outcomes, correlation))
}

/// RMSE of the finite values of `xs` (NaN if none).
fn rmse(xs: &[f64]) -> f64 {
    let squares: Vec<f64> = xs.iter().map(|x| x * x).collect();
    finite_mean(&squares).sqrt()
}

/// Run `runs` missions (seeds `first_seed..`) in parallel; `tick` is called after each.
pub fn monte_carlo(
    config: &Config,
    runs: usize,
    first_seed: u64,
    learned: Option<&LearnedSource>,
    tick: &(dyn Fn() + Sync),
) -> Result<MonteCarloReport> {
    let missions: Vec<Mission> = (0..runs)
        .into_par_iter()
        .map(|i| {
            let r = one_mission(config, first_seed + i as u64, learned);
            tick();
            r
        })
        .collect::<Result<_>>()?;
    MonteCarloReport::from_sums(MonteCarloSums::of_missions(
        config.filter.rho,
        first_seed,
        missions,
    )?)
}

/// One completed run's figures.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunFigures {
    /// Seed of the mission.
    pub seed: u64,
    /// RMSE over the DVL epochs of |position error| \[m\].
    pub position_rmse_m: f64,
    /// RMSE over the DVL epochs of |velocity error| \[m/s\].
    pub velocity_rmse_mps: f64,
}

/// A failed run, as [`FilterFailure`] (kept here so that a shard can be read back).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FailureRecord {
    /// Filter id.
    pub id: String,
    /// Human label.
    pub label: String,
    /// Seed of the run.
    pub seed: u64,
    /// DVL epoch (0-based) at which it stopped, if known.
    pub epoch: Option<usize>,
    /// Time since the start of the scenario \[s\], if known.
    pub time_s: Option<f64>,
    /// What went wrong.
    pub reason: String,
}

impl From<&FilterFailure> for FailureRecord {
    fn from(f: &FilterFailure) -> Self {
        Self {
            id: f.id.clone(),
            label: f.label.clone(),
            seed: f.seed,
            epoch: f.epoch,
            time_s: f.time_s,
            reason: f.reason.clone(),
        }
    }
}

impl From<&FailureRecord> for FilterFailure {
    fn from(f: &FailureRecord) -> Self {
        Self {
            id: f.id.clone(),
            label: f.label.clone(),
            seed: f.seed,
            epoch: f.epoch,
            time_s: f.time_s,
            reason: f.reason.clone(),
        }
    }
}

/// Per-epoch sums over the completed runs of a series (NEES per DVL epoch, NIS per
/// update): an epoch's run-average is defined when no run's value there is
/// non-finite. The length is the shortest completed run's (0 without one).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EpochSums {
    /// Exact sum over the runs of the finite values, per epoch.
    pub sums: Vec<ExactSum>,
    /// Runs whose value is not finite, per epoch.
    pub undefined: Vec<usize>,
}

impl EpochSums {
    fn of(series: &[&Vec<f64>]) -> Self {
        let len = series.iter().map(|s| s.len()).min().unwrap_or(0);
        let mut out = Self {
            sums: vec![ExactSum::default(); len],
            undefined: vec![0; len],
        };
        for s in series {
            for (k, x) in s.iter().take(len).enumerate() {
                if x.is_finite() {
                    out.sums[k].add(*x);
                } else {
                    out.undefined[k] += 1;
                }
            }
        }
        out
    }

    /// Add `other`'s runs (`self_empty` / `other_empty`: whether either has no
    /// completed run, so no length of its own).
    fn merge(&mut self, other: &Self, self_empty: bool, other_empty: bool) {
        if other_empty {
            return;
        }
        if self_empty {
            *self = other.clone();
            return;
        }
        let len = self.sums.len().min(other.sums.len());
        self.sums.truncate(len);
        self.undefined.truncate(len);
        for k in 0..len {
            self.sums[k].merge(&other.sums[k]);
            self.undefined[k] += other.undefined[k];
        }
    }

    /// The run-average per epoch over `runs` runs (NaN where undefined).
    fn averages(&self, runs: usize) -> Vec<f64> {
        self.sums
            .iter()
            .zip(&self.undefined)
            .map(|(s, u)| {
                if *u == 0 && runs > 0 {
                    s.value() / runs as f64
                } else {
                    f64::NAN
                }
            })
            .collect()
    }

    fn check(&self, what: &str) -> std::result::Result<(), String> {
        if self.sums.len() == self.undefined.len() {
            Ok(())
        } else {
            Err(format!(
                "{what}: {} sums but {} undefined counts",
                self.sums.len(),
                self.undefined.len()
            ))
        }
    }
}

/// The sufficient statistics of one variant over a set of missions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VariantSums {
    /// Stable filter id.
    pub id: String,
    /// Human label.
    pub label: String,
    /// Per completed run, in seed order.
    pub runs: Vec<RunFigures>,
    /// Failed runs, in seed order.
    pub failures: Vec<FailureRecord>,
    /// NEES per DVL epoch.
    pub nees: EpochSums,
    /// NIS per update.
    pub nis: EpochSums,
    /// Run-epochs at which P was not positive definite.
    pub covariance_not_positive_definite_epochs: usize,
    /// Updates rejected by the gate.
    pub updates_rejected: usize,
}

/// What a Monte Carlo adds up over its missions: counts, exact sums and the per-run
/// values the percentiles need. [`MonteCarloSums::merge`] of shards over disjoint seeds
/// equals the sums of one run over the union of the seeds (bit for bit:
/// [`ExactSum`]), and [`MonteCarloReport::from_sums`] computes every statistic from it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MonteCarloSums {
    /// The seeds, as sorted disjoint ranges `[first, end)`.
    pub seed_ranges: Vec<[u64; 2]>,
    /// DVL epochs of the first mission (by seed) with a completed run.
    pub epochs: Option<usize>,
    /// Per variant, in the order the missions run them.
    pub variants: Vec<VariantSums>,
    /// Exact sum over the missions of each mission's mean output / IMU-error
    /// correlation (learned variants with a sensitivity).
    pub output_imu_correlation_sum: ExactSum,
    /// Missions that contributed to `output_imu_correlation_sum`.
    pub output_imu_correlation_missions: usize,
}

/// Why shards cannot be merged (the caller names the files).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MergeError {
    /// Two shards share seeds.
    #[error("seed ranges [{}, {}) and [{}, {}) overlap", .0[0], .0[1], .1[0], .1[1])]
    Overlap([u64; 2], [u64; 2]),
    /// The shards ran different filter variants.
    #[error("different filter variants: {0:?} and {1:?}")]
    Variants(Vec<String>, Vec<String>),
    /// A shard's sufficient statistics contradict themselves.
    #[error("{0}")]
    Inconsistent(String),
}

impl MonteCarloSums {
    /// Of missions run on seeds `first_seed, first_seed + 1, ...` in order (`rho`: the
    /// configuration's, for the labels).
    fn of_missions(rho: f64, first_seed: u64, missions: Vec<Mission>) -> Result<Self> {
        let runs = missions.len() as u64;
        let mut correlation = ExactSum::default();
        let mut correlation_missions = 0;
        for c in missions.iter().filter_map(|(_, c)| *c) {
            correlation.add(c);
            correlation_missions += 1;
        }
        let epochs = missions
            .iter()
            .flat_map(|(m, _)| m.iter())
            .find_map(|(_, r)| r.as_ref().ok())
            .map(|r| r.nees.len());
        // Variant ids in job order (the same on every mission).
        let ids: Vec<String> = missions
            .first()
            .map(|(m, _)| m.iter().map(|(id, _)| id.clone()).collect())
            .unwrap_or_default();
        let mut variants = Vec::new();
        for (v, id) in ids.iter().enumerate() {
            let mut completed: Vec<(u64, &FilterRun)> = Vec::new();
            let mut failures = Vec::new();
            for (i, (mission, _)) in missions.iter().enumerate() {
                match mission.get(v).map(|(_, r)| r) {
                    Some(Ok(run)) => completed.push((first_seed + i as u64, run)),
                    Some(Err(f)) => failures.push(FailureRecord::from(f)),
                    None => {}
                }
            }
            let label = filter_label(id, rho);
            let nees: Vec<&Vec<f64>> = completed.iter().map(|(_, r)| &r.nees).collect();
            let nis: Vec<&Vec<f64>> = completed.iter().map(|(_, r)| &r.nis).collect();
            variants.push(VariantSums {
                id: id.clone(),
                label,
                runs: completed
                    .iter()
                    .map(|(seed, r)| RunFigures {
                        seed: *seed,
                        position_rmse_m: rmse(&r.position_error),
                        velocity_rmse_mps: rmse(&r.velocity_error),
                    })
                    .collect(),
                failures,
                nees: EpochSums::of(&nees),
                nis: EpochSums::of(&nis),
                covariance_not_positive_definite_epochs: completed
                    .iter()
                    .map(|(_, r)| r.covariance_not_positive_definite)
                    .sum(),
                updates_rejected: completed.iter().map(|(_, r)| r.rejected).sum(),
            });
        }
        let end = first_seed
            .checked_add(runs)
            .ok_or_else(|| super::PipelineError::Argument {
                flag: "--first-seed".into(),
                reason: format!("seeds {first_seed} + {runs} overflow"),
            })?;
        Ok(Self {
            seed_ranges: if runs == 0 {
                Vec::new()
            } else {
                vec![[first_seed, end]]
            },
            epochs,
            variants,
            output_imu_correlation_sum: correlation,
            output_imu_correlation_missions: correlation_missions,
        })
    }

    /// Missions covered.
    pub fn missions(&self) -> u64 {
        self.seed_ranges.iter().map(|[a, b]| b - a).sum()
    }

    /// Check what a shard read from a file must satisfy: sorted disjoint non-empty
    /// seed ranges, every run and failure on one of those seeds once, per-epoch
    /// arrays of one length.
    pub fn check(&self) -> std::result::Result<(), MergeError> {
        let bad = |m: String| Err(MergeError::Inconsistent(m));
        for r in &self.seed_ranges {
            if r[0] >= r[1] || r[1] > super::MAX_SEED + 1 {
                return bad(format!(
                    "seed range [{}, {}) is empty or above 2^53",
                    r[0], r[1]
                ));
            }
        }
        for w in self.seed_ranges.windows(2) {
            if w[1][0] < w[0][1] {
                return Err(MergeError::Overlap(w[0], w[1]));
            }
        }
        let inside = |seed: u64| {
            self.seed_ranges
                .iter()
                .any(|[a, b]| (*a..*b).contains(&seed))
        };
        for v in &self.variants {
            let mut seeds: Vec<u64> = v.runs.iter().map(|r| r.seed).collect();
            seeds.extend(v.failures.iter().map(|f| f.seed));
            seeds.sort_unstable();
            if let Some(s) = seeds.iter().find(|s| !inside(**s)) {
                return bad(format!(
                    "variant {}: seed {s} is outside the seed ranges {:?}",
                    v.id, self.seed_ranges
                ));
            }
            if let Some(w) = seeds.windows(2).find(|w| w[0] == w[1]) {
                return bad(format!("variant {}: seed {} appears twice", v.id, w[0]));
            }
            if seeds.len() as u64 != self.missions() {
                return bad(format!(
                    "variant {}: {} runs and failures for {} seeds",
                    v.id,
                    seeds.len(),
                    self.missions()
                ));
            }
            v.nees
                .check(&format!("variant {} NEES", v.id))
                .or_else(bad)?;
            v.nis.check(&format!("variant {} NIS", v.id)).or_else(bad)?;
        }
        Ok(())
    }

    /// Add the missions of `other` (seeds disjoint from ours, same variants).
    pub fn merge(&mut self, other: &Self) -> std::result::Result<(), MergeError> {
        for a in &self.seed_ranges {
            for b in &other.seed_ranges {
                if a[0] < b[1] && b[0] < a[1] {
                    return Err(MergeError::Overlap(*a, *b));
                }
            }
        }
        let ids = |s: &Self| s.variants.iter().map(|v| v.id.clone()).collect::<Vec<_>>();
        if ids(self) != ids(other) {
            return Err(MergeError::Variants(ids(self), ids(other)));
        }
        // The first completed mission by seed gives the epochs.
        let first = |s: &Self| s.seed_ranges.first().map_or(u64::MAX, |r| r[0]);
        self.epochs = match (self.epochs, other.epochs) {
            (Some(a), Some(b)) => Some(if first(self) < first(other) { a } else { b }),
            (a, b) => a.or(b),
        };
        for (a, b) in self.variants.iter_mut().zip(&other.variants) {
            let (a_empty, b_empty) = (a.runs.is_empty(), b.runs.is_empty());
            a.nees.merge(&b.nees, a_empty, b_empty);
            a.nis.merge(&b.nis, a_empty, b_empty);
            a.runs.extend_from_slice(&b.runs);
            a.runs.sort_by_key(|r| r.seed);
            a.failures.extend(b.failures.iter().cloned());
            a.failures.sort_by_key(|f| f.seed);
            a.covariance_not_positive_definite_epochs += b.covariance_not_positive_definite_epochs;
            a.updates_rejected += b.updates_rejected;
        }
        self.output_imu_correlation_sum
            .merge(&other.output_imu_correlation_sum);
        self.output_imu_correlation_missions += other.output_imu_correlation_missions;
        self.seed_ranges.extend_from_slice(&other.seed_ranges);
        self.seed_ranges.sort_unstable();
        // Adjacent ranges join: [a, b) + [b, c) = [a, c), as one run over them.
        let mut joined: Vec<[u64; 2]> = Vec::with_capacity(self.seed_ranges.len());
        for r in self.seed_ranges.drain(..) {
            match joined.last_mut() {
                Some(last) if last[1] == r[0] => last[1] = r[1],
                _ => joined.push(r),
            }
        }
        self.seed_ranges = joined;
        Ok(())
    }
}

impl MonteCarloReport {
    /// Every statistic of the report, from its sufficient statistics.
    pub fn from_sums(sums: MonteCarloSums) -> Result<Self> {
        let correlation = (sums.output_imu_correlation_missions > 0).then(|| {
            sums.output_imu_correlation_sum.value() / sums.output_imu_correlation_missions as f64
        });
        let mut variants = BTreeMap::new();
        for v in &sums.variants {
            let n = v.runs.len();
            // The bands are those of an average over the runs that completed.
            let nees_band = chi_square_band(15, n.max(1), 0.95)?;
            let nis_band = chi_square_band(3, n.max(1), 0.95)?;
            let nees = v.nees.averages(n);
            let nis = v.nis.averages(n);
            let in_band = |xs: &[f64], lo: f64, hi: f64| {
                if xs.is_empty() {
                    return f64::NAN;
                }
                100.0 * xs.iter().filter(|x| **x >= lo && **x <= hi).count() as f64
                    / xs.len() as f64
            };
            let figures = |get: fn(&RunFigures) -> f64| {
                MeanInterval::of(&v.runs.iter().map(get).collect::<Vec<_>>())
            };
            variants.insert(
                v.id.clone(),
                VariantConsistency {
                    id: v.id.clone(),
                    label: v.label.clone(),
                    runs_completed: n,
                    failures: v.failures.iter().map(FilterFailure::from).collect(),
                    nees_average: finite_mean(&nees),
                    nees_band: [nees_band.lower, nees_band.upper],
                    nees_epochs_in_band_percent: in_band(&nees, nees_band.lower, nees_band.upper),
                    nis_average: finite_mean(&nis),
                    nis_band: [nis_band.lower, nis_band.upper],
                    nis_epochs_in_band_percent: in_band(&nis, nis_band.lower, nis_band.upper),
                    covariance_not_positive_definite: v.covariance_not_positive_definite_epochs,
                    updates_rejected: v.updates_rejected,
                    position_rmse: figures(|r| r.position_rmse_m),
                    velocity_rmse: figures(|r| r.velocity_rmse_mps),
                    output_imu_correlation: correlation.filter(|_| v.id.starts_with("beamsnet")),
                },
            );
        }
        Ok(Self {
            runs: sums.missions() as usize,
            first_seed: sums.seed_ranges.first().map_or(0, |r| r[0]),
            seed_ranges: sums.seed_ranges.clone(),
            epochs: sums.epochs.unwrap_or(0),
            variants,
            sufficient_statistics: sums,
        })
    }
}
