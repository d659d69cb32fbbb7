//! `plan.json` (`awl-plan/1`): what `awl pierce` writes for the robot.
//!
//! ```json
//! { "format": "awl-plan/1", "workpiece": "...", "shot": "...", "hand_eye": "scan.json" | "FILE",
//!   "axis": "normal" | "tag", "approach_m": 0.1, "depth_m": 0.01, "retract_m": 0.1,
//!   "T_base_model": [[4x4]], "T_base_model_tag": [[4x4]], "T_base_tag": [[4x4]], "T_world_tag": [[4x4]],
//!   "refinement": { "applied": true, "points": 9000, "fitness": 0.97, "rmse_m": 0.0011,
//!                   "correction_m": 0.002, "correction_deg": 0.4, "note": "", "T_base_model": [[4x4]] } | null,
//!   "hand_eye_estimate": { "T_ee_camera": [[4x4]] (used), "T_ee_camera_prior": [[4x4]], "prior": "...",
//!                          "sigma_deg": [3], "sigma_mm": [3], "T_base_model_sigma_deg": [3], "T_base_model_sigma_mm": [3],
//!                          "T_base_model_covariance": [[6x6]] (rad², m²; base-frame (ω, v) of T_base_model_true =
//!                          exp(-(ω, v)) * T_base_model), "views": [ { "view", "fitness", "rmse_m" } ],
//!                          "residual_scale": 1.0 } | null,
//!   "T_base_model_covariance": [[6x6]] (as hand_eye_estimate's; entries null when unbounded),
//!   "covariance_source": "...", "confidence": 0.95, "tolerance_mm": 2.0 | null, "tolerance_deg": 1.0 | null,
//!   "detections": [ { "view": 0, "id": 0, "rmse_px": 0.2, "used": true, "reason": "", "T_base_tag": [[4x4]] | null } ],
//!   "targets": [ { "target": "face-centre@0.2,0.1,0.3", "p_model": [x,y,z], "normal_model": [..],
//!                  "p_base": [..], "normal_base": [..], "axis_base": [..] (unit, into the surface),
//!                  "angle_normal_tag_deg": 0.8, "fit_rms_m": 0.0003, "fit_points": 812, "normal_sigma_deg": 0.1,
//!                  "corners_model": [[x,y,z] x4] | null,
//!                  "approach": POSE, "pierce": POSE, "retract": POSE,
//!                  "predicted_error_mm": 1.4 (95 % bound on the point's error; null: unbounded),
//!                  "predicted_axis_error_deg": 0.5 (95 % bound on the tool axis' error),
//!                  "go": true, "why": null | "the predicted position error 3.1 mm exceeds the tolerance 2.0 mm",
//!                  "reach": REACH | null } ],
//!   "pose_frame": "tool", "robot": ROBOT | null,
//!   "programs": { "urscript": "def awl_pierce(): ...", "techman": "$TMSCT,..." },
//!   "warnings": [] }
//! ```
//! `POSE` = `{ "T": [[4x4]], "xyz": [x,y,z], "quaternion_xyzw": [x,y,z,w], "ur_axis_angle": [x,y,z,rx,ry,rz] }`,
//! base frame, metres. The targets' `approach` / `pierce` / `retract` are tool poses (`T_base_tool`,
//! `pose_frame`). `awl send` checks every pose, joint and program line against the rest of the plan
//! before it sends ([`crate::pierce::verify`]).
//!
//! With `--robot` ([`crate::pierce::reach`]):
//! `ROBOT` = `{ "arm": "ur5e", "T_ee_tool": [[4x4]], "arm_model": ARM (the awl-arm/1 file of the arm:
//!   what `awl send` checks the joints by), "q_reference_rad": [6] | null,
//!   "preferred_configuration": CONF | null, "model_points": 41000, "floor_checked": true }`;
//! `REACH` = `{ "reachable": true, "reason": null | "...", "spin_deg": 10.0, "configuration": CONF | null,
//!   "q_rad": { "approach": [6], "pierce": [6], "retract": [6] } | null,
//!   "tool": { "approach": POSE, "pierce": POSE, "retract": POSE } | null (T_base_tool turned by the spin:
//!   the programs' poses), "flange": { ... } | null (T_base_flange),
//!   "margins": { "limit_deg", "wrist_sin", "elbow_sin", "shoulder_m" } | null,
//!   "clearance": { "m": 0.021, "link": "tool", "against": "model" } | null, "candidates_passed": 100,
//!   "transfer": { "from": "shot" | "target 0", "from_q_rad": [6], "largest_joint_deg": 40.0,
//!   "clearance": { ... } | null, "samples": 120 } | null }` (the program's joint move to the approach,
//!   checked along its swept motion; null: not checked, see the plan's warnings);
//! `CONF` = `{ "shoulder": 1, "elbow": -1, "wrist": 1 }`.

