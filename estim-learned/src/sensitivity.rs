//! Cross-covariance between a process driven by measured samples and a learned
//! measurement fed with the same samples, derived from the model's own sensitivity,
//! over the process steps the filter recorded (estim-core [`StepWindow`]).
//!
//! ## The generic piece: [`LearnedCrossCovariance`]
//!
//! Window sample j (one per process step, oldest first) carries a white noise n_j
//! (K channels, covariance Σ_j per sample, [`InputNoise::input_noise_covariance`]).
//! The same measured sample drives the process and feeds the model, so n_j enters
//! - the error state after step j as A_j n_j ([`InputNoise::input_noise_jacobian`],
//!   sign included: `true = nominal + error` and the nominal integrates the
//!   *measured* sample, hence A_j = -(d f / d u) for an additive input), and
//! - the model output as J_j n_j (J_j = d y / d u_j, Jacobian-vector products of the
//!   [`LearnedMeasurement`]).
//!
//! Hence (first order) D_j = Cov(A_j n_j, v) = A_j Σ_j J_j', the quantity estim-core's
//! [`WindowedCrossCovariance`] asks for, in its sign convention (stated once, in its
//! docs). Two evaluations:
//! - per step ([`WindowedCrossCovariance::step_cross_covariances`], used when other
//!   updates lie inside the window): K JVP directions per step, K L in one batch;
//! - adjoint ([`WindowedCrossCovariance::transported_cross_covariance`], used when the
//!   window holds no other update): row r of M = sum_j Phi(k, j+1) A_j Σ_j J_j' is
//!   J d_r with d_r the stacked rows r of Phi(k, j+1) A_j Σ_j: N directions (zero rows
//!   skipped) instead of K L, in one batch.
//!
//! Layout: the model's first input streams read the process samples, one column per
//! step (their channel counts sum to K, [`InputNoise::input_channels`] gives the
//! channels in that order, and their window is the window L of the update); the
//! remaining streams are per-update values handed in when the struct is built (e.g.
//! the DVL beams of BeamsNet). Nothing is kept between updates: the struct borrows
//! the model, the process model and the per-update values, and is built at each
//! update.

use estim_core::{
    InputSpec, LearnedMeasurement, ProcessModel, Scalar, StepWindow, WindowedCrossCovariance,
};
use estim_ins::{
    earth::radii_of_curvature, ImuSample, InsErrorModel, InsState, Mechanization, ERROR_STATES,
};
use nalgebra::{DMatrix, Matrix3, SMatrix, SVector, Vector3, Vector4};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::beamsnet::BeamsNet;
use crate::measurement::OnnxMeasurement;
use crate::{Error, Result};

/// How a process step's measured input sample carries its noise into the error state
/// (the process side of [`LearnedCrossCovariance`]).
pub trait InputNoise<T: Scalar, const N: usize, const K: usize>: ProcessModel<T, N> {
    /// The K channels of the measured sample as the learned model reads them, in the
    /// order of the model's process-fed input streams (e.g. \[f_b; ω_b\]).
    fn input_channels(&self, input: &Self::Input) -> SVector<T, K>;

    /// A_j (N x K): noise n added to the measured sample of this step enters the error
    /// state after the step as A_j n (`true = nominal + error`; for an input that the
    /// nominal integrates, A_j = -d f / d u).
    fn input_noise_jacobian(
        &self,
        state: &Self::State,
        input: &Self::Input,
        dt: T,
    ) -> SMatrix<T, N, K>;

    /// Σ_j (K x K): covariance of one sample's noise over a step of length `dt`.
    fn input_noise_covariance(&self, dt: T) -> SMatrix<T, K, K>;
}

/// D_j = A_j Σ_j J_j' for a [`LearnedMeasurement`] fed with the samples of the window
/// (see the module docs). Build one per update: it borrows the model, the process
/// model and this update's extra inputs.
#[derive(Debug, Clone, Copy)]
pub struct LearnedCrossCovariance<'a, T: Scalar, L: ?Sized, P: ?Sized, const K: usize> {
    model: &'a L,
    process: &'a P,
    extra: &'a [DMatrix<T>],
    /// Number of leading input streams fed by the process samples.
    process_streams: usize,
    window: usize,
}

fn layout_error(reason: String) -> estim_core::Error {
    estim_core::Error::Model(format!("learned cross-covariance input layout: {reason}"))
}

