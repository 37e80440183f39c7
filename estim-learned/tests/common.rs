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

/// The first-order M `at(step)` of a learned measurement at central-difference steps
/// from 3e-2 to 1e-4 against the default step (`DEFAULT_SENSITIVITY_STEP`): prints
/// max |M(step) - M(default)| / max |M(default)| for each, and asserts it is at most
/// 5 % at steps 2e-3, 3e-3 and 5e-3 (half the 10 % of |M| the Monte Carlo
/// comparisons allow for the first-order approximation).
pub fn assert_m_step_insensitive(label: &str, at: impl Fn(f64) -> nalgebra::SMatrix<f64, 15, 3>) {
    let reference = at(estim_learned::DEFAULT_SENSITIVITY_STEP);
    for step in [3e-2, 1e-2, 5e-3, 3e-3, 2e-3, 1e-3, 3e-4, 1e-4] {
        let change = (at(step) - reference).amax() / reference.amax();
        println!("{label}: step {step:e}: max |M - M(default)| / max |M(default)| = {change:.3}");
        if (2e-3..=5e-3).contains(&step) {
            assert!(change <= 0.05, "{label}, step {step}: {change}");
        }
    }
}
