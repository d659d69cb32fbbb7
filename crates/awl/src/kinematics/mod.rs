//! Arm kinematics: 6R arms as standard Denavit-Hartenberg tables with joint limits, forward
//! kinematics, the closed-form inverse of the arms whose middle three axes are parallel (Universal
//! Robots' e-Series and Techman's TM5/TM12/TM14: [`ik`]), and straight tool lines checked for
//! limits, singularities and joint jumps, with the spin about a piercing axis that keeps the most
//! margin ([`line`]). Built-in tables in [`arms`]; the arm file (`awl-arm/1`) in
//! [`crate::kinematics::arm_file`].
//!
//! Convention: **standard (distal) DH**, as Universal Robots publishes it. Joint `i` (0-based here,
//! 1-based in the vendors' tables) contributes
//! `A_i = Rz(q_i + theta_offset_i) * Tz(d_i) * Tx(a_i) * Rx(alpha_i)`, and
//! `T_base_dh6 = A_0 * A_1 * ... * A_5`; the flange is `T_base_flange = T_base_dh6 * T_dh6_flange`
//! (identity for every built-in arm: their DH frame 6 is the controller's flange / `tool0` frame).
//! `base` is the frame the controller reports TCP poses in. Joint values `q` are the controller's
//! joint angles (radians); metres for lengths.
//!
//! No I/O here: the arm-file reader is [`crate::kinematics::arm_file`].

pub mod arm_file;
pub mod arms;
pub mod collision;
pub mod ik;
pub mod line;

use std::f64::consts::{FRAC_PI_2, PI};

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

use crate::error::{Error, Result};

pub use ik::{Branch, IkParams, IkSolution, IkSolutions, Measure, Measures, Reason, Refusal};
pub use line::{
    FailureKind, LineFailure, LineParams, LineReport, LineSample, Margins, SpinChoice, SpinParams, SpinSearch,
    best_spin, best_spin_with, check_path,
};

/// Six joint values, radians (joint 1 first).
pub type Joints = [f64; 6];

/// One row of a standard DH table (module docs): metres and radians.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DhJoint {
    /// Link length along the new x axis, metres.
    pub a: f64,
    /// Link twist about the new x axis, radians.
    pub alpha: f64,
    /// Link offset along the previous z axis, metres.
    pub d: f64,
    /// Added to the joint value before the rotation about the previous z axis, radians.
    pub theta_offset: f64,
}

impl DhJoint {
    /// `A_i(q)`: the transform from this joint's frame to the previous one, `T_{i-1}_{i}`.
    pub fn transform(&self, q: f64) -> Isometry3<f64> {
        let theta = q + self.theta_offset;
        let rz = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), theta);
        let rx = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), self.alpha);
        let (s, c) = theta.sin_cos();
        Isometry3::from_parts(Translation3::new(self.a * c, self.a * s, self.d), rz * rx)
    }
}

/// A 6R arm: its DH table, joint limits and flange frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Arm {
    /// The arm's name (`ur5e`, `tm5-700`, or the arm file's `name`).
    pub name: String,
    /// Standard DH rows, joint 1 first.
    pub dh: [DhJoint; 6],
    /// Joint limits `[lower, upper]`, radians, `lower < upper`.
    pub limits: [[f64; 2]; 6],
    /// `T_dh6_flange`: the flange in the DH table's last frame (identity for the built-in arms).
    pub dh6_from_flange: Isometry3<f64>,
}

/// Values within this of a multiple of pi/2 are taken as that multiple (tables written with a
/// finite number of digits of pi/2), radians.
pub const RIGHT_ANGLE_SNAP_RAD: f64 = 1e-6;

fn snap_right_angle(v: f64) -> f64 {
    let k = (v / FRAC_PI_2).round();
    if (v - k * FRAC_PI_2).abs() < RIGHT_ANGLE_SNAP_RAD { k * FRAC_PI_2 } else { v }
}

