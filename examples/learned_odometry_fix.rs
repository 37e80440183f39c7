//! A new learned sensor in 17 lines of user code beyond its model, as rustfmt lays
//! them out (its `InputNoise` 11; once per run, `window_capacity` and building the
//! `LearnedCrossCovariance` 2; per fix 4: set the fix, measure, the `LearnedSensor`
//! with a `LinearObservation`, `update_windowed`): a delayed position fix dead-reckoned
//! with the same odometry that drives the filter, its cross-covariance derived by the
//! generic `LearnedCrossCovariance` (no hand derivation).
//!
//! A robot on a plane integrates measured velocity (odometry) at 10 Hz. Once a second a
//! position fix arrives, taken `WINDOW` = 6 odometry samples (0.6 s) earlier. The
//! "learned" sensor carries the fix forward to now with those same 6 odometry samples
//! (its input window is the odometry since the fix was taken, plus the fix itself). So
//! its error holds +dt (sum of those samples' noise), while the filter's error received
//! -dt times the same noise: process and measurement noise are correlated,
//! M = Cov(G w, v) != 0.
//!
//! The filter records its steps (`window_capacity`), the sensor reads that window,
//! `LearnedCrossCovariance` turns the model's Jacobian-vector products and the process's
//! [`InputNoise`] into M, and `update_windowed` fuses it. A seeded Monte Carlo
//! (estim-core's `monte_carlo`, 200 runs) prints the NEES with M and with M neglected.
//!
//! `cargo run --release --example learned_odometry_fix`
//! (its `#[test]`s run with `cargo test --workspace --release --example learned_odometry_fix`,
//! and with every `cargo test --workspace`).

use estim_core::consistency::rand_chacha::ChaCha8Rng;
use estim_core::consistency::{
    average_over_runs, chi_square_band, monte_carlo, nees, ChiSquareBand,
};
use estim_core::nalgebra::{DMatrix, Matrix2, Vector2};
use estim_core::{
    ExtendedKalmanFilter, FilterConfig, InputSpec, LearnedMeasurement, ProcessModel, Result,
    StateAndCovariance, Zero,
};
use estim_learned::{InputNoise, LearnedCrossCovariance, LearnedSensor, LinearObservation};
use rand_distr::{Distribution, StandardNormal};

/// Odometry period [s].
const DT: f64 = 0.1;
/// Odometry velocity noise variance per sample, per axis [m^2/s^2].
const ODOMETRY_VARIANCE: f64 = 0.09;
/// Position-fix noise variance per axis [m^2].
const FIX_VARIANCE: f64 = 0.0025;
/// Odometry samples between two fixes (1 Hz).
const STEPS_PER_FIX: usize = 10;
/// Odometry samples since the fix was taken: the sensor's input window.
const WINDOW: usize = 6;
/// Fixes per run.
const FIXES: usize = 40;
/// Monte Carlo runs (seeded).
pub const RUNS: usize = 200;

// ------------------------------------------------------------------------------------
// The models: the process (odometry integration) and the sensor (dead-reckoned fix).
// ------------------------------------------------------------------------------------

/// p <- p + dt u, u the measured velocity.
#[derive(Debug, Clone, Copy)]
struct Odometry;

impl ProcessModel<f64, 2> for Odometry {
    type State = Vector2<f64>;
    type Input = Vector2<f64>;
    fn propagate(&self, p: &Vector2<f64>, u: &Vector2<f64>, dt: f64) -> Result<Vector2<f64>> {
        Ok(p + u * dt)
    }
    fn transition(&self, _: &Vector2<f64>, _: &Vector2<f64>, _: f64) -> Result<Matrix2<f64>> {
        Ok(Matrix2::identity())
    }
    fn process_noise(&self, _: &Vector2<f64>, _: &Vector2<f64>, dt: f64) -> Result<Matrix2<f64>> {
        Ok(Matrix2::identity() * (dt * dt * ODOMETRY_VARIANCE))
    }
}

