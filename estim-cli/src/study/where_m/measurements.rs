//! A stand-in sensor's measurements over a scenario, with the exact M of each update.

use estim_core::nalgebra::{DMatrix, Matrix3, SMatrix, Vector3};
use estim_core::WindowedCrossCovariance;
use estim_core::{ErrorStateKalmanFilter, FilterConfig, LearnedMeasurement};
use estim_dvl::BeamGeometry;
use estim_ins::{InsErrorModel, ERROR_STATES};
use estim_learned::{driven_error_covariance, LearnedCrossCovariance, IMU_CHANNELS};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::gyro_stand_in::{gyro_update_inputs, GyroStandIn};
use super::stand_in::{update_inputs, StandInNetwork};
use super::{DvlNoise, SensorKind};
use crate::study::run::filter_imu_spec;
use crate::study::{max_correlation, Config, CrossMatrix, PipelineError, Result, Scenario};

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
        let m = cross.transported_cross_covariance(&steps)?.ok_or(
            PipelineError::NoCrossCovariance {
                network: "stand-in network",
            },
        )?;
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
