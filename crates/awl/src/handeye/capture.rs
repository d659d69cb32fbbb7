//! Hand-eye calibration from a capture folder ([`crate::io::capture`]): the tag detected and posed
//! in every view, its planar ambiguity resolved, then [`calibrate`].
//!
//! Per view ([`calibrate_capture`]):
//! 1. detect the declared tag (tag36h11 only) in the color image; a view where it is missing, too
//!    small (`min_side_px`), without a pose, or reprojecting worse than `max_rmse_px` is left out,
//!    with the reason; when no view holds it, the views are searched again with
//!    [`DetectorParams::thorough`] (a dim tag);
//! 2. pose it ([`estimate_tag_pose`]: both IPPE solutions). With one solution the view is
//!    [`FlipChoice::Unambiguous`]. With two, the depth points inside the tag (when the view has a
//!    depth image and at least [`MIN_DEPTH_POINTS`] of them) choose ([`score_depth`],
//!    [`FlipChoice::Depth`]);
//! 3. the remaining two-solution views choose by consistency across views
//!    ([`FlipChoice::Consistency`]): first without any hand-eye, by the angle invariant of
//!    `A X = X B` (a relative flange motion `A_ij` and its relative camera motion `B_ij` rotate
//!    by the same angle), each view taking the solution whose `B_ij` angles best match the `A_ij`
//!    of the other views (sweeps until nothing changes); then, with a first calibration, each takes
//!    the solution whose implied `T_base_tag = T_base_ee * T_ee_camera * T_camera_tag` is nearer the
//!    calibrated one (rotation in radians plus translation in metres / `rotation_weight_m`), and
//!    the calibration runs again when a choice changed;
//! 4. the chosen `T_camera_tag` with the view's `T_base_ee` is one [`HandEyePose`];
//! 5. a detector places a tag's corners a fraction of a pixel inside or outside the true ones
//!    (blur through the camera's tone curve: 0.16-0.21 px inward in both simulators here), so the tag
//!    looks smaller and farther by `2 b / side_px`: every tag translation is scaled by
//!    `1 + κ z` (`z` its depth, `κ = 2 b / (f S)`, `f` the focal length in pixels, `S` the tag's size).
//!    Where the views' tag depths spread enough to tell it from the hand-eye's translation
//!    (`corner_bias_min_depth_ratio`), `κ` is the minimiser of the refinement's cost
//!    (profiled: golden section over `|b| <= corner_bias_max_px`), the translations are corrected
//!    and the calibration runs again on them;
//! 6. each view's residual is weighted by its covariance (`view_weights`): the tag pose from 4
//!    corners (`corner_sigma_px`) knows its depth far worse than its lateral position, and the
//!    recorded flange pose carries the arm's noise (`arm_sigma_mm`, `arm_sigma_deg`); from the
//!    same model the calibration predicts its own error, [`CaptureCalibration::bound`] (a 95 %
//!    bound on `T_ee_camera`'s translation and rotation; `handeye::capture_bound`). The weights are
//!    computed at the first, unweighted solution (step 3) and used from step 5 on.

use nalgebra::{Isometry3, Matrix6, UnitQuaternion};
use serde::Serialize;

use crate::camera::PixelRect;
use crate::error::{Error, Result};
use crate::handeye::capture_bound::{
    BoundInput, CaptureBound, ViewNoise, predict, tag_pose_covariance, view_covariance, view_whitening,
};
use crate::handeye::solve::calibrate_weighted;
use crate::handeye::{HandEyeParams, HandEyePose, HandEyeResult, PoseResidual, calibrate};
use crate::io::capture::Capture;
use crate::tag::SUPPORTED_FAMILY;
use crate::tag::{
    AprilTagDetector, DetectorParams, MIN_DEPTH_POINTS, TagDetector, TagPose, estimate_tag_pose, score_depth,
};

