//! The one correlated-noise measurement update used by every filter.
//!
//! With M = Cov(G w_{k-1}, v_k) (Simon, *Optimal State Estimation*, 2006, sec. 7.1):
//!
//! - S = H P H' + H M + M' H' + R
//! - K = (P H' + M) S^-1
//! - short form: P+ = P - K (H P + M')
//! - Joseph-like form, valid for any gain:
//!   P+ = (I-KH) P (I-KH)' + K R K' - (I-KH) M K' - K M' (I-KH)'
//!
//! With M = 0 these are the textbook Kalman update.

use nalgebra::{SMatrix, SVector};

use crate::gaussian::{all_finite, check_finite, exactly_zero, symmetrize};
use crate::linalg::{
    gram_pair_into, joint_factor_into, minus_product_into, mul_lower_into, mul_static,
    mul_transpose_static, positive_normal, product_transposed, spd_inverse_log_det, Blocks,
};
use crate::scalar::{lit, to_f64};
use crate::{Error, Result, Scalar, StateAndCovariance};

/// How the posterior covariance is computed.
///
/// All four are algebraically identical at the optimal gain (and the first, third
/// and fourth for any gain); they differ in round-off. With A = P H' + M,
/// J = [[P, M], [M', R]] (the joint covariance of the prior error and the
/// measurement noise) and T = [I - K H, -K], the posterior error is T [e; v], so
/// P+ = T J T' (Simon 2006, eq. 7.18 generalised to M). Measured on 2,000
/// ill-conditioned priors (`estim-core/tests/numerical_forms.rs`, table in the crate
/// README), [`CovarianceUpdate::SquareRoot`] is the only form whose posteriors never
/// had an eigenvalue below -1e-12 ||P||; it is the default.
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum CovarianceUpdate {
    /// Joseph-like form, valid for any gain, evaluated expanded as
    /// P - K A' - A K' + K S K' (upper triangle, mirrored).
    JosephLike,
    /// Short form P - K (H P + M'), valid only at the optimal gain.
    Short,
    /// Product form T J T' with T = [I - K H, -K], evaluated as
    /// ((I-KH) P - K M') (I-KH)' - ((I-KH) M - K R) K' over the upper triangle
    /// (exactly symmetric). Needs no factorisation.
    Product,
    /// Square-root form (default): J = L L' by a Cholesky that tolerates round-off
    /// zero pivots (a pivot within 16 (N+M) eps J_jj of zero, with its column, is a
    /// zero column: a positive *semi*definite J is valid), B = T L, P+ = B B' (a
    /// Gram product: positive semidefinite by construction).
    ///
    /// **Fallback.** If J has no square root (a pivot below -16 (N+M) eps J_jj, or a
    /// zero pivot whose column is not zero to round-off) it is not factored around:
    /// the posterior is computed with [`CovarianceUpdate::JosephLike`] (the previous
    /// default, which needs no factor), and [`UpdateOutcome::covariance_form`] says
    /// so. Whether such an M is acceptable at all is the runners' [`crate::JointCheck`]
    /// policy on [[Q_acc, M], [M', R]] (reported in every update report by default,
    /// refused with `Reject`); [`crate::SquareRootKalmanFilter`] always refuses it.
    #[default]
    SquareRoot,
}

/// Everything an update produced.
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[derive(Debug, Clone, PartialEq)]
pub struct UpdateOutcome<T: Scalar, const N: usize, const M: usize> {
    /// Posterior mean and covariance.
    pub posterior: StateAndCovariance<T, N>,
    /// Innovation (residual) y - h(x).
    pub innovation: SVector<T, M>,
    /// Innovation covariance S.
    pub innovation_covariance: SMatrix<T, M, M>,
    /// Gain K.
    pub gain: SMatrix<T, N, M>,
    /// Normalised innovation squared, innovation' S^-1 innovation.
    pub nis: T,
    /// The form that computed the posterior covariance: the one asked for, except
    /// [`CovarianceUpdate::SquareRoot`] falling back to
    /// [`CovarianceUpdate::JosephLike`] when [[P, M], [M', R]] has no square root.
    pub covariance_form: CovarianceUpdate,
}

/// S = H P H' + H M + M' H' + R (Simon 2006, eq. 7.13).
pub fn innovation_covariance<T: Scalar, const N: usize, const M: usize>(
    covariance: &SMatrix<T, N, N>,
    jacobian: &SMatrix<T, M, N>,
    measurement_noise: &SMatrix<T, M, M>,
    cross_covariance: &SMatrix<T, N, M>,
) -> SMatrix<T, M, M> {
    let hm = jacobian * cross_covariance;
    symmetrize(
        &(jacobian * covariance * jacobian.transpose() + hm + hm.transpose() + measurement_noise),
    )
}

