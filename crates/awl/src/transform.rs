//! Rigid transforms: the 4x4 row-major matrices of the file formats <-> `Isometry3<f64>`.
//!
//! In files a transform is `T_a_b` (maps points from frame b into frame a); in code the same
//! transform is named `a_from_b`. Parsing rejects matrices that are not rigid, so the rest of the
//! library can trust every isometry it holds.

use nalgebra::{Isometry3, Matrix3, Matrix4, Matrix6, Rotation3, Translation3, UnitQuaternion, Vector3};

/// Largest deviation from a rigid matrix accepted when parsing (orthonormality, determinant, last row).
pub const RIGID_TOLERANCE: f64 = 1e-6;

/// Largest `|R^T R - I|` that [`isometry_from_rows_reorthonormalised`] replaces by the nearest
/// rotation instead of refusing: the float32 rounding of TF chains and public datasets (a float32
/// rotation written with 7 digits is off by up to ~1e-6, one composed in float32 over a chain, or
/// printed with 4 digits, by up to ~1e-3).
pub const FLOAT32_RIGID_TOLERANCE: f64 = 1e-3;

/// A 4x4 matrix as written in the files: row-major, metres.
pub type Rows = [[f64; 4]; 4];

/// Builds an isometry from a row-major 4x4 matrix, or says why the matrix is not rigid.
///
/// # Errors
/// A message (no file context; the caller adds it) when a value is not finite, the last row is not
/// `[0, 0, 0, 1]`, the rotation block is not orthonormal within [`RIGID_TOLERANCE`], or it is a reflection.
pub fn isometry_from_rows(rows: &Rows) -> Result<Isometry3<f64>, String> {
    if rows.iter().flatten().any(|v| !v.is_finite()) {
        return Err("matrix has a non-finite value (NaN or infinity)".into());
    }
    let last = rows[3];
    let last_dev = (last[0].abs()).max(last[1].abs()).max(last[2].abs()).max((last[3] - 1.0).abs());
    if last_dev > RIGID_TOLERANCE {
        return Err(format!("last row is {last:?}, expected [0, 0, 0, 1]"));
    }
    let r = Matrix3::from_fn(|i, j| rows[i][j]);
    let ortho_dev = (r.transpose() * r - Matrix3::identity()).abs().max();
    if ortho_dev > RIGID_TOLERANCE {
        return Err(format!(
            "rotation block is not orthonormal (|R^T R - I| = {ortho_dev:.3e} > {RIGID_TOLERANCE:e}); a scale or shear is not a rigid transform"
        ));
    }
    let det = r.determinant();
    if (det - 1.0).abs() > RIGID_TOLERANCE * 3.0 {
        return Err(format!(
            "rotation block has determinant {det:.6}, expected +1 (a reflection is not a rigid transform)"
        ));
    }
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let translation = Translation3::new(rows[0][3], rows[1][3], rows[2][3]);
    Ok(Isometry3::from_parts(translation, rotation))
}

