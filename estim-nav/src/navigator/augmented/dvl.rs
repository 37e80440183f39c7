//! The DVL velocity measurement on the augmented state.

use estim_core::MeasurementModel;
use estim_ins::{earth, ACC_BIAS, ATT, GYRO_BIAS, POS, VEL};
use nalgebra::{Matrix3, SMatrix, Vector3};

use super::{
    AugmentedState, AUGMENTED_STATES, DVL_BIAS, DVL_LEVER_ARM, DVL_MISALIGNMENT, DVL_SCALE,
    DVL_TIME_OFFSET,
};
use crate::navigator::{NavigatorError, Result};

/// The DVL velocity measurement on the augmented state (see the module docs for h
/// and its Jacobian). Its noise covariance is R + κ² |ω|² I: a configured R, and
/// optionally ([`AugmentedDvlModel::with_rate_noise`]) a part growing with the
/// angular rate ω of the state (on A-KIT the DVL-versus-reference mismatch grows
/// from about 0.02 m/s below 0.02 rad/s to about 0.1 m/s above 0.1 rad/s).
#[derive(Debug, Clone, PartialEq)]
pub struct AugmentedDvlModel {
    noise_covariance: Matrix3<f64>,
    rate_noise: f64,
    /// Added to a_b: the mean a_b over the window minus a_b at the nominal (set by
    /// [`super::AugmentedNavigator`] for each update; zero otherwise).
    pub(super) acceleration_offset: Vector3<f64>,
}

/// The quantities of one DVL prediction.
struct DvlTerms {
    nav_to_body: Matrix3<f64>,
    body_to_dvl: Matrix3<f64>,
    gain: Matrix3<f64>,
    body_velocity: Vector3<f64>,
    acceleration: Vector3<f64>,
    gravity: Vector3<f64>,
    u: Vector3<f64>,
}

impl AugmentedDvlModel {
    /// A model with measurement-noise covariance `r` (symmetric positive definite).
    ///
    /// # Errors
    /// [`NavigatorError::InvalidValue`] for an R that is not finite, symmetric and positive
    /// definite.
    pub fn new(r: Matrix3<f64>) -> Result<Self> {
        let ok = r.iter().all(|x| x.is_finite())
            && (r - r.transpose()).abs().max() <= 1e-12 * r.abs().max()
            && r.cholesky().is_some();
        if !ok {
            return Err(NavigatorError::invalid(
                "DVL noise covariance",
                format!("{r} is not symmetric positive definite"),
            ));
        }
        Ok(Self {
            noise_covariance: r,
            rate_noise: 0.0,
            acceleration_offset: Vector3::zeros(),
        })
    }

    /// The same model with the rate-dependent noise κ \[m/s per rad/s\] (>= 0).
    ///
    /// # Errors
    /// [`NavigatorError::InvalidValue`] for a κ that is negative or not finite.
    pub fn with_rate_noise(mut self, kappa: f64) -> Result<Self> {
        if !(kappa.is_finite() && kappa >= 0.0) {
            return Err(NavigatorError::invalid(
                "DVL rate noise",
                format!("{kappa:?} m/s per rad/s is not finite and >= 0"),
            ));
        }
        self.rate_noise = kappa;
        Ok(self)
    }

    /// The same model with R replaced by `r` and no rate-dependent noise (κ = 0): the
    /// noise of a velocity that is not the DVL's own, e.g. a learned sensor's.
    ///
    /// # Errors
    /// [`NavigatorError::InvalidValue`] for an `r` that is not finite, symmetric and
    /// positive definite.
    pub fn with_noise_covariance(&self, r: Matrix3<f64>) -> Result<Self> {
        Ok(Self {
            acceleration_offset: self.acceleration_offset,
            ..Self::new(r)?
        })
    }

    /// The same model with its noise scaled by `scale` (finite, > 0): R by the
    /// scale, κ by its square root (so κ² |ω|² scales with R).
    ///
    /// # Errors
    /// [`NavigatorError::InvalidValue`] for a scale that is not finite and positive.
    pub fn with_noise_scale(&self, scale: f64) -> Result<Self> {
        if !(scale.is_finite() && scale > 0.0) {
            return Err(NavigatorError::invalid(
                "DVL noise scale",
                format!("{scale:?} is not finite and positive"),
            ));
        }
        Ok(Self {
            noise_covariance: self.noise_covariance * scale,
            rate_noise: self.rate_noise * scale.sqrt(),
            acceleration_offset: self.acceleration_offset,
        })
    }

    /// a_b at `state` from its specific force alone (no window).
    pub(super) fn raw_acceleration(state: &AugmentedState) -> Vector3<f64> {
        Self::terms_with(state, &Vector3::zeros()).acceleration
    }

