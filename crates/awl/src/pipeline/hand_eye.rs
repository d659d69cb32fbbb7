//! The hand-eye refined from the registered scan (a fuse stage after registration): every base stop
//! with two or more registered views gives `A X = X B` (registered camera motion, recorded flange
//! motion), solved with the recorded `T_ee_camera` as a prior by [`crate::handeye::chain`]. One stop
//! is enough (a fixed arm's scan) when its turns span two axes. Views that disagree with the others
//! are left out stop by stop (with one stop, view by view, down to a third of them); a residual scale
//! above [`DECLINE_RESIDUAL_SCALE`] with nothing left to leave out declines, naming the registrations.
//!
//! It changes nothing of the model: the model frame stays the one the anchor view's recorded pose
//! puts it in (`T_world_base * T_base_ee * T_ee_camera` with the recorded hand-eye), and so do the
//! view poses and `T_world_tag`; the refined hand-eye and its covariance go into report.json and
//! workpiece.json for `awl pierce`, which places the camera on the flange with it.

use nalgebra::{Isometry3, Matrix6, Vector3, Vector6};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::handeye::chain::{
    ChainEstimate, ChainNoise, ChainParams, ChainPrior, ChainView, StopPrior, refine_chain_observed,
};
use crate::scan::{Scan, ViewPose};
use crate::transform::{Rows, rows_from_isometry};

/// Settings of the hand-eye refinement.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct HandEyeConfig {
    /// 1-sigma per axis of the recorded `T_ee_camera`'s translation error, metres. Default 0.002:
    /// a typical calibration is 2-4 mm off in all (issue 54's measurements).
    pub prior_sigma_m: f64,
    /// The recorded hand-eye's 1-sigma rotation error, radians. Default 0.2 deg (0.23-0.27 deg
    /// in all).
    pub prior_sigma_rad: f64,
    /// Degrees of freedom of the prior's Student-t tail (see `handeye::chain::ChainParams`): a
    /// recorded hand-eye the stops show to be farther off than its sigmas (a knocked or remounted
    /// camera) is weighed less, down to `(ν + 6) / (ν + d²)` at Mahalanobis distance `d`; `false`:
    /// a Gaussian prior. Default 6.
    #[serde(with = "crate::off")]
    #[schemars(with = "Option<f64>")]
    pub prior_dof: Option<f64>,
    /// Each view's noise: the arm's pose error at the flange (default 0.7 mm, 0.07 deg per axis)
    /// and the registered camera pose's (default 0.3 mm, 0.02 deg).
    pub noise: ChainNoise,
    /// 1-sigma per axis of each stop's SLAM base pose error (roll, pitch, yaw in radians; x, y, z in
    /// metres, base frame); `false`: each stop's base pose is free. Default 0.25, 0.25, 2 deg and
    /// 3, 3, 0.5 cm: a base on a level floor errs mostly in x, y and yaw.
    #[serde(with = "crate::off")]
    #[schemars(with = "Option<[f64; 6]>")]
    pub stop_sigma: Option<[f64; 6]>,
    /// Within-stop pairs turning less than this do not count as a rotation, radians. Default 5 deg.
    pub min_turn_rad: f64,
    /// Refuse to refine when the rotating pairs' axes span less than this, radians (parallel
    /// axes leave the translation along them unobserved). Default 5 deg.
    pub min_axis_angle_rad: f64,
}

impl Default for HandEyeConfig {
    fn default() -> Self {
        let deg = std::f64::consts::PI / 180.0;
        Self {
            prior_sigma_m: 0.002,
            prior_sigma_rad: 0.2 * deg,
            prior_dof: Some(6.0),
            noise: ChainNoise::default(),
            stop_sigma: Some([0.25 * deg, 0.25 * deg, 2.0 * deg, 0.03, 0.03, 0.005]),
            min_turn_rad: 5.0 * deg,
            min_axis_angle_rad: 5.0 * deg,
        }
    }
}

