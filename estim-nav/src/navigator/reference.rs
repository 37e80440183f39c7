//! A reference (ground-truth) track against the navigator's clock: the time offset
//! that aligns the reference's attitude with the IMU's angular rate, estimated from
//! the two records themselves, for an evaluation (`--truth`).
//!
//! Method: between consecutive reference epochs t_k, t_k+1 the body rotation is
//! r_k = log(C_k' C_k+1) (C the reference's body-to-NED attitude), and the gyroscope
//! measures its integral plus the Earth rate, r_k + C_k' omega_ie^n (t_k+1 - t_k)
//! (Groves, *Principles of GNSS, Inertial, and Multisensor Integrated Navigation
//! Systems*, 2nd ed., eq. 5.34 with the transport rate neglected, below 1e-6 rad/s at
//! AUV speeds). For a candidate offset tau the IMU's integral over
//! [t_k - tau, t_k+1 - tau] is read from the cumulative sum of the body rates; the
//! offset minimizing the summed squared difference over every interval inside the
//! IMU's span is found on a 10 ms grid and refined by a parabola through the grid
//! minimum and its neighbours. Its 1-sigma is the Gauss-Newton one, sigma^2 =
//! s^2 / sum |d I_k / d tau|^2, s^2 the residual variance per component.

use estim_ins::earth::{earth_rate_ned, radii_of_curvature};
use estim_ins::{
    ErrorMatrix, ImuSample, InsState, TrajectorySample, ACC_BIAS, ATT, ERROR_STATES, GYRO_BIAS,
    POS, VEL,
};
use nalgebra::{SVector, UnitQuaternion, Vector3};
use serde::Serialize;

use super::{NavigatorError, Result};

/// Fewest reference intervals inside the IMU's span for an estimate.
pub const MIN_REFERENCE_INTERVALS: usize = 20;

/// A reference clock offset and its 1-sigma.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ReferenceOffset {
    /// tau \[s\]: a reference row stamped t (on the navigator's clock after the
    /// reference's clock scale) refers to navigator time t - tau.
    pub offset_s: f64,
    /// Its 1-sigma \[s\].
    pub sigma_s: f64,
    /// RMS of the angular-increment residual at the optimum, per component \[rad\].
    pub residual_rad: f64,
    /// Reference intervals used.
    pub intervals: usize,
}

/// Cumulative integral of the body rate at each IMU sample's time (sample k holds
/// over [t_k, t_k+1]).
struct RateIntegral<'a> {
    imu: &'a [ImuSample],
    cumulative: Vec<Vector3<f64>>,
}

impl<'a> RateIntegral<'a> {
    fn new(imu: &'a [ImuSample]) -> Self {
        let mut cumulative = Vec::with_capacity(imu.len());
        let mut sum = Vector3::zeros();
        for (k, s) in imu.iter().enumerate() {
            cumulative.push(sum);
            if let Some(next) = imu.get(k + 1) {
                sum += s.angular_rate * (next.time - s.time);
            }
        }
        Self { imu, cumulative }
    }

    /// The integral from the first sample to `t` (inside the span), and the rate at t.
    fn at(&self, t: f64) -> Option<(Vector3<f64>, Vector3<f64>)> {
        let first = self.imu.first()?.time;
        let last = self.imu.last()?.time;
        if !(t >= first && t <= last) {
            return None;
        }
        let k = self.imu.partition_point(|s| s.time <= t).saturating_sub(1);
        let s = &self.imu[k];
        Some((
            self.cumulative[k] + s.angular_rate * (t - s.time),
            s.angular_rate,
        ))
    }
}