/// Settings of [`calibrate_capture`]; every field has a documented default.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CaptureParams {
    /// The AprilTag detector's settings. Default: [`DetectorParams::default`].
    pub detector: DetectorParams,
    /// A detection whose pose reprojects its corners worse than this is left out, pixels. Default 1.5.
    pub max_rmse_px: f64,
    /// A detection whose shortest quad edge is below this is left out, pixels. Default 20.
    pub min_side_px: f64,
    /// The solver's settings. Default: [`HandEyeParams::default`].
    pub handeye: HandEyeParams,
    /// Estimate the detector's corner bias (item 5 of the module docs). Default true.
    pub corner_bias: bool,
    /// Estimate it only when the deepest tag is at least this many times as deep as the nearest
    /// (inliers). Default 1.2.
    pub corner_bias_min_depth_ratio: f64,
    /// The largest corner bias searched, pixels (each way). Default 1.
    pub corner_bias_max_px: f64,
    /// Weight each view's residual by its covariance (item 6 of the module docs). Default true.
    pub view_weights: bool,
    /// The detected tag corners' noise per image axis, pixels (the views' weights and the bound).
    /// Default 0.2.
    pub corner_sigma_px: f64,
    /// The recorded flange pose's translation noise per axis (flange frame), millimetres. Default
    /// 0.6 (awl's simulator; the other simulator's recorded poses scatter 0.61-0.65 mm).
    pub arm_sigma_mm: f64,
    /// The recorded flange pose's rotation noise per axis, degrees. Default 0.06 (awl's simulator;
    /// the other's: 0.068).
    pub arm_sigma_deg: f64,
}

impl Default for CaptureParams {
    fn default() -> Self {
        Self {
            detector: DetectorParams::default(),
            max_rmse_px: 1.5,
            min_side_px: 20.0,
            handeye: HandEyeParams::default(),
            corner_bias: true,
            corner_bias_min_depth_ratio: 1.2,
            corner_bias_max_px: 1.0,
            view_weights: true,
            corner_sigma_px: 0.2,
            arm_sigma_mm: 0.6,
            arm_sigma_deg: 0.06,
        }
    }
}

/// How a view's solution of the planar ambiguity was chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FlipChoice {
    /// The pose had a single solution.
    Unambiguous,
    /// The depth points on the tag fit its plane better.
    Depth,
    /// It agrees better with the other views (see the module docs).
    Consistency,
}

/// What happened to one view of the capture.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CaptureViewReport {
    /// Index of the view in `scan.json`.
    pub index: usize,
    /// Every tag id seen in the view (sorted).
    pub ids_seen: Vec<u32>,
    /// True when the declared tag was found and posed usably.
    pub found: bool,
    /// Why not, when `found` is false.
    pub why_not: Option<String>,
    /// Decision margin of the declared tag's detection (AprilTag's confidence), when seen.
    pub decision_margin: Option<f64>,
    /// The solution used: 1 = the lower reprojection error, 2 = the other one.
    pub solution: Option<u8>,
    /// How it was chosen.
    pub chosen_by: Option<FlipChoice>,
    /// Reprojection RMSE of the solution used, pixels.
    pub rmse_px: Option<f64>,
    /// `second.rmse_px / best.rmse_px` of the two solutions (near 1: the corners cannot tell).
    pub ambiguity: Option<f64>,
    /// The tag in the camera frame, `T_camera_tag` (awl's tag frame), as used.
    #[serde(skip)]
    pub camera_from_tag: Option<Isometry3<f64>>,
    /// Index of this view's pose in [`CaptureCalibration::poses`] (and the result's residuals).
    pub pose: Option<usize>,
    /// This view's residual after calibration (mm, deg, inlier or rejected), when found.
    pub residual: Option<PoseResidual>,
}

/// What [`calibrate_capture`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureCalibration {
    /// One report per view of the capture, in its order.
    pub views: Vec<CaptureViewReport>,
    /// The poses handed to the solver (the views where the tag was found, in order).
    pub poses: Vec<HandEyePose>,
    /// The solver's result (its residuals index [`CaptureCalibration::poses`]).
    pub result: HandEyeResult,
    /// True when the detector's thorough settings (a second search) found the tag.
    pub thorough_search: bool,
    /// The detector's corner bias the calibration corrected, pixels (positive: the corners lay
    /// inside the true ones; item 5 of the module docs); `None` when not estimated.
    pub corner_bias_px: Option<f64>,
    /// Why it was not estimated (empty when it was).
    pub corner_bias_note: String,
    /// The calibration's own predicted error: 95 % bounds on `T_ee_camera`'s translation (mm) and
    /// rotation (deg) from the views' noise (item 6 of the module docs); `None` when refinement is
    /// off (the closed form's error is larger).
    pub bound: Option<CaptureBound>,
}

/// A view where the tag was found: its pose, and the other solution while the choice is open.
struct Seen {
    view: usize,
    pose: TagPose,
    /// Using `pose.second` (solution 2).
    use_second: bool,
    /// Still to be chosen by consistency.
    open: bool,
}

