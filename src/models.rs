//! The committed learned models, embedded in the library: no model file is read at run
//! time, so a built binary does not depend on where the source tree was.
//!
//! Each is the ONNX file and metadata JSON of `models/` (written by `training/`, see
//! training/README.md), compiled in with `include_bytes!`. Loading one builds its tract
//! plan (tens of milliseconds for BeamsNet); keep the result.
//!
//! ```
//! use estim::core::LearnedMeasurement;
//!
//! let beamsnet = estim::models::beamsnet()?;
//! assert_eq!(beamsnet.measurement().input_specs().len(), 3); // acc, gyro, beams
//! # Ok::<(), estim::learned::Error>(())
//! ```

use std::path::Path;

use estim_learned::{BeamsNet, OutageNet, Result, TwoBeamsNet};

/// How the embedded models are named in errors and in `--json` inputs.
pub const BEAMSNET_NAME: &str = "embedded:models/beamsnet.onnx";
/// See [`BEAMSNET_NAME`].
pub const BEAMSNET_RECORDED_NAME: &str = "embedded:models/beamsnet_recorded.onnx";
/// See [`BEAMSNET_NAME`].
pub const TWO_BEAMS_NAME: &str = "embedded:models/two_beams.onnx";
/// See [`BEAMSNET_NAME`].
pub const TWO_BEAMS_RECORDED_NAME: &str = "embedded:models/two_beams_recorded.onnx";
/// See [`BEAMSNET_NAME`].
pub const OUTAGE_NAME: &str = "embedded:models/outage.onnx";
/// See [`BEAMSNET_NAME`].
pub const OUTAGE_RECORDED_NAME: &str = "embedded:models/outage_recorded.onnx";

/// BeamsNetV1 (IMU window + 4 beams -> body velocity), `models/beamsnet.onnx`.
///
/// # Errors
/// The loader's errors (none for the committed files; tested).
pub fn beamsnet() -> Result<BeamsNet> {
    BeamsNet::from_bytes(
        include_bytes!("../models/beamsnet.onnx"),
        include_str!("../models/beamsnet.json"),
        Path::new(BEAMSNET_NAME),
    )
}

/// BeamsNetV1 trained on the recorded IMU windows of A-KIT trajectories 1-3 and 5-12
/// (aligned as the study's filter feeds them; beams from the DVL velocity by the
/// BeamsNet protocol), `models/beamsnet_recorded.onnx`. Its metadata says
/// `imu_source: recorded`; training/README.md has the command and the validation
/// figures. The study uses it on a recorded IMU and [`beamsnet`] (trained on
/// synthesized windows) on a synthesized one.
///
/// # Errors
/// The loader's errors (none for the committed files; tested).
pub fn beamsnet_recorded() -> Result<BeamsNet> {
    BeamsNet::from_bytes(
        include_bytes!("../models/beamsnet_recorded.onnx"),
        include_str!("../models/beamsnet_recorded.json"),
        Path::new(BEAMSNET_RECORDED_NAME),
    )
}

/// The two-beams network (IMU window + beams 1 and 2 -> body velocity),
/// `models/two_beams.onnx`.
///
/// # Errors
/// The loader's errors (none for the committed files; tested).
pub fn two_beams() -> Result<TwoBeamsNet> {
    TwoBeamsNet::from_bytes(
        include_bytes!("../models/two_beams.onnx"),
        include_str!("../models/two_beams.json"),
        Path::new(TWO_BEAMS_NAME),
    )
}

/// The two-beams network trained on the recorded IMU windows of A-KIT trajectories 1-3
/// and 5-12 (aligned as the study's filter feeds them; beams from the DVL velocity by
/// the BeamsNet protocol), `models/two_beams_recorded.onnx`. Its metadata says
/// `imu_source: recorded`; training/README.md has the command and the validation
/// figures. [`two_beams`] is the same network trained on synthesized windows.
///
/// # Errors
/// The loader's errors (none for the committed files; tested).
pub fn two_beams_recorded() -> Result<TwoBeamsNet> {
    TwoBeamsNet::from_bytes(
        include_bytes!("../models/two_beams_recorded.onnx"),
        include_str!("../models/two_beams_recorded.json"),
        Path::new(TWO_BEAMS_RECORDED_NAME),
    )
}

