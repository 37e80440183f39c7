//! The models of [`super::DynUnscentedKalmanFilter`] (f and h with their residual and
//! mean hooks, no Jacobian) and the mapped sigma points a mean hook sees, for sizes
//! known at run time. Every hook writes into a vector the filter owns, so a step
//! allocates nothing.

use nalgebra::{DMatrix, DVector, DVectorView};

use super::linalg::check_finite;
use crate::linalg::semidefinite_cholesky;
use crate::sigma_point::Weights;
use crate::{Error, Result};

#[cfg(doc)]
use super::DynUnscentedKalmanFilter;

/// A process x_k = f(x_{k-1}) + w for [`DynUnscentedKalmanFilter::predict`]: f over
/// `dt`, with a residual and a mean for states that cannot be subtracted or averaged
/// (a heading). The run-time-sized counterpart of [`crate::SigmaPointProcess`]; no
/// Jacobian. A closure `Fn(&DVector<f64>, f64, &mut DVector<f64>) -> Result<()>` is one
/// (with the plain hooks).
///
/// ```
/// use estim_core::dynamic::DynSigmaPointProcess;
/// use estim_core::nalgebra::DVector;
/// use estim_core::Result;
///
/// /// Constant turn: x, y, heading, speed; the heading wrapped to (-pi, pi].
/// struct Turn { rate: f64 }
/// impl DynSigmaPointProcess for Turn {
///     fn propagate(&self, x: &DVector<f64>, dt: f64, out: &mut DVector<f64>) -> Result<()> {
///         out[0] = x[0] + dt * x[3] * x[2].cos();
///         out[1] = x[1] + dt * x[3] * x[2].sin();
///         out[2] = x[2] + dt * self.rate;
///         out[3] = x[3];
///         Ok(())
///     }
///     fn residual(&self, a: &DVector<f64>, b: &DVector<f64>, out: &mut DVector<f64>) -> Result<()> {
///         out.copy_from(a);
///         *out -= b;
///         out[2] = (out[2] + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
///         Ok(())
///     }
/// }
/// let mut out = DVector::zeros(4);
/// Turn { rate: 0.1 }.propagate(&DVector::from_vec(vec![0.0, 0.0, 0.0, 2.0]), 0.5, &mut out)?;
/// assert_eq!(out[0], 1.0);
/// # Ok::<(), estim_core::Error>(())
/// ```
pub trait DynSigmaPointProcess {
    /// f(x) over `dt`, written into `out` (n entries, as x).
    ///
    /// # Errors
    /// Any: the filter passes it on and stays unchanged.
    fn propagate(&self, state: &DVector<f64>, dt: f64, out: &mut DVector<f64>) -> Result<()>;

    /// a - b into `out` (default: the plain difference). Override to wrap angles
    /// (Saerkkae 2013 sec. 5.6 / filterpy's `residual_x`).
    ///
    /// # Errors
    /// Any.
    fn residual(&self, a: &DVector<f64>, b: &DVector<f64>, out: &mut DVector<f64>) -> Result<()> {
        out.copy_from(a);
        *out -= b;
        Ok(())
    }

    /// The mean of propagated sigma points into `out` (default:
    /// [`DynSigmaPoints::weighted_mean_into`]). Override for a circular mean.
    ///
    /// # Errors
    /// Any.
    fn mean(&self, points: &DynSigmaPoints<'_>, out: &mut DVector<f64>) -> Result<()> {
        points.weighted_mean_into(out);
        Ok(())
    }
}

impl<F> DynSigmaPointProcess for F
where
    F: Fn(&DVector<f64>, f64, &mut DVector<f64>) -> Result<()>,
{
    fn propagate(&self, state: &DVector<f64>, dt: f64, out: &mut DVector<f64>) -> Result<()> {
        self(state, dt, out)
    }
}

/// A measurement y = h(x) + v for [`DynUnscentedKalmanFilter::update`], with residual
/// and mean hooks (a bearing). The run-time-sized counterpart of
/// [`crate::SigmaPointMeasurement`]; R is the filter's. A closure
/// `Fn(&DVector<f64>, &mut DVector<f64>) -> Result<()>` is one (with the plain hooks).
///
/// ```
/// use estim_core::dynamic::DynSigmaPointMeasurement;
/// use estim_core::nalgebra::DVector;
/// use estim_core::Result;
///
/// /// Range and bearing from the origin; the bearing residual wrapped.
/// struct RangeBearing;
/// impl DynSigmaPointMeasurement for RangeBearing {
///     fn predict(&self, x: &DVector<f64>, out: &mut DVector<f64>) -> Result<()> {
///         out[0] = x[0].hypot(x[1]);
///         out[1] = x[1].atan2(x[0]);
///         Ok(())
///     }
///     fn residual(&self, a: &DVector<f64>, b: &DVector<f64>, out: &mut DVector<f64>) -> Result<()> {
///         use std::f64::consts::{PI, TAU};
///         out[0] = a[0] - b[0];
///         out[1] = (a[1] - b[1] + PI).rem_euclid(TAU) - PI;
///         Ok(())
///     }
/// }
/// let mut out = DVector::zeros(2);
/// RangeBearing.predict(&DVector::from_vec(vec![3.0, 4.0]), &mut out)?;
/// assert_eq!(out[0], 5.0);
/// # Ok::<(), estim_core::Error>(())
/// ```
pub trait DynSigmaPointMeasurement {
    /// h(x), written into `out` (m entries, as R's size).
    ///
    /// # Errors
    /// Any: the filter passes it on and stays unchanged.
    fn predict(&self, state: &DVector<f64>, out: &mut DVector<f64>) -> Result<()>;

