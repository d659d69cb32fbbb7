//! Tsai & Lenz (1989), "A new technique for fully autonomous and efficient 3D robotics hand/eye
//! calibration", as in OpenCV's `CALIB_HAND_EYE_TSAI`.
//!
//! With the modified Rodrigues vectors `P = 2 sin(angle/2) axis` of `R_A` and `R_B`, every motion gives
//! `[P_A + P_B]x P' = P_B - P_A` where `P' = tan(angle_X/2) axis_X`; the stacked system is solved by
//! least squares and `R_X` is the unit quaternion `(1, P') / |(1, P')|`. The translation then follows
//! from `(R_A - I) t = R_X t_B - t_A`. Accuracy drops as `angle_X` nears 180 degrees.

use nalgebra::{DMatrix, DVector, Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};

use crate::error::{Error, Result};
use crate::handeye::motion::{Motion, skew, translation_least_squares};

/// `2 sin(angle/2) axis` of a rotation (angle in [0, pi]).
fn modified_rodrigues(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    let v = q.imag();
    if q.w < 0.0 { -2.0 * v } else { 2.0 * v }
}

/// `ee_from_camera` by Tsai-Lenz over `motions`.
///
/// # Errors
/// [`Error::Invalid`] when the motions do not determine the rotation or the translation.
pub(crate) fn solve(motions: &[Motion]) -> Result<Isometry3<f64>> {
    let n = motions.len();
    let mut lhs = DMatrix::<f64>::zeros(3 * n, 3);
    let mut rhs = DVector::<f64>::zeros(3 * n);
    for (k, m) in motions.iter().enumerate() {
        let (pa, pb) = (modified_rodrigues(&m.a.rotation), modified_rodrigues(&m.b.rotation));
        lhs.view_mut((3 * k, 0), (3, 3)).copy_from(&skew(&(pa + pb)));
        rhs.rows_mut(3 * k, 3).copy_from(&(pb - pa));
    }
    let svd = lhs.svd(true, true);
    let s = &svd.singular_values;
    if s.min().is_nan() || s.min() <= 1e-9 * s.max().max(1e-300) {
        return Err(Error::invalid("poses", "degenerate motion: the rotation is unobservable (Tsai-Lenz)"));
    }
    let p = svd.solve(&rhs, 0.0).map_err(|m| Error::invalid("poses", format!("Tsai-Lenz rotation: {m}")))?;
    let rotation = UnitQuaternion::from_quaternion(Quaternion::new(1.0, p[0], p[1], p[2]));
    let t = translation_least_squares(motions, &rotation)?;
    Ok(Isometry3::from_parts(Translation3::from(t), rotation))
}
