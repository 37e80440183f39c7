//! The README's claims, asserted with stated margins (the figures themselves are
//! checked byte for byte by `tests/readme_tables.rs`; here each claim must hold, also
//! for seeds other than the README's, so it is not an accident of one draw).
//!
//! - BeamsNet RMSE <= 0.0040 m/s and at least 70 % below least squares on A-KIT 4
//!   and 13 (the targets; measured about 0.0038 and 73 % with the README's seed),
//!   and every row of the paper's Tables I/II within the interval the README documents.
//!   Seeds 7 (the README's), 8 and 9. Metrics coded here, independently of the
//!   pipeline's `velocity_metrics`.
//! - Oracle Monte Carlo: the filter fed the true M is consistent (average NEES inside
//!   the 95 % band of a 20-run average, at least 85 % of the epochs in it; NIS average
//!   inside its band) on two blocks of 20 seeds (1000-1019, the README's, and
//!   3000-3019).
//! - Every "P not PD" count the README gives for the paper's rho = 0.42 (accumulated
//!   basis) is above zero: oracle Monte Carlo on both blocks, the simulated mission and
//!   A-KIT 4 and 13; and rho = 0.42 lies above the largest valid rho at every update.
//!   On the per-step basis M passes the check against Q_acc at every update (against its
//!   own Q_k its largest valid rho is 0.165: `estim compare`) and moves each std by < 1 %.
//!   The README's statements on the paper's ">10 %" (its seed).
//!
//! The A-KIT claims need the data: skipped with a printed reason without it, required
//! in CI (`ESTIM_REQUIRE_DATA=1`).

use std::path::Path;

use crate::study::markdown::default_beamsnet;
use crate::study::{
    analyse, beamsnet_inputs, least_squares_velocities, monte_carlo, Config, PaperMBasis, Scenario,
    BEAMSNET_NEGLECTED, BEAMSNET_SCALED, ORACLE_SCALED, ORACLE_TRUE_M,
};
use estim_core::nalgebra::Vector3;

use super::common;

/// RMSE, MAE, R^2, VAF [%] of |predicted| against |reference| (paper Tables I/II),
/// coded here from their definitions.
fn metrics(reference: &[f64], predicted: &[f64]) -> [f64; 4] {
    let n = reference.len() as f64;
    let errors: Vec<f64> = reference
        .iter()
        .zip(predicted)
        .map(|(r, p)| r - p)
        .collect();
    let mean_reference = reference.iter().sum::<f64>() / n;
    let mean_error = errors.iter().sum::<f64>() / n;
    let residual: f64 = errors.iter().map(|e| e * e).sum();
    let total: f64 = reference.iter().map(|r| (r - mean_reference).powi(2)).sum();
    let error_spread: f64 = errors.iter().map(|e| (e - mean_error).powi(2)).sum();
    [
        (residual / n).sqrt(),
        errors.iter().map(|e| e.abs()).sum::<f64>() / n,
        1.0 - residual / total,
        100.0 * (1.0 - error_spread / total),
    ]
}

/// Metrics of `velocities` against the scenario's DVL reference, over the epochs
/// where both LS and the network give a value.
fn velocity_metrics(
    scenario: &Scenario,
    velocities: &[Option<Vector3<f64>>],
    other: &[Option<Vector3<f64>>],
) -> [f64; 4] {
    let (reference, predicted): (Vec<f64>, Vec<f64>) = scenario
        .dvl
        .iter()
        .zip(velocities.iter().zip(other))
        .filter_map(|(d, (v, o))| {
            o.as_ref()?;
            Some((d.reference_velocity.norm(), v.as_ref()?.norm()))
        })
        .unzip();
    assert!(reference.len() > 300, "{}: too few epochs", scenario.name);
    metrics(&reference, &predicted)
}

/// The intervals the README documents for the rows of the paper's Tables I/II.
struct Interval {
    rmse: (f64, f64),
    mae: (f64, f64),
    r2_min: f64,
    vaf_min: f64,
}

const LS_INTERVAL: Interval = Interval {
    rmse: (0.0120, 0.0160),
    mae: (0.0120, 0.0160),
    r2_min: 0.99,
    vaf_min: 99.9,
};

const BEAMSNET_INTERVAL: Interval = Interval {
    rmse: (0.0, 0.0040),
    mae: (0.0, 0.0033),
    r2_min: 0.999,
    vaf_min: 99.9,
};

