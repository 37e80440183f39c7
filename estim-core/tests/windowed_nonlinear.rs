//! EKF and ESKF with a windowed M on a nonlinear model, against the linearised
//! reference: the affine-Gaussian system obtained by linearising f and h at the
//! filter's own linearisation points (x_j = f(p) + F_j (x_{j-1} - p) + w_j,
//! y = h(q) + H (x - q) + v), conditioned as one stacked Gaussian
//! [x_0; w_1..w_K; v_B; v_A]. Jacobians are coded here, separately from the models.

mod common;

use common::{inv, rel_err};
use estim_core::nalgebra::{DMatrix, DVector, Matrix1, Matrix1x2, Matrix2, Vector1, Vector2};
use estim_core::window::StepWindow;
use estim_core::{
    ErrorStateKalmanFilter, ErrorStateModel, ExtendedKalmanFilter, FilterConfig, MeasurementModel,
    ProcessModel, Result, StateAndCovariance, WindowedCrossCovariance, Zero,
};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

const DT: f64 = 0.1;

/// Pendulum driven by a measured torque u: theta' = omega, omega' = u - sin(theta).
struct Pendulum {
    q: Vec<Matrix2<f64>>,
}

fn f(x: &Vector2<f64>, u: f64) -> Vector2<f64> {
    Vector2::new(x[0] + DT * x[1], x[1] + DT * (u - x[0].sin()))
}

/// Jacobian of `f`, coded independently of the model's `transition`.
fn f_jacobian(x: &DVector<f64>) -> DMatrix<f64> {
    DMatrix::from_row_slice(2, 2, &[1.0, DT, -DT * x[0].cos(), 1.0])
}

impl ProcessModel<f64, 2> for Pendulum {
    type State = Vector2<f64>;
    type Input = (usize, f64);
    fn propagate(&self, x: &Vector2<f64>, u: &(usize, f64), _: f64) -> Result<Vector2<f64>> {
        Ok(f(x, u.1))
    }
    fn transition(&self, x: &Vector2<f64>, _: &(usize, f64), _: f64) -> Result<Matrix2<f64>> {
        Ok(Matrix2::new(1.0, DT, -DT * x[0].cos(), 1.0))
    }
    fn process_noise(&self, _: &Vector2<f64>, u: &(usize, f64), _: f64) -> Result<Matrix2<f64>> {
        Ok(self.q[u.0 - 1])
    }
}

impl ErrorStateModel<f64, 2> for Pendulum {
    fn inject(&self, nominal: &Vector2<f64>, error: &Vector2<f64>) -> Result<Vector2<f64>> {
        Ok(nominal + error)
    }
}

/// B: y = sin(theta) + 0.5 omega + v_B.
struct SensorB(f64);
impl MeasurementModel<f64, 2, 1> for SensorB {
    type State = Vector2<f64>;
    fn predict(&self, x: &Vector2<f64>) -> Result<Vector1<f64>> {
        Ok(Vector1::new(x[0].sin() + 0.5 * x[1]))
    }
    fn jacobian(&self, x: &Vector2<f64>) -> Result<Matrix1x2<f64>> {
        Ok(Matrix1x2::new(x[0].cos(), 0.5))
    }
    fn noise_covariance(&self, _: &Vector2<f64>) -> Result<Matrix1<f64>> {
        Ok(Matrix1::new(self.0))
    }
}

/// A: y = theta^2 + v_A (independent noise).
struct SensorA(f64);
impl MeasurementModel<f64, 2, 1> for SensorA {
    type State = Vector2<f64>;
    fn predict(&self, x: &Vector2<f64>) -> Result<Vector1<f64>> {
        Ok(Vector1::new(x[0] * x[0]))
    }
    fn jacobian(&self, x: &Vector2<f64>) -> Result<Matrix1x2<f64>> {
        Ok(Matrix1x2::new(2.0 * x[0], 0.0))
    }
    fn noise_covariance(&self, _: &Vector2<f64>) -> Result<Matrix1<f64>> {
        Ok(Matrix1::new(self.0))
    }
}

struct KnownD {
    window: usize,
    d: Vec<Vector2<f64>>,
}

