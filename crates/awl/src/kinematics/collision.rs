//! Collision checks of the arm's tool end along a path: the tool (a cylinder of a given radius and
//! length along the tool axis), the flange, the camera body and the three wrist links, each
//! approximated by a capsule (a segment and a radius) placed by forward kinematics
//! ([`Arm::link_frames`]), against the workpiece's model (points, base frame) and the floor plane.
//! Distances are parry3d's capsule-point distances (`parry3d_f64::shape::Capsule`); the floor is a
//! half space (the capsule's lowest end point above it, less the radius).
//!
//! The model's points within [`CollisionParams::exclude_radius_m`] of the target are left out (the
//! tool touches the surface there by design). Pure: no I/O.

use nalgebra::{Isometry3, Point3};
use parry3d_f64::math::Vector as PVector;
use parry3d_f64::query::PointQuery;
use parry3d_f64::shape::Capsule;

use super::line::LineReport;
use super::{Arm, Joints};
use crate::error::{Error, Result};
use crate::segment::FloorPlane;
use crate::spatial::KdIndex;

/// A part of the arm's tool end that collision checks place a capsule on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Link {
    /// The piercing tool: from the tool centre point back along the tool's z axis.
    Tool,
    /// The flange disc.
    Flange,
    /// The eye-in-hand camera's body (needs `T_ee_camera`).
    Camera,
    /// Wrist 1: DH frame 3 to frame 4 (joint 4's housing).
    Wrist1,
    /// Wrist 2: DH frame 4 to frame 5.
    Wrist2,
    /// Wrist 3: DH frame 5 to frame 6 (up to the flange).
    Wrist3,
    /// The upper arm: DH frame 1 to frame 2 (shoulder to elbow, on the DH table's line; the real
    /// link's side offset is within its radius for UR and Techman arms only roughly).
    UpperArm,
    /// The forearm: DH frame 2 to frame 3 (elbow to wrist 1).
    Forearm,
}

impl Link {
    /// The name in messages and plan.json.
    pub fn name(self) -> &'static str {
        match self {
            Link::Tool => "tool",
            Link::Flange => "flange",
            Link::Camera => "camera",
            Link::Wrist1 => "wrist 1",
            Link::Wrist2 => "wrist 2",
            Link::Wrist3 => "wrist 3",
            Link::UpperArm => "upper arm",
            Link::Forearm => "forearm",
        }
    }
}

/// The sizes of the capsules, metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyParams {
    /// The tool's radius. Default 0.004.
    pub tool_radius_m: f64,
    /// The tool's length from its tip back along its z axis; `None`: the distance from the flange's
    /// origin to the tool centre point (a straight tool on the flange). Default `None`.
    pub tool_length_m: Option<f64>,
    /// The flange disc's radius. Default 0.032 (UR e-Series: 63 mm across).
    pub flange_radius_m: f64,
    /// The flange disc's thickness behind the flange face. Default 0.01.
    pub flange_thickness_m: f64,
    /// `T_ee_camera` (ee = flange): where the camera body is; `None`: no camera checked.
    pub ee_from_camera: Option<Isometry3<f64>>,
    /// Half the camera body's width along the camera's x axis. Default 0.045 (a 90 mm RGB-D camera).
    pub camera_half_width_m: f64,
    /// The camera body's radius. Default 0.0125.
    pub camera_radius_m: f64,
    /// How far the body's axis sits behind the optical centre, along -z. Default 0.0125.
    pub camera_behind_m: f64,
    /// The wrist links' radius. Default 0.045.
    pub wrist_radius_m: f64,
    /// The upper arm's and the forearm's radius. Default 0.06 (a UR10e's tubes are 90-120 mm
    /// across).
    pub arm_radius_m: f64,
}

impl Default for BodyParams {
    fn default() -> Self {
        Self {
            tool_radius_m: 0.004,
            tool_length_m: None,
            flange_radius_m: 0.032,
            flange_thickness_m: 0.01,
            ee_from_camera: None,
            camera_half_width_m: 0.045,
            camera_radius_m: 0.0125,
            camera_behind_m: 0.0125,
            wrist_radius_m: 0.045,
            arm_radius_m: 0.06,
        }
    }
}

