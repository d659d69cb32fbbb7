//! Straight tool lines in joint space: a flange path (e.g. approach -> pierce -> retract) stepped
//! every few millimetres, one configuration followed continuously, and the first failure (out of
//! reach, near a singularity, a joint limit, a jump in joint space) or the smallest margins along
//! it; and the spin about a piercing axis that keeps the most margin.
//!
//! Between two poses the position moves linearly and the orientation by slerp (a controller's
//! `movel`).

use std::f64::consts::PI;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use super::ik::{self, Branch, IkParams, IkSolution, Measures, Reason, joint_distance};
use super::{Arm, Joints};

use crate::error::{Error, Result};

/// The three tool poses of one target, base frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToolPoses {
    /// `T_base_approach`: on the axis, before the surface.
    pub approach: Isometry3<f64>,
    /// `T_base_pierce`: on the axis, `depth_m` into the surface.
    pub pierce: Isometry3<f64>,
    /// `T_base_retract`: back out along the axis.
    pub retract: Isometry3<f64>,
}

/// Settings of [`check_path`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineParams {
    /// Largest step along a segment between two checked points, metres. Default 0.002.
    pub step_m: f64,
    /// Largest rotation between two checked points, radians. Default 0.01 (0.57 deg).
    pub step_rad: f64,
    /// A joint moving more than this between two checked points is a jump (a branch flip the
    /// singularity minimums let through), radians. Default 0.1 (5.7 deg).
    pub max_joint_step_rad: f64,
    /// The singularity minimums (and the start's alias reference).
    pub ik: IkParams,
}

impl Default for LineParams {
    fn default() -> Self {
        Self { step_m: 0.002, step_rad: 0.01, max_joint_step_rad: 0.1, ik: IkParams::default() }
    }
}

impl LineParams {
    fn validate(&self) -> Result<()> {
        for (name, v) in
            [("step_m", self.step_m), ("step_rad", self.step_rad), ("max_joint_step_rad", self.max_joint_step_rad)]
        {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::invalid(name, format!("must be a positive finite value, got {v}")));
            }
        }
        Ok(())
    }
}

/// Margins along a path (or their scales in [`SpinParams`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Margins {
    /// Smallest distance of a joint to its limit, radians.
    pub limit_rad: f64,
    /// Smallest `|sin(theta5)|`.
    pub wrist: f64,
    /// Smallest `|sin(theta3)|`.
    pub elbow: f64,
    /// Smallest shoulder distance, metres.
    pub shoulder_m: f64,
}

impl Margins {
    fn infinite() -> Self {
        Self { limit_rad: f64::INFINITY, wrist: f64::INFINITY, elbow: f64::INFINITY, shoulder_m: f64::INFINITY }
    }

    fn include(&mut self, m: &Measures, limit_rad: f64) {
        self.limit_rad = self.limit_rad.min(limit_rad);
        self.wrist = self.wrist.min(m.wrist);
        self.elbow = self.elbow.min(m.elbow);
        self.shoulder_m = self.shoulder_m.min(m.shoulder_m);
    }

    /// The worst of the four margins, each divided by its `scale` (which makes radians, sines and
    /// metres comparable): 0 = at a limit or a singularity, 1 = the worst margin at its scale.
    pub fn score(&self, scale: &Margins) -> f64 {
        [
            self.limit_rad / scale.limit_rad,
            self.wrist / scale.wrist,
            self.elbow / scale.elbow,
            self.shoulder_m / scale.shoulder_m,
        ]
        .into_iter()
        .fold(f64::INFINITY, f64::min)
    }
}

/// One checked point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineSample {
    /// The segment (0 = first pose to second).
    pub segment: usize,
    /// Position along the segment, 0 to 1.
    pub s: f64,
    /// The joints, radians.
    pub q: Joints,
    /// The singularity measures there.
    pub measures: Measures,
    /// The limit margin there, radians.
    pub limit_margin_rad: f64,
}

/// What stopped a path.
#[derive(Debug, Clone, PartialEq)]
pub enum FailureKind {
    /// The followed configuration failed as an inverse-kinematics solution there: out of reach,
    /// a singularity measure below its minimum, or a joint outside its limits (`q_rad`: the
    /// value followed along the path, radians).
    Ik(Reason),
    /// A joint moved too far between two checked points.
    Jump {
        /// The joint, 1-based.
        joint: usize,
        /// The move, radians.
        delta_rad: f64,
        /// The allowed move, radians.
        max_rad: f64,
    },
}

