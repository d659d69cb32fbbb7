//! The scan folder (`awl-scan/1`, see `shared/spec/scan-format.md`): manifest reader and writer,
//! and loading of one view as a point cloud in the camera frame.
//!
//! This is the only place where the manifest's 4x4 matrices become isometries; non-rigid matrices
//! are refused here with the file and the field named.

use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Point3};
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use crate::camera::{DepthCamera, Intrinsics, PixelRect, depth_points_in, depth_to_cloud_every_nth};
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::image::{ColorImage, DepthImage};
use crate::io::image::{read_color_image_every_nth, read_depth_png_every_nth};
use crate::io::{read_bytes, write_atomic};
use crate::transform::{Rows, isometry_from_rows, rows_from_isometry};

/// The format string of this version of the scan folder.
pub const FORMAT: &str = "awl-scan/1";

/// The fiducial stuck on the workpiece.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TagSpec {
    /// Tag family, e.g. `tag36h11`.
    pub family: String,
    /// Tag id within the family.
    pub id: u32,
    /// Black-border edge length, metres.
    #[serde(rename = "size")]
    pub size_m: f64,
}

/// Where a view's measurements are, relative to the scan folder.
#[derive(Debug, Clone, PartialEq)]
pub enum ViewData {
    /// A 16-bit depth PNG and an optional registered 8-bit color image (PNG or JPEG).
    Depth {
        /// Depth image path.
        depth: PathBuf,
        /// Color image path.
        color: Option<PathBuf>,
    },
    /// A point file (PLY or PCD) in the camera frame, metres.
    Points {
        /// Point file path.
        points: PathBuf,
    },
}

/// A view's recorded camera pose (the seed that registration refines).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ViewPose {
    /// The camera pose given directly.
    Camera {
        /// `T_world_camera`.
        world_from_camera: Isometry3<f64>,
    },
    /// SLAM base pose and arm forward kinematics; the camera pose also needs `T_ee_camera`.
    Chain {
        /// `T_world_base` (SLAM).
        world_from_base: Isometry3<f64>,
        /// `T_base_ee` (arm forward kinematics).
        base_from_ee: Isometry3<f64>,
    },
}

/// One view of a scan.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewSpec {
    /// The measurements.
    pub data: ViewData,
    /// The recorded pose.
    pub pose: ViewPose,
    /// Keys the spec does not define (kept so a rewrite does not lose a rig's metadata).
    pub extra: Map<String, Value>,
}

/// A scan folder's manifest, with validated poses. Paths are relative to `dir`.
#[derive(Debug, Clone, PartialEq)]
pub struct Scan {
    /// The folder holding `scan.json`.
    pub dir: PathBuf,
    /// The depth camera; required when any view has a depth image.
    pub camera: Option<DepthCamera>,
    /// `T_ee_camera`, the hand-eye calibration; required when any view gives `T_base_ee`.
    pub ee_from_camera: Option<Isometry3<f64>>,
    /// The tag on the workpiece, if any.
    pub tag: Option<TagSpec>,
    /// The views, in capture order.
    pub views: Vec<ViewSpec>,
    /// What the reader fixed and the user should know (a pose re-orthonormalised, naming its field).
    pub warnings: Vec<String>,
}

/// A view loaded into memory.
#[derive(Debug, Clone)]
pub struct LoadedView {
    /// The recorded camera pose, `T_world_camera`.
    pub world_from_camera: Isometry3<f64>,
    /// Points inside the depth range, camera frame, with colors when the view has them.
    pub cloud_camera: PointCloud,
    /// For a depth view, the pixel (`v * width + u`) each point came from.
    pub pixels: Option<Vec<u32>>,
    /// The color image, when the view has one ([`load_view_every_nth`]: its every `step`-th row
    /// and column).
    pub color: Option<ColorImage>,
    /// What loading the view's files dropped or ignored (a point file's non-finite points, bytes
    /// after its body), each naming the file.
    pub warnings: Vec<String>,
}

