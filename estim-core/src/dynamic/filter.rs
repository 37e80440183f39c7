//! [`DynKalmanFilter`]: the linear Kalman filter with the correlated update, sizes
//! known at run time.

use nalgebra::{DMatrix, DVector};

use super::linalg::{
    block_certificate, check_covariance, check_finite, check_innovation_conditioning, check_size,
    joint_validity_margin, mirror_upper, relative_tolerance, spd_inverse_log_det_into,
    symmetrize_in_place, JointScratch,
};
use super::product::{gemm, gemm_upper};
use crate::{Error, JointCheck, Result};

/// Fail with [`Error::Dimension`] unless the matrix is rows x cols, naming which
/// of the two disagrees.
macro_rules! check_shape {
    ($what:literal, $a:expr, $rows:expr, $cols:expr $(,)?) => {{
        let a: &DMatrix<f64> = $a;
        $crate::dynamic::linalg::check_size(concat!($what, " (rows)"), $rows, a.nrows()).and_then(
            |()| {
                $crate::dynamic::linalg::check_size(concat!($what, " (columns)"), $cols, a.ncols())
            },
        )
    }};
}
pub(crate) use check_shape;

/// ln(2 pi).
const LN_2PI: f64 = 1.837_877_066_409_345_5;

/// What one update attempt of a [`DynKalmanFilter`] produced (scalars; the vectors and
/// matrices of the same attempt are read from the filter: [`DynKalmanFilter::innovation`],
/// [`DynKalmanFilter::innovation_covariance`], [`DynKalmanFilter::gain`]), so that an
/// update allocates nothing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DynUpdateReport {
    /// False when the innovation gate rejected the measurement (state untouched).
    pub accepted: bool,
    /// Normalised innovation squared nu' S^-1 nu.
    pub nis: f64,
    /// ln N(nu; 0, S) = -(m ln 2 pi + ln det S + nis) / 2, this measurement's term of
    /// the log-likelihood.
    pub log_likelihood: f64,
    /// Validity margin of [[Q_acc, M], [M', R]] as the static runners report it
    /// ([`crate::JointCovariance::validity_margin`]: >= 0 iff valid); `None` with
    /// [`JointCheck::Skip`].
    pub joint_min_eigenvalue: Option<f64>,
    /// The gate's NIS threshold, if one is set.
    pub gate_threshold: Option<f64>,
}

/// Buffers of one predict and one update, allocated at construction.
#[derive(Debug, Clone)]
struct Workspace {
    /// n: the predicted or posterior state before the swap.
    state: DVector<f64>,
    /// n x n: F P, then the old covariance after a swap.
    nn: DMatrix<f64>,
    /// n x n: the new covariance before the swap.
    nn_next: DMatrix<f64>,
    /// m: the innovation of the last update attempt.
    innovation: DVector<f64>,
    /// m x n: H P + M' = A'.
    a_t: DMatrix<f64>,
    /// m x n: K'.
    gain_t: DMatrix<f64>,
    /// n x m: A and K.
    a: DMatrix<f64>,
    gain: DMatrix<f64>,
    /// m x n: S K' - A'.
    residual: DMatrix<f64>,
    /// m x m: S, its inverse, scratch.
    s: DMatrix<f64>,
    s_inverse: DMatrix<f64>,
    mm: DMatrix<f64>,
    /// m: S^-1 nu.
    weighted: DVector<f64>,
    joint: JointScratch,
}

impl Workspace {
    fn new(n: usize, m: usize) -> Self {
        Self {
            state: DVector::zeros(n),
            nn: DMatrix::zeros(n, n),
            nn_next: DMatrix::zeros(n, n),
            innovation: DVector::zeros(m),
            a_t: DMatrix::zeros(m, n),
            gain_t: DMatrix::zeros(m, n),
            a: DMatrix::zeros(n, m),
            gain: DMatrix::zeros(n, m),
            residual: DMatrix::zeros(m, n),
            s: DMatrix::zeros(m, m),
            s_inverse: DMatrix::zeros(m, m),
            mm: DMatrix::zeros(m, m),
            weighted: DVector::zeros(m),
            joint: JointScratch::new(n, m),
        }
    }
}