    /// a - b into `out` (default: the plain difference); filterpy's `residual_z`.
    ///
    /// # Errors
    /// Any.
    fn residual(&self, a: &DVector<f64>, b: &DVector<f64>, out: &mut DVector<f64>) -> Result<()> {
        out.copy_from(a);
        *out -= b;
        Ok(())
    }

    /// The mean of mapped sigma points into `out` (default:
    /// [`DynSigmaPoints::weighted_mean_into`]); filterpy's `z_mean_fn`.
    ///
    /// # Errors
    /// Any.
    fn mean(&self, points: &DynSigmaPoints<'_>, out: &mut DVector<f64>) -> Result<()> {
        points.weighted_mean_into(out);
        Ok(())
    }
}

impl<F> DynSigmaPointMeasurement for F
where
    F: Fn(&DVector<f64>, &mut DVector<f64>) -> Result<()>,
{
    fn predict(&self, state: &DVector<f64>, out: &mut DVector<f64>) -> Result<()> {
        self(state, out)
    }
}

/// The 2L + 1 sigma points mapped through f or h, with their mean weights: what a
/// mean hook averages. Stored as the columns of one matrix in filterpy's order: the
/// centre Y_0 (the image of the mean, weight Wm_0, possibly negative), then the L
/// points x + gamma S_j, then the L points x - gamma S_j (each of weight
/// W = 1 / (2 (L + lambda)), so the weights sum to one).
///
/// ```
/// use estim_core::dynamic::DynSigmaPoints;
/// use estim_core::nalgebra::{DMatrix, DVector};
///
/// let images = DMatrix::from_row_slice(1, 3, &[1.0, 2.0, 0.5]); // centre, plus, minus
/// let points = DynSigmaPoints::new(&images, 0.5)?;
/// let mut mean = DVector::zeros(1);
/// points.weighted_mean_into(&mut mean);
/// assert_eq!(mean[0], 0.5 * 1.0 + 0.25 * 2.0 + 0.25 * 0.5);
/// # Ok::<(), estim_core::Error>(())
/// ```
#[derive(Debug, Clone, Copy)]
pub struct DynSigmaPoints<'a> {
    points: &'a DMatrix<f64>,
    centre_weight: f64,
    weight: f64,
}

impl<'a> DynSigmaPoints<'a> {
    /// The columns of `points` (centre, L plus points, L minus points), the centre of
    /// weight `centre_weight` and each other (1 - `centre_weight`) / (2 L).
    ///
    /// # Errors
    /// [`crate::Error::Dimension`] unless `points` has an odd number of columns.
    pub fn new(points: &'a DMatrix<f64>, centre_weight: f64) -> Result<Self> {
        let count = points.ncols();
        if count % 2 != 1 {
            return Err(crate::Error::Dimension {
                what: "sigma points (2 L + 1 columns)",
                expected: count | 1,
                got: count,
            });
        }
        let others = (count - 1).max(1) as f64;
        Ok(Self {
            points,
            centre_weight,
            weight: (1.0 - centre_weight) / others,
        })
    }

    pub(crate) fn with_weights(points: &'a DMatrix<f64>, centre_weight: f64, weight: f64) -> Self {
        Self {
            points,
            centre_weight,
            weight,
        }
    }

