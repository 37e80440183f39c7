//! # estim-learned: ONNX models as learned measurements, BeamsNet, network-derived cross-covariance.
//!
//! - [`OnnxMeasurement`]: any ONNX model + its metadata file as an estim-core
//!   [`LearnedMeasurement`](estim_core::LearnedMeasurement) (inputs declared per
//!   stream and window, normalisation and R from the metadata, batched finite-difference
//!   Jacobian-vector products);
//! - [`BeamsNet`]: BeamsNetV1 (IMU windows + 4 beams -> body velocity);
//! - [`TwoBeamsNet`]: IMU window + two beams -> body velocity (its M is the generic
//!   [`LearnedCrossCovariance`], by Monte Carlo [`Empirical::for_model`]);
//! - [`OutageNet`]: IMU window + last valid DVL velocity + time since it -> body
//!   velocity (a full DVL outage; M as for the two-beams network);
//! - [`metrics`](fn@metrics), [`speed_metrics`]: the paper's RMSE, MAE, R^2, VAF;
//! - [`NetworkSensitivity`], [`Empirical`]: the cross-covariance M between the INS
//!   process noise and the network's output error, from the network's own sensitivity
//!   (Jacobian-vector products in one batched inference) or by Monte Carlo.
//!
//! tract is used in one private module only.
//!
//! ```
//! use estim_core::LearnedMeasurement;
//! use estim_dvl::BeamGeometry;
//! use estim_learned::{default_model_path, OnnxMeasurement};
//! use nalgebra::{DMatrix, Vector3};
//!
//! // BeamsNet through the generic wrapper: inputs as declared by its metadata.
//! let model = OnnxMeasurement::<3>::from_model_path(&default_model_path())?;
//! let names: Vec<&str> = model.input_specs().iter().map(|s| s.name.as_str()).collect();
//! assert_eq!(names, ["acc", "gyro", "beams"]);
//! // A level vehicle moving forward at 2 m/s, steady: f_b = -g on z, no rotation, and
//! // the beams that velocity gives with the geometry BeamsNet was trained on.
//! let forward = Vector3::new(2.0, 0.0, 0.0);
//! let mut acc = DMatrix::zeros(3, 100);
//! acc.row_mut(2).fill(-9.8);
//! let gyro = DMatrix::zeros(3, 100);
//! let beams = BeamGeometry::beamsnet().beams(&forward);
//! let beams = DMatrix::from_column_slice(4, 1, beams.as_slice());
//! let velocity = model.measure(&[acc, gyro, beams])?;
//! assert!((velocity - forward).norm() < 0.1, "{velocity}");
//! # Ok::<(), estim_learned::Error>(())
//! ```
#![deny(missing_docs)]
#![deny(rustdoc::broken_intra_doc_links, rustdoc::private_intra_doc_links)]

mod beamsnet;
mod error;
mod measurement;
mod metadata;
mod metrics;
mod onnx;
mod outage;
mod sensitivity;
mod two_beams;

pub use beamsnet::{default_model_path, BeamsNet, BeamsNetInput, BEAMSNET_WINDOW};
pub use error::{Error, Result};
pub use measurement::{
    LearnedSensor, LinearObservation, Observation, OnnxMeasurement, DEFAULT_SENSITIVITY_STEP,
};
pub use metadata::{
    BeamGeometryMetadata, InputMetadata, ModelMetadata, OutputMetadata, METADATA_FORMAT,
};
pub use metrics::{metrics, speed_metrics, Metrics};
pub use outage::{default_outage_model_path, OutageNet};
pub use sensitivity::{
    driven_error_covariance, CrossMatrix, Empirical, EmpiricalEstimate, InputNoise,
    LearnedCrossCovariance, NetworkSensitivity, IMU_CHANNELS,
};
pub use two_beams::{default_two_beams_model_path, TwoBeamsNet};

/// The README's Rust code blocks, compiled and run as doc-tests (`cargo test` runs
/// them; nothing of it is part of the API).
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