/// The largest tool radius [`BodyParams::validate`] accepts, metres: 0.1 (a 200 mm wide tool is no
/// piercing tool; larger values are typing errors, and every model point within the radius is
/// looked at for every checked point of every path).
pub const MAX_TOOL_RADIUS_M: f64 = 0.1;

/// The largest tool length [`BodyParams::validate`] accepts, and the largest flange-to-TCP distance
/// (`T_ee_tool`) the reach check takes, metres: 1.0 (the tool alone as long as a small arm's reach).
pub const MAX_TOOL_LENGTH_M: f64 = 1.0;

impl BodyParams {
    /// Checks the sizes.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the field for a negative or non-finite size, a `tool_radius_m`
    /// above [`MAX_TOOL_RADIUS_M`] (0.1 m) or a `tool_length_m` above [`MAX_TOOL_LENGTH_M`] (1 m).
    pub fn validate(&self) -> Result<()> {
        let sizes = [
            ("tool_radius_m", self.tool_radius_m),
            ("tool_length_m", self.tool_length_m.unwrap_or(0.0)),
            ("flange_radius_m", self.flange_radius_m),
            ("flange_thickness_m", self.flange_thickness_m),
            ("camera_half_width_m", self.camera_half_width_m),
            ("camera_radius_m", self.camera_radius_m),
            ("camera_behind_m", self.camera_behind_m),
            ("wrist_radius_m", self.wrist_radius_m),
            ("arm_radius_m", self.arm_radius_m),
        ];
        for (name, v) in sizes {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::invalid(name, format!("must be a non-negative length in metres, got {v}")));
            }
        }
        for (name, v, max) in [
            ("tool_radius_m", self.tool_radius_m, MAX_TOOL_RADIUS_M),
            ("tool_length_m", self.tool_length_m.unwrap_or(0.0), MAX_TOOL_LENGTH_M),
        ] {
            if v > max {
                return Err(Error::invalid(
                    name,
                    format!("{v} m is larger than a piercing tool can be (at most {max} m): metres expected"),
                ));
            }
        }
        Ok(())
    }
}

/// One capsule in the base frame: the segment `a`-`b` swept by a ball of `radius_m`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinkCapsule {
    /// Which part.
    pub link: Link,
    /// One end, base frame, metres.
    pub a: Point3<f64>,
    /// The other end.
    pub b: Point3<f64>,
    /// Radius, metres.
    pub radius_m: f64,
}

/// The capsules of the tool end at joints `q`, base frame. The tool ends `radius` short of its tip
/// so that the capsule's tip is the tool's.
pub fn capsules(arm: &Arm, q: &Joints, ee_from_tool: &Isometry3<f64>, body: &BodyParams) -> Vec<LinkCapsule> {
    let frames = arm.link_frames(q);
    let flange = frames[7];
    let tool = flange * ee_from_tool;
    let tool_length = body.tool_length_m.unwrap_or_else(|| ee_from_tool.translation.vector.norm());
    let tip_back = body.tool_radius_m.min(tool_length);
    let mut out = vec![
        LinkCapsule {
            link: Link::Tool,
            a: tool * Point3::new(0.0, 0.0, -tip_back),
            b: tool * Point3::new(0.0, 0.0, -tool_length),
            radius_m: body.tool_radius_m,
        },
        LinkCapsule {
            link: Link::Flange,
            a: flange * Point3::origin(),
            b: flange * Point3::new(0.0, 0.0, -body.flange_thickness_m),
            radius_m: body.flange_radius_m,
        },
    ];
    if let Some(x) = &body.ee_from_camera {
        let camera = flange * x;
        let (w, z) = (body.camera_half_width_m, -body.camera_behind_m);
        out.push(LinkCapsule {
            link: Link::Camera,
            a: camera * Point3::new(-w, 0.0, z),
            b: camera * Point3::new(w, 0.0, z),
            radius_m: body.camera_radius_m,
        });
    }
    for (link, i, radius_m) in [
        (Link::Wrist1, 3, body.wrist_radius_m),
        (Link::Wrist2, 4, body.wrist_radius_m),
        (Link::Wrist3, 5, body.wrist_radius_m),
        (Link::UpperArm, 1, body.arm_radius_m),
        (Link::Forearm, 2, body.arm_radius_m),
    ] {
        out.push(LinkCapsule { link, a: frames[i] * Point3::origin(), b: frames[i + 1] * Point3::origin(), radius_m });
    }
    out
}

