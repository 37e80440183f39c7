//! Long missions through the INS/DVL error-state EKF with each cross-covariance
//! model: the error covariance P must stay symmetric and positive definite (its
//! Cholesky factorisation succeeds) after every predict and every update, and no
//! value may be non-finite.
//!
//! CI runs a 1-hour mission (360,000 IMU steps at 100 Hz, 3,600 DVL updates). The
//! 10-hour mission (3.6 M IMU steps, 36,000 DVL updates) is an ignored test:
//!
//! ```sh
//! cargo test --release --test long_mission -- --ignored --nocapture
//! ```
//!
//! Cross-covariance models: `Zero` (M neglected), `ScaledCorrelation { rho: 0.42 }`
//! (the paper's heuristic; NOT a valid joint covariance for the 15-state filter,
//! which needs rho <= 1/sqrt(15 * 3) = 0.149, see estim-core), and `Fixed(M)` with an
//! M that is valid: half the largest valid scaled correlation on the accumulated
//! process noise of the first DVL interval, checked at every update by the core's
//! joint-covariance report.

use std::time::Instant;

use crate::study::{
    least_squares_velocities, run_filter_with_observer, Config, CrossMatrix, CrossSource,
    FilterRun, MeasurementSet, Scenario,
};
use estim_core::nalgebra::{Matrix3, SMatrix};
use estim_core::{ErrorStateKalmanFilter, Observer, PredictEvent, ScaledCorrelation, UpdateEvent};
use estim_ins::{InsErrorModel, InsState, ERROR_STATES};

type Covariance = SMatrix<f64, ERROR_STATES, ERROR_STATES>;

/// Checks P after every event; records the first failure instead of stopping.
#[derive(Debug)]
struct PositiveDefinite {
    checks: usize,
    cholesky_failures: usize,
    non_finite: usize,
    /// Largest |P_ij - P_ji| / sqrt(P_ii P_jj).
    max_asymmetry: f64,
    /// Smallest eigenvalue of P at the DVL epochs (before and after each update).
    min_eigenvalue: f64,
    /// Smallest eigenvalue of the correlation matrix D^-1/2 P D^-1/2 at the DVL epochs.
    min_correlation_eigenvalue: f64,
    first_failure: Option<String>,
}

impl Default for PositiveDefinite {
    fn default() -> Self {
        Self {
            checks: 0,
            cholesky_failures: 0,
            non_finite: 0,
            max_asymmetry: 0.0,
            min_eigenvalue: f64::INFINITY,
            min_correlation_eigenvalue: f64::INFINITY,
            first_failure: None,
        }
    }
}

impl PositiveDefinite {
    fn check(&mut self, p: &Covariance, what: &str, eigen: bool) {
        self.checks += 1;
        if !p.iter().all(|x| x.is_finite()) {
            self.non_finite += 1;
            self.first_failure
                .get_or_insert_with(|| format!("non-finite P after {what} #{}", self.checks));
            return;
        }
        for i in 0..ERROR_STATES {
            for j in 0..i {
                let scale = (p[(i, i)] * p[(j, j)]).abs().sqrt();
                let a = (p[(i, j)] - p[(j, i)]).abs() / scale.max(f64::MIN_POSITIVE);
                self.max_asymmetry = self.max_asymmetry.max(a);
            }
        }
        if p.cholesky().is_none() {
            self.cholesky_failures += 1;
            self.first_failure
                .get_or_insert_with(|| format!("Cholesky failed after {what} #{}", self.checks));
        }
        if eigen {
            let e = p.symmetric_eigenvalues().min();
            self.min_eigenvalue = self.min_eigenvalue.min(e);
            let d = p.diagonal().map(|x| 1.0 / x.sqrt());
            let corr = Covariance::from_fn(|i, j| p[(i, j)] * d[i] * d[j]);
            self.min_correlation_eigenvalue = self
                .min_correlation_eigenvalue
                .min(corr.symmetric_eigenvalues().min());
        }
    }
}

