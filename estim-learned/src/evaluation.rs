//! LS vs BeamsNet on a set of synthesized examples (the paper's Tables I and II).

use estim_dvl::BeamGeometry;
use nalgebra::Vector3;
use serde::Serialize;

use crate::beamsnet::BeamsNet;
use crate::dataset::BeamsNetSample;
use crate::metrics::{speed_metrics, Metrics};
use crate::Result;

/// Predictions and metrics of least squares and BeamsNet on the same examples.
#[derive(Debug, Clone, Serialize)]
pub struct Evaluation {
    /// Metrics of the least-squares velocity of the beams.
    pub ls: Metrics,
    /// Metrics of BeamsNet.
    pub beamsnet: Metrics,
    /// Reference (target) velocities.
    #[serde(skip)]
    pub reference: Vec<Vector3<f64>>,
    /// Least-squares velocities.
    #[serde(skip)]
    pub ls_velocity: Vec<Vector3<f64>>,
    /// BeamsNet velocities.
    #[serde(skip)]
    pub beamsnet_velocity: Vec<Vector3<f64>>,
}

impl Evaluation {
    /// How much lower BeamsNet's RMSE is than LS's, in percent.
    pub fn rmse_reduction_percent(&self) -> f64 {
        100.0 * (1.0 - self.beamsnet.rmse / self.ls.rmse)
    }
}

/// Evaluate LS (with `geometry`) and BeamsNet on `samples` (one batched inference).
pub fn evaluate(
    beamsnet: &BeamsNet,
    geometry: &BeamGeometry,
    samples: &[BeamsNetSample],
) -> Result<Evaluation> {
    let reference: Vec<Vector3<f64>> = samples.iter().map(|s| s.target).collect();
    let ls_velocity: Vec<Vector3<f64>> = samples
        .iter()
        .map(|s| geometry.least_squares(&s.input.beams))
        .collect();
    let inputs: Vec<_> = samples.iter().map(|s| s.input.clone()).collect();
    let beamsnet_velocity = beamsnet.velocities(&inputs)?;
    Ok(Evaluation {
        ls: speed_metrics(&reference, &ls_velocity)?,
        beamsnet: speed_metrics(&reference, &beamsnet_velocity)?,
        reference,
        ls_velocity,
        beamsnet_velocity,
    })
}
