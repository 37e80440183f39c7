//! The stand-in that dead-reckons both velocity and attitude from the IMU window
//! ([`GyroStandIn`]), and its per-update inputs drawn from a scenario's truth.

use estim_core::nalgebra::{DMatrix, Matrix3, Matrix3x4, Vector3, Vector4};
use estim_core::Result as CoreResult;
use estim_core::{InputSpec, LearnedMeasurement};
use estim_dvl::BeamGeometry;
use estim_learned::IMU_CHANNELS;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use super::stand_in::{dvl_velocity, put_rotation, StandInNetwork};
use super::{DvlNoise, BEAM_NOISE_STD};
use crate::study::Scenario;

/// Input streams of [`GyroStandIn`], in order.
const GYRO_STREAMS: usize = 5;

/// An analytic stand-in that dead-reckons both the velocity and the attitude from the
/// IMU window, as an estim-core [`LearnedMeasurement`] with exact Jacobian-vector
/// products (forward mode through the recursion).
///
/// Inputs: `imu` (6 x L, \[f_b; ω_b\] of the window), `beams` (4 x 1, of the epoch one
/// window ago), `attitude` (9 x 1, C_b^n at that epoch, row-major; from the
/// reference), `gyro_bias` (3 x 1, subtracted from ω), `offset` (3 x 1). With
/// P = (A'A)⁻¹ A' and first-order attitude steps A_i = I + dt [(ω_i - β)×]:
///
/// ```text
/// C_0 = attitude,  C_{i+1} = C_i A_i,  v = C_0 P beams + dt Σ_i C_i f_i,  y = C_L' v + offset
/// ```
///
/// The study sets `offset` = truth - y(noise-free inputs), so the output error is
/// y(noisy) - y(noise-free): to first order J n in the IMU white noise and the beam
/// noise ([`GyroStandIn::noise_covariance_at`]). Gravity, Coriolis and the lever arm
/// are in that offset; the gyroscope noise tilts the carried attitude, as the INS's.
#[derive(Debug, Clone)]
pub struct GyroStandIn {
    specs: Vec<InputSpec>,
    pseudo_inverse: Matrix3x4<f64>,
    dt: f64,
    dvl_covariance: Matrix3<f64>,
}

fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

fn column3(m: &DMatrix<f64>, first_row: usize, column: usize) -> Vector3<f64> {
    Vector3::new(
        m[(first_row, column)],
        m[(first_row + 1, column)],
        m[(first_row + 2, column)],
    )
}

fn beams4(m: &DMatrix<f64>) -> Vector4<f64> {
    Vector4::new(m[0], m[1], m[2], m[3])
}

impl GyroStandIn {
    /// Reading `window` IMU samples of period `dt`, beams of `geometry` with `noise`.
    pub fn new(window: usize, dt: f64, geometry: &BeamGeometry, noise: DvlNoise) -> Self {
        let spec = |name: &str, channels, window| InputSpec {
            name: name.into(),
            channels,
            window,
            sample_rate_hz: 1.0 / dt,
        };
        let pseudo_inverse = *geometry.pseudo_inverse();
        Self {
            specs: vec![
                spec("imu", IMU_CHANNELS, window),
                spec("beams", 4, 1),
                spec("attitude", 9, 1),
                spec("gyro_bias", 3, 1),
                spec("offset", 3, 1),
            ],
            pseudo_inverse,
            dt,
            dvl_covariance: Matrix3::identity() * noise.velocity_std().powi(2)
                + pseudo_inverse * pseudo_inverse.transpose() * BEAM_NOISE_STD.powi(2),
        }
    }

    /// The IMU window L.
    pub fn window(&self) -> usize {
        self.specs[0].window
    }

    fn check(&self, inputs: &[DMatrix<f64>]) -> CoreResult<()> {
        let ok = inputs.len() == GYRO_STREAMS
            && inputs
                .iter()
                .zip(&self.specs)
                .all(|(m, s)| m.shape() == (s.channels, s.window));
        if ok {
            Ok(())
        } else {
            Err(estim_core::Error::Model(format!(
                "gyro stand-in: expected inputs imu 6 x L, beams 4 x 1, attitude 9 x 1, \
                 gyro_bias 3 x 1, offset 3 x 1 (L = {}), got {:?}",
                self.window(),
                inputs.iter().map(DMatrix::shape).collect::<Vec<_>>()
            )))
        }
    }

