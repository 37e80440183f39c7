//! # estim-dvl: beam-level DVL model, least squares, DVL measurement model, calibration.
#![warn(missing_docs)]
