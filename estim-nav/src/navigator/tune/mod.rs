//! Maximum-likelihood noise parameters of the INS/DVL filter: the IMU's white-noise
//! densities, the DVL's beam-level noise and the DVL-versus-motion mismatch, and the
//! scale of the paper's cross-covariance heuristic, with standard errors and a
//! likelihood-ratio test of M = 0. `estim tune` runs it on A-KIT training trajectories.
//!
//! ## Parameters
//!
//! theta = \[q_a, q_g, s_b, s_m, rho\] ([`PARAMETER_NAMES`]):
//! - q_a, q_g: the accelerometer's and the gyroscope's white-noise PSD (the square of
//!   [`estim_ins::SensorSpec::white_noise_density`]); the bias drift stays as given;
//! - R(theta) = s_b (A'A)^-1 + s_m I: s_b the variance of each beam's velocity (A the
//!   beam geometry, so s_b (A'A)^-1 is the least-squares velocity's covariance), s_m a
//!   per-axis variance for what the DVL measures beyond the vehicle's motion; the two
//!   are told apart by their different shares of the horizontal and vertical axes;
//! - M(theta) = rho sqrt(diag Q_acc(theta)) sqrt(diag R(theta))' (the paper's heuristic,
//!   [`estim_core::ScaledCorrelation`], over the process noise accumulated since the
//!   previous update); rho = 0 is M = 0.
//!
//! ## The likelihood
//!
//! The navigator is run once at a linearization point theta_0 ([`linearize`]: its one
//! IMU loop, [`super::run_epochs`], with no gate), and a hook records its steps
//! ([`super::Navigator::last_step`]) between DVL epochs as the accumulated
//! transition Phi_acc and the accumulated process noise split into its three parts,
//! Q_acc(theta) = q_a Q_a + q_g Q_g + Q_bias (Q_d is linear in the PSDs), and at each
//! epoch the DVL Jacobian H, the innovation y_k = z_k - h(nominal), the injected
//! correction Delta_k and the reset Jacobian J_k. The error of the corrected nominal
//! then follows a linear-Gaussian model with a known input (the corrections, which
//! depend on past data only):
//!
//! ```text
//! dx_k = Phi_acc,k J_{k-1} (dx_{k-1} - Delta_{k-1}) + w_k,   y_k = H_k dx_k + v_k
//! ```
//!
//! whose exact Gaussian log-likelihood ([`InsDvlLikelihood`]) is that of a
//! time-varying [`estim_core::KalmanFilter`] with control input, at one step per DVL
//! epoch; at theta = theta_0 it equals the error-state filter's own
//! `log_likelihood()` (tested). The fit ([`tune`]) maximises it with
//! [`estim_core::noise::ml::maximize`] (exact derivatives by dual numbers),
//! relinearizes the filter at the estimate and fits again
//! ([`TuneOptions::linearizations`] passes), then refits with rho fixed at 0 for the
//! likelihood-ratio test. Every DVL epoch enters: the filter runs with no innovation
//! gate, so the likelihood is of all the measurements given.

use estim_core::nalgebra::{Matrix3, SMatrix, SVector, Vector3};
use estim_core::noise::ml::{
    gradient, likelihood_ratio_test, maximize, Bounds, FitOptions, FitStop, LikelihoodRatioTest,
    LogLikelihood, MaximumLikelihood,
};
use estim_core::numeric::lit;
use estim_core::{
    ErrorStateModel, FilterConfig, Fixed, JointCheck, KalmanFilter, MeasurementModel, ProcessModel,
    Scalar, ScaledCorrelation, StateAndCovariance,
};
use estim_dvl::{BeamGeometry, DvlVelocityModel};
use estim_ins::{ErrorMatrix, ImuSample, ImuSpec, InsErrorModel, InsState, ERROR_STATES};

use super::{
    filter_imu_spec, DvlInput, NavigatorError, NavigatorSettings, Result, SurveyInputs,
    IMU_PERIOD_SNAP,
};

