//! Sigma-point (unscented) prediction and correlated-noise update.
//!
//! Scaled unscented transform (Julier & Uhlmann, "Unscented filtering and nonlinear
//! estimation", Proc. IEEE 92(3), 2004; scaling and weights as in Van der Merwe,
//! *Sigma-Point Kalman Filters for Probabilistic Inference in Dynamic State-Space
//! Models*, PhD thesis, 2004, eq. 3.73-3.75): for a Gaussian of dimension L with
//! factor S (S S' = covariance), lambda = alpha^2 (L + kappa) - L and
//! gamma = sqrt(L + lambda),
//!
//! ```text
//! chi_0 = mean, chi_i = mean + gamma S_i, chi_{L+i} = mean - gamma S_i   (S_i: column i)
//! Wm_0 = lambda / (L + lambda), Wc_0 = Wm_0 + 1 - alpha^2 + beta, Wm_i = Wc_i = 1 / (2 (L + lambda))
//! ```
//!
//! **Weight families.** [`UnscentedTransform::new`] takes Van der Merwe's scaled
//! parameters (alpha, beta, kappa), as filterpy's `MerweScaledSigmaPoints`;
//! [`UnscentedTransform::julier`] is Julier's original family with one parameter
//! kappa (alpha = 1, beta = 0, so lambda = kappa and Wc_0 = Wm_0 = kappa / (L + kappa)),
//! as filterpy's `JulierSigmaPoints`. beta must be >= 0; kappa may be negative as long
//! as L + kappa > 0 for the dimension L the transform is used at (else
//! [`Error::InvalidParameter`] at that use).
//!
//! **Negative kappa: the centre-point-modified form.** With kappa < 0 the centre weight
//! can be negative, and the plain covariance sum_i Wc_i (Y_i - y_hat)(Y_i - y_hat)' can
//! then be indefinite on a nonlinear map (kappa = 3 - L, which matches the fourth
//! moments of a Gaussian, is negative for L > 3). When kappa < 0 **and** Wc_0 < 0,
//! every covariance of the transform (predicted P, P_yy) is computed in Julier's
//! modified form, with deviations taken from the propagated centre point:
//!
//! ```text
//! P = sum_{i>0} Wc_i (Y_i - Y_0)(Y_i - Y_0)'  (+ Q or R)         (mean unchanged)
//! ```
//!
//! positive semidefinite because every weight in it is positive (Julier & Uhlmann, "A
//! new extension of the Kalman filter to nonlinear systems", SPIE AeroSense 1997,
//! sec. 4; Julier & Uhlmann 2004, sec. IV). It equals the plain form plus
//! (1 + Wm_0 - Wc_0) (y_hat - Y_0)(y_hat - Y_0)', which vanishes on linear maps
//! (y_hat = Y_0), so the filter still equals the Kalman filter there. P_xy needs no
//! change (its centre term is zero). With kappa >= 0 the plain form is kept, also for
//! a small alpha whose Wc_0 is negative (alpha = 0.1 gives Wc_0 = -96 at L = 3): that
//! is the scaled transform as published and as filterpy computes it.
//!
//! **Two updates** ([`SigmaPointUpdate`], chosen with
//! [`UnscentedTransform::with_update`]):
//!
//! - [`SigmaPointUpdate::Additive`] (default): the textbook UKF update, sigma points
//!   over x alone (L = N), R added to P_yy, M through the statistically linearised
//!   cross terms (see the variant). With M = 0 it is filterpy's Merwe-point UKF.
//! - [`SigmaPointUpdate::Augmented`]: sigma points over the joint [x_k; v_k] with
//!   covariance [[P, M], [M', R]] (L = N + M), each pushed through y = h(x) + v.
//!
//! **Correlated noise, augmented.** The augmented update draws its sigma points over
//! the joint [x_k; v_k] and pushes each through y = h(x) + v. This is exact in the one-step model x_k = f(x_{k-1}) + G w_{k-1},
//! whatever f: x_{k-1} is independent of v_k, so Cov(x_k, v_k) = Cov(G w_{k-1}, v_k)
//! = M. It is the augmented UKF over [x_{k-1}; w; v] (Julier & Uhlmann 2004,
//! sec. V) with the prediction and the update split at x_k (the update redraws its
//! points at x_k instead of reusing the propagated ones, as pykalman's augmented UKF
//! does: see the variant), so that any number of predictions can separate two
//! updates (then M is the carried Cov(e_k, v_k)).
//! On linear models the transform is exact and both updates equal
//! [`crate::update::correlated_update`] (tested to 1e-10, with and without M):
//!
//! ```text
//! y_hat = sum Wm_i Y_i,  P_yy = sum Wc_i (Y_i - y_hat)(Y_i - y_hat)',
//! P_xy  = sum Wc_i (X_i - x)(Y_i - y_hat)'      (= P H' + M when h is linear)
//! K = P_xy P_yy^-1, x+ = x + K (y - y_hat), P+ = P - K P_yy K'
//! ```
//!
//! The joint covariance must have a square root: an indefinite [[P, M], [M', R]]
//! is refused with [`Error::InvalidJointCovariance`], never factored around. Sums
//! are accumulated from deviations to the centre point; the mapped points are kept on
//! the stack for the mean hooks ([`SigmaPoints`]), so nothing is allocated.

