//! AprilTag (tag36h11) detection and tag pose.
//!
//! - [`TagDetector`] finds tags in a color or gray image ([`AprilTagDetector`]: the AprilTag 3 C
//!   library); each [`TagDetection`] has sub-pixel corners in AprilTag order, pixel centres at integer
//!   coordinates (OpenCV convention).
//! - [`estimate_tag_pose`] turns the 4 corners, the [`Intrinsics`](crate::camera::Intrinsics) and the
//!   tag size into `camera_from_tag`: both planar-ambiguity solutions (IPPE, each refined by
//!   Levenberg-Marquardt), the better one first.
//! - [`score_depth`] scores both solutions with depth points on the tag, to resolve the ambiguity.
//!
//! The tag frame is awl's (see `ARCHITECTURE.md`): origin at the tag centre, x right and y up when the
//! tag is read upright, z out of the face toward the viewer; the black-border corners are at
//! `(+-s/2, +-s/2, 0)`. This is NOT the AprilTag library's pose frame (x right, y down, z into the
//! face): that one is `camera_from_tag * Rx(180 deg)`.
//!
//! ```no_run
//! use awl::tag::{AprilTagDetector, DetectorParams, TagDetector, estimate_tag_pose};
//! # fn run(image: &awl::image::ColorImage, k: &awl::camera::Intrinsics) -> awl::Result<()> {
//! let mut detector = AprilTagDetector::new(&DetectorParams::default())?;
//! for d in detector.detect_color(image)?.iter().filter(|d| d.id == 0) {
//!     let pose = estimate_tag_pose(&d.corners_px, k, 0.08)?;
//!     let camera_from_tag = pose.best.camera_from_tag;
//! #   let _ = camera_from_tag;
//! }
//! # Ok(()) }
//! ```

#[cfg(feature = "apriltag")]
mod apriltag_c;
mod depth;
mod detect;
mod ippe;
#[cfg(not(feature = "apriltag"))]
mod no_detector;
mod pose;
mod report;

/// The tag family awl detects (`tag.family` in scan.json and capture files).
pub const SUPPORTED_FAMILY: &str = "tag36h11";

#[cfg(feature = "apriltag")]
pub use apriltag_c::AprilTagDetector;
pub use depth::{DepthScore, DepthScores, MIN_DEPTH_POINTS, score_depth};
pub use detect::{DetectorParams, GrayView, TagDetection, TagDetector};
#[cfg(not(feature = "apriltag"))]
pub use no_detector::AprilTagDetector;
pub use pose::{TagPose, TagPoseSolution, estimate_tag_pose, tag_corners_m};
pub use report::{PosedTag, detect_and_pose};
