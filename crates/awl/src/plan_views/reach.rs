//! Whether the arm can take a view: per candidate flange pose, its joints (inverse kinematics within
//! the limits and away from the singularities, the configuration of the arm's joints at the shot
//! preferred, the whole-turn aliases nearest them) with the tool end's capsules (tool, flange,
//! camera, wrist: [`crate::kinematics::collision`]) clear of the located model, its floor and the
//! shot's own depth points; and the joint-space moves between the views in visiting order, checked
//! along the way ([`Obstacles::check_joint_move`]).

use nalgebra::Isometry3;

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::filter::voxel::{VoxelParams, downsample};
use crate::kinematics::collision::{BodyParams, Clearance, CollisionParams, Obstacles, capsules};
use crate::kinematics::{Arm, Branch, IkParams, Joints, ik};
use crate::pierce::reach::branch_of;
use crate::segment::FloorPlane;

/// The robot `awl plan-views --robot` checks the views for.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewRobot {
    /// The arm (DH table, joint limits).
    pub arm: Arm,
    /// `T_ee_tool`: the piercing tool on the flange.
    pub ee_from_tool: Isometry3<f64>,
    /// The capsules' sizes (the camera's `T_ee_camera` is the hand-eye the views are planned with).
    pub body: BodyParams,
    /// The collision distances.
    pub collision: CollisionParams,
    /// The workpiece's floor, model frame (workpiece.json).
    pub floor: Option<FloorPlane>,
    /// The model and the shot's depth are down-sampled to this voxel as obstacles, metres. Default 0.005.
    pub obstacle_voxel_m: f64,
}

impl ViewRobot {
    /// `arm` with the tool at `ee_from_tool`, the default sizes and distances, no floor.
    pub fn new(arm: Arm, ee_from_tool: Isometry3<f64>) -> Self {
        Self {
            arm,
            ee_from_tool,
            body: BodyParams::default(),
            collision: CollisionParams::default(),
            floor: None,
            obstacle_voxel_m: 0.005,
        }
    }
}

/// The arm the views are checked for, at the shot.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewArm {
    /// The arm (DH table, joint limits).
    pub arm: Arm,
    /// `T_ee_tool`: the piercing tool on the flange (its capsule is checked too).
    pub ee_from_tool: Isometry3<f64>,
    /// The capsules' sizes; `ee_from_camera` is the hand-eye the views are planned with.
    pub body: BodyParams,
    /// The collision distances (no model point is left out: a view has no target zone).
    pub collision: CollisionParams,
    /// The singularity minimums of the inverse kinematics.
    pub ik: IkParams,
    /// The arm's joints at the shot (radians): where the first move starts.
    pub start: Joints,
    /// Whether `start` is the shot's recorded `q` (else the configuration awl chose for its last view).
    pub start_recorded: bool,
    /// The configuration of `start`, tried first at every view.
    pub prefer: Option<Branch>,
}

/// A view's joints and what they were checked for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewJoints {
    /// The joints, radians (`FK(q)` is the view's `T_base_ee`).
    pub q: Joints,
    /// Their configuration.
    pub branch: Branch,
    /// The smallest distance of a joint to its limit, radians.
    pub limit_margin_rad: f64,
    /// The tool end's smallest clearance at the view (`None`: nothing within the collision reach).
    pub clearance: Option<Clearance>,
}

/// The obstacles of the views: the model (model frame, placed by `base_from_model`) and its floor,
/// and the shot's depth points (base frame), on a `voxel_m` grid.
///
/// # Errors
/// [`Error::Invalid`] for a non-positive voxel or a non-finite point.
pub fn view_obstacles(
    model: &PointCloud,
    floor: Option<FloorPlane>,
    base_from_model: &Isometry3<f64>,
    shot_points: &PointCloud,
    voxel_m: f64,
) -> Result<Obstacles> {
    let model_from_base = base_from_model.inverse();
    let mut points = model.points.clone();
    points.extend(shot_points.points.iter().map(|p| (model_from_base * p.cast::<f64>()).cast::<f32>()));
    let all = PointCloud::from_points(points);
    let coarse = downsample(&all, &VoxelParams { voxel_size_m: voxel_m })?;
    Obstacles::new(&coarse.points, floor, base_from_model)
}