    /// y and, with `direction` (one matrix per stream), its directional derivative
    /// (forward mode through the recursion). Inputs checked.
    fn evaluate(
        &self,
        inputs: &[DMatrix<f64>],
        direction: Option<&[DMatrix<f64>]>,
    ) -> (Vector3<f64>, Vector3<f64>) {
        let (imu, beams, bias) = (&inputs[0], beams4(&inputs[1]), column3(&inputs[3], 0, 0));
        let mut c = StandInNetwork::rotation(&inputs[2], 0);
        let mut v = c * (self.pseudo_inverse * beams);
        let (mut dc, mut dv, mut d_bias) = (Matrix3::zeros(), Vector3::zeros(), Vector3::zeros());
        if let Some(d) = direction {
            dc = StandInNetwork::rotation(&d[2], 0);
            dv = dc * (self.pseudo_inverse * beams) + c * (self.pseudo_inverse * beams4(&d[1]));
            d_bias = column3(&d[3], 0, 0);
        }
        for i in 0..self.window() {
            let f = column3(imu, 0, i);
            let step = Matrix3::identity() + skew(&(column3(imu, 3, i) - bias)) * self.dt;
            v += c * f * self.dt;
            if let Some(d) = direction {
                let d_f = column3(&d[0], 0, i);
                let d_omega = column3(&d[0], 3, i) - d_bias;
                dv += (dc * f + c * d_f) * self.dt;
                dc = dc * step + c * skew(&d_omega) * self.dt;
            }
            c *= step;
        }
        let y = c.transpose() * v + column3(&inputs[4], 0, 0);
        let dy = match direction {
            Some(d) => dc.transpose() * v + c.transpose() * dv + column3(&d[4], 0, 0),
            None => Vector3::zeros(),
        };
        (y, dy)
    }

    /// R of the output error at these inputs: the beams' R carried by C_L' C_0, plus
    /// Σ_j J_j Σ_j J_j' over the window's samples, with the closed-form columns
    /// J_f,j = dt C_L' C_j and J_ω,j = dt (E_{j+1}' [(C_j' v)×] - C_L' C_j [W_{j+1}×]),
    /// E_m = A_m ... A_{L-1}, W_m = Σ_{i >= m} dt A_m ... A_{i-1} f_i (backward
    /// recursions E_m = A_m E_{m+1}, W_m = dt f_m + A_m W_{m+1}); `psd` = the
    /// accelerometer and gyroscope white-noise PSDs (per-sample variance PSD / dt).
    ///
    /// # Errors
    /// Inputs not shaped as declared.
    pub fn noise_covariance_at(
        &self,
        inputs: &[DMatrix<f64>],
        psd: [f64; 2],
    ) -> CoreResult<Matrix3<f64>> {
        self.check(inputs)?;
        let (imu, beams, bias) = (&inputs[0], beams4(&inputs[1]), column3(&inputs[3], 0, 0));
        let (window, dt) = (self.window(), self.dt);
        let mut rotations = Vec::with_capacity(window + 1);
        let mut steps = Vec::with_capacity(window);
        let mut c = StandInNetwork::rotation(&inputs[2], 0);
        let mut v = c * (self.pseudo_inverse * beams);
        rotations.push(c);
        for i in 0..window {
            v += c * column3(imu, 0, i) * dt;
            let step = Matrix3::identity() + skew(&(column3(imu, 3, i) - bias)) * dt;
            c *= step;
            steps.push(step);
            rotations.push(c);
        }
        let c_l = rotations[window];
        let carry = c_l.transpose() * rotations[0];
        let mut r = carry * self.dvl_covariance * carry.transpose();
        let (acc, gyro) = (psd[0] / dt, psd[1] / dt);
        let (mut e, mut w) = (Matrix3::identity(), Vector3::zeros());
        for j in (0..window).rev() {
            // Here e = E_{j+1}, w = W_{j+1}.
            let c_j = rotations[j];
            let j_f = c_l.transpose() * c_j * dt;
            let j_omega: Matrix3<f64> = (e.transpose() * skew(&(c_j.transpose() * v))
                - c_l.transpose() * c_j * skew(&w))
                * dt;
            r += j_f * j_f.transpose() * acc + j_omega * j_omega.transpose() * gyro;
            w = column3(imu, 0, j) * dt + steps[j] * w;
            e = steps[j] * e;
        }
        Ok(r)
    }
}

