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
use crate::kinematics::collision::{
    BodyParams, Clearance, Collision, CollisionParams, Link, MAX_TOOL_LENGTH_M, Obstacles, spin_invariant_capsules,
};
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
    /// The joint move the program makes to this target's approach, checked for collisions
    /// (`None`: not checked: a target left out, or the first one when the shot records no joints).
    pub transfer: Option<Transfer>,
    /// The work the search took.
    pub work: ReachWork,
}

/// A program's joint move to a target's approach joints (URScript `movej`, Techman `PTP`), checked
/// along its whole swept motion ([`Obstacles::check_joint_move`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transfer {
    /// Where it starts: `None` the shot's recorded joints, `Some(i)` target `i`'s retract joints.
    pub from_target: Option<usize>,
    /// The joints it starts from, radians.
    pub from_q: Joints,
    /// The largest joint motion along it, radians.
    pub largest_joint_rad: f64,
    /// The smallest clearance along it (`None`: nothing within the collision reach, no floor).
    pub clearance: Option<Clearance>,
    /// Configurations along it checked.
    pub samples: usize,
}

/// The work of one target's reach search, in counts (what the cheap-first order saves).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ReachWork {
    /// Poses solved by inverse kinematics (the three stroke poses of each spin tried, fewer when
    /// one has no solution; none when the reach bound refused the target).
    pub ik_poses: usize,
    /// Candidates (spin x configuration) whose path was stepped every `line.step_m`.
    pub paths_checked: usize,
    /// Candidates whose path was checked for collisions point by point.
    pub collision_paths: usize,
    /// Path points whose capsules were checked for collisions (the spin-invariant check's included).
    pub collision_points: usize,
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
/// The checks run cheapest first and the search stops when its answer is certain: a tool point
/// beyond [`Arm::reach_bound_m`] (plus the flange-to-TCP distance) from the shoulder refuses the
/// target with no inverse kinematics; then per spin the three stroke poses' inverse kinematics,
/// per configuration its solutions there, the paths every `line.step_m`
/// ([`best_spin_with`]); collisions last: each candidate in order of preference, stopped at its
/// first collision. A collision of a capsule on the tool axis (the tool's, the flange's for a
/// straight tool: [`spin_invariant_capsules`], where every spin and configuration puts them)
/// refuses every other candidate whose path is stepped alike without its own check. A reachable
/// target's choice, joints, margins and clearance are those of checking everything.
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
    reach_target_from(arm, ee_from_tool, tool, target, obstacles, reference_q, prefer, None, params)
}

