//! Whether the arm can execute a plan: per target, the spin about the piercing axis and the arm
//! configuration whose straight approach -> pierce -> retract path stays within the joint limits,
//! away from the singularities ([`crate::kinematics::best_spin_with`]) and clear of the workpiece's
//! model and floor ([`crate::kinematics::collision`]); the joints at the three poses and the margins.
//!
//! Frames: the plan's poses (`approach`, `pierce`, `retract`) are the tool's (`T_base_tool`, the
//! controller's TCP = `T_ee_tool`); the reach's poses are the flange's (`T_base_flange` =
//! `T_base_tool * Rz(spin) * T_ee_tool^-1`). The spin turns the tool about its own z axis (the
//! piercing axis), so the tool poses the programs use are the plan's turned by it.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::filter::voxel::{VoxelParams, downsample};
use crate::kinematics::collision::{BodyParams, Clearance, CollisionParams, Obstacles};
use crate::kinematics::{
    Arm, Branch, IkParams, Joints, LineParams, Margins, SpinParams, best_spin_with, ik, wrap_to_pi,
};
use crate::pierce::plan::{PiercePlan, PlannedTarget};
use crate::pierce::tool::ToolPoses;
use crate::scan::Scan;
use crate::segment::FloorPlane;

/// Settings of [`plan_reach`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReachParams {
    /// The line checks (step, singularity minimums).
    pub line: LineParams,
    /// The spin search (`fixed_rad`: `--fixed-spin`).
    pub spin: SpinParams,
    /// The capsules' sizes (the camera's `T_ee_camera` is taken from the plan when it has one).
    pub body: BodyParams,
    /// The collision distances.
    pub collision: CollisionParams,
    /// The model is down-sampled to this voxel for the collision checks, metres. Default 0.004.
    pub model_voxel_m: f64,
}

impl Default for ReachParams {
    fn default() -> Self {
        Self {
            line: LineParams::default(),
            spin: SpinParams::default(),
            body: BodyParams::default(),
            collision: CollisionParams::default(),
            model_voxel_m: 0.004,
        }
    }
}

/// The robot a plan's reach was checked for.
#[derive(Debug, Clone, PartialEq)]
pub struct ReachSetup {
    /// The arm's name.
    pub arm: String,
    /// The arm (its DH table and limits: plan.json's `robot.arm_model`).
    pub model: Arm,
    /// `T_ee_tool`: the tool centre point on the flange (the controller's TCP).
    pub ee_from_tool: Isometry3<f64>,
    /// The joint state the configurations were chosen nearest (the shot's last view's `q`), radians.
    pub reference_q: Option<Joints>,
    /// Its configuration, preferred when a path of it passes.
    pub prefer: Option<Branch>,
    /// Model points checked for collisions (after the voxel), and whether a floor was.
    pub model_points: usize,
    /// Whether the floor plane was checked.
    pub floor: bool,
}

/// The three joint vectors of a target's path, radians.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathJoints {
    /// At the approach pose.
    pub approach: Joints,
    /// At the pierce pose.
    pub pierce: Joints,
    /// At the retract pose.
    pub retract: Joints,
}

/// The reach of one target.
#[derive(Debug, Clone, PartialEq)]
pub struct TargetReach {
    /// Whether a configuration passes the whole path clear of the workpiece.
    pub reachable: bool,
    /// Why not (each kind of failure once, with how many candidates failed so); empty when
    /// reachable.
    pub reason: String,
    /// The spin about the tool axis applied to the plan's tool poses, radians.
    pub spin_rad: f64,
    /// The configuration followed.
    pub branch: Option<Branch>,
    /// The joints at approach, pierce and retract.
    pub joints: Option<PathJoints>,
    /// The tool poses turned by the spin (`T_base_tool`: approach, pierce, retract), what the
    /// programs move to.
    pub tool_poses: Option<ToolPoses>,
    /// The flange poses (`T_base_flange`: approach, pierce, retract).
    pub flange_poses: Option<[Isometry3<f64>; 3]>,
    /// The smallest margins along the path.
    pub margins: Option<Margins>,
    /// The smallest clearance along the path (`None`: nothing within the collision reach and no
    /// floor).
    pub clearance: Option<Clearance>,
    /// Candidates (spin x configuration) whose path passed the kinematic checks.
    pub candidates_passed: usize,
}

impl PlannedTarget {
    /// Why the target must be left out of a program for the arm, when its reach was checked and
    /// it is not reachable (`None`: reachable, or not checked). The no-go gate combines this with
    /// its other rules.
    pub fn reach_refusal(&self) -> Option<String> {
        self.reach.as_ref().filter(|r| !r.reachable).map(|r| format!("not reachable: {}", r.reason))
    }
}

/// The arm's joint state at the shot: the `q` of the last view that records one (scan.json's
/// optional per-view `q`, radians).
///
/// # Errors
/// [`Error::Field`] naming `views[i].q` when it is not an array of 6 finite numbers.
pub fn shot_joints(shot: &Scan) -> Result<Option<Joints>> {
    let mut last = None;
    for (i, v) in shot.views.iter().enumerate() {
        let Some(value) = v.extra.get("q") else { continue };
        let field = format!("views[{i}].q");
        let path = shot.dir.join("scan.json");
        let numbers: Vec<f64> =
            value.as_array().map(|a| a.iter().filter_map(serde_json::Value::as_f64).collect()).unwrap_or_default();
        if numbers.len() != 6 || value.as_array().is_none_or(|a| a.len() != 6) {
            return Err(Error::field(&path, &field, "must be an array of 6 joint values in radians"));
        }
        if numbers.iter().any(|v| !v.is_finite()) {
            return Err(Error::field(&path, &field, "joint values must be finite"));
        }
        last = Some([numbers[0], numbers[1], numbers[2], numbers[3], numbers[4], numbers[5]]);
    }
    Ok(last)
}

