//! The calibration pipeline: validation, closed form, refinement, residuals, outlier rejection.

use nalgebra::{Isometry3, Matrix6};

use crate::error::{Error, Result};
use crate::handeye::diagnosis::{Diagnosis, HandEyeWarning, Inversion, InversionFit, inversion_fits};
use crate::handeye::diversity::{MotionDiversity, diversity};
use crate::handeye::motion::{Motion, pose_pairs};
use crate::handeye::refine::{RefineStats, RefinementCheck, Whitening, cost, refine};
use crate::handeye::residual::{PoseResidual, implied_targets, median, residuals, robust_mean};
use crate::handeye::uncertainty::{HandEyeUncertainty, uncertainty};
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
    let d = iso.translation.vector.amax();
    if d > MAX_POSE_TRANSLATION_M {
        return Err(Error::invalid(
            what(),
            format!(
                "a translation coordinate of {d:.3e} m, beyond the {MAX_POSE_TRANSLATION_M} m a flange or a tag is from the robot \
                 base or the camera: poses are in metres (not millimetres); check this pose"
            ),
        ));
    }
    Ok(())
}

/// The farthest a hand-eye pose's translation may reach (`T_base_ee`: an arm's reach; `T_camera_target`:
/// a tag seen by the camera), metres.
pub const MAX_POSE_TRANSLATION_M: f64 = 100.0;

/// How many of its sigmas the fitted target scale must differ from 1 for [`Diagnosis::ScaleMismatch`].
pub const SCALE_MISMATCH_SIGMAS: f64 = 3.0;

/// The most refinement iterations [`HandEyeParams::max_iterations`] may ask for.
pub const MAX_ITERATIONS: usize = 10_000;

/// Refuses a result with a non-finite value (a NaN residual would otherwise reach the output file),
/// naming the first pose whose residual is not finite.
fn check_result(result: &HandEyeResult) -> Result<()> {
    if let Some(r) = result.residuals.iter().find(|r| !(r.translation_mm.is_finite() && r.rotation_deg.is_finite())) {
        return Err(Error::invalid(
            format!("poses[{}]", r.index),
            format!(
                "its residual is not finite ({} mm / {} deg): the pose is degenerate or far off; remove it",
                r.translation_mm, r.rotation_deg
            ),
        ));
    }
    let finite =
        |x: &Isometry3<f64>| x.translation.vector.iter().chain(x.rotation.coords.iter()).all(|v| v.is_finite());
    let rms = [
        result.rms_translation_mm,
        result.rms_rotation_deg,
        result.rms_all_translation_mm,
        result.rms_all_rotation_deg,
    ];
    if !finite(&result.ee_from_camera) || !finite(&result.base_from_target) || rms.iter().any(|v| !v.is_finite()) {
        return Err(Error::invalid(
            "poses",
            "the calibration's result is not finite: check the poses for a degenerate one",
        ));
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
    params.validate()?;
    if poses.len() > params.max_poses {
        return Err(Error::invalid(
            "poses",
            format!(
                "{} poses, more than max_poses {}; raise max_poses (--max-poses) or calibrate from a subset",
                poses.len(),
                params.max_poses
            ),
        ));
    }
    for (i, p) in poses.iter().enumerate() {
        check_isometry(&p.base_from_ee, || format!("poses[{i}].T_base_ee"))?;
        check_isometry(&p.camera_from_target, || format!("poses[{i}].T_camera_target"))?;
    }
    Ok(())
}

impl HandEyeParams {
    /// Checks every setting.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the field (`outlier_factor`, ...) that is out of range.
    pub fn validate(&self) -> Result<()> {
        let positive = [
            ("rotation_weight_m", self.rotation_weight_m),
            ("outlier_factor", self.outlier_factor),
            ("outlier_floor_mm", self.outlier_floor_mm),
            ("outlier_floor_deg", self.outlier_floor_deg),
            ("tolerance_mm", self.tolerance_mm),
            ("max_scale_sigma_percent", self.max_scale_sigma_percent),
            ("scale_mismatch_percent", self.scale_mismatch_percent),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::invalid(name, format!("must be a positive number, got {v}")));
            }
        }
        let angles = [
            ("min_pair_angle_deg", self.min_pair_angle_deg),
            ("min_axis_angle_deg", self.min_axis_angle_deg),
            ("degenerate_axis_angle_deg", self.degenerate_axis_angle_deg),
            ("max_rejected_fraction", self.max_rejected_fraction),
            ("min_noise_mm", self.min_noise_mm),
        ];
        for (name, v) in angles {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::invalid(name, format!("must be a non-negative number, got {v}")));
            }
        }
        if self.max_rejected_fraction > 1.0 {
            let v = self.max_rejected_fraction;
            return Err(Error::invalid("max_rejected_fraction", format!("must be at most 1, got {v}")));
        }
        if !(self.inverted_fit_factor.is_finite() && self.inverted_fit_factor >= 1.0) {
            let v = self.inverted_fit_factor;
            return Err(Error::invalid("inverted_fit_factor", format!("must be a number >= 1, got {v}")));
        }
        if self.refine && self.max_iterations == 0 {
            return Err(Error::invalid("max_iterations", "must be at least 1 when refining"));
        }
        if self.max_iterations > MAX_ITERATIONS {
            let v = self.max_iterations;
            return Err(Error::invalid("max_iterations", format!("must be at most {MAX_ITERATIONS}, got {v}")));
        }
        if self.max_poses < 3 {
            return Err(Error::invalid("max_poses", format!("must be at least 3, got {}", self.max_poses)));
        }
        Ok(())
    }
}

