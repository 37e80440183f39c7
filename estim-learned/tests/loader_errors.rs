//! Error cases of the model loader and of input assembly.

mod common;

use estim_core::LearnedMeasurement;
use estim_learned::{BeamsNet, Error, OnnxMeasurement};
use nalgebra::DMatrix;

fn good_inputs() -> Vec<DMatrix<f64>> {
    vec![
        DMatrix::from_element(3, 100, 0.01),
        DMatrix::from_element(3, 100, 1e-3),
        DMatrix::from_column_slice(4, 1, &[1.0, 1.0, 1.0, 1.0]),
    ]
}

#[test]
fn committed_model_loads_and_runs() {
    let (_d, model) = common::model_copy(|_| {});
    let m = OnnxMeasurement::<3>::from_model_path(&model).unwrap();
    let y = m.measure(&good_inputs()).unwrap();
    assert!(y.iter().all(|v| v.is_finite()));
    assert_eq!(m.input_specs().len(), 3);
    assert_eq!(m.input_specs()[0].window, 100);
}

#[test]
fn missing_model_file() {
    let (dir, model) = common::model_copy(|_| {});
    std::fs::remove_file(&model).unwrap();
    let e = OnnxMeasurement::<3>::from_model_path(&model).unwrap_err();
    assert!(matches!(e, Error::MissingFile { .. }), "{e}");
    assert!(e.to_string().contains("beamsnet.onnx"), "{e}");
    drop(dir);
}

#[test]
fn missing_metadata_file() {
    let (dir, model) = common::model_copy(|_| {});
    std::fs::remove_file(dir.path().join("beamsnet.json")).unwrap();
    let e = OnnxMeasurement::<3>::from_model_path(&model).unwrap_err();
    assert!(matches!(e, Error::MissingFile { .. }), "{e}");
    assert!(e.to_string().contains("beamsnet.json"), "{e}");
}

#[test]
fn malformed_model_file() {
    let (_dir, model) = common::model_copy(|_| {});
    std::fs::write(&model, b"this is not a protobuf \x00\x01\x02").unwrap();
    let e = OnnxMeasurement::<3>::from_model_path(&model).unwrap_err();
    assert!(matches!(e, Error::MalformedModel { .. }), "{e}");
}

#[test]
fn malformed_metadata_json_and_values() {
    let (dir, model) = common::model_copy(|_| {});
    std::fs::write(dir.path().join("beamsnet.json"), "{ not json").unwrap();
    let e = OnnxMeasurement::<3>::from_model_path(&model).unwrap_err();
    assert!(matches!(e, Error::MalformedMetadata { .. }), "{e}");

    let (_d, model) = common::model_copy(|m| m["inputs"][0]["std"][1] = serde_json::json!(0.0));
    let e = OnnxMeasurement::<3>::from_model_path(&model).unwrap_err();
    assert!(matches!(e, Error::MalformedMetadata { .. }), "{e}");

    let (_d, model) = common::model_copy(|m| {
        m["noise_covariance"] =
            serde_json::json!([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    });
    let e = OnnxMeasurement::<3>::from_model_path(&model).unwrap_err();
    assert!(e.to_string().contains("positive definite"), "{e}");

    // Output size 3 declared, but asked for a 2-vector measurement.
    let (_d, model) = common::model_copy(|_| {});
    let e = OnnxMeasurement::<2>::from_model_path(&model).unwrap_err();
    assert!(matches!(e, Error::MalformedMetadata { .. }), "{e}");
}

#[test]
fn metadata_names_differ_from_model() {
    let (_d, model) =
        common::model_copy(|m| m["inputs"][1]["name"] = serde_json::json!("gyroscope"));
    let e = OnnxMeasurement::<3>::from_model_path(&model).unwrap_err();
    match &e {
        Error::ModelMetadataMismatch {
            expected, given, ..
        } => {
            assert!(expected.contains("gyro:"), "{expected}");
            assert!(given.contains("gyroscope"), "{given}");
        }
        other => panic!("unexpected {other}"),
    }
}

#[test]
fn metadata_shape_differs_from_model() {
    let (_d, model) = common::model_copy(|m| {
        m["inputs"][0]["window"] = serde_json::json!(50);
        m["inputs"][0]["shape"] = serde_json::json!([3, 50]);
    });
    let e = OnnxMeasurement::<3>::from_model_path(&model).unwrap_err();
    assert!(matches!(e, Error::ModelMetadataMismatch { .. }), "{e}");
    assert!(e.to_string().contains("100"), "{e}");
}

#[test]
fn beamsnet_rejects_non_beamsnet_metadata() {
    let (_d, model) = common::model_copy(|m| {
        m["inputs"][2]["channels"] = serde_json::json!(2);
        m["inputs"][2]["window"] = serde_json::json!(2);
        m["inputs"][2]["mean"] = serde_json::json!([0.0, 0.0]);
        m["inputs"][2]["std"] = serde_json::json!([1.0, 1.0]);
    });
    // shape [4] still holds 2 x 2 values, so the ONNX check passes; BeamsNet refuses it.
    assert!(BeamsNet::load(&model).is_err());
}

#[test]
fn input_assembly_errors_list_expected_and_given() {
    let (_d, model) = common::model_copy(|_| {});
    let m = OnnxMeasurement::<3>::from_model_path(&model).unwrap();
    // Wrong count.
    let e = m.measure(&good_inputs()[..2]).unwrap_err().to_string();
    assert!(e.contains("3 inputs") && e.contains("2 inputs"), "{e}");
    // Wrong shape.
    let mut bad = good_inputs();
    bad[0] = DMatrix::zeros(3, 99);
    let e = m.measure(&bad).unwrap_err().to_string();
    assert!(e.contains("3 x 100") && e.contains("3 x 99"), "{e}");
    // Non-finite value.
    let mut bad = good_inputs();
    bad[1][(2, 5)] = f64::NAN;
    let e = m.measure(&bad).unwrap_err().to_string();
    assert!(e.contains("channel 2, sample 5"), "{e}");
    // Direction of the wrong shape for the sensitivity.
    let mut products = [nalgebra::Vector3::zeros(); 1];
    let dirs = [
        DMatrix::zeros(3, 100),
        DMatrix::zeros(3, 99),
        DMatrix::zeros(4, 1),
    ];
    let e = m
        .jacobian_vector_products(&good_inputs(), &dirs, &mut products)
        .unwrap_err()
        .to_string();
    assert!(e.contains("3 x 99"), "{e}");
    // Directions that do not make whole sets of one matrix per input.
    let dirs = [DMatrix::zeros(3, 100), DMatrix::zeros(3, 100)];
    assert!(m
        .jacobian_vector_products(&good_inputs(), &dirs, &mut products)
        .is_err());
}
