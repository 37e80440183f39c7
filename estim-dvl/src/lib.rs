#![doc = include_str!("../README.md")]
#![warn(missing_docs)]

mod calibration;
mod error;
mod error_model;
mod geometry;
mod measurement;

pub use calibration::{
    Calibration, Calibrator, CalibratorBuilder, DvlMeasurement, Estimate, TrajectorySample,
    CALIBRATION_PARAMETERS,
};
pub use error::{Error, Result};
pub use error_model::{BeamsNetProtocol, BeamsNetScripts, DvlErrorModel, DvlErrorModelBuilder};
pub use geometry::{BeamGeometry, BeamGeometryBuilder, BeamSolution};
pub use measurement::{dvl_frame_velocity, DvlVelocityModel, DvlVelocityModelBuilder};

pub use nalgebra;