impl Observer<f64, InsState, ERROR_STATES> for PositiveDefinite {
    fn on_predict(
        &mut self,
        event: &PredictEvent<'_, f64, InsState, ERROR_STATES>,
    ) -> estim_core::Result<()> {
        // The eigenvalues are computed on the prior of each DVL epoch (every 100th
        // predict), Cholesky and symmetry on every predict.
        self.check(
            event.covariance,
            "predict",
            event.propagations_since_update.is_multiple_of(100),
        );
        Ok(())
    }
    fn on_update(
        &mut self,
        event: &UpdateEvent<'_, f64, InsState, ERROR_STATES>,
    ) -> estim_core::Result<()> {
        self.check(event.covariance, "update", true);
        Ok(())
    }
    fn on_rejected(
        &mut self,
        event: &UpdateEvent<'_, f64, InsState, ERROR_STATES>,
    ) -> estim_core::Result<()> {
        self.check(event.covariance, "rejected update", true);
        Ok(())
    }
}

/// A valid fixed M: half the largest valid scaled correlation on the process noise
/// accumulated over the first DVL interval (from the truth's start).
fn valid_fixed_m(scenario: &Scenario, config: &Config, r: &Matrix3<f64>) -> CrossMatrix {
    let process = InsErrorModel::new(scenario.imu_spec);
    let p0 = crate::study::initial_covariance(config, &scenario.imu_spec);
    let mut filter = ErrorStateKalmanFilter::new(process, scenario.truth[0], p0).unwrap();
    let steps = scenario.dvl[0].imu_index;
    for sample in &scenario.imu[..steps] {
        filter.predict(sample, scenario.imu_dt).unwrap();
    }
    let q = *filter.accumulated_process_noise();
    let rho = 0.5 * ScaledCorrelation::largest_valid_rho(&q, r).unwrap();
    let sq = q.diagonal().map(f64::sqrt);
    let sr = r.diagonal().map(f64::sqrt);
    sq * sr.transpose() * rho
}

struct ModelResult {
    name: &'static str,
    pd: PositiveDefinite,
    /// The run, or the typed error that stopped it.
    run: Result<FilterRun, String>,
}

