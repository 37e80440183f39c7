//! # estim-ins: strapdown INS (NED), the 15-state error model, IMU error models and simulator.
#![warn(missing_docs)]
