//! The piercing trials of the reference paper (its Tables I-IV), in simulation: the whole workflow
//! against ground truth.
//!
//! 1. Hand-eye: a simulated calibration capture of the rig's camera ([`calibrate_rig`]: `count`
//!    poses, 0.5 mm / 0.1 degree tag noise) solved by [`crate::handeye::calibrate`]; its
//!    `T_ee_camera` replaces the shots' recorded one, as a user would after calibrating.
//! 2. Modeling (done by the caller: simulate a scan, `fuse`): [`prepare_workpiece`] estimates the
//!    tag on the model and picks the target on it. Where the user clicks is defined through the
//!    model's alignment onto the CAD (ICP from the true pose, as `awl evaluate` does): a face centre
//!    is picked 5 cm off the true centre and 3 mm above the face (the method must find the centre),
//!    a point on a curved surface exactly at the true target (the method snaps it).
//! 3. Per trial ([`run_shot`]): a shot of the workpiece in a new random placement (seeded per trial),
//!    taken with the scan's camera (same intrinsics and depth-scale error, [`ShotSetup::camera_seed`]),
//!    [`crate::pierce::plan`], and the planned point and axis against the shot's truth (robot base
//!    frame): the axis against the true normal at the target, and against the true normal where
//!    the tool meets the surface (the true surface's point nearest the planned one).
//! 4. With an arm ([`ShotSetup::robot`], `awl trial --robot`): each trial's plan checked by
//!    [`crate::pierce::plan_reach`] as `awl pierce --robot` does (the arm's base at the simulated
//!    rig's robot base, the shot's joint state preferred when its views record one), its reach kept
//!    in the row ([`TrialRow::reach`]) beside the target's distance from the base.

mod table;

use std::path::Path;

use nalgebra::{Isometry3, Point3, Vector3};

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::eval::{EvaluateParams, evaluate};
use crate::handeye::{HandEyeParams, calibrate};
use crate::io::scan::read_scan;
use crate::io::truth::{Truth, TruthTarget};
use crate::kinematics::Arm;
use crate::mesh::TriMesh;
use crate::pierce::{PierceParams, ReachParams, TargetReach, plan, plan_reach, shot_joints};
use crate::scan::TagSpec;
use crate::sim::calibration::{CalibrationSimParams, simulate_calibration};
use crate::sim::{SceneKind, ShotPose, SimParams, nearest_surface, rig_ee_from_camera, simulate, write_simulation};
use crate::transform::pose_difference;
use crate::workpiece::{FloorPlane, SurfaceModel, TargetSpec, Workpiece};

pub use table::{TrialSummary, format_table, reach_line};

/// A calibrated hand-eye and how far it is from the truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalibratedHandEye {
    /// The estimated `T_ee_camera`.
    pub ee_from_camera: Isometry3<f64>,
    /// Its error against the rig's true one: translation, metres.
    pub error_m: f64,
    /// ... and rotation, radians.
    pub error_rad: f64,
    /// Poses of the capture.
    pub poses: usize,
}

/// Calibrates the simulated rig's camera from `count` simulated poses (module docs).
///
/// # Errors
/// Any error of the capture simulation or the solver.
pub fn calibrate_rig(seed: u64, count: usize) -> Result<CalibratedHandEye> {
    let truth = rig_ee_from_camera();
    let capture = simulate_calibration(&CalibrationSimParams {
        seed,
        count,
        ee_from_camera: Some(truth),
        ..CalibrationSimParams::default()
    })?;
    let result = calibrate(&capture.poses, &HandEyeParams::default())?;
    let (error_m, error_rad) = pose_difference(&result.ee_from_camera, &truth);
    Ok(CalibratedHandEye { ee_from_camera: result.ee_from_camera, error_m, error_rad, poses: count })
}

/// The modeled workpiece the trials pierce.
#[derive(Debug, Clone)]
pub struct TrialWorkpiece {
    /// The fused model (model frame = the scan's world frame).
    pub model: PointCloud,
    /// The tag.
    pub tag: TagSpec,
    /// `T_world_tag` on the model.
    pub world_from_tag: Isometry3<f64>,
    /// The model's alignment onto the CAD (defines where the user clicks only).
    pub object_from_model: Isometry3<f64>,
    /// The truth target.
    pub target: TruthTarget,
    /// The target as the user gives it (model frame).
    pub spec: TargetSpec,
    /// The floor fusion found (model frame).
    pub floor: Option<FloorPlane>,
}