impl LearnedMeasurement<f64, 3> for GyroStandIn {
    fn input_specs(&self) -> &[InputSpec] {
        &self.specs
    }

    fn measure(&self, inputs: &[DMatrix<f64>]) -> CoreResult<Vector3<f64>> {
        self.check(inputs)?;
        Ok(self.evaluate(inputs, None).0)
    }

    /// R of the beams alone (the per-epoch R with the IMU part is
    /// [`GyroStandIn::noise_covariance_at`]).
    fn noise_covariance(&self) -> Matrix3<f64> {
        self.dvl_covariance
    }

    fn sensitivity(
        &self,
        inputs: &[DMatrix<f64>],
        directions: &[DMatrix<f64>],
        products: &mut [Vector3<f64>],
    ) -> CoreResult<bool> {
        self.check(inputs)?;
        if directions.len() != products.len() * GYRO_STREAMS {
            return Err(estim_core::Error::Model(format!(
                "gyro stand-in: {} direction matrices for {} products",
                directions.len(),
                products.len()
            )));
        }
        for (d, product) in directions
            .chunks_exact(GYRO_STREAMS)
            .zip(products.iter_mut())
        {
            self.check(d)?;
            *product = self.evaluate(inputs, Some(d)).1;
        }
        Ok(true)
    }
}

/// One epoch's per-update inputs of a [`GyroStandIn`] (beams, attitude, gyro bias,
/// offset) and its R; the offset makes the output exact on the noise-free inputs (the
/// clean IMU plus its bias, noise-free beams). `None` when the window does not fit.
#[allow(clippy::too_many_arguments)]
pub(super) fn gyro_update_inputs(
    model: &GyroStandIn,
    scenario: &Scenario,
    lever_arm: &Vector3<f64>,
    geometry: &BeamGeometry,
    psd: [f64; 2],
    noise: DvlNoise,
    end: usize,
    rng: &mut ChaCha8Rng,
) -> Option<(Vec<DMatrix<f64>>, Matrix3<f64>)> {
    let window = model.window();
    let start = end.checked_sub(window)?;
    let now = scenario.truth.get(end)?;
    let then = scenario.truth.get(start)?;
    let mut imu = DMatrix::zeros(IMU_CHANNELS, window);
    let mut clean = DMatrix::zeros(IMU_CHANNELS, window);
    for (column, i) in (start..end).enumerate() {
        let (measured, state) = (scenario.imu.get(i)?, scenario.truth.get(i)?);
        let reference = scenario.clean_imu.get(i)?;
        let f = reference.specific_force + state.acc_bias;
        let w = reference.angular_rate + state.gyro_bias;
        for r in 0..3 {
            imu[(r, column)] = measured.specific_force[r];
            imu[(3 + r, column)] = measured.angular_rate[r];
            clean[(r, column)] = f[r];
            clean[(3 + r, column)] = w[r];
        }
    }
    let mut attitude = DMatrix::zeros(9, 1);
    put_rotation(
        &mut attitude,
        0,
        &then.attitude.to_rotation_matrix().into_inner(),
    );
    let bias = DMatrix::from_column_slice(3, 1, then.gyro_bias.as_slice());
    let v_then = dvl_velocity(then, lever_arm);
    let mut normal = || -> f64 { StandardNormal.sample(&mut *rng) };
    let velocity_noise = Vector3::from_fn(|_, _| normal() * noise.velocity_std());
    let beams = geometry.beams(&(v_then + velocity_noise))
        + Vector4::from_fn(|_, _| normal() * BEAM_NOISE_STD);
    let noise_free = [
        clean,
        DMatrix::from_column_slice(4, 1, geometry.beams(&v_then).as_slice()),
        attitude.clone(),
        bias.clone(),
        DMatrix::zeros(3, 1),
    ];
    let offset = dvl_velocity(now, lever_arm) - model.evaluate(&noise_free, None).0;
    let inputs = vec![
        imu,
        DMatrix::from_column_slice(4, 1, beams.as_slice()),
        attitude,
        bias,
        DMatrix::from_column_slice(3, 1, offset.as_slice()),
    ];
    let r = model.noise_covariance_at(&inputs, psd).ok()?;
    Some((inputs.into_iter().skip(1).collect(), r))
}