/// The outage network (IMU window, last velocity, elapsed time -> body velocity),
/// `models/outage.onnx`.
///
/// # Errors
/// The loader's errors (none for the committed files; tested).
pub fn outage() -> Result<OutageNet> {
    OutageNet::from_bytes(
        include_bytes!("../models/outage.onnx"),
        include_str!("../models/outage.json"),
        Path::new(OUTAGE_NAME),
    )
}

/// The outage network trained on the recorded IMU windows of A-KIT trajectories 1-3
/// and 5-12 (aligned as the study's filter feeds them; last velocity the four-beam least
/// squares of an earlier row's protocol beams), `models/outage_recorded.onnx`. Its
/// metadata says `imu_source: recorded`; training/README.md has the command and the
/// validation figures. [`outage`] is the same network trained on synthesized windows.
///
/// # Errors
/// The loader's errors (none for the committed files; tested).
pub fn outage_recorded() -> Result<OutageNet> {
    OutageNet::from_bytes(
        include_bytes!("../models/outage_recorded.onnx"),
        include_str!("../models/outage_recorded.json"),
        Path::new(OUTAGE_RECORDED_NAME),
    )
}

#[cfg(test)]
mod tests {
    use estim_core::LearnedMeasurement;
    use estim_learned::{default_model_path, default_outage_model_path, OnnxMeasurement};
    use nalgebra::DMatrix;

    /// The embedded model computes what the file in the source tree computes.
    fn same_output(embedded: &OnnxMeasurement<3>, file: &OnnxMeasurement<3>) {
        let inputs: Vec<DMatrix<f64>> = embedded
            .input_specs()
            .iter()
            .enumerate()
            .map(|(k, s)| {
                DMatrix::from_fn(s.channels, s.window, |i, j| {
                    0.01 * (i as f64 + 1.0) - 0.002 * j as f64 + 0.1 * k as f64
                })
            })
            .collect();
        let a = embedded.measure(&inputs).expect("embedded model runs");
        let b = file.measure(&inputs).expect("file model runs");
        assert_eq!(a, b);
        assert_eq!(embedded.noise_covariance(), file.noise_covariance());
    }

    #[test]
    fn embedded_models_equal_the_committed_files() {
        let beamsnet = super::beamsnet().expect("embedded BeamsNet");
        let file = estim_learned::BeamsNet::load(&default_model_path()).expect("file");
        same_output(beamsnet.measurement(), file.measurement());
        let recorded = super::beamsnet_recorded().expect("embedded recorded BeamsNet");
        let path = default_model_path().with_file_name("beamsnet_recorded.onnx");
        let file = estim_learned::BeamsNet::load(&path).expect("file");
        same_output(recorded.measurement(), file.measurement());
        let outage = super::outage().expect("embedded outage network");
        let file = estim_learned::OutageNet::load(&default_outage_model_path()).expect("file");
        same_output(outage.measurement(), file.measurement());
        let two_beams = super::two_beams().expect("embedded two-beams network");
        let path = default_model_path().with_file_name("two_beams.onnx");
        let file = estim_learned::TwoBeamsNet::load(&path).expect("file");
        same_output(two_beams.measurement(), file.measurement());
        let two_beams = super::two_beams_recorded().expect("embedded recorded two-beams network");
        let path = default_model_path().with_file_name("two_beams_recorded.onnx");
        let file = estim_learned::TwoBeamsNet::load(&path).expect("file");
        same_output(two_beams.measurement(), file.measurement());
        let outage = super::outage_recorded().expect("embedded recorded outage network");
        let path = default_outage_model_path().with_file_name("outage_recorded.onnx");
        let file = estim_learned::OutageNet::load(&path).expect("file");
        same_output(outage.measurement(), file.measurement());
    }

