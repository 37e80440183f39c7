//! Expectation-maximisation (EM) of the noise and initial-state parameters of a
//! linear-Gaussian state-space model, and the log-likelihood of its measurements.
//!
//! ## Model and indexing
//!
//! ```text
//! x_0     ~ N(mu_0, Sigma_0)
//! x_{t+1} = F x_t + b_t + w_t      Cov(w_t) = Q      t = 0 .. T-2
//! y_t     = H x_t + d   + v_t      Cov(v_t) = R      t = 0 .. T-1, y_t possibly missing
//! ```
//!
//! This is pykalman's `KalmanFilter` with time-invariant F, H, Q, R and d, and
//! transition offsets b_t constant or given per step ([`TransitionOffsets`]). Epoch 0
//! is measured at the initial state itself (no transition before it), as in pykalman;
//! a missing measurement is `None` (pykalman: a masked row). There is no
//! cross-covariance between w and v here: EM's closed forms are those of the
//! uncorrelated model.
//!
//! Sizes are dynamic (`DMatrix<f64>`, `DVector<f64>`): EM is an offline batch over a
//! recorded sequence whose dimensions come from the data, and it allocates its
//! per-epoch moments anyway; f64 only, since EM's sums over hundreds of epochs are
//! where single precision would lose the digits the likelihood needs.
//!
//! ## Log-likelihood ([`log_likelihood`])
//!
//! The Kalman filter's prediction-error decomposition: the sum over the measured
//! epochs of ln N(nu_t; 0, S_t), nu_t = y_t - H x_{t|t-1} - d, S_t = H P_{t|t-1} H' + R,
//! each term -(m ln 2 pi + ln det S_t + nu_t' S_t^-1 nu_t) / 2 through the Cholesky
//! factor of S_t. The same value as the runners' cumulative
//! [`crate::KalmanFilter::log_likelihood`] on the same model (offsets folded into the
//! measurement), and as pykalman's `loglikelihood`.
//!
//! ## E-step: RTS smoother with lag-one covariances
//!
//! Forward (Kalman filter; x_{0|-1} = mu_0, P_{0|-1} = Sigma_0):
//!
//! ```text
//! x_{t|t-1} = F x_{t-1|t-1} + b_{t-1}         P_{t|t-1} = F P_{t-1|t-1} F' + Q
//! K_t = P_{t|t-1} H' S_t^-1                   (measured epochs; else K_t = 0)
//! x_{t|t} = x_{t|t-1} + K_t nu_t              P_{t|t} = P_{t|t-1} - K_t H P_{t|t-1}
//! ```
//!
//! Backward (Rauch, Tung & Striebel 1965; x_{T-1|T-1} starts it):
//!
//! ```text
//! J_t = P_{t|t} F' P_{t+1|t}^+
//! x_{t|T} = x_{t|t} + J_t (x_{t+1|T} - x_{t+1|t})
//! P_{t|T} = P_{t|t} + J_t (P_{t+1|T} - P_{t+1|t}) J_t'
//! V_{t+1,t} = Cov(x_{t+1}, x_t | all) = P_{t+1|T} J_t'
//! ```
//!
//! The lag-one form V_{t+1,t} = P_{t+1|T} J_t' is de Jong's (1989) closed form of
//! Shumway & Stoffer's (1982) backward recursion for the lag-one covariance. The
//! existing [`crate::smoother`] does not return lag-one covariances, so the recursion
//! is written here. `P^+` is the Moore-Penrose pseudo-inverse with scipy's cutoff
//! (singular values below max(n, n) eps times the largest are dropped), as pykalman's
//! `linalg.pinv`: a P_{t+1|t} that is singular (a state no noise drives and the
//! initial covariance does not spread) still smooths. S_t is inverted through its
//! Cholesky factor; one that is not positive definite is
//! [`Error::InnovationNotPositiveDefinite`].
//!
//! ## M-step (Shumway & Stoffer 1982; Ghahramani & Hinton 1996, eqs. 12-15)
//!
//! With the smoothed moments, for the variables chosen in [`EmVariables`] (the others
//! kept), each from the same E-step, in pykalman's order (H, R, F, Q, mu_0, Sigma_0,
//! b, d); a right-hand side reads a parameter updated before it in that order (when
//! it is learned) and the given one otherwise. Sums over "measured t" are over the
//! epochs with a measurement (n_y of them), sums over t = 0 .. T-2 over every
//! transition, measured or not.
//!
//! ```text
//! H       = [ sum_{measured t} (y_t - d) x_{t|T}' ] [ sum_{measured t} M_t ]^+,
//!                                     M_t = P_{t|T} + x_{t|T} x_{t|T}'
//! R       = 1/n_y sum_{measured t} [ e_t e_t' + H P_{t|T} H' ],   e_t = y_t - H x_{t|T} - d
//! F       = [ sum_{t=0}^{T-2} (V_{t+1,t} + x_{t+1|T} x_{t|T}' - b_t x_{t|T}') ]
//!           [ sum_{t=0}^{T-2} M_t ]^+
//! Q       = 1/(T-1) sum_{t=0}^{T-2} [ f_t f_t' + F P_{t|T} F' + P_{t+1|T}
//!                                     - V_{t+1,t} F' - F V_{t+1,t}' ],
//!                                     f_t = x_{t+1|T} - F x_{t|T} - b_t
//! mu_0    = x_{0|T}
//! Sigma_0 = P_{0|T} + (x_{0|T} - mu_0)(x_{0|T} - mu_0)'
//! b       = 1/(T-1) sum_{t=0}^{T-2} (x_{t+1|T} - F x_{t|T})
//! d       = 1/n_y sum_{measured t} (y_t - H x_{t|T})
//! ```
//!
//! So R and d use the new H when it is learned, Q and b the new F, Sigma_0 the new
//! mu_0; H and R use the old d, F and Q the old b (pykalman's `_em` passes the
//! offsets it was given to those four). These are pykalman's
//! `_em_observation_matrix`, `_em_observation_covariance`, `_em_transition_matrix`,
//! `_em_transition_covariance`, `_em_initial_state_mean`,
//! `_em_initial_state_covariance`, `_em_transition_offset` and
//! `_em_observation_offset`. H and F are the least-squares regressions of the
//! expected sufficient statistics, through the same pseudo-inverse (scipy's
//! cutoff) as pykalman's `linalg.pinv`; learned, b is one constant offset
//! ([`TransitionOffsets::Constant`]) even if per-step ones were given, as in
//! pykalman. With F, H, b, Q, mu_0 and Sigma_0 all learned, the likelihood is
//! invariant under a change of state coordinates (x -> A x for any invertible A):
//! the fit is pykalman's, one point of that family, not a canonical one, and the
//! EM map amplifies round-off faster (on the robot problem pykalman's own Q moves
//! by 9.4e-8 relative after ten iterations when Q_0 is perturbed by 1e-15).
//!
//! Sigma_0 is written in the difference form, algebraically pykalman's
//! `E[x_0 x_0'] - mu_0 E[x_0]' - E[x_0] mu_0' + mu_0 mu_0'` (it is P_{0|T} when
//! mu_0 is learned too). The fitted covariances are symmetrised ((A + A') / 2) and
//! checked like the inputs: the filter's and smoother's products leave a round-off
//! asymmetry that EM iterations amplify (pykalman, which never symmetrises, ends
//! the robot problem's ten iterations of Q, R, mu_0, Sigma_0 with a Q asymmetric by
//! 2.2e-9 relative, and of every parameter by 1.5e-7).
//!
//! Each iteration does not decrease the log-likelihood (Dempster, Laird & Rubin
//! 1977); [`EmFit::log_likelihoods`] records it before the first iteration and after
//! each one.
//!
//! ## Example
//!
//! ```
//! use estim_core::nalgebra::{dmatrix, dvector, DVector};
//! use estim_core::noise::em::{em, log_likelihood, EmStop, EmVariables, LinearGaussianModel};
//!
//! // A random walk observed with noise; start from wrong noise levels.
//! let model = LinearGaussianModel::new(
//!     dmatrix![1.0], dmatrix![1.0], // F, H
//!     dmatrix![1.0], dmatrix![1.0], // Q, R
//!     dvector![0.0], dmatrix![1.0], // mu_0, Sigma_0
//! )?;
//! let ys: Vec<Option<DVector<f64>>> =
//!     [Some(0.1), Some(0.3), None, Some(0.2), Some(0.5), Some(0.4), Some(0.45)]
//!         .iter()
//!         .map(|y| y.map(|y| dvector![y]))
//!         .collect();
//! let start = log_likelihood(&model, &ys)?;
//! let fit = em(&model, &ys, EmVariables::NOISE_COVARIANCES, 20)?;
//! assert_eq!(fit.stop, EmStop::Completed);
//! assert_eq!(fit.log_likelihoods.len(), 21);
//! assert_eq!(fit.log_likelihoods[0], start);
//! assert!(fit.log_likelihoods.windows(2).all(|w| w[1] >= w[0] - 1e-12));
//! # Ok::<(), estim_core::Error>(())
//! ```
//!
//! References: R. H. Shumway and D. S. Stoffer, "An approach to time series
//! smoothing and forecasting using the EM algorithm", J. Time Series Analysis 3(4),
//! 1982; Z. Ghahramani and G. E. Hinton, "Parameter estimation for linear dynamical
//! systems", Tech. Rep. CRG-TR-96-2, University of Toronto, 1996; P. de Jong, "Smoothing
//! and interpolation with the state-space model", JASA 84(408), 1989.

