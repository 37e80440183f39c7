//! Sensor faults injected into the simulated mission (seeded) and what the
//! INS/DVL error-state EKF does with them: outliers rejected by the innovation gate,
//! recovery after a 60 s DVL outage, beam dropouts falling back to 3 beams or no
//! update, IMU gaps bridged, bad timestamps refused.
//!
//! `cargo test --release --test faults -- --nocapture` prints the measured figures.

use crate::study::{
    apply_faults, least_squares_velocities, run_filter, Config, CrossSource, DvlOutage,
    FaultConfig, FilterRun, ImuGap, MeasurementSet, Scenario,
};
use estim_core::nalgebra::Matrix3;
use statrs::distribution::{ChiSquared, ContinuousCDF};

const SEED: u64 = 11;

fn ls_set(scenario: &Scenario, config: &Config) -> MeasurementSet {
    MeasurementSet {
        velocities: least_squares_velocities(scenario, config),
        noise_covariance: Matrix3::identity() * config.dvl.ls_noise_std.powi(2),
    }
}

fn ls_run(scenario: &Scenario, config: &Config, name: &str) -> FilterRun {
    run_filter(
        name,
        scenario,
        config,
        &ls_set(scenario, config),
        &CrossSource::Zero,
        SEED,
    )
    .unwrap()
}

/// No NaN or infinity anywhere in the run; covariance diagonal positive.
fn assert_all_finite(run: &FilterRun) {
    let series: [(&str, &Vec<f64>); 8] = [
        ("time", &run.time),
        ("position_error", &run.position_error),
        ("velocity_error", &run.velocity_error),
        ("attitude_error_deg", &run.attitude_error_deg),
        ("nees", &run.nees),
        ("nis", &run.nis),
        ("joint_min_eigenvalue", &run.joint_min_eigenvalue),
        ("largest_valid_rho", &run.largest_valid_rho),
    ];
    for (name, s) in series {
        assert!(
            s.iter().all(|x| x.is_finite()),
            "{}: non-finite {name}",
            run.name
        );
    }
    assert!(
        run.covariance_diagonal
            .iter()
            .all(|d| d.iter().all(|x| x.is_finite() && *x > 0.0)),
        "{}: covariance diagonal not finite and positive",
        run.name
    );
    assert!(
        run.north_east.iter().flatten().all(|x| x.is_finite()),
        "{}: non-finite north/east",
        run.name
    );
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}

#[test]
fn default_fault_config_changes_nothing() {
    let config = Config::default();
    let clean = Scenario::simulated(&config, SEED).unwrap();
    let mut copy = clean.clone();
    let log = apply_faults(&mut copy, &FaultConfig::default(), SEED).unwrap();
    assert_eq!(log, Default::default());
    assert_eq!(copy.dvl, clean.dvl);
    assert_eq!(copy.imu, clean.imu);
}

