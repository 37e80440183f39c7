//! # estim-core
//!
//! Traits, the one correlated-noise Kalman update, the filters built on it (linear
//! KF, EKF, error-state EKF) and consistency tools. The core knows nothing about
//! navigation: any domain implements [`ProcessModel`] (or [`ErrorStateModel`]),
//! [`MeasurementModel`], [`CrossCovariance`] and, for model-derived measurements,
//! [`LearnedMeasurement`].
//!
//! ## Model and conventions
//!
//! ```text
//! x_k = f(x_{k-1}, u) + G w_{k-1}      Cov(G w_{k-1}) = Q_d   (ProcessModel::process_noise)
//! y_k = h(x_k) + v_k                   Cov(v_k)       = R     (MeasurementModel::noise_covariance)
//! M_k = Cov(G w_{k-1}, v_k)            N x M, state space     (CrossCovariance)
//! ```
//!
//! Time index: M_k pairs the process noise accumulated since the previous
//! measurement with the current measurement noise. Between two measurements the
//! runners accumulate (Q_acc, Phi_acc start at 0 and I after each measurement):
//!
//! ```text
//! Q_acc <- Phi Q_acc Phi' + Q_d        Phi_acc <- Phi Phi_acc
//! ```
//!
//! and hand both to the [`CrossCovariance`] through [`CrossCovarianceContext`].
//!
//! ## The update (Simon, *Optimal State Estimation*, 2006, sec. 7.1)
//!
//! ```text
//! S  = H P H' + H M + M' H' + R
//! K  = (P H' + M) S^-1
//! x+ = x + K (y - h(x))
//! P+ = P - K (H P + M')                                         (short form, optimal K)
//! P+ = (I-KH) P (I-KH)' + K R K' - (I-KH) M K' - K M' (I-KH)'   (Joseph-like, any K; default)
//! NIS = (y - h(x))' S^-1 (y - h(x))
//! ```
//!
//! With M = 0 this is the textbook Kalman update. It is implemented once, in
//! [`correlated_update`], and every runner calls it. The joint covariance
//! [[Q_acc, M], [M', R]] must be positive semidefinite for M to be a covariance at
//! all: [`check_joint_covariance`] tests it (scale invariant, on the correlation
//! matrix), [`largest_valid_scale`] gives the largest valid multiple of a given M,
//! and [`JointCheck`] decides what a runner does with it (skip, report in every
//! [`UpdateReport`], or reject with [`Error::InvalidJointCovariance`]). For the
//! paper's [`ScaledCorrelation`] (M = rho sqrt(diag Q) sqrt(diag R)') with diagonal Q
//! (q nonzero entries) and R (m entries), valid means rho^2 q m <= 1.
//!
//! Numerical guards: NaN or infinity anywhere is [`Error::NonFinite`] naming the
//! quantity; an S that is not positive definite is
//! [`Error::InnovationNotPositiveDefinite`]; an S that factorises but is numerically
//! singular (reciprocal condition of its correlation matrix below 1000 eps) is
//! [`Error::InnovationIllConditioned`]. A result is either finite or an error.
//!
//! ## Runners, gate, observers
//!
//! [`KalmanFilter`] (F, H, Q, R matrices), [`ExtendedKalmanFilter`] (any
//! [`ProcessModel`] on `SVector<T, N>`) and [`ErrorStateKalmanFilter`] (nominal state
//! propagated by the model, error covariance, inject then reset) share the same
//! `predict` / `update` / `step(.., Option<&measurement>, ..)` shape. Every update
//! attempt returns an [`UpdateReport`] (NIS, S, M, the joint eigenvalue, the gain);
//! an innovation [`Gate`] (chi-square quantile of the measurement size) can reject a
//! measurement, which leaves the state untouched and is reported as
//! [`UpdateStatus::RejectedByGate`], not as an error. [`Observer`]s receive every
//! prediction and update (argmin's executor pattern), so writers and plots stay out
//! of the numerical code. Sizes are const generics: a 15-state filter does not
//! allocate per step (the optional joint eigenvalue check does, see [`JointCheck`]).
//!
//! ## Consistency
//!
//! [`nees`], [`nis`], [`chi_square_band`] (two-sided band of the average of R
//! chi-square(dof) values, `chi2_{dof R}` quantiles divided by R) and
//! [`monte_carlo`] (rayon, run i seeded with `ChaCha8Rng::seed_from_u64(i)`,
//! deterministic).
//!
//! ## Walkthrough: the correlated update in another domain
//!
//! A constant-velocity target whose position sensor shares noise with the process
//! (its error contains the same acceleration noise): v_k = c w_{k-1} + e_k, so
//! M = Cov(G w, v) = G c q. Declare M (here [`Fixed`]; or implement
//! [`CrossCovariance`] to derive it from the accumulated process noise), pick a
//! gate, observe, step through the data.
//!
//! ```
//! use estim_core::nalgebra::{Matrix1, Matrix1x2, Matrix2, Matrix2x1, Vector1, Vector2};
//! use estim_core::{
//!     Fixed, FilterConfig, Gate, JointCheck, KalmanFilter, NisRecorder, StateAndCovariance,
//! };
//!
//! let (q, c, r_ind) = (0.04, -0.5, 1e-3);
//! let f = Matrix2::new(1.0, 1.0, 0.0, 1.0);
//! let g = Matrix2x1::new(0.5, 1.0);
//! let h = Matrix1x2::new(1.0, 0.0);
//! let r = Matrix1::new(c * c * q + r_ind);
//! let m = Fixed(g * (c * q)); // Cov(G w_{k-1}, v_k)
//!
//! let config = FilterConfig::builder()
//!     .gate(Gate::Nis { probability: 0.999 })
//!     .joint_check(JointCheck::Reject) // M must be a covariance
//!     .build()?;
//! let initial = StateAndCovariance::new(Vector2::new(0.0, 1.0), Matrix2::identity())?;
//! let mut kf = KalmanFilter::new(f, g * g.transpose() * q, h, r, initial)?
//!     .with_config(config)
//!     .with_observer(NisRecorder::default());
//!
//! for y in [Some(1.02), None, Some(2.97), Some(50.0), Some(4.01)] {
//!     let report = kf.step(y.map(Vector1::new).as_ref(), &m)?;
//!     if let Some(report) = report {
//!         assert!(report.joint_min_eigenvalue.unwrap() >= -1e-9);
//!     }
//! }
//! let nis = kf.observer();
//! assert_eq!((nis.accepted(), nis.rejected()), (3, 1)); // 50.0 is an outlier
//! # Ok::<(), estim_core::Error>(())
//! ```
//!
//! `estim-core/README.md` has a longer version; `examples/correlated_tracker.rs` (in
//! the `estim` package) runs a Monte Carlo of a robot tracked from odometry and a
//! camera fix carried forward with the same odometry, M-aware against M-neglected.
#![warn(missing_docs)]

