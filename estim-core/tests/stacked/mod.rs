//! Independent references for the time-varying and batch tests, coded with dynamic
//! nalgebra matrices and plain formulas (LU inverses, nalgebra's Cholesky for the log
//! density), never the crate's update:
//!
//! - [`Plan`]: a time-varying linear model x_k = F_k x_{k-1} + B_k u_k + w_k,
//!   Cov(w_k) = Q_k, y_k = H_k x_k + v_k, Cov(v_k) = R_k, Cov(w_k, v_k) = M_k (one-step
//!   correlation, state space), some steps unmeasured;
//! - [`textbook`]: the Kalman filter with the correlated update written out
//!   (Simon 2006, sec. 7.1): x = F x + B u, P = F P F' + Q, S = H P H' + H M + M' H' + R,
//!   K = (P H' + M) S^-1, x += K nu, P -= K (H P + M'), and ln N(nu; 0, S) per update;
//! - [`Stacked`]: the joint Gaussian of z = [x_0; w_1..w_K; v's] pushed through the
//!   model, conditioned on the measurements (filtered and smoothed means and
//!   covariances) and the log density of the stacked measurement vector.
#![allow(dead_code)]

use estim_core::nalgebra::{DMatrix, DVector, SMatrix, SVector};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// One measurement of a step.
#[derive(Debug, Clone)]
pub struct Meas {
    pub h: DMatrix<f64>,
    pub r: DMatrix<f64>,
    pub y: DVector<f64>,
    /// M_k = Cov(w_k, v_k) (zero when uncorrelated).
    pub cross: DMatrix<f64>,
}

/// One step k: x_k = F x_{k-1} + B u + w, then the measurement if any.
#[derive(Debug, Clone)]
pub struct Step {
    pub f: DMatrix<f64>,
    pub b: DMatrix<f64>,
    pub u: DVector<f64>,
    pub q: DMatrix<f64>,
    pub meas: Option<Meas>,
}

/// The whole problem.
#[derive(Debug, Clone)]
pub struct Plan {
    pub x0: DVector<f64>,
    pub p0: DMatrix<f64>,
    pub steps: Vec<Step>,
}

pub fn random(rng: &mut ChaCha8Rng, r: usize, c: usize) -> DMatrix<f64> {
    DMatrix::from_fn(r, c, |_, _| rng.random_range(-1.0..1.0))
}

/// L L' / dim + floor I.
pub fn spd(rng: &mut ChaCha8Rng, dim: usize, floor: f64) -> DMatrix<f64> {
    let l = random(rng, dim, dim);
    &l * l.transpose() / dim as f64 + DMatrix::identity(dim, dim) * floor
}

pub fn s<const R: usize, const C: usize>(m: &DMatrix<f64>) -> SMatrix<f64, R, C> {
    SMatrix::from_fn(|r, c| m[(r, c)])
}

pub fn sv<const R: usize>(v: &DVector<f64>) -> SVector<f64, R> {
    SVector::from_fn(|r, _| v[r])
}

pub fn dm<const R: usize, const C: usize>(m: &SMatrix<f64, R, C>) -> DMatrix<f64> {
    DMatrix::from_column_slice(R, C, m.as_slice())
}

pub fn dv<const R: usize>(v: &SVector<f64, R>) -> DVector<f64> {
    DVector::from_column_slice(v.as_slice())
}

/// max |a - b| / max(max |b|, floor).
pub fn rel(a: &DMatrix<f64>, b: &DMatrix<f64>, floor: f64) -> f64 {
    (a - b).amax() / b.amax().max(floor)
}

/// Options of [`make_plan`].
#[derive(Debug, Clone, Copy)]
pub struct Shape {
    pub n: usize,
    pub m: usize,
    pub u: usize,
    pub steps: usize,
    /// Probability that a step is measured.
    pub measured: f64,
    /// Give M_k != 0 to measured steps (only those whose previous step was measured,
    /// or the first, when `one_step_only`).
    pub correlated: bool,
    pub one_step_only: bool,
    /// Per-step random F, B, H, Q, R (else the first step's, for every step).
    pub time_varying: bool,
}

