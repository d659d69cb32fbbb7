//! The workpiece in the robot base frame at piercing time, from a shot (an `awl-scan/1` folder with
//! world = robot base).
//!
//! 1. Tag: every color view of the shot is searched for the workpiece's tag; each detection gives
//!    `T_base_tag = T_base_ee * T_ee_camera * T_camera_tag` (the ambiguity resolved by the view's
//!    depth); the views' estimates are averaged robustly ([`crate::workpiece::robust_mean`]). With the
//!    tag's pose on the model (`T_world_tag` of `workpiece.json`, world = the model's frame):
//!    `T_base_model = T_base_tag * T_world_tag^-1`.
//! 2. Depth (when the shot has it): the shot's points (base frame, voxelised, kept within `crop_m`
//!    of the model placed by the tag) are registered onto the model by point-to-plane ICP seeded by
//!    that pose. This removes the tag's orientation error (1 degree at 30 cm is 5 mm) but not the
//!    hand-eye error, which moves the tag and the points alike. The refined pose is used when ICP
//!    matched enough of the shot and moved the pose by less than the limits; otherwise the tag
//!    pose is kept and the reason reported.

use nalgebra::{Isometry3, Matrix3, Matrix6, Vector6};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::filter::voxel::{VoxelParams, downsample};
use crate::handeye::chain::{ChainNoise, ChainParams, ChainPrior, ChainView, StopPrior, refine_chain};
use crate::io::scan::load_view;
use crate::registration::{IcpLevel, IcpParams, PreparedTarget, register_prepared};
use crate::scan::{LoadedView, Scan, TagSpec, ViewPose};
use crate::spatial::LeafTree;
use crate::transform::{adjoint, pose_difference, skew};
use crate::workpiece::{SurfaceModel, TagEstimateParams, TagView, ViewTagDetection, estimate_from_views};

/// Parameters of the shot-depth refinement.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ShotRefineParams {
    /// Voxel size of the shot's merged points, metres. Default 0.002: the ICP's finest level; with
    /// every point kept (`icp.max_source_points` 200 000), 3 simulated shell runs (30 shots, tilted
    /// 30 deg) located the flank 1.34-1.58 mm mean / 2.68 max instead of 1.64-2.00 / 4.29 with 3 mm
    /// voxels and 20 000 points (the located rotation: 0.92 deg max instead of 1.46). Finer voxels
    /// gained nothing more.
    pub voxel_m: f64,
    /// Shot points farther than this from the model placed by the tag are left out (floor,
    /// support, clutter), metres. Default 0.03.
    pub crop_m: f64,
    /// The ICP schedule. Default: 6 mm voxels / 30 mm gate, 3 / 10, 2 / 4; 40 iterations each;
    /// up to 200 000 shot points per level.
    pub icp: IcpParams,
    /// At least this many shot points must remain after the crop. Default 500.
    pub min_points: usize,
    /// At least this fraction of them must find a model point within the final gate. Default 0.5.
    pub min_fitness: f64,
    /// The refinement may move the tag's pose by at most this much, metres. Default 0.03.
    pub max_correction_m: f64,
    /// ... and rotate it by at most this much, radians. Default 5 degrees.
    pub max_correction_rad: f64,
}

impl Default for ShotRefineParams {
    fn default() -> Self {
        let level =
            |voxel_m: f64, max_correspondence_m: f64| IcpLevel { voxel_m, max_correspondence_m, max_iterations: 40 };
        Self {
            voxel_m: 0.002,
            crop_m: 0.03,
            icp: IcpParams {
                levels: vec![level(0.006, 0.03), level(0.003, 0.01), level(0.002, 0.004)],
                max_source_points: 200_000,
                ..IcpParams::default()
            },
            min_points: 500,
            min_fitness: 0.5,
            max_correction_m: 0.03,
            max_correction_rad: 5f64.to_radians(),
        }
    }
}

/// Parameters of [`locate`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LocateParams {
    /// Tag detection and the robust mean over the shot's views.
    pub tag: TagEstimateParams,
    /// The shot-depth refinement; `None`: the tag pose alone.
    pub refine: Option<ShotRefineParams>,
    /// Each shot view's noise when the views are combined with the hand-eye.
    pub noise: ChainNoise,
    /// A detected tag corner's noise, 1-sigma per image axis, pixels (the tag pose's covariance
    /// when the model is placed by the tag alone). Default 0.3.
    pub tag_corner_px: f64,
}

impl Default for LocateParams {
    fn default() -> Self {
        Self { tag: TagEstimateParams::default(), refine: None, noise: ChainNoise::default(), tag_corner_px: 0.3 }
    }
}

