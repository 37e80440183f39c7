//! The unscented filter and smoother without Jacobians (issue 47): a pendulum
//! observed through sin(angle), filtered and smoothed by `UnscentedKalmanFilter`
//! with models that have no Jacobian, against a separately written UKF and unscented
//! RTS smoother (Saerkkae 2008; plain nalgebra below, sharing no code with the
//! crate); the same smoothed result from models whose Jacobians are right, zero or
//! absent (the Jacobian is unused).

use estim_core::nalgebra::{Matrix1, Matrix1x2, Matrix2, Vector1, Vector2};
use estim_core::sigma_point::UnscentedTransform;
use estim_core::{
    MeasurementModel, ProcessModel, Result, SigmaPointMeasurement, SigmaPointProcess,
    StateAndCovariance, UnscentedKalmanFilter, Zero,
};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

const G: f64 = 9.81;
const DT: f64 = 0.05;
const Q_PSD: f64 = 0.5;
const R_SIGMA: f64 = 0.1;

/// x_k = f(x_{k-1}): explicit Euler of a pendulum (angle, rate).
fn pendulum(x: &Vector2<f64>) -> Vector2<f64> {
    Vector2::new(x[0] + DT * x[1], x[1] - DT * G * x[0].sin())
}

/// Discretised white-noise acceleration on the rate (Bar-Shalom 2001, eq. 6.2.3-8).
fn process_noise() -> Matrix2<f64> {
    Matrix2::new(DT.powi(3) / 3.0, DT * DT / 2.0, DT * DT / 2.0, DT) * Q_PSD
}

/// y = sin(angle) + v.
fn horizontal(x: &Vector2<f64>) -> Vector1<f64> {
    Vector1::new(x[0].sin())
}

fn measurement_noise() -> Matrix1<f64> {
    Matrix1::new(R_SIGMA * R_SIGMA)
}

/// The pendulum with no Jacobian at all.
#[derive(Clone)]
struct PendulumNoJacobian;

impl SigmaPointProcess<f64, 2> for PendulumNoJacobian {
    type Input = ();
    fn propagate(&self, x: &Vector2<f64>, _: &(), _: f64) -> Result<Vector2<f64>> {
        Ok(pendulum(x))
    }
    fn process_noise(&self, _: &Vector2<f64>, _: &(), _: f64) -> Result<Matrix2<f64>> {
        Ok(process_noise())
    }
}

struct HorizontalNoJacobian;

impl SigmaPointMeasurement<f64, 2, 1> for HorizontalNoJacobian {
    fn predict(&self, x: &Vector2<f64>) -> Result<Vector1<f64>> {
        Ok(horizontal(x))
    }
    fn noise_covariance(&self, _: &Vector2<f64>) -> Result<Matrix1<f64>> {
        Ok(measurement_noise())
    }
}

/// The pendulum as an EKF model, with its right Jacobians or (`zero`) zeros.
#[derive(Clone)]
struct PendulumWithJacobian {
    zero: bool,
}

impl ProcessModel<f64, 2> for PendulumWithJacobian {
    type State = Vector2<f64>;
    type Input = ();
    fn propagate(&self, x: &Vector2<f64>, _: &(), _: f64) -> Result<Vector2<f64>> {
        Ok(pendulum(x))
    }
    fn transition(&self, x: &Vector2<f64>, _: &(), _: f64) -> Result<Matrix2<f64>> {
        Ok(if self.zero {
            Matrix2::zeros()
        } else {
            Matrix2::new(1.0, DT, -DT * G * x[0].cos(), 1.0)
        })
    }
    fn process_noise(&self, _: &Vector2<f64>, _: &(), _: f64) -> Result<Matrix2<f64>> {
        Ok(process_noise())
    }
}

struct HorizontalWithJacobian {
    zero: bool,
}

impl MeasurementModel<f64, 2, 1> for HorizontalWithJacobian {
    type State = Vector2<f64>;
    fn predict(&self, x: &Vector2<f64>) -> Result<Vector1<f64>> {
        Ok(horizontal(x))
    }
    fn jacobian(&self, x: &Vector2<f64>) -> Result<Matrix1x2<f64>> {
        Ok(if self.zero {
            Matrix1x2::zeros()
        } else {
            Matrix1x2::new(x[0].cos(), 0.0)
        })
    }
    fn noise_covariance(&self, _: &Vector2<f64>) -> Result<Matrix1<f64>> {
        Ok(measurement_noise())
    }
}

type Steps = Vec<((), f64, Option<Vector1<f64>>)>;

