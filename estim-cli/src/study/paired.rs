//! Paired comparisons of filter variants on the A-KIT trajectories (`estim compare`).
//!
//! Every variant of one (trajectory, seed) cell runs on the same scenario: the same
//! IMU (the recorded one where the trajectory's folder holds it, read through the
//! vehicle file, else synthesized from the reference; [`ImuSelection`]), the same
//! beam-noise draw, the same initial state. The innovation gate is off
//! (`filter.gate_probability = 0`, and the vehicle's gate for a recorded IMU), so every
//! variant takes every DVL update and no difference comes from one variant rejecting
//! updates another accepts; or, with [`Gate::Common`], every variant takes the same
//! updates: those all of them accepted when run with the configured (or the
//! vehicle's) gate.
//! Per cell and variant the run gives three numbers (time-averaged NEES per state with
//! truth: 15 on a synthesized IMU, 9 on a recorded one; time-averaged NIS; position
//! RMSE); per pair of variants the difference of each number is taken inside the cell
//! (a paired difference), and [`PairedInterval`] summarises them.
//!
//! What the interval is: a Student t confidence interval of the mean paired
//! difference, mean +- t_{(1+level)/2, n-1} s / sqrt(n). Two are reported:
//! - over the trajectories (n = number of trajectories), each trajectory's
//!   difference being its mean over the seeds. The seeds redraw only the synthetic
//!   noise (IMU errors on a synthesized IMU, beam noise, initial error on a
//!   synthesized IMU); the real sample is the
//!   trajectories, so this is the interval to read;
//! - over every (trajectory, seed) cell (n = trajectories x seeds), which treats the
//!   seeds as independent real samples: narrower, and optimistic for that reason.
//!
//! Nothing is fitted here. The configured A-KIT parameters are used as they are:
//! `dvl.akit_reference_mismatch_std_mps` (fitted on the training trajectories by
//! `estim dvl mismatch`, 4 and 13 held out) and `dvl.akit_time_offset_s` (-1.48 s,
//! the offset of one of the two calibration groups; see docs/results.md).

use std::path::Path;

use rayon::prelude::*;
use serde::Serialize;
use statrs::distribution::{ContinuousCDF, StudentsT};

use super::report::FilterFailure;
use super::stats::{error_summary, finite_mean, std_summary};
use super::{
    least_squares_velocities, run_variant, Config, CrossSource, FilterRun, ImuSelection,
    LearnedSource, MeasurementSet, PipelineError, Result, Scenario, BEAMSNET_NEGLECTED,
    BEAMSNET_SCALED, LS,
};
use estim_core::nalgebra::Matrix3;

mod markdown;

pub(crate) use markdown::interval_text;
pub use markdown::markdown;

/// Filter id of BeamsNet with the paper's M = rho sqrt(diag Q_k) sqrt(diag R)' built
/// from the last IMU step's process noise Q_k (the paper's letter).
pub const BEAMSNET_PER_STEP: &str = "beamsnet_m_rho_per_step";

/// The variants, in this order: every cell runs least squares, BeamsNet with M
/// neglected, and BeamsNet with the paper's M on the basis [`paper_variant`] gives.
pub const PAIRED_VARIANTS: [&str; 4] = [LS, BEAMSNET_NEGLECTED, BEAMSNET_PER_STEP, BEAMSNET_SCALED];

/// The pairs compared: (minuend, subtrahend); the difference is minuend - subtrahend.
/// A pair no cell ran (the per-step M on a recorded IMU, the accumulated one on a
/// synthesized IMU) is left out of [`PairedStudy::comparisons`].
pub const PAIRS: [(&str, &str); 3] = [
    (BEAMSNET_PER_STEP, BEAMSNET_NEGLECTED),
    (BEAMSNET_SCALED, BEAMSNET_NEGLECTED),
    (BEAMSNET_NEGLECTED, LS),
];