/// The capsules of [`capsules`] that stay where they are when the tool turns about its own z axis
/// (the piercing axis), in the tool frame: the tool's, and the flange's when its axis is the tool's
/// (a straight tool on the flange, within 1e-9 m). Placed at a tool pose they are where every spin
/// and configuration puts them.
pub fn spin_invariant_capsules(ee_from_tool: &Isometry3<f64>, body: &BodyParams) -> Vec<LinkCapsule> {
    let tool_length = body.tool_length_m.unwrap_or_else(|| ee_from_tool.translation.vector.norm());
    let tip_back = body.tool_radius_m.min(tool_length);
    let mut out = vec![LinkCapsule {
        link: Link::Tool,
        a: Point3::new(0.0, 0.0, -tip_back),
        b: Point3::new(0.0, 0.0, -tool_length),
        radius_m: body.tool_radius_m,
    }];
    let tool_from_ee = ee_from_tool.inverse();
    let (a, b) = (tool_from_ee * Point3::origin(), tool_from_ee * Point3::new(0.0, 0.0, -body.flange_thickness_m));
    if [a, b].iter().all(|p| p.x.hypot(p.y) < 1e-9) {
        out.push(LinkCapsule { link: Link::Flange, a, b, radius_m: body.flange_radius_m });
    }
    out
}

/// What a capsule was closest to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Against {
    /// The workpiece's model (its points outside the target's zone).
    Model,
    /// The floor plane.
    Floor,
}

impl Against {
    /// The name in messages and plan.json.
    pub fn name(self) -> &'static str {
        match self {
            Against::Model => "model",
            Against::Floor => "floor",
        }
    }
}

/// The smallest distance found, and between what.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Clearance {
    /// Distance from the capsule's surface, metres (0 when a model point is inside it; negative when
    /// the capsule is below the floor).
    pub distance_m: f64,
    /// The arm's part.
    pub link: Link,
    /// What it is near.
    pub against: Against,
}

impl Clearance {
    fn keep_smaller(best: &mut Option<Clearance>, c: Clearance) {
        if best.is_none_or(|b| c.distance_m < b.distance_m) {
            *best = Some(c);
        }
    }
}

/// Settings of the collision check.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CollisionParams {
    /// Model points within this of the target are left out, metres. Default 0.025.
    pub exclude_radius_m: f64,
    /// A capsule nearer than this to the model or the floor is a collision, metres. Default 0.003
    /// (the model's noise and the capsules' approximation).
    pub min_clearance_m: f64,
    /// Model points farther than this from a capsule are not looked at: a clearance beyond it is
    /// reported as none found, metres. Default 0.05.
    pub reach_m: f64,
}

impl Default for CollisionParams {
    fn default() -> Self {
        Self { exclude_radius_m: 0.025, min_clearance_m: 0.003, reach_m: 0.05 }
    }
}

impl CollisionParams {
    /// Checks the distances.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the field for a negative or non-finite distance (or a zero reach).
    pub fn validate(&self) -> Result<()> {
        for (name, v) in [("exclude_radius_m", self.exclude_radius_m), ("min_clearance_m", self.min_clearance_m)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::invalid(name, format!("must be a non-negative length in metres, got {v}")));
            }
        }
        if !(self.reach_m.is_finite() && self.reach_m > self.min_clearance_m) {
            return Err(Error::invalid(
                "reach_m",
                format!("must be finite and above min_clearance_m {} m, got {}", self.min_clearance_m, self.reach_m),
            ));
        }
        Ok(())
    }
}

