//! Relative motions of pose pairs and the small SO(3) helpers the solvers share.

use nalgebra::{Isometry3, Matrix3, Vector3};

use crate::error::{Error, Result};
use crate::handeye::HandEyePose;

/// One relative motion of a pose pair `i < j`: `a * X = X * b`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Motion {
    /// `ee_j_from_ee_i = base_from_ee_j^-1 * base_from_ee_i`.
    pub a: Isometry3<f64>,
    /// `cam_j_from_cam_i = camera_from_target_j * camera_from_target_i^-1`.
    pub b: Isometry3<f64>,
}

/// The motions of all pairs `i < j` of `poses`, in lexicographic order (OpenCV's pairs and
/// directions, so the closed forms match `cv2.calibrateHandEye` to rounding).
pub(crate) fn all_pairs(poses: &[HandEyePose]) -> Vec<Motion> {
    let mut motions = Vec::with_capacity(poses.len() * poses.len().saturating_sub(1) / 2);
    for (i, pi) in poses.iter().enumerate() {
        for pj in &poses[i + 1..] {
            motions.push(Motion {
                a: pj.base_from_ee.inverse() * pi.base_from_ee,
                b: pj.camera_from_target * pi.camera_from_target.inverse(),
            });
        }
    }
    motions
}

pub(crate) use crate::transform::skew;

/// The least-squares translation shared by Park-Martin and Tsai-Lenz: `(R_A - I) t = R_X t_B - t_A`
/// over all motions, solved by SVD of the stacked system.
///
/// # Errors
/// [`Error::Invalid`] when the system is rank-deficient (every motion rotates about one axis).
pub(crate) fn translation_least_squares(
    motions: &[Motion],
    rotation: &nalgebra::UnitQuaternion<f64>,
) -> Result<Vector3<f64>> {
    let n = motions.len();
    let mut c = nalgebra::DMatrix::<f64>::zeros(3 * n, 3);
    let mut d = nalgebra::DVector::<f64>::zeros(3 * n);
    for (k, m) in motions.iter().enumerate() {
        let block = m.a.rotation.to_rotation_matrix().into_inner() - Matrix3::identity();
        let rhs = rotation * m.b.translation.vector - m.a.translation.vector;
        c.view_mut((3 * k, 0), (3, 3)).copy_from(&block);
        d.rows_mut(3 * k, 3).copy_from(&rhs);
    }
    let svd = c.svd(true, true);
    let s = &svd.singular_values;
    let (max, min) = (s.max(), s.min());
    if min.is_nan() || min <= 1e-9 * max.max(1e-300) {
        return Err(Error::invalid(
            "poses",
            "degenerate motion: the translation is unobservable (all relative rotations share one axis)",
        ));
    }
    let t = svd.solve(&d, 0.0).map_err(|m| Error::invalid("poses", format!("translation least squares: {m}")))?;
    Ok(Vector3::new(t[0], t[1], t[2]))
}
