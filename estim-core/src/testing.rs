//! Independent references for users' own property tests (feature `testing`).
//!
//! Each reference is coded with dynamic matrices and LU inverses, independently of
//! the runners' static-size Cholesky code, from the definitions in DESIGN.md:
//!
//! - [`textbook_step`]: M = 0, the textbook Kalman filter (Simon 2006, sec. 5.1).
//! - [`stacked_reference`]: joint-Gaussian conditioning of the stacked
//!   \[x_{k-1}; w_{k-1}; v_k\] pushed through x_k = F x + G w, y_k = H x_k + v.
//! - [`decorrelated_reference`]: Simon 2006, sec. 7.1: the process noise split into
//!   the part correlated with the measurement noise and the rest, then an
//!   uncorrelated filter.
//!
//! With Cov(w, v) = C the runners' M is G C (state space). A proptest compares a
//! runner's posterior with one of these (enable the feature in dev-dependencies:
//! `estim-core = { version = "...", features = ["testing"] }`):
//!
//! ```
//! use estim_core::nalgebra::{DMatrix, DVector, Matrix1, Matrix1x2, Matrix2, Matrix2x1, Vector1, Vector2};
//! use estim_core::testing::{stacked_reference, LinearStep};
//! use estim_core::{Fixed, KalmanFilter, StateAndCovariance};
//!
//! let (f, g) = (Matrix2::new(1.0, 0.1, 0.0, 1.0), Matrix2x1::new(0.005, 0.1));
//! let (h, r) = (Matrix1x2::new(1.0, 0.0), Matrix1::new(0.04));
//! let (qw, c) = (Matrix1::new(2.0), Matrix1::new(0.1)); // Cov(w), Cov(w, v)
//! let prior = StateAndCovariance::new(Vector2::new(0.0, 1.0), Matrix2::identity())?;
//! let mut kf = KalmanFilter::new(f, g * qw * g.transpose(), h, r, prior.clone())?;
//! kf.predict()?;
//! let y = Vector1::new(0.3);
//! kf.update(&y, &Fixed(g * c))?;
//!
//! let d = |m: &[f64], r, c| DMatrix::from_row_slice(r, c, m);
//! let (x, p) = stacked_reference(&LinearStep {
//!     x0: DVector::from_column_slice(prior.state().as_slice()),
//!     p0: DMatrix::identity(2, 2),
//!     f: d(&[1.0, 0.1, 0.0, 1.0], 2, 2),
//!     g: d(&[0.005, 0.1], 2, 1),
//!     qw: d(&[2.0], 1, 1),
//!     cross: d(&[0.1], 1, 1),
//!     h: d(&[1.0, 0.0], 1, 2),
//!     r: d(&[0.04], 1, 1),
//!     y: DVector::from_column_slice(&[0.3]),
//! })?;
//! assert!((DVector::from_column_slice(kf.estimate().state().as_slice()) - x).amax() < 1e-12);
//! assert!((DMatrix::from_column_slice(2, 2, kf.estimate().covariance().as_slice()) - p).amax() < 1e-12);
//! # Ok::<(), estim_core::Error>(())
//! ```

use nalgebra::{DMatrix, DVector, SMatrix};

use crate::scalar::to_f64;
use crate::{Error, ProcessModel, Result, Scalar};

