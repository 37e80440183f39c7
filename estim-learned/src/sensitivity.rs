//! Cross-covariance M = Cov(G w_{k-1}, v_k) between the INS process noise and the
//! BeamsNet output error, derived from the network itself.
//!
//! The IMU white noise n_i of window sample i (i = 1..100, per-sample covariance
//! Σ = diag(σ_a² I3, σ_g² I3), σ² = PSD / dt) enters both
//! - the INS error state at the update time: δx_k ∋ Γ_i n_i with
//!   Γ_i = Φ(t_k, t_{i+1}) G_i dt (G_i = [-C_b^n into δv | -C_b^n into ψ], the
//!   white-noise columns of the 15-state noise input; `true = nominal + error`, the
//!   nominal mechanization integrates the *measured* IMU, hence the minus signs), and
//! - the network output: y = f(u_true + n) ≈ f(u_true) + Σ_i J_i n_i, so the
//!   measurement error v_k ∋ Σ_i J_i n_i.
//!
//! Hence M = Σ_i Γ_i Σ J_i' (first order). Row r of M is J d_r, a Jacobian-vector
//! product along d_r = the stacked rows r of Γ_i Σ; all rows in ONE batched inference
//! (finite differences), instead of the 600-column Jacobian.

use estim_core::{check_joint_covariance, CrossCovariance, CrossCovarianceContext};
use estim_ins::{
    earth::radii_of_curvature, ImuSample, InsErrorModel, InsState, Mechanization, ERROR_STATES,
};
use nalgebra::{DMatrix, Matrix3, SMatrix, Vector3, Vector4};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::beamsnet::{BeamsNet, BeamsNetInput};
use crate::{Error, Result};

/// 15 x 3 cross-covariance between the INS error state and the BeamsNet output.
pub type CrossMatrix = SMatrix<f64, ERROR_STATES, 3>;

/// The IMU window feeding one BeamsNet update, with the nominal INS states along it.
#[derive(Debug, Clone, PartialEq)]
pub struct ImuWindow {
    /// Nominal INS state at the start of each IMU sample (same length as `imu`).
    pub states: Vec<InsState>,
    /// The IMU samples fed to the network (measured), oldest first.
    pub imu: Vec<ImuSample>,
    /// The beams of the update.
    pub beams: Vector4<f64>,
    /// IMU period \[s\].
    pub dt: f64,
}

impl ImuWindow {
    fn check(&self) -> Result<()> {
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
        Ok(())
    }

    fn input_with(&self, noise: Option<&[(Vector3<f64>, Vector3<f64>)]>) -> BeamsNetInput {
        let force: Vec<Vector3<f64>> = self
            .imu
            .iter()
            .enumerate()
            .map(|(i, s)| s.specific_force + noise.map_or(Vector3::zeros(), |n| n[i].0))
            .collect();
        let rate: Vec<Vector3<f64>> = self
            .imu
            .iter()
            .enumerate()
            .map(|(i, s)| s.angular_rate + noise.map_or(Vector3::zeros(), |n| n[i].1))
            .collect();
        BeamsNetInput::from_samples(&force, &rate, self.beams)
    }
}

/// Per-sample white-noise variances (accelerometer, gyroscope) of the error model.
fn per_sample_variances(model: &InsErrorModel, dt: f64) -> (f64, f64) {
    let psd = model.noise_psd();
    (psd[0] / dt, psd[3] / dt)
}

/// M from the network's own sensitivity (first-order propagation of the IMU noise).
///
/// Set the window of the coming update with [`NetworkSensitivity::set_window`]; the
/// [`CrossCovariance`] implementation then returns M for it after checking that
/// [[Q_acc, M], [M', R]] is PSD.
#[derive(Debug, Clone)]
pub struct NetworkSensitivity {
    beamsnet: BeamsNet,
    error_model: InsErrorModel,
    window: Option<ImuWindow>,
}

impl NetworkSensitivity {
    /// For a model and the INS error model whose IMU noise it sees.
    pub fn new(beamsnet: BeamsNet, error_model: InsErrorModel) -> Self {
        Self {
            beamsnet,
            error_model,
            window: None,
        }
    }

    /// The window of the next update.
    pub fn set_window(&mut self, window: ImuWindow) -> Result<()> {
        window.check()?;
        self.window = Some(window);
        Ok(())
    }

    /// M = Σ_i Γ_i Σ J_i' for `window` (see the module docs): one batched inference of
    /// 1 + (number of nonzero rows) elements.
    pub fn compute(&self, window: &ImuWindow) -> Result<CrossMatrix> {
        window.check()?;
        let n = window.imu.len();
        let dt = window.dt;
        let (var_a, var_g) = per_sample_variances(&self.error_model, dt);
        // Backward pass: transport = Φ(t_k, t_{i+1}); B_i = transport G_i dt Σ (15 x 6).
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
            let (phi, _) =
                self.error_model
                    .transition_and_noise(&window.states[i], &window.imu[i], dt);
            transport *= phi;
        }
        let rows: Vec<usize> = (0..ERROR_STATES)
            .filter(|&r| acc_dirs[r].amax() > 0.0 || gyro_dirs[r].amax() > 0.0)
            .collect();
        let zero_beams = DMatrix::<f64>::zeros(4, 1);
        let directions: Vec<Vec<DMatrix<f64>>> = rows
            .iter()
            .map(|&r| {
                vec![
                    acc_dirs[r].clone(),
                    gyro_dirs[r].clone(),
                    zero_beams.clone(),
                ]
            })
            .collect();
        let inputs = window.input_with(None).to_inputs();
        let jvp = self
            .beamsnet
            .measurement()
            .jacobian_vector_products(&inputs, &directions)?;
        let mut m = CrossMatrix::zeros();
        for (&r, v) in rows.iter().zip(jvp) {
            m.set_row(r, &v.transpose());
        }
        Ok(m)
    }
}