/// Picks the target a user would give for `target` on a model aligned by `object_from_model`.
pub fn pick_target(scene: SceneKind, target: &TruthTarget, object_from_model: &Isometry3<f64>) -> TargetSpec {
    let model_from_object = object_from_model.inverse();
    match scene {
        SceneKind::Box => {
            let n = target.n_object.normalize();
            let along = Vector3::new(0.04, -0.03, 0.02);
            let in_face = along - n * along.dot(&n);
            TargetSpec::FaceCentre(model_from_object * (target.p_object + in_face.normalize() * 0.05 + n * 0.003))
        }
        _ => TargetSpec::Point(model_from_object * target.p_object),
    }
}

/// The target `target_name` of the truth (its first when `None`) on the fused `model` whose tag `wp` gives ([`crate::workpiece::workpiece_from_fuse`]; module docs).
///
/// # Errors
/// [`Error::Invalid`] when no view saw the tag, or the truth has no (such) target; any error of
/// the alignment onto the CAD.
pub fn prepare_workpiece(
    scene: SceneKind,
    wp: &Workpiece,
    truth: &Truth,
    cad: &TriMesh,
    model: &PointCloud,
    target_name: Option<&str>,
) -> Result<TrialWorkpiece> {
    let world_from_tag = wp
        .world_from_tag
        .ok_or_else(|| Error::invalid("workpiece", format!("no tag pose: {}", wp.warnings.join("; "))))?;
    let target = truth.targets.iter().find(|t| target_name.is_none_or(|n| n == t.name)).cloned().ok_or_else(|| {
        let names: Vec<&str> = truth.targets.iter().map(|t| t.name.as_str()).collect();
        Error::invalid("truth.json targets", format!("no target {} (has {names:?})", target_name.unwrap_or("at all")))
    })?;
    let start = truth.world_from_object.inverse();
    let object_from_model = evaluate(model, cad, Some(&start), &EvaluateParams::default())?.object_from_model;
    let spec = pick_target(scene, &target, &object_from_model);
    Ok(TrialWorkpiece {
        model: model.clone(),
        tag: wp.tag.clone(),
        world_from_tag,
        object_from_model,
        target,
        spec,
        floor: wp.floor,
    })
}

/// One trial's outcome, robot base frame.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialRow {
    /// Trial number (1-based).
    pub trial: usize,
    /// Seed of the shot.
    pub shot_seed: u64,
    /// The true target point.
    pub truth: Point3<f64>,
    /// The planned point.
    pub estimate: Point3<f64>,
    /// The point planned from the tag pose alone (no shot-depth refinement).
    pub estimate_tag_only: Point3<f64>,
    /// Angle between the planned axis and the true inward normal, radians.
    pub axis_error_rad: f64,
    /// Where the axis error comes from (it is at most the sum of these two): the rotation error
    /// of the located `T_base_model`, radians ...
    pub locate_rotation_rad: f64,
    /// ... and the angle between the model's normal at the planned point and the true normal at
    /// the target (model frame, through the model's alignment onto the CAD), radians.
    pub model_normal_error_rad: f64,
    /// Whether the shot-depth refinement was applied.
    pub refined: bool,
    /// The hand-eye the plan used (after the shot's views) against the rig's true one: translation
    /// (m) and rotation (rad); `None` when the shot's views were not combined.
    pub hand_eye_error: Option<(f64, f64)>,
    /// Angle between the planned axis and the true inward normal at the true surface's point
    /// nearest the planned point (where the tool meets the surface), radians.
    pub axis_error_at_point_rad: f64,
    /// The plan's predicted 95 % bounds (and their covariances) for this target.
    pub prediction: crate::pierce::Prediction,
    /// The share of the located pose in the predicted position covariance, base frame, m² (the
    /// rest is the model's): for calibrating the prediction.
    pub located_position_covariance: nalgebra::Matrix3<f64>,
    /// The model's outward normal at the target, base frame (unit).
    pub normal_base: Vector3<f64>,
    /// Whether the target is a face centre.
    pub face_centre: bool,
    /// The planned target's reach for [`ShotSetup::robot`] (`None`: no arm given).
    pub reach: Option<TargetReach>,
    /// Views `awl plan-views` added to the shot ([`ShotSetup::plan_views`]).
    pub planned_views: usize,
}

