//! The calibration pipeline: validation, closed form, refinement, residuals, outlier rejection.

use nalgebra::Isometry3;

use crate::error::{Error, Result};
use crate::handeye::diversity::{MotionDiversity, diversity};
use crate::handeye::motion::{Motion, all_pairs};
use crate::handeye::refine::{RefineStats, cost, refine};
use crate::handeye::residual::{PoseResidual, implied_targets, median, residuals, robust_mean};
use crate::handeye::{HandEyeMethod, HandEyeParams, HandEyePose, HandEyeResult, daniilidis, park, tsai};

/// Largest deviation of a quaternion's norm from 1 accepted as rigid.
const UNIT_TOLERANCE: f64 = 1e-6;

fn check_isometry(iso: &Isometry3<f64>, what: impl FnOnce() -> String) -> Result<()> {
    let q = iso.rotation.quaternion();
    if !iso.translation.vector.iter().chain(q.coords.iter()).all(|v| v.is_finite()) {
        return Err(Error::invalid(what(), "non-finite value (NaN or infinity)"));
    }
    let norm = q.norm();
    if (norm - 1.0).abs() > UNIT_TOLERANCE {
        return Err(Error::invalid(what(), format!("not a rigid transform (rotation quaternion norm {norm})")));
    }
    Ok(())
}

fn validate(poses: &[HandEyePose], params: &HandEyeParams) -> Result<()> {
    if poses.len() < 3 {
        return Err(Error::invalid(
            "poses",
            format!("hand-eye calibration needs at least 3 poses, got {}", poses.len()),
        ));
    }
    for (i, p) in poses.iter().enumerate() {
        check_isometry(&p.base_from_ee, || format!("poses[{i}].T_base_ee"))?;
        check_isometry(&p.camera_from_target, || format!("poses[{i}].T_camera_target"))?;
    }
    let positive = [
        ("rotation_weight_m", params.rotation_weight_m),
        ("outlier_factor", params.outlier_factor),
        ("outlier_floor_mm", params.outlier_floor_mm),
        ("outlier_floor_deg", params.outlier_floor_deg),
    ];
    for (name, v) in positive {
        if !(v.is_finite() && v > 0.0) {
            return Err(Error::invalid(name, format!("must be a positive number, got {v}")));
        }
    }
    let angles = [
        ("min_pair_angle_deg", params.min_pair_angle_deg),
        ("min_axis_angle_deg", params.min_axis_angle_deg),
        ("degenerate_axis_angle_deg", params.degenerate_axis_angle_deg),
        ("max_rejected_fraction", params.max_rejected_fraction),
    ];
    for (name, v) in angles {
        if !(v.is_finite() && v >= 0.0) {
            return Err(Error::invalid(name, format!("must be a non-negative number, got {v}")));
        }
    }
    Ok(())
}

/// One solve on a subset of poses.
struct Solve {
    closed: Isometry3<f64>,
    refined: Isometry3<f64>,
    base_from_target: Isometry3<f64>,
    stats: RefineStats,
    diversity: MotionDiversity,
}

fn solve_subset(poses: &[HandEyePose], params: &HandEyeParams) -> Result<Solve> {
    let motions: Vec<Motion> = all_pairs(poses);
    let diversity = diversity(&motions, params.min_pair_angle_deg.to_radians());
    if diversity.rotating_pairs < 2 || diversity.axis_angle_deg < params.degenerate_axis_angle_deg {
        return Err(Error::invalid(
            "poses",
            format!(
                "degenerate motion: {} pose pairs rotate more than {} deg and their rotation axes span {:.3} deg \
                 (need >= {} deg): rotate the arm about at least two different axes",
                diversity.rotating_pairs,
                params.min_pair_angle_deg,
                diversity.axis_angle_deg,
                params.degenerate_axis_angle_deg
            ),
        ));
    }
    let closed = match params.method {
        HandEyeMethod::Park => park::solve(&motions)?,
        HandEyeMethod::Tsai => tsai::solve(&motions)?,
        HandEyeMethod::Daniilidis => daniilidis::solve(&motions)?,
    };
    let w = params.rotation_weight_m;
    let all: Vec<usize> = (0..poses.len()).collect();
    let y0 = robust_mean(&implied_targets(poses, &closed), &all);
    let (refined, base_from_target, stats) = if params.refine {
        refine(poses, &closed, &y0, w, params.max_iterations)
    } else {
        let c = cost(poses, &closed, &y0, w);
        (closed, y0, RefineStats { iterations: 0, converged: true, initial_cost: c, final_cost: c })
    };
    Ok(Solve { closed, refined, base_from_target, stats, diversity })
}

