//! [`OnnxMeasurement`]: any ONNX model described by a [`ModelMetadata`] file, as an
//! estim-core [`LearnedMeasurement`].

use std::path::Path;
use std::sync::Mutex;

use estim_core::{InputSpec, LearnedMeasurement};
use nalgebra::{DMatrix, SMatrix, SVector};

use crate::metadata::{InputMetadata, ModelMetadata, OutputMetadata};
use crate::onnx::OnnxModel;
use crate::{Error, Result};

/// Default finite-difference step of [`OnnxMeasurement::sensitivity`], in normalised
/// input units (the inputs are normalised to unit standard deviation per channel).
pub const DEFAULT_SENSITIVITY_STEP: f64 = 1e-2;

/// An ONNX model fed with windows of sensor samples, producing an `M`-vector
/// measurement with error covariance R from its metadata.
///
/// Inputs are one `channels x window` matrix per [`InputSpec`] (rows are channels,
/// columns are samples, oldest first), in the order of the metadata's `inputs`. They
/// are normalised per channel with the metadata's mean/std, converted to `f32`, and run
/// through the model loaded once at construction.
#[derive(Debug)]
pub struct OnnxMeasurement<const M: usize> {
    metadata: ModelMetadata,
    model: OnnxModel,
    specs: Vec<InputSpec>,
    noise_covariance: SMatrix<f64, M, M>,
    sensitivity_step: f64,
    /// The finite-difference scale of each direction of the last JVP batch, kept so
    /// that a repeated batch allocates nothing (see `jacobian_vector_products`).
    scales: Mutex<Vec<f64>>,
}

impl<const M: usize> Clone for OnnxMeasurement<M> {
    /// The clone gets its own (empty) scratch.
    fn clone(&self) -> Self {
        Self {
            metadata: self.metadata.clone(),
            model: self.model.clone(),
            specs: self.specs.clone(),
            noise_covariance: self.noise_covariance,
            sensitivity_step: self.sensitivity_step,
            scales: Mutex::new(Vec::new()),
        }
    }
}

impl<const M: usize> OnnxMeasurement<M> {
    /// Load from a metadata file; the ONNX file is its `model` entry, relative to the
    /// metadata's folder.
    pub fn from_metadata_path(metadata_path: &Path) -> Result<Self> {
        let metadata = ModelMetadata::from_path(metadata_path)?;
        let model_path = metadata.model_path(metadata_path);
        Self::new(&model_path, metadata, metadata_path)
    }

    /// Load from an ONNX file, taking its metadata from the same path with the
    /// extension `.json` (`beamsnet.onnx` -> `beamsnet.json`).
    pub fn from_model_path(model_path: &Path) -> Result<Self> {
        let metadata_path = model_path.with_extension("json");
        let metadata = ModelMetadata::from_path(&metadata_path)?;
        Self::new(model_path, metadata, &metadata_path)
    }

    /// Load from the bytes of an ONNX file and the text of its metadata JSON (e.g. a
    /// model embedded in a binary with `include_bytes!`); `name` names the model in
    /// errors (its metadata as `name` with the extension `.json`).
    pub fn from_bytes(onnx: &[u8], metadata_json: &str, name: &Path) -> Result<Self> {
        let metadata_path = name.with_extension("json");
        let metadata = ModelMetadata::from_json(metadata_json, &metadata_path)?;
        Self::with_model(metadata, &metadata_path, |inputs, output| {
            OnnxModel::load_bytes(onnx, name, inputs, output)
        })
    }

    fn new(model_path: &Path, metadata: ModelMetadata, metadata_path: &Path) -> Result<Self> {
        Self::with_model(metadata, metadata_path, |inputs, output| {
            OnnxModel::load(model_path, inputs, output)
        })
    }

