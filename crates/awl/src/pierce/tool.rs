//! Tool poses along a piercing axis, and the pose encodings robot controllers take.
//!
//! The tool frame's z axis is the piercing direction (into the surface); its x axis is the base's x
//! projected onto the plane normal to z (the base's y when the axis is within 25 degrees of x), so a
//! target gets the same tool roll whatever the workpiece's pose; y = z x x. Along the axis:
//! approach = `approach_m` before the surface point, pierce = `depth_m` past it, retract = back
//! out to `retract_m` before it.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::error::{Error, Result};

pub use crate::kinematics::line::ToolPoses;

/// The distances along the axis, metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stroke {
    /// Approach stand-off before the surface. Default 0.10.
    pub approach_m: f64,
    /// Piercing depth past the surface. Default 0.01.
    pub depth_m: f64,
    /// Retract stand-off before the surface. Default 0.10.
    pub retract_m: f64,
    /// The deepest `depth_m` accepted: [`MAX_DEPTH_M`] (a piercing depth of a few centimetres), up to
    /// [`MAX_REACH_M`] for a user who asks for long moves (`--allow-long-moves`). Default [`MAX_DEPTH_M`].
    pub max_depth_m: f64,
}

/// The deepest piercing by default, metres: a few centimetres past the surface.
pub const MAX_DEPTH_M: f64 = 0.05;

/// An arm's reach, metres (the largest built-in arm, UR20/UR30, reaches 1.75 m; 2 m leaves a margin):
/// no stand-off, depth or tool position in the base frame may be farther.
pub const MAX_REACH_M: f64 = 2.0;

impl Default for Stroke {
    fn default() -> Self {
        Self { approach_m: 0.10, depth_m: 0.01, retract_m: 0.10, max_depth_m: MAX_DEPTH_M }
    }
}

impl Stroke {
    /// Checks the distances: finite, non-negative, stand-offs within [`MAX_REACH_M`], the depth
    /// within `max_depth_m` (itself at most [`MAX_REACH_M`]).
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the field (`approach_m`, `depth_m`, `retract_m`, `max_depth_m`) for a
    /// negative, non-finite or out-of-range distance, with the limit and how to raise it.
    pub fn validate(&self) -> Result<()> {
        let fields = [
            ("approach_m", self.approach_m, MAX_REACH_M),
            ("retract_m", self.retract_m, MAX_REACH_M),
            ("max_depth_m", self.max_depth_m, MAX_REACH_M),
            ("depth_m", self.depth_m, self.max_depth_m),
        ];
        for (name, v, max) in fields {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::invalid(name, format!("must be a non-negative length in metres, got {v}")));
            }
            if v > max && name == "depth_m" {
                return Err(Error::invalid(
                    name,
                    format!(
                        "{v} m is deeper than the {max} m a piercing goes at most (a few centimetres); \
                         allow_long_moves (--allow-long-moves) raises the limit to {MAX_REACH_M} m"
                    ),
                ));
            }
            if v > max {
                return Err(Error::invalid(name, format!("{v} m is beyond an arm's {max} m reach")));
            }
        }
        Ok(())
    }

    /// `self` with the depth limit raised to [`MAX_REACH_M`] (`--allow-long-moves`).
    pub fn allowing_long_moves(self) -> Self {
        Self { max_depth_m: MAX_REACH_M, ..self }
    }
}

/// The tool orientation for piercing along `axis` (module docs).
///
/// # Errors
/// [`Error::Invalid`] for a zero or non-finite axis.
pub fn tool_rotation(axis: &Vector3<f64>) -> Result<UnitQuaternion<f64>> {
    let z = axis
        .try_normalize(1e-12)
        .filter(|z| z.iter().all(|v| v.is_finite()))
        .ok_or_else(|| Error::invalid("axis", format!("not a direction: {axis:?}")))?;
    let reference = if z.x.abs() < 25f64.to_radians().cos() { Vector3::x() } else { Vector3::y() };
    let x = (reference - z * reference.dot(&z)).normalize();
    let y = z.cross(&x);
    Ok(UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]))))
}

/// Approach, pierce and retract poses for the surface point `p` and piercing direction `axis`.
///
/// # Errors
/// [`Error::Invalid`] for a bad axis or stroke.
pub fn tool_poses(p: &Point3<f64>, axis: &Vector3<f64>, stroke: &Stroke) -> Result<ToolPoses> {
    stroke.validate()?;
    let rotation = tool_rotation(axis)?;
    let z = rotation * Vector3::z();
    let at = |offset: f64| Isometry3::from_parts(Translation3::from(p.coords + z * offset), rotation);
    Ok(ToolPoses { approach: at(-stroke.approach_m), pierce: at(stroke.depth_m), retract: at(-stroke.retract_m) })
}