impl LocateParams {
    /// The default detection and refinement.
    pub fn with_refinement() -> Self {
        Self { refine: Some(ShotRefineParams::default()), ..Self::default() }
    }
}

/// The hand-eye `awl pierce` starts from, with its uncertainty.
#[derive(Debug, Clone, PartialEq)]
pub struct HandEyePrior {
    /// `T_ee_camera` and its covariance.
    pub prior: ChainPrior,
    /// Where it came from, for the report.
    pub source: String,
}

impl HandEyePrior {
    /// The workpiece's hand-eye (`awl fuse`'s refinement, or its recorded one with its prior) when
    /// the shot records the same `T_ee_camera` as the scan did (within 1 µm / 1 µrad); `None` when
    /// the workpiece has none or the shot records another (a new calibration since the scan).
    ///
    /// # Errors
    /// [`Error::Invalid`] when the workpiece's hand-eye matrices are not rigid.
    pub fn of_workpiece(hand_eye: Option<&crate::pipeline::HandEyeReport>, shot: &Scan) -> Result<Option<Self>> {
        let (Some(h), Some(recorded)) = (hand_eye, shot.ee_from_camera) else { return Ok(None) };
        let scan_recorded = crate::transform::isometry_from_rows(&h.recorded)
            .map_err(|e| Error::invalid("workpiece hand_eye T_ee_camera_recorded", e))?;
        let (dt, dr) = pose_difference(&scan_recorded, &recorded);
        if dt > 1e-6 || dr > 1e-6 {
            return Ok(None);
        }
        Self::of_report(h).map(Some)
    }

    /// The hand-eye `awl fuse` left in a workpiece: the refined one, or the recorded one with its
    /// prior when it was not refined.
    ///
    /// # Errors
    /// [`Error::Invalid`] when its matrices are not rigid.
    pub fn of_report(h: &crate::pipeline::HandEyeReport) -> Result<Self> {
        let (ee_from_camera, covariance) = h.used()?;
        let source = if h.refined.is_some() {
            "workpiece.json hand_eye (refined from the scan)"
        } else {
            "workpiece.json hand_eye (recorded; not refined)"
        };
        Ok(Self { prior: ChainPrior { ee_from_camera, covariance }, source: source.into() })
    }

    /// A freshly calibrated `T_ee_camera` (e.g. `--hand-eye FILE`): 0.5 mm / 0.05 deg per axis.
    pub fn calibrated(ee_from_camera: Isometry3<f64>, source: &str) -> Self {
        Self { prior: ChainPrior::isotropic(ee_from_camera, 0.0005, 0.05f64.to_radians()), source: source.into() }
    }

    /// The shot's recorded `T_ee_camera` with the fuse's default prior sigma (2 mm, 0.2 deg per axis).
    pub fn recorded(ee_from_camera: Isometry3<f64>) -> Self {
        let c = crate::pipeline::HandEyeConfig::default();
        Self {
            prior: ChainPrior::isotropic(ee_from_camera, c.prior_sigma_m, c.prior_sigma_rad),
            source: "scan.json T_ee_camera (recorded)".into(),
        }
    }
}

/// What the shot-depth refinement did.
#[derive(Debug, Clone, PartialEq)]
pub struct ShotRefinement {
    /// Whether its pose is used.
    pub applied: bool,
    /// `T_base_model` from ICP (reported even when not applied).
    pub base_from_model: Isometry3<f64>,
    /// Shot points registered (after voxel and crop).
    pub points: usize,
    /// ICP fitness (fraction of them with a model point within the final gate).
    pub fitness: f64,
    /// RMS point-to-plane residual of those, metres.
    pub rmse_m: f64,
    /// How far the refinement moved the model's origin... measured at the tag: translation, metres.
    pub correction_m: f64,
    /// ... and rotation, radians.
    pub correction_rad: f64,
    /// Why it was not applied (empty when applied).
    pub note: String,
}