/// One solve on a subset of poses.
struct Solve {
    closed: Isometry3<f64>,
    refined: Isometry3<f64>,
    base_from_target: Isometry3<f64>,
    stats: RefineStats,
    diversity: MotionDiversity,
}

fn solve_subset(poses: &[HandEyePose], white: Whitening, params: &HandEyeParams) -> Result<Solve> {
    let motions: Vec<Motion> = pose_pairs(poses);
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
    let closed = closed_form(&motions, params.method)?;
    let w = params.rotation_weight_m;
    let all: Vec<usize> = (0..poses.len()).collect();
    let y0 = robust_mean(&implied_targets(poses, &closed), &all);
    let (refined, base_from_target, stats) = if params.refine {
        refine(poses, &closed, &y0, w, white, params.max_iterations)
    } else {
        let c = cost(poses, &closed, &y0, w, white);
        (closed, y0, RefineStats { iterations: 0, converged: true, initial_cost: c, final_cost: c })
    };
    Ok(Solve { closed, refined, base_from_target, stats, diversity })
}

/// `ee_from_camera` by `method`'s closed form over `motions`.
fn closed_form(motions: &[Motion], method: HandEyeMethod) -> Result<Isometry3<f64>> {
    match method {
        HandEyeMethod::Park => park::solve(motions),
        HandEyeMethod::Tsai => tsai::solve(motions),
        HandEyeMethod::Daniilidis => daniilidis::solve(motions),
    }
}

/// How many groups the closed form's jackknife leaves out in turn (one pose each up to this count).
const JACKKNIFE_GROUPS: usize = 12;

/// The 3D RMS 1-sigma (metres, radians) of `method`'s closed form over `poses`, by the grouped
/// jackknife: group `g` holds the poses `i` with `i % G == g`, `G = min(N, 12)`; each group left out
/// in turn gives `X_g`, and the variance is `(G - 1) / G * sum |X_g - mean|^2` (translations; rotations
/// as rotation vectors from `centre`). Groups whose solve fails are skipped; none left gives infinity.
fn jackknife_sigma(poses: &[HandEyePose], method: HandEyeMethod, centre: &Isometry3<f64>) -> (f64, f64) {
    let groups = poses.len().min(JACKKNIFE_GROUPS);
    let solutions: Vec<(nalgebra::Vector3<f64>, nalgebra::Vector3<f64>)> = (0..groups)
        .filter_map(|g| {
            let kept: Vec<HandEyePose> =
                poses.iter().enumerate().filter(|(i, _)| i % groups != g).map(|(_, p)| *p).collect();
            let x = closed_form(&pose_pairs(&kept), method).ok()?;
            Some((x.translation.vector, (centre.rotation.inverse() * x.rotation).scaled_axis()))
        })
        .collect();
    if solutions.len() < 2 {
        return (f64::INFINITY, f64::INFINITY);
    }
    let count = solutions.len() as f64;
    let mean_t = solutions.iter().map(|s| s.0).sum::<nalgebra::Vector3<f64>>() / count;
    let mean_r = solutions.iter().map(|s| s.1).sum::<nalgebra::Vector3<f64>>() / count;
    let factor = (count - 1.0) / count;
    let var_t = factor * solutions.iter().map(|s| (s.0 - mean_t).norm_squared()).sum::<f64>();
    let var_r = factor * solutions.iter().map(|s| (s.1 - mean_r).norm_squared()).sum::<f64>();
    (var_t.sqrt(), var_r.sqrt())
}