/// Linear Kalman filter x_k = F x_{k-1} + B u_k + G w_{k-1}, y_k = H x_k + v_k, with
/// Cov(G w) = Q, Cov(v) = R and the cross-covariance M = Cov(G w_{k-1}, v_k), whose
/// sizes (n states, m measurements, the input's) are known only at run time.
///
/// The same filter as [`crate::KalmanFilter`] (time index, accumulation of Q_acc
/// between updates, joint-covariance check with [`JointCheck::Reject`] by default,
/// commit rule: an error leaves the filter untouched), with `DMatrix<f64>` /
/// `DVector<f64>`:
///
/// ```text
/// predict:  x <- F x + B u        P <- F P F' + Q       Q_acc <- F Q_acc F' + Q
/// update:   S  = H P H' + H M + M' H' + R               (Simon 2006, sec. 7.1)
///           K  = (P H' + M) S^-1       x <- x + K (y - H x)
///           P <- P - K A' - A K' + K S K',  A = P H' + M   (Joseph-like, any gain)
/// ```
///
/// Every buffer is allocated by the constructor: `predict`, `update` and
/// `update_correlated` allocate nothing (`tests/dynamic.rs` counts), except the joint
/// check's eigen decomposition when an M is invalid or too close to call. Matrices live
/// on the heap, so n = 500 runs on a 2 MiB thread stack.
///
/// ```
/// use estim_core::dynamic::DynKalmanFilter;
/// use estim_core::nalgebra::{DMatrix, DVector};
///
/// let f = DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 0.0, 1.0]);
/// let q = DMatrix::identity(2, 2) * 0.01;
/// let h = DMatrix::from_row_slice(1, 2, &[1.0, 0.0]);
/// let r = DMatrix::from_element(1, 1, 0.1);
/// let mut kf = DynKalmanFilter::new(f, q, h, r, DVector::zeros(2), DMatrix::identity(2, 2))?;
/// kf.predict()?;
/// let report = kf.update(&DVector::from_element(1, 1.2))?;
/// assert!(report.accepted && report.nis > 0.0);
/// assert!(kf.state()[0] > 0.0);
/// # Ok::<(), estim_core::Error>(())
/// ```
#[derive(Debug, Clone)]
pub struct DynKalmanFilter {
    transition: DMatrix<f64>,
    /// F' (the product kernel reads column-major operands as they are stored).
    transition_t: DMatrix<f64>,
    process_noise: DMatrix<f64>,
    observation: DMatrix<f64>,
    /// H'.
    observation_t: DMatrix<f64>,
    measurement_noise: DMatrix<f64>,
    control: Option<DMatrix<f64>>,
    state: DVector<f64>,
    covariance: DMatrix<f64>,
    /// Q_acc since the last update attempt (zero right after it).
    accumulated_noise: DMatrix<f64>,
    predicts_since_update: usize,
    /// Q's and R's block certificates for the joint check with M = 0.
    noise_certificate: Option<f64>,
    measurement_certificate: Option<f64>,
    /// False after F or Q was replaced since the last update (Q_acc's certificate is
    /// then recomputed).
    model_unchanged: bool,
    joint_check: JointCheck,
    gate: Option<f64>,
    log_likelihood: f64,
    has_update: bool,
    ws: Workspace,
}

impl DynKalmanFilter {
    /// A filter with transition F (n x n), process noise Q (n x n), observation matrix
    /// H (m x n), measurement noise R (m x m) and the initial estimate (x0, P0); no
    /// control input, no gate, [`JointCheck::Reject`].
    ///
    /// # Errors
    /// [`Error::Dimension`] naming the first matrix whose shape disagrees with n
    /// (from x0) and m (from R); [`Error::NonFinite`]; [`Error::InvalidCovariance`]
    /// when Q, R or P0 is not symmetric positive semidefinite to round-off.
    pub fn new(
        transition: DMatrix<f64>,
        process_noise: DMatrix<f64>,
        observation: DMatrix<f64>,
        measurement_noise: DMatrix<f64>,
        state: DVector<f64>,
        covariance: DMatrix<f64>,
    ) -> Result<Self> {
        let n = state.len();
        let m = measurement_noise.nrows();
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
        check_shape!("transition matrix F", &transition, n, n)?;
        check_shape!("process noise Q", &process_noise, n, n)?;
        check_shape!("observation matrix H", &observation, m, n)?;
        check_shape!("measurement noise R", &measurement_noise, m, m)?;
        check_shape!("initial covariance P0", &covariance, n, n)?;
        check_finite(transition.as_slice(), "transition matrix F")?;
        check_finite(observation.as_slice(), "observation matrix H")?;
        check_finite(state.as_slice(), "initial state x0")?;
        check_covariance(&process_noise, "process noise Q")?;
        check_covariance(&measurement_noise, "measurement noise R")?;
        check_covariance(&covariance, "initial covariance P0")?;
        Ok(Self {
            noise_certificate: block_certificate(&process_noise),
            measurement_certificate: block_certificate(&measurement_noise),
            transition_t: transition.transpose(),
            transition,
            process_noise,
            observation_t: observation.transpose(),
            observation,
            measurement_noise,
            control: None,
            state,
            covariance,
            accumulated_noise: DMatrix::zeros(n, n),
            predicts_since_update: 0,
            model_unchanged: true,
            joint_check: JointCheck::default(),
            gate: None,
            log_likelihood: 0.0,
            has_update: false,
            ws: Workspace::new(n, m),
        })
    }