/// The sensor's model: the fix (2 x 1) plus dt times the sum of the odometry window
/// (2 x WINDOW). Linear, so its Jacobian-vector products are exact.
struct DeadReckonedFix {
    specs: Vec<InputSpec>,
}

impl DeadReckonedFix {
    fn new() -> Self {
        let spec = |name: &str, window| InputSpec {
            name: name.into(),
            channels: 2,
            window,
            sample_rate_hz: 1.0 / DT,
        };
        Self {
            specs: vec![spec("odometry", WINDOW), spec("fix", 1)],
        }
    }
}

/// fix + dt * (sum of the odometry columns), for inputs or directions alike.
fn carry_forward(inputs: &[DMatrix<f64>]) -> Result<Vector2<f64>> {
    match inputs {
        [odometry, fix] if odometry.shape() == (2, WINDOW) && fix.shape() == (2, 1) => {
            Ok(Vector2::new(fix[0], fix[1]) + odometry.column_sum().fixed_rows::<2>(0) * DT)
        }
        _ => Err(estim_core::Error::Model(format!(
            "dead-reckoned fix: expected odometry 2 x {WINDOW} and fix 2 x 1, got {:?}",
            inputs.iter().map(DMatrix::shape).collect::<Vec<_>>()
        ))),
    }
}

impl LearnedMeasurement<f64, 2> for DeadReckonedFix {
    fn input_specs(&self) -> &[InputSpec] {
        &self.specs
    }
    fn measure(&self, inputs: &[DMatrix<f64>]) -> Result<Vector2<f64>> {
        carry_forward(inputs)
    }
    /// R = fix noise + the window's odometry noise, dt^2 sum of WINDOW variances.
    fn noise_covariance(&self) -> Matrix2<f64> {
        Matrix2::identity() * (FIX_VARIANCE + WINDOW as f64 * DT * DT * ODOMETRY_VARIANCE)
    }
    /// Jacobian-vector products: the model is linear, so each is the model applied to
    /// the direction (one odometry and one fix matrix per direction).
    fn sensitivity(
        &self,
        _: &[DMatrix<f64>],
        directions: &[DMatrix<f64>],
        products: &mut [Vector2<f64>],
    ) -> Result<bool> {
        for (d, product) in directions.chunks_exact(2).zip(products) {
            *product = carry_forward(d)?;
        }
        Ok(true)
    }
}

// ------------------------------------------------------------------------------------
// The user's code for the new sensor, beyond its model: its `InputNoise` (11 lines)
// and, per fix, `fuse` (4 lines; the `with_m` branch is the demo's comparison), plus
// two lines once per run in `run` (`window_capacity`, `LearnedCrossCovariance::new`).
// ------------------------------------------------------------------------------------

/// How an odometry sample's noise n enters the error (true = estimate + error; the
/// estimate integrates u + n): A = -dt I, Cov(n) = ODOMETRY_VARIANCE I.
impl InputNoise<f64, 2, 2> for Odometry {
    fn input_channels(&self, u: &Vector2<f64>) -> Vector2<f64> {
        *u
    }
    fn input_noise_jacobian(&self, _: &Vector2<f64>, _: &Vector2<f64>, dt: f64) -> Matrix2<f64> {
        -Matrix2::identity() * dt
    }
    fn input_noise_covariance(&self, _dt: f64) -> Matrix2<f64> {
        Matrix2::identity() * ODOMETRY_VARIANCE
    }
}

