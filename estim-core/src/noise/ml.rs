//! Maximum-likelihood noise parameters: a parameter vector theta maps to the filter's
//! Q(theta), R(theta) and M(theta); the fit maximises the measurements' log-likelihood
//! (every runner reports it, [`crate::UpdateReport::log_likelihood`]) with exact
//! derivatives and gives standard errors from the observed information.
//!
//! ## Model
//!
//! A [`LogLikelihood`] evaluates ln p(y_1..y_K | theta), the sum of the runner's
//! per-update ln N(nu_k; 0, S_k) (with the correlated S and, for windowed M, the
//! conditional Var(v) and E\[v\]). It is written once, generic over the scalar, so the
//! same code runs on `f64` and on dual numbers: the implementation builds Q(theta),
//! R(theta), M(theta) from `theta`, runs a filter over its data and returns the
//! filter's cumulative `log_likelihood()`. A filter's parameters enter only through
//! these matrices; data are converted with [`crate::numeric::lit`].
//!
//! ## Derivatives
//!
//! Forward-mode automatic differentiation ([`num_dual`]): the gradient is P passes of
//! the filter with [`num_dual::Dual64`] (one per free parameter, d/d theta_i in the dual
//! part), the Hessian P (P + 1) / 2 passes with [`num_dual::HyperDual64`] (d^2 / d
//! theta_i d theta_j in the `eps1eps2` part). Both are exact to round-off for the filter
//! as coded, not finite differences. (One pass with num-dual's vector duals, all P
//! derivatives carried together, measured 1.8 times slower on `tests/noise_ml.rs`.)
//!
//! ## Optimiser and bounds
//!
//! [`maximize`] minimises -ln p with argmin's L-BFGS (More-Thuente line search; restarted
//! from its best point when it stops short of its gradient tolerance), then polishes
//! with damped Newton steps on the exact Hessian, over unconstrained coordinates phi,
//! mapped to theta inside [`Bounds`]. When L-BFGS makes no progress at all (from a
//! start far from the optimum its first step, the gradient itself, can overflow
//! exp(phi)), capped steps follow (Newton's direction, or the gradient scaled by the
//! Hessian's diagonal where the Hessian is indefinite), each moving no bounded
//! coordinate by more than 3 in phi (a factor of 20 on a variance), until the Newton
//! step is shorter than that; then L-BFGS again.
//!
//! ```text
//! (-inf, inf): theta = phi                 [lo, inf): theta = lo + exp(phi)
//! (-inf, hi]: theta = hi - exp(phi)        [lo, hi]:  theta = lo + (hi - lo) / (1 + exp(-phi))
//! lo == hi:    theta fixed (not fitted; its standard error is 0)
//! ```
//!
//! so every iterate stays strictly inside the bounds. The bounds are where the model
//! must be valid: variances above 0, and a cross-covariance scale inside the range
//! where the joint covariance [[Q, M], [M', R]] is positive semidefinite (for the
//! paper's `ScaledCorrelation`, |rho| <= 1 / sqrt(q m); for an M built from shared
//! noise, any value). An evaluation that fails inside the bounds ends the fit with
//! that error.
//!
//! ## Standard errors
//!
//! At the optimum theta^, the observed information is I = -d^2 ln p / d theta^2 over the
//! free parameters (in theta's own coordinates, not phi's), its inverse is the
//! asymptotic covariance of theta^ and the standard errors are the square roots of its
//! diagonal (Pawitan 2001, *In All Likelihood*, sec. 2.5 and 9.2). They are `None` when
//! I is not positive definite (a flat or saddle direction, or an optimum on a bound,
//! where the quadratic approximation does not hold).
//!
//! ## Likelihood-ratio test
//!
//! [`likelihood_ratio_test`] compares a fit with a restricted one (e.g. M = 0: fix the
//! cross-covariance scale with lo == hi == 0): Lambda = 2 (ln p_full - ln p_restricted)
//! is asymptotically chi-square with as many degrees of freedom as restrictions (Wilks
//! 1938) when the restricted value is inside the full model's parameter space.
//!
//! ```
//! use estim_core::nalgebra::{Matrix1, SVector, Vector1};
//! use estim_core::noise::ml::{maximize, Bounds, FitOptions, LogLikelihood};
//! use estim_core::numeric::lit;
//! use estim_core::{KalmanFilter, Result, Scalar, StateAndCovariance, Zero};
//!
//! /// A random walk observed in noise; theta = [q, r].
//! struct Walk(Vec<f64>);
//! impl LogLikelihood<2> for Walk {
//!     fn log_likelihood<T: Scalar>(&self, theta: &SVector<T, 2>) -> Result<T> {
//!         let one = Matrix1::new(T::one());
//!         let initial = StateAndCovariance::new(Vector1::new(T::zero()), one * lit::<T>(10.0))?;
//!         let mut kf = KalmanFilter::new(one, one * theta[0], one, one * theta[1], initial)?;
//!         for &y in &self.0 {
//!             kf.step(Some(&Vector1::new(lit(y))), &Zero)?;
//!         }
//!         Ok(kf.log_likelihood())
//!     }
//! }
//! // A walk with step variance 0.09 seen with noise variance 0.04 (uniform draws of
//! // the same variances from a fixed integer sequence, so the example needs no crate).
//! let mut seed = 12345_u64;
//! let mut draw = move || {
//!     seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
//!     ((seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 12f64.sqrt()
//! };
//! let mut x = 0.0;
//! let data = (0..500).map(|_| { x += 0.3 * draw(); x + 0.2 * draw() }).collect();
//! let bounds = Bounds::new(SVector::from([0.0, 0.0]), SVector::from([f64::INFINITY; 2]))?;
//! let fit = maximize(&Walk(data), &SVector::from([1.0, 1.0]), &bounds, &FitOptions::default())?;
//! let se = fit.standard_errors.expect("information positive definite");
//! assert!(fit.converged);
//! assert!((fit.theta[0] - 0.09).abs() < 3.0 * se[0] && (fit.theta[1] - 0.04).abs() < 3.0 * se[1]);
//! # Ok::<(), estim_core::Error>(())
//! ```