    /// The points as the columns of one matrix (dimension x (2L + 1)), filterpy's
    /// order (type docs).
    pub fn points(&self) -> &'a DMatrix<f64> {
        self.points
    }

    /// The number of points, 2L + 1.
    pub fn len(&self) -> usize {
        self.points.ncols()
    }

    /// Never true (there is always the centre point).
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Wm_0, the centre's weight.
    pub fn centre_weight(&self) -> f64 {
        self.centre_weight
    }

    /// W, every other point's weight.
    pub fn weight(&self) -> f64 {
        self.weight
    }

    /// The mean weight of point i (filterpy's `Wm[i]`).
    pub fn mean_weight(&self, i: usize) -> f64 {
        if i == 0 {
            self.centre_weight
        } else {
            self.weight
        }
    }

    /// Point i (column i).
    pub fn point(&self, i: usize) -> DVectorView<'a, f64> {
        self.points.column(i)
    }

    /// sum_i Wm_i Y_i, summed as Y_0 + sum_{i>0} W (Y_i - Y_0) over the +/- pairs in
    /// turn (the static [`crate::sigma_point::SigmaPoints::weighted_mean`], bit for
    /// bit).
    pub fn weighted_mean_into(&self, out: &mut DVector<f64>) {
        let (dim, pairs) = (self.points.nrows(), self.points.ncols() / 2);
        out.fill(0.0);
        for j in 0..pairs {
            for column in [1 + j, 1 + pairs + j] {
                for r in 0..dim {
                    out[r] += (self.points[(r, column)] - self.points[(r, 0)]) * self.weight;
                }
            }
        }
        for r in 0..dim {
            out[r] += self.points[(r, 0)];
        }
    }
}

/// The buffers of one sigma-point pass over a space of `dim` entries from n-state
/// sigma points.
#[derive(Debug, Clone)]
pub(super) struct Pass {
    /// The images of the 2n + 1 points, filterpy's column order (`DynSigmaPoints`).
    pub(super) images: DMatrix<f64>,
    /// The centre's image Y_0, one image, the deviations of the + and - point of a
    /// pair.
    pub(super) centre: DVector<f64>,
    pub(super) image: DVector<f64>,
    pub(super) plus: DVector<f64>,
    pub(super) minus: DVector<f64>,
    /// sum_{i>0} W d_i and its mean, e = residual(mean, Y_0).
    pub(super) d_bar: DVector<f64>,
    pub(super) mean: DVector<f64>,
    pub(super) about_mean: DVector<f64>,
    /// dim x dim: sum_{i>0} W d_i d_i', then the covariance.
    pub(super) second: DMatrix<f64>,
    /// dim x n: every pair's deviations d_j+ and d_j- (column j).
    pub(super) plus_all: DMatrix<f64>,
    pub(super) minus_all: DMatrix<f64>,
    /// dim x n: G, column j = W gamma (d_j+ - d_j-).
    pub(super) spread: DMatrix<f64>,
    /// dim x n: the statistical linearisation G S^-1.
    pub(super) linearised: DMatrix<f64>,
}

impl Pass {
    pub(super) fn new(dim: usize, n: usize) -> Self {
        Self {
            images: DMatrix::zeros(dim, 2 * n + 1),
            centre: DVector::zeros(dim),
            image: DVector::zeros(dim),
            plus: DVector::zeros(dim),
            minus: DVector::zeros(dim),
            d_bar: DVector::zeros(dim),
            mean: DVector::zeros(dim),
            about_mean: DVector::zeros(dim),
            second: DMatrix::zeros(dim, dim),
            plus_all: DMatrix::zeros(dim, n),
            minus_all: DMatrix::zeros(dim, n),
            spread: DMatrix::zeros(dim, n),
            linearised: DMatrix::zeros(dim, n),
        }
    }
}

/// The lower semidefinite Cholesky factor of `covariance` into `factor` (the static
/// [`crate::square_root::covariance_factor`], bit for bit).
pub(super) fn factor_into(
    covariance: &DMatrix<f64>,
    factor: &mut DMatrix<f64>,
    what: &'static str,
) -> Result<()> {
    check_finite(covariance.as_slice(), what)?;
    factor.fill(0.0);
    let n = covariance.nrows();
    if semidefinite_cholesky(n, 0, |i, k| covariance[(i, k)], factor) {
        Ok(())
    } else {
        Err(Error::InvalidCovariance {
            what,
            reason: "not positive semidefinite (a Cholesky pivot is negative beyond round-off)"
                .into(),
        })
    }
}

