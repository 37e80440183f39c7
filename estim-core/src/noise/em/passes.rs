//! The passes of [`super::em`] and their checks: the forward (Kalman) pass, the RTS
//! smoother with lag-one covariances, the M step, and the input checks.

use super::*;

/// The forward pass: predicted and filtered moments of every epoch.
pub(super) struct Forward {
    pub(super) predicted_means: Vec<DVector<f64>>,
    pub(super) predicted_covariances: Vec<DMatrix<f64>>,
    pub(super) filtered_means: Vec<DVector<f64>>,
    pub(super) filtered_covariances: Vec<DMatrix<f64>>,
    pub(super) log_likelihood: f64,
}

/// The smoothed moments: x_{t|T}, P_{t|T} (t = 0 .. T-1) and
/// V_{t+1,t} = Cov(x_{t+1}, x_t | all) (t = 0 .. T-2).
pub(super) struct Smoothed {
    pub(super) means: Vec<DVector<f64>>,
    pub(super) covariances: Vec<DMatrix<f64>>,
    pub(super) lag_one: Vec<DMatrix<f64>>,
}

/// The Kalman filter in pykalman's order of operations (module docs).
pub(super) fn filter(
    model: &LinearGaussianModel,
    measurements: &[Option<DVector<f64>>],
) -> Result<Forward> {
    let steps = measurements.len();
    let f = &model.transition_matrix;
    let h = &model.observation_matrix;
    let m = model.observation_dimension();
    let log_2pi = (2.0 * std::f64::consts::PI).ln();
    let mut forward = Forward {
        predicted_means: Vec::with_capacity(steps),
        predicted_covariances: Vec::with_capacity(steps),
        filtered_means: Vec::with_capacity(steps),
        filtered_covariances: Vec::with_capacity(steps),
        log_likelihood: 0.0,
    };
    for (t, measurement) in measurements.iter().enumerate() {
        let (mean, covariance) = match (
            forward.filtered_means.last(),
            forward.filtered_covariances.last(),
        ) {
            (Some(x), Some(p)) => (
                f * x + model.transition_offsets.at(t - 1),
                f * (p * f.transpose()) + &model.transition_covariance,
            ),
            _ => (
                model.initial_state_mean.clone(),
                model.initial_state_covariance.clone(),
            ),
        };
        let (filtered_mean, filtered_covariance) = match measurement {
            Some(y) => {
                // pykalman's association: S = H (P H') + R, K = (P H') S^-1, and
                // P+ = P - K (H P). With K built from P H' (not from H P), the update
                // shrinks a round-off asymmetry of P instead of carrying it whole
                // into the next predict (where F's growth would amplify it).
                let p_ht = &covariance * h.transpose();
                let s = h * &p_ht + &model.observation_covariance;
                check_finite(s.as_slice(), "innovation covariance")?;
                let chol = s.cholesky().ok_or(Error::InnovationNotPositiveDefinite)?;
                let innovation = y - (h * &mean + &model.observation_offset);
                // K' = S^-1 (P H')' (S symmetric: nalgebra's Cholesky reads its lower
                // triangle).
                let gain = chol.solve(&p_ht.transpose()).transpose();
                let h_p = h * &covariance;
                let whitened = chol
                    .l()
                    .solve_lower_triangular(&innovation)
                    .ok_or(Error::InnovationNotPositiveDefinite)?;
                let log_det = 2.0 * chol.l().diagonal().iter().map(|v| v.ln()).sum::<f64>();
                forward.log_likelihood -=
                    0.5 * (m as f64 * log_2pi + log_det + whitened.norm_squared());
                (&mean + &gain * innovation, &covariance - gain * h_p)
            }
            None => (mean.clone(), covariance.clone()),
        };
        check_finite(filtered_mean.as_slice(), "filtered state mean (overflow)")?;
        check_finite(
            filtered_covariance.as_slice(),
            "filtered state covariance (overflow)",
        )?;
        forward.predicted_means.push(mean);
        forward.predicted_covariances.push(covariance);
        forward.filtered_means.push(filtered_mean);
        forward.filtered_covariances.push(filtered_covariance);
    }
    if !forward.log_likelihood.is_finite() {
        return Err(Error::NonFinite {
            what: "log-likelihood",
        });
    }
    Ok(forward)
}

