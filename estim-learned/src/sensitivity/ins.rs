//! The INS/DVL instance: BeamsNet fed with the IMU samples the error-state filter
//! integrates; its M from the network's sensitivity ([`NetworkSensitivity`]) and by
//! Monte Carlo ([`Empirical`]).

use super::*;

/// 15 x 3 cross-covariance between the INS error state and the BeamsNet output.
pub type CrossMatrix = SMatrix<f64, ERROR_STATES, 3>;

/// Channels of one IMU sample as BeamsNet reads them: \[f_b; ω_b\].
pub const IMU_CHANNELS: usize = 6;

/// The IMU white noise n = \[n_a; n_g\] of one sample (per-sample variance PSD / dt)
/// enters the 15-state error as G\[:, 0..6\] dt n (G = [`InsErrorModel::noise_input`]:
/// -C_b^n into δv and ψ, `true = nominal + error`, the nominal integrates the
/// measured IMU).
impl InputNoise<f64, ERROR_STATES, IMU_CHANNELS> for InsErrorModel {
    fn input_channels(&self, input: &ImuSample) -> SVector<f64, IMU_CHANNELS> {
        let mut v = SVector::<f64, IMU_CHANNELS>::zeros();
        v.fixed_rows_mut::<3>(0).copy_from(&input.specific_force);
        v.fixed_rows_mut::<3>(3).copy_from(&input.angular_rate);
        v
    }

    fn input_noise_jacobian(
        &self,
        state: &InsState,
        _input: &ImuSample,
        dt: f64,
    ) -> SMatrix<f64, ERROR_STATES, IMU_CHANNELS> {
        self.noise_input(state).fixed_columns::<IMU_CHANNELS>(0) * dt
    }

    fn input_noise_covariance(&self, dt: f64) -> SMatrix<f64, IMU_CHANNELS, IMU_CHANNELS> {
        let psd = self.noise_psd();
        SMatrix::<f64, IMU_CHANNELS, IMU_CHANNELS>::from_diagonal(
            &psd.fixed_rows::<IMU_CHANNELS>(0).map(|p| p / dt),
        )
    }
}

fn beams_input(beams: &Vector4<f64>) -> [DMatrix<f64>; 1] {
    [DMatrix::from_column_slice(4, 1, beams.as_slice())]
}

/// M from BeamsNet's own sensitivity: [`LearnedCrossCovariance`] applied to BeamsNet
/// and the INS error model, over the last [`crate::BEAMSNET_WINDOW`] IMU samples the
/// filter integrated (the runner's recorded window: no Phi recomputed here). Build one
/// for the first update and keep it, setting each update's beams with
/// [`NetworkSensitivity::set_beams`] (its workspace is then reused), or build one per
/// update.
///
/// Use it with `ErrorStateKalmanFilter::update_windowed` on a filter configured with
/// `FilterConfig::builder().window_capacity(BEAMSNET_WINDOW)`.
#[derive(Debug, Clone)]
pub struct NetworkSensitivity<'a> {
    generic: LearnedCrossCovariance<'a, f64, OnnxMeasurement<3>, InsErrorModel, 3, IMU_CHANNELS>,
}

impl<'a> NetworkSensitivity<'a> {
    /// For this update's `beams`, the network and the INS error model whose IMU noise
    /// it sees.
    ///
    /// # Errors
    /// Never for a loaded [`BeamsNet`] (its input layout is checked at load).
    pub fn new(
        beamsnet: &'a BeamsNet,
        error_model: &'a InsErrorModel,
        beams: Vector4<f64>,
    ) -> estim_core::Result<Self> {
        Ok(Self {
            generic: LearnedCrossCovariance::new(
                beamsnet.measurement(),
                error_model,
                &beams_input(&beams),
            )?,
        })
    }

    /// Set the beams of the next update (allocates nothing).
    ///
    /// # Errors
    /// Never for a loaded [`BeamsNet`] (its beams stream is 4 x 1).
    pub fn set_beams(&mut self, beams: &Vector4<f64>) -> estim_core::Result<()> {
        self.generic.set_update_input(0, beams.as_slice())
    }

    /// The generic piece underneath.
    pub fn generic(
        &self,
    ) -> &LearnedCrossCovariance<'a, f64, OnnxMeasurement<3>, InsErrorModel, 3, IMU_CHANNELS> {
        &self.generic
    }

    /// The network's velocity on the window (the IMU samples the filter integrated).
    ///
    /// # Errors
    /// A window of the wrong length, the model's errors.
    pub fn measure(
        &self,
        window: &StepWindow<'_, f64, InsState, ImuSample, ERROR_STATES>,
    ) -> estim_core::Result<Vector3<f64>> {
        self.generic.measure(window)
    }
}

