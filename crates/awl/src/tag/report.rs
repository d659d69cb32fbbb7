//! Every tag of an image, each posed (both planar-ambiguity solutions) when the camera and the tag
//! size are known: what `awl tags` prints.

use crate::camera::Intrinsics;
use crate::error::{Error, Result};
use crate::image::ColorImage;
use crate::tag::{TagDetection, TagDetector, TagPose, estimate_tag_pose};

/// One detection and, when asked for, its pose.
#[derive(Debug, Clone, PartialEq)]
pub struct PosedTag {
    /// The detection (corners in pixels, integer = pixel centre).
    pub detection: TagDetection,
    /// Both solutions of [`estimate_tag_pose`] (`T_camera_tag` in awl's tag frame), when a camera
    /// and size were given and the quad gave a pose.
    pub pose: Option<TagPose>,
    /// Why the quad gave no pose (degenerate), when a pose was asked for.
    pub pose_error: Option<String>,
}

/// Detects every tag in `image` and, with `camera = Some((intrinsics, tag_size_m))` (tag
/// black-border edge, metres), poses each one.
///
/// # Errors
/// [`Error::Invalid`] when the image's size differs from the intrinsics', or the detector cannot run.
pub fn detect_and_pose(
    detector: &mut impl TagDetector,
    image: &ColorImage,
    camera: Option<(&Intrinsics, f64)>,
) -> Result<Vec<PosedTag>> {
    if let Some((k, _)) = camera
        && (k.width, k.height) != (image.width, image.height)
    {
        return Err(Error::invalid(
            "image",
            format!("is {}x{}, the intrinsics are for {}x{}", image.width, image.height, k.width, k.height),
        ));
    }
    let found = detector.detect_color(image)?;
    Ok(found
        .into_iter()
        .map(|detection| {
            let Some((k, size)) = camera else { return PosedTag { detection, pose: None, pose_error: None } };
            match estimate_tag_pose(&detection.corners_px, k, size) {
                Ok(pose) => PosedTag { detection, pose: Some(pose), pose_error: None },
                Err(e) => PosedTag { detection, pose: None, pose_error: Some(e.to_string()) },
            }
        })
        .collect())
}
