//! Helpers shared by the tag tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use awl::io::image::read_color_png;
use awl::tag::{AprilTagDetector, DetectorParams, TagDetection, TagDetector};

/// `$AWL_SHARED_DATA`, else `<workspace>/../shared/data`; panics when missing.
pub fn data_dir() -> PathBuf {
    let dir = std::env::var_os("AWL_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"));
    assert!(
        dir.is_dir(),
        "shared test data folder {} is missing: restore it (see shared/data/SOURCES.md) or set AWL_SHARED_DATA",
        dir.display()
    );
    dir
}

/// A detector with the default parameters.
pub fn detector() -> AprilTagDetector {
    AprilTagDetector::new(&DetectorParams::default()).expect("detector")
}

/// Detections in a color PNG.
pub fn detect_file(path: &Path) -> Vec<TagDetection> {
    let image = read_color_png(path).unwrap_or_else(|e| panic!("{e}"));
    detector().detect_color(&image).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// (median, max) of `values` (sorted in place); (NaN, NaN) when empty.
pub fn stats(values: &mut [f64]) -> (f64, f64) {
    if values.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    values.sort_by(f64::total_cmp);
    (values[values.len() / 2], values[values.len() - 1])
}
