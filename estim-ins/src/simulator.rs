//! IMU simulation: from a time-stamped trajectory to specific force and angular rate
//! (inverse mechanization), and a seeded IMU error model.

use nalgebra::{UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::earth::{
    earth_rate_ned, gravity_ned, radii_of_curvature, radii_of_curvature_derivative,
    transport_rate_ned,
};
use crate::error::{Error, Result};
use crate::imu_spec::ImuSpec;
use crate::mechanization::ImuSample;
use crate::InsState;

/// One time-stamped trajectory sample (e.g. a row of A-KIT ground truth).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrajectorySample {
    /// Time \[s\].
    pub time: f64,
    /// Geodetic latitude \[rad\].
    pub latitude: f64,
    /// Geodetic longitude \[rad\].
    pub longitude: f64,
    /// Height above the ellipsoid \[m\] (negative under water).
    pub height: f64,
    /// Velocity NED \[m/s\].
    pub velocity_ned: Vector3<f64>,
    /// Attitude C_b^n.
    pub attitude: UnitQuaternion<f64>,
}

/// Kinematics of a [`Trajectory`] at one instant, with the error-free IMU outputs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kinematics {
    /// Position, velocity, attitude; zero biases; `angular_rate` = ω_ib^b.
    pub state: InsState,
    /// v̇^n \[m/s^2\].
    pub acceleration_ned: Vector3<f64>,
    /// Error-free specific force f^b \[m/s^2\].
    pub specific_force: Vector3<f64>,
    /// Error-free angular rate ω_ib^b \[rad/s\].
    pub angular_rate: Vector3<f64>,
}

/// Natural cubic spline through (t_i, y_i).
#[derive(Debug, Clone, PartialEq)]
struct CubicSpline {
    values: Vec<f64>,
    second: Vec<f64>,
}

impl CubicSpline {
    /// Natural end conditions; tridiagonal (Thomas) solve for the second derivatives.
    fn new(times: &[f64], values: Vec<f64>) -> Self {
        let n = values.len();
        let mut second = vec![0.0; n];
        if n > 2 {
            let mut diag = vec![0.0; n];
            let mut rhs = vec![0.0; n];
            let mut upper = vec![0.0; n];
            for i in 1..n - 1 {
                let h0 = times[i] - times[i - 1];
                let h1 = times[i + 1] - times[i];
                let lower = h0 / 6.0;
                diag[i] = (h0 + h1) / 3.0;
                upper[i] = h1 / 6.0;
                rhs[i] = (values[i + 1] - values[i]) / h1 - (values[i] - values[i - 1]) / h0;
                if i > 1 {
                    let m = lower / diag[i - 1];
                    diag[i] -= m * upper[i - 1];
                    rhs[i] -= m * rhs[i - 1];
                }
            }
            for i in (1..n - 1).rev() {
                second[i] = (rhs[i] - upper[i] * second[i + 1]) / diag[i];
            }
        }
        Self { values, second }
    }

    /// Value, first and second derivative on interval `i` at `t`.
    fn eval(&self, times: &[f64], i: usize, t: f64) -> (f64, f64, f64) {
        let h = times[i + 1] - times[i];
        let a = (times[i + 1] - t) / h;
        let b = (t - times[i]) / h;
        let (y0, y1, m0, m1) = (
            self.values[i],
            self.values[i + 1],
            self.second[i],
            self.second[i + 1],
        );
        let value = a * y0 + b * y1 + ((a * a * a - a) * m0 + (b * b * b - b) * m1) * h * h / 6.0;
        let first = (y1 - y0) / h + ((1.0 - 3.0 * a * a) * m0 + (3.0 * b * b - 1.0) * m1) * h / 6.0;
        let second = a * m0 + b * m1;
        (value, first, second)
    }
}

