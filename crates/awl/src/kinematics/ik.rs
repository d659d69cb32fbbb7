//! Closed-form inverse kinematics of the 6R arms whose joints 2, 3 and 4 are parallel and whose
//! wrist axes meet at right angles (UR and Techman; [`structure`] says which tables qualify).
//!
//! With `theta_i = q_i + theta_offset_i` and the wrist point `p5 = p6 - d6 * z6` (frame 5's
//! origin, on joint 6's axis):
//! - **shoulder** (joint 1): `p5` stays at `D = d2 + d3 + d4` from the plane through joint 1's
//!   axis normal to joint 2's axis, so `r sin(theta1 - phi) = D sin(alpha1)` (`r`, `phi`: `p5` in
//!   polar form about joint 1's axis): two roots, branch `+1` = `phi + asin`, `-1` = `phi + pi - asin`;
//! - **wrist** (joint 5): `z6 . z1 = -sin(alpha4) sin(alpha5) cos(theta5)`: `+-acos`, branch = the
//!   sign of `sin(theta5)`; joint 6 from `z1` seen in the flange frame;
//! - **elbow** (joints 2-4): the planar two-link problem in frame 1, branch = the sign of
//!   `sin(theta3)`; joint 4 closes the rotation.
//!
//! That is up to 8 solutions. Singularity measures: wrist `|sin(theta5)|` (joints 4 and 6 aligned
//! at 0), elbow `|sin(theta3)|` (arm stretched or folded at 0), shoulder: the distance of the
//! wrist point from the plane through joint 1's axis parallel to joint 2's axis, metres,
//! `sqrt(r^2 - D^2)` (for `D = 0`, the wrist point's distance from joint 1's axis; at 0 the two
//! shoulder roots meet).

use std::f64::consts::{FRAC_PI_2, PI};
use std::fmt;

use nalgebra::{Isometry3, Vector3};

use super::{Arm, Joints, wrap_to_pi};
use crate::error::{Error, Result};

/// The configuration of a solution: signs +1 / -1 (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Branch {
    /// +1: `theta1 = phi + asin(..)`, -1: `phi + pi - asin(..)`.
    pub shoulder: i8,
    /// Sign of `sin(theta3)` (+1 when 0).
    pub elbow: i8,
    /// Sign of `sin(theta5)` (+1 when 0).
    pub wrist: i8,
}

impl fmt::Display for Branch {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = |v: i8| if v >= 0 { '+' } else { '-' };
        write!(f, "shoulder {} elbow {} wrist {}", s(self.shoulder), s(self.elbow), s(self.wrist))
    }
}

/// A singularity measure (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Measure {
    /// `|sin(theta5)|`, unitless.
    Wrist,
    /// `|sin(theta3)|`, unitless.
    Elbow,
    /// The wrist point's distance from the plane through joint 1's axis parallel to joint 2's
    /// axis, metres.
    Shoulder,
}

impl Measure {
    /// How the measure is named in messages.
    pub fn name(self) -> &'static str {
        match self {
            Measure::Wrist => "wrist singularity |sin q5|",
            Measure::Elbow => "elbow singularity |sin q3|",
            Measure::Shoulder => {
                "shoulder singularity (wrist point's distance from the plane of joint 1's axis and joint 2's direction, m)"
            }
        }
    }
}

/// The three singularity measures of one solution.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measures {
    /// `|sin(theta5)|`, unitless, 0 = singular.
    pub wrist: f64,
    /// `|sin(theta3)|`, unitless, 0 = singular.
    pub elbow: f64,
    /// Shoulder distance, metres, 0 = singular.
    pub shoulder_m: f64,
}

/// Why a configuration was not returned.
#[derive(Debug, Clone, PartialEq)]
pub enum Reason {
    /// The pose is out of the arm's reach (the message says which part).
    OutOfReach(String),
    /// A singularity measure is below its minimum.
    Singular {
        /// Which measure.
        measure: Measure,
        /// Its value (unitless or metres, as the measure).
        value: f64,
        /// The minimum it had to reach.
        min: f64,
    },
    /// No whole-turn alias of a joint is within its limits.
    JointLimit {
        /// The joint, 1-based.
        joint: usize,
        /// The joint's value in (-pi, pi], radians.
        q_rad: f64,
        /// The limits, radians.
        limits: [f64; 2],
    },
}