fn assert_within(what: &str, m: [f64; 4], i: &Interval) {
    let [rmse, mae, r2, vaf] = m;
    assert!(
        (i.rmse.0..=i.rmse.1).contains(&rmse),
        "{what}: RMSE {rmse:.6} outside {:?}",
        i.rmse
    );
    assert!(
        (i.mae.0..=i.mae.1).contains(&mae),
        "{what}: MAE {mae:.6} outside {:?}",
        i.mae
    );
    assert!(r2 >= i.r2_min, "{what}: R^2 {r2:.6} < {}", i.r2_min);
    assert!(vaf >= i.vaf_min, "{what}: VAF {vaf:.4} < {}", i.vaf_min);
}

fn beamsnet_claims(data: &Path, trajectory: u32, seed: u64) {
    let config = Config {
        seed,
        ..Config::default()
    };
    let scenario = Scenario::akit(data, trajectory, &config, seed).expect("A-KIT scenario");
    let net = estim::models::beamsnet().expect("committed model");
    let geometry = estim::dvl::BeamsNetProtocol::v1().geometry().clone();
    let learned = beamsnet_inputs(&net, &scenario, &geometry, false).expect("inference");
    let ls = least_squares_velocities(&scenario, &config);
    let what = format!("A-KIT {trajectory}, seed {seed}");
    let ls_metrics = velocity_metrics(&scenario, &ls, &learned.velocities);
    let net_metrics = velocity_metrics(&scenario, &learned.velocities, &ls);
    println!("{what}: LS {ls_metrics:?}, BeamsNet {net_metrics:?}");
    assert_within(&format!("{what}, LS"), ls_metrics, &LS_INTERVAL);
    assert_within(
        &format!("{what}, BeamsNet"),
        net_metrics,
        &BEAMSNET_INTERVAL,
    );
    // The target: at least 70 % below LS (measured about 73 %).
    let below = 1.0 - net_metrics[0] / ls_metrics[0];
    assert!(
        below >= 0.70,
        "{what}: BeamsNet only {:.1} % below LS",
        100.0 * below
    );
}

#[test]
fn beamsnet_meets_its_targets_on_akit_4_and_13() {
    let Some(data) = common::data_root() else {
        return;
    };
    for seed in [7, 8, 9] {
        for trajectory in [4, 13] {
            beamsnet_claims(&data, trajectory, seed);
        }
    }
}

/// Time-averaged std improvement [%] of the paper's M over "M neglected" per group.
type Improvements = std::collections::BTreeMap<String, f64>;

/// The paper's rho = 0.42 on both bases of M. Accumulated: the joint covariance is
/// invalid at every update and P loses positive definiteness ("P not PD" > 0).
/// Per-step: valid against Q_acc at every update (not against its own Q_k), P stays
/// positive definite. Returns the
/// time-averaged improvements of (accumulated, per-step).
fn paper_m_claims(scenario: &Scenario, config: &Config) -> (Improvements, Improvements) {
    let learned = default_beamsnet(config).expect("committed model");
    let inputs = learned(scenario).expect("inference");
    let mut out: Vec<Improvements> = Vec::new();
    for basis in [PaperMBasis::Accumulated, PaperMBasis::PerStep] {
        let mut config = config.clone();
        config.filter.paper_m_basis = basis;
        let report = analyse(scenario, &config, Some(&inputs), config.seed).expect("analyse");
        let what = format!("{}, {}", report.name, basis.as_str());
        let scaled = report
            .filters
            .iter()
            .find(|f| f.id == BEAMSNET_SCALED)
            .expect("paper variant");
        let updates = scaled.updates_accepted + scaled.updates_rejected;
        let neglected = report
            .runs
            .iter()
            .find(|r| r.id == BEAMSNET_NEGLECTED)
            .expect("neglected run");
        let largest = match basis {
            PaperMBasis::Accumulated => &neglected.largest_valid_rho,
            _ => &neglected.largest_valid_rho_per_step,
        };
        if basis == PaperMBasis::Accumulated {
            assert!(
                scaled.covariance_not_positive_definite_epochs > 0,
                "{what}: P stayed positive definite with rho = {}",
                config.filter.rho
            );
            assert_eq!(
                scaled.joint_invalid_updates, updates,
                "{what}: joint covariance valid at some update"
            );
            assert!(
                largest.iter().all(|r| *r < config.filter.rho),
                "{what}: rho = {} valid at some update",
                config.filter.rho
            );
        } else {
            assert_eq!(scaled.covariance_not_positive_definite_epochs, 0, "{what}");
            assert_eq!(scaled.joint_invalid_updates, 0, "{what}");
            assert!(
                largest.iter().all(|r| *r >= config.filter.rho),
                "{what}: rho = {} invalid at some update",
                config.filter.rho
            );
        }
        let improvement = report
            .improvements
            .iter()
            .find(|i| i.id == BEAMSNET_SCALED)
            .expect("improvement of the paper's M");
        out.push(
            improvement
                .groups
                .iter()
                .map(|(g, v)| (g.clone(), v.time_average_percent))
                .collect(),
        );
    }
    let per_step = out.pop().expect("two bases");
    let accumulated = out.pop().expect("two bases");
    // Per-step: every group's std moves by less than 1 % (measured at most 0.8 %).
    for (group, v) in &per_step {
        assert!(
            v.abs() < 1.0,
            "{}: per-step basis moves {group} std by {v:.2} %",
            scenario.name
        );
    }
    // Accumulated: misalignment below the paper's 10 % everywhere (measured <= 0.2 %).
    assert!(
        accumulated["misalignment"] < 10.0,
        "{}: misalignment {:.1} %",
        scenario.name,
        accumulated["misalignment"]
    );
    (accumulated, per_step)
}