impl HandEyeConfig {
    /// Checks the settings a fuse would otherwise reject only after registration.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the key that is not a positive number.
    pub fn validate(&self) -> Result<()> {
        let n = &self.noise;
        for (name, v) in [
            ("hand_eye.prior_sigma_m", self.prior_sigma_m),
            ("hand_eye.prior_sigma_rad", self.prior_sigma_rad),
            ("hand_eye.prior_dof", self.prior_dof.unwrap_or(1.0)),
            ("hand_eye.noise.arm_m", n.arm_m),
            ("hand_eye.noise.arm_rad", n.arm_rad),
        ]
        .into_iter()
        .chain(self.stop_sigma.iter().flatten().map(|v| ("hand_eye.stop_sigma", *v)))
        {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::invalid(name, format!("{v} is not a positive number")));
            }
        }
        for (name, v) in [
            ("hand_eye.noise.camera_m", n.camera_m),
            ("hand_eye.noise.camera_rad", n.camera_rad),
            ("hand_eye.min_turn_rad", self.min_turn_rad),
            ("hand_eye.min_axis_angle_rad", self.min_axis_angle_rad),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::invalid(name, format!("{v} is not a finite number >= 0")));
            }
        }
        Ok(())
    }
}

/// What the refinement did (`report.json` `hand_eye`, `workpiece.json` `hand_eye`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HandEyeReport {
    /// The recorded `T_ee_camera` (scan.json).
    #[serde(rename = "T_ee_camera_recorded")]
    pub recorded: Rows,
    /// The refined one; absent when refused.
    #[serde(rename = "T_ee_camera_refined")]
    pub refined: Option<Rows>,
    /// Why it was not refined (empty when refined).
    pub refused: String,
    /// The correction from the recorded to the refined: translation, millimetres.
    pub correction_mm: f64,
    /// ... rotation, degrees.
    pub correction_deg: f64,
    /// 1-sigma of the hand-eye used (the refined one, else the recorded one's prior) per camera axis:
    /// rotation about x, y, z (degrees).
    pub sigma_deg: [f64; 3],
    /// ... translation along x, y, z (millimetres).
    pub sigma_mm: [f64; 3],
    /// Covariance of the hand-eye used: its right perturbation `(ω, v)` in the camera frame, rad²
    /// and m² (row-major 6x6).
    pub covariance: [[f64; 6]; 6],
    /// 1-sigma the data alone give per camera axis (rotation degrees, then translation millimetres);
    /// `null` where the motions do not constrain it.
    pub data_sigma: [Option<f64>; 6],
    /// The least observed rotation axis (camera frame) and its data-alone 1-sigma, degrees.
    pub weakest_rotation: ([f64; 3], Option<f64>),
    /// The least observed translation direction (camera frame) and its data-alone 1-sigma, mm.
    pub weakest_translation: ([f64; 3], Option<f64>),
    /// The base stops used (`base_stop` values, or the index of the first view of a group of
    /// views with identical `T_world_base`).
    pub stops_used: Vec<usize>,
    /// The base stops left out because their views disagreed with the others' (a registration
    /// that slid; see [`MAX_RESIDUAL_SCALE`]), in the order they were left out.
    #[serde(default)]
    pub stops_rejected: Vec<usize>,
    /// The largest translation by which a rejected stop's registered camera motion between two of
    /// its views disagrees with the arm's (through the refined hand-eye), millimetres (0: none
    /// rejected): how far apart parts of the model may be. `awl pierce` adds it to each target's
    /// predicted error.
    #[serde(default)]
    pub rejected_disagreement_mm: f64,
    /// With one base stop (a fixed arm), the views left out because they disagreed with the
    /// others' (see [`MAX_RESIDUAL_SCALE`]), in the order they were left out.
    #[serde(default)]
    pub views_rejected: Vec<usize>,
    /// The views used.
    pub views_used: Vec<usize>,
    /// The directions of motion the views' registrations left unobserved (`views[i].unobserved` of
    /// report.json), left out of the evidence; 0 when every view saw every direction.
    #[serde(default)]
    pub unobserved_left_out: usize,
    /// The correction in sigma of the recorded hand-eye's prior: the Mahalanobis distance of the
    /// refined from the recorded one over the 6 axes (0 when not refined).
    #[serde(default)]
    pub prior_sigmas: f64,
    /// The weight the recorded hand-eye's prior carried (1; less where `hand_eye.prior_dof`
    /// discounted it because the stops contradict it; 0 when not refined).
    #[serde(default)]
    pub prior_weight: f64,
    /// Set when that exceeds [`WRONG_PRIOR_SIGMAS`]: the recorded hand-eye is wrong (empty otherwise).
    #[serde(default)]
    pub warning: String,
    /// Within-stop view pairs that turn more than `min_turn_rad`.
    pub rotating_pairs: usize,
    /// The angle their rotation axes span (see `handeye::MotionDiversity`), degrees.
    pub axis_angle_deg: f64,
    /// `sqrt(chi² / dof)` of the views' residuals (1 when the noise model fits; the covariance is
    /// scaled up by it when larger).
    pub residual_scale: f64,
    /// RMS of the views' flange-frame residuals, millimetres.
    pub rms_mm: f64,
    /// ... degrees.
    pub rms_deg: f64,
}