/// Where and why a path failed.
#[derive(Debug, Clone, PartialEq)]
pub struct LineFailure {
    /// The segment.
    pub segment: usize,
    /// Position along it, 0 to 1.
    pub s: f64,
    /// Distance travelled from the path's start to there, metres.
    pub distance_m: f64,
    /// What happened.
    pub kind: FailureKind,
}

impl std::fmt::Display for LineFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "at {:.1} mm along the path (segment {}, {:.0} %): ",
            self.distance_m * 1e3,
            self.segment,
            self.s * 1e2
        )?;
        match &self.kind {
            FailureKind::Ik(Reason::JointLimit { joint, q_rad, limits }) => write!(
                f,
                "joint {joint} reaches {:.2} deg, outside its limits [{:.1}, {:.1}] deg",
                q_rad.to_degrees(),
                limits[0].to_degrees(),
                limits[1].to_degrees()
            ),
            FailureKind::Ik(reason) => write!(f, "{reason}"),
            FailureKind::Jump { joint, delta_rad, max_rad } => write!(
                f,
                "joint {joint} jumps {:.2} deg between two checked points (allowed {:.2} deg)",
                delta_rad.to_degrees(),
                max_rad.to_degrees()
            ),
        }
    }
}

/// The result of [`check_path`].
#[derive(Debug, Clone, PartialEq)]
pub struct LineReport {
    /// The configuration followed.
    pub branch: Branch,
    /// Every checked point up to the failure (the start first).
    pub samples: Vec<LineSample>,
    /// The first failure, `None` when the whole path passed.
    pub failure: Option<LineFailure>,
    /// The smallest margins over the checked points.
    pub min: Margins,
}

impl LineReport {
    /// Whether the whole path passed.
    pub fn ok(&self) -> bool {
        self.failure.is_none()
    }

    /// The joints at the start of each segment and at the path's end (the path's poses), when
    /// it passed.
    pub fn joints_at_poses(&self) -> Vec<Joints> {
        if !self.ok() {
            return Vec::new();
        }
        let mut out: Vec<Joints> = Vec::new();
        for (k, s) in self.samples.iter().enumerate() {
            if k == 0 || s.s >= 1.0 {
                out.push(s.q);
            }
        }
        out
    }
}

fn interpolate(a: &Isometry3<f64>, b: &Isometry3<f64>, s: f64) -> Option<Isometry3<f64>> {
    let t = a.translation.vector.lerp(&b.translation.vector, s);
    let r = if a.rotation.angle_to(&b.rotation) < 1e-12 {
        a.rotation
    } else {
        a.rotation.try_slerp(&b.rotation, s, 1e-9)?
    };
    Some(Isometry3::from_parts(Translation3::from(t), r))
}

