//! The generic learned cross-covariance against an independently derived closed form,
//! on a linear cart whose measured acceleration drives the process and feeds a
//! "learned" window-mean speed sensor. The closed form fixes the sign convention of
//! estim-core's `WindowedCrossCovariance`: flipping the sign of the noise input (or of
//! D_j anywhere) fails these tests.

use estim_core::nalgebra::{DMatrix, Matrix1, Matrix1x2, Matrix2, SMatrix, Vector1, Vector2};
use estim_core::{
    ExtendedKalmanFilter, FilterConfig, InputSpec, LearnedMeasurement, MeasurementModel,
    ProcessModel, Result, StateAndCovariance, WindowedCrossCovariance,
};
use estim_learned::{InputNoise, LearnedCrossCovariance, LearnedSensor, Observation};

/// p += dt v, v += dt a_measured; acceleration noise variance `q` per sample.
struct Cart {
    q: f64,
}

impl ProcessModel<f64, 2> for Cart {
    type State = Vector2<f64>;
    type Input = f64;
    fn propagate(&self, x: &Vector2<f64>, a: &f64, dt: f64) -> Result<Vector2<f64>> {
        Ok(Vector2::new(x[0] + dt * x[1], x[1] + dt * a))
    }
    fn transition(&self, _: &Vector2<f64>, _: &f64, dt: f64) -> Result<Matrix2<f64>> {
        Ok(Matrix2::new(1.0, dt, 0.0, 1.0))
    }
    fn process_noise(&self, _: &Vector2<f64>, _: &f64, dt: f64) -> Result<Matrix2<f64>> {
        Ok(Matrix2::new(0.0, 0.0, 0.0, dt * dt * self.q))
    }
}

impl InputNoise<f64, 2, 1> for Cart {
    fn input_channels(&self, a: &f64) -> SMatrix<f64, 1, 1> {
        Vector1::new(*a)
    }
    // The nominal integrates a + n: the velocity error (true - nominal) gets -dt n.
    fn input_noise_jacobian(&self, _: &Vector2<f64>, _: &f64, dt: f64) -> SMatrix<f64, 2, 1> {
        SMatrix::<f64, 2, 1>::new(0.0, -dt)
    }
    fn input_noise_covariance(&self, _dt: f64) -> Matrix1<f64> {
        Matrix1::new(self.q)
    }
}

/// y = gain * mean of the last `window` measured accelerations (a learned model's
/// stand-in, linear so its JVPs are exact).
struct MeanAcc {
    specs: Vec<InputSpec>,
    gain: f64,
}

impl MeanAcc {
    fn new(window: usize, gain: f64) -> Self {
        Self {
            specs: vec![InputSpec {
                name: "acc".into(),
                channels: 1,
                window,
                sample_rate_hz: 100.0,
            }],
            gain,
        }
    }
}

impl LearnedMeasurement<f64, 1> for MeanAcc {
    fn input_specs(&self) -> &[InputSpec] {
        &self.specs
    }
    fn measure(&self, inputs: &[DMatrix<f64>]) -> Result<Vector1<f64>> {
        Ok(Vector1::new(self.gain * inputs[0].mean()))
    }
    fn noise_covariance(&self) -> Matrix1<f64> {
        Matrix1::new(0.01)
    }
    fn sensitivity(
        &self,
        _: &[DMatrix<f64>],
        directions: &[DMatrix<f64>],
        products: &mut [Vector1<f64>],
    ) -> Result<bool> {
        for (d, product) in directions.iter().zip(products) {
            *product = Vector1::new(self.gain * d.mean());
        }
        Ok(true)
    }
}

/// Observes the velocity: h(x) and H are the user's; R comes from the learned model
/// through `LearnedSensor`.
struct Velocity;
impl Observation<f64, 2, 1> for Velocity {
    type State = Vector2<f64>;
    fn predict(&self, x: &Vector2<f64>) -> Result<Vector1<f64>> {
        Ok(Vector1::new(x[1]))
    }
    fn jacobian(&self, _: &Vector2<f64>) -> Result<Matrix1x2<f64>> {
        Ok(Matrix1x2::new(0.0, 1.0))
    }
}

/// Independent closed form: v = (gain / L) sum_j n_j, the error after the window
/// e = sum_{m=0}^{L-1} F^m [0; -dt] n_{L-1-m}, F^m = [[1, m dt], [0, 1]], so
/// M = Cov(e, v) = -(gain q dt / L) [dt L (L - 1) / 2; L].
fn closed_form(l: usize, dt: f64, q: f64, gain: f64) -> Vector2<f64> {
    let lf = l as f64;
    -(gain * q * dt / lf) * Vector2::new(dt * lf * (lf - 1.0) / 2.0, lf)
}

