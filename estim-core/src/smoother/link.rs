//! The link between two epochs in dynamic (possibly augmented) coordinates and its
//! joint-Gaussian conditioning on an accepted update (module docs, "The smoother with
//! correlated noise").

use nalgebra::{DMatrix, DVector, SMatrix};

use super::Link;
use crate::observer::UpdateEvent;
use crate::{Error, Result, Scalar};

/// [`Link`] in augmented (dynamic) coordinates.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct DynamicLink<T: Scalar> {
    pub(super) shift: DVector<T>,
    pub(super) previous_covariance: DMatrix<T>,
    pub(super) cross: DMatrix<T>,
}

impl<T: Scalar> DynamicLink<T> {
    pub(super) fn from_static<const N: usize>(link: &Link<T, N>) -> Self {
        Self {
            shift: DVector::from_column_slice(link.shift.as_slice()),
            previous_covariance: DMatrix::from_column_slice(
                N,
                N,
                link.previous_covariance.as_slice(),
            ),
            cross: DMatrix::from_column_slice(N, N, link.cross.as_slice()),
        }
    }

    /// Joint-Gaussian conditioning of the link on one accepted update (innovation nu,
    /// covariance S, gain K, reset J) whose noise has covariance `noise_cross` with
    /// the previous epoch's state (`None`: zero):
    ///
    /// ```text
    /// Cov(z_prev, y) = C H' + X        A = Cov(z_prev, y) S^-1
    /// shift += A nu     P_prev -= A Cov(z_prev, y)'     C <- (C - Cov(z_prev, y) K') J'
    /// ```
    pub(super) fn condition(
        &mut self,
        update: &UpdateTerms<T>,
        noise_cross: Option<&DMatrix<T>>,
    ) -> Result<()> {
        let mut cov_prev_y = &self.cross * update.jacobian.transpose();
        if let Some(x) = noise_cross {
            cov_prev_y += x;
        }
        let a =
            solve_spd(update.innovation_covariance.clone(), cov_prev_y.transpose())?.transpose();
        self.shift += &a * &update.innovation;
        self.previous_covariance -= &a * cov_prev_y.transpose();
        self.previous_covariance = symmetrize_dynamic(&self.previous_covariance);
        let mut cross = &self.cross - &cov_prev_y * update.gain.transpose();
        if let Some(reset) = update.reset.as_ref() {
            cross *= reset.transpose();
        }
        self.cross = cross;
        Ok(())
    }
}

/// One accepted update's terms, in dynamic matrices.
pub(super) struct UpdateTerms<T: Scalar> {
    jacobian: DMatrix<T>,
    innovation_covariance: DMatrix<T>,
    pub(super) innovation: DVector<T>,
    gain: DMatrix<T>,
    reset: Option<DMatrix<T>>,
}

impl<T: Scalar> UpdateTerms<T> {
    /// The terms of an update the gate's recovery rule accepted with its prior
    /// covariance P scaled by `lambda`: the filter's step is then the Kalman step of a
    /// model with an extra, independent process noise (lambda - 1) P at this epoch, so
    /// the innovation covariance the gain used is S + (lambda - 1) H P H' (the report
    /// carries the S before the inflation; the link's cross-covariance with the
    /// previous epoch is unchanged by an independent noise).
    pub(super) fn inflate<const N: usize>(&mut self, prior: &SMatrix<T, N, N>, lambda: T) {
        let p = DMatrix::from_column_slice(N, N, prior.as_slice());
        let extra = &self.jacobian * p * self.jacobian.transpose() * (lambda - T::one());
        self.innovation_covariance += extra;
    }

    pub(super) fn new<S, const N: usize>(event: &UpdateEvent<'_, T, S, N>, gain: &[T]) -> Self {
        let m = event.measurement_size;
        Self {
            jacobian: DMatrix::from_column_slice(m, N, event.jacobian),
            innovation_covariance: DMatrix::from_column_slice(m, m, event.innovation_covariance),
            innovation: DVector::from_column_slice(event.innovation),
            gain: DMatrix::from_column_slice(N, m, gain),
            reset: event
                .reset
                .map(|j| DMatrix::from_column_slice(N, N, j.as_slice())),
        }
    }
}

pub(super) fn symmetrize_dynamic<T: Scalar>(m: &DMatrix<T>) -> DMatrix<T> {
    (m + m.transpose()) * crate::scalar::lit::<T>(0.5)
}

/// x = S^-1 b for a symmetric positive definite S (Cholesky, LU as a fallback for a
/// numerically semidefinite one the forward pass accepted).
fn solve_spd<T: Scalar>(s: DMatrix<T>, b: DMatrix<T>) -> Result<DMatrix<T>> {
    if let Some(chol) = s.clone().cholesky() {
        return Ok(chol.solve(&b));
    }
    s.lu().solve(&b).ok_or(Error::InnovationNotPositiveDefinite)
}
