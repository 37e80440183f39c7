//! Maximum likelihood with a parameter count known at run time: the same optimiser,
//! derivatives and standard errors as [`super::maximize`], over `DVector` parameters.

use nalgebra::{DMatrix, DVector};
use num_dual::{Dual64, HyperDual64};

use super::optimize::{check_interval, fit, gradient_by, information_by, Evaluate};
use super::{FitOptions, FitStop};
use crate::{Error, Result, Scalar};

/// The measurements' log-likelihood as a function of a parameter vector whose length
/// is known at run time, for any scalar (`f64` for values, dual numbers for exact
/// derivatives): [`super::LogLikelihood`] with `DVector` parameters.
///
/// ```
/// use estim_core::nalgebra::{DMatrix, DVector};
/// use estim_core::noise::ml::{maximize_dyn, DynBounds, DynLogLikelihood, FitOptions};
/// use estim_core::numeric::lit;
/// use estim_core::{Result, Scalar};
///
/// /// Zero-mean Gaussian samples; theta = [variance].
/// struct Samples(Vec<f64>);
/// impl DynLogLikelihood for Samples {
///     fn log_likelihood<T: Scalar>(&self, theta: &DVector<T>) -> Result<T> {
///         let v = theta[0];
///         let half_log_2pi_v = (lit::<T>(2.0 * std::f64::consts::PI) * v).ln() * lit(0.5);
///         Ok(self.0.iter().fold(T::zero(), |sum, &y| {
///             sum - half_log_2pi_v - lit::<T>(y * y) / (v * lit(2.0))
///         }))
///     }
/// }
/// let data = Samples(vec![0.5, -1.0, 1.5, -0.5, 0.0, 1.0]);
/// let bounds = DynBounds::new(DVector::from_element(1, 0.0), DVector::from_element(1, f64::INFINITY))?;
/// let fit = maximize_dyn(&data, &DVector::from_element(1, 1.0), &bounds, &FitOptions::default())?;
/// // The closed form: the mean square, with standard error v sqrt(2 / n).
/// let v = data.0.iter().map(|y| y * y).sum::<f64>() / 6.0;
/// assert!((fit.theta[0] - v).abs() < 1e-9);
/// let se = fit.standard_errors.expect("information positive definite");
/// assert!((se[0] - v * (2.0f64 / 6.0).sqrt()).abs() < 1e-9);
/// # let _ = DMatrix::<f64>::zeros(1, 1);
/// # Ok::<(), estim_core::Error>(())
/// ```
pub trait DynLogLikelihood {
    /// ln p(y | theta).
    ///
    /// # Errors
    /// Whatever the model reports (a parameter vector of the wrong length, an invalid
    /// covariance, a non-positive-definite S).
    fn log_likelihood<T: Scalar>(&self, theta: &DVector<T>) -> Result<T>;
}

/// Lower and upper bounds of each of p parameters, p known at run time
/// ([`super::Bounds`] with `DVector` bounds).
#[derive(Debug, Clone, PartialEq)]
pub struct DynBounds {
    lower: DVector<f64>,
    upper: DVector<f64>,
}

impl DynBounds {
    /// Bounds `lower[i] <= theta_i <= upper[i]`; `lower[i] == upper[i]` fixes theta_i.
    ///
    /// # Errors
    /// [`Error::Dimension`] when `upper` and `lower` differ in length;
    /// [`Error::InvalidParameter`] (`bounds`) for a NaN bound, `lower > upper`, or an
    /// infinite fixed value.
    pub fn new(lower: DVector<f64>, upper: DVector<f64>) -> Result<Self> {
        if upper.len() != lower.len() {
            return Err(Error::Dimension {
                what: "upper bounds (one per parameter, as the lower bounds)",
                expected: lower.len(),
                got: upper.len(),
            });
        }
        for i in 0..lower.len() {
            check_interval(i, lower[i], upper[i])?;
        }
        Ok(Self { lower, upper })
    }

    /// No bounds on any of `count` parameters.
    pub fn unbounded(count: usize) -> Self {
        Self {
            lower: DVector::from_element(count, f64::NEG_INFINITY),
            upper: DVector::from_element(count, f64::INFINITY),
        }
    }

    /// Fix parameter `index` at `value`.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] (`bounds`) for an index out of range or a value
    /// outside the current bounds.
    pub fn fix(mut self, index: usize, value: f64) -> Result<Self> {
        if index >= self.lower.len() || !(self.lower[index] <= value && value <= self.upper[index])
        {
            return Err(Error::InvalidParameter {
                name: "bounds",
                reason: format!("cannot fix parameter {index} at {value}: out of range"),
            });
        }
        self.lower[index] = value;
        self.upper[index] = value;
        Ok(self)
    }

    /// The number of parameters.
    pub fn len(&self) -> usize {
        self.lower.len()
    }

    /// Whether there is no parameter.
    pub fn is_empty(&self) -> bool {
        self.lower.is_empty()
    }

    /// The lower bounds.
    pub fn lower(&self) -> &DVector<f64> {
        &self.lower
    }

    /// The upper bounds.
    pub fn upper(&self) -> &DVector<f64> {
        &self.upper
    }

