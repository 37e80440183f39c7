//! Helpers shared by the integration tests.

use std::path::PathBuf;

use estim::datasets::trajectory_files;

/// The data root holding A-KIT (`ESTIM_DATA_DIR`, then `../shared/data` beside the
/// workspace). `None` with a printed reason when absent, unless `ESTIM_REQUIRE_DATA=1`
/// (as in CI), which makes its absence a failure.
pub fn data_root() -> Option<PathBuf> {
    let required = std::env::var("ESTIM_REQUIRE_DATA").is_ok_and(|v| v == "1");
    let found = std::env::var_os("ESTIM_DATA_DIR")
        .map(PathBuf::from)
        .into_iter()
        .chain([
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data"),
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data"),
        ])
        .find(|p| trajectory_files(p, 4).is_ok());
    if found.is_none() {
        assert!(
            !required,
            "ESTIM_REQUIRE_DATA=1 but the A-KIT data was not found"
        );
        eprintln!("skipped: A-KIT data not found (set ESTIM_DATA_DIR)");
    }
    found
}