/// Compares the refined `X` with the closed forms over the final inliers (module docs, step 2): the
/// refined one is kept when its shift from the method's closed form stays within the closed forms'
/// spread plus 3 sigma of the difference (the closed form's jackknife sigma and the refinement's
/// sigma combined, 3D RMS), in translation and in rotation. The refinement's sigma scales with
/// `rotation_weight_m` (at 30 m/rad the limits reach 80-500 mm); without it the limits are tighter
/// but a principal point 2 % off falls back to a closed form 2.4 mm worse (simulated seed 4).
fn refinement_check(
    inliers: &[HandEyePose],
    solve: &Solve,
    uncertainty: &HandEyeUncertainty,
    method: HandEyeMethod,
) -> RefinementCheck {
    let motions = pose_pairs(inliers);
    let closed: Vec<Isometry3<f64>> = [HandEyeMethod::Park, HandEyeMethod::Tsai, HandEyeMethod::Daniilidis]
        .into_iter()
        .filter_map(|m| if m == method { Some(solve.closed) } else { closed_form(&motions, m).ok() })
        .collect();
    let (mut spread_t, mut spread_r) = (0.0f64, 0.0f64);
    for (k, a) in closed.iter().enumerate() {
        for b in &closed[k + 1..] {
            spread_t = spread_t.max((a.translation.vector - b.translation.vector).norm());
            spread_r = spread_r.max(a.rotation.angle_to(&b.rotation));
        }
    }
    let (sigma_t, sigma_r) = jackknife_sigma(inliers, method, &solve.closed);
    let u = uncertainty;
    let refined_t2 = u.translation_sigma_mm.iter().map(|s| (s * 1e-3).powi(2)).sum::<f64>();
    let refined_r2 = u.rotation_sigma_deg.iter().map(|s| s.to_radians().powi(2)).sum::<f64>();
    let limit_t = spread_t + 3.0 * (sigma_t * sigma_t + refined_t2).sqrt();
    let limit_r = spread_r + 3.0 * (sigma_r * sigma_r + refined_r2).sqrt();
    let shift_t = (solve.refined.translation.vector - solve.closed.translation.vector).norm();
    let shift_r = solve.refined.rotation.angle_to(&solve.closed.rotation);
    RefinementCheck {
        shift_mm: shift_t * 1e3,
        shift_deg: shift_r.to_degrees(),
        closed_form_spread_mm: spread_t * 1e3,
        closed_form_spread_deg: spread_r.to_degrees(),
        closed_form_sigma_mm: sigma_t * 1e3,
        closed_form_sigma_deg: sigma_r.to_degrees(),
        limit_mm: limit_t * 1e3,
        limit_deg: limit_r.to_degrees(),
        kept_refined: shift_t <= limit_t && shift_r <= limit_r,
    }
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
    calibrate_weighted(poses, None, params)
}