use argmin::core::{CostFunction, Executor, Gradient, State};
use argmin::solver::linesearch::MoreThuenteLineSearch;
use argmin::solver::quasinewton::LBFGS;
use nalgebra::{SMatrix, SVector};
use num_dual::{Dual64, HyperDual64};

use crate::{Error, Result, Scalar};

/// The measurements' log-likelihood as a function of P noise parameters, for any
/// scalar (`f64` for values, dual numbers for exact derivatives).
pub trait LogLikelihood<const P: usize> {
    /// ln p(y_1..y_K | theta): typically the cumulative `log_likelihood()` of a runner
    /// built with Q(theta), R(theta), M(theta) and run over the data.
    ///
    /// # Errors
    /// Whatever the filter reports (an invalid covariance, a non-positive-definite S).
    fn log_likelihood<T: Scalar>(&self, theta: &SVector<T, P>) -> Result<T>;
}

/// Lower and upper bounds of each parameter (infinite for none; equal to fix it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounds<const P: usize> {
    lower: SVector<f64, P>,
    upper: SVector<f64, P>,
}

impl<const P: usize> Bounds<P> {
    /// Bounds `lower[i] <= theta_i <= upper[i]`; `lower[i] == upper[i]` fixes theta_i.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] (`bounds`) for a NaN bound, `lower > upper`, or an
    /// infinite fixed value.
    pub fn new(lower: SVector<f64, P>, upper: SVector<f64, P>) -> Result<Self> {
        for i in 0..P {
            let (lo, hi) = (lower[i], upper[i]);
            if lo.is_nan() || hi.is_nan() || lo > hi || (lo == hi && !lo.is_finite()) {
                return Err(Error::InvalidParameter {
                    name: "bounds",
                    reason: format!("parameter {i}: lower {lo} and upper {hi} are not an interval"),
                });
            }
        }
        Ok(Self { lower, upper })
    }

    /// No bounds on any parameter.
    pub fn unbounded() -> Self {
        Self {
            lower: SVector::repeat(f64::NEG_INFINITY),
            upper: SVector::repeat(f64::INFINITY),
        }
    }