impl fmt::Display for Reason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Reason::OutOfReach(m) => write!(f, "out of reach: {m}"),
            Reason::Singular { measure, value, min } => {
                write!(f, "near a singularity: {} = {value:.4} is below the minimum {min}", measure.name())
            }
            Reason::JointLimit { joint, q_rad, limits } => write!(
                f,
                "joint {joint} at {:.2} deg has no whole-turn alias within its limits [{:.1}, {:.1}] deg",
                q_rad.to_degrees(),
                limits[0].to_degrees(),
                limits[1].to_degrees()
            ),
        }
    }
}

/// A configuration that was not returned, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct Refusal {
    /// The configuration, when the reason belongs to one (`None`: the whole pose).
    pub branch: Option<Branch>,
    /// Why.
    pub reason: Reason,
}

/// One inverse-kinematics solution.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IkSolution {
    /// Joint values within the limits, radians (the whole-turn alias nearest the reference).
    pub q: Joints,
    /// Its configuration.
    pub branch: Branch,
    /// Its singularity measures.
    pub measures: Measures,
    /// The smallest distance of a joint to its limit, radians.
    pub limit_margin_rad: f64,
}

/// The solutions of one pose, and the configurations refused.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct IkSolutions {
    /// The solutions (at most 8; at singular poses those within [`DUPLICATE_RAD`] of each other
    /// merged), nearest the reference first when one was given.
    pub solutions: Vec<IkSolution>,
    /// What was refused (out of reach, near-singular, outside the limits).
    pub refused: Vec<Refusal>,
}

impl IkSolutions {
    /// The solution of `branch`, if returned.
    pub fn of_branch(&self, branch: Branch) -> Option<&IkSolution> {
        self.solutions.iter().find(|s| s.branch == branch)
    }

    /// Why nothing was returned: each distinct reason once (empty when solutions exist).
    pub fn reason(&self) -> String {
        if !self.solutions.is_empty() {
            return String::new();
        }
        let mut lines: Vec<String> = Vec::new();
        for r in &self.refused {
            let line = r.reason.to_string();
            if !lines.contains(&line) {
                lines.push(line);
            }
        }
        lines.join("; ")
    }
}

/// Settings of [`inverse`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IkParams {
    /// Solutions with `|sin(theta5)|` below this are refused. Default 0.05 (about 2.9 deg from
    /// the wrist singularity).
    pub min_wrist: f64,
    /// Solutions with `|sin(theta3)|` below this are refused. Default 0.05.
    pub min_elbow: f64,
    /// Solutions whose shoulder measure is below this are refused, metres. Default 0.02.
    pub min_shoulder_m: f64,
    /// Joint values the whole-turn aliases are chosen nearest to, and the solutions sorted by
    /// (largest joint difference); `None`: aliases nearest 0, solutions in branch order.
    pub reference: Option<Joints>,
}

impl Default for IkParams {
    fn default() -> Self {
        Self { min_wrist: 0.05, min_elbow: 0.05, min_shoulder_m: 0.02, reference: None }
    }
}

impl IkParams {
    /// No singularity refused (every solution returned, e.g. to count them at a singular pose).
    pub fn no_refusal() -> Self {
        Self { min_wrist: 0.0, min_elbow: 0.0, min_shoulder_m: 0.0, reference: None }
    }

    fn validate(&self) -> Result<()> {
        for (name, v) in
            [("min_wrist", self.min_wrist), ("min_elbow", self.min_elbow), ("min_shoulder_m", self.min_shoulder_m)]
        {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::invalid(name, format!("must be a finite value >= 0, got {v}")));
            }
        }
        if let Some(r) = self.reference
            && r.iter().any(|v| !v.is_finite())
        {
            return Err(Error::invalid("reference", format!("joint values must be finite, got {r:?}")));
        }
        Ok(())
    }
}

/// The signs of the structure's right angles and the offsets the closed form needs.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Structure {
    s1: f64,
    s4: f64,
    s5: f64,
    lateral: f64,
}

/// Whether the arm has the structure this closed form solves: `a1 = a4 = a5 = a6 = 0`,
/// `alpha2 = alpha3 = alpha6 = 0`, `alpha1, alpha4, alpha5 = +-pi/2`, `a2, a3 != 0`.
///
/// # Errors
/// [`Error::Invalid`] naming the first DH entry that breaks it.
pub fn structure(arm: &Arm) -> Result<()> {
    structure_of(arm).map(|_| ())
}