/// A seeded swing from (1.2, 0) with every fourth measurement missing, the truth
/// alongside.
fn swing(seed: u64, len: usize) -> (Steps, Vec<Vector2<f64>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let factor = process_noise().cholesky().expect("Q is SPD").l();
    let mut x = Vector2::new(1.2, 0.0);
    let (mut steps, mut truth) = (Vec::new(), Vec::new());
    for k in 0..len {
        let w = Vector2::new(rng.sample(StandardNormal), rng.sample(StandardNormal));
        x = pendulum(&x) + factor * w;
        let noise: f64 = rng.sample(StandardNormal);
        let y = (k % 4 != 3).then(|| horizontal(&x) + Vector1::new(R_SIGMA * noise));
        steps.push(((), DT, y));
        truth.push(x);
    }
    (steps, truth)
}

fn initial() -> StateAndCovariance<f64, 2> {
    StateAndCovariance::new(Vector2::new(1.0, 0.2), Matrix2::new(0.1, 0.0, 0.0, 0.2)).unwrap()
}

// ------------------------------------------------ the reference: UKF + URTS by hand

/// Merwe's scaled sigma points (Van der Merwe 2004, eq. 3.73-3.75) of N(m, P) in two
/// dimensions, with their mean and covariance weights.
fn sigma_points(
    m: &Vector2<f64>,
    p: &Matrix2<f64>,
    (alpha, beta, kappa): (f64, f64, f64),
) -> (Vec<Vector2<f64>>, Vec<f64>, Vec<f64>) {
    let l = 2.0;
    let lambda = alpha * alpha * (l + kappa) - l;
    let s = p.cholesky().expect("covariance is SPD").l() * (l + lambda).sqrt();
    let mut points = vec![*m];
    points.extend((0..2).map(|i| m + s.column(i)));
    points.extend((0..2).map(|i| m - s.column(i)));
    let wm0 = lambda / (l + lambda);
    let wi = 1.0 / (2.0 * (l + lambda));
    let mut wm = vec![wm0];
    wm.extend([wi; 4]);
    let mut wc = vec![wm0 + 1.0 - alpha * alpha + beta];
    wc.extend([wi; 4]);
    (points, wm, wc)
}

/// The filtered estimates, the predictions m-, P- and the cross-covariances D of
/// each step, and the unscented RTS smoothed estimates (initial epoch first).
#[allow(clippy::type_complexity)]
fn reference(
    steps: &Steps,
    weights: (f64, f64, f64),
) -> (
    Vec<(Vector2<f64>, Matrix2<f64>)>,
    Vec<(Vector2<f64>, Matrix2<f64>)>,
) {
    let (mut m, mut p) = initial().into_parts();
    let mut filtered = vec![(m, p)];
    let mut predictions = Vec::new();
    for (_, _, y) in steps {
        // Predict (Saerkkae 2013, alg. 5.14), with D = Cov(x_{k-1}, x_k) of the points.
        let (x, wm, wc) = sigma_points(&m, &p, weights);
        let fx: Vec<_> = x.iter().map(pendulum).collect();
        let mp: Vector2<f64> = fx.iter().zip(&wm).map(|(f, w)| f * *w).sum();
        let mut pp = process_noise();
        let mut d = Matrix2::zeros();
        for i in 0..5 {
            pp += (fx[i] - mp) * (fx[i] - mp).transpose() * wc[i];
            d += (x[i] - m) * (fx[i] - mp).transpose() * wc[i];
        }
        predictions.push((mp, pp, d));
        (m, p) = (mp, pp);
        if let Some(y) = y {
            // Update (alg. 5.14): points redrawn from the prediction.
            let (x, wm, wc) = sigma_points(&m, &p, weights);
            let hx: Vec<_> = x.iter().map(horizontal).collect();
            let yh: Vector1<f64> = hx.iter().zip(&wm).map(|(h, w)| h * *w).sum();
            let mut s = measurement_noise();
            let mut c = Vector2::zeros();
            for i in 0..5 {
                s += (hx[i] - yh) * (hx[i] - yh).transpose() * wc[i];
                c += (x[i] - m) * (hx[i] - yh)[0] * wc[i];
            }
            let k = c / s[0];
            m += k * (y - yh)[0];
            p -= k * s[0] * k.transpose();
        }
        filtered.push((m, p));
    }
    // Unscented RTS (Saerkkae 2008, eq. 14; 2013, alg. 9.6).
    let mut smoothed = vec![*filtered.last().unwrap()];
    for k in (0..steps.len()).rev() {
        let (mp, pp, d) = &predictions[k];
        let gain = d * pp.try_inverse().expect("P- invertible");
        let (ms_next, ps_next) = smoothed[0];
        let (mk, pk) = filtered[k];
        let ms = mk + gain * (ms_next - mp);
        let ps = pk + gain * (ps_next - pp) * gain.transpose();
        smoothed.insert(0, (ms, ps));
    }
    (filtered, smoothed)
}

