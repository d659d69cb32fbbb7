//! Helpers shared by the integration tests.

use std::path::PathBuf;

/// The shared test data folder: `$AWL_SHARED_DATA` when set, else `<workspace>/../shared/data`.
/// Panics (fails the test) when it is missing: CI has it beside the checkout.
pub fn shared_data() -> PathBuf {
    let dir = std::env::var_os("AWL_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"));
    assert!(
        dir.is_dir(),
        "shared test data folder {} is missing: restore it (see shared/data/SOURCES.md) or set AWL_SHARED_DATA",
        dir.display()
    );
    dir
}
