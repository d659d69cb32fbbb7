//! The views a shot still needs: from what a 2-view shot already shows, the next flange poses at the
//! same base pose that bring each target's predicted error under the tolerance (`awl plan-views`).
//!
//! A candidate view is judged by what it would add to the located pose: it is one more view of the
//! chain `T_model_camera = T_model_base * T_base_ee * T_ee_camera` ([`crate::handeye::chain`]), whose
//! registration onto the model observes the motions the model's surface in its field of view pins
//! down (the point-to-plane information of the model points it would see; a flat face alone leaves
//! its in-plane slide and spin unobserved). The chain's covariance with the candidate added gives
//! each target's predicted bounds ([`crate::pierce::predict`]) before the view is taken.
//!
//! Greedy: each round adds the candidate that lowers the worst target's bound (over the tolerance)
//! most, until every target meets the tolerance, `max_views` are chosen, or no candidate lowers it by
//! [`PlanViewsParams::min_gain`]. A candidate whose camera would stand within
//! [`PlanViewsParams::clearance_m`] of the shot's own depth points (something there) or that sees too
//! little of the model is left out, with the reason.
//!
//! Candidates are given (a cell's taught poses, a view bank) or sampled around the shot
//! ([`sample`]). With an arm ([`ShotState::arm`]), a candidate is used only when the arm reaches it
//! in a configuration clear of the workpiece and the shot's depth, and a view is chosen only when the
//! joint move to it from the one before (the first from the shot's joints) is clear ([`reach`]).
//! Not yet: the targets' local surfaces measured from close views (the axis bound falls only by the
//! located rotation).

pub mod file;
pub mod program;
pub mod reach;
pub mod sample;

use nalgebra::{Isometry3, Matrix6, Point3, SymmetricEigen, Vector3, Vector6};

use crate::camera::DepthCamera;
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::handeye::chain::{ChainNoise, ChainParams, ChainPrior, ChainView, StopPrior, refine_chain_observed};
use crate::kinematics::Joints;
use crate::kinematics::collision::{Clearance, Obstacles};
use crate::pierce::predict::{PredictParams, TargetGeometry, Tolerance, predict};
use crate::plan_views::reach::{ViewArm, ViewJoints, ViewRobot, view_obstacles};
use crate::spatial::KdIndex;

/// A flange pose the arm could take for one more view.
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    /// `T_base_ee`: the commanded flange pose, robot base frame, metres.
    pub base_from_ee: Isometry3<f64>,
    /// Why it is offered (from the candidates file).
    pub why: String,
    /// The view's number in its bank, when it has one.
    pub view: Option<usize>,
}

/// Parameters of [`plan_views`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanViewsParams {
    /// At most this many views are proposed.
    pub max_views: usize,
    /// The bounds to reach.
    pub tolerance: Tolerance,
    /// A candidate is used only when it would see at least this many of the model's points (of at
    /// most [`PlanViewsParams::model_samples`]). Default 300.
    pub min_visible: usize,
    /// The model points looked at per candidate (an even subsample). Default 20 000.
    pub model_samples: usize,
    /// Surface seen at more than this incidence is not counted, radians. Default 75 deg.
    pub max_incidence_rad: f64,
    /// A camera within this of a point of the shot's own depth would stand inside something, metres.
    /// Default 0.05.
    pub clearance_m: f64,
    /// A round must lower the worst target's excess by at least this share to add a view. Default 0.02.
    pub min_gain: f64,
    /// A motion of the registration whose information is below this share of the largest (rotations
    /// scaled by the visible surface's rms radius) is unobserved. Default 1e-3.
    pub unobserved_ratio: f64,
}

impl Default for PlanViewsParams {
    fn default() -> Self {
        Self {
            max_views: 4,
            tolerance: Tolerance::default(),
            min_visible: 300,
            model_samples: 20_000,
            max_incidence_rad: 75f64.to_radians(),
            clearance_m: 0.05,
            min_gain: 0.02,
            unobserved_ratio: 1e-3,
        }
    }
}

