//! Exact cross-covariance when Phi != I, and with a second sensor inside the window.
//!
//! A constant-velocity target integrates a measured acceleration at 100 Hz (dt = 0.01 s,
//! acceleration noise variance q = 0.25 per sample). Every 100 predicts a velocity
//! "sensor" reports a velocity dead-reckoned over the last 50 samples of the *same*
//! accelerometer, so its error contains +dt * (sum of those 50 noise samples) while the
//! filter's error receives -G w from each: its noise shares 50 of the 100 process
//! steps of the interval.
//!
//! Three filters fuse it:
//! - exact: a `WindowedCrossCovariance` giving D_j = Cov(G_j w_j, v) = -dt q G_j for the
//!   50 shared steps; the runner transports them (Phi != I) and applies any update in
//!   between;
//! - recipe: the old advice "M is a fixed share of Q_acc" (here 50/100 of Q_acc H'),
//!   exact only for Phi = I;
//! - neglected: M = 0.
//!
//! Scenario 2 adds an independent position fix 25 steps before each velocity update,
//! i.e. inside the velocity sensor's window.
//!
//! `cargo run --release --example windowed_tracker`

use estim_core::nalgebra::{Matrix1, Matrix1x2, Matrix2, Matrix2x1, Vector1, Vector2};
use estim_core::window::StepWindow;
use estim_core::{
    CrossCovariance, CrossCovarianceContext, ExtendedKalmanFilter, FilterConfig, MeasurementModel,
    ProcessModel, Result, StateAndCovariance, WindowedCrossCovariance, Zero,
};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

const DT: f64 = 0.01;
const Q: f64 = 0.25;
const STEPS_PER_UPDATE: usize = 100;
const SHARED_STEPS: usize = 50;
const R_INDEPENDENT: f64 = 1e-4;
const R_POSITION: f64 = 1e-4;
const POSITION_FIX_AT: usize = 75;
const UPDATES: usize = 40;
const RUNS: usize = 400;

fn noise_input() -> Matrix2x1<f64> {
    Matrix2x1::new(DT * DT / 2.0, DT)
}

struct ConstantVelocity;

impl ProcessModel<f64, 2> for ConstantVelocity {
    type State = Vector2<f64>;
    type Input = f64; // measured acceleration
    fn propagate(&self, x: &Vector2<f64>, a: &f64, dt: f64) -> Result<Vector2<f64>> {
        Ok(Vector2::new(
            x[0] + dt * x[1] + dt * dt / 2.0 * a,
            x[1] + dt * a,
        ))
    }
    fn transition(&self, _: &Vector2<f64>, _: &f64, dt: f64) -> Result<Matrix2<f64>> {
        Ok(Matrix2::new(1.0, dt, 0.0, 1.0))
    }
    fn process_noise(&self, _: &Vector2<f64>, _: &f64, _: f64) -> Result<Matrix2<f64>> {
        Ok(noise_input() * noise_input().transpose() * Q)
    }
}

/// y = H x + v with H picking position (0) or velocity (1).
struct Sensor {
    component: usize,
    variance: f64,
}

impl MeasurementModel<f64, 2, 1> for Sensor {
    type State = Vector2<f64>;
    fn predict(&self, x: &Vector2<f64>) -> Result<Vector1<f64>> {
        Ok(Vector1::new(x[self.component]))
    }
    fn jacobian(&self, _: &Vector2<f64>) -> Result<Matrix1x2<f64>> {
        let mut h = Matrix1x2::zeros();
        h[self.component] = 1.0;
        Ok(h)
    }
    fn noise_covariance(&self, _: &Vector2<f64>) -> Result<Matrix1<f64>> {
        Ok(Matrix1::new(self.variance))
    }
}

fn velocity_sensor() -> Sensor {
    Sensor {
        component: 1,
        variance: SHARED_STEPS as f64 * DT * DT * Q + R_INDEPENDENT,
    }
}

/// The velocity noise is +dt * (sum of the last 50 acceleration noises) + e, the error
/// receives -G w_j: D_j = Cov(-G w_j, dt w_j) = -dt q G for each shared step.
struct SharedAcceleration;

impl WindowedCrossCovariance<f64, Vector2<f64>, f64, 2, 1> for SharedAcceleration {
    fn window_steps(&self) -> usize {
        SHARED_STEPS
    }
    fn step_cross_covariances(
        &self,
        window: &StepWindow<'_, f64, Vector2<f64>, f64, 2>,
        sink: &mut dyn FnMut(&Matrix2x1<f64>) -> Result<()>,
    ) -> Result<()> {
        for _ in window.iter() {
            sink(&(noise_input() * (-DT * Q)))?;
        }
        Ok(())
    }
}