/// The paper's-M variant of a cell on an IMU of `source`: M from the last IMU step's
/// Q_k (the paper's letter) on a synthesized IMU; on a recorded one, M from the Q
/// accumulated since the previous update, the basis the navigator's loop runs.
pub fn paper_variant(source: super::ImuSource) -> &'static str {
    match source {
        super::ImuSource::Synthesized => BEAMSNET_PER_STEP,
        super::ImuSource::Recorded => BEAMSNET_SCALED,
    }
}

/// The per-run numbers compared: (key, what it is). The first three are differences
/// (first variant minus second); the `*_std_improvement_percent` ones are the paper's
/// metric, the percentage by which the first variant's time-averaged standard
/// deviation (summed over the three axes, from P) is below the second's,
/// 100 (second - first) / second, taken inside each cell.
pub const METRICS: [(&str, &str); 5] = [
    (
        "nees",
        "time-averaged NEES against truth (per state when the runs differ in states)",
    ),
    ("nis", "time-averaged NIS (3 dof)"),
    ("position_rmse_m", "position RMSE against truth [m]"),
    (
        "velocity_std_improvement_percent",
        "the paper's metric: % by which the time-averaged velocity std is lower",
    ),
    (
        "misalignment_std_improvement_percent",
        "the paper's metric: % by which the time-averaged misalignment std is lower",
    ),
];

/// Confidence level of every interval of the study.
pub const LEVEL: f64 = 0.95;

/// A Student t confidence interval of a mean paired difference.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PairedInterval {
    /// Number of paired differences.
    pub n: usize,
    /// Their mean.
    pub mean: f64,
    /// Their sample standard deviation (divisor n - 1).
    pub std_dev: f64,
    /// The t quantile t_{(1+level)/2, n-1}.
    pub t_quantile: f64,
    /// Lower bound of the interval.
    pub lo: f64,
    /// Upper bound of the interval.
    pub hi: f64,
    /// Confidence level (0.95).
    pub level: f64,
}