/// [`reach_target`] for a program that comes to this target from joints `from` (`from_target`:
/// `None` the shot's, `Some(i)` target `i`'s retract): a candidate passes only when the joint move
/// from there to its approach joints is clear along its whole swept motion as well
/// ([`Obstacles::check_joint_move`]); the reach's `transfer` says how clear. A candidate whose move
/// collides is passed over for the next (another spin or configuration): the move is re-routed
/// through the arm's other solutions, or the target refused naming it.
///
/// # Errors
/// As [`reach_target`].
#[allow(clippy::too_many_arguments)]
pub fn reach_target_from(
    arm: &Arm,
    ee_from_tool: &Isometry3<f64>,
    tool: &ToolPoses,
    target: &Point3<f64>,
    obstacles: Option<&Obstacles>,
    reference_q: Option<Joints>,
    prefer: Option<Branch>,
    from: Option<(Option<usize>, Joints)>,
    params: &ReachParams,
) -> Result<TargetReach> {
    let mut work = ReachWork::default();
    let mut transfer: Option<Transfer> = None;
    if let Some(reason) = beyond_reach_bound(arm, ee_from_tool, tool) {
        return Ok(unreachable(reason, 0, work));
    }
    let mut line = params.line;
    line.ik.reference = reference_q.or(line.ik.reference);
    let mut clearance: Option<Clearance> = None;
    // a collision of a capsule on the tool axis (spin_invariant_capsules) is where every spin and
    // configuration puts it, at the same points of paths stepped alike (paths of different spins
    // may differ by a step where a segment is a whole number of steps long): those refused at once
    let invariant: Vec<Link> =
        if tool.approach.rotation == tool.pierce.rotation && tool.approach.rotation == tool.retract.rotation {
            spin_invariant_capsules(ee_from_tool, &params.body).iter().map(|c| c.link).collect()
        } else {
            Vec::new()
        };
    let mut on_axis: Vec<([usize; 2], Collision)> = Vec::new();
    let whatever = |c: &Collision| format!("{c}, whatever the spin and configuration");
    let mut accept = |choice: &crate::kinematics::SpinChoice| -> Result<Option<String>> {
        let Some(obstacles) = obstacles else { return Ok(None) };
        let steps = segment_steps(&choice.report);
        if let Some((_, c)) = on_axis.iter().find(|(s, _)| *s == steps) {
            return Ok(Some(whatever(c)));
        }
        work.collision_paths += 1;
        let check =
            obstacles.first_collision(arm, &choice.report, ee_from_tool, &params.body, target, &params.collision);
        work.collision_points += check.samples_checked;
        clearance = check.min;
        let Some(c) = check.collision else {
            let Some((from_target, from_q)) = from else { return Ok(None) };
            let Some(to) = choice.report.joints_at_poses().first().copied() else { return Ok(None) };
            let m = obstacles.check_joint_move(arm, &from_q, &to, ee_from_tool, &params.body, &params.collision);
            work.collision_points += m.samples_checked;
            if let Some(hit) = m.collision {
                let whence = from_target.map_or("the shot's joints".to_string(), |i| format!("target {i}'s retract"));
                return Ok(Some(format!(
                    "the joint move from {whence} to the approach brings the {} {:.1} mm from the {} ({:.0} % of the way)",
                    hit.clearance.link.name(),
                    hit.clearance.distance_m * 1e3,
                    hit.clearance.against.name(),
                    hit.s * 1e2
                )));
            }
            let largest_joint_rad = (0..6).map(|k| (to[k] - from_q[k]).abs()).fold(0.0, f64::max);
            transfer =
                Some(Transfer { from_target, from_q, largest_joint_rad, clearance: m.min, samples: m.samples_checked });
            return Ok(None);
        };
        // 1e-9 m inside the minimum: beyond the rounding of the other paths' forward kinematics
        if invariant.contains(&c.clearance.link) && c.clearance.distance_m < params.collision.min_clearance_m - 1e-9 {
            on_axis.push((steps, c));
            return Ok(Some(whatever(&c)));
        }
        Ok(Some(c.to_string()))
    };
    // coming from known joints, the candidates that move least from them first
    let spin = SpinParams { least_motion: from.is_some(), ..params.spin };
    let search = best_spin_with(arm, tool, ee_from_tool, &line, &spin, prefer, &mut accept)?;
    work.ik_poses = search.ik_poses;
    work.paths_checked = search.paths_checked;
    let Some(best) = search.best else {
        return Ok(unreachable(search.reason(), search.passed, work));
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
        transfer,
        work,
    })
}

fn unreachable(reason: String, candidates_passed: usize, work: ReachWork) -> TargetReach {
    TargetReach {
        reachable: false,
        reason,
        spin_rad: 0.0,
        branch: None,
        joints: None,
        tool_poses: None,
        flange_poses: None,
        margins: None,
        clearance: None,
        candidates_passed,
        transfer: None,
        work,
    }
}

/// Why no spin and configuration can reach a tool pose: one of the three tool points farther from
/// the shoulder than [`Arm::reach_bound_m`] plus the flange-to-TCP distance (1e-9 m slack).
fn beyond_reach_bound(arm: &Arm, ee_from_tool: &Isometry3<f64>, tool: &ToolPoses) -> Option<String> {
    let bound = arm.reach_bound_m() + ee_from_tool.translation.vector.norm();
    let shoulder = arm.shoulder();
    for (name, pose) in [("approach", &tool.approach), ("pierce", &tool.pierce), ("retract", &tool.retract)] {
        let d = (Point3::from(pose.translation.vector) - shoulder).norm();
        if !(d <= bound + 1e-9) {
            return Some(format!(
                "out of reach: the {name} pose's tool point is {d:.3} m from the arm's shoulder, beyond the {bound:.3} m \
                 no configuration and spin reaches with this tool"
            ));
        }
    }
    None
}

