//! The DVL velocity measurement for the 15-state INS error-state filter.

use estim_core::MeasurementModel;
use estim_ins::{InsState, ATT, ERROR_STATES, GYRO_BIAS, VEL};
use nalgebra::{Matrix3, Rotation3, SMatrix, Vector3};

use crate::calibration::Calibration;
use crate::error::{finite, Error, Result};

/// Largest mounting misalignment accepted (rad): the model is meant for small angles.
const MAX_MISALIGNMENT: f64 = 0.5;

/// Velocity a DVL reports, in its own frame, given the body-frame velocity of the IMU
/// point and the body angular rate:
///
/// ```text
/// v_dvl = (1 + k) C_b^d (v_b + omega_b x l),   C_b^d = Rot(mu)^T
/// ```
///
/// with l the lever arm (IMU -> DVL, body frame), k the DVL scale-factor error and
/// Rot(mu) = exp([mu x]) the rotation DVL -> body of the mounting misalignment mu.
/// Rigid-body velocity transport (Groves, *Principles of GNSS, Inertial, and
/// Multisensor Integrated Navigation Systems*, 2nd ed., 2013, eq. 2.165 / 16.18).
pub fn dvl_frame_velocity(
    body_velocity: &Vector3<f64>,
    angular_rate: &Vector3<f64>,
    lever_arm: &Vector3<f64>,
    scale_factor_error: f64,
    mounting_misalignment: &Vector3<f64>,
) -> Vector3<f64> {
    let body_to_dvl = Rotation3::new(*mounting_misalignment).inverse();
    (body_to_dvl * (body_velocity + angular_rate.cross(lever_arm))) * (1.0 + scale_factor_error)
}

/// DVL velocity measurement of the INS error-state filter (estim-core
/// [`MeasurementModel`] with 15 error states, 3 measurements, state [`InsState`]).
///
/// Prediction (Groves 2013, eq. 16.18, with an optional DVL scale factor and mounting
/// misalignment, see [`dvl_frame_velocity`]):
///
/// ```text
/// v_b   = C_n^b v^n + omega_b x l         omega_b = InsState::angular_rate (bias-corrected omega_ib^b)
/// y     = (1 + k) C_b^d v_b
/// ```
///
/// Jacobian with respect to the error state, for the conventions pinned in
/// `estim_ins` (true = nominal + error; C_b^n,true = (I + [psi x]) C_b^n; gyro
/// measured = true + bias, so omega_true = omega - delta b_g):
///
/// ```text
/// dy/d(dv^n)  = (1 + k) C_b^d C_n^b
/// dy/d(psi)   = (1 + k) C_b^d C_n^b [v^n x]
/// dy/d(db_g)  = (1 + k) C_b^d [l x]
/// ```
///
/// and zero for position and accelerometer bias. The earth and transport rates in
/// omega_nb^b = omega_ib^b - C_n^b omega_in^n (below 1e-4 rad/s) are neglected, as in the
/// DESIGN's model.
///
/// ```
/// use estim_core::MeasurementModel;
/// use estim_dvl::DvlVelocityModel;
/// use estim_dvl::nalgebra::{UnitQuaternion, Vector3};
/// use estim_ins::InsState;
///
/// let model = DvlVelocityModel::builder()
///     .lever_arm(Vector3::new(1.5, 0.0, 0.2))
///     .noise_std(0.02)
///     .build()?;
/// let state = InsState {
///     time: 0.0, latitude: 0.57, longitude: 0.61, height: -20.0,
///     velocity_ned: Vector3::new(2.0, 0.0, 0.0),
///     attitude: UnitQuaternion::identity(),
///     acc_bias: Vector3::zeros(), gyro_bias: Vector3::zeros(),
///     angular_rate: Vector3::new(0.0, 0.0, 0.1),
/// };
/// let y = model.predict(&state)?;
/// assert!((y - Vector3::new(2.0, 0.15, 0.0)).norm() < 1e-12);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct DvlVelocityModel {
    lever_arm: Vector3<f64>,
    scale_factor_error: f64,
    mounting_misalignment: Vector3<f64>,
    body_to_dvl: Matrix3<f64>,
    noise_covariance: Matrix3<f64>,
}

