//! # estim-learned: ONNX models as learned measurements, BeamsNet, network-derived cross-covariance.
#![warn(missing_docs)]
