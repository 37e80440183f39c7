//! Shared test helpers (not a test by itself).
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// The committed model folder, `<workspace>/models`.
pub fn models_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join("models")
}

/// Copy the committed BeamsNet model into a temp dir, applying `edit` to its metadata.
pub fn model_copy(edit: impl FnOnce(&mut serde_json::Value)) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let src = models_dir();
    std::fs::copy(src.join("beamsnet.onnx"), dir.path().join("beamsnet.onnx")).unwrap();
    let text = std::fs::read_to_string(src.join("beamsnet.json")).unwrap();
    let mut meta: serde_json::Value = serde_json::from_str(&text).unwrap();
    edit(&mut meta);
    std::fs::write(
        dir.path().join("beamsnet.json"),
        serde_json::to_string(&meta).unwrap(),
    )
    .unwrap();
    let model = dir.path().join("beamsnet.onnx");
    (dir, model)
}

/// The numbers of a (nested) JSON array, flattened in order, as f32 (parity files).
pub fn flatten(v: &serde_json::Value) -> Vec<f32> {
    match v {
        serde_json::Value::Array(a) => a.iter().flat_map(flatten).collect(),
        serde_json::Value::Number(n) => vec![n.as_f64().unwrap() as f32],
        other => panic!("unexpected {other}"),
    }
}

/// An error-state filter (A-KIT IMU model) started at the truth at `start` that
/// integrated `imu` and recorded the steps.
pub fn record(
    mission: &estim_ins::SimulatedMission,
    start: usize,
    imu: &[estim_ins::ImuSample],
) -> estim_core::ErrorStateKalmanFilter<f64, estim_ins::InsErrorModel, { estim_ins::ERROR_STATES }>
{
    let mut filter = estim_core::ErrorStateKalmanFilter::new(
        estim_ins::InsErrorModel::new(estim_ins::ImuSpec::akit_observed()),
        mission.truth[start],
        nalgebra::SMatrix::<f64, { estim_ins::ERROR_STATES }, { estim_ins::ERROR_STATES }>::identity()
            * 1e-6,
    )
    .unwrap()
    .with_config(
        estim_core::FilterConfig::builder()
            .window_capacity(estim_learned::BEAMSNET_WINDOW)
            .build()
            .unwrap(),
    );
    for sample in imu {
        filter.predict(sample, mission.imu_dt).unwrap();
    }
    filter
}
