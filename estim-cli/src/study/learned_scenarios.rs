//! Learned sensors that must use the IMU: the two-beams scenario (a scripted loss of two
//! of the four DVL beams, during which a network maps the IMU window plus the two
//! remaining beams to the velocity), the outage scenario (no DVL at all for up to 60 s,
//! during which a network maps the IMU window, the last valid DVL velocity and the time
//! since it to a velocity pseudo-measurement at 1 Hz), their filter variants, and their
//! Monte Carlo.
//!
//! Outside the loss the filter is aided by BeamsNet (4 beams, M neglected: its
//! network-derived M is about 1e-8, see docs/results.md). During the loss the variants differ
//! only in the two-beams network's M: from the network's sensitivity, empirical (Monte
//! Carlo over IMU noise), neglected, or the paper's rho-heuristic at its largest valid
//! rho; a fifth variant receives no update during the loss (INS only; least squares
//! needs three beams).
//!
//! On a recorded IMU ([`Scenario::imu_source`]) every variant runs through the
//! navigator ([`super::run_recorded`]: the vehicle's DVL model and R outside the event,
//! the network's R during it) and the event window is scored at the reference's epochs
//! inside it, over the 9 states with truth.

mod monte_carlo;

pub use monte_carlo::{learned_monte_carlo, LearnedMonteCarlo, MeanInterval};

use estim_core::nalgebra::DMatrix;
use estim_core::nalgebra::{Matrix3, SMatrix, Vector3};
use estim_core::{ErrorStateKalmanFilter, FilterConfig, WindowedCrossCovariance};
use estim_dvl::BeamGeometry;
use estim_ins::{InsErrorModel, ERROR_STATES};
use estim_learned::{
    driven_error_covariance, BeamsNet, Empirical, LearnedCrossCovariance, OnnxMeasurement,
    OutageNet, TwoBeamsNet, BEAMSNET_WINDOW, IMU_CHANNELS,
};
use rayon::prelude::*;
use serde::Serialize;

use super::run::filter_imu_spec;
use super::stats::finite_mean;
use super::{
    beamsnet_inputs, run_filter_per_epoch_noise, summarise, BeamLoss, Config, CrossMatrix,
    CrossSource, DvlOutage, FilterRun, FilterSummary, ImuSource, MeasurementSet, PipelineError,
    Result, Scenario,
};

/// Filter id: two-beams network, M from its sensitivity.
pub const TWO_BEAMS_NETWORK: &str = "two_beams_m_network";
/// Filter id: two-beams network, M by Monte Carlo over the IMU noise.
pub const TWO_BEAMS_EMPIRICAL: &str = "two_beams_m_empirical";
/// Filter id: two-beams network, M neglected.
pub const TWO_BEAMS_NEGLECTED: &str = "two_beams_m_neglected";
/// Filter id: two-beams network, the paper's M = rho sqrt(diag Q) sqrt(diag R)' at its
/// largest valid rho.
pub const TWO_BEAMS_SCALED: &str = "two_beams_m_rho";
/// Filter id: no update during the loss (INS only).
pub const INS_ONLY_DURING_LOSS: &str = "ins_only_during_loss";

/// Filter id: outage network, M from its sensitivity.
pub const OUTAGE_NETWORK: &str = "outage_m_network";
/// Filter id: outage network, M by Monte Carlo over the IMU noise.
pub const OUTAGE_EMPIRICAL: &str = "outage_m_empirical";
/// Filter id: outage network, M neglected.
pub const OUTAGE_NEGLECTED: &str = "outage_m_neglected";
/// Filter id: outage network, the paper's M at its largest valid rho.
pub const OUTAGE_SCALED: &str = "outage_m_rho";
/// Filter id: no update during the outage (INS only).
pub const INS_ONLY_DURING_OUTAGE: &str = "ins_only_during_outage";

/// Realizations of the empirical M per update in `estim reproduce --scenario
/// two-beams|outage` and the learned-scenario tables of docs/results.md.
pub const STUDY_EMPIRICAL_REALIZATIONS: usize = 400;

