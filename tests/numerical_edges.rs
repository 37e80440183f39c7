//! Numerical edges of the correlated update (estim-core): scales from 1e-9 to 1e9, a
//! nearly singular innovation covariance, and M at the boundary of validity of the
//! joint covariance. Property: a correct answer (against an independently coded
//! reference) or a typed error, never a non-finite value passed on.

use estim_core::nalgebra::{Matrix2, Matrix3, Matrix3x2, Vector2, Vector3};
use estim_core::update::correlated_update;
use estim_core::{CovarianceUpdate, Error, StateAndCovariance};
use proptest::prelude::*;

/// Reference posterior by Gaussian conditioning of the joint of (x, y) written out
/// (Simon 2006, sec. 7.1): Cov(x, y) = P H' + M, Cov(y) = H P H' + H M + M' H' + R.
/// The solve is done in the scaled frame D^-1/2 S D^-1/2, so it does not depend on
/// the code under test's conditioning choices.
fn reference(
    p: &Matrix3<f64>,
    h: &estim_core::nalgebra::Matrix2x3<f64>,
    r: &Matrix2<f64>,
    m: &Matrix3x2<f64>,
    innovation: &Vector2<f64>,
) -> Option<(Vector3<f64>, Matrix3<f64>)> {
    let cxy = p * h.transpose() + m;
    let syy = h * p * h.transpose() + h * m + m.transpose() * h.transpose() + r;
    let d = Vector2::new(syy[(0, 0)].sqrt(), syy[(1, 1)].sqrt());
    let scaled = Matrix2::from_fn(|i, j| syy[(i, j)] / (d[i] * d[j]));
    let inv_scaled = scaled.try_inverse()?;
    let inv = Matrix2::from_fn(|i, j| inv_scaled[(i, j)] / (d[i] * d[j]));
    let gain = cxy * inv;
    Some((gain * innovation, p - gain * cxy.transpose()))
}

fn rel_diff_matrix(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    (a - b).amax() / b.amax().max(f64::MIN_POSITIVE)
}