impl<'a, T, L, P, const K: usize> LearnedCrossCovariance<'a, T, L, P, K>
where
    T: Scalar,
    L: ?Sized,
    P: ?Sized,
{
    /// For `model` whose leading input streams (channels summing to K, one common
    /// window L) read the process samples and whose remaining streams are `extra`
    /// (one matrix per stream, in order, with the declared shapes).
    ///
    /// # Errors
    /// [`estim_core::Error::Model`] naming the mismatch if the streams do not split so.
    pub fn new<const M: usize>(
        model: &'a L,
        process: &'a P,
        extra: &'a [DMatrix<T>],
    ) -> estim_core::Result<Self>
    where
        L: LearnedMeasurement<T, M>,
    {
        let specs: &[InputSpec] = model.input_specs();
        let mut channels = 0;
        let mut process_streams = 0;
        while channels < K {
            let Some(spec) = specs.get(process_streams) else {
                return Err(layout_error(format!(
                    "the streams' channels sum to {channels}, fewer than the process's K = {K}"
                )));
            };
            channels += spec.channels;
            process_streams += 1;
        }
        if channels != K {
            return Err(layout_error(format!(
                "the leading streams' channels sum to {channels}, not the process's K = {K}"
            )));
        }
        let window = specs[0].window;
        if window == 0 || specs[..process_streams].iter().any(|s| s.window != window) {
            return Err(layout_error(
                "the process-fed streams must share one non-zero window".into(),
            ));
        }
        let rest = &specs[process_streams..];
        if rest.len() != extra.len()
            || rest
                .iter()
                .zip(extra)
                .any(|(s, m)| m.shape() != (s.channels, s.window))
        {
            return Err(layout_error(format!(
                "{} per-update inputs given for streams [{}]",
                extra.len(),
                rest.iter()
                    .map(|s| format!("{} {} x {}", s.name, s.channels, s.window))
                    .collect::<Vec<_>>()
                    .join(", ")
            )));
        }
        Ok(Self {
            model,
            process,
            extra,
            process_streams,
            window,
        })
    }

    /// The window L (process steps the model reads).
    pub fn window(&self) -> usize {
        self.window
    }

    /// Zero matrices shaped like the model's inputs.
    fn zero_inputs<const M: usize>(&self) -> Vec<DMatrix<T>>
    where
        L: LearnedMeasurement<T, M>,
    {
        self.model
            .input_specs()
            .iter()
            .map(|s| DMatrix::zeros(s.channels, s.window))
            .collect()
    }

    /// Write the K-vector `v` into column `column` of the process-fed streams.
    fn scatter(&self, inputs: &mut [DMatrix<T>], column: usize, v: &SVector<T, K>) {
        let mut c = 0;
        for m in inputs.iter_mut().take(self.process_streams) {
            for r in 0..m.nrows() {
                m[(r, column)] = v[c];
                c += 1;
            }
        }
    }
}

impl<'a, T, L, P, const K: usize> LearnedCrossCovariance<'a, T, L, P, K>
where
    T: Scalar,
    L: ?Sized,
    P: ?Sized,
{
    /// The model's inputs built from the window's samples (process-fed streams) and
    /// the per-update values.
    ///
    /// # Errors
    /// [`estim_core::Error::Dimension`] if the window is not L steps long.
    pub fn inputs<const N: usize, const M: usize>(
        &self,
        window: &StepWindow<'_, T, P::State, P::Input, N>,
    ) -> estim_core::Result<Vec<DMatrix<T>>>
    where
        L: LearnedMeasurement<T, M>,
        P: InputNoise<T, N, K>,
    {
        self.check_window(window)?;
        let mut inputs = self.zero_inputs::<M>();
        for step in window.iter() {
            let v = self.process.input_channels(step.input);
            self.scatter(&mut inputs, step.position, &v);
        }
        for (slot, m) in inputs[self.process_streams..].iter_mut().zip(self.extra) {
            slot.copy_from(m);
        }
        Ok(inputs)
    }

    /// The model's measurement on the window (the samples the filter consumed).
    ///
    /// # Errors
    /// As [`LearnedCrossCovariance::inputs`], and the model's errors.
    pub fn measure<const N: usize, const M: usize>(
        &self,
        window: &StepWindow<'_, T, P::State, P::Input, N>,
    ) -> estim_core::Result<SVector<T, M>>
    where
        L: LearnedMeasurement<T, M>,
        P: InputNoise<T, N, K>,
    {
        self.model.measure(&self.inputs::<N, M>(window)?)
    }

    fn check_window<S, U, const N: usize>(
        &self,
        window: &StepWindow<'_, T, S, U, N>,
    ) -> estim_core::Result<()> {
        if window.len() != self.window {
            return Err(estim_core::Error::Dimension {
                what: "learned measurement window (process steps)",
                expected: self.window,
                got: window.len(),
            });
        }
        Ok(())
    }

    fn step_dt(dt: Option<T>) -> estim_core::Result<T> {
        dt.ok_or_else(|| {
            estim_core::Error::Model(
                "learned cross-covariance needs each step's dt (ExtendedKalmanFilter or \
                 ErrorStateKalmanFilter)"
                    .into(),
            )
        })
    }

    fn jvps<const M: usize>(
        &self,
        inputs: &[DMatrix<T>],
        directions: &[Vec<DMatrix<T>>],
    ) -> estim_core::Result<Vec<SVector<T, M>>>
    where
        L: LearnedMeasurement<T, M>,
    {
        let out = self.model.sensitivity(inputs, directions)?.ok_or_else(|| {
            estim_core::Error::Model(
                "the learned measurement provides no sensitivity (Jacobian-vector products)".into(),
            )
        })?;
        if out.len() != directions.len() {
            return Err(estim_core::Error::Dimension {
                what: "Jacobian-vector products",
                expected: directions.len(),
                got: out.len(),
            });
        }
        Ok(out)
    }
}