/// Checks the flange path through `poses` (base frame, at least one) from the configuration
/// `start` (an [`ik::inverse`] solution of `poses[0]`), following its branch.
///
/// # Errors
/// [`Error::Invalid`] for no poses, a non-finite pose, a segment turning by 180 degrees (its
/// slerp is ambiguous), `start` not a solution of `poses[0]` (1e-6 m / rad), bad parameters, or an
/// arm without the closed-form structure.
pub fn check_path(arm: &Arm, poses: &[Isometry3<f64>], start: &IkSolution, params: &LineParams) -> Result<LineReport> {
    params.validate()?;
    let first = poses.first().ok_or_else(|| Error::invalid("poses", "a path needs at least one pose"))?;
    let (dt, dr) = crate::transform::pose_difference(&arm.base_from_flange(&start.q), first);
    if !(dt < 1e-6 && dr < 1e-6) {
        return Err(Error::invalid(
            "start",
            format!("its joints put the flange {dt:.3e} m / {dr:.3e} rad from the path's first pose"),
        ));
    }
    let mut min = Margins::infinite();
    min.include(&start.measures, arm.limit_margin_rad(&start.q));
    let mut report = LineReport {
        branch: start.branch,
        samples: vec![LineSample {
            segment: 0,
            s: 0.0,
            q: start.q,
            measures: start.measures,
            limit_margin_rad: arm.limit_margin_rad(&start.q),
        }],
        failure: None,
        min,
    };
    let mut prev = start.q;
    let mut travelled = 0.0;
    for (segment, pair) in poses.windows(2).enumerate() {
        let (a, b) = (&pair[0], &pair[1]);
        let length = (b.translation.vector - a.translation.vector).norm();
        let angle = a.rotation.angle_to(&b.rotation);
        if !(length.is_finite() && angle.is_finite()) {
            return Err(Error::invalid(format!("poses[{}]", segment + 1), "the pose has a non-finite value"));
        }
        let steps = (length / params.step_m).ceil().max((angle / params.step_rad).ceil()).max(1.0) as usize;
        for i in 1..=steps {
            let s = i as f64 / steps as f64;
            let pose = interpolate(a, b, s).ok_or_else(|| {
                Error::invalid(
                    format!("poses[{segment}..{}]", segment + 1),
                    "turns by 180 degrees: the line between them is ambiguous",
                )
            })?;
            let fail = |kind| LineFailure { segment, s, distance_m: travelled + length * s, kind };
            let (raw, refused) = ik::raw_solutions_of(arm, &pose, prev[5], Some(start.branch))?;
            let Some(r) = raw.iter().find(|r| r.branch == start.branch) else {
                let why = refused.iter().find(|f| f.branch.is_none_or(|b| b == start.branch)).map_or_else(
                    || "no solution of this configuration".to_string(),
                    |f| match &f.reason {
                        ik::Reason::OutOfReach(m) => m.clone(),
                        other => other.to_string(),
                    },
                );
                report.failure = Some(fail(FailureKind::Ik(Reason::OutOfReach(why))));
                return Ok(report);
            };
            if let Some(reason) = ik::singular(&r.measures, &params.ik) {
                report.failure = Some(fail(FailureKind::Ik(reason)));
                return Ok(report);
            }
            let mut q = r.q;
            for j in 0..6 {
                q[j] += ((prev[j] - q[j]) / (2.0 * PI)).round() * 2.0 * PI;
            }
            if let Some((j, d)) =
                (0..6).map(|j| (j, (q[j] - prev[j]).abs())).find(|(_, d)| *d > params.max_joint_step_rad)
            {
                report.failure =
                    Some(fail(FailureKind::Jump { joint: j + 1, delta_rad: d, max_rad: params.max_joint_step_rad }));
                return Ok(report);
            }
            if let Some(j) = (0..6).find(|&j| q[j] < arm.limits[j][0] || q[j] > arm.limits[j][1]) {
                report.failure = Some(fail(FailureKind::Ik(Reason::JointLimit {
                    joint: j + 1,
                    q_rad: q[j],
                    limits: arm.limits[j],
                })));
                return Ok(report);
            }
            let margin = arm.limit_margin_rad(&q);
            report.min.include(&r.measures, margin);
            report.samples.push(LineSample { segment, s, q, measures: r.measures, limit_margin_rad: margin });
            prev = q;
        }
        travelled += length;
    }
    Ok(report)
}

/// Settings of [`best_spin`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpinParams {
    /// Spins tried over a full turn about the tool axis (0, +step, -step, +2 step, ...). Default 36
    /// (10 deg apart).
    pub count: usize,
    /// Try only this spin, radians (`--fixed-spin`).
    pub fixed_rad: Option<f64>,
    /// The scale of each margin in [`Margins::score`]. Default: limits 0.5 rad, wrist and elbow
    /// 0.5, shoulder 0.1 m.
    pub scale: Margins,
    /// Rank the passing candidates by the joint motion from `line.ik.reference` to their approach
    /// (the largest joint's, in steps of [`MOTION_STEP_RAD`]) before their margins: what a program
    /// coming from those joints moves least. Default false (margins first).
    pub least_motion: bool,
}

/// The step of [`SpinParams::least_motion`]'s ranking, radians (10 deg: motions closer than this
/// are ranked by their margins).
pub const MOTION_STEP_RAD: f64 = 0.174_532_925_199_432_95;

impl Default for SpinParams {
    fn default() -> Self {
        Self {
            count: 36,
            fixed_rad: None,
            scale: Margins { limit_rad: 0.5, wrist: 0.5, elbow: 0.5, shoulder_m: 0.1 },
            least_motion: false,
        }
    }
}

/// The chosen spin and configuration of one target.
#[derive(Debug, Clone, PartialEq)]
pub struct SpinChoice {
    /// The rotation about the tool's z axis applied to the tool poses, radians.
    pub spin_rad: f64,
    /// The flange poses checked (approach, pierce, retract), base frame.
    pub flange_poses: [Isometry3<f64>; 3],
    /// The configuration at the approach pose.
    pub start: IkSolution,
    /// The path's check.
    pub report: LineReport,
    /// [`Margins::score`] of its margins.
    pub score: f64,
}