impl HandEyeReport {
    /// [`HandEyeReport::rejected_disagreement_mm`] in metres: how far apart parts of the model may
    /// be, for `pierce::PierceParams::model_disagreement_m`.
    pub fn model_disagreement_m(&self) -> f64 {
        self.rejected_disagreement_mm * 1e-3
    }

    /// The hand-eye to use and its covariance: the refined one, else the recorded one.
    ///
    /// # Errors
    /// [`Error::Invalid`] when a stored matrix is not rigid.
    pub fn used(&self) -> Result<(Isometry3<f64>, Matrix6<f64>)> {
        let rows = self.refined.as_ref().unwrap_or(&self.recorded);
        let pose = crate::transform::isometry_from_rows(rows).map_err(|e| Error::invalid("hand_eye", e))?;
        Ok((pose, Matrix6::from_fn(|a, b| self.covariance[a][b])))
    }
}

/// Each view's base stop: its `base_stop` key, else the first view whose recorded `T_world_base`
/// is identical; `None` for views that give `T_world_camera`.
pub fn base_stops(scan: &Scan) -> Vec<Option<usize>> {
    let bases: Vec<Option<Isometry3<f64>>> = (scan.views.iter())
        .map(|v| match v.pose {
            ViewPose::Chain { world_from_base, .. } => Some(world_from_base),
            ViewPose::Camera { .. } => None,
        })
        .collect();
    (scan.views.iter().enumerate())
        .map(|(i, v)| {
            bases[i]?;
            if let Some(stop) = v.extra.get("base_stop").and_then(serde_json::Value::as_u64) {
                return Some(stop as usize);
            }
            bases.iter().position(|b| *b == bases[i])
        })
        .collect()
}

fn finite_or_none(v: f64) -> Option<f64> {
    (v.is_finite() && v < 1e6).then_some(v)
}

fn report_of(
    recorded: &Isometry3<f64>,
    estimate: Option<&ChainEstimate>,
    prior: &ChainPrior,
    refused: String,
) -> HandEyeReport {
    let covariance = estimate.map_or(prior.covariance, |e| e.covariance);
    let used = estimate.map_or(*recorded, |e| e.ee_from_camera);
    let (dt, dr) = crate::transform::pose_difference(recorded, &used);
    let sigma = |k: usize| covariance[(k, k)].max(0.0).sqrt();
    let direction = |v: &Vector3<f64>| [v.x, v.y, v.z];
    let none = ([0.0; 3], None);
    HandEyeReport {
        recorded: rows_from_isometry(recorded),
        refined: estimate.map(|e| rows_from_isometry(&e.ee_from_camera)),
        refused,
        correction_mm: dt * 1e3,
        correction_deg: dr.to_degrees(),
        sigma_deg: std::array::from_fn(|k| sigma(k).to_degrees()),
        sigma_mm: std::array::from_fn(|k| sigma(k + 3) * 1e3),
        covariance: std::array::from_fn(|a| std::array::from_fn(|b| covariance[(a, b)])),
        data_sigma: std::array::from_fn(|k| {
            let s = estimate.map_or(f64::INFINITY, |e| e.data_sigma[k]);
            finite_or_none(if k < 3 { s.to_degrees() } else { s * 1e3 })
        }),
        weakest_rotation: estimate
            .map_or(none, |e| (direction(&e.weakest_rotation.0), finite_or_none(e.weakest_rotation.1.to_degrees()))),
        weakest_translation: estimate
            .map_or(none, |e| (direction(&e.weakest_translation.0), finite_or_none(e.weakest_translation.1 * 1e3))),
        stops_used: Vec::new(),
        stops_rejected: Vec::new(),
        rejected_disagreement_mm: 0.0,
        views_rejected: Vec::new(),
        views_used: Vec::new(),
        unobserved_left_out: 0,
        prior_sigmas: 0.0,
        prior_weight: estimate.map_or(0.0, |e| e.prior_weight),
        warning: String::new(),
        rotating_pairs: 0,
        axis_angle_deg: 0.0,
        residual_scale: estimate.map_or(0.0, |e| e.residual_scale),
        rms_mm: estimate.map_or(0.0, |e| e.rms_m * 1e3),
        rms_deg: estimate.map_or(0.0, |e| e.rms_rad.to_degrees()),
    }
}