use std::path::Path;

use nalgebra::{Isometry3, Point3, Vector3};
use serde_json::{Value, json};

use crate::error::Result;
use crate::io::write_atomic;
use crate::kinematics::arm_file::arm_json;
use crate::pierce::reach::{ReachSetup, TargetReach};
use crate::pierce::{PiercePlan, check_for_robot, quaternion_xyzw, ur_pose};
use crate::transform::rows_from_isometry;

/// The format tag of plan.json.
pub const PLAN_FORMAT: &str = "awl-plan/1";

/// Where a plan's inputs came from (recorded in plan.json).
#[derive(Debug, Clone, Copy)]
pub struct PlanSources<'a> {
    /// The workpiece.json read.
    pub workpiece: &'a Path,
    /// The shot folder.
    pub shot: &'a Path,
    /// Where `T_ee_camera` came from.
    pub hand_eye: &'a str,
}

fn xyz(p: &Point3<f64>) -> [f64; 3] {
    [p.x, p.y, p.z]
}

fn vec3(v: &Vector3<f64>) -> [f64; 3] {
    [v.x, v.y, v.z]
}

/// A number, or null when it is not finite (JSON has no infinity).
fn finite(v: f64) -> Value {
    if v.is_finite() { json!(v) } else { Value::Null }
}

fn pose(t: &Isometry3<f64>) -> Value {
    json!({
        "T": rows_from_isometry(t),
        "xyz": vec3(&t.translation.vector),
        "quaternion_xyzw": quaternion_xyzw(&t.rotation),
        "ur_axis_angle": ur_pose(t),
    })
}

