//! [`AugmentedNavigator`]: the [`Navigator`] on the augmented error model.

use std::borrow::Cow;
use std::collections::VecDeque;

use estim_core::{ErrorStateKalmanFilter, NoObserver};
use estim_ins::{ErrorMatrix, InsErrorModel, InsState, ERROR_STATES};
use nalgebra::{Matrix3, Rotation3, Vector3};
use serde::Serialize;

use super::{
    AugmentedDvlModel, AugmentedErrorModel, AugmentedMatrix, AugmentedState, DvlParameters,
    DvlStatesConfig, AUGMENTED_STATES, DVL_BIAS, DVL_LEVER_ARM, DVL_MISALIGNMENT, DVL_SCALE,
    DVL_STATES, DVL_TIME_OFFSET,
};
use crate::navigator::clock::ImuClock;
use crate::navigator::{
    DvlConfig, NavigationModel, Navigator, NavigatorError, NavigatorSettings, Result,
};

/// Seconds of IMU steps whose a_b the navigator keeps for the time-offset window (a
/// window longer than this uses what is kept).
pub const ACCELERATION_HISTORY_S: f64 = 10.0;

/// The filter type the augmented navigator owns.
pub type AugmentedFilter = ErrorStateKalmanFilter<f64, AugmentedErrorModel, AUGMENTED_STATES>;

/// The DVL states with their 1-sigma (zero for a state not estimated).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DvlStateSolution {
    /// Scale-factor error k.
    pub scale_factor_error: f64,
    /// 1-sigma of k.
    pub scale_factor_sigma: f64,
    /// Mounting misalignment, rotation vector DVL -> body \[rad\].
    pub misalignment_rad: [f64; 3],
    /// 1-sigma of the misalignment error (DVL frame) \[rad\].
    pub misalignment_sigma_rad: [f64; 3],
    /// Velocity bias, DVL frame \[m/s\].
    pub bias_mps: [f64; 3],
    /// 1-sigma of the bias \[m/s\].
    pub bias_sigma_mps: [f64; 3],
    /// Lever arm, body frame \[m\].
    pub lever_arm_m: [f64; 3],
    /// 1-sigma of the lever arm \[m\].
    pub lever_arm_sigma_m: [f64; 3],
    /// Time offset beyond the applied stamp shift \[s\].
    pub time_offset_s: f64,
    /// 1-sigma of the time offset \[s\].
    pub time_offset_sigma_s: f64,
}

impl DvlParameters {
    /// The configured (calibrated) DVL mounting as the initial DVL state: lever arm,
    /// scale factor, misalignment; zero bias and zero time offset (the configured
    /// offset shifts the time stamps, the state estimates what remains).
    ///
    /// # Errors
    /// [`NavigatorError::InvalidValue`] for a misalignment above 0.5 rad or a scale factor
    /// outside (0.5, 1.5).
    pub fn from_config(dvl: &DvlConfig) -> Result<Self> {
        let mu = Vector3::from(dvl.mounting_misalignment_rad);
        if !(mu.iter().all(|v| v.is_finite()) && mu.norm() <= 0.5) {
            return Err(NavigatorError::invalid(
                "dvl.mounting_misalignment_rad",
                format!("|mu| = {} is not at most 0.5 rad", mu.norm()),
            ));
        }
        let k = dvl.scale_factor - 1.0;
        if !k.is_finite() || k.abs() >= 0.5 {
            return Err(NavigatorError::invalid(
                "dvl.scale_factor",
                format!("{} is not in (0.5, 1.5)", dvl.scale_factor),
            ));
        }
        Ok(Self {
            scale_factor_error: dvl.scale_factor - 1.0,
            dvl_to_body: Rotation3::new(mu),
            bias: Vector3::zeros(),
            lever_arm: Vector3::from(dvl.lever_arm_m),
            time_offset: 0.0,
        })
    }
}

