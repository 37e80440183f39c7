//! [`OnnxMeasurement`]: any ONNX model described by a [`ModelMetadata`] file, as an
//! estim-core [`LearnedMeasurement`].

use std::path::Path;

use estim_core::{InputSpec, LearnedMeasurement};
use nalgebra::{DMatrix, SMatrix, SVector};

use crate::metadata::ModelMetadata;
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
#[derive(Debug, Clone)]
pub struct OnnxMeasurement<const M: usize> {
    metadata: ModelMetadata,
    model: OnnxModel,
    specs: Vec<InputSpec>,
    noise_covariance: SMatrix<f64, M, M>,
    sensitivity_step: f64,
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

    fn new(model_path: &Path, metadata: ModelMetadata, metadata_path: &Path) -> Result<Self> {
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
        let model = OnnxModel::load(model_path, &metadata.inputs, &metadata.output)?;
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

    /// Check one set of input windows against the specs and append their normalised
    /// `f32` values to `tensors[k]`.
    fn append_normalised(&self, inputs: &[DMatrix<f64>], tensors: &mut [Vec<f32>]) -> Result<()> {
        let expected = || {
            self.metadata
                .inputs
                .iter()
                .map(|i| format!("{} ({}): {} x {}", i.stream, i.name, i.channels, i.window))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let given = || {
            inputs
                .iter()
                .map(|m| format!("{} x {}", m.nrows(), m.ncols()))
                .collect::<Vec<_>>()
                .join(", ")
        };
        if inputs.len() != self.metadata.inputs.len()
            || inputs
                .iter()
                .zip(&self.metadata.inputs)
                .any(|(m, i)| m.nrows() != i.channels || m.ncols() != i.window)
        {
            return Err(Error::InputMismatch {
                expected: format!("{} inputs [{}]", self.metadata.inputs.len(), expected()),
                given: format!("{} inputs [{}]", inputs.len(), given()),
            });
        }
        for ((m, meta), out) in inputs.iter().zip(&self.metadata.inputs).zip(tensors) {
            for c in 0..meta.channels {
                for s in 0..meta.window {
                    let raw = m[(c, s)];
                    if !raw.is_finite() {
                        return Err(Error::InputMismatch {
                            expected: format!("finite samples in {}", meta.stream),
                            given: format!("{raw} at channel {c}, sample {s}"),
                        });
                    }
                    out.push(((raw - meta.mean[c]) / meta.std[c]) as f32);
                }
            }
        }
        Ok(())
    }

    /// Run the model on several sets of inputs in one batched inference.
    pub fn measure_batch(&self, batch: &[Vec<DMatrix<f64>>]) -> Result<Vec<SVector<f64, M>>> {
        let mut tensors = vec![Vec::new(); self.metadata.inputs.len()];
        for inputs in batch {
            self.append_normalised(inputs, &mut tensors)?;
        }
        let out = self.model.run(batch.len(), &tensors)?;
        Ok(out
            .chunks_exact(M)
            .map(|c| SVector::<f64, M>::from_iterator(c.iter().map(|&v| f64::from(v))))
            .collect())
    }

    /// Run the model on already-normalised `f32` tensors (`batch x shape` each, in the
    /// metadata's input order), e.g. parity vectors exported from training.
    pub fn run_normalised(
        &self,
        batch: usize,
        tensors: &[Vec<f32>],
    ) -> Result<Vec<SVector<f64, M>>> {
        let out = self.model.run(batch, tensors)?;
        Ok(out
            .chunks_exact(M)
            .map(|c| SVector::<f64, M>::from_iterator(c.iter().map(|&v| f64::from(v))))
            .collect())
    }

    /// Jacobian-vector products by forward finite differences, all in ONE batched
    /// inference of `1 + directions.len()` elements: for each direction d (one matrix
    /// per input, raw units), (f(x + s d) - f(x)) / s with s chosen so that the largest
    /// normalised component of s d equals the sensitivity step.
    pub fn jacobian_vector_products(
        &self,
        inputs: &[DMatrix<f64>],
        directions: &[Vec<DMatrix<f64>>],
    ) -> Result<Vec<SVector<f64, M>>> {
        if !(self.sensitivity_step.is_finite() && self.sensitivity_step > 0.0) {
            return Err(Error::InvalidInput {
                what: "sensitivity step",
                reason: format!("{} must be positive", self.sensitivity_step),
            });
        }
        let mut batch = Vec::with_capacity(directions.len() + 1);
        batch.push(inputs.to_vec());
        let mut scales = Vec::with_capacity(directions.len());
        for d in directions {
            if d.len() != inputs.len() || d.iter().zip(inputs).any(|(a, b)| a.shape() != b.shape())
            {
                return Err(Error::InputMismatch {
                    expected: "one direction matrix per input, same shapes as the inputs".into(),
                    given: format!(
                        "[{}]",
                        d.iter()
                            .map(|m| format!("{} x {}", m.nrows(), m.ncols()))
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                });
            }
            // Largest component in normalised units.
            let largest = d
                .iter()
                .zip(&self.metadata.inputs)
                .flat_map(|(m, meta)| {
                    m.row_iter().enumerate().flat_map(move |(c, row)| {
                        row.iter()
                            .map(move |v| (v / meta.std[c]).abs())
                            .collect::<Vec<_>>()
                    })
                })
                .fold(0.0, f64::max);
            let s = if largest > 0.0 {
                self.sensitivity_step / largest
            } else {
                0.0
            };
            scales.push(s);
            batch.push(inputs.iter().zip(d).map(|(x, dx)| x + dx * s).collect());
        }
        let out = self.measure_batch(&batch)?;
        Ok(out[1..]
            .iter()
            .zip(&scales)
            .map(|(y, &s)| {
                if s > 0.0 {
                    (y - out[0]) / s
                } else {
                    SVector::zeros()
                }
            })
            .collect())
    }
}

impl<const M: usize> LearnedMeasurement<f64, M> for OnnxMeasurement<M> {
    fn input_specs(&self) -> &[InputSpec] {
        &self.specs
    }

    fn measure(&self, inputs: &[DMatrix<f64>]) -> estim_core::Result<SVector<f64, M>> {
        let mut out = self.measure_batch(&[inputs.to_vec()])?;
        out.pop()
            .ok_or_else(|| estim_core::Error::Model("model produced no output".into()))
    }

    fn noise_covariance(&self) -> SMatrix<f64, M, M> {
        self.noise_covariance
    }

    fn sensitivity(
        &self,
        inputs: &[DMatrix<f64>],
        directions: &[Vec<DMatrix<f64>>],
    ) -> estim_core::Result<Option<Vec<SVector<f64, M>>>> {
        Ok(Some(self.jacobian_vector_products(inputs, directions)?))
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