/// The workpiece as an obstacle: its model's points and the floor, base frame.
pub struct Obstacles {
    points: Vec<Point3<f32>>,
    index: KdIndex,
    floor: Option<FloorPlane>,
}

impl Obstacles {
    /// The obstacles from the model's points and the floor plane, both in the model frame, placed
    /// by `base_from_model`.
    ///
    /// # Errors
    /// [`Error::Invalid`] for a non-finite point (from the index).
    pub fn new(
        model_points: &[Point3<f32>],
        floor: Option<FloorPlane>,
        base_from_model: &Isometry3<f64>,
    ) -> Result<Self> {
        let points: Vec<Point3<f32>> =
            model_points.iter().map(|p| (base_from_model * p.cast::<f64>()).cast::<f32>()).collect();
        let index = KdIndex::new(&points)?;
        // n_m . p_m + d = 0 with p_m = R^T (p_b - t): (R n_m) . p_b + d - (R n_m) . t = 0
        let floor = floor.and_then(|f| {
            let n = base_from_model.rotation * f.normal;
            FloorPlane::new(n, f.offset_m - n.dot(&base_from_model.translation.vector))
        });
        Ok(Self { points, index, floor })
    }

    /// The number of model points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether there is no model point.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The floor in the base frame, if any.
    pub fn floor(&self) -> Option<&FloorPlane> {
        self.floor.as_ref()
    }

    /// The smallest clearance of `capsules` to the model's points (those farther than
    /// `params.exclude_radius_m` from `target`, when there is one, within `params.reach_m` of a
    /// capsule) and to the floor (always). `None` when nothing is within the reach and there is no
    /// floor.
    pub fn clearance(
        &self,
        capsules: &[LinkCapsule],
        target: Option<&Point3<f64>>,
        params: &CollisionParams,
    ) -> Option<Clearance> {
        let mut best: Option<Clearance> = None;
        let exclude_sq = params.exclude_radius_m * params.exclude_radius_m;
        let excluded = |p: &Point3<f64>| target.is_some_and(|t| (p - t).norm_squared() <= exclude_sq);
        for c in capsules {
            if let Some(floor) = &self.floor {
                let d = floor.height(&c.a).min(floor.height(&c.b)) - c.radius_m;
                Clearance::keep_smaller(&mut best, Clearance { distance_m: d, link: c.link, against: Against::Floor });
            }
            let shape = Capsule::new(PVector::new(c.a.x, c.a.y, c.a.z), PVector::new(c.b.x, c.b.y, c.b.z), c.radius_m);
            // looked at piece by piece, 0.1 m each (an arm link is 0.6 m long): around each piece's
            // centre only the points nearer than its nearest point plus half the piece can be nearer
            // to the piece than that point (none at all beyond the reach)
            let length = (c.b - c.a).norm();
            let pieces = (length / 0.1).ceil().clamp(1.0, 64.0) as usize;
            let half_piece = length / (2.0 * pieces as f64);
            let search = half_piece + c.radius_m + params.reach_m;
            let mut smallest = f64::INFINITY;
            for k in 0..pieces {
                let mid = (c.a + (c.b - c.a) * ((k as f64 + 0.5) / pieces as f64)).cast::<f32>();
                let Some(nearest) = self.index.nearest_within(&mid, search as f32) else { continue };
                let p = self.points[nearest.index as usize].cast::<f64>();
                let radius = if excluded(&p) {
                    search
                } else {
                    // (1e-4 m above: the f32 distance's rounding)
                    (f64::from(nearest.dist_sq).sqrt() + half_piece + 1e-4).min(search)
                };
                for n in self.index.within(&mid, radius as f32) {
                    let p = self.points[n.index as usize].cast::<f64>();
                    if excluded(&p) {
                        continue;
                    }
                    smallest = smallest.min(shape.distance_to_local_point(PVector::new(p.x, p.y, p.z), true));
                }
            }
            if smallest <= params.reach_m {
                Clearance::keep_smaller(
                    &mut best,
                    Clearance { distance_m: smallest, link: c.link, against: Against::Model },
                );
            }
        }
        best
    }

