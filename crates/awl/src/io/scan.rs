//! The scan folder (`awl-scan/1`, see `shared/spec/scan-format.md`): manifest reader and writer
//! of a [`Scan`], and loading of one view (from its files, or its images in memory) as a point
//! cloud in the camera frame.
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
use crate::io::write_atomic;
use crate::scan::{LoadedView, Scan, TagSpec, ViewData, ViewPose, ViewSpec};
use crate::transform::{Rows, isometry_from_rows, rows_from_isometry};

/// The format string of this version of the scan folder.
pub const FORMAT: &str = "awl-scan/1";

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
    #[serde(deserialize_with = "at_most_views")]
    views: Vec<RawView>,
}

/// The most views a scan.json may list: 100 000 (awl is built for scans of thousands; the list is
/// refused as it is parsed, before more are held).
pub const MAX_VIEWS: usize = 100_000;

/// `views`, refused at its [`MAX_VIEWS`]` + 1`-th entry.
fn at_most_views<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Vec<RawView>, D::Error> {
    at_most(d, MAX_VIEWS, || {
        format!("`views` lists more than {MAX_VIEWS} views, the most awl reads from one scan: split the scan")
    })
}

/// A JSON list refused with the message `too_many` at its `max + 1`-th entry, as it is parsed: the
/// vector grows only as entries arrive, so a huge list claims no memory in advance.
pub(crate) fn at_most<'de, D, T>(
    d: D,
    max: usize,
    too_many: impl Fn() -> String,
) -> std::result::Result<Vec<T>, D::Error>
where
    D: serde::Deserializer<'de>,
    T: Deserialize<'de>,
{
    struct AtMost<T, F> {
        max: usize,
        too_many: F,
        item: std::marker::PhantomData<T>,
    }
    impl<'de, T: Deserialize<'de>, F: Fn() -> String> serde::de::Visitor<'de> for AtMost<T, F> {
        type Value = Vec<T>;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            write!(f, "a list of at most {} entries", self.max)
        }
        fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> std::result::Result<Vec<T>, A::Error> {
            let mut items = Vec::new();
            while let Some(item) = seq.next_element()? {
                if items.len() == self.max {
                    return Err(serde::de::Error::custom((self.too_many)()));
                }
                items.push(item);
            }
            Ok(items)
        }
    }
    d.deserialize_seq(AtMost { max, too_many, item: std::marker::PhantomData })
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

/// Reads and parses a JSON file of at most [`MAX_JSON_BYTES`](crate::io::MAX_JSON_BYTES), naming
/// the file (and the line and column) on error.
pub(crate) fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T> {
    parse_json(path, &crate::io::read_bytes_at_most(path, crate::io::MAX_JSON_BYTES)?)
}

