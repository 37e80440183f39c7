//! # estim-core
//!
//! Traits and the correlated-noise Kalman update of estim. The core knows nothing
//! about navigation: any domain implements [`ProcessModel`], [`MeasurementModel`],
//! [`CrossCovariance`] and (for model-derived measurements) [`LearnedMeasurement`].
//!
//! The update (Simon, *Optimal State Estimation*, 2006, sec. 7.1), with
//! M = Cov(G w_{k-1}, v_k):
//!
//! ```text
//! S  = H P H' + H M + M' H' + R
//! K  = (P H' + M) S^-1
//! P+ = P - K (H P + M')                                   (short form)
//! P+ = (I-KH) P (I-KH)' + K R K' - (I-KH) M K' - K M' (I-KH)'   (Joseph-like, any K)
//! ```
#![warn(missing_docs)]

mod config;
mod consistency;
mod cross;
mod error;
mod gaussian;
mod observer;
mod runner;
mod scalar;
mod traits;
mod update;

pub use config::{FilterConfig, FilterConfigBuilder, Gate, JointCheck};
pub use consistency::{average_over_runs, chi_square_band, monte_carlo, nees, nis, ChiSquareBand};
pub use observer::{NisRecorder, NoObserver, Observer, PredictEvent, UpdateEvent, UpdateStatus};
pub use runner::{ErrorStateKalmanFilter, ExtendedKalmanFilter, KalmanFilter, UpdateReport};

pub use cross::{
    check_joint_covariance, joint_covariance, joint_min_correlation_eigenvalue,
    joint_min_eigenvalue, largest_valid_scale, Fixed, ScaledCorrelation, Zero,
};
pub use error::{Error, Result};
pub use gaussian::{check_finite, check_symmetric, symmetrize, StateAndCovariance};
pub use scalar::{lit, to_f64, Scalar};
pub use traits::{
    CrossCovariance, CrossCovarianceContext, ErrorStateModel, InputSpec, LearnedMeasurement,
    MeasurementModel, ProcessModel,
};
pub use update::{
    correlated_update, innovation_covariance, joseph_covariance, CovarianceUpdate, UpdateOutcome,
};

pub use nalgebra;