    /// Fix parameter `index` at `value` (a restricted model, e.g. M = 0).
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] (`bounds`) for an index out of range or a value
    /// outside the current bounds.
    pub fn fix(mut self, index: usize, value: f64) -> Result<Self> {
        if index >= P || !(self.lower[index] <= value && value <= self.upper[index]) {
            return Err(Error::InvalidParameter {
                name: "bounds",
                reason: format!("cannot fix parameter {index} at {value}: out of range"),
            });
        }
        self.lower[index] = value;
        self.upper[index] = value;
        Ok(self)
    }

    /// The lower bounds.
    pub fn lower(&self) -> &SVector<f64, P> {
        &self.lower
    }

    /// The upper bounds.
    pub fn upper(&self) -> &SVector<f64, P> {
        &self.upper
    }

    /// Whether parameter `i` is fixed.
    pub fn is_fixed(&self, i: usize) -> bool {
        self.lower[i] == self.upper[i]
    }

    /// theta_i of the unconstrained coordinate phi (module docs).
    fn theta_at(&self, i: usize, phi: f64) -> f64 {
        let (lo, hi) = (self.lower[i], self.upper[i]);
        match (lo.is_finite(), hi.is_finite()) {
            _ if lo == hi => lo,
            (false, false) => phi,
            (true, false) => lo + phi.exp(),
            (false, true) => hi - phi.exp(),
            (true, true) => lo + (hi - lo) / (1.0 + (-phi).exp()),
        }
    }

    /// d theta_i / d phi.
    fn derivative(&self, i: usize, phi: f64) -> f64 {
        let (lo, hi) = (self.lower[i], self.upper[i]);
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

    /// d^2 theta_i / d phi^2.
    fn second_derivative(&self, i: usize, phi: f64) -> f64 {
        let (lo, hi) = (self.lower[i], self.upper[i]);
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

    /// phi of theta_i, which must lie strictly inside open bounds.
    fn phi_at(&self, i: usize, theta: f64) -> Result<f64> {
        let (lo, hi) = (self.lower[i], self.upper[i]);
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
}

/// The largest move of a bounded parameter's unconstrained coordinate in one step of
/// [`maximize`]'s approach phase: a factor e^3 = 20 on a variance's scale.
const APPROACH_CAP: f64 = 3.0;

/// Options of [`maximize`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitOptions {
    /// Iteration limit of L-BFGS over all restarts (default 500).
    pub max_iterations: u64,
    /// L-BFGS stops when the gradient of -ln p in the unconstrained coordinates has a
    /// norm below this (default 1e-3; the Newton steps then converge quadratically).
    pub gradient_tolerance: f64,
    /// L-BFGS stops when -ln p changes by less than this between iterations (default
    /// 1e-9).
    pub cost_tolerance: f64,
    /// L-BFGS memory (default 7).
    pub memory: usize,
    /// Restarts of L-BFGS from its best point when it stops with the gradient above
    /// `gradient_tolerance` (default 5).
    pub restarts: usize,
    /// Newton steps with the exact Hessian after L-BFGS (default 20).
    pub newton_steps: usize,
    /// Converged when half the Newton decrement g' I^-1 g (g the gradient, I the observed
    /// information, both in theta) is at most this (default 1e-10): the estimate is then
    /// within sqrt(2 tol) standard errors (Mahalanobis) of the stationary point.
    pub decrement_tolerance: f64,
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            max_iterations: 500,
            gradient_tolerance: 1e-3,
            cost_tolerance: 1e-9,
            memory: 7,
            restarts: 5,
            newton_steps: 20,
            decrement_tolerance: 1e-10,
        }
    }
}

/// The result of [`maximize`].
#[derive(Debug, Clone, PartialEq)]
pub struct MaximumLikelihood<const P: usize> {
    /// The estimate theta^ (fixed parameters at their value).
    pub theta: SVector<f64, P>,
    /// ln p(y | theta^).
    pub log_likelihood: f64,
    /// d ln p / d theta at theta^ (0 for fixed parameters).
    pub gradient: SVector<f64, P>,
    /// Observed information -d^2 ln p / d theta^2 at theta^ (zero rows and columns for
    /// fixed parameters).
    pub information: SMatrix<f64, P, P>,
    /// Its inverse over the free parameters (asymptotic covariance of theta^), `None`
    /// when the information is not positive definite.
    pub covariance: Option<SMatrix<f64, P, P>>,
    /// Square roots of the covariance's diagonal (0 for fixed parameters).
    pub standard_errors: Option<SVector<f64, P>>,
    /// L-BFGS iterations run.
    pub iterations: u64,
    /// Whether the observed information is positive definite and half the Newton
    /// decrement is at most `FitOptions::decrement_tolerance` at the returned point.
    pub converged: bool,
    /// argmin's termination status of the last L-BFGS run, as argmin prints it (for
    /// the record; [`MaximumLikelihood::stop`] is the typed reason the fit ended).
    pub termination: String,
    /// Why the fit ended, typed.
    pub stop: FitStop,
}