impl TrialRow {
    /// Estimate minus truth, metres.
    pub fn error(&self) -> Vector3<f64> {
        self.estimate - self.truth
    }

    /// The planned point's distance from the robot base's origin, metres.
    pub fn base_distance_m(&self) -> f64 {
        self.estimate.coords.norm()
    }

    /// ... and from the base's vertical axis (joint 1's), metres.
    pub fn base_horizontal_m(&self) -> f64 {
        self.estimate.coords.xy().norm()
    }
}

/// The arm a trial's plans are checked for (`awl trial --robot`), its base at the simulated rig's
/// robot base (the shots' world frame).
#[derive(Debug, Clone, PartialEq)]
pub struct TrialRobot {
    /// The arm.
    pub arm: Arm,
    /// `T_ee_tool`: the tool centre point on the flange.
    pub ee_from_tool: Isometry3<f64>,
    /// The reach settings (spin, tool capsule, collision distances).
    pub params: ReachParams,
}

/// Seed of trial `k` (1-based) of a run seeded `seed`.
pub fn shot_seed(seed: u64, k: usize) -> u64 {
    seed * 1000 + k as u64
}

/// What every shot of a trial run shares.
#[derive(Debug, Clone)]
pub struct ShotSetup {
    /// The workpiece.
    pub scene: SceneKind,
    /// How it lies.
    pub pose: ShotPose,
    /// Seed of the run (each trial's shot gets [`shot_seed`]).
    pub seed: u64,
    /// Seed of the camera: the scan's, as the same camera takes the shots
    /// ([`SimParams::camera_seed`]).
    pub camera_seed: u64,
    /// The `T_ee_camera` used at piercing time (e.g. [`calibrate_rig`]'s).
    pub ee_from_camera: Isometry3<f64>,
    /// Planning parameters.
    pub params: PierceParams,
    /// The arm each plan's reach is checked for (`None`: not checked).
    pub robot: Option<TrialRobot>,
    /// After the 2-view shot, `awl plan-views` proposes up to this many views among its own
    /// candidates ([`crate::plan_views::sample::sample_candidates`]), the shot is taken again with
    /// them and the target planned from all (0: the shot alone).
    pub plan_views: usize,
}

/// The tolerance the trials plan views for: 1 mm, so that the views are planned while they lower
/// the bound (the trial scores the errors, not a go).
const TRIAL_TOLERANCE_M: f64 = 0.001;

/// The flange poses `awl plan-views` proposes after `planned` (up to `max_views`, among the
/// candidates sampled around the shot's first view and the targets), checked for `robot` when given.
fn planned_flanges(
    planned: &crate::pierce::PiercePlan,
    params: &PierceParams,
    shot: &crate::scan::Scan,
    wp: &TrialWorkpiece,
    robot: Option<&TrialRobot>,
    max_views: usize,
) -> Result<Vec<Isometry3<f64>>> {
    let candidates = crate::plan_views::sample::candidates_after_pierce(planned, shot)?;
    if candidates.is_empty() {
        return Ok(Vec::new());
    }
    let views_params = crate::plan_views::PlanViewsParams {
        max_views,
        tolerance: crate::pierce::Tolerance { position_m: Some(TRIAL_TOLERANCE_M), axis_rad: None },
        ..crate::plan_views::PlanViewsParams::default()
    };
    let robot = robot.map(|r| crate::plan_views::reach::ViewRobot {
        body: r.params.body,
        collision: r.params.collision,
        floor: wp.floor,
        ..crate::plan_views::reach::ViewRobot::new(r.arm.clone(), r.ee_from_tool)
    });
    let views = crate::plan_views::plan_after_pierce(
        planned,
        params,
        shot,
        &wp.model,
        robot.as_ref(),
        &candidates,
        &views_params,
    )?;
    Ok(views.chosen.iter().map(|c| candidates[c.candidate].base_from_ee).collect())
}

