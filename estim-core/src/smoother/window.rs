//! Correlated windows over several epochs: the augmented state [e; s] of each epoch
//! the window spans (module docs, "Windows over several epochs").

use nalgebra::{DMatrix, DVector};

use super::link::{symmetrize_dynamic, DynamicLink, UpdateTerms};
use super::{Augmented, ForwardRecorder};
use crate::window::RecordedWindow;
use crate::Scalar;

const NOT_RECORDED: &str = "a windowed update's recorded window is incomplete";

/// A window's steps on one epoch: the epoch's position among the held ones (`None`:
/// before them) and the window's first and last step in it.
type Segment = (Option<usize>, usize, usize);

/// A link back to the previous epoch in augmented coordinates, with Cov(z_prev, s)
/// next to it (the windowed update's noise shares s).
type OpenLink<T> = (DynamicLink<T>, DMatrix<T>);

impl<T: Scalar, S: Clone, const N: usize> ForwardRecorder<T, S, N> {
    /// The augmented links and covariances of the epochs a correlated window spans
    /// (module docs, "Windows over several epochs"), ending with the windowed update
    /// `update` itself on the newest epoch. Writes nothing unless all of it succeeds.
    pub(super) fn augment_window(
        &mut self,
        window: &dyn RecordedWindow<T, N>,
        update: &UpdateTerms<T>,
    ) -> std::result::Result<(), &'static str> {
        let m = update.innovation.len();
        let segments = self.window_segments(window.steps())?;
        let mut cs = DMatrix::<T>::zeros(N, m);
        let mut vs = DMatrix::<T>::zeros(m, m);
        let mut next_update = 0;
        let mut results: Vec<(usize, Augmented<T>)> = Vec::with_capacity(segments.len());
        for (i, &(epoch, first, last)) in segments.iter().enumerate() {
            let newest = i + 1 == segments.len();
            // The link needs the previous epoch; before the window's first epoch its
            // state is e alone (nothing of the window shared yet).
            let shared_before = if i > 0 { m } else { 0 };
            let mut link = match epoch {
                Some(q) if q > 0 => Some(self.open_link(q, shared_before, &cs, &vs)),
                _ => None,
            };
            for p in first..=last {
                let phi = window.transition(p).ok_or(NOT_RECORDED)?;
                let q = window.process_noise(p).ok_or(NOT_RECORDED)?;
                let d = window.step_cross_covariance(p).ok_or(NOT_RECORDED)?;
                let d = DMatrix::from_column_slice(N, m, d);
                let phi = DMatrix::from_column_slice(N, N, phi.as_slice());
                let q = DMatrix::from_column_slice(N, N, q.as_slice());
                vs += shared_noise_increment(&q, &d).ok_or(
                    "a window step's D_j is not in the range of its process noise (the joint covariance of the window is not valid)",
                )?;
                cs = phi * cs + d;
                while let Some(u) = window.update(next_update).filter(|u| u.after_step == p) {
                    if link.is_some() && p != last {
                        return Err("an update inside an epoch's composed steps");
                    }
                    let transform = DMatrix::from_column_slice(N, N, u.transform.as_slice());
                    let information = DMatrix::from_column_slice(N, N, u.information.as_slice());
                    let weighted = DVector::from_column_slice(u.weighted_innovation.as_slice());
                    if let Some((link, cross_s)) = link.as_mut() {
                        let xi = &link.cross * &information;
                        link.shift += &link.cross * &weighted;
                        link.previous_covariance -= &xi * link.cross.transpose();
                        *cross_s -= &xi * &cs;
                        link.cross = &link.cross * transform.transpose();
                    }
                    vs -= cs.transpose() * &information * &cs;
                    cs = transform * cs;
                    next_update += 1;
                }
            }
            let Some(q) = epoch else {
                continue;
            };
            let augmented = if newest {
                Self::close_newest(link, update)?
            } else {
                self.close_inside(q, link, &cs, &vs)
            };
            results.push((q, augmented));
        }
        if next_update != window.updates() {
            return Err(NOT_RECORDED);
        }
        if results
            .iter()
            .any(|(q, _)| self.epochs[*q].augmented.is_some())
        {
            return Err("correlated windows that overlap on an epoch");
        }
        for (q, augmented) in results {
            self.epochs[q].augmented = Some(augmented);
        }
        Ok(())
    }

    /// The window's `length` steps on the held epochs, oldest first, the last segment
    /// on the newest epoch.
    fn window_segments(&self, length: usize) -> std::result::Result<Vec<Segment>, &'static str> {
        // Walked newest first, then reversed.
        let mut segments: Vec<Segment> = Vec::new();
        let mut remaining = length;
        let mut position = self.epochs.len();
        while remaining > 0 {
            if position == 0 {
                if self.first_index == 0 {
                    return Err("a windowed update's window starts before the recording");
                }
                segments.push((None, 0, remaining - 1));
                break;
            }
            position -= 1;
            let steps = self.epochs[position].steps;
            if steps == 0 {
                return Err("a windowed update's window starts before the recording");
            }
            let first = remaining.saturating_sub(steps);
            segments.push((Some(position), first, remaining - 1));
            remaining = first;
        }
        segments.reverse();
        if segments.last().map(|s| s.0) != Some(Some(self.epochs.len() - 1)) {
            return Err(NOT_RECORDED);
        }
        Ok(segments)
    }

    /// The link of held epoch `q` (> 0) back to the previous one before its updates,
    /// the previous epoch's Markov state being e (`shared_before` = 0) or [e; s]
    /// (`shared_before` = M, with Cov(e, s) = `cs` and Var(s) = `vs`).
    fn open_link(
        &self,
        q: usize,
        shared_before: usize,
        cs: &DMatrix<T>,
        vs: &DMatrix<T>,
    ) -> OpenLink<T> {
        let m = cs.ncols();
        let previous = &self.epochs[q - 1];
        let dim = N + shared_before;
        let mut prior = DMatrix::<T>::zeros(dim, dim);
        prior
            .view_mut((0, 0), (N, N))
            .copy_from_slice(previous.covariance.as_slice());
        if shared_before > 0 {
            prior.view_mut((0, N), (N, m)).copy_from(cs);
            prior.view_mut((N, 0), (m, N)).copy_from(&cs.transpose());
            prior.view_mut((N, N), (m, m)).copy_from(vs);
        }
        let phi = DMatrix::from_column_slice(N, N, self.epochs[q].transition.as_slice());
        // Cov(z_prev, e) = Cov(z_prev, e_prev) Phi' and Cov(z_prev, s) =
        // Cov(z_prev, s_prev) before the epoch's updates.
        let cross_e = prior.columns(0, N) * phi.transpose();
        let cross_s = if shared_before > 0 {
            prior.columns(N, m).into_owned()
        } else {
            DMatrix::zeros(dim, m)
        };
        (
            DynamicLink {
                shift: DVector::zeros(dim),
                previous_covariance: prior,
                cross: cross_e,
            },
            cross_s,
        )
    }

    /// The newest epoch of the window: its state is e alone after the windowed
    /// update, which conditions its link with the noise's cross-covariance.
    fn close_newest(
        link: Option<OpenLink<T>>,
        update: &UpdateTerms<T>,
    ) -> std::result::Result<Augmented<T>, &'static str> {
        let link = match link {
            Some((mut link, cross_s)) => {
                link.condition(update, Some(&cross_s)).map_err(|_| {
                    "a windowed update's innovation covariance could not be factored"
                })?;
                Some(link)
            }
            None => None,
        };
        Ok(Augmented {
            covariance: None,
            link,
        })
    }

    /// An epoch inside the window (held at position `q`): its Markov state is
    /// [e; s], with Cov(e, s) = `cs` and Var(s) = `vs` so far.
    fn close_inside(
        &self,
        q: usize,
        link: Option<OpenLink<T>>,
        cs: &DMatrix<T>,
        vs: &DMatrix<T>,
    ) -> Augmented<T> {
        let m = cs.ncols();
        let dim = N + m;
        let mut covariance = DMatrix::<T>::zeros(dim, dim);
        covariance
            .view_mut((0, 0), (N, N))
            .copy_from_slice(self.epochs[q].covariance.as_slice());
        covariance.view_mut((0, N), (N, m)).copy_from(cs);
        covariance
            .view_mut((N, 0), (m, N))
            .copy_from(&cs.transpose());
        covariance
            .view_mut((N, N), (m, m))
            .copy_from(&symmetrize_dynamic(vs));
        let link = link.map(|(mut link, cross_s)| {
            let rows = link.cross.nrows();
            let mut cross = DMatrix::<T>::zeros(rows, dim);
            cross.columns_mut(0, N).copy_from(&link.cross);
            cross.columns_mut(N, m).copy_from(&cross_s);
            link.cross = cross;
            link.previous_covariance = symmetrize_dynamic(&link.previous_covariance);
            link
        });
        Augmented {
            covariance: Some(covariance),
            link,
        }
    }
}

