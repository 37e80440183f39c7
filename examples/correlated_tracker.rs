//! A non-navigation use of the correlated update: a ground robot tracked in 2-D
//! from wheel odometry (the process input, 10 Hz) and a camera position fix (1 Hz).
//!
//! The camera image is taken 0.5 s before the fix is delivered; the vision module
//! carries its fix forward to the delivery time with the *same* odometry that
//! drives the filter's process model. The odometry error of the last 0.5 s is then
//! in both the process noise and the measurement noise:
//!
//! ```text
//! process:      x_k = x_{k-1} + sum_{10 steps} dt u_odo      G w = -sum_{10} dt e_j
//! measurement:  y_k = p(t_k - 0.5 s) + n + sum_{last 5} dt u_odo = x_k + n + sum_{last 5} dt e_j
//! M_k = Cov(G w, v) = -5 dt^2 sigma_odo^2 I = -Q_acc / 2
//! ```
//!
//! A filter that neglects M is inconsistent (its NEES leaves the chi-square band);
//! the M-aware filter, whose [`CrossCovariance`] derives M from the accumulated
//! process noise the runner hands it, is not.
//!
//! Run: `cargo run --release --example correlated_tracker`

use estim_core::consistency::{average_over_runs, chi_square_band, monte_carlo, nees};
use estim_core::nalgebra::{Matrix2, SMatrix, Vector2};
use estim_core::{
    CrossCovariance, CrossCovarianceContext, ExtendedKalmanFilter, FilterConfig, JointCheck,
    MeasurementModel, ProcessModel, Result, StateAndCovariance, Zero,
};
use rand_distr::{Distribution, StandardNormal};

const DT: f64 = 0.1;
const STEPS_PER_FIX: usize = 10;
const DELAY_STEPS: usize = 5;
const SIGMA_ODO: f64 = 0.3; // m/s per axis, per odometry sample
const SIGMA_CAMERA: f64 = 0.05; // m per axis
const FIXES: usize = 60;
const RUNS: usize = 200;

/// Dead reckoning from odometry velocity: x <- x + dt u_odo.
struct Odometry;

impl ProcessModel<f64, 2> for Odometry {
    type State = Vector2<f64>;
    type Input = Vector2<f64>;
    fn propagate(&self, x: &Vector2<f64>, u: &Vector2<f64>, dt: f64) -> Result<Vector2<f64>> {
        Ok(x + u * dt)
    }
    fn transition(&self, _: &Vector2<f64>, _: &Vector2<f64>, _: f64) -> Result<Matrix2<f64>> {
        Ok(Matrix2::identity())
    }
    fn process_noise(&self, _: &Vector2<f64>, _: &Vector2<f64>, dt: f64) -> Result<Matrix2<f64>> {
        Ok(Matrix2::identity() * (dt * SIGMA_ODO).powi(2))
    }
}

/// The camera fix carried forward with odometry: y = x + v.
struct CameraFix;

impl MeasurementModel<f64, 2, 2> for CameraFix {
    type State = Vector2<f64>;
    fn predict(&self, x: &Vector2<f64>) -> Result<Vector2<f64>> {
        Ok(*x)
    }
    fn jacobian(&self, _: &Vector2<f64>) -> Result<Matrix2<f64>> {
        Ok(Matrix2::identity())
    }
    fn noise_covariance(&self, _: &Vector2<f64>) -> Result<Matrix2<f64>> {
        let carried = DELAY_STEPS as f64 * (DT * SIGMA_ODO).powi(2);
        Ok(Matrix2::identity() * (SIGMA_CAMERA.powi(2) + carried))
    }
}

/// M = -(delay / interval) Q_acc: the share of the accumulated odometry noise that the
/// vision module reused, with opposite sign (process noise is -dt e, the carried
/// fix error is +dt e). A fixed share of Q_acc is exact here only because the
/// transition is the identity; with Phi != I or other updates in between use a
/// `WindowedCrossCovariance` (see `examples/windowed_tracker.rs`).
struct SharedOdometry;

impl CrossCovariance<f64, Vector2<f64>, 2, 2> for SharedOdometry {
    fn cross_covariance(
        &self,
        context: &CrossCovarianceContext<'_, f64, Vector2<f64>, 2, 2>,
    ) -> Result<SMatrix<f64, 2, 2>> {
        let share = DELAY_STEPS as f64 / STEPS_PER_FIX as f64;
        Ok(-context.accumulated_process_noise * share)
    }
}

