//! Robot programs for a plan: URScript (Universal Robots).
//!
//! Poses are the tool centre point in the robot base frame: set the controller's TCP to the tip of
//! the piercing tool before running. Per target: `movel` to approach, `movel` (slow) to pierce,
//! `movel` back to retract.

use std::fmt::Write as _;

use crate::pierce::plan::PiercePlan;
use crate::pierce::tool::ur_pose;

/// Speeds of the generated program.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScriptSpeeds {
    /// Tool speed between targets and to the approach pose, m/s. Default 0.10.
    pub travel_m_s: f64,
    /// Tool speed while piercing and retracting, m/s. Default 0.02.
    pub pierce_m_s: f64,
    /// Tool acceleration, m/s^2. Default 0.5.
    pub accel_m_s2: f64,
}

impl Default for ScriptSpeeds {
    fn default() -> Self {
        Self { travel_m_s: 0.10, pierce_m_s: 0.02, accel_m_s2: 0.5 }
    }
}

fn ur(pose: &nalgebra::Isometry3<f64>) -> String {
    let v = ur_pose(pose);
    format!("p[{:.6}, {:.6}, {:.6}, {:.6}, {:.6}, {:.6}]", v[0], v[1], v[2], v[3], v[4], v[5])
}

/// The URScript program of `plan` (module docs); `source` is named in its header comment.
pub fn urscript(plan: &PiercePlan, speeds: &ScriptSpeeds, source: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# awl pierce: {} target(s) from {source}", plan.targets.len());
    let _ =
        writeln!(s, "# TCP = the tip of the piercing tool; poses in the robot base frame (metres, rotation vectors)");
    let _ = writeln!(s, "def awl_pierce():");
    for (i, t) in plan.targets.iter().enumerate() {
        let p = t.p_base;
        let _ = writeln!(s, "  # target {i}: {} -> p_base ({:.4}, {:.4}, {:.4}) m", t.surface.spec, p.x, p.y, p.z);
        let (a, v, slow) = (speeds.accel_m_s2, speeds.travel_m_s, speeds.pierce_m_s);
        let _ = writeln!(s, "  movel({}, a={a}, v={v})", ur(&t.poses.approach));
        let _ = writeln!(s, "  movel({}, a={a}, v={slow})", ur(&t.poses.pierce));
        let _ = writeln!(s, "  movel({}, a={a}, v={slow})", ur(&t.poses.retract));
    }
    let _ = writeln!(s, "end");
    let _ = writeln!(s, "awl_pierce()");
    s
}