/// Posterior covariance for an arbitrary gain (Joseph-like form).
pub fn joseph_covariance<T: Scalar, const N: usize, const M: usize>(
    covariance: &SMatrix<T, N, N>,
    jacobian: &SMatrix<T, M, N>,
    measurement_noise: &SMatrix<T, M, M>,
    cross_covariance: &SMatrix<T, N, M>,
    gain: &SMatrix<T, N, M>,
) -> SMatrix<T, N, N> {
    let pht_m = covariance * jacobian.transpose() + cross_covariance;
    let s = innovation_covariance(covariance, jacobian, measurement_noise, cross_covariance);
    joseph_from_parts(covariance, &pht_m, &s, gain)
}

/// The Joseph-like form expanded: with A = P H' + M and S = H P H' + H M + M' H' + R,
///
/// (I-KH) P (I-KH)' + K R K' - (I-KH) M K' - K M' (I-KH)' = P - K A' - A K' + K S K'
///
/// exactly, for any gain K (multiply out the left side). Only the upper triangle is
/// computed and mirrored, so the result is exactly symmetric; cost N(N+1)/2 (3M)
/// + N M^2 multiply-adds instead of O(N^3).
#[inline(always)]
fn joseph_from_parts<T: Scalar, const N: usize, const M: usize>(
    covariance: &SMatrix<T, N, N>,
    pht_m: &SMatrix<T, N, M>,
    innovation_covariance: &SMatrix<T, M, M>,
    gain: &SMatrix<T, N, M>,
) -> SMatrix<T, N, N> {
    let mut out = SMatrix::zeros();
    joseph_into(covariance, pht_m, innovation_covariance, gain, &mut out);
    out
}

/// [`joseph_from_parts`] written into `out` (every entry).
#[inline(always)]
fn joseph_into<T: Scalar, const N: usize, const M: usize>(
    covariance: &SMatrix<T, N, N>,
    pht_m: &SMatrix<T, N, M>,
    innovation_covariance: &SMatrix<T, M, M>,
    gain: &SMatrix<T, N, M>,
    out: &mut SMatrix<T, N, N>,
) {
    let ks = mul_static(gain, innovation_covariance);
    for j in 0..N {
        for i in 0..=j {
            let mut v = T::zero();
            for k in 0..M {
                v += (ks[(i, k)] - pht_m[(i, k)]) * gain[(j, k)] - gain[(i, k)] * pht_m[(j, k)];
            }
            // P is symmetric to round-off: average its two triangles like `symmetrize`.
            let p = if i == j {
                covariance[(i, i)]
            } else {
                (covariance[(i, j)] + covariance[(j, i)]) * lit::<T>(0.5)
            };
            out[(i, j)] = p + v;
            out[(j, i)] = p + v;
        }
    }
}

/// I - K H.
#[inline(always)]
fn identity_minus_kh<T: Scalar, const N: usize, const M: usize>(
    gain: &SMatrix<T, N, M>,
    jacobian: &SMatrix<T, M, N>,
) -> SMatrix<T, N, N> {
    let mut a = -mul_static(gain, jacobian);
    for i in 0..N {
        a[(i, i)] += T::one();
    }
    a
}

/// Product form P+ = T J T', T = [I - K H, -K], J = [[P, M], [M', R]]:
/// X = (I-KH) P - K M' (N x N), Y = (I-KH) M - K R (N x M),
/// P+ = X (I-KH)' - Y K', upper triangle mirrored (exactly symmetric). P and R are
/// read through their averaged triangles, so J is exactly symmetric too.
#[inline(always)]
fn product_form<T: Scalar, const N: usize, const M: usize>(
    covariance: &SMatrix<T, N, N>,
    ikh: &SMatrix<T, N, N>,
    cross_covariance: &SMatrix<T, N, M>,
    measurement_noise: &SMatrix<T, M, M>,
    gain: &SMatrix<T, N, M>,
) -> SMatrix<T, N, N> {
    let p = symmetrize(covariance);
    let r = symmetrize(measurement_noise);
    let x = mul_static(ikh, &p) - mul_transpose_static(gain, cross_covariance);
    let y = mul_static(ikh, cross_covariance) - mul_static(gain, &r);
    let mut out = SMatrix::<T, N, N>::zeros();
    for j in 0..N {
        for i in 0..=j {
            let mut v = T::zero();
            for k in 0..N {
                v += x[(i, k)] * ikh[(j, k)];
            }
            for k in 0..M {
                v -= y[(i, k)] * gain[(j, k)];
            }
            out[(i, j)] = v;
            out[(j, i)] = v;
        }
    }
    out
}

/// Square-root form: J = L L' (round-off-tolerant Cholesky), B = [I-KH, -K] L,
/// P+ = B B' (upper triangle, mirrored). `None` if J has no square root (the caller
/// falls back, as documented on [`CovarianceUpdate::SquareRoot`]).
#[cfg(test)]
fn square_root_form<T: Scalar, const N: usize, const M: usize>(
    covariance: &SMatrix<T, N, N>,
    factored: &FactoredInnovation<'_, T, N, M>,
    cross_covariance: &SMatrix<T, N, M>,
    gain: &SMatrix<T, N, M>,
) -> Option<SMatrix<T, N, N>> {
    let mut out = SMatrix::zeros();
    square_root_into(covariance, factored, cross_covariance, gain, &mut out).then_some(out)
}

