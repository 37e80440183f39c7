//! IMU calibration against a reference trajectory: the axis convention (a signed
//! permutation), the IMU clock's scale and offset, and the initial biases.
//!
//! The model and the method are in [`ImuCalibrator`]'s docs.

mod axes;
mod fit;
mod increments;

use nalgebra::{SMatrix, SVector, Vector3};

use crate::error::{Error, Result};
use crate::mechanization::ImuSample;
use crate::simulator::TrajectorySample;

pub use axes::AxisMap;
use fit::{coarse_search, refine};
use increments::{ClockBox, ImuPrefix, ReferenceIncrements};

/// Number of parameters: clock scale, time offset, accelerometer bias (3), gyroscope
/// bias (3), gyroscope scale factor (3), in that order in
/// [`ImuCalibration::covariance`] (a scale factor the motion does not excite is held at
/// 1 and has zero rows and columns there).
pub const IMU_CALIBRATION_PARAMETERS: usize = 11;

type ParameterVector = SVector<f64, IMU_CALIBRATION_PARAMETERS>;
type ParameterMatrix = SMatrix<f64, IMU_CALIBRATION_PARAMETERS, IMU_CALIBRATION_PARAMETERS>;
/// An estimate with its 1-sigma standard error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// The estimate.
    pub value: f64,
    /// Its 1-sigma standard error.
    pub standard_error: f64,
}

/// Result of [`ImuCalibrator::calibrate`] (the model is in [`ImuCalibrator`]'s docs).
#[derive(Debug, Clone, PartialEq)]
pub struct ImuCalibration {
    /// The axis convention, IMU -> body.
    pub axes: AxisMap,
    /// Clock scale s: a sample stamped t is at reference time s t - τ.
    pub clock_scale: Estimate,
    /// Time offset τ \[s\] (the reference time of IMU stamp 0 is -τ).
    pub time_offset_s: Estimate,
    /// Accelerometer bias, body axes \[m/s^2\].
    pub accelerometer_bias: [Estimate; 3],
    /// Gyroscope bias, body axes \[rad/s\].
    pub gyroscope_bias: [Estimate; 3],
    /// Gyroscope scale factor 1 + k per body axis (the gyroscope reads (1 + k) times
    /// the true rate); `None` on an axis whose reference rate varies too little
    /// ([`ImuCalibratorBuilder::min_scale_rate`]), where k is held at 0.
    pub gyroscope_scale: [Option<Estimate>; 3],
    /// Covariance of (s, τ, b_a, b_g, k_g), the standard errors' source (the Newey-West
    /// sandwich of [`ImuCalibrator`]'s method, step 3).
    pub covariance: ParameterMatrix,
    /// RMS of the residual mean specific force per interval, body axes \[m/s^2\].
    pub residual_rms_accelerometer: Vector3<f64>,
    /// RMS of the residual mean angular rate per interval, body axes \[rad/s\].
    pub residual_rms_gyroscope: Vector3<f64>,
    /// Pooled lag-1 autocorrelation of the weighted residuals (0 when white).
    pub residual_lag1_autocorrelation: f64,
    /// Largest ratio, over the fitted parameters, of the variance in `covariance` to the
    /// white-residual variance (J'WJ)^-1: how much the residuals' autocorrelation widens
    /// the sigmas (about 1 when they are white).
    pub max_variance_ratio: f64,
    /// Grid cost of `axes`: unexplained fraction of the reference's variability, summed
    /// over the two sensors (0 = perfect, about 2 = nothing explained).
    pub cost: f64,
    /// The next best axis convention and its grid cost, if any other was admitted.
    pub runner_up: Option<(AxisMap, f64)>,
    /// Runner-up cost / best cost (infinite without a runner-up).
    pub cost_ratio: f64,
    /// Reference intervals used.
    pub intervals: usize,
    /// Levenberg-Marquardt iterations, all rounds.
    pub iterations: usize,
}

