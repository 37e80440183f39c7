//! [`DynUnscentedKalmanFilter`]: the unscented Kalman filter (additive noise, the
//! correlated update, its URTS smoother) for sizes known at run time.

use nalgebra::{DMatrix, DVector};

mod series;

use super::filter::{check_shape, DynUpdateReport};
use super::linalg::{
    block_certificate, check_covariance, check_finite, check_innovation_conditioning, check_size,
    joint_validity_margin, mirror_upper, relative_tolerance, spd_inverse_log_det_into,
    JointScratch,
};
use super::product::{gemm, gemm_upper};
use super::sigma::{
    factor_into, sigma_pass, solve_lower, solve_right_lower, DynSigmaPointMeasurement,
    DynSigmaPointProcess, Pass,
};
use crate::sigma_point::{SigmaPointUpdate, UnscentedTransform, Weights};
use crate::{Error, JointCheck, Result};

/// ln(2 pi).
const LN_2PI: f64 = 1.837_877_066_409_345_5;

/// Buffers of one predict and one update, allocated at construction.
#[derive(Debug, Clone)]
struct Workspace {
    /// n x n: the lower Cholesky factor S of P (S S' = P).
    factor: DMatrix<f64>,
    /// n: one sigma point.
    point: DVector<f64>,
    /// The prediction's pass (dim n) and the update's (dim m).
    process: Pass,
    measurement: Pass,
    /// n x n: the predicted covariance, the posterior, scratch for Q_acc.
    nn: DMatrix<f64>,
    nn_next: DMatrix<f64>,
    /// n x m: P_xy; S^-1 M; the gain K.
    pxy: DMatrix<f64>,
    whitened_cross: DMatrix<f64>,
    gain: DMatrix<f64>,
    /// m x n: K'.
    gain_t: DMatrix<f64>,
    /// n x n: K P_xy'.
    correction: DMatrix<f64>,
    /// m x m: H~ M; P_yy; its inverse; scratch.
    linearised_cross: DMatrix<f64>,
    s: DMatrix<f64>,
    s_inverse: DMatrix<f64>,
    mm: DMatrix<f64>,
    /// m: the innovation, S^-1 nu.
    innovation: DVector<f64>,
    weighted: DVector<f64>,
    /// n: the posterior state.
    state: DVector<f64>,
    joint: JointScratch,
}

impl Workspace {
    fn new(n: usize, m: usize) -> Self {
        Self {
            factor: DMatrix::zeros(n, n),
            point: DVector::zeros(n),
            process: Pass::new(n, n),
            measurement: Pass::new(m, n),
            nn: DMatrix::zeros(n, n),
            nn_next: DMatrix::zeros(n, n),
            pxy: DMatrix::zeros(n, m),
            whitened_cross: DMatrix::zeros(n, m),
            gain: DMatrix::zeros(n, m),
            gain_t: DMatrix::zeros(m, n),
            correction: DMatrix::zeros(n, n),
            linearised_cross: DMatrix::zeros(m, m),
            s: DMatrix::zeros(m, m),
            s_inverse: DMatrix::zeros(m, m),
            mm: DMatrix::zeros(m, m),
            innovation: DVector::zeros(m),
            weighted: DVector::zeros(m),
            state: DVector::zeros(n),
            joint: JointScratch::new(n, m),
        }
    }
}