impl Scan {
    /// Path of `scan.json` in `dir`.
    pub fn manifest_path(dir: &Path) -> PathBuf {
        dir.join("scan.json")
    }

    /// View `index` of the manifest.
    ///
    /// # Errors
    /// [`Error::Field`] (`views`) when the index is out of range.
    pub fn view(&self, index: usize) -> Result<&ViewSpec> {
        self.views.get(index).ok_or_else(|| {
            Error::field(
                Self::manifest_path(&self.dir),
                "views",
                format!("no view {index} (scan has {})", self.views.len()),
            )
        })
    }

    /// Every file the scan reads: `scan.json` and each view's depth, color or point file (paths as
    /// the manifest names them, joined to `dir`; a view may name a file outside the folder).
    pub fn input_files(&self) -> Vec<PathBuf> {
        let mut files = vec![Self::manifest_path(&self.dir)];
        for v in &self.views {
            match &v.data {
                ViewData::Depth { depth, color } => {
                    files.push(self.dir.join(depth));
                    files.extend(color.iter().map(|c| self.dir.join(c)));
                }
                ViewData::Points { points } => files.push(self.dir.join(points)),
            }
        }
        files
    }

    /// The depth camera (`camera` in `scan.json`).
    ///
    /// # Errors
    /// [`Error::Field`] (`camera`) when the scan has none.
    pub fn depth_camera(&self) -> Result<&DepthCamera> {
        self.camera.as_ref().ok_or_else(|| Error::field(Self::manifest_path(&self.dir), "camera", "missing"))
    }

    /// The recorded `T_world_camera` of view `index`.
    ///
    /// # Errors
    /// [`Error::Field`] when the view gives `T_base_ee` but the scan has no `T_ee_camera`
    /// (the reader already refuses that, so only hand-built scans reach it), or the index is out of range.
    pub fn world_from_camera(&self, index: usize) -> Result<Isometry3<f64>> {
        let manifest = Self::manifest_path(&self.dir);
        match self.view(index)?.pose {
            ViewPose::Camera { world_from_camera } => Ok(world_from_camera),
            ViewPose::Chain { world_from_base, base_from_ee } => {
                let ee_from_camera = self
                    .ee_from_camera
                    .ok_or_else(|| Error::field(&manifest, "T_ee_camera", "missing, but views give T_base_ee"))?;
                Ok(world_from_base * base_from_ee * ee_from_camera)
            }
        }
    }
}

#[derive(Deserialize, Serialize)]
struct RawCamera {
    width: u32,
    height: u32,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    distortion: Option<Vec<f64>>,
    depth_scale: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    depth_min: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    depth_max: Option<f64>,
}

#[derive(Deserialize, Serialize)]
struct RawView {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    depth: Option<PathBuf>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    color: Option<PathBuf>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    points: Option<PathBuf>,
    #[serde(rename = "T_world_camera", default, skip_serializing_if = "Option::is_none")]
    world_camera: Option<Rows>,
    #[serde(rename = "T_world_base", default, skip_serializing_if = "Option::is_none")]
    world_base: Option<Rows>,
    #[serde(rename = "T_base_ee", default, skip_serializing_if = "Option::is_none")]
    base_ee: Option<Rows>,
    #[serde(flatten)]
    extra: Map<String, Value>,
}

#[derive(Deserialize, Serialize)]
struct RawScan {
    format: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    camera: Option<RawCamera>,
    #[serde(rename = "T_ee_camera", default, skip_serializing_if = "Option::is_none")]
    ee_camera: Option<Rows>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    tag: Option<TagSpec>,
    views: Vec<RawView>,
}