/// One fix: the model reads the filter's recorded window (the odometry it integrated)
/// and the fix; M comes from `LearnedCrossCovariance` (built once per run, its
/// workspace reused), or is neglected.
fn fuse(
    filter: &mut ExtendedKalmanFilter<f64, Odometry, 2>,
    cross: &mut LearnedCrossCovariance<'_, f64, DeadReckonedFix, Odometry, 2, 2>,
    fix: Vector2<f64>,
    with_m: bool,
) -> Result<()> {
    cross.set_update_input(0, fix.as_slice())?;
    let y = cross.measure(&filter.step_window(WINDOW)?)?;
    // What it measures: h(x) = position, H = I (R comes from the model).
    let sensor = LearnedSensor::new(cross.model(), LinearObservation::new(Matrix2::identity()));
    if with_m {
        filter.update_windowed(&sensor, &y, cross)?;
    } else {
        filter.update(&sensor, &y, &Zero)?;
    }
    Ok(())
}

// ------------------------------------------------------------------------------------
// Simulation and Monte Carlo.
// ------------------------------------------------------------------------------------

/// NEES after each fix of one run. Run `index` of `block` draws from
/// `ChaCha8Rng::seed_from_u64(index)` (as `monte_carlo` seeds it) on stream `block`, so
/// blocks are independent.
fn run(rng: &mut ChaCha8Rng, block: u64, with_m: bool) -> Result<Vec<f64>> {
    rng.set_stream(block);
    let mut normal = || -> f64 { StandardNormal.sample(&mut *rng) };
    let model = DeadReckonedFix::new();
    // Built once per run (the fix is set per update); its workspace serves every fix.
    let mut cross = LearnedCrossCovariance::new(&model, &Odometry, &[DMatrix::zeros(2, 1)])?;
    let p0 = Matrix2::identity() * 0.01;
    let mut truth = Vector2::zeros();
    let start = truth + Vector2::new(normal(), normal()) * 0.1;
    let config = FilterConfig::builder().window_capacity(WINDOW).build()?;
    let mut filter = ExtendedKalmanFilter::new(Odometry, StateAndCovariance::new(start, p0)?)
        .with_config(config);
    let mut out = Vec::with_capacity(FIXES);
    let mut fix = Vector2::zeros();
    for k in 0..FIXES {
        for step in 0..STEPS_PER_FIX {
            let t = (k * STEPS_PER_FIX + step) as f64 * DT;
            let velocity = Vector2::new(1.0 + 0.3 * (0.2 * t).sin(), 0.5 * (0.1 * t).cos());
            if step == STEPS_PER_FIX - WINDOW {
                // The fix is taken now, and reaches the filter WINDOW samples later.
                fix = truth + Vector2::new(normal(), normal()) * FIX_VARIANCE.sqrt();
            }
            let noise = Vector2::new(normal(), normal()) * ODOMETRY_VARIANCE.sqrt();
            truth = Odometry.propagate(&truth, &velocity, DT)?;
            filter.predict(&(velocity + noise), DT)?;
        }
        fuse(&mut filter, &mut cross, fix, with_m)?;
        out.push(nees(
            &(truth - filter.estimate().state()),
            filter.estimate().covariance(),
        )?);
    }
    Ok(out)
}

/// Monte Carlo of one seed block: the run-averaged NEES after each fix, and the 95 %
/// band of such an average for a consistent filter (2 states, RUNS runs).
pub fn average_nees(block: u64, with_m: bool) -> Result<(Vec<f64>, ChiSquareBand)> {
    let runs = monte_carlo(RUNS, |_, rng| run(rng, block, with_m))
        .into_iter()
        .collect::<Result<Vec<_>>>()?;
    Ok((average_over_runs(&runs)?, chi_square_band(2, RUNS, 0.95)?))
}

/// Time mean of the per-fix averages, and the share of fixes whose average is in band.
pub fn summary(averages: &[f64], band: &ChiSquareBand) -> (f64, f64) {
    let mean = averages.iter().sum::<f64>() / averages.len() as f64;
    let inside = averages.iter().filter(|a| band.contains(**a)).count();
    (mean, inside as f64 / averages.len() as f64)
}

