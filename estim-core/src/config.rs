//! Runner configuration: covariance form, innovation gate, joint-covariance policy.

use crate::{CovarianceUpdate, Error, Result};

/// Innovation gate: reject a measurement whose normalised innovation squared (NIS)
/// is implausibly large for its size.
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[non_exhaustive]
pub enum Gate {
    /// Accept every measurement (default).
    #[default]
    None,
    /// Reject when NIS exceeds the chi-square quantile of `probability` for the
    /// measurement size M (e.g. 0.999 rejects 0.1 % of consistent measurements).
    Nis {
        /// Probability in (0, 1) of the chi-square(M) quantile used as threshold.
        probability: f64,
    },
    /// Reject when NIS exceeds this fixed threshold (any measurement size).
    NisThreshold(f64),
}

/// What the innovation gate does after a run of rejections.
///
/// A filter whose covariance has become smaller than its actual error rejects exactly
/// the measurements that would correct it, and stays locked out: its error grows while
/// every update is gated. A recovery rule lets such a filter admit it is lost.
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum GateRecovery {
    /// Keep rejecting (default).
    #[default]
    None,
    /// After `after` consecutive rejections (by any measurement model of this filter),
    /// the next measurement the gate would reject is accepted with the prior covariance
    /// inflated, P -> lambda P, by the smallest lambda >= 1 that brings its NIS down to
    /// the gate threshold: one fading-memory step (Fagin 1964; Sorenson & Sacks 1971,
    /// "Recursive fading memory filtering"), sized so the measurement lies on the gate's
    /// boundary. lambda is at most [`GateRecovery::MAX_INFLATION`]; a measurement that
    /// still fails the gate there (its innovation lies where H P H' is zero) stays
    /// rejected. The update report gives lambda in `covariance_inflation`.
    ///
    /// The inflation is a deliberate change of the model, not a Kalman step: a later
    /// windowed cross-covariance whose window contains it is exact for the inflated
    /// covariance the filter carried, not for the original model.
    Inflate {
        /// Consecutive rejections before the rule applies, at least 1.
        after: usize,
    },
}

impl GateRecovery {
    /// The largest covariance inflation factor the [`GateRecovery::Inflate`] rule uses.
    pub const MAX_INFLATION: f64 = 1e6;
}

/// Measurement sizes whose gate threshold is precomputed by [`FilterConfig::build`].
const CACHED_SIZES: usize = 16;

impl Gate {
    /// The NIS threshold for a measurement of size `m`; `None` when the gate is off.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for a probability outside (0, 1), a non-positive
    /// threshold or `m = 0`, and for [`Gate::Nis`] when estim-core is built without its
    /// `consistency` feature (no chi-square quantile; use [`Gate::NisThreshold`]).
    pub fn threshold(&self, m: usize) -> Result<Option<f64>> {
        match *self {
            Gate::None => Ok(None),
            Gate::Nis { probability } => {
                if !(probability > 0.0 && probability < 1.0) {
                    return Err(Error::InvalidParameter {
                        name: "gate probability",
                        reason: format!("{probability} is not in (0, 1)"),
                    });
                }
                chi_square_quantile(m, probability).map(Some)
            }
            Gate::NisThreshold(t) => {
                if t.is_finite() && t > 0.0 {
                    Ok(Some(t))
                } else {
                    Err(Error::InvalidParameter {
                        name: "gate threshold",
                        reason: format!("{t} is not a positive finite number"),
                    })
                }
            }
        }
    }
}

/// The `probability` quantile of chi-square(`m`).
#[cfg(feature = "consistency")]
fn chi_square_quantile(m: usize, probability: f64) -> Result<f64> {
    if m == 0 {
        return Err(Error::InvalidParameter {
            name: "measurement size",
            reason: "chi-square with 0 degrees of freedom".into(),
        });
    }
    crate::consistency::chi_square_quantile(m as f64, probability)
}