/// max |a - b| / max(1, |b|) over state and covariance.
fn gap(a: &StateAndCovariance<f64, 2>, b: &(Vector2<f64>, Matrix2<f64>)) -> f64 {
    let rel = |x: f64, y: f64| (x - y).abs() / y.abs().max(1.0);
    let states = a.state().iter().zip(b.0.iter()).map(|(x, y)| rel(*x, *y));
    let covariances = a
        .covariance()
        .iter()
        .zip(b.1.iter())
        .map(|(x, y)| rel(*x, *y));
    states.chain(covariances).fold(0.0, f64::max)
}

#[test]
fn smoother_without_jacobians_is_the_unscented_rts_smoother() {
    let (steps, _) = swing(47, 80);
    for weights in [(1.0, 2.0, 0.0), (0.5, 2.0, 1.0), (1.0, 0.0, 1.0)] {
        let transform = UnscentedTransform::new(weights.0, weights.1, weights.2).unwrap();
        let ukf = UnscentedKalmanFilter::new(PendulumNoJacobian, transform, initial());
        let batch = ukf
            .smooth_batch(&steps, &HorizontalNoJacobian, &Zero)
            .unwrap();
        let (filtered, smoothed) = reference(&steps, weights);
        let filtered_gap = batch
            .filtered
            .iter()
            .zip(&filtered[1..])
            .map(|(a, b)| gap(a, b))
            .fold(0.0, f64::max);
        let smoothed_gap = std::iter::once(&batch.initial)
            .chain(&batch.estimates)
            .zip(&smoothed)
            .map(|(a, b)| gap(a, b))
            .fold(0.0, f64::max);
        println!("{weights:?}: filtered {filtered_gap:.1e}, smoothed {smoothed_gap:.1e}");
        assert!(filtered_gap < 1e-10, "filtered {filtered_gap:e}");
        assert!(smoothed_gap < 1e-10, "smoothed {smoothed_gap:e}");
        // The smoother moved the estimates (it is not the filter again).
        let moved = (batch.estimates[10].state() - batch.filtered[10].state()).norm();
        assert!(moved > 1e-3, "smoothing moved epoch 10 by {moved:e}");
    }
}

#[test]
fn smoothed_result_does_not_depend_on_the_jacobians() {
    let (steps, truth) = swing(7, 200);
    let transform = UnscentedTransform::default();
    let none = UnscentedKalmanFilter::new(PendulumNoJacobian, transform, initial())
        .smooth_batch(&steps, &HorizontalNoJacobian, &Zero)
        .unwrap();
    let rmse = |estimates: &[StateAndCovariance<f64, 2>]| {
        let sum: f64 = estimates
            .iter()
            .zip(&truth)
            .map(|(e, x)| (e.state()[0] - x[0]).powi(2))
            .sum();
        (sum / truth.len() as f64).sqrt()
    };
    for zero in [false, true] {
        let ukf = UnscentedKalmanFilter::new(PendulumWithJacobian { zero }, transform, initial());
        let batch = ukf
            .smooth_batch(&steps, &HorizontalWithJacobian { zero }, &Zero)
            .unwrap();
        // Bit for bit: the Jacobians are never evaluated into anything.
        assert_eq!(batch, none, "zero Jacobians: {zero}");
    }
    let (filtered, smoothed) = (rmse(&none.filtered), rmse(&none.estimates));
    println!("angle RMSE: filtered {filtered:.4}, smoothed {smoothed:.4}");
    assert!(
        smoothed < filtered,
        "smoothed {smoothed} filtered {filtered}"
    );
}

#[test]
fn one_call_gives_filtered_and_smoothed_and_plain_update_is_zero_cross() {
    let (steps, _) = swing(11, 40);
    let transform = UnscentedTransform::default();
    let ukf = UnscentedKalmanFilter::new(PendulumNoJacobian, transform, initial());
    let both = ukf
        .smooth_batch(&steps, &HorizontalNoJacobian, &Zero)
        .unwrap();
    let mut forward = ukf.clone();
    let filtered = forward
        .filter_batch(&steps, &HorizontalNoJacobian, &Zero)
        .unwrap();
    // The same forward pass, bit for bit.
    assert_eq!(both.filtered, filtered.estimates);
    assert_eq!(both.log_likelihood, filtered.log_likelihood);

    // step_uncorrelated is step with Zero, bit for bit.
    let (mut plain, mut zero) = (ukf.clone(), ukf);
    for (_, dt, y) in &steps {
        let a = plain
            .step_uncorrelated(&(), *dt, &HorizontalNoJacobian, y.as_ref())
            .unwrap();
        let b = zero
            .step(&(), *dt, &HorizontalNoJacobian, y.as_ref(), &Zero)
            .unwrap();
        assert_eq!(a, b);
        assert_eq!(plain.estimate(), zero.estimate());
    }
}