/// The configuration of the joint state `q`.
///
/// # Errors
/// As [`ik::inverse`].
pub fn branch_of(arm: &Arm, q: &Joints) -> Result<Option<Branch>> {
    let params = IkParams { reference: Some(*q), ..IkParams::no_refusal() };
    let s = ik::inverse(arm, &arm.base_from_flange(q), &params)?;
    Ok(s.solutions.first().map(|s| s.branch))
}

/// The reach of one target (tool poses `tool`, surface point `target`, both base frame).
///
/// # Errors
/// As [`best_spin_with`].
#[allow(clippy::too_many_arguments)]
pub fn reach_target(
    arm: &Arm,
    ee_from_tool: &Isometry3<f64>,
    tool: &ToolPoses,
    target: &Point3<f64>,
    obstacles: Option<&Obstacles>,
    reference_q: Option<Joints>,
    prefer: Option<Branch>,
    params: &ReachParams,
) -> Result<TargetReach> {
    let mut line = params.line;
    line.ik.reference = reference_q.or(line.ik.reference);
    let mut clearance: Option<Clearance> = None;
    let mut accept = |choice: &crate::kinematics::SpinChoice| -> Result<Option<String>> {
        let Some(obstacles) = obstacles else { return Ok(None) };
        let check = obstacles.check_path(arm, &choice.report, ee_from_tool, &params.body, target, &params.collision);
        clearance = check.min;
        Ok(check.collision.map(|c| c.to_string()))
    };
    let search = best_spin_with(arm, tool, ee_from_tool, &line, &params.spin, prefer, &mut accept)?;
    let Some(best) = search.best else {
        return Ok(TargetReach {
            reachable: false,
            reason: search.reason(),
            spin_rad: 0.0,
            branch: None,
            joints: None,
            tool_poses: None,
            flange_poses: None,
            margins: None,
            clearance: None,
            candidates_passed: search.passed,
        });
    };
    let q = best.report.joints_at_poses();
    let joints = (q.len() == 3).then(|| PathJoints { approach: q[0], pierce: q[1], retract: q[2] });
    let rz = Isometry3::from_parts(
        Translation3::identity(),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), best.spin_rad),
    );
    Ok(TargetReach {
        reachable: true,
        reason: String::new(),
        spin_rad: wrap_to_pi(best.spin_rad),
        branch: Some(best.start.branch),
        joints,
        tool_poses: Some(ToolPoses {
            approach: tool.approach * rz,
            pierce: tool.pierce * rz,
            retract: tool.retract * rz,
        }),
        flange_poses: Some(best.flange_poses),
        margins: Some(best.report.min),
        clearance: if obstacles.is_some() { clearance } else { None },
        candidates_passed: search.passed,
    })
}

/// Checks every target of `plan` for `arm` with the tool at `ee_from_tool` (`T_ee_tool`) against
/// the model (`model`, model frame; `floor`, model frame, from workpiece.json), preferring the
/// configuration of `reference_q` (the shot's joint state): fills each target's `reach` and the
/// plan's `reach`. The camera's capsule uses the plan's `T_ee_camera` (the shot's combination)
/// when it has one, else `params.body.ee_from_camera`.
///
/// # Errors
/// [`Error::Invalid`] for bad parameters, a non-finite `T_ee_tool` or reference; as
/// [`reach_target`].
pub fn plan_reach(
    plan: &mut PiercePlan,
    arm: &Arm,
    ee_from_tool: &Isometry3<f64>,
    model: &PointCloud,
    floor: Option<FloorPlane>,
    reference_q: Option<Joints>,
    params: &ReachParams,
) -> Result<()> {
    params.body.validate()?;
    params.collision.validate()?;
    if !(params.model_voxel_m.is_finite() && params.model_voxel_m > 0.0) {
        return Err(Error::invalid(
            "model_voxel_m",
            format!("must be a positive length, got {}", params.model_voxel_m),
        ));
    }
    let t = ee_from_tool.translation.vector;
    if !(t.iter().all(|v| v.is_finite()) && ee_from_tool.rotation.coords.iter().all(|v| v.is_finite())) {
        return Err(Error::invalid("T_ee_tool", "must be finite"));
    }
    let mut params = *params;
    if let Some(h) = &plan.located.hand_eye {
        params.body.ee_from_camera = Some(h.ee_from_camera);
    }
    let prefer = match &reference_q {
        Some(q) => branch_of(arm, q)?,
        None => None,
    };
    let coarse = downsample(model, &VoxelParams { voxel_size_m: params.model_voxel_m })?;
    let obstacles = Obstacles::new(&coarse.points, floor, &plan.located.base_from_model)?;
    for t in &mut plan.targets {
        let r = reach_target(arm, ee_from_tool, &t.poses, &t.p_base, Some(&obstacles), reference_q, prefer, &params)?;
        t.reach = Some(r);
    }
    plan.reach = Some(ReachSetup {
        arm: arm.name.clone(),
        model: arm.clone(),
        ee_from_tool: *ee_from_tool,
        reference_q,
        prefer,
        model_points: obstacles.len(),
        floor: obstacles.floor().is_some(),
    });
    Ok(())
}
