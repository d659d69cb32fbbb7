//! A hand-eye calibration capture: an `awl-scan/1` folder whose views are color images (PNG or
//! JPEG; a depth PNG optional) of a tag held fixed in the robot base frame, each with the flange
//! pose `T_base_ee` of the arm's forward kinematics.
//!
//! Read with [`read_capture`]. `scan.json` names the tag (`tag`) and the camera (`camera`; its
//! `depth_scale` is needed only when a view has a depth image). A view's `T_world_base` is
//! identity or absent (world = robot base); a view without `T_base_ee`, or with `points`, is
//! refused naming the view. `T_ee_camera`, when present, is ignored: it is what is calibrated.

use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Point3};
use serde::Deserialize;

use crate::camera::{DepthCamera, Intrinsics, PixelRect, depth_points_in};
use crate::error::{Error, Result};
use crate::image::ColorImage;
use crate::io::image::{read_color_image, read_depth_png};
use crate::io::scan::{FORMAT, RawIntrinsics, check_size, intrinsics_from_parts, pose_field, positive, read_json};
use crate::scan::TagSpec;
use crate::transform::Rows;

/// A `T_world_base` farther than this from identity is refused in a capture, metres or radians.
const IDENTITY_TOLERANCE: f64 = 1e-6;

/// One view of a capture.
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureView {
    /// The color image (PNG or JPEG), relative to the capture folder.
    pub color: PathBuf,
    /// The 16-bit depth PNG registered to it, relative to the capture folder, when the view has one.
    pub depth: Option<PathBuf>,
    /// `T_base_ee`: the flange in the arm's base frame (forward kinematics).
    pub base_from_ee: Isometry3<f64>,
}

/// A hand-eye calibration capture folder, validated (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct Capture {
    /// The folder holding `scan.json`.
    pub dir: PathBuf,
    /// The color camera's intrinsics (`camera` in `scan.json`).
    pub intrinsics: Intrinsics,
    /// The depth camera (the same intrinsics, its depth scale and range), when `camera` gives a
    /// `depth_scale`; required when a view has a depth image.
    pub depth_camera: Option<DepthCamera>,
    /// The tag held fixed in the scene.
    pub tag: TagSpec,
    /// The views, in capture order.
    pub views: Vec<CaptureView>,
}

#[derive(Deserialize)]
struct RawCaptureCamera {
    #[serde(flatten)]
    intrinsics: RawIntrinsics,
    #[serde(default)]
    depth_scale: Option<f64>,
    #[serde(default)]
    depth_min: Option<f64>,
    #[serde(default)]
    depth_max: Option<f64>,
}

#[derive(Deserialize)]
struct RawCaptureView {
    #[serde(default)]
    color: Option<PathBuf>,
    #[serde(default)]
    depth: Option<PathBuf>,
    #[serde(default)]
    points: Option<PathBuf>,
    #[serde(rename = "T_world_camera", default)]
    world_camera: Option<Rows>,
    #[serde(rename = "T_world_base", default)]
    world_base: Option<Rows>,
    #[serde(rename = "T_base_ee", default)]
    base_ee: Option<Rows>,
}

#[derive(Deserialize)]
struct RawCapture {
    format: String,
    #[serde(default)]
    camera: Option<RawCaptureCamera>,
    #[serde(default)]
    tag: Option<TagSpec>,
    views: Vec<RawCaptureView>,
}

impl Capture {
    /// Path of the capture's `scan.json`.
    pub fn manifest_path(&self) -> PathBuf {
        self.dir.join("scan.json")
    }

    /// The color image of view `index`, its size checked against the camera.
    ///
    /// # Errors
    /// [`Error::Field`] for an index out of range; any error of [`read_color_image`] (naming the
    /// file: a JPEG that does not decode among them); [`Error::Format`] when its size is not the
    /// camera's.
    pub fn read_color(&self, index: usize) -> Result<ColorImage> {
        let path = self.dir.join(&self.view(index)?.color);
        let image = read_color_image(&path)?;
        let (w, h) = (self.intrinsics.width, self.intrinsics.height);
        if (image.width, image.height) != (w, h) {
            let (iw, ih) = (image.width, image.height);
            return Err(Error::format(&path, format!("image is {iw}x{ih}, scan.json camera says {w}x{h}")));
        }
        Ok(image)
    }