fn filter(window: usize, steps: usize, dt: f64, q: f64) -> ExtendedKalmanFilter<f64, Cart, 2> {
    let config = FilterConfig::builder()
        .window_capacity(window)
        .build()
        .unwrap();
    let initial = StateAndCovariance::new(Vector2::zeros(), Matrix2::identity()).unwrap();
    let mut ekf = ExtendedKalmanFilter::new(Cart { q }, initial).with_config(config);
    for i in 0..steps {
        ekf.predict(&(0.1 + 0.01 * i as f64), dt).unwrap();
    }
    ekf
}

#[test]
fn adjoint_and_per_step_forms_match_the_closed_form() {
    for &(l, dt, q, gain) in &[
        (1, 0.1, 0.02, 1.0),
        (7, 0.05, 0.3, 0.7),
        (50, 0.01, 1e-3, 2.0),
    ] {
        let ekf = filter(l, l + 3, dt, q);
        let model = MeanAcc::new(l, gain);
        let window = ekf.step_window(l).unwrap();
        let cross = LearnedCrossCovariance::new(&model, ekf.process(), &[]).unwrap();
        let expected = closed_form(l, dt, q, gain);
        let adjoint = cross
            .transported_cross_covariance(&window)
            .unwrap()
            .unwrap();
        // Per-step D_j transported with an independently formed F^m.
        let mut per_step = Vector2::zeros();
        let mut j = 0;
        cross
            .step_cross_covariances(&window, &mut |d: &SMatrix<f64, 2, 1>| {
                let m = (l - 1 - j) as f64;
                per_step += Matrix2::new(1.0, m * dt, 0.0, 1.0) * d;
                j += 1;
                Ok(())
            })
            .unwrap();
        assert_eq!(j, l);
        for (name, got) in [("adjoint", adjoint), ("per step", per_step)] {
            assert!(
                (got - expected).norm() <= 1e-12 * expected.norm(),
                "{name}, L = {l}: {got} vs closed form {expected}"
            );
        }
        // The measurement on the runner's window is the model on the consumed samples.
        let y = cross.measure::<2>(&window).unwrap();
        let mean: f64 = (3..l + 3).map(|i| 0.1 + 0.01 * i as f64).sum::<f64>() / l as f64;
        assert!((y[0] - gain * mean).abs() < 1e-12);
    }
}

#[test]
fn the_filter_uses_the_exact_cross_covariance() {
    let (l, dt, q) = (20, 0.02, 0.05);
    let mut ekf = filter(l, 40, dt, q);
    let model = MeanAcc::new(l, 1.0);
    let cart = Cart { q };
    let cross = LearnedCrossCovariance::new(&model, &cart, &[]).unwrap();
    let window = ekf.step_window(l).unwrap();
    let y = cross.measure::<2>(&window).unwrap();
    let sensor = LearnedSensor::new(&model, Velocity);
    let prior = ekf.estimate().clone();
    assert_eq!(
        MeasurementModel::<f64, 2, 1>::noise_covariance(&sensor, prior.state()).unwrap(),
        model.noise_covariance()
    );
    let report = ekf.update_windowed(&sensor, &y, &cross).unwrap();
    let expected = closed_form(l, dt, q, 1.0);
    assert!((report.cross_covariance - expected).norm() <= 1e-12 * expected.norm());
    // The posterior is the correlated update (Simon 2006, sec. 7.1) with that M,
    // coded here: S = H P H' + H M + M' H' + R, K = (P H' + M) S^-1.
    let p = prior.covariance();
    let h = Matrix1x2::new(0.0, 1.0);
    let s = h * p * h.transpose()
        + h * expected
        + expected.transpose() * h.transpose()
        + model.noise_covariance();
    let k = (p * h.transpose() + expected) / s[0];
    let x = prior.state() + k * (y[0] - prior.state()[1]);
    assert!((ekf.estimate().state() - x).norm() <= 1e-12 * x.norm().max(1.0));
}

#[test]
fn layout_mismatches_are_typed_errors() {
    let model = MeanAcc::new(5, 1.0);
    let extra = [DMatrix::zeros(4, 1)];
    // An extra input the model does not declare.
    assert!(
        LearnedCrossCovariance::<f64, _, Cart, 1, 1>::new(&model, &Cart { q: 1.0 }, &extra)
            .is_err()
    );
    // K larger than the model's channels.
    assert!(
        LearnedCrossCovariance::<f64, _, Cart, 1, 2>::new(&model, &Cart { q: 1.0 }, &[]).is_err()
    );
    // A window of the wrong length.
    let ekf = filter(8, 8, 0.1, 1.0);
    let cross = LearnedCrossCovariance::new(&model, ekf.process(), &[]).unwrap();
    let window = ekf.step_window(8).unwrap();
    assert!(cross.transported_cross_covariance(&window).is_err());
    assert!(ekf.step_window(9).is_err());
}
