//! DVL calibration against a reference trajectory: lever arm, scale factor, mounting
//! misalignment and time offset by nonlinear least squares.

use nalgebra::{DMatrix, DVector, Rotation3, SMatrix, SVector, Vector3};

use crate::error::{finite, Error, Result};
use crate::measurement::dvl_frame_velocity;

/// Number of calibration parameters: lever arm (3), scale factor (1), misalignment (3),
/// time offset (1).
pub const CALIBRATION_PARAMETERS: usize = 8;

/// One sample of a reference trajectory (e.g. a post-processed INS solution).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrajectorySample {
    /// Time \[s\].
    pub time: f64,
    /// Velocity north, east, down \[m/s\].
    pub velocity_ned: Vector3<f64>,
    /// Roll, pitch, yaw \[rad\]: C_b^n = Rz(yaw) Ry(pitch) Rx(roll).
    pub roll_pitch_yaw: Vector3<f64>,
}

/// One DVL velocity (DVL frame) with its time stamp.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DvlMeasurement {
    /// Time stamp \[s\], on the trajectory's clock.
    pub time: f64,
    /// Velocity reported by the DVL \[m/s\].
    pub velocity: Vector3<f64>,
}

/// A parameter estimate with its standard error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// The estimate.
    pub value: f64,
    /// Its standard error (0 for a parameter held fixed).
    pub standard_error: f64,
}

/// Result of [`Calibrator::calibrate`].
///
/// Model of a DVL sample stamped t (see [`dvl_frame_velocity`]):
///
/// ```text
/// y(t) = (1 + k) Rot(mu)^T ( v_b(t - tau) + omega_b(t - tau) x l )
/// ```
///
/// where v_b = C_n^b v^n and omega_b come from the reference trajectory; a positive
/// time offset tau means the DVL stamps lag the motion they measured.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    /// Lever arm l (IMU / reference point -> DVL, body frame) \[m\].
    pub lever_arm: [Estimate; 3],
    /// DVL scale-factor error k.
    pub scale_factor_error: Estimate,
    /// Mounting misalignment mu (rotation vector DVL -> body) \[rad\].
    pub mounting_misalignment: [Estimate; 3],
    /// Time offset tau \[s\].
    pub time_offset: Estimate,
    /// Covariance of the 8 parameters (order: l, k, mu, tau; rows of fixed ones zero).
    pub covariance: SMatrix<f64, CALIBRATION_PARAMETERS, CALIBRATION_PARAMETERS>,
    /// RMS of the residuals per DVL axis at the estimate \[m/s\].
    pub residual_rms: Vector3<f64>,
    /// RMS of the residuals per axis with every parameter zero \[m/s\].
    pub residual_rms_uncalibrated: Vector3<f64>,
    /// Lag-1 autocorrelation of the residuals per axis: near 0 when they are white, as
    /// the standard errors assume; well above 0 means the standard errors are optimistic.
    pub residual_lag1_autocorrelation: Vector3<f64>,
    /// DVL samples used.
    pub samples: usize,
    /// Levenberg-Marquardt iterations of the final fit.
    pub iterations: usize,
}

impl Calibration {
    /// The lever-arm estimate as a vector \[m\].
    pub fn lever_arm_vector(&self) -> Vector3<f64> {
        Vector3::from_fn(|i, _| self.lever_arm[i].value)
    }

    /// The mounting-misalignment estimate as a vector \[rad\].
    pub fn mounting_misalignment_vector(&self) -> Vector3<f64> {
        Vector3::from_fn(|i, _| self.mounting_misalignment[i].value)
    }

    /// The parameters as a vector (l, k, mu, tau).
    pub fn parameters(&self) -> SVector<f64, CALIBRATION_PARAMETERS> {
        let mut p = SVector::zeros();
        for i in 0..3 {
            p[i] = self.lever_arm[i].value;
            p[4 + i] = self.mounting_misalignment[i].value;
        }
        p[3] = self.scale_factor_error.value;
        p[7] = self.time_offset.value;
        p
    }
}

/// Calibration settings; build with [`Calibrator::builder`].
#[derive(Debug, Clone, PartialEq)]
pub struct Calibrator {
    max_time_offset: f64,
    estimate_time_offset: bool,
    time_offset_grid_step: f64,
    max_iterations: usize,
    weight_axes: bool,
}