/// Index of the worst outlier among the inliers, if any (see the module docs for the rule).
fn worst_outlier(res: &[PoseResidual], params: &HandEyeParams) -> Option<usize> {
    let mut t: Vec<f64> = res.iter().filter(|r| r.inlier).map(|r| r.translation_mm).collect();
    let mut r: Vec<f64> = res.iter().filter(|r| r.inlier).map(|r| r.rotation_deg).collect();
    let limit_t = (params.outlier_factor * median(&mut t)).max(params.outlier_floor_mm);
    let limit_r = (params.outlier_factor * median(&mut r)).max(params.outlier_floor_deg);
    res.iter()
        .filter(|p| p.inlier)
        .map(|p| (p.index, (p.translation_mm / limit_t).max(p.rotation_deg / limit_r)))
        .filter(|&(_, ratio)| ratio > 1.0)
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(i, _)| i)
}

/// Calibrates `ee_from_camera` from `poses` (see the module docs for the method).
///
/// # Errors
/// [`Error::Invalid`] naming `poses[i].T_base_ee` / `poses[i].T_camera_target` for a non-finite or
/// non-rigid pose, `poses` for fewer than 3 poses or degenerate motion, or the parameter at fault.
pub fn calibrate(poses: &[HandEyePose], params: &HandEyeParams) -> Result<HandEyeResult> {
    validate(poses, params)?;
    let n = poses.len();
    let max_rejected = ((params.max_rejected_fraction * n as f64).floor() as usize).min(n - 3);
    let mut inlier = vec![true; n];
    let mut rejected = Vec::new();
    let mut warnings = Vec::new();
    loop {
        let subset: Vec<HandEyePose> = poses.iter().zip(&inlier).filter(|(_, k)| **k).map(|(p, _)| *p).collect();
        let solve = solve_subset(&subset, params)?;
        let targets = implied_targets(poses, &solve.refined);
        let kept: Vec<usize> = (0..n).filter(|&i| inlier[i]).collect();
        let mean = robust_mean(&targets, &kept);
        let res = residuals(&targets, &mean, &inlier);
        if let Some(worst) = worst_outlier(&res, params) {
            if rejected.len() < max_rejected {
                inlier[worst] = false;
                rejected.push(worst);
                continue;
            }
            warnings.push(format!(
                "pose {worst} still looks like an outlier, but {} of {n} poses are rejected already (the cap)",
                rejected.len()
            ));
        }
        return Ok(finish(solve, res, rejected, warnings, params));
    }
}

fn finish(
    solve: Solve,
    res: Vec<PoseResidual>,
    rejected: Vec<usize>,
    mut warnings: Vec<String>,
    params: &HandEyeParams,
) -> HandEyeResult {
    let d = solve.diversity;
    if d.axis_angle_deg < params.min_axis_angle_deg {
        warnings.push(format!(
            "poor motion diversity: the rotation axes span only {:.2} deg (want >= {} deg); the rotation about \
             the dominant axis and the translation along it are poorly determined",
            d.axis_angle_deg, params.min_axis_angle_deg
        ));
    }
    if !solve.stats.converged {
        warnings.push(format!("refinement did not converge in {} iterations", solve.stats.iterations));
    }
    let inliers: Vec<&PoseResidual> = res.iter().filter(|r| r.inlier).collect();
    let count = inliers.len().max(1) as f64;
    let rms_translation_mm = (inliers.iter().map(|r| r.translation_mm.powi(2)).sum::<f64>() / count).sqrt();
    let rms_rotation_deg = (inliers.iter().map(|r| r.rotation_deg.powi(2)).sum::<f64>() / count).sqrt();
    HandEyeResult {
        ee_from_camera: solve.refined,
        closed_form_ee_from_camera: solve.closed,
        base_from_target: solve.base_from_target,
        method: params.method,
        residuals: res,
        rejected,
        rms_translation_mm,
        rms_rotation_deg,
        diversity: d,
        refinement: solve.stats,
        warnings,
    }
}