/// The README's statements on the paper's M (its seed): "P not PD" > 0 on the
/// accumulated basis on every data set, a valid per-step M, and the std improvements
/// the README describes (accumulated: > 10 % on velocity only on trajectory 13,
/// below 10 % on trajectory 4 and the simulated mission).
#[test]
fn paper_m_statements_hold_on_every_data_set() {
    let config = Config::default();
    assert!(config.filter.rho > 0.0);
    let simulated = Scenario::simulated(&config, config.seed).expect("simulated mission");
    let (accumulated, _) = paper_m_claims(&simulated, &config);
    assert!(accumulated["velocity"] < 10.0, "simulated: {accumulated:?}");
    let Some(data) = common::data_root() else {
        return;
    };
    let trajectory4 = Scenario::akit(&data, 4, &config, config.seed).expect("A-KIT 4");
    let (accumulated, _) = paper_m_claims(&trajectory4, &config);
    assert!(accumulated["velocity"] < 10.0, "A-KIT 4: {accumulated:?}");
    let trajectory13 = Scenario::akit(&data, 13, &config, config.seed).expect("A-KIT 13");
    let (accumulated, _) = paper_m_claims(&trajectory13, &config);
    assert!(accumulated["velocity"] > 10.0, "A-KIT 13: {accumulated:?}");
}

#[test]
fn oracle_monte_carlo_true_m_is_consistent_and_paper_rho_is_not() {
    let config = Config::default();
    for first_seed in [1000, 3000] {
        let report = monte_carlo(&config, 20, first_seed, None, &|| {}).expect("Monte Carlo");
        let aware = &report.variants[ORACLE_TRUE_M];
        println!(
            "seeds {first_seed}..: true M NEES {:.2} (band {:?}), {:.1} % of epochs in band, NIS {:.2} (band {:?})",
            aware.nees_average,
            aware.nees_band,
            aware.nees_epochs_in_band_percent,
            aware.nis_average,
            aware.nis_band
        );
        let inside = |x: f64, band: [f64; 2]| band[0] <= x && x <= band[1];
        assert!(
            inside(aware.nees_average, aware.nees_band),
            "seeds {first_seed}..: true-M NEES {} outside {:?}",
            aware.nees_average,
            aware.nees_band
        );
        // About 95 % of the epochs should fall in the band; 85 % leaves room for the
        // correlation between epochs of 20 runs.
        assert!(
            aware.nees_epochs_in_band_percent >= 85.0,
            "seeds {first_seed}..: {} % of epochs in band",
            aware.nees_epochs_in_band_percent
        );
        assert!(
            inside(aware.nis_average, aware.nis_band),
            "seeds {first_seed}..: true-M NIS {} outside {:?}",
            aware.nis_average,
            aware.nis_band
        );
        assert_eq!(aware.covariance_not_positive_definite, 0);
        let paper = &report.variants[ORACLE_SCALED];
        assert!(
            paper.covariance_not_positive_definite > 0,
            "seeds {first_seed}..: P stayed positive definite with rho = {}",
            config.filter.rho
        );
    }
}
