//! What `awl send` checks before a byte leaves for the robot: plan.json read back
//! ([`read_plan_to_send`]), every number a program moves by checked against the rest of the plan,
//! and the programs regenerated from the plan's tool poses and joints and compared, line by line,
//! with the ones the plan carries.
//!
//! The checks, each refusing with the field or the program line:
//! - each pose's four encodings (`T`, `xyz`, `quaternion_xyzw`, `ur_axis_angle`) agree, within
//!   [`SAME_M`] / [`SAME_RAD`];
//! - the tool poses follow from `p_base`, `axis_base` and the stroke (`approach_m`, `depth_m`,
//!   `retract_m`) as `awl pierce` made them;
//! - with a checked reach: the joints are finite and within the arm's limits (`robot.arm_model`), the
//!   arm's forward kinematics at them give the flange poses and, with `T_ee_tool`, the reach's tool
//!   poses (within [`FK_M`] / [`FK_RAD`]), which are the plan's turned by `spin_deg`;
//! - a target that goes has no `why`, finite predicted bounds, within the tolerance when the plan
//!   has one, and is reachable when its reach was checked; one that does not go says why;
//! - the poses are within an arm's reach ([`ProgramPlan::validate`]);
//! - the URScript program and the Techman packets equal, byte for byte, the ones made from all that
//!   with [`ScriptSpeeds::default`].

use std::path::Path;

use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion, Vector3};
use serde_json::Value;

use crate::error::{Error, Result};
use crate::io::scan::pose_field;
use crate::kinematics::arm_file::parse_arm;
use crate::kinematics::{Arm, Joints};
use crate::pierce::plan_file::PLAN_FORMAT;
use crate::pierce::script::{ProgramPlan, ProgramTarget, ScriptSpeeds, techman_packets_of, urscript_of};
use crate::pierce::tool::{Stroke, ToolPoses, tool_poses};
use crate::transform::pose_difference;

/// Two encodings of one pose agree within this, metres (the JSON numbers round-trip exactly: this
/// only absorbs the arithmetic between encodings).
pub const SAME_M: f64 = 1e-9;
/// ... and within this, radians.
pub const SAME_RAD: f64 = 1e-9;
/// The arm's forward kinematics at the plan's joints reach its poses within this, metres (the
/// inverse kinematics solve to about 1e-12 m).
pub const FK_M: f64 = 1e-6;
/// ... and within this, radians.
pub const FK_RAD: f64 = 1e-6;

/// What `awl send` needs from a plan.json, once it is verified: its programs and the targets that
/// must not be run.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanToSend {
    /// The URScript program (`programs.urscript`).
    pub urscript: String,
    /// The Techman listen-node packets (`programs.techman`).
    pub techman: String,
    /// Per refused target: its index, its `target` string and why (`reach.reachable` false, or the
    /// gate's `go` false with its `why`).
    pub refused: Vec<(usize, String, String)>,
}

/// Reads plan.json and verifies it ([`verify_plan`]).
///
/// # Errors
/// [`Error::Io`]; [`Error::Format`] for invalid JSON; as [`verify_plan`].
pub fn read_plan_to_send(path: &Path) -> Result<PlanToSend> {
    let value: Value = crate::io::scan::read_json(path)?;
    verify_plan(path, &value)
}