/// A smooth trajectory through time-stamped samples (the interpolation of [`Trajectory`]).
///
/// # Interpolation
///
/// - Position: on each interval a cubic Hermite polynomial in (latitude, longitude,
///   height) whose end values are the samples and whose end derivatives are the sampled
///   velocities mapped by L̇ = v_N/(R_N+h), λ̇ = v_E/((R_E+h) cos L), ḣ = -v_D. The
///   curve passes through every sample's position *and* velocity; velocity is continuous
///   and acceleration piecewise linear.
/// - Attitude: a natural cubic spline (C²) of roll, pitch and unwrapped yaw (ZYX
///   Euler angles of C_b^n); ω_nb^b follows from the Euler rates (Groves eq. 2.58
///   inverse). Fine for vehicles away from ±90° pitch (AUVs).
///
/// # Inverse mechanization (Groves eqs. 5.46, 5.53 solved for the IMU outputs)
///
/// f^b = C_n^b \[v̇^n + (2 ω_ie^n + ω_en^n) × v^n - g^n\],  ω_ib^b = ω_nb^b + C_n^b (ω_ie^n + ω_en^n).
///
/// An [`ImuSample`] is the mean of these over its interval (3-point Gauss-Legendre on
/// each piece between sample times, so the acceleration kinks are integrated exactly),
/// which is what the [`Mechanization`](crate::Mechanization) expects.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    times: Vec<f64>,
    samples: Vec<TrajectorySample>,
    /// (lat, lon, h) at each sample used by the position Hermite curve (the samples'
    /// own positions, or those integrated from the velocity spline).
    positions: Vec<Vector3<f64>>,
    /// d(lat, lon, h)/dt at each sample.
    position_rates: Vec<Vector3<f64>>,
    euler: [CubicSpline; 3],
    /// Natural cubic splines of v_N, v_E, v_D for [`Trajectory::velocity_driven`].
    velocity_splines: Option<[CubicSpline; 3]>,
}

impl Trajectory {
    /// Build from at least two samples with strictly increasing times and finite values;
    /// the position curve passes through every sample's position and velocity (cubic
    /// Hermite, acceleration piecewise linear).
    ///
    /// # Errors
    /// [`Error::Trajectory`] naming the offending sample index.
    pub fn new(samples: Vec<TrajectorySample>) -> Result<Self> {
        Self::build(samples, false)
    }

    /// Like [`Trajectory::new`], but velocity is a natural cubic spline (C², smooth
    /// acceleration) through the sampled velocities and position its integral from the
    /// first sample (RK4, 16 steps per interval). Use it when the samples' positions and
    /// velocities disagree (post-processed ground truth such as A-KIT: 6.6 cm per 1 s step
    /// RMS on trajectory 4), which would otherwise show up as spurious accelerations; the
    /// positions then drift from the sampled ones by the data's own inconsistency.
    ///
    /// # Errors
    /// As [`Trajectory::new`].
    pub fn velocity_driven(samples: Vec<TrajectorySample>) -> Result<Self> {
        Self::build(samples, true)
    }