    /// With a control matrix B (n x u): [`Self::predict_with_input`] adds B u.
    ///
    /// # Errors
    /// [`Error::Dimension`] if B does not have n rows; [`Error::NonFinite`].
    pub fn with_control(mut self, control: DMatrix<f64>) -> Result<Self> {
        self.set_control(Some(control))?;
        Ok(self)
    }

    /// With this joint-covariance policy ([`JointCheck::Reject`] by default).
    #[must_use]
    pub fn with_joint_check(mut self, joint_check: JointCheck) -> Self {
        self.joint_check = joint_check;
        self
    }

    /// With an innovation gate: a measurement whose NIS exceeds `threshold` is
    /// rejected (state untouched, [`DynUpdateReport::accepted`] false).
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] unless the threshold is positive (and not NaN).
    pub fn with_nis_gate(mut self, threshold: f64) -> Result<Self> {
        if threshold.is_nan() || threshold <= 0.0 {
            return Err(Error::InvalidParameter {
                name: "nis gate threshold",
                reason: format!("{threshold} is not positive"),
            });
        }
        self.gate = Some(threshold);
        Ok(self)
    }

    /// Number of states n.
    pub fn state_size(&self) -> usize {
        self.state.len()
    }

    /// Number of measurements m.
    pub fn measurement_size(&self) -> usize {
        self.measurement_noise.nrows()
    }

    /// The state estimate x.
    pub fn state(&self) -> &DVector<f64> {
        &self.state
    }

    /// Its covariance P.
    pub fn covariance(&self) -> &DMatrix<f64> {
        &self.covariance
    }

    /// F.
    pub fn transition(&self) -> &DMatrix<f64> {
        &self.transition
    }

    /// F' (kept beside F).
    pub(crate) fn transition_transposed(&self) -> &DMatrix<f64> {
        &self.transition_t
    }

    /// H' (kept beside H).
    pub(crate) fn observation_transposed(&self) -> &DMatrix<f64> {
        &self.observation_t
    }

    /// Q = Cov(G w).
    pub fn process_noise(&self) -> &DMatrix<f64> {
        &self.process_noise
    }

    /// H.
    pub fn observation(&self) -> &DMatrix<f64> {
        &self.observation
    }

    /// R.
    pub fn measurement_noise(&self) -> &DMatrix<f64> {
        &self.measurement_noise
    }

    /// B, if set.
    pub fn control(&self) -> Option<&DMatrix<f64>> {
        self.control.as_ref()
    }

    /// The joint-covariance policy.
    pub fn joint_check(&self) -> JointCheck {
        self.joint_check
    }

    /// The NIS gate threshold, if any.
    pub fn nis_gate(&self) -> Option<f64> {
        self.gate
    }

    /// Sum of the accepted updates' log-likelihood terms since construction.
    pub fn log_likelihood(&self) -> f64 {
        self.log_likelihood
    }

    /// Q_acc: the process noise accumulated since the last update attempt.
    pub fn accumulated_process_noise(&self) -> &DMatrix<f64> {
        &self.accumulated_noise
    }

    /// Predicts since the last update attempt.
    pub fn predicts_since_update(&self) -> usize {
        self.predicts_since_update
    }

    /// Innovation y - H x of the last update attempt (zeros before the first).
    pub fn innovation(&self) -> &DVector<f64> {
        &self.ws.innovation
    }

    /// Innovation covariance S of the last update attempt.
    pub fn innovation_covariance(&self) -> &DMatrix<f64> {
        &self.ws.s
    }

    /// S^-1 of the last update attempt.
    pub fn innovation_covariance_inverse(&self) -> &DMatrix<f64> {
        &self.ws.s_inverse
    }

    /// The gain K (n x m) of the last accepted update, transposed: K' (m x n).
    pub fn gain_transposed(&self) -> &DMatrix<f64> {
        &self.ws.gain_t
    }

    /// The gain K (n x m) of the last accepted update.
    pub fn gain(&self) -> &DMatrix<f64> {
        &self.ws.gain
    }

    /// Whether an update has been attempted (the last-update accessors hold its values).
    pub fn has_update(&self) -> bool {
        self.has_update
    }

    /// Replace the estimate (x, P), checked as in [`Self::new`]. Q_acc is kept.
    ///
    /// # Errors
    /// [`Error::Dimension`], [`Error::NonFinite`], [`Error::InvalidCovariance`]; the
    /// filter is then unchanged.
    pub fn set_estimate(&mut self, state: &DVector<f64>, covariance: &DMatrix<f64>) -> Result<()> {
        check_size("state x", self.state.len(), state.len())?;
        let n = self.state.len();
        check_shape!("covariance P", covariance, n, n)?;
        check_finite(state.as_slice(), "state x")?;
        check_covariance(covariance, "covariance P")?;
        self.state.copy_from(state);
        self.covariance.copy_from(covariance);
        Ok(())
    }

    /// Replace F for the following predicts.
    ///
    /// # Errors
    /// [`Error::Dimension`], [`Error::NonFinite`]; the filter is then unchanged.
    pub fn set_transition(&mut self, transition: &DMatrix<f64>) -> Result<()> {
        let n = self.state.len();
        check_shape!("transition matrix F", transition, n, n)?;
        check_finite(transition.as_slice(), "transition matrix F")?;
        self.transition.copy_from(transition);
        transition.transpose_to(&mut self.transition_t);
        self.model_unchanged = false;
        Ok(())
    }

    /// Replace Q for the following predicts (checked as in [`Self::new`]; allocates
    /// its certificate).
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

    /// Replace H for the following updates.
    ///
    /// # Errors
    /// [`Error::Dimension`], [`Error::NonFinite`].
    pub fn set_observation(&mut self, observation: &DMatrix<f64>) -> Result<()> {
        check_shape!(
            "observation matrix H",
            observation,
            self.measurement_size(),
            self.state.len(),
        )?;
        check_finite(observation.as_slice(), "observation matrix H")?;
        self.observation.copy_from(observation);
        observation.transpose_to(&mut self.observation_t);
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

    /// Replace (or remove) the control matrix B (n x u).
    ///
    /// # Errors
    /// [`Error::Dimension`] if B does not have n rows; [`Error::NonFinite`].
    pub fn set_control(&mut self, control: Option<DMatrix<f64>>) -> Result<()> {
        if let Some(b) = &control {
            check_size("control matrix B (rows)", self.state.len(), b.nrows())?;
            check_finite(b.as_slice(), "control matrix B")?;
        }
        self.control = control;
        Ok(())
    }

    /// Prior without control input: x <- F x, P <- F P F' + Q.
    ///
    /// # Errors
    /// [`Error::NonFinite`] if the prediction overflows (the filter is then
    /// unchanged).
    pub fn predict(&mut self) -> Result<()> {
        self.predict_inner(None, None)
    }

    /// Prior with control input: x <- F x + B u, P <- F P F' + Q.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] without a control matrix; [`Error::Dimension`] if u
    /// does not have B's column count; [`Error::NonFinite`].
    pub fn predict_with_input(&mut self, input: &DVector<f64>) -> Result<()> {
        let Some(b) = &self.control else {
            return Err(Error::InvalidParameter {
                name: "control input u",
                reason: "the filter has no control matrix B (with_control)".into(),
            });
        };
        check_size("control input u", b.ncols(), input.len())?;
        check_finite(input.as_slice(), "control input u")?;
        self.predict_inner(Some(input), None)
    }

    /// The prior of an extended filter: x <- `propagated` (f(x), n entries, finite:
    /// checked by the caller), P <- F P F' + Q with F the Jacobian set before.
    pub(crate) fn predict_propagated(&mut self, propagated: &DVector<f64>) -> Result<()> {
        self.predict_inner(None, Some(propagated))
    }

    fn predict_inner(
        &mut self,
        input: Option<&DVector<f64>>,
        propagated: Option<&DVector<f64>>,
    ) -> Result<()> {
        let ws = &mut self.ws;
        match propagated {
            Some(x) => ws.state.copy_from(x),
            None => ws.state.gemv(1.0, &self.transition, &self.state, 0.0),
        }
        if let (Some(b), Some(u)) = (&self.control, input) {
            ws.state.gemv(1.0, b, u, 1.0);
        }
        gemm(&mut ws.nn, 1.0, &self.transition, &self.covariance, 0.0);
        ws.nn_next.copy_from(&self.process_noise);
        // F P F' + Q is symmetric: its upper triangle, mirrored.
        gemm_upper(&mut ws.nn_next, 1.0, &ws.nn, &self.transition_t, 1.0);
        mirror_upper(&mut ws.nn_next);
        if !(ws.state.iter().all(|v| v.is_finite()) && ws.nn_next.iter().all(|v| v.is_finite())) {
            return Err(Error::NonFinite {
                what: "predicted state or covariance (overflow)",
            });
        }
        std::mem::swap(&mut self.state, &mut ws.state);
        std::mem::swap(&mut self.covariance, &mut ws.nn_next);
        // Q_acc <- F Q_acc F' + Q (Q itself after an update).
        if self.predicts_since_update == 0 {
            self.accumulated_noise.copy_from(&self.process_noise);
        } else {
            gemm(
                &mut ws.nn,
                1.0,
                &self.transition,
                &self.accumulated_noise,
                0.0,
            );
            ws.nn_next.copy_from(&self.process_noise);
            gemm_upper(&mut ws.nn_next, 1.0, &ws.nn, &self.transition_t, 1.0);
            mirror_upper(&mut ws.nn_next);
            std::mem::swap(&mut self.accumulated_noise, &mut ws.nn_next);
            self.model_unchanged = false;
        }
        self.predicts_since_update += 1;
        if self.predicts_since_update == 1 {
            self.model_unchanged = true;
        }
        Ok(())
    }

    /// Update with y, uncorrelated noise (M = 0).
    ///
    /// # Errors
    /// As [`Self::update_correlated`].
    pub fn update(&mut self, measurement: &DVector<f64>) -> Result<DynUpdateReport> {
        self.update_inner(measurement.as_slice(), None, None)
    }

    /// Update with y and the cross-covariance M = Cov(G w, v) (n x m) of the noise
    /// accumulated since the last update with this measurement's noise. The joint
    /// covariance [[Q_acc, M], [M', R]] is checked by the filter's policy
    /// ([`JointCheck::Reject`] by default: an M that is not a covariance is refused).
    ///
    /// # Errors
    /// [`Error::Dimension`] for a y of the wrong length or an M of the wrong shape;
    /// [`Error::NonFinite`]; [`Error::InvalidJointCovariance`];
    /// [`Error::InnovationNotPositiveDefinite`]; [`Error::InnovationIllConditioned`].
    /// On an error the filter is unchanged.
    pub fn update_correlated(
        &mut self,
        measurement: &DVector<f64>,
        cross_covariance: &DMatrix<f64>,
    ) -> Result<DynUpdateReport> {
        self.update_inner(measurement.as_slice(), Some(cross_covariance), None)
    }

    /// [`Self::update_correlated`] from a slice (no vector needed), M optional.
    ///
    /// # Errors
    /// As [`Self::update_correlated`].
    pub fn update_slice(
        &mut self,
        measurement: &[f64],
        cross_covariance: Option<&DMatrix<f64>>,
    ) -> Result<DynUpdateReport> {
        self.update_inner(measurement, cross_covariance, None)
    }

    /// The update of an extended filter: innovation y - `predicted` (h(x), m entries,
    /// finite: checked by the caller) with H the Jacobian set before.
    pub(crate) fn update_predicted(
        &mut self,
        measurement: &[f64],
        predicted: &DVector<f64>,
        cross_covariance: Option<&DMatrix<f64>>,
    ) -> Result<DynUpdateReport> {
        self.update_inner(measurement, cross_covariance, Some(predicted))
    }

    /// The joint check of the next update with `cross` (None: M = 0), by the policy.
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

    fn update_inner(
        &mut self,
        measurement: &[f64],
        cross: Option<&DMatrix<f64>>,
        predicted: Option<&DVector<f64>>,
    ) -> Result<DynUpdateReport> {
        let (n, m) = (self.state.len(), self.measurement_size());
        check_size("measurement y", m, measurement.len())?;
        check_finite(measurement, "measurement y")?;
        if let Some(c) = cross {
            check_shape!("cross-covariance M", c, n, m)?;
            check_finite(c.as_slice(), "cross-covariance M")?;
        }
        let joint_min_eigenvalue = self.joint_margin(cross)?;
        let ws = &mut self.ws;
        // nu = y - H x (y - h(x) in an extended filter).
        ws.innovation.copy_from_slice(measurement);
        match predicted {
            Some(h) => ws.innovation -= h,
            None => ws
                .innovation
                .gemv(-1.0, &self.observation, &self.state, 1.0),
        }
        // A' = H P + M' (P symmetric), S = H P H' + H M + M' H' + R.
        gemm(&mut ws.a_t, 1.0, &self.observation, &self.covariance, 0.0);
        ws.s.copy_from(&self.measurement_noise);
        gemm(&mut ws.s, 1.0, &ws.a_t, &self.observation_t, 1.0);
        if let Some(c) = cross {
            gemm(&mut ws.mm, 1.0, &self.observation, c, 0.0);
            for j in 0..m {
                for i in 0..m {
                    ws.s[(i, j)] += ws.mm[(i, j)] + ws.mm[(j, i)];
                }
            }
            for j in 0..n {
                for i in 0..m {
                    ws.a_t[(i, j)] += c[(j, i)];
                }
            }
        }
        symmetrize_in_place(&mut ws.s);
        check_finite(ws.s.as_slice(), "innovation covariance (overflow)")?;
        let log_det = spd_inverse_log_det_into(&ws.s, &mut ws.mm, &mut ws.s_inverse)
            .ok_or(Error::InnovationNotPositiveDefinite)?;
        check_innovation_conditioning(&ws.s, &ws.s_inverse)?;
        ws.weighted.gemv(1.0, &ws.s_inverse, &ws.innovation, 0.0);
        let nis = ws.innovation.dot(&ws.weighted);
        let log_likelihood = -0.5 * (m as f64 * LN_2PI + log_det + nis);
        if !(nis.is_finite() && log_likelihood.is_finite()) {
            return Err(Error::Overflow {
                what: "normalised innovation squared",
            });
        }
        self.has_update = true;
        let gate_threshold = self.gate;
        if gate_threshold.is_some_and(|t| nis > t) {
            self.close_interval();
            return Ok(DynUpdateReport {
                accepted: false,
                nis,
                log_likelihood,
                joint_min_eigenvalue,
                gate_threshold,
            });
        }
        let ws = &mut self.ws;
        // K' = S^-1 A'; x+ = x + K nu.
        gemm(&mut ws.gain_t, 1.0, &ws.s_inverse, &ws.a_t, 0.0);
        ws.state.copy_from(&self.state);
        ws.state.gemv_tr(1.0, &ws.gain_t, &ws.innovation, 1.0);
        // P+ = P + K (S K' - A') - A K' (Joseph-like, expanded; module docs).
        ws.residual.copy_from(&ws.a_t);
        gemm(&mut ws.residual, 1.0, &ws.s, &ws.gain_t, -1.0);
        ws.nn_next.copy_from(&self.covariance);
        ws.gain_t.transpose_to(&mut ws.gain);
        ws.a_t.transpose_to(&mut ws.a);
        // P's triangles averaged (as the static Joseph form reads P), then the two
        // terms on the upper triangle only, mirrored: exactly symmetric.
        symmetrize_in_place(&mut ws.nn_next);
        gemm_upper(&mut ws.nn_next, 1.0, &ws.gain, &ws.residual, 1.0);
        gemm_upper(&mut ws.nn_next, -1.0, &ws.a, &ws.gain_t, 1.0);
        mirror_upper(&mut ws.nn_next);
        if !(ws.state.iter().all(|v| v.is_finite()) && ws.nn_next.iter().all(|v| v.is_finite())) {
            return Err(Error::NonFinite {
                what: "posterior state or covariance (overflow)",
            });
        }
        std::mem::swap(&mut self.state, &mut ws.state);
        std::mem::swap(&mut self.covariance, &mut ws.nn_next);
        self.log_likelihood += log_likelihood;
        self.close_interval();
        Ok(DynUpdateReport {
            accepted: true,
            nis,
            log_likelihood,
            joint_min_eigenvalue,
            gate_threshold,
        })
    }

    /// After an update attempt: Q_acc and the predict count start again.
    fn close_interval(&mut self) {
        self.accumulated_noise.fill(0.0);
        self.predicts_since_update = 0;
    }
}
