//! Robot programs for a plan: URScript (Universal Robots) and Techman listen-node packets.
//!
//! Poses are the tool centre point in the robot base frame: set the controller's TCP to the tip of
//! the piercing tool before running. Per target: a linear move to approach, a slow one to pierce,
//! and back out to retract (URScript `movel`; Techman `Line("CAP", ...)`).
//!
//! When the plan's reach was checked ([`crate::pierce::reach`]), the programs set the TCP from
//! `T_ee_tool` (URScript `set_tcp`, Techman `ChangeTCP`), move in joint space to the approach
//! joints (`movej`, `PTP("JPP", ...)`, the configuration checked) and then linearly in and out
//! along the spun tool poses; a target whose reach was refused is left out (a comment says why in
//! the URScript; [`crate::pierce::PlannedTarget::reach_refusal`]). So is a target whose predicted
//! error exceeds the tolerance ([`crate::pierce::PlannedTarget::no_go_reason`]).
//!
//! The URScript program is a single `def ... end` (the form UR's primary / secondary client
//! interfaces run, every other line indented): the controller runs it when it arrives there; load it
//! as a script file otherwise.

use std::fmt::Write as _;

use nalgebra::{Isometry3, Point3};

use crate::error::{Error, Result};
use crate::kinematics::Joints;
use crate::kinematics::collision::MAX_TOOL_LENGTH_M;
use crate::pierce::plan::PiercePlan;
use crate::pierce::safety::{arm_reach, check_for_robot, check_pose};
use crate::pierce::tool::{MAX_REACH_M, ToolPoses, tm_pose, ur_pose};

/// Speeds of the generated program.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScriptSpeeds {
    /// Tool speed between targets and to the approach pose, m/s. Default 0.10.
    pub travel_m_s: f64,
    /// Tool speed while piercing and retracting, m/s. Default 0.02.
    pub pierce_m_s: f64,
    /// Tool acceleration, m/s^2. Default 0.5.
    pub accel_m_s2: f64,
    /// Joint speed of the joint-space move to the approach (URScript `movej`), rad/s. Default 0.5.
    pub joint_rad_s: f64,
    /// Joint acceleration of that move, rad/s^2. Default 1.0.
    pub joint_rad_s2: f64,
    /// Techman `PTP` speed, percent of the arm's top joint speed. Default 20.
    pub tm_joint_percent: u32,
}

impl Default for ScriptSpeeds {
    fn default() -> Self {
        Self {
            travel_m_s: 0.10,
            pierce_m_s: 0.02,
            accel_m_s2: 0.5,
            joint_rad_s: 0.5,
            joint_rad_s2: 1.0,
            tm_joint_percent: 20,
        }
    }
}

fn ur(pose: &Isometry3<f64>) -> String {
    let v = ur_pose(pose);
    format!("p[{:.6}, {:.6}, {:.6}, {:.6}, {:.6}, {:.6}]", v[0], v[1], v[2], v[3], v[4], v[5])
}

