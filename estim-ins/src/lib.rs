//! # estim-ins: strapdown INS (NED), the 15-state error model, IMU error models and simulator.
#![warn(missing_docs)]

mod state;

pub use state::{InsState, ACC_BIAS, ATT, ERROR_STATES, GYRO_BIAS, POS, VEL};