/// [`calibrate`] with the refinement's residuals whitened per pose by `white` (aligned with
/// `poses`; see `handeye::refine`); the closed form, the residuals, the outlier rule and
/// [`HandEyeResult::uncertainty`] (from the unweighted residuals at the weighted solution) are
/// [`calibrate`]'s.
///
/// # Errors
/// [`calibrate`]'s, and [`Error::Invalid`] when `white` does not hold one matrix a pose.
pub(crate) fn calibrate_weighted(
    poses: &[HandEyePose],
    white: Option<&[Matrix6<f64>]>,
    params: &HandEyeParams,
) -> Result<HandEyeResult> {
    validate(poses, params)?;
    if let Some(m) = white
        && (m.len() != poses.len() || !m.iter().all(|m| m.iter().all(|v| v.is_finite())))
    {
        return Err(Error::invalid(
            "whitening",
            format!("{} finite matrices for {} poses (one a pose is needed)", m.len(), poses.len()),
        ));
    }
    let n = poses.len();
    let max_rejected = ((params.max_rejected_fraction * n as f64).floor() as usize).min(n - 3);
    let mut inlier = vec![true; n];
    let mut rejected = Vec::new();
    let mut warnings = Vec::new();
    loop {
        let subset: Vec<HandEyePose> = poses.iter().zip(&inlier).filter(|(_, k)| **k).map(|(p, _)| *p).collect();
        let subset_white: Option<Vec<Matrix6<f64>>> =
            white.map(|m| m.iter().zip(&inlier).filter(|(_, k)| **k).map(|(m, _)| *m).collect());
        let solve = solve_subset(&subset, subset_white.as_deref(), params)?;
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
            warnings.push(HandEyeWarning::new(
                Diagnosis::RejectionCapReached,
                format!(
                    "pose {worst} still looks like an outlier, but {} of {n} poses are rejected already (the cap, \
                     max_rejected_fraction {}): check the capture, or raise the cap",
                    rejected.len(),
                    params.max_rejected_fraction
                ),
            ));
        }
        let inliers: Vec<HandEyePose> = poses.iter().zip(&inlier).filter(|(_, k)| **k).map(|(p, _)| *p).collect();
        let uncertainty = uncertainty(
            &inliers,
            &solve.refined,
            &solve.base_from_target,
            params.rotation_weight_m,
            params.min_noise_mm * 1e-3,
        );
        let mut solve = solve;
        let mut res = res;
        let refined_ee_from_camera = solve.refined;
        let check = params.refine.then(|| refinement_check(&inliers, &solve, &uncertainty, params.method));
        if let Some(c) = check.filter(|c| !c.kept_refined) {
            warnings.push(HandEyeWarning::new(
                Diagnosis::RefinementDisagrees,
                format!(
                    "the refinement moved T_ee_camera {:.2} mm / {:.3} deg from the {} closed form, more than the \
                     noise explains ({:.2} mm / {:.3} deg: the closed forms' spread {:.2} mm / {:.3} deg plus 3 sigma); \
                     the result is the closed form. The poses likely hold a systematic error (a wrong tag size, a \
                     biased detector, or noise unlike rotation_weight_m {} m/rad): check the other warnings",
                    c.shift_mm,
                    c.shift_deg,
                    params.method.name(),
                    c.limit_mm,
                    c.limit_deg,
                    c.closed_form_spread_mm,
                    c.closed_form_spread_deg,
                    params.rotation_weight_m
                ),
            ));
            let targets = implied_targets(poses, &solve.closed);
            solve.refined = solve.closed;
            solve.base_from_target = robust_mean(&targets, &kept);
            res = residuals(&targets, &solve.base_from_target, &inlier);
        }
        let fits = inversion_fits(poses);
        check_convention(&res, &fits, &solve, params, &mut warnings)?;
        let mut result = finish(solve, res, rejected, warnings, uncertainty, fits, params);
        result.refined_ee_from_camera = refined_ee_from_camera;
        result.refinement_check = check;
        check_result(&result)?;
        return Ok(result);
    }
}