impl<'a, T, L, P, const N: usize, const M: usize, const K: usize>
    WindowedCrossCovariance<T, P::State, P::Input, N, M> for LearnedCrossCovariance<'a, T, L, P, K>
where
    T: Scalar,
    L: LearnedMeasurement<T, M> + ?Sized,
    P: InputNoise<T, N, K> + ?Sized,
{
    fn window_steps(&self) -> usize {
        self.window
    }

    /// Per step: D_j = A_j Σ_j J_j', J_j' from K unit directions per step (K L JVPs in
    /// one call).
    fn step_cross_covariances(
        &self,
        window: &StepWindow<'_, T, P::State, P::Input, N>,
        sink: &mut dyn FnMut(&SMatrix<T, N, M>) -> estim_core::Result<()>,
    ) -> estim_core::Result<()> {
        let inputs = self.inputs::<N, M>(window)?;
        let zero = self.zero_inputs::<M>();
        let mut directions = Vec::with_capacity(K * self.window);
        for j in 0..self.window {
            for c in 0..K {
                let mut d = zero.clone();
                let mut e = SVector::<T, K>::zeros();
                e[c] = T::one();
                self.scatter(&mut d, j, &e);
                directions.push(d);
            }
        }
        let jvp = self.jvps::<M>(&inputs, &directions)?;
        for step in window.iter() {
            let dt = Self::step_dt(step.dt)?;
            let a = self
                .process
                .input_noise_jacobian(step.state, step.input, dt);
            let sigma = self.process.input_noise_covariance(dt);
            // J_j' (K x M): row c = (J_j e_c)'.
            let jt = SMatrix::<T, K, M>::from_fn(|c, m| jvp[step.position * K + c][m]);
            sink(&(a * sigma * jt))?;
        }
        Ok(())
    }

    /// Adjoint form: row r of M is J d_r, d_r the stacked rows r of Phi(k, j+1) A_j Σ_j
    /// (N directions, zero rows skipped).
    fn transported_cross_covariance(
        &self,
        window: &StepWindow<'_, T, P::State, P::Input, N>,
    ) -> estim_core::Result<Option<SMatrix<T, N, M>>> {
        let inputs = self.inputs::<N, M>(window)?;
        let zero = self.zero_inputs::<M>();
        let mut directions: Vec<Vec<DMatrix<T>>> = vec![zero; N];
        let mut nonzero = [false; N];
        window.for_each_transport(|step, transport| {
            let dt = Self::step_dt(step.dt)?;
            let a = self
                .process
                .input_noise_jacobian(step.state, step.input, dt);
            let sigma = self.process.input_noise_covariance(dt);
            let b = transport * a * sigma;
            for (r, d) in directions.iter_mut().enumerate() {
                let row: SVector<T, K> = b.row(r).transpose();
                if row.iter().any(|v| *v != T::zero()) {
                    nonzero[r] = true;
                }
                self.scatter(d, step.position, &row);
            }
            Ok(())
        })?;
        let rows: Vec<usize> = (0..N).filter(|&r| nonzero[r]).collect();
        let kept: Vec<Vec<DMatrix<T>>> = rows
            .iter()
            .map(|&r| std::mem::take(&mut directions[r]))
            .collect();
        let jvp = self.jvps::<M>(&inputs, &kept)?;
        let mut m = SMatrix::<T, N, M>::zeros();
        for (&r, v) in rows.iter().zip(jvp) {
            m.set_row(r, &v.transpose());
        }
        Ok(Some(m))
    }
}