/// The square-root form written into `out` (every entry); false, with `out`
/// untouched, if J has no square root.
#[inline(always)]
fn square_root_into<T: Scalar, const N: usize, const M: usize>(
    covariance: &SMatrix<T, N, N>,
    factored: &FactoredInnovation<'_, T, N, M>,
    cross_covariance: &SMatrix<T, N, M>,
    gain: &SMatrix<T, N, M>,
    out: &mut SMatrix<T, N, N>,
) -> bool {
    let mut l = Blocks::<T, N, M, N, M>::zeros();
    if !joint_factor_into(
        covariance,
        cross_covariance,
        factored.measurement_noise,
        &mut l,
    ) {
        return false;
    }
    // B1 = (I-KH) L11 - K L21 = L11 - K (H L11 + L21) (N x N, N^2 M work instead
    // of N^3), B2 = -K L22 (N x M; the sign does not matter in B B'). L11 and L22
    // are lower triangular: the products skip the leading zeros of each column
    // (terms a * 0 added to a sum that is still +0 leave it +0, so bit for bit the
    // same as the full products); L21 = 0 when M = 0.
    // Products written into their buffers (returned by value they were copied).
    let mut hl = SMatrix::<T, M, N>::zeros();
    mul_lower_into(factored.jacobian, &l.a, &mut hl);
    if factored.correlated {
        hl += l.c;
    }
    let mut b1 = SMatrix::<T, N, N>::zeros();
    minus_product_into(&l.a, gain, &hl, &mut b1);
    let mut b2 = SMatrix::<T, N, M>::zeros();
    mul_lower_into(gain, &l.d, &mut b2);
    if gram_pair_into(&b1, &b2, out) {
        return true;
    }
    // Column (axpy) order over the whole matrix: column j of B B' is the sum over k of
    // column k of B times B_jk, one vector operation per term instead of a dot
    // product per entry of the upper triangle. Exactly symmetric all the same:
    // entries (i, j) and (j, i) add the same products (B_ik B_jk = B_jk B_ik exactly)
    // in the same order of k.
    for j in 0..N {
        let mut column = [T::zero(); N];
        for k in 0..N {
            let bjk = b1[(j, k)];
            for (i, v) in column.iter_mut().enumerate() {
                *v += b1[(i, k)] * bjk;
            }
        }
        for k in 0..M {
            let bjk = b2[(j, k)];
            for (i, v) in column.iter_mut().enumerate() {
                *v += b2[(i, k)] * bjk;
            }
        }
        for (i, v) in column.into_iter().enumerate() {
            out[(i, j)] = v;
        }
    }
    true
}

/// Multiple of machine epsilon below which S counts as numerically singular (see
/// [`Error::InnovationIllConditioned`]).
pub(crate) const RCOND_FLOOR: f64 = 1000.0;

/// S factorised once: used for the NIS, the gate and the gain.
pub(crate) struct FactoredInnovation<'a, T: Scalar, const N: usize, const M: usize> {
    pub(crate) covariance: SMatrix<T, M, M>,
    /// S^-1 (closed form for one or two measurements, else from the Cholesky factor;
    /// exactly symmetric).
    pub(crate) inverse: SMatrix<T, M, M>,
    /// P H'.
    pub(crate) pht: SMatrix<T, N, M>,
    pub(crate) nis: T,
    /// ln det S, from the factorization that gave `inverse`.
    pub(crate) log_det: T,
    /// Whether M is nonzero (skips the cross terms when it is zero).
    pub(crate) correlated: bool,
    /// R (for the product and square-root forms; borrowed, not copied).
    pub(crate) measurement_noise: &'a SMatrix<T, M, M>,
    /// H (for the product and square-root forms).
    pub(crate) jacobian: &'a SMatrix<T, M, N>,
}