use nalgebra::{SMatrix, SVector};

mod points;

use points::PlainMeasurement;
pub use points::SigmaPoints;
pub(crate) use points::{MeasurementHooks, ModelHooks};

use crate::gaussian::check_finite;
use crate::linalg::{joint_factor, mul_static, spd_inverse_log_det};
use crate::scalar::{lit, to_f64};
use crate::square_root::covariance_factor;
use crate::update::check_innovation_conditioning;
use crate::{Error, Result, Scalar, SigmaPointMeasurement, StateAndCovariance};

/// Which sigma-point update [`unscented_update`] runs. Both reduce to
/// [`crate::update::correlated_update`] on a linear measurement, with and without M.
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum SigmaPointUpdate {
    /// The textbook (additive-noise) UKF update (default): 2N + 1 sigma points over
    /// the state x alone (L = N), pushed through h; R is added to P_yy, and M enters
    /// through the statistically linearised measurement H~ = P_xy' P^-1:
    ///
    /// ```text
    /// P_yy = sum Wc_i (Y_i - y_hat)(Y_i - y_hat)' + R + H~ M + M' H~'
    /// P_xy = sum Wc_i (X_i - x)(Y_i - y_hat)' + M
    /// ```
    ///
    /// With M = 0 this is the Merwe scaled-sigma-point UKF of filterpy
    /// (`UnscentedKalmanFilter` with `MerweScaledSigmaPoints`); as M goes to 0 it is
    /// continuous. H~ M is computed as G' L21' with L21 = M' S^-T the joint factor's
    /// block and G the sigma points' whitened cross terms (no inverse of P).
    #[default]
    Additive,
    /// The augmented update: 2(N + M) + 1 sigma points over the joint [x; v] with
    /// covariance [[P, M], [M', R]], each pushed through y = h(x) + v. With M = 0 it is
    /// another filter than the textbook one on a nonlinear h (its points spread over
    /// N + M dimensions).
    ///
    /// **Relation to pykalman's `UnscentedKalmanFilter`** (its augmented UKF: points
    /// over [x; w; v], L = 2N + M for a measurement of dimension M, Julier's weights
    /// with kappa = 3 - L, the plain covariance form). With no prediction before the
    /// update (pykalman's first step) its w-points sit at the state mean with v = 0,
    /// where the centre point is, so their weight merges with the centre weight; with a
    /// zero cross-covariance and [`UnscentedTransform::julier`]`(3 - (N + M))` this
    /// update is then the same sums, hence the same posterior, as long as N + M <= 3
    /// (for N + M > 3, kappa < 0 selects the centre-point-modified form here, which
    /// pykalman does not use). After a prediction they are different filters on a
    /// nonlinear h: pykalman corrects with its propagated points f(x_i, w_i) and their
    /// v_i, while this update redraws its points from the predicted mean and covariance.
    /// The predicted moments themselves agree ([`unscented_predict`] with
    /// `julier(3 - N)`, N <= 3), so with a linear h the two still agree. Tested in
    /// `estim-core/tests/unscented_pykalman.rs` against pykalman 0.11.2 for
    /// N + M = 2 and 3: equal to 1e-12 relative without a prediction; after one
    /// prediction through a nonlinear f, range and bearing measurements differ by
    /// 4e-4 to 4e-2 relative (in x or P).
    Augmented,
}

/// Parameters of the scaled unscented transform (see the module docs), validated,
/// and the sigma-point update it runs.
///
/// With the `serde` feature: `{ "alpha": .., "beta": .., "kappa": .. }`, checked by
/// [`UnscentedTransform::new`] on deserialization.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(try_from = "UncheckedUnscentedTransform")
)]
pub struct UnscentedTransform {
    alpha: f64,
    beta: f64,
    kappa: f64,
    #[cfg_attr(feature = "serde", serde(default))]
    update: SigmaPointUpdate,
}