/// IMU calibration against a reference trajectory: the axis convention, the IMU
/// clock's scale and offset, and the initial biases. Settings; build with
/// [`ImuCalibrator::builder`], run with [`ImuCalibrator::calibrate`].
///
/// # Model
///
/// An IMU sample stamped t (IMU clock) covers the reference-clock instant
/// T = s t - τ (s: clock scale, τ: time offset; "a sample stamped t measures the motion
/// at t - τ" when s = 1). Its axes map to the body axes (x forward, y right, z down) by a
/// signed permutation P, the same for both triads, and
///
/// ```text
/// P f_imu(T) = f^b(T) + b_a + noise,     P ω_imu(T) = (1 + k_g) ∘ ω_ib^b(T) + b_g + noise,
/// ```
///
/// with k_g the gyroscope's scale-factor error per body axis (∘: per component). k_g is
/// fitted on an axis whose reference rate varies enough to tell a scale from a bias
/// ([`ImuCalibratorBuilder::min_scale_rate`]); elsewhere it is held at 0.
///
/// The IMU values are read as piecewise-constant rates on the reference clock (both
/// sides are integrated in reference seconds, so a stretched IMU clock does not show up
/// as a gravity error). Over each interval \[T_j, T_{j+1}\] between reference epochs
/// the residual is
///
/// ```text
/// r_j = P ∫ (f_imu, ω_imu) dT - (b_a, b_g) (T_{j+1} - T_j) - (∫ f^b dT, (1 + k_g) ∘ ∫ ω_ib^b dT),
/// ```
///
/// where the reference integrals come from the inverse mechanization of
/// [`Trajectory::velocity_driven`](crate::Trajectory::velocity_driven) (Groves 2013
/// eqs. 5.46 and 5.53 solved for the IMU outputs:
/// f^b = C_n^b \[v̇^n + (2 ω_ie^n + ω_en^n) × v^n - g^n\],
/// ω_ib^b = ω_nb^b + C_n^b (ω_ie^n + ω_en^n), WGS-84 gravity and Earth rate), integrated
/// by Gauss-Legendre quadrature over the interval. The velocity spline passes through
/// the reference velocities, so ∫ v̇^n dT is exactly the reference's Δv^n.
///
/// # Method
///
/// 1. Grid over (s, τ) in the search box (τ step
///    [`ImuCalibratorBuilder::time_offset_grid_step`], s step such that the largest time
///    shift it causes is one τ step). At each point
///    the IMU integrals are formed once (prefix sums), and for each of the 48 signed
///    permutations (proper and improper) the biases, which enter linearly, are
///    eliminated in closed form (variable projection, Golub & Pereyra, SIAM J. Numer.
///    Anal. 10(2), 1973). The cost is the unexplained fraction of the reference's
///    variability, RSS_acc / SS_acc + RSS_gyro / SS_gyro (SS: the reference increments'
///    sum of squares about their best constant rate), which makes the two sensors
///    commensurable without a noise model. A permutation whose biases at a grid point
///    exceed [`ImuCalibratorBuilder::max_accelerometer_bias`] or
///    [`ImuCalibratorBuilder::max_gyroscope_bias`] is not admitted there: free biases
///    would otherwise absorb gravity mapped onto a wrong axis.
/// 2. The best permutation's grid optimum is refined by Levenberg-Marquardt (Nocedal &
///    Wright, *Numerical Optimization*, 2nd ed., 2006, sec. 10.3) over (s, τ, b_a, b_g, k_g),
///    each of the six channels weighted by the inverse of its residual variance,
///    re-estimated over three rounds; the (s, τ) columns of the Jacobian are central
///    differences spanning a few IMU samples (the integrals are piecewise linear in τ).
/// 3. Covariance: the sandwich (J'WJ)^-1 B (J'WJ)^-1 with the weights of the last round,
///    B the Newey-West estimate of the covariance of J'Wr from the per-interval scores
///    J_j' W r_j (Bartlett weights to lag floor(4 (M/100)^(2/9)); Newey & West,
///    Econometrica 55(3), 1987; the lag rule of Newey & West, Rev. Econ. Stud. 61(4),
///    1994). For white residuals B ≈ J'WJ and it reduces to the usual (J'WJ)^-1 (Seber
///    & Wild, *Nonlinear Regression*, 1989, sec. 2.1); for residuals correlated over a
///    few intervals (a reference that is itself an INS solution) it widens the sigmas
///    where that correlation matters. On A-KIT the clock scale's errors against the
///    scale the time columns imply have an RMS of 0.8 sigma with it, 1.8 sigma without.
///
/// # Example
///
/// An IMU mounted with its y axis reversed, stamping 0.3 s late, simulated from a
/// turning, rolling trajectory; the calibrator sees the IMU and the 1 Hz reference:
///
/// ```
/// use estim_ins::{AxisMap, ImuCalibrator, ImuSample, Trajectory, TrajectorySample};
/// use nalgebra::{UnitQuaternion, Vector3};
///
/// let motion = |t: f64| {
///     let yaw = 0.8 * (t / 9.0).sin();
///     let (roll, pitch) = (0.05 * (t / 2.0).sin(), 0.04 * (t / 3.0).cos());
///     TrajectorySample {
///         time: t,
///         latitude: 0.57,
///         longitude: 0.61,
///         height: -15.0,
///         velocity_ned: Vector3::new(1.5 * yaw.cos(), 1.5 * yaw.sin(), 0.1 * (t / 5.0).sin()),
///         attitude: UnitQuaternion::from_euler_angles(roll, pitch, yaw),
///     }
/// };
/// let knots = (0..=280).map(|k| motion(-5.0 + 0.25 * f64::from(k))).collect();
/// let truth = Trajectory::velocity_driven(knots)?;
/// let axes = AxisMap::from_labels(&["x", "-y", "z"])?;
/// let to_imu = axes.matrix().transpose();
/// let imu: Vec<ImuSample> = (0..6_000)
///     .map(|k| {
///         let stamp = 0.01 * f64::from(k);
///         let clean = truth.imu_sample(stamp - 0.3, 0.01)?; // the motion at t - 0.3
///         let (f, w) = (to_imu * clean.specific_force, to_imu * clean.angular_rate);
///         Ok(ImuSample::new(stamp, f, w))
///     })
///     .collect::<estim_ins::Result<_>>()?;
/// let reference: Vec<TrajectorySample> = (0..=60).map(|j| motion(f64::from(j))).collect();
///
/// let calibrator = ImuCalibrator::builder().max_time_offset(1.0).build()?;
/// let calibration = calibrator.calibrate(&imu, &reference)?;
/// assert_eq!(calibration.axes, axes);
/// assert!((calibration.time_offset_s.value - 0.3).abs() < 0.01);
/// assert!((calibration.clock_scale.value - 1.0).abs() < 1e-3);
/// assert!(ImuCalibrator::builder().max_time_offset(-1.0).build().is_err());
/// # Ok::<(), estim_ins::Error>(())
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct ImuCalibrator {
    max_time_offset: f64,
    max_clock_scale_error: f64,
    time_offset_grid_step: f64,
    max_accelerometer_bias: f64,
    max_gyroscope_bias: f64,
    min_cost_ratio: f64,
    min_intervals: usize,
    min_reference_interval: f64,
    max_iterations: usize,
    min_scale_rate: f64,
}

