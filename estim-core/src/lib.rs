//! # estim-core
//!
//! Traits, the one correlated-noise Kalman update, the filters built on it (linear
//! KF, EKF, error-state EKF, square-root KF, unscented KF) and consistency tools. The core knows nothing about
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
//! runners accumulate (Q_acc, Phi_acc start at 0 and I after each measurement;
//! `FilterConfig::track_accumulated_noise(false)` turns this off):
//!
//! ```text
//! Q_acc <- Phi Q_acc Phi' + Q_d        Phi_acc <- Phi Phi_acc
//! ```
//!
//! and hand both to a one-step [`CrossCovariance`] through [`CrossCovarianceContext`].
//! That is exact when the measurement noise is correlated with the accumulated noise
//! as a whole (e.g. one predict per update). It is **not** exact when the noise shares
//! only some of the steps (a learned sensor's input window), when Phi != I, or when
//! other sensors update inside the window: a fixed share of Q_acc is right only for
//! Phi = I.
//!
//! ## Exact cross-covariance over a window (multi-rate, several sensors)
//!
//! A [`WindowedCrossCovariance`] supplies, for each process step j of its
//! measurement's window, D_j = Cov(G_j w_j, v). With
//! `FilterConfig::window_capacity(L_max)` the runners record each step (state before
//! it, input, dt, Phi) and each accepted update (J (I - K H), H' S^-1 H, H' S^-1 nu),
//! and `update_windowed` computes, in one pass over the window,
//!
//! ```text
//! C <- Phi_j C + D_j            each step of the window
//! on another update A:  E[v] += C' H_A' S_A^-1 nu_A,  Var(v) -= C' H_A' S_A^-1 H_A C,
//!                       C <- J (I - K_A H_A) C
//! M = C,  innovation y - h(x) - E[v],  R replaced by Var(v)
//! ```
//!
//! which equals joint-Gaussian conditioning of the stacked
//! [x_0; w_1..w_K; v; other sensors' noises] (`tests/windowed.rs`: 36 sizes, 1..60
//! predicts, windows 1..K, a second sensor inside the window, before it or at the
//! same epoch; KF, EKF, ESKF; `tests/windowed_nonlinear.rs`: EKF/ESKF against the
//! linearised reference). Invariants (module [`window`]): memory bounded by
//! `L_max` recorded steps, allocated once; nothing recorded with capacity 0 (the
//! default), so predict costs what it did; a correlated update inside another
//! measurement's window (e.g. a window longer than the update interval: coloured
//! noise) is [`Error::ColouredMeasurementNoise`], never approximated; a window
//! longer than what is recorded is [`Error::WindowUnavailable`].
//!
//! ## The update (Simon, *Optimal State Estimation*, 2006, sec. 7.1)
//!
//! ```text
//! S  = H P H' + H M + M' H' + R
//! K  = (P H' + M) S^-1
//! x+ = x + K (y - h(x))
//! P+ = P - K (H P + M')                                         (short form, optimal K)
//! P+ = (I-KH) P (I-KH)' + K R K' - (I-KH) M K' - K M' (I-KH)'   (Joseph-like, any K)
//! P+ = (T L)(T L)', T = [I-KH, -K], L L' = [[P, M], [M', R]]   (square root, any K; default)
//! NIS = (y - h(x))' S^-1 (y - h(x))
//! ```
//!
//! With M = 0 this is the textbook Kalman update. It is implemented once, in
//! [`update::correlated_update`], and every runner calls it. The joint covariance
//! [[Q_acc, M], [M', R]] must be positive semidefinite for M to be a covariance at
//! all: [`JointCovariance::check`] tests it (scale invariant, on the correlation
//! matrix), [`JointCovariance::largest_valid_scale`] gives the largest valid multiple of a given M,
//! and [`JointCheck`] decides what a runner does with it: reject it with
//! [`Error::InvalidJointCovariance`] before touching the state (the default), or, as
//! explicit opt-ins, use it and report the margin in every [`UpdateReport`], or skip
//! the check. For the
//! paper's [`ScaledCorrelation`] (M = rho sqrt(diag Q) sqrt(diag R)') with diagonal Q
//! (q nonzero entries) and R (m entries), valid means rho^2 q m <= 1.
//!
//! Numerical guards: NaN or infinity anywhere is [`Error::NonFinite`] naming the
//! quantity; an S that is not positive definite is
//! [`Error::InnovationNotPositiveDefinite`]; an S that factorises but is numerically
//! singular (reciprocal condition of its correlation matrix below 1000 eps) is
//! [`Error::InnovationIllConditioned`]; finite inputs whose result leaves the scalar's
//! range (Q_d of dt = 1e300, a NEES of 1e400) are [`Error::Overflow`]. A result is
//! either finite or an error.
//!
//! [`CovarianceUpdate`] documents the four forms, why the square-root one is the
//! default, and its fallback when [[P, M], [M', R]] has no square root.
//!
//! ## Square-root and sigma-point forms
//!
//! [`SquareRootKalmanFilter`] keeps a Cholesky factor of P and refuses an M whose
//! joint covariance with Q_acc has no square root; [`square_root::square_root_predict`] and
//! [`square_root::square_root_update`] are its steps as free functions (for error-state
//! runners). [`UnscentedKalmanFilter`] predicts and updates by sigma points
//! ([`sigma_point::unscented_predict`], [`sigma_point::unscented_update`], also free
//! functions). The update is one of two named forms
//! ([`sigma_point::SigmaPointUpdate`]): the textbook additive update (default;
//! sigma points over x, R added, M through the linearised cross terms) or the
//! augmented one (sigma points over the joint [x; v] with covariance
//! [[P, M], [M', R]]); the weight families (Merwe alpha/beta/kappa, Julier kappa, a
//! negative kappa with the centre-point-modified covariance) are in [`sigma_point`].
//!
//! ## Runners, gate, observers
//!
//! [`KalmanFilter`] (F, H, Q, R matrices), [`ExtendedKalmanFilter`] (any
//! [`ProcessModel`] on `SVector<T, N>`), [`ErrorStateKalmanFilter`] (nominal state
//! propagated by the model, error covariance, inject then reset),
//! [`SquareRootKalmanFilter`] (F, H, Q, R, a factor of P) and [`UnscentedKalmanFilter`]
//! (any [`SigmaPointProcess`] and [`SigmaPointMeasurement`]: no Jacobian; every
//! [`ProcessModel`] / [`MeasurementModel`] on `SVector<T, N>` is one) share one runner core and
//! the same `predict` / `update` / `update_windowed` / `step(.., Option<&measurement>, ..)`
//! shape (and `update_uncorrelated` / `step_uncorrelated`, the same with M = 0: no
//! cross-covariance argument), configuration, gate and observer events. Every update
//! attempt returns an [`UpdateReport`] (NIS, S, M, the joint eigenvalue, the gain);
//! an innovation [`Gate`] (chi-square quantile of the measurement size) can reject a
//! measurement, which leaves the state untouched and is reported as
//! [`UpdateStatus::RejectedByGate`], not as an error; [`GateRecovery`] says what the
//! gate does after a run of rejections (a filter locked out by its own gate).
//! [`Observer`]s receive every
//! prediction and update (argmin's executor pattern), so writers and plots stay out
//! of the numerical code; the events carry Phi, Q_d, H, R, M, S and K, so a smoother
//! can record the forward pass. Commit rule: a predict or update either fails before
//! touching anything or commits, then notifies; an observer's error is returned with
//! the result committed. Sizes are const generics: a 15-state filter does not
//! allocate per step (the optional joint eigenvalue check does, see [`JointCheck`]).
//!
//! ## Learning the noise, batch calls
//!
//! Module [`noise`]: maximum-likelihood Q(theta), R(theta) and M(theta) from any runner's
//! log-likelihood, with exact derivatives from dual numbers and standard errors
//! (`noise::ml`, feature `fit`); EM of a linear-Gaussian model ([`noise::em`]); Q_d of
//! integrator chains and Van Loan's discretization ([`noise::process`]). Every runner
//! filters or smooths a slice of steps in one call (`filter_batch`, `smooth_batch`:
//! estimates and the log-likelihood); [`KalmanFilter`] also takes a control input and
//! per-step F, Q, H and R.
//!
//! ## Sizes known at run time
//!
//! Module [`dynamic`]: [`DynKalmanFilter`] is the linear filter with the same
//! correlated update and joint check on `DMatrix<f64>`, allocating at construction
//! only (no allocation per step, nothing large on the stack), with a whole series
//! filtered and smoothed in one call ([`DynKalmanFilter::filter_and_smooth`]). The
//! macros [`dmatrix!`] and [`dvector!`] write its matrices without a direct nalgebra
//! dependency. The Python package (`python/`) is built on it.
//!
//! ## Hand-tuned paths and `ESTIM_FORCE_PORTABLE`
//!
//! Three hot loops have a hand-tuned build beside the portable one, chosen at run
//! time from the CPU's features (read once per process): the linear runner's
//! predict and update compiled for AVX2 (the same bits as the portable build), the
//! dense products of 8 or more states by an AVX-512F loop with fused multiply-adds
//! (the same values to round-off), and the joint factor of 8 or more states compiled
//! for AVX-512F (the same bits). Setting the environment variable
//! `ESTIM_FORCE_PORTABLE=1` before the first filter runs forces the portable path
//! everywhere in estim-core and in the crates that dispatch through it (estim-ins's
//! kernels: module [`dispatch`] is the one switch; `ESTIM_FORCE_PORTABLE=1 cargo test`
//! runs the suite on it); unit tests compare each hand-tuned build with the portable
//! one in the same process (`dispatch::with_features`, feature `testing`).
//!
//! ## Consistency
//!
//! Module [`consistency`]: [`consistency::nees`], [`consistency::nis`], `chi_square_band` (two-sided band of the average of R
//! chi-square(dof) values, `chi2_{dof R}` quantiles divided by R) and
//! `monte_carlo` (rayon, run i seeded with `ChaCha8Rng::seed_from_u64(i)`,
//! deterministic).
//!
//! Cargo feature `consistency` (default on): `chi_square_band`, `monte_carlo` and the
//! chi-square quantile of [`Gate::Nis`] need statrs, rayon and rand. With
//! `default-features = false` none of them is compiled; `nees`, `nis` and every filter
//! remain, and [`Gate::Nis`] is refused with [`Error::InvalidParameter`] (use
//! [`Gate::NisThreshold`]).
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
#![deny(missing_docs)]
#![deny(rustdoc::broken_intra_doc_links, rustdoc::private_intra_doc_links)]

