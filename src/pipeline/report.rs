//! The reproduction report: per trajectory, the filter variants and their summaries.

use std::collections::BTreeMap;

use estim_core::chi_square_band;
use estim_core::nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use serde::Serialize;

use super::stats::{
    error_summary, finite_mean, improvement_percent, std_summary, ErrorSummary, StdSummary, GROUPS,
};
use super::{
    run_filter, Config, CrossMatrix, CrossSource, FilterRun, MeasurementSet, Result, Scenario,
};

/// Name of the least-squares variant.
pub const LS: &str = "LS";
/// BeamsNet with M neglected.
pub const BEAMSNET_NEGLECTED: &str = "BeamsNet, M neglected";
/// BeamsNet with the paper's M (rho).
pub const BEAMSNET_SCALED: &str = "BeamsNet, M = rho (paper)";
/// BeamsNet with M from the network's sensitivity.
pub const BEAMSNET_SENSITIVITY: &str = "BeamsNet, M from network";

/// What a learned model produced for a scenario.
#[derive(Debug, Clone)]
pub struct LearnedInputs {
    /// The model's velocity per DVL epoch.
    pub velocities: Vec<Option<Vector3<f64>>>,
    /// Its error covariance R.
    pub noise_covariance: Matrix3<f64>,
    /// M_k per epoch from the network's sensitivity, if computed.
    pub sensitivity: Option<Vec<CrossMatrix>>,
}

/// RMSE, MAE, R^2, VAF of the velocity norm (paper Tables I/II).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct VelocityMetrics {
    /// Root-mean-square error \[m/s\].
    pub rmse: f64,
    /// Mean absolute error \[m/s\].
    pub mae: f64,
    /// Coefficient of determination.
    pub r2: f64,
    /// Variance accounted for \[%\].
    pub vaf: f64,
}

/// Summary of one filter variant on one trajectory.
#[derive(Debug, Clone, Serialize)]
pub struct FilterSummary {
    /// Variant name.
    pub name: String,
    /// Per state group: time-averaged and final std summed over the three axes.
    pub std: BTreeMap<String, StdSummary>,
    /// |position error| against truth \[m\].
    pub position_error_m: ErrorSummary,
    /// |velocity error| against truth \[m/s\].
    pub velocity_error_mps: ErrorSummary,
    /// |attitude error| against truth \[deg\].
    pub attitude_error_deg: ErrorSummary,
    /// Time-averaged NEES (15 states) against truth, over the epochs where P was
    /// positive definite.
    pub nees_average: f64,
    /// Epochs at which P was not positive definite.
    pub covariance_not_positive_definite_epochs: usize,
    /// 95 % band of a time average of independent chi-square(15) values over the
    /// epochs (successive NEES are correlated in time, so this band is a guide).
    pub nees_band: [f64; 2],
    /// Time-averaged NIS (3 dof).
    pub nis_average: f64,
    /// 95 % band of the time-averaged NIS.
    pub nis_band: [f64; 2],
    /// Updates accepted.
    pub updates_accepted: usize,
    /// Updates rejected by the innovation gate.
    pub updates_rejected: usize,
    /// Smallest eigenvalue of [[Q_acc, M], [M', R]] over all updates.
    pub joint_min_eigenvalue: f64,
    /// Updates whose joint covariance was not PSD.
    pub joint_invalid_updates: usize,
    /// Whether every update's joint covariance was PSD.
    pub joint_valid: bool,
    /// Median over updates of the largest valid rho of the paper's heuristic.
    pub largest_valid_rho: f64,
}

/// % improvement of an M-aware variant over "M neglected", per group (paper Fig. 5).
#[derive(Debug, Clone, Serialize)]
pub struct Improvement {
    /// The M-aware variant.
    pub variant: String,
    /// Per group: (time-average %, final %).
    pub groups: BTreeMap<String, ImprovementValues>,
}

/// Time-average and final % improvement.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ImprovementValues {
    /// On the time-averaged std.
    pub time_average_percent: f64,
    /// On the final std.
    pub final_percent: f64,
}