prop_compose! {
    /// A random SPD 3x3 from a lower-triangular factor with diagonal in [0.5, 2].
    fn spd()(l in proptest::collection::vec(-1.0f64..1.0, 6),
             d in proptest::collection::vec(0.5f64..2.0, 3)) -> Matrix3<f64> {
        let f = Matrix3::new(d[0], 0.0, 0.0, l[0], d[1], 0.0, l[1], l[2], d[2]);
        f * f.transpose()
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2_000, failure_persistence: None, ..ProptestConfig::default() })]

    /// P, R, M scaled by s and the innovation by sqrt(s), s = 10^k, k in [-9, 9]:
    /// the gain is scale-free, the mean scales by sqrt(s), P+ by s. The update must
    /// match the reference at every scale (relative 1e-9) or return a typed error.
    #[test]
    fn update_is_correct_across_scales(p0 in spd(),
                                       h in proptest::collection::vec(-1.0f64..1.0, 6),
                                       r_diag in proptest::collection::vec(0.1f64..1.0, 2),
                                       rho in -0.9f64..0.9,
                                       y in proptest::collection::vec(-1.0f64..1.0, 2),
                                       k in -9i32..=9) {
        let s = 10f64.powi(k);
        let h = estim_core::nalgebra::Matrix2x3::from_row_slice(&h);
        let r0 = Matrix2::from_diagonal(&Vector2::from_row_slice(&r_diag));
        // A valid M: rho times the part of the joint covariance Cauchy-Schwarz allows
        // on the first state only, |M_i1| <= sqrt(P_11 R_11).
        let mut m0 = Matrix3x2::zeros();
        m0[(0, 0)] = rho * (p0[(0, 0)] * r0[(0, 0)]).sqrt() * 0.5;
        let prior = StateAndCovariance::new(Vector3::zeros(), p0 * s).unwrap();
        let innovation = Vector2::from_row_slice(&y) * s.sqrt();
        for form in [CovarianceUpdate::JosephLike, CovarianceUpdate::Short] {
            match correlated_update(&prior, &innovation, &h, &(r0 * s), &(m0 * s), form) {
                Ok(out) => {
                    let (mean, cov) = out.posterior.into_parts();
                    prop_assert!(mean.iter().chain(cov.iter()).all(|x| x.is_finite()));
                    let (rm, rp) = reference(&(p0 * s), &h, &(r0 * s), &(m0 * s), &innovation)
                        .expect("reference invertible when the update succeeded");
                    let scale_mean = rm.amax().max(s.sqrt() * 1e-6);
                    prop_assert!((mean - rm).amax() / scale_mean < 1e-9,
                        "mean {mean} vs {rm} at s = {s}");
                    prop_assert!(rel_diff_matrix(&cov, &rp) < 1e-9, "P+ at s = {s}");
                }
                Err(e) => prop_assert!(matches!(e,
                    Error::InnovationIllConditioned { .. } | Error::InnovationNotPositiveDefinite),
                    "unexpected error {e}"),
            }
        }
    }

    /// Nearly singular S: R -> 0 and H with nearly dependent rows. A correct answer
    /// or a typed error; never a non-finite posterior.
    #[test]
    fn nearly_singular_innovation_covariance(p0 in spd(), eps_exp in -18i32..-2,
                                             r_exp in -20i32..-2,
                                             y in proptest::collection::vec(-1.0f64..1.0, 2)) {
        let eps = 10f64.powi(eps_exp);
        let h = estim_core::nalgebra::Matrix2x3::new(1.0, 0.5, 0.0, 1.0, 0.5 + eps, 0.0);
        let r = Matrix2::identity() * 10f64.powi(r_exp);
        let prior = StateAndCovariance::new(Vector3::zeros(), p0).unwrap();
        let innovation = Vector2::from_row_slice(&y);
        match correlated_update(&prior, &innovation, &h, &r, &Matrix3x2::zeros(),
                                CovarianceUpdate::JosephLike) {
            Ok(out) => {
                let (mean, cov) = out.posterior.into_parts();
                prop_assert!(mean.iter().chain(cov.iter()).all(|x| x.is_finite()));
                prop_assert!(out.nis.is_finite());
            }
            Err(e) => prop_assert!(matches!(e,
                Error::InnovationIllConditioned { .. } | Error::InnovationNotPositiveDefinite
                | Error::NonFinite { .. }), "unexpected error {e}"),
        }
    }
}

/// M at the boundary of validity: the joint covariance [[P, M], [M', R]] exactly
/// singular (state 1 and the measurement noise perfectly correlated, |M_1| =
/// sqrt(P_11 R)). The posterior must match the hand-computed one, stay finite and
/// positive semidefinite to round-off.
#[test]
fn m_at_the_validity_boundary() {
    let p = Matrix3::from_diagonal(&Vector3::new(4.0, 1.0, 9.0));
    // Measurement of state 2 (H = [0 1 0]) with noise perfectly correlated with
    // state 1: |M_1| = sqrt(P_11 R) = 1.
    let h = estim_core::nalgebra::Matrix1x3::new(0.0, 1.0, 0.0);
    let r = estim_core::nalgebra::Matrix1::new(0.25);
    for sign in [1.0, -1.0] {
        let mut m = estim_core::nalgebra::Matrix3x1::zeros();
        m[0] = sign * (4.0f64 * 0.25).sqrt();
        let prior = StateAndCovariance::new(Vector3::zeros(), p).unwrap();
        let out = correlated_update(
            &prior,
            &estim_core::nalgebra::Vector1::new(0.3),
            &h,
            &r,
            &m,
            CovarianceUpdate::JosephLike,
        )
        .unwrap();
        let (_, cov) = out.posterior.into_parts();
        // Independent: S = P22 + R = 1.25, K = [M1, P22, 0]/S, P+ = P - K (H P + M')
        let s = 1.25;
        let k = Vector3::new(m[0], 1.0, 0.0) / s;
        let expected = p - k * Vector3::new(m[0], 1.0, 0.0).transpose();
        assert!((cov - expected).amax() < 1e-12, "{cov} vs {expected}");
        let min_eig = cov.symmetric_eigenvalues().min();
        assert!(min_eig > -1e-12, "{min_eig}");
        assert!(cov.iter().all(|x| x.is_finite()));
    }
}