    /// The depth points (camera frame, metres, depth range applied) of view `index` inside
    /// `rect`; `None` when the view has no depth image.
    ///
    /// # Errors
    /// [`Error::Field`] for an index out of range; any error of the depth PNG reader; a size other
    /// than the camera's.
    pub fn read_depth_points(&self, index: usize, rect: &PixelRect) -> Result<Option<Vec<Point3<f32>>>> {
        let Some(depth) = &self.view(index)?.depth else { return Ok(None) };
        let camera = self
            .depth_camera
            .as_ref()
            .ok_or_else(|| Error::field(self.manifest_path(), "camera.depth_scale", "missing, but views have depth"))?;
        let path = self.dir.join(depth);
        let image = read_depth_png(&path)?;
        check_size(&path, camera, image.width, image.height)?;
        Ok(Some(depth_points_in(&image, camera, rect)))
    }

    fn view(&self, index: usize) -> Result<&CaptureView> {
        self.views.get(index).ok_or_else(|| {
            Error::field(self.manifest_path(), "views", format!("no view {index} (capture has {})", self.views.len()))
        })
    }
}

fn view_from_raw(path: &Path, i: usize, raw: RawCaptureView) -> Result<CaptureView> {
    let field = |name: &str| format!("views[{i}].{name}");
    if raw.points.is_some() {
        return Err(Error::field(path, field("points"), "a capture view is a color image (PNG or JPEG), not points"));
    }
    let color = raw.color.ok_or_else(|| {
        Error::field(path, field("color"), "missing: a capture view needs a color image (PNG or JPEG)")
    })?;
    let Some(base_ee) = raw.base_ee else {
        let also = if raw.world_camera.is_some() { " (T_world_camera alone does not give the flange)" } else { "" };
        return Err(Error::field(
            path,
            field("T_base_ee"),
            format!("missing: each capture view needs the flange pose from the arm's forward kinematics{also}"),
        ));
    };
    if raw.world_camera.is_some() {
        return Err(Error::field(path, field("T_world_camera"), "give T_base_ee in a capture, not T_world_camera"));
    }
    if let Some(rows) = raw.world_base {
        let world_from_base = pose_field(path, &field("T_world_base"), &rows)?;
        let (t, r) = (world_from_base.translation.vector.norm(), world_from_base.rotation.angle());
        if t > IDENTITY_TOLERANCE || r > IDENTITY_TOLERANCE {
            return Err(Error::field(
                path,
                field("T_world_base"),
                format!(
                    "must be identity or absent in a capture (the tag is fixed in the robot base frame); this one \
                     moves the base {:.3} mm, {:.4} deg",
                    t * 1e3,
                    r.to_degrees()
                ),
            ));
        }
    }
    let base_from_ee = pose_field(path, &field("T_base_ee"), &base_ee)?;
    Ok(CaptureView { color, depth: raw.depth, base_from_ee })
}

