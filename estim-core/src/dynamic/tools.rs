//! Free functions on run-time-sized values: the joint-covariance check, NEES and NIS.

use nalgebra::{DMatrix, DVector};

use super::filter::check_shape;
use super::linalg::{check_finite, joint_validity_margin as margin, JointScratch};
use crate::{Error, Result};

/// The validity margin of the joint covariance [[Q, M], [M', R]] (Q: n x n, M: n x m,
/// R: m x m), as [`crate::JointCovariance::validity_margin`] computes it for static
/// sizes: >= -[`crate::JointCovariance::tolerance`] iff it is positive semidefinite
/// (the smallest LDL' pivot of its correlation matrix, in [0, 1], when certified; else
/// its smallest eigenvalue, or -1 when a zero variance has a nonzero covariance).
///
/// ```
/// use estim_core::{dmatrix, dynamic::joint_validity_margin};
///
/// let (q, r) = (dmatrix![0.04, 0.0; 0.0, 0.01], dmatrix![0.1]);
/// // corr(w_1, v) = 0.5: a covariance.
/// assert!(joint_validity_margin(&q, &dmatrix![0.5 * (0.04f64 * 0.1).sqrt(); 0.0], &r)? >= 0.0);
/// // corr(w_1, v) = 1.5: not one.
/// assert!(joint_validity_margin(&q, &dmatrix![1.5 * (0.04f64 * 0.1).sqrt(); 0.0], &r)? < 0.0);
/// # Ok::<(), estim_core::Error>(())
/// ```
///
/// # Errors
/// [`Error::Dimension`] for disagreeing shapes; [`Error::NonFinite`].
pub fn joint_validity_margin(
    process_noise: &DMatrix<f64>,
    cross_covariance: &DMatrix<f64>,
    measurement_noise: &DMatrix<f64>,
) -> Result<f64> {
    let (n, m) = (process_noise.nrows(), measurement_noise.nrows());
    check_shape!("process noise Q", process_noise, n, n)?;
    check_shape!("measurement noise R", measurement_noise, m, m)?;
    check_shape!("cross-covariance M", cross_covariance, n, m)?;
    margin(
        process_noise,
        Some(cross_covariance),
        measurement_noise,
        None,
        None,
        &mut JointScratch::new(n, m),
    )
}

/// Normalised squared error e' C^-1 e, scale-free as [`crate::consistency::nees`]
/// (NEES of an estimation error under its covariance; NIS of an innovation under S).
///
/// # Errors
/// [`Error::Dimension`]; [`Error::NonFinite`]; [`Error::InvalidCovariance`] when C is
/// not symmetric positive definite; [`Error::Overflow`].
pub fn normalised_squared_error(error: &DVector<f64>, covariance: &DMatrix<f64>) -> Result<f64> {
    let n = error.len();
    check_shape!("covariance", covariance, n, n)?;
    check_finite(error.as_slice(), "error vector")?;
    check_finite(covariance.as_slice(), "covariance")?;
    crate::gaussian::check_symmetric_entries(n, |i, j| covariance[(i, j)], "covariance")?;
    let not_positive_definite = || Error::InvalidCovariance {
        what: "covariance",
        reason: "not positive definite".into(),
    };
    if (0..n).any(|i| covariance[(i, i)] <= 0.0) {
        return Err(not_positive_definite());
    }
    let sd: Vec<f64> = (0..n).map(|i| covariance[(i, i)].sqrt()).collect();
    let w = DVector::from_fn(n, |i, _| error[i] / sd[i]);
    let correlation = DMatrix::from_fn(n, n, |i, j| {
        (covariance[(i, j)] + covariance[(j, i)]) * 0.5 / sd[i] / sd[j]
    });
    let chol = correlation.cholesky().ok_or_else(not_positive_definite)?;
    let value = w.dot(&chol.solve(&w));
    if value.is_finite() {
        Ok(value)
    } else {
        Err(Error::Overflow {
            what: "normalised squared error (NEES or NIS)",
        })
    }
}