/// The shot's views registered one by one onto the model and combined with the hand-eye prior
/// ([`crate::handeye::chain`], one stop whose base is the robot base): `T_base_model` and
/// `T_ee_camera` at once, with their covariance.
#[derive(Debug, Clone, PartialEq)]
pub struct ShotHandEye {
    /// The `T_ee_camera` the plan uses (the prior refined by the shot's views).
    pub ee_from_camera: Isometry3<f64>,
    /// Its covariance (right perturbation `(ω, v)` in the camera frame; rad², m²).
    pub ee_from_camera_covariance: Matrix6<f64>,
    /// The prior's `T_ee_camera` and where it came from.
    pub prior: Isometry3<f64>,
    /// Where the prior came from (`workpiece.json hand_eye`, `scan.json T_ee_camera`, a file).
    pub prior_source: String,
    /// Covariance of `T_base_model`'s error: `T_base_model_true = D^-1 * T_base_model`, `D =
    /// (exp ω, v)` in the base frame (rad², m²).
    pub base_from_model_covariance: Matrix6<f64>,
    /// Per registered view: index, ICP fitness, inlier RMSE (m).
    pub views: Vec<(usize, f64, f64)>,
    /// `sqrt(chi² / dof)` of the views' residuals against the chain.
    pub residual_scale: f64,
}

/// The workpiece located in the base frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Located {
    /// `T_base_tag`: the robust mean of the shot views' detections.
    pub base_from_tag: Isometry3<f64>,
    /// `T_base_model` from the tag alone.
    pub base_from_model_tag: Isometry3<f64>,
    /// `T_base_model` used: the refined one when applied, else the tag's.
    pub base_from_model: Isometry3<f64>,
    /// The shot-depth refinement, when asked for and the shot has depth.
    pub refinement: Option<ShotRefinement>,
    /// Shot views searched for the tag.
    pub views_checked: Vec<usize>,
    /// Every tag detection in the shot (`world_from_tag` = `T_base_tag` of that view).
    pub detections: Vec<ViewTagDetection>,
    /// The hand-eye combined with the shot's own views, and the located pose's covariance
    /// (`None` when the shot's views do not give `T_base_ee`, or none registered onto the model).
    pub hand_eye: Option<ShotHandEye>,
    /// Covariance of `base_from_model`'s error: `T_base_model_true = exp(-(ω, v)) * T_base_model`,
    /// `(ω, v)` in the base frame (rad², m²). From the hand-eye combination when it was made, else
    /// the hand-eye's prior carried through the shot's views with the arm's noise and that of the
    /// fit used (the shot-depth registration's, or each tag detection's from its corners).
    pub base_from_model_covariance: Matrix6<f64>,
    /// Which of those [`Located::base_from_model_covariance`] is.
    pub covariance_source: String,
    /// Things the user should know.
    pub warnings: Vec<String>,
}

fn shot_error(shot: &Scan, message: impl Into<String>) -> Error {
    Error::invalid(format!("shot {}", shot.dir.display()), message)
}