/// A passed path's steps per segment (its points after the start).
fn segment_steps(report: &crate::kinematics::LineReport) -> [usize; 2] {
    let mut steps = [0; 2];
    for p in report.samples.iter().skip(1) {
        if let Some(n) = steps.get_mut(p.segment) {
            *n += 1;
        }
    }
    steps
}

/// Checks every target of `plan` for `arm` with the tool at `ee_from_tool` (`T_ee_tool`) against
/// the model (`model`, model frame; `floor`, model frame, from workpiece.json), preferring the
/// configuration of `reference_q` (the shot's joint state): fills each target's `reach` and the
/// plan's `reach`. The camera's capsule uses the plan's `T_ee_camera` (the shot's combination)
/// when it has one, else `params.body.ee_from_camera`.
///
/// # Errors
/// [`Error::Invalid`] for bad parameters, a non-finite `T_ee_tool` or one whose TCP is more than
/// [`MAX_TOOL_LENGTH_M`] (1 m) from the flange, a non-finite reference; as [`reach_target`].
pub fn plan_reach(
    plan: &mut PiercePlan,
    arm: &Arm,
    ee_from_tool: &Isometry3<f64>,
    model: &PointCloud,
    floor: Option<FloorPlane>,
    reference_q: Option<Joints>,
    params: &ReachParams,
) -> Result<()> {
    plan_reach_with(plan, arm, ee_from_tool, model, floor, reference_q, params, &|_, _| {})
}