/// The plan as JSON (module docs).
pub fn plan_json(plan: &PiercePlan, sources: &PlanSources<'_>) -> Value {
    let l = &plan.located;
    let refinement = l.refinement.as_ref().map(|r| {
        json!({
            "applied": r.applied, "points": r.points, "fitness": r.fitness,
            "rmse_m": if r.rmse_m.is_finite() { json!(r.rmse_m) } else { Value::Null },
            "correction_m": r.correction_m, "correction_deg": r.correction_rad.to_degrees(),
            "note": r.note, "T_base_model": rows_from_isometry(&r.base_from_model),
        })
    });
    let hand_eye = l.hand_eye.as_ref().map(|h| {
        let sd = |c: &nalgebra::Matrix6<f64>, k: usize, unit: f64| c[(k, k)].max(0.0).sqrt() * unit;
        let (cx, cg) = (&h.ee_from_camera_covariance, &h.base_from_model_covariance);
        json!({
            "T_ee_camera": rows_from_isometry(&h.ee_from_camera),
            "T_ee_camera_prior": rows_from_isometry(&h.prior), "prior": h.prior_source,
            "sigma_deg": (0..3).map(|k| sd(cx, k, 180.0 / std::f64::consts::PI)).collect::<Vec<_>>(),
            "sigma_mm": (3..6).map(|k| sd(cx, k, 1e3)).collect::<Vec<_>>(),
            "T_base_model_sigma_deg": (0..3).map(|k| sd(cg, k, 180.0 / std::f64::consts::PI)).collect::<Vec<_>>(),
            "T_base_model_sigma_mm": (3..6).map(|k| sd(cg, k, 1e3)).collect::<Vec<_>>(),
            "T_base_model_covariance": (0..6).map(|a| (0..6).map(|b| cg[(a, b)]).collect::<Vec<_>>()).collect::<Vec<_>>(),
            "views": h.views.iter().map(|(i, f, r)| json!({"view": i, "fitness": f, "rmse_m": r})).collect::<Vec<_>>(),
            "residual_scale": h.residual_scale,
        })
    });
    let detections: Vec<Value> = l
        .detections
        .iter()
        .map(|d| {
            json!({
                "view": d.view, "id": d.id, "corners_px": d.corners_px,
                "rmse_px": if d.rmse_px.is_finite() { json!(d.rmse_px) } else { Value::Null },
                "flipped_by_depth": d.flipped_by_depth, "used": d.used, "reason": d.reason,
                "T_base_tag": d.world_from_tag.as_ref().map(rows_from_isometry),
            })
        })
        .collect();
    let targets: Vec<Value> = plan
        .targets
        .iter()
        .map(|t| {
            let s = &t.surface;
            json!({
                "target": s.spec.to_string(),
                "p_model": xyz(&s.point), "normal_model": vec3(&s.normal),
                "p_base": xyz(&t.p_base), "normal_base": vec3(&t.normal_base), "axis_base": vec3(&t.axis_base),
                "angle_normal_tag_deg": s.angle_to_tag_z_rad.map(f64::to_degrees),
                "fit_rms_m": s.fit_rms_m, "fit_points": s.points,
                "normal_sigma_deg": finite((s.normal_covariance.trace() / 2.0).sqrt().to_degrees()),
                "corners_model": s.corners.map(|c| c.map(|p| xyz(&p))),
                "approach": pose(&t.poses.approach), "pierce": pose(&t.poses.pierce), "retract": pose(&t.poses.retract),
                "predicted_error_mm": finite(t.prediction.position_bound_m * 1e3),
                "predicted_axis_error_deg": finite(t.prediction.axis_bound_rad.to_degrees()),
                "go": t.go(), "why": t.no_go_reason(),
                "reach": t.reach.as_ref().map(reach_json),
            })
        })
        .collect();
    json!({
        "format": PLAN_FORMAT,
        "workpiece": sources.workpiece.display().to_string(),
        "shot": sources.shot.display().to_string(),
        "hand_eye": sources.hand_eye,
        "axis": plan.axis.name(),
        "approach_m": plan.stroke.approach_m, "depth_m": plan.stroke.depth_m, "retract_m": plan.stroke.retract_m,
        "T_base_model": rows_from_isometry(&l.base_from_model),
        "T_base_model_tag": rows_from_isometry(&l.base_from_model_tag),
        "T_base_tag": rows_from_isometry(&l.base_from_tag),
        "T_world_tag": rows_from_isometry(&plan.world_from_tag),
        "views_checked": l.views_checked,
        "T_base_model_covariance": (0..6).map(|a| (0..6).map(|b| finite(l.base_from_model_covariance[(a, b)])).collect::<Vec<_>>()).collect::<Vec<_>>(),
        "covariance_source": l.covariance_source,
        "confidence": plan.confidence,
        "tolerance_mm": plan.tolerance.position_m.map(|t| t * 1e3),
        "tolerance_deg": plan.tolerance.axis_rad.map(f64::to_degrees),
        "refinement": refinement,
        "hand_eye_estimate": hand_eye,
        "detections": detections,
        "targets": targets,
        "pose_frame": "tool",
        "robot": plan.reach.as_ref().map(robot_json),
        "warnings": plan.warnings,
    })
}