/// Without the `consistency` feature there is no chi-square quantile: refuse the gate.
#[cfg(not(feature = "consistency"))]
fn chi_square_quantile(_m: usize, _probability: f64) -> Result<f64> {
    Err(Error::InvalidParameter {
        name: "gate",
        reason: "Gate::Nis needs estim-core's `consistency` feature (chi-square quantiles); \
                 use Gate::NisThreshold"
            .into(),
    })
}

/// What a runner does with the joint covariance [[Q_acc, M], [M', R]] at each update.
///
/// Both checking policies use [`crate::JointCovariance::validity_margin`]: a static LDL' of the
/// joint correlation matrix first (no allocation, about (N+M)^3/6 multiply-adds), and
/// an allocating (N+M)-square eigen decomposition only when that factorisation does
/// not certify the matrix (invalid, or too close to call). The reported number is >=
/// -[`crate::JointCovariance::tolerance`] iff the joint covariance is valid: for a valid one it is
/// the smallest LDL' pivot of the correlation matrix (0 when singular, at most 1; an
/// upper bound on its smallest eigenvalue), for an invalid one the smallest eigenvalue.
/// `Skip` avoids even the factorisation and reports `None`.
///
/// The default is `Reject`: an M that is not a covariance is refused before it touches
/// the state, as is an M != 0 when Q_acc = 0 (a correlated update with no predict
/// since the previous one; any nonzero covariance beside a zero variance is invalid).
/// `Report` (use the update and only report the margin) and `Skip` are explicit
/// opt-ins, for studies of what an invalid M does.
///
/// ```
/// use estim_core::nalgebra::{Matrix1, Matrix1x2, Matrix2, Matrix2x1, Vector1, Vector2};
/// use estim_core::{Error, FilterConfig, Fixed, JointCheck, KalmanFilter, StateAndCovariance};
///
/// let initial = StateAndCovariance::new(Vector2::zeros(), Matrix2::identity())?;
/// let q = Matrix2::new(0.25, 0.5, 0.5, 1.0) * 0.01;
/// let kf = |config: FilterConfig| {
///     KalmanFilter::new(Matrix2::new(1.0, 1.0, 0.0, 1.0), q, Matrix1x2::new(1.0, 0.0),
///         Matrix1::new(0.01), initial.clone()).map(|kf| kf.with_config(config))
/// };
/// // |corr(w_1, v)| = 0.5 / sqrt(0.25 * 0.01 * 100) > 1: not a covariance.
/// let m = Fixed(Matrix2x1::new(0.5, 0.0) * 0.01);
/// let mut refused = kf(FilterConfig::default())?;
/// refused.predict()?;
/// let before = refused.estimate().clone();
/// let err = refused.update(&Vector1::new(0.1), &m).unwrap_err();
/// assert!(matches!(err, Error::InvalidJointCovariance { .. }));
/// assert_eq!(refused.estimate(), &before); // untouched by the refused update
///
/// let report_only = FilterConfig::builder().joint_check(JointCheck::Report).build()?;
/// let mut used = kf(report_only)?;
/// used.predict()?;
/// let report = used.update(&Vector1::new(0.1), &m)?;
/// assert!(report.joint_min_eigenvalue.unwrap() < 0.0); // used, and said so
/// # Ok::<(), Error>(())
/// ```
///
/// With M = 0 the joint is
/// block diagonal and its LDL' is Q_acc's and R's apart; a runner keeps Q_acc's part
/// from its last update and reuses it while Q_acc is unchanged (a time-invariant
/// model with one predict per update factors its Q once), with the same result.
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum JointCheck {
    /// Do not compute it; the update report says `None` (not checked). Opt-in.
    Skip,
    /// Compute the validity margin, put it in the update report, and use M even when
    /// it is not a covariance. Opt-in (a study of an invalid M, e.g. the paper's rho
    /// beyond its bound).
    Report,
    /// Compute it and fail with [`Error::InvalidJointCovariance`] when the joint
    /// covariance is not positive semidefinite (tolerance of
    /// [`crate::JointCovariance::check`]); the state is left untouched. The default.
    /// A one-step update with M != 0 and `track_accumulated_noise(false)` cannot be
    /// checked and fails with [`Error::NotTracked`].
    #[default]
    Reject,
}