/// Check that a [`ProcessModel`]'s speed hooks equal their defaults at one point
/// (state, input, dt, covariance), each entry within `tolerance` relative to the
/// largest entry of the default's result:
///
/// - `transition_and_noise` against `transition` and `process_noise` called apart;
/// - `propagate_covariance(P, Phi, Q_d)` against Phi P Phi' + Q_d (nalgebra's
///   products);
/// - `compose_transitions(Phi_2, Phi)` against Phi_2 Phi, with Phi_2 the transition
///   at the propagated state.
///
/// A tolerance of 0 asks for the same bits; a sparse override that skips exact zeros
/// usually meets it, one that reorders sums needs a few eps.
///
/// ```
/// use estim_core::nalgebra::{Matrix2, SMatrix, Vector2};
/// use estim_core::testing::check_speed_hooks;
/// use estim_core::{ProcessModel, Result};
///
/// /// Constant velocity, with Phi P Phi' written out for Phi = [[1, dt], [0, 1]].
/// struct ConstantVelocity;
/// impl ProcessModel<f64, 2> for ConstantVelocity {
///     type State = Vector2<f64>;
///     type Input = ();
///     fn propagate(&self, x: &Vector2<f64>, _: &(), dt: f64) -> Result<Vector2<f64>> {
///         Ok(Vector2::new(x[0] + dt * x[1], x[1]))
///     }
///     fn transition(&self, _: &Vector2<f64>, _: &(), dt: f64) -> Result<Matrix2<f64>> {
///         Ok(Matrix2::new(1.0, dt, 0.0, 1.0))
///     }
///     fn process_noise(&self, _: &Vector2<f64>, _: &(), dt: f64) -> Result<Matrix2<f64>> {
///         Ok(Matrix2::new(dt * dt * dt / 3.0, dt * dt / 2.0, dt * dt / 2.0, dt) * 0.01)
///     }
///     fn propagate_covariance(&self, p: &Matrix2<f64>, phi: &Matrix2<f64>, q: &Matrix2<f64>) -> Matrix2<f64> {
///         let dt = phi[(0, 1)];
///         let p01 = p[(0, 1)] + dt * p[(1, 1)];
///         let p00 = p[(0, 0)] + dt * p[(1, 0)] + dt * p01;
///         Matrix2::new(p00, p01, p01, p[(1, 1)]) + q
///     }
/// }
///
/// let p = Matrix2::new(2.0, 0.3, 0.3, 1.0);
/// check_speed_hooks(&ConstantVelocity, &Vector2::new(0.0, 1.0), &(), 0.1, &p, 1e-14)?;
/// # Ok::<(), estim_core::Error>(())
/// ```
///
/// # Errors
/// [`Error::SpeedHookMismatch`] naming the first hook that differs; the model's own
/// errors.
pub fn check_speed_hooks<T, P, const N: usize>(
    model: &P,
    state: &P::State,
    input: &P::Input,
    dt: T,
    covariance: &SMatrix<T, N, N>,
    tolerance: T,
) -> Result<()>
where
    T: Scalar,
    P: ProcessModel<T, N>,
{
    let compare =
        |hook: &'static str, got: &SMatrix<T, N, N>, want: &SMatrix<T, N, N>| -> Result<()> {
            let scale = want.amax();
            let difference = (got - want).amax();
            let relative = if scale > T::zero() {
                difference / scale
            } else {
                difference
            };
            // NaN differences fail too.
            if relative <= tolerance {
                Ok(())
            } else {
                Err(Error::SpeedHookMismatch {
                    hook,
                    difference: to_f64(relative),
                    tolerance: to_f64(tolerance),
                })
            }
        };
    let transition = model.transition(state, input, dt)?;
    let noise = model.process_noise(state, input, dt)?;
    let (joint_transition, joint_noise) = model.transition_and_noise(state, input, dt)?;
    compare("transition_and_noise", &joint_transition, &transition)?;
    compare("transition_and_noise", &joint_noise, &noise)?;
    let propagated = model.propagate_covariance(covariance, &transition, &noise);
    let want = transition * covariance * transition.transpose() + noise;
    compare("propagate_covariance", &propagated, &want)?;
    let next = model.propagate(state, input, dt)?;
    let later = model.transition(&next, input, dt)?;
    let composed = model.compose_transitions(&later, &transition);
    compare("compose_transitions", &composed, &(later * transition))
}