impl PairedInterval {
    /// The t interval of the mean of `differences` at `level`: mean +- t s / sqrt(n),
    /// t the (1 + level) / 2 quantile of Student's t with n - 1 degrees of freedom.
    /// With fewer than two values (or a non-finite one) the bounds are NaN.
    pub fn of(differences: &[f64], level: f64) -> Self {
        let n = differences.len();
        let nan = Self {
            n,
            mean: f64::NAN,
            std_dev: f64::NAN,
            t_quantile: f64::NAN,
            lo: f64::NAN,
            hi: f64::NAN,
            level,
        };
        if differences.iter().any(|d| !d.is_finite()) {
            return nan;
        }
        let mean = differences.iter().sum::<f64>() / n.max(1) as f64;
        if n < 2 {
            return Self { mean, ..nan };
        }
        let std_dev =
            (differences.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt();
        let t_quantile = match StudentsT::new(0.0, 1.0, (n - 1) as f64) {
            Ok(t) => t.inverse_cdf(0.5 * (1.0 + level)),
            Err(_) => f64::NAN,
        };
        let half = t_quantile * std_dev / (n as f64).sqrt();
        Self {
            n,
            mean,
            std_dev,
            t_quantile,
            lo: mean - half,
            hi: mean + half,
            level,
        }
    }
}

/// The three numbers of one run.
#[derive(Debug, Clone, Serialize)]
pub struct CellRun {
    /// A-KIT trajectory.
    pub trajectory: u32,
    /// Which IMU the run integrated.
    pub imu_source: super::ImuSource,
    /// Seed (IMU synthesis, beam noise, initial error).
    pub seed: u64,
    /// Filter id.
    pub id: String,
    /// Time-averaged NEES (over the epochs where P was positive definite).
    pub nees: f64,
    /// The states NEES is over (15 on a synthesized IMU, 9 on a recorded one).
    pub nees_states: usize,
    /// The NEES the pairs compare: `nees`, or `nees / nees_states` in a study whose
    /// runs differ in `nees_states` ([`PairedStudy::nees_per_state`]).
    #[serde(skip)]
    nees_compared: f64,
    /// Time-averaged NIS.
    pub nis: f64,
    /// Position RMSE \[m\].
    pub position_rmse_m: f64,
    /// Time average of the velocity std summed over N, E, D \[m/s\] (the paper's
    /// std metric, from the diagonal of P at the DVL epochs).
    pub velocity_std_mps: f64,
    /// Time average of the misalignment std summed over the three axes \[rad\].
    pub misalignment_std_rad: f64,
    /// Epochs at which P was not positive definite.
    pub covariance_not_positive_definite_epochs: usize,
    /// DVL updates applied (the gate is off in these runs).
    pub updates_accepted: usize,
    /// Median over the updates of the largest valid rho of the paper's per-step M
    /// against the per-step Q_k itself ([`FilterRun::largest_valid_rho_per_step_own`]).
    pub largest_valid_rho_per_step_own: f64,
    /// The paper's M at this study's rho: smallest and largest value over the updates
    /// of the cross term's forward (x) entry over R's, (H M + M' H')_xx / R_xx; `[0]`
    /// accumulated basis, `[1]` per-step basis. Its swing follows the heading.
    pub paper_cross_term_over_r: [[f64; 2]; 2],
    /// Of the twelve 30-degree heading sectors, how many the true heading visits at the
    /// DVL epochs (12: the vehicle turned through every heading).
    pub heading_sectors_visited: usize,
}

impl CellRun {
    fn metric(&self, key: &str) -> f64 {
        match key {
            "nees" => self.nees_compared,
            "nis" => self.nis,
            "velocity_std_improvement_percent" => self.velocity_std_mps,
            "misalignment_std_improvement_percent" => self.misalignment_std_rad,
            _ => self.position_rmse_m,
        }
    }
}

/// The paired value of `key` in one cell: `minuend - subtrahend`, or for the paper's
/// std metric the improvement 100 (subtrahend - minuend) / subtrahend.
fn cell_difference(key: &str, minuend: &CellRun, subtrahend: &CellRun) -> f64 {
    let (a, b) = (minuend.metric(key), subtrahend.metric(key));
    if key.ends_with("_std_improvement_percent") {
        super::stats::improvement_percent(b, a)
    } else {
        a - b
    }
}

/// One metric of one pair.
#[derive(Debug, Clone, Serialize)]
pub struct MetricDifference {
    /// Metric key (`nees`, `nis`, `position_rmse_m`).
    pub metric: String,
    /// The interval over trajectories (each the mean over its seeds): the honest one.
    pub over_trajectories: PairedInterval,
    /// The interval over every (trajectory, seed) cell (seeds taken as independent).
    pub over_cells: PairedInterval,
    /// Per trajectory: (trajectory, mean difference over its seeds).
    pub per_trajectory: Vec<(u32, f64)>,
}

/// One pair of variants.
#[derive(Debug, Clone, Serialize)]
pub struct Comparison {
    /// The minuend's filter id.
    pub minuend: String,
    /// The subtrahend's filter id.
    pub subtrahend: String,
    /// "minuend - subtrahend" in words.
    pub label: String,
    /// Cells where both completed (a cell where either failed is left out).
    pub cells: usize,
    /// One entry per metric of [`METRICS`].
    pub metrics: Vec<MetricDifference>,
}

/// The whole study.
#[derive(Debug, Clone, Serialize)]
pub struct PairedStudy {
    /// Trajectories, in the order run.
    pub trajectories: Vec<u32>,
    /// Seeds, in the order run.
    pub seeds: Vec<u64>,
    /// How the innovation gate entered.
    pub gate: Gate,
    /// The paper's rho of the per-step variant.
    pub rho: f64,
    /// Which IMU each trajectory used, by trajectory number.
    pub imu_sources: std::collections::BTreeMap<u32, super::ImuSource>,
    /// Whether the NEES compared is per state: the runs' NEES are over different
    /// numbers of states (recorded and synthesized IMUs in one study); else it is the
    /// NEES over their common [`CellRun::nees_states`].
    pub nees_per_state: bool,
    /// Every run that completed.
    pub runs: Vec<CellRun>,
    /// Every run that stopped on a numerical failure.
    pub failures: Vec<FilterFailure>,
    /// The pairs of [`PAIRS`].
    pub comparisons: Vec<Comparison>,
}

/// How the innovation gate enters a paired comparison.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Gate {
    /// The gate is off: every variant takes every update.
    Off,
    /// Common gate decisions: each variant first runs with the configured gate; then
    /// all run with the gate off on the updates that all of them accepted.
    Common,
}