/// Builder of a [`Calibrator`]; `build()` validates.
#[must_use]
#[derive(Debug, Clone)]
pub struct CalibratorBuilder {
    max_time_offset: f64,
    estimate_time_offset: bool,
    time_offset_grid_step: f64,
    max_iterations: usize,
    weight_axes: bool,
}

impl Default for CalibratorBuilder {
    fn default() -> Self {
        Self {
            max_time_offset: 3.0,
            estimate_time_offset: true,
            time_offset_grid_step: 0.25,
            max_iterations: 100,
            weight_axes: true,
        }
    }
}

impl CalibratorBuilder {
    /// Largest |time offset| searched \[s\] (default 3). DVL samples closer than this to
    /// either end of the trajectory are not used.
    pub fn max_time_offset(mut self, seconds: f64) -> Self {
        self.max_time_offset = seconds;
        self
    }

    /// Estimate the time offset (default true); if false it is held at zero.
    pub fn estimate_time_offset(mut self, yes: bool) -> Self {
        self.estimate_time_offset = yes;
        self
    }

    /// Spacing of the initial grid search over the time offset \[s\] (default 0.25).
    pub fn time_offset_grid_step(mut self, seconds: f64) -> Self {
        self.time_offset_grid_step = seconds;
        self
    }

    /// Iteration limit of each Levenberg-Marquardt fit (default 100).
    pub fn max_iterations(mut self, n: usize) -> Self {
        self.max_iterations = n;
        self
    }

    /// Weight each DVL axis by the inverse of its residual variance from a first fit
    /// (default true; the vertical axis of a DVL is usually much quieter).
    pub fn weight_axes(mut self, yes: bool) -> Self {
        self.weight_axes = yes;
        self
    }

    /// Validate: positive, finite offsets and steps, at least one iteration.
    pub fn build(self) -> Result<Calibrator> {
        let m = finite("max_time_offset", self.max_time_offset)?;
        let s = finite("time_offset_grid_step", self.time_offset_grid_step)?;
        if m <= 0.0 {
            return Err(Error::InvalidParameter {
                name: "max_time_offset",
                reason: format!("{m} s is not positive"),
            });
        }
        if s <= 0.0 || s > m {
            return Err(Error::InvalidParameter {
                name: "time_offset_grid_step",
                reason: format!("{s} s is not in (0, max_time_offset]"),
            });
        }
        if self.max_iterations == 0 {
            return Err(Error::InvalidParameter {
                name: "max_iterations",
                reason: "must be at least 1".into(),
            });
        }
        Ok(Calibrator {
            max_time_offset: m,
            estimate_time_offset: self.estimate_time_offset,
            time_offset_grid_step: s,
            max_iterations: self.max_iterations,
            weight_axes: self.weight_axes,
        })
    }
}

/// Body velocity and angular rate of the reference trajectory, interpolated in time.
struct Reference {
    time: Vec<f64>,
    body_velocity: Vec<Vector3<f64>>,
    angular_rate: Vec<Vector3<f64>>,
}

impl Reference {
    fn new(trajectory: &[TrajectorySample]) -> Result<Self> {
        let n = trajectory.len();
        if n < 5 {
            return Err(Error::InvalidData {
                what: "trajectory",
                reason: format!("{n} samples, at least 5 needed"),
            });
        }
        for (i, s) in trajectory.iter().enumerate() {
            let ok = s.time.is_finite()
                && s.velocity_ned.iter().all(|x| x.is_finite())
                && s.roll_pitch_yaw.iter().all(|x| x.is_finite());
            if !ok {
                return Err(Error::InvalidData {
                    what: "trajectory",
                    reason: format!("sample {i} holds a non-finite value"),
                });
            }
            if i > 0 && s.time <= trajectory[i - 1].time {
                return Err(Error::InvalidData {
                    what: "trajectory",
                    reason: format!("time does not increase at sample {i}"),
                });
            }
        }
        let rot: Vec<Rotation3<f64>> = trajectory
            .iter()
            .map(|s| {
                let [r, p, y] = [s.roll_pitch_yaw.x, s.roll_pitch_yaw.y, s.roll_pitch_yaw.z];
                Rotation3::from_euler_angles(r, p, y)
            })
            .collect();
        let time: Vec<f64> = trajectory.iter().map(|s| s.time).collect();
        let body_velocity = trajectory
            .iter()
            .zip(&rot)
            .map(|(s, c)| c.inverse() * s.velocity_ned)
            .collect();
        let angular_rate = (0..n).map(|i| body_rate(&rot, &time, i)).collect();
        Ok(Self {
            time,
            body_velocity,
            angular_rate,
        })
    }

