//! Noise models from data: process-noise discretization, the likelihood of the
//! measurements as a function of noise parameters, maximum-likelihood and EM fits.
//!
//! - [`adaptive`]: an online scale on a sensor's noise level from past innovations
//!   (covariance matching with fading weights).
//! - [`process`]: Q_d of integrator chains (filterpy's forms) and Van Loan's
//!   discretization of (F, G Qc G').
//! - `ml` (feature `fit`, default on): maximum-likelihood Q(theta), R(theta) and
//!   M(theta) for any runner, with exact gradients and observed information from dual
//!   numbers, standard errors and the likelihood-ratio test (e.g. of M = 0); also
//!   for parameter counts known at run time (`maximize_dyn`), with a ready
//!   linear-Gaussian model whose Q and R scales or diagonals are fitted.
//! - [`em`]: EM of Q, R, mu_0, Sigma_0 and also F, H and the offsets b, d of a
//!   linear-Gaussian model (pykalman's `em`, up to `em_vars='all'`), and its
//!   log-likelihood.
//!
//! The submodules are independent of each other; each one's docs give its model,
//! conventions and references.

pub mod adaptive;
pub mod em;
#[cfg(feature = "fit")]
pub mod ml;
pub mod process;