impl PlanViewsParams {
    /// Checks the settings.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming `--max-views` (0 or over 64) or a tolerance that is not a positive number.
    pub fn validate(&self) -> Result<()> {
        if self.max_views == 0 || self.max_views > 64 {
            return Err(Error::invalid("--max-views", format!("{} is not between 1 and 64", self.max_views)));
        }
        self.tolerance.validate()?;
        if self.tolerance.position_m.is_none() && self.tolerance.axis_rad.is_none() {
            return Err(Error::invalid(
                "--tolerance-mm / --tolerance-deg",
                "give at least one tolerance: the views are planned to meet it",
            ));
        }
        Ok(())
    }
}

/// What is known at the shot, for [`plan_views`].
#[derive(Debug, Clone)]
pub struct ShotState<'a> {
    /// `T_base_model` located from the shot.
    pub base_from_model: Isometry3<f64>,
    /// The hand-eye used (`T_ee_camera`) and its prior covariance before the shot's views.
    pub prior: ChainPrior,
    /// The flange poses (`T_base_ee`) of the shot's views that registered onto the model.
    pub shot_flanges: Vec<Isometry3<f64>>,
    /// Each view's noise.
    pub noise: ChainNoise,
    /// The camera (intrinsics and range).
    pub camera: DepthCamera,
    /// The model (model frame, with normals).
    pub model: &'a PointCloud,
    /// The shot's own depth points, base frame (obstacles).
    pub shot_points: &'a PointCloud,
    /// The targets and the model's share of their errors.
    pub targets: Vec<TargetGeometry>,
    /// The bounds' probability and the model's share.
    pub predict: PredictParams,
    /// The arm the views are checked for, and its obstacles; `None`: not checked.
    pub arm: Option<ArmCheck<'a>>,
}

/// The arm at the shot and what it must stay clear of.
#[derive(Clone, Copy)]
pub struct ArmCheck<'a> {
    /// The arm, its tool and its joints at the shot.
    pub arm: &'a ViewArm,
    /// The model, its floor and the shot's depth points, base frame.
    pub obstacles: &'a Obstacles,
}

impl std::fmt::Debug for ArmCheck<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ArmCheck").field("arm", &self.arm.arm.name).field("obstacles", &self.obstacles.len()).finish()
    }
}

/// A chosen view's joints and the move to it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewReach {
    /// The joints at the view.
    pub joints: ViewJoints,
    /// The smallest clearance of the joint move to it from the view before (the first from the
    /// shot's joints); `None`: nothing within the collision reach.
    pub move_clearance: Option<Clearance>,
}

/// Each target's predicted 95 % bounds: position (m), axis (rad).
pub type Bounds = Vec<(f64, f64)>;

/// One proposed view.
#[derive(Debug, Clone, PartialEq)]
pub struct ChosenView {
    /// Index into the candidates.
    pub candidate: usize,
    /// Model points (of the subsample) the view would see.
    pub visible: usize,
    /// Motions its registration would leave unobserved.
    pub unobserved: usize,
    /// Each target's bounds once this view (and the ones before) are taken.
    pub bounds: Bounds,
    /// Why it was chosen.
    pub why: String,
    /// With an arm: its joints and the move to it.
    pub reach: Option<ViewReach>,
}

/// The plan.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewPlan {
    /// Each target's bounds from the shot's views alone.
    pub before: Bounds,
    /// The views to take, in visiting order.
    pub chosen: Vec<ChosenView>,
    /// Whether every target meets the tolerance once they are taken.
    pub met: bool,
    /// Why the plan stops where it does.
    pub stop: String,
    /// Candidates left out, and why.
    pub left_out: Vec<(usize, String)>,
    /// With an arm: its joints at the shot (radians), where the first move starts, and whether the
    /// shot recorded them.
    pub start: Option<(Joints, bool)>,
}

/// What one candidate would add.
struct Evidence {
    view: ChainView,
    unobserved: Vec<Vector6<f64>>,
    visible: usize,
    joints: Option<ViewJoints>,
}

