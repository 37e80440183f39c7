//! [`TwoBeamsNet`]: an IMU window plus two of the four DVL beams -> body velocity (the
//! missing-beams case; training/two_beams.py).

use std::path::{Path, PathBuf};

use nalgebra::{DMatrix, Vector4};

use crate::beamsnet::BEAMSNET_WINDOW;
use crate::measurement::OnnxMeasurement;
use crate::{Error, Result};

/// The committed model, `models/two_beams.onnx` at the workspace root.
pub fn default_two_beams_model_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join("models")
        .join("two_beams.onnx")
}

/// TwoBeamsNet as a learned measurement of the body-frame DVL velocity: inputs `acc`
/// 3 x 100, `gyro` 3 x 100, `beams` 2 x 1 (the two beams listed by
/// [`TwoBeamsNet::beams_used`]).
#[derive(Debug, Clone)]
pub struct TwoBeamsNet {
    inner: OnnxMeasurement<3>,
    beams_used: [usize; 2],
}

impl TwoBeamsNet {
    /// Load an ONNX file and its metadata (`<model>.json` beside it). The beams used
    /// are read from the metadata's `training.beams_used` (1-based; default 1 and 2).
    pub fn load(model_path: &Path) -> Result<Self> {
        Self::from_measurement(
            OnnxMeasurement::<3>::from_model_path(model_path)?,
            model_path,
        )
    }

    /// [`TwoBeamsNet::load`] from the bytes of the ONNX file and the text of its metadata
    /// JSON (e.g. embedded in a binary); `name` names the model in errors.
    ///
    /// # Errors
    /// As [`TwoBeamsNet::load`].
    pub fn from_bytes(onnx: &[u8], metadata_json: &str, name: &Path) -> Result<Self> {
        Self::from_measurement(
            OnnxMeasurement::<3>::from_bytes(onnx, metadata_json, name)?,
            name,
        )
    }

    fn from_measurement(inner: OnnxMeasurement<3>, model_path: &Path) -> Result<Self> {
        let meta = inner.metadata();
        let bad = |reason: String| Error::MalformedMetadata {
            path: model_path.with_extension("json"),
            reason,
        };
        inner.require_inputs(
            model_path,
            "TwoBeamsNet",
            &[
                ("acc", 3, BEAMSNET_WINDOW),
                ("gyro", 3, BEAMSNET_WINDOW),
                ("beams", 2, 1),
            ],
        )?;
        let used = match meta.training.as_ref().and_then(|t| t.get("beams_used")) {
            None => [1, 2],
            Some(v) => {
                let list: Vec<u64> = v
                    .as_array()
                    .map(|a| a.iter().filter_map(serde_json::Value::as_u64).collect())
                    .unwrap_or_default();
                match list.as_slice() {
                    [a, b] if (1..=4).contains(a) && (1..=4).contains(b) && a != b => {
                        [*a as usize, *b as usize]
                    }
                    _ => {
                        return Err(bad(format!(
                            "training.beams_used must be two different beams in 1..=4, got {v}"
                        )))
                    }
                }
            }
        };
        Ok(Self {
            inner,
            beams_used: [used[0] - 1, used[1] - 1],
        })
    }

    /// The committed model ([`default_two_beams_model_path`]).
    pub fn load_default() -> Result<Self> {
        Self::load(&default_two_beams_model_path())
    }

    /// The generic measurement underneath.
    pub fn measurement(&self) -> &OnnxMeasurement<3> {
        &self.inner
    }

    /// The two beams fed to the network (0-based indices into the four beams).
    pub fn beams_used(&self) -> [usize; 2] {
        self.beams_used
    }

    /// The network's per-update input (the `beams` stream, 2 x 1) picked from four
    /// beam readings; `None` if one of the two it uses is missing (not finite). With
    /// the IMU window it is what [`LearnedCrossCovariance`](crate::LearnedCrossCovariance)
    /// and [`Empirical::for_model`](crate::Empirical::for_model) take as `extra`.
    pub fn beam_inputs(&self, beams: &Vector4<f64>) -> Option<Vec<DMatrix<f64>>> {
        let picked = self.beams_used.map(|i| beams[i]);
        picked
            .iter()
            .all(|b| b.is_finite())
            .then(|| vec![DMatrix::from_column_slice(2, 1, &picked)])
    }
}