pub(crate) fn structure_of(arm: &Arm) -> Result<Structure> {
    let dh = &arm.dh;
    let fail = |field: String, need: &str, got: f64| {
        Error::invalid(
            format!("arm `{}`: {field}", arm.name),
            format!("is {got}; the closed-form inverse kinematics needs {need} (a UR / Techman-like arm)"),
        )
    };
    for i in [0, 3, 4, 5] {
        if dh[i].a != 0.0 {
            return Err(fail(format!("dh[{i}].a"), "0", dh[i].a));
        }
    }
    for i in [1, 2, 5] {
        if dh[i].alpha != 0.0 {
            return Err(fail(format!("dh[{i}].alpha"), "0", dh[i].alpha));
        }
    }
    for i in [0, 3, 4] {
        if dh[i].alpha.abs() != FRAC_PI_2 {
            return Err(fail(format!("dh[{i}].alpha"), "+-pi/2", dh[i].alpha));
        }
    }
    for i in [1, 2] {
        if dh[i].a == 0.0 {
            return Err(fail(format!("dh[{i}].a"), "a non-zero length", 0.0));
        }
    }
    Ok(Structure {
        s1: dh[0].alpha.signum(),
        s4: dh[3].alpha.signum(),
        s5: dh[4].alpha.signum(),
        lateral: dh[1].d + dh[2].d + dh[3].d,
    })
}

/// A closed-form solution before limits: joint values in (-pi, pi].
#[derive(Debug, Clone, Copy)]
pub(crate) struct Raw {
    pub(crate) q: Joints,
    pub(crate) branch: Branch,
    pub(crate) measures: Measures,
}

const REACH_SLACK: f64 = 1e-10;

/// Solutions nearer than this (largest joint difference) are one, radians.
pub const DUPLICATE_RAD: f64 = 1e-6;

/// Every closed-form solution of `base_from_flange`, and the out-of-reach reasons of the
/// configurations that have none. At the wrist singularity (joints 4 and 6 aligned) the solutions
/// are a family; the one with `q6 = q6_if_free` is returned.
pub(crate) fn raw_solutions(
    arm: &Arm,
    base_from_flange: &Isometry3<f64>,
    q6_if_free: f64,
) -> Result<(Vec<Raw>, Vec<Refusal>)> {
    raw_solutions_of(arm, base_from_flange, q6_if_free, None)
}

/// [`raw_solutions`] of the configuration `only` (all when `None`): the same values, bit for bit,
/// a quarter of the work for one (a path following its configuration).
pub(crate) fn raw_solutions_of(
    arm: &Arm,
    base_from_flange: &Isometry3<f64>,
    q6_if_free: f64,
    only: Option<Branch>,
) -> Result<(Vec<Raw>, Vec<Refusal>)> {
    let st = structure_of(arm)?;
    let finite = base_from_flange
        .translation
        .vector
        .iter()
        .chain(base_from_flange.rotation.coords.iter())
        .all(|v| v.is_finite());
    if !finite {
        return Err(Error::invalid("base_from_flange", "the pose has a non-finite value"));
    }
    let dh = &arm.dh;
    let w = base_from_flange * arm.dh6_from_flange.inverse();
    let z6 = w.rotation * Vector3::z();
    let p5 = w.translation.vector - z6 * dh[5].d;
    let r = p5.x.hypot(p5.y);
    let phi = p5.y.atan2(p5.x);
    let mut out = Vec::with_capacity(8);
    let mut refused = Vec::new();
    let lateral = st.lateral;
    if r + REACH_SLACK < lateral.abs() {
        refused.push(Refusal {
            branch: None,
            reason: Reason::OutOfReach(format!(
                "the wrist point is {r:.4} m from joint 1's axis, inside the arm's {:.4} m shoulder offset",
                lateral.abs()
            )),
        });
        return Ok((out, refused));
    }
    let k = if r < 1e-12 { 0.0 } else { (lateral * st.s1 / r).clamp(-1.0, 1.0) };
    let shoulder_m = (r * r - lateral * lateral).max(0.0).sqrt();
    let (a2, a3) = (dh[1].a, dh[2].a);
    for shoulder in [1i8, -1] {
        if only.is_some_and(|b| b.shoulder != shoulder) {
            continue;
        }
        let theta1 = if shoulder > 0 { phi + k.asin() } else { phi + PI - k.asin() };
        let (s_1, c_1) = theta1.sin_cos();
        let z1 = Vector3::new(st.s1 * s_1, -st.s1 * c_1, 0.0);
        // cos from the dot product, |sin| from the cross product: exact near theta5 = 0 or pi,
        // where acos alone would lose half the digits (and joint 6 would follow the noise)
        let c5 = -(z6.dot(&z1)) * st.s4 * st.s5;
        let s5_abs = z6.cross(&z1).norm();
        let z1_in_6 = w.rotation.inverse() * z1;
        for wrist in [1i8, -1] {
            if only.is_some_and(|b| b.wrist != wrist) {
                continue;
            }
            let theta5 = (f64::from(wrist) * s5_abs).atan2(c5);
            let s_5 = theta5.sin();
            let theta6 = if s_5.abs() < 1e-12 {
                q6_if_free + dh[5].theta_offset
            } else {
                let g = st.s4 * s_5.signum();
                (-z1_in_6.y * g).atan2(z1_in_6.x * g)
            };
            let q1 = theta1 - dh[0].theta_offset;
            let q5 = theta5 - dh[4].theta_offset;
            let q6 = theta6 - dh[5].theta_offset;
            let t14 = dh[0].transform(q1).inverse() * w * dh[5].transform(q6).inverse() * dh[4].transform(q5).inverse();
            let p = t14.translation.vector;
            let c3 = (p.x * p.x + p.y * p.y - a2 * a2 - a3 * a3) / (2.0 * a2 * a3);
            if c3.abs() > 1.0 + REACH_SLACK {
                let need = p.x.hypot(p.y);
                let message = format!(
                    "the wrist needs {need:.4} m between joints 2 and 4, the arm spans {:.4}-{:.4} m",
                    (a2.abs() - a3.abs()).abs(),
                    a2.abs() + a3.abs()
                );
                for elbow in [1i8, -1] {
                    if only.is_some_and(|b| b.elbow != elbow) {
                        continue;
                    }
                    let branch = Some(Branch { shoulder, elbow, wrist });
                    refused.push(Refusal { branch, reason: Reason::OutOfReach(message.clone()) });
                }
                continue;
            }
            let c3 = c3.clamp(-1.0, 1.0);
            let x4 = t14.rotation * Vector3::x();
            let theta234 = x4.y.atan2(x4.x);
            for elbow in [1i8, -1] {
                if only.is_some_and(|b| b.elbow != elbow) {
                    continue;
                }
                let theta3 = f64::from(elbow) * c3.acos();
                let (s_3, c_3) = theta3.sin_cos();
                let theta2 = p.y.atan2(p.x) - (a3 * s_3).atan2(a2 + a3 * c_3);
                let theta4 = theta234 - theta2 - theta3;
                let q =
                    [q1, theta2 - dh[1].theta_offset, theta3 - dh[2].theta_offset, theta4 - dh[3].theta_offset, q5, q6]
                        .map(wrap_to_pi);
                out.push(Raw {
                    q,
                    branch: Branch { shoulder, elbow, wrist },
                    measures: Measures { wrist: s_5.abs(), elbow: s_3.abs(), shoulder_m },
                });
            }
        }
    }
    Ok((out, refused))
}