/// The serialized form of [`UnscentedTransform`], checked by `TryFrom`.
#[cfg(feature = "serde")]
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct UncheckedUnscentedTransform {
    alpha: f64,
    beta: f64,
    kappa: f64,
    #[serde(default)]
    update: SigmaPointUpdate,
}

#[cfg(feature = "serde")]
impl TryFrom<UncheckedUnscentedTransform> for UnscentedTransform {
    type Error = Error;

    fn try_from(u: UncheckedUnscentedTransform) -> Result<Self> {
        Ok(Self::new(u.alpha, u.beta, u.kappa)?.with_update(u.update))
    }
}

impl Default for UnscentedTransform {
    /// alpha = 1, beta = 2, kappa = 0: all weights but the centre's covariance weight
    /// positive (Wm_0 = 0, Wc_0 = 2), so P_yy is a positive combination; beta = 2 is
    /// optimal for Gaussian priors (Van der Merwe 2004, sec. 3.2.2). The
    /// [`SigmaPointUpdate::Additive`] update.
    fn default() -> Self {
        Self {
            alpha: 1.0,
            beta: 2.0,
            kappa: 0.0,
            update: SigmaPointUpdate::Additive,
        }
    }
}

impl UnscentedTransform {
    /// Transform with spread `alpha` (> 0), prior-knowledge weight `beta` (>= 0) and
    /// secondary scaling `kappa` (finite; a negative kappa needs L + kappa > 0 at the
    /// dimension L of each use, and selects the centre-point-modified covariance where
    /// Wc_0 < 0: see the module docs).
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming the offending parameter.
    pub fn new(alpha: f64, beta: f64, kappa: f64) -> Result<Self> {
        if !(alpha.is_finite() && alpha > 0.0) {
            return Err(Error::InvalidParameter {
                name: "alpha",
                reason: format!("must be finite and > 0, got {alpha}"),
            });
        }
        if !(beta.is_finite() && beta >= 0.0) {
            return Err(Error::InvalidParameter {
                name: "beta",
                reason: format!("must be finite and >= 0, got {beta}"),
            });
        }
        if !kappa.is_finite() {
            return Err(Error::InvalidParameter {
                name: "kappa",
                reason: format!("must be finite, got {kappa}"),
            });
        }
        Ok(Self {
            alpha,
            beta,
            kappa,
            update: SigmaPointUpdate::default(),
        })
    }

    /// Julier's family (Julier & Uhlmann 2004): alpha = 1, beta = 0 and `kappa`, so
    /// lambda = kappa; kappa = 3 - L matches the fourth moments of a Gaussian (for
    /// L > 3 it is negative, and the centre-point-modified covariance keeps the
    /// results positive semidefinite: see the module docs).
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for a non-finite kappa.
    pub fn julier(kappa: f64) -> Result<Self> {
        Self::new(1.0, 0.0, kappa)
    }

    /// The same weights with the sigma-point update `update`.
    #[must_use]
    pub fn with_update(self, update: SigmaPointUpdate) -> Self {
        Self { update, ..self }
    }

    /// The sigma-point update [`unscented_update`] runs.
    pub fn update(&self) -> SigmaPointUpdate {
        self.update
    }

    /// The weights at dimension `l` (module docs).
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] if l + kappa <= 0 (no spread).
    pub(crate) fn weights<T: Scalar>(&self, l: usize) -> Result<Weights<T>> {
        let l = l as f64;
        let spread = self.alpha * self.alpha * (l + self.kappa); // = L + lambda
        if !(spread > 0.0 && spread.is_finite()) {
            return Err(Error::InvalidParameter {
                name: "kappa",
                reason: format!(
                    "L + kappa must be > 0, got L = {l} and kappa = {}",
                    self.kappa
                ),
            });
        }
        let lambda = spread - l;
        let wm0 = lambda / spread;
        let wc0 = wm0 + 1.0 - self.alpha * self.alpha + self.beta;
        Ok(Weights {
            gamma: lit(spread.sqrt()),
            mean_centre: lit(wm0),
            covariance_centre: lit(wc0),
            other: lit(0.5 / spread),
            centre_modified: self.kappa < 0.0 && wc0 < 0.0,
        })
    }
}

/// The weights of one use of the transform.
pub(crate) struct Weights<T> {
    /// sqrt(L + lambda).
    pub(crate) gamma: T,
    /// Wm_0.
    pub(crate) mean_centre: T,
    /// Wc_0.
    pub(crate) covariance_centre: T,
    /// Wm_i = Wc_i, i > 0.
    pub(crate) other: T,
    /// Covariances in the centre-point-modified form (module docs).
    pub(crate) centre_modified: bool,
}