/// The event of a learned-sensor study and the network that fills in during it.
#[derive(Debug, Clone, Copy)]
pub enum LearnedEvent<'a> {
    /// Two beams lost; the two-beams network (IMU window + the two kept beams).
    TwoBeams {
        /// The network.
        net: &'a TwoBeamsNet,
        /// Which beams are kept, when and how long.
        loss: BeamLoss,
    },
    /// A full DVL outage; the outage network (IMU window + last valid velocity + time
    /// since it).
    Outage {
        /// The network.
        net: &'a OutageNet,
        /// When and how long.
        outage: DvlOutage,
    },
}

impl LearnedEvent<'_> {
    /// Scenario name (`two-beams`, `outage`).
    pub fn name(&self) -> &'static str {
        match self {
            Self::TwoBeams { .. } => "two-beams",
            Self::Outage { .. } => "outage",
        }
    }

    /// Filter ids: network M, empirical M, M neglected, the paper's M, INS only.
    pub fn ids(&self) -> [&'static str; 5] {
        match self {
            Self::TwoBeams { .. } => [
                TWO_BEAMS_NETWORK,
                TWO_BEAMS_EMPIRICAL,
                TWO_BEAMS_NEGLECTED,
                TWO_BEAMS_SCALED,
                INS_ONLY_DURING_LOSS,
            ],
            Self::Outage { .. } => [
                OUTAGE_NETWORK,
                OUTAGE_EMPIRICAL,
                OUTAGE_NEGLECTED,
                OUTAGE_SCALED,
                INS_ONLY_DURING_OUTAGE,
            ],
        }
    }

    /// What happens, in words.
    pub fn describe(&self) -> String {
        match self {
            Self::TwoBeams { loss, .. } => format!(
                "beams {} and {} only from {} s for {} s",
                loss.kept[0] + 1,
                loss.kept[1] + 1,
                loss.start_s,
                loss.duration_s
            ),
            Self::Outage { outage, .. } => format!(
                "no DVL from {} s for {} s",
                outage.start_s, outage.duration_s
            ),
        }
    }

    /// Apply the event to `scenario`; the DVL epochs it affects.
    fn apply(&self, scenario: &mut Scenario) -> Result<Vec<usize>> {
        match self {
            Self::TwoBeams { loss, .. } => scenario.lose_beams(loss),
            Self::Outage { outage, .. } => scenario.lose_dvl(outage),
        }
    }

    /// The network's measurements over `epochs` of the (modified) scenario.
    fn measurements(
        &self,
        scenario: &Scenario,
        geometry: &BeamGeometry,
        epochs: &[usize],
        empirical_realizations: usize,
        seed: u64,
    ) -> Result<LearnedMeasurements> {
        match self {
            Self::TwoBeams { net, .. } => {
                two_beams_measurements(net, scenario, epochs, empirical_realizations, seed)
            }
            Self::Outage { net, .. } => learned_measurements(
                net.measurement(),
                scenario,
                &outage_extras(net, scenario, geometry, epochs),
                empirical_realizations,
                seed,
            ),
        }
    }
}

/// Human label of a learned-scenario filter id (`rho`: the one the scaled variant
/// used); an unknown id is its own label.
pub fn learned_filter_label(id: &str, rho: f64) -> String {
    match id {
        TWO_BEAMS_NETWORK => "two beams, M from network".into(),
        TWO_BEAMS_EMPIRICAL => "two beams, M empirical".into(),
        TWO_BEAMS_NEGLECTED => "two beams, M neglected".into(),
        TWO_BEAMS_SCALED => format!("two beams, M = rho {rho:.3} (paper's form, largest valid)"),
        INS_ONLY_DURING_LOSS => "INS only during the loss".into(),
        OUTAGE_NETWORK => "outage network, M from network".into(),
        OUTAGE_EMPIRICAL => "outage network, M empirical".into(),
        OUTAGE_NEGLECTED => "outage network, M neglected".into(),
        OUTAGE_SCALED => format!("outage network, M = rho {rho:.3} (paper's form, largest valid)"),
        INS_ONLY_DURING_OUTAGE => "INS only during the outage".into(),
        other => other.into(),
    }
}

