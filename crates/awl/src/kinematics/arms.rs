//! The built-in arms: Universal Robots e-Series and Techman TM5-700, TM5-900, TM12, TM14, as
//! standard DH tables (see [`super`]) with the vendors' joint limits.
//!
//! Each table was checked against the vendor's ROS description (its URDF joint chain, transcribed
//! independently in `tests/py/check_kinematics.py`): the DH frame 6 is UR's `tool0` and Techman's
//! `flange` link, within 1e-15 m, at random joint values.

use std::f64::consts::{FRAC_PI_2, PI};

use nalgebra::Isometry3;

use super::{Arm, DhJoint};

/// The built-in names, as [`super::Arm::by_name`] takes them (case-insensitive).
pub const KNOWN: [&str; 10] = ["ur3e", "ur5e", "ur10e", "ur16e", "ur20", "ur30", "tm5-700", "tm5-900", "tm12", "tm14"];

/// A UR table from its six published lengths (metres): every UR has
/// `a = [0, a2, a3, 0, 0, 0]`, `d = [d1, 0, 0, d4, d5, d6]`, `alpha = [pi/2, 0, 0, pi/2, -pi/2, 0]`,
/// no offsets.
fn ur(d1: f64, a2: f64, a3: f64, d4: f64, d5: f64, d6: f64) -> [DhJoint; 6] {
    let row = |a, alpha, d| DhJoint { a, alpha, d, theta_offset: 0.0 };
    [
        row(0.0, FRAC_PI_2, d1),
        row(a2, 0.0, 0.0),
        row(a3, 0.0, 0.0),
        row(0.0, FRAC_PI_2, d4),
        row(0.0, -FRAC_PI_2, d5),
        row(0.0, 0.0, d6),
    ]
}

/// UR e-Series joint limits: +-360 deg on every joint (the e-Series user manuals, "Technical
/// specifications": working range +-360 deg on all joints), except the elbow at +-180 deg:
/// ur_description (`config/*/joint_limits.yaml`) limits it so because the upper arm stops the
/// elbow near +-180 deg anyway; we follow it, as a plan beyond that cannot run.
const UR_LIMITS: [[f64; 2]; 6] = [
    [-2.0 * PI, 2.0 * PI],
    [-2.0 * PI, 2.0 * PI],
    [-PI, PI],
    [-2.0 * PI, 2.0 * PI],
    [-2.0 * PI, 2.0 * PI],
    [-2.0 * PI, 2.0 * PI],
];

/// A Techman table from its published lengths (metres). Techman's URDF chain (tm_description,
/// `xacro/macro.<model>-nominal.urdf.xacro`: joint_1 at z = d1; joint_2 rpy (-90, -90, 0) deg;
/// joint_3 at x = a2; joint_4 at (a3, 0, d4) rpy (0, 0, 90) deg; joint_5 at y = -d5 rpy (90, 0, 0)
/// deg; joint_6 at y = -d6 rpy (90, 0, 0) deg) is, in standard DH:
/// `alpha = [-pi/2, 0, 0, pi/2, pi/2, 0]`, `a = [0, a2, a3, 0, 0, 0]`, `d = [d1, 0, 0, d4, d5, d6]`,
/// `theta_offset = [0, -pi/2, 0, pi/2, 0, 0]`; d4 is negative (the wrist sits behind the arm plane).
fn tm(d1: f64, a2: f64, a3: f64, d4: f64, d5: f64, d6: f64) -> [DhJoint; 6] {
    let row = |a, alpha, d, theta_offset| DhJoint { a, alpha, d, theta_offset };
    [
        row(0.0, -FRAC_PI_2, d1, 0.0),
        row(a2, 0.0, 0.0, -FRAC_PI_2),
        row(a3, 0.0, 0.0, 0.0),
        row(0.0, FRAC_PI_2, d4, FRAC_PI_2),
        row(0.0, FRAC_PI_2, d5, 0.0),
        row(0.0, 0.0, d6, 0.0),
    ]
}

