//! An oracle "learned" sensor whose error is an exact linear function of the IMU noise
//! the INS integrates, so its true cross-covariance M is known in closed form.
//!
//! It measures the velocity at the DVL with error
//!
//! ```text
//! e_k = alpha C_n^b(t_k) sum_{i in window} C_b^n(t_i) n_a,i dt  +  u_k,   u_k ~ N(0, sigma^2 I)
//! ```
//!
//! where n_a,i is the accelerometer white noise of IMU sample i (the window is the
//! samples since the previous update). This is what a network that integrates the
//! accelerometer does to first order. The INS error state receives w_i = G_i n_a,i dt
//! (G_i = -C_b^n(t_i) on the velocity rows) and propagates with Phi, so
//!
//! ```text
//! M_k = Cov(sum_i Phi(k, i+1) w_i, e_k) = sum_i Phi(k, i+1) G_i,acc (q dt) alpha (C_n^b(t_k) C_b^n(t_i))'
//! R   = (alpha^2 q T + sigma^2) I          (q = accelerometer white-noise PSD, T = window length)
//! ```
//!
//! computed with the forward recursion S <- Phi_i S + G_i,acc X_i. Monte Carlo runs
//! fed this M test whether the filter with the correlated update is consistent.

use estim_core::nalgebra::{Matrix3, SMatrix, Vector3};
use estim_core::ProcessModel;
use estim_dvl::dvl_frame_velocity;
use estim_ins::{InsErrorModel, ERROR_STATES, VEL};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use super::run::filter_imu_spec;
use super::{Config, CrossMatrix, MeasurementSet, Result, Scenario};

/// The oracle sensor's parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OracleSensor {
    /// Gain on the integrated accelerometer noise.
    pub alpha: f64,
    /// Std of the independent part of the error \[m/s\].
    pub independent_std: f64,
}

impl Default for OracleSensor {
    fn default() -> Self {
        Self {
            alpha: 1.0,
            independent_std: 0.002,
        }
    }
}

/// Measurements, R and the true M_k per DVL epoch of the oracle sensor on `scenario`.
pub fn oracle_measurements(
    scenario: &Scenario,
    config: &Config,
    sensor: OracleSensor,
    seed: u64,
) -> Result<(MeasurementSet, Vec<CrossMatrix>)> {
    let model = InsErrorModel::new(filter_imu_spec(&scenario.imu_spec)?);
    let q = scenario
        .imu_spec
        .accelerometer()
        .white_noise_density
        .powi(2);
    let dt = scenario.imu_dt;
    let lever_arm = Vector3::from(config.dvl.lever_arm_m);
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0AC1E);
    let mut velocities = Vec::with_capacity(scenario.dvl.len());
    let mut cross = Vec::with_capacity(scenario.dvl.len());
    let mut window_start = 0;
    let mut window_len = 0.0;
    for epoch in &scenario.dvl {
        let k = epoch.imu_index.min(scenario.imu.len());
        let truth_k = &scenario.truth[k];
        let c_nb_k = truth_k.attitude.inverse().to_rotation_matrix().into_inner();
        let mut integrated = Vector3::zeros();
        let mut s = CrossMatrix::zeros();
        for i in window_start..k {
            let state = &scenario.truth[i];
            let c_bn_i = state.attitude.to_rotation_matrix().into_inner();
            // White noise of sample i: measured - clean - bias (scale factors are off
            // in the default configuration; with them on this is first order).
            let noise = scenario.imu[i].specific_force
                - scenario.clean_imu[i].specific_force
                - state.acc_bias;
            integrated += c_bn_i * noise * dt;
            let phi = model.transition(state, &scenario.imu[i], dt)?;
            let g_acc: SMatrix<f64, ERROR_STATES, 3> = {
                let mut g = SMatrix::<f64, ERROR_STATES, 3>::zeros();
                g.fixed_view_mut::<3, 3>(VEL, 0).copy_from(&(-c_bn_i));
                g
            };
            let x: Matrix3<f64> = (c_nb_k * c_bn_i).transpose() * (q * dt * sensor.alpha);
            s = phi * s + g_acc * x;
        }
        window_len = ((k - window_start) as f64 * dt).max(window_len);
        window_start = k;
        let body_velocity = truth_k.attitude.inverse() * truth_k.velocity_ned;
        let truth_velocity = dvl_frame_velocity(
            &body_velocity,
            &truth_k.angular_rate,
            &lever_arm,
            0.0,
            &Vector3::zeros(),
        );
        let independent = Vector3::from_fn(|_, _| {
            let n: f64 = StandardNormal.sample(&mut rng);
            n * sensor.independent_std
        });
        // The oracle shares the DVL's outages (an epoch with no beam gives no measurement).
        let available = epoch.beams.iter().any(|b| b.is_finite());
        velocities.push(
            available.then(|| truth_velocity + sensor.alpha * c_nb_k * integrated + independent),
        );
        cross.push(s);
    }
    let r = Matrix3::identity()
        * (sensor.alpha.powi(2) * q * window_len + sensor.independent_std.powi(2));
    Ok((
        MeasurementSet {
            velocities,
            noise_covariance: r,
        },
        cross,
    ))
}
