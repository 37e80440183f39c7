//! [`OutageNet`]: an IMU window plus the last valid DVL velocity and the time since it
//! -> body velocity, a pseudo-measurement at 1 Hz through a full DVL outage of up to
//! 60 s (training/outage.py).

use std::path::{Path, PathBuf};

use nalgebra::{DMatrix, Vector3};

use crate::beamsnet::BEAMSNET_WINDOW;
use crate::measurement::OnnxMeasurement;
use crate::{Error, Result};

/// The committed model, `models/outage.onnx` at the workspace root.
pub fn default_outage_model_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join("models")
        .join("outage.onnx")
}

/// OutageNet as a learned measurement of the body-frame DVL velocity: inputs `acc`
/// 3 x 100, `gyro` 3 x 100, `last_velocity` 3 x 1 (m/s), `elapsed` 1 x 1 (s).
#[derive(Debug, Clone)]
pub struct OutageNet {
    inner: OnnxMeasurement<3>,
    max_elapsed_s: f64,
}

impl OutageNet {
    /// Load an ONNX file and its metadata (`<model>.json` beside it). The longest
    /// elapsed time it was trained on is read from `training.max_elapsed_s` (default
    /// 60 s).
    ///
    /// # Errors
    /// The loader's errors; [`Error::MalformedMetadata`] if the inputs are not acc and
    /// gyro windows of 100 samples, a 3-vector and a scalar, or the maximum elapsed time
    /// is not positive.
    pub fn load(model_path: &Path) -> Result<Self> {
        Self::from_measurement(
            OnnxMeasurement::<3>::from_model_path(model_path)?,
            model_path,
        )
    }

    /// [`OutageNet::load`] from the bytes of the ONNX file and the text of its metadata
    /// JSON (e.g. embedded in a binary); `name` names the model in errors.
    ///
    /// # Errors
    /// As [`OutageNet::load`].
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
            "OutageNet",
            &[
                ("acc", 3, BEAMSNET_WINDOW),
                ("gyro", 3, BEAMSNET_WINDOW),
                ("last_velocity", 3, 1),
                ("elapsed", 1, 1),
            ],
        )?;
        let max_elapsed_s = match meta.training.as_ref().and_then(|t| t.get("max_elapsed_s")) {
            None => 60.0,
            Some(v) => v
                .as_f64()
                .filter(|s| s.is_finite() && *s > 0.0)
                .ok_or_else(|| {
                    bad(format!(
                        "training.max_elapsed_s must be a positive number, got {v}"
                    ))
                })?,
        };
        Ok(Self {
            inner,
            max_elapsed_s,
        })
    }

    /// The committed model ([`default_outage_model_path`]).
    ///
    /// # Errors
    /// As [`OutageNet::load`].
    pub fn load_default() -> Result<Self> {
        Self::load(&default_outage_model_path())
    }

    /// The generic measurement underneath.
    pub fn measurement(&self) -> &OnnxMeasurement<3> {
        &self.inner
    }

    /// The longest time since the last valid velocity the network was trained on \[s\].
    pub fn max_elapsed_s(&self) -> f64 {
        self.max_elapsed_s
    }

    /// The per-update inputs (`last_velocity` 3 x 1, `elapsed` 1 x 1), or `None` when
    /// the velocity is not finite or the elapsed time is not in (0, max_elapsed_s]
    /// (the network is not used outside what it was trained on). With the IMU window
    /// they are what [`LearnedCrossCovariance`](crate::LearnedCrossCovariance) and
    /// [`Empirical::for_model`](crate::Empirical::for_model) take as `extra`: neither
    /// depends on the IMU noise.
    pub fn extra_inputs(
        &self,
        last_velocity: &Vector3<f64>,
        elapsed_s: f64,
    ) -> Option<Vec<DMatrix<f64>>> {
        let usable = last_velocity.iter().all(|v| v.is_finite())
            && elapsed_s.is_finite()
            && elapsed_s > 0.0
            && elapsed_s <= self.max_elapsed_s;
        usable.then(|| {
            vec![
                DMatrix::from_column_slice(3, 1, last_velocity.as_slice()),
                DMatrix::from_element(1, 1, elapsed_s),
            ]
        })
    }
}