/// A seeded plan; the measurements are sampled from the model (with x_0 ~ N(x0, P0)).
pub fn make_plan(shape: Shape, seed: u64) -> Plan {
    let Shape { n, m, u, .. } = shape;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let x0 = DVector::from_fn(n, |_, _| rng.random_range(-2.0..2.0));
    let p0 = spd(&mut rng, n, 0.2);
    let mut steps: Vec<Step> = Vec::with_capacity(shape.steps);
    let mut previous_measured = true;
    // (F, B, Q, H, R, M): drawn for every step, or once.
    let mut model = None;
    for k in 0..shape.steps {
        if shape.time_varying || k == 0 {
            let f = DMatrix::identity(n, n) * 0.9 + random(&mut rng, n, n) * (0.3 / n as f64);
            let b = random(&mut rng, n, u);
            // The joint [[Q, M], [M', R]] of (w_k, v_k): SPD, so M is a valid cross term.
            let joint = spd(&mut rng, n + m, 0.05);
            let h = random(&mut rng, m, n);
            model = Some((
                f,
                b,
                joint.view((0, 0), (n, n)).into_owned(),
                h,
                joint.view((n, n), (m, m)).into_owned(),
                joint.view((0, n), (n, m)).into_owned(),
            ));
        }
        let (f, b, q, h, r, cross) = model.clone().expect("drawn at k = 0");
        let u_k = DVector::from_fn(u, |_, _| rng.random_range(-1.0..1.0));
        let measured = rng.random_bool(shape.measured);
        let correlate = shape.correlated && (!shape.one_step_only || previous_measured);
        let meas = measured.then(|| Meas {
            h,
            r,
            y: DVector::zeros(m),
            cross: if correlate {
                cross
            } else {
                DMatrix::zeros(n, m)
            },
        });
        previous_measured = measured;
        steps.push(Step {
            f,
            b,
            u: u_k,
            q,
            meas,
        });
    }
    let mut plan = Plan { x0, p0, steps };
    sample(&mut plan, &mut rng);
    plan
}

/// Draw x_0, w's and v's (with their cross-covariances) and fill in the y's.
fn sample(plan: &mut Plan, rng: &mut ChaCha8Rng) {
    let n = plan.x0.len();
    let normal = |rng: &mut ChaCha8Rng, d: usize| {
        // Sum of 12 uniforms minus 6: unit variance, mean zero (enough for test data).
        DVector::from_fn(d, |_, _| {
            (0..12).map(|_| rng.random_range(0.0..1.0)).sum::<f64>() - 6.0
        })
    };
    let chol = |c: &DMatrix<f64>| c.clone().cholesky().expect("SPD").l();
    let mut x = &plan.x0 + chol(&plan.p0) * normal(rng, n);
    for step in &mut plan.steps {
        let (w, v) = match &step.meas {
            Some(meas) => {
                let m = meas.r.nrows();
                let mut joint = DMatrix::zeros(n + m, n + m);
                joint.view_mut((0, 0), (n, n)).copy_from(&step.q);
                joint.view_mut((n, n), (m, m)).copy_from(&meas.r);
                joint.view_mut((0, n), (n, m)).copy_from(&meas.cross);
                joint
                    .view_mut((n, 0), (m, n))
                    .copy_from(&meas.cross.transpose());
                let e = chol(&joint) * normal(rng, n + m);
                (e.rows(0, n).into_owned(), Some(e.rows(n, m).into_owned()))
            }
            None => (chol(&step.q) * normal(rng, n), None),
        };
        x = &step.f * &x + &step.b * &step.u + w;
        if let (Some(meas), Some(v)) = (step.meas.as_mut(), v) {
            meas.y = &meas.h * &x + v;
        }
    }
}

/// The textbook filter's output per step.
#[derive(Debug, Clone)]
pub struct Reference {
    pub states: Vec<DVector<f64>>,
    pub covariances: Vec<DMatrix<f64>>,
    /// Q_acc after each step's predict (before its update).
    pub accumulated: Vec<DMatrix<f64>>,
    pub log_likelihood: f64,
}

/// The textbook correlated Kalman filter over the plan (see the module docs).
pub fn textbook(plan: &Plan) -> Reference {
    let mut x = plan.x0.clone();
    let mut p = plan.p0.clone();
    let n = x.len();
    let mut q_acc = DMatrix::zeros(n, n);
    let mut out = Reference {
        states: Vec::new(),
        covariances: Vec::new(),
        accumulated: Vec::new(),
        log_likelihood: 0.0,
    };
    for step in &plan.steps {
        x = &step.f * &x + &step.b * &step.u;
        p = &step.f * &p * step.f.transpose() + &step.q;
        q_acc = &step.f * &q_acc * step.f.transpose() + &step.q;
        out.accumulated.push(q_acc.clone());
        if let Some(meas) = &step.meas {
            let (h, r, mc) = (&meas.h, &meas.r, &meas.cross);
            let s = h * &p * h.transpose() + h * mc + mc.transpose() * h.transpose() + r;
            let lu = s.clone().lu();
            let s_inv = lu.try_inverse().expect("S invertible");
            let k = (&p * h.transpose() + mc) * &s_inv;
            let nu = &meas.y - h * &x;
            let nis = (nu.transpose() * &s_inv * &nu)[(0, 0)];
            let m = nu.len() as f64;
            out.log_likelihood += -0.5
                * (m * (2.0 * std::f64::consts::PI).ln() + s.clone().lu().determinant().ln() + nis);
            x = &x + &k * nu;
            p = &p - &k * (h * &p + mc.transpose());
            q_acc = DMatrix::zeros(n, n);
        }
        out.states.push(x.clone());
        out.covariances.push(p.clone());
    }
    out
}