/// Locates the workpiece (its model, in `T_world_tag`'s frame) in the shot's base frame.
///
/// # Errors
/// [`Error::Invalid`] naming the shot folder when the shot declares another tag than the
/// workpiece's, has no color image, or no view shows the tag usably (listing the views checked
/// and what each saw); any error loading a view.
pub fn locate(
    shot: &Scan,
    tag: &TagSpec,
    world_from_tag: &Isometry3<f64>,
    model: &SurfaceModel<'_>,
    params: &LocateParams,
    prior: Option<&HandEyePrior>,
) -> Result<Located> {
    if let Some(declared) = &shot.tag
        && (declared.family != tag.family || declared.id != tag.id || (declared.size_m - tag.size_m).abs() > 1e-6)
    {
        return Err(shot_error(
            shot,
            format!(
                "scan.json declares tag {} id {} size {} m, but the workpiece's tag is {} id {} size {} m",
                declared.family, declared.id, declared.size_m, tag.family, tag.id, tag.size_m
            ),
        ));
    }
    // every view is placed with the hand-eye the plan starts from
    let recorded = shot.ee_from_camera;
    let prior = match (prior, recorded) {
        (Some(p), _) => Some(p.clone()),
        (None, Some(x)) => Some(HandEyePrior::recorded(x)),
        (None, None) => None,
    };
    let placed;
    let shot = match &prior {
        Some(p) if recorded != Some(p.prior.ee_from_camera) => {
            placed = Scan { ee_from_camera: Some(p.prior.ee_from_camera), ..shot.clone() };
            &placed
        }
        _ => shot,
    };
    // every view is decoded once (in parallel, kept in order; the first view that fails is
    // reported): its color for the tag, its points for the refinement
    let rays = shot.camera.as_ref().map(|c| c.intrinsics.ray_table());
    let loaded: Vec<Result<LoadedView>> =
        (0..shot.views.len()).into_par_iter().map(|i| load_view(shot, i, rays.as_deref())).collect();
    let loaded: Vec<LoadedView> = loaded.into_iter().collect::<Result<_>>()?;
    let views: Vec<TagView<'_>> = loaded
        .iter()
        .enumerate()
        .filter_map(|(index, l)| {
            let image = l.color.as_ref()?;
            Some(TagView {
                index,
                image,
                points_camera: &l.cloud_camera.points,
                world_from_camera: l.world_from_camera,
            })
        })
        .collect();
    let camera = match &shot.camera {
        Some(camera) if !views.is_empty() => camera,
        _ => return Err(shot_error(shot, "no view has a color image: the tag cannot be detected")),
    };
    // the model at each ICP level, indexed once for every registration onto it, built while the
    // tag is searched
    let (estimate, target) = rayon::join(
        || estimate_from_views(&views, &camera.intrinsics, tag, &params.tag),
        || {
            let Some(p) = &params.refine else { return Ok(None) };
            let (levels, crop) =
                rayon::join(|| PreparedTarget::new(model.cloud, &p.icp), || LeafTree::new(&model.cloud.points));
            Ok::<_, Error>(Some(OnModelTarget { levels: levels?, crop: crop? }))
        },
    );
    let estimate = estimate?;
    let Some(base_from_tag) = estimate.world_from_tag else {
        let checked: Vec<String> = estimate.views_checked.iter().map(usize::to_string).collect();
        let seen: Vec<String> = estimate.detections.iter().map(|d| format!("view {}: {}", d.view, d.reason)).collect();
        let seen = if seen.is_empty() { "no tag of any id".to_string() } else { seen.join("; ") };
        // the detections may all have been seen and disagree: the estimate's warning says how
        let why: Vec<&str> = estimate.warnings.iter().filter(|w| w.contains("disagree")).map(String::as_str).collect();
        let why = if why.is_empty() { String::new() } else { format!(": {}", why.join("; ")) };
        return Err(shot_error(
            shot,
            format!(
                "tag {} id {} not found usably in the views checked [{}] ({seen}){why}",
                tag.family,
                tag.id,
                checked.join(", ")
            ),
        ));
    };
    let base_from_model_tag = base_from_tag * world_from_tag.inverse();
    let target = target?;
    // what reading the shot fixed or dropped (each naming its file), then the tag's
    let mut warnings = shot.warnings.clone();
    warnings.extend(loaded.iter().flat_map(|v| v.warnings.iter().cloned()));
    warnings.extend(estimate.warnings);
    let mut base_from_model = base_from_model_tag;
    let refinement = match (&params.refine, &target) {
        (Some(p), Some(target)) => {
            let r = refine_with_depth(&loaded, target, &base_from_model_tag, world_from_tag, p)?;
            if r.applied {
                base_from_model = r.base_from_model;
            } else {
                warnings.push(format!("shot-depth refinement not applied ({}): the tag pose is used", r.note));
            }
            Some(r)
        }
        _ => None,
    };
    let hand_eye = match (&params.refine, &target, &prior) {
        (Some(p), Some(target), Some(prior)) => {
            combine_views(shot, &loaded, target, &base_from_model, prior, p, &params.noise, &mut warnings)?
        }
        _ => None,
    };
    let depth_applied = refinement.as_ref().is_some_and(|r| r.applied);
    let (base_from_model_covariance, covariance_source) = match &hand_eye {
        Some(h) => {
            base_from_model = h.base_from_model;
            (h.summary.base_from_model_covariance, "the shot's views combined with the hand-eye".to_string())
        }
        None => {
            let tag_px = params.tag_corner_px;
            let fits: Vec<(usize, Matrix6<f64>)> = if depth_applied {
                let c = registration_covariance(&params.noise);
                (0..loaded.len()).map(|i| (i, c)).collect()
            } else {
                estimate
                    .detections
                    .iter()
                    .filter(|d| d.used)
                    .filter_map(|d| {
                        let l = loaded.get(d.view)?;
                        let camera_from_tag = l.world_from_camera.inverse() * d.world_from_tag?;
                        Some((d.view, tag_covariance(&camera.intrinsics, tag.size_m, &camera_from_tag, tag_px)))
                    })
                    .collect()
            };
            let flanges: Vec<Option<Isometry3<f64>>> = (0..shot.views.len())
                .map(|i| match shot.views[i].pose {
                    ViewPose::Chain { world_from_base, base_from_ee } => Some(world_from_base * base_from_ee),
                    ViewPose::Camera { .. } => None,
                })
                .collect();
            let c = transported_covariance(&fits, &flanges, &loaded, prior.as_ref(), &params.noise);
            let source = if depth_applied {
                "the hand-eye's prior and the shot-depth registration"
            } else {
                "the hand-eye's prior and the tag's corners"
            };
            (c, source.to_string())
        }
    };
    Ok(Located {
        base_from_tag,
        base_from_model_tag,
        base_from_model,
        refinement,
        views_checked: estimate.views_checked,
        detections: estimate.detections,
        hand_eye: hand_eye.map(|h| h.summary),
        base_from_model_covariance,
        covariance_source,
        warnings,
    })
}