/// Human label of a variant of this study.
pub fn variant_label(id: &str) -> String {
    match id {
        BEAMSNET_PER_STEP => "BeamsNet, M = rho 0.42 (per-step Q_k)".into(),
        BEAMSNET_SCALED => "BeamsNet, M = rho 0.42 (accumulated Q)".into(),
        other => super::filter_label(other, f64::NAN),
    }
}

/// The least-squares and BeamsNet measurements of a recorded scenario, each R with
/// `dvl.akit_reference_mismatch_std_mps` added, as `estim reproduce --data` uses them.
pub(crate) fn recorded_sets(
    scenario: &Scenario,
    config: &Config,
    learned: &LearnedSource,
) -> Result<[MeasurementSet; 2]> {
    let mismatch = Matrix3::identity() * config.dvl.akit_reference_mismatch_std.powi(2);
    let ls = MeasurementSet {
        velocities: least_squares_velocities(scenario, config),
        noise_covariance: Matrix3::identity() * config.dvl.ls_noise_std.powi(2) + mismatch,
    };
    let inputs = learned(scenario)?;
    let net = MeasurementSet {
        velocities: inputs.velocities,
        noise_covariance: inputs.noise_covariance + mismatch,
    };
    Ok([ls, net])
}

/// The variants on one (trajectory, seed) cell, gate off.
fn cell(
    config: &Config,
    data: &Path,
    trajectory: u32,
    seed: u64,
    gate: Gate,
    learned: &LearnedSource,
    imu: &ImuSelection,
) -> Result<(
    super::ImuSource,
    Vec<std::result::Result<CellRun, FilterFailure>>,
)> {
    let gated = Config {
        seed,
        ..config.clone()
    };
    let mut config = gated.clone();
    config.filter.gate_probability = 0.0;
    // `scenario` keeps a recorded survey's own gate (for Gate::Common's decisions);
    // `open` is the one every compared run uses.
    let scenario = Scenario::akit_selected(data, trajectory, &config, seed, imu)?;
    let open = scenario.without_recorded_gate()?;
    let mut visited = [false; 12];
    for d in &scenario.dvl {
        if let Some(t) = scenario.truth.get(d.imu_index) {
            let heading = t
                .attitude
                .euler_angles()
                .2
                .rem_euclid(std::f64::consts::TAU);
            visited[((heading.to_degrees() / 30.0) as usize).min(11)] = true;
        }
    }
    let sectors = visited.iter().filter(|v| **v).count();
    let [ls, net] = recorded_sets(&scenario, &config, learned)?;
    let mut jobs = [
        (LS, ls, CrossSource::Zero),
        (BEAMSNET_NEGLECTED, net.clone(), CrossSource::Zero),
        (
            paper_variant(scenario.imu_source),
            net,
            match scenario.imu_source {
                super::ImuSource::Synthesized => CrossSource::ScaledPerStep(config.filter.rho),
                super::ImuSource::Recorded => CrossSource::Scaled(config.filter.rho),
            },
        ),
    ];
    if gate == Gate::Common {
        // The gated runs decide; an update stays where all three accepted it.
        let mut decisions = Vec::with_capacity(jobs.len());
        for (id, set, cross) in &jobs {
            match run_variant(id, &scenario, &gated, set, cross, seed)? {
                Ok(run) => decisions.push(run.update_accepted),
                Err(failure) => return Ok((scenario.imu_source, vec![Err(failure)])),
            }
        }
        for (_, set, _) in &mut jobs {
            for (k, v) in set.velocities.iter_mut().enumerate() {
                if !decisions.iter().all(|d| d.get(k) == Some(&Some(true))) {
                    *v = None;
                }
            }
        }
    }
    let runs = jobs
        .iter()
        .map(|(id, set, cross)| {
            Ok(
                run_variant(id, &open, &config, set, cross, seed)?.map(|run: FilterRun| CellRun {
                    trajectory,
                    imu_source: scenario.imu_source,
                    seed,
                    id: id.to_string(),
                    nees: finite_mean(&run.nees),
                    nees_states: run.nees_states,
                    nees_compared: finite_mean(&run.nees),
                    nis: finite_mean(&run.nis),
                    position_rmse_m: error_summary(&run.position_error).rmse,
                    velocity_std_mps: std_summary(&run.covariance_diagonal, estim_ins::VEL)
                        .time_average,
                    misalignment_std_rad: std_summary(&run.covariance_diagonal, estim_ins::ATT)
                        .time_average,
                    covariance_not_positive_definite_epochs: run.covariance_not_positive_definite,
                    updates_accepted: run.accepted,
                    largest_valid_rho_per_step_own: median(&run.largest_valid_rho_per_step_own),
                    paper_cross_term_over_r: std::array::from_fn(|basis| {
                        let values = run
                            .paper_cross_term_over_r
                            .iter()
                            .map(|b| b[basis][0])
                            .map(|v| v * config.filter.rho);
                        let (lo, hi) = values
                            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                                (lo.min(v), hi.max(v))
                            });
                        [lo, hi]
                    }),
                    heading_sectors_visited: sectors,
                }),
            )
        })
        .collect::<Result<_>>()?;
    Ok((scenario.imu_source, runs))
}