/// Unscented Kalman filter with sizes known at run time: x_k = f(x_{k-1}) + w,
/// y_k = h(x_k) + v, Cov(w) = Q, Cov(v) = R, and optionally M = Cov(x_k, v_k) (the
/// correlated update). f and h are [`DynSigmaPointProcess`] / [`DynSigmaPointMeasurement`]
/// models (closures, or types with residual and mean hooks for angles) given to each
/// call; no Jacobian anywhere.
///
/// The same filter as the static [`crate::UnscentedKalmanFilter`] with the
/// [`SigmaPointUpdate::Additive`] update, on `DMatrix<f64>` / `DVector<f64>` (tested
/// equal to it to 1e-12, `tests/dynamic_unscented.rs`):
///
/// ```text
/// predict: chi = x, x +/- gamma S_j (S S' = P, semidefinite Cholesky), Y_i = f(chi_i)
///          x- = mean(Y),  P- = sum Wc_i (Y_i - x-)(Y_i - x-)' + Q
/// update:  Z_i = h(chi_i) with chi_i the points of (x-, P-), y_hat = mean(Z)
///          P_yy = sum Wc_i (Z_i - y_hat)(...)' + R + H~ M + M' H~'
///          P_xy = sum Wc_i (chi_i - x-)(Z_i - y_hat)' + M
///          K = P_xy P_yy^-1,  x+ = x- + K (y - y_hat),  P+ = P- - K P_xy'
/// ```
///
/// with the weights of the [`UnscentedTransform`] (Van der Merwe's alpha, beta, kappa or
/// Julier's kappa; the centre-point-modified covariance for a negative kappa: the
/// [`crate::sigma_point`] module docs), deviations through the models' residual hooks
/// and means through their mean hooks. H~ = P_xy' P^-1 (before M), the statistical
/// linearisation of h from the update's own points, enters only through M.
///
/// - **Joint check**: as [`super::DynKalmanFilter`]: [[Q_acc, M], [M', R]] checked by
///   the policy ([`JointCheck::Reject`] by default), Q_acc <- Phi~ Q_acc Phi~' + Q
///   between updates with Phi~ = D' P^-1 the prediction's statistical linearisation
///   (D = Cov(chi, f(chi)) of its points).
/// - **Smoothing**: [`Self::filter_and_smooth`] returns the filtered and the smoothed
///   estimates of one forward pass: the unscented RTS smoother (Saerkkae, IEEE TAC
///   53(3), 2008), run as the linear backward pass over Phi~ and H~ (P Phi~' is the
///   points' D exactly); [`Self::rts_smooth`] is Saerkkae's URTS over given filtered
///   estimates (filterpy's `rts_smoother`).
/// - Memory is allocated at construction: predict and update allocate nothing (with
///   models that allocate nothing; `tests/dynamic_alloc.rs` counts), except the joint
///   check's eigen decomposition when an M is invalid or too close to call.
/// - Commit rule: an error (also one of a model) leaves the filter unchanged.
///
/// ```
/// use estim_core::dynamic::DynUnscentedKalmanFilter;
/// use estim_core::nalgebra::{DMatrix, DVector};
/// use estim_core::sigma_point::UnscentedTransform;
///
/// // A pendulum (angle, rate) seen through sin(angle).
/// let f = |x: &DVector<f64>, dt: f64, out: &mut DVector<f64>| {
///     out[0] = x[0] + dt * x[1];
///     out[1] = x[1] - dt * 9.81 * x[0].sin();
///     Ok(())
/// };
/// let h = |x: &DVector<f64>, out: &mut DVector<f64>| {
///     out[0] = x[0].sin();
///     Ok(())
/// };
/// let mut ukf = DynUnscentedKalmanFilter::new(
///     UnscentedTransform::new(0.5, 2.0, 0.0)?,
///     DMatrix::from_diagonal(&DVector::from_vec(vec![0.0, 1e-5])),
///     DMatrix::from_element(1, 1, 1e-2),
///     DVector::from_vec(vec![0.3, 0.0]),
///     DMatrix::identity(2, 2) * 0.1,
/// )?;
/// ukf.predict(&f, 0.01)?;
/// let report = ukf.update(&h, &DVector::from_element(1, 0.29))?;
/// assert!(report.accepted && report.nis >= 0.0);
/// # Ok::<(), estim_core::Error>(())
/// ```
#[derive(Debug, Clone)]
pub struct DynUnscentedKalmanFilter {
    transform: UnscentedTransform,
    process_noise: DMatrix<f64>,
    measurement_noise: DMatrix<f64>,
    state: DVector<f64>,
    covariance: DMatrix<f64>,
    /// Q_acc since the last update attempt (zero right after it).
    accumulated_noise: DMatrix<f64>,
    predicts_since_update: usize,
    noise_certificate: Option<f64>,
    measurement_certificate: Option<f64>,
    /// False after Q was replaced since the last predict.
    model_unchanged: bool,
    joint_check: JointCheck,
    log_likelihood: f64,
    ws: Workspace,
}