    /// (v_b, omega_b) at time t by cubic Hermite interpolation with Catmull-Rom tangents.
    fn at(&self, t: f64) -> (Vector3<f64>, Vector3<f64>) {
        let n = self.time.len();
        let i = match self.time.partition_point(|&x| x <= t) {
            0 => 0,
            k if k >= n => n - 2,
            k => k - 1,
        };
        let (t0, t1) = (self.time[i], self.time[i + 1]);
        let h = t1 - t0;
        let s = (t - t0) / h;
        let tangent = |y: &[Vector3<f64>], j: usize| -> Vector3<f64> {
            let (a, b) = (j.saturating_sub(1), (j + 1).min(n - 1));
            (y[b] - y[a]) / (self.time[b] - self.time[a])
        };
        let (s2, s3) = (s * s, s * s * s);
        let h00 = 2.0 * s3 - 3.0 * s2 + 1.0;
        let h10 = s3 - 2.0 * s2 + s;
        let h01 = -2.0 * s3 + 3.0 * s2;
        let h11 = s3 - s2;
        let interp = |y: &[Vector3<f64>]| {
            y[i] * h00 + tangent(y, i) * (h10 * h) + y[i + 1] * h01 + tangent(y, i + 1) * (h11 * h)
        };
        (interp(&self.body_velocity), interp(&self.angular_rate))
    }
}

/// Body angular rate omega_nb^b at sample i from the attitude sequence: derivative at 0
/// of r(s) = log(C_i' C(t_i + s)); five-point central difference where the spacing is
/// uniform, three-point otherwise, one-sided at the ends.
fn body_rate(rot: &[Rotation3<f64>], time: &[f64], i: usize) -> Vector3<f64> {
    let n = rot.len();
    let rel = |j: usize| (rot[i].inverse() * rot[j]).scaled_axis();
    if i == 0 {
        return rel(1) / (time[1] - time[0]);
    }
    if i == n - 1 {
        return -rel(n - 2) / (time[n - 1] - time[n - 2]);
    }
    if i >= 2 && i + 2 < n {
        let h = time[i + 1] - time[i];
        let uniform = [
            time[i] - time[i - 1],
            time[i - 1] - time[i - 2],
            time[i + 2] - time[i + 1],
        ]
        .iter()
        .all(|d| (d - h).abs() <= 1e-6 * h);
        if uniform {
            return ((rel(i + 1) - rel(i - 1)) * 8.0 - (rel(i + 2) - rel(i - 2))) / (12.0 * h);
        }
    }
    (rel(i + 1) - rel(i - 1)) / (time[i + 1] - time[i - 1])
}

type Params = SVector<f64, CALIBRATION_PARAMETERS>;

struct Problem<'a> {
    reference: Reference,
    dvl: Vec<&'a DvlMeasurement>,
    weights: Vector3<f64>,
}