/// The INS/DVL navigator with DVL error states: [`Navigator`] (same IMU timing rules,
/// same gate, same code) on the 26-state [`AugmentedErrorModel`], with the DVL update
/// [`AugmentedDvlModel`] and the depth and fix models on the augmented state.
/// With every DVL state off ([`DvlStatesConfig::none`]) it estimates what
/// [`Navigator`](crate::navigator::Navigator) does (tested to 1e-12).
///
/// With `dvl.adaptive_noise_window` in the settings, the DVL noise level is adapted
/// online ([`estim_core::noise::adaptive::NoiseScale`]): one scale λ multiplies the DVL model's noise
/// ([`AugmentedDvlModel::with_noise_scale`]) and the Gauss-Markov bias variance, and
/// is estimated from the past innovations with D = λR + the bias block of the prior
/// covariance.
pub type AugmentedNavigator<O = NoObserver> = Navigator<AugmentedErrorModel, O, AUGMENTED_STATES>;

impl AugmentedNavigator {
    /// A navigator from checked settings (IMU model, gate, depth and fix sensors, the
    /// DVL's R; its mounting gives the initial DVL state by
    /// [`DvlParameters::from_config`]), the DVL states to estimate, the initial INS
    /// state and its 15 x 15 covariance, and the nominal IMU period \[s\].
    ///
    /// # Errors
    /// [`NavigatorError::InvalidValue`] for a bad period or state settings; the core's for
    /// a covariance that is not finite and symmetric.
    pub fn with_states(
        settings: &NavigatorSettings,
        states: &DvlStatesConfig,
        initial: InsState,
        covariance: ErrorMatrix,
        imu_period_s: f64,
    ) -> Result<Self> {
        let dvl = DvlParameters::from_config(&settings.config.dvl)?;
        Self::with_dvl(settings, states, initial, dvl, covariance, imu_period_s)
    }

    /// [`AugmentedNavigator::with_states`] with the initial DVL state given.
    ///
    /// # Errors
    /// As [`AugmentedNavigator::with_states`].
    pub fn with_dvl(
        settings: &NavigatorSettings,
        states: &DvlStatesConfig,
        initial: InsState,
        dvl: DvlParameters,
        covariance: ErrorMatrix,
        imu_period_s: f64,
    ) -> Result<Self> {
        let imu_clock = ImuClock::new(imu_period_s, initial.time)?;
        let process = AugmentedErrorModel::new(InsErrorModel::new(settings.filter_spec), states)?;
        let mut p = AugmentedMatrix::zeros();
        p.fixed_view_mut::<ERROR_STATES, ERROR_STATES>(0, 0)
            .copy_from(&covariance);
        let prior = states.prior_variances();
        for i in 0..DVL_STATES {
            p[(ERROR_STATES + i, ERROR_STATES + i)] = prior[i];
        }
        let nominal = AugmentedState {
            ins: initial,
            dvl,
            specific_force: Vector3::zeros(),
        };
        let filter = ErrorStateKalmanFilter::new(process, nominal, p)?
            .with_config(settings.filter_config.clone());
        let r = estim_core::MeasurementModel::noise_covariance(&settings.dvl, &initial)?;
        Self::assemble(filter, AugmentedDvlModel::new(r)?, settings, imu_clock)
    }
}

impl<O> AugmentedNavigator<O> {
    /// Set the Gauss-Markov bias sigma \[m/s\] from the next prediction on (as
    /// [`AugmentedErrorModel::set_bias_std`]).
    ///
    /// # Errors
    /// As [`AugmentedErrorModel::set_bias_std`].
    pub fn set_bias_std(&mut self, sigma: f64) -> Result<()> {
        self.filter_mut().process_mut().set_bias_std(sigma)
    }
}

/// (end time, length, a_b after it) of the IMU steps of the last
/// [`ACCELERATION_HISTORY_S`] (kept when the time offset is estimated).
#[derive(Debug, Clone, Default)]
pub struct AccelerationWindow(VecDeque<(f64, f64, Vector3<f64>)>);

impl AccelerationWindow {
    /// Keep a step of length `dt` ending at `end` with body acceleration `a`.
    fn push(&mut self, end: f64, dt: f64, a: Vector3<f64>) {
        self.0.push_back((end, dt, a));
        while self
            .0
            .front()
            .is_some_and(|(t, _, _)| *t < end - ACCELERATION_HISTORY_S)
        {
            self.0.pop_front();
        }
    }

