//! The augmented process model: the INS error model and the DVL states' dynamics.

use estim_core::{ErrorStateModel, ProcessModel};
use estim_ins::{ErrorMatrix, ImuSample, InsErrorModel, ERROR_STATES};
use nalgebra::{Rotation3, SVector, Vector3};

use super::{
    AugmentedMatrix, AugmentedState, AugmentedVector, DvlParameters, DvlStatesConfig,
    AUGMENTED_STATES, DVL_BIAS, DVL_LEVER_ARM, DVL_MISALIGNMENT, DVL_SCALE, DVL_STATES,
    DVL_TIME_OFFSET,
};
use crate::navigator::{NavigatorError, Result};

/// constant except the Gauss-Markov bias, b_k = e^{-dt/tau} b_{k-1} + w,
/// Var w = sigma^2 (1 - e^{-2 dt/tau}) (the exact discretisation of
/// db/dt = -b/tau + w_c, PSD 2 sigma^2 / tau).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AugmentedErrorModel {
    ins: InsErrorModel,
    bias: Option<(f64, f64)>,
    states: DvlStatesConfig,
}

impl AugmentedErrorModel {
    /// The model over `ins` with the DVL states of `states` (checked).
    ///
    /// # Errors
    /// As [`DvlStatesConfig::check`].
    pub fn new(ins: InsErrorModel, states: &DvlStatesConfig) -> Result<Self> {
        states.check()?;
        let b = states.bias;
        Ok(Self {
            ins,
            bias: b.estimate.then_some((b.std_mps, b.time_constant_s)),
            states: *states,
        })
    }

    /// The Gauss-Markov bias (sigma \[m/s\], tau \[s\]), if estimated.
    pub fn bias(&self) -> Option<(f64, f64)> {
        self.bias
    }

    /// Set the Gauss-Markov bias sigma \[m/s\] (> 0, finite) from the next
    /// prediction on; tau is kept.
    ///
    /// # Errors
    /// [`NavigatorError::Conflict`] when the bias is not estimated,
    /// [`NavigatorError::InvalidValue`] when sigma is not finite and positive.
    pub fn set_bias_std(&mut self, sigma: f64) -> Result<()> {
        match &mut self.bias {
            Some((s, _)) if sigma.is_finite() && sigma > 0.0 => {
                *s = sigma;
                Ok(())
            }
            Some(_) => Err(NavigatorError::invalid(
                "DVL bias sigma",
                format!("{sigma:?} m/s is not finite and positive"),
            )),
            None => Err(NavigatorError::conflict(
                "DVL bias sigma",
                "the DVL bias is not estimated: it has no sigma to set",
            )),
        }
    }

    /// The DVL states estimated (as configured; the bias sigma as set at the start).
    pub fn states(&self) -> &DvlStatesConfig {
        &self.states
    }

    /// The INS error model.
    pub fn ins(&self) -> &InsErrorModel {
        &self.ins
    }

    /// Transition factor of the bias over `dt` (1 when the bias is not estimated).
    fn bias_decay(&self, dt: f64) -> f64 {
        self.bias.map_or(1.0, |(_, tau)| (-dt / tau).exp())
    }

    /// The diagonal of the DVL block of Phi over `dt`.
    fn dvl_transition(&self, dt: f64) -> SVector<f64, DVL_STATES> {
        let mut d = SVector::<f64, DVL_STATES>::repeat(1.0);
        let phi = self.bias_decay(dt);
        for i in 0..3 {
            d[4 + i] = phi;
        }
        d
    }
}

fn ins_error(error: &AugmentedVector) -> SVector<f64, ERROR_STATES> {
    error.fixed_rows::<ERROR_STATES>(0).into_owned()
}

impl ProcessModel<f64, AUGMENTED_STATES> for AugmentedErrorModel {
    type State = AugmentedState;
    type Input = ImuSample;

    fn propagate(
        &self,
        state: &AugmentedState,
        input: &ImuSample,
        dt: f64,
    ) -> estim_core::Result<AugmentedState> {
        Ok(AugmentedState {
            ins: self.ins.propagate(&state.ins, input, dt)?,
            dvl: DvlParameters {
                // The conditional mean of a Gauss-Markov process decays.
                bias: state.dvl.bias * self.bias_decay(dt),
                ..state.dvl
            },
            specific_force: input.specific_force,
        })
    }

    fn transition(
        &self,
        state: &AugmentedState,
        input: &ImuSample,
        dt: f64,
    ) -> estim_core::Result<AugmentedMatrix> {
        Ok(self.transition_and_noise(state, input, dt)?.0)
    }

    fn process_noise(
        &self,
        state: &AugmentedState,
        input: &ImuSample,
        dt: f64,
    ) -> estim_core::Result<AugmentedMatrix> {
        Ok(self.transition_and_noise(state, input, dt)?.1)
    }

    fn transition_and_noise(
        &self,
        state: &AugmentedState,
        input: &ImuSample,
        dt: f64,
    ) -> estim_core::Result<(AugmentedMatrix, AugmentedMatrix)> {
        let (phi_ins, q_ins) =
            ProcessModel::transition_and_noise(&self.ins, &state.ins, input, dt)?;
        let mut phi = AugmentedMatrix::zeros();
        let mut q = AugmentedMatrix::zeros();
        phi.fixed_view_mut::<ERROR_STATES, ERROR_STATES>(0, 0)
            .copy_from(&phi_ins);
        q.fixed_view_mut::<ERROR_STATES, ERROR_STATES>(0, 0)
            .copy_from(&q_ins);
        let d = self.dvl_transition(dt);
        for i in 0..DVL_STATES {
            phi[(ERROR_STATES + i, ERROR_STATES + i)] = d[i];
        }
        if let Some((sigma, _)) = self.bias {
            let phi_b = d[4];
            for i in 0..3 {
                q[(DVL_BIAS + i, DVL_BIAS + i)] = sigma * sigma * (1.0 - phi_b * phi_b);
            }
        }
        Ok((phi, q))
    }