/// The rotation as a quaternion `[x, y, z, w]` with `w >= 0`.
pub fn quaternion_xyzw(rotation: &UnitQuaternion<f64>) -> [f64; 4] {
    let q = rotation.quaternion();
    let s = if q.w < 0.0 { -1.0 } else { 1.0 };
    [q.i * s, q.j * s, q.k * s, q.w * s]
}

/// A pose as Universal Robots' `p[x, y, z, rx, ry, rz]`: metres and a rotation vector (axis times
/// angle, radians, angle in [0, pi]).
pub fn ur_pose(pose: &Isometry3<f64>) -> [f64; 6] {
    let t = pose.translation.vector;
    let r = pose.rotation.scaled_axis();
    [t.x, t.y, t.z, r.x, r.y, r.z]
}

/// A pose as Techman's `x, y, z, rx, ry, rz`: millimetres and fixed-axis angles in degrees,
/// `R = Rz(rz) Ry(ry) Rx(rx)` (the TM driver's convention, ROS roll-pitch-yaw).
pub fn tm_pose(pose: &Isometry3<f64>) -> [f64; 6] {
    let t = pose.translation.vector * 1e3;
    let (rx, ry, rz) = pose.rotation.euler_angles();
    [t.x, t.y, t.z, rx.to_degrees(), ry.to_degrees(), rz.to_degrees()]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tool_z_is_the_axis_and_the_stroke_runs_along_it() {
        let p = Point3::new(0.8, -0.1, 0.3);
        for axis in [Vector3::new(0.0, 0.0, -1.0), Vector3::new(0.3, -0.5, -0.8), Vector3::new(-1.0, 0.0, 0.0)] {
            let poses = tool_poses(&p, &axis, &Stroke::default()).expect("poses");
            let n = axis.normalize();
            for pose in [poses.approach, poses.pierce, poses.retract] {
                assert!((pose.rotation * Vector3::z() - n).norm() < 1e-12);
                let x = pose.rotation * Vector3::x();
                assert!(x.dot(&n).abs() < 1e-12);
            }
            assert!((poses.approach.translation.vector - (p.coords - n * 0.10)).norm() < 1e-12);
            assert!((poses.pierce.translation.vector - (p.coords + n * 0.01)).norm() < 1e-12);
            assert_eq!(poses.approach, poses.retract);
        }
        assert!(tool_poses(&p, &Vector3::zeros(), &Stroke::default()).is_err());
        let bad = Stroke { depth_m: -0.01, ..Stroke::default() };
        assert!(tool_poses(&p, &Vector3::z(), &bad).expect_err("an error").to_string().contains("depth_m"));
    }

    #[test]
    fn techman_angles_compose_as_rz_ry_rx_in_degrees_and_millimetres() {
        let (rx, ry, rz) = (25f64, -40f64, 130f64);
        let axis = |v: Vector3<f64>, deg: f64| {
            UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(v), deg.to_radians())
        };
        let r = axis(Vector3::z(), rz) * axis(Vector3::y(), ry) * axis(Vector3::x(), rx);
        let tm = tm_pose(&Isometry3::from_parts(Translation3::new(0.5, -0.25, 0.125), r));
        let expected = [500.0, -250.0, 125.0, rx, ry, rz];
        for (a, b) in tm.iter().zip(expected) {
            assert!((a - b).abs() < 1e-9, "{tm:?} vs {expected:?}");
        }
    }

    #[test]
    fn quaternion_and_ur_rotation_vector_encode_the_same_rotation() {
        let r = UnitQuaternion::from_euler_angles(0.3, -2.9, 1.4);
        let q = quaternion_xyzw(&r);
        assert!(q[3] >= 0.0);
        let back = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[3], q[0], q[1], q[2]));
        assert!(back.angle_to(&r) < 1e-12);
        let pose = Isometry3::from_parts(Translation3::new(0.1, 0.2, 0.3), r);
        let ur = ur_pose(&pose);
        let rv = Vector3::new(ur[3], ur[4], ur[5]);
        assert!(rv.norm() <= std::f64::consts::PI + 1e-12);
        assert!(UnitQuaternion::from_scaled_axis(rv).angle_to(&r) < 1e-12);
        // a half turn about z: UR's rotation vector is (0, 0, pi)
        let half = ur_pose(&Isometry3::rotation(Vector3::z() * std::f64::consts::PI));
        assert!((half[5].abs() - std::f64::consts::PI).abs() < 1e-9);
    }
}