/// [`pose_field`], re-orthonormalising a rotation off by float32 rounding
/// ([`crate::transform::FLOAT32_RIGID_TOLERANCE`]) with a warning naming the field.
fn pose_field_lenient(path: &Path, field: &str, rows: &Rows, warnings: &mut Vec<String>) -> Result<Isometry3<f64>> {
    let (pose, deviation) =
        crate::transform::isometry_from_rows_reorthonormalised(rows).map_err(|m| Error::field(path, field, m))?;
    if let Some(dev) = deviation {
        warnings.push(format!(
            "{}: `{field}`: rotation off orthonormal by {dev:.1e} (float32 rounding?), re-orthonormalised",
            path.display()
        ));
    }
    Ok(pose)
}

/// Parses a 4x4 pose field, naming the file and the field when it is not rigid.
pub(crate) fn pose_field(path: &Path, field: &str, rows: &Rows) -> Result<Isometry3<f64>> {
    let pose = isometry_from_rows(rows).map_err(|m| Error::field(path, field, m))?;
    // the largest coordinate (a norm would overflow to infinity for 1e300)
    let d = pose.translation.vector.amax();
    if d > MAX_TRANSLATION_M {
        return Err(Error::field(
            path,
            field,
            format!(
                "a translation coordinate of {d:.3e} m, beyond the {MAX_TRANSLATION_M} m any awl frame spans: poses \
                 are in metres (not millimetres)"
            ),
        ));
    }
    Ok(pose)
}

/// The farthest a pose in a file may translate, metres (a SLAM map, a robot base, a camera: 100 km
/// is past any of them; a value beyond is a unit mistake or garbage).
pub const MAX_TRANSLATION_M: f64 = 1e5;

/// Parses JSON text, naming the file, line and column on error.
pub(crate) fn parse_json<T: serde::de::DeserializeOwned>(path: &Path, bytes: &[u8]) -> Result<T> {
    serde_json::from_slice(bytes).map_err(|e| {
        let token = token_at(bytes, e.line(), e.column());
        if ["NaN", "-NaN", "Infinity", "-Infinity", "nan", "inf", "-inf"].iter().any(|t| token.starts_with(t)) {
            let (line, column) = (e.line(), e.column());
            Error::format(path, format!("non-finite number `{token}` (NaN or infinity) at line {line} column {column}: every number must be finite"))
        } else {
            Error::format(path, format!("invalid JSON: {e}"))
        }
    })
}

/// The word starting at a 1-based (line, column) of `bytes` (serde_json points just past its start).
fn token_at(bytes: &[u8], line: usize, column: usize) -> String {
    let text = String::from_utf8_lossy(bytes);
    let Some(line_text) = text.lines().nth(line.saturating_sub(1)) else { return String::new() };
    let chars: Vec<char> = line_text.chars().collect();
    let word = |c: &char| c.is_alphanumeric() || *c == '-' || *c == '.';
    let mut begin = column.saturating_sub(1).min(chars.len());
    while begin > 0 && word(&chars[begin - 1]) {
        begin -= 1;
    }
    chars[begin..].iter().take_while(|c| word(c)).collect()
}

pub(crate) fn positive(path: &Path, field: &str, value: f64) -> Result<f64> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(Error::field(path, field, format!("must be a positive number, got {value}")))
    }
}

/// The intrinsics of a camera block (`prefix` names it in errors, e.g. `camera.`), validated: a
/// positive size and focal lengths, a finite principal point, up to 5 finite distortion terms.
pub(crate) fn intrinsics_from_parts(path: &Path, prefix: &str, raw: &RawIntrinsics) -> Result<Intrinsics> {
    if raw.width == 0 || raw.height == 0 {
        return Err(Error::field(path, format!("{prefix}width"), "image size must be positive"));
    }
    crate::io::image::check_image_pixels(u64::from(raw.width), u64::from(raw.height))
        .map_err(|m| Error::field(path, format!("{prefix}width"), m))?;
    let mut distortion = [0.0; 5];
    if let Some(d) = &raw.distortion {
        if d.len() > 5 || d.iter().any(|k| !k.is_finite()) {
            return Err(Error::field(
                path,
                format!("{prefix}distortion"),
                "expected up to 5 finite numbers [k1, k2, p1, p2, k3]",
            ));
        }
        distortion[..d.len()].copy_from_slice(d);
    }
    let intrinsics = Intrinsics {
        width: raw.width,
        height: raw.height,
        fx: positive(path, &format!("{prefix}fx"), raw.fx)?,
        fy: positive(path, &format!("{prefix}fy"), raw.fy)?,
        cx: raw.cx,
        cy: raw.cy,
        distortion,
    };
    if !raw.cx.is_finite() || !raw.cy.is_finite() {
        return Err(Error::field(path, format!("{prefix}cx"), "principal point must be finite"));
    }
    Ok(intrinsics)
}