impl WindowedCrossCovariance<f64, Vector2<f64>, (usize, f64), 2, 1> for KnownD {
    fn window_steps(&self) -> usize {
        self.window
    }
    fn step_cross_covariances(
        &self,
        window: &StepWindow<'_, f64, Vector2<f64>, (usize, f64), 2>,
        sink: &mut dyn FnMut(&Vector2<f64>) -> Result<()>,
    ) -> Result<()> {
        for step in window.iter() {
            sink(&self.d[step.input.0 - 1])?;
        }
        Ok(())
    }
}

struct Case {
    k: usize,
    window: usize,
    a_at: usize,
    m0: Vector2<f64>,
    p0: Matrix2<f64>,
    u: Vec<f64>,
    q: Vec<Matrix2<f64>>,
    d: Vec<Vector2<f64>>,
    r_b: f64,
    r_a: f64,
    y_b: f64,
    y_a: f64,
}

fn case(seed: u64) -> Case {
    use rand::RngExt;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let k = rng.random_range(5..=40usize);
    let window = rng.random_range(1..=k);
    let a_at = rng.random_range(1..=k);
    let mut q = Vec::new();
    let mut d = Vec::new();
    let mut r_b = 0.01;
    for j in 1..=k {
        let b = Matrix2::from_fn(|_, _| rng.random_range(-1.0..1.0));
        let qj = (b * b.transpose() + Matrix2::identity() * 0.1) * 1e-3;
        if j + window > k {
            let a = Vector2::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
            r_b += (a.transpose() * qj * a)[0];
            d.push(qj * a);
        } else {
            d.push(Vector2::zeros());
        }
        q.push(qj);
    }
    Case {
        k,
        window,
        a_at,
        m0: Vector2::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)),
        p0: Matrix2::new(0.05, 0.01, 0.01, 0.08),
        u: (0..k).map(|_| rng.random_range(-1.0..1.0)).collect(),
        q,
        d,
        r_b,
        r_a: 0.02,
        y_b: rng.random_range(-1.0..1.0),
        y_a: rng.random_range(0.0..1.0),
    }
}

fn dvec(v: &Vector2<f64>) -> DVector<f64> {
    DVector::from_column_slice(v.as_slice())
}

/// Linearised stacked reference given the linearisation points: `before[j]` the
/// estimate before predict j+1, `q_a`, `q_b` the estimates the measurements were
/// linearised at.
fn reference(
    c: &Case,
    before: &[Vector2<f64>],
    q_a: &Vector2<f64>,
    q_b: &Vector2<f64>,
) -> (DVector<f64>, DMatrix<f64>) {
    let (n, k) = (2, c.k);
    let dim = n * (k + 1) + 2;
    let (vb, va) = (n * (k + 1), n * (k + 1) + 1);
    let mut cov = DMatrix::zeros(dim, dim);
    cov.view_mut((0, 0), (n, n))
        .copy_from(&DMatrix::from_column_slice(2, 2, c.p0.as_slice()));
    for j in 1..=k {
        let w = n * j;
        cov.view_mut((w, w), (n, n))
            .copy_from(&DMatrix::from_column_slice(2, 2, c.q[j - 1].as_slice()));
        for i in 0..n {
            cov[(w + i, vb)] = c.d[j - 1][i];
            cov[(vb, w + i)] = c.d[j - 1][i];
        }
    }
    cov[(vb, vb)] = c.r_b;
    cov[(va, va)] = c.r_a;
    let mut mean = DVector::zeros(dim);
    mean.rows_mut(0, n).copy_from(&dvec(&c.m0));
    // x_j = L z + offset.
    let mut l = DMatrix::zeros(n, dim);
    l.view_mut((0, 0), (n, n)).fill_with_identity();
    let mut offset = DVector::zeros(n);
    let mut rows = Vec::new();
    let mut ys = Vec::new();
    for j in 1..=k {
        let p = dvec(&before[j - 1]);
        let fj = f_jacobian(&p);
        let c_j = dvec(&f(&before[j - 1], c.u[j - 1])) - &fj * &p;
        l = &fj * &l;
        offset = &fj * &offset + c_j;
        for i in 0..n {
            l[(i, n * j + i)] += 1.0;
        }
        if j == c.a_at {
            // y_A = h(q) + H (x - q) + v_A, H = [2 theta, 0].
            let h = DMatrix::from_row_slice(1, 2, &[2.0 * q_a[0], 0.0]);
            let mut t = &h * &l;
            t[(0, va)] += 1.0;
            let known = q_a[0] * q_a[0] - (&h * dvec(q_a))[0] + (&h * &offset)[0];
            rows.push(t);
            ys.push(c.y_a - known);
        }
    }
    let h = DMatrix::from_row_slice(1, 2, &[q_b[0].cos(), 0.5]);
    let mut t = &h * &l;
    t[(0, vb)] += 1.0;
    let known = q_b[0].sin() + 0.5 * q_b[1] - (&h * dvec(q_b))[0] + (&h * &offset)[0];
    rows.push(t);
    ys.push(c.y_b - known);
    let mut tm = DMatrix::zeros(rows.len(), dim);
    for (i, r) in rows.iter().enumerate() {
        tm.row_mut(i).copy_from(&r.row(0));
    }
    let y = DVector::from_vec(ys);
    let sxy = &l * &cov * tm.transpose();
    let syy = &tm * &cov * tm.transpose();
    let gain = &sxy * inv(&syy);
    (
        &l * &mean + &offset + &gain * (y - &tm * &mean),
        &l * &cov * l.transpose() - &gain * sxy.transpose(),
    )
}

