//! tract reproduces PyTorch on the parity vectors exported by training/train_beamsnet.py,
//! for the BeamsNet of synthesized windows and the one of recorded windows.

mod common;
use common::flatten;

use estim_learned::OnnxMeasurement;

#[test]
fn tract_matches_pytorch_within_1e_5() {
    check_parity("beamsnet");
}

#[test]
fn recorded_beamsnet_tract_matches_pytorch_within_1e_5() {
    check_parity("beamsnet_recorded");
}

/// `models/NAME.onnx` run by tract on the cases of `models/NAME_parity.json`, one by
/// one and batched, within 1e-5 of PyTorch's outputs.
fn check_parity(name: &str) {
    let dir = common::models_dir();
    let model = OnnxMeasurement::<3>::from_model_path(&dir.join(format!("{name}.onnx"))).unwrap();
    let text = std::fs::read_to_string(dir.join(format!("{name}_parity.json"))).unwrap();
    let parity: serde_json::Value = serde_json::from_str(&text).unwrap();
    let cases = parity["cases"].as_array().unwrap();
    assert!(cases.len() >= 2);
    let mut batched = vec![Vec::new(), Vec::new(), Vec::new()];
    let mut expected = Vec::new();
    let mut worst = 0.0f64;
    for case in cases {
        let tensors: Vec<Vec<f32>> = ["acc", "gyro", "beams"]
            .iter()
            .map(|k| flatten(&case[*k]))
            .collect();
        let want = flatten(&case["velocity"]);
        let got = model.run_normalised(1, &tensors).unwrap();
        for (g, w) in got[0].iter().zip(&want) {
            worst = worst.max((g - f64::from(*w)).abs());
        }
        for (b, t) in batched.iter_mut().zip(tensors) {
            b.extend(t);
        }
        expected.push(want);
    }
    // The same cases in one batch give the same answers.
    let got = model.run_normalised(cases.len(), &batched).unwrap();
    for (g, w) in got.iter().zip(&expected) {
        for (a, b) in g.iter().zip(w) {
            worst = worst.max((a - f64::from(*b)).abs());
        }
    }
    println!("{name}: worst |tract - pytorch| = {worst:e}");
    assert!(worst <= 1e-5, "worst deviation {worst:e}");
}
