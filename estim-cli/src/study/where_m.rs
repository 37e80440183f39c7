//! "Where M matters": a simulation study of when the exact cross-covariance M between
//! the INS process noise and a learned velocity sensor's error changes the filter.
//!
//! The sweep: IMU grade (the presets of [`GRADES`], sources in their doc comments in
//! `estim_ins::ImuSpec`) x DVL noise ([`DvlNoise`]) x sensor type ([`SensorKind`]).
//! Per cell, seeded simulated missions are filtered twice, with the exact M (from the
//! sensor's own Jacobian-vector products through estim-learned's generic
//! [`LearnedCrossCovariance`]) and with M neglected, and the run-averaged NEES and the
//! filter's velocity and attitude standard deviations are compared.
//!
//! The sensors are analytic stand-ins for networks with the named behaviour
//! ([`StandInNetwork`]), not trained networks: their error is known in closed form, so
//! the exact M and R are known and the filter with them should be consistent.

use estim_core::consistency::chi_square_band;
use estim_core::nalgebra::{DMatrix, Matrix3, Matrix3x4, SMatrix, Vector3, Vector4};
use estim_core::{ErrorStateKalmanFilter, FilterConfig, InputSpec, LearnedMeasurement};
use estim_core::{Result as CoreResult, WindowedCrossCovariance};
use estim_dvl::{dvl_frame_velocity, BeamGeometry};
use estim_ins::{InsErrorModel, InsState, ATT, ERROR_STATES, VEL};
use estim_learned::{driven_error_covariance, LearnedCrossCovariance, IMU_CHANNELS};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;
use serde::Serialize;

use super::run::filter_imu_spec;
use super::{
    max_correlation, run_filter_per_epoch_noise, Config, CrossMatrix, CrossSource, FilterRun,
    MeasurementSet, PipelineError, Result, Scenario,
};

/// The IMU grades swept (preset names of `imu.preset`; numbers and sources in the doc
/// comments of `estim_ins::ImuSpec::navigation_grade_fog`, `tactical_mems`,
/// `consumer_mems` and `akit_observed`).
pub const GRADES: [&str; 4] = [
    "navigation_grade_fog",
    "tactical_mems",
    "consumer_mems",
    "akit_observed",
];

/// Per-beam noise std of the beam-level DVL noise \[m/s\]: the BeamsNet protocol's
/// `0.042**2 * randn` (shared DESIGN.md, "Pitfalls").
pub const BEAM_NOISE_STD: f64 = 0.042 * 0.042;

/// Velocity noise std per axis of the mismatch-level DVL noise \[m/s\]: the A-KIT
/// DVL-vs-reference mismatch fitted on the training trajectories (`estim dvl
/// mismatch`, `dvl.akit_reference_mismatch_std_mps`).
pub const MISMATCH_STD: f64 = 0.017;

/// Duration of each simulated mission of the study \[s\].
pub const MISSION_DURATION_S: f64 = 120.0;

/// Relative change of NEES or a std above which a cell is flagged.
pub const FLAG_THRESHOLD: f64 = 0.10;

/// The DVL noise of a cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DvlNoise {
    /// Independent noise of [`BEAM_NOISE_STD`] on each of the four beams, solved by least
    /// squares: R = σ_b² (A'A)⁻¹.
    Beam,
    /// The beam noise plus a velocity noise of [`MISMATCH_STD`] per axis:
    /// R = σ_m² I + σ_b² (A'A)⁻¹.
    Mismatch,
}

impl DvlNoise {
    /// Both levels.
    pub const ALL: [Self; 2] = [Self::Beam, Self::Mismatch];

    /// Velocity noise std per axis added before the beams are formed \[m/s\].
    fn velocity_std(self) -> f64 {
        match self {
            Self::Beam => 0.0,
            Self::Mismatch => MISMATCH_STD,
        }
    }

    /// Short label.
    pub fn label(self) -> &'static str {
        match self {
            Self::Beam => "beam 0.00176 m/s",
            Self::Mismatch => "mismatch 0.017 m/s",
        }
    }
}

/// The sensor type of a cell: what the stand-in network does with the IMU window.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SensorKind {
    /// The velocity from this epoch's beams; reads the IMU window but its output does
    /// not depend on it (BeamsNet under its protocol): M = 0 by construction.
    BeamsOnly,
    /// The velocity solved from the beams one DVL period (L IMU steps) ago, carried
    /// forward to now by integrating the accelerometer samples of the window it was
    /// fed: its error holds +dt Σ n of the same samples whose noise enters the INS
    /// velocity error as -dt Σ n.
    DeadReckoning,
    /// As `DeadReckoning`, but half of the carried increment comes from the
    /// accelerometer and half from a noise-free motion model: error +dt Σ n / 2.
    HalfDeadReckoning,
    /// As `DeadReckoning`, with the attitude also dead-reckoned from the window's
    /// gyroscope samples (from the attitude at the beams' epoch): it shares the
    /// accelerometer and the gyroscope white noise ([`GyroStandIn`]).
    GyroDeadReckoning,
}

