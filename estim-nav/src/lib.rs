//! # estim-nav: the INS/DVL navigator and the readers of its log files
//!
//! The navigator is the error-state filter assembled from estim-ins (mechanization,
//! the 15-state error model), estim-dvl (the DVL velocity model) and, with the default
//! feature `learned`, estim-learned (BeamsNet as the DVL sensor), fed with a survey's
//! own logs and producing a navigation solution with its uncertainty; no ground truth
//! is needed.
//!
//! - [`navigator`]: the navigator, its one IMU loop, the batch and streaming runs,
//!   the smoother and the noise fit ([`navigator::tune`]);
//! - [`datasets`]: the readers of A-KIT's and users' files (IMU, DVL velocity, beams,
//!   depth, position fixes, ground truth) and the rules for finding the data on disk;
//! - [`SurveyInputs::load`](navigator::SurveyInputs::load): a survey's files, read,
//!   checked and merged in one call ([`SurveyFiles`]);
//! - [`imu_spikes`]: isolated wild samples of an IMU log, warned about by
//!   [`check_survey`];
//! - [`truth`]: a reference trajectory on the navigator's clock and the evaluation of
//!   a run against it; [`truth::read_vehicle`] reads a vehicle TOML.
#![deny(missing_docs)]
#![deny(rustdoc::broken_intra_doc_links, rustdoc::private_intra_doc_links)]

pub mod datasets;
pub mod imu_spikes;
pub mod navigator;
mod survey;
mod survey_checks;
pub mod truth;

pub use survey::{LoadedSurvey, Pd0Load, SurveyError, SurveyFiles};
pub use survey_checks::{check_in_imu_span, check_survey, AidingTimes, SurveyWarning};
