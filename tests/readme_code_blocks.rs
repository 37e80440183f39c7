//! Every README's code blocks are either compiled or say what they are.
//!
//! The ```rust blocks of each README run as doc-tests of the crate whose API they use
//! (`#[doc = include_str!("../README.md")]` on a `#[cfg(doctest)]` item of that crate's
//! lib.rs). This test keeps it so: every fence names its language (a bare ``` would be
//! compiled as Rust by rustdoc, or silently not, depending on the file), and a README
//! holding a Rust block is included by its crate's lib.rs.

use std::path::Path;

/// (README, the lib.rs that must include it when it holds Rust).
const READMES: &[(&str, &str)] = &[
    ("README.md", "src/lib.rs"),
    ("estim-core/README.md", "estim-core/src/lib.rs"),
    ("estim-ins/README.md", "estim-ins/src/lib.rs"),
    ("estim-dvl/README.md", "estim-dvl/src/lib.rs"),
    ("estim-learned/README.md", "estim-learned/src/lib.rs"),
    ("training/README.md", ""),
];

/// The language tag of each opening fence, with its line number.
fn fences(text: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let mut open = false;
    for (i, line) in text.lines().enumerate() {
        let t = line.trim();
        if let Some(tag) = t.strip_prefix("```") {
            if !open {
                out.push((i + 1, tag.trim().to_string()));
            }
            open = !open;
        }
    }
    assert!(!open, "unclosed code fence");
    out
}

#[test]
fn every_rust_block_is_a_doc_test_and_every_fence_is_tagged() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut rust_blocks = 0;
    for (readme, lib) in READMES {
        let text = std::fs::read_to_string(root.join(readme)).expect("README readable");
        let fences = fences(&text);
        for (line, tag) in &fences {
            assert!(
                !tag.is_empty(),
                "{readme}:{line}: untagged code fence (say rust, sh, text, toml, ...)"
            );
        }
        let rust = fences
            .iter()
            .filter(|(_, tag)| tag.split(',').next() == Some("rust"))
            .count();
        rust_blocks += rust;
        if rust > 0 {
            assert!(
                !lib.is_empty(),
                "{readme}: Rust blocks but no crate runs them"
            );
            let lib_text = std::fs::read_to_string(root.join(lib)).expect("lib.rs readable");
            assert!(
                lib_text.contains("include_str!(\"../README.md\")"),
                "{readme} has {rust} Rust block(s) but {lib} does not include it as doc-tests"
            );
        }
    }
    // The READMEs' examples (facade, core, dvl x2, learned, the learned-sensor example).
    assert!(rust_blocks >= 5, "only {rust_blocks} Rust blocks found");
}
