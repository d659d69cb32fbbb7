//! A calibration capture's views weighted by their noise, and the calibration's own predicted error
//! bound ([`CaptureBound`]).
//!
//! Per view `i`, the refinement's residual `r_i = (t(D_i), log R(D_i))` (metres, radians), with
//! `D_i = Y^-1 E_i X P_i` (`handeye::refine`), carries two noises:
//! - the detected tag pose `P_i = T_camera_tag`, from the tag's 4 corners, each with isotropic noise
//!   of `corner_sigma_px` pixels a image axis: `P_measured = P exp(d)` (`exp(v, w) = [Rot(w) | v]`, a
//!   perturbation in the tag frame) with `Σ_P = (J^T J)^-1 σ_px²`, `J` the 8x6 Jacobian of the
//!   projected corners (pinhole, lens distortion ignored) with respect to `d` (central differences).
//!   A 4-corner pose is elongated: face-on at 0.5 m (615 px focal length, a 14 cm tag, 0.2 px) its
//!   depth's 1-sigma is 0.41 mm against 0.115 mm laterally, and its tilt is loose too;
//! - the recorded flange pose `E_recorded = E exp(n)`, `n` per axis in the flange frame with
//!   `arm_sigma_mm` / `arm_sigma_deg`.
//!
//! `r_i`'s covariance is `S_i = G diag(Σ_arm, Σ_P) G^T`, `G = dr_i / d(n, d)` (central differences,
//! at the current solution). The refinement whitens each view's residual by `L_i = S_i^(-1/2)`
//! ([`view_whitening`]): the weighted least squares is then the maximum-likelihood estimate.
//!
//! The predicted covariance of the unknowns (`X`, `Y`, and the corner bias's depth scale `κ` when it
//! was estimated, `handeye::capture` item 5) is the sandwich `A^-1 B A^-1`, `A = Σ J_i^T W_i J_i`,
//! `B = Σ J_i^T W_i S_i W_i J_i`, over the inlier views: `J_i` the Jacobian of `r_i`, `W_i` the
//! weights the refinement used (`L_i^T L_i`, or `diag(1, 1, 1, w², w², w²)` unweighted). With the
//! views weighted it is `A^-1`, the Cramér-Rao bound of this model (the one
//! `bench/handeye_bound/bound.py --capture` computes independently). It is scaled by
//! `max(1, sqrt(χ² / dof))`, `χ² = Σ r_i^T S_i^-1 r_i`: the residuals larger than the assumed
//! noise widen it, smaller ones never narrow it. The 95 % bounds are the 95 % quantiles of the 3D
//! error's length (translation, rotation) under that Gaussian ([`norm_quantile`]).

use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Matrix6, SMatrix, SymmetricEigen, Translation3, UnitQuaternion};
use nalgebra::{Vector3, Vector6};
use serde::Serialize;

use crate::camera::Intrinsics;
use crate::error::{Error, Result};
use crate::handeye::HandEyePose;
use crate::handeye::refine::{H, residual, shifted_unknowns};
use crate::handeye::uncertainty::floored_inverse;
use crate::tag::tag_corners_m;

/// The probability of [`CaptureBound::translation_mm`] and [`CaptureBound::rotation_deg`].
pub const BOUND_PROBABILITY: f64 = 0.95;

