//! The experiments' shared layer: the configuration file of `reproduce`,
//! `montecarlo`, `evaluate`, `simulate` and the A-KIT modes of `smooth` and `tune`
//! ([`Config`], with `[faults]`), their error type, and the sensors synthesized from a
//! reference (IMU, BeamsNet-protocol beams, the seeded initial state). The paper's
//! pipeline (`crate::study`) and `estim simulate` build on it; it uses neither.

mod config;
mod error;
mod faults;
mod synthesis;

#[cfg(test)]
pub use config::SensorSection;
pub use config::{AkitTruth, Config, PaperMBasis, MAX_SEED};
pub use error::{PipelineError, Result};
#[cfg(test)]
pub use faults::ImuGap;
pub use faults::{DvlOutage, FaultConfig};
pub use synthesis::{
    dvl_epochs, initial_bias_std, initial_covariance, initial_nominal, protocol, synthesize_imu,
    DvlEpoch,
};
