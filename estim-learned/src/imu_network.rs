//! Cross-covariance M for any learned velocity sensor fed with an IMU window plus other,
//! IMU-independent inputs (beams, a last valid DVL velocity, a time since it, ...).
//!
//! Same first-order derivation as [`NetworkSensitivity`](crate::NetworkSensitivity)
//! (see `sensitivity.rs`): the IMU white noise n_i of window sample i enters the INS
//! error state at the update as Γ_i n_i, Γ_i = Φ(t_k, t_{i+1}) G_i dt, and the network
//! output as J_i n_i, so M = Σ_i Γ_i Σ J_i'. Here the model is any
//! [`OnnxMeasurement<3>`] whose first two inputs are the accelerometer and gyroscope
//! windows (3 x n each) and whose further inputs are given as they are (zero direction:
//! their errors are independent of the IMU noise).
//!
//! Kept apart from `sensitivity.rs` so that the generalisation of `NetworkSensitivity`
//! (estim issue 16) can absorb it.

use estim_ins::{ImuSample, InsErrorModel, InsState, Mechanization, ERROR_STATES};
use nalgebra::{DMatrix, SMatrix, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::measurement::OnnxMeasurement;
use crate::sensitivity::{error_state, per_sample_variances};
use crate::{CrossMatrix, EmpiricalEstimate, Error, Result};

/// An IMU window and the other inputs of one update of an IMU-fed network.
#[derive(Debug, Clone, PartialEq)]
pub struct ImuNetworkWindow {
    /// Nominal INS state at the start of each IMU sample (same length as `imu`).
    pub states: Vec<InsState>,
    /// The IMU samples fed to the network (measured), oldest first.
    pub imu: Vec<ImuSample>,
    /// The network's inputs after acc and gyro, raw units, in the metadata's order.
    pub others: Vec<DMatrix<f64>>,
    /// IMU period [s].
    pub dt: f64,
}

impl ImuNetworkWindow {
    fn check(&self, model: &OnnxMeasurement<3>) -> Result<()> {
        if self.imu.is_empty() || self.states.len() != self.imu.len() {
            return Err(Error::InvalidInput {
                what: "IMU window",
                reason: format!(
                    "{} states for {} IMU samples (need equal, non-zero)",
                    self.states.len(),
                    self.imu.len()
                ),
            });
        }
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return Err(Error::InvalidInput {
                what: "IMU window",
                reason: format!("dt = {} must be positive", self.dt),
            });
        }
        let inputs = &model.metadata().inputs;
        let ok = inputs.len() == 2 + self.others.len()
            && inputs[..2]
                .iter()
                .all(|i| i.channels == 3 && i.window == self.imu.len());
        if !ok {
            return Err(Error::InputMismatch {
                expected: format!(
                    "acc and gyro windows of {} samples then {} other inputs",
                    self.imu.len(),
                    inputs.len().saturating_sub(2)
                ),
                given: format!(
                    "model inputs {:?}, {} other inputs",
                    inputs
                        .iter()
                        .map(|i| (i.name.as_str(), i.channels, i.window))
                        .collect::<Vec<_>>(),
                    self.others.len()
                ),
            });
        }
        Ok(())
    }

    /// The model inputs, with `noise` (acc, gyro per sample) added to the IMU.
    pub fn inputs_with(&self, noise: Option<&[(Vector3<f64>, Vector3<f64>)]>) -> Vec<DMatrix<f64>> {
        let n = self.imu.len();
        let extra = |i: usize| noise.map_or((Vector3::zeros(), Vector3::zeros()), |v| v[i]);
        let acc = DMatrix::from_fn(3, n, |r, c| self.imu[c].specific_force[r] + extra(c).0[r]);
        let gyro = DMatrix::from_fn(3, n, |r, c| self.imu[c].angular_rate[r] + extra(c).1[r]);
        let mut out = Vec::with_capacity(2 + self.others.len());
        out.push(acc);
        out.push(gyro);
        out.extend(self.others.iter().cloned());
        out
    }
}

/// M from the network's own sensitivity, for any IMU-window network (module docs).
#[derive(Debug, Clone)]
pub struct ImuNetworkSensitivity {
    model: OnnxMeasurement<3>,
    error_model: InsErrorModel,
}

impl ImuNetworkSensitivity {
    /// For a model and the INS error model whose IMU noise it sees.
    pub fn new(model: OnnxMeasurement<3>, error_model: InsErrorModel) -> Self {
        Self { model, error_model }
    }

    /// M = Σ_i Γ_i Σ J_i' for `window`: one batched inference of 1 + (rows of Γ that
    /// are not zero) elements.
    pub fn compute(&self, window: &ImuNetworkWindow) -> Result<CrossMatrix> {
        Ok(self.compute_with_window_noise(window)?.0)
    }

