//! Helpers shared by the tag tests.
#![allow(dead_code, unused_imports)]

use std::path::Path;

pub use crate::common::shared_data as data_dir;
use awl::io::image::read_color_png;
use awl::tag::{AprilTagDetector, DetectorParams, TagDetection, TagDetector};

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