/// The whole-turn alias of `v` within `[lo, hi]` nearest `near`, if any.
pub(crate) fn alias_within(v: f64, near: f64, [lo, hi]: [f64; 2]) -> Option<f64> {
    let turns = ((near - v) / (2.0 * PI)).round();
    let candidates = [turns - 1.0, turns, turns + 1.0].map(|k| v + k * 2.0 * PI);
    let mut best: Option<f64> = None;
    for c in candidates {
        if c >= lo && c <= hi && best.is_none_or(|b| (c - near).abs() < (b - near).abs()) {
            best = Some(c);
        }
    }
    if best.is_none() {
        // far references: any alias within the limits, nearest the reference
        let mut k = ((lo - v) / (2.0 * PI)).ceil();
        while v + k * 2.0 * PI <= hi {
            let c = v + k * 2.0 * PI;
            if best.is_none_or(|b| (c - near).abs() < (b - near).abs()) {
                best = Some(c);
            }
            k += 1.0;
        }
    }
    best
}

/// The refusal of a singular solution, if a measure is below its minimum.
pub(crate) fn singular(m: &Measures, p: &IkParams) -> Option<Reason> {
    [
        (Measure::Wrist, m.wrist, p.min_wrist),
        (Measure::Elbow, m.elbow, p.min_elbow),
        (Measure::Shoulder, m.shoulder_m, p.min_shoulder_m),
    ]
    .into_iter()
    .find(|(_, value, min)| value < min)
    .map(|(measure, value, min)| Reason::Singular { measure, value, min })
}

/// Largest joint difference between two joint vectors, radians.
pub fn joint_distance(a: &Joints, b: &Joints) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
}