    fn with_model(
        metadata: ModelMetadata,
        metadata_path: &Path,
        load: impl FnOnce(&[InputMetadata], &OutputMetadata) -> Result<OnnxModel>,
    ) -> Result<Self> {
        if metadata.output.size != M {
            return Err(Error::MalformedMetadata {
                path: metadata_path.to_path_buf(),
                reason: format!(
                    "output size {} but this measurement has size {M}",
                    metadata.output.size
                ),
            });
        }
        let r = SMatrix::<f64, M, M>::from_fn(|i, j| metadata.noise_covariance[i][j]);
        if r.cholesky().is_none() {
            return Err(Error::MalformedMetadata {
                path: metadata_path.to_path_buf(),
                reason: "noise_covariance is not positive definite".into(),
            });
        }
        let model = load(&metadata.inputs, &metadata.output)?;
        let specs = metadata
            .inputs
            .iter()
            .map(|i| InputSpec {
                name: i.stream.clone(),
                channels: i.channels,
                window: i.window,
                sample_rate_hz: i.sample_rate_hz,
            })
            .collect();
        Ok(Self {
            metadata,
            model,
            specs,
            noise_covariance: r,
            sensitivity_step: DEFAULT_SENSITIVITY_STEP,
            scales: Mutex::new(Vec::new()),
        })
    }

    /// Replace the finite-difference step of [`LearnedMeasurement::sensitivity`]
    /// (normalised input units, > 0).
    #[must_use]
    pub fn with_sensitivity_step(mut self, step: f64) -> Self {
        self.sensitivity_step = step;
        self
    }

    /// The metadata the model was loaded with.
    pub fn metadata(&self) -> &ModelMetadata {
        &self.metadata
    }

    /// Check that the metadata declares exactly `expected` inputs as (name, channels,
    /// window), for a network-specific loader; the error names the metadata file
    /// beside `model_path` and what `network` needs.
    pub(crate) fn require_inputs(
        &self,
        model_path: &Path,
        network: &str,
        expected: &[(&str, usize, usize)],
    ) -> Result<()> {
        let declared = &self.metadata.inputs;
        let matches = declared.len() == expected.len()
            && declared
                .iter()
                .zip(expected)
                .all(|(d, &(_, channels, window))| (d.channels, d.window) == (channels, window));
        if matches {
            return Ok(());
        }
        let needed: Vec<String> = expected
            .iter()
            .map(|(name, channels, window)| format!("{name} {channels}x{window}"))
            .collect();
        Err(Error::MalformedMetadata {
            path: model_path.with_extension("json"),
            reason: format!("{network} needs inputs {}", needed.join(", ")),
        })
    }

    /// Check one set of input windows against the specs (count, shapes).
    fn check_inputs(&self, inputs: &[DMatrix<f64>]) -> Result<()> {
        if inputs.len() == self.metadata.inputs.len()
            && inputs
                .iter()
                .zip(&self.metadata.inputs)
                .all(|(m, i)| m.nrows() == i.channels && m.ncols() == i.window)
        {
            return Ok(());
        }
        let expected = self
            .metadata
            .inputs
            .iter()
            .map(|i| format!("{} ({}): {} x {}", i.stream, i.name, i.channels, i.window))
            .collect::<Vec<_>>()
            .join(", ");
        let given = inputs
            .iter()
            .map(|m| format!("{} x {}", m.nrows(), m.ncols()))
            .collect::<Vec<_>>()
            .join(", ");
        Err(Error::InputMismatch {
            expected: format!("{} inputs [{expected}]", self.metadata.inputs.len()),
            given: format!("{} inputs [{given}]", inputs.len()),
        })
    }

    /// Write input `k` of one batch element, normalised, into `out` (its
    /// `channels * window` values, channel-major): `raw + scale * direction` when a
    /// direction is given. Inputs checked by [`Self::check_inputs`].
    fn write_normalised(
        &self,
        k: usize,
        raw: &DMatrix<f64>,
        perturbation: Option<(&DMatrix<f64>, f64)>,
        out: &mut [f32],
    ) -> Result<()> {
        let meta = &self.metadata.inputs[k];
        for c in 0..meta.channels {
            for s in 0..meta.window {
                let x = match perturbation {
                    Some((d, scale)) => raw[(c, s)] + scale * d[(c, s)],
                    None => raw[(c, s)],
                };
                if !x.is_finite() {
                    return Err(Error::InputMismatch {
                        expected: format!("finite samples in {}", meta.stream),
                        given: format!("{x} at channel {c}, sample {s}"),
                    });
                }
                out[c * meta.window + s] = ((x - meta.mean[c]) / meta.std[c]) as f32;
            }
        }
        Ok(())
    }

