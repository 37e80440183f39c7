//! # estim-dvl: beam-level DVL model, least squares, DVL measurement model, calibration.
//!
//! See `README.md` of this crate for the equations and conventions.
#![warn(missing_docs)]

mod error;
mod geometry;

pub use error::{Error, Result};
pub use geometry::{BeamGeometry, BeamGeometryBuilder, BeamSolution};

pub use nalgebra;