/// Verifies a plan.json's value (module docs); `path` names it in errors.
///
/// # Errors
/// [`Error::Field`] naming the field (`format`, `targets[i].pierce.xyz`, `targets[i].reach.q_rad`,
/// `programs.urscript`, ...) and what is wrong: missing, of the wrong kind, not finite, out of
/// range, or not what the rest of the plan gives (for a program: its first line that differs).
pub fn verify_plan(path: &Path, value: &Value) -> Result<PlanToSend> {
    let field = |name: &str, message: String| Error::field(path, name, message);
    if value.get("format").and_then(Value::as_str) != Some(PLAN_FORMAT) {
        return Err(field("format", format!("must be \"{PLAN_FORMAT}\" (a plan.json of awl pierce)")));
    }
    let program = |key: &str| {
        value.get("programs").and_then(|p| p.get(key)).and_then(Value::as_str).map(str::to_string).ok_or_else(|| {
            field(&format!("programs.{key}"), "missing: write the plan again with this awl pierce".into())
        })
    };
    let (urscript, techman) = (program("urscript")?, program("techman")?);
    let reader = Reader { path, value };
    let stroke = Stroke {
        approach_m: reader.number("approach_m")?,
        depth_m: reader.number("depth_m")?,
        retract_m: reader.number("retract_m")?,
        ..Stroke::default()
    }
    .allowing_long_moves();
    stroke.validate().map_err(|e| field("approach_m / depth_m / retract_m", e.to_string()))?;
    let tolerance_mm = reader.optional_number("tolerance_mm")?;
    let tolerance_deg = reader.optional_number("tolerance_deg")?;
    let robot = match value.get("robot").filter(|r| !r.is_null()) {
        None => None,
        Some(r) => Some(reader.robot(r)?),
    };
    let targets = value.get("targets").and_then(Value::as_array).ok_or_else(|| field("targets", "missing".into()))?;
    let mut refused = Vec::new();
    let mut program_targets = Vec::new();
    for (i, t) in targets.iter().enumerate() {
        let target = TargetReader { reader: &reader, value: t, prefix: format!("targets[{i}]") };
        let (program_target, why) = target.verify(&stroke, robot.as_ref(), tolerance_mm, tolerance_deg)?;
        if let Some(why) = why {
            refused.push((i, program_target.spec.clone(), why));
        }
        program_targets.push(program_target);
    }
    let source = value.get("workpiece").and_then(Value::as_str).unwrap_or_default();
    let plan = ProgramPlan {
        source: source.to_string(),
        tcp: robot.as_ref().map(|(arm, ee_from_tool)| (arm.name.clone(), *ee_from_tool)),
        targets: program_targets,
    };
    let message = |e: Error| field("targets", format!("no program can be made from the plan: {e}"));
    let speeds = ScriptSpeeds::default();
    let expected_ur = urscript_of(&plan, &speeds).map_err(message)?;
    let expected_tm = techman_packets_of(&plan, &speeds).map_err(message)?;
    same_program(path, "programs.urscript", &urscript, &expected_ur, "\n")?;
    same_program(path, "programs.techman", &techman, &expected_tm, "\r\n")?;
    Ok(PlanToSend { urscript, techman, refused })
}

/// Refuses `found` unless it equals `expected`, naming the first line (split at `separator`) that
/// differs.
fn same_program(path: &Path, name: &str, found: &str, expected: &str, separator: &str) -> Result<()> {
    if found == expected {
        return Ok(());
    }
    let (f, e): (Vec<&str>, Vec<&str>) = (found.split(separator).collect(), expected.split(separator).collect());
    let k = f.iter().zip(&e).position(|(a, b)| a != b).unwrap_or(f.len().min(e.len()));
    let shown = |lines: &[&str]| lines.get(k).map_or("(no line)".to_string(), |l| format!("`{}`", l.escape_debug()));
    Err(Error::field(
        path,
        name,
        format!(
            "line {} is {}, but the plan's poses and joints give {}: the program was changed after awl pierce wrote \
             it (or the plan was); nothing is sent: plan again",
            k + 1,
            shown(&f),
            shown(&e)
        ),
    ))
}

/// Reads numbers and poses from a plan.json value, naming `path` and the field in errors.
struct Reader<'a> {
    path: &'a Path,
    value: &'a Value,
}