mod likelihood;
mod linearize;
pub use likelihood::InsDvlLikelihood;
pub use linearize::{linearize, Linearization};

/// Number of parameters.
pub const TUNE_PARAMETERS: usize = 5;

/// The parameters' names, in theta's order.
pub const PARAMETER_NAMES: [&str; TUNE_PARAMETERS] = [
    "accelerometer_psd",
    "gyroscope_psd",
    "dvl_beam_variance",
    "dvl_mismatch_variance",
    "m_scale",
];

/// The parameters' units, in theta's order.
pub const PARAMETER_UNITS: [&str; TUNE_PARAMETERS] =
    ["(m/s^2)^2/Hz", "(rad/s)^2/Hz", "(m/s)^2", "(m/s)^2", "1"];

/// Index of rho (the M scale) in theta.
pub const M_SCALE: usize = 4;

/// theta = \[q_a, q_g, s_b, s_m, rho\] (module docs).
pub type TuneParameters = SVector<f64, TUNE_PARAMETERS>;

/// One trajectory to learn from: IMU samples, DVL velocities and the initial state.
#[derive(Debug, Clone, Copy)]
pub struct TuneTrajectory<'a> {
    /// IMU samples in time order; sample j is held from its time to the next one's.
    pub imu: &'a [ImuSample],
    /// Nominal IMU period \[s\] (an interval within [`IMU_PERIOD_SNAP`] relative of it
    /// is taken as exactly the period, as the navigator does).
    pub imu_period: f64,
    /// DVL measurements: (time of the motion measured \[s\], i.e. the stamp minus the
    /// DVL's time offset; velocity in the DVL frame \[m/s\]), times ascending, within
    /// the IMU's span (up to one period after the last sample). A time between two IMU
    /// samples cuts the held sample's interval there, as the navigator does.
    pub dvl: &'a [(f64, Vector3<f64>)],
    /// The nominal state at the first IMU sample's time.
    pub initial: InsState,
    /// Its error covariance.
    pub covariance: ErrorMatrix,
}

/// The fixed part of the model: the IMU's error model (its white-noise densities are
/// replaced by theta), the DVL model (lever arm, scale factor, misalignment; its R is
/// replaced by R(theta)) and the beam geometry of R(theta).
#[derive(Debug, Clone)]
pub struct TuneModel {
    /// The IMU's error model (the filter uses [`filter_imu_spec`] of it).
    pub sensor_spec: ImuSpec,
    /// The DVL measurement model.
    pub dvl: DvlVelocityModel,
    /// The beam geometry: R(theta)'s beam term is s_b (A'A)^-1.
    pub geometry: BeamGeometry,
}

impl TuneModel {
    /// (A'A)^-1 of the beam geometry.
    pub fn beam_covariance(&self) -> Matrix3<f64> {
        let pinv = self.geometry.pseudo_inverse();
        pinv * pinv.transpose()
    }

    /// R(theta) = s_b (A'A)^-1 + s_m I.
    pub fn measurement_noise(&self, theta: &TuneParameters) -> Matrix3<f64> {
        measurement_noise(&self.beam_covariance(), theta[2], theta[3])
    }

    /// The filter's IMU spec at theta (white-noise densities sqrt(q_a), sqrt(q_g)).
    ///
    /// # Errors
    /// [`NavigatorError::InvalidValue`] for a negative or non-finite PSD.
    pub fn filter_spec(&self, theta: &TuneParameters) -> Result<ImuSpec> {
        let (qa, qg) = (theta[0], theta[1]);
        if !(qa.is_finite() && qa >= 0.0 && qg.is_finite() && qg >= 0.0) {
            return Err(NavigatorError::invalid(
                "tune",
                format!("IMU PSDs {qa}, {qg} must be finite and >= 0"),
            ));
        }
        let mut acc = *self.sensor_spec.accelerometer();
        let mut gyro = *self.sensor_spec.gyroscope();
        acc.white_noise_density = qa.sqrt();
        gyro.white_noise_density = qg.sqrt();
        let spec = ImuSpec::builder()
            .accelerometer(acc)
            .gyroscope(gyro)
            .build()?;
        filter_imu_spec(&spec)
    }