impl Seen {
    fn chosen(&self) -> Isometry3<f64> {
        match (self.use_second, self.pose.second) {
            (true, Some(s)) => s.camera_from_tag,
            _ => self.pose.best.camera_from_tag,
        }
    }
    fn candidate(&self, second: bool) -> Isometry3<f64> {
        match (second, self.pose.second) {
            (true, Some(s)) => s.camera_from_tag,
            _ => self.pose.best.camera_from_tag,
        }
    }
}

fn shortest_side_px(c: &[[f64; 2]; 4]) -> f64 {
    (0..4).map(|i| (c[i][0] - c[(i + 1) % 4][0]).hypot(c[i][1] - c[(i + 1) % 4][1])).fold(f64::INFINITY, f64::min)
}

/// Detects and poses the declared tag in every view with `detector_params` (see the module docs,
/// steps 1-2): the reports and the views where it was found.
fn search(
    capture: &Capture,
    params: &CaptureParams,
    detector_params: &DetectorParams,
) -> Result<(Vec<CaptureViewReport>, Vec<Seen>)> {
    let mut detector = AprilTagDetector::new(detector_params)?;
    let (k, tag) = (&capture.intrinsics, &capture.tag);
    let (mut reports, mut seen) = (Vec::new(), Vec::new());
    for index in 0..capture.views.len() {
        let image = capture.read_color(index)?;
        let found = detector.detect_color(&image)?;
        drop(image);
        let mut ids_seen: Vec<u32> = found.iter().map(|d| d.id).collect();
        ids_seen.sort_unstable();
        let mut report = CaptureViewReport {
            index,
            ids_seen,
            found: false,
            why_not: None,
            decision_margin: None,
            solution: None,
            chosen_by: None,
            rmse_px: None,
            ambiguity: None,
            camera_from_tag: None,
            pose: None,
            residual: None,
        };
        // the declared tag: the most confident detection of its id
        let best =
            found.iter().filter(|d| d.id == tag.id).max_by(|a, b| a.decision_margin.total_cmp(&b.decision_margin));
        let Some(d) = best else {
            report.why_not = Some(if report.ids_seen.is_empty() {
                "no tag seen".into()
            } else {
                format!("tag id {} not seen (saw ids {:?})", tag.id, report.ids_seen)
            });
            reports.push(report);
            continue;
        };
        report.decision_margin = Some(d.decision_margin);
        let side = shortest_side_px(&d.corners_px);
        if side < params.min_side_px {
            report.why_not = Some(format!("tag too small in the image ({side:.1} px < {} px)", params.min_side_px));
            reports.push(report);
            continue;
        }
        let pose = match estimate_tag_pose(&d.corners_px, k, tag.size_m) {
            Ok(pose) => pose,
            Err(e) => {
                report.why_not = Some(format!("no pose: {e}"));
                reports.push(report);
                continue;
            }
        };
        report.ambiguity = pose.ambiguity();
        if pose.best.rmse_px > params.max_rmse_px {
            report.why_not = Some(format!("reprojection RMSE {:.2} px > {} px", pose.best.rmse_px, params.max_rmse_px));
            reports.push(report);
            continue;
        }
        let (mut use_second, mut open) = (false, false);
        if pose.second.is_none() {
            report.chosen_by = Some(FlipChoice::Unambiguous);
        } else {
            let rect = PixelRect::around(&d.corners_px, 2.0, k.width, k.height);
            let points = capture.read_depth_points(index, &rect)?.unwrap_or_default();
            let scores = score_depth(&pose, &d.corners_px, k, &points);
            if scores.best.points >= MIN_DEPTH_POINTS {
                use_second = scores.prefers_second();
                report.chosen_by = Some(FlipChoice::Depth);
            } else {
                open = true;
                report.chosen_by = Some(FlipChoice::Consistency);
            }
        }
        report.found = true;
        seen.push(Seen { view: index, pose, use_second, open });
        reports.push(report);
    }
    Ok((reports, seen))
}