mod config;
pub mod consistency;
mod cross;
pub use linalg::dispatch;
pub mod dynamic;
mod error;
mod gaussian;
mod linalg;
pub mod noise;
pub mod numeric;
mod observer;
mod runner;
mod scalar;
pub mod sigma_point;
pub mod smoother;
pub mod square_root;
#[cfg(any(test, feature = "testing"))]
pub mod testing;

/// Helpers of the unit tests.
#[cfg(test)]
pub(crate) mod test_support {
    use nalgebra::SMatrix;
    use rand::RngExt;

    /// An N x N factor G whose first `rank` columns are uniform in [-1, 1) and the rest
    /// zero, so G G' has rank `rank` at most (column-major draws, as `from_fn`).
    pub(crate) fn rank_deficient_factor<const N: usize>(
        rng: &mut impl rand::Rng,
        rank: usize,
    ) -> SMatrix<f64, N, N> {
        SMatrix::from_fn(|_, j| {
            if j < rank {
                rng.random_range(-1.0..1.0)
            } else {
                0.0
            }
        })
    }
}
mod traits;
pub mod update;
pub mod window;

pub use config::{FilterConfig, FilterConfigBuilder, Gate, GateRecovery, JointCheck};
pub use cross::{Fixed, JointCovariance, ScaledCorrelation, Zero};
pub use dynamic::{DynKalmanFilter, MeasurementSeries};
pub use error::{Error, Result};
pub use gaussian::StateAndCovariance;
pub use observer::{
    MarkEvent, NisRecorder, NoObserver, Observer, PredictEvent, UpdateEvent, UpdateStatus,
};
pub use runner::FilteredBatch;
pub use runner::{
    ErrorStateKalmanFilter, ExtendedKalmanFilter, KalmanFilter, SquareRootKalmanFilter,
    UnscentedKalmanFilter, UpdateReport,
};
pub use scalar::Scalar;
pub use traits::{
    CrossCovariance, CrossCovarianceContext, ErrorStateModel, InputSpec, LearnedMeasurement,
    MeasurementModel, ProcessModel, SigmaPointMeasurement, SigmaPointProcess,
};
pub use update::CovarianceUpdate;
pub use window::WindowedCrossCovariance;

/// nalgebra, re-exported whole (`estim_core::nalgebra::...` is nalgebra's API), except
/// that `dmatrix!` and `dvector!` are estim-core's f64 macros ([`dmatrix!`],
/// [`dvector!`]): nalgebra's own expand to paths through a crate named `nalgebra`, so
/// they do not compile in a crate that depends on estim-core alone; these do.
///
/// ```
/// use estim_core::nalgebra::{dmatrix, dvector, DMatrix};
///
/// let f: DMatrix<f64> = dmatrix![1.0, 1.0; 0.0, 1.0];
/// assert_eq!(f * dvector![0.0, 2.0], dvector![2.0, 2.0]);
/// ```
pub mod nalgebra {
    pub use crate::{dmatrix, dvector};
    pub use ::nalgebra::*;
}

/// The README's Rust code blocks, compiled and run as doc-tests (`cargo test` runs
/// them; nothing of it is part of the API).
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
