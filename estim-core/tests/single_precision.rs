//! estim-core in `f32` end to end: the linear KF (with a correlated M and the joint
//! check set to reject), the EKF and the error-state EKF, each against the same filter
//! coded independently here in `f64` from the textbook formulas (Simon 2006, sec. 7.1),
//! starting from a valid covariance whose two triangles differ by one f32 ulp (which the
//! former fixed 1e-9 symmetry tolerance rejected).

use estim_core::nalgebra::{Matrix1, Matrix1x2, Matrix2, Matrix2x1, Vector1, Vector2};
use estim_core::numeric::relative_tolerance;
use estim_core::{
    ErrorStateKalmanFilter, ErrorStateModel, ExtendedKalmanFilter, FilterConfig, Fixed, JointCheck,
    KalmanFilter, MeasurementModel, ProcessModel, Result, StateAndCovariance,
};

const DT: f64 = 0.1;
const Q_PSD: f64 = 0.5;
const R: f64 = 0.04;
/// Cov(G w, v): valid (|M|^2 well below Q R).
const M: [f64; 2] = [2e-4, 3e-3];

fn cv_f64() -> (Matrix2<f64>, Matrix2<f64>) {
    let f = Matrix2::new(1.0, DT, 0.0, 1.0);
    let (d2, d3) = (DT * DT, DT * DT * DT);
    let q = Matrix2::new(d3 / 3.0, d2 / 2.0, d2 / 2.0, DT) * Q_PSD;
    (f, q)
}

fn to_f32(m: &Matrix2<f64>) -> Matrix2<f32> {
    m.map(|x| x as f32)
}

/// The initial covariance in f32: 0.3 and the next float up off the diagonal.
fn initial_covariance() -> Matrix2<f32> {
    let p = Matrix2::new(1.0f32, 0.3, f32::from_bits(0.3f32.to_bits() + 1), 2.0);
    // The asymmetry is one ulp (relative 1.5e-8 of the largest entry): a valid f32
    // covariance, rejected by a fixed 1e-9 and accepted by the scalar's tolerance.
    let asymmetry = (p[(0, 1)] - p[(1, 0)]).abs() / 2.0;
    assert!(asymmetry > 1e-9 && asymmetry < relative_tolerance::<f32>());
    p
}

fn measurement(k: usize) -> f64 {
    let t = k as f64 * DT;
    t + 0.3 * (1.7 * t).sin()
}

/// Textbook correlated KF in f64 (position measured, M = Cov(G w_{k-1}, v_k)).
fn reference(steps: usize, m: Matrix2x1<f64>) -> (Vector2<f64>, Matrix2<f64>) {
    let (f, q) = cv_f64();
    let h = Matrix1x2::new(1.0, 0.0);
    let p0 = initial_covariance().map(f64::from);
    let mut p = (p0 + p0.transpose()) * 0.5;
    let mut x = Vector2::new(0.0, 1.0);
    for k in 0..steps {
        x = f * x;
        p = f * p * f.transpose() + q;
        let s = (h * p * h.transpose() + h * m + m.transpose() * h.transpose())[0] + R;
        let gain = (p * h.transpose() + m) / s;
        x += gain * (measurement(k) - x[0]);
        p -= gain * (h * p + m.transpose());
        p = (p + p.transpose()) * 0.5;
    }
    (x, p)
}

/// Relative error of an f32 result against the f64 reference, entrywise over the
/// reference's scale.
fn close(x32: &Vector2<f32>, p32: &Matrix2<f32>, x: &Vector2<f64>, p: &Matrix2<f64>) -> f64 {
    let dx = (x32.map(f64::from) - x).amax() / x.amax();
    let dp = (p32.map(f64::from) - p).amax() / p.amax();
    dx.max(dp)
}

/// 100 steps of f32 against f64: a few hundred roundings of 6e-8 each, with a stable
/// filter damping them; 1e-4 leaves a wide margin while still catching a wrong formula
/// (errors of order 1).
const F32_AGREEMENT: f64 = 1e-4;

