//! Which DVL error states the augmented filter estimates, and their priors.

use nalgebra::SVector;
use serde::{Deserialize, Serialize};

use super::DVL_STATES;
use crate::navigator::{NavigatorError, Result};

macro_rules! state_config {
    ($(#[$doc:meta])* $name:ident, $field:ident: $ty:ty, $unit:literal) => {
        $(#[$doc])*
        #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
        #[serde(deny_unknown_fields)]
        pub struct $name {
            /// Estimate this state (else it stays at its initial value, zero variance).
            pub estimate: bool,
            #[doc = concat!("Prior 1-sigma ", $unit, ".")]
            pub $field: $ty,
        }

        impl $name {
            /// (estimated, prior 1-sigma).
            pub fn prior(&self) -> (bool, $ty) {
                (self.estimate, self.$field)
            }
        }
    };
}

/// A prior 1-sigma for a three-axis state: one value for every axis (`0.01`) or one
/// per axis (`[0.01, 0.0, 0.01]`). An axis whose sigma is 0 is held at its initial
/// value while the others are estimated.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(untagged, expecting = "a number or an array of 3 numbers")]
pub enum AxisSigma {
    /// The same sigma on every axis.
    All(f64),
    /// One sigma per axis (x, y, z of the state's frame).
    PerAxis([f64; 3]),
}

impl AxisSigma {
    /// The sigma of each axis.
    pub fn axes(&self) -> [f64; 3] {
        match *self {
            Self::All(sigma) => [sigma; 3],
            Self::PerAxis(sigmas) => sigmas,
        }
    }

    /// Check against the largest sigma `max`: one value in (0, max]; per axis, each
    /// in [0, max] and at least one above 0.
    fn check(&self, key: &str, max: f64) -> Result<()> {
        let in_range = |s: f64| s.is_finite() && (0.0..=max).contains(&s);
        match *self {
            Self::All(s) if !(in_range(s) && s > 0.0) => Err(NavigatorError::invalid(
                format!("dvl_states.{key}"),
                format!("{s:?} is not in (0, {max}]"),
            )),
            Self::PerAxis(axes) if !axes.iter().all(|&s| in_range(s)) => {
                Err(NavigatorError::invalid(
                    format!("dvl_states.{key}"),
                    format!("{axes:?}: each axis must be in [0, {max}] (0 holds that axis)"),
                ))
            }
            Self::PerAxis(axes) if axes.iter().all(|&s| s == 0.0) => Err(NavigatorError::invalid(
                format!("dvl_states.{key}"),
                "every axis is 0; set estimate = false to hold the state",
            )),
            _ => Ok(()),
        }
    }
}

impl From<f64> for AxisSigma {
    fn from(sigma: f64) -> Self {
        Self::All(sigma)
    }
}

state_config!(
    /// Scale-factor error settings (`prior_std` dimensionless).
    ScaleFactorState,
    prior_std: f64,
    "(dimensionless)"
);
state_config!(
    /// Mounting-misalignment settings (`prior_std_rad`, DVL frame: x roll, y pitch,
    /// z yaw of the DVL).
    MisalignmentState,
    prior_std_rad: AxisSigma,
    "per axis \\[rad\\]"
);
state_config!(
    /// Lever-arm settings (`prior_std_m`, body frame).
    LeverArmState,
    prior_std_m: AxisSigma,
    "per axis \\[m\\]"
);
state_config!(
    /// Time-offset settings (`prior_std_s`).
    TimeOffsetState,
    prior_std_s: f64,
    "\\[s\\]"
);

/// The velocity-bias settings: a first-order Gauss-Markov process per DVL axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BiasConfig {
    /// Estimate the bias.
    pub estimate: bool,
    /// Steady-state 1-sigma \[m/s\] (also the prior 1-sigma).
    pub std_mps: f64,
    /// Correlation time \[s\] (driving-noise PSD 2 sigma^2 / tau).
    pub time_constant_s: f64,
}

/// Which DVL error states the augmented filter estimates (serde; unknown keys refused).
/// Units: scale factor dimensionless, misalignment rad, lever arm m, time offset s.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DvlStatesConfig {
    /// Scale-factor error (default estimated, prior 1-sigma 0.005).
    pub scale_factor: ScaleFactorState,
    /// Mounting misalignment \[rad\] (default estimated, prior 1-sigma 0.01 rad).
    pub misalignment: MisalignmentState,
    /// Velocity bias (default estimated, 0.01 m/s, 60 s).
    pub bias: BiasConfig,
    /// Lever arm \[m\] (default estimated, prior 1-sigma 0.1 m).
    pub lever_arm: LeverArmState,
    /// Time offset \[s\] (default estimated, prior 1-sigma 0.5 s).
    pub time_offset: TimeOffsetState,
}

