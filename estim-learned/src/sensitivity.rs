//! Cross-covariance between a process driven by measured samples and a learned
//! measurement fed with the same samples, derived from the model's own sensitivity,
//! over the process steps the filter recorded (estim-core [`StepWindow`]).

use std::cell::RefCell;

use estim_core::window::StepWindow;
use estim_core::{InputSpec, LearnedMeasurement, ProcessModel, Scalar, WindowedCrossCovariance};
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
/// (derivation below).
///
/// Build it once, beside the filter, and keep it from one update to the next: it
/// borrows the model and the process model and owns a workspace (the model's inputs,
/// the JVP directions and their products) sized from the model's declared input
/// shapes, so that after the first update neither [`measure`](Self::measure) nor the
/// cross-covariance allocates anything of estim's. Per update, set the per-update
/// inputs ([`set_update_input`](Self::set_update_input), e.g. this update's fix), then
/// `measure` the window and pass `self` to `update_windowed`. Building one per update
/// works too; it then allocates its workspace each time.
///
/// ## The generic piece: [`LearnedCrossCovariance`]
///
/// Window sample j (one per process step, oldest first) carries a white noise n_j
/// (K channels, covariance Σ_j per sample, [`InputNoise::input_noise_covariance`]).
/// The same measured sample drives the process and feeds the model, so n_j enters
/// - the error state after step j as A_j n_j ([`InputNoise::input_noise_jacobian`],
///   sign included: `true = nominal + error` and the nominal integrates the
///   *measured* sample, hence A_j = -(d f / d u) for an additive input), and
/// - the model output as J_j n_j (J_j = d y / d u_j, Jacobian-vector products of the
///   [`LearnedMeasurement`]).
///
/// Hence (first order) D_j = Cov(A_j n_j, v) = A_j Σ_j J_j', the quantity estim-core's
/// [`WindowedCrossCovariance`] asks for, in its sign convention (stated once, in its
/// docs). Two evaluations:
/// - per step ([`WindowedCrossCovariance::step_cross_covariances`], used when other
///   updates lie inside the window): K JVP directions per step, K L in one batch;
/// - adjoint ([`WindowedCrossCovariance::transported_cross_covariance`], used when the
///   window holds no other update): row r of M = sum_j Phi(k, j+1) A_j Σ_j J_j' is
///   J d_r with d_r the stacked rows r of Phi(k, j+1) A_j Σ_j: N directions (zero rows
///   skipped) instead of K L, in one batch.
///
/// Layout: the model's first input streams read the process samples, one column per
/// step (their channel counts sum to K, [`InputNoise::input_channels`] gives the
/// channels in that order, and their window is the window L of the update); the
/// remaining streams are per-update values (e.g. the DVL beams of BeamsNet), set when
/// the struct is built and replaced per update.
///
/// Allocation: the struct is built once and kept; its workspace (the model's inputs,
/// the direction sets, the products) is sized from the declared input shapes and,
/// for the directions, at the first update. After that an update allocates nothing
/// of estim's; the model's own [`LearnedMeasurement::measure`] and
/// [`LearnedMeasurement::sensitivity`] write into those buffers (a pure-Rust model
/// can then run allocation-free: `tests/no_allocation.rs`).
#[derive(Debug)]
pub struct LearnedCrossCovariance<'a, T, L, P, const M: usize, const K: usize>
where
    T: Scalar,
    L: ?Sized,
    P: ?Sized,
{
    model: &'a L,
    process: &'a P,
    /// Number of leading input streams fed by the process samples.
    process_streams: usize,
    window: usize,
    /// Borrowed mutably by one call at a time (the trait methods take `&self`).
    workspace: RefCell<Workspace<T, M>>,
}

/// What [`LearnedCrossCovariance`] reuses from one update to the next.
#[derive(Debug, Clone)]
struct Workspace<T: Scalar, const M: usize> {
    /// One matrix per input stream: the process-fed ones are refilled from the window
    /// at each call, the per-update ones hold the values last set.
    inputs: Vec<DMatrix<T>>,
    /// Direction sets one after another, one matrix per input stream each; grown to
    /// the largest number of directions asked for (N for the adjoint form, K L per
    /// step), then reused.
    directions: Vec<DMatrix<T>>,
    /// One Jacobian-vector product per direction set.
    products: Vec<SVector<T, M>>,
}

impl<T: Scalar, const M: usize> Workspace<T, M> {
    /// At least `count` direction sets and products, the first `count` sets zeroed.
    fn zeroed_directions(&mut self, count: usize) {
        let streams = self.inputs.len();
        while self.directions.len() < count * streams {
            let like = &self.inputs[self.directions.len() % streams];
            self.directions
                .push(DMatrix::zeros(like.nrows(), like.ncols()));
        }
        if self.products.len() < count {
            self.products.resize(count, SVector::zeros());
        }
        for d in &mut self.directions[..count * streams] {
            d.fill(T::zero());
        }
    }
}