/// The rotating within-stop pairs and the angle their flange rotation axes span (radians).
fn within_stop_diversity(views: &[ChainView], min_turn_rad: f64) -> (usize, f64) {
    let mut scatter = nalgebra::Matrix3::zeros();
    let mut rotating = 0;
    for (i, a) in views.iter().enumerate() {
        for b in views[i + 1..].iter().filter(|b| b.stop == a.stop) {
            let turn = (a.base_from_ee.inverse() * b.base_from_ee).rotation;
            if turn.angle() > min_turn_rad
                && let Some(axis) = turn.axis()
            {
                scatter += axis.into_inner() * axis.into_inner().transpose();
                rotating += 1;
            }
        }
    }
    if rotating == 0 {
        return (0, 0.0);
    }
    let mut l: Vec<f64> =
        nalgebra::SymmetricEigen::new(scatter / rotating as f64).eigenvalues.iter().copied().collect();
    l.sort_by(f64::total_cmp);
    (rotating, 2.0 * l[1].clamp(0.0, 1.0).sqrt().asin())
}

/// Why `views` (grouped by stop) cannot determine the hand-eye (empty when they can), the
/// rotating within-stop pairs and the angle their axes span (radians).
fn refusal(views: &[(usize, ChainView)], config: &HandEyeConfig) -> (String, usize, f64) {
    let chain: Vec<ChainView> = views.iter().map(|(_, v)| *v).collect();
    let mut stops: Vec<usize> = chain.iter().map(|v| v.stop).collect();
    stops.sort_unstable();
    stops.dedup();
    let (rotating, axis_angle) = within_stop_diversity(&chain, config.min_turn_rad);
    let refused = if stops.is_empty() {
        "no usable stop: no base stop holds two or more registered views (views of one stop share `base_stop` or \
         an identical T_world_base)"
            .to_string()
    } else if rotating < 2 || axis_angle < config.min_axis_angle_rad {
        format!(
            "parallel rotation axes: {rotating} within-stop view pairs turn more than {:.1} deg and their axes span \
             {:.2} deg (need {:.1} deg): turn the flange about different axes at the stops",
            config.min_turn_rad.to_degrees(),
            axis_angle.to_degrees(),
            config.min_axis_angle_rad.to_degrees()
        )
    } else {
        String::new()
    };
    (refused, rotating, axis_angle)
}

/// The largest translation (metres) between a registered within-stop camera motion of the
/// `stops` and the arm's through `ee_from_camera` (`X⁻¹ B X`).
fn disagreement(views: &[(usize, ChainView)], stops: &[usize], ee_from_camera: &Isometry3<f64>) -> f64 {
    let mut worst = 0.0_f64;
    for (k, (_, a)) in views.iter().enumerate().filter(|(_, (_, v))| stops.contains(&v.stop)) {
        for (_, b) in views[k + 1..].iter().filter(|(_, b)| b.stop == a.stop) {
            let registered = a.model_from_camera.inverse() * b.model_from_camera;
            let arm = ee_from_camera.inverse() * a.base_from_ee.inverse() * b.base_from_ee * ee_from_camera;
            worst = worst.max((registered.inverse() * arm).translation.vector.norm());
        }
    }
    worst
}

/// The views' residuals may exceed the noise model's by this factor (`sqrt(chi² / dof)`) before the
/// stop that disagrees most is left out: 2, where the scans with consistent registrations measure
/// 0.76-1.24.
pub const MAX_RESIDUAL_SCALE: f64 = 2.0;