/// A target's three linear moves with their tool speeds (m/s): to approach at the travel speed, to
/// pierce and back out to retract at the piercing speed.
fn strokes<'a>(poses: &'a ToolPoses, speeds: &ScriptSpeeds) -> [(&'a Isometry3<f64>, f64); 3] {
    let (travel, slow) = (speeds.travel_m_s, speeds.pierce_m_s);
    [(&poses.approach, travel), (&poses.pierce, slow), (&poses.retract, slow)]
}

impl ScriptSpeeds {
    /// Checks the speeds: finite and positive, tool speeds at most 1 m/s, acceleration at most
    /// 5 m/s^2, joint speed at most pi rad/s, joint acceleration at most 40 rad/s^2, the Techman
    /// joint speed 1-100 %.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the field.
    pub fn validate(&self) -> Result<()> {
        for (name, v, max) in [
            ("travel_m_s", self.travel_m_s, 1.0),
            ("pierce_m_s", self.pierce_m_s, 1.0),
            ("accel_m_s2", self.accel_m_s2, 5.0),
            ("joint_rad_s", self.joint_rad_s, std::f64::consts::PI),
            ("joint_rad_s2", self.joint_rad_s2, 40.0),
        ] {
            if !(v.is_finite() && v > 0.0 && v <= max) {
                return Err(Error::invalid(name, format!("must be in (0, {max}], got {v}")));
            }
        }
        if !(1..=100).contains(&self.tm_joint_percent) {
            return Err(Error::invalid(
                "tm_joint_percent",
                format!("must be 1-100 (percent of the top joint speed), got {}", self.tm_joint_percent),
            ));
        }
        Ok(())
    }
}

/// The most characters of one word from a file, a path or an argument that a program carries (the
/// rest is cut and marked `...`).
pub const MAX_PROGRAM_TEXT_CHARS: usize = 160;

/// `text` reduced to what a robot program may carry from outside awl: printable ASCII (space to
/// `~`) only, every other character (line breaks of any kind, NUL, control and bidirectional
/// characters, any non-ASCII) replaced by `?`, and at most [`MAX_PROGRAM_TEXT_CHARS`] characters.
/// The one place every word from a file, a path or an argument passes before it reaches a URScript
/// or Techman program ([`ProgramPlan`]): no such word can end a comment or start a statement.
pub fn program_text(text: &str) -> String {
    let mut out: String =
        text.chars().take(MAX_PROGRAM_TEXT_CHARS).map(|c| if (' '..='~').contains(&c) { c } else { '?' }).collect();
    if text.chars().nth(MAX_PROGRAM_TEXT_CHARS).is_some() {
        out.push_str("...");
    }
    out
}

/// One target of a [`ProgramPlan`].
#[derive(Debug, Clone, PartialEq)]
pub struct ProgramTarget {
    /// The target as asked (`face-centre@x,y,z`), printable ASCII ([`program_text`]).
    pub spec: String,
    /// The surface point, base frame, metres (named in a comment).
    pub p_base: Point3<f64>,
    /// Why it is left out of the programs, printable ASCII (`None`: it goes).
    pub left_out: Option<String>,
    /// With a checked reach: the joints at the approach pose, radians, the joint move's goal.
    pub approach_q: Option<Joints>,
    /// The tool poses moved through (`T_base_tool`; with a checked reach, turned by its spin).
    pub poses: ToolPoses,
}

/// What a plan's robot programs are made of, and nothing else: the tool poses, the approach joints,
/// the TCP, and a few words for comments, each reduced to printable ASCII ([`program_text`]). The
/// programs of `awl pierce` ([`ProgramPlan::of`]) and the ones `awl send` regenerates from
/// plan.json to check what it sends ([`crate::pierce::verify`]) both come from it.
#[derive(Debug, Clone, PartialEq)]
pub struct ProgramPlan {
    /// Where the plan came from (the workpiece file), named in the URScript header.
    pub source: String,
    /// With a checked reach: the arm's name and `T_ee_tool`, the TCP the programs set.
    pub tcp: Option<(String, Isometry3<f64>)>,
    /// The targets, in the plan's order.
    pub targets: Vec<ProgramTarget>,
}

impl ProgramPlan {
    /// The program content of `plan`, whose workpiece file is `source`.
    pub fn of(plan: &PiercePlan, source: &str) -> Self {
        let tcp = plan.reach.as_ref().map(|r| (program_text(&r.arm), r.ee_from_tool));
        let targets = plan
            .targets
            .iter()
            .map(|t| {
                let reach = t.reach.as_ref().and_then(|r| r.joints.zip(r.tool_poses)).filter(|_| tcp.is_some());
                ProgramTarget {
                    spec: program_text(&t.surface.spec.to_string()),
                    p_base: t.p_base,
                    left_out: t.no_go_reason().map(|why| program_text(&why)),
                    approach_q: reach.map(|(q, _)| q.approach),
                    poses: reach.map_or(t.poses, |(_, poses)| poses),
                }
            })
            .collect();
        Self { source: program_text(source), tcp, targets }
    }

    /// Keeps every word printable ASCII ([`program_text`]), whoever built the plan.
    fn sanitized(&self) -> Self {
        let mut p = self.clone();
        p.source = program_text(&p.source);
        if let Some((arm, _)) = &mut p.tcp {
            *arm = program_text(arm);
        }
        for t in &mut p.targets {
            t.spec = program_text(&t.spec);
            t.left_out = t.left_out.as_deref().map(program_text);
        }
        p
    }

    /// Checks every number a program would carry: poses finite, unit rotations, within
    /// [`MAX_REACH_M`] of the base; joints finite and within +-2 pi; `T_ee_tool` finite and within
    /// [`MAX_TOOL_LENGTH_M`] of the flange; `p_base` finite.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the target and the value.
    pub fn validate(&self) -> Result<()> {
        if let Some((_, tcp)) = &self.tcp {
            check_pose(
                "T_ee_tool",
                tcp,
                MAX_TOOL_LENGTH_M,
                "the flange",
                &format!("a piercing tool's {MAX_TOOL_LENGTH_M} m: check T_ee_tool"),
            )?;
        }
        for (i, t) in self.targets.iter().enumerate() {
            let name = |what: &str| format!("targets[{i}] (`{}`).{what}", t.spec);
            if !t.p_base.coords.iter().all(|v| v.is_finite()) {
                return Err(Error::invalid(name("p_base"), "not finite"));
            }
            for (what, pose) in
                [("approach", &t.poses.approach), ("pierce", &t.poses.pierce), ("retract", &t.poses.retract)]
            {
                check_pose(&name(what), pose, MAX_REACH_M, "the robot base", &arm_reach())?;
            }
            if let Some(q) = &t.approach_q {
                check_joints(&name("q_rad.approach"), q)?;
            }
        }
        Ok(())
    }
}

/// Refuses joints `name` that are not finite angles within +-2 pi (radians), what a joint move may carry.
///
/// # Errors
/// [`Error::Invalid`] naming `name` and the joint.
pub(crate) fn check_joints(name: &str, q: &Joints) -> Result<()> {
    if let Some(k) = q.iter().position(|v| !(v.is_finite() && v.abs() <= 2.0 * std::f64::consts::PI)) {
        return Err(Error::invalid(name, format!("joint {} is {} rad: not a finite angle within +-2 pi", k + 1, q[k])));
    }
    Ok(())
}

/// The URScript program of `plan` (module docs); `source` is named in its header comment.
///
/// # Errors
/// [`Error::Invalid`] from [`check_for_robot`] or [`ScriptSpeeds::validate`]: no program is made
/// from a non-finite or out-of-range value.
pub fn urscript(plan: &PiercePlan, speeds: &ScriptSpeeds, source: &str) -> Result<String> {
    check_for_robot(plan)?;
    urscript_of(&ProgramPlan::of(plan, source), speeds)
}

/// The URScript program of `program` (module docs): every line one of awl's templates, the words
/// in its comments printable ASCII.
///
/// # Errors
/// [`Error::Invalid`] from [`ProgramPlan::validate`] or [`ScriptSpeeds::validate`].
pub fn urscript_of(program: &ProgramPlan, speeds: &ScriptSpeeds) -> Result<String> {
    let program = program.sanitized();
    program.validate()?;
    speeds.validate()?;
    let mut s = String::new();
    let _ = writeln!(s, "def awl_pierce():");
    let go = program.targets.iter().filter(|t| t.left_out.is_none()).count();
    let _ = writeln!(s, "  # awl pierce: {go} of {} target(s) from {}", program.targets.len(), program.source);
    let _ =
        writeln!(s, "  # TCP = the tip of the piercing tool; poses in the robot base frame (metres, rotation vectors)");
    if let Some((arm, ee_from_tool)) = &program.tcp {
        let _ = writeln!(s, "  # reach checked for {arm}: T_ee_tool as the TCP");
        let _ = writeln!(s, "  set_tcp({})", ur(ee_from_tool));
    }
    for (i, t) in program.targets.iter().enumerate() {
        let p = t.p_base;
        let _ = writeln!(s, "  # target {i}: {} -> p_base ({:.4}, {:.4}, {:.4}) m", t.spec, p.x, p.y, p.z);
        if let Some(why) = &t.left_out {
            let _ = writeln!(s, "  # left out: {why}");
            continue;
        }
        match &t.approach_q {
            Some(j) => {
                let _ = writeln!(s, "  {}", ur_movej(j, speeds));
                for (pose, v) in &strokes(&t.poses, speeds)[1..] {
                    let _ = writeln!(s, "  movel({}, a={}, v={v})", ur(pose), speeds.accel_m_s2);
                }
            }
            None => {
                for (pose, v) in strokes(&t.poses, speeds) {
                    let _ = writeln!(s, "  movel({}, a={}, v={v})", ur(pose), speeds.accel_m_s2);
                }
            }
        }
    }
    let _ = writeln!(s, "end");
    Ok(s)
}

/// One Techman listen-node packet: `$TMSCT,<length>,<id>,<script>,*<checksum>` and CR LF, where the
/// length counts the bytes of `<id>,<script>` and the checksum is the XOR of every byte between `$`
/// and `*`, as two upper-case hex digits. `id` must be alphanumeric; a script's lines are joined
/// with CR LF.
pub fn tmsct_packet(id: &str, script: &str) -> String {
    let data = format!("{id},{script}");
    let body = format!("TMSCT,{},{data},", data.len());
    let checksum = body.bytes().fold(0u8, |a, b| a ^ b);
    format!("${body}*{checksum:02X}\r\n")
}

fn tm_line(pose: &Isometry3<f64>, speed_m_s: f64, accel_m_s2: f64) -> String {
    let v = tm_pose(pose);
    // speed in mm/s, time to reach it in ms, no blending, precise positioning
    let speed_mm_s = (speed_m_s * 1e3).round().max(1.0);
    let accel_ms = (speed_m_s / accel_m_s2 * 1e3).round().max(1.0);
    format!(
        "Line(\"CAP\",{:.3},{:.3},{:.3},{:.4},{:.4},{:.4},{speed_mm_s},{accel_ms},0,true)",
        v[0], v[1], v[2], v[3], v[4], v[5]
    )
}

/// URScript's joint move to `q` (radians) at the joint speed and acceleration of `speeds`.
pub(crate) fn ur_movej(q: &Joints, speeds: &ScriptSpeeds) -> String {
    format!(
        "movej([{:.6}, {:.6}, {:.6}, {:.6}, {:.6}, {:.6}], a={}, v={})",
        q[0], q[1], q[2], q[3], q[4], q[5], speeds.joint_rad_s2, speeds.joint_rad_s
    )
}

/// Techman's joint move to `q` (radians; the packet carries degrees) at `speeds`.
pub(crate) fn tm_ptp(q: &Joints, speeds: &ScriptSpeeds) -> String {
    let d = q.map(f64::to_degrees);
    let accel_ms = (speeds.joint_rad_s / speeds.joint_rad_s2 * 1e3).round().max(1.0);
    // joint angles in degrees, speed percent, time to top speed in ms, no blending, precise
    format!(
        "PTP(\"JPP\",{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{},{accel_ms},0,true)",
        d[0], d[1], d[2], d[3], d[4], d[5], speeds.tm_joint_percent
    )
}

/// The Techman listen-node packets of `plan` (module docs): per target, one `$TMSCT` packet (id
/// `awl<i>`) that selects the robot base and moves approach -> pierce -> retract, then one that
/// leaves the listen node (`ScriptExit()`). With a checked reach: the TCP set from `T_ee_tool`,
/// a joint move to the approach joints, then the two linear moves; no-go targets left out.
/// Send them in order to the listen node (TCP port 5890), each after the previous one's reply.
///
/// # Errors
/// As [`urscript`].
pub fn techman_packets(plan: &PiercePlan, speeds: &ScriptSpeeds) -> Result<String> {
    check_for_robot(plan)?;
    techman_packets_of(&ProgramPlan::of(plan, ""), speeds)
}

/// The Techman listen-node packets of `program` ([`techman_packets`]): no word from outside awl
/// reaches them, only numbers and awl's templates.
///
/// # Errors
/// As [`urscript_of`].
pub fn techman_packets_of(program: &ProgramPlan, speeds: &ScriptSpeeds) -> Result<String> {
    program.validate()?;
    speeds.validate()?;
    let mut out = String::new();
    for (i, t) in program.targets.iter().enumerate() {
        if t.left_out.is_some() {
            continue;
        }
        let mut lines = vec!["ChangeBase(\"RobotBase\")".to_string()];
        match (&program.tcp, &t.approach_q) {
            (Some((_, ee_from_tool)), Some(q)) => {
                let v = tm_pose(ee_from_tool);
                lines.push(format!(
                    "ChangeTCP({:.3},{:.3},{:.3},{:.4},{:.4},{:.4})",
                    v[0], v[1], v[2], v[3], v[4], v[5]
                ));
                lines.push(tm_ptp(q, speeds));
                lines.extend(
                    strokes(&t.poses, speeds)[1..].iter().map(|(pose, v)| tm_line(pose, *v, speeds.accel_m_s2)),
                );
            }
            _ => lines.extend(strokes(&t.poses, speeds).map(|(pose, v)| tm_line(pose, v, speeds.accel_m_s2))),
        }
        out.push_str(&tmsct_packet(&format!("awl{i}"), &lines.join("\r\n")));
    }
    out.push_str(&tmsct_packet("awlexit", "ScriptExit()"));
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tmsct_packets_match_published_listen_node_examples() {
        // length and XOR checksum as in the TM listen-node examples of the TM ROS driver's users
        assert_eq!(tmsct_packet("1", "var_i++"), "$TMSCT,9,1,var_i++,*06\r\n");
        assert_eq!(tmsct_packet("2", "StopAndClearBuffer()"), "$TMSCT,22,2,StopAndClearBuffer(),*64\r\n");
        assert_eq!(tmsct_packet("2", "OK"), "$TMSCT,4,2,OK,*5F\r\n");
    }
}
