//! The reproduction report: per trajectory, the filter variants and their summaries.

use std::collections::BTreeMap;

use estim_core::consistency::chi_square_band;
use estim_core::nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use serde::Serialize;

use super::stats::{
    error_summary, finite_mean, improvement_percent, std_summary, ErrorSummary, StdSummary, GROUPS,
};
use super::{
    run_filter, Config, CrossMatrix, CrossSource, FilterRun, MeasurementSet, Result, Scenario,
};

/// Filter id of the least-squares DVL variant (ids are stable across commands and
/// releases; scripts key on them, humans read [`filter_label`]).
pub const LS: &str = "ls";
/// Filter id: BeamsNet with M neglected.
pub const BEAMSNET_NEGLECTED: &str = "beamsnet_m_neglected";
/// Filter id: BeamsNet with the paper's M = rho sqrt(diag Q) sqrt(diag R)'.
pub const BEAMSNET_SCALED: &str = "beamsnet_m_rho";
/// Filter id: BeamsNet with M from the network's sensitivity.
pub const BEAMSNET_SENSITIVITY: &str = "beamsnet_m_network";
/// Velocity-source id of the BeamsNet output (velocity tables, `beamsnet eval`).
pub const BEAMSNET: &str = "beamsnet";
/// The paper's rho (Cohen & Klein); a label says "(paper)" only for this value.
pub const PAPER_RHO: f64 = 0.42;

/// Human label of a filter id, stating the rho actually used for the scaled-M
/// variants ("BeamsNet, M = rho 0.42 (paper)" only when rho is the paper's 0.42).
/// An unknown id is its own label.
pub fn filter_label(id: &str, rho: f64) -> String {
    let scaled = |sensor: &str| {
        if rho == PAPER_RHO {
            format!("{sensor}, M = rho {rho} (paper)")
        } else {
            format!("{sensor}, M = rho {rho}")
        }
    };
    match id {
        LS => "LS".into(),
        BEAMSNET => "BeamsNet".into(),
        BEAMSNET_NEGLECTED => "BeamsNet, M neglected".into(),
        BEAMSNET_SCALED => scaled("BeamsNet"),
        BEAMSNET_SENSITIVITY => "BeamsNet, M from network".into(),
        super::ORACLE_NEGLECTED => "oracle, M neglected".into(),
        super::ORACLE_TRUE_M => "oracle, true M".into(),
        super::ORACLE_SCALED => scaled("oracle"),
        other => other.into(),
    }
}

/// A filter variant that stopped: which one, on which seed, where, and why. The
/// other variants of the same run are unaffected and reported as usual.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FilterFailure {
    /// Filter id.
    pub id: String,
    /// Human label.
    pub label: String,
    /// Seed of the run (initial error, simulated mission, faults).
    pub seed: u64,
    /// DVL epoch (0-based) at which it stopped, if the failure is tied to one.
    pub epoch: Option<usize>,
    /// Time since the start of the scenario \[s\], if known.
    pub time_s: Option<f64>,
    /// What went wrong.
    pub reason: String,
}

impl FilterFailure {
    /// Turn a [`super::PipelineError::FilterStopped`] into a failure record; any other
    /// error (bad input, not specific to one filter) is handed back unchanged.
    pub fn from_error(
        id: &str,
        label: &str,
        seed: u64,
        error: super::PipelineError,
    ) -> Result<Self> {
        match error {
            super::PipelineError::FilterStopped {
                epoch,
                time_s,
                source,
            } => Ok(Self {
                id: id.into(),
                label: label.into(),
                seed,
                epoch: Some(epoch),
                time_s: Some(time_s),
                reason: source.to_string(),
            }),
            other => Err(other),
        }
    }
}

impl std::fmt::Display for FilterFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "filter {} ({}) failed, seed {}",
            self.id, self.label, self.seed
        )?;
        if let (Some(e), Some(t)) = (self.epoch, self.time_s) {
            write!(f, ", DVL epoch {e} (t = {t:.2} s)")?;
        }
        write!(f, ": {}", self.reason)
    }
}

/// What a learned model produced for a scenario.
#[derive(Debug, Clone)]
pub struct LearnedInputs {
    /// The model's velocity per DVL epoch.
    pub velocities: Vec<Option<Vector3<f64>>>,
    /// Its error covariance R.
    pub noise_covariance: Matrix3<f64>,
    /// M_k per epoch from the network's sensitivity, if computed.
    pub sensitivity: Option<Vec<CrossMatrix>>,
    /// With the sensitivity: per epoch with a measurement, the largest correlation
    /// coefficient |M_ij| / sqrt(Q_w,ii R_jj) between the output error and the
    /// IMU-driven INS error (velocity and attitude rows; Q_w the INS error covariance
    /// driven by the window's IMU white noise).
    pub output_imu_correlation: Option<Vec<f64>>,
}