impl Reader<'_> {
    fn error(&self, name: &str, message: impl Into<String>) -> Error {
        Error::field(self.path, name, message)
    }

    fn number(&self, name: &str) -> Result<f64> {
        self.number_at(self.value.get(name), name)
    }

    fn number_at(&self, v: Option<&Value>, name: &str) -> Result<f64> {
        let x = v.and_then(Value::as_f64).ok_or_else(|| self.error(name, "missing or not a number"))?;
        if x.is_finite() { Ok(x) } else { Err(self.error(name, "not finite")) }
    }

    fn optional_number(&self, name: &str) -> Result<Option<f64>> {
        match self.value.get(name) {
            None | Some(Value::Null) => Ok(None),
            v => self.number_at(v, name).map(Some),
        }
    }

    fn numbers<const N: usize>(&self, v: Option<&Value>, name: &str) -> Result<[f64; N]> {
        let a = v.and_then(Value::as_array).filter(|a| a.len() == N);
        let a = a.ok_or_else(|| self.error(name, format!("missing or not an array of {N} numbers")))?;
        let mut out = [0.0; N];
        for (k, x) in a.iter().enumerate() {
            out[k] = self.number_at(Some(x), &format!("{name}[{k}]"))?;
        }
        Ok(out)
    }

    fn rows(&self, v: Option<&Value>, name: &str) -> Result<Isometry3<f64>> {
        let rows: [[f64; 4]; 4] = {
            let a = v.and_then(Value::as_array).filter(|a| a.len() == 4);
            let a = a.ok_or_else(|| self.error(name, "missing or not a 4x4 matrix"))?;
            let mut rows = [[0.0; 4]; 4];
            for (r, row) in a.iter().enumerate() {
                rows[r] = self.numbers::<4>(Some(row), &format!("{name}[{r}]"))?;
            }
            rows
        };
        pose_field(self.path, name, &rows)
    }

    /// A `POSE` block: its `T` and every other encoding checked against it.
    fn pose(&self, v: Option<&Value>, name: &str) -> Result<Isometry3<f64>> {
        let v = v.filter(|v| v.is_object()).ok_or_else(|| self.error(name, "missing pose"))?;
        let t = self.rows(v.get("T"), &format!("{name}.T"))?;
        let xyz = self.numbers::<3>(v.get("xyz"), &format!("{name}.xyz"))?;
        let q = self.numbers::<4>(v.get("quaternion_xyzw"), &format!("{name}.quaternion_xyzw"))?;
        let ur = self.numbers::<6>(v.get("ur_axis_angle"), &format!("{name}.ur_axis_angle"))?;
        let quaternion = Quaternion::new(q[3], q[0], q[1], q[2]);
        if (quaternion.norm() - 1.0).abs() > SAME_RAD {
            return Err(self.error(&format!("{name}.quaternion_xyzw"), "not a unit quaternion"));
        }
        let pose =
            Isometry3::from_parts(Translation3::new(xyz[0], xyz[1], xyz[2]), UnitQuaternion::new_unchecked(quaternion));
        let ur_rotation = UnitQuaternion::from_scaled_axis(Vector3::new(ur[3], ur[4], ur[5]));
        let ur_offset = (Vector3::new(ur[0], ur[1], ur[2]) - pose.translation.vector).norm();
        for (what, dt, dr) in [
            ("T", (t.translation.vector - pose.translation.vector).norm(), t.rotation.angle_to(&pose.rotation)),
            ("ur_axis_angle", ur_offset, ur_rotation.angle_to(&pose.rotation)),
        ] {
            if !(dt <= SAME_M && dr <= SAME_RAD) {
                return Err(self.error(
                    &format!("{name}.{what}"),
                    format!(
                        "differs from xyz + quaternion_xyzw by {:.3e} m / {:.3e} rad: the pose was edited; plan again",
                        dt, dr
                    ),
                ));
            }
        }
        Ok(pose)
    }

    /// The `robot` block: the arm (`arm_model`, whose `name` must be `arm`) and `T_ee_tool`.
    fn robot(&self, r: &Value) -> Result<(Arm, Isometry3<f64>)> {
        let model = r.get("arm_model").filter(|m| m.is_object()).ok_or_else(|| {
            self.error(
                "robot.arm_model",
                "missing: the arm is needed to check the joints; plan again with this awl pierce",
            )
        })?;
        let bytes = serde_json::to_vec(model).map_err(|e| self.error("robot.arm_model", e.to_string()))?;
        let arm = parse_arm(self.path, &bytes).map_err(|e| self.error("robot.arm_model", e.to_string()))?;
        if r.get("arm").and_then(Value::as_str) != Some(arm.name.as_str()) {
            return Err(self.error("robot.arm", format!("is not the arm_model's name `{}`", arm.name)));
        }
        let ee_from_tool = self.rows(r.get("T_ee_tool"), "robot.T_ee_tool")?;
        Ok((arm, ee_from_tool))
    }
}

