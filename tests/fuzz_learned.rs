//! Fuzzing of the learned-model files on stable Rust: the JSON metadata
//! (`ModelMetadata::from_json`) and the ONNX file (`OnnxMeasurement::from_model_path`),
//! by arbitrary bytes and byte mutations of the committed files.
//! Property: no panic; a typed error naming the file, or a model that loads.
//!
//! ```sh
//! ESTIM_FUZZ_CASES=1000000 cargo test --release --test fuzz_learned metadata_
//! ESTIM_FUZZ_CASES=2000 cargo test --release --test fuzz_learned onnx_   # tract is slow per case
//! ```

use std::path::Path;

use estim_learned::{default_model_path, ModelMetadata, OnnxMeasurement};
use proptest::prelude::*;
use proptest::test_runner::Config;

fn cases(default: u32) -> u32 {
    std::env::var("ESTIM_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// The committed model files (part of the repository, so their absence is a failure).
fn committed(ext: &str) -> Option<Vec<u8>> {
    let path = default_model_path().with_extension(ext);
    Some(std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display())))
}

#[derive(Debug, Clone)]
enum ByteEdit {
    Flip(usize, u8),
    Delete(usize, usize),
    Insert(usize, Vec<u8>),
    Truncate(usize),
}

fn byte_edit() -> impl Strategy<Value = ByteEdit> {
    prop_oneof![
        (any::<usize>(), any::<u8>()).prop_map(|(a, b)| ByteEdit::Flip(a, b)),
        (any::<usize>(), 0usize..64).prop_map(|(a, n)| ByteEdit::Delete(a, n)),
        (
            any::<usize>(),
            proptest::collection::vec(any::<u8>(), 1..16)
        )
            .prop_map(|(a, b)| ByteEdit::Insert(a, b)),
        any::<usize>().prop_map(ByteEdit::Truncate),
    ]
}

fn mutate(mut bytes: Vec<u8>, edits: &[ByteEdit]) -> Vec<u8> {
    for e in edits {
        match e {
            ByteEdit::Flip(a, b) if !bytes.is_empty() => {
                let i = a % bytes.len();
                bytes[i] ^= b.max(&1);
            }
            ByteEdit::Flip(..) => {}
            ByteEdit::Delete(a, n) if !bytes.is_empty() => {
                let a = a % bytes.len();
                let b = (a + n).min(bytes.len());
                bytes.drain(a..b);
            }
            ByteEdit::Delete(..) => {}
            ByteEdit::Insert(a, ins) => {
                let a = a % (bytes.len() + 1);
                bytes.splice(a..a, ins.iter().copied());
            }
            ByteEdit::Truncate(a) => bytes.truncate(a % (bytes.len() + 1)),
        }
    }
    bytes
}

/// JSON values that stress the metadata's validation.
const JSON_VALUES: [&str; 10] = [
    "null",
    "-1",
    "0",
    "1e400",
    "[]",
    "[[]]",
    "{}",
    "\"\"",
    "18446744073709551616",
    "[1e308, -1e308]",
];

fn check_metadata(bytes: &[u8]) {
    let text = String::from_utf8_lossy(bytes);
    if let Ok(m) = ModelMetadata::from_json(&text, Path::new("fuzz/beamsnet.json")) {
        // Accepted: it re-validates.
        assert!(m.check(Path::new("fuzz/beamsnet.json")).is_ok());
    }
}

proptest! {
    #![proptest_config(Config { cases: cases(2_000), failure_persistence: None, ..Config::default() })]

    #[test]
    fn metadata_survives_byte_mutations(edits in proptest::collection::vec(byte_edit(), 1..4)) {
        let Some(valid) = committed("json") else { return Ok(()); };
        check_metadata(&mutate(valid, &edits));
    }

    #[test]
    fn metadata_survives_value_replacement(key in any::<usize>(),
                                           value in proptest::sample::select(JSON_VALUES.to_vec())) {
        // Structure-aware: replace the value of one `"key": value` pair.
        let Some(valid) = committed("json") else { return Ok(()); };
        let mut json: serde_json::Value = serde_json::from_slice(&valid).unwrap();
        let replacement: serde_json::Value = serde_json::from_str(value).unwrap_or(serde_json::Value::Null);
        if let Some(obj) = json.as_object_mut() {
            let keys: Vec<String> = obj.keys().cloned().collect();
            let k = &keys[key % keys.len()];
            obj.insert(k.clone(), replacement);
        }
        check_metadata(json.to_string().as_bytes());
    }

    #[test]
    fn metadata_survives_arbitrary_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        check_metadata(&bytes);
    }
}

proptest! {
    // tract parses and optimises the model per case: fewer cases by default.
    #![proptest_config(Config { cases: cases(24), failure_persistence: None, ..Config::default() })]

    #[test]
    fn onnx_survives_byte_mutations(edits in proptest::collection::vec(byte_edit(), 1..4)) {
        let (Some(model), Some(meta)) = (committed("onnx"), committed("json")) else { return Ok(()); };
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("beamsnet.json"), meta).unwrap();
        let path = dir.path().join("beamsnet.onnx");
        std::fs::write(&path, mutate(model, &edits)).unwrap();
        if let Err(e) = OnnxMeasurement::<3>::from_model_path(&path) {
            assert!(e.to_string().contains("beamsnet.onnx") || e.to_string().contains("beamsnet.json"), "{e}");
        }
    }
}