/// One run: NEES of (M-aware, M-neglecting) at each fix.
fn run(rng: &mut rand_chacha::ChaCha8Rng) -> Result<(Vec<f64>, Vec<f64>)> {
    let mut normal = || -> f64 { StandardNormal.sample(&mut *rng) };
    let p0 = Matrix2::identity() * 0.25;
    let mut truth = Vector2::new(0.0, 0.0);
    let start = truth + Vector2::new(normal(), normal()) * 0.5;
    // The camera fix is a pure consistency question, so reject an invalid M loudly.
    let config = FilterConfig::builder()
        .joint_check(JointCheck::Reject)
        .build()?;
    let mut aware = ExtendedKalmanFilter::new(Odometry, StateAndCovariance::new(start, p0)?)
        .with_config(config.clone());
    let mut neglect = ExtendedKalmanFilter::new(Odometry, StateAndCovariance::new(start, p0)?)
        .with_config(config);
    let (mut nees_aware, mut nees_neglect) = (Vec::new(), Vec::new());
    let mut t = 0.0f64;
    for _ in 0..FIXES {
        let mut carried = Vector2::zeros();
        let mut image_position = truth;
        for step in 0..STEPS_PER_FIX {
            // The robot drives a wide circle, 1 m/s.
            let heading = 0.1 * t;
            let velocity = Vector2::new(heading.cos(), heading.sin());
            let odometry = velocity + Vector2::new(normal(), normal()) * SIGMA_ODO;
            if step == STEPS_PER_FIX - DELAY_STEPS {
                image_position = truth;
            }
            truth += velocity * DT;
            if step >= STEPS_PER_FIX - DELAY_STEPS {
                carried += odometry * DT;
            }
            aware.predict(&odometry, DT)?;
            neglect.predict(&odometry, DT)?;
            t += DT;
        }
        let camera = image_position + Vector2::new(normal(), normal()) * SIGMA_CAMERA;
        let fix = camera + carried;
        aware.update(&CameraFix, &fix, &SharedOdometry)?;
        neglect.update(&CameraFix, &fix, &Zero)?;
        nees_aware.push(nees(
            &(truth - aware.estimate().state()),
            aware.estimate().covariance(),
        )?);
        nees_neglect.push(nees(
            &(truth - neglect.estimate().state()),
            neglect.estimate().covariance(),
        )?);
    }
    Ok((nees_aware, nees_neglect))
}

fn main() -> anyhow::Result<()> {
    let runs = monte_carlo(RUNS, |_, rng| run(rng));
    let (mut aware, mut neglect) = (Vec::new(), Vec::new());
    for r in runs {
        let (a, n) = r?;
        aware.push(a);
        neglect.push(n);
    }
    let aware = average_over_runs(&aware)?;
    let neglect = average_over_runs(&neglect)?;
    let band = chi_square_band(2, RUNS, 0.95)?;
    println!("Robot tracked from odometry (10 Hz) and a delayed camera fix carried forward");
    println!("with the same odometry (1 Hz); {RUNS} seeded Monte Carlo runs of {FIXES} fixes.");
    println!(
        "95 % band of the average NEES (2 states, {RUNS} runs): [{:.3}, {:.3}]",
        band.lower, band.upper
    );
    println!();
    println!("{:>6}  {:>12}  {:>12}", "fix", "M-aware", "M-neglected");
    for k in [0, 4, 9, 19, 29, 39, 49, FIXES - 1] {
        println!("{:>6}  {:>12.3}  {:>12.3}", k + 1, aware[k], neglect[k]);
    }
    let inside = |s: &[f64]| s.iter().filter(|v| band.contains(**v)).count();
    let mean = |s: &[f64]| s.iter().sum::<f64>() / s.len() as f64;
    println!();
    println!(
        "time-mean NEES: M-aware {:.3}, M-neglected {:.3} (expected 2)",
        mean(&aware),
        mean(&neglect)
    );
    println!(
        "fixes with the average NEES inside the band: M-aware {}/{FIXES}, M-neglected {}/{FIXES}",
        inside(&aware),
        inside(&neglect)
    );
    Ok(())
}