impl CrossCovariance<f64, InsState, ERROR_STATES, 3> for NetworkSensitivity {
    fn cross_covariance(
        &self,
        context: &CrossCovarianceContext<'_, f64, InsState, ERROR_STATES, 3>,
    ) -> estim_core::Result<CrossMatrix> {
        let window = self.window.as_ref().ok_or_else(|| {
            estim_core::Error::Model("NetworkSensitivity: no IMU window set for this update".into())
        })?;
        let m = self.compute(window)?;
        check_joint_covariance(
            context.accumulated_process_noise,
            &m,
            context.measurement_noise,
        )?;
        Ok(m)
    }
}

/// Error state `reference - nominal` (true = nominal + error) between two INS states.
fn error_state(reference: &InsState, nominal: &InsState) -> SMatrix<f64, ERROR_STATES, 1> {
    let (rn, re) = radii_of_curvature(nominal.latitude);
    let h = nominal.height;
    let mut e = SMatrix::<f64, ERROR_STATES, 1>::zeros();
    e[0] = (reference.latitude - nominal.latitude) * (rn + h);
    e[1] = (reference.longitude - nominal.longitude) * (re + h) * nominal.latitude.cos();
    e[2] = -(reference.height - nominal.height);
    e.fixed_rows_mut::<3>(3)
        .copy_from(&(reference.velocity_ned - nominal.velocity_ned));
    // C_ref = (I + [ψ×]) C_nom  =>  [ψ×] ≈ C_ref C_nom' - I.
    let d: Matrix3<f64> = (reference.attitude * nominal.attitude.inverse())
        .to_rotation_matrix()
        .into_inner();
    e[6] = 0.5 * (d[(2, 1)] - d[(1, 2)]);
    e[7] = 0.5 * (d[(0, 2)] - d[(2, 0)]);
    e[8] = 0.5 * (d[(1, 0)] - d[(0, 1)]);
    e
}

/// M by Monte Carlo (for validation): seeded IMU white-noise realizations added to the
/// window, the nominal INS re-integrated with them (nonlinear mechanization) and the
/// network re-run on them; M = sample Cov(δx_k, y) over the realizations.
#[derive(Debug, Clone)]
pub struct Empirical {
    beamsnet: BeamsNet,
    error_model: InsErrorModel,
    realizations: usize,
    seed: u64,
    window: Option<ImuWindow>,
}

/// Monte Carlo estimate of M with its per-element standard error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EmpiricalEstimate {
    /// Sample cross-covariance.
    pub cross_covariance: CrossMatrix,
    /// Standard error of each element, sqrt(var(δx_r (y_c - ȳ_c)) / N).
    pub standard_error: CrossMatrix,
}

impl Empirical {
    /// `realizations` (>= 2) noise draws from `seed`.
    pub fn new(
        beamsnet: BeamsNet,
        error_model: InsErrorModel,
        realizations: usize,
        seed: u64,
    ) -> Self {
        Self {
            beamsnet,
            error_model,
            realizations,
            seed,
            window: None,
        }
    }

    /// The window of the next update.
    pub fn set_window(&mut self, window: ImuWindow) -> Result<()> {
        window.check()?;
        self.window = Some(window);
        Ok(())
    }

    /// Run the Monte Carlo for `window` (the window's IMU is taken as noise-free).
    pub fn estimate(&self, window: &ImuWindow) -> Result<EmpiricalEstimate> {
        window.check()?;
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
        let strip = |s: &InsState| InsState {
            acc_bias: Vector3::zeros(),
            gyro_bias: Vector3::zeros(),
            ..*s
        };
        let start = strip(&window.states[0]);
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
        let mut inputs = Vec::with_capacity(self.realizations);
        for _ in 0..self.realizations {
            let noise: Vec<(Vector3<f64>, Vector3<f64>)> = (0..window.imu.len())
                .map(|_| {
                    let a = Vector3::new(normal(), normal(), normal()) * sa;
                    let g = Vector3::new(normal(), normal(), normal()) * sg;
                    (a, g)
                })
                .collect();
            errors.push(error_state(&reference, &integrate(Some(&noise))));
            inputs.push(window.input_with(Some(&noise)));
        }
        let outputs = self.beamsnet.velocities(&inputs)?;
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

impl CrossCovariance<f64, InsState, ERROR_STATES, 3> for Empirical {
    fn cross_covariance(
        &self,
        context: &CrossCovarianceContext<'_, f64, InsState, ERROR_STATES, 3>,
    ) -> estim_core::Result<CrossMatrix> {
        let window = self.window.as_ref().ok_or_else(|| {
            estim_core::Error::Model("Empirical: no IMU window set for this update".into())
        })?;
        let m = self.estimate(window)?.cross_covariance;
        check_joint_covariance(
            context.accumulated_process_noise,
            &m,
            context.measurement_noise,
        )?;
        Ok(m)
    }
}