    /// Values per batch element of input `k`.
    fn element_size(&self, k: usize) -> usize {
        let meta = &self.metadata.inputs[k];
        meta.channels * meta.window
    }

    /// Run the model on several sets of inputs in one batched inference.
    pub fn measure_batch(&self, batch: &[Vec<DMatrix<f64>>]) -> Result<Vec<SVector<f64, M>>> {
        for inputs in batch {
            self.check_inputs(inputs)?;
        }
        let mut out = Vec::with_capacity(batch.len());
        self.model.run_with(
            batch.len(),
            |k, values| {
                let size = self.element_size(k);
                for (inputs, chunk) in batch.iter().zip(values.chunks_exact_mut(size)) {
                    self.write_normalised(k, &inputs[k], None, chunk)?;
                }
                Ok(())
            },
            |values| {
                out.extend(values.chunks_exact(M).map(to_output::<M>));
                Ok(())
            },
        )?;
        Ok(out)
    }

    /// Run the model on one set of inputs: nothing copied but the normalised values
    /// written into the model's (reused) input tensors.
    fn measure_one(&self, inputs: &[DMatrix<f64>]) -> Result<SVector<f64, M>> {
        self.check_inputs(inputs)?;
        let mut y = SVector::<f64, M>::zeros();
        self.model.run_with(
            1,
            |k, values| self.write_normalised(k, &inputs[k], None, values),
            |values| {
                y = to_output::<M>(values);
                Ok(())
            },
        )?;
        Ok(y)
    }

    /// Run the model on already-normalised `f32` tensors (`batch x shape` each, in the
    /// metadata's input order), e.g. parity vectors exported from training.
    pub fn run_normalised(
        &self,
        batch: usize,
        tensors: &[Vec<f32>],
    ) -> Result<Vec<SVector<f64, M>>> {
        let out = self.model.run(batch, tensors)?;
        Ok(out.chunks_exact(M).map(to_output::<M>).collect())
    }