/// Builder of a [`DvlVelocityModel`]; `build()` validates. R must be given
/// ([`DvlVelocityModelBuilder::noise_std`] or [`DvlVelocityModelBuilder::noise_covariance`]).
#[must_use]
#[derive(Debug, Clone, Default)]
pub struct DvlVelocityModelBuilder {
    lever_arm: Vector3<f64>,
    scale_factor_error: f64,
    mounting_misalignment: Vector3<f64>,
    noise_covariance: Option<Matrix3<f64>>,
}

impl DvlVelocityModelBuilder {
    /// Lever arm IMU -> DVL in the body frame \[m\] (default zero).
    pub fn lever_arm(mut self, lever_arm: Vector3<f64>) -> Self {
        self.lever_arm = lever_arm;
        self
    }

    /// DVL scale-factor error k (measured = (1 + k) true; default 0), |k| < 0.5.
    pub fn scale_factor_error(mut self, k: f64) -> Self {
        self.scale_factor_error = k;
        self
    }

    /// Mounting misalignment mu \[rad\] (rotation vector DVL -> body; default zero),
    /// |mu| <= 0.5 rad.
    pub fn mounting_misalignment(mut self, mu: Vector3<f64>) -> Self {
        self.mounting_misalignment = mu;
        self
    }

    /// Lever arm, scale-factor error and mounting misalignment from a [`Calibration`].
    /// Its time offset is not part of this model: shift the DVL time stamps by
    /// `-time_offset` before the updates.
    pub fn calibration(self, calibration: &Calibration) -> Self {
        self.lever_arm(calibration.lever_arm_vector())
            .scale_factor_error(calibration.scale_factor_error.value)
            .mounting_misalignment(calibration.mounting_misalignment_vector())
    }

    /// R = diag(std^2) with the same standard deviation on each axis \[m/s\].
    pub fn noise_std(mut self, std: f64) -> Self {
        self.noise_covariance = Some(Matrix3::from_diagonal_element(std * std));
        self
    }

    /// A full R (symmetric positive definite) [m^2/s^2].
    pub fn noise_covariance(mut self, r: Matrix3<f64>) -> Self {
        self.noise_covariance = Some(r);
        self
    }

    /// Validate: finite values, |k| < 0.5, |mu| <= 0.5 rad, R symmetric positive definite.
    pub fn build(self) -> Result<DvlVelocityModel> {
        if !self.lever_arm.iter().all(|x| x.is_finite()) {
            return Err(Error::InvalidParameter {
                name: "lever_arm",
                reason: "non-finite component".into(),
            });
        }
        let k = finite("scale_factor_error", self.scale_factor_error)?;
        if k.abs() >= 0.5 {
            return Err(Error::InvalidParameter {
                name: "scale_factor_error",
                reason: format!("{k} is outside (-0.5, 0.5)"),
            });
        }
        let mu = self.mounting_misalignment;
        if !mu.iter().all(|x| x.is_finite()) || mu.norm() > MAX_MISALIGNMENT {
            return Err(Error::InvalidParameter {
                name: "mounting_misalignment",
                reason: format!(
                    "|mu| = {} rad (finite and at most {MAX_MISALIGNMENT} rad required)",
                    mu.norm()
                ),
            });
        }
        let r = self.noise_covariance.ok_or(Error::MissingParameter {
            name: "noise_covariance",
            hint: "call noise_std(..) or noise_covariance(..)",
        })?;
        estim_core::numeric::check_finite(r.as_slice(), "DVL noise covariance")?;
        estim_core::numeric::check_symmetric(&r, "DVL noise covariance")?;
        if r.cholesky().is_none() {
            return Err(Error::InvalidParameter {
                name: "noise_covariance",
                reason: "not positive definite".into(),
            });
        }
        Ok(DvlVelocityModel {
            lever_arm: self.lever_arm,
            scale_factor_error: k,
            mounting_misalignment: mu,
            body_to_dvl: Rotation3::new(mu).inverse().into_inner(),
            noise_covariance: r,
        })
    }
}