/// Why [`maximize`] returned where it did.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum FitStop {
    /// Every parameter is fixed: nothing was fitted.
    NoFreeParameter,
    /// Converged ([`MaximumLikelihood::converged`]): the observed information is
    /// positive definite and half the Newton decrement is at most
    /// [`FitOptions::decrement_tolerance`].
    Converged,
    /// The Newton phase ended (its [`FitOptions::newton_steps`] steps taken, or none
    /// allowed) with half the decrement at the returned point above its tolerance.
    NewtonStepLimit,
    /// The Hessian of -ln p in the unconstrained coordinates is not positive definite
    /// where Newton stopped (a saddle, a flat direction, an optimum on a bound): no
    /// Newton step is defined.
    HessianNotPositiveDefinite,
    /// No damped Newton step (40 halvings) decreased -ln p, and every trial point was
    /// evaluated: the optimum to round-off, or a likelihood too rough for Newton.
    NoDecrease,
    /// The last Newton step's trial points that did not decrease -ln p include points
    /// the model refused: its evaluation failed with `error`, the last one (e.g.
    /// [`Error::InvalidJointCovariance`] from a filter's joint check where theta
    /// leaves the region in which M is a covariance, or
    /// [`Error::InnovationNotPositiveDefinite`]).
    Refused {
        /// The model's error at the last refused trial point.
        error: Error,
    },
    /// Half the Newton decrement reached its tolerance, but the observed information at
    /// the returned point is not positive definite (no standard errors).
    InformationNotPositiveDefinite,
}

/// ln p and its gradient d ln p / d theta at `theta` (exact, one
/// [`num_dual::Dual64`] pass per free parameter; entries of parameters flagged in
/// `fixed` are 0 and not evaluated).
///
/// # Errors
/// The model's errors.
pub fn gradient<L: LogLikelihood<P>, const P: usize>(
    model: &L,
    theta: &SVector<f64, P>,
    fixed: &[bool; P],
) -> Result<(f64, SVector<f64, P>)> {
    let mut grad = SVector::<f64, P>::zeros();
    let mut value = None;
    for i in (0..P).filter(|&i| !fixed[i]) {
        let dual = SVector::<Dual64, P>::from_fn(|j, _| Dual64::new(theta[j], f64::from(j == i)));
        let l = model.log_likelihood(&dual)?;
        grad[i] = l.eps;
        value = Some(l.re);
    }
    let value = match value {
        Some(v) => v,
        None => model.log_likelihood(theta)?,
    };
    Ok((value, grad))
}

/// The observed information -d^2 ln p / d theta^2 at `theta` (exact, one
/// [`num_dual::HyperDual64`] pass per pair of free parameters; rows and columns of
/// parameters flagged in `fixed` are 0).
///
/// # Errors
/// The model's errors.
pub fn observed_information<L: LogLikelihood<P>, const P: usize>(
    model: &L,
    theta: &SVector<f64, P>,
    fixed: &[bool; P],
) -> Result<SMatrix<f64, P, P>> {
    let mut info = SMatrix::<f64, P, P>::zeros();
    for i in (0..P).filter(|&i| !fixed[i]) {
        for j in (i..P).filter(|&j| !fixed[j]) {
            let hyper = SVector::<HyperDual64, P>::from_fn(|k, _| {
                HyperDual64::new(theta[k], f64::from(k == i), f64::from(k == j), 0.0)
            });
            let h = -model.log_likelihood(&hyper)?.eps1eps2;
            info[(i, j)] = h;
            info[(j, i)] = h;
        }
    }
    Ok(info)
}

/// The problem argmin sees: -ln p over the free parameters' unconstrained coordinates.
struct Objective<'a, L, const P: usize> {
    model: &'a L,
    bounds: &'a Bounds<P>,
    free: Vec<usize>,
    fixed: [bool; P],
}

