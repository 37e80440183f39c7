//! A test model whose measurement noise shares the process noise of a window of
//! several steps (a learned sensor fed the same accelerometer samples as the process):
//! two-axis constant velocity, x = [p_x, v_x, p_y, v_y], step dt, acceleration a_j ~
//! N(0, diag(q_x, q_y)) entering as G a_j, G = [dt^2/2, dt] per axis. Every `interval`
//! steps the position is measured (a fix carried forward with the same accelerometer)
//! with noise
//!
//! ```text
//! v = c dt sum_{j in the last `window` steps} a_j + e,    e ~ N(0, r I_2)
//! ```
//!
//! so, per axis, D_j = Cov(G a_j, v) = c dt q G for each step of the window and
//! Var(v) = c^2 dt^2 window q + r. theta = [q_x, q_y, r, c]; c = 0 is M = 0.
#![allow(dead_code)]

use estim_core::nalgebra::{SMatrix, SVector};
use estim_core::noise::ml::LogLikelihood;
use estim_core::numeric::lit;
use estim_core::window::StepWindow;
use estim_core::{
    FilterConfig, JointCheck, KalmanFilter, Result, Scalar, StateAndCovariance,
    WindowedCrossCovariance,
};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// The model's constants (all but theta).
#[derive(Debug, Clone, Copy)]
pub struct Setup {
    pub dt: f64,
    pub interval: usize,
    pub window: usize,
    pub updates: usize,
    pub initial_std: [f64; 4],
}

impl Default for Setup {
    fn default() -> Self {
        Self {
            dt: 0.1,
            interval: 4,
            window: 3,
            updates: 300,
            initial_std: [1.0, 0.5, 1.0, 0.5],
        }
    }
}

/// The simulated measurements and the setup.
#[derive(Debug, Clone)]
pub struct Dataset {
    pub setup: Setup,
    pub measurements: Vec<[f64; 2]>,
}

pub fn transition<T: Scalar>(dt: f64) -> SMatrix<T, 4, 4> {
    let mut f = SMatrix::<T, 4, 4>::identity();
    f[(0, 1)] = lit(dt);
    f[(2, 3)] = lit(dt);
    f
}

pub fn observation<T: Scalar>() -> SMatrix<T, 2, 4> {
    let mut h = SMatrix::<T, 2, 4>::zeros();
    h[(0, 0)] = T::one();
    h[(1, 2)] = T::one();
    h
}

/// Q = blockdiag(q_x G G', q_y G G').
pub fn process_noise<T: Scalar>(dt: f64, qx: T, qy: T) -> SMatrix<T, 4, 4> {
    let g = [dt * dt / 2.0, dt];
    let mut q = SMatrix::<T, 4, 4>::zeros();
    for (axis, var) in [(0, qx), (2, qy)] {
        for r in 0..2 {
            for c in 0..2 {
                q[(axis + r, axis + c)] = var * lit::<T>(g[r] * g[c]);
            }
        }
    }
    q
}

/// D_j (the same for each of the window's steps).
pub struct SharedAcceleration<T: Scalar> {
    pub window: usize,
    pub d: SMatrix<T, 4, 2>,
}

impl<T: Scalar> WindowedCrossCovariance<T, SVector<T, 4>, (), 4, 2> for SharedAcceleration<T> {
    fn window_steps(&self) -> usize {
        self.window
    }
    fn step_cross_covariances(
        &self,
        window: &StepWindow<'_, T, SVector<T, 4>, (), 4>,
        sink: &mut dyn FnMut(&SMatrix<T, 4, 2>) -> Result<()>,
    ) -> Result<()> {
        for _ in window.iter() {
            sink(&self.d)?;
        }
        Ok(())
    }
}

impl Dataset {
    /// Draw a dataset for `theta` = [q_x, q_y, r, c] (seeded).
    pub fn simulate(setup: Setup, theta: [f64; 4], seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut normal = move || -> f64 { StandardNormal.sample(&mut rng) };
        let [qx, qy, r, c] = theta;
        let f = transition::<f64>(setup.dt);
        let mut x = SVector::<f64, 4>::from_fn(|i, _| setup.initial_std[i] * normal());
        let mut recent: std::collections::VecDeque<[f64; 2]> = Default::default();
        let mut measurements = Vec::with_capacity(setup.updates);
        for step in 1..=setup.updates * setup.interval {
            let a = [qx.sqrt() * normal(), qy.sqrt() * normal()];
            x = f * x;
            let g = [setup.dt * setup.dt / 2.0, setup.dt];
            x[0] += g[0] * a[0];
            x[1] += g[1] * a[0];
            x[2] += g[0] * a[1];
            x[3] += g[1] * a[1];
            recent.push_back(a);
            if recent.len() > setup.window {
                recent.pop_front();
            }
            if step % setup.interval == 0 {
                let shared = |axis: usize| recent.iter().map(|a| a[axis]).sum::<f64>() * setup.dt;
                let v = [
                    c * shared(0) + r.sqrt() * normal(),
                    c * shared(1) + r.sqrt() * normal(),
                ];
                measurements.push([x[0] + v[0], x[2] + v[1]]);
            }
        }
        Self {
            setup,
            measurements,
        }
    }
}

impl LogLikelihood<4> for Dataset {
    fn log_likelihood<T: Scalar>(&self, theta: &SVector<T, 4>) -> Result<T> {
        let s = self.setup;
        let (qx, qy, r, c) = (theta[0], theta[1], theta[2], theta[3]);
        let q = process_noise(s.dt, qx, qy);
        let h = observation::<T>();
        let (g0, g1, dt) = (lit::<T>(s.dt * s.dt / 2.0), lit::<T>(s.dt), lit::<T>(s.dt));
        let mut d = SMatrix::<T, 4, 2>::zeros();
        let mut var_v = SMatrix::<T, 2, 2>::identity() * r;
        for (axis, var) in [(0, qx), (1, qy)] {
            d[(2 * axis, axis)] = c * dt * var * g0;
            d[(2 * axis + 1, axis)] = c * dt * var * g1;
            var_v[(axis, axis)] += c * c * dt * dt * var * lit::<T>(s.window as f64);
        }
        let p0 = SMatrix::<T, 4, 4>::from_diagonal(&SVector::from_fn(|i, _| {
            lit::<T>(s.initial_std[i] * s.initial_std[i])
        }));
        let initial = StateAndCovariance::new(SVector::zeros(), p0)?;
        let config = FilterConfig::builder()
            .window_capacity(s.window)
            .joint_check(JointCheck::Skip)
            .build()?;
        let mut kf = KalmanFilter::new(transition(s.dt), q, h, var_v, initial)?.with_config(config);
        let cross = SharedAcceleration {
            window: s.window,
            d,
        };
        for y in &self.measurements {
            for _ in 0..s.interval {
                kf.predict()?;
            }
            kf.update_windowed(&SVector::from([lit::<T>(y[0]), lit::<T>(y[1])]), &cross)?;
        }
        Ok(kf.log_likelihood())
    }
}
