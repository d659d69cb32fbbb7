//! `world_from_tag` from the color views of a fused scan: detect the declared tag in every view,
//! estimate its pose (the planar ambiguity resolved by the view's depth points), map it to the world
//! with the view's registered pose, reject outliers and average (see [`robust_mean`]).

use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::camera::{Intrinsics, PixelRect};
use crate::error::{Error, Result};
use crate::image::ColorImage;
use crate::io::scan::{load_depth_points, read_view_color};
use crate::scan::{Scan, TagSpec};
use crate::tag::SUPPORTED_FAMILY;
use crate::tag::{
    AprilTagDetector, DetectorParams, TagDetection, TagDetector, TagPoseSolution, estimate_tag_pose, score_depth,
};
use crate::workpiece::mean::{MeanParams, robust_mean};

/// Parameters of [`estimate_world_from_tag`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TagEstimateParams {
    /// The AprilTag detector's settings. Default: [`DetectorParams::default`].
    pub detector: DetectorParams,
    /// A detection whose pose reprojects its corners worse than this is rejected, pixels. Default 1.5.
    pub max_rmse_px: f64,
    /// A detection whose shortest quad edge is below this is rejected (too small for a reliable
    /// pose), pixels. Default 20.
    pub min_side_px: f64,
    /// Outlier rejection and averaging of the per-view poses. Default: [`MeanParams::default`].
    pub mean: MeanParams,
}

impl Default for TagEstimateParams {
    fn default() -> Self {
        Self { detector: DetectorParams::default(), max_rmse_px: 1.5, min_side_px: 20.0, mean: MeanParams::default() }
    }
}

/// One tag detected in one view.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewTagDetection {
    /// Index of the view in the scan.
    pub view: usize,
    /// Decoded tag id.
    pub id: u32,
    /// Black-border corners in AprilTag order, pixels (integer = pixel centre).
    pub corners_px: [[f64; 2]; 4],
    /// Reprojection RMSE of the chosen pose solution, pixels (NaN when no pose was estimated).
    pub rmse_px: f64,
    /// True when the depth points preferred the second planar-ambiguity solution.
    pub flipped_by_depth: bool,
    /// The tag pose this view gives, `T_world_tag` (None when no pose was estimated).
    pub world_from_tag: Option<Isometry3<f64>>,
    /// True when this detection went into the mean.
    pub used: bool,
    /// Why it was rejected (empty when used).
    pub reason: String,
}

/// A view handed to [`estimate_from_views`]: its image, depth points and registered pose.
#[derive(Debug, Clone, Copy)]
pub struct TagView<'a> {
    /// Index of the view in the scan (reported back in [`ViewTagDetection::view`]).
    pub index: usize,
    /// The color image.
    pub image: &'a ColorImage,
    /// The view's depth points, camera frame (may be empty: then the ambiguity is not resolved by depth).
    pub points_camera: &'a [Point3<f32>],
    /// The view's registered `T_world_camera`.
    pub world_from_camera: Isometry3<f64>,
}

/// A used detection's line of sight, world frame: from the camera centre through the tag origin it saw.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sighting {
    /// The view.
    pub view: usize,
    /// The camera centre.
    pub camera: Point3<f64>,
    /// The tag origin this view estimated (its direction from the camera is precise; its range is not).
    pub tag_origin: Point3<f64>,
}

/// Result of the tag estimation.
#[derive(Debug, Clone, PartialEq)]
pub struct TagEstimate {
    /// The mean `T_world_tag`; None when no view saw the declared tag usably.
    pub world_from_tag: Option<Isometry3<f64>>,
    /// The views searched for the tag: those with a color image and a registered pose (in
    /// [`search_tags`], less those whose seed camera is behind the tag's face as seen before).
    pub views_checked: Vec<usize>,
    /// Every tag found in those views, used or not.
    pub detections: Vec<ViewTagDetection>,
    /// The lines of sight of the detections used (for [`crate::workpiece::refine_on_model`]).
    pub sightings: Vec<Sighting>,
    /// What the caller should tell the user (e.g. the tag was not seen).
    pub warnings: Vec<String>,
}