/// A learned network's measurements over a scenario's event epochs.
#[derive(Debug, Clone)]
pub struct LearnedMeasurements {
    /// Velocity per DVL epoch (`None` outside the loss or without a full window).
    pub velocities: Vec<Option<Vector3<f64>>>,
    /// M per DVL epoch from the network's sensitivity (zero where no measurement).
    pub network_m: Vec<CrossMatrix>,
    /// M per DVL epoch by Monte Carlo, if asked for.
    pub empirical_m: Option<Vec<CrossMatrix>>,
    /// Per measured epoch: the largest |correlation| between a velocity or attitude
    /// component of the IMU-driven INS error over the window and a component of the
    /// network's output error, M_ij / sqrt(Q_w,ii R_jj).
    pub output_imu_correlation: Vec<f64>,
    /// The network's R.
    pub noise_covariance: Matrix3<f64>,
}

/// A learned network's outputs and M over the epochs listed in `extras` (epoch index,
/// the network's per-update inputs after the IMU window) of `scenario`.
///
/// As [`beamsnet_inputs`]: the window of epoch k is the [`BEAMSNET_WINDOW`] IMU samples
/// before the update; M_k is the generic [`LearnedCrossCovariance`] over the steps of an
/// error-state filter that starts from the scenario's truth at the window's first
/// sample and records them (`window_capacity`), so the Phi and noise input are the
/// filter's own. `empirical_realizations` = 0 skips the Monte Carlo M
/// ([`Empirical::for_model`], same recorded window, seed `seed + k`).
pub fn learned_measurements(
    model: &OnnxMeasurement<3>,
    scenario: &Scenario,
    extras: &[(usize, Vec<DMatrix<f64>>)],
    empirical_realizations: usize,
    seed: u64,
) -> Result<LearnedMeasurements> {
    let n = BEAMSNET_WINDOW;
    let error_model =
        InsErrorModel::new(filter_imu_spec(&scenario.imu_spec).unwrap_or(scenario.imu_spec));
    let recording = FilterConfig::builder().window_capacity(n).build()?;
    let r = estim_core::LearnedMeasurement::noise_covariance(model);
    let len = scenario.dvl.len();
    let mut velocities = vec![None; len];
    let mut network_m = vec![CrossMatrix::zeros(); len];
    let mut empirical_m = (empirical_realizations > 0).then(|| vec![CrossMatrix::zeros(); len]);
    let mut correlation = Vec::new();
    for (k, extra) in extras {
        let k = *k;
        let Some(epoch) = scenario.dvl.get(k) else {
            return Err(PipelineError::DvlEpoch {
                scenario: scenario.name.clone(),
                epoch: k,
                reason: format!("learned-sensor epoch beyond the scenario's {len} DVL epochs"),
            });
        };
        let end = epoch.imu_index.min(scenario.imu.len());
        if end < n {
            continue;
        }
        // The covariance of the recording filter plays no part in M.
        let mut recorder = ErrorStateKalmanFilter::new(
            error_model,
            scenario.truth[end - n],
            SMatrix::<f64, ERROR_STATES, ERROR_STATES>::identity(),
        )?
        .with_config(recording.clone());
        for sample in &scenario.imu[end - n..end] {
            recorder.predict(sample, scenario.imu_dt)?;
        }
        let steps = recorder.step_window(n)?;
        let generic =
            LearnedCrossCovariance::<f64, _, _, 3, IMU_CHANNELS>::new(model, &error_model, extra)?;
        velocities[k] = Some(generic.measure::<ERROR_STATES>(&steps)?);
        let m = generic.transported_cross_covariance(&steps)?.ok_or(
            PipelineError::NoCrossCovariance {
                network: "network sensitivity",
            },
        )?;
        let q_w =
            driven_error_covariance::<f64, _, ERROR_STATES, IMU_CHANNELS>(&error_model, &steps)?;
        network_m[k] = m;
        correlation.push(max_correlation(&m, &q_w, &r));
        if let Some(out) = empirical_m.as_mut() {
            out[k] = Empirical::for_model(
                model,
                &error_model,
                extra.clone(),
                empirical_realizations,
                seed.wrapping_add(k as u64),
            )
            .estimate(&steps)?
            .cross_covariance;
        }
    }
    Ok(LearnedMeasurements {
        velocities,
        network_m,
        empirical_m,
        output_imu_correlation: correlation,
        noise_covariance: r,
    })
}