/// A calibration capture's predicted error (module docs of `handeye::capture_bound`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CaptureBound {
    /// 95 % bound on the distance of `T_ee_camera`'s translation from the truth, millimetres.
    pub translation_mm: f64,
    /// 95 % bound on the angle of `T_ee_camera`'s rotation from the truth, degrees.
    pub rotation_deg: f64,
    /// Predicted RMS 3D error of the translation (square root of the covariance's trace), millimetres.
    pub translation_rms_mm: f64,
    /// Predicted RMS 3D error of the rotation, degrees.
    pub rotation_rms_deg: f64,
    /// Predicted 1-sigma of the translation along the flange axes x, y, z, millimetres.
    pub translation_sigma_mm: [f64; 3],
    /// Predicted 1-sigma of the rotation about the camera axes x, y, z, degrees.
    pub rotation_sigma_deg: [f64; 3],
    /// `χ² / dof` of the inlier views' residuals under the assumed noise (about 1 when it is right).
    pub normalized_cost: f64,
    /// The factor the covariance's square root was scaled by: `max(1, sqrt(normalized_cost))`.
    pub noise_scale: f64,
    /// True when the refinement weighted the views by their covariance.
    pub weighted: bool,
    /// True when the corner bias was estimated and its uncertainty is included.
    pub with_corner_bias: bool,
    /// The inlier views it is computed from.
    pub views: usize,
    /// The tag corners' assumed noise per image axis, pixels.
    pub corner_sigma_px: f64,
    /// The flange pose's assumed noise per axis (flange frame), millimetres.
    pub arm_sigma_mm: f64,
    /// The flange pose's assumed noise per axis, degrees.
    pub arm_sigma_deg: f64,
}

/// The noise assumed per view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ViewNoise {
    /// Tag corner noise per image axis, pixels.
    pub corner_sigma_px: f64,
    /// Flange translation noise per axis, metres.
    pub arm_sigma_m: f64,
    /// Flange rotation noise per axis, radians.
    pub arm_sigma_rad: f64,
}

/// `[Rot(w) | v]` of `(v, w)`.
fn exp6(xi: &Vector6<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(xi[0], xi[1], xi[2]),
        UnitQuaternion::from_scaled_axis(Vector3::new(xi[3], xi[4], xi[5])),
    )
}

fn unit6(k: usize, h: f64) -> Vector6<f64> {
    let mut e = Vector6::zeros();
    e[k] = h;
    e
}

/// The covariance of a tag pose `camera_from_tag` (a right perturbation `(v, w)` in the tag frame,
/// metres and radians) from its 4 corners with `sigma_px` pixels of noise per axis (module docs);
/// `None` when a corner is behind the camera or the corners do not fix the pose.
pub(crate) fn tag_pose_covariance(
    k: &Intrinsics,
    tag_size_m: f64,
    camera_from_tag: &Isometry3<f64>,
    sigma_px: f64,
) -> Option<Matrix6<f64>> {
    let corners = tag_corners_m(tag_size_m);
    let project = |p: &Isometry3<f64>| -> Option<SMatrix<f64, 8, 1>> {
        let mut uv = SMatrix::<f64, 8, 1>::zeros();
        for (i, c) in corners.iter().enumerate() {
            let q = p * c;
            if q.z <= 1e-9 {
                return None;
            }
            uv[2 * i] = k.fx * q.x / q.z + k.cx;
            uv[2 * i + 1] = k.fy * q.y / q.z + k.cy;
        }
        Some(uv)
    };
    let mut j = SMatrix::<f64, 8, 6>::zeros();
    for c in 0..6 {
        let plus = project(&(camera_from_tag * exp6(&unit6(c, H))))?;
        let minus = project(&(camera_from_tag * exp6(&unit6(c, -H))))?;
        j.set_column(c, &((plus - minus) / (2.0 * H)));
    }
    (j.transpose() * j).try_inverse().map(|m| m * sigma_px * sigma_px).filter(|m| m.iter().all(|v| v.is_finite()))
}