impl DynUnscentedKalmanFilter {
    /// A filter with the sigma points of `transform`, process noise Q (n x n),
    /// measurement noise R (m x m) and the initial estimate (x0, P0);
    /// [`JointCheck::Reject`].
    ///
    /// # Errors
    /// [`Error::Dimension`] for an empty x0 or R or a shape that disagrees with n (from
    /// x0) and m (from R); [`Error::NonFinite`]; [`Error::InvalidCovariance`] when Q, R
    /// or P0 is not symmetric positive semidefinite to round-off;
    /// [`Error::InvalidParameter`] for the [`SigmaPointUpdate::Augmented`] update (not
    /// available at run-time sizes) or weights without spread at n (n + kappa <= 0).
    pub fn new(
        transform: UnscentedTransform,
        process_noise: DMatrix<f64>,
        measurement_noise: DMatrix<f64>,
        state: DVector<f64>,
        covariance: DMatrix<f64>,
    ) -> Result<Self> {
        let (n, m) = (state.len(), measurement_noise.nrows());
        if n == 0 {
            return Err(Error::Dimension {
                what: "state (x0 must have at least one entry)",
                expected: 1,
                got: 0,
            });
        }
        if m == 0 {
            return Err(Error::Dimension {
                what: "measurement noise R (at least one measurement)",
                expected: 1,
                got: 0,
            });
        }
        if transform.update() != SigmaPointUpdate::Additive {
            return Err(Error::InvalidParameter {
                name: "sigma-point update",
                reason: "the run-time-sized filter has the additive update only".into(),
            });
        }
        transform.weights::<f64>(n)?;
        check_shape!("process noise Q", &process_noise, n, n)?;
        check_shape!("measurement noise R", &measurement_noise, m, m)?;
        check_shape!("initial covariance P0", &covariance, n, n)?;
        check_finite(state.as_slice(), "initial state x0")?;
        check_covariance(&process_noise, "process noise Q")?;
        check_covariance(&measurement_noise, "measurement noise R")?;
        check_covariance(&covariance, "initial covariance P0")?;
        Ok(Self {
            transform,
            noise_certificate: block_certificate(&process_noise),
            measurement_certificate: block_certificate(&measurement_noise),
            process_noise,
            measurement_noise,
            state,
            covariance,
            accumulated_noise: DMatrix::zeros(n, n),
            predicts_since_update: 0,
            model_unchanged: true,
            joint_check: JointCheck::default(),
            log_likelihood: 0.0,
            ws: Workspace::new(n, m),
        })
    }

    /// With this joint-covariance policy ([`JointCheck::Reject`] by default).
    #[must_use]
    pub fn with_joint_check(mut self, joint_check: JointCheck) -> Self {
        self.joint_check = joint_check;
        self
    }

    /// Number of states n.
    pub fn state_size(&self) -> usize {
        self.state.len()
    }

    /// Number of measurements m.
    pub fn measurement_size(&self) -> usize {
        self.measurement_noise.nrows()
    }

    /// The unscented transform (weights).
    pub fn transform(&self) -> &UnscentedTransform {
        &self.transform
    }

    /// The state estimate x.
    pub fn state(&self) -> &DVector<f64> {
        &self.state
    }

    /// Its covariance P.
    pub fn covariance(&self) -> &DMatrix<f64> {
        &self.covariance
    }

    /// Q.
    pub fn process_noise(&self) -> &DMatrix<f64> {
        &self.process_noise
    }

    /// R.
    pub fn measurement_noise(&self) -> &DMatrix<f64> {
        &self.measurement_noise
    }