/// The candidate's view onto the model, or why it cannot be used.
fn evidence(
    state: &ShotState<'_>,
    base_from_ee: &Isometry3<f64>,
    obstacles: &KdIndex,
    params: &PlanViewsParams,
) -> std::result::Result<Evidence, String> {
    let view = chain_view(state, base_from_ee);
    let model_from_camera = view.model_from_camera;
    let camera_base = (base_from_ee * state.prior.ee_from_camera).translation.vector;
    if let Some(n) = obstacles.nearest(&Point3::from(camera_base).cast::<f32>())
        && f64::from(n.dist_sq).sqrt() < params.clearance_m
    {
        return Err(format!(
            "the camera would stand {:.0} mm from a point of the shot's depth (something is there)",
            f64::from(n.dist_sq).sqrt() * 1e3
        ));
    }
    let camera_from_model = model_from_camera.inverse();
    let centre = model_from_camera.translation.vector;
    let normals = state.model.normals.as_ref();
    let stride = (state.model.len() / params.model_samples.max(1)).max(1);
    let cos_max = params.max_incidence_rad.cos();
    let (w, h) = (f64::from(state.camera.intrinsics.width), f64::from(state.camera.intrinsics.height));
    let mut seen: Vec<(Vector3<f64>, Vector3<f64>)> = Vec::new();
    for i in (0..state.model.len()).step_by(stride) {
        let p = state.model.points[i].cast::<f64>();
        let q = camera_from_model * p;
        if !(q.z >= state.camera.depth_min_m && q.z <= state.camera.depth_max_m) {
            continue;
        }
        let Some(px) = state.camera.intrinsics.project(&q) else { continue };
        if !(px.x >= -0.5 && px.y >= -0.5 && px.x < w - 0.5 && px.y < h - 0.5) {
            continue;
        }
        let Some(n) = normals.map(|n| n[i].cast::<f64>()) else { continue };
        let to_camera = (centre - p.coords).normalize();
        if n.dot(&to_camera) < cos_max {
            continue;
        }
        seen.push((p.coords, n));
    }
    if seen.len() < params.min_visible {
        return Err(format!("it would see {} model points (at least {} needed)", seen.len(), params.min_visible));
    }
    let unobserved = unobserved_motions(&seen, params.unobserved_ratio);
    let joints = match &state.arm {
        Some(a) => Some(a.arm.joints_of(base_from_ee, a.obstacles)?),
        None => None,
    };
    Ok(Evidence { view, unobserved, visible: seen.len(), joints })
}

/// A view from the flange pose `base_from_ee` as the chain sees it: at the shot's one base pose
/// (the robot base), its camera placed on the located model by the hand-eye.
fn chain_view(state: &ShotState<'_>, base_from_ee: &Isometry3<f64>) -> ChainView {
    ChainView {
        stop: 0,
        world_from_base: Isometry3::identity(),
        base_from_ee: *base_from_ee,
        model_from_camera: state.base_from_model.inverse() * base_from_ee * state.prior.ee_from_camera,
    }
}

/// The motions (twists `(ω, v)` in the model frame: a point moves at `v + ω × p`) that a
/// point-to-plane registration onto the `seen` points and normals leaves unobserved.
fn unobserved_motions(seen: &[(Vector3<f64>, Vector3<f64>)], ratio: f64) -> Vec<Vector6<f64>> {
    let n = seen.len() as f64;
    let c = seen.iter().map(|(p, _)| p).sum::<Vector3<f64>>() / n;
    let radius = (seen.iter().map(|(p, _)| (p - c).norm_squared()).sum::<f64>() / n).sqrt().max(1e-6);
    let mut h = Matrix6::zeros();
    for (p, normal) in seen {
        // rotations scaled by the radius: both halves in metres
        let r = (p - c).cross(normal) / radius;
        let j = Vector6::new(r.x, r.y, r.z, normal.x, normal.y, normal.z);
        h += j * j.transpose();
    }
    let e = SymmetricEigen::new(h);
    let largest = e.eigenvalues.max();
    (0..6)
        .filter(|&k| e.eigenvalues[k] < ratio * largest)
        .map(|k| {
            let d = e.eigenvectors.column(k);
            let omega = Vector3::new(d[0], d[1], d[2]) / radius;
            let v_c = Vector3::new(d[3], d[4], d[5]);
            let v = v_c - omega.cross(&c);
            Vector6::new(omega.x, omega.y, omega.z, v.x, v.y, v.z)
        })
        .collect()
}