/// Above this residual scale with nothing left to leave out, the refinement declines and names the
/// registrations as the cause (no "recalibrate" warning): 5, 2.5 times the limit.
pub const DECLINE_RESIDUAL_SCALE: f64 = 5.0;

/// Refines the scan's recorded hand-eye from the registered `poses` (`T_world_camera` per view,
/// `None`: left out), each view's `unobserved` motions (twists of its pose in the world frame,
/// see `registration::Unobserved`; a short list: none) left out of its evidence. `None` when the
/// scan records no hand-eye (its views give `T_world_camera`).
///
/// # Errors
/// [`Error::Invalid`] for a setting that is not a positive number.
pub fn refine_hand_eye(
    scan: &Scan,
    poses: &[Option<Isometry3<f64>>],
    unobserved: &[Vec<Vector6<f64>>],
    config: &HandEyeConfig,
) -> Result<Option<HandEyeReport>> {
    let Some(recorded) = scan.ee_from_camera else { return Ok(None) };
    config.validate()?;
    let prior = ChainPrior::isotropic(recorded, config.prior_sigma_m, config.prior_sigma_rad);
    let stops = base_stops(scan);
    let mut views: Vec<(usize, ChainView)> = Vec::new();
    for (i, (spec, pose)) in scan.views.iter().zip(poses).enumerate() {
        if let (ViewPose::Chain { world_from_base, base_from_ee }, Some(pose), Some(stop)) = (spec.pose, pose, stops[i])
        {
            views.push((i, ChainView { stop, world_from_base, base_from_ee, model_from_camera: *pose }));
        }
    }
    // stops with two or more registered views
    let counts: Vec<usize> =
        views.iter().map(|(_, a)| views.iter().filter(|(_, b)| b.stop == a.stop).count()).collect();
    let mut kept = counts.iter().map(|&c| c >= 2);
    views.retain(|_| kept.next().unwrap_or(false));
    let all_views = views.clone();
    let stops_prior = config.stop_sigma.map_or(StopPrior::Free, StopPrior::Sigma);
    let params =
        ChainParams { noise: config.noise, stops: stops_prior, max_iterations: 30, prior_dof: config.prior_dof };
    let gaussian = ChainParams { prior_dof: None, ..params };
    let solve = |views: &[(usize, ChainView)], params: &ChainParams| {
        let chain: Vec<ChainView> = views.iter().map(|(_, v)| *v).collect();
        let left_out: Vec<Vec<Vector6<f64>>> =
            views.iter().map(|(i, _)| unobserved.get(*i).cloned().unwrap_or_default()).collect();
        refine_chain_observed(&chain, &left_out, &prior, params)
    };
    // stops whose views disagree with the rest (a registration that slid) are left out one at a
    // time, the worst first, while the views' residuals exceed the noise model's
    // MAX_RESIDUAL_SCALE times and the stops left can still determine the hand-eye; solved with a
    // Gaussian prior meanwhile, so that the outliers stand out
    let (mut refused, mut rotating, mut axis_angle) = refusal(&views, config);
    let mut stops_rejected = Vec::new();
    let mut views_rejected: Vec<usize> = Vec::new();
    let mut estimate = None;
    while refused.is_empty() {
        let e = solve(&views, &gaussian)?;
        if e.residual_scale <= MAX_RESIDUAL_SCALE {
            estimate = Some(if params.prior_dof.is_some() { solve(&views, &params)? } else { e });
            break;
        }
        let mut per_stop: Vec<(usize, f64, usize)> = Vec::new();
        for ((_, v), chi2) in views.iter().zip(&e.view_chi2) {
            match per_stop.iter_mut().find(|(s, _, _)| *s == v.stop) {
                Some(entry) => (entry.1, entry.2) = (entry.1 + chi2, entry.2 + 1),
                None => per_stop.push((v.stop, *chi2, 1)),
            }
        }
        // with one stop (a fixed arm) the view that disagrees most goes, while a third of them are left
        let one_stop = per_stop.len() == 1;
        let worst = if one_stop {
            (views.iter().zip(&e.view_chi2)).max_by(|a, b| a.1.total_cmp(b.1)).map_or(usize::MAX, |w| w.0.0)
        } else {
            (per_stop.iter())
                .max_by(|a, b| (a.1 / a.2 as f64).total_cmp(&(b.1 / b.2 as f64)))
                .map_or(usize::MAX, |w| w.0)
        };
        let remaining: Vec<(usize, ChainView)> =
            views.iter().copied().filter(|(i, v)| if one_stop { *i != worst } else { v.stop != worst }).collect();
        let next = refusal(&remaining, config);
        if !next.0.is_empty() || (one_stop && 3 * remaining.len() < all_views.len()) {
            if e.residual_scale > DECLINE_RESIDUAL_SCALE {
                // far beyond the noise: the registrations, not the hand-eye, disagree with the arm
                refused = format!(
                    "the views' registered motions disagree with the arm's {:.1} times beyond the noise model \
                     (residual scale; limit {MAX_RESIDUAL_SCALE}, declined above {DECLINE_RESIDUAL_SCALE}) with \
                     nothing left to leave out: registrations that slid (a symmetric or featureless part), not \
                     the hand-eye, are the likely cause; the recorded hand-eye is used unchecked",
                    e.residual_scale
                );
                break;
            }
            // nothing can go: the estimate stands, its covariance scaled by the residuals
            estimate = Some(e);
            break;
        }
        if one_stop {
            views_rejected.push(worst)
        } else {
            stops_rejected.push(worst)
        }
        (views, (refused, rotating, axis_angle)) = (remaining, next);
    }
    let mut stops_used: Vec<usize> = views.iter().map(|(_, v)| v.stop).collect();
    stops_used.sort_unstable();
    stops_used.dedup();
    let mut report = report_of(&recorded, estimate.as_ref(), &prior, refused);
    report.stops_used = stops_used;
    if let Some(e) = &estimate {
        report.rejected_disagreement_mm = disagreement(&all_views, &stops_rejected, &e.ee_from_camera) * 1e3;
    }
    report.stops_rejected = stops_rejected;
    report.views_rejected = views_rejected;
    report.views_used = views.iter().map(|(i, _)| *i).collect();
    report.unobserved_left_out = views.iter().map(|(i, _)| unobserved.get(*i).map_or(0, Vec::len)).sum();
    report.rotating_pairs = rotating;
    report.axis_angle_deg = axis_angle.to_degrees();
    if let Some(e) = &estimate {
        // the correction measured against the recorded hand-eye's stated uncertainty
        let delta = crate::handeye::chain::log(&(recorded.inverse() * e.ee_from_camera));
        let information = prior.covariance.try_inverse().unwrap_or_else(Matrix6::zeros);
        report.prior_sigmas = delta.dot(&(information * delta)).max(0.0).sqrt();
        if report.prior_sigmas > WRONG_PRIOR_SIGMAS {
            report.warning = format!(
                "the recorded hand-eye (scan.json T_ee_camera) is {:.1} mm / {:.2} deg from what the scan's base stops \
                 show, {:.1} sigma of its stated uncertainty (hand_eye.prior_sigma_m {} mm, prior_sigma_rad {:.2} deg): \
                 recalibrate (awl calibrate hand-eye); awl pierce uses the refined one",
                report.correction_mm,
                report.correction_deg,
                report.prior_sigmas,
                config.prior_sigma_m * 1e3,
                config.prior_sigma_rad.to_degrees()
            );
        }
    }
    Ok(Some(report))
}

