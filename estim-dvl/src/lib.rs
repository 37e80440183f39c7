#![doc = include_str!("../README.md")]
#![deny(missing_docs)]
#![deny(rustdoc::broken_intra_doc_links, rustdoc::private_intra_doc_links)]

mod calibration;
mod error;
mod error_model;
mod geometry;
mod measurement;
mod pd0;

pub use calibration::{
    Calibration, Calibrator, CalibratorBuilder, DvlMeasurement, Estimate, TrajectorySample,
    CALIBRATION_PARAMETERS,
};
pub use error::{Error, Result};
pub use error_model::{BeamsNetProtocol, BeamsNetScripts, DvlErrorModel, DvlErrorModelBuilder};
pub use geometry::{BeamGeometry, BeamGeometryBuilder, BeamSolution};
pub use measurement::{dvl_frame_velocity, DvlVelocityModel, DvlVelocityModelBuilder};
pub use pd0::{
    read_pd0, read_pd0_file, read_pd0_from, write_pd0_csv, BottomTrack, CoordinateSystem,
    CoordinateTransform, FixedLeader, Pd0Ensemble, Pd0Issue, Pd0Read, Pd0Report, Pd0Skip,
    RealTimeClock, PD0_CSV_HEADER,
};

pub use nalgebra;