/// Checked configuration shared by the runners. Build with [`FilterConfig::builder`];
/// [`FilterConfig::default`] is the square-root form, no gate, an invalid joint
/// covariance refused ([`JointCheck::Reject`]).
///
/// With the `serde` feature it serializes as its settings (those of
/// [`FilterConfigBuilder`]; missing keys take the defaults, unknown keys are refused)
/// and deserializes through [`FilterConfigBuilder::build`], so an invalid gate is
/// refused and the gate thresholds are recomputed.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(try_from = "FilterConfigBuilder", into = "FilterConfigBuilder")
)]
pub struct FilterConfig {
    form: CovarianceUpdate,
    gate: Gate,
    gate_recovery: GateRecovery,
    joint_check: JointCheck,
    track_accumulated_noise: bool,
    window_capacity: usize,
    /// Gate threshold for M = 1..=CACHED_SIZES (index M-1), so the per-update gate
    /// costs no quantile computation.
    thresholds: [Option<f64>; CACHED_SIZES],
}

impl Default for FilterConfig {
    fn default() -> Self {
        Self {
            form: CovarianceUpdate::default(),
            gate: Gate::None,
            gate_recovery: GateRecovery::None,
            joint_check: JointCheck::default(),
            track_accumulated_noise: true,
            window_capacity: 0,
            thresholds: [None; CACHED_SIZES],
        }
    }
}

impl FilterConfig {
    /// The largest [`FilterConfigBuilder::window_capacity`]: 2^16 recorded steps
    /// (11 minutes of a 100 Hz process; each step keeps an N x N transition, the
    /// state and the input, allocated once when the runner starts).
    pub const MAX_WINDOW_CAPACITY: usize = 1 << 16;

    /// Start a configuration from the defaults.
    pub fn builder() -> FilterConfigBuilder {
        FilterConfigBuilder {
            form: CovarianceUpdate::default(),
            gate: Gate::None,
            gate_recovery: GateRecovery::None,
            joint_check: JointCheck::default(),
            track_accumulated_noise: true,
            window_capacity: 0,
        }
    }

    /// The covariance update form.
    pub fn covariance_update(&self) -> CovarianceUpdate {
        self.form
    }

    /// The innovation gate.
    pub fn gate(&self) -> Gate {
        self.gate
    }

    /// What the gate does after a run of rejections.
    pub fn gate_recovery(&self) -> GateRecovery {
        self.gate_recovery
    }

    /// The joint-covariance policy.
    pub fn joint_check(&self) -> JointCheck {
        self.joint_check
    }

    /// Whether the runners accumulate Q_acc and Phi_acc between updates (for
    /// [`crate::CrossCovariance`] models and the joint check of one-step updates).
    pub fn track_accumulated_noise(&self) -> bool {
        self.track_accumulated_noise
    }

    /// How many process steps the runners keep for exact windowed cross-covariances
    /// (0: none, nothing recorded; see [`crate::WindowedCrossCovariance`]).
    pub fn window_capacity(&self) -> usize {
        self.window_capacity
    }

    /// NIS threshold for a measurement of size `m` (cached for small sizes).
    pub fn gate_threshold(&self, m: usize) -> Result<Option<f64>> {
        match m {
            1..=CACHED_SIZES => Ok(self.thresholds[m - 1]),
            _ => self.gate.threshold(m),
        }
    }
}

/// Builder of [`FilterConfig`] (consuming setters, validated by [`FilterConfigBuilder::build`]).
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(default, deny_unknown_fields)
)]
#[must_use]
pub struct FilterConfigBuilder {
    form: CovarianceUpdate,
    gate: Gate,
    gate_recovery: GateRecovery,
    joint_check: JointCheck,
    track_accumulated_noise: bool,
    window_capacity: usize,
}

