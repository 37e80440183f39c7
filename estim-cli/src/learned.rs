//! The learned measurement (BeamsNet) as the pipeline sees it.

use std::path::Path;

use crate::study::{beamsnet_inputs, Config, LearnedSource};
use anyhow::Context;
use estim::learned::BeamsNet;

/// The BeamsNet sensor: the committed models (one per IMU source,
/// [`crate::study::committed_beamsnet`]), or `model` (metadata JSON beside it) for
/// every scenario, with M from the network's sensitivity.
pub fn sensor(config: &Config, model: Option<&Path>) -> anyhow::Result<Option<Box<LearnedSource>>> {
    let net = match model {
        Some(path) => BeamsNet::load(path)
            .with_context(|| format!("{}: cannot load model", path.display()))?,
        None => {
            return crate::study::committed_beamsnet(config)
                .map(Some)
                .context("the committed BeamsNet models")
        }
    };
    let protocol = if config.dvl.protocol == "v2" {
        estim::dvl::BeamsNetProtocol::v2()
    } else {
        estim::dvl::BeamsNetProtocol::v1()
    };
    let geometry = protocol.geometry().clone();
    Ok(Some(Box::new(move |scenario| {
        beamsnet_inputs(&net, scenario, &geometry, true)
    })))
}