impl<L, const P: usize> Clone for Objective<'_, L, P> {
    fn clone(&self) -> Self {
        Self {
            model: self.model,
            bounds: self.bounds,
            free: self.free.clone(),
            fixed: self.fixed,
        }
    }
}

impl<L: LogLikelihood<P>, const P: usize> Objective<'_, L, P> {
    fn theta(&self, phi: &[f64]) -> SVector<f64, P> {
        theta_of(self.bounds, &self.free, phi)
    }
}

/// theta of the free parameters' unconstrained coordinates (fixed ones at their value).
fn theta_of<const P: usize>(bounds: &Bounds<P>, free: &[usize], phi: &[f64]) -> SVector<f64, P> {
    let mut theta = SVector::from_fn(|i, _| bounds.lower[i]);
    for (&i, &p) in free.iter().zip(phi) {
        theta[i] = bounds.theta_at(i, p);
    }
    theta
}

impl<L: LogLikelihood<P>, const P: usize> CostFunction for Objective<'_, L, P> {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, phi: &Vec<f64>) -> std::result::Result<f64, argmin::core::Error> {
        Ok(-self.model.log_likelihood(&self.theta(phi))?)
    }
}

impl<L: LogLikelihood<P>, const P: usize> Gradient for Objective<'_, L, P> {
    type Param = Vec<f64>;
    type Gradient = Vec<f64>;
    fn gradient(&self, phi: &Vec<f64>) -> std::result::Result<Vec<f64>, argmin::core::Error> {
        let theta = self.theta(phi);
        let (_, grad) = gradient(self.model, &theta, &self.fixed)?;
        Ok(self
            .free
            .iter()
            .zip(phi)
            .map(|(&i, &p)| -grad[i] * self.bounds.derivative(i, p))
            .collect())
    }
}

