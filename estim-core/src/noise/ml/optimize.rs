//! The optimiser behind [`super::maximize`] and [`super::maximize_dyn`], written once
//! over parameter slices: the bound transforms, exact derivatives by dual numbers, the
//! L-BFGS global phase, the capped approach steps and the damped Newton polish (the
//! module docs of [`super`] describe each).

use argmin::core::{CostFunction, Executor, Gradient, State};
use argmin::solver::linesearch::MoreThuenteLineSearch;
use argmin::solver::quasinewton::LBFGS;
use nalgebra::{DMatrix, DVector};
use num_dual::{Dual64, HyperDual64};

use super::{FitOptions, FitStop};
use crate::{Error, Result};

/// A log-likelihood as the optimiser sees it: values, exact gradients and observed
/// information at parameter vectors of a fixed length.
pub(super) trait Evaluate {
    /// ln p(y | theta).
    fn value(&self, theta: &[f64]) -> Result<f64>;
    /// ln p and d ln p / d theta (0 where `fixed`).
    fn gradient(&self, theta: &[f64], fixed: &[bool]) -> Result<(f64, Vec<f64>)>;
    /// -d^2 ln p / d theta^2 (zero rows and columns where `fixed`).
    fn information(&self, theta: &[f64], fixed: &[bool]) -> Result<DMatrix<f64>>;
}

/// ln p and its gradient from one [`Dual64`] pass per free parameter (`eval` maps the
/// dual parameter vector to the dual log-likelihood); ln p alone by `value` when every
/// parameter is fixed.
pub(super) fn gradient_by(
    theta: &[f64],
    fixed: &[bool],
    eval: impl Fn(&[Dual64]) -> Result<Dual64>,
    value: impl Fn() -> Result<f64>,
) -> Result<(f64, Vec<f64>)> {
    let mut grad = vec![0.0; theta.len()];
    let mut at = None;
    for i in (0..theta.len()).filter(|&i| !fixed[i]) {
        let dual: Vec<Dual64> = theta
            .iter()
            .enumerate()
            .map(|(j, &t)| Dual64::new(t, f64::from(j == i)))
            .collect();
        let l = eval(&dual)?;
        grad[i] = l.eps;
        at = Some(l.re);
    }
    let at = match at {
        Some(v) => v,
        None => value()?,
    };
    Ok((at, grad))
}

/// The observed information from one [`HyperDual64`] pass per pair of free parameters.
pub(super) fn information_by(
    theta: &[f64],
    fixed: &[bool],
    eval: impl Fn(&[HyperDual64]) -> Result<HyperDual64>,
) -> Result<DMatrix<f64>> {
    let p = theta.len();
    let mut info = DMatrix::zeros(p, p);
    for i in (0..p).filter(|&i| !fixed[i]) {
        for j in (i..p).filter(|&j| !fixed[j]) {
            let hyper: Vec<HyperDual64> = theta
                .iter()
                .enumerate()
                .map(|(k, &t)| HyperDual64::new(t, f64::from(k == i), f64::from(k == j), 0.0))
                .collect();
            let h = -eval(&hyper)?.eps1eps2;
            info[(i, j)] = h;
            info[(j, i)] = h;
        }
    }
    Ok(info)
}

/// `parameter {i}`'s interval check shared by the bounds types: not NaN, lower <= upper,
/// a fixed value finite.
pub(super) fn check_interval(i: usize, lo: f64, hi: f64) -> Result<()> {
    if lo.is_nan() || hi.is_nan() || lo > hi || (lo == hi && !lo.is_finite()) {
        return Err(Error::InvalidParameter {
            name: "bounds",
            reason: format!("parameter {i}: lower {lo} and upper {hi} are not an interval"),
        });
    }
    Ok(())
}