/// The old recipe: M = -(50/100) Q_acc H' (right only for Phi = I).
struct ShareOfAccumulated;

impl CrossCovariance<f64, Vector2<f64>, 2, 1> for ShareOfAccumulated {
    fn cross_covariance(
        &self,
        context: &CrossCovarianceContext<'_, f64, Vector2<f64>, 2, 1>,
    ) -> Result<Matrix2x1<f64>> {
        let share = SHARED_STEPS as f64 / STEPS_PER_UPDATE as f64;
        Ok(-context.accumulated_process_noise * context.jacobian.transpose() * share)
    }
}

#[derive(Clone, Copy)]
enum Variant {
    Exact,
    Recipe,
    Neglected,
}

/// Time-averaged NEES over updates 10.. of one run, and M at the first update.
fn run(seed: u64, variant: Variant, position_fix: bool) -> Result<(f64, Matrix2x1<f64>)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut normal = || -> f64 { StandardNormal.sample(&mut rng) };
    let p0 = Matrix2::new(0.01, 0.0, 0.0, 0.01);
    let mut truth = Vector2::new(0.0, 1.0);
    let start = truth + Vector2::new(normal(), normal()) * 0.1;
    let config = FilterConfig::builder()
        .window_capacity(STEPS_PER_UPDATE)
        .build()?;
    let mut filter =
        ExtendedKalmanFilter::new(ConstantVelocity, StateAndCovariance::new(start, p0)?)
            .with_config(config);
    let (velocity, position) = (
        velocity_sensor(),
        Sensor {
            component: 0,
            variance: R_POSITION,
        },
    );
    let mut shared = [0.0; STEPS_PER_UPDATE];
    let (mut nees_sum, mut count, mut first_m) = (0.0, 0usize, Matrix2x1::zeros());
    for update in 0..UPDATES {
        for (step, slot) in shared.iter_mut().enumerate() {
            let w = normal() * Q.sqrt();
            let true_acc = 0.3 * (update as f64 * 0.1).sin();
            truth = ConstantVelocity.propagate(&truth, &true_acc, DT)?;
            // The nominal integrates the measured acceleration true_acc + w; with
            // true = estimate + error the error receives -G w (the sign convention of
            // `WindowedCrossCovariance`).
            filter.predict(&(true_acc + w), DT)?;
            *slot = w;
            if position_fix && step + 1 == POSITION_FIX_AT {
                let y = Vector1::new(truth[0] + normal() * R_POSITION.sqrt());
                filter.update(&position, &y, &Zero)?;
            }
        }
        let carried: f64 = shared[STEPS_PER_UPDATE - SHARED_STEPS..].iter().sum();
        // Dead-reckoned with the same accelerometer: its error is +dt * (sum of w).
        let v = DT * carried + normal() * R_INDEPENDENT.sqrt();
        let y = Vector1::new(truth[1] + v);
        let report = match variant {
            Variant::Exact => filter.update_windowed(&velocity, &y, &SharedAcceleration)?,
            Variant::Recipe => filter.update(&velocity, &y, &ShareOfAccumulated)?,
            Variant::Neglected => filter.update(&velocity, &y, &Zero)?,
        };
        if update == 0 {
            first_m = report.cross_covariance;
        }
        if update >= 10 {
            let e = truth - filter.estimate().state();
            nees_sum += estim_core::consistency::nees(&e, filter.estimate().covariance())?;
            count += 1;
        }
    }
    Ok((nees_sum / count as f64, first_m))
}

fn main() -> Result<()> {
    let band = estim_core::consistency::chi_square_band(2, RUNS * (UPDATES - 10), 0.95)?;
    println!(
        "{RUNS} runs x {UPDATES} velocity updates, {STEPS_PER_UPDATE} predicts each, the last {SHARED_STEPS} shared;"
    );
    println!(
        "time-averaged NEES over updates 10.. (2 states; 95 % band of the average if epochs were independent: {:.3}-{:.3})",
        band.lower, band.upper
    );
    for (title, fix) in [
        ("velocity sensor only", false),
        (
            "plus a position fix 25 steps before each velocity update",
            true,
        ),
    ] {
        println!("\n{title}:");
        for (name, variant) in [
            ("exact (windowed)", Variant::Exact),
            ("share of Q_acc", Variant::Recipe),
            ("M neglected", Variant::Neglected),
        ] {
            let mut total = 0.0;
            let mut m = Matrix2x1::zeros();
            for seed in 0..RUNS as u64 {
                let (nees, first) = run(seed, variant, fix)?;
                total += nees;
                m = first;
            }
            println!(
                "  {name:<17} M at the first update = [{:+.3e}, {:+.3e}]   NEES {:.3}",
                m[0],
                m[1],
                total / RUNS as f64
            );
        }
    }
    Ok(())
}