impl Arm {
    /// An arm from its table; twists within [`RIGHT_ANGLE_SNAP_RAD`] of a multiple of pi/2 are made
    /// exact (the closed-form inverse needs exact right angles).
    ///
    /// # Errors
    /// [`Error::Invalid`] naming `dh[i].a` / `alpha` / `d` / `theta_offset` or `limits[i]` for a
    /// non-finite value, a reversed or empty limit, or limits wider than +-4 pi.
    pub fn new(name: &str, dh: [DhJoint; 6], limits: [[f64; 2]; 6], dh6_from_flange: Isometry3<f64>) -> Result<Self> {
        let mut dh = dh;
        for (i, j) in dh.iter_mut().enumerate() {
            for (field, v) in [("a", j.a), ("alpha", j.alpha), ("d", j.d), ("theta_offset", j.theta_offset)] {
                if !v.is_finite() {
                    return Err(Error::invalid(
                        format!("arm `{name}`: dh[{i}].{field}"),
                        format!("must be finite, got {v}"),
                    ));
                }
            }
            j.alpha = snap_right_angle(j.alpha);
            j.theta_offset = snap_right_angle(j.theta_offset);
        }
        for (i, [lo, hi]) in limits.iter().enumerate() {
            let what = format!("arm `{name}`: limits[{i}]");
            if !(lo.is_finite() && hi.is_finite()) {
                return Err(Error::invalid(what, format!("must be finite radians, got [{lo}, {hi}]")));
            }
            if lo >= hi {
                return Err(Error::invalid(
                    what,
                    format!("lower {lo} rad is not below upper {hi} rad (reversed or empty)"),
                ));
            }
            if lo.abs() > 4.0 * PI + 1e-9 || hi.abs() > 4.0 * PI + 1e-9 {
                return Err(Error::invalid(
                    what,
                    format!("[{lo}, {hi}] rad is beyond +-4 pi (+-720 deg): radians expected"),
                ));
            }
        }
        let t = dh6_from_flange.translation.vector;
        if !(t.iter().all(|v| v.is_finite()) && dh6_from_flange.rotation.coords.iter().all(|v| v.is_finite())) {
            return Err(Error::invalid(format!("arm `{name}`: T_dh6_flange"), "must be finite"));
        }
        Ok(Self { name: name.to_string(), dh, limits, dh6_from_flange })
    }

    /// A built-in arm by name, case-insensitive (`ur5e`, `UR5e`, `tm5-700`, `TM5-700`; the
    /// names of [`arms::KNOWN`]).
    ///
    /// # Errors
    /// [`Error::Invalid`] about `robot` listing the known names.
    pub fn by_name(name: &str) -> Result<Self> {
        arms::builtin(name).ok_or_else(|| {
            Error::invalid(
                "robot",
                format!("unknown arm `{name}`; known: {} (or give an arm file)", arms::KNOWN.join(", ")),
            )
        })
    }

    /// `T_base_flange` at joint values `q` (radians). Non-finite `q` gives a non-finite pose.
    pub fn base_from_flange(&self, q: &Joints) -> Isometry3<f64> {
        self.base_from_dh6(q) * self.dh6_from_flange
    }

    /// `T_base_dh6`: the DH table's last frame at `q`.
    pub fn base_from_dh6(&self, q: &Joints) -> Isometry3<f64> {
        self.dh.iter().zip(q).fold(Isometry3::identity(), |acc, (j, &qi)| acc * j.transform(qi))
    }

    /// `T_base_i` for the DH frames 0 (the base, identity) to 6, then the flange (8 frames): the
    /// link frames collision checks place their shapes in.
    pub fn link_frames(&self, q: &Joints) -> [Isometry3<f64>; 8] {
        let mut frames = [Isometry3::identity(); 8];
        for i in 0..6 {
            frames[i + 1] = frames[i] * self.dh[i].transform(q[i]);
        }
        frames[7] = frames[6] * self.dh6_from_flange;
        frames
    }

    /// The centre of [`Self::reach_bound_m`]: `(0, 0, d1)`, base frame, metres (joint 2's height on
    /// joint 1's axis for UR and Techman arms).
    pub fn shoulder(&self) -> Point3<f64> {
        Point3::new(0.0, 0.0, self.dh[0].d)
    }

