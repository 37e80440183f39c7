//! Error-state RTS smoothing of the 15-state INS/DVL filter with the nominal
//! trajectory re-injected (`estim smooth`): on the embedded simulated mission and,
//! when the data is present, on A-KIT trajectories 4 and 13.

use super::common;

use crate::study::{
    least_squares_measurements, run_filter, smooth_scenario, Config, CrossSource, Scenario,
    SmoothReport,
};

fn check_report(r: &SmoothReport) {
    let (f, s) = (&r.filtered, &r.smoothed);
    let n = r.time.len();
    assert!(n > 10, "{}: only {n} epochs", r.name);
    // The last epoch's smoothed estimate is the filtered one.
    assert!((f.position_error[n - 1] - s.position_error[n - 1]).abs() < 1e-9);
    // Smoothing conditions on more data: P_s <= P_f, so its position trace too.
    for k in 0..n {
        assert!(
            s.position_3sigma[k] <= f.position_3sigma[k] * (1.0 + 1e-9),
            "{} epoch {k}: smoothed 3-sigma {} above filtered {}",
            r.name,
            s.position_3sigma[k],
            f.position_3sigma[k]
        );
    }
    // Velocity is observed by the DVL, so the smoother (which also uses the later
    // updates) must beat the filter on it. Position is not observable from DVL aiding
    // alone (its initial error stays), so no gain is asserted there: measured, the
    // smoothed position RMSE is within 0.8 % of the filtered one (README).
    assert!(
        r.smoothed_summary.velocity_mps.rmse < r.filtered_summary.velocity_mps.rmse,
        "{}: smoothed velocity RMSE {} not below filtered {}",
        r.name,
        r.smoothed_summary.velocity_mps.rmse,
        r.filtered_summary.velocity_mps.rmse
    );
    assert!(r.smoothed_summary.mean_nees.is_finite());
}

#[test]
fn simulated_mission_smoother_beats_the_filter_and_records_it_exactly() {
    let config = Config::default();
    let scenario = Scenario::simulated(&config, config.seed).expect("scenario");
    let report =
        smooth_scenario(&scenario, &config, &CrossSource::Zero, config.seed).expect("smooth");
    check_report(&report);
    // The recorded filtered values are the runner's own (same seed, same run): at the
    // DVL epochs the filter reports the same position errors.
    let measurements = least_squares_measurements(&scenario, &config);
    let run = run_filter(
        "LS",
        &scenario,
        &config,
        &measurements,
        &CrossSource::Zero,
        config.seed,
    )
    .expect("filter");
    assert_eq!(run.rejected, 0);
    assert_eq!(report.time.len(), run.time.len());
    for k in 0..run.time.len() {
        assert!((report.time[k] - run.time[k]).abs() < 1e-9);
        assert!((report.filtered.position_error[k] - run.position_error[k]).abs() < 1e-9);
        assert!((report.filtered.nees[k] - run.nees[k]).abs() <= 1e-9 * run.nees[k].abs());
    }
}

#[test]
fn correlated_dvl_noise_is_smoothed_at_updates() {
    let config = Config::default();
    let scenario = Scenario::simulated(&config, config.seed).expect("scenario");
    let report = smooth_scenario(&scenario, &config, &CrossSource::Scaled(0.1), config.seed)
        .expect("the composed-step recording covers a one-step M over 100 predicts");
    check_report(&report);
}

#[test]
fn akit_trajectories_4_and_13() {
    let Some(root) = common::data_root() else {
        return;
    };
    let config = Config::default();
    for n in [4, 13] {
        let scenario = Scenario::akit(&root, n, &config, config.seed).expect("scenario");
        let report =
            smooth_scenario(&scenario, &config, &CrossSource::Zero, config.seed).expect("smooth");
        check_report(&report);
    }
}