/// One target of a plan.json.
struct TargetReader<'a> {
    reader: &'a Reader<'a>,
    value: &'a Value,
    prefix: String,
}

impl TargetReader<'_> {
    fn name(&self, what: &str) -> String {
        format!("{}.{what}", self.prefix)
    }

    fn error(&self, what: &str, message: impl Into<String>) -> Error {
        self.reader.error(&self.name(what), message)
    }

    fn pose(&self, v: Option<&Value>, what: &str) -> Result<Isometry3<f64>> {
        self.reader.pose(v, &self.name(what))
    }

    /// The approach / pierce / retract poses of `v`, named `what.approach` ... (`approach` ... when
    /// `what` is empty).
    fn three(&self, v: Option<&Value>, what: &str) -> Result<ToolPoses> {
        let one = |key: &str| {
            let name = if what.is_empty() { key.to_string() } else { format!("{what}.{key}") };
            self.pose(v.and_then(|v| v.get(key)), &name)
        };
        Ok(ToolPoses { approach: one("approach")?, pierce: one("pierce")?, retract: one("retract")? })
    }

    fn joints(&self, v: Option<&Value>, what: &str, arm: &Arm) -> Result<Joints> {
        let q = self.reader.numbers::<6>(v, &self.name(what))?;
        if !arm.within_limits(&q) {
            return Err(self.error(what, format!("{q:?} rad is outside the limits of {}", arm.name)));
        }
        Ok(q)
    }

    /// The target's program content and, when it must not run, why.
    fn verify(
        &self,
        stroke: &Stroke,
        robot: Option<&(Arm, Isometry3<f64>)>,
        tolerance_mm: Option<f64>,
        tolerance_deg: Option<f64>,
    ) -> Result<(ProgramTarget, Option<String>)> {
        let t = self.value;
        let spec = t.get("target").and_then(Value::as_str).ok_or_else(|| self.error("target", "missing"))?;
        let p = self.reader.numbers::<3>(t.get("p_base"), &self.name("p_base"))?;
        let axis = self.reader.numbers::<3>(t.get("axis_base"), &self.name("axis_base"))?;
        let (p_base, axis) = (Point3::from(p), Vector3::from(axis));
        if (axis.norm() - 1.0).abs() > 1e-6 {
            return Err(self.error("axis_base", "not a unit vector"));
        }
        let poses = self.three(Some(t), "")?;
        let made = tool_poses(&p_base, &axis, stroke).map_err(|e| self.error("axis_base", e.to_string()))?;
        for (what, found, expected) in [
            ("approach", &poses.approach, &made.approach),
            ("pierce", &poses.pierce, &made.pierce),
            ("retract", &poses.retract, &made.retract),
        ] {
            let (dt, dr) = pose_difference(found, expected);
            if !(dt <= SAME_M && dr <= SAME_RAD) {
                return Err(self.error(
                    what,
                    format!(
                        "is {dt:.3e} m / {dr:.3e} rad from the pose p_base, axis_base and the stroke give: the plan was \
                         edited; plan again"
                    ),
                ));
            }
        }
        let go = t.get("go").and_then(Value::as_bool).ok_or_else(|| self.error("go", "missing or not true / false"))?;
        let why = match t.get("why") {
            None | Some(Value::Null) => None,
            Some(Value::String(s)) => Some(s.clone()),
            Some(_) => return Err(self.error("why", "not a string")),
        };
        if go == why.is_some() {
            return Err(self.error("go", "disagrees with `why`: a target goes exactly when it has no `why`"));
        }
        if go {
            for (what, tolerance) in [("predicted_error_mm", tolerance_mm), ("predicted_axis_error_deg", tolerance_deg)]
            {
                let bound = t.get(what).and_then(Value::as_f64).filter(|b| b.is_finite() && *b >= 0.0);
                let Some(bound) = bound else {
                    return Err(self.error(what, "a target that goes needs a finite bound: it must be no-go"));
                };
                if let Some(tol) = tolerance.filter(|tol| !(bound <= *tol)) {
                    return Err(self.error(what, format!("{bound} exceeds the plan's tolerance {tol}, yet go is true")));
                }
            }
        }
        let reach = t.get("reach").filter(|r| !r.is_null());
        // `why` holds every reason, the reach's included
        let refusal = why.clone();
        let mut program = ProgramTarget { spec: spec.to_string(), p_base, left_out: why, approach_q: None, poses };
        match (robot, reach) {
            (None, None) => {}
            (None, Some(_)) => return Err(self.error("reach", "present, but the plan has no `robot`")),
            (Some(_), None) => return Err(self.error("reach", "missing, but the plan has a `robot`")),
            (Some((arm, ee_from_tool)), Some(r)) => {
                let reachable = r.get("reachable").and_then(Value::as_bool);
                if reachable != Some(true) {
                    if go {
                        return Err(self.error("reach.reachable", "not true, yet go is true"));
                    }
                } else {
                    program.approach_q = Some(self.verify_reach(r, arm, ee_from_tool, &poses)?);
                    program.poses = self.three(r.get("tool"), "reach.tool")?;
                }
            }
        }
        Ok((program, refusal))
    }

    /// A reachable target's joints checked against the arm and the poses; the approach joints.
    fn verify_reach(&self, r: &Value, arm: &Arm, ee_from_tool: &Isometry3<f64>, poses: &ToolPoses) -> Result<Joints> {
        let spin = self.reader.number_at(r.get("spin_deg"), &self.name("reach.spin_deg"))?.to_radians();
        let rz = Isometry3::rotation(Vector3::z() * spin);
        let tool = self.three(r.get("tool"), "reach.tool")?;
        let flange = self.three(r.get("flange"), "reach.flange")?;
        let q = r.get("q_rad");
        let mut approach_q = [0.0; 6];
        for (what, plan_pose, tool_pose, flange_pose) in [
            ("approach", &poses.approach, &tool.approach, &flange.approach),
            ("pierce", &poses.pierce, &tool.pierce, &flange.pierce),
            ("retract", &poses.retract, &tool.retract, &flange.retract),
        ] {
            let (dt, dr) = pose_difference(tool_pose, &(plan_pose * rz));
            if !(dt <= SAME_M && dr <= SAME_RAD) {
                return Err(self.error(
                    &format!("reach.tool.{what}"),
                    format!("is {dt:.3e} m / {dr:.3e} rad from the target's {what} pose turned by spin_deg: edited"),
                ));
            }
            let joints = self.joints(q.and_then(|q| q.get(what)), &format!("reach.q_rad.{what}"), arm)?;
            let at = arm.base_from_flange(&joints);
            for (name, found, expected) in [
                (format!("reach.flange.{what}"), flange_pose, at),
                (format!("reach.tool.{what}"), tool_pose, at * ee_from_tool),
            ] {
                let (dt, dr) = pose_difference(found, &expected);
                if !(dt <= FK_M && dr <= FK_RAD) {
                    return Err(self.error(
                        &name,
                        format!(
                            "is {:.3} mm / {:.4} deg from where the arm's joints reach.q_rad.{what} put it: the joints or \
                             the pose were edited; plan again",
                            dt * 1e3,
                            dr.to_degrees()
                        ),
                    ));
                }
            }
            if what == "approach" {
                approach_q = joints;
            }
        }
        Ok(approach_q)
    }
}
