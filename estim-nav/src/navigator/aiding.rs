//! Depth and position-fix measurements of the INS error-state filter (estim-core
//! [`MeasurementModel`]s on any nominal state with an INS part, [`InsNominal`], over
//! any error state whose first 15 states are estim-ins'), with the sensor's lever arm.
//! Their Jacobian columns beyond the 15 INS states are zero.
//!
//! Conventions of estim-ins: true = nominal + error, position error δp in metres
//! N, E, D (h_true = h - δp_D), misalignment ψ in NED with C_true = (I + [ψ×]) C.
//! A sensor at lever arm l (body frame) sits at p + C l; to first order
//! (I + [ψ×]) C l = C l + ψ × (C l) = C l - [(C l)×] ψ.

use estim_core::MeasurementModel;
use estim_ins::{earth, InsState, ATT, ERROR_STATES, POS};
use nalgebra::{Matrix1, Matrix2, SMatrix, Vector1, Vector2, Vector3};
use std::marker::PhantomData;

/// A nominal state with an INS part, whose error state has `N` states, the first 15
/// the INS ones (estim-ins' layout). It ties the state to its error-state size, so
/// that a model on it infers `N`.
pub trait InsNominal<const N: usize> {
    /// The INS nominal state.
    fn ins(&self) -> &InsState;
}

impl InsNominal<ERROR_STATES> for InsState {
    fn ins(&self) -> &InsState {
        self
    }
}

/// Refuses, at compile time, an error state smaller than the INS one.
const fn check_states<const N: usize>() {
    assert!(
        N >= ERROR_STATES,
        "the error state must hold the 15 INS states"
    );
}

/// Depth of a pressure sensor at `lever_arm` (body frame) below the surface \[m\]:
///
/// ```text
/// y = -h + (C_b^n l)_D
/// dy/dδp_D = 1,   dy/dψ = -[(C_b^n l)×] row D
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct DepthModel<S = InsState> {
    lever_arm: Vector3<f64>,
    variance: f64,
    state: PhantomData<fn(&S)>,
}

impl<S> DepthModel<S> {
    /// A depth sensor with `lever_arm` \[m\] and noise std `std_m` (> 0, checked by
    /// the navigator's configuration).
    pub fn new(lever_arm: Vector3<f64>, std_m: f64) -> Self {
        Self {
            lever_arm,
            variance: std_m * std_m,
            state: PhantomData,
        }
    }
}

impl<S: InsNominal<N>, const N: usize> MeasurementModel<f64, N, 1> for DepthModel<S> {
    type State = S;

    fn predict(&self, state: &S) -> estim_core::Result<Vector1<f64>> {
        let state = state.ins();
        let arm = state.attitude * self.lever_arm;
        Ok(Vector1::new(-state.height + arm[2]))
    }

    fn jacobian(&self, state: &S) -> estim_core::Result<SMatrix<f64, 1, N>> {
        const { check_states::<N>() };
        let arm = state.ins().attitude * self.lever_arm;
        let mut h = SMatrix::<f64, 1, N>::zeros();
        h[POS + 2] = 1.0;
        let attitude = -arm.cross_matrix();
        for j in 0..3 {
            h[ATT + j] = attitude[(2, j)];
        }
        Ok(h)
    }

    fn noise_covariance(&self, _state: &S) -> estim_core::Result<Matrix1<f64>> {
        Ok(Matrix1::new(self.variance))
    }
}

/// A horizontal position fix (latitude, longitude) of an antenna or transponder at
/// `lever_arm`, as a measurement in metres on the fix's own tangent plane: y = 0 and
///
/// ```text
/// h(x) = [(lat - lat_f) M_N + s_N (C l)_N,  (lon - lon_f) M_E + s_E (C l)_E]
/// M_N = R_N(lat_f),  M_E = R_E(lat_f) cos lat_f        (metres per radian at the fix)
/// s_N = M_N / (R_N(lat) + h),  s_E = M_E / ((R_E(lat) + h) cos lat)
/// dh/dδp_N = s_N,  dh/dδp_E = s_E,  dh/dψ = -s [(C l)×] (rows N, E)
/// ```
///
/// so that the innovation y - h(x) is the fix minus the predicted sensor position,
/// north and east, in metres (terms of second order in the lever arm over the Earth's
/// radius neglected).
#[derive(Debug, Clone, PartialEq)]
pub struct PositionFixModel<S = InsState> {
    latitude: f64,
    longitude: f64,
    lever_arm: Vector3<f64>,
    variance: f64,
    state: PhantomData<fn(&S)>,
}

impl<S> PositionFixModel<S> {
    /// A fix at `latitude`, `longitude` \[rad\] with horizontal 1-sigma `sigma_m`.
    pub fn new(latitude: f64, longitude: f64, sigma_m: f64, lever_arm: Vector3<f64>) -> Self {
        Self {
            latitude,
            longitude,
            lever_arm,
            variance: sigma_m * sigma_m,
            state: PhantomData,
        }
    }
}