/// Checks that `tag` can be detected.
///
/// # Errors
/// [`Error::Invalid`] for another family than tag36h11 or a non-positive size.
pub fn check_tag_spec(tag: &TagSpec) -> Result<()> {
    if tag.family != SUPPORTED_FAMILY {
        return Err(Error::invalid(
            "tag.family",
            format!("\"{}\" is not supported (only {SUPPORTED_FAMILY})", tag.family),
        ));
    }
    if !(tag.size_m.is_finite() && tag.size_m > 0.0) {
        return Err(Error::invalid("tag.size", format!("must be a positive length in metres, got {}", tag.size_m)));
    }
    Ok(())
}

fn shortest_side_px(c: &[[f64; 2]; 4]) -> f64 {
    (0..4)
        .map(|i| ((c[i][0] - c[(i + 1) % 4][0]).powi(2) + (c[i][1] - c[(i + 1) % 4][1]).powi(2)).sqrt())
        .fold(f64::INFINITY, f64::min)
}

/// A detection posed in its view's camera frame, checked, not yet placed in the world.
#[derive(Debug, Clone, PartialEq)]
struct Posed {
    /// The detection (`world_from_tag` None until [`place`]).
    detection: ViewTagDetection,
    /// The chosen pose solution (None when no pose was estimated).
    camera_from_tag: Option<Isometry3<f64>>,
    /// The other solution of the planar ambiguity, when distinct and within `max_rmse_px` of the
    /// corners (as plausible as an accepted detection).
    camera_from_tag_other: Option<Isometry3<f64>>,
}

/// Detects and poses the tags of one view (every id; only the declared one gets a pose).
fn detect_view(
    detector: &mut AprilTagDetector,
    view: &TagView<'_>,
    intrinsics: &Intrinsics,
    tag: &TagSpec,
    params: &TagEstimateParams,
) -> Result<Vec<Found>> {
    let found = detector.detect_color(view.image)?;
    Ok(place(pose_detections(found, view.index, view.points_camera, intrinsics, tag, params), &view.world_from_camera))
}

/// The detections of view `index` posed in its camera frame: the declared tag posed (its planar
/// ambiguity resolved by the view's depth points) and checked, the others listed with the reason.
fn pose_detections(
    found: Vec<TagDetection>,
    index: usize,
    points_camera: &[Point3<f32>],
    intrinsics: &Intrinsics,
    tag: &TagSpec,
    params: &TagEstimateParams,
) -> Vec<Posed> {
    let mut out = Vec::new();
    for d in found {
        let mut det = ViewTagDetection {
            view: index,
            id: d.id,
            corners_px: d.corners_px,
            rmse_px: f64::NAN,
            flipped_by_depth: false,
            world_from_tag: None,
            used: false,
            reason: String::new(),
        };
        if d.id != tag.id {
            det.reason = format!("tag id {} is not the declared id {}", d.id, tag.id);
            out.push(Posed { detection: det, camera_from_tag: None, camera_from_tag_other: None });
            continue;
        }
        let side = shortest_side_px(&d.corners_px);
        let mut pose = match estimate_tag_pose(&d.corners_px, intrinsics, tag.size_m) {
            Ok(p) => p,
            Err(e) => {
                det.reason = format!("no pose: {e}");
                out.push(Posed { detection: det, camera_from_tag: None, camera_from_tag_other: None });
                continue;
            }
        };
        if score_depth(&pose, &d.corners_px, intrinsics, points_camera).prefers_second() {
            pose = pose.swapped();
            det.flipped_by_depth = true;
        }
        det.rmse_px = pose.best.rmse_px;
        if side < params.min_side_px {
            det.reason = format!("tag too small in the image ({side:.1} px < {} px)", params.min_side_px);
        } else if det.rmse_px > params.max_rmse_px {
            det.reason = format!("reprojection RMSE {:.2} px > {} px", det.rmse_px, params.max_rmse_px);
        } else {
            det.used = true;
        }
        let plausible = |s: &TagPoseSolution| s.rmse_px <= params.max_rmse_px;
        let camera_from_tag_other = pose.second.filter(plausible).map(|s| s.camera_from_tag);
        out.push(Posed { detection: det, camera_from_tag: Some(pose.best.camera_from_tag), camera_from_tag_other });
    }
    out
}

/// A view's posed detections placed in the world by its registered pose, each with the camera
/// centre.
fn place(posed: Vec<Posed>, world_from_camera: &Isometry3<f64>) -> Vec<Found> {
    let camera = Point3::from(world_from_camera.translation.vector);
    posed
        .into_iter()
        .map(|p| {
            let world_from_tag = p.camera_from_tag.map(|t| world_from_camera * t);
            (ViewTagDetection { world_from_tag, ..p.detection }, camera)
        })
        .collect()
}