/// Each target's bounds with the shot's views and `extra` ones.
fn bounds_with(state: &ShotState<'_>, base: &[Evidence], extra: &[&Evidence]) -> Result<Bounds> {
    let all: Vec<&Evidence> = base.iter().chain(extra.iter().copied()).collect();
    let views: Vec<ChainView> = all.iter().map(|e| e.view).collect();
    let unobserved: Vec<Vec<Vector6<f64>>> = all.iter().map(|e| e.unobserved.clone()).collect();
    let chain = ChainParams { noise: state.noise, stops: StopPrior::Known, max_iterations: 30, prior_dof: None };
    let estimate = refine_chain_observed(&views, &unobserved, &state.prior, &chain)?;
    let g = Matrix6::from_fn(|a, b| estimate.joint_covariance[(a + 6, b + 6)]);
    Ok(state
        .targets
        .iter()
        .map(|t| {
            let p = predict(&state.base_from_model, &g, t, &state.predict);
            (p.position_bound_m, p.axis_bound_rad)
        })
        .collect())
}

/// How far the worst target is over the tolerance (0: every one meets it): the largest bound over
/// its tolerance.
fn excess(bounds: &Bounds, tolerance: &Tolerance) -> f64 {
    bounds
        .iter()
        .map(|&(p, a)| {
            let over_p = tolerance.position_m.map_or(0.0, |t| p / t);
            let over_a = tolerance.axis_rad.map_or(0.0, |t| a / t);
            over_p.max(over_a)
        })
        .fold(0.0, f64::max)
}

