//! The stand-in that solves the beams and dead-reckons a share of the IMU window
//! ([`StandInNetwork`]), and its per-update inputs drawn from a scenario's truth.

use estim_core::nalgebra::{DMatrix, Matrix3, Matrix3x4, Vector3, Vector4};
use estim_core::Result as CoreResult;
use estim_core::{InputSpec, LearnedMeasurement};
use estim_dvl::{dvl_frame_velocity, BeamGeometry};
use estim_ins::InsState;
use estim_learned::IMU_CHANNELS;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use super::{DvlNoise, SensorKind, BEAM_NOISE_STD};
use crate::study::Scenario;

/// Input streams of [`StandInNetwork`], in order.
const STREAMS: usize = 4;

/// An analytic stand-in for a learned velocity sensor, as an estim-core
/// [`LearnedMeasurement`] with exact Jacobian-vector products.
///
/// Inputs (one matrix per stream, columns oldest first):
/// 0. `imu` (6 x L): \[f_b; ω_b\] of the window's IMU samples (the samples the filter
///    integrated); the gyroscope rows are read and not used;
/// 1. `beams` (4 x 1): the four beam velocities it solves (by least squares);
/// 2. `carry` (9 x (L + 1)): column 0 the rotation C_{b_k <- b_then} from the body frame
///    of the beams' epoch to the body frame now, column 1 + i the rotation
///    C_{b_k <- b_i} of window sample i (row-major 3 x 3 each): the attitude comes
///    from outside the network (an AHRS stand-in), so the gyroscope noise is not shared;
/// 3. `offset` (3 x 1): the part of the motion since the beams' epoch that does not
///    come from the accelerometer (gravity, Coriolis, the lever arm, the discretisation
///    and the bias-free part of the increment), in the DVL frame now.
///
/// Output (velocity at the DVL, body frame now):
///
/// ```text
/// y = C_then P beams + α dt Σ_i C_i f_i + offset,   P = (A'A)⁻¹ A'
/// ```
///
/// linear in `imu` and `beams`, bilinear in `carry`: its Jacobian-vector products are
/// computed exactly. α = [`SensorKind::imu_gain`]. Built by the study (which fills the
/// per-update inputs from the simulation's truth); its error is C_then e_then + α dt
/// Σ_i C_i n_i, so R_k = C_then R_dvl C_then' + α² q T I per epoch
/// ([`StandInNetwork::noise_covariance_at`]).
#[derive(Debug, Clone)]
pub struct StandInNetwork {
    kind: SensorKind,
    specs: Vec<InputSpec>,
    pseudo_inverse: Matrix3x4<f64>,
    dt: f64,
    /// R of the beams' velocity in the frame of their epoch.
    dvl_covariance: Matrix3<f64>,
    /// q T: the variance per axis of dt Σ n over the window.
    integrated_noise_variance: f64,
}

impl StandInNetwork {
    /// The stand-in of `kind` reading `window` IMU samples of period `dt`, beams of
    /// `geometry` with noise `noise`; `accelerometer_psd` = q, the accelerometer
    /// white-noise PSD \[(m/s^2)^2/Hz\].
    pub fn new(
        kind: SensorKind,
        window: usize,
        dt: f64,
        geometry: &BeamGeometry,
        noise: DvlNoise,
        accelerometer_psd: f64,
    ) -> Self {
        let spec = |name: &str, channels, window| InputSpec {
            name: name.into(),
            channels,
            window,
            sample_rate_hz: 1.0 / dt,
        };
        let pseudo_inverse = *geometry.pseudo_inverse();
        let dvl_covariance = Matrix3::identity() * noise.velocity_std().powi(2)
            + pseudo_inverse * pseudo_inverse.transpose() * BEAM_NOISE_STD.powi(2);
        Self {
            kind,
            specs: vec![
                spec("imu", IMU_CHANNELS, window),
                spec("beams", 4, 1),
                spec("carry", 9, window + 1),
                spec("offset", 3, 1),
            ],
            pseudo_inverse,
            dt,
            dvl_covariance,
            integrated_noise_variance: accelerometer_psd * dt * window as f64,
        }
    }

    /// The IMU window L.
    pub fn window(&self) -> usize {
        self.specs[0].window
    }

    /// The sensor type.
    pub fn kind(&self) -> SensorKind {
        self.kind
    }

    /// R at an update whose beams' frame is rotated by `carry_then` into the frame now.
    pub fn noise_covariance_at(&self, carry_then: &Matrix3<f64>) -> Matrix3<f64> {
        carry_then * self.dvl_covariance * carry_then.transpose()
            + Matrix3::identity() * (self.kind.imu_gain().powi(2) * self.integrated_noise_variance)
    }

    fn check(&self, inputs: &[DMatrix<f64>]) -> CoreResult<()> {
        let ok = inputs.len() == STREAMS
            && inputs
                .iter()
                .zip(&self.specs)
                .all(|(m, s)| m.shape() == (s.channels, s.window));
        if ok {
            Ok(())
        } else {
            Err(estim_core::Error::Model(format!(
                "stand-in network: expected inputs imu 6 x L, beams 4 x 1, carry 9 x (L + 1), \
                 offset 3 x 1 (L = {}), got {:?}",
                self.window(),
                inputs.iter().map(DMatrix::shape).collect::<Vec<_>>()
            )))
        }
    }

    /// Rotation `column` of a `carry` matrix.
    pub(super) fn rotation(carry: &DMatrix<f64>, column: usize) -> Matrix3<f64> {
        Matrix3::from_fn(|r, c| carry[(3 * r + c, column)])
    }