/// Numerical singularity test of S, invariant to the units of each measurement
/// component: the reciprocal 1-norm condition number of the correlation matrix
/// C = D^-1/2 S D^-1/2 (D = diag S), from C^-1 = D^1/2 S^-1 D^1/2. A singular S
/// computed in floating point has rcond of order M eps; anything below RCOND_FLOOR
/// eps is refused, i.e. cond(C) above ~4e12 (the gain would have fewer than ~4
/// correct digits).
///
/// One measurement: rcond = 1. Two: C = [[1, rho], [rho, 1]], rcond = (1 - |rho|) /
/// (1 + |rho|) exactly, so rcond <= floor iff rho^2 = b^2 / (a d) >= k = ((1 - floor)
/// / (1 + floor))^2: tested as b^2 >= k a d, no square root or division, where a d is
/// a normal number (else the general computation).
#[inline(always)]
pub(crate) fn check_innovation_conditioning<T: Scalar, const M: usize>(
    s: &SMatrix<T, M, M>,
    inverse: &SMatrix<T, M, M>,
) -> Result<()> {
    let floor = T::default_epsilon() * lit::<T>(RCOND_FLOOR);
    if M == 1 {
        return Ok(());
    }
    if M == 2 {
        let (a, b, d) = (s[(0, 0)], s[(M - 1, 0)], s[(M - 1, M - 1)]);
        let ad = a * d;
        let bb = b * b;
        if positive_normal(ad) && bb.is_finite() {
            let k = (T::one() - floor) / (T::one() + floor);
            if bb < k * k * ad {
                return Ok(());
            }
            let rho = (bb / ad).sqrt();
            return Err(Error::InnovationIllConditioned {
                reciprocal_condition: to_f64((T::one() - rho) / (T::one() + rho)),
            });
        }
    }
    let sd = s.diagonal().map(|v| v.sqrt());
    let isd = sd.map(|v| T::one() / v);
    let mut norm_c = T::zero();
    let mut norm_c_inv = T::zero();
    for j in 0..M {
        let (mut col_c, mut col_c_inv) = (T::zero(), T::zero());
        for i in 0..M {
            col_c += s[(i, j)].abs() * isd[i];
            col_c_inv += inverse[(i, j)].abs() * sd[i];
        }
        norm_c = norm_c.max(col_c * isd[j]);
        norm_c_inv = norm_c_inv.max(col_c_inv * sd[j]);
    }
    // rcond = 1 / (||C||_1 ||C^-1||_1) <= floor, tested as a product (the division
    // only on the error path): the product is not finite and positive, or at least
    // 1 / floor.
    let product = norm_c * norm_c_inv;
    if !(product.is_finite() && product > T::zero() && product * floor < T::one()) {
        return Err(Error::InnovationIllConditioned {
            reciprocal_condition: to_f64(T::one() / product),
        });
    }
    Ok(())
}

/// Form and factorise S, compute the NIS. Checks finiteness of every input and the
/// conditioning of S.
#[inline(always)]
pub(crate) fn factor_innovation<'a, T: Scalar, const N: usize, const M: usize>(
    prior: &StateAndCovariance<T, N>,
    innovation: &SVector<T, M>,
    jacobian: &'a SMatrix<T, M, N>,
    measurement_noise: &'a SMatrix<T, M, M>,
    cross_covariance: &SMatrix<T, N, M>,
) -> Result<FactoredInnovation<'a, T, N, M>> {
    let p = prior.covariance();
    let correlated = !exactly_zero(cross_covariance.as_slice());
    let pht = product_transposed(p, jacobian);
    let s = if correlated {
        innovation_covariance(p, jacobian, measurement_noise, cross_covariance)
    } else {
        // M = 0: skip the zero products H M; S = H (P H') + R, upper triangle mirrored
        // (same value as innovation_covariance up to round-off).
        let mut s = SMatrix::<T, M, M>::zeros();
        for j in 0..M {
            for i in 0..=j {
                let mut v = (measurement_noise[(i, j)] + measurement_noise[(j, i)]) * lit::<T>(0.5);
                for l in 0..N {
                    v += jacobian[(i, l)] * pht[(l, j)];
                }
                s[(i, j)] = v;
                s[(j, i)] = v;
            }
        }
        s
    };
    // A NaN or infinity in H, R, M or P always reaches S (IEEE: NaN * 0 = NaN,
    // inf * 0 = NaN), so one check of S guards them all; the cold path names the
    // culprit.
    if !all_finite(s.as_slice()) {
        check_finite(jacobian.as_slice(), "measurement jacobian")?;
        check_finite(measurement_noise.as_slice(), "measurement noise covariance")?;
        check_finite(cross_covariance.as_slice(), "cross-covariance")?;
        check_finite(p.as_slice(), "prior covariance")?;
        return Err(Error::NonFinite {
            what: "innovation covariance (overflow)",
        });
    }
    check_finite(innovation.as_slice(), "innovation")?;
    let (inverse, log_det) = spd_inverse_log_det(&s).ok_or(Error::InnovationNotPositiveDefinite)?;
    check_innovation_conditioning(&s, &inverse)?;
    let nis = innovation.dot(&mul_static(&inverse, innovation));
    if !nis.is_finite() {
        return Err(Error::NonFinite {
            what: "normalised innovation squared",
        });
    }
    Ok(FactoredInnovation {
        covariance: s,
        inverse,
        pht,
        nis,
        log_det,
        correlated,
        measurement_noise,
        jacobian,
    })
}