    /// M and the covariance of the INS error that the window's IMU white noise alone
    /// drives, Q_w = Σ_i Γ_i Σ Γ_i' (15 x 15): with R, the correlation between the
    /// network's output error and that IMU-driven error is M_ij / sqrt(Q_w,ii R_jj).
    pub fn compute_with_window_noise(
        &self,
        window: &ImuNetworkWindow,
    ) -> Result<(CrossMatrix, SMatrix<f64, ERROR_STATES, ERROR_STATES>)> {
        window.check(&self.model)?;
        let mut q_w = SMatrix::<f64, ERROR_STATES, ERROR_STATES>::zeros();
        let n = window.imu.len();
        let dt = window.dt;
        let (var_a, var_g) = per_sample_variances(&self.error_model, dt);
        let mut transport = SMatrix::<f64, ERROR_STATES, ERROR_STATES>::identity();
        let mut acc_dirs = vec![DMatrix::<f64>::zeros(3, n); ERROR_STATES];
        let mut gyro_dirs = vec![DMatrix::<f64>::zeros(3, n); ERROR_STATES];
        for i in (0..n).rev() {
            let g = self.error_model.noise_input(&window.states[i]);
            let b = transport * g.fixed_columns::<6>(0) * dt;
            for r in 0..ERROR_STATES {
                for k in 0..3 {
                    acc_dirs[r][(k, i)] = b[(r, k)] * var_a;
                    gyro_dirs[r][(k, i)] = b[(r, 3 + k)] * var_g;
                }
            }
            let sigma = nalgebra::SMatrix::<f64, 6, 6>::from_diagonal(
                &nalgebra::SVector::<f64, 6>::from_column_slice(&[
                    var_a, var_a, var_a, var_g, var_g, var_g,
                ]),
            );
            q_w += b * sigma * b.transpose();
            let (phi, _) =
                self.error_model
                    .transition_and_noise(&window.states[i], &window.imu[i], dt);
            transport *= phi;
        }
        let rows: Vec<usize> = (0..ERROR_STATES)
            .filter(|&r| acc_dirs[r].amax() > 0.0 || gyro_dirs[r].amax() > 0.0)
            .collect();
        let directions: Vec<Vec<DMatrix<f64>>> = rows
            .iter()
            .map(|&r| {
                let mut d = vec![acc_dirs[r].clone(), gyro_dirs[r].clone()];
                d.extend(
                    window
                        .others
                        .iter()
                        .map(|o| DMatrix::zeros(o.nrows(), o.ncols())),
                );
                d
            })
            .collect();
        let jvp = self
            .model
            .jacobian_vector_products(&window.inputs_with(None), &directions)?;
        let mut m = CrossMatrix::zeros();
        for (&r, v) in rows.iter().zip(jvp) {
            m.set_row(r, &v.transpose());
        }
        Ok((m, q_w))
    }
}

/// M by Monte Carlo for any IMU-window network: seeded IMU white-noise realizations
/// added to the window, the nominal INS re-integrated with them and the network re-run;
/// M = sample Cov(δx_k, y).
#[derive(Debug, Clone)]
pub struct ImuNetworkEmpirical {
    model: OnnxMeasurement<3>,
    error_model: InsErrorModel,
    realizations: usize,
    seed: u64,
}

impl ImuNetworkEmpirical {
    /// `realizations` (>= 2) noise draws from `seed`.
    pub fn new(
        model: OnnxMeasurement<3>,
        error_model: InsErrorModel,
        realizations: usize,
        seed: u64,
    ) -> Self {
        Self {
            model,
            error_model,
            realizations,
            seed,
        }
    }

    /// Run the Monte Carlo for `window` (its IMU is taken as noise-free).
    pub fn estimate(&self, window: &ImuNetworkWindow) -> Result<EmpiricalEstimate> {
        window.check(&self.model)?;
        if self.realizations < 2 {
            return Err(Error::InvalidInput {
                what: "realizations",
                reason: format!("{} < 2", self.realizations),
            });
        }
        let dt = window.dt;
        let (var_a, var_g) = per_sample_variances(&self.error_model, dt);
        let (sa, sg) = (var_a.sqrt(), var_g.sqrt());
        let mech = Mechanization::new();
        let start = InsState {
            acc_bias: Vector3::zeros(),
            gyro_bias: Vector3::zeros(),
            ..window.states[0]
        };
        let integrate = |noise: Option<&[(Vector3<f64>, Vector3<f64>)]>| {
            let mut s = start;
            for (i, imu) in window.imu.iter().enumerate() {
                let mut m = *imu;
                if let Some(n) = noise {
                    m.specific_force += n[i].0;
                    m.angular_rate += n[i].1;
                }
                s = mech.step_unchecked(&s, &m, dt);
            }
            s
        };
        let reference = integrate(None);
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        let mut normal = || -> f64 { StandardNormal.sample(&mut rng) };
        let mut errors = Vec::with_capacity(self.realizations);
        let mut batch = Vec::with_capacity(self.realizations);
        for _ in 0..self.realizations {
            let noise: Vec<(Vector3<f64>, Vector3<f64>)> = (0..window.imu.len())
                .map(|_| {
                    let a = Vector3::new(normal(), normal(), normal()) * sa;
                    let g = Vector3::new(normal(), normal(), normal()) * sg;
                    (a, g)
                })
                .collect();
            errors.push(error_state(&reference, &integrate(Some(&noise))));
            batch.push(window.inputs_with(Some(&noise)));
        }
        let outputs = self.model.measure_batch(&batch)?;
        let n = self.realizations as f64;
        let mean_x = errors
            .iter()
            .fold(SMatrix::<f64, ERROR_STATES, 1>::zeros(), |a, e| a + e)
            / n;
        let mean_y = outputs.iter().fold(Vector3::zeros(), |a, y| a + y) / n;
        let mut sum = CrossMatrix::zeros();
        let mut sum_sq = CrossMatrix::zeros();
        for (x, y) in errors.iter().zip(&outputs) {
            let p = (x - mean_x) * (y - mean_y).transpose();
            sum += p;
            sum_sq += p.component_mul(&p);
        }
        let m = sum / (n - 1.0);
        let var = (sum_sq / n - (sum / n).component_mul(&(sum / n))).map(|v| v.max(0.0));
        Ok(EmpiricalEstimate {
            cross_covariance: m,
            standard_error: (var / n).map(f64::sqrt),
        })
    }
}