impl Default for FilterConfigBuilder {
    /// [`FilterConfig::builder`].
    fn default() -> Self {
        FilterConfig::builder()
    }
}

impl From<FilterConfig> for FilterConfigBuilder {
    /// The settings a configuration was built from.
    fn from(config: FilterConfig) -> Self {
        Self {
            form: config.form,
            gate: config.gate,
            gate_recovery: config.gate_recovery,
            joint_check: config.joint_check,
            track_accumulated_noise: config.track_accumulated_noise,
            window_capacity: config.window_capacity,
        }
    }
}

impl TryFrom<FilterConfigBuilder> for FilterConfig {
    type Error = Error;

    /// [`FilterConfigBuilder::build`].
    fn try_from(builder: FilterConfigBuilder) -> Result<Self> {
        builder.build()
    }
}

impl FilterConfigBuilder {
    /// Posterior covariance form (square-root by default; see `CovarianceUpdate`).
    pub fn covariance_update(self, form: CovarianceUpdate) -> Self {
        Self { form, ..self }
    }

    /// Innovation gate (none by default).
    pub fn gate(self, gate: Gate) -> Self {
        Self { gate, ..self }
    }

    /// What the gate does after a run of rejections (none by default; needs a gate).
    pub fn gate_recovery(self, gate_recovery: GateRecovery) -> Self {
        Self {
            gate_recovery,
            ..self
        }
    }

    /// Joint-covariance policy ([`JointCheck::Reject`] by default).
    pub fn joint_check(self, joint_check: JointCheck) -> Self {
        Self {
            joint_check,
            ..self
        }
    }

    /// Accumulate Q_acc and Phi_acc between updates (default `true`). Turn it off when
    /// every update uses [`crate::Zero`], [`crate::Fixed`] or a
    /// [`crate::WindowedCrossCovariance`]: predict then does no accumulation work.
    /// Models that read Q_acc ([`crate::ScaledCorrelation`]) fail with
    /// [`Error::NotTracked`] without it, and the joint check of a one-step update
    /// with M != 0 cannot be made (`Reject`, the default: that error; `Report`: `None`).
    pub fn track_accumulated_noise(self, track_accumulated_noise: bool) -> Self {
        Self {
            track_accumulated_noise,
            ..self
        }
    }

    /// Keep the last `steps` process steps (transition, state, input, dt) and the
    /// updates among them, so that a [`crate::WindowedCrossCovariance`] whose
    /// measurement noise shares up to `steps` steps of process noise gets its exact
    /// M (default 0: nothing kept, windowed updates fail with
    /// [`Error::WindowUnavailable`]). Memory: `steps` records, allocated once; at
    /// most [`FilterConfig::MAX_WINDOW_CAPACITY`] (checked by
    /// [`FilterConfigBuilder::build`]).
    pub fn window_capacity(self, steps: usize) -> Self {
        Self {
            window_capacity: steps,
            ..self
        }
    }

