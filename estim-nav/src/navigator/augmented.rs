//! The INS/DVL error state augmented with DVL error states: scale-factor error,
//! mounting misalignment, a velocity bias (first-order Gauss-Markov), lever arm and
//! time offset, each optional.
//!
//! # Layout
//!
//! A fixed 26-state error vector, the 15 INS states of estim-ins first, then
//!
//! | index | state | unit | dynamics |
//! |---|---|---|---|
//! | [`DVL_SCALE`] | scale-factor error δk | - | constant |
//! | [`DVL_MISALIGNMENT`]..+3 | mounting misalignment δμ (DVL frame) | rad | constant |
//! | [`DVL_BIAS`]..+3 | velocity bias δb (DVL frame) | m/s | Gauss-Markov, tau, sigma |
//! | [`DVL_LEVER_ARM`]..+3 | lever arm δl (body frame) | m | constant |
//! | [`DVL_TIME_OFFSET`] | time offset δτ | s | constant |
//!
//! A state that is not estimated ([`DvlStatesConfig`]) has zero prior variance and zero
//! process noise: its rows and columns of P stay exactly zero, its gain is zero, its
//! nominal value stays at the configured (calibrated) value. The same holds for one
//! axis of the misalignment or the lever arm whose prior sigma is 0 ([`AxisSigma`]);
//! for the misalignment, the rotation vector's component along a held axis can still
//! change at second order as the other axes' corrections compose. The filter's default
//! square-root covariance update accepts such a singular P (a zero pivot with a zero
//! column is a zero column, estim-core `CovarianceUpdate::SquareRoot`).
//!
//! # Conventions
//!
//! true = nominal + error for every state except the misalignment, which is a right
//! perturbation of the rotation DVL -> body: Rot_true = Rot exp(\[δμ×\]), so
//! C_b^d,true = (I - \[δμ×\]) C_b^d to first order. The INS conventions are estim-ins'.
//!
//! # DVL measurement
//!
//! A sample stamped t measures the motion at t - τ; to first order in τ,
//!
//! ```text
//! a_b = (f - b_a) + C_n^b g^n - ω × (C_n^b v^n)       body-frame acceleration
//! u   = C_n^b v^n + ω × l - τ ā_b                      velocity at the DVL, at t - τ
//! y   = (1 + k) C_b^d u + b
//! ```
//!
//! with f the specific force of the last IMU sample (raw, kept in
//! [`AugmentedState::specific_force`]), ω the bias-corrected angular rate of the
//! mechanization, g^n = \[0, 0, g(L, h)\] (Coriolis and transport rate, below 3e-4
//! m/s^2 at AUV speeds, and the angular acceleration in d(ω × l)/dt are neglected in
//! a_b). ā_b is a_b plus a constant: in [`AugmentedNavigator`], the mean of a_b over
//! the IMU steps of the last |τ| seconds (nominal τ) minus a_b at the nominal, so that
//! at the nominal C v^n - τ ā_b is the nominal's body velocity at t - τ. The IMU
//! noise integrated into v^n over the window then cancels, and the noise of the
//! regressor ā_b is independent of the INS velocity error at t - τ: for a delay (τ >
//! 0) the time-offset state has no errors-in-variables bias (with the last sample's
//! a_b it has: the raw specific force's noise is in both). For τ < 0 (the DVL measures
//! after its stamp) the window lies before the measured time and the estimate is
//! pulled towards zero, and near τ = 0 the window is one IMU step, whose noise a
//! noisy IMU's filter takes for signal (`dvl_states_limits` in `batch.rs`). A model
//! used on its own has no window (ā_b = a_b). Jacobian, with G = (1 + k) C_b^d,
//! C = C_n^b, v_b = C v^n:
//!
//! ```text
//! dy/dδp_D = G τ C e_D ∂g/∂h            (h_true = h - δp_D)
//! dy/dδp_N = -G τ C e_D ∂g/∂L / (R_N + h)
//! dy/dδv   = G (C + τ [ω×] C)
//! dy/dψ    = G (C [v×] - τ C [g×] + τ [ω×] C [v×])
//! dy/dδb_a = G τ
//! dy/dδb_g = G ([l×] + τ [v_b×])
//! dy/dδk   = C_b^d u
//! dy/dδμ   = (1 + k) [(C_b^d u)×]
//! dy/dδb   = I
//! dy/dδl   = G [ω×]
//! dy/dδτ   = -G ā_b
//! ```
//!
//! Each block is checked against central differences of the prediction through
//! [`AugmentedErrorModel`]'s injection (tests below).