/// Reads and validates the capture folder `dir` (or its `scan.json`): see the module docs.
///
/// # Errors
/// [`Error::Io`] when `scan.json` cannot be read; [`Error::Format`] for invalid JSON or a wrong
/// `format`; [`Error::Field`] naming the field for a missing camera or tag, no views, a view
/// without a color image or `T_base_ee`, a non-identity `T_world_base`, a non-rigid matrix, or a
/// depth image without `camera.depth_scale`.
pub fn read_capture(dir_or_manifest: &Path) -> Result<Capture> {
    let is_manifest = dir_or_manifest.is_file() || crate::io::extension(dir_or_manifest) == "json";
    let (dir, path) = if is_manifest {
        (dir_or_manifest.parent().map(Path::to_path_buf).unwrap_or_default(), dir_or_manifest.to_path_buf())
    } else {
        (dir_or_manifest.to_path_buf(), dir_or_manifest.join("scan.json"))
    };
    let raw: RawCapture = read_json(&path)?;
    if raw.format != FORMAT {
        return Err(Error::field(&path, "format", format!("expected \"{FORMAT}\", got \"{}\"", raw.format)));
    }
    let camera =
        raw.camera.ok_or_else(|| Error::field(&path, "camera", "missing: a capture needs the camera's intrinsics"))?;
    let intrinsics = intrinsics_from_parts(&path, "camera.", &camera.intrinsics)?;
    let tag = raw.tag.ok_or_else(|| {
        Error::field(&path, "tag", "missing: name the tag held fixed in the scene ({\"family\", \"id\", \"size\"})")
    })?;
    positive(&path, "tag.size", tag.size_m)?;
    if raw.views.is_empty() {
        return Err(Error::field(&path, "views", "the capture has no views"));
    }
    let views =
        raw.views.into_iter().enumerate().map(|(i, v)| view_from_raw(&path, i, v)).collect::<Result<Vec<_>>>()?;
    let depth_camera = match camera.depth_scale {
        Some(scale) => {
            let depth_min_m = camera.depth_min.unwrap_or(0.0);
            let depth_max_m = camera.depth_max.unwrap_or(f64::INFINITY);
            if !(depth_min_m >= 0.0 && depth_max_m > depth_min_m) {
                return Err(Error::field(
                    &path,
                    "camera.depth_max",
                    format!("empty depth range [{depth_min_m}, {depth_max_m}]"),
                ));
            }
            let depth_scale = positive(&path, "camera.depth_scale", scale)?;
            Some(DepthCamera { intrinsics, depth_scale, depth_min_m, depth_max_m })
        }
        None => None,
    };
    if depth_camera.is_none() && views.iter().any(|v| v.depth.is_some()) {
        return Err(Error::field(&path, "camera.depth_scale", "missing, but views have depth images"));
    }
    Ok(Capture { dir, intrinsics, depth_camera, tag, views })
}

/// Reads a camera intrinsics file (`K.json`): `{"width", "height", "fx", "fy", "cx", "cy",
/// "distortion"?}` (pixels; `distortion` Brown-Conrady `[k1, k2, p1, p2, k3]`, zeros when absent).
/// Given a scan's `scan.json` (it has `format`), its `camera` block is read instead.
///
/// # Errors
/// As [`read_camera_file`].
pub fn read_intrinsics(path: &Path) -> Result<Intrinsics> {
    Ok(read_camera_file(path)?.0)
}

/// The intrinsics of a `K.json` (see [`read_intrinsics`]) or of a scan folder's / capture's
/// `scan.json` (a folder is read as its `scan.json`), and the scan's `tag` when it names one. Only
/// the camera and the tag are read: a capture whose views have no depth is read as well as a scan.
///
/// # Errors
/// [`Error::Io`] when unreadable; [`Error::Format`] for invalid JSON or a missing key;
/// [`Error::Field`] naming the invalid field (`camera.fx`, `tag.size`, ...).
pub fn read_camera_file(path: &Path) -> Result<(Intrinsics, Option<TagSpec>)> {
    let path = if path.is_dir() { path.join("scan.json") } else { path.to_path_buf() };
    let path = path.as_path();
    let value: serde_json::Value = read_json(path)?;
    let is_scan = value.get("format").is_some();
    let (block, prefix) = if is_scan {
        let camera = value.get("camera").ok_or_else(|| Error::field(path, "camera", "missing"))?;
        (camera.clone(), "camera.")
    } else {
        (value.clone(), "")
    };
    let raw: RawIntrinsics = serde_json::from_value(block).map_err(|e| {
        Error::format(
            path,
            format!("not camera intrinsics ({{\"width\", \"height\", \"fx\", \"fy\", \"cx\", \"cy\", \"distortion\"?}}): {e}"),
        )
    })?;
    let intrinsics = intrinsics_from_parts(path, prefix, &raw)?;
    let tag = match value.get("tag").filter(|_| is_scan) {
        Some(t) => {
            let tag: TagSpec = serde_json::from_value(t.clone())
                .map_err(|e| Error::field(path, "tag", format!("expected {{\"family\", \"id\", \"size\"}}: {e}")))?;
            positive(path, "tag.size", tag.size_m)?;
            Some(tag)
        }
        None => None,
    };
    Ok((intrinsics, tag))
}