/// Builder of an [`ImuCalibrator`]; `build()` validates.
#[must_use]
#[derive(Debug, Clone)]
pub struct ImuCalibratorBuilder {
    settings: ImuCalibrator,
}

impl Default for ImuCalibratorBuilder {
    fn default() -> Self {
        Self {
            settings: ImuCalibrator {
                max_time_offset: 3.0,
                max_clock_scale_error: 0.01,
                time_offset_grid_step: 0.1,
                max_accelerometer_bias: 1.0,
                max_gyroscope_bias: 0.1,
                min_cost_ratio: 1.5,
                min_intervals: 30,
                min_reference_interval: 0.5,
                max_iterations: 50,
                min_scale_rate: 0.01,
            },
        }
    }
}

impl ImuCalibratorBuilder {
    /// Largest |τ| searched \[s\] (default 3).
    pub fn max_time_offset(mut self, seconds: f64) -> Self {
        self.settings.max_time_offset = seconds;
        self
    }

    /// Largest |s - 1| searched (default 0.01).
    pub fn max_clock_scale_error(mut self, fraction: f64) -> Self {
        self.settings.max_clock_scale_error = fraction;
        self
    }

    /// τ spacing of the coarse grid \[s\] (default 0.1; well below the time over which
    /// the motion changes).
    pub fn time_offset_grid_step(mut self, seconds: f64) -> Self {
        self.settings.time_offset_grid_step = seconds;
        self
    }