impl<T, L, P, const M: usize, const K: usize> Clone for LearnedCrossCovariance<'_, T, L, P, M, K>
where
    T: Scalar,
    L: ?Sized,
    P: ?Sized,
{
    fn clone(&self) -> Self {
        Self {
            model: self.model,
            process: self.process,
            process_streams: self.process_streams,
            window: self.window,
            workspace: RefCell::new(self.workspace.borrow().clone()),
        }
    }
}

fn layout_error(reason: String) -> estim_core::Error {
    estim_core::Error::Model(format!("learned cross-covariance input layout: {reason}"))
}

fn busy() -> estim_core::Error {
    estim_core::Error::Model(
        "learned cross-covariance: its workspace is in use by another call on the same \
         value (a re-entrant call from the model)"
            .into(),
    )
}

/// Write the K-vector `v` into column `column` of the leading (process-fed) streams.
fn scatter<T: Scalar, const K: usize>(inputs: &mut [DMatrix<T>], column: usize, v: &SVector<T, K>) {
    let mut c = 0;
    for m in inputs.iter_mut() {
        if c == K {
            break;
        }
        for r in 0..m.nrows() {
            m[(r, column)] = v[c];
            c += 1;
        }
    }
}

/// Set channel `channel` (of the K process channels) of column `column` to `value`.
fn set_channel<T: Scalar>(inputs: &mut [DMatrix<T>], column: usize, channel: usize, value: T) {
    let mut first = 0;
    for m in inputs.iter_mut() {
        if channel < first + m.nrows() {
            m[(channel - first, column)] = value;
            return;
        }
        first += m.nrows();
    }
}

impl<'a, T, L, P, const M: usize, const K: usize> LearnedCrossCovariance<'a, T, L, P, M, K>
where
    T: Scalar,
    L: LearnedMeasurement<T, M> + ?Sized,
    P: ?Sized,
{
    /// For `model` whose leading input streams (channels summing to K, one common
    /// window L) read the process samples and whose remaining streams are `extra`
    /// (one matrix per stream, in order, with the declared shapes; copied into the
    /// workspace, replace them per update with
    /// [`set_update_input`](Self::set_update_input)).
    ///
    /// # Errors
    /// [`estim_core::Error::Model`] naming the mismatch if the streams do not split so.
    pub fn new(model: &'a L, process: &'a P, extra: &[DMatrix<T>]) -> estim_core::Result<Self> {
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
        let inputs = specs[..process_streams]
            .iter()
            .map(|s| DMatrix::zeros(s.channels, s.window))
            .chain(extra.iter().cloned())
            .collect();
        Ok(Self {
            model,
            process,
            process_streams,
            window,
            workspace: RefCell::new(Workspace {
                inputs,
                directions: Vec::new(),
                products: Vec::new(),
            }),
        })
    }
}

impl<'a, T, L, P, const M: usize, const K: usize> LearnedCrossCovariance<'a, T, L, P, M, K>
where
    T: Scalar,
    L: ?Sized,
    P: ?Sized,
{
    /// The window L (process steps the model reads).
    pub fn window(&self) -> usize {
        self.window
    }

    /// The learned model.
    pub fn model(&self) -> &'a L {
        self.model
    }

    /// The process model whose input noise the model sees.
    pub fn process(&self) -> &'a P {
        self.process
    }

    /// Replace per-update input `index` (0 = the first stream after the process-fed
    /// ones) with `values`, column-major (`channels x window` of its declared shape,
    /// e.g. a 2 x 1 fix as its 2 values). Copies into the workspace; allocates nothing.
    ///
    /// # Errors
    /// [`estim_core::Error::Dimension`] for an index past the per-update streams or a
    /// length that is not the stream's.
    pub fn set_update_input(&mut self, index: usize, values: &[T]) -> estim_core::Result<()> {
        let inputs = &mut self.workspace.get_mut().inputs;
        let streams = inputs.len() - self.process_streams;
        let slot =
            inputs
                .get_mut(self.process_streams + index)
                .ok_or(estim_core::Error::Dimension {
                    what: "per-update input streams of the learned measurement",
                    expected: streams,
                    got: index + 1,
                })?;
        if values.len() != slot.len() {
            return Err(estim_core::Error::Dimension {
                what: "values of a per-update input stream (channels x window)",
                expected: slot.len(),
                got: values.len(),
            });
        }
        slot.copy_from_slice(values);
        Ok(())
    }

    /// Write the K-vector `v` into column `column` of the process-fed streams of
    /// `inputs` (shaped as the model's inputs).
    pub(crate) fn scatter(&self, inputs: &mut [DMatrix<T>], column: usize, v: &SVector<T, K>) {
        scatter(&mut inputs[..self.process_streams], column, v);
    }

    /// Fill the process-fed streams of `inputs` from the window's samples.
    fn fill_inputs<const N: usize>(
        &self,
        inputs: &mut [DMatrix<T>],
        window: &StepWindow<'_, T, P::State, P::Input, N>,
    ) -> estim_core::Result<()>
    where
        P: InputNoise<T, N, K>,
    {
        if window.len() != self.window {
            return Err(estim_core::Error::Dimension {
                what: "learned measurement window (process steps)",
                expected: self.window,
                got: window.len(),
            });
        }
        for step in window.iter() {
            let v = self.process.input_channels(step.input);
            self.scatter(inputs, step.position, &v);
        }
        Ok(())
    }

    /// A copy of the model's inputs built from the window's samples (process-fed
    /// streams) and the per-update values (allocates; for validation, e.g. a Monte
    /// Carlo that perturbs them).
    ///
    /// # Errors
    /// [`estim_core::Error::Dimension`] if the window is not L steps long.
    pub fn inputs<const N: usize>(
        &self,
        window: &StepWindow<'_, T, P::State, P::Input, N>,
    ) -> estim_core::Result<Vec<DMatrix<T>>>
    where
        P: InputNoise<T, N, K>,
    {
        let mut inputs = self
            .workspace
            .try_borrow()
            .map_err(|_| busy())?
            .inputs
            .clone();
        self.fill_inputs(&mut inputs, window)?;
        Ok(inputs)
    }

    /// The model's measurement on the window (the samples the filter consumed) and
    /// the per-update inputs; the inputs are written into the workspace, nothing is
    /// allocated.
    ///
    /// # Errors
    /// As [`LearnedCrossCovariance::inputs`], and the model's errors.
    pub fn measure<const N: usize>(
        &self,
        window: &StepWindow<'_, T, P::State, P::Input, N>,
    ) -> estim_core::Result<SVector<T, M>>
    where
        L: LearnedMeasurement<T, M>,
        P: InputNoise<T, N, K>,
    {
        let mut workspace = self.workspace.try_borrow_mut().map_err(|_| busy())?;
        self.fill_inputs(&mut workspace.inputs, window)?;
        self.model.measure(&workspace.inputs)
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

    /// The model's JVPs for the first `count` direction sets of the workspace, into
    /// its first `count` products.
    fn products(&self, workspace: &mut Workspace<T, M>, count: usize) -> estim_core::Result<()>
    where
        L: LearnedMeasurement<T, M>,
    {
        let streams = workspace.inputs.len();
        let Workspace {
            inputs,
            directions,
            products,
        } = workspace;
        let provided = self.model.sensitivity(
            inputs,
            &directions[..count * streams],
            &mut products[..count],
        )?;
        if provided {
            Ok(())
        } else {
            Err(estim_core::Error::Model(
                "the learned measurement provides no sensitivity (Jacobian-vector products)".into(),
            ))
        }
    }
}

