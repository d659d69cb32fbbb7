//! [`AprilTagDetector`] in a build without the `apriltag` feature: it cannot be made, and
//! [`AprilTagDetector::new`] names the feature.

use super::detect::{DetectorParams, GrayView, TagDetection, TagDetector};
use crate::error::{Error, Result};

/// Stands for the AprilTag 3 C detector in a build without the `apriltag` feature: it cannot be made.
#[derive(Debug)]
pub struct AprilTagDetector {
    never: std::convert::Infallible,
}

impl AprilTagDetector {
    /// Refuses: this build has no tag detector.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the `apriltag` feature, or out-of-range `params`.
    pub fn new(params: &DetectorParams) -> Result<Self> {
        params.check()?;
        Err(Error::invalid(
            "AprilTag detector",
            "awl was built without its `apriltag` feature (the AprilTag C library): build with it, the default, to detect tags",
        ))
    }
}

impl TagDetector for AprilTagDetector {
    fn detect_gray(&mut self, _image: GrayView<'_>) -> Result<Vec<TagDetection>> {
        match self.never {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn without_the_feature_the_detector_names_it() {
        let e = AprilTagDetector::new(&DetectorParams::default()).expect_err("no detector").to_string();
        assert!(e.contains("`apriltag` feature"), "{e}");
    }
}