/// The two-beams network's outputs and M over the epochs `epochs` of `scenario`
/// (epochs where a beam it reads is missing are skipped); see
/// [`learned_measurements`].
pub fn two_beams_measurements(
    net: &TwoBeamsNet,
    scenario: &Scenario,
    epochs: &[usize],
    empirical_realizations: usize,
    seed: u64,
) -> Result<LearnedMeasurements> {
    let extras: Vec<(usize, Vec<DMatrix<f64>>)> = epochs
        .iter()
        .filter_map(|&k| {
            let epoch = scenario.dvl.get(k)?;
            Some((k, net.beam_inputs(&epoch.beams)?))
        })
        .collect();
    learned_measurements(
        net.measurement(),
        scenario,
        &extras,
        empirical_realizations,
        seed,
    )
}

/// The outage network's per-update inputs over the epochs `epochs` (inside the outage)
/// of `scenario`: the last valid velocity is the least-squares velocity
/// ([`BeamGeometry::solve_nan`], three beams or more) of the last epoch before the
/// first epoch of `epochs`, the elapsed time is measured from it. Epochs beyond the
/// network's trained range, or with no valid epoch before, are left out.
pub fn outage_extras(
    net: &OutageNet,
    scenario: &Scenario,
    geometry: &BeamGeometry,
    epochs: &[usize],
) -> Vec<(usize, Vec<DMatrix<f64>>)> {
    let Some(&first) = epochs.iter().min() else {
        return Vec::new();
    };
    let time = |k: usize| {
        scenario
            .dvl
            .get(k)
            .and_then(|e| scenario.truth.get(e.imu_index))
            .map(|s| s.time)
    };
    let last = (0..first).rev().find_map(|k| {
        let v = geometry.solve_nan(&scenario.dvl[k].beams).velocity()?;
        Some((time(k)?, v))
    });
    let Some((t_last, v_last)) = last else {
        return Vec::new();
    };
    epochs
        .iter()
        .filter_map(|&k| {
            let extra = net.extra_inputs(&v_last, time(k)? - t_last)?;
            Some((k, extra))
        })
        .collect()
}

/// max over velocity and attitude rows i and outputs j of |M_ij| / sqrt(Q_ii R_jj).
pub fn max_correlation(
    m: &CrossMatrix,
    q: &SMatrix<f64, ERROR_STATES, ERROR_STATES>,
    r: &Matrix3<f64>,
) -> f64 {
    let mut best = 0.0_f64;
    for i in 3..9 {
        for j in 0..3 {
            let d = (q[(i, i)] * r[(j, j)]).sqrt();
            if d > 0.0 {
                best = best.max((m[(i, j)] / d).abs());
            }
        }
    }
    best
}

/// Summary of one variant over the loss window.
#[derive(Debug, Clone, Serialize)]
pub struct LossWindowSummary {
    /// Mean NEES over the DVL epochs of the loss (on a recorded IMU over the
    /// reference's epochs within it, and over 9 states; NaN epochs skipped).
    pub nees_mean: f64,
    /// Position error RMSE over the loss epochs \[m\].
    pub position_rmse_m: f64,
    /// Velocity error RMSE over the loss epochs [m/s].
    pub velocity_rmse_mps: f64,
    /// Mean NIS of the updates during the loss.
    pub nis_mean: f64,
}

/// Everything reported for one scenario of a learned-sensor study.
#[derive(Debug, Clone, Serialize)]
pub struct LearnedStudy {
    /// The event (`two-beams`, `outage`).
    pub event: String,
    /// What happens, in words.
    pub description: String,
    /// Scenario name.
    pub scenario: String,
    /// The IMU the filter integrated and the networks were fed.
    pub imu_source: ImuSource,
    /// The states with truth over which NEES is taken (9 on a recorded IMU).
    pub nees_states: usize,
    /// DVL epochs of the event with a network measurement.
    pub loss_epochs: usize,
    /// rho used by the paper's variant (largest valid over the run, times 0.99).
    pub paper_rho: f64,
    /// Mean over the loss epochs of the largest |correlation| between the network's
    /// output error and the IMU-driven INS error (velocity and attitude components).
    pub output_imu_correlation: f64,
    /// max |M_network - M_empirical| / max |M_empirical| over the loss epochs (if the
    /// empirical M was computed).
    pub network_vs_empirical_relative: Option<f64>,
    /// Per variant, the whole run.
    pub filters: Vec<FilterSummary>,
    /// Per variant, the loss window only (same order as `filters`).
    pub loss_window: Vec<LossWindowSummary>,
    /// Raw runs (not serialised).
    #[serde(skip)]
    pub runs: Vec<FilterRun>,
}