    /// Phi is block diagonal (the INS block, and a diagonal DVL block): the INS block
    /// goes through [`InsErrorModel`]'s structured propagation, the rest is scaled.
    /// Equal to the dense Phi P Phi' + Q for that structure.
    fn propagate_covariance(
        &self,
        covariance: &AugmentedMatrix,
        transition: &AugmentedMatrix,
        process_noise: &AugmentedMatrix,
    ) -> AugmentedMatrix {
        let phi_ins: ErrorMatrix = transition
            .fixed_view::<ERROR_STATES, ERROR_STATES>(0, 0)
            .into_owned();
        let p_ins: ErrorMatrix = covariance
            .fixed_view::<ERROR_STATES, ERROR_STATES>(0, 0)
            .into_owned();
        let q_ins: ErrorMatrix = process_noise
            .fixed_view::<ERROR_STATES, ERROR_STATES>(0, 0)
            .into_owned();
        let d: SVector<f64, DVL_STATES> =
            SVector::from_fn(|i, _| transition[(ERROR_STATES + i, ERROR_STATES + i)]);
        let mut out = AugmentedMatrix::zeros();
        out.fixed_view_mut::<ERROR_STATES, ERROR_STATES>(0, 0)
            .copy_from(&self.ins.propagate_covariance(&p_ins, &phi_ins, &q_ins));
        let p_id = covariance.fixed_view::<ERROR_STATES, DVL_STATES>(0, ERROR_STATES);
        let mut cross = phi_ins * p_id;
        for j in 0..DVL_STATES {
            let mut column = cross.column_mut(j);
            column *= d[j];
        }
        out.fixed_view_mut::<ERROR_STATES, DVL_STATES>(0, ERROR_STATES)
            .copy_from(&cross);
        out.fixed_view_mut::<DVL_STATES, ERROR_STATES>(ERROR_STATES, 0)
            .copy_from(&cross.transpose());
        for i in 0..DVL_STATES {
            for j in 0..DVL_STATES {
                let (r, c) = (ERROR_STATES + i, ERROR_STATES + j);
                out[(r, c)] = d[i] * covariance[(r, c)] * d[j] + process_noise[(r, c)];
            }
        }
        out
    }

    /// Block diagonal as [`AugmentedErrorModel::propagate_covariance`].
    fn compose_transitions(
        &self,
        later: &AugmentedMatrix,
        earlier: &AugmentedMatrix,
    ) -> AugmentedMatrix {
        let a: ErrorMatrix = later
            .fixed_view::<ERROR_STATES, ERROR_STATES>(0, 0)
            .into_owned();
        let b: ErrorMatrix = earlier
            .fixed_view::<ERROR_STATES, ERROR_STATES>(0, 0)
            .into_owned();
        let mut out = AugmentedMatrix::zeros();
        out.fixed_view_mut::<ERROR_STATES, ERROR_STATES>(0, 0)
            .copy_from(&self.ins.compose_transitions(&a, &b));
        for i in ERROR_STATES..AUGMENTED_STATES {
            out[(i, i)] = later[(i, i)] * earlier[(i, i)];
        }
        out
    }
}

impl ErrorStateModel<f64, AUGMENTED_STATES> for AugmentedErrorModel {
    /// The INS part by estim-ins' injection; the DVL states added, the misalignment
    /// composed on the right (see the module docs).
    fn inject(
        &self,
        nominal: &AugmentedState,
        error: &AugmentedVector,
    ) -> estim_core::Result<AugmentedState> {
        let ins = self.ins.inject(&nominal.ins, &ins_error(error))?;
        Ok(AugmentedState {
            ins,
            dvl: inject_dvl(&nominal.dvl, error),
            specific_force: nominal.specific_force,
        })
    }

    /// estim-ins' reset for the INS block; identity for the DVL states (the
    /// misalignment's own reset, I - \[δμ̂×\]/2, differs from I by less than the
    /// prior sigma of 0.1 rad over 2 and is neglected as in most DVL filters).
    fn reset_jacobian(&self, nominal: &AugmentedState, error: &AugmentedVector) -> AugmentedMatrix {
        let mut j = AugmentedMatrix::identity();
        j.fixed_view_mut::<ERROR_STATES, ERROR_STATES>(0, 0)
            .copy_from(&self.ins.reset_jacobian(&nominal.ins, &ins_error(error)));
        j
    }
}

fn inject_dvl(dvl: &DvlParameters, error: &AugmentedVector) -> DvlParameters {
    let v3 = |start: usize| Vector3::new(error[start], error[start + 1], error[start + 2]);
    DvlParameters {
        scale_factor_error: dvl.scale_factor_error + error[DVL_SCALE],
        dvl_to_body: dvl.dvl_to_body * Rotation3::new(v3(DVL_MISALIGNMENT)),
        bias: dvl.bias + v3(DVL_BIAS),
        lever_arm: dvl.lever_arm + v3(DVL_LEVER_ARM),
        time_offset: dvl.time_offset + error[DVL_TIME_OFFSET],
    }
}
