//! How well the poses determine `X = ee_from_camera`: the covariance of the refinement's
//! least-squares problem at its solution, and the same problem with one more unknown, a scale
//! factor `s` on every `camera_from_target` translation (a wrong tag or board size).
//!
//! The Jacobian `J` (6N x 12: `X`'s translation in the flange frame and rotation `R_X exp(dw)`,
//! then `Y`'s; 6N x 13 with `s`) is taken by central differences like the refinement's, at the
//! solution. The covariance is `sigma^2 (J^T J)^-1` with `sigma^2 = cost / (6N - 12)` (the residual
//! noise per component, metres; rotations enter weighted by `rotation_weight_m`), floored at
//! [`crate::handeye::HandEyeParams::min_noise_mm`] so that exact or over-fitted data is still judged
//! by its geometry. Directions the data leaves free (eigenvalues of `J^T J` below `1e-14` of the
//! largest) get the floor eigenvalue: a huge, finite sigma.
//!
//! The scale that fits best is one Gauss-Newton step of the 13-unknown problem from the solution
//! (`s = 1 - [(J^T J)^-1 J^T r]_s`): the problem is linear in `s` to first order, so a 3 % size error
//! comes out to about 0.01 % (its sigma is 0.1-0.4 % on the simulated captures). The translation's
//! 95 % bound is the 0.95 quantile of the error's norm under its 3x3 covariance (`1.96 sigma` when
//! one direction dominates, `2.80 sigma` when all three are alike).

use nalgebra::{DMatrix, DVector, Isometry3, SymmetricEigen, Translation3, Vector3};
use serde::Serialize;

use crate::handeye::HandEyePose;
use crate::handeye::capture_bound::norm_quantile;
use crate::handeye::refine::{H, residual, shifted_unknowns};

/// The 1-sigma uncertainty of a hand-eye solution (module docs of `handeye::uncertainty`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct HandEyeUncertainty {
    /// Residual noise per component the sigmas assume: the refinement's RMS, at least the floor,
    /// millimetres (rotations weighted as in the refinement).
    pub noise_mm: f64,
    /// 1-sigma of `T_ee_camera`'s translation along the flange axes x, y, z, millimetres.
    pub translation_sigma_mm: [f64; 3],
    /// 1-sigma of `T_ee_camera`'s rotation about the camera axes x, y, z, degrees.
    pub rotation_sigma_deg: [f64; 3],
    /// 1-sigma of the translation along its worst determined direction, millimetres.
    pub worst_translation_sigma_mm: f64,
    /// That direction (unit, flange frame).
    pub worst_translation_direction: [f64; 3],
    /// The radius the translation's error stays within with 95 % probability (3D, from its
    /// covariance), millimetres.
    pub translation_bound_95_mm: f64,
    /// 1-sigma of a scale factor on every `T_camera_target` translation (tag size) fitted with the
    /// rest, percent.
    pub scale_sigma_percent: f64,
    /// The scale factor on every `T_camera_target` translation that fits best, dimensionless: 1 for
    /// the right tag size, about 1/1.03 when the size given to the detector is 3 % too large (every
    /// translation 3 % too long). The right size is the given one times this factor.
    pub fitted_scale: f64,
    /// How far `T_ee_camera`'s translation moves to absorb a 1 % scale error, millimetres.
    pub translation_mm_per_scale_percent: f64,
}

/// `pose` with its `camera_from_target` translation scaled by `s`.
fn scaled(pose: &HandEyePose, s: f64) -> HandEyePose {
    let mut c = pose.camera_from_target;
    c.translation = Translation3::from(c.translation.vector * s);
    HandEyePose { base_from_ee: pose.base_from_ee, camera_from_target: c }
}