    /// y(imu, beams, carry, offset): linear in (imu, beams, offset) for a fixed carry
    /// and linear in the carry for fixed (imu, beams), which the JVPs use.
    fn evaluate(
        &self,
        imu: &DMatrix<f64>,
        beams: &DMatrix<f64>,
        carry: &DMatrix<f64>,
        offset: &DMatrix<f64>,
    ) -> Vector3<f64> {
        let beams = Vector4::new(beams[0], beams[1], beams[2], beams[3]);
        let mut y = Self::rotation(carry, 0) * (self.pseudo_inverse * beams)
            + Vector3::new(offset[0], offset[1], offset[2]);
        let alpha = self.kind.imu_gain();
        if alpha != 0.0 {
            for i in 0..self.window() {
                let f = Vector3::new(imu[(0, i)], imu[(1, i)], imu[(2, i)]);
                y += Self::rotation(carry, i + 1) * f * (alpha * self.dt);
            }
        }
        y
    }
}

impl LearnedMeasurement<f64, 3> for StandInNetwork {
    fn input_specs(&self) -> &[InputSpec] {
        &self.specs
    }

    fn measure(&self, inputs: &[DMatrix<f64>]) -> CoreResult<Vector3<f64>> {
        self.check(inputs)?;
        Ok(self.evaluate(&inputs[0], &inputs[1], &inputs[2], &inputs[3]))
    }

    /// R with no rotation since the beams' epoch (the per-epoch R is
    /// [`StandInNetwork::noise_covariance_at`]).
    fn noise_covariance(&self) -> Matrix3<f64> {
        self.noise_covariance_at(&Matrix3::identity())
    }

    /// Exact JVPs: y is linear in (imu, beams, offset) for a fixed carry and linear in
    /// the carry for fixed (imu, beams), so J d = y(d_imu, d_beams, carry, d_offset) +
    /// y(imu, beams, d_carry, 0).
    fn sensitivity(
        &self,
        inputs: &[DMatrix<f64>],
        directions: &[DMatrix<f64>],
        products: &mut [Vector3<f64>],
    ) -> CoreResult<bool> {
        self.check(inputs)?;
        if directions.len() != products.len() * STREAMS {
            return Err(estim_core::Error::Model(format!(
                "stand-in network: {} direction matrices for {} products",
                directions.len(),
                products.len()
            )));
        }
        let zero_offset = DMatrix::zeros(3, 1);
        for (d, product) in directions.chunks_exact(STREAMS).zip(products.iter_mut()) {
            self.check(d)?;
            *product = self.evaluate(&d[0], &d[1], &inputs[2], &d[3])
                + self.evaluate(&inputs[0], &inputs[1], &d[2], &zero_offset);
        }
        Ok(true)
    }
}

/// Row-major 3 x 3 rotation into column `column` of a 9-row matrix.
pub(super) fn put_rotation(carry: &mut DMatrix<f64>, column: usize, rotation: &Matrix3<f64>) {
    for r in 0..3 {
        for c in 0..3 {
            carry[(3 * r + c, column)] = rotation[(r, c)];
        }
    }
}

/// The true velocity at the DVL in the body frame of truth sample `i`.
pub(super) fn dvl_velocity(state: &InsState, lever_arm: &Vector3<f64>) -> Vector3<f64> {
    let body_velocity = state.attitude.inverse() * state.velocity_ned;
    dvl_frame_velocity(
        &body_velocity,
        &state.angular_rate,
        lever_arm,
        0.0,
        &Vector3::zeros(),
    )
}

/// One epoch's per-update inputs of a [`StandInNetwork`] (beams, carry, offset) and the
/// rotation C_then, drawn from the scenario's truth and clean IMU; `None` when the
/// window does not fit in the scenario.
pub(super) fn update_inputs(
    model: &StandInNetwork,
    scenario: &Scenario,
    lever_arm: &Vector3<f64>,
    geometry: &BeamGeometry,
    noise: DvlNoise,
    end: usize,
    rng: &mut ChaCha8Rng,
) -> Option<(Vec<DMatrix<f64>>, Matrix3<f64>)> {
    let window = model.window();
    let start = end.checked_sub(window)?;
    let now = scenario.truth.get(end)?;
    let then_index = if model.kind().carries() { start } else { end };
    let then = scenario.truth.get(then_index)?;
    let to_now = now.attitude.inverse().to_rotation_matrix().into_inner();
    let rotation_to_now = |s: &InsState| to_now * s.attitude.to_rotation_matrix().into_inner();
    let carry_then = rotation_to_now(then);
    let mut carry = DMatrix::zeros(9, window + 1);
    put_rotation(&mut carry, 0, &carry_then);
    let alpha = model.kind().imu_gain();
    let mut clean_increment = Vector3::zeros();
    for (column, i) in (start..end).enumerate() {
        let state = scenario.truth.get(i)?;
        let rotation = rotation_to_now(state);
        put_rotation(&mut carry, column + 1, &rotation);
        // The measured specific force without its white noise: clean + bias.
        let noise_free = scenario.clean_imu.get(i)?.specific_force + state.acc_bias;
        clean_increment += rotation * noise_free * (alpha * scenario.imu_dt);
    }
    let v_then = dvl_velocity(then, lever_arm);
    let mut normal = || -> f64 { StandardNormal.sample(&mut *rng) };
    let velocity_noise = Vector3::from_fn(|_, _| normal() * noise.velocity_std());
    let beams = geometry.beams(&(v_then + velocity_noise))
        + Vector4::from_fn(|_, _| normal() * BEAM_NOISE_STD);
    let offset = dvl_velocity(now, lever_arm) - carry_then * v_then - clean_increment;
    Some((
        vec![
            DMatrix::from_column_slice(4, 1, beams.as_slice()),
            carry,
            DMatrix::from_column_slice(3, 1, offset.as_slice()),
        ],
        carry_then,
    ))
}