    /// Jacobian-vector products by forward finite differences, all in ONE batched
    /// inference of `1 + products.len()` elements: for each direction d (one matrix
    /// per input, raw units; the directions one after another in `directions`, as in
    /// [`LearnedMeasurement::sensitivity`]), product = (f(x + s d) - f(x)) / s with s
    /// chosen so that the largest normalised component of s d equals the sensitivity
    /// step. The perturbed inputs are written straight into the model's input tensors
    /// and the products into `products` (no copy of x or d; the scales go to a buffer
    /// kept between calls, so a repeated batch allocates nothing here).
    ///
    /// # Errors
    /// [`Error::InvalidInput`] for a non-positive step; [`Error::InputMismatch`] for
    /// inputs or directions not shaped as the metadata declares, or
    /// `directions.len() != products.len() * inputs.len()`; the inference's errors.
    pub fn jacobian_vector_products(
        &self,
        inputs: &[DMatrix<f64>],
        directions: &[DMatrix<f64>],
        products: &mut [SVector<f64, M>],
    ) -> Result<()> {
        if !(self.sensitivity_step.is_finite() && self.sensitivity_step > 0.0) {
            return Err(Error::InvalidInput {
                what: "sensitivity step",
                reason: format!("{} must be positive", self.sensitivity_step),
            });
        }
        self.check_inputs(inputs)?;
        let streams = inputs.len();
        if directions.len() != products.len() * streams
            || directions
                .iter()
                .enumerate()
                .any(|(i, d)| d.shape() != inputs[i % streams].shape())
        {
            return Err(Error::InputMismatch {
                expected: format!(
                    "{} directions of one matrix per input each ({} matrices), shaped as the \
                     inputs",
                    products.len(),
                    products.len() * streams
                ),
                given: format!(
                    "[{}]",
                    directions
                        .iter()
                        .map(|m| format!("{} x {}", m.nrows(), m.ncols()))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            });
        }
        if products.is_empty() {
            return Ok(());
        }
        // One scale per direction, in a buffer kept between calls (a fresh one when
        // another thread holds it).
        let mut local;
        let mut guard = self.scales.try_lock();
        let scales: &mut Vec<f64> = match guard.as_deref_mut() {
            Ok(kept) => kept,
            Err(_) => {
                local = Vec::new();
                &mut local
            }
        };
        scales.clear();
        scales.extend(
            directions
                .chunks_exact(streams)
                .map(|d| self.direction_scale(d)),
        );
        let scales = &*scales;
        self.model.run_with(
            1 + products.len(),
            |k, values| {
                let mut chunks = values.chunks_exact_mut(self.element_size(k));
                if let Some(first) = chunks.next() {
                    self.write_normalised(k, &inputs[k], None, first)?;
                }
                for ((d, &s), chunk) in directions.chunks_exact(streams).zip(scales).zip(chunks) {
                    self.write_normalised(k, &inputs[k], Some((&d[k], s)), chunk)?;
                }
                Ok(())
            },
            |values| {
                let mut outputs = values.chunks_exact(M).map(to_output::<M>);
                let base = outputs.next().unwrap_or_else(SVector::zeros);
                for ((y, &s), product) in outputs.zip(scales).zip(products.iter_mut()) {
                    *product = if s > 0.0 {
                        (y - base) / s
                    } else {
                        SVector::zeros()
                    };
                }
                Ok(())
            },
        )
    }

    /// The finite-difference scale s of a direction: the largest normalised component
    /// of s d equals the sensitivity step (0 for a zero direction).
    fn direction_scale(&self, direction: &[DMatrix<f64>]) -> f64 {
        let mut largest = 0.0_f64;
        for (m, meta) in direction.iter().zip(&self.metadata.inputs) {
            for (c, row) in m.row_iter().enumerate() {
                for v in row.iter() {
                    largest = largest.max((v / meta.std[c]).abs());
                }
            }
        }
        if largest > 0.0 {
            self.sensitivity_step / largest
        } else {
            0.0
        }
    }
}

/// One batch element's `f32` output as an `f64` vector.
fn to_output<const M: usize>(values: &[f32]) -> SVector<f64, M> {
    SVector::<f64, M>::from_fn(|i, _| f64::from(values[i]))
}

impl<const M: usize> LearnedMeasurement<f64, M> for OnnxMeasurement<M> {
    fn input_specs(&self) -> &[InputSpec] {
        &self.specs
    }

    fn measure(&self, inputs: &[DMatrix<f64>]) -> estim_core::Result<SVector<f64, M>> {
        Ok(self.measure_one(inputs)?)
    }

    fn noise_covariance(&self) -> SMatrix<f64, M, M> {
        self.noise_covariance
    }