#[test]
fn linear_kalman_filter_in_f32_matches_the_f64_reference_with_correlated_noise() {
    let (f, q) = cv_f64();
    let m = Matrix2x1::new(M[0], M[1]);
    let config = FilterConfig::builder()
        .joint_check(JointCheck::Reject)
        .build()
        .unwrap();
    let initial = StateAndCovariance::new(Vector2::new(0.0f32, 1.0), initial_covariance()).unwrap();
    let mut kf = KalmanFilter::new(
        to_f32(&f),
        to_f32(&q),
        Matrix1x2::new(1.0f32, 0.0),
        Matrix1::new(R as f32),
        initial,
    )
    .unwrap()
    .with_config(config);
    let cross = Fixed(m.map(|v| v as f32));
    for k in 0..100 {
        let report = kf
            .step(Some(&Vector1::new(measurement(k) as f32)), &cross)
            .unwrap()
            .unwrap();
        assert!(report.is_accepted());
        assert!(report.joint_min_eigenvalue.unwrap() >= -relative_tolerance::<f32>());
    }
    let (x, p) = reference(100, m);
    let err = close(kf.estimate().state(), kf.estimate().covariance(), &x, &p);
    assert!(err < F32_AGREEMENT, "{err:e}");
}

/// Constant velocity as a nonlinear-filter process model in f32.
struct ConstantVelocity;

impl ProcessModel<f32, 2> for ConstantVelocity {
    type State = Vector2<f32>;
    type Input = ();
    fn propagate(&self, x: &Vector2<f32>, _: &(), dt: f32) -> Result<Vector2<f32>> {
        Ok(Vector2::new(x[0] + dt * x[1], x[1]))
    }
    fn transition(&self, _: &Vector2<f32>, _: &(), dt: f32) -> Result<Matrix2<f32>> {
        Ok(Matrix2::new(1.0, dt, 0.0, 1.0))
    }
    fn process_noise(&self, _: &Vector2<f32>, _: &(), _: f32) -> Result<Matrix2<f32>> {
        Ok(to_f32(&cv_f64().1))
    }
}

impl ErrorStateModel<f32, 2> for ConstantVelocity {
    fn inject(&self, nominal: &Vector2<f32>, error: &Vector2<f32>) -> Result<Vector2<f32>> {
        Ok(nominal + error)
    }
}

struct Position;

impl MeasurementModel<f32, 2, 1> for Position {
    type State = Vector2<f32>;
    fn predict(&self, x: &Vector2<f32>) -> Result<Vector1<f32>> {
        Ok(Vector1::new(x[0]))
    }
    fn jacobian(&self, _: &Vector2<f32>) -> Result<Matrix1x2<f32>> {
        Ok(Matrix1x2::new(1.0, 0.0))
    }
    fn noise_covariance(&self, _: &Vector2<f32>) -> Result<Matrix1<f32>> {
        Ok(Matrix1::new(R as f32))
    }
}

#[test]
fn extended_and_error_state_filters_in_f32_match_the_f64_reference() {
    let m = Matrix2x1::new(M[0], M[1]);
    let cross = Fixed(m.map(|v| v as f32));
    let initial = StateAndCovariance::new(Vector2::new(0.0f32, 1.0), initial_covariance()).unwrap();
    let mut ekf = ExtendedKalmanFilter::new(ConstantVelocity, initial);
    let mut eskf = ErrorStateKalmanFilter::new(
        ConstantVelocity,
        Vector2::new(0.0f32, 1.0),
        initial_covariance(),
    )
    .unwrap();
    for k in 0..100 {
        let y = Vector1::new(measurement(k) as f32);
        ekf.step(&(), DT as f32, &Position, Some(&y), &cross)
            .unwrap();
        eskf.step(&(), DT as f32, &Position, Some(&y), &cross)
            .unwrap();
    }
    let (x, p) = reference(100, m);
    let err = close(ekf.estimate().state(), ekf.estimate().covariance(), &x, &p);
    assert!(err < F32_AGREEMENT, "EKF {err:e}");
    let err = close(eskf.nominal(), eskf.covariance(), &x, &p);
    assert!(err < F32_AGREEMENT, "ESKF {err:e}");
}