    /// Checks every point of a passed path (`report` of [`super::check_path`]) with the tool on
    /// the flange at `ee_from_tool`: the smallest clearance along it and the first collision.
    pub fn check_path(
        &self,
        arm: &Arm,
        report: &LineReport,
        ee_from_tool: &Isometry3<f64>,
        body: &BodyParams,
        target: &Point3<f64>,
        params: &CollisionParams,
    ) -> PathClearance {
        self.check_samples(arm, report, ee_from_tool, body, target, params, false)
    }

    /// [`Self::check_path`] stopped at the first collision: the same `collision`, and `min` the
    /// smallest clearance over the points checked up to it (over the whole path when it is clear).
    pub fn first_collision(
        &self,
        arm: &Arm,
        report: &LineReport,
        ee_from_tool: &Isometry3<f64>,
        body: &BodyParams,
        target: &Point3<f64>,
        params: &CollisionParams,
    ) -> PathClearance {
        self.check_samples(arm, report, ee_from_tool, body, target, params, true)
    }

    /// A joint-space move (URScript `movej`, Techman `PTP`: every joint from `from` to `to` together,
    /// the straight line in joint space) checked so that the whole swept motion is bounded, not only
    /// its samples: no point of a capsule moves faster than [`joint_levers_m`] allow (metres per
    /// radian of each joint), so from a sample whose clearance is `c` the move advances until a point
    /// may have come `c - min_clearance_m` nearer (at least [`SWEEP_MARGIN_M`]). Conservative
    /// advancement: between the samples the capsules stay at least `min_clearance_m -`
    /// [`SWEEP_MARGIN_M`] from the model's points and the floor; a sample nearer than
    /// `min_clearance_m` is the collision (segment 0, `s` from 0 to 1). No model point is left out.
    pub fn check_joint_move(
        &self,
        arm: &Arm,
        from: &Joints,
        to: &Joints,
        ee_from_tool: &Isometry3<f64>,
        body: &BodyParams,
        params: &CollisionParams,
    ) -> PathClearance {
        let levers = joint_levers_m(arm, &capsules(arm, from, ee_from_tool, body), &arm.base_from_flange(from));
        // metres a capsule point may move per unit of s
        let speed: f64 = (0..6).map(|k| (to[k] - from[k]).abs() * levers[k]).sum();
        let mut out = PathClearance { min: None, collision: None, samples_checked: 0 };
        let mut s = 0.0f64;
        loop {
            let q: Joints = std::array::from_fn(|k| from[k] + (to[k] - from[k]) * s);
            out.samples_checked += 1;
            let c = self.clearance(&capsules(arm, &q, ee_from_tool, body), None, params);
            if let Some(c) = c {
                Clearance::keep_smaller(&mut out.min, c);
                if c.distance_m < params.min_clearance_m {
                    out.collision = Some(Collision { segment: 0, s, clearance: c });
                    break;
                }
            }
            if s >= 1.0 {
                break;
            }
            // nothing within the reach and no floor: the clearance is at least the reach
            let room = c.map_or(params.reach_m, |c| c.distance_m.min(params.reach_m)) - params.min_clearance_m;
            let ds = if speed > 0.0 { room.max(SWEEP_MARGIN_M) / speed } else { 1.0 };
            s = (s + ds).min(1.0);
        }
        out
    }

    #[allow(clippy::too_many_arguments)]
    fn check_samples(
        &self,
        arm: &Arm,
        report: &LineReport,
        ee_from_tool: &Isometry3<f64>,
        body: &BodyParams,
        target: &Point3<f64>,
        params: &CollisionParams,
        stop: bool,
    ) -> PathClearance {
        let mut out = PathClearance { min: None, collision: None, samples_checked: 0 };
        for sample in &report.samples {
            out.samples_checked += 1;
            let Some(c) = self.clearance(&capsules(arm, &sample.q, ee_from_tool, body), Some(target), params) else {
                continue;
            };
            Clearance::keep_smaller(&mut out.min, c);
            if c.distance_m < params.min_clearance_m && out.collision.is_none() {
                out.collision = Some(Collision { segment: sample.segment, s: sample.s, clearance: c });
                if stop {
                    break;
                }
            }
        }
        out
    }
}