/// RMSE, MAE, R^2, VAF of the velocity norm (paper Tables I/II).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct VelocityMetrics {
    /// Root-mean-square error \[m/s\].
    #[serde(rename = "rmse_mps")]
    pub rmse: f64,
    /// Mean absolute error \[m/s\].
    #[serde(rename = "mae_mps")]
    pub mae: f64,
    /// Coefficient of determination.
    pub r2: f64,
    /// Variance accounted for \[%\].
    #[serde(rename = "vaf_percent")]
    pub vaf: f64,
}

/// Summary of one filter variant on one trajectory.
#[derive(Debug, Clone, Serialize)]
pub struct FilterSummary {
    /// Stable filter id (`ls`, `beamsnet_m_rho`, ...).
    pub id: String,
    /// Human label, stating the rho used (serialised as `label`).
    #[serde(rename = "label")]
    pub name: String,
    /// Per state group: time-averaged and final std summed over the three axes
    /// (serialised with the unit in each key: `position_m`, `velocity_mps`, ...).
    #[serde(serialize_with = "super::stats::serialize_groups_with_units")]
    pub std: BTreeMap<String, StdSummary>,
    /// |position error| against truth \[m\].
    pub position_error_m: ErrorSummary,
    /// Horizontal position error (north and east) against truth \[m\].
    pub horizontal_position_error_m: ErrorSummary,
    /// |velocity error| against truth \[m/s\].
    pub velocity_error_mps: ErrorSummary,
    /// |attitude error| against truth \[deg\].
    pub attitude_error_deg: ErrorSummary,
    /// Time-averaged NEES against truth over `nees_states` states, over the epochs
    /// where P was positive definite.
    pub nees_average: f64,
    /// The states NEES is over: 15, or 9 on a recorded IMU (position, velocity,
    /// attitude: the IMU's true biases are unknown).
    pub nees_states: usize,
    /// Epochs at which P was not positive definite.
    pub covariance_not_positive_definite_epochs: usize,
    /// 95 % band of a time average of independent chi-square(`nees_states`) values over
    /// the epochs (successive NEES are correlated in time, so this band is a guide).
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
    /// Filter id of the M-aware variant.
    pub id: String,
    /// Its label (serialised as `label`).
    #[serde(rename = "label")]
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
    /// Which IMU the filters integrated: `recorded` or `synthesized`.
    pub imu_source: super::ImuSource,
    /// With a recorded IMU: the vehicle file it was read with and the reference's
    /// clock offset against it (`source`, `offset_s`, `sigma_s`, ...).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub recorded: Option<serde_json::Value>,
    /// Duration \[s\].
    pub duration_s: f64,
    /// DVL epochs.
    pub dvl_epochs: usize,
    /// LS and learned velocity against the DVL reference (Tables I/II), keyed by
    /// velocity-source id (`ls`, `beamsnet`); serialised as an array of objects with
    /// `id` and `label`.
    #[serde(serialize_with = "serialize_velocity")]
    pub velocity: BTreeMap<String, VelocityMetrics>,
    /// Summaries of the filters that completed.
    pub filters: Vec<FilterSummary>,
    /// Filters that stopped (their results are absent from `filters`).
    pub failures: Vec<FilterFailure>,
    /// Improvements of the M-aware variants over M neglected.
    pub improvements: Vec<Improvement>,
    /// The raw time series (not serialised; for CSV and plots).
    #[serde(skip)]
    pub runs: Vec<FilterRun>,
    /// Truth north/east relative to the start at the DVL epochs \[m\] (for plots).
    #[serde(skip)]
    pub truth_north_east: Vec<[f64; 2]>,
}