    /// The DVL model with R(theta).
    fn dvl_with_noise(&self, r: Matrix3<f64>) -> Result<DvlVelocityModel> {
        Ok(DvlVelocityModel::builder()
            .lever_arm(*self.dvl.lever_arm())
            .scale_factor_error(self.dvl.scale_factor_error())
            .mounting_misalignment(*self.dvl.mounting_misalignment())
            .noise_covariance(r)
            .build()?)
    }
}

impl TuneModel {
    /// The model of a navigator configuration: its IMU spec, its DVL model (lever arm,
    /// scale factor, misalignment) and its beam geometry.
    pub fn from_settings(settings: &NavigatorSettings) -> Self {
        Self {
            sensor_spec: *settings.sensor_spec(),
            dvl: settings.dvl_model().clone(),
            geometry: settings.beam_geometry().clone(),
        }
    }

    /// A starting point from a configuration: the IMU spec's white-noise PSDs, and the
    /// DVL's per-axis variance `dvl_std^2` split evenly between the beam term and the
    /// mismatch term (the beam term's share averaged over the axes), rho = 0.
    pub fn start(&self, dvl_std: f64) -> TuneParameters {
        let beam = self.beam_covariance();
        let half = 0.5 * dvl_std * dvl_std;
        TuneParameters::from([
            self.sensor_spec.accelerometer().white_noise_density.powi(2),
            self.sensor_spec.gyroscope().white_noise_density.powi(2),
            half / (beam.trace() / 3.0),
            half,
            0.0,
        ])
    }
}

/// A survey's inputs as [`tune`] takes them, with the navigator's arithmetic
/// ([`super::navigate`]): each DVL row at its stamp minus the configured time offset,
/// applied at the nearest IMU sample time within half a period; beams solved by least
/// squares with the configured geometry (3 or 4 beams); the initial state and
/// covariance from the configuration, the first fix and a coarse alignment.
#[derive(Debug, Clone)]
pub struct SurveyMeasurements {
    /// (time, DVL-frame velocity) per usable DVL row.
    pub dvl: Vec<(f64, Vector3<f64>)>,
    /// The initial nominal state.
    pub initial: InsState,
    /// Its error covariance.
    pub covariance: ErrorMatrix,
    /// The nominal IMU period \[s\].
    pub imu_period: f64,
    /// Rows skipped: no bottom lock, fewer than 3 beams, or outside the IMU's span.
    pub skipped: usize,
}

impl SurveyMeasurements {
    /// The trajectory over `imu` (the same IMU samples the measurements came with).
    pub fn trajectory<'a>(&'a self, imu: &'a [ImuSample]) -> TuneTrajectory<'a> {
        TuneTrajectory {
            imu,
            imu_period: self.imu_period,
            dvl: &self.dvl,
            initial: self.initial,
            covariance: self.covariance,
        }
    }
}