impl<'a, T, L, P, const N: usize, const M: usize, const K: usize>
    WindowedCrossCovariance<T, P::State, P::Input, N, M>
    for LearnedCrossCovariance<'a, T, L, P, M, K>
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
        let mut workspace = self.workspace.try_borrow_mut().map_err(|_| busy())?;
        self.fill_inputs(&mut workspace.inputs, window)?;
        let streams = workspace.inputs.len();
        let count = K * self.window;
        workspace.zeroed_directions(count);
        for j in 0..self.window {
            for c in 0..K {
                let set = (j * K + c) * streams;
                set_channel(
                    &mut workspace.directions[set..set + self.process_streams],
                    j,
                    c,
                    T::one(),
                );
            }
        }
        self.products(&mut workspace, count)?;
        for step in window.iter() {
            let dt = Self::step_dt(step.dt)?;
            let a = self
                .process
                .input_noise_jacobian(step.state, step.input, dt);
            let sigma = self.process.input_noise_covariance(dt);
            // J_j' (K x M): row c = (J_j e_c)'.
            let jt =
                SMatrix::<T, K, M>::from_fn(|c, m| workspace.products[step.position * K + c][m]);
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
        let mut workspace = self.workspace.try_borrow_mut().map_err(|_| busy())?;
        self.fill_inputs(&mut workspace.inputs, window)?;
        let streams = workspace.inputs.len();
        workspace.zeroed_directions(N);
        let mut nonzero = [false; N];
        let directions = &mut workspace.directions;
        window.for_each_transport(|step, transport| {
            let dt = Self::step_dt(step.dt)?;
            let a = self
                .process
                .input_noise_jacobian(step.state, step.input, dt);
            let sigma = self.process.input_noise_covariance(dt);
            let b = transport * a * sigma;
            for (r, d) in directions.chunks_exact_mut(streams).take(N).enumerate() {
                let row: SVector<T, K> = b.row(r).transpose();
                if row.iter().any(|v| *v != T::zero()) {
                    nonzero[r] = true;
                }
                self.scatter(d, step.position, &row);
            }
            Ok(())
        })?;
        // Move the non-zero rows' directions to the front (swapping matrices, no copy);
        // rows[i] is the row of direction set i.
        let mut rows = [0; N];
        let mut kept = 0;
        for r in (0..N).filter(|&r| nonzero[r]) {
            for s in 0..streams {
                workspace
                    .directions
                    .swap(kept * streams + s, r * streams + s);
            }
            rows[kept] = r;
            kept += 1;
        }
        let mut m = SMatrix::<T, N, M>::zeros();
        if kept > 0 {
            self.products(&mut workspace, kept)?;
            for (&r, v) in rows[..kept].iter().zip(&workspace.products) {
                m.set_row(r, &v.transpose());
            }
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