/// The sigma points of (x, S S') through `map`: images into `pass.images` (filterpy's
/// order), deviations d_i = residual(Y_i, Y_0) summed as the static
/// `predict_with_hooks` / `sigma_statistics` sum them (pair by pair), the mean from the
/// hook into `pass.mean`, and the covariance sum_i Wc_i (Y_i - mean)(...)' (or the
/// centre-point-modified form) into `pass.second`, without noise; the whitened cross
/// terms G into `pass.spread`.
#[allow(clippy::too_many_arguments)] // the pass's buffers and its three hooks
pub(super) fn sigma_pass(
    weights: &Weights<f64>,
    x: &DVector<f64>,
    factor: &DMatrix<f64>,
    point: &mut DVector<f64>,
    pass: &mut Pass,
    map: impl Fn(&DVector<f64>, &mut DVector<f64>) -> Result<()>,
    residual: impl Fn(&DVector<f64>, &DVector<f64>, &mut DVector<f64>) -> Result<()>,
    mean: impl Fn(&DynSigmaPoints<'_>, &mut DVector<f64>) -> Result<()>,
    what: &'static str,
) -> Result<()> {
    let n = x.len();
    let dim = pass.image.len();
    let (gamma, wi) = (weights.gamma, weights.other);
    map(x, &mut pass.centre)?;
    check_finite(pass.centre.as_slice(), what)?;
    pass.images.set_column(0, &pass.centre);
    pass.d_bar.fill(0.0);
    pass.second.fill(0.0);
    for j in 0..n {
        for (k, sign) in [1.0, -1.0].into_iter().enumerate() {
            let g = gamma * sign;
            for r in 0..n {
                point[r] = x[r] + factor[(r, j)] * g;
            }
            map(point, &mut pass.image)?;
            check_finite(pass.image.as_slice(), what)?;
            pass.images.set_column(1 + j + k * n, &pass.image);
            let d = if k == 0 {
                &mut pass.plus
            } else {
                &mut pass.minus
            };
            residual(&pass.image, &pass.centre, d)?;
            check_finite(d.as_slice(), what)?;
            for r in 0..dim {
                pass.d_bar[r] += d[r] * wi;
            }
            for c in 0..dim {
                let bc = d[c] * wi;
                for r in 0..dim {
                    pass.second[(r, c)] += d[r] * bc;
                }
            }
        }
        for r in 0..dim {
            pass.spread[(r, j)] = (pass.plus[r] - pass.minus[r]) * (wi * gamma);
        }
        pass.plus_all.set_column(j, &pass.plus);
        pass.minus_all.set_column(j, &pass.minus);
    }
    let points = DynSigmaPoints::with_weights(&pass.images, weights.mean_centre, wi);
    mean(&points, &mut pass.mean)?;
    check_finite(pass.mean.as_slice(), what)?;
    let weighted = (0..dim).all(|r| pass.mean[r] == pass.centre[r] + pass.d_bar[r]);
    if weighted {
        let w = weights.mean_correction();
        add_outer(&mut pass.second, &pass.d_bar, &pass.d_bar, w);
    } else if !weights.centre_modified {
        // e = residual(mean, Y_0): add -s e' - e s' + (Wc_0 + 1 - Wm_0) e e'.
        residual(&pass.mean, &pass.centre, &mut pass.about_mean)?;
        check_finite(pass.about_mean.as_slice(), what)?;
        let total = weights.covariance_centre + 1.0 - weights.mean_centre;
        add_outer(&mut pass.second, &pass.d_bar, &pass.about_mean, -1.0);
        add_outer(&mut pass.second, &pass.about_mean, &pass.d_bar, -1.0);
        add_outer(&mut pass.second, &pass.about_mean, &pass.about_mean, total);
    }
    Ok(())
}

/// out += w a b' (the static `add_outer`'s order of operations).
fn add_outer(out: &mut DMatrix<f64>, a: &DVector<f64>, b: &DVector<f64>, w: f64) {
    for c in 0..b.len() {
        let bc = b[c] * w;
        for r in 0..a.len() {
            out[(r, c)] += a[r] * bc;
        }
    }
}

/// X with X S = G for the lower-triangular semidefinite factor S (zero pivots give
/// zero columns): the static `solve_right_lower`.
pub(super) fn solve_right_lower(g: &DMatrix<f64>, s: &DMatrix<f64>, x: &mut DMatrix<f64>) {
    let (rows, n) = (g.nrows(), g.ncols());
    x.fill(0.0);
    for j in (0..n).rev() {
        let pivot = s[(j, j)];
        if pivot == 0.0 {
            continue;
        }
        for r in 0..rows {
            let mut v = g[(r, j)];
            for k in j + 1..n {
                v -= x[(r, k)] * s[(k, j)];
            }
            x[(r, j)] = v / pivot;
        }
    }
}

/// Z with S Z = B for the lower-triangular semidefinite factor S (rows zero where S
/// has a zero pivot), by forward substitution.
pub(super) fn solve_lower(s: &DMatrix<f64>, b: &DMatrix<f64>, z: &mut DMatrix<f64>) {
    let (n, cols) = (b.nrows(), b.ncols());
    z.fill(0.0);
    for c in 0..cols {
        for i in 0..n {
            let pivot = s[(i, i)];
            if pivot == 0.0 {
                continue;
            }
            let mut v = b[(i, c)];
            for k in 0..i {
                v -= s[(i, k)] * z[(k, c)];
            }
            z[(i, c)] = v / pivot;
        }
    }
}