    /// Validate and precompute the gate thresholds.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for an invalid gate, for a
    /// [`GateRecovery::Inflate`] with `after = 0` or without a gate, and for a
    /// window capacity above [`FilterConfig::MAX_WINDOW_CAPACITY`].
    pub fn build(self) -> Result<FilterConfig> {
        if self.window_capacity > FilterConfig::MAX_WINDOW_CAPACITY {
            return Err(Error::InvalidParameter {
                name: "window_capacity",
                reason: format!(
                    "{} steps exceeds the bound of {} recorded steps",
                    self.window_capacity,
                    FilterConfig::MAX_WINDOW_CAPACITY
                ),
            });
        }
        let mut thresholds = [None; CACHED_SIZES];
        for (i, t) in thresholds.iter_mut().enumerate() {
            *t = self.gate.threshold(i + 1)?;
        }
        if let GateRecovery::Inflate { after } = self.gate_recovery {
            if after == 0 {
                return Err(Error::InvalidParameter {
                    name: "gate recovery",
                    reason: "`after` must be at least 1 consecutive rejection".into(),
                });
            }
            if matches!(self.gate, Gate::None) {
                return Err(Error::InvalidParameter {
                    name: "gate recovery",
                    reason: "a recovery rule needs an innovation gate (Gate::None rejects nothing)"
                        .into(),
                });
            }
        }
        Ok(FilterConfig {
            form: self.form,
            gate: self.gate,
            gate_recovery: self.gate_recovery,
            joint_check: self.joint_check,
            track_accumulated_noise: self.track_accumulated_noise,
            window_capacity: self.window_capacity,
            thresholds,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[cfg(feature = "consistency")]
    fn gate_thresholds_match_published_chi_square_quantiles() {
        // Published 95 % and 99 % quantiles (e.g. NIST/SEMATECH e-Handbook table 1.3.6.7.4).
        let g = FilterConfig::builder()
            .gate(Gate::Nis { probability: 0.95 })
            .build()
            .unwrap();
        for (m, q) in [(1, 3.841), (2, 5.991), (3, 7.815), (4, 9.488), (6, 12.592)] {
            let t = g.gate_threshold(m).unwrap().unwrap();
            assert!((t - q).abs() < 1e-3, "m={m}: {t} vs {q}");
        }
        let t99 = Gate::Nis { probability: 0.99 }
            .threshold(20)
            .unwrap()
            .unwrap();
        assert!((t99 - 37.566).abs() < 1e-3);
    }

    #[test]
    fn invalid_gates_are_typed_errors() {
        #[cfg(not(feature = "consistency"))]
        assert!(matches!(
            FilterConfig::builder()
                .gate(Gate::Nis { probability: 0.99 })
                .build(),
            Err(Error::InvalidParameter { name: "gate", .. })
        ));
        for gate in [
            Gate::Nis { probability: 0.0 },
            Gate::Nis { probability: 1.0 },
            Gate::Nis {
                probability: f64::NAN,
            },
            Gate::NisThreshold(-1.0),
            Gate::NisThreshold(f64::INFINITY),
        ] {
            assert!(matches!(
                FilterConfig::builder().gate(gate).build(),
                Err(Error::InvalidParameter { .. })
            ));
        }
    }

    #[test]
    fn invalid_gate_recoveries_are_typed_errors() {
        for (gate, after) in [
            (Gate::NisThreshold(9.0), 0),
            (Gate::None, 1),
            (Gate::None, 5),
        ] {
            assert!(matches!(
                FilterConfig::builder()
                    .gate(gate)
                    .gate_recovery(GateRecovery::Inflate { after })
                    .build(),
                Err(Error::InvalidParameter {
                    name: "gate recovery",
                    ..
                })
            ));
        }
        let ok = FilterConfig::builder()
            .gate(Gate::NisThreshold(9.0))
            .gate_recovery(GateRecovery::Inflate { after: 3 })
            .build()
            .unwrap();
        assert_eq!(ok.gate_recovery(), GateRecovery::Inflate { after: 3 });
    }

    /// A window capacity beyond the bound is a typed error at `build`, naming the
    /// key and the bound (it used to build and then fail allocating the window).
    #[test]
    fn window_capacity_is_bounded() {
        for steps in [usize::MAX, FilterConfig::MAX_WINDOW_CAPACITY + 1] {
            let err = FilterConfig::builder()
                .window_capacity(steps)
                .build()
                .unwrap_err();
            match err {
                Error::InvalidParameter { name, reason } => {
                    assert_eq!(name, "window_capacity");
                    assert!(reason.contains("65536"), "{reason}");
                }
                other => panic!("{other}"),
            }
        }
        let config = FilterConfig::builder()
            .window_capacity(FilterConfig::MAX_WINDOW_CAPACITY)
            .build()
            .unwrap();
        assert_eq!(config.window_capacity(), FilterConfig::MAX_WINDOW_CAPACITY);
    }
}
