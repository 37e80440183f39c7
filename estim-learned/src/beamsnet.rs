//! [`BeamsNet`]: the BeamsNetV1 ONNX model (IMU windows + 4 DVL beams -> body velocity).

use std::path::{Path, PathBuf};

use estim_core::LearnedMeasurement;
use nalgebra::{DMatrix, Matrix3, Vector3, Vector4};

use crate::measurement::OnnxMeasurement;
use crate::Result;

/// Samples per IMU window of BeamsNetV1 (1 s at 100 Hz).
pub const BEAMSNET_WINDOW: usize = 100;

/// The committed model, `models/beamsnet.onnx` at the workspace root (metadata beside it).
pub fn default_model_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join("models")
        .join("beamsnet.onnx")
}

/// One BeamsNet input: the IMU window preceding a DVL sample and the 4 beams of that
/// sample.
#[derive(Debug, Clone, PartialEq)]
pub struct BeamsNetInput {
    /// Specific force f^b, 3 x 100 (rows x, y, z; columns oldest first) [m/s^2].
    pub acc: DMatrix<f64>,
    /// Angular rate ω_ib^b, 3 x 100 [rad/s].
    pub gyro: DMatrix<f64>,
    /// Beam velocities \[m/s\].
    pub beams: Vector4<f64>,
}

impl BeamsNetInput {
    /// From per-sample specific force and angular rate (oldest first) and the beams.
    pub fn from_samples(
        specific_force: &[Vector3<f64>],
        angular_rate: &[Vector3<f64>],
        beams: Vector4<f64>,
    ) -> Self {
        let to_matrix = |s: &[Vector3<f64>]| DMatrix::from_fn(3, s.len(), |r, c| s[c][r]);
        Self {
            acc: to_matrix(specific_force),
            gyro: to_matrix(angular_rate),
            beams,
        }
    }

    /// The inputs in [`LearnedMeasurement`] order: acc (3 x 100), gyro (3 x 100),
    /// beams (4 x 1).
    pub fn to_inputs(&self) -> Vec<DMatrix<f64>> {
        vec![
            self.acc.clone(),
            self.gyro.clone(),
            DMatrix::from_column_slice(4, 1, self.beams.as_slice()),
        ]
    }
}

/// BeamsNetV1 as a learned measurement of the body-frame DVL velocity.
///
/// A thin layer over [`OnnxMeasurement<3>`] that checks the metadata declares the
/// BeamsNet inputs (`acc` 3 x 100, `gyro` 3 x 100, `beams` 4 x 1).
#[derive(Debug, Clone)]
pub struct BeamsNet {
    inner: OnnxMeasurement<3>,
}

impl BeamsNet {
    /// Load an ONNX file and its metadata (`<model>.json` beside it).
    pub fn load(model_path: &Path) -> Result<Self> {
        Self::from_measurement(
            OnnxMeasurement::<3>::from_model_path(model_path)?,
            model_path,
        )
    }

    /// [`BeamsNet::load`] from the bytes of the ONNX file and the text of its metadata
    /// JSON (e.g. embedded in a binary); `name` names the model in errors.
    ///
    /// # Errors
    /// As [`BeamsNet::load`].
    pub fn from_bytes(onnx: &[u8], metadata_json: &str, name: &Path) -> Result<Self> {
        Self::from_measurement(
            OnnxMeasurement::<3>::from_bytes(onnx, metadata_json, name)?,
            name,
        )
    }

    fn from_measurement(inner: OnnxMeasurement<3>, model_path: &Path) -> Result<Self> {
        inner.require_inputs(
            model_path,
            "BeamsNet",
            &[
                ("acc", 3, BEAMSNET_WINDOW),
                ("gyro", 3, BEAMSNET_WINDOW),
                ("beams", 4, 1),
            ],
        )?;
        Ok(Self { inner })
    }

    /// The committed model ([`default_model_path`]).
    pub fn load_default() -> Result<Self> {
        Self::load(&default_model_path())
    }

    /// The generic measurement underneath.
    pub fn measurement(&self) -> &OnnxMeasurement<3> {
        &self.inner
    }

    /// Body-frame velocity for one input.
    pub fn velocity(&self, input: &BeamsNetInput) -> Result<Vector3<f64>> {
        Ok(self.inner.measure(&input.to_inputs())?)
    }

    /// Body-frame velocities for many inputs, in one batched inference.
    pub fn velocities(&self, inputs: &[BeamsNetInput]) -> Result<Vec<Vector3<f64>>> {
        let batch: Vec<Vec<DMatrix<f64>>> = inputs.iter().map(|i| i.to_inputs()).collect();
        self.inner.measure_batch(&batch)
    }

    /// R, the output error covariance from the validation residuals.
    pub fn noise_covariance(&self) -> Matrix3<f64> {
        self.inner.noise_covariance()
    }
}