impl WindowedCrossCovariance<f64, InsState, ImuSample, ERROR_STATES, 3> for NetworkSensitivity<'_> {
    fn window_steps(&self) -> usize {
        crate::BEAMSNET_WINDOW
    }

    fn step_cross_covariances(
        &self,
        window: &StepWindow<'_, f64, InsState, ImuSample, ERROR_STATES>,
        sink: &mut dyn FnMut(&CrossMatrix) -> estim_core::Result<()>,
    ) -> estim_core::Result<()> {
        self.generic.step_cross_covariances(window, sink)
    }

    fn transported_cross_covariance(
        &self,
        window: &StepWindow<'_, f64, InsState, ImuSample, ERROR_STATES>,
    ) -> estim_core::Result<Option<CrossMatrix>> {
        self.generic.transported_cross_covariance(window)
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

/// M by Monte Carlo (for validation), over the runner's recorded window: seeded IMU
/// white-noise realizations added to the window's samples, the nominal INS
/// re-integrated from the window's first state with them (nonlinear mechanization)
/// and the network re-run on them; M = sample Cov(δx_k, y). Build one per update
/// (it borrows the network and error model; nothing is kept between updates).
///
/// For a network that is not linear at the noise scale this is not the first-order M:
/// by Stein's lemma Cov(n, y(x + n)) = Σ E_n[J(x + n)], the Jacobian averaged over the
/// noise, where [`LearnedCrossCovariance`] takes J at the window's samples (measured
/// on the two-beams network: `estim-learned/tests/two_beams.rs`).
///
/// Any 3-output [`OnnxMeasurement`] laid out as [`LearnedCrossCovariance`] expects
/// (leading streams \[f_b; ω_b\] over the window, then per-update inputs) works:
/// [`Empirical::new`] for BeamsNet, [`Empirical::for_model`] for the others (e.g. the
/// two-beams network).
///
/// As a [`WindowedCrossCovariance`]: the transported M is the full nonlinear Monte
/// Carlo; the per-step D_j (used only when other updates lie inside the window) are
/// sample Cov(A_j n_j, y) with A_j the linear noise input of
/// [`InputNoise::input_noise_jacobian`].
#[derive(Debug, Clone)]
pub struct Empirical<'a> {
    model: &'a OnnxMeasurement<3>,
    error_model: &'a InsErrorModel,
    extra: Vec<DMatrix<f64>>,
    realizations: usize,
    seed: u64,
}

/// Monte Carlo estimate of M with its per-element standard error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EmpiricalEstimate {
    /// Sample cross-covariance.
    pub cross_covariance: CrossMatrix,
    /// Standard error of each element, sqrt(var(δx_r (y_c - ȳ_c)) / N).
    pub standard_error: CrossMatrix,
}

/// The draws of one Monte Carlo run.
struct Draws {
    noise: Vec<Vec<SVector<f64, IMU_CHANNELS>>>,
    errors: Vec<SMatrix<f64, ERROR_STATES, 1>>,
    outputs: Vec<Vector3<f64>>,
}

impl<'a> Empirical<'a> {
    /// `realizations` (>= 2) noise draws from `seed`, for this update's `beams`.
    pub fn new(
        beamsnet: &'a BeamsNet,
        error_model: &'a InsErrorModel,
        beams: Vector4<f64>,
        realizations: usize,
        seed: u64,
    ) -> Self {
        Self::for_model(
            beamsnet.measurement(),
            error_model,
            beams_input(&beams).to_vec(),
            realizations,
            seed,
        )
    }

    /// The same for any 3-output model whose leading input streams read the IMU
    /// (\[f_b; ω_b\], one column per window step) and whose remaining streams are
    /// `extra` (this update's values, one matrix per stream, e.g. two beams).
    pub fn for_model(
        model: &'a OnnxMeasurement<3>,
        error_model: &'a InsErrorModel,
        extra: Vec<DMatrix<f64>>,
        realizations: usize,
        seed: u64,
    ) -> Self {
        Self {
            model,
            error_model,
            extra,
            realizations,
            seed,
        }
    }

    /// Window L the model reads.
    ///
    /// # Errors
    /// [`Error::InvalidInput`] if the model's inputs do not split into IMU streams and
    /// the given per-update inputs.
    fn generic(
        &self,
    ) -> Result<LearnedCrossCovariance<'_, f64, OnnxMeasurement<3>, InsErrorModel, 3, IMU_CHANNELS>>
    {
        LearnedCrossCovariance::new(self.model, self.error_model, &self.extra).map_err(|e| {
            Error::InvalidInput {
                what: "learned model inputs",
                reason: e.to_string(),
            }
        })
    }