/// A camera's intrinsics as JSON gives them (`distortion` optional).
#[derive(Deserialize, Serialize)]
pub(crate) struct RawIntrinsics {
    pub(crate) width: u32,
    pub(crate) height: u32,
    pub(crate) fx: f64,
    pub(crate) fy: f64,
    pub(crate) cx: f64,
    pub(crate) cy: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(crate) distortion: Option<Vec<f64>>,
}

fn camera_from_raw(path: &Path, raw: &RawCamera) -> Result<DepthCamera> {
    let parts = RawIntrinsics {
        width: raw.width,
        height: raw.height,
        fx: raw.fx,
        fy: raw.fy,
        cx: raw.cx,
        cy: raw.cy,
        distortion: raw.distortion.clone(),
    };
    let intrinsics = intrinsics_from_parts(path, "camera.", &parts)?;
    let depth_min_m = raw.depth_min.unwrap_or(0.0);
    let depth_max_m = raw.depth_max.unwrap_or(f64::INFINITY);
    if !(depth_min_m >= 0.0 && depth_max_m > depth_min_m) {
        return Err(Error::field(
            path,
            "camera.depth_max",
            format!("empty depth range [{depth_min_m}, {depth_max_m}]"),
        ));
    }
    Ok(DepthCamera {
        intrinsics,
        depth_scale: positive(path, "camera.depth_scale", raw.depth_scale)?,
        depth_min_m,
        depth_max_m,
    })
}

fn view_from_raw(
    path: &Path,
    i: usize,
    raw: RawView,
    has_hand_eye: bool,
    warnings: &mut Vec<String>,
) -> Result<ViewSpec> {
    let field = |name: &str| format!("views[{i}].{name}");
    let data = match (raw.depth, raw.points) {
        (Some(depth), None) => ViewData::Depth { depth, color: raw.color },
        (None, Some(points)) if raw.color.is_none() => ViewData::Points { points },
        (None, Some(_)) => {
            return Err(Error::field(path, field("color"), "a color image goes with a depth image, not with points"));
        }
        (Some(_), Some(_)) => {
            return Err(Error::field(path, field("points"), "a view gives either depth or points, not both"));
        }
        (None, None) => return Err(Error::field(path, field("depth"), "a view needs `depth` or `points`")),
    };
    let pose = match (raw.world_camera, raw.world_base, raw.base_ee) {
        (Some(rows), None, None) => {
            ViewPose::Camera { world_from_camera: pose_field_lenient(path, &field("T_world_camera"), &rows, warnings)? }
        }
        (None, Some(wb), Some(be)) => {
            if !has_hand_eye {
                return Err(Error::field(path, "T_ee_camera", format!("missing, but views[{i}] gives T_base_ee")));
            }
            ViewPose::Chain {
                world_from_base: pose_field_lenient(path, &field("T_world_base"), &wb, warnings)?,
                base_from_ee: pose_field_lenient(path, &field("T_base_ee"), &be, warnings)?,
            }
        }
        (Some(_), _, _) => {
            return Err(Error::field(
                path,
                field("T_world_camera"),
                "give T_world_camera or T_world_base + T_base_ee, not both",
            ));
        }
        (None, Some(_), None) => return Err(Error::field(path, field("T_base_ee"), "missing (T_world_base is given)")),
        (None, None, Some(_)) => return Err(Error::field(path, field("T_world_base"), "missing (T_base_ee is given)")),
        (None, None, None) => return Err(Error::field(path, field("T_world_camera"), "a view needs a pose")),
    };
    Ok(ViewSpec { data, pose, extra: raw.extra })
}

