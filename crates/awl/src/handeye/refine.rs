//! Levenberg-Marquardt refinement of `X = ee_from_camera` jointly with `Y = base_from_target` over
//! all poses (not pairs: each measurement enters once, so the noise stays independent).
//!
//! Per pose, the discrepancy `D_i = Y^-1 * base_from_ee_i * X * camera_from_target_i` (identity for
//! perfect data; with target-frame detector noise `dT_i` it is `dT_i`) gives the residual
//! `(t(D_i), w log R(D_i))`: metres and radians weighted by `w` metres per radian. The update is
//! `t += dt`, `R = R exp(dw)` for `X` and `Y`; the 6N x 12 Jacobian is taken by central differences
//! (step 1e-6 m / rad). The cost is `sum |t(D_i)|^2 + w^2 |log R(D_i)|^2`.
//!
//! With per-pose whitening matrices `L_i` (a calibration capture's view covariances,
//! [`crate::handeye::capture`]), the residual is `L_i (t(D_i), log R(D_i))` instead (metres and
//! radians unweighted, then whitened: dimensionless), and the cost its squared norm summed.

use nalgebra::{Isometry3, Matrix6, SMatrix, SVector, Translation3, UnitQuaternion, Vector3, Vector6};
use serde::Serialize;

use crate::handeye::HandEyePose;

pub(crate) type Vector12 = SVector<f64, 12>;
type Matrix12 = SMatrix<f64, 12, 12>;

/// Statistics of one refinement.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RefineStats {
    /// LM steps taken (accepted or not).
    pub iterations: usize,
    /// True when the step or the relative cost change fell below 1e-12 before the iteration cap.
    pub converged: bool,
    /// Cost at the start (closed form and robust mean target), square metres.
    pub initial_cost: f64,
    /// Cost at the solution, square metres.
    pub final_cost: f64,
}

/// How far the refinement moved `T_ee_camera` from the closed forms, against how far the noise
/// lets it move (see [`crate::handeye`]'s module docs, step 2).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RefinementCheck {
    /// Translation between the refined and the method's closed-form `T_ee_camera`, millimetres.
    pub shift_mm: f64,
    /// Rotation between them, degrees.
    pub shift_deg: f64,
    /// Largest translation between two of the three closed forms (Park, Tsai, Daniilidis), millimetres.
    pub closed_form_spread_mm: f64,
    /// Largest rotation between two of them, degrees.
    pub closed_form_spread_deg: f64,
    /// The method's closed form's 1-sigma (3D RMS) by a grouped jackknife over the poses, millimetres.
    pub closed_form_sigma_mm: f64,
    /// Its rotation's 1-sigma (3D RMS), degrees.
    pub closed_form_sigma_deg: f64,
    /// The largest translation shift the noise explains: the spread plus 3 sigma of the difference
    /// (the closed form's and the refinement's 3D sigmas combined), millimetres.
    pub limit_mm: f64,
    /// The same for the rotation, degrees.
    pub limit_deg: f64,
    /// True when the refined solution is the result; false when the shift exceeded a limit and the
    /// closed form is the result.
    pub kept_refined: bool,
}

/// The weighted residual of one pose.
pub(crate) fn residual(p: &HandEyePose, x: &Isometry3<f64>, y_inv: &Isometry3<f64>, w: f64) -> Vector6<f64> {
    let d = y_inv * p.base_from_ee * x * p.camera_from_target;
    let r = d.rotation.scaled_axis() * w;
    let t = d.translation.vector;
    Vector6::new(t.x, t.y, t.z, r.x, r.y, r.z)
}

/// The residual of one pose: with a whitening matrix `white`, `white * (t(D), log R(D))`; without,
/// [`residual`] (rotation weighted by `w` metres per radian).
pub(crate) fn weighted_residual(
    p: &HandEyePose,
    x: &Isometry3<f64>,
    y_inv: &Isometry3<f64>,
    w: f64,
    white: Option<&Matrix6<f64>>,
) -> Vector6<f64> {
    match white {
        Some(l) => l * residual(p, x, y_inv, 1.0),
        None => residual(p, x, y_inv, w),
    }
}

/// Per-pose whitening matrices (aligned with the poses), or none: the rotation weight alone.
pub(crate) type Whitening<'a> = Option<&'a [Matrix6<f64>]>;

/// The refinement cost of `(x, y)` (see the module docs).
pub(crate) fn cost(poses: &[HandEyePose], x: &Isometry3<f64>, y: &Isometry3<f64>, w: f64, white: Whitening) -> f64 {
    let y_inv = y.inverse();
    (poses.iter().enumerate())
        .map(|(k, p)| weighted_residual(p, x, &y_inv, w, white.map(|m| &m[k])).norm_squared())
        .sum()
}

fn perturb(iso: &Isometry3<f64>, dt: Vector3<f64>, dw: Vector3<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(iso.translation.vector + dt),
        iso.rotation * UnitQuaternion::from_scaled_axis(dw),
    )
}

pub(crate) fn apply(x: &Isometry3<f64>, y: &Isometry3<f64>, s: &Vector12) -> (Isometry3<f64>, Isometry3<f64>) {
    let v = |k: usize| Vector3::new(s[k], s[k + 1], s[k + 2]);
    (perturb(x, v(0), v(3)), perturb(y, v(6), v(9)))
}