/// The result of [`best_spin`].
#[derive(Debug, Clone, PartialEq)]
pub struct SpinSearch {
    /// The passing (spin, configuration) of the highest score (ties: the smaller spin, then the
    /// configuration nearest the reference), `None` when none passed.
    pub best: Option<SpinChoice>,
    /// (spin, configuration, why it failed) of every candidate that did not pass; configuration
    /// `None` when the approach pose itself had no solution.
    pub failures: Vec<(f64, Option<Branch>, String)>,
    /// Candidates whose path passed (before any `accept` of [`best_spin_with`]).
    pub passed: usize,
    /// Poses solved by [`ik::inverse`] (the three stroke poses of each spin tried, fewer when
    /// one has no solution): the cheap checks' work.
    pub ik_poses: usize,
    /// Candidates whose path was stepped by [`check_path`]: those with a solution of their
    /// configuration at all three poses.
    pub paths_checked: usize,
    /// Candidates given to `accept`.
    pub accept_calls: usize,
}

impl SpinSearch {
    /// Why no candidate passed: each kind of failure once (its text up to the first number), with
    /// how many candidates failed so and its first instance.
    pub fn reason(&self) -> String {
        let mut kinds: Vec<(String, usize, String)> = Vec::new();
        for (_, _, why) in &self.failures {
            let text = why.split_once("): ").map_or(why.as_str(), |(_, r)| r);
            let first = text.split("; ").next().unwrap_or(text).to_string();
            let key: String = first.chars().take_while(|c| !c.is_ascii_digit()).collect();
            match kinds.iter_mut().find(|(k, _, _)| *k == key) {
                Some((_, n, _)) => *n += 1,
                None => kinds.push((key, 1, first)),
            }
        }
        kinds.iter().map(|(_, n, first)| format!("{n} x {first}")).collect::<Vec<_>>().join("; ")
    }
}

/// The spins tried: `fixed`, or `count` over a full turn, smallest first.
fn spins(params: &SpinParams) -> Result<Vec<f64>> {
    if let Some(s) = params.fixed_rad {
        if !s.is_finite() {
            return Err(Error::invalid("fixed_spin", format!("must be finite radians, got {s}")));
        }
        return Ok(vec![s]);
    }
    if params.count == 0 {
        return Err(Error::invalid("spin count", "must be at least 1"));
    }
    let step = 2.0 * PI / params.count as f64;
    let mut out = vec![0.0];
    let mut k = 1;
    while out.len() < params.count {
        out.push(k as f64 * step);
        if out.len() < params.count {
            out.push(-(k as f64) * step);
        }
        k += 1;
    }
    Ok(out)
}

/// For the target's tool poses (`tool`: approach, pierce, retract along the axis, base frame,
/// [`crate::pierce::tool_poses`]) and the tool on the flange (`ee_from_tool`, `T_ee_tool`): the spin
/// about the tool axis and the configuration whose approach -> pierce -> retract path passes with
/// the best [`Margins::score`] (the largest worst margin along it). Every spin and every
/// configuration at the approach is tried, the cheap checks first: per spin the inverse
/// kinematics of the three poses (a spin with a pose without any solution fails there, no path
/// stepped), per configuration its solution at the pierce and retract poses (one refused there,
/// out of reach, singular or outside the limits, fails without stepping: its path would pass
/// through that pose), then the path every `line.step_m` ([`check_path`]).
///
/// # Errors
/// As [`check_path`] and [`ik::inverse`]; [`Error::Invalid`] for a non-finite fixed spin or a zero
/// count.
pub fn best_spin(
    arm: &Arm,
    tool: &ToolPoses,
    ee_from_tool: &Isometry3<f64>,
    line: &LineParams,
    spin: &SpinParams,
) -> Result<SpinSearch> {
    best_spin_with(arm, tool, ee_from_tool, line, spin, None, &mut |_| Ok(None))
}