/// Chooses up to `params.max_views` of `candidates` (module docs).
///
/// # Errors
/// [`Error::Invalid`] for bad parameters, no target, or a chain that cannot be solved.
pub fn plan_views(state: &ShotState<'_>, candidates: &[Candidate], params: &PlanViewsParams) -> Result<ViewPlan> {
    params.validate()?;
    if state.targets.is_empty() {
        return Err(Error::invalid("targets", "no target given"));
    }
    if state.model.normals.is_none() {
        return Err(Error::invalid("model", "has no normals: the views' incidence cannot be judged"));
    }
    let obstacles = KdIndex::new(&state.shot_points.points)?;
    // the shot's own views, as registered
    let base: Vec<Evidence> = state
        .shot_flanges
        .iter()
        .map(|f| Evidence { view: chain_view(state, f), unobserved: Vec::new(), visible: 0, joints: None })
        .collect();
    if base.is_empty() {
        return Err(Error::invalid("shot", "no view registered onto the model: nothing to plan from"));
    }
    let before = bounds_with(state, &base, &[])?;
    let mut left_out = Vec::new();
    let mut usable: Vec<(usize, Evidence)> = Vec::new();
    for (i, c) in candidates.iter().enumerate() {
        match evidence(state, &c.base_from_ee, &obstacles, params) {
            Ok(e) => usable.push((i, e)),
            Err(why) => left_out.push((i, why)),
        }
    }
    let mut chosen: Vec<ChosenView> = Vec::new();
    let mut taken: Vec<usize> = Vec::new();
    let mut current = before.clone();
    let mut at = state.arm.map(|a| a.arm.start);
    let mut move_refused: Vec<(usize, String)> = Vec::new();
    let stop = loop {
        let now = excess(&current, &params.tolerance);
        if now <= 1.0 {
            break if chosen.is_empty() {
                "the shot's views already meet the tolerance".to_string()
            } else {
                "the tolerance is met".to_string()
            };
        }
        if chosen.len() >= params.max_views {
            break format!("{} views chosen (--max-views); the tolerance is not met", params.max_views);
        }
        let picked: Vec<&Evidence> = taken.iter().map(|&k| &usable[k].1).collect();
        let mut scored: Vec<(usize, f64, Bounds)> = Vec::new();
        for (k, (_, e)) in usable.iter().enumerate() {
            if taken.contains(&k) {
                continue;
            }
            let mut with = picked.clone();
            with.push(e);
            let b = bounds_with(state, &base, &with)?;
            scored.push((k, excess(&b, &params.tolerance), b));
        }
        // the best first, ties in the candidates' order
        scored.sort_by(|a, b| a.1.total_cmp(&b.1));
        let mut pick = None;
        for (k, x, b) in scored {
            if x > now * (1.0 - params.min_gain) {
                break;
            }
            let reach = match (&state.arm, &usable[k].1.joints, &at) {
                (Some(a), Some(j), Some(from)) => match a.arm.check_move(from, &j.q, a.obstacles) {
                    Ok(move_clearance) => Some(ViewReach { joints: *j, move_clearance }),
                    Err(why) => {
                        let from =
                            if chosen.is_empty() { "the shot".to_string() } else { format!("view {}", chosen.len()) };
                        move_refused.push((usable[k].0, format!("from {from}: {why}")));
                        continue;
                    }
                },
                _ => None,
            };
            pick = Some((k, x, b, reach));
            break;
        }
        match pick {
            Some((k, x, b, reach)) => {
                let (index, e) = &usable[k];
                chosen.push(ChosenView {
                    candidate: *index,
                    visible: e.visible,
                    unobserved: e.unobserved.len(),
                    why: format!(
                        "lowers the worst target's bound from {:.2} to {:.2} times the tolerance ({}: {})",
                        now,
                        x,
                        candidates[*index].why,
                        if e.unobserved.is_empty() {
                            "its registration observes every motion".to_string()
                        } else {
                            format!("{} motions unobserved by its registration", e.unobserved.len())
                        }
                    ),
                    bounds: b.clone(),
                    reach,
                });
                if let Some(r) = reach {
                    at = Some(r.joints.q);
                }
                taken.push(k);
                current = b;
            }
            None => break "no usable candidate lowers the worst target's bound further".to_string(),
        }
    };
    for (i, why) in move_refused {
        if !chosen.iter().any(|c| c.candidate == i) && !left_out.iter().any(|(j, _)| *j == i) {
            left_out.push((i, why));
        }
    }
    left_out.sort_by_key(|(i, _)| *i);
    Ok(ViewPlan {
        met: excess(&current, &params.tolerance) <= 1.0,
        before,
        chosen,
        stop,
        left_out,
        start: state.arm.map(|a| (a.arm.start, a.arm.start_recorded)),
    })
}

/// The shot's depth points, base frame, on a 1 cm grid (the obstacles of [`ShotState`]).
///
/// # Errors
/// Any error loading a view.
pub fn shot_obstacles(shot: &crate::scan::Scan) -> Result<PointCloud> {
    let rays = shot.camera.as_ref().map(|c| c.intrinsics.ray_table());
    let mut merged = PointCloud::default();
    for i in 0..shot.views.len() {
        let view = crate::io::scan::load_view(shot, i, rays.as_deref())?;
        merged.extend(&view.cloud_camera.transformed(&view.world_from_camera));
    }
    crate::filter::voxel::downsample(&merged, &crate::filter::voxel::VoxelParams { voxel_size_m: 0.01 })
}