/// D' Q^+ D: the variance a window step adds to the shared part s of the measurement
/// noise (v = sum_j D_j' Q_j^+ G_j w_j + an independent rest), or `None` when D is not
/// in the range of Q (then no valid joint covariance has these blocks). Q^+ from the
/// symmetric eigendecomposition, eigenvalues below 1e-12 of the largest taken as zero.
fn shared_noise_increment<T: Scalar>(q: &DMatrix<T>, d: &DMatrix<T>) -> Option<DMatrix<T>> {
    use crate::scalar::lit;
    let eigen = symmetrize_dynamic(q).symmetric_eigen();
    let largest = eigen
        .eigenvalues
        .iter()
        .fold(T::zero(), |a, &b| if b.abs() > a { b.abs() } else { a });
    let floor = largest * lit::<T>(1e-12);
    let vectors = &eigen.eigenvectors;
    let projected = vectors.transpose() * d;
    let mut scaled = projected.clone();
    let mut residual = T::zero();
    for (i, &lambda) in eigen.eigenvalues.iter().enumerate() {
        for j in 0..d.ncols() {
            if lambda > floor {
                scaled[(i, j)] = projected[(i, j)] / lambda;
            } else {
                let r = projected[(i, j)].abs();
                residual = if r > residual { r } else { residual };
                scaled[(i, j)] = T::zero();
            }
        }
    }
    let size = d
        .iter()
        .fold(T::zero(), |a, &b| if b.abs() > a { b.abs() } else { a });
    if residual > lit::<T>(1e-6) * size + T::default_epsilon() {
        return None;
    }
    Some(symmetrize_dynamic(&(projected.transpose() * scaled)))
}