fn run_mission(hours: f64) -> Vec<ModelResult> {
    let mut config = Config::default();
    config.mission.duration_s = hours * 3600.0;
    let t = Instant::now();
    let scenario = Scenario::simulated(&config, config.seed).unwrap();
    println!(
        "{hours} h mission: {} IMU steps, {} DVL epochs, generated in {:.1} s",
        scenario.imu.len(),
        scenario.dvl.len(),
        t.elapsed().as_secs_f64()
    );
    let r = Matrix3::identity() * config.dvl.ls_noise_std.powi(2);
    let set = MeasurementSet {
        velocities: least_squares_velocities(&scenario, &config),
        noise_covariance: r,
    };
    let m = valid_fixed_m(&scenario, &config, &r);
    let models: [(&'static str, CrossSource); 3] = [
        ("Zero", CrossSource::Zero),
        ("ScaledCorrelation{0.42}", CrossSource::Scaled(0.42)),
        (
            "Fixed(valid M)",
            CrossSource::PerEpoch(vec![m; scenario.dvl.len()]),
        ),
    ];
    models
        .into_iter()
        .map(|(name, cross)| {
            let mut pd = PositiveDefinite::default();
            let t = Instant::now();
            let run = run_filter_with_observer(
                name,
                &scenario,
                &config,
                &set,
                &cross,
                config.seed,
                &mut pd,
            )
            .map_err(|e| e.to_string());
            let seconds = t.elapsed().as_secs_f64();
            println!(
                "{name:<24} run {seconds:6.1} s; {} checks, Cholesky failures {}, non-finite {}, \
                 max asymmetry {:.1e}, min eigenvalue of P {:.3e}, of its correlation matrix {:.3e}",
                pd.checks,
                pd.cholesky_failures,
                pd.non_finite,
                pd.max_asymmetry,
                pd.min_eigenvalue,
                pd.min_correlation_eigenvalue,
            );
            match &run {
                Ok(run) => println!(
                    "{:<24} updates {} accepted / {} gated; joint covariance min eigenvalue {:.3e}; \
                     final position error {:.1} m",
                    "",
                    run.accepted,
                    run.rejected,
                    run.joint_min_eigenvalue
                        .iter()
                        .copied()
                        .fold(f64::INFINITY, f64::min),
                    run.position_error.last().copied().unwrap_or(f64::NAN),
                ),
                Err(e) => println!(
                    "{:<24} stopped by a typed error after {} checks (about t = {:.0} s): {e}",
                    "",
                    pd.checks,
                    pd.checks as f64 / 101.0
                ),
            }
            ModelResult { name, pd, run }
        })
        .collect()
}

/// Zero and the valid fixed M: P symmetric and positive definite at every step, no
/// non-finite value. The paper's rho = 0.42 (an invalid joint covariance at every
/// update): P may lose positive definiteness; the pipeline must then report it
/// (`FilterRun::covariance_not_positive_definite`) and produce no non-finite P.
fn assert_healthy(results: &[ModelResult], imu_steps: usize) {
    for r in results {
        let pd = &r.pd;
        assert_eq!(pd.non_finite, 0, "{}: non-finite P", r.name);
        if r.name.starts_with("Scaled") {
            match &r.run {
                Err(e) => {
                    assert!(e.contains("not positive definite"), "{}: {e}", r.name);
                    continue;
                }
                // The pipeline runs the paper's heuristic as the paper did and reports
                // what it does: every update's joint covariance invalid, and the epochs
                // at which P lost positive definiteness (their NEES excluded, as NaN).
                Ok(run) if pd.first_failure.is_some() => {
                    let worst = run
                        .joint_min_eigenvalue
                        .iter()
                        .copied()
                        .fold(f64::INFINITY, f64::min);
                    assert!(
                        worst < 0.0,
                        "{}: P lost definiteness with a valid joint covariance",
                        r.name
                    );
                    assert!(
                        run.covariance_not_positive_definite > 0,
                        "{}: loss of definiteness not reported",
                        r.name
                    );
                    continue;
                }
                Ok(_) => {}
            }
        }
        // The core symmetrises after each update; the predict keeps symmetry to
        // rounding (measured below 1.5e-14). Not asserted for an indefinite P above:
        // its asymmetry relative to sqrt(P_ii P_jj) is not a rounding measure once
        // the "correlations" reach 100 (measured 2.5e-12 with rho = 0.42, 10 hours).
        assert!(pd.max_asymmetry < 1e-12, "{}: {}", r.name, pd.max_asymmetry);
        let run = r.run.as_ref().unwrap_or_else(|e| panic!("{}: {e}", r.name));
        assert!(
            pd.first_failure.is_none(),
            "{}: {:?}",
            r.name,
            pd.first_failure
        );
        // One check per predict and per update attempt.
        assert_eq!(pd.checks, imu_steps + run.nis.len(), "{}", r.name);
        assert!(pd.min_eigenvalue > 0.0, "{}: {}", r.name, pd.min_eigenvalue);
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        assert!(
            finite(&run.position_error)
                && finite(&run.velocity_error)
                && finite(&run.nees)
                && finite(&run.nis)
                && finite(&run.joint_min_eigenvalue),
            "{}: non-finite value in the run",
            r.name
        );
    }
    // The fixed M is valid at every update (joint covariance PSD).
    let fixed = results
        .iter()
        .find(|r| r.name.starts_with("Fixed"))
        .unwrap();
    let worst = fixed
        .run
        .as_ref()
        .unwrap()
        .joint_min_eigenvalue
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min);
    assert!(worst >= 0.0, "fixed M invalid at some update: {worst}");
}

#[test]
fn one_hour_mission_keeps_p_positive_definite() {
    let results = run_mission(1.0);
    assert_healthy(&results, 360_000);
}

#[test]
#[ignore = "10-hour mission: about 75 s to generate and 25 s per model in release; run with --ignored"]
fn ten_hour_mission_keeps_p_positive_definite() {
    let results = run_mission(10.0);
    assert_healthy(&results, 3_600_000);
    assert_eq!(results[0].run.as_ref().unwrap().time.len(), 36_000);
}