/// Reads and validates `DIR/scan.json` (or the file itself when given a path to it).
///
/// # Errors
/// [`Error::Io`] when the manifest cannot be read; [`Error::Format`] for invalid JSON or a wrong
/// `format`; [`Error::Field`] for a missing or invalid field (non-rigid matrix, NaN, no views,...).
pub fn read_scan(dir_or_manifest: &Path) -> Result<Scan> {
    let is_manifest = dir_or_manifest.is_file() || crate::io::extension(dir_or_manifest) == "json";
    let (dir, path) = if !is_manifest {
        (dir_or_manifest.to_path_buf(), Scan::manifest_path(dir_or_manifest))
    } else {
        let dir = dir_or_manifest.parent().map(Path::to_path_buf).unwrap_or_default();
        (dir, dir_or_manifest.to_path_buf())
    };
    let raw: RawScan = parse_json(&path, &read_bytes(&path)?)?;
    if raw.format != FORMAT {
        return Err(Error::field(&path, "format", format!("expected \"{FORMAT}\", got \"{}\"", raw.format)));
    }
    if raw.views.is_empty() {
        return Err(Error::field(&path, "views", "the scan has no views"));
    }
    let camera = raw.camera.as_ref().map(|c| camera_from_raw(&path, c)).transpose()?;
    let mut warnings = Vec::new();
    let ee_from_camera =
        raw.ee_camera.map(|rows| pose_field_lenient(&path, "T_ee_camera", &rows, &mut warnings)).transpose()?;
    if let Some(tag) = &raw.tag {
        positive(&path, "tag.size", tag.size_m)?;
    }
    let views = raw
        .views
        .into_iter()
        .enumerate()
        .map(|(i, v)| view_from_raw(&path, i, v, ee_from_camera.is_some(), &mut warnings))
        .collect::<Result<Vec<_>>>()?;
    if camera.is_none() && views.iter().any(|v| matches!(v.data, ViewData::Depth { .. })) {
        return Err(Error::field(&path, "camera", "missing, but views have depth images"));
    }
    Ok(Scan { dir, camera, ee_from_camera, tag: raw.tag, views, warnings })
}

/// Writes `scan.dir/scan.json` atomically (images and point files are the caller's to write).
///
/// # Errors
/// [`Error::Io`] when the manifest cannot be written.
pub fn write_scan(scan: &Scan) -> Result<()> {
    let camera = scan.camera.map(|c| RawCamera {
        width: c.intrinsics.width,
        height: c.intrinsics.height,
        fx: c.intrinsics.fx,
        fy: c.intrinsics.fy,
        cx: c.intrinsics.cx,
        cy: c.intrinsics.cy,
        distortion: Some(c.intrinsics.distortion.to_vec()),
        depth_scale: c.depth_scale,
        depth_min: Some(c.depth_min_m),
        depth_max: c.depth_max_m.is_finite().then_some(c.depth_max_m),
    });
    let views = scan
        .views
        .iter()
        .map(|v| {
            let (depth, color, points) = match &v.data {
                ViewData::Depth { depth, color } => (Some(depth.clone()), color.clone(), None),
                ViewData::Points { points } => (None, None, Some(points.clone())),
            };
            let (world_camera, world_base, base_ee) = match &v.pose {
                ViewPose::Camera { world_from_camera } => (Some(rows_from_isometry(world_from_camera)), None, None),
                ViewPose::Chain { world_from_base, base_from_ee } => {
                    (None, Some(rows_from_isometry(world_from_base)), Some(rows_from_isometry(base_from_ee)))
                }
            };
            RawView { depth, color, points, world_camera, world_base, base_ee, extra: v.extra.clone() }
        })
        .collect();
    let raw = RawScan {
        format: FORMAT.into(),
        camera,
        ee_camera: scan.ee_from_camera.as_ref().map(rows_from_isometry),
        tag: scan.tag.clone(),
        views,
    };
    let path = Scan::manifest_path(&scan.dir);
    let text = serde_json::to_string_pretty(&raw).map_err(|e| Error::invalid("scan manifest", e.to_string()))?;
    write_atomic(&path, text.as_bytes())
}

