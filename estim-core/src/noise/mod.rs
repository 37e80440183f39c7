//! Noise models from data: process-noise discretization, the likelihood of the
//! measurements as a function of noise parameters, maximum-likelihood and EM fits.
//!
//! The submodules are independent of each other; each one's docs give its model,
//! conventions and references.
//! - [`process`]: Q_d of integrator chains (filterpy's forms) and Van Loan's discretization.

pub mod process;
