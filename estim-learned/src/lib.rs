//! # estim-learned: ONNX models as learned measurements, BeamsNet, network-derived cross-covariance.
//!
//! - [`OnnxMeasurement`]: any ONNX model + its metadata file as an estim-core
//!   [`LearnedMeasurement`](estim_core::LearnedMeasurement) (inputs declared per
//!   stream and window, normalisation and R from the metadata, batched finite-difference
//!   Jacobian-vector products);
//! - [`BeamsNet`]: BeamsNetV1 (IMU windows + 4 beams -> body velocity);
//! - [`synthesize`], [`dataset_row`], [`write_npy`]: BeamsNet training data;
//! - [`metrics`](fn@metrics), [`speed_metrics`], [`evaluate`]: the paper's RMSE, MAE, R^2, VAF.
//!
//! tract is used in one private module only.
#![warn(missing_docs)]

mod beamsnet;
mod dataset;
mod error;
mod evaluation;
mod measurement;
mod metadata;
mod metrics;
mod onnx;
mod sensitivity;

pub use beamsnet::{default_model_path, BeamsNet, BeamsNetInput, BEAMSNET_WINDOW};
pub use dataset::{
    dataset_row, synthesize, write_npy, BeamsNetSample, SynthesizedRun, DATASET_COLUMNS,
    IMU_RATE_HZ,
};
pub use error::{Error, Result};
pub use evaluation::{evaluate, Evaluation};
pub use measurement::{OnnxMeasurement, DEFAULT_SENSITIVITY_STEP};
pub use metadata::{
    BeamGeometryMetadata, InputMetadata, ModelMetadata, OutputMetadata, METADATA_FORMAT,
};
pub use metrics::{metrics, speed_metrics, Metrics};
pub use sensitivity::{CrossMatrix, Empirical, EmpiricalEstimate, ImuWindow, NetworkSensitivity};