/// [`best_spin`] with two more rules: the candidates whose path passed are taken in order of
/// preference — those of the configuration `prefer` first (e.g. the configuration of the arm's
/// joint state at the shot), then by [`Margins::score`], highest first (ties: the smaller spin,
/// then the configuration nearest the reference) — and `accept` is asked about each in that
/// order until it accepts one (`Ok(None)`); a refusal (`Ok(Some(why))`, e.g. a collision) is added
/// to the failures and the next candidate asked.
///
/// # Errors
/// As [`best_spin`], and any error of `accept`.
pub fn best_spin_with(
    arm: &Arm,
    tool: &ToolPoses,
    ee_from_tool: &Isometry3<f64>,
    line: &LineParams,
    spin: &SpinParams,
    prefer: Option<Branch>,
    accept: &mut dyn FnMut(&SpinChoice) -> Result<Option<String>>,
) -> Result<SpinSearch> {
    let tool_from_ee = ee_from_tool.inverse();
    let mut search =
        SpinSearch { best: None, failures: Vec::new(), passed: 0, ik_poses: 0, paths_checked: 0, accept_calls: 0 };
    let mut passed: Vec<SpinChoice> = Vec::new();
    'spins: for s in spins(spin)? {
        let rz =
            Isometry3::from_parts(Translation3::identity(), UnitQuaternion::from_axis_angle(&Vector3::z_axis(), s));
        let flange_poses = [tool.approach, tool.pierce, tool.retract].map(|t| t * rz * tool_from_ee);
        let mut at_poses: Vec<ik::IkSolutions> = Vec::with_capacity(3);
        for (name, pose) in ["approach", "pierce", "retract"].iter().zip(&flange_poses) {
            let solved = ik::inverse(arm, pose, &line.ik)?;
            search.ik_poses += 1;
            if solved.solutions.is_empty() {
                search.failures.push((
                    s,
                    None,
                    format!("{name} (spin {:.0} deg): {}", s.to_degrees(), solved.reason()),
                ));
                continue 'spins;
            }
            at_poses.push(solved);
        }
        'starts: for start in &at_poses[0].solutions {
            for (name, solved) in ["pierce", "retract"].iter().zip(&at_poses[1..]) {
                // refused there (the whole pose, or this configuration): the path through it fails.
                // A limit is certain only away from the wrist singularity, where joint 6 is not
                // free (it is then chosen differently here and along the path)
                let certain = |r: &&ik::Refusal| {
                    r.branch.is_none_or(|b| b == start.branch)
                        && (line.ik.min_wrist > 0.0 || !matches!(r.reason, Reason::JointLimit { .. }))
                };
                if let Some(r) = solved.refused.iter().find(certain) {
                    search.failures.push((
                        s,
                        Some(start.branch),
                        format!("{} (spin {:.0} deg): at the {name} pose: {}", start.branch, s.to_degrees(), r.reason),
                    ));
                    continue 'starts;
                }
            }
            search.paths_checked += 1;
            let report = check_path(arm, &flange_poses, start, line)?;
            if let Some(f) = &report.failure {
                search.failures.push((
                    s,
                    Some(start.branch),
                    format!("{} (spin {:.0} deg): {f}", start.branch, s.to_degrees()),
                ));
                continue;
            }
            let score = report.min.score(&spin.scale);
            passed.push(SpinChoice { spin_rad: s, flange_poses, start: *start, report, score });
        }
    }
    search.passed = passed.len();
    // stable: equal keys keep the search order (smaller spin, then nearer the reference)
    let steps = |c: &SpinChoice| match (spin.least_motion, line.ik.reference) {
        (true, Some(r)) => {
            let largest = (0..6).map(|k| (c.start.q[k] - r[k]).abs()).fold(0.0, f64::max);
            (largest / MOTION_STEP_RAD).floor() as i64
        }
        _ => 0,
    };
    passed.sort_by(|a, b| {
        let other = |c: &SpinChoice| prefer.is_some_and(|p| p != c.start.branch);
        other(a).cmp(&other(b)).then(steps(a).cmp(&steps(b))).then(b.score.total_cmp(&a.score))
    });
    for choice in passed {
        search.accept_calls += 1;
        match accept(&choice)? {
            None => {
                search.best = Some(choice);
                break;
            }
            Some(why) => search.failures.push((
                choice.spin_rad,
                Some(choice.start.branch),
                format!("{} (spin {:.0} deg): {why}", choice.start.branch, choice.spin_rad.to_degrees()),
            )),
        }
    }
    Ok(search)
}

/// Largest joint move between two consecutive checked points of a report, radians.
pub fn largest_step_rad(report: &LineReport) -> f64 {
    report.samples.windows(2).map(|w| joint_distance(&w[0].q, &w[1].q)).fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spins_start_at_zero_and_alternate() {
        let s = spins(&SpinParams { count: 4, ..SpinParams::default() }).expect("spins");
        assert_eq!(s.len(), 4);
        assert_eq!(s[0], 0.0);
        assert!((s[1] - PI / 2.0).abs() < 1e-15 && (s[2] + PI / 2.0).abs() < 1e-15 && (s[3] - PI).abs() < 1e-15);
        assert!(spins(&SpinParams { count: 0, ..SpinParams::default() }).is_err());
        assert!(spins(&SpinParams { fixed_rad: Some(f64::NAN), ..SpinParams::default() }).is_err());
    }
}