/// The reference's time offset against an IMU in body axes on the navigator's clock,
/// searched within +-`search_s`.
///
/// # Errors
/// [`NavigatorError::Inputs`] when fewer than [`MIN_REFERENCE_INTERVALS`] reference
/// intervals fall inside the IMU's span at every candidate offset, or the records are
/// not finite.
pub fn reference_time_offset(
    imu: &[ImuSample],
    reference: &[TrajectorySample],
    search_s: f64,
) -> Result<ReferenceOffset> {
    if !(search_s.is_finite() && search_s > 0.0) {
        return Err(NavigatorError::Inputs(format!(
            "reference time-offset search of {search_s} s: not a positive span"
        )));
    }
    let integral = RateIntegral::new(imu);
    // Expected gyro integral over each reference interval.
    let expected: Vec<(f64, f64, Vector3<f64>)> = reference
        .windows(2)
        .filter_map(|w| {
            let (a, b) = (&w[0], &w[1]);
            let dt = b.time - a.time;
            let relative: UnitQuaternion<f64> = a.attitude.inverse() * b.attitude;
            let earth = a
                .attitude
                .inverse_transform_vector(&earth_rate_ned(a.latitude));
            let v = relative.scaled_axis() + earth * dt;
            (dt > 0.0 && v.iter().all(|x| x.is_finite())).then_some((a.time, b.time, v))
        })
        .collect();
    let cost = |tau: f64| -> Option<(f64, usize, f64)> {
        let mut sum = 0.0;
        let mut slope = 0.0;
        let mut n = 0;
        for (ta, tb, v) in &expected {
            let (Some((ia, wa)), Some((ib, wb))) = (integral.at(ta - tau), integral.at(tb - tau))
            else {
                continue;
            };
            sum += (ib - ia - v).norm_squared();
            slope += (wb - wa).norm_squared();
            n += 1;
        }
        (n >= MIN_REFERENCE_INTERVALS).then(|| (sum / n as f64, n, slope))
    };
    let step = 0.01;
    let count = (search_s / step).ceil() as i64;
    let grid: Vec<(f64, f64)> = (-count..=count)
        .filter_map(|i| {
            let tau = i as f64 * step;
            cost(tau).map(|(c, _, _)| (tau, c))
        })
        .collect();
    let best = grid
        .iter()
        .enumerate()
        .filter(|(_, (_, c))| c.is_finite())
        .min_by(|a, b| a.1 .1.total_cmp(&b.1 .1))
        .map(|(i, _)| i)
        .ok_or_else(|| {
            NavigatorError::Inputs(format!(
                "the reference has fewer than {MIN_REFERENCE_INTERVALS} intervals inside the \
                 IMU's span at every offset within +-{search_s} s"
            ))
        })?;
    let (mut tau, _) = grid[best];
    if best > 0 && best + 1 < grid.len() {
        let (c0, c1, c2) = (grid[best - 1].1, grid[best].1, grid[best + 1].1);
        let curvature = c0 - 2.0 * c1 + c2;
        if curvature > 0.0 {
            tau += 0.5 * step * (c0 - c2) / curvature;
        }
    }
    let (mean_square, n, slope) = cost(tau).ok_or_else(|| {
        NavigatorError::Inputs("the reference's refined offset left the IMU's span".into())
    })?;
    let variance = mean_square / 3.0;
    let sigma = if slope > 0.0 {
        (variance / slope).sqrt()
    } else {
        f64::INFINITY
    };
    Ok(ReferenceOffset {
        offset_s: tau,
        sigma_s: sigma,
        residual_rad: variance.sqrt(),
        intervals: n,
    })
}

/// The error state of `nominal` against `truth`, in the filter's convention (true =
/// nominal + error, misalignment in NED): position N, E, D \[m\], velocity \[m/s\],
/// misalignment \[rad\] (the rotation vector of C_true C_nominal'), biases.
pub fn error_state(truth: &InsState, nominal: &InsState) -> SVector<f64, ERROR_STATES> {
    let (rn, re) = radii_of_curvature(nominal.latitude);
    let mut e = SVector::<f64, ERROR_STATES>::zeros();
    e[POS] = (truth.latitude - nominal.latitude) * (rn + nominal.height);
    e[POS + 1] =
        (truth.longitude - nominal.longitude) * (re + nominal.height) * nominal.latitude.cos();
    e[POS + 2] = -(truth.height - nominal.height);
    e.fixed_rows_mut::<3>(VEL)
        .copy_from(&(truth.velocity_ned - nominal.velocity_ned));
    e.fixed_rows_mut::<3>(ATT)
        .copy_from(&(truth.attitude * nominal.attitude.inverse()).scaled_axis());
    e.fixed_rows_mut::<3>(ACC_BIAS)
        .copy_from(&(truth.acc_bias - nominal.acc_bias));
    e.fixed_rows_mut::<3>(GYRO_BIAS)
        .copy_from(&(truth.gyro_bias - nominal.gyro_bias));
    e
}

/// NEES of the first `states` entries of an error (the states that have truth), with
/// the matching block of the covariance; `None` when that block is not positive
/// definite.
pub fn nees_of_block(
    error: &SVector<f64, ERROR_STATES>,
    covariance: &ErrorMatrix,
    start: usize,
    states: usize,
) -> Option<f64> {
    let block = covariance
        .view((start, start), (states, states))
        .clone_owned();
    let e = error.rows(start, states).clone_owned();
    let chol = block.cholesky()?;
    let v = e.dot(&chol.solve(&e));
    v.is_finite().then_some(v)
}

