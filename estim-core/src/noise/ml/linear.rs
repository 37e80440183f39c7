//! The noise of a linear-Gaussian model with run-time sizes as a [`DynLogLikelihood`]:
//! positive scales of Q and R, or their diagonals, for [`super::maximize_dyn`].

use nalgebra::{DMatrix, DVector};

use super::DynLogLikelihood;
use crate::dynamic::DynKalmanFilter;
use crate::gaussian::check_finite;
use crate::numeric::lit;
use crate::{Error, Result, Scalar};

/// What [`LinearNoiseModel`]'s parameters are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum NoiseParameters {
    /// theta = [q, r]: Q(theta) = q Q_0, R(theta) = r R_0 (the given Q_0, R_0 keep
    /// their shape; the start is q = r = 1).
    Scales,
    /// theta = [diag Q; diag R] (n + m entries): Q(theta) = diag(theta_0..n),
    /// R(theta) = diag(theta_n..n+m), off-diagonal terms zero (the given Q_0, R_0 give
    /// only the start, their diagonals).
    Diagonals,
}

/// A linear-Gaussian model x_k = F x_{k-1} + w_k, y_k = H x_k + v_k (Cov(w) = Q(theta),
/// Cov(v) = R(theta), x_0 ~ N(x0, P0)) with its measurements y_1..y_K (`None` =
/// missing), whose log-likelihood ln p(y_1..y_K | theta) is that of
/// [`DynKalmanFilter::filter_series`]: predict, then update at each step, the sum of
/// ln N(nu_k; 0, S_k) over the measured steps. Written over `DMatrix<T>` for any
/// scalar, so [`super::maximize_dyn`] differentiates it exactly.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearNoiseModel {
    transition: DMatrix<f64>,
    observation: DMatrix<f64>,
    process_noise: DMatrix<f64>,
    measurement_noise: DMatrix<f64>,
    state: DVector<f64>,
    covariance: DMatrix<f64>,
    measurements: Vec<Option<DVector<f64>>>,
    parameters: NoiseParameters,
}

impl LinearNoiseModel {
    /// The model (arguments in [`DynKalmanFilter::new`]'s order) with its
    /// measurements and parameterisation.
    ///
    /// # Errors
    /// Those of [`DynKalmanFilter::new`] for the model; [`Error::Dimension`] and
    /// [`Error::NonFinite`] for a measurement not of size m or not finite.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        transition: DMatrix<f64>,
        process_noise: DMatrix<f64>,
        observation: DMatrix<f64>,
        measurement_noise: DMatrix<f64>,
        state: DVector<f64>,
        covariance: DMatrix<f64>,
        measurements: Vec<Option<DVector<f64>>>,
        parameters: NoiseParameters,
    ) -> Result<Self> {
        // The filter's own checks of sizes, finiteness and covariances.
        DynKalmanFilter::new(
            transition.clone(),
            process_noise.clone(),
            observation.clone(),
            measurement_noise.clone(),
            state.clone(),
            covariance.clone(),
        )?;
        let m = measurement_noise.nrows();
        for y in measurements.iter().flatten() {
            if y.len() != m {
                return Err(Error::Dimension {
                    what: "measurement",
                    expected: m,
                    got: y.len(),
                });
            }
            check_finite(y.as_slice(), "measurement")?;
        }
        Ok(Self {
            transition,
            observation,
            process_noise,
            measurement_noise,
            state,
            covariance,
            measurements,
            parameters,
        })
    }

    /// The number of parameters: 2 for [`NoiseParameters::Scales`], n + m for
    /// [`NoiseParameters::Diagonals`].
    pub fn parameter_count(&self) -> usize {
        match self.parameters {
            NoiseParameters::Scales => 2,
            NoiseParameters::Diagonals => self.state.len() + self.measurement_noise.nrows(),
        }
    }

    /// The parameters of the given Q_0, R_0: [1, 1], or their diagonals.
    pub fn initial_parameters(&self) -> DVector<f64> {
        match self.parameters {
            NoiseParameters::Scales => DVector::from_element(2, 1.0),
            NoiseParameters::Diagonals => DVector::from_iterator(
                self.parameter_count(),
                self.process_noise
                    .diagonal()
                    .iter()
                    .chain(self.measurement_noise.diagonal().iter())
                    .copied(),
            ),
        }
    }

    /// Q(theta) and R(theta).
    ///
    /// # Errors
    /// [`Error::Dimension`] when theta is not [`Self::parameter_count`] long.
    pub fn noise_at<T: Scalar>(&self, theta: &DVector<T>) -> Result<(DMatrix<T>, DMatrix<T>)> {
        if theta.len() != self.parameter_count() {
            return Err(Error::Dimension {
                what: "noise parameters",
                expected: self.parameter_count(),
                got: theta.len(),
            });
        }
        let (n, m) = (self.state.len(), self.measurement_noise.nrows());
        Ok(match self.parameters {
            NoiseParameters::Scales => (
                self.process_noise.map(lit::<T>) * theta[0],
                self.measurement_noise.map(lit::<T>) * theta[1],
            ),
            NoiseParameters::Diagonals => (
                DMatrix::from_diagonal(&theta.rows(0, n).into_owned()),
                DMatrix::from_diagonal(&theta.rows(n, m).into_owned()),
            ),
        })
    }
}

impl DynLogLikelihood for LinearNoiseModel {
    /// The Kalman filter's prediction-error decomposition (the module docs of
    /// [`crate::noise::em`]), with S_k's Cholesky factor for ln det S_k and
    /// nu_k' S_k^-1 nu_k, K = P H' S^-1 and the Joseph-form posterior.
    fn log_likelihood<T: Scalar>(&self, theta: &DVector<T>) -> Result<T> {
        let (q, r) = self.noise_at(theta)?;
        let f = self.transition.map(lit::<T>);
        let h = self.observation.map(lit::<T>);
        let (n, m) = (self.state.len(), self.measurement_noise.nrows());
        let identity = DMatrix::<T>::identity(n, n);
        let log_2pi = lit::<T>((2.0 * std::f64::consts::PI).ln());
        let mut x = self.state.map(lit::<T>);
        let mut p = self.covariance.map(lit::<T>);
        let mut total = T::zero();
        for y in &self.measurements {
            x = &f * &x;
            p = &f * &p * f.transpose() + &q;
            let Some(y) = y else { continue };
            let innovation = y.map(lit::<T>) - &h * &x;
            let p_ht = &p * h.transpose();
            let s = &h * &p_ht + &r;
            let chol = s.cholesky().ok_or(Error::InnovationNotPositiveDefinite)?;
            let whitened = chol
                .l()
                .solve_lower_triangular(&innovation)
                .ok_or(Error::InnovationNotPositiveDefinite)?;
            let log_det = chol
                .l()
                .diagonal()
                .iter()
                .fold(T::zero(), |sum, d| sum + d.ln())
                * lit(2.0);
            total -= (lit::<T>(m as f64) * log_2pi + log_det + whitened.norm_squared()) * lit(0.5);
            let gain = chol.solve(&p_ht.transpose()).transpose();
            x += &gain * innovation;
            let a = &identity - &gain * &h;
            p = &a * &p * a.transpose() + &gain * &r * gain.transpose();
        }
        Ok(total)
    }
}