/// `J^T J` and `J^T r` of the 13-unknown problem (`X`, `Y`, scale) at `(x, y, s = 1)`, and the cost there.
fn normal_matrix(
    poses: &[HandEyePose],
    x: &Isometry3<f64>,
    y: &Isometry3<f64>,
    w: f64,
) -> (DMatrix<f64>, DVector<f64>, f64) {
    let shifted = shifted_unknowns(x, y);
    let y_inv = y.inverse();
    let mut jtj = DMatrix::<f64>::zeros(13, 13);
    let mut jtr = DVector::<f64>::zeros(13);
    let mut cost = 0.0;
    for p in poses {
        let r = residual(p, x, &y_inv, w);
        cost += r.norm_squared();
        let mut j = DMatrix::<f64>::zeros(6, 13);
        for (k, ((xp, yp_inv), (xm, ym_inv))) in shifted.iter().enumerate() {
            let col = (residual(p, xp, yp_inv, w) - residual(p, xm, ym_inv, w)) / (2.0 * H);
            j.set_column(k, &col);
        }
        let col =
            (residual(&scaled(p, 1.0 + H), x, &y_inv, w) - residual(&scaled(p, 1.0 - H), x, &y_inv, w)) / (2.0 * H);
        j.set_column(12, &col);
        jtj += j.transpose() * &j;
        jtr += j.transpose() * DVector::from_column_slice(r.as_slice());
    }
    (jtj, jtr, cost)
}

/// The inverse of a symmetric positive semi-definite `m`, eigenvalues floored at `1e-14` of the largest.
pub(crate) fn floored_inverse(m: &DMatrix<f64>) -> DMatrix<f64> {
    let eig = SymmetricEigen::new(m.clone());
    let largest = eig.eigenvalues.iter().copied().fold(0.0f64, f64::max).max(1e-300);
    let inv = eig.eigenvalues.map(|l| 1.0 / l.max(1e-14 * largest));
    &eig.eigenvectors * DMatrix::from_diagonal(&inv) * eig.eigenvectors.transpose()
}

/// The uncertainty of `(x, y)` over `poses` (module docs), the noise floored at `min_noise_m`.
pub(crate) fn uncertainty(
    poses: &[HandEyePose],
    x: &Isometry3<f64>,
    y: &Isometry3<f64>,
    w: f64,
    min_noise_m: f64,
) -> HandEyeUncertainty {
    let (jtj, jtr, cost) = normal_matrix(poses, x, y, w);
    let dof = (6 * poses.len()).saturating_sub(12).max(1) as f64;
    let noise = (cost / dof).sqrt().max(min_noise_m);
    let var = noise * noise;
    let c12 = floored_inverse(&jtj.view((0, 0), (12, 12)).into_owned()) * var;
    let inv13 = floored_inverse(&jtj);
    let step = -(&inv13 * &jtr);
    let c13 = inv13 * var;
    let translation_sigma_mm = [0, 1, 2].map(|k| c12[(k, k)].max(0.0).sqrt() * 1e3);
    let rotation_sigma_deg = [3, 4, 5].map(|k| c12[(k, k)].max(0.0).sqrt().to_degrees());
    let tt = c12.view((0, 0), (3, 3)).into_owned();
    let eig = SymmetricEigen::new(tt);
    let variances = [0, 1, 2].map(|k| eig.eigenvalues[k].max(0.0));
    let worst = eig.eigenvalues.imax();
    let mut dir =
        Vector3::new(eig.eigenvectors[(0, worst)], eig.eigenvectors[(1, worst)], eig.eigenvectors[(2, worst)]);
    if dir[dir.iamax()] < 0.0 {
        dir = -dir;
    }
    let css = c13[(12, 12)].max(1e-300);
    let shift = Vector3::new(c13[(0, 12)], c13[(1, 12)], c13[(2, 12)]) / css * 0.01;
    HandEyeUncertainty {
        noise_mm: noise * 1e3,
        translation_sigma_mm,
        rotation_sigma_deg,
        worst_translation_sigma_mm: eig.eigenvalues[worst].max(0.0).sqrt() * 1e3,
        worst_translation_direction: [dir.x, dir.y, dir.z],
        translation_bound_95_mm: norm_quantile(variances, 0.95) * 1e3,
        scale_sigma_percent: css.sqrt() * 100.0,
        fitted_scale: 1.0 + step[12],
        translation_mm_per_scale_percent: shift.norm() * 1e3,
    }
}