pub(crate) fn check_size(path: &Path, camera: &DepthCamera, width: u32, height: u32) -> Result<()> {
    let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
    if (width, height) != (w, h) {
        return Err(Error::format(path, format!("image is {width}x{height}, scan.json camera says {w}x{h}")));
    }
    Ok(())
}

/// The scan's camera and the depth image at `depth` (relative to the scan folder), its size checked.
fn read_depth<'a>(scan: &'a Scan, depth: &Path) -> Result<(&'a DepthCamera, DepthImage)> {
    read_depth_every_nth(scan, depth, 1)
}

/// [`read_depth`] keeping every `step`-th row and column ([`read_depth_png_every_nth`]).
fn read_depth_every_nth<'a>(scan: &'a Scan, depth: &Path, step: usize) -> Result<(&'a DepthCamera, DepthImage)> {
    let camera = scan.depth_camera()?;
    let depth_path = scan.dir.join(depth);
    let (image, (width, height)) = read_depth_png_every_nth(&depth_path, step)?;
    check_size(&depth_path, camera, width, height)?;
    Ok((camera, image))
}

/// The color image at `color` (relative to the scan folder), its size checked against `camera`.
pub(crate) fn read_color(scan: &Scan, camera: &DepthCamera, color: &Path) -> Result<ColorImage> {
    read_color_every_nth(scan, camera, color, 1)
}

/// [`read_color`] keeping every `step`-th row and column ([`read_color_image_every_nth`]: PNG or JPEG).
fn read_color_every_nth(scan: &Scan, camera: &DepthCamera, color: &Path, step: usize) -> Result<ColorImage> {
    let color_path = scan.dir.join(color);
    let (image, (width, height)) = read_color_image_every_nth(&color_path, step)?;
    check_size(&color_path, camera, width, height)?;
    Ok(image)
}

/// The points of `depth` and `color`, images of every `step`-th row and column of the camera's
/// ([`read_depth_png_every_nth`]): [`depth_to_cloud_every_nth`] on them with a step of 1 and the
/// camera's `ray_table_every_nth(step)`, built here when `rays` is `None`. The same points and
/// pixel numbers as the full images with `step`.
fn back_project(
    depth: &DepthImage,
    color: Option<&ColorImage>,
    camera: &DepthCamera,
    rays: Option<&[[f32; 2]]>,
    step: usize,
) -> (PointCloud, Vec<u32>) {
    match rays {
        Some(rays) => depth_to_cloud_every_nth(depth, color, camera, rays, 1),
        None => depth_to_cloud_every_nth(depth, color, camera, &camera.intrinsics.ray_table_every_nth(step), 1),
    }
}

/// A depth view's points in the camera frame (depth range applied), without colors: the color
/// image is not read; only those of the pixels in `rect` when given (their rays computed, no ray
/// table). `None` for a point-file view.
///
/// # Errors
/// As [`load_view`].
pub fn load_depth_points(scan: &Scan, index: usize, rect: Option<&PixelRect>) -> Result<Option<Vec<Point3<f32>>>> {
    let ViewData::Depth { depth, .. } = &scan.view(index)?.data else { return Ok(None) };
    let (camera, image) = read_depth(scan, depth)?;
    let whole = PixelRect { u: 0..image.width, v: 0..image.height };
    Ok(Some(depth_points_in(&image, camera, rect.unwrap_or(&whole))))
}