fn main() -> Result<()> {
    println!(
        "{RUNS} runs x {FIXES} fixes; each fix dead-reckoned over the last {WINDOW} of \
         {STEPS_PER_FIX} odometry samples"
    );
    for (name, with_m) in [
        ("M from LearnedCrossCovariance", true),
        ("M neglected", false),
    ] {
        let (averages, band) = average_nees(0, with_m)?;
        let (mean, inside) = summary(&averages, &band);
        println!(
            "{name:<30} NEES (2 states) averaged over runs, time mean {mean:.3}; \
             95 % band {:.3}-{:.3}; fixes in band {:.0} %",
            band.lower,
            band.upper,
            100.0 * inside
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// In band with M, out of band without, in each of 5 independent seed blocks
    /// (blocks 0..5 = ChaCha streams 0..5 of seeds 0..RUNS): the time mean of the
    /// run-averaged NEES lies in the 95 % band of one epoch's average (a time mean of
    /// a consistent filter varies less than one epoch's, so this is a loose check
    /// for it), and at least 80 % of the fixes have their average in that band (95 %
    /// expected for a consistent filter). Neglecting M must put the time mean above
    /// the band.
    #[test]
    fn nees_is_in_band_with_m_and_out_of_band_without_over_five_seed_blocks() {
        for block in 0..5 {
            let (aware, band) = average_nees(block, true).unwrap();
            let (mean, inside) = summary(&aware, &band);
            assert!(
                band.contains(mean) && inside >= 0.8,
                "block {block}, with M: NEES {mean:.3}, {inside:.2} of fixes in band {band:?}"
            );
            eprintln!(
                "block {block}: with M {mean:.3} ({:.0} % of fixes in band)",
                100.0 * inside
            );
            let (neglected, _) = average_nees(block, false).unwrap();
            let (mean, _) = summary(&neglected, &band);
            eprintln!("block {block}: M neglected {mean:.3}");
            assert!(
                mean > band.upper,
                "block {block}, M neglected: NEES {mean:.3} not above {band:?}"
            );
        }
    }

    /// The generic M against the closed form of this sensor: v = e_fix + dt sum n_j over
    /// the window, the error receives -dt n_j, so M = -WINDOW dt^2 ODOMETRY_VARIANCE I.
    #[test]
    fn generic_cross_covariance_equals_the_closed_form() {
        use estim_core::WindowedCrossCovariance;
        let config = FilterConfig::builder()
            .window_capacity(WINDOW)
            .build()
            .unwrap();
        let initial = StateAndCovariance::new(Vector2::zeros(), Matrix2::identity()).unwrap();
        let mut filter = ExtendedKalmanFilter::new(Odometry, initial).with_config(config);
        for i in 0..STEPS_PER_FIX {
            filter
                .predict(&Vector2::new(1.0, 0.1 * i as f64), DT)
                .unwrap();
        }
        let model = DeadReckonedFix::new();
        let fix = [DMatrix::from_column_slice(2, 1, &[3.0, -1.0])];
        let cross = LearnedCrossCovariance::new(&model, &Odometry, &fix).unwrap();
        let window = filter.step_window(WINDOW).unwrap();
        let m: Matrix2<f64> = cross
            .transported_cross_covariance(&window)
            .unwrap()
            .unwrap();
        let expected = -Matrix2::identity() * (WINDOW as f64 * DT * DT * ODOMETRY_VARIANCE);
        assert!((m - expected).abs().max() < 1e-15, "{m} vs {expected}");
        // The measurement is the fix carried forward by the window's odometry.
        let y = cross.measure(&window).unwrap();
        let sum_y: f64 = (STEPS_PER_FIX - WINDOW..STEPS_PER_FIX)
            .map(|i| 0.1 * i as f64)
            .sum();
        assert!((y - Vector2::new(3.0 + WINDOW as f64 * DT, -1.0 + DT * sum_y)).norm() < 1e-12);
    }
}
