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
//! ## Sizes known at run time
//!
//! [`maximize_dyn`] is [`maximize`] for a parameter count known only at run time (a
//! model read from a file, a Python array): a [`DynLogLikelihood`] takes `DVector`
//! parameters, [`DynBounds`] bounds them, and [`DynMaximumLikelihood`] holds the same
//! results as [`MaximumLikelihood`] in `DVector` / `DMatrix`. Both run one optimiser
//! written over parameter slices (the same L-BFGS, approach and Newton phases, the same
//! dual-number derivatives), so on the same problem they agree to round-off
//! (`tests/noise_ml_dyn.rs`). [`LinearNoiseModel`] is a ready [`DynLogLikelihood`]:
//! a linear-Gaussian model with run-time sizes whose Q and R are scaled, or whose
//! diagonals are the parameters ([`NoiseParameters`]).
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

mod dynamic;
mod linear;
mod optimize;

use nalgebra::{DMatrix, DVector, SMatrix, SVector};
use num_dual::{Dual64, HyperDual64};

pub use dynamic::{
    gradient_dyn, maximize_dyn, observed_information_dyn, DynBounds, DynLogLikelihood,
    DynMaximumLikelihood,
};
pub use linear::{LinearNoiseModel, NoiseParameters};

use crate::{Error, Result, Scalar};
use optimize::{check_interval, fit, gradient_by, information_by, Evaluate};

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
            check_interval(i, lower[i], upper[i])?;
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
}

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
    let (value, grad) = Static(model).gradient(theta.as_slice(), fixed)?;
    Ok((value, SVector::from_column_slice(&grad)))
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
    let info = Static(model).information(theta.as_slice(), fixed)?;
    Ok(SMatrix::from_column_slice(info.as_slice()))
}

/// A [`LogLikelihood`] as the optimiser's [`Evaluate`].
struct Static<'a, L, const P: usize>(&'a L);

impl<L: LogLikelihood<P>, const P: usize> Evaluate for Static<'_, L, P> {
    fn value(&self, theta: &[f64]) -> Result<f64> {
        self.0
            .log_likelihood(&SVector::<f64, P>::from_column_slice(theta))
    }
    fn gradient(&self, theta: &[f64], fixed: &[bool]) -> Result<(f64, Vec<f64>)> {
        gradient_by(
            theta,
            fixed,
            |dual: &[Dual64]| self.0.log_likelihood(&SVector::from_column_slice(dual)),
            || self.value(theta),
        )
    }
    fn information(&self, theta: &[f64], fixed: &[bool]) -> Result<DMatrix<f64>> {
        information_by(theta, fixed, |hyper: &[HyperDual64]| {
            self.0.log_likelihood(&SVector::from_column_slice(hyper))
        })
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
    let found = fit(
        &Static(model),
        initial.as_slice(),
        bounds.lower.as_slice(),
        bounds.upper.as_slice(),
        options,
    )?;
    let vector = |v: &DVector<f64>| SVector::<f64, P>::from_column_slice(v.as_slice());
    let matrix = |m: &DMatrix<f64>| SMatrix::<f64, P, P>::from_column_slice(m.as_slice());
    Ok(MaximumLikelihood {
        theta: vector(&found.theta),
        log_likelihood: found.log_likelihood,
        gradient: vector(&found.gradient),
        information: matrix(&found.information),
        covariance: found.covariance.as_ref().map(matrix),
        standard_errors: found.standard_errors.as_ref().map(vector),
        iterations: found.iterations,
        converged: found.converged,
        termination: found.termination,
        stop: found.stop,
    })
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