use std::ops::BitOr;

use nalgebra::{DMatrix, DVector};

use crate::gaussian::check_finite;
use crate::linalg::cholesky::Square;
use crate::linalg::semidefinite_cholesky;
use crate::{Error, Result};

mod passes;
use passes::*;

/// The transition offsets b_t of x_{t+1} = F x_t + b_t + w_t.
#[derive(Debug, Clone, PartialEq)]
pub enum TransitionOffsets {
    /// One offset for every step (zero for a model without offsets).
    Constant(DVector<f64>),
    /// b_t for t = 0 .. T-2: exactly one per transition of the measurement sequence
    /// (T - 1 for T epochs), checked when the model meets its measurements.
    PerStep(Vec<DVector<f64>>),
}

impl TransitionOffsets {
    /// b_t (`t` < T - 1, checked by the caller).
    fn at(&self, t: usize) -> &DVector<f64> {
        match self {
            Self::Constant(b) => b,
            Self::PerStep(bs) => &bs[t],
        }
    }
}

/// A linear-Gaussian state-space model (see the module docs for its equations):
/// F (n x n), offsets b_t, H (m x n), d (m), Q (n x n), R (m x m), mu_0 (n),
/// Sigma_0 (n x n).
///
/// Checked on construction: sizes agree, every entry finite, Q, R and Sigma_0
/// symmetric (entrywise, [`crate::numeric::relative_tolerance`]) and positive
/// semidefinite to round-off (the crate's semidefinite Cholesky, pivot tolerance
/// 16 n eps). A value of this type is always valid.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearGaussianModel {
    transition_matrix: DMatrix<f64>,
    transition_offsets: TransitionOffsets,
    observation_matrix: DMatrix<f64>,
    observation_offset: DVector<f64>,
    transition_covariance: DMatrix<f64>,
    observation_covariance: DMatrix<f64>,
    initial_state_mean: DVector<f64>,
    initial_state_covariance: DMatrix<f64>,
}

