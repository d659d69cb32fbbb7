//! Closed-form starts for the tag pose: the plane-to-image homography, and IPPE (Collins & Bartoli,
//! "Infinitesimal Plane-based Pose Estimation", IJCV 2014), which gives the two rotations that
//! explain the homography's first-order behaviour at the tag centre (the two sides of the planar
//! ambiguity), each with its least-squares translation.
//!
//! Everything here works in undistorted normalised image coordinates (`x/z`, `y/z`) and in the tag
//! plane `z = 0` of awl's tag frame, with the model centred on the origin.

use nalgebra::{Matrix2, Matrix3, Rotation3, SMatrix, SVector, Unit, Vector2, Vector3};

/// The homography `H` (with `H[(2, 2)] = 1`) mapping tag-plane points `(x, y, 1)` to normalised
/// image points, from 4 correspondences; `None` when they are degenerate (three collinear points).
pub(crate) fn homography(model: &[Vector2<f64>; 4], image: &[Vector2<f64>; 4]) -> Option<Matrix3<f64>> {
    // Condition the model side: scale to a unit spread so the 8 x 8 system is well balanced.
    let spread = model.iter().map(|m| m.norm()).sum::<f64>() / 4.0;
    if spread <= 0.0 || !spread.is_finite() {
        return None;
    }
    let mut a = SMatrix::<f64, 8, 8>::zeros();
    let mut b = SVector::<f64, 8>::zeros();
    for (k, (m, p)) in model.iter().zip(image).enumerate() {
        let (x, y) = (m.x / spread, m.y / spread);
        let (u, v) = (p.x, p.y);
        let r = 2 * k;
        a.row_mut(r).copy_from_slice(&[x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y]);
        a.row_mut(r + 1).copy_from_slice(&[0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y]);
        b[r] = u;
        b[r + 1] = v;
    }
    let h = a.lu().solve(&b)?;
    if !h.iter().all(|v| v.is_finite()) {
        return None;
    }
    let unit = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], 1.0);
    // Undo the conditioning: H_model = H_unit * diag(1/spread, 1/spread, 1).
    Some(unit * Matrix3::from_diagonal(&Vector3::new(1.0 / spread, 1.0 / spread, 1.0)))
}

/// The rotation taking the optical axis `z` onto the unit ray through the normalised point `v`.
fn rotation_to_ray(v: &Vector2<f64>) -> Rotation3<f64> {
    let ray = Vector3::new(v.x, v.y, 1.0).normalize();
    let axis = Vector3::z().cross(&ray);
    let sin = axis.norm();
    if sin < 1e-15 {
        return Rotation3::identity();
    }
    Rotation3::from_axis_angle(&Unit::new_unchecked(axis / sin), sin.atan2(ray.z))
}