/// Parses JSON text, naming the file, line and column on error.
pub(crate) fn parse_json<T: serde::de::DeserializeOwned>(path: &Path, bytes: &[u8]) -> Result<T> {
    serde_json::from_slice(bytes).map_err(|e| {
        let token = token_at(bytes, e.line(), e.column());
        if ["NaN", "-NaN", "Infinity", "-Infinity", "nan", "inf", "-inf"].iter().any(|t| token.starts_with(t)) {
            let (line, column) = (e.line(), e.column());
            Error::format(path, format!("non-finite number `{token}` (NaN or infinity) at line {line} column {column}: every number must be finite"))
        } else if e.classify() == serde_json::error::Category::Data {
            // well-formed JSON whose content is refused: a missing key, a wrong type, a limit
            Error::format(path, e.to_string())
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
    let raw: RawScan = read_json(&path)?;
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
/// [`Error::Io`] when the manifest cannot be written; [`Error::Field`] (`views[i]`) for a view
/// whose images are held in memory (write them as files first).
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
    let path = Scan::manifest_path(&scan.dir);
    let views = scan
        .views
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let (depth, color, points) = match &v.data {
                ViewData::Depth { depth, color } => (Some(depth.clone()), color.clone(), None),
                ViewData::Points { points } => (None, None, Some(points.clone())),
                ViewData::Images { .. } => {
                    let why = "its images are held in memory: write them as files and name them first";
                    return Err(Error::field(&path, format!("views[{i}]"), why));
                }
            };
            let (world_camera, world_base, base_ee) = match &v.pose {
                ViewPose::Camera { world_from_camera } => (Some(rows_from_isometry(world_from_camera)), None, None),
                ViewPose::Chain { world_from_base, base_from_ee } => {
                    (None, Some(rows_from_isometry(world_from_base)), Some(rows_from_isometry(base_from_ee)))
                }
            };
            Ok(RawView { depth, color, points, world_camera, world_base, base_ee, extra: v.extra.clone() })
        })
        .collect::<Result<Vec<_>>>()?;
    let raw = RawScan {
        format: FORMAT.into(),
        camera,
        ee_camera: scan.ee_from_camera.as_ref().map(rows_from_isometry),
        tag: scan.tag.clone(),
        views,
    };
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

/// The depth image of a view's data, of every `step`-th row and column of the camera's
/// ([`read_depth_png_every_nth`] for a file, [`DepthImage::every_nth`] for one in memory), its size
/// checked against the scan's camera. `None` for a point-file view.
fn view_depth_every_nth<'a>(
    scan: &'a Scan,
    data: &ViewData,
    step: usize,
) -> Result<Option<(&'a DepthCamera, DepthImage)>> {
    let (camera, image) = match data {
        ViewData::Points { .. } => return Ok(None),
        ViewData::Depth { depth, .. } => {
            let camera = scan.depth_camera()?;
            let path = scan.dir.join(depth);
            let (image, (width, height)) = read_depth_png_every_nth(&path, step)?;
            check_size(&path, camera, width, height)?;
            (camera, image)
        }
        ViewData::Images { depth, .. } => {
            let camera = scan.depth_camera()?;
            check_size(&Scan::manifest_path(&scan.dir), camera, depth.width, depth.height)?;
            (camera, if step <= 1 { DepthImage::clone(depth) } else { depth.every_nth(step) })
        }
    };
    Ok(Some((camera, image)))
}

/// The color image of a view's data, of every `step`-th row and column of the camera's
/// ([`read_color_image_every_nth`] for a file: PNG or JPEG), its size checked against `camera`.
/// `None` when the view has no color image.
fn view_color_every_nth(scan: &Scan, camera: &DepthCamera, data: &ViewData, step: usize) -> Result<Option<ColorImage>> {
    match data {
        ViewData::Depth { color: Some(color), .. } => {
            let path = scan.dir.join(color);
            let (image, (width, height)) = read_color_image_every_nth(&path, step)?;
            check_size(&path, camera, width, height)?;
            Ok(Some(image))
        }
        ViewData::Images { color: Some(color), .. } => {
            check_size(&Scan::manifest_path(&scan.dir), camera, color.width, color.height)?;
            Ok(Some(if step <= 1 { ColorImage::clone(color) } else { color.every_nth(step) }))
        }
        _ => Ok(None),
    }
}

/// The color image of view `index` (a file, or held in memory), its size checked against the
/// scan's camera; `None` when the view has none.
///
/// # Errors
/// As [`load_view`].
pub fn read_view_color(scan: &Scan, index: usize) -> Result<Option<ColorImage>> {
    let data = &scan.view(index)?.data;
    if !data.has_color() {
        return Ok(None);
    }
    view_color_every_nth(scan, scan.depth_camera()?, data, 1)
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
    let Some((camera, image)) = view_depth_every_nth(scan, &scan.view(index)?.data, 1)? else { return Ok(None) };
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
    let data = &scan.view(index)?.data;
    if let ViewData::Points { points } = data {
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
        return Ok(LoadedView { world_from_camera, cloud_camera, pixels: None, color: None, warnings });
    }
    // the images decoded on the coarse grid: back-projected there with a step of 1
    let Some((camera, depth_image)) = view_depth_every_nth(scan, data, step)? else {
        return Err(Error::field(Scan::manifest_path(&scan.dir), format!("views[{index}]"), "has no depth image"));
    };
    let color = view_color_every_nth(scan, camera, data, step)?;
    let (cloud_camera, pixels) = back_project(&depth_image, color.as_ref(), camera, rays, step);
    Ok(LoadedView { world_from_camera, cloud_camera, pixels: Some(pixels), color, warnings: Vec::new() })
}