/// How much nearer than [`CollisionParams::min_clearance_m`] a capsule may come between two samples
/// of a joint move ([`Obstacles::check_joint_move`]), metres: 0.5 mm (so a 3 mm minimum holds 2.5 mm
/// along the whole swept motion).
pub const SWEEP_MARGIN_M: f64 = 0.0005;

/// For each joint, a length no capsule point is farther from that joint's axis, whatever the
/// joints, metres: a point moves at most this far per radian of the joint. Joint `k`'s axis passes
/// through DH frame `k - 1`'s origin; the chain from there to the flange is at most the rows'
/// `sqrt(a^2 + d^2)` from row `k` on plus `T_dh6_flange`'s offset, and a capsule point fixed to
/// the flange (tool, flange, camera: `capsules` at `base_from_flange`) at most its distance from
/// the flange beyond that. The wrists' capsule ends are the chain's own origins.
pub fn joint_levers_m(arm: &Arm, capsules: &[LinkCapsule], base_from_flange: &Isometry3<f64>) -> [f64; 6] {
    let flange_from_base = base_from_flange.inverse();
    let beyond_flange = capsules
        .iter()
        .filter(|c| matches!(c.link, Link::Tool | Link::Flange | Link::Camera))
        .flat_map(|c| [c.a, c.b])
        .map(|p| (flange_from_base * p).coords.norm())
        .fold(0.0, f64::max);
    let flange = arm.dh6_from_flange.translation.vector.norm();
    std::array::from_fn(|k| arm.dh[k..].iter().map(|j| j.a.hypot(j.d)).sum::<f64>() + flange + beyond_flange)
}

/// Where a path first came too near.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Collision {
    /// The segment of the path (0 = its first pose to its second; approach -> pierce for a target).
    pub segment: usize,
    /// Position along it, 0 to 1.
    pub s: f64,
    /// The clearance there.
    pub clearance: Clearance,
}

impl std::fmt::Display for Collision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let c = &self.clearance;
        write!(
            f,
            "collision: the {} is {:.1} mm from the {} at {:.0} % of segment {}",
            c.link.name(),
            c.distance_m * 1e3,
            c.against.name(),
            self.s * 1e2,
            self.segment
        )
    }
}