impl<T: Scalar> Weights<T> {
    /// The weight of d_bar d_bar' that turns sum_{i>0} W_i d_i d_i' (d_i = Y_i - Y_0,
    /// d_bar = sum_{i>0} W_i d_i = y_hat - Y_0) into the covariance: Wc_0 - Wm_0 - 1 in
    /// the plain form (sum_i Wc_i (d_i - d_bar)(d_i - d_bar)', with sum_{i>0} W_i =
    /// 1 - Wm_0), zero in the centre-point-modified form.
    pub(crate) fn mean_correction(&self) -> T {
        if self.centre_modified {
            T::zero()
        } else {
            self.covariance_centre - self.mean_centre - T::one()
        }
    }
}

/// Sigma-point prediction x_k = f(x_{k-1}) + G w, Cov(G w) = `process_noise`:
/// mean sum Wm_i f(chi_i), covariance sum Wc_i (f(chi_i) - mean)(...)' + Q_d (or the
/// centre-point-modified form, module docs).
///
/// # Errors
/// [`Error::NonFinite`]; [`Error::InvalidCovariance`] if the prior covariance has
/// no square root; [`Error::InvalidParameter`] if N + kappa <= 0; the errors of
/// `propagate`.
pub fn unscented_predict<T, F, const N: usize>(
    transform: &UnscentedTransform,
    prior: &StateAndCovariance<T, N>,
    propagate: F,
    process_noise: &SMatrix<T, N, N>,
) -> Result<StateAndCovariance<T, N>>
where
    T: Scalar,
    F: Fn(&SVector<T, N>) -> Result<SVector<T, N>>,
{
    Ok(unscented_predict_linearised(transform, prior, propagate, process_noise)?.0)
}

/// [`unscented_predict`], and the statistical linearisation of `propagate` from the
/// same sigma points: Phi~ = D' P^-1 with D = sum Wc_i (chi_i - x)(f(chi_i) - mean)'
/// the cross-covariance of prior and propagated points (Saerkkae 2013, *Bayesian
/// Filtering and Smoothing*, sec. 9.1 and alg. 9.6's D_{k+1}), so that P Phi~' = D
/// exactly: the RTS smoother of the linearised model is then the unscented RTS
/// smoother. With S S' = P and g_j = W gamma (f(chi_j+) - f(chi_j-)), D = S G' and
/// Phi~ = G S^-1 (no inverse of P; a zero column of a singular S gives a zero
/// column of Phi~, and still P Phi~' = D). On a linear map Phi~ = Phi.
///
/// # Errors
/// Those of [`unscented_predict`].
pub fn unscented_predict_linearised<T, F, const N: usize>(
    transform: &UnscentedTransform,
    prior: &StateAndCovariance<T, N>,
    propagate: F,
    process_noise: &SMatrix<T, N, N>,
) -> Result<(StateAndCovariance<T, N>, SMatrix<T, N, N>)>
where
    T: Scalar,
    F: Fn(&SVector<T, N>) -> Result<SVector<T, N>>,
{
    predict_with_hooks(
        transform,
        prior,
        propagate,
        |a, b| a - b,
        |points| Ok(points.weighted_mean()),
        process_noise,
    )
}

