//! The check every robot-facing writer makes before a plan reaches a file (plan.json, URScript,
//! Techman packets): [`check_for_robot`].

use nalgebra::{Isometry3, Point3, Vector3};

use crate::error::{Error, Result};
use crate::pierce::plan::PiercePlan;
use crate::pierce::tool::MAX_REACH_M;

/// How far from the robot base the workpiece model's origin may be placed, metres: the model sits
/// within an arm's reach of the base that pierces it, with room for a large workpiece around it.
pub const MAX_MODEL_DISTANCE_M: f64 = 10.0;

fn finite_pose(pose: &Isometry3<f64>) -> bool {
    pose.translation.vector.iter().all(|v| v.is_finite()) && pose.rotation.coords.iter().all(|v| v.is_finite())
}

/// Refuses a plan with a non-finite or out-of-range value that would reach the robot: the stroke
/// ([`crate::pierce::Stroke::validate`]), `T_base_model` (finite, origin within
/// [`MAX_MODEL_DISTANCE_M`]), and per target `p_base` and `axis_base` (finite, a unit axis) and the
/// approach / pierce / retract poses (finite, unit rotation, within [`MAX_REACH_M`] of the base).
///
/// # Errors
/// [`Error::Invalid`] naming the value (`targets[i] (SPEC).approach`, `T_base_model`, `depth_m`, ...)
/// and the limit; nothing should be written from such a plan.
pub fn check_for_robot(plan: &PiercePlan) -> Result<()> {
    plan.stroke.validate()?;
    let model = &plan.located.base_from_model;
    if !finite_pose(model) {
        return Err(Error::invalid("T_base_model", "not finite: no robot program is written from it"));
    }
    let d = model.translation.vector.norm();
    if d > MAX_MODEL_DISTANCE_M {
        return Err(Error::invalid(
            "T_base_model",
            format!(
                "places the model {d:.3} m from the robot base, beyond {MAX_MODEL_DISTANCE_M} m: check the shot's poses"
            ),
        ));
    }
    for (i, t) in plan.targets.iter().enumerate() {
        let name = |what: &str| format!("targets[{i}] (`{}`).{what}", t.surface.spec);
        let finite_point = |p: &Point3<f64>| p.coords.iter().all(|v| v.is_finite());
        let finite_vector = |v: &Vector3<f64>| v.iter().all(|x| x.is_finite());
        if !finite_point(&t.p_base) {
            return Err(Error::invalid(name("p_base"), "not finite"));
        }
        if !finite_vector(&t.axis_base) || (t.axis_base.norm() - 1.0).abs() > 1e-6 {
            return Err(Error::invalid(name("axis_base"), format!("not a finite unit vector: {:?}", t.axis_base)));
        }
        for (what, pose) in
            [("approach", &t.poses.approach), ("pierce", &t.poses.pierce), ("retract", &t.poses.retract)]
        {
            check_pose(&name(what), pose, MAX_REACH_M, "the robot base", &arm_reach())?;
        }
    }
    Ok(())
}

/// The limit a tool point in the base frame is held to, for [`check_pose`], and what to do.
pub(crate) fn arm_reach() -> String {
    format!("an arm's {MAX_REACH_M} m reach: bring the base closer or check the shot's poses")
}

/// Refuses a tool pose `name` that is not finite, whose rotation is not a unit quaternion, or whose
/// point is farther than `max_m` metres from `from` (the frame's origin), saying it is beyond
/// `limit` (which names `max_m`).
///
/// # Errors
/// [`Error::Invalid`] naming `name`.
pub(crate) fn check_pose(name: &str, pose: &Isometry3<f64>, max_m: f64, from: &str, limit: &str) -> Result<()> {
    if !finite_pose(pose) {
        return Err(Error::invalid(name, "the tool pose is not finite"));
    }
    if (pose.rotation.coords.norm() - 1.0).abs() > 1e-6 {
        return Err(Error::invalid(name, "the tool rotation is not a unit quaternion"));
    }
    let v = pose.translation.vector;
    if v.norm() > max_m {
        return Err(Error::invalid(
            name,
            format!(
                "the tool point ({:.3}, {:.3}, {:.3}) m is {:.3} m from {from}, beyond {limit}",
                v.x,
                v.y,
                v.z,
                v.norm()
            ),
        ));
    }
    Ok(())
}