/// Checks that every view of `shot` was taken from one base pose (the planned views are taken from
/// it too).
///
/// # Errors
/// [`Error::Invalid`] naming the first view whose `T_world_base` differs from the first's.
pub fn check_one_base(shot: &crate::scan::Scan) -> Result<()> {
    let bases: Vec<(usize, Isometry3<f64>)> = (shot.views.iter().enumerate())
        .filter_map(|(i, v)| match v.pose {
            crate::scan::ViewPose::Chain { world_from_base, .. } => Some((i, world_from_base)),
            crate::scan::ViewPose::Camera { .. } => None,
        })
        .collect();
    if let Some(&(first, base)) = bases.first()
        && let Some((i, other)) = bases.iter().find(|(_, b)| {
            let (dt, dr) = crate::transform::pose_difference(b, &base);
            dt > 1e-6 || dr > 1e-6
        })
    {
        let (dt, dr) = crate::transform::pose_difference(other, &base);
        return Err(Error::invalid(
            format!("shot {} views[{i}].T_world_base", shot.dir.display()),
            format!(
                "differs from view {first}'s by {:.1} mm / {:.2} deg: a shot's views are taken from one base pose \
                 (the robot base), and the planned views are taken from it too",
                dt * 1e3,
                dr.to_degrees()
            ),
        ));
    }
    Ok(())
}

/// [`plan_views`] after a pierce of the shot's views (`pierce`, planned with `params`): its located
/// pose, the hand-eye it used and the shot's views that registered, its targets; with `robot`, every
/// view and move checked for it from the shot's recorded joints (views[i].q), else from the
/// configuration of its last view that [`ViewArm::at_shot`] chooses.
///
/// # Errors
/// [`Error::Invalid`] when the shot has no camera or its views were not combined with the hand-eye
/// (no flange poses, or none registered onto the model); any error of [`plan_views`].
#[allow(clippy::too_many_arguments)]
pub fn plan_after_pierce(
    pierce: &crate::pierce::PiercePlan,
    pierce_params: &crate::pierce::PierceParams,
    shot: &crate::scan::Scan,
    model: &PointCloud,
    robot: Option<&ViewRobot>,
    candidates: &[Candidate],
    params: &PlanViewsParams,
) -> Result<ViewPlan> {
    let shot_error = |m: &str| Error::invalid(format!("shot {}", shot.dir.display()), m.to_string());
    let camera = shot.camera.ok_or_else(|| shot_error("has no camera"))?;
    check_one_base(shot)?;
    let Some(h) = &pierce.located.hand_eye else {
        return Err(shot_error(
            "its views were not combined with the hand-eye (no T_base_ee, or none registered onto the model): \
             views cannot be planned from it",
        ));
    };
    let shot_flanges: Vec<Isometry3<f64>> = h
        .views
        .iter()
        .filter_map(|&(i, _, _)| match shot.views.get(i)?.pose {
            crate::scan::ViewPose::Chain { world_from_base, base_from_ee } => Some(world_from_base * base_from_ee),
            crate::scan::ViewPose::Camera { .. } => None,
        })
        .collect();
    let prior = match &pierce_params.hand_eye {
        Some(p) => p.prior,
        None => crate::pierce::HandEyePrior::recorded(h.prior).prior,
    };
    let obstacles = shot_obstacles(shot)?;
    let arm = match robot {
        Some(r) => {
            let mut body = r.body;
            body.ee_from_camera = Some(prior.ee_from_camera);
            let placed =
                view_obstacles(model, r.floor, &pierce.located.base_from_model, &obstacles, r.obstacle_voxel_m)?;
            let last = shot_flanges.last().copied().ok_or_else(|| shot_error("no view registered onto the model"))?;
            let recorded = crate::pierce::reach::shot_joints(shot)?;
            let arm = ViewArm::at_shot(r.arm.clone(), r.ee_from_tool, body, r.collision, recorded, &last, &placed)?;
            Some((arm, placed))
        }
        None => None,
    };
    let state = ShotState {
        base_from_model: pierce.located.base_from_model,
        prior,
        shot_flanges,
        noise: pierce_params.locate.noise,
        camera,
        model,
        shot_points: &obstacles,
        targets: pierce
            .targets
            .iter()
            .map(|t| crate::pierce::target_geometry(&t.surface, &t.axis_base, pierce_params))
            .collect(),
        predict: pierce_params.predict,
        arm: arm.as_ref().map(|(arm, obstacles)| ArmCheck { arm, obstacles }),
    };
    plan_views(&state, candidates, params)
}