/// The RTS smoother with the lag-one covariances (module docs).
pub(super) fn smooth(model: &LinearGaussianModel, forward: &Forward) -> Result<Smoothed> {
    let steps = forward.filtered_means.len();
    let f_t = model.transition_matrix.transpose();
    let mut means = forward.filtered_means.clone();
    let mut covariances = forward.filtered_covariances.clone();
    let mut lag_one = vec![DMatrix::zeros(0, 0); steps.saturating_sub(1)];
    for t in (0..steps.saturating_sub(1)).rev() {
        let predicted_inverse = pseudo_inverse(
            &forward.predicted_covariances[t + 1],
            "predicted state covariance",
        )?;
        let gain = &forward.filtered_covariances[t] * (&f_t * predicted_inverse);
        check_finite(gain.as_slice(), "smoother gain (overflow)")?;
        means[t] =
            &forward.filtered_means[t] + &gain * (&means[t + 1] - &forward.predicted_means[t + 1]);
        covariances[t] = &forward.filtered_covariances[t]
            + &gain
                * ((&covariances[t + 1] - &forward.predicted_covariances[t + 1])
                    * gain.transpose());
        lag_one[t] = &covariances[t + 1] * gain.transpose();
    }
    Ok(Smoothed {
        means,
        covariances,
        lag_one,
    })
}

/// The M-step for `vars` (module docs), in pykalman's order H, R, F, Q, mu_0,
/// Sigma_0, b, d, each from the same E-step and the parameters already updated;
/// the others are kept.
pub(super) fn maximise(
    model: &LinearGaussianModel,
    measurements: &[Option<DVector<f64>>],
    smoothed: &Smoothed,
    vars: EmVariables,
) -> Result<LinearGaussianModel> {
    let mut next = model.clone();
    let (n, m) = (model.state_dimension(), model.observation_dimension());
    // The old offsets: H and R use the old d, F and Q the old b (pykalman's `_em`).
    let (b, d) = (&model.transition_offsets, &model.observation_offset);
    let second_moment =
        |t: usize| &smoothed.covariances[t] + &smoothed.means[t] * smoothed.means[t].transpose();
    if vars.contains(EmVariables::OBSERVATION_MATRIX) {
        let (mut cross, mut moment) = (DMatrix::zeros(m, n), DMatrix::zeros(n, n));
        for (t, y) in measurements.iter().enumerate() {
            if let Some(y) = y {
                cross += (y - d) * smoothed.means[t].transpose();
                moment += second_moment(t);
            }
        }
        next.observation_matrix =
            regress(&cross, &moment, "observation matrix M-step sums (overflow)")?;
    }
    if vars.contains(EmVariables::OBSERVATION_COVARIANCE) {
        let h = &next.observation_matrix;
        let (mut sum, mut count) = (DMatrix::zeros(m, m), 0usize);
        for (t, y) in measurements.iter().enumerate() {
            if let Some(y) = y {
                let error = y - h * &smoothed.means[t] - d;
                sum += &error * error.transpose() + h * (&smoothed.covariances[t] * h.transpose());
                count += 1;
            }
        }
        next.observation_covariance = symmetric_part(sum / count as f64);
    }
    if vars.contains(EmVariables::TRANSITION_MATRIX) {
        let (mut cross, mut moment) = (DMatrix::zeros(n, n), DMatrix::zeros(n, n));
        for t in 0..smoothed.lag_one.len() {
            let previous = smoothed.means[t].transpose();
            cross +=
                &smoothed.lag_one[t] + &smoothed.means[t + 1] * &previous - b.at(t) * &previous;
            moment += second_moment(t);
        }
        next.transition_matrix =
            regress(&cross, &moment, "transition matrix M-step sums (overflow)")?;
    }
    if vars.contains(EmVariables::TRANSITION_COVARIANCE) {
        let f = &next.transition_matrix;
        let mut sum = DMatrix::zeros(n, n);
        for t in 0..smoothed.lag_one.len() {
            let error = &smoothed.means[t + 1] - f * &smoothed.means[t] - b.at(t);
            let lag_f = &smoothed.lag_one[t] * f.transpose();
            sum += &error * error.transpose()
                + f * (&smoothed.covariances[t] * f.transpose())
                + &smoothed.covariances[t + 1]
                - &lag_f
                - lag_f.transpose();
        }
        next.transition_covariance = symmetric_part(sum / smoothed.lag_one.len() as f64);
    }
    if vars.contains(EmVariables::INITIAL_STATE_MEAN) {
        next.initial_state_mean = smoothed.means[0].clone();
    }
    if vars.contains(EmVariables::INITIAL_STATE_COVARIANCE) {
        let offset = &smoothed.means[0] - &next.initial_state_mean;
        next.initial_state_covariance =
            symmetric_part(&smoothed.covariances[0] + &offset * offset.transpose());
    }
    if vars.contains(EmVariables::TRANSITION_OFFSETS) {
        let f = &next.transition_matrix;
        let mut sum = DVector::zeros(n);
        for t in 0..smoothed.lag_one.len() {
            sum += &smoothed.means[t + 1] - f * &smoothed.means[t];
        }
        next.transition_offsets = TransitionOffsets::Constant(sum / smoothed.lag_one.len() as f64);
    }
    if vars.contains(EmVariables::OBSERVATION_OFFSET) {
        let h = &next.observation_matrix;
        let (mut sum, mut count) = (DVector::zeros(m), 0usize);
        for (t, y) in measurements.iter().enumerate() {
            if let Some(y) = y {
                sum += y - h * &smoothed.means[t];
                count += 1;
            }
        }
        next.observation_offset = sum / count as f64;
    }
    fitted(next.validate()).map(|()| next)
}