    /// Sum of the accepted updates' log-likelihood terms since construction.
    pub fn log_likelihood(&self) -> f64 {
        self.log_likelihood
    }

    /// Q_acc: the process noise accumulated since the last update attempt.
    pub fn accumulated_process_noise(&self) -> &DMatrix<f64> {
        &self.accumulated_noise
    }

    /// The innovation y - y_hat of the last update attempt (through the
    /// measurement's residual hook).
    pub fn innovation(&self) -> &DVector<f64> {
        &self.ws.innovation
    }

    /// P_yy of the last update attempt.
    pub fn innovation_covariance(&self) -> &DMatrix<f64> {
        &self.ws.s
    }

    /// P_yy^-1 of the last update attempt.
    pub fn innovation_covariance_inverse(&self) -> &DMatrix<f64> {
        &self.ws.s_inverse
    }

    /// The predicted measurement y_hat of the last update attempt.
    pub fn predicted_measurement(&self) -> &DVector<f64> {
        &self.ws.measurement.mean
    }

    /// P_xy (with M) of the last update attempt.
    pub fn state_measurement_covariance(&self) -> &DMatrix<f64> {
        &self.ws.pxy
    }

    /// The gain K of the last accepted update.
    pub fn gain(&self) -> &DMatrix<f64> {
        &self.ws.gain
    }

    /// The last update's sigma points through h, m x (2n + 1) (filterpy's
    /// `sigmas_h`, transposed; order of [`super::DynSigmaPoints`]).
    pub fn measurement_sigma_points(&self) -> &DMatrix<f64> {
        &self.ws.measurement.images
    }

    /// The last prediction's sigma points through f, n x (2n + 1).
    pub fn propagated_sigma_points(&self) -> &DMatrix<f64> {
        &self.ws.process.images
    }

    /// The last prediction's statistical linearisation Phi~ = D' P^-1.
    pub fn linearised_transition(&self) -> &DMatrix<f64> {
        &self.ws.process.linearised
    }

    /// The last update's statistical linearisation H~ = P_xy' P^-1 (before M).
    pub fn linearised_observation(&self) -> &DMatrix<f64> {
        &self.ws.measurement.linearised
    }

    /// Replace the estimate (x, P), checked as in [`Self::new`]. Q_acc is kept.
    ///
    /// # Errors
    /// [`Error::Dimension`], [`Error::NonFinite`], [`Error::InvalidCovariance`]; the
    /// filter is then unchanged.
    pub fn set_estimate(&mut self, state: &DVector<f64>, covariance: &DMatrix<f64>) -> Result<()> {
        let n = self.state.len();
        check_size("state x", n, state.len())?;
        check_shape!("covariance P", covariance, n, n)?;
        check_finite(state.as_slice(), "state x")?;
        check_covariance(covariance, "covariance P")?;
        self.state.copy_from(state);
        self.covariance.copy_from(covariance);
        Ok(())
    }

    /// Replace Q for the following predicts (checked as in [`Self::new`]).
    ///
    /// # Errors
    /// [`Error::Dimension`], [`Error::NonFinite`], [`Error::InvalidCovariance`].
    pub fn set_process_noise(&mut self, process_noise: &DMatrix<f64>) -> Result<()> {
        let n = self.state.len();
        check_shape!("process noise Q", process_noise, n, n)?;
        check_covariance(process_noise, "process noise Q")?;
        self.process_noise.copy_from(process_noise);
        self.noise_certificate = block_certificate(process_noise);
        self.model_unchanged = false;
        Ok(())
    }

    /// Replace R for the following updates (checked as in [`Self::new`]).
    ///
    /// # Errors
    /// [`Error::Dimension`], [`Error::NonFinite`], [`Error::InvalidCovariance`].
    pub fn set_measurement_noise(&mut self, measurement_noise: &DMatrix<f64>) -> Result<()> {
        let m = self.measurement_size();
        check_shape!("measurement noise R", measurement_noise, m, m)?;
        check_covariance(measurement_noise, "measurement noise R")?;
        self.measurement_noise.copy_from(measurement_noise);
        self.measurement_certificate = block_certificate(measurement_noise);
        Ok(())
    }

