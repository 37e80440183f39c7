//! Sizes known at run time: the linear Kalman filter with the correlated update, its
//! joint-covariance check, a whole series filtered and smoothed in one call, and the
//! Gaussian log-likelihood, on `DMatrix<f64>` / `DVector<f64>`.
//!
//! The static runners ([`crate::KalmanFilter`] and the others) take their sizes as
//! const generics: the compiler knows them, nothing is allocated per step, but a size
//! read from a file or a Python array needs a dispatch over compiled-in sizes, and
//! large sizes put their matrices on the stack. [`DynKalmanFilter`] is the same linear
//! filter for sizes known only at run time:
//!
//! - the same math (Simon 2006, sec. 7.1; the crate docs): S = H P H' + H M + M' H' + R,
//!   K = (P H' + M) S^-1, the Joseph-like posterior valid for any gain; the same
//!   accumulation of Q_acc between updates, and the same joint check of
//!   [[Q_acc, M], [M', R]] ([`crate::JointCheck`], `Reject` by default) with the same
//!   validity margin and errors ([`crate::Error`]);
//! - a plain [`DynKalmanFilter::update`] where there is no M, and
//!   [`DynKalmanFilter::update_correlated`] where there is;
//! - memory allocated at construction only: every buffer of a predict and an update
//!   lives in the filter and is reused (no allocation per step), and every matrix is on
//!   the heap, so n = 500 runs on a 2 MiB thread stack;
//! - [`DynKalmanFilter::filter_series`] over a [`MeasurementSeries`] (NaN rows or a
//!   mask for missing measurements) and [`DynKalmanFilter::filter_and_smooth`], which
//!   returns the filtered and the smoothed estimates of one forward pass;
//! - the products run through a register-blocked kernel that allocates nothing
//!   (portable, AVX2 and AVX-512F builds through the crate's one CPU dispatch),
//!   single threaded.
//!
//! [`DynUnscentedKalmanFilter`] is the unscented filter for run-time sizes: f and h as
//! [`DynSigmaPointProcess`] / [`DynSigmaPointMeasurement`] (closures, or types with
//! residual and mean hooks for angles), no Jacobian, the correlated update with the same
//! joint check, the filtered and URTS-smoothed estimates of one forward pass, no
//! allocation per step; it equals the static [`crate::UnscentedKalmanFilter`] to 1e-12
//! (`tests/dynamic_unscented.rs`).
//!
//! [`DynExtendedKalmanFilter`] is the extended filter for run-time sizes: f, F(x), h,
//! H(x) from [`DynProcessModel`] / [`DynMeasurementModel`] (types or pairs of
//! closures) writing into the filter's buffers, [`DynKalmanFilter`]'s core (the
//! correlated update, its joint check, the gate) at each step's linearisation, the
//! filtered and smoothed estimates of one forward pass, no allocation per step; it
//! equals the static [`crate::ExtendedKalmanFilter`] to 1e-12
//! (`tests/dynamic_extended.rs`).
//!
//! On the same problems [`DynKalmanFilter`]'s estimates equal [`crate::KalmanFilter`]'s and
//! `smooth_batch`'s to 1e-12 (`tests/dynamic.rs`), with and without M. EM and the
//! log-likelihood of a linear-Gaussian model with run-time sizes are in
//! [`crate::noise::em`] (`log_likelihood`, `em`).
//!
//! `estim_core::dmatrix!` and `estim_core::dvector!` (also reached as
//! `estim_core::nalgebra::{dmatrix, dvector}`) build the matrices without a direct
//! nalgebra dependency: nalgebra's own macros expand to paths through a crate named
//! `nalgebra`, which a user of `estim_core::nalgebra` alone does not have. The Python
//! bindings (`python/`, no nalgebra dependency of their own) compile with them.

mod batch;
mod extended;
mod filter;
mod linalg;
mod macros;
mod product;
mod sigma;
mod tools;
mod unscented;

pub use batch::{FilteredAndSmoothed, FilteredSeries, MeasurementSeries, Trajectory};
pub use extended::{DynExtendedKalmanFilter, DynMeasurementModel, DynProcessModel};
pub use filter::{DynKalmanFilter, DynUpdateReport};
pub use sigma::{DynSigmaPointMeasurement, DynSigmaPointProcess, DynSigmaPoints};
pub use tools::{joint_validity_margin, normalised_squared_error};
pub use unscented::DynUnscentedKalmanFilter;
