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

mod ins;
pub use ins::{CrossMatrix, Empirical, EmpiricalEstimate, NetworkSensitivity, IMU_CHANNELS};