use estim_ins::{InsState, ERROR_STATES};
use nalgebra::{Rotation3, SMatrix, SVector, Vector3};

use super::aiding::InsNominal;

mod dvl;
mod model;
mod navigator;
mod states;
#[cfg(test)]
mod tests;

pub use dvl::AugmentedDvlModel;
pub use model::AugmentedErrorModel;
pub use navigator::{
    AccelerationWindow, AugmentedFilter, AugmentedNavigator, DvlStateSolution,
    ACCELERATION_HISTORY_S,
};
pub use states::{
    AxisSigma, BiasConfig, DvlStatesConfig, LeverArmState, MisalignmentState, ScaleFactorState,
    TimeOffsetState,
};

/// Size of the augmented error state.
pub const AUGMENTED_STATES: usize = ERROR_STATES + DVL_STATES;
/// Number of DVL error states.
pub const DVL_STATES: usize = 11;
/// Index of the DVL scale-factor error.
pub const DVL_SCALE: usize = ERROR_STATES;
/// First index of the DVL mounting misalignment (3).
pub const DVL_MISALIGNMENT: usize = ERROR_STATES + 1;
/// First index of the DVL velocity bias (3).
pub const DVL_BIAS: usize = ERROR_STATES + 4;
/// First index of the DVL lever arm (3).
pub const DVL_LEVER_ARM: usize = ERROR_STATES + 7;
/// Index of the DVL time offset.
pub const DVL_TIME_OFFSET: usize = ERROR_STATES + 10;

/// Square matrix of the augmented error state.
pub type AugmentedMatrix = SMatrix<f64, AUGMENTED_STATES, AUGMENTED_STATES>;
/// Vector of the augmented error state.
pub type AugmentedVector = SVector<f64, AUGMENTED_STATES>;

/// The DVL parameters the augmented filter carries as its nominal DVL state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DvlParameters {
    /// Scale-factor error k (measured = (1 + k) true).
    pub scale_factor_error: f64,
    /// Rotation DVL -> body (the mounting misalignment).
    pub dvl_to_body: Rotation3<f64>,
    /// Velocity bias in the DVL frame \[m/s\].
    pub bias: Vector3<f64>,
    /// Lever arm IMU -> DVL in the body frame \[m\].
    pub lever_arm: Vector3<f64>,
    /// Time offset τ \[s\] beyond the shift already applied to the time stamps.
    pub time_offset: f64,
}

impl Default for DvlParameters {
    fn default() -> Self {
        Self {
            scale_factor_error: 0.0,
            dvl_to_body: Rotation3::identity(),
            bias: Vector3::zeros(),
            lever_arm: Vector3::zeros(),
            time_offset: 0.0,
        }
    }
}

impl DvlParameters {
    /// The mounting misalignment as a rotation vector DVL -> body \[rad\].
    pub fn mounting_misalignment(&self) -> Vector3<f64> {
        self.dvl_to_body.scaled_axis()
    }
}

/// Nominal state of the augmented filter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AugmentedState {
    /// The INS nominal state.
    pub ins: InsState,
    /// The DVL parameters.
    pub dvl: DvlParameters,
    /// Raw specific force of the last IMU sample integrated \[m/s^2\] (for the
    /// time-offset term of the DVL prediction; zero before the first step).
    pub specific_force: Vector3<f64>,
}

impl InsNominal<AUGMENTED_STATES> for AugmentedState {
    fn ins(&self) -> &InsState {
        &self.ins
    }
}