/// theta of the unconstrained coordinate phi in [lo, hi] (module docs of [`super`]).
fn theta_at(lo: f64, hi: f64, phi: f64) -> f64 {
    match (lo.is_finite(), hi.is_finite()) {
        _ if lo == hi => lo,
        (false, false) => phi,
        (true, false) => lo + phi.exp(),
        (false, true) => hi - phi.exp(),
        (true, true) => lo + (hi - lo) / (1.0 + (-phi).exp()),
    }
}

/// d theta / d phi.
fn derivative(lo: f64, hi: f64, phi: f64) -> f64 {
    match (lo.is_finite(), hi.is_finite()) {
        _ if lo == hi => 0.0,
        (false, false) => 1.0,
        (true, false) => phi.exp(),
        (false, true) => -phi.exp(),
        (true, true) => {
            let s = 1.0 / (1.0 + (-phi).exp());
            (hi - lo) * s * (1.0 - s)
        }
    }
}

/// d^2 theta / d phi^2.
fn second_derivative(lo: f64, hi: f64, phi: f64) -> f64 {
    match (lo.is_finite(), hi.is_finite()) {
        _ if lo == hi => 0.0,
        (false, false) => 0.0,
        (true, false) => phi.exp(),
        (false, true) => -phi.exp(),
        (true, true) => {
            let s = 1.0 / (1.0 + (-phi).exp());
            (hi - lo) * s * (1.0 - s) * (1.0 - 2.0 * s)
        }
    }
}

/// phi of parameter `i` = theta, which must lie strictly inside open bounds.
fn phi_at(i: usize, lo: f64, hi: f64, theta: f64) -> Result<f64> {
    let inside = theta.is_finite()
        && (lo == hi || ((!lo.is_finite() || theta > lo) && (!hi.is_finite() || theta < hi)));
    if !inside {
        return Err(Error::InvalidParameter {
            name: "initial",
            reason: format!(
                "parameter {i} = {theta} must be finite and strictly inside ({lo}, {hi})"
            ),
        });
    }
    Ok(match (lo.is_finite(), hi.is_finite()) {
        _ if lo == hi => 0.0,
        (false, false) => theta,
        (true, false) => (theta - lo).ln(),
        (false, true) => (hi - theta).ln(),
        (true, true) => {
            let s = (theta - lo) / (hi - lo);
            (s / (1.0 - s)).ln()
        }
    })
}

/// The largest move of a bounded parameter's unconstrained coordinate in one step of
/// the approach phase: a factor e^3 = 20 on a variance's scale.
const APPROACH_CAP: f64 = 3.0;

/// What [`fit`] found, with run-time sizes (the callers convert).
pub(super) struct Found {
    pub theta: DVector<f64>,
    pub log_likelihood: f64,
    pub gradient: DVector<f64>,
    pub information: DMatrix<f64>,
    pub covariance: Option<DMatrix<f64>>,
    pub standard_errors: Option<DVector<f64>>,
    pub iterations: u64,
    pub converged: bool,
    pub termination: String,
    pub stop: FitStop,
}

/// The problem argmin sees: -ln p over the free parameters' unconstrained coordinates.
struct Objective<'a, E> {
    model: &'a E,
    lower: &'a [f64],
    upper: &'a [f64],
    free: Vec<usize>,
    fixed: Vec<bool>,
}

impl<E> Clone for Objective<'_, E> {
    fn clone(&self) -> Self {
        Self {
            model: self.model,
            lower: self.lower,
            upper: self.upper,
            free: self.free.clone(),
            fixed: self.fixed.clone(),
        }
    }
}

impl<E: Evaluate> Objective<'_, E> {
    /// theta of the free parameters' unconstrained coordinates (fixed ones at their
    /// value).
    fn theta(&self, phi: &[f64]) -> Vec<f64> {
        let mut theta = self.lower.to_vec();
        for (&i, &p) in self.free.iter().zip(phi) {
            theta[i] = theta_at(self.lower[i], self.upper[i], p);
        }
        theta
    }

    fn derivative(&self, i: usize, phi: f64) -> f64 {
        derivative(self.lower[i], self.upper[i], phi)
    }

    fn bounded(&self, i: usize) -> bool {
        self.lower[i].is_finite() || self.upper[i].is_finite()
    }
}