/// Step of the central differences of the unknowns of `(x, y)`.
pub(crate) const H: f64 = 1e-6;

/// `(x, y^-1)` shifted by `+H` and `-H` along each of the 12 unknowns, for central differences.
pub(crate) type Shifted = Vec<((Isometry3<f64>, Isometry3<f64>), (Isometry3<f64>, Isometry3<f64>))>;

/// [`Shifted`] at `(x, y)`.
pub(crate) fn shifted_unknowns(x: &Isometry3<f64>, y: &Isometry3<f64>) -> Shifted {
    (0..12)
        .map(|k| {
            let mut e = Vector12::zeros();
            e[k] = H;
            let (xp, yp) = apply(x, y, &e);
            let (xm, ym) = apply(x, y, &(-e));
            ((xp, yp.inverse()), (xm, ym.inverse()))
        })
        .collect()
}

/// Normal equations `(J^T J, J^T r)` at `(x, y)`.
fn normal_equations(
    poses: &[HandEyePose],
    x: &Isometry3<f64>,
    y: &Isometry3<f64>,
    w: f64,
    white: Whitening,
) -> (Matrix12, Vector12) {
    let shifted = shifted_unknowns(x, y);
    let y_inv = y.inverse();
    let (mut h, mut g) = (Matrix12::zeros(), Vector12::zeros());
    for (i, p) in poses.iter().enumerate() {
        let l = white.map(|m| &m[i]);
        let r = weighted_residual(p, x, &y_inv, w, l);
        let mut j = SMatrix::<f64, 6, 12>::zeros();
        for (k, ((xp, yp_inv), (xm, ym_inv))) in shifted.iter().enumerate() {
            let col = (weighted_residual(p, xp, yp_inv, w, l) - weighted_residual(p, xm, ym_inv, w, l)) / (2.0 * H);
            j.set_column(k, &col);
        }
        h += j.transpose() * j;
        g += j.transpose() * r;
    }
    (h, g)
}

/// Refines `(x, y)` over `poses` (whitened by `white` when given); returns the solution and its statistics.
pub(crate) fn refine(
    poses: &[HandEyePose],
    x0: &Isometry3<f64>,
    y0: &Isometry3<f64>,
    w: f64,
    white: Whitening,
    max_iterations: usize,
) -> (Isometry3<f64>, Isometry3<f64>, RefineStats) {
    let (mut x, mut y) = (*x0, *y0);
    let initial_cost = cost(poses, &x, &y, w, white);
    let mut current = initial_cost;
    let mut lambda = 1e-6;
    let mut stats = RefineStats { iterations: 0, converged: false, initial_cost, final_cost: initial_cost };
    while stats.iterations < max_iterations {
        stats.iterations += 1;
        let (h, g) = normal_equations(poses, &x, &y, w, white);
        let mut damped = h;
        for i in 0..12 {
            damped[(i, i)] += lambda * h[(i, i)].max(1e-12);
        }
        let Some(step) = damped.cholesky().map(|c| -c.solve(&g)) else {
            lambda *= 10.0;
            continue;
        };
        let (cx, cy) = apply(&x, &y, &step);
        let next = cost(poses, &cx, &cy, w, white);
        if next <= current {
            let change = current - next;
            (x, y, current) = (cx, cy, next);
            lambda = (lambda * 0.1).max(1e-12);
            if step.norm() < 1e-12 || change <= 1e-12 * current.max(1e-30) {
                stats.converged = true;
                break;
            }
        } else {
            lambda *= 10.0;
            if step.norm() < 1e-12 || lambda > 1e12 {
                stats.converged = step.norm() < 1e-12;
                break;
            }
        }
    }
    stats.final_cost = current;
    (x, y, stats)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transform::isometry_from_translation_rotvec;

    #[test]
    fn refinement_reaches_the_truth_from_a_perturbed_start_on_exact_data() {
        let x = isometry_from_translation_rotvec(Vector3::new(0.03, -0.02, 0.05), Vector3::new(0.2, -1.4, 0.3));
        let y = isometry_from_translation_rotvec(Vector3::new(0.6, 0.1, 0.0), Vector3::new(0.1, 0.5, -0.2));
        let poses: Vec<HandEyePose> = (0..6)
            .map(|k| {
                let f = k as f64;
                let e = isometry_from_translation_rotvec(
                    Vector3::new(0.3 + 0.02 * f, -0.1 * f.sin(), 0.4),
                    Vector3::new(0.3 * f.cos(), 0.4 * (2.0 * f).sin(), 0.5 * f - 1.0),
                );
                HandEyePose { base_from_ee: e, camera_from_target: (e * x).inverse() * y }
            })
            .collect();
        let kick = isometry_from_translation_rotvec(Vector3::new(0.01, -0.02, 0.005), Vector3::new(0.05, 0.03, -0.04));
        let (rx, ry, stats) = refine(&poses, &(x * kick), &(y * kick), 0.5, None, 50);
        let (dx, rxe) = crate::transform::pose_difference(&rx, &x);
        let (dy, rye) = crate::transform::pose_difference(&ry, &y);
        assert!(stats.converged && stats.final_cost < 1e-24, "{stats:?}");
        assert!(dx < 1e-11 && rxe < 1e-11 && dy < 1e-11 && rye < 1e-11, "{dx:e} {rxe:e} {dy:e} {rye:e}");
    }
}
