//! Models shared by estim-core's benches: a linear process x <- Phi x with fixed Q, and a
//! linear sensor y = H x + v with fixed R (15 states, 3 measurements).

use estim_core::nalgebra::{SMatrix, SVector};
use estim_core::{MeasurementModel, ProcessModel, Result};

pub const N: usize = 15;
pub const M: usize = 3;

/// x_{k+1} = Phi x_k + w_k, Cov(w_k) = Q.
pub struct Dense {
    pub phi: SMatrix<f64, N, N>,
    pub q: SMatrix<f64, N, N>,
}

impl ProcessModel<f64, N> for Dense {
    type State = SVector<f64, N>;
    type Input = ();
    fn propagate(&self, x: &Self::State, _: &(), _: f64) -> Result<Self::State> {
        Ok(self.phi * x)
    }
    fn transition(&self, _: &Self::State, _: &(), _: f64) -> Result<SMatrix<f64, N, N>> {
        Ok(self.phi)
    }
    fn process_noise(&self, _: &Self::State, _: &(), _: f64) -> Result<SMatrix<f64, N, N>> {
        Ok(self.q)
    }
}

/// y = H x + v, Cov(v) = R.
pub struct Sensor {
    pub h: SMatrix<f64, M, N>,
    pub r: SMatrix<f64, M, M>,
}

impl MeasurementModel<f64, N, M> for Sensor {
    type State = SVector<f64, N>;
    fn predict(&self, x: &Self::State) -> Result<SVector<f64, M>> {
        Ok(self.h * x)
    }
    fn jacobian(&self, _: &Self::State) -> Result<SMatrix<f64, M, N>> {
        Ok(self.h)
    }
    fn noise_covariance(&self, _: &Self::State) -> Result<SMatrix<f64, M, M>> {
        Ok(self.r)
    }
}