/// A registered camera pose's error covariance ([`ChainNoise`]'s camera terms; rad², m²).
fn registration_covariance(noise: &ChainNoise) -> Matrix6<f64> {
    let (r, t) = (noise.camera_rad.powi(2), noise.camera_m.powi(2));
    Matrix6::from_diagonal(&Vector6::new(r, r, r, t, t, t))
}

/// The covariance of a tag's pose from its four corners: `camera_from_tag_true = exp((ω, v)) *
/// camera_from_tag`, `(ω, v)` in the camera frame (rad², m²). Each corner has `corner_px` of noise
/// per image axis where the tag faces the camera, growing as `sqrt(L / l)` where its shorter edge
/// shrinks from `L` (facing) to `l` pixels (a line fitted to fewer pixels): a tag seen at a
/// grazing angle is less certain, and so is one seen face on (its tilt moves the corners little).
fn tag_covariance(
    intrinsics: &crate::camera::Intrinsics,
    size_m: f64,
    camera_from_tag: &Isometry3<f64>,
    corner_px: f64,
) -> Matrix6<f64> {
    let h = size_m / 2.0;
    let corners = [(-h, -h), (h, -h), (h, h), (-h, h)].map(|(x, y)| camera_from_tag * nalgebra::Point3::new(x, y, 0.0));
    if corners.iter().any(|p| p.z <= 1e-6) {
        return Matrix6::from_diagonal_element(f64::INFINITY);
    }
    let pixel =
        |p: &nalgebra::Point3<f64>| nalgebra::Vector2::new(intrinsics.fx * p.x / p.z, intrinsics.fy * p.y / p.z);
    let facing_px = intrinsics.fx.min(intrinsics.fy) * size_m / camera_from_tag.translation.vector.norm();
    let mut info = Matrix6::zeros();
    for (k, p) in corners.iter().enumerate() {
        let edge = |other: usize| (pixel(p) - pixel(&corners[other])).norm();
        let shortest_px = edge((k + 1) % 4).min(edge((k + 3) % 4)).max(1e-6);
        let sigma_px = corner_px.max(1e-3) * (facing_px / shortest_px).max(1.0).sqrt();
        let proj = nalgebra::Matrix2x3::new(
            intrinsics.fx / p.z,
            0.0,
            -intrinsics.fx * p.x / (p.z * p.z),
            0.0,
            intrinsics.fy / p.z,
            -intrinsics.fy * p.y / (p.z * p.z),
        );
        let mut dp = nalgebra::Matrix3x6::zeros();
        dp.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-skew(&p.coords)));
        dp.fixed_view_mut::<3, 3>(0, 3).copy_from(&Matrix3::identity());
        let j = proj * dp;
        info += j.transpose() * j / (sigma_px * sigma_px);
    }
    info.try_inverse().unwrap_or_else(|| Matrix6::from_diagonal_element(f64::INFINITY))
}

/// `T_base_model`'s covariance (base frame, `(ω, v)`) from `fits`: per view that placed the model,
/// its index (into `loaded` and `flanges`) and its fit's covariance (camera frame). The hand-eye's error is common to
/// the views; the arm's and the fit's are averaged over them.
fn transported_covariance(
    fits: &[(usize, Matrix6<f64>)],
    flanges: &[Option<Isometry3<f64>>],
    loaded: &[LoadedView],
    prior: Option<&HandEyePrior>,
    noise: &ChainNoise,
) -> Matrix6<f64> {
    if fits.is_empty() {
        return Matrix6::from_diagonal_element(f64::INFINITY);
    }
    let n = fits.len() as f64;
    let (ar, at) = (noise.arm_rad.powi(2), noise.arm_m.powi(2));
    let arm = Matrix6::from_diagonal(&Vector6::new(ar, ar, ar, at, at, at));
    let mut mean_ad = Matrix6::zeros();
    let mut averaged = Matrix6::zeros();
    for &(i, ref fit) in fits {
        let base_from_camera = loaded[i].world_from_camera;
        let ad = adjoint(&base_from_camera);
        mean_ad += ad / n;
        averaged += ad * fit * ad.transpose() / (n * n);
        // the arm's error at the view's flange (at the camera when the view has no flange)
        let flange = flanges.get(i).copied().flatten().unwrap_or(base_from_camera);
        let af = adjoint(&flange);
        averaged += af * arm * af.transpose() / (n * n);
    }
    let common = prior.map_or(Matrix6::zeros(), |p| mean_ad * p.prior.covariance * mean_ad.transpose());
    common + averaged
}