/// Maximise ln p(y | theta) inside `bounds` from `initial` (module docs: optimiser,
/// coordinates, standard errors).
///
/// # Errors
/// [`Error::InvalidParameter`] (`initial`) for a start outside the open bounds, the
/// model's errors at any evaluated point, and [`Error::InvalidParameter`]
/// (`optimizer`) for an argmin failure (its message).
pub fn maximize<L: LogLikelihood<P>, const P: usize>(
    model: &L,
    initial: &SVector<f64, P>,
    bounds: &Bounds<P>,
    options: &FitOptions,
) -> Result<MaximumLikelihood<P>> {
    let fixed: [bool; P] = std::array::from_fn(|i| bounds.is_fixed(i));
    let free: Vec<usize> = (0..P).filter(|&i| !fixed[i]).collect();
    let mut phi = free
        .iter()
        .map(|&i| bounds.phi_at(i, initial[i]))
        .collect::<Result<Vec<f64>>>()?;
    let objective = Objective {
        model,
        bounds,
        free: free.clone(),
        fixed,
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
    let theta = theta_of(bounds, &free, &phi);
    let (log_likelihood, grad) = gradient(model, &theta, &fixed)?;
    let information = observed_information(model, &theta, &fixed)?;
    let covariance = free_inverse(&information, &free);
    let standard_errors = covariance
        .as_ref()
        .map(|c| SVector::from_fn(|i, _| c[(i, i)].max(0.0).sqrt()));
    let decrement = covariance.as_ref().map(|c| grad.dot(&(c * grad)));
    let converged = free.is_empty()
        || decrement.is_some_and(|d| d.is_finite() && d / 2.0 <= options.decrement_tolerance);
    let stop = match newton_stop {
        FitStop::NoFreeParameter => FitStop::NoFreeParameter,
        _ if converged => FitStop::Converged,
        // A small decrement where Newton ended, but not at the returned point.
        FitStop::InformationNotPositiveDefinite if covariance.is_some() => FitStop::NewtonStepLimit,
        other => other,
    };
    Ok(MaximumLikelihood {
        theta,
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
fn newton_step<L: LogLikelihood<P>, const P: usize>(
    objective: &Objective<'_, L, P>,
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
fn approach<L: LogLikelihood<P>, const P: usize>(
    objective: &Objective<'_, L, P>,
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
fn safeguarded_step<L: LogLikelihood<P>, const P: usize>(
    objective: &Objective<'_, L, P>,
    phi: &[f64],
    cap: Option<f64>,
) -> Result<Step> {
    let (bounds, free) = (objective.bounds, &objective.free);
    let theta = theta_of(bounds, free, phi);
    let (value, g) = gradient(objective.model, &theta, &objective.fixed)?;
    let info = observed_information(objective.model, &theta, &objective.fixed)?;
    let n = free.len();
    // Chain rule to phi for the cost -ln p: J_i = d theta_i / d phi_i.
    let jac: Vec<f64> = free
        .iter()
        .zip(phi)
        .map(|(&i, &p)| bounds.derivative(i, p))
        .collect();
    let curv: Vec<f64> = free
        .iter()
        .zip(phi)
        .map(|(&i, &p)| bounds.second_derivative(i, p))
        .collect();
    let grad = nalgebra::DVector::from_fn(n, |r, _| -g[free[r]] * jac[r]);
    let hess = nalgebra::DMatrix::from_fn(n, n, |r, c| {
        let diag = if r == c { -g[free[r]] * curv[r] } else { 0.0 };
        info[(free[r], free[c])] * jac[r] * jac[c] + diag
    });
    let mut step = match (hess.clone().cholesky(), cap) {
        (Some(chol), _) => -chol.solve(&grad),
        (None, None) => return Ok(Step::Failed(FitStop::HessianNotPositiveDefinite)),
        (None, Some(_)) => nalgebra::DVector::from_fn(n, |r, _| {
            -grad[r] / hess[(r, r)].abs().max(f64::MIN_POSITIVE)
        }),
    };
    let longest = free
        .iter()
        .zip(step.iter())
        .filter(|(&i, _)| bounds.lower[i].is_finite() || bounds.upper[i].is_finite())
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
        let candidate = objective
            .model
            .log_likelihood(&theta_of(bounds, free, &next));
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
/// P x P matrix (zeros elsewhere); `None` unless that block is positive definite.
fn free_inverse<const P: usize>(
    information: &SMatrix<f64, P, P>,
    free: &[usize],
) -> Option<SMatrix<f64, P, P>> {
    let n = free.len();
    let block = nalgebra::DMatrix::from_fn(n, n, |r, c| information[(free[r], free[c])]);
    let inverse = block.cholesky()?.inverse();
    let mut out = SMatrix::zeros();
    for (r, &i) in free.iter().enumerate() {
        for (c, &j) in free.iter().enumerate() {
            out[(i, j)] = inverse[(r, c)];
        }
    }
    Some(out)
}

/// A likelihood-ratio test of a restricted model against a fuller one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LikelihoodRatioTest {
    /// Lambda = 2 (ln p_full - ln p_restricted), at least 0.
    pub statistic: f64,
    /// Degrees of freedom (number of restrictions).
    pub degrees_of_freedom: usize,
    /// P(chi-square(dof) >= Lambda): the asymptotic p-value.
    pub p_value: f64,
}

/// The likelihood-ratio test of `restricted` (maximised log-likelihood of the restricted
/// model) against `full`, with `degrees_of_freedom` restrictions (module docs). A
/// slightly negative difference (the restricted optimum found a hair higher, within
/// optimiser tolerance) is taken as 0.
///
/// # Errors
/// [`Error::InvalidParameter`] for non-finite log-likelihoods or zero degrees of
/// freedom.
pub fn likelihood_ratio_test(
    full: f64,
    restricted: f64,
    degrees_of_freedom: usize,
) -> Result<LikelihoodRatioTest> {
    use statrs::distribution::{ChiSquared, ContinuousCDF};
    if !full.is_finite() || !restricted.is_finite() || degrees_of_freedom == 0 {
        return Err(Error::InvalidParameter {
            name: "likelihood ratio test",
            reason: format!(
                "log-likelihoods {full} / {restricted} must be finite and dof {degrees_of_freedom} > 0"
            ),
        });
    }
    let statistic = (2.0 * (full - restricted)).max(0.0);
    let chi2 = ChiSquared::new(degrees_of_freedom as f64).map_err(|e| Error::InvalidParameter {
        name: "likelihood ratio test",
        reason: e.to_string(),
    })?;
    Ok(LikelihoodRatioTest {
        statistic,
        degrees_of_freedom,
        p_value: chi2.sf(statistic),
    })
}