/// One linear predict + update with correlated noise, in dynamic sizes (n states,
/// p process-noise inputs, m measurements).
#[derive(Debug, Clone, PartialEq)]
pub struct LinearStep {
    /// Prior mean x_{k-1} (n).
    pub x0: DVector<f64>,
    /// Prior covariance P_{k-1} (n x n).
    pub p0: DMatrix<f64>,
    /// Transition F (n x n).
    pub f: DMatrix<f64>,
    /// Noise input G (n x p).
    pub g: DMatrix<f64>,
    /// Cov(w) (p x p).
    pub qw: DMatrix<f64>,
    /// Cov(w_{k-1}, v_k) (p x m); the runners' M is G times this.
    pub cross: DMatrix<f64>,
    /// Measurement matrix H (m x n).
    pub h: DMatrix<f64>,
    /// Measurement noise covariance R (m x m).
    pub r: DMatrix<f64>,
    /// The measurement y_k (m).
    pub y: DVector<f64>,
}

impl LinearStep {
    fn sizes(&self) -> Result<(usize, usize, usize)> {
        let n = self.x0.len();
        let p = self.g.ncols();
        let m = self.y.len();
        type Check = (&'static str, (usize, usize), (usize, usize));
        let checks: [Check; 7] = [
            ("P0", self.p0.shape(), (n, n)),
            ("F", self.f.shape(), (n, n)),
            ("G", self.g.shape(), (n, p)),
            ("Cov(w)", self.qw.shape(), (p, p)),
            ("Cov(w, v)", self.cross.shape(), (p, m)),
            ("H", self.h.shape(), (m, n)),
            ("R", self.r.shape(), (m, m)),
        ];
        for (what, got, expected) in checks {
            if got != expected {
                return Err(Error::Dimension {
                    what,
                    expected: expected.0 * expected.1,
                    got: got.0 * got.1,
                });
            }
        }
        Ok((n, p, m))
    }
}

fn inverse(m: DMatrix<f64>, what: &'static str) -> Result<DMatrix<f64>> {
    m.lu().try_inverse().ok_or(Error::InvalidCovariance {
        what,
        reason: "singular (LU inverse failed)".into(),
    })
}

/// Posterior (x_k, P_k) of the textbook Kalman filter, M = 0 (the step's `cross` is
/// ignored): x = F x0, P = F P0 F' + G Qw G', then K = P H' (H P H' + R)^-1.
///
/// # Errors
/// [`Error::Dimension`] for inconsistent sizes, [`Error::InvalidCovariance`] for a
/// singular innovation covariance.
pub fn textbook_step(step: &LinearStep) -> Result<(DVector<f64>, DMatrix<f64>)> {
    let (n, _, _) = step.sizes()?;
    let x = &step.f * &step.x0;
    let p = &step.f * &step.p0 * step.f.transpose() + &step.g * &step.qw * step.g.transpose();
    let s = &step.h * &p * step.h.transpose() + &step.r;
    let k = &p * step.h.transpose() * inverse(s, "innovation covariance")?;
    let x = &x + &k * (&step.y - &step.h * &x);
    let p = (DMatrix::identity(n, n) - &k * &step.h) * p;
    Ok((x, p))
}

/// Posterior (x_k, P_k) by joint-Gaussian conditioning of the stacked
/// z = \[x_{k-1}; w_{k-1}; v_k\] ~ N(\[x0; 0; 0\], \[\[P0, 0, 0\], \[0, Qw, C\], \[0, C', R\]\])
/// pushed through x_k = F x + G w, y_k = H x_k + v.
///
/// # Errors
/// As [`textbook_step`].
pub fn stacked_reference(step: &LinearStep) -> Result<(DVector<f64>, DMatrix<f64>)> {
    let (n, p, m) = step.sizes()?;
    let dim = n + p + m;
    let mut sigma = DMatrix::zeros(dim, dim);
    sigma.view_mut((0, 0), (n, n)).copy_from(&step.p0);
    sigma.view_mut((n, n), (p, p)).copy_from(&step.qw);
    sigma.view_mut((n, n + p), (p, m)).copy_from(&step.cross);
    sigma
        .view_mut((n + p, n), (m, p))
        .copy_from(&step.cross.transpose());
    sigma.view_mut((n + p, n + p), (m, m)).copy_from(&step.r);
    let mut mean = DVector::zeros(dim);
    mean.rows_mut(0, n).copy_from(&step.x0);
    let mut t = DMatrix::zeros(n + m, dim);
    t.view_mut((0, 0), (n, n)).copy_from(&step.f);
    t.view_mut((0, n), (n, p)).copy_from(&step.g);
    t.view_mut((n, 0), (m, n)).copy_from(&(&step.h * &step.f));
    t.view_mut((n, n), (m, p)).copy_from(&(&step.h * &step.g));
    t.view_mut((n, n + p), (m, m))
        .copy_from(&DMatrix::identity(m, m));
    let mu = &t * mean;
    let c = &t * sigma * t.transpose();
    let cxx = c.view((0, 0), (n, n)).clone_owned();
    let cxy = c.view((0, n), (n, m)).clone_owned();
    let cyy = c.view((n, n), (m, m)).clone_owned();
    let k = &cxy * inverse(cyy, "innovation covariance")?;
    let x = mu.rows(0, n) + &k * (&step.y - mu.rows(n, m));
    let p = cxx - &k * cxy.transpose();
    Ok((x, p))
}

/// Posterior (x_k, P_k) by decorrelation (Simon 2006, sec. 7.1): y_k = (H F) x_{k-1} +
/// nu with nu = H G w + v; G w = D nu + w~, D = Cov(G w, nu) Cov(nu)^-1, so that
/// x_k = (F - D H F) x_{k-1} + D y_k + w~ with w~ uncorrelated with nu: an
/// uncorrelated update of x_{k-1}, then the decorrelated prediction.
///
/// # Errors
/// As [`textbook_step`].
pub fn decorrelated_reference(step: &LinearStep) -> Result<(DVector<f64>, DMatrix<f64>)> {
    let (n, _, _) = step.sizes()?;
    let (f, h) = (&step.f, &step.h);
    let qd = &step.g * &step.qw * step.g.transpose();
    let mx = &step.g * &step.cross;
    let r_nu = h * &qd * h.transpose() + h * &mx + mx.transpose() * h.transpose() + &step.r;
    let c_wnu = &qd * h.transpose() + &mx;
    let d = &c_wnu * inverse(r_nu.clone(), "Cov(H G w + v)")?;
    let q_tilde = &qd - &d * &r_nu * d.transpose();
    let hs = h * f;
    let s = &hs * &step.p0 * hs.transpose() + &r_nu;
    let k = &step.p0 * hs.transpose() * inverse(s, "innovation covariance")?;
    let xs = &step.x0 + &k * (&step.y - &hs * &step.x0);
    let ps = (DMatrix::identity(n, n) - &k * &hs) * &step.p0;
    let a = f - &d * &hs;
    let x = &a * xs + &d * &step.y;
    let p = &a * ps * a.transpose() + q_tilde;
    Ok((x, p))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn d(m: &[f64], r: usize, c: usize) -> DMatrix<f64> {
        DMatrix::from_row_slice(r, c, m)
    }

    fn step(cross: f64) -> LinearStep {
        LinearStep {
            x0: DVector::from_column_slice(&[0.5, -1.0]),
            p0: d(&[1.0, 0.2, 0.2, 0.5], 2, 2),
            f: d(&[1.0, 0.1, 0.0, 0.9], 2, 2),
            g: d(&[0.005, 0.0, 0.1, 0.3], 2, 2),
            qw: d(&[2.0, 0.1, 0.1, 1.0], 2, 2),
            cross: d(&[cross, -0.5 * cross], 2, 1),
            h: d(&[1.0, 0.5], 1, 2),
            r: d(&[0.04], 1, 1),
            y: DVector::from_column_slice(&[0.3]),
        }
    }

    #[test]
    fn the_three_references_agree() {
        let uncorrelated = step(0.0);
        let (xt, pt) = textbook_step(&uncorrelated).unwrap();
        let (xs, ps) = stacked_reference(&uncorrelated).unwrap();
        assert!((&xt - &xs).amax() < 1e-12 && (&pt - &ps).amax() < 1e-12);
        let correlated = step(0.1);
        let (xs, ps) = stacked_reference(&correlated).unwrap();
        let (xd, pd) = decorrelated_reference(&correlated).unwrap();
        assert!((&xd - &xs).amax() < 1e-12 && (&pd - &ps).amax() < 1e-12);
        // The correlation matters: the textbook posterior differs.
        let (xt, _) = textbook_step(&correlated).unwrap();
        assert!((&xt - &xs).amax() > 1e-4);
    }

    #[test]
    fn inconsistent_sizes_are_typed_errors() {
        let mut s = step(0.1);
        s.r = d(&[0.04, 0.0, 0.0, 0.04], 2, 2);
        assert!(matches!(
            stacked_reference(&s),
            Err(Error::Dimension { what: "R", .. })
        ));
    }

    /// The speed-hook check passes the defaults and a correct sparse override, and
    /// names each hook an override gets wrong.
    #[test]
    fn speed_hooks_are_checked_against_their_defaults() {
        use crate::ProcessModel;
        use nalgebra::{Matrix2, Vector2};
        #[derive(Clone, Copy)]
        enum Wrong {
            Nothing,
            Joint,
            Propagate,
            Compose,
        }
        struct Cv(Wrong);
        impl ProcessModel<f64, 2> for Cv {
            type State = Vector2<f64>;
            type Input = ();
            fn propagate(&self, x: &Vector2<f64>, _: &(), dt: f64) -> Result<Vector2<f64>> {
                Ok(Vector2::new(x[0] + dt * x[1], x[1]))
            }
            fn transition(&self, _: &Vector2<f64>, _: &(), dt: f64) -> Result<Matrix2<f64>> {
                Ok(Matrix2::new(1.0, dt, 0.0, 1.0))
            }
            fn process_noise(&self, _: &Vector2<f64>, _: &(), dt: f64) -> Result<Matrix2<f64>> {
                Ok(Matrix2::new(0.0, 0.0, 0.0, dt * 0.01))
            }
            fn transition_and_noise(
                &self,
                x: &Vector2<f64>,
                u: &(),
                dt: f64,
            ) -> Result<(Matrix2<f64>, Matrix2<f64>)> {
                let q = self.process_noise(x, u, dt)?;
                let q = match self.0 {
                    Wrong::Joint => q * 2.0,
                    _ => q,
                };
                Ok((self.transition(x, u, dt)?, q))
            }
            fn propagate_covariance(
                &self,
                p: &Matrix2<f64>,
                phi: &Matrix2<f64>,
                q: &Matrix2<f64>,
            ) -> Matrix2<f64> {
                // Phi P Phi' for Phi = [[1, dt], [0, 1]], written out.
                let dt = phi[(0, 1)];
                let p01 = p[(0, 1)] + dt * p[(1, 1)];
                let p00 = p[(0, 0)] + dt * p[(1, 0)] + dt * p01;
                let wrong = if matches!(self.0, Wrong::Propagate) {
                    1e-3
                } else {
                    0.0
                };
                Matrix2::new(p00 + wrong, p01, p01, p[(1, 1)]) + q
            }
            fn compose_transitions(
                &self,
                later: &Matrix2<f64>,
                earlier: &Matrix2<f64>,
            ) -> Matrix2<f64> {
                match self.0 {
                    Wrong::Compose => earlier * later * 1.5,
                    _ => later * earlier,
                }
            }
        }
        let p = Matrix2::new(2.0, 0.3, 0.3, 1.0);
        let x = Vector2::new(0.0, 1.0);
        assert_eq!(
            check_speed_hooks(&Cv(Wrong::Nothing), &x, &(), 0.1, &p, 1e-14),
            Ok(())
        );
        for (wrong, hook) in [
            (Wrong::Joint, "transition_and_noise"),
            (Wrong::Propagate, "propagate_covariance"),
            (Wrong::Compose, "compose_transitions"),
        ] {
            match check_speed_hooks(&Cv(wrong), &x, &(), 0.1, &p, 1e-14) {
                Err(Error::SpeedHookMismatch { hook: got, .. }) => assert_eq!(got, hook),
                other => panic!("{hook}: {other:?}"),
            }
        }
    }
}