/// The least-squares M-step of a matrix, cross moment^+ (pykalman's
/// `np.dot(res1, linalg.pinv(res2))`); `what` names the sums in an error.
pub(super) fn regress(
    cross: &DMatrix<f64>,
    moment: &DMatrix<f64>,
    what: &'static str,
) -> Result<DMatrix<f64>> {
    check_finite(cross.as_slice(), what)?;
    check_finite(moment.as_slice(), what)?;
    Ok(cross * pseudo_inverse(moment, what)?)
}

/// Names a fitted covariance's failure as such.
pub(super) fn fitted(result: Result<()>) -> Result<()> {
    result.map_err(|error| match error {
        Error::InvalidCovariance { what, reason } => Error::InvalidCovariance {
            what,
            reason: format!("fitted by EM: {reason}"),
        },
        other => other,
    })
}

/// (A + A') / 2.
pub(super) fn symmetric_part(a: DMatrix<f64>) -> DMatrix<f64> {
    (&a + a.transpose()) * 0.5
}

/// The Moore-Penrose pseudo-inverse through the SVD, singular values at or below
/// n eps sigma_max dropped (scipy.linalg.pinv's default cutoff, as pykalman);
/// `what` names the matrix in the error.
pub(super) fn pseudo_inverse(a: &DMatrix<f64>, what: &'static str) -> Result<DMatrix<f64>> {
    let svd = a.clone().svd(true, true);
    let largest = svd.singular_values.max();
    let cutoff = a.nrows().max(a.ncols()) as f64 * f64::EPSILON * largest;
    // nalgebra keeps singular values strictly above its eps; a zero matrix has none.
    svd.pseudo_inverse(cutoff)
        .map_err(|reason| Error::InvalidCovariance {
            what,
            reason: format!("no pseudo-inverse: {reason}"),
        })
}

pub(super) fn check_size(got: usize, expected: usize, what: &'static str) -> Result<()> {
    if got == expected {
        Ok(())
    } else {
        Err(Error::Dimension {
            what,
            expected,
            got,
        })
    }
}

/// Rows then columns: [`Error::Dimension`] names the first that disagrees.
pub(super) fn check_shape(
    m: &DMatrix<f64>,
    (rows, cols): (usize, usize),
    what: &'static str,
) -> Result<()> {
    check_size(m.nrows(), rows, what)?;
    check_size(m.ncols(), cols, what)
}

/// Finite, symmetric entrywise ([`crate::gaussian::check_symmetric`]'s rule) and
/// positive semidefinite to round-off (the crate's semidefinite Cholesky).
pub(super) fn check_covariance(m: &DMatrix<f64>, what: &'static str) -> Result<()> {
    check_finite(m.as_slice(), what)?;
    let n = m.nrows();
    crate::gaussian::check_symmetric_entries(n, |i, j| m[(i, j)], what)?;
    let mut factor = Factor(DMatrix::zeros(n, n));
    if semidefinite_cholesky(n, 0, |i, k| m[(i, k)], &mut factor) {
        Ok(())
    } else {
        Err(Error::InvalidCovariance {
            what,
            reason: "not positive semidefinite (a Cholesky pivot is negative beyond round-off)"
                .into(),
        })
    }
}

/// A dynamic matrix as the semidefinite Cholesky's output.
pub(super) struct Factor(DMatrix<f64>);

impl Square<f64> for Factor {
    fn value(&self, i: usize, k: usize) -> f64 {
        self.0[(i, k)]
    }
    fn set(&mut self, i: usize, k: usize, v: f64) {
        self.0[(i, k)] = v;
    }
}

/// T >= 1, each measurement of size m and finite, per-step offsets numbering T - 1.
pub(super) fn check_measurements(
    model: &LinearGaussianModel,
    measurements: &[Option<DVector<f64>>],
) -> Result<()> {
    if measurements.is_empty() {
        return Err(Error::InvalidParameter {
            name: "measurements",
            reason: "the sequence has no epoch".into(),
        });
    }
    for y in measurements.iter().flatten() {
        check_size(y.len(), model.observation_dimension(), "measurement")?;
        check_finite(y.as_slice(), "measurement")?;
    }
    if let TransitionOffsets::PerStep(offsets) = &model.transition_offsets {
        check_size(
            offsets.len(),
            measurements.len() - 1,
            "transition offsets (one per step, T - 1)",
        )?;
    }
    Ok(())
}
