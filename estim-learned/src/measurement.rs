//! [`OnnxMeasurement`]: any ONNX model described by a [`ModelMetadata`] file, as an
//! estim-core [`LearnedMeasurement`].

use std::path::Path;
use std::sync::Mutex;

use estim_core::{InputSpec, LearnedMeasurement};
use nalgebra::{DMatrix, SMatrix, SVector};

use crate::metadata::{InputMetadata, ModelMetadata, OutputMetadata};
use crate::onnx::OnnxModel;
use crate::{Error, Result};

/// Default central-difference step of [`OnnxMeasurement::sensitivity`], in normalised
/// input units (the inputs are normalised to unit standard deviation per channel).
///
/// The central difference's truncation error grows with the step (as step² from the
/// networks' curvature, faster where the two evaluations straddle a ReLU kink) and its
/// rounding error as u / step (float32 inputs and outputs, unit roundoff u = 2^-24);
/// for a smooth response the sum is smallest near u^(1/3) = 3.9e-3 (Nocedal & Wright,
/// Numerical Optimization, 2nd ed., §8.1).
/// Measured on the outage and two-beams networks (the `step_insensitive` tests in
/// `estim-learned/tests/outage.rs` and `tests/two_beams.rs`,
/// `cargo test --release -p estim-learned step_insensitive -- --nocapture`): their
/// first-order M changes by at most 2.3 % over steps 2e-3 to 5e-3, and by up to 26 %
/// at 1e-2 (ReLU kinks straddled) and 36 % at 1e-4 (rounding).
pub const DEFAULT_SENSITIVITY_STEP: f64 = 4e-3;

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

    /// Replace the central-difference step of [`LearnedMeasurement::sensitivity`]
    /// (normalised input units, > 0; default [`DEFAULT_SENSITIVITY_STEP`]).
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

    /// Jacobian-vector products by central finite differences, all in ONE batched
    /// inference of `2 * products.len()` elements: for each direction d (one matrix
    /// per input, raw units; the directions one after another in `directions`, as in
    /// [`LearnedMeasurement::sensitivity`]), product = (f(x + s d) - f(x - s d)) / (2 s)
    /// with s chosen so that the largest normalised component of s d equals the
    /// sensitivity step (see [`DEFAULT_SENSITIVITY_STEP`]). The error is O(s²) (exact
    /// for a quadratic response up to float32 rounding), where a forward difference
    /// (f(x + s d) - f(x)) / s would carry an O(s) curvature term. The perturbed inputs are written straight into the model's input tensors
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
        // Batch element 2 i is x + s_i d_i, element 2 i + 1 is x - s_i d_i.
        self.model.run_with(
            2 * products.len(),
            |k, values| {
                let size = self.element_size(k);
                let pairs = values.chunks_exact_mut(2 * size);
                for ((d, &s), pair) in directions.chunks_exact(streams).zip(scales).zip(pairs) {
                    let (plus, minus) = pair.split_at_mut(size);
                    self.write_normalised(k, &inputs[k], Some((&d[k], s)), plus)?;
                    self.write_normalised(k, &inputs[k], Some((&d[k], -s)), minus)?;
                }
                Ok(())
            },
            |values| {
                let pairs = values.chunks_exact(2 * M);
                for ((pair, &s), product) in pairs.zip(scales).zip(products.iter_mut()) {
                    *product = if s > 0.0 {
                        let (plus, minus) = pair.split_at(M);
                        (to_output::<M>(plus) - to_output::<M>(minus)) / (2.0 * s)
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

    /// Central-difference Jacobian-vector products in one batched inference
    /// ([`OnnxMeasurement::jacobian_vector_products`]); always available.
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

#[cfg(test)]
mod tests {
    use super::*;
    use prost::Message;
    use tract_onnx::pb;

    const CHANNELS: usize = 3;
    const WINDOW: usize = 4;
    const INPUTS: usize = CHANNELS * WINDOW;
    const MEAN: [f64; CHANNELS] = [0.5, -1.0, 2.0];
    const STD: [f64; CHANNELS] = [2.0, 0.5, 1.0];

    /// Weights of the quadratic test model y = (z ∘ z) A + z B (z: the normalised input,
    /// flattened channel-major): A all positive so that a forward difference's
    /// curvature term s (dz ∘ dz) A cannot cancel.
    fn quadratic_weight(j: usize, m: usize) -> f32 {
        0.25 + 0.05 * ((j * 7 + m * 3) % 11) as f32
    }
    fn linear_weight(j: usize, m: usize) -> f32 {
        0.2 * ((j * 5 + m) % 7) as f32 - 0.6
    }

    fn tensor_type(dims: &[pb::tensor_shape_proto::dimension::Value]) -> Option<pb::TypeProto> {
        let dim = dims
            .iter()
            .map(|v| pb::tensor_shape_proto::Dimension {
                value: Some(v.clone()),
                ..Default::default()
            })
            .collect();
        Some(pb::TypeProto {
            value: Some(pb::type_proto::Value::TensorType(pb::type_proto::Tensor {
                elem_type: pb::tensor_proto::DataType::Float as i32,
                shape: Some(pb::TensorShapeProto { dim }),
            })),
            ..Default::default()
        })
    }

    fn node(op: &str, inputs: &[&str], output: &str) -> pb::NodeProto {
        pb::NodeProto {
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: vec![output.to_string()],
            name: output.to_string(),
            op_type: op.to_string(),
            ..Default::default()
        }
    }

    fn weights(name: &str, w: impl Fn(usize, usize) -> f32) -> pb::TensorProto {
        pb::TensorProto {
            dims: vec![INPUTS as i64, 2],
            data_type: pb::tensor_proto::DataType::Float as i32,
            float_data: (0..INPUTS)
                .flat_map(|j| (0..2).map(move |m| (j, m)))
                .map(|(j, m)| w(j, m))
                .collect(),
            name: name.to_string(),
            ..Default::default()
        }
    }

    /// ONNX bytes of x [batch, 3, 4] -> y [batch, 2] = (z ∘ z) A + z B, z = flatten(x).
    fn quadratic_onnx() -> Vec<u8> {
        use pb::tensor_shape_proto::dimension::Value;
        let graph = pb::GraphProto {
            node: vec![
                node("Flatten", &["x"], "z"),
                node("Mul", &["z", "z"], "zz"),
                node("MatMul", &["zz", "a"], "qa"),
                node("MatMul", &["z", "b"], "lb"),
                node("Add", &["qa", "lb"], "y"),
            ],
            name: "quadratic".into(),
            initializer: vec![weights("a", quadratic_weight), weights("b", linear_weight)],
            input: vec![pb::ValueInfoProto {
                name: "x".into(),
                r#type: tensor_type(&[
                    Value::DimParam("batch".into()),
                    Value::DimValue(CHANNELS as i64),
                    Value::DimValue(WINDOW as i64),
                ]),
                ..Default::default()
            }],
            output: vec![pb::ValueInfoProto {
                name: "y".into(),
                r#type: tensor_type(&[Value::DimParam("batch".into()), Value::DimValue(2)]),
                ..Default::default()
            }],
            ..Default::default()
        };
        pb::ModelProto {
            ir_version: 7,
            opset_import: vec![pb::OperatorSetIdProto {
                domain: String::new(),
                version: 13,
            }],
            graph: Some(graph),
            ..Default::default()
        }
        .encode_to_vec()
    }

    fn quadratic_model() -> OnnxMeasurement<2> {
        let metadata = serde_json::json!({
            "format": crate::metadata::METADATA_FORMAT,
            "name": "quadratic",
            "model": "quadratic.onnx",
            "inputs": [{
                "name": "x", "stream": "x", "channels": CHANNELS, "window": WINDOW,
                "sample_rate_hz": 100.0, "shape": [CHANNELS, WINDOW],
                "mean": MEAN, "std": STD,
            }],
            "output": {"name": "y", "size": 2},
            "noise_covariance": [[1.0, 0.0], [0.0, 1.0]],
        });
        OnnxMeasurement::from_bytes(
            &quadratic_onnx(),
            &metadata.to_string(),
            Path::new("quadratic.onnx"),
        )
        .unwrap()
    }

    /// The normalised input z and normalised direction dz of raw matrices, flattened
    /// channel-major.
    fn normalised(raw: &DMatrix<f64>, mean: bool) -> Vec<f64> {
        (0..CHANNELS)
            .flat_map(|c| (0..WINDOW).map(move |s| (c, s)))
            .map(|(c, s)| (raw[(c, s)] - if mean { MEAN[c] } else { 0.0 }) / STD[c])
            .collect()
    }

    /// The central difference is exact for a quadratic response: the JVPs equal the
    /// analytic directional derivative 2 (z ∘ dz) A + dz B within the float32 rounding
    /// bound 16 u F / s (u = 2^-24; F the sum of the absolute terms of y; a 12-term
    /// dot product plus the rounding of the inputs, Higham, Accuracy and Stability of
    /// Numerical Algorithms, 2nd ed., §3.1) at every step, where a forward difference
    /// would be off by its curvature term s (dz ∘ dz) A, above 10 times that bound at
    /// steps 1e-1 and 1e-2. Three directions in one batch, one of them zero.
    #[test]
    fn central_jvp_is_exact_for_a_quadratic_response() {
        let x = DMatrix::from_fn(CHANNELS, WINDOW, |c, s| {
            MEAN[c] + STD[c] * 1.5 * ((3 * c + s) as f64 * 0.7).sin()
        });
        let directions = [
            DMatrix::from_fn(CHANNELS, WINDOW, |c, s| ((c + 2 * s) as f64).cos()),
            DMatrix::from_fn(
                CHANNELS,
                WINDOW,
                |c, s| if (c, s) == (1, 2) { 0.3 } else { 0.0 },
            ),
            DMatrix::zeros(CHANNELS, WINDOW),
        ];
        let z = normalised(&x, true);
        let u = f64::from(f32::EPSILON) / 2.0;
        for step in [1e-1, 1e-2, DEFAULT_SENSITIVITY_STEP] {
            let model = quadratic_model().with_sensitivity_step(step);
            let mut products = [SVector::<f64, 2>::zeros(); 3];
            model
                .jacobian_vector_products(std::slice::from_ref(&x), &directions, &mut products)
                .unwrap();
            for (d, product) in directions.iter().zip(&products) {
                let dz = normalised(d, false);
                let largest = dz.iter().fold(0.0f64, |a, v| a.max(v.abs()));
                if largest == 0.0 {
                    assert_eq!(*product, SVector::<f64, 2>::zeros());
                    continue;
                }
                let s = step / largest;
                for m in 0..2 {
                    let (a, b) = (
                        |j| f64::from(quadratic_weight(j, m)),
                        |j| f64::from(linear_weight(j, m)),
                    );
                    let exact: f64 = (0..INPUTS)
                        .map(|j| 2.0 * z[j] * dz[j] * a(j) + dz[j] * b(j))
                        .sum();
                    let terms: f64 = (0..INPUTS)
                        .map(|j| {
                            let zj = z[j].abs() + s * dz[j].abs();
                            zj * zj * a(j) + zj * b(j).abs()
                        })
                        .sum();
                    let bound = 16.0 * u * terms / s;
                    let curvature: f64 = s * (0..INPUTS).map(|j| dz[j] * dz[j] * a(j)).sum::<f64>();
                    let error = (product[m] - exact).abs();
                    println!(
                        "step {step:e} output {m}: |error| {error:.2e}, bound {bound:.2e}, \
                         forward's curvature term {curvature:.2e}"
                    );
                    assert!(error <= bound, "step {step}: {} vs {exact}", product[m]);
                    if step >= 1e-2 && dz.iter().filter(|v| **v != 0.0).count() > 1 {
                        assert!(
                            curvature > 10.0 * bound,
                            "step {step}: {curvature} vs {bound}"
                        );
                    }
                }
            }
        }
    }
}