/// z = [x_0; w_1..w_K; v's] ~ N(mean, cov); x_k = A_k z + c_k, y = T z + d.
pub struct Stacked {
    mean: DVector<f64>,
    cov: DMatrix<f64>,
    states: Vec<(DMatrix<f64>, DVector<f64>)>,
    /// One per measurement, in step order.
    rows: Vec<Rows>,
}

/// A measurement's rows of y = T z + d.
struct Rows {
    step: usize,
    t: DMatrix<f64>,
    d: DVector<f64>,
    y: DVector<f64>,
}

impl Stacked {
    pub fn new(plan: &Plan) -> Self {
        let n = plan.x0.len();
        let k = plan.steps.len();
        let sizes: usize = plan
            .steps
            .iter()
            .filter_map(|s| s.meas.as_ref().map(|m| m.r.nrows()))
            .sum();
        let dim = n + k * n + sizes;
        let mut mean = DVector::zeros(dim);
        mean.rows_mut(0, n).copy_from(&plan.x0);
        let mut cov = DMatrix::zeros(dim, dim);
        cov.view_mut((0, 0), (n, n)).copy_from(&plan.p0);
        let mut a = DMatrix::zeros(n, dim);
        a.view_mut((0, 0), (n, n)).fill_with_identity();
        let mut c = DVector::zeros(n);
        let mut states = vec![(a.clone(), c.clone())];
        let mut rows = Vec::new();
        let mut v_at = n + k * n;
        for (j, step) in plan.steps.iter().enumerate() {
            let w = n + j * n;
            cov.view_mut((w, w), (n, n)).copy_from(&step.q);
            a = &step.f * &a;
            for r in 0..n {
                a[(r, w + r)] += 1.0;
            }
            c = &step.f * &c + &step.b * &step.u;
            if let Some(meas) = &step.meas {
                let m = meas.r.nrows();
                cov.view_mut((v_at, v_at), (m, m)).copy_from(&meas.r);
                cov.view_mut((w, v_at), (n, m)).copy_from(&meas.cross);
                cov.view_mut((v_at, w), (m, n))
                    .copy_from(&meas.cross.transpose());
                let mut t = &meas.h * &a;
                for r in 0..m {
                    t[(r, v_at + r)] += 1.0;
                }
                rows.push(Rows {
                    step: j + 1,
                    t,
                    d: &meas.h * &c,
                    y: meas.y.clone(),
                });
                v_at += m;
            }
            states.push((a.clone(), c.clone()));
        }
        Self {
            mean,
            cov,
            states,
            rows,
        }
    }

    /// The stacked (T, d, y) of the measurements of steps <= `upto`.
    fn measurements(&self, upto: usize) -> Option<(DMatrix<f64>, DVector<f64>, DVector<f64>)> {
        let chosen: Vec<_> = self.rows.iter().filter(|r| r.step <= upto).collect();
        if chosen.is_empty() {
            return None;
        }
        let total: usize = chosen.iter().map(|r| r.t.nrows()).sum();
        let dim = self.mean.len();
        let (mut t, mut d, mut y) = (
            DMatrix::zeros(total, dim),
            DVector::zeros(total),
            DVector::zeros(total),
        );
        let mut at = 0;
        for rows in chosen {
            let m = rows.t.nrows();
            t.rows_mut(at, m).copy_from(&rows.t);
            d.rows_mut(at, m).copy_from(&rows.d);
            y.rows_mut(at, m).copy_from(&rows.y);
            at += m;
        }
        Some((t, d, y))
    }

    /// E[x_k | y's of steps <= upto] and its covariance (plain Gaussian conditioning,
    /// LU inverse of the measurements' covariance).
    pub fn conditional(&self, k: usize, upto: usize) -> (DVector<f64>, DMatrix<f64>) {
        let (a, c) = &self.states[k];
        let mean = a * &self.mean + c;
        let cov = a * &self.cov * a.transpose();
        let Some((t, d, y)) = self.measurements(upto) else {
            return (mean, cov);
        };
        let syy = &t * &self.cov * t.transpose();
        let sxy = a * &self.cov * t.transpose();
        let gain = &sxy * syy.lu().try_inverse().expect("Cov(y) invertible");
        let innovation = y - (&t * &self.mean + d);
        (mean + &gain * innovation, cov - &gain * sxy.transpose())
    }

    /// ln p(all y's): the stacked measurement vector's Gaussian log density
    /// (nalgebra's Cholesky).
    pub fn log_density(&self) -> f64 {
        let Some((t, d, y)) = self.measurements(usize::MAX) else {
            return 0.0;
        };
        let syy = &t * &self.cov * t.transpose();
        let chol = syy.cholesky().expect("Cov(y) SPD");
        let log_det = 2.0 * chol.l().diagonal().iter().map(|v| v.ln()).sum::<f64>();
        let r = y - (&t * &self.mean + d);
        let quad = r.dot(&chol.solve(&r));
        -0.5 * (r.len() as f64 * (2.0 * std::f64::consts::PI).ln() + log_det + quad)
    }
}