/// Estimates `T_world_tag` from in-memory views (see the module docs). Views that do not see the
/// tag are not errors: the estimate is None and a warning names the views searched. When no view
/// holds a usable detection, they are searched again with [`DetectorParams::thorough`].
///
/// # Errors
/// [`Error::Invalid`] for an unsupported tag spec or when the detector cannot run.
pub fn estimate_from_views(
    views: &[TagView<'_>],
    intrinsics: &Intrinsics,
    tag: &TagSpec,
    params: &TagEstimateParams,
) -> Result<TagEstimate> {
    check_tag_spec(tag)?;
    let search = |detector_params: &DetectorParams| {
        detect_each(views.len(), detector_params, |detector, k| {
            Ok((views[k].index, detect_view(detector, &views[k], intrinsics, tag, params)?))
        })
    };
    let mut searched = search(&params.detector)?;
    let seen = |searched: &[(usize, Vec<Found>)]| searched.iter().flat_map(|(_, f)| f).any(|(d, _)| d.used);
    if let Some(thorough) = params.detector.thorough().filter(|_| !seen(&searched)) {
        searched = search(&thorough)?;
    }
    let views_checked = searched.iter().map(|(index, _)| *index).collect();
    finish(searched.into_iter().flat_map(|(_, found)| found).collect(), views_checked, tag, params)
}

/// A detection and the camera centre of its view (world frame).
type Found = (ViewTagDetection, Point3<f64>);

/// `detect(detector, k)` for `k` in `0..n`, in order of `k`, in parallel on one detector per
/// thread, each taking one contiguous run of `k` (a detector's decode table costs as much CPU as
/// a view's detection; rayon's `map_init` builds one per job, not per thread).
fn detect_each<T: Send>(
    n: usize,
    params: &DetectorParams,
    detect: impl Fn(&mut AprilTagDetector, usize) -> Result<T> + Sync + Send,
) -> Result<Vec<T>> {
    params.check()?;
    let run = n.div_ceil(rayon::current_num_threads().max(1)).max(1);
    let runs: Vec<Vec<T>> = (0..n.div_ceil(run))
        .into_par_iter()
        .map(|r| {
            let mut detector = AprilTagDetector::new(params)?;
            (r * run..n.min((r + 1) * run)).map(|k| detect(&mut detector, k)).collect()
        })
        .collect::<Result<_>>()?;
    Ok(runs.into_iter().flatten().collect())
}

fn finish(
    found: Vec<Found>,
    views_checked: Vec<usize>,
    tag: &TagSpec,
    params: &TagEstimateParams,
) -> Result<TagEstimate> {
    let (mut detections, cameras): (Vec<ViewTagDetection>, Vec<Point3<f64>>) = found.into_iter().unzip();
    let mut warnings = Vec::new();
    let candidates: Vec<usize> = (0..detections.len()).filter(|&i| detections[i].used).collect();
    let poses: Vec<Isometry3<f64>> = candidates.iter().filter_map(|&i| detections[i].world_from_tag).collect();
    let mut world_from_tag = None;
    if poses.is_empty() {
        let seen: Vec<String> = detections.iter().map(|d| format!("view {}: {}", d.view, d.reason)).collect();
        let list: Vec<String> = views_checked.iter().map(usize::to_string).collect();
        let detail = if seen.is_empty() { String::new() } else { format!(" ({})", seen.join("; ")) };
        warnings.push(format!(
            "tag {} id {} not found usably in any of the views checked [{}]{detail}: no T_world_tag",
            tag.family,
            tag.id,
            list.join(", ")
        ));
    } else {
        let mean = robust_mean(&poses, &params.mean)?;
        for (k, &i) in candidates.iter().enumerate() {
            if let Some(reason) = &mean.rejected[k] {
                detections[i].used = false;
                detections[i].reason = if mean.agreed {
                    reason.clone()
                } else {
                    format!("disagrees with the other detection(s) ({reason}); none is used")
                };
            }
        }
        if !mean.agreed {
            let list: Vec<String> = candidates
                .iter()
                .map(|&i| {
                    let d = &detections[i];
                    let t = d.world_from_tag.map_or(nalgebra::Vector3::zeros(), |t| t.translation.vector);
                    format!("view {} at ({:.4}, {:.4}, {:.4}) m", d.view, t.x, t.y, t.z)
                })
                .collect();
            warnings.push(format!(
                "the {} detections of tag {} id {} disagree beyond {:.0} mm / {:.1} deg ({}): none is used, as awl cannot \
                 tell which is right; check the camera's intrinsics, the views' poses and T_ee_camera, or add a view \
                 of the tag",
                candidates.len(),
                tag.family,
                tag.id,
                params.mean.max_translation_m * 1e3,
                params.mean.max_rotation_rad.to_degrees(),
                list.join(", ")
            ));
        } else {
            world_from_tag = Some(mean.mean);
        }
        if mean.agreed && mean.used < 2 {
            warnings.push(format!("T_world_tag rests on a single view (view {})", detections[candidates[0]].view));
        }
    }
    let sightings = detections
        .iter()
        .zip(&cameras)
        .filter_map(|(d, c)| {
            let t = d.world_from_tag.filter(|_| d.used)?;
            Some(Sighting { view: d.view, camera: *c, tag_origin: Point3::from(t.translation.vector) })
        })
        .collect();
    Ok(TagEstimate { world_from_tag, views_checked, detections, sightings, warnings })
}

/// The declared tag searched for in every color view of a scan and posed in each view's camera
/// frame: needs no registered pose, so it can run beside the fuse; [`TagSearch::place`] then maps
/// it to the world with the fuse's poses.
#[derive(Debug, Clone, PartialEq)]
pub struct TagSearch {
    /// The tag searched for.
    pub tag: TagSpec,
    /// Each view searched (those with a color image, less those behind the tag's face as seen
    /// before, by the seed poses): its index and what was found in it.
    views: Vec<(usize, Vec<Posed>)>,
}

/// A camera more than this beyond the plane of a tag's face (the angle between the face's outward
/// normal and the direction to the camera; the face turns away at 90°) cannot see the tag, degrees.
/// The margin covers the seed poses' errors (about 1° and 1-3 cm between views).
const BEHIND_FACE_DEG: f64 = 100.0;

/// A used detection of the declared tag placed by its view's seed pose: the tag's origin and the
/// outward normal of each solution of the planar ambiguity, world frame.
struct SeenFace {
    origin: Point3<f64>,
    normals: Vec<Vector3<f64>>,
}

impl SeenFace {
    fn of(posed: &Posed, world_from_camera: &Isometry3<f64>) -> Option<Self> {
        let best = posed.camera_from_tag.filter(|_| posed.detection.used)?;
        let normal = |t: Isometry3<f64>| (world_from_camera * t) * Vector3::z();
        let normals = std::iter::once(best).chain(posed.camera_from_tag_other).map(normal).collect();
        Some(Self { origin: world_from_camera * Point3::from(best.translation.vector), normals })
    }
}

/// True when the camera of `world_from_camera` is behind the face of a sighting in `faces`,
/// whichever of its plausible planar-ambiguity solutions is the right one.
fn behind_a_face(faces: &[SeenFace], world_from_camera: &Isometry3<f64>) -> bool {
    let min_cos = BEHIND_FACE_DEG.to_radians().cos();
    let camera = Point3::from(world_from_camera.translation.vector);
    faces.iter().any(|f| {
        let to_camera = (camera - f.origin).normalize();
        f.normals.iter().all(|n| n.dot(&to_camera) < min_cos)
    })
}

/// Searches the color views of `scan` for its declared tag (see [`TagSearch`]): `None` when the
/// scan declares no tag. When no view holds a usable detection, the views are searched again with
/// [`DetectorParams::thorough`] (a very dim tag).
///
/// # Errors
/// [`Error::Invalid`] for an unsupported tag spec or when the detector cannot run;
/// [`Error::Field`] for a scan without a camera; any error of loading a view.
pub fn search_tags(scan: &Scan, params: &TagEstimateParams) -> Result<Option<TagSearch>> {
    let Some(tag) = scan.tag.as_ref() else { return Ok(None) };
    check_tag_spec(tag)?;
    let mut views = search_views(scan, tag, params, &params.detector)?;
    let seen = |views: &[(usize, Vec<Posed>)]| views.iter().flat_map(|(_, p)| p).any(|p| p.detection.used);
    if let Some(thorough) = params.detector.thorough().filter(|_| !seen(&views)) {
        views = search_views(scan, tag, params, &thorough)?;
    }
    Ok(Some(TagSearch { tag: tag.clone(), views }))
}

/// [`search_tags`]'s pass over the views with `detector_params`: each view searched, with what it
/// holds.
fn search_views(
    scan: &Scan,
    tag: &TagSpec,
    params: &TagEstimateParams,
    detector_params: &DetectorParams,
) -> Result<Vec<(usize, Vec<Posed>)>> {
    let camera = scan.depth_camera()?;
    let (width, height) = (camera.intrinsics.width, camera.intrinsics.height);
    // one detector, the views in turn: the search runs beside the fuse, on the cores the fuse
    // leaves idle, and a second detector would add its decode table and image buffers (~8 MB)
    // to the fuse's peak.
    // Each view's depth is decoded only when the declared tag is in its color image (for the
    // planar ambiguity; most views do not see the tag), and back-projected only around the tag:
    // the depth scores read the points inside its quad alone. Once the tag is seen, a view whose
    // seed camera is behind its face is not searched (`BEHIND_FACE_DEG`).
    let mut detector = AprilTagDetector::new(detector_params)?;
    let (mut views, mut faces) = (Vec::new(), Vec::new());
    for (index, view) in scan.views.iter().enumerate() {
        if !view.data.has_color() {
            continue;
        }
        let seed = scan.world_from_camera(index).ok();
        if seed.is_some_and(|seed| behind_a_face(&faces, &seed)) {
            continue;
        }
        let Some(image) = read_view_color(scan, index)? else { continue };
        let found = detector.detect_color(&image)?;
        drop(image);
        let corners: Vec<[f64; 2]> = found.iter().filter(|d| d.id == tag.id).flat_map(|d| d.corners_px).collect();
        let points_camera = if corners.is_empty() {
            Vec::new()
        } else {
            // a back-projected pixel projects back within 1e-3 px: 2 px of margin keep every point
            // that can project inside the quad
            let rect = PixelRect::around(&corners, 2.0, width, height);
            load_depth_points(scan, index, Some(&rect))?.unwrap_or_default()
        };
        let posed = pose_detections(found, index, &points_camera, &camera.intrinsics, tag, params);
        if let Some(seed) = seed {
            faces.extend(posed.iter().filter_map(|p| SeenFace::of(p, &seed)));
        }
        views.push((index, posed));
    }
    Ok(views)
}

impl TagSearch {
    /// `T_world_tag` from the views searched that have a registered pose (`world_from_camera[i]`,
    /// e.g. [`crate::pipeline::FuseOutput::poses`], one entry per view of the scan).
    ///
    /// # Errors
    /// [`Error::Invalid`] when a searched view's index has no entry in `world_from_camera`.
    pub fn place(
        &self,
        world_from_camera: &[Option<Isometry3<f64>>],
        params: &TagEstimateParams,
    ) -> Result<TagEstimate> {
        let (mut detections, mut views_checked) = (Vec::new(), Vec::new());
        for (index, posed) in &self.views {
            let pose = world_from_camera.get(*index).ok_or_else(|| {
                Error::invalid("view poses", format!("no pose for view {index} ({} poses)", world_from_camera.len()))
            })?;
            if let Some(pose) = pose {
                views_checked.push(*index);
                detections.extend(place(posed.clone(), pose));
            }
        }
        finish(detections, views_checked, &self.tag, params)
    }
}

/// Estimates `T_world_tag` from the views of `scan` that have a color image and a registered pose
/// (`world_from_camera[i]`, e.g. [`crate::pipeline::FuseOutput::poses`]): [`search_tags`], then
/// [`TagSearch::place`].
///
/// # Errors
/// [`Error::Invalid`] when the scan declares no tag or an unsupported one, or `world_from_camera`
/// does not have one entry per view; any error of loading a view.
pub fn estimate_world_from_tag(
    scan: &Scan,
    world_from_camera: &[Option<Isometry3<f64>>],
    params: &TagEstimateParams,
) -> Result<TagEstimate> {
    if world_from_camera.len() != scan.views.len() {
        return Err(Error::invalid(
            "view poses",
            format!("{} poses for {} views", world_from_camera.len(), scan.views.len()),
        ));
    }
    let search =
        search_tags(scan, params)?.ok_or_else(|| Error::invalid("scan.json tag", "the scan declares no tag"))?;
    search.place(world_from_camera, params)
}