/// Step 3's first part: the open views choose by the rotation-angle invariant of `A X = X B`.
fn choose_by_angles(capture: &Capture, seen: &mut [Seen]) {
    let flange: Vec<UnitQuaternion<f64>> = seen.iter().map(|s| capture.views[s.view].base_from_ee.rotation).collect();
    for _sweep in 0..10 {
        let mut changed = false;
        for i in 0..seen.len() {
            if !seen[i].open {
                continue;
            }
            let cost = |second: bool| -> f64 {
                let c_i = seen[i].candidate(second).rotation;
                (0..seen.len())
                    .filter(|&j| j != i)
                    .map(|j| {
                        let a = (flange[i].inverse() * flange[j]).angle();
                        let b = (c_i * seen[j].chosen().rotation.inverse()).angle();
                        (a - b).abs()
                    })
                    .sum()
            };
            let second = cost(true) < cost(false);
            if second != seen[i].use_second {
                seen[i].use_second = second;
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
}

/// Step 3's second part: each open view takes the solution whose implied `T_base_tag` is nearer
/// `base_from_target`; true when a choice changed.
fn choose_by_target(capture: &Capture, seen: &mut [Seen], result: &HandEyeResult, weight_m: f64) -> bool {
    let mut changed = false;
    for s in seen.iter_mut().filter(|s| s.open) {
        let base_from_ee = capture.views[s.view].base_from_ee;
        let distance = |second: bool| {
            let implied = base_from_ee * result.ee_from_camera * s.candidate(second);
            let delta = result.base_from_target.inverse() * implied;
            delta.rotation.angle() + delta.translation.vector.norm() / weight_m
        };
        let second = distance(true) < distance(false);
        if second != s.use_second {
            s.use_second = second;
            changed = true;
        }
    }
    changed
}

fn poses_of(capture: &Capture, seen: &[Seen]) -> Vec<HandEyePose> {
    seen.iter()
        .map(|s| HandEyePose { base_from_ee: capture.views[s.view].base_from_ee, camera_from_target: s.chosen() })
        .collect()
}

/// `view 0: no tag seen; view 3: ...` for the views where the tag was not found.
fn what_each_saw(reports: &[CaptureViewReport]) -> String {
    reports
        .iter()
        .map(|r| match &r.why_not {
            Some(why) => format!("view {}: {why}", r.index),
            None => format!("view {}: found", r.index),
        })
        .collect::<Vec<_>>()
        .join("; ")
}

/// Calibrates `T_ee_camera` from a capture (see the module docs).
///
/// # Errors
/// [`Error::Field`] naming `scan.json`'s `tag.family` for a family other than tag36h11, its `tag`
/// when no view holds the tag (what each view saw listed), its `views` when fewer than 3 views do
/// (listed) or the solver refuses the motions (degenerate: pure translations, one rotation axis;
/// the views named); any error of reading a view's images (naming the file: a JPEG that does not
/// decode among them); [`Error::Invalid`] for bad parameters.
pub fn calibrate_capture(capture: &Capture, params: &CaptureParams) -> Result<CaptureCalibration> {
    let manifest = capture.manifest_path();
    let tag = &capture.tag;
    if tag.family != SUPPORTED_FAMILY {
        return Err(Error::field(
            &manifest,
            "tag.family",
            format!("\"{}\" is not supported (only {SUPPORTED_FAMILY})", tag.family),
        ));
    }
    let (mut reports, mut seen) = search(capture, params, &params.detector)?;
    let mut thorough_search = false;
    if seen.is_empty()
        && let Some(thorough) = params.detector.thorough()
    {
        let (r, s) = search(capture, params, &thorough)?;
        thorough_search = !s.is_empty();
        if thorough_search {
            (reports, seen) = (r, s);
        }
    }
    let name = format!("{} id {} ({} m)", tag.family, tag.id, tag.size_m);
    if seen.is_empty() {
        return Err(Error::field(
            &manifest,
            "tag",
            format!("{name} was not found in any of the {} views: {}", capture.views.len(), what_each_saw(&reports)),
        ));
    }
    if seen.len() < 3 {
        let views: Vec<usize> = seen.iter().map(|s| s.view).collect();
        return Err(Error::field(
            &manifest,
            "views",
            format!(
                "{name} was found in only {} of {} views ({views:?}); hand-eye calibration needs at least 3: {}",
                seen.len(),
                capture.views.len(),
                what_each_saw(&reports)
            ),
        ));
    }
    choose_by_angles(capture, &mut seen);
    let views: Vec<usize> = seen.iter().map(|s| s.view).collect();
    let solve = |seen: &[Seen]| {
        calibrate(&poses_of(capture, seen), &params.handeye).map_err(|e| {
            Error::field(
                &manifest,
                "views",
                format!("calibration from the views {views:?} (poses[k] is the k-th of them) failed: {e}"),
            )
        })
    };
    let mut result = solve(&seen)?;
    for _ in 0..3 {
        if !choose_by_target(capture, &mut seen, &result, params.handeye.rotation_weight_m) {
            break;
        }
        result = solve(&seen)?;
    }
    if params.corner_bias
        && !(params.corner_bias_max_px.is_finite()
            && params.corner_bias_max_px > 0.0
            && params.corner_bias_min_depth_ratio.is_finite()
            && params.corner_bias_min_depth_ratio >= 1.0)
    {
        return Err(Error::invalid(
            "corner_bias_max_px / corner_bias_min_depth_ratio",
            format!(
                "{} px and {} must be a positive number and a ratio >= 1",
                params.corner_bias_max_px, params.corner_bias_min_depth_ratio
            ),
        ));
    }
    let noise = params.view_noise()?;
    let detected = poses_of(capture, &seen);
    let tag_covariances = (detected.iter().zip(&seen))
        .map(|(p, s)| {
            tag_pose_covariance(&capture.intrinsics, tag.size_m, &p.camera_from_target, noise.corner_sigma_px)
                .ok_or_else(|| {
                    Error::field(
                        &manifest,
                        "views",
                        format!(
                            "view {}: the tag's 4 corners do not fix its pose (a corner behind the camera?)",
                            s.view
                        ),
                    )
                })
        })
        .collect::<Result<Vec<Matrix6<f64>>>>()?;
    let covariances = |poses: &[HandEyePose], result: &HandEyeResult| -> Vec<Matrix6<f64>> {
        (poses.iter().zip(&tag_covariances))
            .map(|(p, c)| view_covariance(p, &result.ee_from_camera, &result.base_from_target, c, &noise))
            .collect()
    };
    let white = if params.view_weights && params.handeye.refine {
        let w = (covariances(&detected, &result).iter().zip(&seen))
            .map(|(c, s)| view_whitening(c, &format!("view {}", s.view)))
            .collect::<Result<Vec<_>>>()?;
        result = calibrate_weighted(&detected, Some(&w), &params.handeye).map_err(|e| {
            Error::field(&manifest, "views", format!("calibration from the views {views:?} weighted failed: {e}"))
        })?;
        Some(w)
    } else {
        None
    };
    let (mut poses, mut corner_bias_px, mut corner_bias_note, mut kappa) =
        (detected.clone(), None, String::new(), None);
    if params.corner_bias {
        match corner_bias(capture, &detected, &result, white.as_deref(), params) {
            Ok(k) => {
                let corrected = scaled_by_depth(&detected, k);
                result = calibrate_weighted(&corrected, white.as_deref(), &params.handeye).map_err(|e| {
                    Error::field(
                        &manifest,
                        "views",
                        format!("calibration from the views {views:?} with the corner bias corrected failed: {e}"),
                    )
                })?;
                poses = corrected;
                corner_bias_px = Some(k * capture.intrinsics.fx * tag.size_m / 2.0);
                kappa = Some(k);
            }
            Err(why) => corner_bias_note = why,
        }
    } else {
        corner_bias_note = "not estimated (corner_bias off)".into();
    }
    let bound = params.handeye.refine.then(|| {
        let inlier = |k: &usize| !result.rejected.contains(k);
        let keep = |v: &[HandEyePose]| -> Vec<HandEyePose> { (0..v.len()).filter(inlier).map(|k| v[k]).collect() };
        let (kept, kept_detected) = (keep(&poses), keep(&detected));
        let all_covariances = covariances(&poses, &result);
        let kept_covariances: Vec<Matrix6<f64>> = (0..poses.len()).filter(inlier).map(|k| all_covariances[k]).collect();
        let kept_white: Option<Vec<Matrix6<f64>>> =
            white.as_ref().map(|w| (0..poses.len()).filter(inlier).map(|k| w[k]).collect());
        let input = BoundInput {
            poses: &kept,
            covariances: &kept_covariances,
            whitening: kept_white.as_deref(),
            rotation_weight_m: params.handeye.rotation_weight_m,
            x: result.ee_from_camera,
            y: result.base_from_target,
            corner_bias: kappa.map(|k| (kept_detected.as_slice(), k)),
        };
        predict(&input, &noise)
    });
    for (k, s) in seen.iter().enumerate() {
        let report = &mut reports[s.view];
        report.solution = Some(if s.use_second && s.pose.second.is_some() { 2 } else { 1 });
        let used = if s.use_second { s.pose.second.unwrap_or(s.pose.best) } else { s.pose.best };
        report.rmse_px = Some(used.rmse_px);
        report.camera_from_tag = Some(s.chosen());
        report.pose = Some(k);
        report.residual = result.residuals.get(k).copied();
    }
    Ok(CaptureCalibration { views: reports, poses, result, thorough_search, corner_bias_px, corner_bias_note, bound })
}

impl CaptureParams {
    /// The views' noise (module docs, item 6), checked.
    fn view_noise(&self) -> Result<ViewNoise> {
        let (px, mm, deg) = (self.corner_sigma_px, self.arm_sigma_mm, self.arm_sigma_deg);
        if !(px.is_finite() && px > 0.0) {
            return Err(Error::invalid("corner_sigma_px", format!("must be a positive number of pixels, got {px}")));
        }
        if !(mm.is_finite() && mm >= 0.0 && deg.is_finite() && deg >= 0.0) {
            return Err(Error::invalid(
                "arm_sigma_mm / arm_sigma_deg",
                format!("must be non-negative numbers, got {mm} mm and {deg} deg"),
            ));
        }
        Ok(ViewNoise { corner_sigma_px: px, arm_sigma_m: mm * 1e-3, arm_sigma_rad: deg.to_radians() })
    }
}

/// Each pose's tag translation divided by `1 + kappa z` (`z` its depth, metres; `kappa` per metre).
fn scaled_by_depth(poses: &[HandEyePose], kappa: f64) -> Vec<HandEyePose> {
    (poses.iter())
        .map(|p| {
            let mut camera_from_target = p.camera_from_target;
            let t = camera_from_target.translation.vector;
            camera_from_target.translation.vector = t / (1.0 + kappa * t.z);
            HandEyePose { camera_from_target, ..*p }
        })
        .collect()
}

/// The depth scale `κ` (per metre) of the detector's corner bias that minimises the refinement's
/// cost (whitened by `white` when given) over `result`'s inliers (golden section), or why it is not
/// estimated.
fn corner_bias(
    capture: &Capture,
    poses: &[HandEyePose],
    result: &HandEyeResult,
    white: Option<&[Matrix6<f64>]>,
    params: &CaptureParams,
) -> std::result::Result<f64, String> {
    let inliers: Vec<HandEyePose> =
        (poses.iter().enumerate()).filter(|(k, _)| !result.rejected.contains(k)).map(|(_, p)| *p).collect();
    let white: Option<Vec<Matrix6<f64>>> =
        white.map(|w| (0..poses.len()).filter(|k| !result.rejected.contains(k)).map(|k| w[k]).collect());
    let white = white.as_deref();
    let depths = inliers.iter().map(|p| p.camera_from_target.translation.z);
    let (near, far) = depths.fold((f64::INFINITY, 0.0_f64), |(a, b), z| (a.min(z), b.max(z)));
    if !(near > 0.0 && far >= params.corner_bias_min_depth_ratio * near) {
        return Err(format!(
            "not estimated: the tag's depths span {near:.3}-{far:.3} m, less than corner_bias_min_depth_ratio {} \
             (a bias would look like the hand-eye's translation): take views nearer and farther",
            params.corner_bias_min_depth_ratio
        ));
    }
    let h = &params.handeye;
    let cost = |kappa: f64| {
        let scaled = scaled_by_depth(&inliers, kappa);
        let (_, _, stats) = super::refine::refine(
            &scaled,
            &result.ee_from_camera,
            &result.base_from_target,
            h.rotation_weight_m,
            white,
            h.max_iterations,
        );
        stats.final_cost
    };
    // κ = 2 b / (f S) for a bias of b pixels
    let limit = 2.0 * params.corner_bias_max_px / (capture.intrinsics.fx * capture.tag.size_m);
    let ratio = (5f64.sqrt() - 1.0) / 2.0;
    let (mut a, mut b) = (-limit, limit);
    let (mut c, mut d) = (b - ratio * (b - a), a + ratio * (b - a));
    let (mut fc, mut fd) = (cost(c), cost(d));
    for _ in 0..40 {
        if fc < fd {
            (b, d, fd) = (d, c, fc);
            c = b - ratio * (b - a);
            fc = cost(c);
        } else {
            (a, c, fc) = (c, d, fd);
            d = a + ratio * (b - a);
            fd = cost(d);
        }
    }
    let kappa = (a + b) / 2.0;
    if kappa.abs() > 0.99 * limit {
        return Err(format!(
            "not estimated: the best corner bias lies at the search's edge ({} px, corner_bias_max_px): the \
             detections or the poses hold a larger error than a corner bias",
            params.corner_bias_max_px
        ));
    }
    Ok(kappa)
}
