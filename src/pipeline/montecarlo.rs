//! Monte Carlo consistency: N seeded simulated missions with known truth; per filter
//! variant the run-averaged NEES / NIS against their 95 % chi-square bands.

use std::collections::BTreeMap;

use estim_core::chi_square_band;
use rayon::prelude::*;
use serde::Serialize;

use super::report::{
    least_squares_velocities, LearnedInputs, BEAMSNET_NEGLECTED, BEAMSNET_SCALED,
    BEAMSNET_SENSITIVITY, LS,
};
use super::stats::finite_mean;
use super::{
    apply_faults, oracle_measurements, run_filter, Config, CrossSource, FilterRun, MeasurementSet,
    OracleSensor, Result, Scenario,
};
use estim_core::nalgebra::Matrix3;

/// Produces a learned sensor's measurements (and optionally M) for a scenario.
pub type LearnedSource = dyn Fn(&Scenario) -> Result<LearnedInputs> + Sync;

/// Oracle sensor, M neglected.
pub const ORACLE_NEGLECTED: &str = "oracle, M neglected";
/// Oracle sensor, true M.
pub const ORACLE_TRUE_M: &str = "oracle, true M";
/// Oracle sensor, the paper's M = rho.
pub const ORACLE_SCALED: &str = "oracle, M = rho (paper)";

/// Consistency of one variant over the runs.
#[derive(Debug, Clone, Serialize)]
pub struct VariantConsistency {
    /// Average over runs and epochs of the NEES (15 states).
    pub nees_average: f64,
    /// 95 % band of a run-average of chi-square(15) at one epoch.
    pub nees_band: [f64; 2],
    /// Percentage of epochs whose run-averaged NEES lies in `nees_band` (95 expected).
    pub nees_epochs_in_band_percent: f64,
    /// Average over runs and updates of the NIS (3 dof).
    pub nis_average: f64,
    /// 95 % band of a run-average of chi-square(3).
    pub nis_band: [f64; 2],
    /// Percentage of update epochs whose run-averaged NIS lies in `nis_band`.
    pub nis_epochs_in_band_percent: f64,
    /// Run-epochs at which P was not positive definite (excluded from the averages).
    pub covariance_not_positive_definite: usize,
    /// Updates rejected by the gate, all runs.
    pub updates_rejected: usize,
    /// Position error RMSE over runs and epochs \[m\].
    pub position_rmse_m: f64,
}

/// The Monte Carlo report.
#[derive(Debug, Clone, Serialize)]
pub struct MonteCarloReport {
    /// Runs.
    pub runs: usize,
    /// Seeds used: `first_seed .. first_seed + runs`.
    pub first_seed: u64,
    /// DVL epochs per mission (of the first mission; every mission has the same length).
    pub epochs: usize,
    /// Per variant.
    pub variants: BTreeMap<String, VariantConsistency>,
}

/// One mission's runs of every variant.
fn one_mission(
    config: &Config,
    seed: u64,
    learned: Option<&LearnedSource>,
) -> Result<Vec<FilterRun>> {
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
    if let Some(make) = learned {
        let l = make(&scenario)?;
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
    jobs.iter()
        .map(|(name, set, cross)| run_filter(name, &scenario, config, set, cross, seed))
        .collect()
}

/// Run `runs` missions (seeds `first_seed..`) in parallel; `tick` is called after each.
pub fn monte_carlo(
    config: &Config,
    runs: usize,
    first_seed: u64,
    learned: Option<&LearnedSource>,
    tick: &(dyn Fn() + Sync),
) -> Result<MonteCarloReport> {
    let all: Vec<Vec<FilterRun>> = (0..runs)
        .into_par_iter()
        .map(|i| {
            let r = one_mission(config, first_seed + i as u64, learned);
            tick();
            r
        })
        .collect::<Result<_>>()?;
    let nees_band = chi_square_band(15, runs.max(1), 0.95)?;
    let nis_band = chi_square_band(3, runs.max(1), 0.95)?;
    let mut variants = BTreeMap::new();
    let Some(first) = all.first() else {
        return Ok(MonteCarloReport {
            runs,
            first_seed,
            epochs: 0,
            variants,
        });
    };
    for (v, run0) in first.iter().enumerate() {
        let epochs = run0.nees.len();
        let per_epoch = |get: &dyn Fn(&FilterRun) -> &Vec<f64>, len: usize| -> Vec<f64> {
            (0..len)
                .map(|k| {
                    all.iter()
                        .map(|runs| get(&runs[v]).get(k).copied().unwrap_or(f64::NAN))
                        .sum::<f64>()
                        / runs as f64
                })
                .collect()
        };
        let nees = per_epoch(&|r| &r.nees, epochs);
        let nis_len = all.iter().map(|r| r[v].nis.len()).min().unwrap_or(0);
        let nis = per_epoch(&|r| &r.nis, nis_len);
        let in_band = |xs: &[f64], lo: f64, hi: f64| {
            100.0 * xs.iter().filter(|x| **x >= lo && **x <= hi).count() as f64
                / xs.len().max(1) as f64
        };
        let mean = finite_mean;
        let pos: Vec<f64> = all
            .iter()
            .flat_map(|r| r[v].position_error.iter().map(|e| e * e))
            .collect();
        variants.insert(
            run0.name.clone(),
            VariantConsistency {
                nees_average: mean(&nees),
                nees_band: [nees_band.lower, nees_band.upper],
                nees_epochs_in_band_percent: in_band(&nees, nees_band.lower, nees_band.upper),
                nis_average: mean(&nis),
                nis_band: [nis_band.lower, nis_band.upper],
                nis_epochs_in_band_percent: in_band(&nis, nis_band.lower, nis_band.upper),
                covariance_not_positive_definite: all
                    .iter()
                    .map(|r| r[v].covariance_not_positive_definite)
                    .sum(),
                updates_rejected: all.iter().map(|r| r[v].rejected).sum(),
                position_rmse_m: mean(&pos).sqrt(),
            },
        );
    }
    Ok(MonteCarloReport {
        runs,
        first_seed,
        epochs: first.first().map_or(0, |r| r.nees.len()),
        variants,
    })
}