impl DvlVelocityModel {
    /// A builder (lever arm, scale factor and misalignment zero; R required).
    pub fn builder() -> DvlVelocityModelBuilder {
        DvlVelocityModelBuilder::default()
    }

    /// Lever arm IMU -> DVL, body frame \[m\].
    pub fn lever_arm(&self) -> &Vector3<f64> {
        &self.lever_arm
    }

    /// DVL scale-factor error k.
    pub fn scale_factor_error(&self) -> f64 {
        self.scale_factor_error
    }

    /// Mounting misalignment mu \[rad\].
    pub fn mounting_misalignment(&self) -> &Vector3<f64> {
        &self.mounting_misalignment
    }

    /// The same model with R replaced by `r` (finite, symmetric, positive definite), e.g.
    /// a learned sensor's R for an update whose velocity the network gave.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for an `r` that is not finite, symmetric and positive
    /// definite.
    pub fn with_noise_covariance(&self, r: Matrix3<f64>) -> Result<Self> {
        let ok = r.iter().all(|x| x.is_finite())
            && (r - r.transpose()).abs().max() <= 1e-12 * r.abs().max()
            && r.cholesky().is_some();
        if !ok {
            return Err(Error::InvalidParameter {
                name: "noise covariance",
                reason: format!("{r} is not symmetric positive definite"),
            });
        }
        Ok(Self {
            noise_covariance: r,
            ..self.clone()
        })
    }

    /// The same model with R multiplied by `scale` (finite, > 0), e.g. a noise level
    /// adapted online (`estim_core::noise::adaptive::NoiseScale`).
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for a scale that is not finite and positive.
    pub fn with_noise_scale(&self, scale: f64) -> Result<Self> {
        if !(scale.is_finite() && scale > 0.0) {
            return Err(Error::InvalidParameter {
                name: "noise scale",
                reason: format!("{scale} is not finite and positive"),
            });
        }
        Ok(Self {
            noise_covariance: self.noise_covariance * scale,
            ..self.clone()
        })
    }
}

impl MeasurementModel<f64, ERROR_STATES, 3> for DvlVelocityModel {
    type State = InsState;

    fn predict(&self, state: &InsState) -> estim_core::Result<Vector3<f64>> {
        let body_velocity = state.attitude.inverse() * state.velocity_ned;
        let y = dvl_frame_velocity(
            &body_velocity,
            &state.angular_rate,
            &self.lever_arm,
            self.scale_factor_error,
            &self.mounting_misalignment,
        );
        if y.iter().all(|x| x.is_finite()) {
            Ok(y)
        } else {
            Err(estim_core::Error::NonFinite {
                what: "DVL velocity prediction (state)",
            })
        }
    }

    fn jacobian(&self, state: &InsState) -> estim_core::Result<SMatrix<f64, 3, ERROR_STATES>> {
        let gain = self.body_to_dvl * (1.0 + self.scale_factor_error);
        let nav_to_body = state.attitude.inverse().to_rotation_matrix().into_inner();
        let mut h = SMatrix::<f64, 3, ERROR_STATES>::zeros();
        h.fixed_view_mut::<3, 3>(0, VEL)
            .copy_from(&(gain * nav_to_body));
        h.fixed_view_mut::<3, 3>(0, ATT)
            .copy_from(&(gain * nav_to_body * state.velocity_ned.cross_matrix()));
        h.fixed_view_mut::<3, 3>(0, GYRO_BIAS)
            .copy_from(&(gain * self.lever_arm.cross_matrix()));
        estim_core::numeric::check_finite(h.as_slice(), "DVL Jacobian")?;
        Ok(h)
    }

    fn noise_covariance(&self, _state: &InsState) -> estim_core::Result<Matrix3<f64>> {
        Ok(self.noise_covariance)
    }
}