mod config;
mod consistency;
mod cross;
mod error;
mod gaussian;
mod observer;
mod runner;
mod scalar;
mod smoother;
mod traits;
mod update;
pub mod window;

pub use config::{FilterConfig, FilterConfigBuilder, Gate, JointCheck};
pub use consistency::{average_over_runs, chi_square_band, monte_carlo, nees, nis, ChiSquareBand};
pub use observer::{NisRecorder, NoObserver, Observer, PredictEvent, UpdateEvent, UpdateStatus};
pub use runner::{ErrorStateKalmanFilter, ExtendedKalmanFilter, KalmanFilter, UpdateReport};

pub use cross::{
    check_joint_covariance, joint_covariance, joint_min_correlation_eigenvalue,
    joint_min_eigenvalue, largest_valid_scale, Fixed, ScaledCorrelation, Zero,
};
pub use error::{Error, Result};
pub use gaussian::{check_finite, check_symmetric, symmetrize, StateAndCovariance};
pub use scalar::{lit, to_f64, Scalar};
pub use smoother::{FixedLagSmoother, ForwardRecorder, RecordAt, Smoothed};
pub use traits::{
    CrossCovariance, CrossCovarianceContext, ErrorStateModel, InputSpec, LearnedMeasurement,
    MeasurementModel, ProcessModel,
};
pub use update::{
    correlated_update, innovation_covariance, joseph_covariance, CovarianceUpdate, UpdateOutcome,
};
pub use window::{ProcessStep, StepWindow, WindowedCrossCovariance};

pub use nalgebra;