impl Default for DvlStatesConfig {
    fn default() -> Self {
        Self {
            scale_factor: ScaleFactorState {
                estimate: true,
                prior_std: 0.005,
            },
            misalignment: MisalignmentState {
                estimate: true,
                prior_std_rad: AxisSigma::All(0.01),
            },
            bias: BiasConfig {
                estimate: true,
                std_mps: 0.01,
                time_constant_s: 60.0,
            },
            lever_arm: LeverArmState {
                estimate: true,
                prior_std_m: AxisSigma::All(0.1),
            },
            time_offset: TimeOffsetState {
                estimate: true,
                prior_std_s: 0.5,
            },
        }
    }
}

impl DvlStatesConfig {
    /// Every DVL state off (the augmented filter then estimates what the 15-state
    /// navigator does).
    pub fn none() -> Self {
        let mut c = Self::default();
        c.scale_factor.estimate = false;
        c.misalignment.estimate = false;
        c.bias.estimate = false;
        c.lever_arm.estimate = false;
        c.time_offset.estimate = false;
        c
    }

    /// Check every value.
    ///
    /// # Errors
    /// [`NavigatorError::InvalidValue`] naming the key (`dvl_states.<group>.<key>`) of a
    /// prior sigma, bias sigma or time constant that is not positive and finite (only
    /// for estimated states), or a prior larger than the model allows (scale factor
    /// 0.1, misalignment 0.1 rad, lever arm 10 m, time offset 5 s).
    pub fn check(&self) -> Result<()> {
        let groups = [
            ("scale_factor.prior_std", self.scale_factor.prior(), 0.1),
            ("time_offset.prior_std_s", self.time_offset.prior(), 5.0),
        ];
        for (key, (estimate, std), max) in groups {
            if estimate {
                AxisSigma::All(std).check(key, max)?;
            }
        }
        let axis_groups = [
            ("misalignment.prior_std_rad", self.misalignment.prior(), 0.1),
            ("lever_arm.prior_std_m", self.lever_arm.prior(), 10.0),
        ];
        for (key, (estimate, sigma), max) in axis_groups {
            if estimate {
                sigma.check(key, max)?;
            }
        }
        let b = self.bias;
        if b.estimate {
            if !(b.std_mps.is_finite() && b.std_mps > 0.0 && b.std_mps <= 1.0) {
                return Err(NavigatorError::invalid(
                    "dvl_states.bias.std_mps",
                    format!("{:?} is not in (0, 1]", b.std_mps),
                ));
            }
            if !(b.time_constant_s.is_finite() && b.time_constant_s > 0.0) {
                return Err(NavigatorError::invalid(
                    "dvl_states.bias.time_constant_s",
                    format!("{:?} is not positive and finite", b.time_constant_s),
                ));
            }
        }
        Ok(())
    }

    /// Prior variance of each DVL state (zero for a state not estimated).
    pub fn prior_variances(&self) -> SVector<f64, DVL_STATES> {
        let v = |(estimate, std): (bool, f64)| if estimate { std * std } else { 0.0 };
        let b = if self.bias.estimate {
            self.bias.std_mps.powi(2)
        } else {
            0.0
        };
        let axes = |(estimate, sigma): (bool, AxisSigma)| {
            if estimate {
                sigma.axes().map(|s| s * s)
            } else {
                [0.0; 3]
            }
        };
        let (misalignment, lever_arm) = (
            axes(self.misalignment.prior()),
            axes(self.lever_arm.prior()),
        );
        let mut out = SVector::<f64, DVL_STATES>::zeros();
        out[0] = v(self.scale_factor.prior());
        for i in 0..3 {
            out[1 + i] = misalignment[i];
            out[4 + i] = b;
            out[7 + i] = lever_arm[i];
        }
        out[10] = v(self.time_offset.prior());
        out
    }
}