    /// The training provenance a recorded-IMU model's metadata must show: recorded
    /// windows aligned as the filter feeds them, training trajectories only (4 and 13
    /// held out), validated on 3 and 10. Returns its `training` object.
    fn assert_trained_on_recorded_windows(json: &str) -> serde_json::Value {
        let meta: serde_json::Value = serde_json::from_str(json).unwrap();
        assert_eq!(meta["imu_source"], "recorded");
        let training = &meta["training"];
        assert_eq!(training["imu_source"], "recorded");
        let data = &training["dataset_metadata"];
        assert_eq!(data["imu_source"], "recorded");
        assert_eq!(data["window_alignment"]["rule"], "filter");
        assert_eq!(data["held_out_trajectories"], serde_json::json!([4, 13]));
        let used: Vec<u64> = data["trajectories"]
            .as_array()
            .unwrap()
            .iter()
            .map(|t| t["trajectory"].as_u64().unwrap())
            .collect();
        assert_eq!(used, [1, 2, 3, 5, 6, 7, 8, 9, 10, 11, 12]);
        assert_eq!(
            training["validation_trajectories"],
            serde_json::json!([3, 10])
        );
        let trained: Vec<u64> = training["train_trajectories"]
            .as_array()
            .unwrap()
            .iter()
            .map(|t| t.as_u64().unwrap())
            .collect();
        assert_eq!(trained, [1, 2, 5, 6, 7, 8, 9, 11, 12]);
        training.clone()
    }

    /// The recorded-IMU BeamsNet says what it was trained on.
    #[test]
    fn recorded_beamsnet_was_trained_on_recorded_windows() {
        let training =
            assert_trained_on_recorded_windows(include_str!("../models/beamsnet_recorded.json"));
        // The validation figures training/README.md reports.
        let speed = training["validation_speed_rmse_mps"].as_f64().unwrap();
        println!(
            "recorded BeamsNet validation: |v| RMSE {speed:.5} m/s, per axis {}",
            training["validation_rmse_mps"]
        );
        assert!((speed - 0.00360).abs() < 5e-6, "{speed}");
    }

    /// Per-axis validation RMSE (m/s) under `imu_dependence[key]`.
    fn axis_rmse(meta: &serde_json::Value, key: &str) -> Vec<f64> {
        meta["imu_dependence"][key]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect()
    }

    /// The recorded-IMU two-beams network says what it was trained on, and has the
    /// validation figures training/README.md reports.
    #[test]
    fn recorded_two_beams_was_trained_on_recorded_windows() {
        let json = include_str!("../models/two_beams_recorded.json");
        let training = assert_trained_on_recorded_windows(json);
        assert_eq!(training["beams_used"], serde_json::json!([1, 2]));
        let meta: serde_json::Value = serde_json::from_str(json).unwrap();
        let rmse = axis_rmse(&meta, "validation_rmse_per_axis_mps");
        let imu_replaced = axis_rmse(&meta, "validation_rmse_imu_replaced_per_axis_mps");
        println!("recorded two-beams validation RMSE {rmse:?}, IMU replaced {imu_replaced:?}");
        assert!((rmse[1] - 0.0390).abs() < 5e-5, "{rmse:?}");
        // The lateral velocity comes from the IMU.
        assert!(imu_replaced[1] > 3.0 * rmse[1], "{imu_replaced:?}");
    }

    /// The recorded-IMU outage network says what it was trained on, and has the
    /// validation figures training/README.md reports.
    #[test]
    fn recorded_outage_was_trained_on_recorded_windows() {
        let json = include_str!("../models/outage_recorded.json");
        let training = assert_trained_on_recorded_windows(json);
        assert_eq!(training["max_elapsed_s"], 60.0);
        let meta: serde_json::Value = serde_json::from_str(json).unwrap();
        let rmse = axis_rmse(&meta, "validation_rmse_per_axis_mps");
        let hold = axis_rmse(&meta, "validation_rmse_hold_last_velocity_per_axis_mps");
        println!("recorded outage validation RMSE {rmse:?}, holding the last velocity {hold:?}");
        assert!((rmse[0] - 0.1635).abs() < 5e-4, "{rmse:?}");
        assert!((rmse[1] - 0.1241).abs() < 5e-4, "{rmse:?}");
        assert!(
            rmse.iter().zip(&hold).all(|(r, h)| r < h),
            "{rmse:?} {hold:?}"
        );
    }
}