    /// The weights at n.
    fn weights(&self) -> Result<Weights<f64>> {
        self.transform.weights::<f64>(self.state.len())
    }

    /// Prior over `dt`: the sigma points of (x, P) through `process`, their mean and
    /// covariance plus Q (struct docs); Phi~ for Q_acc and the smoother.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for dt not finite and positive;
    /// [`Error::InvalidCovariance`] if P has no square root; [`Error::NonFinite`]; the
    /// model's errors. The filter is then unchanged.
    pub fn predict<P: DynSigmaPointProcess + ?Sized>(
        &mut self,
        process: &P,
        dt: f64,
    ) -> Result<()> {
        if !(dt.is_finite() && dt > 0.0) {
            return Err(Error::InvalidParameter {
                name: "dt",
                reason: format!("{dt} is not a positive finite time step"),
            });
        }
        let weights = self.weights()?;
        factor_into(&self.covariance, &mut self.ws.factor, "prior covariance")?;
        let ws = &mut self.ws;
        sigma_pass(
            &weights,
            &self.state,
            &ws.factor,
            &mut ws.point,
            &mut ws.process,
            |x, out| process.propagate(x, dt, out),
            |a, b, out| process.residual(a, b, out),
            |points, out| process.mean(points, out),
            "propagated sigma point",
        )?;
        let pass = &mut ws.process;
        // P- = (sum + sum')/2 + (Q + Q')/2, as the static prediction.
        let n = self.state.len();
        for j in 0..n {
            for i in 0..n {
                ws.nn_next[(i, j)] = (pass.second[(i, j)] + pass.second[(j, i)]) * 0.5
                    + (self.process_noise[(i, j)] + self.process_noise[(j, i)]) * 0.5;
            }
        }
        check_finite(ws.nn_next.as_slice(), "predicted covariance")?;
        solve_right_lower(&pass.spread, &ws.factor, &mut pass.linearised);
        check_finite(
            pass.linearised.as_slice(),
            "statistically linearised transition",
        )?;
        self.state.copy_from(&pass.mean);
        std::mem::swap(&mut self.covariance, &mut ws.nn_next);
        // Q_acc <- Phi~ Q_acc Phi~' + Q (Q itself after an update).
        if self.predicts_since_update == 0 {
            self.accumulated_noise.copy_from(&self.process_noise);
            self.model_unchanged = true;
        } else {
            gemm(
                &mut ws.nn,
                1.0,
                &pass.linearised,
                &self.accumulated_noise,
                0.0,
            );
            ws.nn_next.copy_from(&self.process_noise);
            pass.linearised.transpose_to(&mut ws.correction);
            gemm_upper(&mut ws.nn_next, 1.0, &ws.nn, &ws.correction, 1.0);
            mirror_upper(&mut ws.nn_next);
            std::mem::swap(&mut self.accumulated_noise, &mut ws.nn_next);
            self.model_unchanged = false;
        }
        self.predicts_since_update += 1;
        Ok(())
    }

    /// Update with y through `model`, M = 0: the textbook UKF update (filterpy's
    /// `update(z)`).
    ///
    /// # Errors
    /// As [`Self::update_correlated`].
    pub fn update<H: DynSigmaPointMeasurement + ?Sized>(
        &mut self,
        model: &H,
        measurement: &DVector<f64>,
    ) -> Result<DynUpdateReport> {
        self.update_inner(model, measurement.as_slice(), None)
    }