    fn draw(
        &self,
        window: &StepWindow<'_, f64, InsState, ImuSample, ERROR_STATES>,
    ) -> Result<Draws> {
        if self.realizations < 2 {
            return Err(Error::InvalidInput {
                what: "realizations",
                reason: format!("{} < 2", self.realizations),
            });
        }
        let generic = self.generic()?;
        if window.len() != generic.window() {
            return Err(Error::InvalidInput {
                what: "IMU window",
                reason: format!(
                    "{} steps, the model reads {}",
                    window.len(),
                    generic.window()
                ),
            });
        }
        let base = generic.inputs::<ERROR_STATES>(window)?;
        let steps: Vec<_> = window.iter().collect();
        let dts = steps
            .iter()
            .map(|s| {
                s.dt.filter(|dt| dt.is_finite() && *dt > 0.0)
                    .ok_or_else(|| Error::InvalidInput {
                        what: "IMU window",
                        reason: format!("step {} has no positive dt", s.position),
                    })
            })
            .collect::<Result<Vec<f64>>>()?;
        let sigmas: Vec<SVector<f64, IMU_CHANNELS>> = dts
            .iter()
            .map(|&dt| {
                self.error_model
                    .input_noise_covariance(dt)
                    .diagonal()
                    .map(f64::sqrt)
            })
            .collect();
        let mech = Mechanization::new();
        // Biases are not integrated by the re-run (the noise is what is compared).
        let start = InsState {
            acc_bias: Vector3::zeros(),
            gyro_bias: Vector3::zeros(),
            ..*steps[0].state
        };
        let integrate = |noise: Option<&[SVector<f64, IMU_CHANNELS>]>| {
            let mut s = start;
            for (i, step) in steps.iter().enumerate() {
                let mut m = *step.input;
                if let Some(n) = noise {
                    m.specific_force += n[i].fixed_rows::<3>(0);
                    m.angular_rate += n[i].fixed_rows::<3>(3);
                }
                s = mech.step_unchecked(&s, &m, dts[i]);
            }
            s
        };
        let reference = integrate(None);
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        let mut noise = Vec::with_capacity(self.realizations);
        let mut errors = Vec::with_capacity(self.realizations);
        let mut inputs = Vec::with_capacity(self.realizations);
        for _ in 0..self.realizations {
            let n: Vec<SVector<f64, IMU_CHANNELS>> = sigmas
                .iter()
                .map(|s| {
                    SVector::<f64, IMU_CHANNELS>::from_fn(|i, _| {
                        let z: f64 = StandardNormal.sample(&mut rng);
                        z * s[i]
                    })
                })
                .collect();
            errors.push(error_state(&reference, &integrate(Some(&n))));
            let mut noisy = base.clone();
            for (step, n) in steps.iter().zip(&n) {
                let channels = self.error_model.input_channels(step.input) + n;
                generic.scatter(&mut noisy, step.position, &channels);
            }
            inputs.push(noisy);
            noise.push(n);
        }
        let outputs = self.model.measure_batch(&inputs)?;
        Ok(Draws {
            noise,
            errors,
            outputs,
        })
    }

    /// Run the Monte Carlo over `window` (its IMU taken as noise-free).
    ///
    /// # Errors
    /// [`Error::InvalidInput`] for fewer than 2 realizations, a window that is not the
    /// model's or per-update inputs that do not fit its streams; the network's errors.
    pub fn estimate(
        &self,
        window: &StepWindow<'_, f64, InsState, ImuSample, ERROR_STATES>,
    ) -> Result<EmpiricalEstimate> {
        let draws = self.draw(window)?;
        let n = self.realizations as f64;
        let mean_x = draws
            .errors
            .iter()
            .fold(SMatrix::<f64, ERROR_STATES, 1>::zeros(), |a, e| a + e)
            / n;
        let mean_y = draws.outputs.iter().fold(Vector3::zeros(), |a, y| a + y) / n;
        let mut sum = CrossMatrix::zeros();
        let mut sum_sq = CrossMatrix::zeros();
        for (x, y) in draws.errors.iter().zip(&draws.outputs) {
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

impl WindowedCrossCovariance<f64, InsState, ImuSample, ERROR_STATES, 3> for Empirical<'_> {
    fn window_steps(&self) -> usize {
        self.model.input_specs().first().map_or(0, |s| s.window)
    }

    fn step_cross_covariances(
        &self,
        window: &StepWindow<'_, f64, InsState, ImuSample, ERROR_STATES>,
        sink: &mut dyn FnMut(&CrossMatrix) -> estim_core::Result<()>,
    ) -> estim_core::Result<()> {
        let draws = self.draw(window)?;
        let n = self.realizations as f64;
        let mean_y = draws.outputs.iter().fold(Vector3::zeros(), |a, y| a + y) / n;
        for step in window.iter() {
            let dt = step.dt.unwrap_or(0.0);
            let a = self
                .error_model
                .input_noise_jacobian(step.state, step.input, dt);
            let mut d = CrossMatrix::zeros();
            for (noise, y) in draws.noise.iter().zip(&draws.outputs) {
                d += a * noise[step.position] * (y - mean_y).transpose();
            }
            sink(&(d / (n - 1.0)))?;
        }
        Ok(())
    }

    fn transported_cross_covariance(
        &self,
        window: &StepWindow<'_, f64, InsState, ImuSample, ERROR_STATES>,
    ) -> estim_core::Result<Option<CrossMatrix>> {
        Ok(Some(self.estimate(window)?.cross_covariance))
    }
}
