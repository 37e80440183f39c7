//! The learned measurement (BeamsNet) as the pipeline sees it.

use std::path::Path;

use estim::pipeline::{Config, LearnedSource};

/// The BeamsNet sensor, if available in this build. (Wired when estim-learned lands.)
pub fn sensor(
    _config: &Config,
    _model: Option<&Path>,
) -> anyhow::Result<Option<Box<LearnedSource>>> {
    Ok(None)
}