    /// A distance from [`Self::shoulder`] no joint values put the flange's origin beyond, metres:
    /// `|a1|`, plus `sqrt(a_i^2 + d_i^2)` of rows 2 to 6 (each row moves the frame's origin by
    /// `d_i` along one axis and `a_i` along a perpendicular one), plus `T_dh6_flange`'s offset.
    /// Larger than the reach the vendors state (it ignores the links' directions): a pose beyond
    /// it is out of reach for certain.
    pub fn reach_bound_m(&self) -> f64 {
        self.dh[0].a.abs()
            + self.dh[1..].iter().map(|j| j.a.hypot(j.d)).sum::<f64>()
            + self.dh6_from_flange.translation.vector.norm()
    }

    /// The smallest distance of `q` to a joint limit, radians (negative when outside one).
    pub fn limit_margin_rad(&self, q: &Joints) -> f64 {
        q.iter().zip(&self.limits).map(|(v, [lo, hi])| (v - lo).min(hi - v)).fold(f64::INFINITY, f64::min)
    }

    /// Whether every joint of `q` is within its limits.
    pub fn within_limits(&self, q: &Joints) -> bool {
        self.limit_margin_rad(q) >= 0.0
    }
}

/// `v` moved by whole turns to (-pi, pi].
pub fn wrap_to_pi(v: f64) -> f64 {
    let w = v.rem_euclid(2.0 * PI);
    if w > PI { w - 2.0 * PI } else { w }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_and_snap() {
        assert!((wrap_to_pi(3.0 * PI) - PI).abs() < 1e-12);
        assert!((wrap_to_pi(-PI) - PI).abs() < 1e-12);
        assert!((wrap_to_pi(0.5) - 0.5).abs() < 1e-15);
        // pi/2 written with 8 digits, as tables print it
        let written: f64 = "1.5707963".parse().expect("number");
        assert_eq!(snap_right_angle(written), FRAC_PI_2);
        assert_eq!(snap_right_angle(-written), -FRAC_PI_2);
        assert_eq!(snap_right_angle(0.3), 0.3);
    }

    #[test]
    fn no_joint_values_put_the_flange_beyond_the_reach_bound() {
        for name in arms::KNOWN {
            let arm = Arm::by_name(name).expect(name);
            let bound = arm.reach_bound_m();
            let mut farthest: f64 = 0.0;
            // a deterministic sweep: joints 2 to 4 over a grid, the wrist stretched and folded
            for i in 0..24 {
                for j in 0..24 {
                    for k in 0..8 {
                        let q = [
                            0.3,
                            f64::from(i) * PI / 12.0,
                            f64::from(j) * PI / 12.0 - PI,
                            f64::from(k) * PI / 4.0,
                            1.0,
                            0.2,
                        ];
                        farthest =
                            farthest.max((arm.base_from_flange(&q).translation.vector - arm.shoulder().coords).norm());
                    }
                }
            }
            assert!(farthest <= bound + 1e-12, "{name}: {farthest} > {bound}");
            // and the bound is not loose by more than the wrist offsets (d4, d5, d6 at most)
            let wrist: f64 = arm.dh[3..].iter().map(|j| j.d.abs()).sum();
            assert!(bound - farthest < wrist, "{name}: {farthest} vs {bound}");
        }
        // UR5e: 0.425 + 0.3922 + 0.1333 + 0.0997 + 0.0996 m
        assert!((Arm::by_name("ur5e").expect("ur5e").reach_bound_m() - 1.1498).abs() < 1e-12);
    }

    #[test]
    fn dh_row_matches_its_definition() {
        let j = DhJoint { a: 0.3, alpha: 0.7, d: 0.2, theta_offset: 0.1 };
        let q = 0.4;
        let rz = Isometry3::rotation(Vector3::z() * (q + 0.1));
        let expected = rz
            * Isometry3::translation(0.0, 0.0, 0.2)
            * Isometry3::translation(0.3, 0.0, 0.0)
            * Isometry3::rotation(Vector3::x() * 0.7);
        let (dt, dr) = crate::transform::pose_difference(&j.transform(q), &expected);
        assert!(dt < 1e-15 && dr < 1e-15, "{dt} {dr}");
    }
}