/// The covariance `S` of a view's residual `(t(D), log R(D))` (module docs) at `(x, y)`, with the
/// tag pose's covariance `tag_covariance`.
pub(crate) fn view_covariance(
    pose: &HandEyePose,
    x: &Isometry3<f64>,
    y: &Isometry3<f64>,
    tag_covariance: &Matrix6<f64>,
    noise: &ViewNoise,
) -> Matrix6<f64> {
    let y_inv = y.inverse();
    let r = |n: &Vector6<f64>, d: &Vector6<f64>| {
        let p = HandEyePose {
            base_from_ee: pose.base_from_ee * exp6(n),
            camera_from_target: pose.camera_from_target * exp6(d),
        };
        residual(&p, x, &y_inv, 1.0)
    };
    let zero = Vector6::zeros();
    let mut g = SMatrix::<f64, 6, 12>::zeros();
    for c in 0..6 {
        g.set_column(c, &((r(&unit6(c, H), &zero) - r(&unit6(c, -H), &zero)) / (2.0 * H)));
        g.set_column(6 + c, &((r(&zero, &unit6(c, H)) - r(&zero, &unit6(c, -H))) / (2.0 * H)));
    }
    let mut noise_cov = SMatrix::<f64, 12, 12>::zeros();
    for c in 0..3 {
        noise_cov[(c, c)] = noise.arm_sigma_m.powi(2);
        noise_cov[(3 + c, 3 + c)] = noise.arm_sigma_rad.powi(2);
    }
    noise_cov.fixed_view_mut::<6, 6>(6, 6).copy_from(tag_covariance);
    let s = g * noise_cov * g.transpose();
    (s + s.transpose()) / 2.0
}

/// `S^(-1/2)` (symmetric) of a view covariance; an error naming `what` when `S` is not positive definite.
pub(crate) fn view_whitening(s: &Matrix6<f64>, what: &str) -> Result<Matrix6<f64>> {
    let eig = SymmetricEigen::new(*s);
    let smallest = eig.eigenvalues.min();
    if !(smallest.is_finite() && smallest > 0.0) {
        return Err(Error::invalid(
            what,
            format!("its residual's covariance is not positive definite (smallest eigenvalue {smallest:e})"),
        ));
    }
    let inv_sqrt = eig.eigenvalues.map(|l| 1.0 / l.sqrt());
    Ok(eig.eigenvectors * Matrix6::from_diagonal(&inv_sqrt) * eig.eigenvectors.transpose())
}

/// What [`predict`] needs: the inlier views at the solution.
pub(crate) struct BoundInput<'a> {
    /// The poses the solution was fitted to (inliers).
    pub poses: &'a [HandEyePose],
    /// Each pose's residual covariance `S_i`.
    pub covariances: &'a [Matrix6<f64>],
    /// The whitening the refinement used per pose, or `None`: the rotation weight `w` alone.
    pub whitening: Option<&'a [Matrix6<f64>]>,
    /// The rotation weight, metres per radian (unweighted refinement).
    pub rotation_weight_m: f64,
    /// The solution `X = T_ee_camera`.
    pub x: Isometry3<f64>,
    /// The solution `Y = T_base_target`.
    pub y: Isometry3<f64>,
    /// The detected poses (inliers) and the corner bias's depth scale `κ` (per metre), when it was
    /// estimated: `poses` are then `detected` with their translations divided by `1 + κ z`.
    pub corner_bias: Option<(&'a [HandEyePose], f64)>,
}

