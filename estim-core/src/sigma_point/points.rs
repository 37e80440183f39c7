//! The mapped sigma points a mean hook sees ([`SigmaPoints`]), and the measurement
//! hooks the update's sums ask for (a [`SigmaPointMeasurement`], or a closure with
//! the plain hooks).

use nalgebra::SVector;

use crate::scalar::lit;
use crate::{Result, Scalar, SigmaPointMeasurement};

#[cfg(doc)]
use super::unscented_update;

/// Sigma points mapped through a function (e.g. a measurement model's h), with their
/// mean weights: what [`SigmaPointMeasurement::mean`] averages. The centre point
/// Y_0 has weight Wm_0 (possibly negative); every other point has the same weight
/// W = (1 - Wm_0) / (number of other points), so the weights sum to one.
///
/// ```
/// use estim_core::nalgebra::Vector1;
/// use estim_core::sigma_point::SigmaPoints;
///
/// let centre = Vector1::new(1.0);
/// let pairs = [[Vector1::new(2.0), Vector1::new(0.5)]];
/// let points = SigmaPoints::new(&centre, 0.5, &pairs);
/// assert_eq!(points.len(), 3);
/// assert_eq!(points.iter().map(|(w, _)| w).sum::<f64>(), 1.0);
/// assert_eq!(points.weighted_mean(), Vector1::new(0.5 * 1.0 + 0.25 * 2.0 + 0.25 * 0.5));
/// ```
#[derive(Debug, Clone, Copy)]
pub struct SigmaPoints<'a, T: Scalar, const D: usize> {
    pub(super) centre: &'a SVector<T, D>,
    pub(super) centre_weight: T,
    pub(super) weight: T,
    /// The +/- pairs, in two runs (the augmented update's state and noise columns).
    pub(super) pairs: [&'a [[SVector<T, D>; 2]]; 2],
}

impl<'a, T: Scalar, const D: usize> SigmaPoints<'a, T, D> {
    /// The points `centre` (weight `centre_weight`) and `pairs` (each of the others
    /// weighing (1 - `centre_weight`) / (2 `pairs.len()`)).
    pub fn new(
        centre: &'a SVector<T, D>,
        centre_weight: T,
        pairs: &'a [[SVector<T, D>; 2]],
    ) -> Self {
        let others = lit::<T>(2.0 * pairs.len().max(1) as f64);
        Self {
            centre,
            centre_weight,
            weight: (T::one() - centre_weight) / others,
            pairs: [pairs, &[]],
        }
    }

    /// The centre point Y_0 (the image of the mean).
    pub fn centre(&self) -> &SVector<T, D> {
        self.centre
    }

    /// The number of points, 2L + 1.
    pub fn len(&self) -> usize {
        1 + 2 * (self.pairs[0].len() + self.pairs[1].len())
    }

    /// Never true (there is always the centre point).
    pub fn is_empty(&self) -> bool {
        false
    }

    /// (mean weight, point), the centre first.
    pub fn iter(&self) -> impl Iterator<Item = (T, &'a SVector<T, D>)> + '_ {
        let weight = self.weight;
        std::iter::once((self.centre_weight, self.centre)).chain(
            self.pairs
                .iter()
                .flat_map(|run| run.iter())
                .flat_map(move |pair| pair.iter().map(move |y| (weight, y))),
        )
    }

    /// sum_i Wm_i Y_i, summed as Y_0 + sum_{i>0} W (Y_i - Y_0) (the weights sum to
    /// one): what the filter uses when the model does not override
    /// [`SigmaPointMeasurement::mean`].
    pub fn weighted_mean(&self) -> SVector<T, D> {
        let mut d_bar = SVector::<T, D>::zeros();
        for run in self.pairs {
            for pair in run {
                for y in pair {
                    d_bar += (y - self.centre) * self.weight;
                }
            }
        }
        self.centre + d_bar
    }
}

/// What [`sigma_statistics`] asks of a measurement: h and the two hooks.
pub(crate) trait MeasurementHooks<T: Scalar, const N: usize, const M: usize> {
    /// h(x).
    fn predict(&self, state: &SVector<T, N>) -> Result<SVector<T, M>>;
    /// a - b.
    fn residual(&self, a: &SVector<T, M>, b: &SVector<T, M>) -> SVector<T, M>;
    /// The mean of mapped sigma points.
    fn mean(&self, points: &SigmaPoints<'_, T, M>) -> Result<SVector<T, M>>;
}

/// A [`SigmaPointMeasurement`] as [`MeasurementHooks`].
pub(crate) struct ModelHooks<'a, Mm: ?Sized>(pub(crate) &'a Mm);

impl<T, Mm, const N: usize, const M: usize> MeasurementHooks<T, N, M> for ModelHooks<'_, Mm>
where
    T: Scalar,
    Mm: SigmaPointMeasurement<T, N, M> + ?Sized,
{
    fn predict(&self, state: &SVector<T, N>) -> Result<SVector<T, M>> {
        self.0.predict(state)
    }

    fn residual(&self, a: &SVector<T, M>, b: &SVector<T, M>) -> SVector<T, M> {
        self.0.residual(a, b)
    }

    fn mean(&self, points: &SigmaPoints<'_, T, M>) -> Result<SVector<T, M>> {
        self.0.mean(points)
    }
}

/// A measurement function with the default hooks (plain difference and weighted
/// mean), for the closure-based [`unscented_update`].
pub(super) struct PlainMeasurement<H>(pub(super) H);

impl<T, H, const N: usize, const M: usize> MeasurementHooks<T, N, M> for PlainMeasurement<H>
where
    T: Scalar,
    H: Fn(&SVector<T, N>) -> Result<SVector<T, M>>,
{
    fn predict(&self, state: &SVector<T, N>) -> Result<SVector<T, M>> {
        (self.0)(state)
    }

    fn residual(&self, a: &SVector<T, M>, b: &SVector<T, M>) -> SVector<T, M> {
        a - b
    }

    fn mean(&self, points: &SigmaPoints<'_, T, M>) -> Result<SVector<T, M>> {
        Ok(points.weighted_mean())
    }
}