/// [`isometry_from_rows`], except that a rotation block off orthonormal by more than
/// [`RIGID_TOLERANCE`] but at most [`FLOAT32_RIGID_TOLERANCE`] (float32 rounding) is replaced by
/// the nearest rotation: then the deviation `|R^T R - I|` comes back beside the isometry, for a
/// warning.
///
/// # Errors
/// As [`isometry_from_rows`], with [`FLOAT32_RIGID_TOLERANCE`] in place of [`RIGID_TOLERANCE`] for
/// the rotation block.
pub fn isometry_from_rows_reorthonormalised(rows: &Rows) -> Result<(Isometry3<f64>, Option<f64>), String> {
    let r = Matrix3::from_fn(|i, j| rows[i][j]);
    let ortho_dev = (r.transpose() * r - Matrix3::identity()).abs().max();
    if !(ortho_dev > RIGID_TOLERANCE && ortho_dev <= FLOAT32_RIGID_TOLERANCE)
        || rows.iter().flatten().any(|v| !v.is_finite())
    {
        return isometry_from_rows(rows).map(|iso| (iso, None)).map_err(|e| {
            if e.contains("orthonormal") {
                format!("{e} (float32 rounding up to {FLOAT32_RIGID_TOLERANCE:e} is re-orthonormalised)")
            } else {
                e
            }
        });
    }
    let last = rows[3];
    let last_dev = (last[0].abs()).max(last[1].abs()).max(last[2].abs()).max((last[3] - 1.0).abs());
    if last_dev > RIGID_TOLERANCE {
        return Err(format!("last row is {last:?}, expected [0, 0, 0, 1]"));
    }
    let det = r.determinant();
    if (det - 1.0).abs() > FLOAT32_RIGID_TOLERANCE * 3.0 {
        return Err(format!(
            "rotation block has determinant {det:.6}, expected +1 (a reflection is not a rigid transform)"
        ));
    }
    // the nearest rotation (polar decomposition by iteration from the quaternion of the block)
    // (the quaternion of a block that is not orthonormal is not unit: normalised before it is used)
    let start = UnitQuaternion::new_normalize(
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)).into_inner(),
    );
    let nearest = Rotation3::from_matrix_eps(&r, 1e-15, 100, start.to_rotation_matrix());
    let translation = Translation3::new(rows[0][3], rows[1][3], rows[2][3]);
    let rotation = UnitQuaternion::new_normalize(UnitQuaternion::from_rotation_matrix(&nearest).into_inner());
    Ok((Isometry3::from_parts(translation, rotation), Some(ortho_dev)))
}

/// The row-major 4x4 matrix of an isometry, as written in files.
pub fn rows_from_isometry(a_from_b: &Isometry3<f64>) -> Rows {
    let m: Matrix4<f64> = a_from_b.to_homogeneous();
    let mut rows = [[0.0; 4]; 4];
    for (i, row) in rows.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = m[(i, j)];
        }
    }
    rows
}

/// Rotation angle of an isometry in radians, in [0, pi].
pub fn rotation_angle_rad(a_from_b: &Isometry3<f64>) -> f64 {
    a_from_b.rotation.angle()
}

/// Difference between two poses of the same frame: (translation distance in metres, rotation angle in radians).
pub fn pose_difference(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    let delta = a.inverse() * b;
    ((a.translation.vector - b.translation.vector).norm(), delta.rotation.angle())
}

/// An isometry from a translation (metres) and a rotation vector (axis * angle, radians).
pub fn isometry_from_translation_rotvec(t: Vector3<f64>, rotvec: Vector3<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_scaled_axis(rotvec))
}

