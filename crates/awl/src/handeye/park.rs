//! Park & Martin (1994), "Robot sensor calibration: solving AX = XB on the Euclidean group".
//!
//! With `alpha = log(R_A)` and `beta = log(R_B)` (rotation vectors), `R_X beta = alpha` for every
//! motion; the rotation minimising `sum |alpha - R_X beta|^2` is the Kabsch solution of
//! `M = sum beta alpha^T` (equal to Park's `(M^T M)^-1/2 M^T` when `M` has full rank, and still
//! defined when the axes only span a plane). The translation follows by linear least squares.

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion};

use crate::error::{Error, Result};
use crate::handeye::motion::{Motion, translation_least_squares};

/// The rotation `R` minimising `sum |p_k - R q_k|^2` over pairs `(p_k, q_k)`, given `h = sum q_k p_k^T`.
pub(crate) fn kabsch(h: &Matrix3<f64>) -> Result<UnitQuaternion<f64>> {
    let svd = h.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err(Error::invalid("poses", "rotation SVD failed"));
    };
    let v = v_t.transpose();
    let mut d = Matrix3::identity();
    if (v * u.transpose()).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = v * d * u.transpose();
    Ok(UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)))
}

/// `ee_from_camera` by Park-Martin over `motions`.
///
/// # Errors
/// [`Error::Invalid`] when the motions do not determine the rotation or the translation.
pub(crate) fn solve(motions: &[Motion]) -> Result<Isometry3<f64>> {
    let mut h = Matrix3::zeros();
    for m in motions {
        h += m.b.rotation.scaled_axis() * m.a.rotation.scaled_axis().transpose();
    }
    let rotation = kabsch(&h)?;
    let t = translation_least_squares(motions, &rotation)?;
    Ok(Isometry3::from_parts(Translation3::from(t), rotation))
}
