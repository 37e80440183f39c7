//! A simulated INS/DVL mission with known noise for `estim::navigator::tune`: the IMU
//! corrupted with a known spec (no scale factors, which the 15-state filter does not
//! model), DVL velocities h(truth) + v at 1 Hz with v ~ N(0, s_b (A'A)^-1 + s_m I).
//! Shared by tests/navigate_tune.rs and benches/tune.rs.
#![allow(dead_code)]

use estim::dvl::{BeamGeometry, DvlVelocityModel};
use estim::ins::{ErrorMatrix, ImuSample, ImuSpec, InsState, Mission, MissionConfig};
use estim::navigator::tune::{TuneModel, TuneParameters, TuneTrajectory};
use estim_core::nalgebra::{SVector, Vector3};
use estim_core::MeasurementModel;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// The mission's data.
pub struct TuneMission {
    pub imu: Vec<ImuSample>,
    pub imu_period: f64,
    pub dvl: Vec<(f64, Vector3<f64>)>,
    pub initial: InsState,
    pub covariance: ErrorMatrix,
    pub model: TuneModel,
    /// The parameters the data were drawn with (rho = 0: independent DVL noise).
    pub truth: TuneParameters,
}

impl TuneMission {
    pub fn trajectory(&self) -> TuneTrajectory<'_> {
        TuneTrajectory {
            imu: &self.imu,
            imu_period: self.imu_period,
            dvl: &self.dvl,
            initial: self.initial,
            covariance: self.covariance,
        }
    }
}

/// A mission of `duration` s (seeded: the trajectory, the IMU errors, the DVL noise).
pub fn mission(duration: f64, seed: u64) -> TuneMission {
    let mut spec = ImuSpec::akit_observed();
    let (mut acc, mut gyro) = (*spec.accelerometer(), *spec.gyroscope());
    acc.scale_factor = 0.0;
    gyro.scale_factor = 0.0;
    spec = ImuSpec::builder()
        .accelerometer(acc)
        .gyroscope(gyro)
        .build()
        .expect("valid spec");
    let config = MissionConfig::builder()
        .duration(duration)
        .imu_spec(spec)
        .build()
        .expect("valid mission");
    let mission = Mission::generate(&config, seed).expect("mission");
    let geometry = BeamGeometry::beamsnet();
    let pinv = geometry.pseudo_inverse();
    let beam = pinv * pinv.transpose();
    let (sb, sm) = (0.01f64.powi(2), 0.005f64.powi(2));
    let r = beam * sb + estim_core::nalgebra::Matrix3::identity() * sm;
    let dvl_model = DvlVelocityModel::builder()
        .lever_arm(Vector3::new(1.5, 0.0, 0.3))
        .noise_covariance(r)
        .build()
        .expect("valid DVL model");
    let chol = r.cholesky().expect("R positive definite").l();
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7e57);
    let per_second = (1.0 / mission.imu_dt).round() as usize;
    let dvl = (per_second..mission.imu.len())
        .step_by(per_second)
        .map(|k| {
            let n = Vector3::from_fn(|_, _| StandardNormal.sample(&mut rng));
            let clean = dvl_model.predict(&mission.truth[k]).expect("finite truth");
            (mission.imu[k].time, clean + chol * n)
        })
        .collect();
    let (a, g) = (spec.accelerometer(), spec.gyroscope());
    let acc_bias = (a.turn_on_bias.powi(2) + a.bias_instability.powi(2)).sqrt();
    let gyro_bias = (g.turn_on_bias.powi(2) + g.bias_instability.powi(2)).sqrt();
    let std = [
        1.0, 1.0, 1.0, 0.05, 0.05, 0.05, 1e-3, 1e-3, 5e-3, acc_bias, acc_bias, acc_bias, gyro_bias,
        gyro_bias, gyro_bias,
    ];
    let covariance = ErrorMatrix::from_diagonal(&SVector::from_fn(|i, _| std[i] * std[i]));
    let mut initial = mission.truth[0];
    initial.acc_bias = Vector3::zeros();
    initial.gyro_bias = Vector3::zeros();
    TuneMission {
        imu: mission.imu,
        imu_period: mission.imu_dt,
        dvl,
        initial,
        covariance,
        model: TuneModel {
            sensor_spec: spec,
            dvl: dvl_model,
            geometry,
        },
        truth: TuneParameters::from([
            a.white_noise_density.powi(2),
            g.white_noise_density.powi(2),
            sb,
            sm,
            0.0,
        ]),
    }
}
