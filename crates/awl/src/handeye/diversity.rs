//! How diverse the relative rotations are: the rotation of `X` about an axis shared by every motion,
//! and its translation along that axis, cannot be observed.

use nalgebra::{Matrix3, SymmetricEigen};
use serde::Serialize;

use crate::handeye::motion::Motion;

/// Diversity of a set of relative motions (see the module docs of [`crate::handeye`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MotionDiversity {
    /// Pose pairs the closed forms used (all of them up to 447 poses, at most 100 000).
    pub pairs: usize,
    /// Pairs whose arm rotation exceeds `min_pair_angle_deg` (the ones the axes come from).
    pub rotating_pairs: usize,
    /// Largest relative arm rotation over all pairs, degrees.
    pub max_rotation_deg: f64,
    /// `2 asin(sqrt(l2))`, `l2` the middle eigenvalue of the axes' scatter `mean(k k^T)`: the angle
    /// between two equally used rotation axes, 0 when all axes are parallel, degrees.
    pub axis_angle_deg: f64,
    /// `sqrt(l3)` of the smallest eigenvalue: 0 when the axes lie in a plane (harmless), up to
    /// `1/sqrt(3)` for axes spread over every direction.
    pub axis_spread_3d: f64,
}

/// The diversity of `motions`, counting only pairs whose arm rotation exceeds `min_pair_angle_rad`.
pub(crate) fn diversity(motions: &[Motion], min_pair_angle_rad: f64) -> MotionDiversity {
    let mut scatter = Matrix3::zeros();
    let mut rotating = 0usize;
    let mut max_angle = 0.0f64;
    for m in motions {
        let angle = m.a.rotation.angle();
        max_angle = max_angle.max(angle);
        if angle > min_pair_angle_rad
            && let Some(axis) = m.a.rotation.axis()
        {
            scatter += axis.into_inner() * axis.into_inner().transpose();
            rotating += 1;
        }
    }
    let (mut axis_angle_deg, mut axis_spread_3d) = (0.0, 0.0);
    if rotating > 0 {
        let mut l: Vec<f64> = SymmetricEigen::new(scatter / rotating as f64).eigenvalues.iter().copied().collect();
        l.sort_by(f64::total_cmp);
        axis_angle_deg = 2.0 * l[1].clamp(0.0, 1.0).sqrt().asin().to_degrees();
        axis_spread_3d = l[0].max(0.0).sqrt();
    }
    MotionDiversity {
        pairs: motions.len(),
        rotating_pairs: rotating,
        max_rotation_deg: max_angle.to_degrees(),
        axis_angle_deg,
        axis_spread_3d,
    }
}