/// The two IPPE rotations `camera_from_tag` for homography `h` (model centred on the origin);
/// `None` when `h` is degenerate.
///
/// Derivation: with `R = Rv * R'` where `Rv` turns the optical axis onto the ray through the image
/// `v` of the tag centre, the homography's Jacobian at the origin is `J = B * R'_22 / t_z` with
/// `B = [I2 | -v] * Rv[:, 0..2]`. The top-left 2x2 of a rotation has largest singular value 1, so
/// `t_z = 1 / gamma` with `gamma` the largest singular value of `A = B^-1 J`, `R'_22 = A / gamma`, and the
/// third row of `R'`'s first two columns is `+-b` (unit columns, orthogonal): the two solutions.
pub(crate) fn ippe_rotations(h: &Matrix3<f64>) -> Option<[Rotation3<f64>; 2]> {
    let h = h / h[(2, 2)];
    let v = Vector2::new(h[(0, 2)], h[(1, 2)]);
    let j = Matrix2::new(
        h[(0, 0)] - h[(2, 0)] * v.x,
        h[(0, 1)] - h[(2, 1)] * v.x,
        h[(1, 0)] - h[(2, 0)] * v.y,
        h[(1, 1)] - h[(2, 1)] * v.y,
    );
    let rv = rotation_to_ray(&v);
    let m = rv.matrix();
    let b = Matrix2::new(
        m[(0, 0)] - v.x * m[(2, 0)],
        m[(0, 1)] - v.x * m[(2, 1)],
        m[(1, 0)] - v.y * m[(2, 0)],
        m[(1, 1)] - v.y * m[(2, 1)],
    );
    let a = b.try_inverse()? * j;
    let gamma = a.svd(false, false).singular_values.max();
    if !(gamma.is_finite() && gamma > 1e-12) {
        return None;
    }
    let r22 = a / gamma;
    let b0 = (1.0 - r22[(0, 0)].powi(2) - r22[(1, 0)].powi(2)).max(0.0).sqrt();
    let mut b1 = (1.0 - r22[(0, 1)].powi(2) - r22[(1, 1)].powi(2)).max(0.0).sqrt();
    if r22[(0, 0)] * r22[(0, 1)] + r22[(1, 0)] * r22[(1, 1)] > 0.0 {
        b1 = -b1;
    }
    let build = |sign: f64| {
        // Gram-Schmidt against rounding, then complete the right-handed frame.
        let c0 = Vector3::new(r22[(0, 0)], r22[(1, 0)], sign * b0).normalize();
        let c1 = Vector3::new(r22[(0, 1)], r22[(1, 1)], sign * b1);
        let c1 = (c1 - c0 * c0.dot(&c1)).normalize();
        let r_prime = Matrix3::from_columns(&[c0, c1, c0.cross(&c1)]);
        rv * Rotation3::from_matrix_unchecked(r_prime)
    };
    Some([build(1.0), build(-1.0)])
}

/// The translation minimising the algebraic reprojection error of `model` (tag plane) onto the
/// normalised `image` points for a fixed rotation: linear least squares, 8 equations, 3 unknowns.
pub(crate) fn translation_for(
    rotation: &Rotation3<f64>,
    model: &[Vector2<f64>; 4],
    image: &[Vector2<f64>; 4],
) -> Option<Vector3<f64>> {
    let mut ata = Matrix3::zeros();
    let mut atb = Vector3::zeros();
    for (m, p) in model.iter().zip(image) {
        let q = rotation * Vector3::new(m.x, m.y, 0.0);
        // u * (q.z + tz) = q.x + tx  ->  tx - u tz = u q.z - q.x (and the same for v).
        for (row, rhs) in
            [(Vector3::new(1.0, 0.0, -p.x), p.x * q.z - q.x), (Vector3::new(0.0, 1.0, -p.y), p.y * q.z - q.y)]
        {
            ata += row * row.transpose();
            atb += row * rhs;
        }
    }
    ata.try_inverse().map(|inv| inv * atb)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion};

    fn project(pose: &Isometry3<f64>, m: &Vector2<f64>) -> Vector2<f64> {
        let p = pose * Point3::new(m.x, m.y, 0.0);
        Vector2::new(p.x / p.z, p.y / p.z)
    }

    #[test]
    fn ippe_recovers_an_exact_pose_as_one_of_its_two_solutions() {
        let h = 0.05;
        let model = [Vector2::new(-h, -h), Vector2::new(h, -h), Vector2::new(h, h), Vector2::new(-h, h)];
        for (k, (rx, ry, rz)) in
            [(2.9, 0.3, 0.1), (2.5, -0.4, 1.2), (3.1, 0.0, 0.0), (2.2, 0.6, -2.0)].iter().enumerate()
        {
            let rotation = UnitQuaternion::from_euler_angles(*rx, *ry, *rz);
            let pose = Isometry3::from_parts(Translation3::new(0.05 * k as f64, -0.03, 0.6), rotation);
            let image = model.map(|m| project(&pose, &m));
            let hom = homography(&model, &image).expect("homography");
            let rotations = ippe_rotations(&hom).expect("ippe");
            let best = rotations
                .iter()
                .map(|r| {
                    let t = translation_for(r, &model, &image).expect("t");
                    (r.angle_to(&pose.rotation.to_rotation_matrix()), (t - pose.translation.vector).norm())
                })
                .min_by(|a, b| a.0.total_cmp(&b.0))
                .expect("two");
            assert!(best.0 < 1e-9 && best.1 < 1e-9, "case {k}: rotation {} rad, translation {} m", best.0, best.1);
        }
    }
}