/// [`SurveyMeasurements`] of `inputs` (depth and fixes only seed the initial state;
/// the likelihood is of the DVL velocities).
///
/// # Errors
/// [`NavigatorError::Inputs`] for no IMU samples, no initial position, DVL velocities
/// in earth coordinates (their rotation into the body frame would need the filter's
/// attitude, which the likelihood does not model), or no usable DVL row.
pub fn survey_measurements(
    inputs: &SurveyInputs,
    settings: &NavigatorSettings,
) -> Result<SurveyMeasurements> {
    let imu = &inputs.imu;
    let imu_period = super::initial::imu_period(imu, settings)?;
    let (initial, covariance, _) = super::initial::initial_state(inputs, settings)?;
    let offset = settings.config().dvl.time_offset_s;
    let mut dvl = Vec::with_capacity(inputs.dvl.len());
    let mut skipped = 0;
    for (row, record) in inputs.dvl.iter().enumerate() {
        let velocity = match record.input {
            DvlInput::Velocity(v) => Some(v),
            DvlInput::Beams(beams) => settings.beam_geometry().solve(&beams).velocity(),
            DvlInput::NoLock => None,
            DvlInput::EarthVelocity(_) => {
                return Err(NavigatorError::Inputs(format!(
                    "DVL row {row} (t = {} s): tune takes body-frame velocities or beams, \
                     not earth-frame velocities",
                    record.time
                )))
            }
        };
        match (
            velocity,
            super::batch::snap(imu, imu_period, record.time - offset),
        ) {
            (Some(v), Some(time)) => dvl.push((time, v)),
            _ => skipped += 1,
        }
    }
    if dvl.is_empty() {
        return Err(NavigatorError::Inputs(
            "no usable DVL row inside the IMU's span".into(),
        ));
    }
    // Stable, as the navigator merges its events.
    dvl.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(SurveyMeasurements {
        dvl,
        initial,
        covariance,
        imu_period,
        skipped,
    })
}

fn measurement_noise<T: Scalar>(beam: &SMatrix<T, 3, 3>, sb: T, sm: T) -> SMatrix<T, 3, 3> {
    beam * sb + SMatrix::<T, 3, 3>::identity() * sm
}

/// Options of [`tune`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TuneOptions {
    /// The optimiser's options.
    pub fit: FitOptions,
    /// Linearizations: the first at the starting point, each next one at the previous
    /// fit's estimate (default 2).
    pub linearizations: usize,
    /// rho is bounded by this fraction of the largest valid |rho| at the last
    /// linearization point (default 0.99), so that the joint covariance stays valid.
    pub rho_margin: f64,
    /// Parameters held at a value instead of fitted (`None`: fitted), in theta's
    /// order ([`PARAMETER_NAMES`]); e.g. an IMU density from its data sheet where the
    /// data cannot tell it (a degenerate optimum, [`TuneStatus::Degenerate`]). An
    /// m_scale beyond the largest valid value of a linearization is refused.
    pub fixed: [Option<f64>; TUNE_PARAMETERS],
}

impl Default for TuneOptions {
    fn default() -> Self {
        Self {
            fit: FitOptions::default(),
            linearizations: 2,
            rho_margin: 0.99,
            fixed: [None; TUNE_PARAMETERS],
        }
    }
}

/// Outward derivatives of ln p (times the parameter's scale) down to this value count
/// as zero in the optimality check of a parameter on its bound
/// ([`TuneStatus::ConvergedOnBound`]).
pub const BOUND_GRADIENT_TOLERANCE: f64 = 1e-3;

/// How a fit ended, for a user deciding whether to use it.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum TuneStatus {
    /// Converged inside the bounds: the observed information over the free parameters
    /// is positive definite and the Newton decrement below tolerance.
    Converged,
    /// Converged with these parameters on a bound that is not degenerate (|rho| at the
    /// largest valid M, one of R's two variances at zero): with them held there, the others converged, and ln p does not
    /// increase inward from the bound (the optimality conditions of a bounded
    /// maximum, to [`BOUND_GRADIENT_TOLERANCE`]).
    ConvergedOnBound {
        /// The parameters on their bound.
        parameters: Vec<&'static str>,
    },
    /// A degenerate optimum: an IMU white-noise density went to zero (below 1e-6 of
    /// its start), or both of R's terms did. That noise is then absent from the
    /// filter, which no filter can use, and the data cannot tell it from a small one:
    /// hold them at a value ([`TuneOptions::fixed`]) and fit again. (One of R's two
    /// terms alone at zero leaves R positive definite: a bounded optimum,
    /// [`TuneStatus::ConvergedOnBound`].)
    Degenerate {
        /// The variances at zero.
        parameters: Vec<&'static str>,
    },
    /// The fit did not converge, for this reason (the optimizer's typed stop of the
    /// fit that decides: the full fit, or the refit with the parameters on a bound
    /// held there).
    NotConverged {
        /// Why the optimizer stopped.
        stop: FitStop,
        /// Parameters on a bound (held there for the refit).
        on_bound: Vec<&'static str>,
    },
}