impl<E: Evaluate> CostFunction for Objective<'_, E> {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, phi: &Vec<f64>) -> std::result::Result<f64, argmin::core::Error> {
        Ok(-self.model.value(&self.theta(phi))?)
    }
}

impl<E: Evaluate> Gradient for Objective<'_, E> {
    type Param = Vec<f64>;
    type Gradient = Vec<f64>;
    fn gradient(&self, phi: &Vec<f64>) -> std::result::Result<Vec<f64>, argmin::core::Error> {
        let theta = self.theta(phi);
        let (_, grad) = self.model.gradient(&theta, &self.fixed)?;
        Ok(self
            .free
            .iter()
            .zip(phi)
            .map(|(&i, &p)| -grad[i] * self.derivative(i, p))
            .collect())
    }
}

/// Maximise `model` inside [lower, upper] (equal bounds fix a parameter) from
/// `initial`: the algorithm of [`super::maximize`], for parameter vectors of any
/// length (the three slices have the same, checked by the callers).
pub(super) fn fit<E: Evaluate>(
    model: &E,
    initial: &[f64],
    lower: &[f64],
    upper: &[f64],
    options: &FitOptions,
) -> Result<Found> {
    let p = initial.len();
    let fixed: Vec<bool> = (0..p).map(|i| lower[i] == upper[i]).collect();
    let free: Vec<usize> = (0..p).filter(|&i| !fixed[i]).collect();
    let mut phi = free
        .iter()
        .map(|&i| phi_at(i, lower[i], upper[i], initial[i]))
        .collect::<Result<Vec<f64>>>()?;
    let objective = Objective {
        model,
        lower,
        upper,
        free: free.clone(),
        fixed: fixed.clone(),
    };
    let mut iterations = 0;
    let mut termination = String::from("no free parameter");
    let mut newton_stop = FitStop::NoFreeParameter;
    if !free.is_empty() {
        // Global phase: L-BFGS, restarted from its best point with a fresh memory when
        // it stops (cost tolerance, failed line search) short of the gradient tolerance.
        for _ in 0..=options.restarts {
            let solver = LBFGS::new(MoreThuenteLineSearch::new(), options.memory.max(1))
                .with_tolerance_grad(options.gradient_tolerance)
                .and_then(|s| s.with_tolerance_cost(options.cost_tolerance))
                .map_err(optimizer_error)?;
            let budget = options.max_iterations.saturating_sub(iterations).max(1);
            let result = Executor::new(objective.clone(), solver)
                .configure(|state| state.param(phi.clone()).max_iters(budget))
                .run()
                .map_err(model_or_optimizer_error)?;
            let state = result.state();
            iterations += state.get_iter();
            let mut moved = false;
            if let Some(best) = state.get_best_param() {
                moved = *best != phi;
                phi.clone_from(best);
            }
            termination = format!("{:?}", state.get_termination_status());
            let grad = objective.gradient(&phi).map_err(model_or_optimizer_error)?;
            let norm = grad.iter().map(|g| g * g).sum::<f64>().sqrt();
            if norm <= options.gradient_tolerance || iterations >= options.max_iterations {
                break;
            }
            // No progress at all (from a start far from the optimum, L-BFGS's first
            // step, the gradient itself, can overflow exp(phi) and end the line
            // search): approach with capped steps, then L-BFGS again.
            if !moved && !approach(&objective, &mut phi, options.newton_steps)? {
                break;
            }
        }
        // Local phase: Newton steps with the exact Hessian (quadratic convergence), each
        // halved until -ln p decreases enough (Armijo); stops when the Newton decrement
        // is below tolerance or the Hessian is not positive definite.
        newton_stop = FitStop::NewtonStepLimit;
        for _ in 0..options.newton_steps {
            match newton_step(&objective, &phi)? {
                Ok((next, decrement)) if decrement / 2.0 > options.decrement_tolerance => {
                    phi = next;
                }
                Ok((next, _)) => {
                    phi = next;
                    newton_stop = FitStop::InformationNotPositiveDefinite;
                    break;
                }
                Err(failure) => {
                    newton_stop = failure;
                    break;
                }
            }
        }
    }
    let theta = objective.theta(&phi);
    let (log_likelihood, grad) = model.gradient(&theta, &fixed)?;
    let information = model.information(&theta, &fixed)?;
    let grad = DVector::from_vec(grad);
    let covariance = free_inverse(&information, &free);
    let standard_errors = covariance
        .as_ref()
        .map(|c| DVector::from_fn(p, |i, _| c[(i, i)].max(0.0).sqrt()));
    let decrement = covariance.as_ref().map(|c| grad.dot(&(c * &grad)));
    let converged = free.is_empty()
        || decrement.is_some_and(|d| d.is_finite() && d / 2.0 <= options.decrement_tolerance);
    let stop = match newton_stop {
        FitStop::NoFreeParameter => FitStop::NoFreeParameter,
        _ if converged => FitStop::Converged,
        // A small decrement where Newton ended, but not at the returned point.
        FitStop::InformationNotPositiveDefinite if covariance.is_some() => FitStop::NewtonStepLimit,
        other => other,
    };
    Ok(Found {
        theta: DVector::from_vec(theta),
        log_likelihood,
        gradient: grad,
        information,
        covariance,
        standard_errors,
        iterations,
        converged,
        termination,
        stop,
    })
}