    /// Largest |accelerometer bias| per axis admitted \[m/s^2\] (default 1.0, about 0.1 g,
    /// far above any IMU grade's turn-on bias (Groves 2013, sec. 4.4.1) and far below
    /// gravity, so that gravity mapped onto a wrong axis is not explained as a bias).
    pub fn max_accelerometer_bias(mut self, mps2: f64) -> Self {
        self.settings.max_accelerometer_bias = mps2;
        self
    }

    /// Largest |gyroscope bias| per axis admitted \[rad/s\] (default 0.1).
    pub fn max_gyroscope_bias(mut self, radps: f64) -> Self {
        self.settings.max_gyroscope_bias = radps;
        self
    }

    /// Smallest runner-up / best cost ratio accepted (default 1.5); below it the motion
    /// does not separate the axes and `calibrate` refuses.
    pub fn min_cost_ratio(mut self, ratio: f64) -> Self {
        self.settings.min_cost_ratio = ratio;
        self
    }

    /// Fewest reference intervals inside the IMU log (default 30).
    pub fn min_intervals(mut self, n: usize) -> Self {
        self.settings.min_intervals = n;
        self
    }

    /// Shortest reference interval \[s\] (default 0.5): denser reference epochs are
    /// thinned to this spacing (the information is in the motion, not in the rate).
    pub fn min_reference_interval(mut self, seconds: f64) -> Self {
        self.settings.min_reference_interval = seconds;
        self
    }

    /// Smallest RMS, about its mean, of the reference's angular rate on a body axis for
    /// the gyroscope's scale factor on that axis to be fitted \[rad/s\] (default 0.01,
    /// about 0.6 deg/s: a vehicle that turns, as opposed to one that holds its heading,
    /// where a scale cannot be told from a bias). Infinite: never fit a scale.
    pub fn min_scale_rate(mut self, radps: f64) -> Self {
        self.settings.min_scale_rate = radps;
        self
    }

    /// Iteration limit of each Levenberg-Marquardt round (default 50).
    pub fn max_iterations(mut self, n: usize) -> Self {
        self.settings.max_iterations = n;
        self
    }