/// Run a learned-sensor study on `scenario` (the event is applied here): BeamsNet
/// outside the event, the event's network during it, with the five variants.
pub fn learned_study(
    scenario: &Scenario,
    config: &Config,
    beamsnet: &BeamsNet,
    event: &LearnedEvent<'_>,
    empirical_realizations: usize,
    seed: u64,
) -> Result<LearnedStudy> {
    let [id_network, id_empirical, id_neglected, id_scaled, id_ins_only] = event.ids();
    let mut scenario = scenario.clone();
    let epochs = event.apply(&mut scenario)?;
    let geometry: BeamGeometry = if config.dvl.protocol == "v2" {
        estim_dvl::BeamsNetProtocol::v2().geometry().clone()
    } else {
        estim_dvl::BeamsNetProtocol::v1().geometry().clone()
    };
    // BeamsNet outside the event (fewer than 3 beams give no BeamsNet measurement).
    let four = beamsnet_inputs(beamsnet, &scenario, &geometry, false)?;
    let two = event.measurements(&scenario, &geometry, &epochs, empirical_realizations, seed)?;
    let mismatch = if scenario.trajectory.is_some() {
        Matrix3::identity() * config.dvl.akit_reference_mismatch_std.powi(2)
    } else {
        Matrix3::zeros()
    };
    let r_four = four.noise_covariance + mismatch;
    let r_two = two.noise_covariance + mismatch;
    let mut velocities = four.velocities.clone();
    let mut noise = vec![None; scenario.dvl.len()];
    for (k, v) in two.velocities.iter().enumerate() {
        if let Some(v) = v {
            velocities[k] = Some(*v);
            noise[k] = Some(r_two);
        }
    }
    let set = MeasurementSet {
        velocities,
        noise_covariance: r_four,
    };
    let ins_only = MeasurementSet {
        velocities: four.velocities.clone(),
        noise_covariance: r_four,
    };
    let neglected = run_filter_per_epoch_noise(
        id_neglected,
        &scenario,
        config,
        &set,
        &noise,
        &CrossSource::Zero,
        seed,
    )?;
    // The paper's heuristic at the largest rho valid at every update of this run.
    let paper_rho = 0.99
        * neglected
            .largest_valid_rho
            .iter()
            .copied()
            .filter(|r| r.is_finite())
            .fold(1.0_f64, f64::min);
    let mut jobs: Vec<(&str, &MeasurementSet, CrossSource)> = vec![
        (
            id_network,
            &set,
            CrossSource::PerEpoch(two.network_m.clone()),
        ),
        (id_scaled, &set, CrossSource::Scaled(paper_rho)),
        (id_ins_only, &ins_only, CrossSource::Zero),
    ];
    if let Some(m) = &two.empirical_m {
        jobs.insert(1, (id_empirical, &set, CrossSource::PerEpoch(m.clone())));
    }
    let mut runs: Vec<FilterRun> = jobs
        .par_iter()
        .map(|(name, s, cross)| {
            run_filter_per_epoch_noise(name, &scenario, config, s, &noise, cross, seed)
        })
        .collect::<Result<_>>()?;
    // Order: network, empirical (if any), neglected, paper, INS only.
    let at = if two.empirical_m.is_some() { 2 } else { 1 };
    runs.insert(at, neglected);
    for run in &mut runs {
        run.name = learned_filter_label(&run.id, paper_rho);
    }
    let filters = runs.iter().map(summarise).collect::<Result<Vec<_>>>()?;
    let in_loss: Vec<usize> = epochs
        .iter()
        .copied()
        .filter(|&k| two.velocities.get(k).is_some_and(Option::is_some))
        .collect();
    let loss_window = runs
        .iter()
        .map(|run| loss_summary(run, &loss_samples(&scenario, run, &epochs), &epochs, &set))
        .collect();
    let network_vs_empirical_relative = two.empirical_m.as_ref().map(|emp| {
        let (mut diff, mut scale) = (0.0_f64, 0.0_f64);
        for &k in &in_loss {
            diff = diff.max((two.network_m[k] - emp[k]).amax());
            scale = scale.max(emp[k].amax());
        }
        diff / scale
    });
    Ok(LearnedStudy {
        event: event.name().into(),
        description: event.describe(),
        scenario: scenario.name.clone(),
        imu_source: scenario.imu_source,
        nees_states: runs.first().map_or(ERROR_STATES, |r| r.nees_states),
        loss_epochs: in_loss.len(),
        paper_rho,
        output_imu_correlation: finite_mean(&two.output_imu_correlation),
        network_vs_empirical_relative,
        filters,
        loss_window,
        runs,
    })
}