/// Run [`PAIRED_VARIANTS`] on every (trajectory, seed) of A-KIT under `data`, on the
/// IMU `imu` selects, with the gate off or common gate decisions ([`Gate`]), with
/// `learned` as the BeamsNet sensor (its M is not used), and compare [`PAIRS`]. The
/// cells run in parallel (rayon).
///
/// # Errors
/// An empty or repeated trajectory or seed list; the loaders' and the pipeline's
/// errors (a variant's numerical failure is recorded, not an error).
pub fn paired_study(
    config: &Config,
    data: &Path,
    trajectories: &[u32],
    seeds: &[u64],
    gate: Gate,
    learned: &LearnedSource,
    imu: &ImuSelection,
) -> Result<PairedStudy> {
    if trajectories.is_empty() || seeds.is_empty() {
        return Err(PipelineError::Argument {
            flag: "compare".into(),
            reason: "a paired comparison needs at least one trajectory and one seed".into(),
        });
    }
    for (what, repeated) in [
        ("trajectory", has_repeat(trajectories)),
        ("seed", has_repeat(seeds)),
    ] {
        if let Some(x) = repeated {
            return Err(PipelineError::Argument {
                flag: "compare".into(),
                reason: format!("{what} {x} given twice"),
            });
        }
    }
    let cells: Vec<(u32, u64)> = trajectories
        .iter()
        .flat_map(|t| seeds.iter().map(move |s| (*t, *s)))
        .collect();
    let outcomes: Vec<_> = cells
        .par_iter()
        .map(|(t, s)| cell(config, data, *t, *s, gate, learned, imu).map(|o| (*t, o)))
        .collect::<Result<_>>()?;
    let mut runs = Vec::new();
    let mut failures = Vec::new();
    let mut imu_sources = std::collections::BTreeMap::new();
    for (trajectory, (source, outcomes)) in outcomes {
        imu_sources.insert(trajectory, source);
        for outcome in outcomes {
            match outcome {
                Ok(run) => runs.push(run),
                Err(f) => failures.push(f),
            }
        }
    }
    let nees_per_state = runs.iter().any(|r| r.nees_states != runs[0].nees_states);
    if nees_per_state {
        for r in &mut runs {
            r.nees_compared = r.nees / r.nees_states as f64;
        }
    }
    let comparisons = PAIRS
        .iter()
        .map(|(a, b)| compare(&runs, trajectories, seeds, a, b))
        .filter(|c: &Comparison| c.cells > 0)
        .collect();
    Ok(PairedStudy {
        trajectories: trajectories.to_vec(),
        seeds: seeds.to_vec(),
        gate,
        rho: config.filter.rho,
        imu_sources,
        nees_per_state,
        runs,
        failures,
        comparisons,
    })
}