impl LinearGaussianModel {
    /// A model without offsets (b = 0, d = 0): transition F, observation H,
    /// transition covariance Q, observation covariance R, initial mean mu_0 and
    /// covariance Sigma_0. n is F's row count, m is H's.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for n = 0 or m = 0; [`Error::Dimension`] naming the
    /// first quantity whose size disagrees with n and m; [`Error::NonFinite`];
    /// [`Error::InvalidCovariance`] if Q, R or Sigma_0 is not symmetric positive
    /// semidefinite to round-off.
    pub fn new(
        transition_matrix: DMatrix<f64>,
        observation_matrix: DMatrix<f64>,
        transition_covariance: DMatrix<f64>,
        observation_covariance: DMatrix<f64>,
        initial_state_mean: DVector<f64>,
        initial_state_covariance: DMatrix<f64>,
    ) -> Result<Self> {
        let (n, m) = (transition_matrix.nrows(), observation_matrix.nrows());
        let model = Self {
            transition_matrix,
            transition_offsets: TransitionOffsets::Constant(DVector::zeros(n)),
            observation_matrix,
            observation_offset: DVector::zeros(m),
            transition_covariance,
            observation_covariance,
            initial_state_mean,
            initial_state_covariance,
        };
        model.validate()?;
        Ok(model)
    }