    /// Update with y through `model` and the cross-covariance M = Cov(x_k, v_k)
    /// (n x m), checked by the joint policy ([`JointCheck::Reject`] by default).
    ///
    /// # Errors
    /// [`Error::Dimension`] for a y or M of the wrong shape; [`Error::NonFinite`];
    /// [`Error::InvalidJointCovariance`]; [`Error::InvalidCovariance`] if P has no
    /// square root; [`Error::InnovationNotPositiveDefinite`];
    /// [`Error::InnovationIllConditioned`]; the model's errors. The filter is then
    /// unchanged.
    pub fn update_correlated<H: DynSigmaPointMeasurement + ?Sized>(
        &mut self,
        model: &H,
        measurement: &DVector<f64>,
        cross_covariance: &DMatrix<f64>,
    ) -> Result<DynUpdateReport> {
        self.update_inner(model, measurement.as_slice(), Some(cross_covariance))
    }

    /// [`Self::update_correlated`] from a slice, M optional.
    ///
    /// # Errors
    /// As [`Self::update_correlated`].
    pub fn update_slice<H: DynSigmaPointMeasurement + ?Sized>(
        &mut self,
        model: &H,
        measurement: &[f64],
        cross_covariance: Option<&DMatrix<f64>>,
    ) -> Result<DynUpdateReport> {
        self.update_inner(model, measurement, cross_covariance)
    }

    /// The joint check of the next update with `cross`, by the policy (as
    /// [`super::DynKalmanFilter`]'s).
    fn joint_margin(&mut self, cross: Option<&DMatrix<f64>>) -> Result<Option<f64>> {
        if self.joint_check == JointCheck::Skip {
            return Ok(None);
        }
        let correlated = cross.is_some_and(|c| c.iter().any(|v| *v != 0.0));
        let known_noise = if self.predicts_since_update == 1 && self.model_unchanged {
            Some(self.noise_certificate)
        } else {
            None
        };
        let margin = joint_validity_margin(
            &self.accumulated_noise,
            cross.filter(|_| correlated),
            &self.measurement_noise,
            known_noise,
            Some(self.measurement_certificate),
            &mut self.ws.joint,
        )?;
        if self.joint_check == JointCheck::Reject && margin < -relative_tolerance() {
            return Err(Error::InvalidJointCovariance {
                min_eigenvalue: margin,
            });
        }
        Ok(Some(margin))
    }