#[test]
fn beam_outliers_are_rejected_by_the_gate() {
    // One beam off by 0.5-2 m/s moves the least-squares velocity by at least
    // 0.5 * 0.13 m/s on the vertical axis and 0.5 * 0.52 m/s on each horizontal
    // axis (20 deg Janus geometry), against an innovation std of about 0.02 m/s: NIS
    // in the hundreds, far above the 0.9999 gate (21.1 for 3 dof). A consistent
    // filter rejects a fraction 1e-4 of good epochs (0.04 expected in 400), so the
    // rejected epochs are expected to be exactly the outlier epochs.
    let config = Config::default();
    let mut scenario = Scenario::simulated(&config, SEED).unwrap();
    let faults = FaultConfig {
        beam_outlier_probability: 0.05,
        beam_dropout_probability: 0.02,
        ..FaultConfig::default()
    };
    let log = apply_faults(&mut scenario, &faults, SEED).unwrap();
    let set = ls_set(&scenario, &config);
    let run = run_filter(
        "outliers",
        &scenario,
        &config,
        &set,
        &CrossSource::Zero,
        SEED,
    )
    .unwrap();
    assert_all_finite(&run);
    // Independent threshold: chi-square(3) quantile from statrs.
    let threshold = ChiSquared::new(3.0)
        .unwrap()
        .inverse_cdf(config.filter.gate_probability);
    let attempted: Vec<usize> = (0..set.velocities.len())
        .filter(|&i| set.velocities[i].is_some())
        .collect();
    assert_eq!(attempted.len(), run.nis.len());
    let rejected: Vec<usize> = attempted
        .iter()
        .zip(&run.nis)
        .filter(|(_, nis)| **nis > threshold)
        .map(|(i, _)| *i)
        .collect();
    println!(
        "outliers injected {} (epochs {:?}), beams dropped {}, updates accepted {} rejected {}",
        log.outliers, log.outlier_epochs, log.beams_dropped, run.accepted, run.rejected
    );
    assert!(
        log.outliers >= 10,
        "too few outliers to test: {}",
        log.outliers
    );
    assert_eq!(run.rejected, rejected.len());
    assert_eq!(rejected, log.outlier_epochs);
    let smallest_outlier_nis = attempted
        .iter()
        .zip(&run.nis)
        .filter(|(i, _)| log.outlier_epochs.contains(i))
        .map(|(_, n)| *n)
        .fold(f64::INFINITY, f64::min);
    println!(
        "smallest NIS of an outlier epoch {smallest_outlier_nis:.1} (threshold {threshold:.2})"
    );

    // The same faults without the gate: the outliers reach the state.
    let clean = Scenario::simulated(&config, SEED).unwrap();
    let base = ls_run(&clean, &config, "clean");
    let mut ungated_config = config.clone();
    ungated_config.filter.gate_probability = 0.0;
    let ungated = run_filter(
        "ungated",
        &scenario,
        &ungated_config,
        &set,
        &CrossSource::Zero,
        SEED,
    )
    .unwrap();
    let (v_base, v_gated, v_ungated) = (
        rms(&base.velocity_error),
        rms(&run.velocity_error),
        rms(&ungated.velocity_error),
    );
    println!(
        "velocity error RMS: fault-free {v_base:.4}, outliers gated {v_gated:.4}, ungated {v_ungated:.4} m/s"
    );
    // Gated: within 10 % of the fault-free run (17 missed updates out of 400 and 20
    // 3-beam solutions); ungated: at least twice as large.
    assert!(v_gated < 1.1 * v_base, "{v_gated} vs {v_base}");
    assert!(v_ungated > 2.0 * v_base, "{v_ungated} vs {v_base}");
}

#[test]
fn position_recovers_after_a_60_s_dvl_outage() {
    let config = Config::default();
    let clean = Scenario::simulated(&config, SEED).unwrap();
    let base = ls_run(&clean, &config, "clean");
    let (start, duration) = (150.0, 60.0);
    let mut scenario = clean.clone();
    let faults = FaultConfig {
        dvl_outages: vec![DvlOutage {
            start_s: start,
            duration_s: duration,
        }],
        ..FaultConfig::default()
    };
    let log = apply_faults(&mut scenario, &faults, SEED).unwrap();
    assert_eq!(log.epochs_in_outage, 60);
    let run = ls_run(&scenario, &config, "outage");
    assert_all_finite(&run);
    assert_eq!(run.accepted + 60, base.accepted);
    let end = start + duration;
    let index = |t: f64| run.time.iter().position(|x| *x >= t).unwrap();
    let (i_start, i_end) = (index(start), index(end));
    // During the outage the INS runs free: the position std grows and the error drifts.
    let pos_var = |r: &FilterRun, i: usize| r.covariance_diagonal[i][..3].iter().sum::<f64>();
    let drift = run.position_error[i_end - 1] - base.position_error[i_end - 1];
    println!(
        "outage {start}-{end} s: position error at its end {:.3} m (fault-free {:.3}), position std {:.3} m (fault-free {:.3})",
        run.position_error[i_end - 1],
        base.position_error[i_end - 1],
        pos_var(&run, i_end - 1).sqrt(),
        pos_var(&base, i_end - 1).sqrt()
    );
    assert!(pos_var(&run, i_end - 1) > 2.0 * pos_var(&base, i_end - 1));
    assert!(drift > 0.1, "the outage had no visible effect: {drift}");
    // Recovery. Velocity is observed: 20 s after the outage its error is back within
    // 0.005 m/s of the fault-free run (measured difference below 0.001 m/s).
    // Position is not observed by a velocity aid, so the drift accumulated in the
    // outage cannot be removed, only stopped: from 30 s after the outage the position
    // error stays within 0.5 m of the fault-free run (measured: at most about 0.3 m;
    // the bound is about twice the excess that remains).
    let i_rec_v = index(end + 20.0);
    let worst_v = (i_rec_v..run.time.len())
        .map(|i| (run.velocity_error[i] - base.velocity_error[i]).abs())
        .fold(0.0, f64::max);
    let i_rec_p = index(end + 30.0);
    let worst_p = (i_rec_p..run.time.len())
        .map(|i| run.position_error[i] - base.position_error[i])
        .fold(f64::NEG_INFINITY, f64::max);
    println!(
        "after the outage: largest |velocity error - fault-free| from +20 s {worst_v:.5} m/s; largest position excess from +30 s {worst_p:.3} m"
    );
    assert!(worst_v < 0.005, "{worst_v}");
    assert!(worst_p < 0.5, "{worst_p}");
    // Before the outage both runs are the same run.
    assert_eq!(
        run.position_error[..i_start],
        base.position_error[..i_start]
    );
}