/// Every inverse-kinematics solution of `base_from_flange` (the flange pose in the base frame):
/// the configurations within the joint limits and away from the singularities, the others
/// refused with their reason. A pose out of reach gives no solutions and its reason
/// ([`IkSolutions::reason`]). At the wrist singularity (`sin(theta5) = 0`: joints 4 and 6
/// aligned) each configuration is a family of solutions; the one with joint 6 at the reference's
/// (else 0) is returned.
///
/// # Errors
/// [`Error::Invalid`] for an arm without the structure ([`structure`]), a non-finite pose, or bad
/// parameters.
pub fn inverse(arm: &Arm, base_from_flange: &Isometry3<f64>, params: &IkParams) -> Result<IkSolutions> {
    params.validate()?;
    let q6_if_free = params.reference.map_or(0.0, |r| r[5]);
    let (raw, mut refused) = raw_solutions(arm, base_from_flange, q6_if_free)?;
    let mut solutions: Vec<IkSolution> = Vec::with_capacity(raw.len());
    'next: for r in raw {
        if let Some(reason) = singular(&r.measures, params) {
            refused.push(Refusal { branch: Some(r.branch), reason });
            continue;
        }
        let near = params.reference.unwrap_or([0.0; 6]);
        let mut q = [0.0; 6];
        for j in 0..6 {
            match alias_within(r.q[j], near[j], arm.limits[j]) {
                Some(v) => q[j] = v,
                None => {
                    let reason = Reason::JointLimit { joint: j + 1, q_rad: r.q[j], limits: arm.limits[j] };
                    refused.push(Refusal { branch: Some(r.branch), reason });
                    continue 'next;
                }
            }
        }
        // singular poses give the same joints on two branches: keep the first. 1e-6 rad, as at
        // the stretched elbow theta3 = +-acos(1 - 1e-16) = +-1.5e-8 (the pose fixes it no better)
        if solutions.iter().any(|s| joint_distance(&s.q, &q) < DUPLICATE_RAD) {
            continue;
        }
        solutions.push(IkSolution {
            q,
            branch: r.branch,
            measures: r.measures,
            limit_margin_rad: arm.limit_margin_rad(&q),
        });
    }
    if let Some(reference) = params.reference {
        solutions.sort_by(|a, b| joint_distance(&a.q, &reference).total_cmp(&joint_distance(&b.q, &reference)));
    }
    Ok(IkSolutions { solutions, refused })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_configuration_is_solved_bit_for_bit_as_among_all() {
        for name in ["ur5e", "tm5-700"] {
            let arm = Arm::by_name(name).expect(name);
            for k in 0..50 {
                let t = f64::from(k);
                let q = [0.1 * t, -1.0 + 0.05 * t, 0.02 * t - 0.5, 0.3 - 0.04 * t, 0.5 + 0.07 * t, -0.03 * t];
                // poses within reach, and past it (stretched 1.6 times from the shoulder)
                let mut far = arm.base_from_flange(&q);
                far.translation.vector *= 1.6;
                for pose in [arm.base_from_flange(&q), far] {
                    let (all, all_refused) = raw_solutions(&arm, &pose, 0.4).expect("raw");
                    for shoulder in [1i8, -1] {
                        for elbow in [1i8, -1] {
                            for wrist in [1i8, -1] {
                                let b = Branch { shoulder, elbow, wrist };
                                let (one, refused) = raw_solutions_of(&arm, &pose, 0.4, Some(b)).expect("raw");
                                let mine: Vec<_> = all.iter().filter(|r| r.branch == b).collect();
                                assert_eq!(one.len(), mine.len());
                                for (x, y) in one.iter().zip(mine) {
                                    assert_eq!((x.q, x.measures), (y.q, y.measures));
                                }
                                let theirs: Vec<_> =
                                    all_refused.iter().filter(|r| r.branch.is_none_or(|c| c == b)).collect();
                                assert_eq!(refused.iter().collect::<Vec<_>>(), theirs);
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn aliases_fit_limits_and_prefer_the_reference() {
        let lim = [-2.0 * PI, 2.0 * PI];
        assert!((alias_within(3.0, 0.0, lim).expect("in") - 3.0).abs() < 1e-15);
        assert!((alias_within(3.0, -3.0, lim).expect("in") - (3.0 - 2.0 * PI)).abs() < 1e-12);
        assert_eq!(alias_within(3.0, 0.0, [-1.0, 1.0]), None);
        let v = alias_within(-3.0, 0.0, [0.0, 4.0]).expect("alias");
        assert!((v - (2.0 * PI - 3.0)).abs() < 1e-12);
        // a reference many turns away still finds the alias within the limits
        let v = alias_within(0.5, 40.0, lim).expect("alias");
        assert!((v - 0.5).abs() < 1e-12, "{v}"); // 0.5 + 2 pi is past 2 pi
        let v = alias_within(-0.5, 40.0, lim).expect("alias");
        assert!((v - (2.0 * PI - 0.5)).abs() < 1e-12, "{v}");
    }
}