/// The cross-product matrix `[v]x` (`[v]x w = v x w`).
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// The adjoint of `a_from_b` for `(ω, v)` perturbations (rotation first):
/// `a_from_b * exp(ξ) * b_from_a = exp(Ad ξ)`, so a covariance `C` in frame b is `Ad C Adᵀ` in a.
pub fn adjoint(a_from_b: &Isometry3<f64>) -> Matrix6<f64> {
    let r = a_from_b.rotation.to_rotation_matrix().into_inner();
    let mut ad = Matrix6::zeros();
    ad.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    ad.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    ad.fixed_view_mut::<3, 3>(3, 0).copy_from(&(skew(&a_from_b.translation.vector) * r));
    ad
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_round_trip_is_exact_for_axis_aligned_rotations() {
        let rows = [[0.0, -1.0, 0.0, 0.5], [1.0, 0.0, 0.0, -0.25], [0.0, 0.0, 1.0, 2.0], [0.0, 0.0, 0.0, 1.0]];
        let iso = isometry_from_rows(&rows).expect("rigid");
        let back = rows_from_isometry(&iso);
        for i in 0..4 {
            for j in 0..4 {
                assert!((rows[i][j] - back[i][j]).abs() < 1e-15, "({i},{j})");
            }
        }
    }

    #[test]
    fn rejects_scale_shear_reflection_and_bad_last_row() {
        let mut scaled = rows_from_isometry(&Isometry3::identity());
        scaled[0][0] = 1.001;
        assert!(isometry_from_rows(&scaled).expect_err("an error").contains("orthonormal"));
        let mut reflected = rows_from_isometry(&Isometry3::identity());
        reflected[2][2] = -1.0;
        assert!(isometry_from_rows(&reflected).expect_err("an error").contains("determinant"));
        let mut last = rows_from_isometry(&Isometry3::identity());
        last[3][0] = 0.1;
        assert!(isometry_from_rows(&last).expect_err("an error").contains("last row"));
        let mut nan = rows_from_isometry(&Isometry3::identity());
        nan[1][3] = f64::NAN;
        assert!(isometry_from_rows(&nan).expect_err("an error").contains("non-finite"));
    }

    /// A rotation rounded to 4 digits (|R^T R - I| ~ 1e-4) is re-orthonormalised, within that
    /// rounding of the exact one; a 2 % scale is still refused.
    #[test]
    fn float32_rounding_is_reorthonormalised_and_larger_errors_refused() {
        let iso = isometry_from_translation_rotvec(Vector3::new(0.1, 0.2, 0.3), Vector3::new(0.3, -0.2, 1.0));
        let mut rows = rows_from_isometry(&iso);
        for row in rows.iter_mut().take(3) {
            for v in row.iter_mut().take(3) {
                *v = (*v * 1e4).round() / 1e4;
            }
        }
        assert!(isometry_from_rows(&rows).is_err(), "refused by the strict reader");
        let (fixed, dev) = isometry_from_rows_reorthonormalised(&rows).expect("re-orthonormalised");
        let dev = dev.expect("a deviation reported");
        assert!(dev > RIGID_TOLERANCE && dev < 2e-4, "deviation {dev}");
        let (dt, dr) = pose_difference(&fixed, &iso);
        println!("re-orthonormalised: deviation {dev:.2e}, {dt:.1e} m {dr:.2e} rad from the exact pose");
        // measured |R^T R - I| 7.0e-5 and 2.8e-5 rad from the exact pose (the rounding itself)
        assert!(dt < 1e-12 && dr < 1e-4, "{dt} m {dr} rad from the exact pose");
        let r = fixed.rotation.to_rotation_matrix().into_inner();
        let ortho = (r.transpose() * r - Matrix3::identity()).abs().max();
        assert!(
            ortho < 1e-12,
            "re-orthonormalised rotation off by {ortho:e}, quaternion norm {}",
            fixed.rotation.into_inner().norm()
        );
        let exact = isometry_from_rows_reorthonormalised(&rows_from_isometry(&iso)).expect("exact");
        assert_eq!(exact.1, None);
        let mut scaled = rows_from_isometry(&Isometry3::identity());
        scaled[0][0] = 1.01;
        let err = isometry_from_rows_reorthonormalised(&scaled).expect_err("2 % scale");
        assert!(err.contains("orthonormal") && err.contains("re-orthonormalised"), "{err}");
    }

    #[test]
    fn accepts_rounding_below_tolerance() {
        let iso = isometry_from_translation_rotvec(Vector3::new(0.1, 0.2, 0.3), Vector3::new(0.3, -0.2, 1.0));
        let mut rows = rows_from_isometry(&iso);
        for row in rows.iter_mut().take(3) {
            for v in row.iter_mut() {
                *v = (*v * 1e8).round() / 1e8;
            }
        }
        let parsed = isometry_from_rows(&rows).expect("rounded to 1e-8 is still rigid");
        let (dt, dr) = pose_difference(&iso, &parsed);
        assert!(dt < 1e-8 && dr < 1e-7, "dt {dt} dr {dr}");
    }
}