impl TuneStatus {
    /// Whether the fit can be used as it stands (converged, inside or on a valid
    /// bound).
    pub fn is_usable(&self) -> bool {
        matches!(self, Self::Converged | Self::ConvergedOnBound { .. })
    }

    /// A short machine-readable name: `converged`, `converged_on_bound`, `degenerate`
    /// or `not_converged`.
    pub fn as_str(&self) -> &'static str {
        match self {
            Self::Converged => "converged",
            Self::ConvergedOnBound { .. } => "converged_on_bound",
            Self::Degenerate { .. } => "degenerate",
            Self::NotConverged { .. } => "not_converged",
        }
    }
}

impl std::fmt::Display for TuneStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Converged => write!(f, "converged"),
            Self::ConvergedOnBound { parameters } => write!(
                f,
                "converged, with {} on its bound (a bounded maximum)",
                parameters.join(", ")
            ),
            Self::Degenerate { parameters } => write!(
                f,
                "degenerate optimum: {} went to zero, which the data cannot tell from a \
                 small value and which no filter can use; hold them at a value (--fix \
                 NAME=VALUE) and fit again",
                parameters.join(", ")
            ),
            Self::NotConverged { stop, on_bound } => {
                write!(f, "not converged: {stop:?}")?;
                if !on_bound.is_empty() {
                    write!(f, " (with {} held on its bound)", on_bound.join(", "))?;
                }
                Ok(())
            }
        }
    }
}

/// The result of [`tune`].
#[derive(Debug, Clone)]
pub struct TuneFit {
    /// The fit with rho free.
    pub full: MaximumLikelihood<TUNE_PARAMETERS>,
    /// Whether each parameter of `full` ended on its bound (a variance below 1e-6 of its
    /// starting value, or |rho| within 1e-4 relative of its bound).
    pub on_bound: [bool; TUNE_PARAMETERS],
    /// Standard errors of `full` from the observed information over the parameters
    /// that are neither on a bound nor held (`None` for those, where the quadratic
    /// approximation does not hold, and for all when that information is not positive
    /// definite). `full.standard_errors` is the same when no parameter is on a bound.
    pub standard_errors: [Option<f64>; TUNE_PARAMETERS],
    /// How the fit ended ([`TuneStatus`]): use `full` only when
    /// [`TuneStatus::is_usable`].
    pub status: TuneStatus,
    /// The parameters held at a value ([`TuneOptions::fixed`]).
    pub fixed: [Option<f64>; TUNE_PARAMETERS],
    /// The refit with the parameters on a bound held there (`None` when none is on
    /// one); it decides [`TuneStatus::ConvergedOnBound`].
    pub boundary: Option<MaximumLikelihood<TUNE_PARAMETERS>>,
    /// The fit with rho = 0 (M = 0), on the same linearization.
    pub restricted: MaximumLikelihood<TUNE_PARAMETERS>,
    /// The likelihood-ratio test of rho = 0 (1 degree of freedom).
    pub test: LikelihoodRatioTest,
    /// The linearization points, in order (the first is the start).
    pub points: Vec<TuneParameters>,
    /// The bound on |rho| of the last pass.
    pub rho_bound: f64,
    /// DVL epochs in all.
    pub epochs: usize,
}