    fn build(samples: Vec<TrajectorySample>, velocity_driven: bool) -> Result<Self> {
        if samples.len() < 2 {
            return Err(Error::Trajectory {
                reason: format!("{} samples, at least 2 needed", samples.len()),
            });
        }
        for (i, s) in samples.iter().enumerate() {
            let finite = [s.time, s.latitude, s.longitude, s.height]
                .iter()
                .chain(s.velocity_ned.iter())
                .chain(s.attitude.coords.iter())
                .all(|x| x.is_finite());
            if !finite {
                return Err(Error::Trajectory {
                    reason: format!("sample {i} holds a non-finite value"),
                });
            }
            if s.latitude.abs() >= 1.5 {
                return Err(Error::Trajectory {
                    reason: format!("sample {i}: latitude {} too close to a pole", s.latitude),
                });
            }
            if i > 0 && s.time <= samples[i - 1].time {
                return Err(Error::Trajectory {
                    reason: format!("sample {i}: time {} does not increase", s.time),
                });
            }
        }
        let times: Vec<f64> = samples.iter().map(|s| s.time).collect();
        let velocity_splines = velocity_driven.then(|| {
            let component = |k: usize| samples.iter().map(|s| s.velocity_ned[k]).collect();
            [
                CubicSpline::new(&times, component(0)),
                CubicSpline::new(&times, component(1)),
                CubicSpline::new(&times, component(2)),
            ]
        });
        let position_rate = |p: &Vector3<f64>, v: &Vector3<f64>| {
            let (rn, re) = radii_of_curvature(p.x);
            Vector3::new(v.x / (rn + p.z), v.y / ((re + p.z) * p.x.cos()), -v.z)
        };
        let positions: Vec<Vector3<f64>> = match &velocity_splines {
            None => samples
                .iter()
                .map(|s| Vector3::new(s.latitude, s.longitude, s.height))
                .collect(),
            Some(splines) => {
                let velocity_at =
                    |i: usize, t: f64| Vector3::from_fn(|k, _| splines[k].eval(&times, i, t).0);
                let first = &samples[0];
                let mut p = Vector3::new(first.latitude, first.longitude, first.height);
                let mut out = vec![p];
                for i in 0..times.len() - 1 {
                    const STEPS: usize = 16;
                    let h = (times[i + 1] - times[i]) / STEPS as f64;
                    for j in 0..STEPS {
                        let t = times[i] + j as f64 * h;
                        let k1 = position_rate(&p, &velocity_at(i, t));
                        let k2 = position_rate(&(p + k1 * (0.5 * h)), &velocity_at(i, t + 0.5 * h));
                        let k3 = position_rate(&(p + k2 * (0.5 * h)), &velocity_at(i, t + 0.5 * h));
                        let k4 = position_rate(&(p + k3 * h), &velocity_at(i, t + h));
                        p += (k1 + 2.0 * k2 + 2.0 * k3 + k4) * (h / 6.0);
                    }
                    out.push(p);
                }
                out
            }
        };
        let position_rates = positions
            .iter()
            .zip(&samples)
            .map(|(p, s)| position_rate(p, &s.velocity_ned))
            .collect();
        let mut roll = Vec::with_capacity(samples.len());
        let mut pitch = Vec::with_capacity(samples.len());
        let mut yaw: Vec<f64> = Vec::with_capacity(samples.len());
        for s in &samples {
            let (r, p, y) = s.attitude.euler_angles();
            roll.push(r);
            pitch.push(p);
            let y = match yaw.last() {
                // Unwrap: pick the 2π multiple nearest the previous yaw.
                Some(prev) => {
                    prev + (y - prev + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                        - std::f64::consts::PI
                }
                None => y,
            };
            yaw.push(y);
        }
        let euler = [
            CubicSpline::new(&times, roll),
            CubicSpline::new(&times, pitch),
            CubicSpline::new(&times, yaw),
        ];
        Ok(Self {
            times,
            samples,
            positions,
            position_rates,
            euler,
            velocity_splines,
        })
    }

    /// Time of the first sample \[s\].
    #[must_use]
    pub fn start_time(&self) -> f64 {
        self.times[0]
    }

    /// Time of the last sample \[s\].
    #[must_use]
    pub fn end_time(&self) -> f64 {
        self.times[self.times.len() - 1]
    }

    /// The samples the trajectory was built from.
    #[must_use]
    pub fn samples(&self) -> &[TrajectorySample] {
        &self.samples
    }

    fn interval(&self, t: f64) -> usize {
        let i = self.times.partition_point(|&x| x <= t);
        i.clamp(1, self.times.len() - 1) - 1
    }

    /// Kinematics and error-free IMU outputs at time `t`.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] if `t` is outside \[start, end\] (or not finite).
    pub fn evaluate(&self, t: f64) -> Result<Kinematics> {
        if !(t >= self.start_time() && t <= self.end_time()) {
            return Err(Error::InvalidParameter {
                name: "time",
                reason: format!(
                    "{t} outside the trajectory [{}, {}]",
                    self.start_time(),
                    self.end_time()
                ),
            });
        }
        Ok(self.evaluate_in(self.interval(t), t))
    }

    fn evaluate_in(&self, i: usize, t: f64) -> Kinematics {
        let (t0, t1) = (self.times[i], self.times[i + 1]);
        let h = t1 - t0;
        let s = (t - t0) / h;
        let (p0, p1) = (self.positions[i], self.positions[i + 1]);
        let (m0, m1) = (self.position_rates[i] * h, self.position_rates[i + 1] * h);
        // Cubic Hermite basis and its derivatives with respect to s.
        let (s2, s3) = (s * s, s * s * s);
        let pos = p0 * (2.0 * s3 - 3.0 * s2 + 1.0)
            + m0 * (s3 - 2.0 * s2 + s)
            + p1 * (-2.0 * s3 + 3.0 * s2)
            + m1 * (s3 - s2);
        let rate = (p0 * (6.0 * s2 - 6.0 * s)
            + m0 * (3.0 * s2 - 4.0 * s + 1.0)
            + p1 * (-6.0 * s2 + 6.0 * s)
            + m1 * (3.0 * s2 - 2.0 * s))
            / h;
        let accel = (p0 * (12.0 * s - 6.0)
            + m0 * (6.0 * s - 4.0)
            + p1 * (-12.0 * s + 6.0)
            + m1 * (6.0 * s - 2.0))
            / (h * h);
        let (lat, height) = (pos.x, pos.z);
        let (rn0, re0) = radii_of_curvature(lat);
        let (drn, dre) = radii_of_curvature_derivative(lat);
        let (rn, re) = (rn0 + height, re0 + height);
        let (sl, cl) = lat.sin_cos();
        let (velocity, acceleration) = match &self.velocity_splines {
            Some(splines) => {
                let v = splines.each_ref().map(|c| c.eval(&self.times, i, t));
                (
                    Vector3::new(v[0].0, v[1].0, v[2].0),
                    Vector3::new(v[0].1, v[1].1, v[2].1),
                )
            }
            None => (
                Vector3::new(rn * rate.x, re * cl * rate.y, -rate.z),
                // d/dt of the velocity line above.
                Vector3::new(
                    (drn * rate.x + rate.z) * rate.x + rn * accel.x,
                    (dre * rate.x + rate.z) * cl * rate.y - re * sl * rate.x * rate.y
                        + re * cl * accel.y,
                    -accel.z,
                ),
            ),
        };
        let (roll, droll, _) = self.euler[0].eval(&self.times, i, t);
        let (pitch, dpitch, _) = self.euler[1].eval(&self.times, i, t);
        let (yaw, dyaw, _) = self.euler[2].eval(&self.times, i, t);
        let attitude = UnitQuaternion::from_euler_angles(roll, pitch, yaw);
        let (sr, cr) = roll.sin_cos();
        let (sp, cp) = pitch.sin_cos();
        let body_rate_nb = Vector3::new(
            droll - dyaw * sp,
            dpitch * cr + dyaw * sr * cp,
            -dpitch * sr + dyaw * cr * cp,
        );
        let w_ie = earth_rate_ned(lat);
        let w_en = transport_rate_ned(lat, height, &velocity);
        let c_nb = attitude.inverse();
        let specific_force =
            c_nb * (acceleration + (2.0 * w_ie + w_en).cross(&velocity) - gravity_ned(lat, height));
        let angular_rate = body_rate_nb + c_nb * (w_ie + w_en);
        let mut state = InsState::new(t, lat, pos.y, height, velocity, attitude);
        state.angular_rate = angular_rate;
        Kinematics {
            state,
            acceleration_ned: acceleration,
            specific_force,
            angular_rate,
        }
    }

    /// The error-free IMU sample over \[t, t + dt\]: mean specific force and angular rate.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] if the interval leaves the trajectory or dt <= 0.
    pub fn imu_sample(&self, t: f64, dt: f64) -> Result<ImuSample> {
        if !(dt.is_finite() && dt > 0.0) {
            return Err(Error::InvalidParameter {
                name: "dt",
                reason: format!("must be finite and > 0, got {dt}"),
            });
        }
        self.evaluate(t)?;
        self.evaluate(t + dt)?;
        Ok(self.imu_sample_in(t, dt))
    }

    /// [`Trajectory::imu_sample`] without the range checks, for a caller whose interval
    /// is inside the trajectory up to rounding (e.g. between two of its sample times).
    pub(crate) fn mean_outputs(&self, t: f64, dt: f64) -> ImuSample {
        self.imu_sample_in(t, dt)
    }

    fn imu_sample_in(&self, t: f64, dt: f64) -> ImuSample {
        // 3-point Gauss-Legendre nodes and weights on [0, 1].
        const NODES: [f64; 3] = [0.112_701_665_379_258_3, 0.5, 0.887_298_334_620_741_7];
        const WEIGHTS: [f64; 3] = [5.0 / 18.0, 8.0 / 18.0, 5.0 / 18.0];
        let end = t + dt;
        let mut force = Vector3::zeros();
        let mut rate = Vector3::zeros();
        let mut a = t;
        let mut i = self.interval(t);
        while a < end {
            let b = end.min(self.times[i + 1]).max(a);
            let len = b - a;
            if len > 0.0 {
                for (x, w) in NODES.iter().zip(WEIGHTS) {
                    let k = self.evaluate_in(i, a + x * len);
                    force += k.specific_force * (w * len);
                    rate += k.angular_rate * (w * len);
                }
            }
            if b >= end || i + 2 >= self.times.len() {
                break;
            }
            a = b;
            i += 1;
        }
        ImuSample::new(t, force / dt, rate / dt)
    }

    /// Error-free simulation at `rate_hz`: the truth states at t_k = start + k/rate
    /// (k = 0..=N, t_N <= end) and the N IMU samples between them.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] if the rate is not > 0 or yields no full step.
    pub fn simulate(&self, rate_hz: f64) -> Result<(Vec<InsState>, Vec<ImuSample>)> {
        crate::error::positive("rate_hz", rate_hz)?;
        let dt = 1.0 / rate_hz;
        let span = self.end_time() - self.start_time();
        // Guard against t_N landing a rounding error past the end.
        let steps = ((span / dt) * (1.0 - 1e-12)).floor() as usize;
        if steps == 0 {
            return Err(Error::InvalidParameter {
                name: "rate_hz",
                reason: format!("{rate_hz} Hz gives no full step over {span} s"),
            });
        }
        let t0 = self.start_time();
        let mut truth = Vec::with_capacity(steps + 1);
        let mut imu = Vec::with_capacity(steps);
        for k in 0..=steps {
            let t = t0 + k as f64 * dt;
            truth.push(self.evaluate_in(self.interval(t), t).state);
            if k < steps {
                imu.push(self.imu_sample_in(t, dt));
            }
        }
        Ok((truth, imu))
    }
}

/// Seeded IMU error generator: measured = (1 + scale) ∘ true + turn-on bias +
/// Gauss-Markov drift + white noise, per axis (the [`InsState`] bias convention plus an
/// unmodelled scale factor).
///
/// White noise per sample has σ = density / √dt; the drift follows the exact discrete
/// first-order Gauss-Markov process b_{k+1} = e^{-dt/τ} b_k + σ √(1 - e^{-2dt/τ}) n_k,
/// started from its steady state.
#[derive(Debug, Clone)]
pub struct ImuErrorGenerator {
    spec: ImuSpec,
    rng: ChaCha8Rng,
    acc_turn_on: Vector3<f64>,
    gyro_turn_on: Vector3<f64>,
    acc_scale: Vector3<f64>,
    gyro_scale: Vector3<f64>,
    acc_drift: Vector3<f64>,
    gyro_drift: Vector3<f64>,
}

impl ImuErrorGenerator {
    /// Draw the constant errors (turn-on biases, scale factors, initial drift) from `seed`.
    #[must_use]
    pub fn new(spec: ImuSpec, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut draw = |sigma: f64| {
            Vector3::new(
                sigma * normal(&mut rng),
                sigma * normal(&mut rng),
                sigma * normal(&mut rng),
            )
        };
        let (a, g) = (*spec.accelerometer(), *spec.gyroscope());
        let acc_turn_on = draw(a.turn_on_bias);
        let gyro_turn_on = draw(g.turn_on_bias);
        let acc_scale = draw(a.scale_factor);
        let gyro_scale = draw(g.scale_factor);
        let acc_drift = draw(a.bias_instability);
        let gyro_drift = draw(g.bias_instability);
        Self {
            spec,
            rng,
            acc_turn_on,
            gyro_turn_on,
            acc_scale,
            gyro_scale,
            acc_drift,
            gyro_drift,
        }
    }