/// One prediction of a copy of a filter's estimate over `dt` (the runners' predict:
/// the nominal propagated, P <- Phi P Phi' + Q).
pub(crate) fn predict_copy<P, const N: usize>(
    process: &P,
    nominal: &P::State,
    covariance: &nalgebra::SMatrix<f64, N, N>,
    input: &P::Input,
    dt: f64,
) -> estim_core::Result<(P::State, nalgebra::SMatrix<f64, N, N>)>
where
    P: estim_core::ProcessModel<f64, N>,
{
    let (phi, q) = process.transition_and_noise(nominal, input, dt)?;
    let next = process.propagate(nominal, input, dt)?;
    Ok((next, process.propagate_covariance(covariance, &phi, &q)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use estim_ins::Trajectory;

    /// A turning, rolling track at 1 Hz for 120 s.
    fn track() -> Vec<TrajectorySample> {
        (0..=120)
            .map(|k| {
                let t = f64::from(k);
                let yaw = 0.3 * (0.05 * t).sin() + 0.01 * t;
                let roll = 0.05 * (0.3 * t).sin();
                let pitch = 0.03 * (0.17 * t).cos();
                TrajectorySample {
                    time: t,
                    latitude: 0.57 + 1e-7 * t,
                    longitude: 0.61,
                    height: -20.0,
                    velocity_ned: Vector3::new(1.5 * yaw.cos(), 1.5 * yaw.sin(), 0.0),
                    attitude: UnitQuaternion::from_euler_angles(roll, pitch, yaw),
                }
            })
            .collect()
    }

    #[test]
    fn a_known_offset_is_found_within_its_sigma() {
        let samples = track();
        let trajectory = Trajectory::velocity_driven(samples.clone()).unwrap();
        let (_, imu) = trajectory.simulate(100.0).unwrap();
        for tau in [-1.3, -0.45, 0.0, 0.47, 2.2] {
            // The reference stamps each row tau later than the IMU's clock.
            let shifted: Vec<TrajectorySample> = samples
                .iter()
                .map(|s| TrajectorySample {
                    time: s.time + tau,
                    ..*s
                })
                .collect();
            let est = reference_time_offset(&imu, &shifted, 5.0).unwrap();
            assert!(
                (est.offset_s - tau).abs() < 0.01,
                "tau {tau}: {} +- {}",
                est.offset_s,
                est.sigma_s
            );
            assert!(est.sigma_s.is_finite() && est.sigma_s < 0.05);
            assert!(est.intervals >= MIN_REFERENCE_INTERVALS);
        }
    }

    #[test]
    fn too_short_a_reference_is_refused() {
        let samples = track();
        let trajectory = Trajectory::velocity_driven(samples.clone()).unwrap();
        let (_, imu) = trajectory.simulate(100.0).unwrap();
        let short = &samples[..10];
        assert!(matches!(
            reference_time_offset(&imu, short, 5.0),
            Err(NavigatorError::Inputs(_))
        ));
        assert!(reference_time_offset(&imu, &samples, f64::NAN).is_err());
    }

    #[test]
    fn error_state_of_a_known_displacement() {
        let truth = InsState::new(
            0.0,
            0.5,
            0.6,
            -20.0,
            Vector3::new(1.0, 2.0, 0.1),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.01),
        );
        let mut nominal = truth;
        let (rn, _) = radii_of_curvature(nominal.latitude);
        nominal.latitude -= 3.0 / (rn + nominal.height);
        nominal.height += 0.5;
        nominal.velocity_ned.x -= 0.2;
        nominal.attitude = UnitQuaternion::identity();
        let e = error_state(&truth, &nominal);
        assert!((e[POS] - 3.0).abs() < 1e-6);
        assert!((e[POS + 2] - 0.5).abs() < 1e-12);
        assert!((e[VEL] - 0.2).abs() < 1e-12);
        assert!((e[ATT + 2] - 0.01).abs() < 1e-12);
        let p = ErrorMatrix::identity() * 4.0;
        // Position block: (9 + 0 + 0.25) / 4.
        let nees = nees_of_block(&e, &p, POS, 3).unwrap();
        assert!((nees - (9.0 + 0.25) / 4.0).abs() < 1e-6, "{nees}");
    }
}