    /// Validate: finite positive bounds and steps, a step no larger than the offset
    /// range, a scale error below 0.5, a cost ratio >= 1, at least 10 intervals and one
    /// iteration.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming the setting.
    pub fn build(self) -> Result<ImuCalibrator> {
        let s = self.settings;
        let positive = |name: &'static str, v: f64| crate::error::positive(name, v).map(|_| ());
        positive("max_time_offset", s.max_time_offset)?;
        positive("max_clock_scale_error", s.max_clock_scale_error)?;
        positive("time_offset_grid_step", s.time_offset_grid_step)?;
        positive("max_accelerometer_bias", s.max_accelerometer_bias)?;
        positive("max_gyroscope_bias", s.max_gyroscope_bias)?;
        positive("min_reference_interval", s.min_reference_interval)?;
        if s.min_scale_rate.is_nan() || s.min_scale_rate <= 0.0 {
            return Err(Error::InvalidParameter {
                name: "min_scale_rate",
                reason: format!("{} is not a positive number", s.min_scale_rate),
            });
        }
        let invalid =
            |name: &'static str, reason: String| Err(Error::InvalidParameter { name, reason });
        if s.time_offset_grid_step > s.max_time_offset {
            return invalid(
                "time_offset_grid_step",
                format!("{} s exceeds max_time_offset", s.time_offset_grid_step),
            );
        }
        if s.max_clock_scale_error >= 0.5 {
            return invalid(
                "max_clock_scale_error",
                format!("{} is not below 0.5", s.max_clock_scale_error),
            );
        }
        if !(s.min_cost_ratio.is_finite() && s.min_cost_ratio >= 1.0) {
            return invalid(
                "min_cost_ratio",
                format!("{} is not >= 1", s.min_cost_ratio),
            );
        }
        if s.min_intervals < 10 {
            return invalid("min_intervals", format!("{} is below 10", s.min_intervals));
        }
        if s.max_iterations == 0 {
            return invalid("max_iterations", "must be at least 1".into());
        }
        Ok(s)
    }
}

impl Default for ImuCalibrator {
    fn default() -> Self {
        ImuCalibratorBuilder::default().settings
    }
}

/// Largest number of clock-scale grid values (times far from zero need times relative
/// to a nearby epoch).
const MAX_SCALE_GRID: usize = 2001;

/// Largest number of (clock scale, time offset) grid points (about 4 s of search on a
/// 400-interval log; the defaults on a 400 s log need about 5,000).
const MAX_GRID_POINTS: usize = 200_000;

impl ImuCalibrator {
    /// A builder with the defaults (τ within ±3 s, s within 1 ± 0.01).
    pub fn builder() -> ImuCalibratorBuilder {
        ImuCalibratorBuilder::default()
    }

    /// Estimate the axis convention, clock scale and offset and the biases of `imu`
    /// (samples in IMU axes, stamped on the IMU clock, each the mean over
    /// \[its time, the next sample's time\]) against `reference` (epochs on the
    /// reference clock). Times should be relative to a nearby epoch: the scale acts
    /// about time 0.
    ///
    /// # Errors
    /// - [`Error::NonFinite`] for a non-finite IMU value; [`Error::ImuTime`] for IMU
    ///   times that do not increase or leave a gap; [`Error::Trajectory`] for a bad
    ///   reference;
    /// - [`Error::CalibrationTooShort`]: too few reference intervals inside the IMU log
    ///   for every clock in the search box;
    /// - [`Error::CalibrationNoMotion`]: the reference neither turns nor accelerates;
    /// - [`Error::CalibrationNoAxes`]: no axis convention keeps the biases in bounds;
    /// - [`Error::CalibrationAmbiguousAxes`]: the best two conventions fit about
    ///   equally well;
    /// - [`Error::CalibrationDegenerate`]: singular normal equations;
    /// - [`Error::InvalidParameter`] (`imu times`) for times so far from 0 that the
    ///   clock-scale grid would be unbounded.
    pub fn calibrate(
        &self,
        imu: &[ImuSample],
        reference: &[TrajectorySample],
    ) -> Result<ImuCalibration> {
        let prefix = ImuPrefix::new(imu)?;
        let reference = ReferenceIncrements::new(reference, self.min_reference_interval)?;
        let clock_box = ClockBox::new(self, &prefix)?;
        let reference = reference.inside(&prefix, &clock_box);
        if reference.len() < self.min_intervals {
            return Err(Error::CalibrationTooShort {
                intervals: reference.len(),
                min: self.min_intervals,
            });
        }
        let search = coarse_search(self, &prefix, &reference, &clock_box)?;
        let fit = refine(self, &prefix, &reference, &clock_box, &search)?;
        Ok(fit.into_calibration(&search, reference.len(), clock_box.center))
    }
}