impl Problem<'_> {
    fn residuals(&self, p: &Params) -> DVector<f64> {
        let lever = Vector3::new(p[0], p[1], p[2]);
        let mu = Vector3::new(p[4], p[5], p[6]);
        let mut r = DVector::zeros(3 * self.dvl.len());
        for (j, m) in self.dvl.iter().enumerate() {
            let (vb, w) = self.reference.at(m.time - p[7]);
            let y = dvl_frame_velocity(&vb, &w, &lever, p[3], &mu);
            for a in 0..3 {
                r[3 * j + a] = (m.velocity[a] - y[a]) * self.weights[a];
            }
        }
        r
    }

    /// Jacobian of the residuals over the free parameters (central differences).
    fn jacobian(&self, p: &Params, free: &[usize]) -> DMatrix<f64> {
        let mut jac = DMatrix::zeros(3 * self.dvl.len(), free.len());
        for (c, &k) in free.iter().enumerate() {
            let step = if k == 7 { 1e-5 } else { 1e-6 };
            let mut plus = *p;
            let mut minus = *p;
            plus[k] += step;
            minus[k] -= step;
            let d = (self.residuals(&plus) - self.residuals(&minus)) / (2.0 * step);
            jac.set_column(c, &d);
        }
        jac
    }

    /// Levenberg-Marquardt over the free parameters; returns (p, iterations).
    fn fit(
        &self,
        start: &Params,
        free: &[usize],
        max_iterations: usize,
        max_time_offset: f64,
    ) -> Result<(Params, usize)> {
        let mut p = *start;
        let mut cost = self.residuals(&p).norm_squared();
        let mut lambda = 1e-6;
        let mut iterations = 0;
        while iterations < max_iterations {
            iterations += 1;
            let jac = self.jacobian(&p, free);
            let r = self.residuals(&p);
            let normal = jac.transpose() * &jac;
            let gradient = jac.transpose() * r;
            let mut improved = false;
            let mut converged = false;
            for _ in 0..20 {
                let mut damped = normal.clone();
                for d in 0..free.len() {
                    damped[(d, d)] += lambda * normal[(d, d)].max(1e-12);
                }
                let Some(chol) = damped.cholesky() else {
                    lambda *= 10.0;
                    continue;
                };
                let step = -chol.solve(&gradient);
                let mut trial = p;
                for (c, &k) in free.iter().enumerate() {
                    trial[k] += step[c];
                }
                if trial[7].abs() > max_time_offset {
                    lambda *= 10.0;
                    continue;
                }
                let trial_cost = self.residuals(&trial).norm_squared();
                if trial_cost <= cost {
                    converged = cost - trial_cost <= 1e-12 * cost.max(f64::MIN_POSITIVE)
                        || step.amax() < 1e-12;
                    p = trial;
                    cost = trial_cost;
                    lambda = (lambda * 0.1).max(1e-12);
                    improved = true;
                    break;
                }
                lambda *= 10.0;
            }
            if !improved || converged {
                break;
            }
        }
        Ok((p, iterations))
    }
}

impl Calibrator {
    /// A builder with the defaults (time offset estimated within +-3 s, axis weighting).
    pub fn builder() -> CalibratorBuilder {
        CalibratorBuilder::default()
    }

    /// Estimate lever arm, scale factor, misalignment and (optionally) time offset.
    ///
    /// Method: the time offset is first located on a grid (Levenberg-Marquardt over the
    /// other parameters at each grid point), then all parameters are refined together by
    /// Levenberg-Marquardt with central-difference Jacobians. With axis weighting the fit
    /// is repeated with each axis weighted by the inverse of its residual variance.
    /// Standard errors: sqrt(diag(s^2 (J'J)^-1)), s^2 = RSS / (3n - p) of the weighted
    /// residuals (Seber & Wild, *Nonlinear Regression*, 1989, sec. 2.1). They assume white
    /// residuals; see [`Calibration::residual_lag1_autocorrelation`].
    ///
    /// Errors: a trajectory or log with non-finite values, non-increasing time, too few
    /// samples inside the trajectory's span less the time-offset margin, or singular
    /// normal equations (a parameter the motion does not excite at all).
    pub fn calibrate(
        &self,
        trajectory: &[TrajectorySample],
        dvl: &[DvlMeasurement],
    ) -> Result<Calibration> {
        let reference = Reference::new(trajectory)?;
        check_dvl_log(dvl)?;
        let margin = if self.estimate_time_offset {
            self.max_time_offset
        } else {
            0.0
        };
        let (first, last) = (reference.time[0], reference.time[reference.time.len() - 1]);
        let used: Vec<&DvlMeasurement> = dvl
            .iter()
            .filter(|m| m.time - margin >= first && m.time + margin <= last)
            .collect();
        let free: Vec<usize> = if self.estimate_time_offset {
            (0..8).collect()
        } else {
            (0..7).collect()
        };
        let needed = 2 * free.len();
        if used.len() < needed {
            return Err(Error::InvalidData {
                what: "DVL log",
                reason: format!(
                    "{} samples within the trajectory span (less a {margin} s margin), at least {needed} needed",
                    used.len()
                ),
            });
        }
        let mut problem = Problem {
            reference,
            dvl: used,
            weights: Vector3::repeat(1.0),
        };
        let zero = Params::zeros();
        let uncalibrated = axis_rms(&problem.residuals(&zero));

        let start = if self.estimate_time_offset {
            self.time_offset_grid_start(&problem)?
        } else {
            zero
        };
        let (mut p, mut iterations) =
            problem.fit(&start, &free, self.max_iterations, self.max_time_offset)?;
        if self.weight_axes {
            let rms = axis_rms(&problem.residuals(&p));
            if rms.iter().all(|x| *x > 0.0) {
                problem.weights = rms.map(|x| 1.0 / x);
                (p, iterations) =
                    problem.fit(&p, &free, self.max_iterations, self.max_time_offset)?;
            }
        }

        let r = problem.residuals(&p);
        let jac = problem.jacobian(&p, &free);
        let dof = r.len() - free.len();
        let s2 = r.norm_squared() / dof as f64;
        let normal = jac.transpose() * &jac;
        let inverse = normal
            .cholesky()
            .map(|c| c.inverse())
            .ok_or_else(|| Error::Numerical {
                what: "calibration",
                reason: "normal equations are singular: the motion does not excite every parameter"
                    .into(),
            })?;
        let mut covariance = SMatrix::<f64, 8, 8>::zeros();
        for (a, &ka) in free.iter().enumerate() {
            for (b, &kb) in free.iter().enumerate() {
                covariance[(ka, kb)] = s2 * inverse[(a, b)];
            }
        }
        let est = |k: usize| Estimate {
            value: p[k],
            standard_error: covariance[(k, k)].max(0.0).sqrt(),
        };
        let unweighted: DVector<f64> = DVector::from_iterator(
            r.len(),
            r.iter()
                .enumerate()
                .map(|(i, x)| x / problem.weights[i % 3]),
        );
        Ok(Calibration {
            lever_arm: [est(0), est(1), est(2)],
            scale_factor_error: est(3),
            mounting_misalignment: [est(4), est(5), est(6)],
            time_offset: est(7),
            covariance,
            residual_rms: axis_rms(&unweighted),
            residual_rms_uncalibrated: uncalibrated,
            residual_lag1_autocorrelation: lag1(&unweighted),
            samples: problem.dvl.len(),
            iterations,
        })
    }
}