/// The samples of `run`'s time series inside the loss (the DVL epochs `epochs`): those
/// epochs themselves, or on a recorded IMU (series at the reference's epochs) the
/// reference's epochs from the loss's first DVL epoch to its last.
fn loss_samples(scenario: &Scenario, run: &FilterRun, epochs: &[usize]) -> Vec<usize> {
    if scenario.recorded.is_none() {
        return epochs.to_vec();
    }
    let t0 = scenario.truth.first().map_or(0.0, |s| s.time);
    let times: Vec<f64> = epochs
        .iter()
        .filter_map(|&k| scenario.dvl.get(k))
        .filter_map(|e| scenario.truth.get(e.imu_index))
        .map(|s| s.time - t0)
        .collect();
    let first = times.iter().copied().fold(f64::INFINITY, f64::min);
    let last = times.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    (0..run.time.len())
        .filter(|&i| run.time[i] >= first && run.time[i] <= last)
        .collect()
}

/// NEES and errors of `run` at its samples `samples`, and the NIS of its updates at the
/// DVL epochs `epochs`.
fn loss_summary(
    run: &FilterRun,
    samples: &[usize],
    epochs: &[usize],
    set: &MeasurementSet,
) -> LossWindowSummary {
    let pick =
        |xs: &[f64]| -> Vec<f64> { samples.iter().filter_map(|&k| xs.get(k).copied()).collect() };
    let rms = |xs: Vec<f64>| finite_mean(&xs.iter().map(|x| x * x).collect::<Vec<_>>()).sqrt();
    // NIS is recorded per attempted update: map epochs to update indices.
    let mut update_index = Vec::with_capacity(set.velocities.len());
    let mut u = 0;
    for v in &set.velocities {
        update_index.push(v.map(|_| {
            u += 1;
            u - 1
        }));
    }
    let nis: Vec<f64> = epochs
        .iter()
        .filter_map(|&k| update_index.get(k).copied().flatten())
        .filter_map(|i| run.nis.get(i).copied())
        .collect();
    LossWindowSummary {
        nees_mean: finite_mean(&pick(&run.nees)),
        position_rmse_m: rms(pick(&run.position_error)),
        velocity_rmse_mps: rms(pick(&run.velocity_error)),
        nis_mean: if run.id == INS_ONLY_DURING_LOSS || run.id == INS_ONLY_DURING_OUTAGE {
            f64::NAN
        } else {
            finite_mean(&nis)
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_interval_matches_hand_computed_percentiles() {
        // 0..=40: mean 20; 2.5th percentile at position 0.025 * 40 = 1, 97.5th at 39.
        let xs: Vec<f64> = (0..=40).map(f64::from).collect();
        let m = MeanInterval::of(&xs);
        assert_eq!((m.mean, m.lo, m.hi), (20.0, 1.0, 39.0));
        // Interpolated: [0, 10] -> 0.25 and 9.75; NaN ignored.
        let m = MeanInterval::of(&[10.0, f64::NAN, 0.0]);
        assert_eq!((m.mean, m.lo, m.hi), (5.0, 0.25, 9.75));
        assert!(MeanInterval::of(&[]).mean.is_nan());
    }

    #[test]
    fn max_correlation_is_normalised_by_both_variances() {
        let mut m = CrossMatrix::zeros();
        let mut q = SMatrix::<f64, ERROR_STATES, ERROR_STATES>::identity() * 4.0;
        m[(4, 1)] = 0.3; // velocity east x output y
        m[(0, 0)] = 100.0; // position rows are not counted
        q[(4, 4)] = 9.0;
        let r = Matrix3::from_diagonal(&Vector3::new(1.0, 0.25, 1.0));
        // 0.3 / sqrt(9 * 0.25) = 0.2
        assert!((max_correlation(&m, &q, &r) - 0.2).abs() < 1e-15);
    }

    #[test]
    fn beam_loss_blanks_the_other_beams_inside_the_window_only() {
        let config = Config::default();
        let mut s = Scenario::simulated(&config, 3).unwrap();
        let before = s.clone();
        let loss = BeamLoss::two_beams();
        let affected = s.lose_beams(&loss).unwrap();
        // 1 Hz DVL: epochs at t = 200 .. 319 s.
        assert_eq!(affected.len(), 120);
        let t0 = s.truth[0].time;
        for (k, (a, b)) in s.dvl.iter().zip(&before.dvl).enumerate() {
            let t = s.truth[a.imu_index].time - t0;
            let inside = (200.0..320.0).contains(&t);
            assert_eq!(affected.contains(&k), inside, "epoch {k} at {t} s");
            assert_eq!(a.beams[0], b.beams[0]);
            assert_eq!(a.beams[1], b.beams[1]);
            for i in 2..4 {
                assert_eq!(a.beams[i].is_nan(), inside);
            }
        }
        let bad = BeamLoss {
            kept: [1, 1],
            ..loss
        };
        assert!(s.lose_beams(&bad).is_err());
    }

    #[test]
    fn dvl_outage_blanks_every_beam_inside_the_window_only() {
        let config = Config::default();
        let mut s = Scenario::simulated(&config, 4).unwrap();
        let before = s.clone();
        let outage = DvlOutage {
            start_s: 200.0,
            duration_s: 60.0,
        };
        let affected = s.lose_dvl(&outage).unwrap();
        // 1 Hz DVL: epochs at t = 200 .. 259 s.
        assert_eq!(affected.len(), 60);
        let t0 = s.truth[0].time;
        for (k, (a, b)) in s.dvl.iter().zip(&before.dvl).enumerate() {
            let t = s.truth[a.imu_index].time - t0;
            let inside = (200.0..260.0).contains(&t);
            assert_eq!(affected.contains(&k), inside, "epoch {k} at {t} s");
            if inside {
                assert!(a.beams.iter().all(|v| v.is_nan()));
            } else {
                assert_eq!(a.beams, b.beams);
            }
        }
        let bad = DvlOutage {
            start_s: f64::NAN,
            duration_s: 1.0,
        };
        assert!(s.lose_dvl(&bad).is_err());
    }

    #[test]
    fn outage_extras_hold_the_last_least_squares_velocity_and_the_elapsed_time() {
        let Ok(net) = estim::models::outage() else {
            panic!("the committed outage model must load");
        };
        let config = Config::default();
        let mut s = Scenario::simulated(&config, 5).unwrap();
        let epochs = s
            .lose_dvl(&DvlOutage {
                start_s: 200.0,
                duration_s: 70.0,
            })
            .unwrap();
        let geometry = estim_dvl::BeamsNetProtocol::v1().geometry().clone();
        let extras = outage_extras(&net, &s, &geometry, &epochs);
        // Elapsed 1 .. 60 s are used, 61 .. 70 s are beyond the trained range.
        assert_eq!(extras.len(), 60);
        let last = epochs[0] - 1;
        let t_last = s.truth[s.dvl[last].imu_index].time;
        // Independent reference: four-beam least squares, pinv(A) b.
        let a = geometry.matrix();
        let pinv = (a.transpose() * a).try_inverse().unwrap() * a.transpose();
        let v_last = pinv * s.dvl[last].beams;
        for (k, extra) in &extras {
            let elapsed = s.truth[s.dvl[*k].imu_index].time - t_last;
            assert!((extra[1][0] - elapsed).abs() < 1e-9);
            for i in 0..3 {
                assert!((extra[0][i] - v_last[i]).abs() < 1e-12);
            }
        }
    }
}