/// A correction farther than this many sigma of the recorded hand-eye's prior (the Mahalanobis
/// distance over its 6 axes) says the recorded one is wrong: 4.1, the 99 % point of a chi with 6
/// degrees of freedom.
pub const WRONG_PRIOR_SIGMAS: f64 = 4.1;

#[cfg(test)]
mod tests {
    use nalgebra::{Translation3, UnitQuaternion};
    use serde_json::{Map, json};

    use super::*;
    use crate::scan::{ViewData, ViewSpec};

    /// A scan of `stops` stops of 2 views whose flange turns 30 deg about `axis(stop)` between
    /// them, registered exactly (`T_world_camera` = the recorded chain with the true hand-eye).
    fn scan(stops: usize, axis: impl Fn(usize) -> Vector3<f64>, tagged: bool) -> (Scan, Vec<Option<Isometry3<f64>>>) {
        let truth = Isometry3::from_parts(
            Translation3::new(0.03, -0.02, 0.05),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 1.57)),
        );
        let recorded = truth
            * Isometry3::from_parts(
                Translation3::new(0.002, -0.001, 0.001),
                UnitQuaternion::from_scaled_axis(Vector3::new(0.003, -0.002, 0.004)),
            );
        let (mut views, mut poses) = (Vec::new(), Vec::new());
        for s in 0..stops {
            let a = s as f64;
            let world_from_base = Isometry3::from_parts(
                Translation3::new(a.cos(), a.sin(), 0.45),
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), a),
            );
            for k in 0..2 {
                let turn = UnitQuaternion::from_scaled_axis(axis(s).normalize() * (0.5 * k as f64));
                let base_from_ee = Isometry3::from_parts(Translation3::new(0.5, 0.1 * k as f64, 0.4), turn);
                let mut extra = Map::new();
                if tagged {
                    extra.insert("base_stop".into(), json!(s));
                }
                views.push(ViewSpec {
                    data: ViewData::Points { points: "v.ply".into() },
                    pose: ViewPose::Chain { world_from_base, base_from_ee },
                    extra,
                });
                poses.push(Some(world_from_base * base_from_ee * truth));
            }
        }
        (
            Scan {
                dir: ".".into(),
                camera: None,
                ee_from_camera: Some(recorded),
                tag: None,
                views,
                warnings: Vec::new(),
            },
            poses,
        )
    }

    #[test]
    fn stops_give_the_hand_eye_or_say_why_not() {
        let spread = |s: usize| [Vector3::x(), Vector3::y(), Vector3::new(1.0, 1.0, 1.0), Vector3::z()][s % 4];
        let (s, poses) = scan(4, spread, true);
        let r = refine_hand_eye(&s, &poses, &[], &HandEyeConfig::default()).expect("refine").expect("a hand-eye");
        assert!(r.refused.is_empty(), "{}", r.refused);
        assert_eq!((r.stops_used.len(), r.views_used.len(), r.rotating_pairs), (4, 8, 4));
        // exact motions: the recorded 2.45 mm / 0.309 deg come down to 0.97 mm / 0.085 deg (measured;
        // 4 pairs at the default 0.7 mm / 0.07 deg noise weigh about as much as the 2 mm / 0.2 deg prior)
        let truth = Isometry3::from_parts(
            Translation3::new(0.03, -0.02, 0.05),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 1.57)),
        );
        let refined = crate::transform::isometry_from_rows(r.refined.as_ref().expect("refined")).expect("rigid");
        let (before, after) = (
            crate::transform::pose_difference(&s.ee_from_camera.expect("recorded"), &truth),
            crate::transform::pose_difference(&refined, &truth),
        );
        assert!(after.0 < 0.6 * before.0 && after.1 < 0.4 * before.1, "{before:?} -> {after:?}");
        // the same scan without base_stop keys: the identical T_world_base group the views
        let (s, poses) = scan(4, spread, false);
        let untagged =
            refine_hand_eye(&s, &poses, &[], &HandEyeConfig::default()).expect("refine").expect("a hand-eye");
        assert_eq!(untagged.stops_used, vec![0, 2, 4, 6]);
        assert!((untagged.correction_mm - r.correction_mm).abs() < 1e-9);
        // one stop of two views (a fixed arm's, too few): one turning pair, refused, named
        let (s, poses) = scan(1, spread, true);
        let one = refine_hand_eye(&s, &poses, &[], &HandEyeConfig::default()).expect("refine").expect("a report");
        assert!(one.refined.is_none() && one.refused.starts_with("parallel rotation axes"), "{}", one.refused);
        // every stop turning about the same axis: refused, named
        let (s, poses) = scan(4, |_| Vector3::z(), true);
        let parallel = refine_hand_eye(&s, &poses, &[], &HandEyeConfig::default()).expect("refine").expect("a report");
        assert!(parallel.refused.starts_with("parallel rotation axes"), "{}", parallel.refused);
        assert!(parallel.axis_angle_deg < 1e-6);
        // a view left out of the registration: its stop has one view, so it is not used
        let (s, mut poses) = scan(3, spread, true);
        poses[1] = None;
        let partial = refine_hand_eye(&s, &poses, &[], &HandEyeConfig::default()).expect("refine").expect("a report");
        assert_eq!(partial.stops_used, vec![1, 2]);
        // a view whose registration slid 20 mm: its stop is left out and named, the others decide
        let (s, mut poses) = scan(5, spread, true);
        poses[3] = poses[3].map(|p| Translation3::new(0.02, 0.0, 0.0) * p);
        let slid = refine_hand_eye(&s, &poses, &[], &HandEyeConfig::default()).expect("refine").expect("a report");
        assert_eq!((slid.stops_rejected.clone(), slid.stops_used.clone()), (vec![1], vec![0, 2, 3, 4]));
        assert!((slid.rejected_disagreement_mm - 20.0).abs() < 1.0, "{}", slid.rejected_disagreement_mm);
        assert!(slid.residual_scale <= MAX_RESIDUAL_SCALE, "{}", slid.residual_scale);
        let refined = crate::transform::isometry_from_rows(slid.refined.as_ref().expect("refined")).expect("rigid");
        let after = crate::transform::pose_difference(&refined, &truth);
        assert!(after.0 < 0.6 * before.0 && after.1 < 0.4 * before.1, "{before:?} -> {after:?}");
        // the same without the slid view's stop
        let (s, mut poses) = scan(5, spread, true);
        poses[2] = None;
        poses[3] = None;
        let clean = refine_hand_eye(&s, &poses, &[], &HandEyeConfig::default()).expect("refine").expect("a report");
        assert!(clean.stops_rejected.is_empty() && clean.rejected_disagreement_mm == 0.0);
        assert!(
            (clean.correction_mm - slid.correction_mm).abs() < 1e-6,
            "{} {}",
            clean.correction_mm,
            slid.correction_mm
        );
        // one stop (a fixed arm's): the same ten views under one `base_stop`; the slid view alone goes
        let (mut s, mut poses) = scan(5, spread, true);
        for v in &mut s.views {
            v.extra.insert("base_stop".into(), json!(0));
        }
        poses[3] = poses[3].map(|p| Translation3::new(0.02, 0.0, 0.0) * p);
        let fixed = refine_hand_eye(&s, &poses, &[], &HandEyeConfig::default()).expect("refine").expect("a report");
        assert!(fixed.refused.is_empty(), "{}", fixed.refused);
        assert_eq!((fixed.stops_used.clone(), fixed.views_rejected.clone()), (vec![0], vec![3]));
        assert!(
            fixed.stops_rejected.is_empty() && fixed.residual_scale <= MAX_RESIDUAL_SCALE,
            "{}",
            fixed.residual_scale
        );
        let refined = crate::transform::isometry_from_rows(fixed.refined.as_ref().expect("refined")).expect("rigid");
        let after = crate::transform::pose_difference(&refined, &truth);
        assert!(after.0 < 0.6 * before.0 && after.1 < 0.4 * before.1, "{before:?} -> {after:?}");
        // both stops of two slid: leaving either out leaves one turn, so nothing can go, and residuals
        // this far beyond the noise decline (naming the registrations), with no "recalibrate"
        let (s, mut poses) = scan(2, spread, true);
        for i in [1, 3] {
            poses[i] = poses[i].map(|p| Translation3::new(0.02, 0.0, 0.0) * p);
        }
        let both = refine_hand_eye(&s, &poses, &[], &HandEyeConfig::default()).expect("refine").expect("a report");
        println!("both stops slid: {}", both.refused);
        assert!(both.refused.starts_with("the views' registered motions disagree with the arm's"), "{}", both.refused);
        assert!(both.refined.is_none() && both.warning.is_empty() && both.stops_rejected.is_empty());
        // refused before the fuse registers anything
        let bad_dof = HandEyeConfig { prior_dof: Some(-1.0), ..HandEyeConfig::default() };
        let config = crate::pipeline::FuseConfig { hand_eye: Some(bad_dof), ..crate::pipeline::FuseConfig::default() };
        assert!(config.check().expect_err("bad dof").to_string().contains("hand_eye.prior_dof"));
        let bad = HandEyeConfig { prior_sigma_m: 0.0, ..HandEyeConfig::default() };
        assert!(refine_hand_eye(&s, &poses, &[], &bad).expect_err("zero sigma").to_string().contains("prior_sigma_m"));
    }
}