/// One damped Newton step on -ln p in the unconstrained coordinates: the new point
/// and the Newton decrement g' H^-1 g at the old one, or why there is none.
fn newton_step<E: Evaluate>(
    objective: &Objective<'_, E>,
    phi: &[f64],
) -> Result<std::result::Result<(Vec<f64>, f64), FitStop>> {
    Ok(match safeguarded_step(objective, phi, None)? {
        Step::Taken(next, decrement) => Ok((next, decrement)),
        // Not produced without a cap.
        Step::Capped(..) => Err(FitStop::NoDecrease),
        Step::Failed(why) => Err(why),
    })
}

/// Up to `steps` capped steps ([`safeguarded_step`] with [`APPROACH_CAP`]) from `phi`,
/// ending early at the first full Newton step; whether `phi` moved.
fn approach<E: Evaluate>(
    objective: &Objective<'_, E>,
    phi: &mut Vec<f64>,
    steps: usize,
) -> Result<bool> {
    let mut moved = false;
    for _ in 0..steps {
        match safeguarded_step(objective, phi, Some(APPROACH_CAP))? {
            Step::Capped(next) => *phi = next,
            Step::Taken(next, _) => {
                *phi = next;
                return Ok(true);
            }
            Step::Failed(_) => break,
        }
        moved = true;
    }
    Ok(moved)
}

/// What [`safeguarded_step`] did.
enum Step {
    /// A full-length Newton direction, damped until -ln p decreased (point, decrement).
    Taken(Vec<f64>, f64),
    /// The direction was longer than the cap and was shortened to it (point).
    Capped(Vec<f64>),
    /// No step decreased -ln p, or the Newton direction was not defined: why.
    Failed(FitStop),
}

