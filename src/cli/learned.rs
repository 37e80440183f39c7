//! The learned measurement (BeamsNet) as the pipeline sees it.

use std::path::Path;

use estim::pipeline::{Config, LearnedInputs, Scenario};

/// A function producing the learned measurements of a scenario.
pub type LearnedFn = dyn Fn(&Scenario) -> estim::pipeline::Result<LearnedInputs> + Sync;

/// The BeamsNet sensor, if available in this build. (Wired when estim-learned lands.)
pub fn sensor(_config: &Config, _model: Option<&Path>) -> anyhow::Result<Option<Box<LearnedFn>>> {
    Ok(None)
}