impl Calibrator {
    /// The start of the joint fit: the time offset located on a grid, the other
    /// parameters fitted (10 iterations) at each grid point; the lowest cost wins.
    fn time_offset_grid_start(&self, problem: &Problem<'_>) -> Result<Params> {
        let zero = Params::zeros();
        let mut start = zero;
        let others: Vec<usize> = (0..7).collect();
        let steps = (self.max_time_offset / self.time_offset_grid_step).floor() as i64;
        let mut best = f64::INFINITY;
        for s in -steps..=steps {
            let mut p = zero;
            p[7] = s as f64 * self.time_offset_grid_step;
            let (p, _) = problem.fit(&p, &others, 10, self.max_time_offset)?;
            let cost = problem.residuals(&p).norm_squared();
            if cost < best {
                best = cost;
                start = p;
            }
        }
        Ok(start)
    }
}

/// A DVL log's values are finite and its times increase.
fn check_dvl_log(dvl: &[DvlMeasurement]) -> Result<()> {
    for (i, m) in dvl.iter().enumerate() {
        if !(m.time.is_finite() && m.velocity.iter().all(|x| x.is_finite())) {
            return Err(Error::InvalidData {
                what: "DVL log",
                reason: format!("sample {i} holds a non-finite value"),
            });
        }
        if i > 0 && m.time <= dvl[i - 1].time {
            return Err(Error::InvalidData {
                what: "DVL log",
                reason: format!("time does not increase at sample {i}"),
            });
        }
    }
    Ok(())
}

fn axis_rms(r: &DVector<f64>) -> Vector3<f64> {
    let n = (r.len() / 3).max(1) as f64;
    Vector3::from_fn(|a, _| (r.iter().skip(a).step_by(3).map(|x| x * x).sum::<f64>() / n).sqrt())
}

fn lag1(r: &DVector<f64>) -> Vector3<f64> {
    Vector3::from_fn(|a, _| {
        let x: Vec<f64> = r.iter().skip(a).step_by(3).copied().collect();
        let mean = x.iter().sum::<f64>() / x.len().max(1) as f64;
        let var: f64 = x.iter().map(|v| (v - mean).powi(2)).sum();
        let cov: f64 = x.windows(2).map(|w| (w[0] - mean) * (w[1] - mean)).sum();
        if var > 0.0 {
            cov / var
        } else {
            0.0
        }
    })
}
