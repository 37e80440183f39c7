//! # estim
//!
//! State estimation with correlated process and measurement noise. When a learned
//! model turns raw sensor data into a measurement and the same sensors drive the
//! process model, the two noises are correlated and a standard EKF is inconsistent;
//! estim's update accounts for the cross-covariance M.
//!
//! This facade re-exports the member crates, each behind the feature of its name
//! (estim-core always; `default-features = false` is estim-core alone):
//! - [`core`]: traits, the correlated update, KF/EKF/error-state EKF runners, consistency
//!   tools (features `consistency`, `fit`: estim-core's own);
//! - [`ins`] (`ins`): strapdown INS, 15-state error model, IMU simulator;
//! - [`dvl`] (`dvl`): DVL beams, least squares, DVL measurement model, calibration;
//! - [`learned`] (`learned`): ONNX learned measurements, BeamsNet, network-derived
//!   cross-covariance, and the committed learned models, embedded ([`models`]);
//! - [`navigator`] and [`datasets`] (`nav`, estim-nav): the INS/DVL error-state filter fed
//!   with real logs, the readers of A-KIT's and users' log files, and a survey loaded in
//!   one call ([`SurveyFiles`]).
#![deny(missing_docs)]
#![deny(rustdoc::broken_intra_doc_links, rustdoc::private_intra_doc_links)]

#[cfg(feature = "learned")]
pub mod models;

pub use estim_core as core;
#[cfg(feature = "dvl")]
pub use estim_dvl as dvl;
#[cfg(feature = "ins")]
pub use estim_ins as ins;
#[cfg(feature = "learned")]
pub use estim_learned as learned;
#[cfg(feature = "nav")]
pub use estim_nav::truth;
#[cfg(feature = "nav")]
pub use estim_nav::{
    check_in_imu_span, check_survey, AidingTimes, LoadedSurvey, Pd0Load, SurveyError, SurveyFiles,
    SurveyWarning,
};
#[cfg(feature = "nav")]
pub use estim_nav::{datasets, imu_spikes, navigator};

/// The README's Rust code blocks, compiled and run as doc-tests (`cargo test` runs
/// them; nothing of it is part of the API).
#[cfg(all(doctest, feature = "nav"))]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