    /// The same model with transition offsets b_t.
    ///
    /// # Errors
    /// [`Error::Dimension`] if an offset is not of size n; [`Error::NonFinite`].
    pub fn with_transition_offsets(mut self, offsets: TransitionOffsets) -> Result<Self> {
        self.transition_offsets = offsets;
        self.validate()?;
        Ok(self)
    }

    /// The same model with observation offset d.
    ///
    /// # Errors
    /// [`Error::Dimension`] if d is not of size m; [`Error::NonFinite`].
    pub fn with_observation_offset(mut self, offset: DVector<f64>) -> Result<Self> {
        self.observation_offset = offset;
        self.validate()?;
        Ok(self)
    }

    /// State size n.
    pub fn state_dimension(&self) -> usize {
        self.transition_matrix.nrows()
    }

    /// Measurement size m.
    pub fn observation_dimension(&self) -> usize {
        self.observation_matrix.nrows()
    }

    /// F (n x n).
    pub fn transition_matrix(&self) -> &DMatrix<f64> {
        &self.transition_matrix
    }

    /// The transition offsets b_t.
    pub fn transition_offsets(&self) -> &TransitionOffsets {
        &self.transition_offsets
    }

    /// H (m x n).
    pub fn observation_matrix(&self) -> &DMatrix<f64> {
        &self.observation_matrix
    }

    /// d (m).
    pub fn observation_offset(&self) -> &DVector<f64> {
        &self.observation_offset
    }

    /// Q = Cov(w_t) (n x n).
    pub fn transition_covariance(&self) -> &DMatrix<f64> {
        &self.transition_covariance
    }

    /// R = Cov(v_t) (m x m).
    pub fn observation_covariance(&self) -> &DMatrix<f64> {
        &self.observation_covariance
    }

    /// mu_0, the mean of x_0 (n).
    pub fn initial_state_mean(&self) -> &DVector<f64> {
        &self.initial_state_mean
    }

    /// Sigma_0 = Cov(x_0) (n x n).
    pub fn initial_state_covariance(&self) -> &DMatrix<f64> {
        &self.initial_state_covariance
    }

    fn validate(&self) -> Result<()> {
        let (n, m) = (self.state_dimension(), self.observation_dimension());
        if n == 0 || m == 0 {
            return Err(Error::InvalidParameter {
                name: "model dimensions",
                reason: format!("state size {n} and measurement size {m} must both be at least 1"),
            });
        }
        check_shape(&self.transition_matrix, (n, n), "transition matrix")?;
        check_shape(&self.observation_matrix, (m, n), "observation matrix")?;
        check_shape(&self.transition_covariance, (n, n), "transition covariance")?;
        check_shape(
            &self.observation_covariance,
            (m, m),
            "observation covariance",
        )?;
        check_size(self.initial_state_mean.len(), n, "initial state mean")?;
        check_shape(
            &self.initial_state_covariance,
            (n, n),
            "initial state covariance",
        )?;
        check_size(self.observation_offset.len(), m, "observation offset")?;
        match &self.transition_offsets {
            TransitionOffsets::Constant(b) => check_size(b.len(), n, "transition offset")?,
            TransitionOffsets::PerStep(bs) => {
                for b in bs {
                    check_size(b.len(), n, "transition offset")?;
                    check_finite(b.as_slice(), "transition offset")?;
                }
            }
        }
        if let TransitionOffsets::Constant(b) = &self.transition_offsets {
            check_finite(b.as_slice(), "transition offset")?;
        }
        check_finite(self.transition_matrix.as_slice(), "transition matrix")?;
        check_finite(self.observation_matrix.as_slice(), "observation matrix")?;
        check_finite(self.observation_offset.as_slice(), "observation offset")?;
        check_finite(self.initial_state_mean.as_slice(), "initial state mean")?;
        check_covariance(&self.transition_covariance, "transition covariance")?;
        check_covariance(&self.observation_covariance, "observation covariance")?;
        check_covariance(&self.initial_state_covariance, "initial state covariance")
    }
}