    /// Current total accelerometer bias (turn-on + drift) \[m/s^2\].
    #[must_use]
    pub fn acc_bias(&self) -> Vector3<f64> {
        self.acc_turn_on + self.acc_drift
    }

    /// Current total gyroscope bias (turn-on + drift) \[rad/s\].
    #[must_use]
    pub fn gyro_bias(&self) -> Vector3<f64> {
        self.gyro_turn_on + self.gyro_drift
    }

    /// Scale-factor errors (accelerometer, gyroscope), dimensionless.
    #[must_use]
    pub fn scale_factors(&self) -> (Vector3<f64>, Vector3<f64>) {
        (self.acc_scale, self.gyro_scale)
    }

    /// Corrupt one error-free sample covering `dt` seconds, then advance the drift by dt.
    #[must_use]
    pub fn corrupt(&mut self, clean: &ImuSample, dt: f64) -> ImuSample {
        let (a, g) = (*self.spec.accelerometer(), *self.spec.gyroscope());
        let root_dt = dt.sqrt();
        let white_a = self.triad(a.white_noise_density / root_dt);
        let white_g = self.triad(g.white_noise_density / root_dt);
        let out = ImuSample::new(
            clean.time,
            clean.specific_force
                + clean.specific_force.component_mul(&self.acc_scale)
                + self.acc_bias()
                + white_a,
            clean.angular_rate
                + clean.angular_rate.component_mul(&self.gyro_scale)
                + self.gyro_bias()
                + white_g,
        );
        let decay_a = (-dt / a.bias_time_constant).exp();
        let decay_g = (-dt / g.bias_time_constant).exp();
        let drive_a = self.triad(a.bias_instability * (1.0 - decay_a * decay_a).sqrt());
        let drive_g = self.triad(g.bias_instability * (1.0 - decay_g * decay_g).sqrt());
        self.acc_drift = self.acc_drift * decay_a + drive_a;
        self.gyro_drift = self.gyro_drift * decay_g + drive_g;
        out
    }

    fn triad(&mut self, sigma: f64) -> Vector3<f64> {
        Vector3::new(
            sigma * normal(&mut self.rng),
            sigma * normal(&mut self.rng),
            sigma * normal(&mut self.rng),
        )
    }
}

fn normal(rng: &mut ChaCha8Rng) -> f64 {
    StandardNormal.sample(rng)
}