/// The velocity table as an array of `{id, label, rmse_mps, ...}` (order: LS first).
fn serialize_velocity<S: serde::Serializer>(
    map: &BTreeMap<String, VelocityMetrics>,
    serializer: S,
) -> std::result::Result<S::Ok, S::Error> {
    use serde::ser::SerializeSeq;
    #[derive(Serialize)]
    struct Row<'a> {
        id: &'a str,
        label: String,
        #[serde(flatten)]
        metrics: &'a VelocityMetrics,
    }
    let mut keys: Vec<&String> = map.keys().collect();
    keys.sort_by_key(|k| (k.as_str() != LS, k.as_str()));
    let mut seq = serializer.serialize_seq(Some(map.len()))?;
    for k in keys {
        seq.serialize_element(&Row {
            id: k,
            label: filter_label(k, f64::NAN),
            metrics: &map[k],
        })?;
    }
    seq.end()
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
        id: run.id.clone(),
        name: run.name.clone(),
        std,
        position_error_m: error_summary(&run.position_error),
        horizontal_position_error_m: error_summary(
            &run.axis_error
                .iter()
                .map(|e| e[0].hypot(e[1]))
                .collect::<Vec<_>>(),
        ),
        velocity_error_mps: error_summary(&run.velocity_error),
        attitude_error_deg: error_summary(&run.attitude_error_deg),
        nees_average: finite_mean(&run.nees),
        nees_states: run.nees_states,
        covariance_not_positive_definite_epochs: run.covariance_not_positive_definite,
        nees_band: band(run.nees_states, run.nees.len())?,
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
    let mismatch = if scenario.is_recorded() {
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
    // Every variant starts from the same initial error (same seed). Each succeeds or
    // fails on its own: a numerical failure of one is recorded, the others are kept.
    let outcomes: Vec<Result<std::result::Result<FilterRun, FilterFailure>>> = jobs
        .par_iter()
        .map(|(id, set, cross)| run_variant(id, scenario, config, set, cross, seed))
        .collect();
    let mut runs = Vec::new();
    let mut failures = Vec::new();
    for outcome in outcomes {
        match outcome? {
            Ok(run) => runs.push(run),
            Err(failure) => failures.push(failure),
        }
    }
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
        add(BEAMSNET, &l.velocities);
    }

    let improvements = improvements_over_neglected(&filters);
    let duration_s = match (scenario.truth.first(), scenario.truth.last()) {
        (Some(a), Some(b)) => b.time - a.time,
        _ => 0.0,
    };
    let truth_north_east = truth_north_east(scenario);
    Ok(TrajectoryReport {
        truth_north_east,
        name: scenario.name.clone(),
        trajectory: scenario.trajectory,
        imu_source: scenario.imu_source,
        recorded: scenario.recorded.as_ref().map(|r| {
            serde_json::json!({
                "vehicle": r.vehicle,
                "truth_time_offset": r.truth_time_offset,
                "nees_states": super::RECORDED_NEES_STATES,
                "scored_at": "reference_epochs",
            })
        }),
        duration_s,
        dvl_epochs: scenario.dvl.len(),
        velocity,
        filters,
        failures,
        improvements,
        runs,
    })
}

/// The std improvements of each M-aware BeamsNet variant over M neglected (none
/// without both), per group: time average and final value, in percent.
fn improvements_over_neglected(filters: &[FilterSummary]) -> Vec<Improvement> {
    let mut improvements = Vec::new();
    if let Some(neglected) = filters.iter().find(|f| f.id == BEAMSNET_NEGLECTED) {
        for aware in filters
            .iter()
            .filter(|f| f.id == BEAMSNET_SCALED || f.id == BEAMSNET_SENSITIVITY)
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
                id: aware.id.clone(),
                variant: aware.name.clone(),
                groups,
            });
        }
    }
    improvements
}

/// The reference's north-east track \[m\] from its first point: at its own epochs on a
/// recorded IMU (where the runs are scored), else at the DVL epochs.
fn truth_north_east(scenario: &Scenario) -> Vec<[f64; 2]> {
    match (&scenario.recorded, scenario.truth.first()) {
        // Recorded: at the reference's epochs, where the runs are scored.
        (Some(recorded), _) => match recorded.truth_epochs.first() {
            Some((_, t0)) => {
                let (rn, re) = estim_ins::earth::radii_of_curvature(t0.latitude);
                recorded
                    .truth_epochs
                    .iter()
                    .map(|(_, t)| {
                        [
                            (t.latitude - t0.latitude) * (rn + t0.height),
                            (t.longitude - t0.longitude) * (re + t0.height) * t0.latitude.cos(),
                        ]
                    })
                    .collect()
            }
            None => Vec::new(),
        },
        (None, Some(t0)) => {
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
        (None, None) => Vec::new(),
    }
}

/// Run one filter variant (id `id`, labelled with [`filter_label`]): `Ok(Ok(run))`
/// when it completed, `Ok(Err(failure))` when it stopped on a numerical failure,
/// `Err` for an error that is not the variant's own (bad input).
pub fn run_variant(
    id: &str,
    scenario: &Scenario,
    config: &Config,
    set: &MeasurementSet,
    cross: &CrossSource,
    seed: u64,
) -> Result<std::result::Result<FilterRun, FilterFailure>> {
    let label = filter_label(id, config.filter.rho);
    let outcome = match &scenario.recorded {
        Some(recorded) => super::run_recorded(id, scenario, recorded, set, cross),
        None => run_filter(id, scenario, config, set, cross, seed),
    };
    match outcome {
        Ok(mut run) => {
            run.name = label;
            Ok(Ok(run))
        }
        Err(e) => FilterFailure::from_error(id, &label, seed, e).map(Err),
    }
}