    /// Whether parameter `i` is fixed.
    pub fn is_fixed(&self, i: usize) -> bool {
        self.lower[i] == self.upper[i]
    }
}

/// The result of [`maximize_dyn`]: [`super::MaximumLikelihood`] with run-time sizes.
#[derive(Debug, Clone, PartialEq)]
pub struct DynMaximumLikelihood {
    /// The estimate theta^ (fixed parameters at their value).
    pub theta: DVector<f64>,
    /// ln p(y | theta^).
    pub log_likelihood: f64,
    /// d ln p / d theta at theta^ (0 for fixed parameters).
    pub gradient: DVector<f64>,
    /// Observed information -d^2 ln p / d theta^2 at theta^ (zero rows and columns for
    /// fixed parameters).
    pub information: DMatrix<f64>,
    /// Its inverse over the free parameters (asymptotic covariance of theta^), `None`
    /// when the information is not positive definite.
    pub covariance: Option<DMatrix<f64>>,
    /// Square roots of the covariance's diagonal (0 for fixed parameters).
    pub standard_errors: Option<DVector<f64>>,
    /// L-BFGS iterations run.
    pub iterations: u64,
    /// Whether the observed information is positive definite and half the Newton
    /// decrement is at most `FitOptions::decrement_tolerance` at the returned point.
    pub converged: bool,
    /// argmin's termination status of the last L-BFGS run, as argmin prints it.
    pub termination: String,
    /// Why the fit ended, typed.
    pub stop: FitStop,
}

/// A [`DynLogLikelihood`] as the optimiser's [`Evaluate`].
struct Dynamic<'a, L>(&'a L);

impl<L: DynLogLikelihood> Evaluate for Dynamic<'_, L> {
    fn value(&self, theta: &[f64]) -> Result<f64> {
        self.0.log_likelihood(&DVector::from_column_slice(theta))
    }
    fn gradient(&self, theta: &[f64], fixed: &[bool]) -> Result<(f64, Vec<f64>)> {
        gradient_by(
            theta,
            fixed,
            |dual: &[Dual64]| self.0.log_likelihood(&DVector::from_column_slice(dual)),
            || self.value(theta),
        )
    }
    fn information(&self, theta: &[f64], fixed: &[bool]) -> Result<DMatrix<f64>> {
        information_by(theta, fixed, |hyper: &[HyperDual64]| {
            self.0.log_likelihood(&DVector::from_column_slice(hyper))
        })
    }
}

/// `fixed` has one flag per parameter.
fn check_flags(theta: &DVector<f64>, fixed: &[bool]) -> Result<()> {
    if fixed.len() == theta.len() {
        Ok(())
    } else {
        Err(Error::Dimension {
            what: "fixed flags (one per parameter)",
            expected: theta.len(),
            got: fixed.len(),
        })
    }
}

/// ln p and its exact gradient at `theta` ([`super::gradient`] with run-time sizes).
///
/// # Errors
/// [`Error::Dimension`] when `fixed` is not one flag per parameter; the model's errors.
pub fn gradient_dyn<L: DynLogLikelihood>(
    model: &L,
    theta: &DVector<f64>,
    fixed: &[bool],
) -> Result<(f64, DVector<f64>)> {
    check_flags(theta, fixed)?;
    let (value, grad) = Dynamic(model).gradient(theta.as_slice(), fixed)?;
    Ok((value, DVector::from_vec(grad)))
}

/// The exact observed information at `theta` ([`super::observed_information`] with
/// run-time sizes).
///
/// # Errors
/// [`Error::Dimension`] when `fixed` is not one flag per parameter; the model's errors.
pub fn observed_information_dyn<L: DynLogLikelihood>(
    model: &L,
    theta: &DVector<f64>,
    fixed: &[bool],
) -> Result<DMatrix<f64>> {
    check_flags(theta, fixed)?;
    Dynamic(model).information(theta.as_slice(), fixed)
}

/// Maximise ln p(y | theta) inside `bounds` from `initial`: [`super::maximize`]'s
/// algorithm (the same code) for a parameter count known at run time.
///
/// # Errors
/// [`Error::Dimension`] when `initial` and `bounds` differ in length; those of
/// [`super::maximize`].
pub fn maximize_dyn<L: DynLogLikelihood>(
    model: &L,
    initial: &DVector<f64>,
    bounds: &DynBounds,
    options: &FitOptions,
) -> Result<DynMaximumLikelihood> {
    if initial.len() != bounds.len() {
        return Err(Error::Dimension {
            what: "initial parameters (one per bound)",
            expected: bounds.len(),
            got: initial.len(),
        });
    }
    let found = fit(
        &Dynamic(model),
        initial.as_slice(),
        bounds.lower.as_slice(),
        bounds.upper.as_slice(),
        options,
    )?;
    Ok(DynMaximumLikelihood {
        theta: found.theta,
        log_likelihood: found.log_likelihood,
        gradient: found.gradient,
        information: found.information,
        covariance: found.covariance,
        standard_errors: found.standard_errors,
        iterations: found.iterations,
        converged: found.converged,
        termination: found.termination,
        stop: found.stop,
    })
}