/// Median of the finite values (NaN if none).
fn median(values: &[f64]) -> f64 {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn has_repeat<T: PartialEq + std::fmt::Display>(xs: &[T]) -> Option<String> {
    xs.iter()
        .enumerate()
        .find(|(i, x)| xs[..*i].contains(x))
        .map(|(_, x)| x.to_string())
}

/// The paired differences minuend - subtrahend of every metric.
fn compare(
    runs: &[CellRun],
    trajectories: &[u32],
    seeds: &[u64],
    minuend: &str,
    subtrahend: &str,
) -> Comparison {
    let find = |t: u32, s: u64, id: &str| {
        runs.iter()
            .find(|r| r.trajectory == t && r.seed == s && r.id == id)
    };
    // Per trajectory, the cells where both variants completed.
    let pairs: Vec<(u32, Vec<(&CellRun, &CellRun)>)> = trajectories
        .iter()
        .map(|t| {
            let p = seeds
                .iter()
                .filter_map(|s| Some((find(*t, *s, minuend)?, find(*t, *s, subtrahend)?)))
                .collect();
            (*t, p)
        })
        .collect();
    let metrics = METRICS
        .iter()
        .map(|(key, _)| {
            let per_cell: Vec<f64> = pairs
                .iter()
                .flat_map(|(_, p)| p.iter().map(|(a, b)| cell_difference(key, a, b)))
                .collect();
            let per_trajectory: Vec<(u32, f64)> = pairs
                .iter()
                .filter(|(_, p)| !p.is_empty())
                .map(|(t, p)| {
                    let d: f64 = p.iter().map(|(a, b)| cell_difference(key, a, b)).sum();
                    (*t, d / p.len() as f64)
                })
                .collect();
            let means: Vec<f64> = per_trajectory.iter().map(|(_, d)| *d).collect();
            MetricDifference {
                metric: key.to_string(),
                over_trajectories: PairedInterval::of(&means, LEVEL),
                over_cells: PairedInterval::of(&per_cell, LEVEL),
                per_trajectory,
            }
        })
        .collect();
    Comparison {
        minuend: minuend.into(),
        subtrahend: subtrahend.into(),
        label: format!("{} - {}", variant_label(minuend), variant_label(subtrahend)),
        cells: pairs.iter().map(|(_, p)| p.len()).sum(),
        metrics,
    }
}

/// The committed BeamsNet for each IMU source as this study's sensor, without its
/// sensitivity (the study does not use the network-derived M; computing it would
/// triple the cost): on a recorded IMU the network trained on recorded windows, on a
/// synthesized one the network trained on synthesized windows (as
/// [`super::committed_beamsnet`]).
///
/// # Errors
/// The committed models cannot be loaded.
pub fn beamsnet_without_sensitivity(config: &Config) -> Result<Box<LearnedSource>> {
    let synthesized = estim::models::beamsnet()?;
    let recorded = estim::models::beamsnet_recorded()?;
    let protocol = if config.dvl.protocol == "v2" {
        estim_dvl::BeamsNetProtocol::v2()
    } else {
        estim_dvl::BeamsNetProtocol::v1()
    };
    let geometry = protocol.geometry().clone();
    Ok(Box::new(move |scenario| {
        let net = match scenario.imu_source {
            super::ImuSource::Recorded => &recorded,
            super::ImuSource::Synthesized => &synthesized,
        };
        super::beamsnet_inputs(net, scenario, &geometry, false)
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The interval against a formula coded here by hand and a published t quantile
    /// (t_{0.975, 12} = 2.178812829667228, e.g. NIST/SEMATECH e-Handbook, table 1.3.6.7.2;
    /// t_{0.975, 4} = 2.776445105197793).
    #[test]
    fn paired_interval_matches_the_textbook_formula() {
        let d = [
            1.2, -0.4, 0.8, 2.5, 0.1, -1.3, 0.9, 1.7, 0.3, -0.2, 1.1, 0.6, 0.4,
        ];
        let n = d.len() as f64;
        let mut sum = 0.0;
        for x in d {
            sum += x;
        }
        let mean = sum / n;
        let mut ss = 0.0;
        for x in d {
            ss += (x - mean) * (x - mean);
        }
        let sd = (ss / (n - 1.0)).sqrt();
        let half = 2.178812829667228 * sd / n.sqrt();
        let got = PairedInterval::of(&d, 0.95);
        assert_eq!(got.n, 13);
        assert!((got.mean - mean).abs() < 1e-15);
        assert!((got.std_dev - sd).abs() < 1e-14);
        assert!((got.t_quantile - 2.178812829667228).abs() < 1e-9);
        assert!((got.lo - (mean - half)).abs() < 1e-9);
        assert!((got.hi - (mean + half)).abs() < 1e-9);

        // Five differences by hand: mean 2, sd sqrt(2.5), t_{0.975,4} = 2.776445105197793.
        let got = PairedInterval::of(&[0.0, 1.0, 2.0, 3.0, 4.0], 0.95);
        let half = 2.776445105197793 * 2.5f64.sqrt() / 5f64.sqrt();
        assert!((got.lo - (2.0 - half)).abs() < 1e-9 && (got.hi - (2.0 + half)).abs() < 1e-9);

        // One value: a mean, no interval; a NaN: nothing.
        let one = PairedInterval::of(&[3.0], 0.95);
        assert_eq!(one.mean, 3.0);
        assert!(one.lo.is_nan() && one.hi.is_nan());
        assert!(PairedInterval::of(&[1.0, f64::NAN], 0.95).mean.is_nan());
    }

    /// The heading dependence of the paper's M, against the formula docs/results.md
    /// gives: level vehicle at rest, heading psi, zero lever arm, Q diagonal with
    /// velocity std s per NED axis. Then the forward entry of the cross term over R_xx is
    /// 2 s (cos psi + sin psi) / sqrt(R_xx) at rho = 1: it changes sign over a turn.
    #[test]
    fn paper_cross_term_depends_on_heading() {
        use estim_core::nalgebra::{SMatrix, SVector, UnitQuaternion, Vector3};
        use estim_core::{MeasurementModel, ScaledCorrelation};
        let (s, r_x) = (0.003_f64, 0.0174_f64.powi(2));
        let r = Matrix3::from_diagonal(&Vector3::new(r_x, 2.0 * r_x, 3.0 * r_x));
        let model = estim_dvl::DvlVelocityModel::builder()
            .noise_covariance(r)
            .build()
            .expect("model");
        let mut q_diag = SVector::<f64, 15>::from_element(1e-8);
        for i in 3..6 {
            q_diag[i] = s * s;
        }
        let q = SMatrix::<f64, 15, 15>::from_diagonal(&q_diag);
        let unit = ScaledCorrelation::unit(&q, &r);
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for k in 0..360 {
            let psi = (k as f64).to_radians();
            let state = estim_ins::InsState {
                time: 0.0,
                latitude: 0.57,
                longitude: 0.61,
                height: -20.0,
                velocity_ned: Vector3::zeros(),
                attitude: UnitQuaternion::from_euler_angles(0.0, 0.0, psi),
                acc_bias: Vector3::zeros(),
                gyro_bias: Vector3::zeros(),
                angular_rate: Vector3::zeros(),
            };
            let h = model.jacobian(&state).expect("H");
            let got = 2.0 * (h * unit)[(0, 0)] / r_x;
            let expected = 2.0 * s * (psi.cos() + psi.sin()) / r_x.sqrt();
            assert!(
                (got - expected).abs() < 1e-12,
                "psi {k} deg: {got} vs {expected}"
            );
            lo = lo.min(got);
            hi = hi.max(got);
        }
        let amplitude = 2.0 * 2f64.sqrt() * s / r_x.sqrt();
        assert!(
            (hi - amplitude).abs() < 1e-3 * amplitude && (lo + amplitude).abs() < 1e-3 * amplitude
        );
    }
}