/// The collision check of one path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathClearance {
    /// The smallest clearance over the path (`None`: nothing within the reach, no floor).
    pub min: Option<Clearance>,
    /// The first point nearer than the minimum clearance, if any.
    pub collision: Option<Collision>,
    /// The path's points checked (all of them, or up to the first collision).
    pub samples_checked: usize,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tool_sizes_beyond_a_piercing_tool_are_refused_by_name() {
        let ok = BodyParams { tool_radius_m: 0.1, tool_length_m: Some(1.0), ..BodyParams::default() };
        ok.validate().expect("0.1 m radius, 1 m length: the largest accepted");
        for (body, name) in [
            (BodyParams { tool_radius_m: 0.1001, ..BodyParams::default() }, "tool_radius_m"),
            (BodyParams { tool_radius_m: 1e9, ..BodyParams::default() }, "tool_radius_m"),
            (BodyParams { tool_length_m: Some(1.001), ..BodyParams::default() }, "tool_length_m"),
            (BodyParams { tool_length_m: Some(f64::INFINITY), ..BodyParams::default() }, "tool_length_m"),
        ] {
            let e = body.validate().expect_err("refused").to_string();
            assert!(e.starts_with(name) && e.contains("m"), "{e}");
        }
    }

    #[test]
    fn the_tool_and_a_straight_tool_s_flange_are_spin_invariant() {
        let body = BodyParams::default();
        let straight = spin_invariant_capsules(&Isometry3::translation(0.0, 0.0, 0.15), &body);
        assert_eq!(straight.iter().map(|c| c.link).collect::<Vec<_>>(), [Link::Tool, Link::Flange]);
        // the flange's face 150 mm behind the tip, its back 10 mm farther
        assert!((straight[1].a - Point3::new(0.0, 0.0, -0.15)).norm() < 1e-15);
        assert!((straight[1].b - Point3::new(0.0, 0.0, -0.16)).norm() < 1e-15);
        let offset = spin_invariant_capsules(&Isometry3::translation(0.03, 0.0, 0.15), &body);
        assert_eq!(offset.iter().map(|c| c.link).collect::<Vec<_>>(), [Link::Tool]);
    }

    #[test]
    fn a_joint_move_through_a_wall_is_refused_where_it_hits_and_one_clear_of_it_passes() {
        let arm = Arm::by_name("ur5e").expect("ur5e");
        let tool = Isometry3::translation(0.0, 0.0, 0.15);
        let body = BodyParams::default();
        let params = CollisionParams::default();
        let from: Joints = [0.0, -1.2, 1.4, -1.8, -1.57, 0.0];
        let mut to = from;
        to[0] = 1.2;
        // a wall of points in the plane the tool end sweeps through halfway (joint 1 at 0.6 rad)
        let mid = {
            let mut q = from;
            q[0] = 0.6;
            arm.base_from_flange(&q) * tool * Point3::origin()
        };
        let normal = nalgebra::Vector3::new(-(0.6f64).sin(), (0.6f64).cos(), 0.0);
        let along = normal.cross(&nalgebra::Vector3::z());
        let mut wall = Vec::new();
        for i in -20..=20 {
            for k in -20..=20 {
                let p = mid + along * (f64::from(i) * 0.005) + nalgebra::Vector3::z() * (f64::from(k) * 0.005);
                wall.push(p.cast::<f32>());
            }
        }
        let obstacles = Obstacles::new(&wall, None, &Isometry3::identity()).expect("obstacles");
        let hit = obstacles.check_joint_move(&arm, &from, &to, &tool, &body, &params);
        let c = hit.collision.expect("the move crosses the wall");
        assert!(c.s > 0.3 && c.s < 0.55, "hits at {}", c.s);
        // the same move stopped just short of the wall: the longest clear one in steps of 0.01 rad
        let mut short = from;
        let mut clear = None;
        for i in 30..60 {
            let mut q = from;
            q[0] = 0.01 * f64::from(i);
            let c = obstacles.check_joint_move(&arm, &from, &q, &tool, &body, &params);
            if c.collision.is_some() {
                break;
            }
            (short, clear) = (q, Some(c));
        }
        let clear = clear.expect("a move short of the wall is clear");
        let nearest = clear.min.expect("the wall is within the reach").distance_m;
        assert!(nearest < 0.02, "the move ends near the wall: {nearest} m");
        // the swept motion, brute force: 20 000 samples of it keep 2.5 mm (3 mm less the sweep margin)
        let mut closest = f64::INFINITY;
        let levers = joint_levers_m(&arm, &capsules(&arm, &from, &tool, &body), &arm.base_from_flange(&from));
        for i in 0..=20_000 {
            let mut q = from;
            q[0] = short[0] * f64::from(i) / 20_000.0;
            let c = obstacles.clearance(&capsules(&arm, &q, &tool, &body), None, &params);
            assert!(c.is_none_or(|c| c.distance_m >= params.min_clearance_m - SWEEP_MARGIN_M), "{i}: {c:?}");
            closest = closest.min(c.map_or(f64::INFINITY, |c| c.distance_m));
            // and the levers bound the motion: no capsule end moves farther than lever x angle
            if i > 0 {
                let mut p = q;
                p[0] -= short[0] / 20_000.0;
                for (a, b) in capsules(&arm, &p, &tool, &body).iter().zip(capsules(&arm, &q, &tool, &body)) {
                    let moved = (a.a - b.a).norm().max((a.b - b.b).norm());
                    assert!(moved <= levers[0] * short[0] / 20_000.0 * (1.0 + 1e-9), "{moved}");
                }
            }
        }
        assert!(closest >= params.min_clearance_m - SWEEP_MARGIN_M && closest <= nearest + 1e-12, "{closest}");
        println!("{:.2} rad of joint 1: {} samples, clearance {nearest:.4} m", short[0], clear.samples_checked);
    }
}