/// Refuses (or, with `allow_inverted_fit`, warns) when the poses look inverted: one field inverted
/// fits them `inverted_fit_factor` times better than the poses as given (see
/// [`HandEyeParams::inverted_fit_factor`]); or both fields inverted, which fits exactly as well (the
/// solver then returns `T_base_target` as `T_ee_camera` and the reverse), betrayed by a camera
/// farther from the flange than the target from the robot base.
fn check_convention(
    res: &[PoseResidual],
    fits: &[InversionFit],
    solve: &Solve,
    params: &HandEyeParams,
    warnings: &mut Vec<HandEyeWarning>,
) -> Result<()> {
    let mut given: Vec<f64> = res.iter().map(|r| r.translation_mm).collect();
    let given = median(&mut given);
    let singles: Vec<&InversionFit> = fits.iter().filter(|f| f.inversion != Inversion::Both).collect();
    let best = singles.iter().copied().min_by(|a, b| a.median_translation_mm.total_cmp(&b.median_translation_mm));
    // The two single inversions are each other's both-inverted: on exact data both fit, one with
    // T_ee_camera and T_base_target swapped, and their residuals differ only by the lever arms the
    // noise acts on. Of those that fit, the one named puts the camera nearer the flange, relative to
    // the target's distance from the base (the same plausibility as the both-inverted rule below).
    let ratio = |f: &InversionFit| f.camera_from_flange_m / f.target_from_base_m.max(1e-9);
    let fitting = |f: &&InversionFit| f.median_translation_mm * params.inverted_fit_factor <= given;
    let chosen = singles.iter().copied().filter(fitting).min_by(|a, b| ratio(a).total_cmp(&ratio(b)));
    let accept = "or accept the poses as given with allow_inverted_fit (--allow-inverted-fit)";
    // shuffled or shifted pairs fit no convention either, and can look like an inverted one
    let pairs = "the robot and camera poses are not pairs taken at the same moments (shuffled, shifted by one, or \
                 stamped at different times): pose k's T_base_ee and T_camera_target must be recorded at the same stop";
    let (what, message) = match chosen {
        Some(chosen) if given > params.outlier_floor_mm => {
            let fields = chosen.inversion.fields();
            let (what, holds) = match chosen.inversion {
                Inversion::BaseFromEe => ("poses[*].T_base_ee", "T_ee_base"),
                _ => ("poses[*].T_camera_target", "T_target_camera"),
            };
            let other = singles.iter().find(|f| f.inversion != chosen.inversion).map_or(String::new(), |o| {
                format!(
                    " (with every {} inverted instead they fit {} ({:.2} mm), but put the camera {:.3} m from the \
                     flange and the target {:.3} m from the robot base, against {:.3} m and {:.3} m)",
                    o.inversion.fields(),
                    if fitting(o) { "too" } else { "worse" },
                    o.median_translation_mm,
                    o.camera_from_flange_m,
                    o.target_from_base_m,
                    chosen.camera_from_flange_m,
                    chosen.target_from_base_m,
                )
            });
            let message = format!(
                "the poses fit {:.0}x better with every {fields} inverted (median residual {:.2} mm / {:.3} deg, \
                 against {given:.1} mm as given){other}: the file most likely holds {holds}; invert {fields} in \
                 every pose, {accept}. If it does hold the fields as named, {pairs}",
                given / chosen.median_translation_mm.max(1e-12),
                chosen.median_translation_mm,
                chosen.median_rotation_deg,
            );
            (what, message)
        }
        _ => {
            let camera_m = solve.refined.translation.vector.norm();
            let target_m = solve.base_from_target.translation.vector.norm();
            if camera_m <= target_m {
                return Ok(());
            }
            let message = if given > params.outlier_floor_mm {
                // both inverted fit exactly as well as the right convention: a bad fit as given is not that
                let single = best.map_or(f64::NAN, |b| b.median_translation_mm);
                format!(
                    "the poses fit no convention (median residual {given:.1} mm as given, {single:.1} mm with the \
                     better single field inverted) and the solution puts the camera {camera_m:.3} m from the flange, \
                     farther than the target from the robot base ({target_m:.3} m): most likely {pairs}. If they are \
                     pairs, the file may hold T_ee_base and T_target_camera: invert both fields in every pose, {accept}"
                )
            } else {
                format!(
                    "the solution puts the camera {camera_m:.3} m from the flange, farther than the target from the \
                     robot base ({target_m:.3} m): the file most likely holds T_ee_base and T_target_camera (both \
                     inverted fit exactly as well, with T_ee_camera and T_base_target swapped); invert both fields in \
                     every pose, {accept}. Or {pairs}"
                )
            };
            ("poses[*].T_base_ee and T_camera_target", message)
        }
    };
    if params.allow_inverted_fit {
        warnings.push(HandEyeWarning::new(Diagnosis::InvertedConvention, message));
        Ok(())
    } else {
        Err(Error::invalid(what, message))
    }
}

