//! The robot programs that visit a plan's views (`awl plan-views --urscript / --tm`): joint moves
//! only (URScript `movej`, Techman `PTP("JPP", ...)`), from the shot's recorded joints through each
//! view's checked joints in visiting order ([`crate::plan_views::reach`]: every move checked for
//! collisions along its straight line in joint space, the line both controllers follow).
//!
//! URScript: `def awl_views():`, a `movej` to each view and a `sleep` of the dwell, in which the
//! cell's camera takes the view; the program ends at the last view. Techman: one listen-node packet
//! per view (id `awlv<k>`: the robot base selected, one `PTP`), then `ScriptExit()`; send a view's
//! packet, take the view once the arm has stopped, then send the next. Every line is one of the
//! statements [`crate::robot::statements`] accepts; both are checked before they are returned.

use std::fmt::Write as _;

use crate::error::{Error, Result};
use crate::kinematics::Joints;
use crate::pierce::script::{ScriptSpeeds, check_joints, program_text, tm_ptp, tmsct_packet, ur_movej};
use crate::plan_views::ViewPlan;
use crate::robot::statements::{check_techman_statements, check_urscript_statements};

/// The longest dwell at a view, seconds.
pub const MAX_DWELL_S: f64 = 60.0;

/// What a views program is made of.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewsProgram {
    /// The arm the joints were checked for (printable ASCII in comments).
    pub arm: String,
    /// The arm's joints at the shot, radians: where the first move starts.
    pub start: Joints,
    /// Each view's joints, radians, in visiting order.
    pub views: Vec<Joints>,
    /// The wait at each view, seconds (0 to [`MAX_DWELL_S`]).
    pub dwell_s: f64,
}

impl ViewsProgram {
    /// The program of `plan` for the arm named `arm`, waiting `dwell_s` at each view.
    ///
    /// # Errors
    /// [`Error::Invalid`] when the plan was made without an arm (no joints), or its start joints were
    /// not recorded by the shot: the first move would start from joints nobody checked.
    pub fn of(plan: &ViewPlan, arm: &str, dwell_s: f64) -> Result<Self> {
        let Some((start, recorded)) = plan.start else {
            return Err(Error::invalid("the views", "were not checked for an arm: give --robot and --tcp"));
        };
        if !recorded {
            return Err(Error::invalid(
                "the shot's views[i].q",
                "the shot records no joints (q, radians, in scan.json's views): a program's first move would start \
                 from joints awl did not check; record them, or move the arm with the poses of views.json",
            ));
        }
        let views = (plan.chosen.iter())
            .map(|c| c.reach.map(|r| r.joints.q))
            .collect::<Option<Vec<Joints>>>()
            .ok_or_else(|| Error::invalid("the views", "a chosen view has no checked joints"))?;
        Ok(Self { arm: program_text(arm), start, views, dwell_s })
    }

    /// Checks every number the programs carry: joints finite within +-2 pi, the dwell within
    /// 0-[`MAX_DWELL_S`] s.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the value.
    pub fn validate(&self) -> Result<()> {
        check_joints("the shot's q", &self.start)?;
        for (k, q) in self.views.iter().enumerate() {
            check_joints(&format!("views[{k}].q"), q)?;
        }
        check_dwell(self.dwell_s)
    }
}

/// Refuses a wait at each view (`--dwell-s`) that is not 0-[`MAX_DWELL_S`] seconds.
///
/// # Errors
/// [`Error::Invalid`] naming `--dwell-s`.
pub fn check_dwell(dwell_s: f64) -> Result<()> {
    if !(dwell_s.is_finite() && (0.0..=MAX_DWELL_S).contains(&dwell_s)) {
        return Err(Error::invalid("--dwell-s", format!("must be 0-{MAX_DWELL_S} seconds, got {dwell_s}")));
    }
    Ok(())
}

/// The URScript program of `program` (module docs).
///
/// # Errors
/// [`Error::Invalid`] from [`ViewsProgram::validate`], [`ScriptSpeeds::validate`] or the statement check.
pub fn views_urscript(program: &ViewsProgram, speeds: &ScriptSpeeds) -> Result<String> {
    program.validate()?;
    speeds.validate()?;
    let mut s = String::new();
    let _ = writeln!(s, "def awl_views():");
    let _ = writeln!(
        s,
        "  # awl plan-views: {} view(s), joints checked for {}",
        program.views.len(),
        program_text(&program.arm)
    );
    let _ =
        writeln!(s, "  # each joint move checked for collisions from the one before; run it from the shot's joints:");
    let _ = writeln!(s, "  # {}", joints_text(&program.start));
    for (k, q) in program.views.iter().enumerate() {
        let _ = writeln!(s, "  # view {}: take it during the wait", k + 1);
        let _ = writeln!(s, "  {}", ur_movej(q, speeds));
        let _ = writeln!(s, "  sleep({:.3})", program.dwell_s);
    }
    let _ = writeln!(s, "end");
    check_urscript_statements(&s)?;
    Ok(s)
}

/// The Techman listen-node packets of `program` (module docs).
///
/// # Errors
/// As [`views_urscript`].
pub fn views_techman(program: &ViewsProgram, speeds: &ScriptSpeeds) -> Result<String> {
    program.validate()?;
    speeds.validate()?;
    let mut packets = Vec::new();
    for (k, q) in program.views.iter().enumerate() {
        packets.push(tmsct_packet(
            &format!("awlv{}", k + 1),
            &format!("ChangeBase(\"RobotBase\")\r\n{}", tm_ptp(q, speeds)),
        ));
    }
    packets.push(tmsct_packet("awlexit", "ScriptExit()"));
    check_techman_statements(&packets)?;
    Ok(packets.concat())
}

fn joints_text(q: &Joints) -> String {
    let deg: Vec<String> = q.iter().map(|v| format!("{:.2}", v.to_degrees())).collect();
    format!("q = [{}] deg", deg.join(", "))
}