/// The Gaussian log density ln N(nu; 0, S) = -(M ln(2 pi) + ln det S + nu' S^-1 nu) / 2
/// of an innovation nu of size `M`, from ln det S and the NIS nu' S^-1 nu (the
/// prediction-error decomposition's term: Harvey, *Forecasting, Structural Time Series
/// Models and the Kalman Filter*, 1989, sec. 3.4, eq. 3.4.7).
#[inline(always)]
pub(crate) fn innovation_log_likelihood<T: Scalar, const M: usize>(log_det: T, nis: T) -> T {
    let size = lit::<T>(M as f64);
    -(size * T::two_pi().ln() + log_det + nis) * lit::<T>(0.5)
}

/// Gain, posterior mean and covariance from a factored S.
#[inline(always)]
pub(crate) fn finish_update<T: Scalar, const N: usize, const M: usize>(
    prior: &StateAndCovariance<T, N>,
    innovation: &SVector<T, M>,
    cross_covariance: &SMatrix<T, N, M>,
    form: CovarianceUpdate,
    factored: FactoredInnovation<'_, T, N, M>,
) -> Result<UpdateOutcome<T, N, M>> {
    let mut covariance = SMatrix::zeros();
    let mut gain = SMatrix::zeros();
    let finished = finish_update_into(
        prior,
        innovation,
        cross_covariance,
        form,
        &factored,
        &mut gain,
        &mut covariance,
    )?;
    Ok(UpdateOutcome {
        posterior: StateAndCovariance::new_unchecked(finished.state, covariance),
        innovation: *innovation,
        innovation_covariance: factored.covariance,
        gain,
        nis: factored.nis,
        covariance_form: finished.covariance_form,
    })
}

/// What [`finish_update_into`] returns besides the gain and the posterior covariance.
pub(crate) struct Finished<T: Scalar, const N: usize> {
    /// Posterior mean.
    pub(crate) state: SVector<T, N>,
    /// As [`UpdateOutcome::covariance_form`].
    pub(crate) covariance_form: CovarianceUpdate,
}

/// [`finish_update`] with the posterior covariance written into `covariance` (a
/// buffer of the caller's: the runners keep one, so that P+ is written once and
/// committed by a swap instead of moving through every return value; at N = 15 the
/// copies were a fifth of a predict + update). `covariance` is unspecified after an
/// error.
#[inline(always)]
pub(crate) fn finish_update_into<T: Scalar, const N: usize, const M: usize>(
    prior: &StateAndCovariance<T, N>,
    innovation: &SVector<T, M>,
    cross_covariance: &SMatrix<T, N, M>,
    form: CovarianceUpdate,
    factored: &FactoredInnovation<'_, T, N, M>,
    gain: &mut SMatrix<T, N, M>,
    covariance: &mut SMatrix<T, N, N>,
) -> Result<Finished<T, N>> {
    let p = prior.covariance();
    // K = (P H' + M) S^-1 (Simon 2006, eq. 7.13).
    let with_cross;
    let pht_m = if factored.correlated {
        with_cross = factored.pht + cross_covariance;
        &with_cross
    } else {
        &factored.pht
    };
    *gain = mul_static(pht_m, &factored.inverse);
    let gain = &*gain;
    let state = prior.state() + mul_static(gain, innovation);
    let mut covariance_form = form;
    match form {
        CovarianceUpdate::JosephLike => {
            joseph_into(p, pht_m, &factored.covariance, gain, covariance)
        }
        CovarianceUpdate::Short => *covariance = symmetrize(&(p - gain * pht_m.transpose())),
        CovarianceUpdate::Product => {
            *covariance = product_form(
                p,
                &identity_minus_kh(gain, factored.jacobian),
                cross_covariance,
                factored.measurement_noise,
                gain,
            )
        }
        CovarianceUpdate::SquareRoot => {
            if !square_root_into(p, factored, cross_covariance, gain, covariance) {
                covariance_form = CovarianceUpdate::JosephLike;
                joseph_into(p, pht_m, &factored.covariance, gain, covariance);
            }
        }
    }
    check_finite(state.as_slice(), "posterior state")?;
    check_finite(covariance.as_slice(), "posterior covariance")?;
    Ok(Finished {
        state,
        covariance_form,
    })
}