/// Loads view `index`: its points in the camera frame (depth range applied), colors, and seed pose.
///
/// # Errors
/// Any error of the image or point-file readers (naming the file); [`Error::Format`] when an image
/// size does not match the camera.
pub fn load_view(scan: &Scan, index: usize, rays: Option<&[[f32; 2]]>) -> Result<LoadedView> {
    load_view_every_nth(scan, index, rays, 1)
}

/// [`load_view`] keeping a depth view's pixels on every `step`-th row and column only, each
/// point's pixel numbered on that coarser grid ([`crate::camera::every_nth_grid`]; see
/// [`crate::camera::depth_to_cloud_every_nth`]); `rays`, when given, is the camera's
/// `ray_table_every_nth(step)`. A point-file view is loaded whole.
///
/// # Errors
/// As [`load_view`].
pub fn load_view_every_nth(scan: &Scan, index: usize, rays: Option<&[[f32; 2]]>, step: usize) -> Result<LoadedView> {
    let world_from_camera = scan.world_from_camera(index)?;
    match &scan.view(index)?.data {
        ViewData::Depth { depth, color } => {
            // the images decoded on the coarse grid: back-projected there with a step of 1
            let (camera, depth_image) = read_depth_every_nth(scan, depth, step)?;
            let color = color.as_deref().map(|c| read_color_every_nth(scan, camera, c, step)).transpose()?;
            let (cloud_camera, pixels) = back_project(&depth_image, color.as_ref(), camera, rays, step);
            Ok(LoadedView { world_from_camera, cloud_camera, pixels: Some(pixels), color, warnings: Vec::new() })
        }
        ViewData::Points { points } => {
            let crate::io::Loaded { value: mut cloud_camera, warnings } =
                crate::io::mesh::read_cloud_checked(&scan.dir.join(points))?;
            if let Some(camera) = &scan.camera {
                let keep: Vec<usize> = (0..cloud_camera.len())
                    .filter(|&i| {
                        let z = f64::from(cloud_camera.points[i].z);
                        z >= camera.depth_min_m && z <= camera.depth_max_m
                    })
                    .collect();
                cloud_camera = cloud_camera.select(&keep);
            }
            Ok(LoadedView { world_from_camera, cloud_camera, pixels: None, color: None, warnings })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::every_nth_grid;
    use crate::sim::{SceneKind, SimParams, simulate, write_simulation};

    /// A view loaded at every `step`-th pixel, from images decoded on that grid only: the points,
    /// colors and pixel numbers of the full images back-projected at that step.
    #[test]
    fn every_nth_pixel_equals_the_full_images_at_that_step() {
        let sim = simulate(&SimParams { views: 1, seed: 5, ..SimParams::scan(SceneKind::Box) }).expect("simulate");
        let dir = tempfile::tempdir().expect("tempdir");
        write_simulation(dir.path(), &sim, false).expect("write");
        let scan = read_scan(dir.path()).expect("read");
        let ViewData::Depth { depth, color: Some(color) } = &scan.views[0].data else { panic!("a color depth view") };
        let (camera, full_depth) = read_depth(&scan, depth).expect("depth");
        let full_color = read_color(&scan, camera, color).expect("color");
        for step in [1, 2, 3] {
            let rays = camera.intrinsics.ray_table_every_nth(step);
            let (want, want_pixels) = depth_to_cloud_every_nth(&full_depth, Some(&full_color), camera, &rays, step);
            assert!(want.len() > 10_000 / (step * step), "{} points at step {step}", want.len());
            for table in [Some(rays.as_slice()), None] {
                let got = load_view_every_nth(&scan, 0, table, step).expect("view");
                assert_eq!(got.cloud_camera, want, "step {step}");
                assert_eq!(got.pixels.as_deref(), Some(want_pixels.as_slice()), "step {step}");
                let thinned = got.color.expect("color image");
                let (w, h) = every_nth_grid(full_color.width as usize, full_color.height as usize, step);
                assert_eq!((thinned.width as usize, thinned.height as usize), (w, h));
                assert_eq!(thinned.data[w + 1], full_color.data[step * full_color.width as usize + step]);
            }
        }
    }
}