impl ViewArm {
    /// The arm set up at a shot: `start` the shot's recorded joints, or (`None`) the configuration of
    /// its last flange pose `last_flange` whose tool end is clear and whose singularity measures are
    /// largest.
    ///
    /// # Errors
    /// [`Error::Invalid`] for bad sizes or distances, a non-finite recorded joint, or a last view the
    /// arm cannot be at (no configuration reaches it clear of the obstacles).
    pub fn at_shot(
        arm: Arm,
        ee_from_tool: Isometry3<f64>,
        body: BodyParams,
        collision: CollisionParams,
        recorded: Option<Joints>,
        last_flange: &Isometry3<f64>,
        obstacles: &Obstacles,
    ) -> Result<Self> {
        body.validate()?;
        collision.validate()?;
        let mut out = Self {
            arm,
            ee_from_tool,
            body,
            collision,
            ik: IkParams::default(),
            start: [0.0; 6],
            start_recorded: recorded.is_some(),
            prefer: None,
        };
        out.start = match recorded {
            Some(q) => {
                if q.iter().any(|v| !v.is_finite()) {
                    return Err(Error::invalid("the shot's q", "joint values must be finite"));
                }
                q
            }
            None => {
                let s = ik::inverse(&out.arm, last_flange, &out.ik)?;
                let clear = s.solutions.iter().filter(|sol| out.collision_at(&sol.q, obstacles).is_ok());
                let best = clear.max_by(|a, b| {
                    let m = |s: &ik::IkSolution| s.measures.wrist.min(s.measures.elbow);
                    m(a).total_cmp(&m(b))
                });
                let Some(best) = best else {
                    return Err(Error::invalid(
                        "the shot's last view",
                        format!(
                            "the {} cannot be at its flange pose clear of the workpiece ({}): check --robot and the shot",
                            out.arm.name,
                            if s.solutions.is_empty() { s.reason() } else { "every configuration collides".into() }
                        ),
                    ));
                };
                best.q
            }
        };
        out.prefer = branch_of(&out.arm, &out.start)?;
        Ok(out)
    }

    /// The tool end's clearance at `q`, or the collision.
    fn collision_at(&self, q: &Joints, obstacles: &Obstacles) -> std::result::Result<Option<Clearance>, String> {
        let c = obstacles.clearance(&capsules(&self.arm, q, &self.ee_from_tool, &self.body), None, &self.collision);
        match c {
            Some(c) if c.distance_m < self.collision.min_clearance_m => Err(format!(
                "the {} would be {:.1} mm from the {}",
                c.link.name(),
                c.distance_m * 1e3,
                c.against.name()
            )),
            c => Ok(c),
        }
    }

    /// The joints of the flange pose `base_from_ee`: the configuration at the shot first, then the
    /// others nearest the shot's joints; the first whose tool end is clear. Or why none.
    pub fn joints_of(
        &self,
        base_from_ee: &Isometry3<f64>,
        obstacles: &Obstacles,
    ) -> std::result::Result<ViewJoints, String> {
        let params = IkParams { reference: Some(self.start), ..self.ik };
        let s = ik::inverse(&self.arm, base_from_ee, &params).map_err(|e| e.to_string())?;
        if s.solutions.is_empty() {
            return Err(format!("the {} cannot reach it: {}", self.arm.name, s.reason()));
        }
        let mut order: Vec<&ik::IkSolution> = s.solutions.iter().filter(|x| Some(x.branch) == self.prefer).collect();
        order.extend(s.solutions.iter().filter(|x| Some(x.branch) != self.prefer));
        let mut first_why = None;
        for sol in order {
            match self.collision_at(&sol.q, obstacles) {
                Ok(clearance) => {
                    return Ok(ViewJoints {
                        q: sol.q,
                        branch: sol.branch,
                        limit_margin_rad: sol.limit_margin_rad,
                        clearance,
                    });
                }
                Err(why) => {
                    first_why.get_or_insert(why);
                }
            }
        }
        Err(format!("every configuration collides: {}", first_why.unwrap_or_default()))
    }

    /// The joint move from `from` to `to`: its smallest clearance, or where it collides.
    pub fn check_move(
        &self,
        from: &Joints,
        to: &Joints,
        obstacles: &Obstacles,
    ) -> std::result::Result<Option<Clearance>, String> {
        let c = obstacles.check_joint_move(&self.arm, from, to, &self.ee_from_tool, &self.body, &self.collision);
        match c.collision {
            Some(hit) => Err(format!(
                "the joint move to it would bring the {} {:.1} mm from the {} ({:.0} % of the way)",
                hit.clearance.link.name(),
                hit.clearance.distance_m * 1e3,
                hit.clearance.against.name(),
                hit.s * 1e2
            )),
            None => Ok(c.min),
        }
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Point3, Vector3};

    use super::*;

    #[test]
    fn the_obstacles_take_a_fused_model_s_points_whatever_it_carries() {
        // a model with normals and colors (what awl fuse writes), 1 cm apart; the shot's points 0.5 m up
        let points: Vec<Point3<f32>> = (0..100).map(|i| Point3::new(i as f32 * 0.01, 0.0, 0.0)).collect();
        let mut model = PointCloud::from_points(points.clone());
        model.normals = Some(vec![Vector3::z(); 100]);
        model.colors = Some(vec![[200, 10, 10]; 100]);
        let shot = PointCloud::from_points(points.iter().map(|p| p + Vector3::new(0.0, 0.0, 0.5)).collect());
        let base_from_model = Isometry3::translation(0.3, 0.0, 0.1);
        let o = view_obstacles(&model, None, &base_from_model, &shot, 0.005).expect("obstacles");
        assert_eq!(o.len(), 200);
        assert!(view_obstacles(&model, None, &base_from_model, &shot, 0.0).is_err(), "a zero voxel is refused");
    }
}