/// Fit theta on `trajectories` from `start` (module docs).
///
/// # Errors
/// [`NavigatorError::InvalidValue`] for no trajectories, zero linearizations, an invalid
/// start or a held m_scale beyond its valid range; [`linearize`]'s; the fit's errors as [`NavigatorError::Core`].
pub fn tune(
    trajectories: &[TuneTrajectory<'_>],
    model: &TuneModel,
    start: &TuneParameters,
    options: &TuneOptions,
) -> Result<TuneFit> {
    if trajectories.is_empty() || options.linearizations == 0 {
        return Err(NavigatorError::invalid(
            "tune",
            "at least one trajectory and one linearization are needed",
        ));
    }
    if !(start.iter().take(4).all(|v| *v > 0.0) && start[M_SCALE].is_finite()) {
        return Err(NavigatorError::invalid(
            "tune",
            format!(
                "the starting variances {:?} must be positive",
                &start.as_slice()[..4]
            ),
        ));
    }
    let beam_covariance = model.beam_covariance();
    let mut point = *start;
    let mut points = vec![point];
    loop {
        let linearized = trajectories
            .iter()
            .map(|t| linearize(t, model, &point))
            .collect::<Result<Vec<_>>>()?;
        let rho_bound = options.rho_margin
            * linearized
                .iter()
                .map(|l| l.largest_valid_rho)
                .fold(f64::INFINITY, f64::min);
        let likelihood = InsDvlLikelihood {
            beam_covariance,
            trajectories: &linearized,
        };
        let mut lower = SVector::from([0.0, 0.0, 0.0, 0.0, -rho_bound]);
        let mut upper = SVector::from([f64::INFINITY; TUNE_PARAMETERS]);
        upper[M_SCALE] = rho_bound;
        let mut begin = point;
        begin[M_SCALE] = begin[M_SCALE].clamp(-0.5 * rho_bound, 0.5 * rho_bound);
        for (i, value) in options.fixed.iter().enumerate() {
            if let Some(v) = *value {
                if i == M_SCALE && v.abs() > rho_bound {
                    return Err(NavigatorError::invalid(
                        "tune",
                        format!(
                            "m_scale held at {v} is beyond the largest valid value \
                         +-{rho_bound:.4} at this linearization (M would not be a \
                         cross-covariance)"
                        ),
                    ));
                }
                (lower[i], upper[i], begin[i]) = (v, v, v);
            }
        }
        let bounds = Bounds::new(lower, upper)?;
        let full = maximize(&likelihood, &begin, &bounds, &options.fit)?;
        if points.len() < options.linearizations {
            point = full.theta;
            points.push(point);
            continue;
        }
        let on_bound: [bool; TUNE_PARAMETERS] = std::array::from_fn(|i| {
            if options.fixed[i].is_some() {
                false
            } else if i == M_SCALE {
                full.theta[i].abs() >= (1.0 - 1e-4) * rho_bound
            } else {
                full.theta[i] < 1e-6 * start[i]
            }
        });
        let (status, boundary) = fit_status(
            &likelihood,
            &full,
            &on_bound,
            (lower, upper),
            start,
            rho_bound,
            &options.fit,
        )?;
        lower[M_SCALE] = 0.0;
        upper[M_SCALE] = 0.0;
        let restricted_bounds = Bounds::new(lower, upper)?;
        let mut begin = full.theta;
        begin[M_SCALE] = 0.0;
        let restricted = maximize(&likelihood, &begin, &restricted_bounds, &options.fit)?;
        let test = likelihood_ratio_test(full.log_likelihood, restricted.log_likelihood, 1)?;
        let held: [bool; TUNE_PARAMETERS] =
            std::array::from_fn(|i| on_bound[i] || options.fixed[i].is_some());
        let standard_errors = interior_standard_errors(&full.information, &held);
        return Ok(TuneFit {
            full,
            on_bound,
            standard_errors,
            status,
            fixed: options.fixed,
            boundary,
            restricted,
            test,
            points,
            rho_bound,
            epochs: linearized.iter().map(Linearization::epochs).sum(),
        });
    }
}

/// The [`TuneStatus`] of `full`, with the refit that holds the parameters `on_bound`
/// at their values (when any is).
fn fit_status(
    likelihood: &InsDvlLikelihood<'_>,
    full: &MaximumLikelihood<TUNE_PARAMETERS>,
    on_bound: &[bool; TUNE_PARAMETERS],
    (mut lower, mut upper): (TuneParameters, TuneParameters),
    start: &TuneParameters,
    rho_bound: f64,
    options: &FitOptions,
) -> Result<(TuneStatus, Option<MaximumLikelihood<TUNE_PARAMETERS>>)> {
    let named = |pick: &dyn Fn(usize) -> bool| -> Vec<&'static str> {
        (0..TUNE_PARAMETERS)
            .filter(|&i| on_bound[i] && pick(i))
            .map(|i| PARAMETER_NAMES[i])
            .collect()
    };
    if !on_bound.contains(&true) {
        let status = if full.converged {
            TuneStatus::Converged
        } else {
            TuneStatus::NotConverged {
                stop: full.stop.clone(),
                on_bound: Vec::new(),
            }
        };
        return Ok((status, None));
    }
    for i in (0..TUNE_PARAMETERS).filter(|&i| on_bound[i]) {
        (lower[i], upper[i]) = (full.theta[i], full.theta[i]);
    }
    let refit = maximize(
        likelihood,
        &full.theta,
        &Bounds::new(lower, upper)?,
        options,
    )?;
    // A zero IMU density leaves that sensor's white noise out of Q altogether; one of
    // R's two terms at zero leaves R positive definite (a bounded optimum), both do not.
    let r_gone = on_bound[2] && on_bound[3];
    let degenerate = named(&|i| i < 2 || (i < M_SCALE && r_gone));
    if !degenerate.is_empty() {
        return Ok((
            TuneStatus::Degenerate {
                parameters: degenerate,
            },
            Some(refit),
        ));
    }
    // A bounded maximum: ln p does not increase inward from each bound (its outward
    // derivative, times the parameter's scale, is not below -tolerance).
    let (_, slope) = gradient(likelihood, &refit.theta, &on_bound.map(|b| !b))?;
    let optimal = (0..TUNE_PARAMETERS).filter(|&i| on_bound[i]).all(|i| {
        let (outward, scale) = if i == M_SCALE {
            (slope[i] * full.theta[i].signum(), rho_bound)
        } else {
            (-slope[i], start[i])
        };
        outward * scale >= -BOUND_GRADIENT_TOLERANCE
    });
    let on = named(&|_| true);
    let status = if refit.converged && optimal {
        TuneStatus::ConvergedOnBound { parameters: on }
    } else {
        TuneStatus::NotConverged {
            stop: if optimal {
                refit.stop.clone()
            } else {
                FitStop::NoDecrease
            },
            on_bound: on,
        }
    };
    Ok((status, Some(refit)))
}

/// sqrt of the diagonal of the inverse of `information` over the parameters not on a
/// bound (`None` for those on one, and for all when that block is not positive
/// definite).
fn interior_standard_errors(
    information: &SMatrix<f64, TUNE_PARAMETERS, TUNE_PARAMETERS>,
    on_bound: &[bool; TUNE_PARAMETERS],
) -> [Option<f64>; TUNE_PARAMETERS] {
    let interior: Vec<usize> = (0..TUNE_PARAMETERS).filter(|&i| !on_bound[i]).collect();
    let n = interior.len();
    let block = estim_core::nalgebra::DMatrix::from_fn(n, n, |r, c| {
        information[(interior[r], interior[c])]
    });
    let mut out = [None; TUNE_PARAMETERS];
    if let Some(chol) = block.cholesky() {
        let inverse = chol.inverse();
        for (r, &i) in interior.iter().enumerate() {
            out[i] = Some(inverse[(r, r)].max(0.0).sqrt());
        }
    }
    out
}