/// Techman joint limits in degrees, the same in tm_description's xacro macros and the TM hardware
/// manuals: J1 +-270, J2 +-180, J3 +-`j3_deg`, J4 +-180, J5 +-180, J6 +-270.
fn tm_limits(j3_deg: f64) -> [[f64; 2]; 6] {
    [270.0, 180.0, j3_deg, 180.0, 180.0, 270.0].map(|v: f64| [-v.to_radians(), v.to_radians()])
}

/// The built-in arm `name` (case-insensitive; `_` may stand for `-`), or `None`.
pub fn builtin(name: &str) -> Option<Arm> {
    let key = name.trim().to_ascii_lowercase().replace('_', "-");
    let (dh, limits) = match key.as_str() {
        // Universal Robots, "DH parameters for calculations of kinematics and dynamics" (UR support
        // article, e-Series section; UR20 and UR30 in its attached files), the same numbers as
        // ur_description's `config/<model>/default_kinematics.yaml` (forearm x = a2, wrist_1 x = a3).
        "ur3e" => (ur(0.15185, -0.24355, -0.2132, 0.13105, 0.08535, 0.0921), UR_LIMITS),
        "ur5e" => (ur(0.1625, -0.425, -0.3922, 0.1333, 0.0997, 0.0996), UR_LIMITS),
        "ur10e" => (ur(0.1807, -0.6127, -0.57155, 0.17415, 0.11985, 0.11655), UR_LIMITS),
        // UR16e: the UR article and ur_description agree (a2 -0.4784, a3 -0.36; the rest as UR10e).
        "ur16e" => (ur(0.1807, -0.4784, -0.36, 0.17415, 0.11985, 0.11655), UR_LIMITS),
        "ur20" => (ur(0.2363, -0.862, -0.7287, 0.201, 0.1593, 0.1543), UR_LIMITS),
        // UR30: ur_description's ur30/default_kinematics.yaml (the UR article gives it in an
        // attachment with the same wrist as the UR20).
        "ur30" => (ur(0.2363, -0.637, -0.5037, 0.201, 0.1593, 0.1543), UR_LIMITS),
        // Techman: tmr_ros2 tm_description `xacro/macro.<model>-nominal.urdf.xacro`, release 1.12.5
        // ("modify TM5-900, TM5-700 series nominal DH parameters"). The sources disagree for the
        // TM5: releases before 1.12.5 (and write-ups copied from them) give d1 0.1451, d4 -0.1222,
        // d6 0.1144 for both TM5 models; 1.12.5 changed them to 0.1452, -0.1223, 0.11315 (d6 as
        // the TM12/TM14 always had). We take 1.12.5. Real arms differ by their factory
        // calibration, which the TM driver can read out.
        "tm5-700" => (tm(0.1452, 0.329, 0.3115, -0.1223, 0.106, 0.11315), tm_limits(155.0)),
        "tm5-900" => (tm(0.1452, 0.429, 0.4115, -0.1223, 0.106, 0.11315), tm_limits(155.0)),
        "tm12" => (tm(0.1652, 0.6361, 0.5579, -0.1563, 0.106, 0.11315), tm_limits(166.0)),
        "tm14" => (tm(0.1652, 0.5361, 0.4579, -0.1563, 0.106, 0.11315), tm_limits(163.0)),
        _ => return None,
    };
    let canonical = KNOWN.iter().find(|k| **k == key).copied().unwrap_or("arm");
    Arm::new(canonical, dh, limits, Isometry3::identity()).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_known_name_builds() {
        for name in KNOWN {
            let arm = builtin(name).expect(name);
            assert_eq!(arm.name, name);
            assert!(builtin(&name.to_uppercase()).is_some());
        }
        assert!(builtin("tm5_700").is_some());
        assert!(builtin("ur5").is_none());
    }
}
