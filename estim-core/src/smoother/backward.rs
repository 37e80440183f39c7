//! The backward pass over the held epochs: static coordinates, or augmented ones
//! inside a correlated window.

use nalgebra::{DMatrix, DVector, SMatrix, SVector};

use super::link::{symmetrize_dynamic, DynamicLink};
use super::{ForwardRecorder, Smoothed};
use crate::gaussian::symmetrize;
use crate::{Error, Result, Scalar};

impl<T: Scalar, S: Clone, const N: usize> ForwardRecorder<T, S, N> {
    /// Backward pass over the held epochs with positions `from..=to` (positions in
    /// `self.epochs`), returning them oldest first.
    pub(super) fn backward(&self, from: usize, to: usize) -> Result<Vec<Smoothed<T, S, N>>> {
        if self.epochs.range(from..=to).any(|e| e.augmented.is_some()) {
            self.backward_augmented(from, to)
        } else {
            self.backward_static(from, to)
        }
    }

    /// The epoch's Markov-state covariance (augmented inside a window).
    fn markov_covariance(&self, position: usize) -> DMatrix<T> {
        let epoch = &self.epochs[position];
        match epoch.augmented.as_ref().and_then(|a| a.covariance.as_ref()) {
            Some(covariance) => covariance.clone(),
            None => DMatrix::from_column_slice(N, N, epoch.covariance.as_slice()),
        }
    }

    /// [`ForwardRecorder::backward_static`] in the epochs' Markov coordinates, e
    /// augmented with s inside a correlated window (module docs).
    fn backward_augmented(&self, from: usize, to: usize) -> Result<Vec<Smoothed<T, S, N>>> {
        let head = |c: &DVector<T>, p: &DMatrix<T>| {
            (
                SVector::<T, N>::from_fn(|i, _| c[i]),
                SMatrix::<T, N, N>::from_fn(|i, j| p[(i, j)]),
            )
        };
        let mut out = Vec::with_capacity(to + 1 - from);
        let mut covariance = self.markov_covariance(to);
        let mut correction = DVector::<T>::zeros(covariance.nrows());
        let (c, p) = head(&correction, &covariance);
        out.push(self.smoothed(to, c, p));
        for k in (from..to).rev() {
            let unsupported = |reason| Error::SmootherUnsupported {
                epoch: self.first_index + k,
                reason,
            };
            let next = &self.epochs[k + 1];
            let link = match (
                next.augmented.as_ref().and_then(|a| a.link.as_ref()),
                next.link.as_ref(),
            ) {
                (Some(link), _) => link.clone(),
                (None, Some(link)) => DynamicLink::from_static(link),
                (None, None) => return Err(unsupported("no link to this epoch was recorded")),
            };
            let next_covariance = self.markov_covariance(k + 1);
            if link.cross.ncols() != next_covariance.nrows()
                || correction.len() != next_covariance.nrows()
                || link.cross.nrows() != link.shift.len()
            {
                return Err(unsupported("inconsistent augmented link"));
            }
            // G = C P_{k+1}^+ (a pseudo-inverse where a shared part is still zero).
            let gain = psd_solve(&next_covariance, &link.cross.transpose())
                .ok_or_else(|| Error::InvalidCovariance {
                    what: "filtered covariance (smoother gain)",
                    reason: format!(
                        "not positive semidefinite at epoch {}",
                        self.first_index + k + 1
                    ),
                })?
                .transpose();
            correction = &link.shift + &gain * &correction;
            covariance = symmetrize_dynamic(
                &(&link.previous_covariance
                    + &gain * (&covariance - &next_covariance) * gain.transpose()),
            );
            if correction.iter().any(|v| !v.is_finite())
                || covariance.iter().any(|v| !v.is_finite())
            {
                return Err(Error::NonFinite {
                    what: "smoothed estimate",
                });
            }
            let (c, p) = head(&correction, &covariance);
            out.push(self.smoothed(k, c, p));
        }
        out.reverse();
        Ok(out)
    }