impl SensorKind {
    /// The three types.
    pub const ALL: [Self; 4] = [
        Self::BeamsOnly,
        Self::DeadReckoning,
        Self::HalfDeadReckoning,
        Self::GyroDeadReckoning,
    ];

    /// Gain α on the integrated accelerometer samples.
    pub fn imu_gain(self) -> f64 {
        match self {
            Self::BeamsOnly => 0.0,
            Self::DeadReckoning | Self::GyroDeadReckoning => 1.0,
            Self::HalfDeadReckoning => 0.5,
        }
    }

    /// Whether the beams are those of the previous DVL epoch (carried forward).
    fn carries(self) -> bool {
        !matches!(self, Self::BeamsOnly)
    }

    /// Short label.
    pub fn label(self) -> &'static str {
        match self {
            Self::BeamsOnly => "beams only",
            Self::DeadReckoning => "dead-reckons IMU",
            Self::HalfDeadReckoning => "half IMU",
            Self::GyroDeadReckoning => "dead-reckons IMU + gyro",
        }
    }
}

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
    fn rotation(carry: &DMatrix<f64>, column: usize) -> Matrix3<f64> {
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
fn gyro_update_inputs(
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

/// Row-major 3 x 3 rotation into column `column` of a 9-row matrix.
fn put_rotation(carry: &mut DMatrix<f64>, column: usize, rotation: &Matrix3<f64>) {
    for r in 0..3 {
        for c in 0..3 {
            carry[(3 * r + c, column)] = rotation[(r, c)];
        }
    }
}

/// The true velocity at the DVL in the body frame of truth sample `i`.
fn dvl_velocity(state: &InsState, lever_arm: &Vector3<f64>) -> Vector3<f64> {
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
fn update_inputs(
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

/// A stand-in sensor's measurements over a scenario: velocity, R and exact M per DVL
/// epoch, and the output / IMU-error correlation per measured epoch.
#[derive(Debug, Clone)]
pub struct StandInMeasurements {
    /// Velocity per DVL epoch (`None` without a full window).
    pub velocities: Vec<Option<Vector3<f64>>>,
    /// R per DVL epoch.
    pub noise_covariances: Vec<Option<Matrix3<f64>>>,
    /// Exact M per DVL epoch ([`LearnedCrossCovariance`] over the steps an error-state
    /// filter started from the truth at the window's first sample recorded; zero
    /// where no measurement).
    pub cross_covariances: Vec<CrossMatrix>,
    /// Per measured epoch: max over velocity / attitude rows and outputs of
    /// |M_ij| / sqrt(Q_w,ii R_jj) (Q_w: the INS error the window's IMU noise drives).
    pub output_imu_correlation: Vec<f64>,
}

/// The measurements of `kind` on `scenario` (one DVL epoch every `window` IMU samples)
/// with DVL noise `noise`; beam and velocity noise drawn from `seed`.
pub fn stand_in_measurements(
    kind: SensorKind,
    noise: DvlNoise,
    scenario: &Scenario,
    config: &Config,
    seed: u64,
) -> Result<StandInMeasurements> {
    let window = (config.mission.dvl_period_s / scenario.imu_dt).round() as usize;
    let error_model = InsErrorModel::new(filter_imu_spec(&scenario.imu_spec)?);
    let accelerometer_psd = scenario
        .imu_spec
        .accelerometer()
        .white_noise_density
        .powi(2);
    let gyroscope_psd = scenario.imu_spec.gyroscope().white_noise_density.powi(2);
    let geometry = BeamGeometry::beamsnet();
    let lever_arm = Vector3::from(config.dvl.lever_arm_m);
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x3E2E_0001);
    if kind == SensorKind::GyroDeadReckoning {
        let model = GyroStandIn::new(window, scenario.imu_dt, &geometry, noise);
        let psd = [accelerometer_psd, gyroscope_psd];
        return measurements_of(&model, window, scenario, &error_model, |end| {
            gyro_update_inputs(
                &model, scenario, &lever_arm, &geometry, psd, noise, end, &mut rng,
            )
        });
    }
    let model = StandInNetwork::new(
        kind,
        window,
        scenario.imu_dt,
        &geometry,
        noise,
        accelerometer_psd,
    );
    measurements_of(&model, window, scenario, &error_model, |end| {
        let (extra, carry_then) = update_inputs(
            &model, scenario, &lever_arm, &geometry, noise, end, &mut rng,
        )?;
        Some((extra, model.noise_covariance_at(&carry_then)))
    })
}

/// The measurements of `model` over the scenario's DVL epochs; `per_update(end)` gives
/// the per-update inputs and R of the epoch whose window ends at IMU sample `end`.
fn measurements_of<L: LearnedMeasurement<f64, 3>>(
    model: &L,
    window: usize,
    scenario: &Scenario,
    error_model: &InsErrorModel,
    mut per_update: impl FnMut(usize) -> Option<(Vec<DMatrix<f64>>, Matrix3<f64>)>,
) -> Result<StandInMeasurements> {
    let recording = FilterConfig::builder().window_capacity(window).build()?;
    let len = scenario.dvl.len();
    let mut out = StandInMeasurements {
        velocities: vec![None; len],
        noise_covariances: vec![None; len],
        cross_covariances: vec![CrossMatrix::zeros(); len],
        output_imu_correlation: Vec::with_capacity(len),
    };
    let blank: Vec<DMatrix<f64>> = model.input_specs()[1..]
        .iter()
        .map(|s| DMatrix::zeros(s.channels, s.window))
        .collect();
    let mut cross =
        LearnedCrossCovariance::<f64, _, _, 3, IMU_CHANNELS>::new(model, error_model, &blank)?;
    for (k, epoch) in scenario.dvl.iter().enumerate() {
        let end = epoch.imu_index.min(scenario.imu.len());
        let Some((extra, r)) = per_update(end) else {
            continue;
        };
        for (index, values) in extra.iter().enumerate() {
            cross.set_update_input(index, values.as_slice())?;
        }
        // The covariance of the recording filter plays no part in M.
        let mut recorder = ErrorStateKalmanFilter::new(
            *error_model,
            scenario.truth[end - window],
            SMatrix::<f64, ERROR_STATES, ERROR_STATES>::identity(),
        )?
        .with_config(recording.clone());
        for sample in &scenario.imu[end - window..end] {
            recorder.predict(sample, scenario.imu_dt)?;
        }
        let steps = recorder.step_window(window)?;
        let y = cross.measure::<ERROR_STATES>(&steps)?;
        let m = cross
            .transported_cross_covariance(&steps)?
            .ok_or_else(|| PipelineError::Invalid("stand-in network gave no M".into()))?;
        let q_w =
            driven_error_covariance::<f64, _, ERROR_STATES, IMU_CHANNELS>(error_model, &steps)?;
        out.velocities[k] = Some(y);
        out.noise_covariances[k] = Some(r);
        out.cross_covariances[k] = m;
        out.output_imu_correlation
            .push(max_correlation(&m, &q_w, &r));
    }
    Ok(out)
}

/// The configuration of the study's missions for `grade`: `base` with that IMU preset
/// (`base`'s per-sensor overrides, if any, still apply), the mission cut to
/// `duration_s` and the innovation gate off (the two filters of a pair then fuse the
/// same updates).
pub fn cell_config(base: &Config, grade: &str, duration_s: f64) -> Config {
    let mut config = base.clone();
    config.imu.preset = grade.into();
    config.mission.duration_s = duration_s;
    config.filter.gate_probability = 0.0;
    config
}

/// The two filter runs of one mission and one sensor, and the sensor's mean
/// output / IMU-error correlation.
#[derive(Debug, Clone)]
pub struct PairedRuns {
    /// Exact M.
    pub exact: FilterRun,
    /// M neglected.
    pub neglected: FilterRun,
    /// Mean over the measured epochs of the output / IMU-error correlation.
    pub correlation: f64,
}

/// Filter one scenario with `kind`'s measurements, exact M and M neglected.
pub fn paired_runs(
    kind: SensorKind,
    noise: DvlNoise,
    scenario: &Scenario,
    config: &Config,
    seed: u64,
) -> Result<PairedRuns> {
    let sensor = stand_in_measurements(kind, noise, scenario, config, seed)?;
    // The set's R only configures the navigator: every measured epoch has its own R.
    let set = MeasurementSet {
        velocities: sensor.velocities,
        noise_covariance: Matrix3::identity() * MISMATCH_STD.powi(2),
    };
    let neglected = run_filter_per_epoch_noise(
        "m_neglected",
        scenario,
        config,
        &set,
        &sensor.noise_covariances,
        &CrossSource::Zero,
        seed,
    )?;
    // M = 0 exactly (beams only): the exact-M filter is the same filter.
    let exact = if sensor
        .cross_covariances
        .iter()
        .all(|m| m.iter().all(|v| *v == 0.0))
    {
        let mut run = neglected.clone();
        run.id = "m_exact".into();
        run
    } else {
        run_filter_per_epoch_noise(
            "m_exact",
            scenario,
            config,
            &set,
            &sensor.noise_covariances,
            &CrossSource::PerEpoch(sensor.cross_covariances),
            seed,
        )?
    };
    let correlation = if sensor.output_imu_correlation.is_empty() {
        0.0
    } else {
        sensor.output_imu_correlation.iter().sum::<f64>()
            / sensor.output_imu_correlation.len() as f64
    };
    Ok(PairedRuns {
        exact,
        neglected,
        correlation,
    })
}

/// One filter's statistics over the runs of a cell.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct FilterStats {
    /// NEES (15 states) averaged over the runs at each DVL epoch, then over the epochs.
    pub nees_average: f64,
    /// Share of the DVL epochs whose run-averaged NEES lies in the cell's `nees_band`
    /// \[%\].
    pub nees_epochs_in_band_percent: f64,
    /// sqrt(P_vN + P_vE + P_vD) averaged over runs and epochs \[m/s\].
    pub velocity_std_mps: f64,
    /// sqrt(P_ψN + P_ψE + P_ψD) averaged over runs and epochs \[deg\].
    pub attitude_std_deg: f64,
    /// Per run the RMSE over its epochs of |velocity error|, averaged over the runs
    /// \[m/s\].
    pub velocity_rmse_mps: f64,
    /// Mean over runs, epochs and the three axes of e_v,i² / P_v,ii, the velocity
    /// error normalised by its own variance (1 for a consistent filter whatever the
    /// correlations; the velocity part of the NEES, which M acts on first) \[-\].
    pub velocity_normalised_error: f64,
}

fn root_sum(diagonal: &[f64; 15], first: usize) -> f64 {
    (diagonal[first] + diagonal[first + 1] + diagonal[first + 2]).sqrt()
}

impl FilterStats {
    fn of(runs: &[&FilterRun], band: &estim_core::consistency::ChiSquareBand) -> Self {
        let epochs = runs.iter().map(|r| r.nees.len()).min().unwrap_or(0);
        let n = runs.len() as f64;
        let averages: Vec<f64> = (0..epochs)
            .map(|e| runs.iter().map(|r| r.nees[e]).sum::<f64>() / n)
            .collect();
        let finite: Vec<f64> = averages.iter().copied().filter(|a| a.is_finite()).collect();
        let in_band = averages.iter().filter(|a| band.contains(**a)).count();
        let mean_over = |f: &dyn Fn(&FilterRun) -> f64| runs.iter().map(|r| f(r)).sum::<f64>() / n;
        let per_epoch_mean = |run: &FilterRun, g: &dyn Fn(&[f64; 15]) -> f64| {
            run.covariance_diagonal.iter().map(g).sum::<f64>()
                / run.covariance_diagonal.len().max(1) as f64
        };
        Self {
            nees_average: finite.iter().sum::<f64>() / finite.len().max(1) as f64,
            nees_epochs_in_band_percent: 100.0 * in_band as f64 / epochs.max(1) as f64,
            velocity_std_mps: mean_over(&|r| per_epoch_mean(r, &|d| root_sum(d, VEL))),
            attitude_std_deg: mean_over(&|r| per_epoch_mean(r, &|d| root_sum(d, ATT).to_degrees())),
            velocity_rmse_mps: mean_over(&|r| {
                let s: f64 = r.velocity_error.iter().map(|e| e * e).sum();
                (s / r.velocity_error.len().max(1) as f64).sqrt()
            }),
            velocity_normalised_error: mean_over(&|r| {
                let s: f64 = r
                    .axis_error
                    .iter()
                    .zip(&r.covariance_diagonal)
                    .map(|(e, p)| (0..3).map(|i| e[3 + i].powi(2) / p[VEL + i]).sum::<f64>())
                    .sum();
                s / (3 * r.axis_error.len().max(1)) as f64
            }),
        }
    }
}

/// One cell of the sweep.
#[derive(Debug, Clone, Serialize)]
pub struct Cell {
    /// IMU preset.
    pub imu: String,
    /// DVL noise level.
    pub dvl_noise: DvlNoise,
    /// Sensor type.
    pub sensor: SensorKind,
    /// Gain α of the sensor on the integrated accelerometer noise.
    pub imu_gain: f64,
    /// Mean over runs and measured epochs of the largest output / IMU-error
    /// correlation coefficient.
    pub output_imu_correlation: f64,
    /// 95 % band of a run-average of chi-square(15) at one epoch.
    pub nees_band: [f64; 2],
    /// The filter with the exact M.
    pub exact: FilterStats,
    /// The filter with M neglected.
    pub neglected: FilterStats,
    /// (exact - neglected) / neglected of the NEES average.
    pub nees_change: f64,
    /// The same of the velocity std.
    pub velocity_std_change: f64,
    /// The same of the attitude std.
    pub attitude_std_change: f64,
    /// Some |change| > [`FLAG_THRESHOLD`].
    pub m_matters: bool,
}

/// The study's report.
#[derive(Debug, Clone, Serialize)]
pub struct WhereM {
    /// Missions per cell.
    pub runs: usize,
    /// Seed of the first mission (missions use seeds S..S+runs; every cell of a grade
    /// sees the same missions).
    pub first_seed: u64,
    /// Mission duration \[s\].
    pub mission_duration_s: f64,
    /// DVL epochs per mission.
    pub epochs: usize,
    /// The cells, grade-major.
    pub cells: Vec<Cell>,
}

fn relative(exact: f64, neglected: f64) -> f64 {
    (exact - neglected) / neglected
}

/// Run the sweep: for every grade, `runs` missions (seeds `first_seed..`, in parallel),
/// each filtered by every (DVL noise, sensor) pair with exact and neglected M.
/// `grades` and `sensors` restrict the sweep (e.g. one cell in a test); `tick` is
/// called after each mission of each grade.
pub fn where_m(
    base: &Config,
    grades: &[&str],
    noises: &[DvlNoise],
    sensors: &[SensorKind],
    runs: usize,
    first_seed: u64,
    tick: &(dyn Fn() + Sync),
) -> Result<WhereM> {
    if runs == 0 {
        return Err(PipelineError::Invalid("runs must be at least 1".into()));
    }
    let band = chi_square_band(ERROR_STATES, runs, 0.95)?;
    let pairs: Vec<(DvlNoise, SensorKind)> = noises
        .iter()
        .flat_map(|n| sensors.iter().map(move |s| (*n, *s)))
        .collect();
    let mut cells = Vec::new();
    let mut epochs = 0;
    for grade in grades {
        let config = cell_config(base, grade, base.mission.duration_s);
        // runs x pairs
        let missions: Vec<Vec<PairedRuns>> = (0..runs)
            .into_par_iter()
            .map(|i| {
                let seed = first_seed + i as u64;
                let scenario = Scenario::simulated(&config, seed)?;
                let out = pairs
                    .iter()
                    .map(|(noise, kind)| {
                        paired_runs(*kind, *noise, &scenario, &config, seed).map_err(|e| {
                            PipelineError::Invalid(format!(
                                "{grade}, {noise:?} DVL noise, {kind:?}, seed {seed}: {e}"
                            ))
                        })
                    })
                    .collect::<Result<Vec<_>>>();
                tick();
                out
            })
            .collect::<Result<_>>()?;
        for (p, (noise, kind)) in pairs.iter().enumerate() {
            let exact_runs: Vec<&FilterRun> = missions.iter().map(|m| &m[p].exact).collect();
            let neglected_runs: Vec<&FilterRun> =
                missions.iter().map(|m| &m[p].neglected).collect();
            epochs = exact_runs.first().map_or(0, |r| r.nees.len());
            let exact = FilterStats::of(&exact_runs, &band);
            let neglected = FilterStats::of(&neglected_runs, &band);
            let nees_change = relative(exact.nees_average, neglected.nees_average);
            let velocity_std_change = relative(exact.velocity_std_mps, neglected.velocity_std_mps);
            let attitude_std_change = relative(exact.attitude_std_deg, neglected.attitude_std_deg);
            cells.push(Cell {
                imu: (*grade).into(),
                dvl_noise: *noise,
                sensor: *kind,
                imu_gain: kind.imu_gain(),
                output_imu_correlation: missions.iter().map(|m| m[p].correlation).sum::<f64>()
                    / runs as f64,
                nees_band: [band.lower, band.upper],
                exact,
                neglected,
                nees_change,
                velocity_std_change,
                attitude_std_change,
                m_matters: [nees_change, velocity_std_change, attitude_std_change]
                    .iter()
                    .any(|c| c.abs() > FLAG_THRESHOLD),
            });
        }
    }
    Ok(WhereM {
        runs,
        first_seed,
        mission_duration_s: base.mission.duration_s,
        epochs,
        cells,
    })
}

/// The markdown table of the report.
pub fn markdown(report: &WhereM) -> String {
    let mut s = String::from(
        "| IMU | DVL noise | sensor | corr. | NEES exact M | NEES M neglected | NEES change | \
         vel. e²/P exact / neglected | vel. std exact [m/s] | vel. std change | \
         att. std exact [deg] | att. std change | \\|change\\| > 10 % |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let pct = |c: f64| format!("{:+.1} %", 100.0 * c);
    for c in &report.cells {
        s.push_str(&format!(
            "| {} | {} | {} | {:.2} | {:.2} ({:.0} % in band) | {:.2} ({:.0} % in band) | {} | \
             {:.2} / {:.2} | {:.5} | {} | {:.4} | {} | {} |\n",
            c.imu,
            c.dvl_noise.label(),
            c.sensor.label(),
            c.output_imu_correlation,
            c.exact.nees_average,
            c.exact.nees_epochs_in_band_percent,
            c.neglected.nees_average,
            c.neglected.nees_epochs_in_band_percent,
            pct(c.nees_change),
            c.exact.velocity_normalised_error,
            c.neglected.velocity_normalised_error,
            c.exact.velocity_std_mps,
            pct(c.velocity_std_change),
            c.exact.attitude_std_deg,
            pct(c.attitude_std_change),
            if c.m_matters { "yes" } else { "no" },
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use estim_ins::ImuSpec;

    /// A short mission of `grade` (5 DVL epochs).
    fn short(grade: &str, seed: u64) -> (Config, Scenario) {
        let config = cell_config(&Config::default(), grade, 5.0);
        let scenario = Scenario::simulated(&config, seed).expect("simulated mission");
        (config, scenario)
    }

    /// The generic M of the dead-reckoning stand-ins against two references coded
    /// apart from it: the forward recursion S <- Phi_j S + G_j,acc q dt α C_{b_k <- b_j}'
    /// over the recorded steps (Simon 2006 sec. 7.1 carried over the window; the
    /// oracle's form), to rounding; and the closed form of its velocity block,
    /// -α q T C_b^n(t_k) (Phi_vv = I over 1 s up to the Earth-rate terms), to 1e-3.
    #[test]
    fn dead_reckoning_m_equals_the_closed_form() {
        let (config, scenario) = short("akit_observed", 11);
        let error_model = InsErrorModel::new(filter_imu_spec(&scenario.imu_spec).unwrap());
        let q = scenario
            .imu_spec
            .accelerometer()
            .white_noise_density
            .powi(2);
        let dt = scenario.imu_dt;
        let window = 100;
        for kind in [SensorKind::DeadReckoning, SensorKind::HalfDeadReckoning] {
            let alpha = kind.imu_gain();
            let sensor =
                stand_in_measurements(kind, DvlNoise::Beam, &scenario, &config, 3).unwrap();
            for (k, epoch) in scenario.dvl.iter().enumerate() {
                let end = epoch.imu_index;
                let m = sensor.cross_covariances[k];
                let recording = FilterConfig::builder()
                    .window_capacity(window)
                    .build()
                    .unwrap();
                let mut recorder = ErrorStateKalmanFilter::new(
                    error_model,
                    scenario.truth[end - window],
                    SMatrix::<f64, ERROR_STATES, ERROR_STATES>::identity(),
                )
                .unwrap()
                .with_config(recording);
                for sample in &scenario.imu[end - window..end] {
                    recorder.predict(sample, dt).unwrap();
                }
                let c_nb_k = scenario.truth[end]
                    .attitude
                    .inverse()
                    .to_rotation_matrix()
                    .into_inner();
                let mut s = CrossMatrix::zeros();
                for (j, step) in recorder.step_window(window).unwrap().iter().enumerate() {
                    let c_bn_nominal = step.state.attitude.to_rotation_matrix().into_inner();
                    let c_bn_truth = scenario.truth[end - window + j]
                        .attitude
                        .to_rotation_matrix()
                        .into_inner();
                    let mut g = CrossMatrix::zeros();
                    g.fixed_view_mut::<3, 3>(VEL, 0).copy_from(
                        &(-c_bn_nominal * (c_nb_k * c_bn_truth).transpose() * (q * dt * alpha)),
                    );
                    s = step.transition * s + g;
                }
                let scale = s.abs().max();
                assert!(scale > 0.0);
                assert!(
                    (m - s).abs().max() <= 1e-12 * scale,
                    "{kind:?} epoch {k}: generic {m} vs recursion {s}"
                );
                let closed = -c_nb_k.transpose() * (alpha * q * dt * window as f64);
                let velocity_block = m.fixed_view::<3, 3>(VEL, 0).into_owned();
                assert!(
                    (velocity_block - closed).abs().max() <= 1e-3 * closed.abs().max(),
                    "{kind:?} epoch {k}: {velocity_block} vs {closed}"
                );
            }
        }
    }

    /// The beams-only stand-in reads the IMU window and ignores it: its M is zero to the
    /// bit, at every epoch, for every grade's window.
    #[test]
    fn beams_only_m_is_zero() {
        for grade in GRADES {
            let (config, scenario) = short(grade, 5);
            let sensor = stand_in_measurements(
                SensorKind::BeamsOnly,
                DvlNoise::Mismatch,
                &scenario,
                &config,
                1,
            )
            .unwrap();
            assert_eq!(
                sensor.velocities.iter().flatten().count(),
                scenario.dvl.len()
            );
            assert!(sensor
                .cross_covariances
                .iter()
                .all(|m| m.iter().all(|v| *v == 0.0)));
        }
    }

    /// The stand-ins' errors against the truth at the DVL have the R they report: the
    /// mean of e' R⁻¹ e over 3 missions x 60 epochs is that of chi-square(3), 3 with
    /// standard error sqrt(6 / 180) = 0.18; asserted within 0.75 (4 standard errors).
    /// The IMU noise is the A-KIT level with the accelerometer noise x 3, so that the
    /// carried IMU noise dominates R where α > 0.
    /// The A-KIT IMU level with the accelerometer white noise x 3.
    fn noisy_accelerometer(mut config: Config) -> Config {
        let acc = *ImuSpec::akit_observed().accelerometer();
        config.imu.accelerometer = Some(super::super::config::SensorSection {
            white_noise_density: 3.0 * acc.white_noise_density,
            bias_instability: acc.bias_instability,
            bias_time_constant: acc.bias_time_constant,
            turn_on_bias: acc.turn_on_bias,
            scale_factor: acc.scale_factor,
        });
        config
    }

    #[test]
    fn stand_in_errors_have_the_reported_covariance() {
        for kind in SensorKind::ALL {
            for noise in DvlNoise::ALL {
                let mut sum = 0.0;
                let mut count = 0;
                for seed in 0..3 {
                    let config =
                        noisy_accelerometer(cell_config(&Config::default(), "akit_observed", 60.0));
                    let scenario = Scenario::simulated(&config, 40 + seed).unwrap();
                    let sensor =
                        stand_in_measurements(kind, noise, &scenario, &config, seed).unwrap();
                    for (k, epoch) in scenario.dvl.iter().enumerate() {
                        let (Some(y), Some(r)) =
                            (sensor.velocities[k], sensor.noise_covariances[k])
                        else {
                            continue;
                        };
                        let e = y - epoch.reference_velocity;
                        sum += (e.transpose() * r.try_inverse().unwrap() * e)[0];
                        count += 1;
                    }
                }
                let mean = sum / count as f64;
                assert_eq!(count, 180);
                assert!(
                    (mean - 3.0).abs() < 0.75,
                    "{kind:?} {noise:?}: mean e'R^-1 e {mean}"
                );
            }
        }
    }

    /// Where M matters most (the A-KIT IMU with the accelerometer noise x 3, beam-level
    /// DVL noise, the dead-reckoning stand-in: correlation 0.99), 100 missions of 30 s
    /// (seeds 500-599): with the exact M the time mean of the run-averaged NEES lies in
    /// the 95 % band of one epoch's run-average (13.95-16.09; a consistent filter's
    /// time mean varies less than one epoch's) and at least 70 % of the epochs have
    /// their average in it (95 % expected; successive epochs are correlated); with M
    /// neglected the time mean is above the band. Other seed blocks (set
    /// `WHERE_M_FIRST_SEED`, and `WHERE_M_RUNS` / `WHERE_M_DURATION` to vary the cell)
    /// measured before committing: first seeds 500 (the default), 0, 100, 200, 300,
    /// 400 give exact 14.60, 14.95, 15.57, 14.62, 15.25, 15.37 (100 % of epochs in
    /// band) and neglected 16.91, 17.24, 17.84, 16.80, 17.51, 17.63. With 40 missions
    /// of 60 s the exact filter's time mean spread wider than that band (it left it in
    /// 2 of 5 blocks): the unobservable states keep each run's NEES level, so the time
    /// mean averages over runs more than over epochs.
    #[test]
    fn exact_m_is_consistent_and_neglected_m_is_not_where_m_matters() {
        let env = |name: &str, default: u64| {
            std::env::var(name)
                .ok()
                .and_then(|s| s.parse().ok())
                .unwrap_or(default)
        };
        let first_seed = env("WHERE_M_FIRST_SEED", 500);
        let runs = env("WHERE_M_RUNS", 100) as usize;
        let mut base = noisy_accelerometer(Config::default());
        base.mission.duration_s = env("WHERE_M_DURATION", 30) as f64;
        let report = where_m(
            &base,
            &["akit_observed"],
            &[DvlNoise::Beam],
            &[SensorKind::DeadReckoning],
            runs,
            first_seed,
            &|| {},
        )
        .unwrap();
        let cell = &report.cells[0];
        let [lower, upper] = cell.nees_band;
        eprintln!(
            "seeds {first_seed}..: exact {:.2} ({:.0} % in band), neglected {:.2}, band {lower:.2}-{upper:.2}, corr. {:.2}",
            cell.exact.nees_average,
            cell.exact.nees_epochs_in_band_percent,
            cell.neglected.nees_average,
            cell.output_imu_correlation
        );
        assert!(
            (lower..=upper).contains(&cell.exact.nees_average)
                && cell.exact.nees_epochs_in_band_percent >= 70.0,
            "exact M: {:?}",
            cell.exact
        );
        assert!(
            cell.neglected.nees_average > upper,
            "M neglected: {:?}",
            cell.neglected
        );
        // The sign: the exact M raises the velocity std.
        assert!(cell.velocity_std_change > 0.0, "{cell:?}");
    }

    /// The gyro stand-in (mismatch-level DVL noise) on one epoch of a short consumer-MEMS
    /// mission: its inputs and the
    /// recorded window of an error-state filter started from the truth.
    fn gyro_epoch() -> (GyroStandIn, Vec<DMatrix<f64>>, [f64; 2], Scenario, usize) {
        let (config, scenario) = short("consumer_mems", 21);
        let geometry = BeamGeometry::beamsnet();
        let model = GyroStandIn::new(100, scenario.imu_dt, &geometry, DvlNoise::Mismatch);
        let psd = [
            scenario
                .imu_spec
                .accelerometer()
                .white_noise_density
                .powi(2),
            scenario.imu_spec.gyroscope().white_noise_density.powi(2),
        ];
        let end = scenario.dvl[2].imu_index;
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let lever_arm = Vector3::from(config.dvl.lever_arm_m);
        let (extra, _) = gyro_update_inputs(
            &model,
            &scenario,
            &lever_arm,
            &geometry,
            psd,
            DvlNoise::Mismatch,
            end,
            &mut rng,
        )
        .unwrap();
        let mut imu = DMatrix::zeros(IMU_CHANNELS, 100);
        for (column, sample) in scenario.imu[end - 100..end].iter().enumerate() {
            for r in 0..3 {
                imu[(r, column)] = sample.specific_force[r];
                imu[(3 + r, column)] = sample.angular_rate[r];
            }
        }
        let inputs = std::iter::once(imu).chain(extra).collect();
        (model, inputs, psd, scenario, end)
    }

    /// One unit direction (stream `stream`, element (row, column)) in the model's shapes.
    fn unit(
        inputs: &[DMatrix<f64>],
        stream: usize,
        row: usize,
        column: usize,
    ) -> Vec<DMatrix<f64>> {
        let mut d: Vec<DMatrix<f64>> = inputs
            .iter()
            .map(|m| DMatrix::zeros(m.nrows(), m.ncols()))
            .collect();
        d[stream][(row, column)] = 1.0;
        d
    }

    /// The gyro stand-in's JVPs against central finite differences of its `measure`
    /// (every input stream, a sample of elements; step 1e-4 of max(|element|, 1),
    /// agreement to 1e-6 relative: the model is a polynomial, linear in all but the
    /// gyroscope samples and the attitude, of low curvature at that step), and its closed-form R against the R assembled from JVP columns
    /// (G σ_v² G' + J_b σ_b² J_b' + Σ_j J_j Σ_j J_j', to 1e-9 relative).
    #[test]
    fn gyro_stand_in_jvps_and_r_match_independent_references() {
        let (model, inputs, psd, _, _) = gyro_epoch();
        let elements = [
            (0, 0, 0),
            (0, 2, 50),
            (0, 3, 0),
            (0, 4, 37),
            (0, 5, 99),
            (1, 1, 0),
            (2, 4, 0),
            (3, 2, 0),
            (4, 0, 0),
        ];
        for (stream, row, column) in elements {
            let d = unit(&inputs, stream, row, column);
            let mut product = [Vector3::zeros()];
            model.sensitivity(&inputs, &d, &mut product).unwrap();
            let h = 1e-4 * inputs[stream][(row, column)].abs().max(1.0);
            let shifted = |sign: f64| {
                let mut x = inputs.clone();
                x[stream][(row, column)] += sign * h;
                model.measure(&x).unwrap()
            };
            let fd = (shifted(1.0) - shifted(-1.0)) / (2.0 * h);
            assert!(
                (product[0] - fd).norm() <= 1e-6 * fd.norm().max(1e-9),
                "stream {stream} ({row}, {column}): jvp {} fd {}",
                product[0],
                fd
            );
        }
        // R from JVP columns.
        let dt = 0.01;
        let column_of = |stream, row, column| {
            let mut p = [Vector3::zeros()];
            model
                .sensitivity(&inputs, &unit(&inputs, stream, row, column), &mut p)
                .unwrap();
            p[0]
        };
        let j_beams = Matrix3x4::from_columns(&[
            column_of(1, 0, 0),
            column_of(1, 1, 0),
            column_of(1, 2, 0),
            column_of(1, 3, 0),
        ]);
        let g = j_beams * BeamGeometry::beamsnet().matrix();
        let mut reference = g * g.transpose() * MISMATCH_STD.powi(2)
            + j_beams * j_beams.transpose() * BEAM_NOISE_STD.powi(2);
        for j in 0..100 {
            for c in 0..6 {
                let col = column_of(0, c, j);
                let variance = if c < 3 { psd[0] } else { psd[1] } / dt;
                reference += col * col.transpose() * variance;
            }
        }
        let r = model.noise_covariance_at(&inputs, psd).unwrap();
        assert!(
            (r - reference).abs().max() <= 1e-9 * reference.abs().max(),
            "closed form {r} vs JVP columns {reference}"
        );
    }

    /// The generic (adjoint) M of the gyro stand-in against the forward recursion
    /// S <- Phi_j S + A_j Σ_j J_j' with J_j from per-sample JVPs, over the recorded
    /// steps, to 1e-9 relative; the attitude rows are non-zero (the gyroscope noise is
    /// shared).
    #[test]
    fn gyro_stand_in_m_equals_the_forward_recursion() {
        let (model, inputs, _, scenario, end) = gyro_epoch();
        let error_model = InsErrorModel::new(filter_imu_spec(&scenario.imu_spec).unwrap());
        let recording = FilterConfig::builder()
            .window_capacity(100)
            .build()
            .unwrap();
        let mut recorder = ErrorStateKalmanFilter::new(
            error_model,
            scenario.truth[end - 100],
            SMatrix::<f64, ERROR_STATES, ERROR_STATES>::identity(),
        )
        .unwrap()
        .with_config(recording);
        for sample in &scenario.imu[end - 100..end] {
            recorder.predict(sample, scenario.imu_dt).unwrap();
        }
        let steps = recorder.step_window(100).unwrap();
        let cross = LearnedCrossCovariance::<f64, _, _, 3, IMU_CHANNELS>::new(
            &model,
            &error_model,
            &inputs[1..],
        )
        .unwrap();
        let m = cross.transported_cross_covariance(&steps).unwrap().unwrap();
        let mut s = CrossMatrix::zeros();
        for step in steps.iter() {
            let dt = step.dt.unwrap();
            let mut jt = SMatrix::<f64, IMU_CHANNELS, 3>::zeros();
            for c in 0..IMU_CHANNELS {
                let mut p = [Vector3::zeros()];
                model
                    .sensitivity(&inputs, &unit(&inputs, 0, c, step.position), &mut p)
                    .unwrap();
                jt.set_row(c, &p[0].transpose());
            }
            let a = estim_learned::InputNoise::input_noise_jacobian(
                &error_model,
                step.state,
                step.input,
                dt,
            );
            let sigma = estim_learned::InputNoise::<f64, ERROR_STATES, IMU_CHANNELS>::input_noise_covariance(
                &error_model,
                dt,
            );
            s = step.transition * s + a * sigma * jt;
        }
        assert!(
            (m - s).abs().max() <= 1e-9 * s.abs().max(),
            "adjoint {m} vs forward {s}"
        );
        assert!(m.fixed_view::<3, 3>(ATT, 0).abs().max() > 0.0);
    }
}