/// The shot's points (base frame), merged and voxelised.
fn shot_points(views: &[LoadedView], voxel_m: f64) -> Result<PointCloud> {
    let mut merged = PointCloud::default();
    for view in views {
        merged.extend(&view.cloud_camera.transformed(&view.world_from_camera));
    }
    downsample(&merged, &VoxelParams { voxel_size_m: voxel_m })
}

fn refine_with_depth(
    views: &[LoadedView],
    model: &OnModelTarget<'_>,
    seed: &Isometry3<f64>,
    world_from_tag: &Isometry3<f64>,
    params: &ShotRefineParams,
) -> Result<ShotRefinement> {
    let points = shot_points(views, params.voxel_m)?;
    let model_from_base = seed.inverse();
    let source = near_model(&points, &model.crop, &model_from_base, params.crop_m);
    let mut r = ShotRefinement {
        applied: false,
        base_from_model: *seed,
        points: source.len(),
        fitness: 0.0,
        rmse_m: f64::NAN,
        correction_m: 0.0,
        correction_rad: 0.0,
        note: String::new(),
    };
    if source.len() < params.min_points {
        r.note = format!("{} shot points near the model, fewer than {}", source.len(), params.min_points);
        return Ok(r);
    }
    let icp = register_prepared(&source, &model.levels, &model_from_base, &params.icp)?;
    r.base_from_model = icp.target_from_source.inverse();
    r.fitness = icp.fitness;
    r.rmse_m = icp.inlier_rmse_m;
    // the correction as it moves the tag (where the targets are read from)
    let (dt, dr) = pose_difference(&(r.base_from_model * world_from_tag), &(seed * world_from_tag));
    (r.correction_m, r.correction_rad) = (dt, dr);
    if r.fitness < params.min_fitness {
        r.note = format!("ICP fitness {:.2} < {}", r.fitness, params.min_fitness);
    } else if dt > params.max_correction_m || dr > params.max_correction_rad {
        r.note = format!(
            "it would move the tag {:.1} mm / {:.2} deg (limits {:.1} mm / {:.2} deg)",
            dt * 1e3,
            dr.to_degrees(),
            params.max_correction_m * 1e3,
            params.max_correction_rad.to_degrees()
        );
    } else {
        r.applied = true;
    }
    Ok(r)
}

/// Views whose residuals exceed the noise model this many times (`sqrt(chi² / dof)`) are not combined.
const MAX_RESIDUAL_SCALE: f64 = 3.0;

/// [`ShotHandEye`] and the pose it locates.
struct Combined {
    summary: ShotHandEye,
    base_from_model: Isometry3<f64>,
}