    fn backward_static(&self, from: usize, to: usize) -> Result<Vec<Smoothed<T, S, N>>> {
        let mut out = Vec::with_capacity(to + 1 - from);
        let newest = &self.epochs[to];
        let mut correction = SVector::<T, N>::zeros();
        let mut covariance = newest.covariance;
        out.push(self.smoothed(to, correction, covariance));
        for k in (from..to).rev() {
            let next = &self.epochs[k + 1];
            let Some(link) = next.link.as_ref() else {
                return Err(Error::SmootherUnsupported {
                    epoch: self.first_index + k,
                    reason: "no link to this epoch was recorded",
                });
            };
            // G = C P_{k+1}^-1, i.e. G' = P_{k+1}^-1 C'; a pseudo-inverse where P_{k+1}
            // is only semidefinite (states held at their value: zero rows and columns,
            // zero in C too).
            let gain = match next.covariance.cholesky() {
                Some(c) => Some(c.solve(&link.cross.transpose()).transpose()),
                None => psd_solve(
                    &DMatrix::from_column_slice(N, N, next.covariance.as_slice()),
                    &DMatrix::from_column_slice(N, N, link.cross.transpose().as_slice()),
                )
                .map(|g| SMatrix::<T, N, N>::from_column_slice(g.transpose().as_slice())),
            }
            .ok_or_else(|| Error::InvalidCovariance {
                what: "filtered covariance (smoother gain)",
                reason: format!(
                    "not positive semidefinite at epoch {}",
                    self.first_index + k + 1
                ),
            })?;
            correction = link.shift + gain * correction;
            covariance = symmetrize(
                &(link.previous_covariance
                    + gain * (covariance - next.covariance) * gain.transpose()),
            );
            if correction.iter().any(|v| !v.is_finite())
                || covariance.iter().any(|v| !v.is_finite())
            {
                return Err(Error::NonFinite {
                    what: "smoothed estimate",
                });
            }
            out.push(self.smoothed(k, correction, covariance));
        }
        out.reverse();
        Ok(out)
    }
}

/// x = P^+ b for a symmetric positive semidefinite P, scale-free: the
/// eigendecomposition of the correlation matrix, eigenvalues below 1e-10 taken as zero
/// (an augmented state [e; s] is singular where s is still fully determined by e's
/// noise, e.g. a window's first step with fewer noise components than M); rows and
/// columns of zero variance are left out. `None` if P has a negative variance or a
/// clearly negative eigenvalue.
fn psd_solve<T: Scalar>(p: &DMatrix<T>, b: &DMatrix<T>) -> Option<DMatrix<T>> {
    use crate::scalar::lit;
    if (0..p.nrows()).any(|i| p[(i, i)] < T::zero()) {
        return None;
    }
    let kept: Vec<usize> = (0..p.nrows()).filter(|&i| p[(i, i)] > T::zero()).collect();
    let scale: Vec<T> = kept.iter().map(|&i| p[(i, i)].sqrt()).collect();
    let k = kept.len();
    let correlation = symmetrize_dynamic(&DMatrix::from_fn(k, k, |i, j| {
        p[(kept[i], kept[j])] / (scale[i] * scale[j])
    }));
    let rhs = DMatrix::from_fn(k, b.ncols(), |i, j| b[(kept[i], j)] / scale[i]);
    let eigen = correlation.symmetric_eigen();
    let mut projected = eigen.eigenvectors.transpose() * &rhs;
    for (i, &lambda) in eigen.eigenvalues.iter().enumerate() {
        if lambda < -lit::<T>(1e-8) {
            return None;
        }
        let inverse = if lambda > lit::<T>(1e-10) {
            T::one() / lambda
        } else {
            T::zero()
        };
        for j in 0..rhs.ncols() {
            projected[(i, j)] *= inverse;
        }
    }
    let solved = &eigen.eigenvectors * projected;
    let mut x = DMatrix::<T>::zeros(p.nrows(), b.ncols());
    for (i, &row) in kept.iter().enumerate() {
        for j in 0..b.ncols() {
            x[(row, j)] = solved[(i, j)] / scale[i];
        }
    }
    Some(x)
}