/// The correlated-noise Kalman update of `prior` with innovation `innovation` = y - h(x).
///
/// For an error-state filter the prior mean is the error estimate (usually zero).
///
/// # Errors
/// [`Error::NonFinite`] for NaN/inf inputs (or a non-finite result),
/// [`Error::InnovationNotPositiveDefinite`] when S cannot be factorised,
/// [`Error::InnovationIllConditioned`] when S is numerically singular: the reciprocal
/// 1-norm condition number of its correlation matrix is below 1000 machine epsilons
/// (scale invariant: the units of each component do not matter).
pub fn correlated_update<T: Scalar, const N: usize, const M: usize>(
    prior: &StateAndCovariance<T, N>,
    innovation: &SVector<T, M>,
    jacobian: &SMatrix<T, M, N>,
    measurement_noise: &SMatrix<T, M, M>,
    cross_covariance: &SMatrix<T, N, M>,
    form: CovarianceUpdate,
) -> Result<UpdateOutcome<T, N, M>> {
    let factored = factor_innovation(
        prior,
        innovation,
        jacobian,
        measurement_noise,
        cross_covariance,
    )?;
    finish_update(prior, innovation, cross_covariance, form, factored)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::spd_inverse;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The square-root form as first written (general joint elimination, full
    /// products, dot-product Gram): the reference the faster evaluation must equal.
    fn square_root_reference<const N: usize, const M: usize>(
        covariance: &SMatrix<f64, N, N>,
        factored: &FactoredInnovation<'_, f64, N, M>,
        cross_covariance: &SMatrix<f64, N, M>,
        gain: &SMatrix<f64, N, M>,
    ) -> Option<SMatrix<f64, N, N>> {
        let l = crate::linalg::joint_factor_general(
            covariance,
            cross_covariance,
            factored.measurement_noise,
        )?;
        let hl = mul_static(factored.jacobian, &l.a) + l.c;
        let b1 = l.a - mul_static(gain, &hl);
        let b2 = mul_static(gain, &l.d);
        let (b1, b2) = (b1.transpose(), b2.transpose());
        let mut out = SMatrix::<f64, N, N>::zeros();
        for j in 0..N {
            for i in 0..=j {
                let mut v = 0.0;
                for k in 0..N {
                    v += b1[(k, i)] * b1[(k, j)];
                }
                for k in 0..M {
                    v += b2[(k, i)] * b2[(k, j)];
                }
                out[(i, j)] = v;
                out[(j, i)] = v;
            }
        }
        Some(out)
    }

    /// nalgebra's LU inverse (partial pivoting) of a static matrix, through a dynamic one.
    fn lu_inverse<const M: usize>(x: &SMatrix<f64, M, M>) -> Option<SMatrix<f64, M, M>> {
        let inverse = nalgebra::DMatrix::from_column_slice(M, M, x.as_slice())
            .lu()
            .try_inverse()?;
        Some(SMatrix::from_column_slice(inverse.as_slice()))
    }

    /// rcond of S's correlation matrix as documented, written independently: C formed
    /// explicitly, inverted by nalgebra's LU with partial pivoting (backward stable;
    /// its closed-form 3 x 3 inverse is not, near singularity), 1-norms as column sums.
    fn reference_rcond<const M: usize>(s: &SMatrix<f64, M, M>) -> Option<f64> {
        let c =
            SMatrix::<f64, M, M>::from_fn(|i, j| s[(i, j)] / (s[(i, i)].sqrt() * s[(j, j)].sqrt()));
        let inverse = lu_inverse(&c)?;
        let norm = |x: &SMatrix<f64, M, M>| {
            (0..M)
                .map(|j| (0..M).map(|i| x[(i, j)].abs()).sum::<f64>())
                .fold(0.0, f64::max)
        };
        Some(1.0 / (norm(&c) * norm(&inverse)))
    }

    /// A random SPD S of size M with correlations up to about `rho_max` and variances
    /// within `decades` decades of `centre` (seeded by the caller's generator).
    fn random_spd<const M: usize>(
        rng: &mut ChaCha8Rng,
        rho_max: f64,
        centre: f64,
        decades: f64,
    ) -> SMatrix<f64, M, M> {
        // Rank one plus a small multiple of I: correlations up to about rho_max.
        let g = SVector::<f64, M>::from_fn(|_, _| rng.random_range(0.2..1.0));
        let c = g * g.transpose() + SMatrix::identity() * (1.0 - rho_max).max(1e-16);
        let sd = SVector::<f64, M>::from_fn(|_, _| {
            (centre * 10f64.powf(rng.random_range(-decades..decades))).sqrt()
        });
        let c = SMatrix::<f64, M, M>::from_fn(|i, j| c[(i, j)] / (c[(i, i)] * c[(j, j)]).sqrt());
        SMatrix::<f64, M, M>::from_fn(|i, j| c[(i, j)] * sd[i] * sd[j])
    }

    /// S^-1 for one, two (closed forms) and three measurements (the factor) equals
    /// nalgebra's LU inverse to round-off scaled by the condition number, at every
    /// scale including those where the closed form hands over to the factor
    /// (determinants beyond the normal range); seeded (four other seed blocks checked).
    #[test]
    fn spd_inverse_equals_an_lu_inverse_at_every_size_and_scale() {
        fn check<const M: usize>(rng: &mut ChaCha8Rng) -> usize {
            let mut compared = 0;
            for case in 0..400 {
                let centre = [1.0, 1e-160, 1e160, 1e-300, 1e300, 1e-30][case % 6];
                let s = random_spd::<M>(rng, 0.999, centre, 2.0);
                let (Some(ours), Some(lu)) = (spd_inverse(&s), lu_inverse(&s)) else {
                    continue;
                };
                if !lu.iter().all(|v| v.is_finite()) {
                    continue;
                }
                let Some(rcond) = reference_rcond(&s) else {
                    continue;
                };
                assert_eq!(ours, ours.transpose(), "M {M} case {case}");
                // Compare in the correlation scale, where entries are O(1 / rcond).
                let d = s.diagonal().map(f64::sqrt);
                let worst = (0..M)
                    .flat_map(|i| (0..M).map(move |j| (i, j)))
                    .map(|(i, j)| ((ours[(i, j)] - lu[(i, j)]) * d[i] * d[j]).abs())
                    .fold(0.0, f64::max);
                assert!(
                    worst <= 64.0 * f64::EPSILON / (rcond * rcond),
                    "M {M} case {case}: {worst:e} (rcond {rcond:e})"
                );
                compared += 1;
            }
            compared
        }
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        assert!(check::<1>(&mut rng) > 300);
        assert!(check::<2>(&mut rng) > 300);
        assert!(check::<3>(&mut rng) > 300);
    }

    /// ln det S from the inverse's own factorization (closed forms for one and two
    /// measurements, Cholesky pivots for three and four) equals an independent
    /// reference, sum ln s_ii + ln det C with C the correlation matrix and det C from
    /// nalgebra's LU, at every scale (where det S itself overflows or underflows).
    /// Bound: ln det C carries the relative round-off of det C, of order eps / rcond;
    /// each ln s_ii an absolute eps |ln s_ii|. Seeded.
    #[test]
    fn spd_log_det_equals_an_lu_reference_at_every_size_and_scale() {
        fn check<const M: usize>(rng: &mut ChaCha8Rng) -> usize {
            let mut compared = 0;
            for case in 0..400 {
                let centre = [1.0, 1e-160, 1e160, 1e-300, 1e300, 1e-30][case % 6];
                let s = random_spd::<M>(rng, 0.999, centre, 2.0);
                let (Some((inverse, ours)), Some(rcond)) =
                    (spd_inverse_log_det(&s), reference_rcond(&s))
                else {
                    continue;
                };
                assert_eq!(Some(inverse), spd_inverse(&s), "M {M} case {case}");
                let c = nalgebra::DMatrix::from_fn(M, M, |i, j| {
                    s[(i, j)] / (s[(i, i)].sqrt() * s[(j, j)].sqrt())
                });
                let logs = (0..M).map(|i| s[(i, i)].ln());
                let scale: f64 = logs.clone().map(f64::abs).sum();
                let reference = logs.sum::<f64>() + c.lu().determinant().ln();
                let bound = 64.0 * f64::EPSILON / rcond + 8.0 * f64::EPSILON * scale;
                assert!(
                    (ours - reference).abs() <= bound,
                    "M {M} case {case}: {ours} vs {reference} (bound {bound:e})"
                );
                compared += 1;
            }
            compared
        }
        let mut rng = ChaCha8Rng::seed_from_u64(31);
        assert!(check::<1>(&mut rng) > 300);
        assert!(check::<2>(&mut rng) > 300);
        assert!(check::<3>(&mut rng) > 300);
        assert!(check::<4>(&mut rng) > 300);
    }

    /// The conditioning test of one and two measurements (closed forms: rcond = 1,
    /// and b^2 >= k a d for two) decides as the documented 1-norm rcond of the
    /// correlation matrix, written independently, except within 1 % of the floor, and
    /// reports that rcond when it refuses. Why 1 %: an rcond r is itself computed with
    /// relative round-off of order eps / r, 4.5e-4 at the floor (1000 eps), for either
    /// side. Correlations up to 1 - 1e-15 so that both outcomes occur; seeded (four
    /// other seed blocks checked).
    #[test]
    fn conditioning_closed_forms_decide_as_the_one_norm_rcond() {
        fn check<const M: usize>(rng: &mut ChaCha8Rng) -> (usize, usize) {
            let floor = f64::EPSILON * RCOND_FLOOR;
            let (mut passed, mut refused) = (0, 0);
            for case in 0..2000 {
                let rho_max = 1.0 - 10f64.powf(-rng.random_range(0.0..15.5));
                let centre = [1.0, 1e-150, 1e150][case % 3];
                let s = random_spd::<M>(rng, rho_max, centre, 3.0);
                let Some(inverse) = spd_inverse(&s) else {
                    continue;
                };
                let Some(rcond) = reference_rcond(&s) else {
                    continue;
                };
                if (rcond / floor - 1.0).abs() < 1e-2 {
                    continue;
                }
                match check_innovation_conditioning(&s, &inverse) {
                    Ok(()) => {
                        assert!(rcond > floor, "M {M} case {case}: rcond {rcond:e}");
                        passed += 1;
                    }
                    Err(Error::InnovationIllConditioned {
                        reciprocal_condition,
                    }) => {
                        assert!(rcond <= floor, "M {M} case {case}: rcond {rcond:e}");
                        // Relative round-off of order eps / rcond on either side.
                        assert!(
                            (reciprocal_condition - rcond).abs()
                                <= 1e-3 * rcond + 16.0 * f64::EPSILON,
                            "M {M} case {case}: {reciprocal_condition:e} vs {rcond:e}"
                        );
                        refused += 1;
                    }
                    Err(e) => panic!("M {M} case {case}: {e}"),
                }
            }
            (passed, refused)
        }
        let mut rng = ChaCha8Rng::seed_from_u64(22);
        let (passed, _) = check::<1>(&mut rng);
        assert!(passed > 1500, "{passed}");
        let (passed, refused) = check::<2>(&mut rng);
        assert!(passed > 300 && refused > 100, "{passed} / {refused}");
        let (passed, refused) = check::<3>(&mut rng);
        assert!(passed > 300 && refused > 100, "{passed} / {refused}");
    }

    /// The square-root posterior (triangular products, M = 0 shortcut, axpy-order
    /// Gram) equals the reference bit for bit (== : only the sign of exact zeros is
    /// free), with M = 0 and M != 0, including singular priors, at (6, 2); seeded.
    #[test]
    fn square_root_form_equals_the_reference_exactly() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut compared = 0;
        for case in 0..300 {
            let rank = 1 + case % 6;
            let g = crate::test_support::rank_deficient_factor::<6>(&mut rng, rank);
            let p = g * g.transpose();
            let h = SMatrix::<f64, 2, 6>::from_fn(|_, _| rng.random_range(-1.0..1.0));
            let r = SMatrix::<f64, 2, 2>::new(0.3, 0.05, 0.05, 0.2);
            let m = if case % 2 == 0 {
                SMatrix::<f64, 6, 2>::zeros()
            } else {
                // Small enough that the joint stays valid for most priors.
                g.fixed_view::<6, 2>(0, 0) * 0.01 * rng.random_range(0.0..1.0)
            };
            let prior = StateAndCovariance::new_unchecked(SVector::zeros(), p);
            let y = SVector::<f64, 2>::new(0.1, -0.2);
            let Ok(factored) = factor_innovation(&prior, &y, &h, &r, &m) else {
                continue;
            };
            let gain = mul_static(&(factored.pht + m), &factored.inverse);
            let fast = square_root_form(&p, &factored, &m, &gain);
            let reference = square_root_reference(&p, &factored, &m, &gain);
            assert_eq!(fast, reference, "case {case}");
            compared += usize::from(fast.is_some());
        }
        assert!(compared > 200, "{compared}");
    }

    /// At (15, 3) the products run through the fused AVX-512 product where the CPU has
    /// it (`crate::linalg::fused_product`): the posterior then equals the reference to round-off
    /// (each entry within 64 eps of the largest prior variance; a fused multiply-add
    /// differs from a separate one by at most half an ulp of each term) and stays
    /// exactly symmetric; without it the posterior is the reference bit for bit.
    #[test]
    fn square_root_form_equals_the_reference_to_round_off_at_fused_product_sizes() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let mut compared = 0;
        for case in 0..100 {
            let rank = 1 + case % 15;
            let g = crate::test_support::rank_deficient_factor::<15>(&mut rng, rank);
            let p = g * g.transpose();
            let h = SMatrix::<f64, 3, 15>::from_fn(|_, _| rng.random_range(-1.0..1.0));
            let r = SMatrix::<f64, 3, 3>::new(0.3, 0.05, 0.0, 0.05, 0.2, 0.01, 0.0, 0.01, 0.1);
            let m = if case % 2 == 0 {
                SMatrix::<f64, 15, 3>::zeros()
            } else {
                g.fixed_view::<15, 3>(0, 0) * 0.01 * rng.random_range(0.0..1.0)
            };
            let prior = StateAndCovariance::new_unchecked(SVector::zeros(), p);
            let y = SVector::<f64, 3>::new(0.1, -0.2, 0.3);
            let Ok(factored) = factor_innovation(&prior, &y, &h, &r, &m) else {
                continue;
            };
            let gain = mul_static(&(factored.pht + m), &factored.inverse);
            let (Some(fast), Some(reference)) = (
                square_root_form(&p, &factored, &m, &gain),
                square_root_reference(&p, &factored, &m, &gain),
            ) else {
                continue;
            };
            let scale = p.diagonal().amax();
            let worst = (fast - reference).amax();
            assert!(
                worst <= 64.0 * f64::EPSILON * scale,
                "case {case}: {worst:e} (scale {scale:e})"
            );
            assert_eq!(fast, fast.transpose(), "case {case}");
            if !crate::linalg::fused_product::available() {
                assert_eq!(fast, reference, "case {case}");
            }
            compared += 1;
        }
        assert!(compared > 60, "{compared}");
    }
}