/// Q_w = sum_j Phi(k, j+1) A_j Σ_j A_j' Phi(k, j+1)': the covariance of the error
/// state at the update that the window's input noise alone drives (the process side
/// of the joint covariance of [`LearnedCrossCovariance`]; no other update inside the
/// window). With M and R it gives the correlation between the model's output error and
/// that input-driven error, M_ij / sqrt(Q_w,ii R_jj).
///
/// # Errors
/// A step without dt (only the EKF and error-state runners record it).
pub fn driven_error_covariance<T, P, const N: usize, const K: usize>(
    process: &P,
    window: &StepWindow<'_, T, P::State, P::Input, N>,
) -> estim_core::Result<SMatrix<T, N, N>>
where
    T: Scalar,
    P: InputNoise<T, N, K> + ?Sized,
{
    let mut q = SMatrix::<T, N, N>::zeros();
    window.for_each_transport(|step, transport| {
        let dt = step.dt.ok_or_else(|| {
            estim_core::Error::Model(
                "the input-driven error covariance needs each step's dt".into(),
            )
        })?;
        let b = transport * process.input_noise_jacobian(step.state, step.input, dt);
        q += b * process.input_noise_covariance(dt) * b.transpose();
        Ok(())
    })?;
    Ok(q)
}

// ---------------------------------------------------------------------------------
// The INS/DVL instance: BeamsNet fed with the IMU samples the error-state filter
// integrates.
// ---------------------------------------------------------------------------------

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
/// filter integrated (the runner's recorded window: no Phi recomputed here, nothing
/// kept between updates). Build one per update with the update's beams.
///
/// Use it with `ErrorStateKalmanFilter::update_windowed` on a filter configured with
/// `FilterConfig::builder().window_capacity(BEAMSNET_WINDOW)`.
#[derive(Debug, Clone)]
pub struct NetworkSensitivity<'a> {
    beamsnet: &'a BeamsNet,
    error_model: &'a InsErrorModel,
    beams: [DMatrix<f64>; 1],
}

impl<'a> NetworkSensitivity<'a> {
    /// For this update's `beams`, the network and the INS error model whose IMU noise
    /// it sees.
    pub fn new(
        beamsnet: &'a BeamsNet,
        error_model: &'a InsErrorModel,
        beams: Vector4<f64>,
    ) -> Self {
        Self {
            beamsnet,
            error_model,
            beams: beams_input(&beams),
        }
    }

    /// The generic piece underneath.
    ///
    /// # Errors
    /// Never for a loaded [`BeamsNet`] (its metadata is checked at load).
    pub fn generic(
        &self,
    ) -> estim_core::Result<
        LearnedCrossCovariance<'_, f64, OnnxMeasurement<3>, InsErrorModel, IMU_CHANNELS>,
    > {
        LearnedCrossCovariance::new::<3>(self.beamsnet.measurement(), self.error_model, &self.beams)
    }

    /// The network's velocity on the window (the IMU samples the filter integrated).
    ///
    /// # Errors
    /// A window of the wrong length, the model's errors.
    pub fn measure(
        &self,
        window: &StepWindow<'_, f64, InsState, ImuSample, ERROR_STATES>,
    ) -> estim_core::Result<Vector3<f64>> {
        self.generic()?.measure::<ERROR_STATES, 3>(window)
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
        self.generic()?.step_cross_covariances(window, sink)
    }

    fn transported_cross_covariance(
        &self,
        window: &StepWindow<'_, f64, InsState, ImuSample, ERROR_STATES>,
    ) -> estim_core::Result<Option<CrossMatrix>> {
        self.generic()?.transported_cross_covariance(window)
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
    ) -> Result<LearnedCrossCovariance<'_, f64, OnnxMeasurement<3>, InsErrorModel, IMU_CHANNELS>>
    {
        LearnedCrossCovariance::new::<3>(self.model, self.error_model, &self.extra).map_err(|e| {
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
        let base = generic.inputs::<ERROR_STATES, 3>(window)?;
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
