//! The candidates file of `awl plan-views --candidates` and the `views.json` it writes.
//!
//! Candidates: a JSON object with `candidates`, each `{ "T_base_ee": [[4x4]] }` (or
//! `T_base_ee_commanded`, as the view banks of `../shared/data/sim_reference/*_bank/bank.json` name it:
//! the commanded flange pose, robot base frame, metres), with an optional `why` and `view`.

use std::path::Path;

use serde::Deserialize;
use serde_json::{Value, json};

use crate::error::{Error, Result};
use crate::io::scan::{pose_field, read_json};
use crate::kinematics::collision::Clearance;
use crate::plan_views::{Candidate, ViewPlan};
use crate::transform::{Rows, rows_from_isometry};

/// At most this many candidates are read from one file.
pub const MAX_CANDIDATES: usize = 10_000;

#[derive(Deserialize)]
struct CandidateEntry {
    #[serde(rename = "T_base_ee")]
    base_from_ee: Option<Rows>,
    #[serde(rename = "T_base_ee_commanded")]
    commanded: Option<Rows>,
    why: Option<String>,
    view: Option<usize>,
}

#[derive(Deserialize)]
struct CandidatesFile {
    candidates: Vec<CandidateEntry>,
}

/// Reads the candidates (module docs).
///
/// # Errors
/// [`Error::Format`] / [`Error::Field`] naming the file and the candidate: not JSON, no
/// `candidates`, none at all, more than [`MAX_CANDIDATES`], a pose missing or not rigid.
pub fn read_candidates(path: &Path) -> Result<Vec<Candidate>> {
    let file: CandidatesFile = read_json(path)?;
    if file.candidates.is_empty() {
        return Err(Error::format(path, "`candidates` is empty: give at least one flange pose"));
    }
    if file.candidates.len() > MAX_CANDIDATES {
        return Err(Error::format(
            path,
            format!("{} candidates, more than the {MAX_CANDIDATES} awl plans over", file.candidates.len()),
        ));
    }
    file.candidates
        .into_iter()
        .enumerate()
        .map(|(i, c)| {
            let (field, rows) = match (&c.base_from_ee, &c.commanded) {
                (Some(r), _) => (format!("candidates[{i}].T_base_ee"), r),
                (None, Some(r)) => (format!("candidates[{i}].T_base_ee_commanded"), r),
                (None, None) => {
                    return Err(Error::format(path, format!("candidates[{i}] has no T_base_ee (4x4, metres)")));
                }
            };
            let base_from_ee = pose_field(path, &field, rows)?;
            Ok(Candidate { base_from_ee, why: c.why.unwrap_or_else(|| format!("candidate {i}")), view: c.view })
        })
        .collect()
}

#[derive(Deserialize)]
struct ViewsFile {
    format: String,
    views: Vec<ViewEntry>,
}

#[derive(Deserialize)]
struct ViewEntry {
    #[serde(rename = "T_base_ee")]
    base_from_ee: Rows,
}

/// The proposed flange poses of a `views.json` (`awl-views/1`), in visiting order.
///
/// # Errors
/// [`Error::Format`] / [`Error::Field`] naming the file: not JSON, another format, more than
/// [`MAX_CANDIDATES`] views, a pose that is not rigid.
pub fn read_view_poses(path: &Path) -> Result<Vec<nalgebra::Isometry3<f64>>> {
    let file: ViewsFile = read_json(path)?;
    if file.format != "awl-views/1" {
        return Err(Error::field(path, "format", format!("`{}`, expected `awl-views/1`", file.format)));
    }
    if file.views.len() > MAX_CANDIDATES {
        return Err(Error::format(path, format!("{} views, more than {MAX_CANDIDATES}", file.views.len())));
    }
    (file.views.iter().enumerate())
        .map(|(i, v)| pose_field(path, &format!("views[{i}].T_base_ee"), &v.base_from_ee))
        .collect()
}

fn bounds_json(bounds: &[(f64, f64)], names: &[String]) -> Value {
    let finite = |v: f64| if v.is_finite() { json!(v) } else { Value::Null };
    Value::Array(
        bounds
            .iter()
            .zip(names)
            .map(|(&(p, a), name)| {
                json!({ "target": name, "position_bound_mm": finite(p * 1e3), "axis_bound_deg": finite(a.to_degrees()) })
            })
            .collect(),
    )
}

/// `views.json` (`awl-views/1`): the proposed views in visiting order, each with its commanded
/// `T_base_ee`, its joints `q` (radians; null when no arm was given) and what they were checked for
/// (the arm, the configuration, the joint limit margin, the clearances at the view and along the
/// joint move to it, mm), the bounds of every target once it is taken and why it was chosen; the
/// joints the first move starts from (`start_q`, and whether the shot recorded them), the bounds
/// before and after, whether they meet the tolerance, and why the plan stops there.
pub fn views_json(
    plan: &ViewPlan,
    candidates: &[Candidate],
    target_names: &[String],
    tolerance: (Option<f64>, Option<f64>),
    arm: Option<&str>,
) -> Value {
    let mm = |c: &Option<Clearance>| {
        c.map(|c| json!({ "mm": c.distance_m * 1e3, "link": c.link.name(), "against": c.against.name() }))
    };
    let views: Vec<Value> = plan
        .chosen
        .iter()
        .map(|c| {
            let cand = &candidates[c.candidate];
            let (q, reach) = match (&c.reach, arm) {
                (Some(r), Some(arm)) => (
                    json!(r.joints.q),
                    json!({
                        "arm": arm,
                        "configuration": r.joints.branch.to_string(),
                        "limit_margin_deg": r.joints.limit_margin_rad.to_degrees(),
                        "clearance": mm(&r.joints.clearance),
                        "move_clearance": mm(&r.move_clearance),
                    }),
                ),
                _ => (Value::Null, json!("not checked: give --robot and --tcp")),
            };
            json!({
                "candidate": c.candidate,
                "bank_view": cand.view,
                "T_base_ee": rows_from_isometry(&cand.base_from_ee),
                "q": q,
                "reach": reach,
                "visible_model_points": c.visible,
                "unobserved_motions": c.unobserved,
                "bounds_after": bounds_json(&c.bounds, target_names),
                "why": c.why,
            })
        })
        .collect();
    let after = plan.chosen.last().map_or(&plan.before, |c| &c.bounds);
    json!({
        "format": "awl-views/1",
        "pose_frame": "flange (T_base_ee, robot base frame, metres)",
        "tolerance_mm": tolerance.0.map(|t| t * 1e3),
        "tolerance_deg": tolerance.1.map(f64::to_degrees),
        "bounds_before": bounds_json(&plan.before, target_names),
        "views": views,
        "bounds_after": bounds_json(after, target_names),
        "start_q": plan.start.map(|(q, recorded)| json!({ "q": q, "recorded": recorded })),
        "met": plan.met,
        "stop": plan.stop,
        "left_out": plan.left_out.iter().map(|(i, why)| json!({ "candidate": i, "bank_view": candidates[*i].view, "why": why })).collect::<Vec<_>>(),
    })
}