/// One damped step on -ln p in the unconstrained coordinates. Without a cap: the
/// Newton step (`None` when the Hessian is not positive definite). With `cap`: far from
/// the optimum, where the Hessian may be indefinite and a full step may overflow a
/// bounded parameter's transform (exp(phi)), the direction is Newton's when the Hessian
/// is positive definite, else the gradient scaled by the Hessian's diagonal magnitude;
/// it is shortened so that no bounded coordinate moves by more than `cap`, and halved
/// while -ln p does not decrease (an evaluation that fails counts as no decrease).
fn safeguarded_step<E: Evaluate>(
    objective: &Objective<'_, E>,
    phi: &[f64],
    cap: Option<f64>,
) -> Result<Step> {
    let free = &objective.free;
    let theta = objective.theta(phi);
    let (value, g) = objective.model.gradient(&theta, &objective.fixed)?;
    let info = objective.model.information(&theta, &objective.fixed)?;
    let n = free.len();
    // Chain rule to phi for the cost -ln p: J_i = d theta_i / d phi_i.
    let jac: Vec<f64> = free
        .iter()
        .zip(phi)
        .map(|(&i, &p)| objective.derivative(i, p))
        .collect();
    let curv: Vec<f64> = free
        .iter()
        .zip(phi)
        .map(|(&i, &p)| second_derivative(objective.lower[i], objective.upper[i], p))
        .collect();
    let grad = DVector::from_fn(n, |r, _| -g[free[r]] * jac[r]);
    let hess = DMatrix::from_fn(n, n, |r, c| {
        let diag = if r == c { -g[free[r]] * curv[r] } else { 0.0 };
        info[(free[r], free[c])] * jac[r] * jac[c] + diag
    });
    let mut step = match (hess.clone().cholesky(), cap) {
        (Some(chol), _) => -chol.solve(&grad),
        (None, None) => return Ok(Step::Failed(FitStop::HessianNotPositiveDefinite)),
        (None, Some(_)) => DVector::from_fn(n, |r, _| {
            -grad[r] / hess[(r, r)].abs().max(f64::MIN_POSITIVE)
        }),
    };
    let longest = free
        .iter()
        .zip(step.iter())
        .filter(|(&i, _)| objective.bounded(i))
        .map(|(_, d)| d.abs())
        .fold(0.0, f64::max);
    let capped = match cap {
        Some(cap) if longest > cap => {
            step *= cap / longest;
            true
        }
        _ => false,
    };
    let decrement = -grad.dot(&step);
    if !decrement.is_finite() || (capped && decrement <= 0.0) {
        return Ok(Step::Failed(FitStop::NoDecrease));
    }
    let mut t = 1.0;
    let mut refused = None;
    for _ in 0..40 {
        let next: Vec<f64> = phi
            .iter()
            .zip(step.iter())
            .map(|(p, d)| p + t * d)
            .collect();
        let candidate = objective.model.value(&objective.theta(&next));
        if let Err(error) = &candidate {
            refused = Some(error.clone());
        }
        if let Ok(l) = candidate {
            if capped && l.is_finite() && -l < -value {
                return Ok(Step::Capped(next));
            }
            if !capped
                && (-l <= -value - 1e-4 * t * decrement
                    || decrement / 2.0 <= f64::EPSILON * value.abs())
            {
                return Ok(Step::Taken(next, decrement));
            }
        }
        t *= 0.5;
    }
    Ok(Step::Failed(match refused {
        Some(error) => FitStop::Refused { error },
        None => FitStop::NoDecrease,
    }))
}

fn model_or_optimizer_error(e: argmin::core::Error) -> Error {
    match e.downcast::<Error>() {
        Ok(model_error) => model_error,
        Err(other) => optimizer_error(other),
    }
}

fn optimizer_error(e: impl std::fmt::Display) -> Error {
    Error::InvalidParameter {
        name: "optimizer",
        reason: e.to_string(),
    }
}

/// The inverse of the information restricted to the free parameters, embedded in a
/// p x p matrix (zeros elsewhere); `None` unless that block is positive definite.
fn free_inverse(information: &DMatrix<f64>, free: &[usize]) -> Option<DMatrix<f64>> {
    let n = free.len();
    let block = DMatrix::from_fn(n, n, |r, c| information[(free[r], free[c])]);
    let inverse = block.cholesky()?.inverse();
    let p = information.nrows();
    let mut out = DMatrix::zeros(p, p);
    for (r, &i) in free.iter().enumerate() {
        for (c, &j) in free.iter().enumerate() {
            out[(i, j)] = inverse[(r, c)];
        }
    }
    Some(out)
}