/// Which parameters [`em`] learns; the others stay as given. A small bit set:
/// combine with `|`, e.g. `EmVariables::TRANSITION_COVARIANCE |
/// EmVariables::OBSERVATION_COVARIANCE` (= [`EmVariables::NOISE_COVARIANCES`]).
/// Whatever the set, one iteration updates its members in pykalman's order H, R, F,
/// Q, mu_0, Sigma_0, b, d (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct EmVariables(u8);

impl EmVariables {
    /// Nothing: [`em`] only evaluates the log-likelihood.
    pub const NONE: Self = Self(0);
    /// Q.
    pub const TRANSITION_COVARIANCE: Self = Self(1);
    /// R.
    pub const OBSERVATION_COVARIANCE: Self = Self(2);
    /// mu_0.
    pub const INITIAL_STATE_MEAN: Self = Self(4);
    /// Sigma_0.
    pub const INITIAL_STATE_COVARIANCE: Self = Self(8);
    /// F (pykalman's `transition_matrices`).
    pub const TRANSITION_MATRIX: Self = Self(16);
    /// H (pykalman's `observation_matrices`).
    pub const OBSERVATION_MATRIX: Self = Self(32);
    /// b: one constant offset is learned, [`TransitionOffsets::Constant`], even from
    /// per-step ones (as pykalman, which warns that the time-varying offsets become
    /// one).
    pub const TRANSITION_OFFSETS: Self = Self(64);
    /// d (pykalman's `observation_offsets`).
    pub const OBSERVATION_OFFSET: Self = Self(128);
    /// Q and R (pykalman's `test_kalman_fit`).
    pub const NOISE_COVARIANCES: Self = Self(1 | 2);
    /// Q, R, mu_0 and Sigma_0 (pykalman's default `em_vars`).
    pub const NOISE_AND_INITIAL_STATE: Self = Self(1 | 2 | 4 | 8);
    /// Every parameter: Q, R, mu_0, Sigma_0, F, H, b and d (pykalman's
    /// `em_vars='all'`).
    pub const ALL: Self = Self(u8::MAX);

    /// Whether every variable of `other` is in `self`.
    pub const fn contains(self, other: Self) -> bool {
        self.0 & other.0 == other.0
    }

    /// Whether no variable is chosen.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }
}

impl BitOr for EmVariables {
    type Output = Self;
    fn bitor(self, other: Self) -> Self {
        Self(self.0 | other.0)
    }
}

/// What [`em`] returns.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct EmFit {
    /// The model after the last iteration (the unchosen parameters as given).
    pub model: LinearGaussianModel,
    /// The log-likelihood (nats) of the measurements under the model after k
    /// iterations, k = 0 ..= iterations: element 0 is the given model's, the last
    /// is [`EmFit::model`]'s. Non-decreasing up to round-off. Shorter than
    /// `iterations + 1` when the fit stopped early ([`EmFit::stop`]).
    pub log_likelihoods: Vec<f64>,
    /// Why the iterations ended.
    pub stop: EmStop,
}

/// Why [`em`] stopped iterating.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum EmStop {
    /// Every requested iteration ran.
    Completed,
    /// Iteration `iteration` (1-based) produced no valid model: its smoother pass, its
    /// M-step or the fitted model's filter pass failed the library's checks with
    /// `error` (e.g. [`Error::InvalidCovariance`] for a fitted covariance that is not
    /// positive semidefinite, [`Error::NonFinite`] for an M-step sum that overflows,
    /// [`Error::InnovationNotPositiveDefinite`] for the fitted model's S). The fit
    /// holds the model of the iteration before (the given model when `iteration` is
    /// 1) and `iteration` log-likelihoods.
    Refused {
        /// The iteration that failed, 1-based.
        iteration: usize,
        /// The check that refused it.
        error: Error,
    },
}