/// [`unscented_predict_linearised`] with a state residual and mean (the hooks of
/// [`crate::SigmaPointProcess`]): deviations d_i = residual(f(chi_i), f(chi_0)), the
/// mean from the hook, e = residual(mean, f(chi_0)) and the covariance about it as in
/// [`sigma_statistics`].
pub(crate) fn predict_with_hooks<T, F, D, A, const N: usize>(
    transform: &UnscentedTransform,
    prior: &StateAndCovariance<T, N>,
    propagate: F,
    residual: D,
    mean: A,
    process_noise: &SMatrix<T, N, N>,
) -> Result<(StateAndCovariance<T, N>, SMatrix<T, N, N>)>
where
    T: Scalar,
    F: Fn(&SVector<T, N>) -> Result<SVector<T, N>>,
    D: Fn(&SVector<T, N>, &SVector<T, N>) -> SVector<T, N>,
    A: Fn(&SigmaPoints<'_, T, N>) -> Result<SVector<T, N>>,
{
    check_finite(process_noise.as_slice(), "process noise")?;
    let s = covariance_factor(prior.covariance(), "prior covariance")?;
    let weights = transform.weights::<T>(N)?;
    let (gamma, wi) = (weights.gamma, weights.other);
    let x = prior.state();
    let centre = propagate(x)?;
    check_finite(centre.as_slice(), "propagated sigma point")?;
    // Deviations d_i = f(chi_i) - f(chi_0): mean = f(chi_0) + d_bar, covariance
    // sum_{i>0} W_i d_i d_i' + (Weights::mean_correction) d_bar d_bar'.
    let mut d_bar = SVector::<T, N>::zeros();
    let mut second = SMatrix::<T, N, N>::zeros();
    let mut spread = SMatrix::<T, N, N>::zeros(); // G, column j = g_j
    let mut mapped = [[SVector::<T, N>::zeros(); 2]; N];
    for (i, images) in mapped.iter_mut().enumerate() {
        let mut pair = [SVector::<T, N>::zeros(); 2];
        for (k, sign) in [T::one(), -T::one()].into_iter().enumerate() {
            let point = x + s.column(i) * (gamma * sign);
            let y = propagate(&point)?;
            let d = residual(&y, &centre);
            check_finite(d.as_slice(), "propagated sigma point")?;
            d_bar += d * wi;
            add_outer(&mut second, &d, &d, wi);
            pair[k] = d;
            images[k] = y;
        }
        spread.set_column(i, &((pair[0] - pair[1]) * (wi * gamma)));
    }
    let points = SigmaPoints {
        centre: &centre,
        centre_weight: weights.mean_centre,
        weight: wi,
        pairs: [&mapped, &[]],
    };
    let mean = mean(&points)?;
    check_finite(mean.as_slice(), "predicted state")?;
    let mut p = second;
    if mean == centre + d_bar {
        add_outer(&mut p, &d_bar, &d_bar, weights.mean_correction());
    } else if !weights.centre_modified {
        let e = residual(&mean, &centre);
        check_finite(e.as_slice(), "predicted state")?;
        add_about_mean(&mut p, &weights, &d_bar, &e);
    }
    let p = symmetric_sum(&p, process_noise);
    check_finite(p.as_slice(), "predicted covariance")?;
    let transition = solve_right_lower(&spread, &s);
    check_finite(transition.as_slice(), "statistically linearised transition")?;
    Ok((StateAndCovariance::from_step(mean, p)?, transition))
}

/// sum_{i>0} W d_i d_i' (in `second`) to sum_i Wc_i (d_i - e)(d_i - e)' (d_0 = 0) for
/// s = sum_{i>0} W d_i: add -s e' - e s' + (Wc_0 + 1 - Wm_0) e e'.
fn add_about_mean<T: Scalar, const D: usize>(
    second: &mut SMatrix<T, D, D>,
    weights: &Weights<T>,
    s: &SVector<T, D>,
    e: &SVector<T, D>,
) {
    let total = weights.covariance_centre + T::one() - weights.mean_centre;
    add_outer(second, s, e, -T::one());
    add_outer(second, e, s, -T::one());
    add_outer(second, e, e, total);
}

/// The statistical linearisation H~ = P_xy' P^-1 of `model`'s h about `prior`, from
/// the 2N + 1 sigma points over x of `transform`'s weights at L = N (P_xy of those
/// points alone, before R and M): with S S' = P and g_j = W gamma (h(chi_j+) -
/// h(chi_j-)) (differences through [`SigmaPointMeasurement::residual`]),
/// H~ = G S^-1. On a linear h, H~ = H. What the unscented runner uses in place of a
/// Jacobian (its bookkeeping, never the estimate).
///
/// # Errors
/// [`Error::InvalidCovariance`] if P has no square root, [`Error::InvalidParameter`]
/// if N + kappa <= 0, [`Error::NonFinite`], the errors of `model.predict`.
pub fn measurement_linearisation<T, Mm, const N: usize, const M: usize>(
    transform: &UnscentedTransform,
    prior: &StateAndCovariance<T, N>,
    model: &Mm,
) -> Result<SMatrix<T, M, N>>
where
    T: Scalar,
    Mm: SigmaPointMeasurement<T, N, M> + ?Sized,
{
    let s = covariance_factor(prior.covariance(), "prior covariance")?;
    let weights = transform.weights::<T>(N)?;
    let (gamma, wi) = (weights.gamma, weights.other);
    let x = prior.state();
    let centre = model.predict(x)?;
    check_finite(centre.as_slice(), "predicted measurement")?;
    let mut spread = SMatrix::<T, M, N>::zeros();
    for j in 0..N {
        let plus = model.predict(&(x + s.column(j) * gamma))?;
        let minus = model.predict(&(x - s.column(j) * gamma))?;
        let g = (model.residual(&plus, &centre) - model.residual(&minus, &centre)) * (wi * gamma);
        spread.set_column(j, &g);
    }
    let h = solve_right_lower(&spread, &s);
    check_finite(h.as_slice(), "statistically linearised measurement")?;
    Ok(h)
}

/// X with X S = G for a lower-triangular S whose zero pivots come with zero columns
/// (a semidefinite Cholesky factor): back substitution, X's column j zero where S_jj
/// is (G's column j is then zero too: the sigma points along it coincide).
fn solve_right_lower<T: Scalar, const R: usize, const N: usize>(
    g: &SMatrix<T, R, N>,
    s: &SMatrix<T, N, N>,
) -> SMatrix<T, R, N> {
    let mut x = SMatrix::<T, R, N>::zeros();
    for j in (0..N).rev() {
        let pivot = s[(j, j)];
        if pivot.is_zero() {
            continue;
        }
        for r in 0..R {
            let mut v = g[(r, j)];
            for k in j + 1..N {
                v -= x[(r, k)] * s[(k, j)];
            }
            x[(r, j)] = v / pivot;
        }
    }
    x
}

/// Everything a sigma-point update produced.
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[derive(Debug, Clone, PartialEq)]
pub struct UnscentedOutcome<T: Scalar, const N: usize, const M: usize> {
    /// Posterior mean and covariance.
    pub posterior: StateAndCovariance<T, N>,
    /// Predicted measurement sum Wm_i Y_i.
    pub predicted_measurement: SVector<T, M>,
    /// Innovation y - predicted measurement.
    pub innovation: SVector<T, M>,
    /// Innovation covariance P_yy.
    pub innovation_covariance: SMatrix<T, M, M>,
    /// Cross-covariance P_xy of state and measurement.
    pub state_measurement_covariance: SMatrix<T, N, M>,
    /// Gain K = P_xy P_yy^-1.
    pub gain: SMatrix<T, N, M>,
    /// Normalised innovation squared.
    pub nis: T,
}

/// Sigma-point update with correlated noise, in the form of
/// [`UnscentedTransform::update`]: [`SigmaPointUpdate::Additive`] (sigma points over
/// x, R and the linearised cross terms of M added) or
/// [`SigmaPointUpdate::Augmented`] (sigma points over the joint
/// [x; v] ~ N([x; 0], [[P, M], [M', R]]), each pushed through y = h(x) + v); see the
/// module docs. `cross_covariance` is M = Cov(x_k, v_k).
///
/// # Errors
/// [`Error::NonFinite`]; [`Error::InvalidJointCovariance`] if
/// [[P, M], [M', R]] has no square root; [`Error::InnovationNotPositiveDefinite`] /
/// [`Error::InnovationIllConditioned`] for P_yy as for
/// [`crate::update::correlated_update`]; [`Error::InvalidParameter`] if L + kappa <= 0 (L = N,
/// or N + M for the augmented update); the errors of `predict_measurement`.
pub fn unscented_update<T, H, const N: usize, const M: usize>(
    transform: &UnscentedTransform,
    prior: &StateAndCovariance<T, N>,
    measurement: &SVector<T, M>,
    predict_measurement: H,
    measurement_noise: &SMatrix<T, M, M>,
    cross_covariance: &SMatrix<T, N, M>,
) -> Result<UnscentedOutcome<T, N, M>>
where
    T: Scalar,
    H: Fn(&SVector<T, N>) -> Result<SVector<T, M>>,
{
    check_finite(measurement.as_slice(), "measurement")?;
    let stats = sigma_statistics(
        transform,
        prior,
        &PlainMeasurement(predict_measurement),
        measurement_noise,
        cross_covariance,
    )?;
    let innovation = measurement - stats.predicted;
    let (inverse, nis, _) = stats.factor(&innovation)?;
    let mut gain = SMatrix::zeros();
    let mut post = SMatrix::zeros();
    let state = stats.posterior(prior, &innovation, &inverse, &mut gain, &mut post)?;
    Ok(UnscentedOutcome {
        posterior: StateAndCovariance::from_step(state, post)?,
        predicted_measurement: stats.predicted,
        innovation,
        innovation_covariance: stats.innovation_covariance,
        state_measurement_covariance: stats.cross,
        gain,
        nis,
    })
}

/// What the sigma points of an update give before the measurement is used: y_hat,
/// P_yy (with R and the cross terms of M) and P_xy.
pub(crate) struct SigmaStatistics<T: Scalar, const N: usize, const M: usize> {
    /// y_hat = sum Wm_i Y_i.
    pub(crate) predicted: SVector<T, M>,
    /// P_yy.
    pub(crate) innovation_covariance: SMatrix<T, M, M>,
    /// P_xy.
    pub(crate) cross: SMatrix<T, N, M>,
}

impl<T: Scalar, const N: usize, const M: usize> SigmaStatistics<T, N, M> {
    /// P_yy^-1 (checked as [`crate::update::correlated_update`] checks S), the NIS of
    /// `innovation` and ln det P_yy (from the same factorization).
    pub(crate) fn factor(&self, innovation: &SVector<T, M>) -> Result<(SMatrix<T, M, M>, T, T)> {
        check_finite(innovation.as_slice(), "innovation")?;
        let pyy = &self.innovation_covariance;
        let (inverse, log_det) =
            spd_inverse_log_det(pyy).ok_or(Error::InnovationNotPositiveDefinite)?;
        check_innovation_conditioning(pyy, &inverse)?;
        let nis = innovation.dot(&mul_static(&inverse, innovation));
        if !nis.is_finite() {
            return Err(Error::NonFinite {
                what: "normalised innovation squared",
            });
        }
        Ok((inverse, nis, log_det))
    }

    /// K = P_xy P_yy^-1 into `gain`, P+ = P - K P_yy K' = P - K P_xy' into
    /// `covariance` (upper triangle, mirrored); returns x + K innovation.
    pub(crate) fn posterior(
        &self,
        prior: &StateAndCovariance<T, N>,
        innovation: &SVector<T, M>,
        inverse: &SMatrix<T, M, M>,
        gain: &mut SMatrix<T, N, M>,
        covariance: &mut SMatrix<T, N, N>,
    ) -> Result<SVector<T, N>> {
        *gain = mul_static(&self.cross, inverse);
        let state = prior.state() + mul_static(gain, innovation);
        let kpxy = mul_static(gain, &self.cross.transpose());
        let p = prior.covariance();
        let half = lit::<T>(0.5);
        for j in 0..N {
            for i in 0..=j {
                let v = (p[(i, j)] + p[(j, i)]) * half - (kpxy[(i, j)] + kpxy[(j, i)]) * half;
                covariance[(i, j)] = v;
                covariance[(j, i)] = v;
            }
        }
        check_finite(state.as_slice(), "posterior state")?;
        check_finite(covariance.as_slice(), "posterior covariance")?;
        Ok(state)
    }
}

/// The sigma-point statistics of an update of `prior` with noise covariance
/// `measurement_noise` and cross-covariance M = `cross_covariance`, in the form of
/// [`UnscentedTransform::update`] (see [`unscented_update`]), with `model`'s h and
/// its residual and mean hooks: deviations d_i = residual(Y_i, Y_0) from the centre
/// point, y_hat = mean(Y), e = residual(y_hat, Y_0) and, in the plain form,
/// P_yy = sum_i Wc_i (d_i - e)(d_i - e)' (d_0 = 0), summed as
/// sum_{i>0} W d_i d_i' - s e' - e s' + (Wc_0 + 1 - Wm_0) e e' with s = sum_{i>0} W d_i
/// (for the weighted mean e = s, and this is the form with `mean_correction`).
pub(crate) fn sigma_statistics<T, Mm, const N: usize, const M: usize>(
    transform: &UnscentedTransform,
    prior: &StateAndCovariance<T, N>,
    model: &Mm,
    measurement_noise: &SMatrix<T, M, M>,
    cross_covariance: &SMatrix<T, N, M>,
) -> Result<SigmaStatistics<T, N, M>>
where
    T: Scalar,
    Mm: MeasurementHooks<T, N, M>,
{
    check_finite(measurement_noise.as_slice(), "measurement noise covariance")?;
    check_finite(cross_covariance.as_slice(), "cross-covariance")?;
    check_finite(prior.state().as_slice(), "prior state")?;
    check_finite(prior.covariance().as_slice(), "prior covariance")?;
    let p = prior.covariance();
    let Some(l) = joint_factor(p, cross_covariance, measurement_noise) else {
        return Err(Error::InvalidJointCovariance {
            min_eigenvalue: to_f64(crate::cross::joint_min_correlation_eigenvalue(
                p,
                cross_covariance,
                measurement_noise,
            )?),
        });
    };
    let x = prior.state();
    let centre = model.predict(x)?;
    check_finite(centre.as_slice(), "predicted measurement")?;
    let mut d_bar = SVector::<T, M>::zeros();
    let mut second = SMatrix::<T, M, M>::zeros();
    let mut cross = SMatrix::<T, N, M>::zeros();
    // The mapped points, kept for the mean hook: pairs along the state columns, then
    // (augmented) along the noise columns.
    let mut state_points = [[SVector::<T, M>::zeros(); 2]; N];
    let mut noise_points = [[SVector::<T, M>::zeros(); 2]; M];
    let columns = match transform.update {
        SigmaPointUpdate::Additive => N,
        SigmaPointUpdate::Augmented => N + M,
    };
    let weights = transform.weights::<T>(columns)?;
    let (gamma, wi) = (weights.gamma, weights.other);
    // Additive only: H~ M = G' L21' (module docs of `SigmaPointUpdate::Additive`).
    let mut linearised_cross = SMatrix::<T, M, M>::zeros();
    // Column j of the joint factor: state part (L11 or L21 rows) and noise part (the
    // additive update spreads over the state part alone).
    for j in 0..columns {
        let (dx, dv): (SVector<T, N>, SVector<T, M>) = match transform.update {
            SigmaPointUpdate::Additive => (l.a.column(j).into_owned(), SVector::zeros()),
            SigmaPointUpdate::Augmented if j < N => {
                (l.a.column(j).into_owned(), l.c.column(j).into_owned())
            }
            SigmaPointUpdate::Augmented => (SVector::zeros(), l.d.column(j - N).into_owned()),
        };
        let mut pair = [SVector::<T, M>::zeros(); 2];
        let mut mapped = [SVector::<T, M>::zeros(); 2];
        for (k, sign) in [T::one(), -T::one()].into_iter().enumerate() {
            let g = gamma * sign;
            let y = model.predict(&(x + dx * g))? + dv * g;
            let d = model.residual(&y, &centre);
            check_finite(d.as_slice(), "predicted measurement")?;
            d_bar += d * wi;
            add_outer(&mut second, &d, &d, wi);
            // sum W_i (X_i - x)(Y_i - y_hat)' = sum W_i g dx (d_i - e)'; the e part
            // vanishes because the dx of each +/- pair cancel.
            for c in 0..M {
                for r in 0..N {
                    cross[(r, c)] += dx[r] * g * d[c] * wi;
                }
            }
            pair[k] = d;
            mapped[k] = y;
        }
        if j < N {
            state_points[j] = mapped;
        } else {
            noise_points[j - N] = mapped;
        }
        if transform.update == SigmaPointUpdate::Additive {
            // P_xy = sum_j S_j g_j' with g_j = W_i gamma (d_j+ - d_j-), so
            // H~ = P_xy' P^-1 = G' S^-1 and H~ M = G' S^-1 M = G' L21'.
            let g = (pair[0] - pair[1]) * (wi * gamma);
            let l21 = l.c.column(j).into_owned();
            add_outer(&mut linearised_cross, &g, &l21, T::one());
        }
    }
    let points = SigmaPoints {
        centre: &centre,
        centre_weight: weights.mean_centre,
        weight: wi,
        pairs: [
            &state_points[..columns.min(N)],
            &noise_points[..columns - columns.min(N)],
        ],
    };
    let predicted = model.mean(&points)?;
    check_finite(predicted.as_slice(), "predicted measurement")?;
    let mut pyy = second;
    if predicted == centre + d_bar {
        // The weighted mean: e = s, taken as is (not by a subtraction that loses
        // digits when |Y_0| is large against the spread).
        add_outer(&mut pyy, &d_bar, &d_bar, weights.mean_correction());
    } else if !weights.centre_modified {
        let e = model.residual(&predicted, &centre);
        check_finite(e.as_slice(), "predicted measurement")?;
        add_about_mean(&mut pyy, &weights, &d_bar, &e);
    }
    if transform.update == SigmaPointUpdate::Additive {
        pyy += linearised_cross + linearised_cross.transpose() + measurement_noise;
        cross += cross_covariance;
    }
    let pyy = symmetric_sum(&pyy, &SMatrix::zeros());
    check_finite(pyy.as_slice(), "innovation covariance")?;
    Ok(SigmaStatistics {
        predicted,
        innovation_covariance: pyy,
        cross,
    })
}

/// out += w a b'.
#[inline(always)]
fn add_outer<T: Scalar, const R: usize, const C: usize>(
    out: &mut SMatrix<T, R, C>,
    a: &SVector<T, R>,
    b: &SVector<T, C>,
    w: T,
) {
    for c in 0..C {
        let bc = b[c] * w;
        for r in 0..R {
            out[(r, c)] += a[r] * bc;
        }
    }
}

/// (A + A')/2 + (B + B')/2, exactly symmetric.
fn symmetric_sum<T: Scalar, const N: usize>(
    a: &SMatrix<T, N, N>,
    b: &SMatrix<T, N, N>,
) -> SMatrix<T, N, N> {
    let half = lit::<T>(0.5);
    SMatrix::from_fn(|i, j| (a[(i, j)] + a[(j, i)]) * half + (b[(i, j)] + b[(j, i)]) * half)
}
