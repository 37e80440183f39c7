//! # estim-ins: strapdown INS (NED), the 15-state error model, IMU error models and simulator.
//!
//! - [`earth`]: WGS-84 radii of curvature, normal gravity, Earth and transport rates;
//! - [`Mechanization`]: second-order strapdown navigation in NED at any IMU rate;
//! - [`InsErrorModel`]: the 15-state error model as an estim-core
//!   [`ProcessModel`](estim_core::ProcessModel) + [`ErrorStateModel`](estim_core::ErrorStateModel);
//! - [`ImuSpec`]: checked IMU error specifications and presets;
//! - [`Trajectory`], [`ImuErrorGenerator`], [`Mission`]: IMU from a trajectory, synthetic AUV missions;
//! - [`ImuCalibrator`]: an IMU's axis convention, clock and biases against a reference trajectory.
//!
//! Conventions are pinned in [`InsState`]'s docs: NED, body x forward y right z
//! down, `true = nominal + error`, misalignment ψ in NED with C_true = (I + \[ψ×\]) C_nominal.
//!
//! ```
//! use estim_core::ProcessModel;
//! use estim_ins::{ErrorMatrix, InsErrorModel, Mechanization, Mission, MissionConfig};
//!
//! // A seeded 60 s AUV mission at 100 Hz (truth, corrupted and clean IMU).
//! let config = MissionConfig::builder().duration(60.0).build()?;
//! let mission = Mission::generate(&config, 7)?;
//! let model = InsErrorModel::new(*config.imu_spec());
//! let mut state = mission.truth[0];
//! let mut covariance = ErrorMatrix::identity() * 1e-4;
//! for imu in &mission.imu {
//!     let (phi, q) = model.transition_and_noise(&state, imu, mission.imu_dt);
//!     covariance = model.propagate_covariance(&covariance, &phi, &q);
//!     state = Mechanization::new().step(&state, imu, mission.imu_dt)?;
//! }
//! assert!((state.time - 60.0).abs() < 1e-6);
//! assert!(covariance[(0, 0)] > 1e-4); // unaided: position uncertainty grows
//! # Ok::<(), estim_ins::Error>(())
//! ```
#![deny(missing_docs)]
#![deny(rustdoc::broken_intra_doc_links, rustdoc::private_intra_doc_links)]

mod calibrate;
pub mod earth;
mod error;
mod error_model;
mod imu_spec;
mod kernel;
mod mechanization;
mod mission;
mod simulator;
mod state;

pub use calibrate::{
    AxisMap, Estimate, ImuCalibration, ImuCalibrator, ImuCalibratorBuilder,
    IMU_CALIBRATION_PARAMETERS,
};
pub use error::{Error, Result};
pub use error_model::{inject, ErrorMatrix, InsErrorModel, NoiseInput};
pub use imu_spec::{ImuSpec, ImuSpecBuilder, SensorSpec};
pub use mechanization::{navigation_rates, ImuSample, Mechanization, NavigationRates};
pub use mission::{Mission, MissionConfig, MissionConfigBuilder, SimulatedMission};
pub use simulator::{ImuErrorGenerator, Kinematics, Trajectory, TrajectorySample};
pub use state::{InsState, ACC_BIAS, ATT, ERROR_STATES, GYRO_BIAS, POS, VEL};

/// The README's Rust code blocks, compiled and run as doc-tests (`cargo test` runs
/// them; nothing of it is part of the API).
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