/// The log-likelihood (nats) of `measurements` (epochs 0 .. T-1, `None` = missing)
/// under `model`: the sum over the measured epochs of ln N(nu_t; 0, S_t) (module docs).
/// 0 when no epoch is measured.
///
/// # Errors
/// [`Error::InvalidParameter`] for an empty sequence; [`Error::Dimension`] for a
/// measurement not of size m or per-step offsets not numbering T - 1;
/// [`Error::NonFinite`] for a non-finite measurement or an overflow;
/// [`Error::InnovationNotPositiveDefinite`] if some S_t is not positive definite.
pub fn log_likelihood(
    model: &LinearGaussianModel,
    measurements: &[Option<DVector<f64>>],
) -> Result<f64> {
    check_measurements(model, measurements)?;
    Ok(filter(model, measurements)?.log_likelihood)
}

/// `iterations` EM iterations from `model` on `measurements`, learning `vars` (module
/// docs for the E- and M-steps). Each iteration is one filter and smoother pass and
/// the closed-form M-step; one more filter pass gives the fitted model's
/// log-likelihood. `iterations = 0` returns the model and its log-likelihood.
///
/// An iteration whose result fails the library's checks (a fitted covariance not
/// positive semidefinite to round-off, a smoother gain, an M-step sum or a fitted value
/// that overflows, a fitted model whose S is not positive definite) stops the fit:
/// the result holds the last valid model and says why in [`EmFit::stop`]
/// ([`EmStop::Refused`], with the typed error).
///
/// # Errors
/// Those of [`log_likelihood`] for the given model; [`Error::InvalidParameter`] when
/// learning R, H or d with no measured epoch or Q, F or b with fewer than 2 epochs
/// (nothing to average).
pub fn em(
    model: &LinearGaussianModel,
    measurements: &[Option<DVector<f64>>],
    vars: EmVariables,
    iterations: usize,
) -> Result<EmFit> {
    check_measurements(model, measurements)?;
    let measured = measurements.iter().filter(|y| y.is_some()).count();
    for (var, what) in [
        (
            EmVariables::OBSERVATION_COVARIANCE,
            "observation covariance",
        ),
        (EmVariables::OBSERVATION_MATRIX, "observation matrix"),
        (EmVariables::OBSERVATION_OFFSET, "observation offset"),
    ] {
        if vars.contains(var) && measured == 0 {
            return Err(Error::InvalidParameter {
                name: "measurements",
                reason: format!("learning the {what} needs at least one measured epoch"),
            });
        }
    }
    for (var, what) in [
        (EmVariables::TRANSITION_COVARIANCE, "transition covariance"),
        (EmVariables::TRANSITION_MATRIX, "transition matrix"),
        (EmVariables::TRANSITION_OFFSETS, "transition offsets"),
    ] {
        if vars.contains(var) && measurements.len() < 2 {
            return Err(Error::InvalidParameter {
                name: "measurements",
                reason: format!("learning the {what} needs at least 2 epochs"),
            });
        }
    }
    let mut model = model.clone();
    // The given model's filter pass: its failure is the input's, an error.
    let mut forward = filter(&model, measurements)?;
    let mut log_likelihoods = Vec::with_capacity(iterations.saturating_add(1).min(1 << 16));
    log_likelihoods.push(forward.log_likelihood);
    let mut stop = EmStop::Completed;
    for iteration in 1..=iterations {
        let next = smooth(&model, &forward)
            .and_then(|smoothed| maximise(&model, measurements, &smoothed, vars))
            .and_then(|fitted| filter(&fitted, measurements).map(|pass| (fitted, pass)));
        match next {
            Ok((fitted, pass)) => {
                log_likelihoods.push(pass.log_likelihood);
                model = fitted;
                forward = pass;
            }
            Err(error) => {
                stop = EmStop::Refused { iteration, error };
                break;
            }
        }
    }
    Ok(EmFit {
        model,
        log_likelihoods,
        stop,
    })
}