    fn terms(&self, state: &AugmentedState) -> DvlTerms {
        Self::terms_with(state, &self.acceleration_offset)
    }

    fn terms_with(state: &AugmentedState, acceleration_offset: &Vector3<f64>) -> DvlTerms {
        let ins = &state.ins;
        let dvl = &state.dvl;
        let nav_to_body = ins.attitude.inverse().to_rotation_matrix().into_inner();
        let body_to_dvl = dvl.dvl_to_body.inverse().into_inner();
        let gain = body_to_dvl * (1.0 + dvl.scale_factor_error);
        let body_velocity = nav_to_body * ins.velocity_ned;
        let gravity = earth::gravity_ned(ins.latitude, ins.height);
        let omega = ins.angular_rate;
        let acceleration = (state.specific_force - ins.acc_bias) + nav_to_body * gravity
            - omega.cross(&body_velocity)
            + acceleration_offset;
        let u = body_velocity + omega.cross(&dvl.lever_arm) - acceleration * dvl.time_offset;
        DvlTerms {
            nav_to_body,
            body_to_dvl,
            gain,
            body_velocity,
            acceleration,
            gravity,
            u,
        }
    }
}

impl MeasurementModel<f64, AUGMENTED_STATES, 3> for AugmentedDvlModel {
    type State = AugmentedState;

    fn predict(&self, state: &AugmentedState) -> estim_core::Result<Vector3<f64>> {
        let t = self.terms(state);
        let y = t.gain * t.u + state.dvl.bias;
        if y.iter().all(|x| x.is_finite()) {
            Ok(y)
        } else {
            Err(estim_core::Error::NonFinite {
                what: "augmented DVL prediction (state)",
            })
        }
    }

    fn jacobian(
        &self,
        state: &AugmentedState,
    ) -> estim_core::Result<SMatrix<f64, 3, AUGMENTED_STATES>> {
        let t = self.terms(state);
        let ins = &state.ins;
        let dvl = &state.dvl;
        let tau = dvl.time_offset;
        let c = t.nav_to_body;
        let omega_x = ins.angular_rate.cross_matrix();
        let v_x = ins.velocity_ned.cross_matrix();
        let mut h = SMatrix::<f64, 3, AUGMENTED_STATES>::zeros();
        // Position: through g(L, h) in the time-offset term.
        let (dg_dlat, dg_dh) = earth::normal_gravity_gradient(ins.latitude, ins.height);
        let (rn, _) = earth::radii_of_curvature(ins.latitude);
        let down = c.column(2).into_owned();
        let pos_n = t.gain * down * (-tau * dg_dlat / (rn + ins.height));
        let pos_d = t.gain * down * (tau * dg_dh);
        h.fixed_view_mut::<3, 1>(0, POS).copy_from(&pos_n);
        h.fixed_view_mut::<3, 1>(0, POS + 2).copy_from(&pos_d);
        h.fixed_view_mut::<3, 3>(0, VEL)
            .copy_from(&(t.gain * (c + omega_x * c * tau)));
        h.fixed_view_mut::<3, 3>(0, ATT).copy_from(
            &(t.gain * (c * v_x - c * t.gravity.cross_matrix() * tau + omega_x * c * v_x * tau)),
        );
        h.fixed_view_mut::<3, 3>(0, ACC_BIAS)
            .copy_from(&(t.gain * tau));
        h.fixed_view_mut::<3, 3>(0, GYRO_BIAS).copy_from(
            &(t.gain * (dvl.lever_arm.cross_matrix() + t.body_velocity.cross_matrix() * tau)),
        );
        let in_dvl = t.body_to_dvl * t.u;
        h.fixed_view_mut::<3, 1>(0, DVL_SCALE).copy_from(&in_dvl);
        h.fixed_view_mut::<3, 3>(0, DVL_MISALIGNMENT)
            .copy_from(&(in_dvl.cross_matrix() * (1.0 + dvl.scale_factor_error)));
        h.fixed_view_mut::<3, 3>(0, DVL_BIAS)
            .copy_from(&Matrix3::identity());
        h.fixed_view_mut::<3, 3>(0, DVL_LEVER_ARM)
            .copy_from(&(t.gain * omega_x));
        h.fixed_view_mut::<3, 1>(0, DVL_TIME_OFFSET)
            .copy_from(&(-(t.gain * t.acceleration)));
        estim_core::numeric::check_finite(h.as_slice(), "augmented DVL Jacobian")?;
        Ok(h)
    }

    fn noise_covariance(&self, state: &AugmentedState) -> estim_core::Result<Matrix3<f64>> {
        let rate = self.rate_noise * state.ins.angular_rate.norm();
        Ok(self.noise_covariance + Matrix3::identity() * (rate * rate))
    }
}