/// Simulates the shot of trial `k` (1-based) into `dir`, plans the target and compares with the
/// truth; with [`ShotSetup::robot`], checks the plan's reach for the arm.
///
/// # Errors
/// Any error of the simulation, writing, or planning (e.g. the tag not found), or of the reach
/// check's inputs; an unreachable target is not an error (its row says why).
pub fn run_shot(wp: &TrialWorkpiece, setup: &ShotSetup, k: usize, dir: &Path) -> Result<TrialRow> {
    let shot_seed = shot_seed(setup.seed, k);
    let (scene, pose, params) = (setup.scene, setup.pose, &setup.params);
    let mut sim =
        simulate(&SimParams { seed: shot_seed, camera_seed: Some(setup.camera_seed), ..SimParams::shot(scene, pose) })?;
    write_simulation(dir, &sim, false)?;
    let mut shot = read_scan(dir)?;
    shot.ee_from_camera = Some(setup.ee_from_camera);
    let truth_target = sim
        .truth
        .targets
        .iter()
        .find(|t| t.name == wp.target.name)
        .cloned()
        .ok_or_else(|| Error::invalid("shot truth", format!("no target {}", wp.target.name)))?;
    let (truth, n_base) = match (truth_target.p_world, truth_target.n_world) {
        (Some(p), Some(n)) => (p, n),
        _ => return Err(Error::invalid("shot truth", "the target has no p_world / n_world")),
    };
    let surface = SurfaceModel::new(&wp.model)?.with_floor(wp.floor);
    let mut planned = plan(&surface, &wp.tag, &wp.world_from_tag, &shot, std::slice::from_ref(&wp.spec), params)?;
    let mut planned_views = 0;
    if setup.plan_views > 0 {
        let flanges = planned_flanges(&planned, params, &shot, wp, setup.robot.as_ref(), setup.plan_views)?;
        if !flanges.is_empty() {
            planned_views = flanges.len();
            let sim_params =
                SimParams { seed: shot_seed, camera_seed: Some(setup.camera_seed), ..SimParams::shot(scene, pose) };
            sim = crate::sim::simulate_with_views(&sim_params, &flanges)?;
            let dir = dir.join("planned");
            write_simulation(&dir, &sim, false)?;
            shot = read_scan(&dir)?;
            shot.ee_from_camera = Some(setup.ee_from_camera);
            planned = plan(&surface, &wp.tag, &wp.world_from_tag, &shot, std::slice::from_ref(&wp.spec), params)?;
        }
    }
    if let Some(robot) = &setup.robot {
        let reference = shot_joints(&shot)?;
        plan_reach(&mut planned, &robot.arm, &robot.ee_from_tool, &wp.model, wp.floor, reference, &robot.params)?;
    }
    let t = &planned.targets[0];
    let true_base_from_model = sim.truth.world_from_object * wp.object_from_model;
    let true_n_model = wp.object_from_model.inverse_transform_vector(&truth_target.n_object);
    let object_from_base = sim.truth.world_from_object.inverse();
    let (_, n_object_at_point) = nearest_surface(scene, &(object_from_base * t.p_base));
    let n_base_at_point = sim.truth.world_from_object.rotation * n_object_at_point;
    Ok(TrialRow {
        trial: k,
        shot_seed,
        truth,
        estimate: t.p_base,
        estimate_tag_only: planned.located.base_from_model_tag * t.surface.point,
        axis_error_rad: t.axis_base.angle(&-n_base),
        locate_rotation_rad: planned.located.base_from_model.rotation.angle_to(&true_base_from_model.rotation),
        model_normal_error_rad: t.surface.normal.angle(&true_n_model),
        refined: planned.located.refinement.as_ref().is_some_and(|r| r.applied),
        hand_eye_error: match (&planned.located.hand_eye, sim.truth.ee_from_camera) {
            (Some(h), Some(truth)) => Some(pose_difference(&h.ee_from_camera, &truth)),
            _ => None,
        },
        axis_error_at_point_rad: t.axis_base.angle(&-n_base_at_point),
        prediction: t.prediction,
        located_position_covariance: crate::handeye::chain::point_covariance(
            &planned.located.base_from_model.inverse(),
            &planned.located.base_from_model_covariance,
            &t.surface.point,
        ),
        normal_base: t.normal_base,
        face_centre: t.surface.corners.is_some(),
        reach: t.reach.clone(),
        planned_views,
    })
}