#[test]
fn beam_dropouts_fall_back_to_three_beams_or_no_update() {
    let config = Config::default();
    let mut scenario = Scenario::simulated(&config, SEED).unwrap();
    let faults = FaultConfig {
        beam_dropout_probability: 0.3,
        ..FaultConfig::default()
    };
    let log = apply_faults(&mut scenario, &faults, SEED).unwrap();
    let set = ls_set(&scenario, &config);
    let none = set.velocities.iter().filter(|v| v.is_none()).count();
    // Independent count of epochs with fewer than 3 beams.
    let short = scenario
        .dvl
        .iter()
        .filter(|d| d.beams.iter().filter(|b| b.is_finite()).count() < 3)
        .count();
    assert_eq!(none, short);
    assert_eq!(none, log.epochs_without_velocity);
    let run = run_filter(
        "dropouts",
        &scenario,
        &config,
        &set,
        &CrossSource::Zero,
        SEED,
    )
    .unwrap();
    assert_all_finite(&run);
    assert_eq!(run.accepted + run.rejected, scenario.dvl.len() - none);
    let base = ls_run(
        &Scenario::simulated(&config, SEED).unwrap(),
        &config,
        "clean",
    );
    println!(
        "dropouts: {} beams dropped, {} epochs without velocity, rejected {}, position error RMS {:.3} m (fault-free {:.3})",
        log.beams_dropped,
        none,
        run.rejected,
        rms(&run.position_error),
        rms(&base.position_error)
    );
    assert!(log.beams_dropped > 300);
    // 30 % beam dropout leaves about 35 % of epochs without velocity; the gaps are
    // short (seconds), so the position error stays within 1 m RMS of fault-free.
    assert!(rms(&run.position_error) < rms(&base.position_error) + 1.0);
}

#[test]
fn imu_gaps_are_bridged_and_bad_timestamps_refused() {
    let config = Config::default();
    let clean = Scenario::simulated(&config, SEED).unwrap();
    let base = ls_run(&clean, &config, "clean");
    let mut scenario = clean.clone();
    let faults = FaultConfig {
        imu_gap_rate_per_s: 0.1,
        imu_gap_samples: 10,
        imu_gaps: vec![ImuGap {
            start_s: 100.0,
            samples: 50,
        }],
        ..FaultConfig::default()
    };
    let log = apply_faults(&mut scenario, &faults, SEED).unwrap();
    assert_eq!(
        scenario.imu.len() + log.imu_samples_removed,
        clean.imu.len()
    );
    assert!(log.imu_gaps >= 20, "{log:?}");
    let run = ls_run(&scenario, &config, "gaps");
    assert_all_finite(&run);
    // Same number of epochs and the same time axis as the fault-free run: dt came
    // from the timestamps (a run with a silent fixed dt would end ~4.5 s early).
    assert_eq!(run.time, base.time);
    let (p, p0) = (rms(&run.position_error), rms(&base.position_error));
    let (v, v0) = (rms(&run.velocity_error), rms(&base.velocity_error));
    println!(
        "IMU gaps: {} gaps, {} samples removed; position error RMS {p:.3} m (fault-free {p0:.3}), velocity {v:.4} m/s ({v0:.4})",
        log.imu_gaps, log.imu_samples_removed
    );
    // Holding a sample for 0.1-0.5 s during smooth manoeuvres costs little; bound:
    // 20 % on both RMS errors.
    assert!(p < 1.2 * p0 && v < 1.2 * v0);

    // Duplicate and backward timestamps are typed errors naming the sample.
    let mut dup = clean.clone();
    dup.imu[500].time = dup.imu[499].time;
    let e = ls_run_err(&dup, &config);
    assert!(
        e.contains("IMU sample 500") && e.contains("duplicate"),
        "{e}"
    );
    let mut back = clean.clone();
    back.imu[700].time -= 0.05;
    let e = ls_run_err(&back, &config);
    assert!(
        e.contains("IMU sample 700") && e.contains("backward"),
        "{e}"
    );
    let mut nan = clean.clone();
    nan.imu[3].time = f64::NAN;
    let e = ls_run_err(&nan, &config);
    assert!(
        e.contains("IMU sample 3") && e.contains("non-finite"),
        "{e}"
    );
}