fn configuration(b: &crate::kinematics::Branch) -> Value {
    json!({ "shoulder": b.shoulder, "elbow": b.elbow, "wrist": b.wrist })
}

fn three(poses: [&Isometry3<f64>; 3]) -> Value {
    json!({ "approach": pose(poses[0]), "pierce": pose(poses[1]), "retract": pose(poses[2]) })
}

/// A target's `reach` block (module docs).
pub fn reach_json(r: &TargetReach) -> Value {
    json!({
        "reachable": r.reachable,
        "reason": if r.reachable { Value::Null } else { json!(r.reason) },
        "spin_deg": r.spin_rad.to_degrees(),
        "configuration": r.branch.as_ref().map(configuration),
        "q_rad": r.joints.map(|j| json!({ "approach": j.approach, "pierce": j.pierce, "retract": j.retract })),
        "tool": r.tool_poses.as_ref().map(|p| three([&p.approach, &p.pierce, &p.retract])),
        "flange": r.flange_poses.as_ref().map(|p| three([&p[0], &p[1], &p[2]])),
        "margins": r.margins.map(|m| json!({
            "limit_deg": m.limit_rad.to_degrees(), "wrist_sin": m.wrist, "elbow_sin": m.elbow, "shoulder_m": m.shoulder_m,
        })),
        "clearance": r.clearance.map(|c| json!({ "m": c.distance_m, "link": c.link.name(), "against": c.against.name() })),
        "candidates_passed": r.candidates_passed,
        "transfer": r.transfer.map(|m| json!({
            "from": m.from_target.map_or("shot".to_string(), |i| format!("target {i}")),
            "from_q_rad": m.from_q,
            "largest_joint_deg": m.largest_joint_rad.to_degrees(),
            "clearance": m.clearance.map(|c| json!({ "m": c.distance_m, "link": c.link.name(), "against": c.against.name() })),
            "samples": m.samples,
        })),
    })
}

/// The plan's `robot` block (module docs).
pub fn robot_json(r: &ReachSetup) -> Value {
    json!({
        "arm": r.arm,
        "T_ee_tool": rows_from_isometry(&r.ee_from_tool),
        "q_reference_rad": r.reference_q,
        "preferred_configuration": r.prefer.as_ref().map(configuration),
        "arm_model": serde_json::from_str::<Value>(&arm_json(&r.model)).unwrap_or(Value::Null),
        "model_points": r.model_points,
        "floor_checked": r.floor,
    })
}

/// The `programs` block: the URScript program and the Techman packets, as `awl send` sends them.
pub fn programs_json(urscript: &str, techman: &str) -> Value {
    json!({ "urscript": urscript, "techman": techman })
}

/// The text of a plan's JSON value (e.g. [`plan_json`] with [`programs_json`] added), once the plan
/// passes [`check_for_robot`].
///
/// # Errors
/// As [`check_for_robot`].
pub fn plan_value_text(plan: &PiercePlan, value: &Value) -> Result<String> {
    check_for_robot(plan)?;
    let mut text = serde_json::to_string_pretty(value).unwrap_or_default();
    text.push('\n');
    Ok(text)
}

/// The text of plan.json, once the plan passes [`check_for_robot`].
///
/// # Errors
/// [`crate::Error::Invalid`] from [`check_for_robot`]: no plan file holds a non-finite or
/// out-of-range pose.
pub fn plan_text(plan: &PiercePlan, sources: &PlanSources<'_>) -> Result<String> {
    check_for_robot(plan)?;
    let mut text = serde_json::to_string_pretty(&plan_json(plan, sources)).unwrap_or_default();
    text.push('\n');
    Ok(text)
}

/// Writes plan.json atomically ([`plan_text`]).
///
/// # Errors
/// As [`plan_text`]; [`crate::Error::Io`] when the file cannot be written.
pub fn write_plan(path: &Path, plan: &PiercePlan, sources: &PlanSources<'_>) -> Result<()> {
    write_atomic(path, plan_text(plan, sources)?.as_bytes())
}