/// The predicted covariance and the 95 % bounds (module docs).
pub(crate) fn predict(input: &BoundInput, noise: &ViewNoise) -> CaptureBound {
    let n_unknowns = if input.corner_bias.is_some() { 13 } else { 12 };
    let shifted = shifted_unknowns(&input.x, &input.y);
    let y_inv = input.y.inverse();
    let (mut a, mut b) = (DMatrix::<f64>::zeros(n_unknowns, n_unknowns), DMatrix::<f64>::zeros(n_unknowns, n_unknowns));
    let mut chi2 = 0.0;
    let w = input.rotation_weight_m;
    let unweighted = Matrix6::from_diagonal(&Vector6::new(1.0, 1.0, 1.0, w * w, w * w, w * w));
    for (i, p) in input.poses.iter().enumerate() {
        let s = &input.covariances[i];
        let r = residual(p, &input.x, &y_inv, 1.0);
        let s_inv = floored_inverse(&DMatrix::from_column_slice(6, 6, s.as_slice()));
        chi2 += (r.transpose() * Matrix6::from_column_slice(s_inv.as_slice()) * r)[(0, 0)];
        let mut j = DMatrix::<f64>::zeros(6, n_unknowns);
        for (k, ((xp, yp_inv), (xm, ym_inv))) in shifted.iter().enumerate() {
            let col = (residual(p, xp, yp_inv, 1.0) - residual(p, xm, ym_inv, 1.0)) / (2.0 * H);
            j.set_column(k, &DVector::from_column_slice(col.as_slice()));
        }
        if let Some((detected, kappa)) = input.corner_bias {
            let scaled = |kappa: f64| {
                let mut c = detected[i].camera_from_target;
                let t = c.translation.vector;
                c.translation.vector = t / (1.0 + kappa * t.z);
                HandEyePose { camera_from_target: c, ..detected[i] }
            };
            let col = (residual(&scaled(kappa + H), &input.x, &y_inv, 1.0)
                - residual(&scaled(kappa - H), &input.x, &y_inv, 1.0))
                / (2.0 * H);
            j.set_column(12, &DVector::from_column_slice(col.as_slice()));
        }
        let weight = match input.whitening {
            Some(l) => l[i].transpose() * l[i],
            None => unweighted,
        };
        let weight = DMatrix::from_column_slice(6, 6, weight.as_slice());
        let s = DMatrix::from_column_slice(6, 6, s.as_slice());
        let jw = j.transpose() * &weight;
        a += &jw * &j;
        b += &jw * s * jw.transpose();
    }
    let a_inv = floored_inverse(&a);
    let cov = &a_inv * b * &a_inv;
    let dof = (6 * input.poses.len()).saturating_sub(n_unknowns).max(1) as f64;
    let normalized_cost = chi2 / dof;
    let noise_scale = normalized_cost.sqrt().max(1.0);
    let block = |o: usize| Matrix3::from_fn(|r, c| cov[(o + r, o + c)]) * noise_scale.powi(2);
    let (ct, cr) = (block(0), block(3));
    let eig = |m: &Matrix3<f64>| {
        let e = SymmetricEigen::new((m + m.transpose()) / 2.0).eigenvalues;
        [e[0].max(0.0), e[1].max(0.0), e[2].max(0.0)]
    };
    CaptureBound {
        translation_mm: norm_quantile(eig(&ct), BOUND_PROBABILITY) * 1e3,
        rotation_deg: norm_quantile(eig(&cr), BOUND_PROBABILITY).to_degrees(),
        translation_rms_mm: ct.trace().max(0.0).sqrt() * 1e3,
        rotation_rms_deg: cr.trace().max(0.0).sqrt().to_degrees(),
        translation_sigma_mm: [0, 1, 2].map(|k| ct[(k, k)].max(0.0).sqrt() * 1e3),
        rotation_sigma_deg: [0, 1, 2].map(|k| cr[(k, k)].max(0.0).sqrt().to_degrees()),
        normalized_cost,
        noise_scale,
        weighted: input.whitening.is_some(),
        with_corner_bias: input.corner_bias.is_some(),
        views: input.poses.len(),
        corner_sigma_px: noise.corner_sigma_px,
        arm_sigma_mm: noise.arm_sigma_m * 1e3,
        arm_sigma_deg: noise.arm_sigma_rad.to_degrees(),
    }
}

