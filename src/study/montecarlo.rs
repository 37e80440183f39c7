//! Monte Carlo consistency: N seeded simulated missions with known truth; per filter
//! variant the run-averaged NEES / NIS against their 95 % chi-square bands.

use std::collections::BTreeMap;

use estim_core::consistency::chi_square_band;
use rayon::prelude::*;
use serde::Serialize;

use super::learned_scenarios::MeanInterval;
use super::report::{
    filter_label, least_squares_velocities, run_variant, FilterFailure, LearnedInputs,
    BEAMSNET_NEGLECTED, BEAMSNET_SCALED, BEAMSNET_SENSITIVITY, LS,
};
use super::stats::finite_mean;
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
    /// Runs.
    pub runs: usize,
    /// Seeds used: `first_seed .. first_seed + runs`.
    pub first_seed: u64,
    /// DVL epochs per mission (of the first completed run; every mission has the same length).
    pub epochs: usize,
    /// Per variant, keyed by filter id; serialised as an array (each entry has its id).
    #[serde(serialize_with = "variants_as_array")]
    pub variants: BTreeMap<String, VariantConsistency>,
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
    let correlations: Vec<f64> = missions.iter().filter_map(|(_, c)| *c).collect();
    let all: Vec<Vec<Outcome>> = missions.into_iter().map(|(o, _)| o).collect();
    // Variant ids in job order (the same on every mission).
    let ids: Vec<String> = all
        .first()
        .map(|m| m.iter().map(|(id, _)| id.clone()).collect())
        .unwrap_or_default();
    let mut variants = BTreeMap::new();
    for (v, id) in ids.iter().enumerate() {
        let mut completed: Vec<&FilterRun> = Vec::new();
        let mut failures = Vec::new();
        for mission in &all {
            match mission.get(v).map(|(_, r)| r) {
                Some(Ok(run)) => completed.push(run),
                Some(Err(f)) => failures.push(f.clone()),
                None => {}
            }
        }
        let n = completed.len();
        // The bands are those of an average over the runs that completed.
        let nees_band = chi_square_band(15, n.max(1), 0.95)?;
        let nis_band = chi_square_band(3, n.max(1), 0.95)?;
        let per_epoch = |get: &dyn Fn(&FilterRun) -> &Vec<f64>, len: usize| -> Vec<f64> {
            (0..len)
                .map(|k| {
                    completed
                        .iter()
                        .map(|run| get(run).get(k).copied().unwrap_or(f64::NAN))
                        .sum::<f64>()
                        / n as f64
                })
                .collect()
        };
        let epochs = completed.iter().map(|r| r.nees.len()).min().unwrap_or(0);
        let nees = per_epoch(&|r| &r.nees, epochs);
        let nis_len = completed.iter().map(|r| r.nis.len()).min().unwrap_or(0);
        let nis = per_epoch(&|r| &r.nis, nis_len);
        let in_band = |xs: &[f64], lo: f64, hi: f64| {
            if xs.is_empty() {
                return f64::NAN;
            }
            100.0 * xs.iter().filter(|x| **x >= lo && **x <= hi).count() as f64 / xs.len() as f64
        };
        let mean = finite_mean;
        variants.insert(
            id.clone(),
            VariantConsistency {
                id: id.clone(),
                label: filter_label(id, config.filter.rho),
                runs_completed: n,
                failures,
                nees_average: mean(&nees),
                nees_band: [nees_band.lower, nees_band.upper],
                nees_epochs_in_band_percent: in_band(&nees, nees_band.lower, nees_band.upper),
                nis_average: mean(&nis),
                nis_band: [nis_band.lower, nis_band.upper],
                nis_epochs_in_band_percent: in_band(&nis, nis_band.lower, nis_band.upper),
                covariance_not_positive_definite: completed
                    .iter()
                    .map(|r| r.covariance_not_positive_definite)
                    .sum(),
                updates_rejected: completed.iter().map(|r| r.rejected).sum(),
                position_rmse: MeanInterval::of(
                    &completed
                        .iter()
                        .map(|r| rmse(&r.position_error))
                        .collect::<Vec<_>>(),
                ),
                velocity_rmse: MeanInterval::of(
                    &completed
                        .iter()
                        .map(|r| rmse(&r.velocity_error))
                        .collect::<Vec<_>>(),
                ),
                output_imu_correlation: (id.starts_with("beamsnet") && !correlations.is_empty())
                    .then(|| finite_mean(&correlations)),
            },
        );
    }
    Ok(MonteCarloReport {
        runs,
        first_seed,
        epochs: all
            .iter()
            .flat_map(|m| m.iter())
            .find_map(|(_, r)| r.as_ref().ok())
            .map_or(0, |r| r.nees.len()),
        variants,
    })
}
