//! BeamsNet as the pipeline's learned sensor: network velocities per DVL epoch and,
//! optionally, M_k from the network's sensitivity.

use estim_core::nalgebra::{Vector3, Vector4};
use estim_core::{ErrorStateKalmanFilter, FilterConfig, WindowedCrossCovariance};
use estim_dvl::BeamGeometry;
use estim_ins::{InsErrorModel, ERROR_STATES};
use estim_learned::{
    driven_error_covariance, BeamsNet, BeamsNetInput, NetworkSensitivity, BEAMSNET_WINDOW,
    IMU_CHANNELS,
};

use super::run::filter_imu_spec;
use super::{LearnedInputs, Result, Scenario};

/// The committed BeamsNet for each IMU source, with M from the network's sensitivity:
/// on a recorded IMU the network trained on recorded windows
/// ([`estim::models::beamsnet_recorded`]), on a synthesized one the network trained
/// on synthesized windows ([`estim::models::beamsnet`]). What `estim reproduce`, `estim
/// report` and `estim montecarlo` use without `--model`.
///
/// # Errors
/// The loaders' errors (none for the committed files; tested).
pub fn committed_beamsnet(config: &super::Config) -> Result<Box<super::LearnedSource>> {
    let synthesized = estim::models::beamsnet()?;
    let recorded = estim::models::beamsnet_recorded()?;
    let protocol = if config.dvl.protocol == "v2" {
        estim_dvl::BeamsNetProtocol::v2()
    } else {
        estim_dvl::BeamsNetProtocol::v1()
    };
    let geometry = protocol.geometry().clone();
    Ok(Box::new(move |scenario: &Scenario| {
        let net = match scenario.imu_source {
            super::ImuSource::Recorded => &recorded,
            super::ImuSource::Synthesized => &synthesized,
        };
        beamsnet_inputs(net, scenario, &geometry, true)
    }))
}

/// Beams for the network: a missing beam is replaced by its value predicted from the
/// 3-beam least-squares velocity (A v); fewer than 3 beams give `None`.
///
/// BeamsNet was trained on 4 beams; this fallback keeps the network usable through
/// single-beam dropouts (the LS path uses the 3-beam solution directly).
pub fn complete_beams(geometry: &BeamGeometry, beams: &Vector4<f64>) -> Option<Vector4<f64>> {
    if beams.iter().all(|b| b.is_finite()) {
        return Some(*beams);
    }
    let velocity = geometry.solve_nan(beams).velocity()?;
    let predicted = geometry.beams(&velocity);
    Some(Vector4::from_fn(|i, _| {
        if beams[i].is_finite() {
            beams[i]
        } else {
            predicted[i]
        }
    }))
}

/// The network's velocity per DVL epoch (one batched inference) and, if
/// `with_sensitivity`, M_k per epoch from [`NetworkSensitivity`].
///
/// The window of epoch k is the [`BEAMSNET_WINDOW`] IMU samples before the update (the
/// samples integrated since the previous update at 1 Hz). M_k is linearised along a
/// nominal started from the scenario's truth at the window's first sample and
/// integrated over the window by an error-state filter that records its steps
/// (`window_capacity`); [`NetworkSensitivity`] reads that recorded window (the
/// filter's own Phi, no transition recomputed here). The fusion filter's nominal
/// differs by its error, a second-order effect on M. Epochs with less than a full
/// window or fewer than 3 beams get no measurement.
pub fn beamsnet_inputs(
    net: &BeamsNet,
    scenario: &Scenario,
    geometry: &BeamGeometry,
    with_sensitivity: bool,
) -> Result<LearnedInputs> {
    let n = BEAMSNET_WINDOW;
    let error_model =
        InsErrorModel::new(filter_imu_spec(&scenario.imu_spec).unwrap_or(scenario.imu_spec));
    let recording = FilterConfig::builder().window_capacity(n).build()?;
    let mut inputs = Vec::new();
    let mut slots = Vec::with_capacity(scenario.dvl.len());
    let mut cross = Vec::with_capacity(scenario.dvl.len());
    let mut correlation = Vec::new();
    let r = net.noise_covariance();
    for epoch in &scenario.dvl {
        let end = epoch.imu_index.min(scenario.imu.len());
        let beams = if end >= n {
            complete_beams(geometry, &epoch.beams)
        } else {
            None
        };
        let Some(beams) = beams else {
            slots.push(None);
            cross.push(super::CrossMatrix::zeros());
            continue;
        };
        let window = &scenario.imu[end - n..end];
        let force: Vec<Vector3<f64>> = window.iter().map(|s| s.specific_force).collect();
        let rate: Vec<Vector3<f64>> = window.iter().map(|s| s.angular_rate).collect();
        slots.push(Some(inputs.len()));
        inputs.push(BeamsNetInput::from_samples(&force, &rate, beams));
        if with_sensitivity {
            // The covariance of the recording filter plays no part in M.
            let mut recorder = ErrorStateKalmanFilter::new(
                error_model,
                scenario.truth[end - n],
                estim_core::nalgebra::SMatrix::<f64, ERROR_STATES, ERROR_STATES>::identity(),
            )?
            .with_config(recording.clone());
            for sample in window {
                recorder.predict(sample, scenario.imu_dt)?;
            }
            let steps = recorder.step_window(n)?;
            let m = NetworkSensitivity::new(net, &error_model, beams)?
                .transported_cross_covariance(&steps)?
                .ok_or(super::PipelineError::NoCrossCovariance {
                    network: "network sensitivity",
                })?;
            let q_w = driven_error_covariance::<f64, _, ERROR_STATES, IMU_CHANNELS>(
                &error_model,
                &steps,
            )?;
            correlation.push(super::max_correlation(&m, &q_w, &r));
            cross.push(m);
        }
    }
    let outputs = if inputs.is_empty() {
        Vec::new()
    } else {
        net.velocities(&inputs)?
    };
    let velocities = slots
        .iter()
        .map(|s| s.and_then(|i| outputs.get(i).copied()))
        .collect();
    Ok(LearnedInputs {
        velocities,
        noise_covariance: r,
        sensitivity: with_sensitivity.then_some(cross),
        output_imu_correlation: with_sensitivity.then_some(correlation),
    })
}