    fn sensitivity(
        &self,
        inputs: &[DMatrix<f64>],
        directions: &[DMatrix<f64>],
        products: &mut [SVector<f64, M>],
    ) -> estim_core::Result<bool> {
        self.jacobian_vector_products(inputs, directions, products)?;
        Ok(true)
    }
}

/// What a learned output measures, written by the user: h(x) and its Jacobian H
/// (e.g. the velocity in the body frame at the DVL). The learned model supplies the
/// value y and its error covariance R; this trait supplies the rest of the
/// measurement model (see [`LearnedSensor`]).
pub trait Observation<T: estim_core::Scalar, const N: usize, const M: usize> {
    /// The state h reads.
    type State;
    /// h(x).
    ///
    /// # Errors
    /// The user's (e.g. a state outside h's domain).
    fn predict(&self, state: &Self::State) -> estim_core::Result<SVector<T, M>>;
    /// H = dh/dx at `state` (in the filter's error convention).
    ///
    /// # Errors
    /// As [`Observation::predict`].
    fn jacobian(&self, state: &Self::State) -> estim_core::Result<SMatrix<T, M, N>>;
}

/// The common case of an [`Observation`]: the learned output measures a linear
/// function of a vector state, h(x) = H x with a constant H (e.g. a position fix, H =
/// I; a velocity out of \[position; velocity\], H = \[0 I\]). For a state that is not
/// an `SVector` (an error-state filter's nominal state), or a nonlinear h, implement
/// [`Observation`].
///
/// ```
/// use estim_core::nalgebra::{Matrix1x2, Vector1, Vector2};
/// use estim_learned::{LinearObservation, Observation};
///
/// // The velocity of a [position; velocity] state.
/// let velocity = LinearObservation::new(Matrix1x2::new(0.0, 1.0));
/// let x = Vector2::new(3.0, -0.5);
/// assert_eq!(velocity.predict(&x)?, Vector1::new(-0.5));
/// assert_eq!(velocity.jacobian(&x)?, Matrix1x2::new(0.0, 1.0));
/// # Ok::<(), estim_core::Error>(())
/// ```
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinearObservation<T: estim_core::Scalar, const N: usize, const M: usize> {
    jacobian: SMatrix<T, M, N>,
}

impl<T: estim_core::Scalar, const N: usize, const M: usize> LinearObservation<T, N, M> {
    /// h(x) = `jacobian` x.
    pub fn new(jacobian: SMatrix<T, M, N>) -> Self {
        Self { jacobian }
    }
}

impl<T: estim_core::Scalar, const N: usize, const M: usize> Observation<T, N, M>
    for LinearObservation<T, N, M>
{
    type State = SVector<T, N>;

    fn predict(&self, state: &SVector<T, N>) -> estim_core::Result<SVector<T, M>> {
        Ok(self.jacobian * state)
    }

    fn jacobian(&self, _state: &SVector<T, N>) -> estim_core::Result<SMatrix<T, M, N>> {
        Ok(self.jacobian)
    }
}

/// A [`LearnedMeasurement`] plus the user's [`Observation`] (h(x), H) as an estim-core
/// [`MeasurementModel`](estim_core::MeasurementModel), with R from the learned model.
///
/// One type implementing both `LearnedMeasurement` and `MeasurementModel` does not
/// compile cleanly (both traits have a `noise_covariance`, E0034 at the call site);
/// this adapter keeps them apart. It borrows the learned model, so building one per
/// update costs nothing.
#[derive(Debug, Clone, Copy)]
pub struct LearnedSensor<'a, L: ?Sized, H> {
    learned: &'a L,
    observation: H,
}

impl<'a, L: ?Sized, H> LearnedSensor<'a, L, H> {
    /// The learned model's output, observed through `observation`.
    pub fn new(learned: &'a L, observation: H) -> Self {
        Self {
            learned,
            observation,
        }
    }

    /// The learned model.
    pub fn learned(&self) -> &'a L {
        self.learned
    }

    /// The user's observation.
    pub fn observation(&self) -> &H {
        &self.observation
    }
}

impl<T, L, H, const N: usize, const M: usize> estim_core::MeasurementModel<T, N, M>
    for LearnedSensor<'_, L, H>
where
    T: estim_core::Scalar,
    L: LearnedMeasurement<T, M> + ?Sized,
    H: Observation<T, N, M>,
{
    type State = H::State;

    fn predict(&self, state: &H::State) -> estim_core::Result<SVector<T, M>> {
        self.observation.predict(state)
    }

    fn jacobian(&self, state: &H::State) -> estim_core::Result<SMatrix<T, M, N>> {
        self.observation.jacobian(state)
    }

    fn noise_covariance(&self, _state: &H::State) -> estim_core::Result<SMatrix<T, M, M>> {
        Ok(self.learned.noise_covariance())
    }
}