fn ls_run_err(scenario: &Scenario, config: &Config) -> String {
    run_filter(
        "bad",
        scenario,
        config,
        &ls_set(scenario, config),
        &CrossSource::Zero,
        SEED,
    )
    .unwrap_err()
    .to_string()
}

#[test]
fn injection_is_reproducible_from_the_seed() {
    let config = Config::default();
    let clean = Scenario::simulated(&config, SEED).unwrap();
    let faults = FaultConfig::from_toml(
        "beam_dropout_probability = 0.05\nbeam_outlier_probability = 0.05\n\
         imu_gap_rate_per_s = 0.05\n[[dvl_outages]]\nstart_s = 50.0\nduration_s = 20.0\n",
        std::path::Path::new("faults.toml"),
    )
    .unwrap();
    let inject = |seed| {
        let mut s = clean.clone();
        let log = apply_faults(&mut s, &faults, seed).unwrap();
        (s, log)
    };
    let (a, log_a) = inject(5);
    let (b, log_b) = inject(5);
    let (c, log_c) = inject(6);
    assert_eq!(log_a, log_b);
    // NaN != NaN: compare the beams bit for bit.
    let bits = |s: &Scenario| -> Vec<u64> {
        s.dvl
            .iter()
            .flat_map(|d| d.beams.iter().map(|b| b.to_bits()))
            .collect()
    };
    assert_eq!(bits(&a), bits(&b));
    assert_eq!(a.imu, b.imu);
    assert_ne!(log_a, log_c);
    assert_eq!(log_a.epochs_in_outage, 20);
    assert_eq!(log_c.epochs_in_outage, 20);
    // Every outlier sits on an epoch outside the outage, with at least 3 beams.
    for &i in &log_a.outlier_epochs {
        assert!(a.dvl[i].beams.iter().filter(|b| b.is_finite()).count() >= 3);
    }
    let _ = c;
}

#[test]
fn non_finite_inputs_are_typed_errors() {
    // Never a NaN passed on: a non-finite IMU sample or velocity measurement stops
    // the run with a typed error. (Non-finite beams never get this far: the least
    // squares treats them as missing beams.)
    let config = Config::default();
    let clean = Scenario::simulated(&config, SEED).unwrap();
    let mut bad_imu = clean.clone();
    bad_imu.imu[250].specific_force.x = f64::NAN;
    let e = ls_run_err(&bad_imu, &config);
    assert!(e.contains("non-finite"), "{e}");
    for bad in [f64::NAN, f64::INFINITY] {
        let mut set = ls_set(&clean, &config);
        set.velocities[5] = Some(estim_core::nalgebra::Vector3::new(bad, 0.0, 0.0));
        let e = run_filter("bad", &clean, &config, &set, &CrossSource::Zero, SEED)
            .unwrap_err()
            .to_string();
        assert!(e.contains("non-finite value in measurement"), "{e}");
    }
    let mut beams = clean.clone();
    beams.dvl[5].beams[2] = f64::INFINITY;
    let set = ls_set(&beams, &config);
    assert!(set.velocities[5].is_some(), "3-beam solution expected");
    let run = run_filter("inf beam", &beams, &config, &set, &CrossSource::Zero, SEED).unwrap();
    assert_all_finite(&run);
}