/// Everything reported for one trajectory.
#[derive(Debug, Clone, Serialize)]
pub struct TrajectoryReport {
    /// Scenario name.
    pub name: String,
    /// A-KIT trajectory number, if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub trajectory: Option<u32>,
    /// Duration \[s\].
    pub duration_s: f64,
    /// DVL epochs.
    pub dvl_epochs: usize,
    /// LS and learned velocity against the DVL reference (Tables I/II).
    pub velocity: BTreeMap<String, VelocityMetrics>,
    /// Filter summaries.
    pub filters: Vec<FilterSummary>,
    /// Improvements of the M-aware variants over M neglected.
    pub improvements: Vec<Improvement>,
    /// The raw time series (not serialised; for CSV and plots).
    #[serde(skip)]
    pub runs: Vec<FilterRun>,
    /// Truth north/east relative to the start at the DVL epochs \[m\] (for plots).
    #[serde(skip)]
    pub truth_north_east: Vec<[f64; 2]>,
}

/// Velocity-norm metrics computed here (the learned crate has its own; tests compare).
pub fn velocity_metrics(reference: &[f64], predicted: &[f64]) -> VelocityMetrics {
    let n = reference.len().max(1) as f64;
    let err: Vec<f64> = reference
        .iter()
        .zip(predicted)
        .map(|(r, p)| r - p)
        .collect();
    let mean_ref = reference.iter().sum::<f64>() / n;
    let mean_err = err.iter().sum::<f64>() / n;
    let ss_res: f64 = err.iter().map(|e| e * e).sum();
    let ss_tot: f64 = reference.iter().map(|r| (r - mean_ref).powi(2)).sum();
    let var_err = err.iter().map(|e| (e - mean_err).powi(2)).sum::<f64>() / n;
    let var_ref = ss_tot / n;
    VelocityMetrics {
        rmse: (ss_res / n).sqrt(),
        mae: err.iter().map(|e| e.abs()).sum::<f64>() / n,
        r2: 1.0 - ss_res / ss_tot,
        vaf: 100.0 * (1.0 - var_err / var_ref),
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn band(dof: usize, runs: usize) -> Result<[f64; 2]> {
    let b = chi_square_band(dof, runs.max(1), 0.95)?;
    Ok([b.lower, b.upper])
}

/// Summarise one run.
pub fn summarise(run: &FilterRun) -> Result<FilterSummary> {
    let std = GROUPS
        .iter()
        .map(|(g, i)| (g.to_string(), std_summary(&run.covariance_diagonal, *i)))
        .collect();
    // Scale of the joint covariance for the PSD tolerance: none here, the core's
    // check reported the eigenvalue; count clearly negative ones.
    let invalid = run
        .joint_min_eigenvalue
        .iter()
        .filter(|e| **e < -1e-12)
        .count();
    Ok(FilterSummary {
        name: run.name.clone(),
        std,
        position_error_m: error_summary(&run.position_error),
        velocity_error_mps: error_summary(&run.velocity_error),
        attitude_error_deg: error_summary(&run.attitude_error_deg),
        nees_average: finite_mean(&run.nees),
        covariance_not_positive_definite_epochs: run.covariance_not_positive_definite,
        nees_band: band(15, run.nees.len())?,
        nis_average: finite_mean(&run.nis),
        nis_band: band(3, run.nis.len())?,
        updates_accepted: run.accepted,
        updates_rejected: run.rejected,
        joint_min_eigenvalue: run
            .joint_min_eigenvalue
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min),
        joint_invalid_updates: invalid,
        joint_valid: invalid == 0,
        largest_valid_rho: median(run.largest_valid_rho.clone()),
    })
}

/// Least-squares velocity per epoch from the beams (3-beam solutions where one is
/// missing, none where fewer than 3).
pub fn least_squares_velocities(scenario: &Scenario, config: &Config) -> Vec<Option<Vector3<f64>>> {
    let geometry = if config.dvl.protocol == "v2" {
        estim_dvl::BeamsNetProtocol::v2()
    } else {
        estim_dvl::BeamsNetProtocol::v1()
    };
    scenario
        .dvl
        .iter()
        .map(|d| geometry.geometry().solve_nan(&d.beams).velocity())
        .collect()
}

/// Run every variant on `scenario` and summarise.
pub fn analyse(
    scenario: &Scenario,
    config: &Config,
    learned: Option<&LearnedInputs>,
    seed: u64,
) -> Result<TrajectoryReport> {
    // On real data the DVL and the ground truth disagree beyond the sensor noise.
    let mismatch = if scenario.trajectory.is_some() {
        Matrix3::identity() * config.dvl.akit_reference_mismatch_std.powi(2)
    } else {
        Matrix3::zeros()
    };
    let ls = MeasurementSet {
        velocities: least_squares_velocities(scenario, config),
        noise_covariance: Matrix3::identity() * config.dvl.ls_noise_std.powi(2) + mismatch,
    };
    let mut jobs: Vec<(&str, MeasurementSet, CrossSource)> =
        vec![(LS, ls.clone(), CrossSource::Zero)];
    if let Some(l) = learned {
        let set = MeasurementSet {
            velocities: l.velocities.clone(),
            noise_covariance: l.noise_covariance + mismatch,
        };
        jobs.push((BEAMSNET_NEGLECTED, set.clone(), CrossSource::Zero));
        jobs.push((
            BEAMSNET_SCALED,
            set.clone(),
            CrossSource::paper(config.filter.rho, config.filter.paper_m_basis),
        ));
        if let Some(m) = &l.sensitivity {
            jobs.push((BEAMSNET_SENSITIVITY, set, CrossSource::PerEpoch(m.clone())));
        }
    }
    // Every variant starts from the same initial error (same seed).
    let runs: Vec<FilterRun> = jobs
        .par_iter()
        .map(|(name, set, cross)| run_filter(name, scenario, config, set, cross, seed))
        .collect::<Result<_>>()?;
    let filters: Vec<FilterSummary> = runs.iter().map(summarise).collect::<Result<_>>()?;

    let mut velocity = BTreeMap::new();
    let reference: Vec<f64> = scenario
        .dvl
        .iter()
        .map(|d| d.reference_velocity.norm())
        .collect();
    let mut add = |name: &str, v: &[Option<Vector3<f64>>]| {
        let (r, p): (Vec<f64>, Vec<f64>) = reference
            .iter()
            .zip(v)
            .filter_map(|(r, p)| p.map(|p| (*r, p.norm())))
            .unzip();
        if !r.is_empty() {
            velocity.insert(name.to_string(), velocity_metrics(&r, &p));
        }
    };
    add(LS, &ls.velocities);
    if let Some(l) = learned {
        add("BeamsNet", &l.velocities);
    }

    let mut improvements = Vec::new();
    if let Some(neglected) = filters.iter().find(|f| f.name == BEAMSNET_NEGLECTED) {
        for aware in filters
            .iter()
            .filter(|f| f.name == BEAMSNET_SCALED || f.name == BEAMSNET_SENSITIVITY)
        {
            let groups = GROUPS
                .iter()
                .map(|(g, _)| {
                    let (n, a) = (neglected.std[*g], aware.std[*g]);
                    (
                        g.to_string(),
                        ImprovementValues {
                            time_average_percent: improvement_percent(
                                n.time_average,
                                a.time_average,
                            ),
                            final_percent: improvement_percent(n.final_value, a.final_value),
                        },
                    )
                })
                .collect();
            improvements.push(Improvement {
                variant: aware.name.clone(),
                groups,
            });
        }
    }
    let duration_s = match (scenario.truth.first(), scenario.truth.last()) {
        (Some(a), Some(b)) => b.time - a.time,
        _ => 0.0,
    };
    let truth_north_east = match scenario.truth.first() {
        Some(t0) => {
            let (rn, re) = estim_ins::earth::radii_of_curvature(t0.latitude);
            scenario
                .dvl
                .iter()
                .filter_map(|d| scenario.truth.get(d.imu_index))
                .map(|t| {
                    [
                        (t.latitude - t0.latitude) * (rn + t0.height),
                        (t.longitude - t0.longitude) * (re + t0.height) * t0.latitude.cos(),
                    ]
                })
                .collect()
        }
        None => Vec::new(),
    };
    Ok(TrajectoryReport {
        truth_north_east,
        name: scenario.name.clone(),
        trajectory: scenario.trajectory,
        duration_s,
        dvl_epochs: scenario.dvl.len(),
        velocity,
        filters,
        improvements,
        runs,
    })
}