impl<S> PositionFixModel<S> {
    /// Metres per radian at the fix (M_N, M_E) and the scales (s_N, s_E) at `state`.
    fn metrics(&self, state: &InsState) -> ([f64; 2], [f64; 2]) {
        let (rn_f, re_f) = earth::radii_of_curvature(self.latitude);
        let fix = [rn_f, re_f * self.latitude.cos()];
        let (rn, re) = earth::radii_of_curvature(state.latitude);
        let here = [
            rn + state.height,
            (re + state.height) * state.latitude.cos(),
        ];
        (fix, [fix[0] / here[0], fix[1] / here[1]])
    }
}

impl<S: InsNominal<N>, const N: usize> MeasurementModel<f64, N, 2> for PositionFixModel<S> {
    type State = S;

    fn predict(&self, state: &S) -> estim_core::Result<Vector2<f64>> {
        let state = state.ins();
        let (fix, scale) = self.metrics(state);
        let arm = state.attitude * self.lever_arm;
        let y = Vector2::new(
            (state.latitude - self.latitude) * fix[0] + scale[0] * arm[0],
            (state.longitude - self.longitude) * fix[1] + scale[1] * arm[1],
        );
        if y.iter().all(|v| v.is_finite()) {
            Ok(y)
        } else {
            Err(estim_core::Error::NonFinite {
                what: "position fix prediction (state)",
            })
        }
    }

    fn jacobian(&self, state: &S) -> estim_core::Result<SMatrix<f64, 2, N>> {
        const { check_states::<N>() };
        let state = state.ins();
        let (_, scale) = self.metrics(state);
        let arm = state.attitude * self.lever_arm;
        let attitude = -arm.cross_matrix();
        let mut h = SMatrix::<f64, 2, N>::zeros();
        for i in 0..2 {
            h[(i, POS + i)] = scale[i];
            for j in 0..3 {
                h[(i, ATT + j)] = scale[i] * attitude[(i, j)];
            }
        }
        estim_core::numeric::check_finite(h.as_slice(), "position fix Jacobian")?;
        Ok(h)
    }

    fn noise_covariance(&self, _state: &S) -> estim_core::Result<Matrix2<f64>> {
        Ok(Matrix2::from_diagonal_element(self.variance))
    }
}

/// The measurement of a fix: zero (the model predicts the offset from the fix).
pub(crate) const FIX_MEASUREMENT: Vector2<f64> = Vector2::new(0.0, 0.0);

#[cfg(test)]
mod tests {
    use super::*;
    use estim_ins::inject;
    use nalgebra::{SVector, UnitQuaternion};

    fn state() -> InsState {
        let mut s = InsState::new(
            0.0,
            0.57,
            0.61,
            -35.0,
            Vector3::new(1.4, -0.6, 0.1),
            UnitQuaternion::from_euler_angles(0.05, -0.08, 2.3),
        );
        s.angular_rate = Vector3::new(0.01, -0.02, 0.05);
        s
    }

    /// Central differences of h(inject(x, e)) along each error-state axis against H.
    fn check<Mm: MeasurementModel<f64, ERROR_STATES, M, State = InsState>, const M: usize>(
        model: &Mm,
    ) {
        let x = state();
        let h = model.jacobian(&x).unwrap();
        for j in 0..ERROR_STATES {
            let step = if (ATT..ATT + 3).contains(&j) {
                1e-6
            } else {
                1e-3
            };
            let mut e = SVector::<f64, ERROR_STATES>::zeros();
            e[j] = step;
            let plus = model.predict(&inject(&x, &e)).unwrap();
            let minus = model.predict(&inject(&x, &(-e))).unwrap();
            let numeric = (plus - minus) / (2.0 * step);
            for i in 0..M {
                let tol = 1e-6 * (1.0 + h[(i, j)].abs());
                assert!(
                    (numeric[i] - h[(i, j)]).abs() <= tol,
                    "row {i}, column {j}: finite difference {} vs Jacobian {}",
                    numeric[i],
                    h[(i, j)]
                );
            }
        }
    }

    #[test]
    fn depth_jacobian_matches_finite_differences() {
        check(&DepthModel::new(Vector3::new(0.8, -0.3, 0.4), 0.1));
        check(&DepthModel::new(Vector3::zeros(), 0.1));
    }

    #[test]
    fn fix_jacobian_matches_finite_differences() {
        check(&PositionFixModel::new(
            0.5701,
            0.6099,
            2.0,
            Vector3::new(-0.5, 0.2, -1.2),
        ));
    }

    #[test]
    fn predictions_have_the_documented_signs() {
        let x = state();
        // Under water h < 0: depth = -h (plus the lever arm's vertical component).
        let d = DepthModel::new(Vector3::zeros(), 0.1).predict(&x).unwrap();
        assert_eq!(d[0], 35.0);
        // A fix at the vehicle: zero offset.
        let f = PositionFixModel::new(x.latitude, x.longitude, 1.0, Vector3::zeros())
            .predict(&x)
            .unwrap();
        assert_eq!(f, Vector2::zeros());
    }
}
