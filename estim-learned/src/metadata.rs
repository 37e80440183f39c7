//! The metadata file stored beside an ONNX model (`<model>.json`).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::{Error, Result};

/// Format tag of the metadata files this crate reads.
pub const METADATA_FORMAT: &str = "estim-learned-model/1";

/// One input tensor of a model: which sensor stream feeds it, over what window, and
/// how its raw samples are normalised before inference
/// (`normalised = (raw - mean[channel]) / std[channel]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InputMetadata {
    /// Name of the ONNX input tensor.
    pub name: String,
    /// Sensor stream feeding it (e.g. `"acc"`).
    pub stream: String,
    /// Channels per sample.
    pub channels: usize,
    /// Samples per window.
    pub window: usize,
    /// Sample rate of the stream \[Hz\].
    pub sample_rate_hz: f64,
    /// Shape of the tensor without the batch axis (e.g. `[3, 100]` or `[4]`); its
    /// elements are the `channels x window` matrix in row-major (channel-major) order.
    pub shape: Vec<usize>,
    /// Per-channel mean subtracted before inference.
    pub mean: Vec<f64>,
    /// Per-channel standard deviation divided by before inference.
    pub std: Vec<f64>,
    /// Unit of the raw samples.
    #[serde(default)]
    pub unit: Option<String>,
    /// Free text.
    #[serde(default)]
    pub description: Option<String>,
}

/// The model output.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OutputMetadata {
    /// Name of the ONNX output tensor.
    pub name: String,
    /// Number of output values per batch element.
    pub size: usize,
    /// Unit.
    #[serde(default)]
    pub unit: Option<String>,
    /// Frame or meaning.
    #[serde(default)]
    pub frame: Option<String>,
}

/// Janus-configuration beam geometry recorded with a DVL model: beam i points along
/// `[cos(psi_i) sin(theta), sin(psi_i) sin(theta), cos(theta)]` (body frame).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BeamGeometryMetadata {
    /// Beam angle from the body z axis \[deg\].
    pub theta_deg: f64,
    /// Azimuth of each beam \[deg\].
    pub psi_deg: Vec<f64>,
}

/// Everything stored beside an ONNX model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelMetadata {
    /// Must equal [`METADATA_FORMAT`].
    pub format: String,
    /// Model name.
    pub name: String,
    /// ONNX file name, relative to the metadata file's folder.
    pub model: String,
    /// Input tensors, in the order of the ONNX graph inputs.
    pub inputs: Vec<InputMetadata>,
    /// The output tensor.
    pub output: OutputMetadata,
    /// Output error covariance R (from validation residuals), `size x size`, row-major rows.
    pub noise_covariance: Vec<Vec<f64>>,
    /// Beam geometry (DVL models only).
    #[serde(default)]
    pub beam_geometry: Option<BeamGeometryMetadata>,
    /// Beam simulation protocol used to make the training data (free form).
    #[serde(default)]
    pub beam_protocol: Option<serde_json::Value>,
    /// Training provenance: trajectories, seed, command, versions (free form).
    #[serde(default)]
    pub training: Option<serde_json::Value>,
}

impl ModelMetadata {
    /// Read and validate a metadata file.
    pub fn from_path(path: &Path) -> Result<Self> {
        if !path.is_file() {
            return Err(Error::MissingFile {
                path: path.to_path_buf(),
                what: "model metadata (JSON)",
            });
        }
        let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_json(&text, path)
    }

    /// Parse and validate metadata text; `path` is only used in error messages.
    pub fn from_json(text: &str, path: &Path) -> Result<Self> {
        let meta: ModelMetadata =
            serde_json::from_str(text).map_err(|e| Error::MalformedMetadata {
                path: path.to_path_buf(),
                reason: e.to_string(),
            })?;
        meta.check(path)?;
        Ok(meta)
    }

    /// The ONNX file this metadata describes (`model` relative to the metadata folder).
    pub fn model_path(&self, metadata_path: &Path) -> PathBuf {
        metadata_path
            .parent()
            .unwrap_or_else(|| Path::new("."))
            .join(&self.model)
    }

    /// Validate internal consistency.
    pub fn check(&self, path: &Path) -> Result<()> {
        let bad = |reason: String| Error::MalformedMetadata {
            path: path.to_path_buf(),
            reason,
        };
        if self.format != METADATA_FORMAT {
            return Err(bad(format!(
                "format is {:?}, expected {METADATA_FORMAT:?}",
                self.format
            )));
        }
        if self.inputs.is_empty() {
            return Err(bad("no inputs declared".into()));
        }
        for input in &self.inputs {
            let name = &input.name;
            if input.channels == 0 || input.window == 0 {
                return Err(bad(format!(
                    "input {name}: channels {} and window {} must be positive",
                    input.channels, input.window
                )));
            }
            let elems: usize = input.shape.iter().product();
            if input.shape.is_empty() || elems != input.channels * input.window {
                return Err(bad(format!(
                    "input {name}: shape {:?} does not hold channels x window = {} x {}",
                    input.shape, input.channels, input.window
                )));
            }
            if !(input.sample_rate_hz.is_finite() && input.sample_rate_hz > 0.0) {
                return Err(bad(format!(
                    "input {name}: sample_rate_hz {} must be positive",
                    input.sample_rate_hz
                )));
            }
            if input.mean.len() != input.channels || input.std.len() != input.channels {
                return Err(bad(format!(
                    "input {name}: mean/std have {}/{} entries, expected one per channel ({})",
                    input.mean.len(),
                    input.std.len(),
                    input.channels
                )));
            }
            if input.mean.iter().any(|m| !m.is_finite())
                || input.std.iter().any(|s| !(s.is_finite() && *s > 0.0))
            {
                return Err(bad(format!(
                    "input {name}: mean must be finite and std finite and positive"
                )));
            }
        }
        let m = self.output.size;
        if m == 0 {
            return Err(bad("output size is 0".into()));
        }
        if self.noise_covariance.len() != m || self.noise_covariance.iter().any(|r| r.len() != m) {
            return Err(bad(format!("noise_covariance must be {m} x {m}")));
        }
        for (i, row) in self.noise_covariance.iter().enumerate() {
            for (j, v) in row.iter().enumerate() {
                if !v.is_finite() {
                    return Err(bad(format!("noise_covariance[{i}][{j}] is not finite")));
                }
                let t = self.noise_covariance[j][i];
                if (v - t).abs() > 1e-9 * v.abs().max(t.abs()).max(f64::MIN_POSITIVE) {
                    return Err(bad(format!(
                        "noise_covariance is not symmetric at ({i}, {j})"
                    )));
                }
            }
            if row[i] <= 0.0 {
                return Err(bad(format!(
                    "noise_covariance[{i}][{i}] = {} must be positive",
                    row[i]
                )));
            }
        }
        if let Some(g) = &self.beam_geometry {
            if !g.theta_deg.is_finite() || g.psi_deg.is_empty() {
                return Err(bad("beam_geometry needs theta_deg and psi_deg".into()));
            }
        }
        Ok(())
    }
}