    /// The mean a_b over the last `width` seconds before `time`: the kept steps' a_b
    /// weighted by their overlap with the window; the last step's a_b for a window
    /// of zero width; `None` before the first step.
    fn mean(&self, time: f64, width: f64) -> Option<Vector3<f64>> {
        let start = time - width;
        let (mut sum, mut covered) = (Vector3::zeros(), 0.0);
        for (end, dt, a) in self.0.iter().rev() {
            let overlap = end.min(time) - (end - dt).max(start);
            if overlap > 0.0 {
                sum += a * overlap;
                covered += overlap;
            }
            if end - dt <= start {
                break;
            }
        }
        if covered > 0.0 {
            Some(sum / covered)
        } else {
            self.0.back().map(|(_, _, a)| *a)
        }
    }
}

/// The DVL error states in the [`Navigator`]: the time-offset window of body
/// accelerations, the bias block of P in the adaptive noise level's D (D = λR + the
/// bias block of the prior covariance), and the bias variance following λ.
impl NavigationModel<AUGMENTED_STATES> for AugmentedErrorModel {
    type Dvl = AugmentedDvlModel;
    type DvlMemory = AccelerationWindow;

    fn ins_covariance(covariance: &AugmentedMatrix) -> ErrorMatrix {
        covariance
            .fixed_view::<ERROR_STATES, ERROR_STATES>(0, 0)
            .into_owned()
    }

    fn scale_dvl_noise(model: &AugmentedDvlModel, scale: f64) -> Result<AugmentedDvlModel> {
        model.with_noise_scale(scale)
    }

    fn replace_dvl_noise(model: &AugmentedDvlModel, r: Matrix3<f64>) -> Result<AugmentedDvlModel> {
        model.with_noise_covariance(r)
    }

    fn after_step(
        &self,
        memory: &mut AccelerationWindow,
        nominal: &AugmentedState,
        end: f64,
        dt: f64,
    ) {
        if self.states().time_offset.estimate {
            memory.push(end, dt, AugmentedDvlModel::raw_acceleration(nominal));
        }
    }

    fn dvl_model_at<'a>(
        &self,
        memory: &AccelerationWindow,
        nominal: &AugmentedState,
        time: f64,
        model: &'a AugmentedDvlModel,
    ) -> Cow<'a, AugmentedDvlModel> {
        let mut model = model.clone();
        if self.states().time_offset.estimate {
            let width = nominal.dvl.time_offset.abs();
            if let Some(mean) = memory.mean(time, width) {
                model.acceleration_offset = mean - AugmentedDvlModel::raw_acceleration(nominal);
            }
        }
        Cow::Owned(model)
    }

    fn adaptive_noise_prior(covariance: &AugmentedMatrix) -> Option<Matrix3<f64>> {
        Some(
            covariance
                .fixed_view::<3, 3>(DVL_BIAS, DVL_BIAS)
                .into_owned(),
        )
    }

    fn on_noise_scale(&mut self, scale: f64) -> Result<()> {
        let bias = self.states().bias;
        if bias.estimate {
            self.set_bias_std(bias.std_mps * scale.sqrt())?;
        }
        Ok(())
    }

    fn dvl_states(x: &AugmentedState, p: &AugmentedMatrix) -> Option<DvlStateSolution> {
        let sigma = |i: usize| p[(i, i)].max(0.0).sqrt();
        let group = |start: usize| [sigma(start), sigma(start + 1), sigma(start + 2)];
        Some(DvlStateSolution {
            scale_factor_error: x.dvl.scale_factor_error,
            scale_factor_sigma: sigma(DVL_SCALE),
            misalignment_rad: x.dvl.mounting_misalignment().into(),
            misalignment_sigma_rad: group(DVL_MISALIGNMENT),
            bias_mps: x.dvl.bias.into(),
            bias_sigma_mps: group(DVL_BIAS),
            lever_arm_m: x.dvl.lever_arm.into(),
            lever_arm_sigma_m: group(DVL_LEVER_ARM),
            time_offset_s: x.dvl.time_offset,
            time_offset_sigma_s: sigma(DVL_TIME_OFFSET),
        })
    }
}