/// Registers each shot view with depth onto the model (seeded by `base_from_model`, the prior's
/// hand-eye and the view's `T_base_ee`) and solves the chain of those views with the prior.
/// `None` (with a warning) when no view gives `T_base_ee` or none registers.
#[allow(clippy::too_many_arguments)]
fn combine_views(
    shot: &Scan,
    loaded: &[LoadedView],
    model: &OnModelTarget<'_>,
    base_from_model: &Isometry3<f64>,
    prior: &HandEyePrior,
    params: &ShotRefineParams,
    noise: &ChainNoise,
    warnings: &mut Vec<String>,
) -> Result<Option<Combined>> {
    let x = prior.prior.ee_from_camera;
    // a view's own registration may move it from where the merged shot put it by what the prior's
    // hand-eye error, the arm's pose error and the registration's explain together (3 sigma, the
    // rotation's at 0.6 m) and a little more; a view that moves farther slid on its own and is left out
    let c = &prior.prior.covariance;
    let he_rad = (0..3).map(|k| c[(k, k)]).fold(0.0, f64::max);
    let he_m = (3..6).map(|k| c[(k, k)]).fold(0.0, f64::max);
    let sigma_rad = (he_rad + noise.arm_rad.powi(2) + noise.camera_rad.powi(2)).sqrt();
    let sigma_m = (he_m + noise.arm_m.powi(2) + noise.camera_m.powi(2)).sqrt();
    let gate_rad = 3.0 * sigma_rad + 0.1f64.to_radians();
    let gate_m = 3.0 * sigma_m + 0.6 * gate_rad + 0.001;
    // each view registered on its own (in parallel), then taken in order
    // per view: its flange, the seed and its fit (`None`: no flange pose, or it did not register)
    type ViewFit = Option<(Isometry3<f64>, Isometry3<f64>, OnModel)>;
    let fits: Vec<Result<ViewFit>> = (0..loaded.len())
        .into_par_iter()
        .map(|i| {
            let ViewPose::Chain { world_from_base, base_from_ee } = shot.views[i].pose else { return Ok(None) };
            // world = the robot base at piercing time: the view's flange in it
            let base_from_ee = world_from_base * base_from_ee;
            let seed = base_from_model.inverse() * base_from_ee * x;
            let points = downsample(&loaded[i].cloud_camera, &VoxelParams { voxel_size_m: params.voxel_m })?;
            Ok(register_onto_model(&points, model, &seed, params)?.map(|r| (base_from_ee, seed, r)))
        })
        .collect();
    let mut views = Vec::new();
    let mut registered = Vec::new();
    for (i, fit) in fits.into_iter().enumerate() {
        let Some((base_from_ee, seed, r)) = fit? else { continue };
        let (dt, dr) = pose_difference(&r.model_from_source, &seed);
        if dt > gate_m || dr > gate_rad {
            warnings.push(format!(
                "shot view {i}: its own registration moved it {:.1} mm / {:.2} deg from the merged shot's fit \
                 (more than the hand-eye's {:.1} mm / {:.2} deg explain): left out of the hand-eye combination",
                dt * 1e3,
                dr.to_degrees(),
                gate_m * 1e3,
                gate_rad.to_degrees()
            ));
            continue;
        }
        views.push(ChainView {
            stop: 0,
            world_from_base: Isometry3::identity(),
            base_from_ee,
            model_from_camera: r.model_from_source,
        });
        registered.push((i, r.fitness, r.rmse_m));
    }
    if views.is_empty() {
        warnings.push("no shot view registered onto the model on its own: the hand-eye is not combined".into());
        return Ok(None);
    }
    let chain = ChainParams { noise: *noise, stops: StopPrior::Known, max_iterations: 30, prior_dof: None };
    let e = refine_chain(&views, &prior.prior, &chain)?;
    if e.residual_scale > MAX_RESIDUAL_SCALE {
        warnings.push(format!(
            "the shot's views disagree with the hand-eye and the arm's poses ({:.1} times the noise model): the \
             merged shot's fit is used",
            e.residual_scale
        ));
        return Ok(None);
    }
    let g_covariance = Matrix6::from_fn(|a, b| e.joint_covariance[(a + 6, b + 6)]);
    // G = model_from_base with right perturbation D (base frame): base_from_model = G^-1, whose
    // error is D^-1 on the left, the covariance's convention
    let summary = ShotHandEye {
        ee_from_camera: e.ee_from_camera,
        ee_from_camera_covariance: e.covariance,
        prior: x,
        prior_source: prior.source.clone(),
        base_from_model_covariance: g_covariance,
        views: registered,
        residual_scale: e.residual_scale,
    };
    Ok(Some(Combined { summary, base_from_model: e.model_from_world.inverse() }))
}

/// The points of `points` (source frame) within `crop_m` metres of the model placed by
/// `model_from_source`, in their order.
fn near_model(points: &PointCloud, model: &LeafTree, model_from_source: &Isometry3<f64>, crop_m: f64) -> PointCloud {
    let crop_sq = (crop_m * crop_m) as f32;
    let keep: Vec<usize> = (0..points.len())
        .into_par_iter()
        .filter(|&i| {
            let q = (model_from_source * points.points[i].cast::<f64>()).cast::<f32>();
            // the first model point that near answers; a shot point far from the model (floor,
            // clutter) visits few nodes
            model.any_within(&q, crop_sq)
        })
        .collect();
    points.select(&keep)
}

/// The model as the shot's points are registered onto it, built once for every registration: its
/// ICP levels, and a tree of its points for the crop ([`near_model`]).
struct OnModelTarget<'m> {
    levels: PreparedTarget<'m>,
    crop: LeafTree,
}

/// One source registered onto the model.
struct OnModel {
    model_from_source: Isometry3<f64>,
    fitness: f64,
    rmse_m: f64,
}