fn finish(
    solve: Solve,
    res: Vec<PoseResidual>,
    rejected: Vec<usize>,
    mut warnings: Vec<HandEyeWarning>,
    uncertainty: HandEyeUncertainty,
    inversion_fits: Vec<InversionFit>,
    params: &HandEyeParams,
) -> HandEyeResult {
    let d = solve.diversity;
    if d.axis_angle_deg < params.min_axis_angle_deg {
        warnings.push(HandEyeWarning::new(
            Diagnosis::PoorMotionDiversity,
            format!(
                "poor motion diversity: the rotation axes span only {:.2} deg (want >= {} deg); the rotation about \
                 the dominant axis and the translation along it are poorly determined: rotate the flange about \
                 other axes too",
                d.axis_angle_deg, params.min_axis_angle_deg
            ),
        ));
    }
    if !solve.stats.converged {
        warnings.push(HandEyeWarning::new(
            Diagnosis::RefinementNotConverged,
            format!(
                "refinement did not converge in {} iterations (max_iterations): the result may not be the \
                 least-squares solution",
                solve.stats.iterations
            ),
        ));
    }
    let u = &uncertainty;
    if u.translation_bound_95_mm > params.tolerance_mm {
        let [x, y, z] = u.worst_translation_direction;
        warnings.push(HandEyeWarning::new(
            Diagnosis::TranslationUndetermined,
            format!(
                "translation not determined to the tolerance: T_ee_camera's translation error is predicted within \
                 {:.2} mm (95 %), over tolerance_mm {} (1-sigma {:.2} mm along its worst direction [{x:.2}, {y:.2}, \
                 {z:.2}], flange frame; per axis x {:.2}, y {:.2}, z {:.2} mm): add poses that rotate the flange \
                 more, and about axes perpendicular to that direction (tilt the camera more around the target)",
                u.translation_bound_95_mm,
                params.tolerance_mm,
                u.worst_translation_sigma_mm,
                u.translation_sigma_mm[0],
                u.translation_sigma_mm[1],
                u.translation_sigma_mm[2],
            ),
        ));
    }
    let scale_percent = (u.fitted_scale - 1.0) * 100.0;
    if u.scale_sigma_percent > params.max_scale_sigma_percent {
        warnings.push(HandEyeWarning::new(
            Diagnosis::ScaleUndetermined,
            format!(
                "target scale not determined: a scale factor on the T_camera_target translations (a wrong tag or \
                 board size) has a 1-sigma of {:.2} % (max_scale_sigma_percent {}); a 3 % size error would move \
                 T_ee_camera's translation by {:.1} mm without raising the residuals: check the tag size, and add \
                 poses at other distances from the target (nearer and farther) with the flange moving, not only \
                 rotating about the target",
                u.scale_sigma_percent,
                params.max_scale_sigma_percent,
                3.0 * u.translation_mm_per_scale_percent,
            ),
        ));
    } else if scale_percent.abs() > params.scale_mismatch_percent
        && scale_percent.abs() > SCALE_MISMATCH_SIGMAS * u.scale_sigma_percent
    {
        warnings.push(HandEyeWarning::new(
            Diagnosis::ScaleMismatch,
            format!(
                "tag or board size wrong: the T_camera_target translations fit best scaled by {:.4} ({scale_percent:+.2} \
                 % +- {:.2} % at 1 sigma; scale_mismatch_percent {}): the size given to the detector is {:.1} % too \
                 {}. Measure the printed tag / board square and give the detector its true size (about {:.4} x the \
                 size given), then calibrate again; the size error moves T_ee_camera's translation by about {:.1} mm",
                u.fitted_scale,
                u.scale_sigma_percent,
                params.scale_mismatch_percent,
                (1.0 / u.fitted_scale - 1.0).abs() * 100.0,
                if u.fitted_scale < 1.0 { "large" } else { "small" },
                u.fitted_scale,
                scale_percent.abs() * u.translation_mm_per_scale_percent,
            ),
        ));
    }
    let rms = |rows: &[&PoseResidual]| {
        let count = rows.len().max(1) as f64;
        (
            (rows.iter().map(|r| r.translation_mm.powi(2)).sum::<f64>() / count).sqrt(),
            (rows.iter().map(|r| r.rotation_deg.powi(2)).sum::<f64>() / count).sqrt(),
        )
    };
    let inliers: Vec<&PoseResidual> = res.iter().filter(|r| r.inlier).collect();
    let (rms_translation_mm, rms_rotation_deg) = rms(&inliers);
    let (rms_all_translation_mm, rms_all_rotation_deg) = rms(&res.iter().collect::<Vec<_>>());
    HandEyeResult {
        ee_from_camera: solve.refined,
        closed_form_ee_from_camera: solve.closed,
        refined_ee_from_camera: solve.refined,
        base_from_target: solve.base_from_target,
        method: params.method,
        residuals: res,
        rejected,
        rms_translation_mm,
        rms_rotation_deg,
        rms_all_translation_mm,
        rms_all_rotation_deg,
        uncertainty,
        inversion_fits,
        diversity: d,
        refinement: solve.stats,
        refinement_check: None,
        warnings,
    }
}