/// The error function (Abramowitz and Stegun 7.1.26: within 1.5e-7).
fn erf(x: f64) -> f64 {
    let t = 1.0 / (1.0 + 0.327_591_1 * x.abs());
    let poly =
        t * (0.254_829_592 + t * (-0.284_496_736 + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    let y = 1.0 - poly * (-x * x).exp();
    if x >= 0.0 { y } else { -y }
}

/// `P(|e| <= radius)` for `e ~ N(0, diag(variances))` in 3D: the largest variance in closed form
/// (so that the integrand stays continuous, even with the other two zero), the other two on a grid
/// (midpoint rule, 0-7 sigma, one quadrant).
fn norm_cdf(variances: [f64; 3], radius: f64) -> f64 {
    let mut v = variances;
    v.sort_by(|a, b| b.total_cmp(a));
    let (steps, top) = (175, 7.0);
    let h = top / steps as f64;
    // the half-normal density times the step
    let weight = |z: f64| (-0.5 * z * z).exp() * (2.0 / std::f64::consts::PI).sqrt() * h;
    let r2 = radius * radius;
    // P(v0 z0^2 <= rest)
    let closed = |rest: f64| if rest <= 0.0 { 0.0 } else { erf((rest / (2.0 * v[0])).sqrt()) };
    if v[1] <= 0.0 {
        return closed(r2);
    }
    let mut total = 0.0;
    for i in 0..steps {
        let z1 = (i as f64 + 0.5) * h;
        let rest1 = r2 - v[1] * z1 * z1;
        if rest1 <= 0.0 {
            break;
        }
        let inner = if v[2] <= 0.0 {
            closed(rest1)
        } else {
            (0..steps)
                .map(|j| (j as f64 + 0.5) * h)
                .map(|z2| weight(z2) * closed(rest1 - v[2] * z2 * z2))
                .take_while(|p| *p > 0.0)
                .sum()
        };
        total += weight(z1) * inner;
    }
    total
}

/// The `p` quantile of `|e|`, `e ~ N(0, diag(variances))` in 3D (the eigenvalues of its
/// covariance), by bisection on [`norm_cdf`]; 0 for no variance.
pub(crate) fn norm_quantile(variances: [f64; 3], p: f64) -> f64 {
    let largest = variances.iter().copied().fold(0.0f64, f64::max);
    if largest <= 0.0 {
        return 0.0;
    }
    // |e|^2 <= largest * chi2_3, whose 0.999 quantile is 16.27
    let (mut lo, mut hi) = (0.0, (16.3 * largest).sqrt() * (variances.iter().sum::<f64>() / largest).sqrt());
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if norm_cdf(variances, mid) < p { lo = mid } else { hi = mid }
    }
    0.5 * (lo + hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_norm_quantile_matches_chi_distributions() {
        // isotropic: chi with 3 dof, 95 %: sqrt(7.8147) = 2.7955; one axis: 1.95996; two: sqrt(5.9915)
        let q3 = norm_quantile([1.0, 1.0, 1.0], 0.95);
        let q1 = norm_quantile([4.0, 0.0, 0.0], 0.95);
        let q2 = norm_quantile([0.0, 1.0, 1.0], 0.95);
        assert!((q3 - 2.7955).abs() < 2e-3, "{q3}");
        assert!((q1 - 2.0 * 1.95996).abs() < 4e-3, "{q1}");
        assert!((q2 - 5.9915f64.sqrt()).abs() < 2e-3, "{q2}");
        assert_eq!(norm_quantile([0.0; 3], 0.95), 0.0);
        assert!((erf(1.0) - 0.842_700_79).abs() < 2e-7 && (erf(-0.5) + 0.520_499_88).abs() < 2e-7);
    }

    #[test]
    fn a_face_on_tag_is_known_far_worse_in_depth_than_laterally() {
        let k =
            Intrinsics { width: 640, height: 480, fx: 615.0, fy: 615.0, cx: 320.0, cy: 240.0, distortion: [0.0; 5] };
        let pose = Isometry3::translation(0.0, 0.0, 0.5);
        let c = tag_pose_covariance(&k, 0.14, &pose, 0.2).expect("a pose");
        // right perturbation in the tag frame, which here is the camera's: depth is z
        let (lateral, depth) = (c[(0, 0)].sqrt(), c[(2, 2)].sqrt());
        // measured 0.41 mm and 0.115 mm
        assert!(depth > 3.0 * lateral, "depth {depth:e} m, lateral {lateral:e} m");
        assert!((0.3e-3..0.5e-3).contains(&depth) && (0.08e-3..0.15e-3).contains(&lateral), "{depth:e} {lateral:e}");
        assert!(tag_pose_covariance(&k, 0.14, &Isometry3::translation(0.0, 0.0, -0.5), 0.2).is_none());
    }
}
