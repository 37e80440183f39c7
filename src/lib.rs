//! # estim
//!
//! State estimation with correlated process and measurement noise. When a learned
//! model turns raw sensor data into a measurement and the same sensors drive the
//! process model, the two noises are correlated and a standard EKF is inconsistent;
//! estim's update accounts for the cross-covariance M.
//!
//! This facade re-exports the member crates:
//! - [`core`]: traits, the correlated update, KF/EKF/error-state EKF runners, consistency tools;
//! - [`ins`]: strapdown INS, 15-state error model, IMU simulator;
//! - [`dvl`]: DVL beams, least squares, DVL measurement model, calibration;
//! - [`learned`]: ONNX learned measurements, BeamsNet, network-derived cross-covariance;
//!
//! - [`navigator`] (estim-nav): the INS/DVL error-state filter fed with real logs;
//!
//! and holds the readers of A-KIT and users' log files ([`datasets`], estim-nav's with
//! the rows shared between A-KIT trajectories) and the committed learned models,
//! embedded ([`models`]).
#![deny(missing_docs)]
#![deny(rustdoc::broken_intra_doc_links, rustdoc::private_intra_doc_links)]

pub mod datasets;
pub mod models;

pub use estim_core as core;
pub use estim_dvl as dvl;
pub use estim_ins as ins;
pub use estim_learned as learned;
pub use estim_nav::navigator;
pub use estim_nav::{LoadedSurvey, Pd0Load, SurveyError, SurveyFiles};

/// The README's Rust code blocks, compiled and run as doc-tests (`cargo test` runs
/// them; nothing of it is part of the API).
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