fn check(
    what: &str,
    seed: u64,
    x: &Vector2<f64>,
    p: &Matrix2<f64>,
    r: &(DVector<f64>, DMatrix<f64>),
) {
    let em = rel_err(
        &DMatrix::from_column_slice(2, 1, x.as_slice()),
        &DMatrix::from_column_slice(2, 1, r.0.as_slice()),
    );
    let ec = rel_err(&DMatrix::from_column_slice(2, 2, p.as_slice()), &r.1);
    assert!(
        em < 1e-9 && ec < 1e-9,
        "{what} seed {seed}: mean {em:e}, covariance {ec:e}"
    );
}

#[test]
fn ekf_and_eskf_match_the_linearised_stacked_reference() {
    for seed in 0..64 {
        let c = case(seed);
        let config = FilterConfig::builder()
            .window_capacity(c.k)
            .build()
            .expect("config");
        let process = || Pendulum { q: c.q.clone() };
        let cross = KnownD {
            window: c.window,
            d: c.d.clone(),
        };
        let initial = StateAndCovariance::new(c.m0, c.p0).expect("initial");
        let mut ekf = ExtendedKalmanFilter::new(process(), initial).with_config(config.clone());
        let mut eskf = ErrorStateKalmanFilter::new(process(), c.m0, c.p0)
            .expect("eskf")
            .with_config(config);
        let (sensor_a, sensor_b) = (SensorA(c.r_a), SensorB(c.r_b));
        let mut before = Vec::new();
        let mut q_a = Vector2::zeros();
        for j in 1..=c.k {
            before.push(*ekf.estimate().state());
            assert!((ekf.estimate().state() - eskf.nominal()).amax() < 1e-12);
            ekf.predict(&(j, c.u[j - 1]), DT).expect("predict");
            eskf.predict(&(j, c.u[j - 1]), DT).expect("predict");
            if j == c.a_at {
                q_a = *ekf.estimate().state();
                ekf.update(&sensor_a, &Vector1::new(c.y_a), &Zero)
                    .expect("A");
                eskf.update(&sensor_a, &Vector1::new(c.y_a), &Zero)
                    .expect("A");
            }
        }
        let q_b = *ekf.estimate().state();
        let r = reference(&c, &before, &q_a, &q_b);
        ekf.update_windowed(&sensor_b, &Vector1::new(c.y_b), &cross)
            .expect("B");
        eskf.update_windowed(&sensor_b, &Vector1::new(c.y_b), &cross)
            .expect("B");
        check(
            "EKF",
            seed,
            ekf.estimate().state(),
            ekf.estimate().covariance(),
            &r,
        );
        check("ESKF", seed, eskf.nominal(), eskf.covariance(), &r);
    }
}