/// ICP of `points` (source frame) onto the model from `model_from_source`, keeping the points
/// within `crop_m` of the model there; `None` when too few points remain, the fit is poor or the
/// correction exceeds the limits.
fn register_onto_model(
    points: &PointCloud,
    model: &OnModelTarget<'_>,
    model_from_source: &Isometry3<f64>,
    params: &ShotRefineParams,
) -> Result<Option<OnModel>> {
    let near = near_model(points, &model.crop, model_from_source, params.crop_m);
    if near.len() < params.min_points {
        return Ok(None);
    }
    let icp = register_prepared(&near, &model.levels, model_from_source, &params.icp)?;
    let (dt, dr) = pose_difference(&icp.target_from_source, model_from_source);
    if icp.fitness < params.min_fitness || dt > params.max_correction_m || dr > params.max_correction_rad {
        return Ok(None);
    }
    Ok(Some(OnModel { model_from_source: icp.target_from_source, fitness: icp.fitness, rmse_m: icp.inlier_rmse_m }))
}

#[cfg(test)]
mod tests {
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    use super::*;
    use crate::camera::Intrinsics;

    fn camera() -> Intrinsics {
        Intrinsics { width: 640, height: 480, fx: 600.0, fy: 600.0, cx: 320.0, cy: 240.0, distortion: [0.0; 5] }
    }

    /// The 95 % bound on the error of a point 25 cm across the tag from its centre (the tag's pose
    /// error alone), metres, the tag `distance_m` away and turned `tilt_deg` from facing the camera.
    fn bound_m(distance_m: f64, tilt_deg: f64) -> f64 {
        let camera_from_tag = Isometry3::from_parts(
            Translation3::new(0.02, -0.01, distance_m),
            UnitQuaternion::from_scaled_axis(Vector3::y() * tilt_deg.to_radians()),
        );
        let c = tag_covariance(&camera(), 0.08, &camera_from_tag, 0.3);
        let p = camera_from_tag * nalgebra::Point3::new(0.25, 0.0, 0.0);
        let mut j = nalgebra::Matrix3x6::zeros();
        j.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-skew(&p.coords)));
        j.fixed_view_mut::<3, 3>(0, 3).copy_from(&Matrix3::identity());
        crate::pierce::predict::norm_quantile(&(j * c * j.transpose()), 0.95)
    }

    #[test]
    fn a_tag_seen_at_a_grazing_angle_or_far_away_is_less_certain() {
        let b: Vec<f64> = [0.0, 30.0, 60.0, 75.0, 80.0].iter().map(|t| bound_m(0.4, *t)).collect();
        println!("bounds at 0, 30, 60, 75, 80 deg: {:?} mm", b.iter().map(|v| v * 1e3).collect::<Vec<_>>());
        // face on, the tilt is weakly seen; beyond 60 deg, the shrinking edges' corners
        // measured 11.0, 5.0, 3.7, 4.1, 4.5 mm
        assert!(b[0] > 2.0 * b[2] && b[4] > 1.15 * b[2] && b[4] > b[3] && b[3] > b[2], "{b:?}");
        assert!(bound_m(0.8, 30.0) > 2.0 * bound_m(0.4, 30.0));
        // behind the camera: unbounded
        let behind = Isometry3::translation(0.0, 0.0, -0.4);
        assert!(tag_covariance(&camera(), 0.08, &behind, 0.3)[(0, 0)].is_infinite());
    }

    #[test]
    fn the_adjoint_carries_a_perturbation_between_frames() {
        let a_from_b = Isometry3::from_parts(
            Translation3::new(0.3, -0.2, 0.5),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.4, -0.1, 0.9)),
        );
        let xi = Vector6::new(0.001, -0.002, 0.0015, 0.0003, 0.0001, -0.0002);
        let exp = |x: &Vector6<f64>| {
            crate::transform::isometry_from_translation_rotvec(
                Vector3::new(x[3], x[4], x[5]),
                Vector3::new(x[0], x[1], x[2]),
            )
        };
        let moved = a_from_b * exp(&xi) * a_from_b.inverse();
        let carried = exp(&(adjoint(&a_from_b) * xi));
        // first order: the difference is of the order of |xi|^2 (1e-6), where leaving out the
        // translation's lever arm errs by |t| |ω| (1e-3)
        let (dt, dr) = pose_difference(&moved, &carried);
        assert!(dt < 3e-6 && dr < 1e-9, "{dt} {dr}");
        let mut rotation_only = adjoint(&a_from_b);
        rotation_only.fixed_view_mut::<3, 3>(3, 0).fill(0.0);
        let (naive, _) = pose_difference(&moved, &exp(&(rotation_only * xi)));
        assert!(naive > 5e-4, "{naive}");
    }
}