    fn update_inner<H: DynSigmaPointMeasurement + ?Sized>(
        &mut self,
        model: &H,
        measurement: &[f64],
        cross: Option<&DMatrix<f64>>,
    ) -> Result<DynUpdateReport> {
        let (n, m) = (self.state.len(), self.measurement_size());
        check_size("measurement y", m, measurement.len())?;
        check_finite(measurement, "measurement y")?;
        if let Some(c) = cross {
            check_shape!("cross-covariance M", c, n, m)?;
            check_finite(c.as_slice(), "cross-covariance M")?;
        }
        let joint_min_eigenvalue = self.joint_margin(cross)?;
        let weights = self.weights()?;
        factor_into(&self.covariance, &mut self.ws.factor, "prior covariance")?;
        let ws = &mut self.ws;
        let correlated = cross.filter(|c| c.iter().any(|v| *v != 0.0));
        if let Some(c) = correlated {
            // S^-1 M (rows zero where S has a zero pivot): H~ M = G S^-1 M.
            solve_lower(&ws.factor, c, &mut ws.whitened_cross);
        }
        sigma_pass(
            &weights,
            &self.state,
            &ws.factor,
            &mut ws.point,
            &mut ws.measurement,
            |x, out| model.predict(x, out),
            |a, b, out| model.residual(a, b, out),
            |points, out| model.mean(points, out),
            "predicted measurement",
        )?;
        let pass = &mut ws.measurement;
        // P_xy = sum_i W (chi_i - x) d_i' summed point by point as the static update
        // sums it (the e part cancels over each +/- pair).
        sum_state_measurement_products(
            &mut ws.pxy,
            &ws.factor,
            [&pass.plus_all, &pass.minus_all],
            weights.gamma,
            weights.other,
        );
        if let Some(c) = correlated {
            gemm(
                &mut ws.linearised_cross,
                1.0,
                &pass.spread,
                &ws.whitened_cross,
                0.0,
            );
            ws.pxy += c;
        } else {
            ws.linearised_cross.fill(0.0);
        }
        // P_yy = sym(sum + (H~ M + M' H~') + R), as the static update.
        for j in 0..m {
            for i in 0..m {
                let lc = ws.linearised_cross[(i, j)] + ws.linearised_cross[(j, i)];
                ws.mm[(i, j)] = pass.second[(i, j)] + (lc + self.measurement_noise[(i, j)]);
            }
        }
        for j in 0..m {
            for i in 0..m {
                ws.s[(i, j)] = (ws.mm[(i, j)] + ws.mm[(j, i)]) * 0.5;
            }
        }
        check_finite(ws.s.as_slice(), "innovation covariance")?;
        solve_right_lower(&pass.spread, &ws.factor, &mut pass.linearised);
        // nu = residual(y, y_hat).
        pass.image.copy_from_slice(measurement);
        model.residual(&pass.image, &pass.mean, &mut ws.innovation)?;
        check_finite(ws.innovation.as_slice(), "innovation")?;
        let log_det = spd_inverse_log_det_into(&ws.s, &mut ws.mm, &mut ws.s_inverse)
            .ok_or(Error::InnovationNotPositiveDefinite)?;
        check_innovation_conditioning(&ws.s, &ws.s_inverse)?;
        ws.weighted.gemv(1.0, &ws.s_inverse, &ws.innovation, 0.0);
        let nis = ws.innovation.dot(&ws.weighted);
        let log_likelihood = -0.5 * (m as f64 * LN_2PI + log_det + nis);
        if !(nis.is_finite() && log_likelihood.is_finite()) {
            return Err(Error::NonFinite {
                what: "normalised innovation squared",
            });
        }
        // K = P_xy P_yy^-1, x+ = x + K nu, P+ = sym(P) - sym(K P_xy').
        gemm(&mut ws.gain, 1.0, &ws.pxy, &ws.s_inverse, 0.0);
        ws.state.copy_from(&self.state);
        ws.state.gemv(1.0, &ws.gain, &ws.innovation, 1.0);
        ws.pxy.transpose_to(&mut ws.gain_t);
        gemm(&mut ws.correction, 1.0, &ws.gain, &ws.gain_t, 0.0);
        let p = &self.covariance;
        for j in 0..n {
            for i in 0..=j {
                let v = (p[(i, j)] + p[(j, i)]) * 0.5
                    - (ws.correction[(i, j)] + ws.correction[(j, i)]) * 0.5;
                ws.nn_next[(i, j)] = v;
                ws.nn_next[(j, i)] = v;
            }
        }
        check_finite(ws.state.as_slice(), "posterior state")?;
        check_finite(ws.nn_next.as_slice(), "posterior covariance")?;
        ws.gain.transpose_to(&mut ws.gain_t);
        std::mem::swap(&mut self.state, &mut ws.state);
        std::mem::swap(&mut self.covariance, &mut ws.nn_next);
        self.log_likelihood += log_likelihood;
        self.accumulated_noise.fill(0.0);
        self.predicts_since_update = 0;
        Ok(DynUpdateReport {
            accepted: true,
            nis,
            log_likelihood,
            joint_min_eigenvalue,
            gate_threshold: None,
        })
    }
}

/// P_xy = sum_i W (chi_i - x) d_i' over the +/- sigma points of `factor`'s columns
/// (chi_i - x = +/- gamma column j; `deviations` the measurement deviations d of the
/// plus and the minus points), summed point by point.
fn sum_state_measurement_products(
    pxy: &mut DMatrix<f64>,
    factor: &DMatrix<f64>,
    deviations: [&DMatrix<f64>; 2],
    gamma: f64,
    weight: f64,
) {
    let (n, m) = pxy.shape();
    pxy.fill(0.0);
    for j in 0..n {
        for (d, sign) in deviations.into_iter().zip([1.0, -1.0]) {
            let g = gamma * sign;
            for c in 0..m {
                for r in 0..n {
                    pxy[(r, c)] += factor[(r, j)] * g * d[(c, j)] * weight;
                }
            }
        }
    }
}
