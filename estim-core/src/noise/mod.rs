//! Noise models from data: process-noise discretization, the likelihood of the
//! measurements as a function of noise parameters, maximum-likelihood and EM fits.
//!
//! The submodules are independent of each other; each one's docs give its model,
//! conventions and references.
//! - [`em`]: EM of Q, R, mu_0, Sigma_0 of a linear-Gaussian model, and its log-likelihood.

pub mod em;