/// [`plan_reach`], calling `progress(done, total)` (targets, the first call with `done` 0) after
/// each target's reach is known: what a progress display follows.
///
/// # Errors
/// As [`plan_reach`].
#[allow(clippy::too_many_arguments)]
pub fn plan_reach_with(
    plan: &mut PiercePlan,
    arm: &Arm,
    ee_from_tool: &Isometry3<f64>,
    model: &PointCloud,
    floor: Option<FloorPlane>,
    reference_q: Option<Joints>,
    params: &ReachParams,
    progress: &dyn Fn(usize, usize),
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
    if t.norm() > MAX_TOOL_LENGTH_M {
        return Err(Error::invalid(
            "T_ee_tool",
            format!(
                "puts the tool centre point {:.3} m from the flange, more than a piercing tool's {MAX_TOOL_LENGTH_M} m",
                t.norm()
            ),
        ));
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
    let total = plan.targets.len();
    progress(0, total);
    // where the arm is when the program moves to the next target: the shot's joints, then each
    // target's retract; its configuration preferred and its joints the nearest (a consistent
    // configuration), the move from it checked
    let mut at: Option<(Option<usize>, Joints)> = reference_q.map(|q| (None, q));
    for (i, t) in plan.targets.iter_mut().enumerate() {
        let (reference, prefer) = match at {
            Some((Some(_), q)) => (Some(q), branch_of(arm, &q)?.or(prefer)),
            _ => (reference_q, prefer),
        };
        // a target left out for its bounds gets no move: the program goes past it
        let from = if t.refusal.is_none() { at } else { None };
        let r = reach_target_from(
            arm,
            ee_from_tool,
            &t.poses,
            &t.p_base,
            Some(&obstacles),
            reference,
            prefer,
            from,
            &params,
        )?;
        if t.refusal.is_none()
            && let Some(j) = r.joints.filter(|_| r.reachable)
        {
            at = Some((Some(i), j.retract));
        }
        t.reach = Some(r);
        progress(i + 1, total);
    }
    if reference_q.is_none() && plan.targets.iter().any(|t| t.go()) {
        plan.warnings.push(
            "the program's first joint move starts wherever the arm is: the shot records no joints (views[i].q), so \
             that move is not checked for collisions (the moves between targets are); record the arm's joints in the \
             shot, or bring the arm near the first approach before running the program"
                .to_string(),
        );
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinematics::{SpinChoice, check_path};
    use crate::pierce::{Stroke, tool_poses};

    /// A square plate of points, `half` metres half-width every `step`, at height `z` about (`cx`, `cy`).
    fn plate(cx: f64, cy: f64, z: f64, half: f64, step: f64) -> Vec<Point3<f32>> {
        let n = (half / step).round() as i32;
        let mut out = Vec::new();
        for i in -n..=n {
            for j in -n..=n {
                out.push(Point3::new((cx + f64::from(i) * step) as f32, (cy + f64::from(j) * step) as f32, z as f32));
            }
        }
        out
    }

    /// UR5e, a 150 mm straight tool, the default stroke pointing down at `p`.
    fn setup(p: [f64; 3]) -> (Arm, Isometry3<f64>, Point3<f64>, ToolPoses, ReachParams) {
        let arm = Arm::by_name("ur5e").expect("ur5e");
        let ee_from_tool = Isometry3::translation(0.0, 0.0, 0.15);
        let target = Point3::from(Vector3::from(p));
        let poses = tool_poses(&target, &-Vector3::z(), &Stroke::default()).expect("poses");
        let mut params = ReachParams::default();
        params.body.ee_from_camera = Some(Isometry3::translation(0.0, 0.07, 0.03));
        (arm, ee_from_tool, target, poses, params)
    }

    #[test]
    fn out_of_reach_targets_are_refused_with_their_reason_before_any_path() {
        // 3 m out: beyond the UR5e's bound (1.150 m + the 0.15 m tool) with no inverse kinematics
        let (arm, ee_from_tool, target, poses, params) = setup([3.0, 0.0, 0.1]);
        assert!((arm.reach_bound_m() - 1.1498).abs() < 1e-9, "{}", arm.reach_bound_m());
        let obstacles = Obstacles::new(&plate(3.0, 0.0, 0.1, 0.1, 0.004), None, &Isometry3::identity()).expect("obst");
        let r = reach_target(&arm, &ee_from_tool, &poses, &target, Some(&obstacles), None, None, &params).expect("r");
        assert!(!r.reachable);
        assert!(
            r.reason.starts_with("out of reach: the approach pose's tool point is 3.000 m from the arm's shoulder")
                && r.reason.contains("beyond the 1.300 m"),
            "{}",
            r.reason
        );
        assert_eq!(r.work, ReachWork::default(), "no IK, no path, no collision");

        // 1.0 m out, 0.2 m up: inside the bound, beyond the arm (0.817 m from joint 2 to joint 4
        // at most): every spin's approach has no solution: 36 poses solved, no path stepped
        let (arm, ee_from_tool, target, poses, params) = setup([1.0, 0.0, 0.2]);
        let obstacles = Obstacles::new(&plate(1.0, 0.0, 0.2, 0.1, 0.004), None, &Isometry3::identity()).expect("obst");
        let r = reach_target(&arm, &ee_from_tool, &poses, &target, Some(&obstacles), None, None, &params).expect("r");
        println!("1 m out: {} ({:?})", r.reason, r.work);
        assert!(!r.reachable);
        assert!(r.reason.starts_with("36 x out of reach: the wrist needs"), "{}", r.reason);
        assert_eq!(r.work, ReachWork { ik_poses: 36, paths_checked: 0, collision_paths: 0, collision_points: 0 });
        assert_eq!(r.candidates_passed, 0);
    }

    #[test]
    fn a_tool_through_the_model_is_refused_once_for_every_candidate() {
        // an overhang 50 mm above the target: the straight approach passes through it
        let (arm, ee_from_tool, target, poses, params) = setup([0.45, 0.15, 0.10]);
        let mut points = plate(0.45, 0.15, 0.10, 0.15, 0.004);
        points.extend(plate(0.45, 0.15, 0.15, 0.10, 0.004));
        let obstacles = Obstacles::new(&points, None, &Isometry3::identity()).expect("obstacles");
        let r = reach_target(&arm, &ee_from_tool, &poses, &target, Some(&obstacles), None, None, &params).expect("r");
        println!("overhang: {} ({:?}, {} passed)", r.reason, r.work, r.candidates_passed);
        assert!(!r.reachable);
        // the kinematics pass (36 spins x 8 configurations here), the tool collides at the overhang
        assert_eq!(r.candidates_passed, 288);
        assert!(
            r.reason.starts_with("288 x collision: the tool is") && r.reason.contains("whatever the spin"),
            "{}",
            r.reason
        );
        // one candidate's path checked up to the overhang (the approach starts 100 mm above the
        // target, the overhang 50 mm above: 2 mm steps) for each of the (at most two) steppings of
        // the 110 mm approach -> pierce segment; the others refused by its tool collision
        assert!(r.work.collision_paths <= 2, "{:?}", r.work);
        assert!(r.work.collision_points <= 2 * 30, "{:?}", r.work);
        assert_eq!(r.work.ik_poses, 3 * 36);
        assert_eq!(r.work.paths_checked, 288);
    }

    /// The search before the cheap-first order: every spin's approach solved, every path stepped,
    /// every candidate's whole path checked for collisions in order of preference.
    fn check_everything(
        arm: &Arm,
        ee_from_tool: &Isometry3<f64>,
        tool: &ToolPoses,
        target: &Point3<f64>,
        obstacles: &Obstacles,
        params: &ReachParams,
    ) -> (Option<SpinChoice>, Option<Clearance>, usize) {
        let mut passed = Vec::new();
        for k in 0..params.spin.count {
            let step = 2.0 * std::f64::consts::PI / params.spin.count as f64;
            let s = if k == 0 { 0.0 } else { step * k.div_ceil(2) as f64 * if k % 2 == 1 { 1.0 } else { -1.0 } };
            let rz = Isometry3::rotation(Vector3::z() * s);
            let flange = [tool.approach, tool.pierce, tool.retract].map(|t| t * rz * ee_from_tool.inverse());
            for start in ik::inverse(arm, &flange[0], &params.line.ik).expect("ik").solutions {
                let report = check_path(arm, &flange, &start, &params.line).expect("path");
                if report.ok() {
                    let score = report.min.score(&params.spin.scale);
                    passed.push(SpinChoice { spin_rad: s, flange_poses: flange, start, report, score });
                }
            }
        }
        let n = passed.len();
        passed.sort_by(|a, b| b.score.total_cmp(&a.score));
        for c in passed {
            let check = obstacles.check_path(arm, &c.report, ee_from_tool, &params.body, target, &params.collision);
            if check.collision.is_none() {
                return (Some(c), check.min, n);
            }
        }
        (None, None, n)
    }

    #[test]
    fn reachable_targets_get_the_choice_of_checking_everything() {
        // a plate with a 120 mm wall 60 mm beside the target: the camera and wrist hit it at some
        // spins, so the choice runs down the preference order
        let (arm, ee_from_tool, target, poses, params) = setup([0.45, 0.15, 0.10]);
        let mut points = plate(0.45, 0.15, 0.10, 0.15, 0.004);
        for i in 0..=75 {
            for k in 0..=30 {
                let (y, z) = (0.15 - 0.15 + f64::from(i) * 0.004, 0.10 + f64::from(k) * 0.004);
                points.push(Point3::new(0.51_f32, y as f32, z as f32));
            }
        }
        let obstacles = Obstacles::new(&points, None, &Isometry3::identity()).expect("obstacles");
        let r = reach_target(&arm, &ee_from_tool, &poses, &target, Some(&obstacles), None, None, &params).expect("r");
        let (best, clearance, passed) = check_everything(&arm, &ee_from_tool, &poses, &target, &obstacles, &params);
        let best = best.expect("reachable");
        println!("wall: spin {:.0} deg {:?}, {:?}", r.spin_rad.to_degrees(), r.branch, r.work);
        assert!(r.reachable, "{}", r.reason);
        assert!(r.work.collision_paths > 1, "some candidates collide first: {:?}", r.work);
        assert_eq!(r.spin_rad, wrap_to_pi(best.spin_rad));
        assert_eq!(r.branch, Some(best.start.branch));
        let j = r.joints.expect("joints");
        let q = best.report.joints_at_poses();
        assert_eq!([j.approach, j.pierce, j.retract].to_vec(), q);
        assert_eq!(r.margins, Some(best.report.min));
        assert_eq!(r.clearance, clearance);
        assert_eq!(r.candidates_passed, passed);
    }
}
