//! Registration of all views: the sequential scheme (each view against the growing model, seeded
//! by its recorded pose, judged by the acceptance rule), then (optional) rounds of refining every
//! view against all the others, then the joint refinement of all of them at once (which undoes the
//! drift of the sequential pass). The anchor view (the first usable one) fixes the model frame.

use nalgebra::{Isometry3, Point3, Vector3, Vector6};

use super::config::{AcceptanceRule, RegistrationConfig, RejectPolicy};
use super::prepare::{PreparedView, Views};
use super::report::{ViewReport, ViewStatus};
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::filter::voxel::{VoxelAccumulator, VoxelParams, downsample};
use crate::registration::{
    IcpParams, IcpResult, JointLevelStats, Unobserved, refine_jointly, register, register_levels_expecting,
};
use crate::transform::rows_from_isometry;

/// Final poses (`None`: left out) and one report per scan view.
pub(crate) struct Registered {
    pub poses: Vec<Option<Isometry3<f64>>>,
    pub reports: Vec<ViewReport>,
    /// The joint refinement's levels (empty when off).
    pub joint: Vec<JointLevelStats>,
    pub warnings: Vec<String>,
}

fn centroid(cloud: &PointCloud) -> Point3<f64> {
    let sum = cloud.points.iter().fold(Vector3::zeros(), |a, p| a + p.coords.cast::<f64>());
    Point3::from(sum / cloud.len().max(1) as f64)
}

/// Centroid displacement (m) and rotation (rad) between two poses of one view.
fn correction(view: &PreparedView, from: &Isometry3<f64>, to: &Isometry3<f64>) -> (f64, f64) {
    let c = centroid(&view.cloud);
    ((to * c - from * c).norm(), (from.inverse() * to).rotation.angle())
}

/// The acceptance rule: `Ok` or the first failing check, with its numbers.
fn judge(rule: &AcceptanceRule, r: &IcpResult, moved: (f64, f64)) -> std::result::Result<(), String> {
    if rule.require_converged && !r.converged {
        return Err(format!("ICP did not converge in {} iterations", r.iterations));
    }
    if r.fitness < rule.min_fitness {
        return Err(format!("fitness {:.3} < {:.3}", r.fitness, rule.min_fitness));
    }
    if r.inlier_rmse_m > rule.max_inlier_rmse_m {
        return Err(format!("inlier RMSE {:.2} mm > {:.2} mm", r.inlier_rmse_m * 1e3, rule.max_inlier_rmse_m * 1e3));
    }
    if r.observed_conditioning < rule.min_conditioning {
        return Err(format!(
            "ill-conditioned (degenerate geometry): {:.1e} < {:.1e}",
            r.observed_conditioning, rule.min_conditioning
        ));
    }
    if moved.0 > rule.max_correction_m {
        return Err(format!("correction {:.1} mm > {:.1} mm", moved.0 * 1e3, rule.max_correction_m * 1e3));
    }
    if moved.1 > rule.max_correction_rad {
        return Err(format!(
            "correction {:.2} deg > {:.2} deg",
            moved.1.to_degrees(),
            rule.max_correction_rad.to_degrees()
        ));
    }
    Ok(())
}

pub(super) fn blank_report(index: usize, view: &std::result::Result<PreparedView, String>) -> ViewReport {
    let (status, reason, points, seed) = match view {
        Ok(v) => (ViewStatus::Excluded, String::new(), v.cloud.len(), Some(rows_from_isometry(&v.seed))),
        Err(e) => (ViewStatus::Skipped, e.clone(), 0, None),
    };
    ViewReport {
        index,
        status,
        reason,
        points,
        seed,
        pose: None,
        correction_mm: 0.0,
        correction_deg: 0.0,
        iterations: 0,
        fitness: 0.0,
        inlier_rmse_mm: 0.0,
        conditioning: 0.0,
        unobserved: Vec::new(),
        converged: false,
        levels: Vec::new(),
    }
}

fn record(report: &mut ViewReport, r: &IcpResult) {
    report.iterations += r.iterations;
    report.fitness = r.fitness;
    report.inlier_rmse_mm = r.inlier_rmse_m * 1e3;
    report.conditioning = r.conditioning;
    report.converged = r.converged;
    report.levels = r.levels.clone();
}

/// The error of a scan with no usable view, naming each view's reason (view index, reason).
pub(super) fn no_usable_view<'a>(reasons: impl IntoIterator<Item = (usize, &'a str)>) -> Error {
    let reasons: Vec<String> = reasons.into_iter().map(|(i, reason)| format!("view {i}: {reason}")).collect();
    Error::invalid("scan", format!("no usable view ({})", reasons.join("; ")))
}

/// Marks the anchor's report.
pub(super) fn make_anchor(report: &mut ViewReport) {
    report.status = ViewStatus::Anchor;
    report.reason = "first usable view: fixes the model frame".into();
}

/// The pose a view is merged at after its registration `result` (`None`: left out), by the
/// acceptance rule and the reject policy; its report filled in.
pub(super) fn settle(
    config: &RegistrationConfig,
    view: &PreparedView,
    result: &IcpResult,
    symmetries: &Symmetries,
    report: &mut ViewReport,
) -> Option<Isometry3<f64>> {
    record(report, result);
    report.unobserved = result.unobserved.clone();
    let verdict =
        judge(&config.accept, result, correction(view, &view.seed, &result.target_from_source)).and_then(|()| {
            symmetries.unconfirmed(result).map_or(Ok(()), |u| {
            Err(format!(
                "ill-conditioned (degenerate geometry): {:.1e} < {:.1e}, a {:?} about axis {:.2?} unobserved in this \
                 view only",
                u.eigen_ratio, config.icp.unobserved_ratio, u.kind, u.axis
            ))
        })
        });
    match verdict {
        Ok(()) => {
            report.status = ViewStatus::Accepted;
            Some(result.target_from_source)
        }
        Err(reason) => {
            report.reason = reason;
            (config.on_reject == RejectPolicy::KeepSeed).then(|| {
                report.status = ViewStatus::SeedKept;
                view.seed
            })
        }
    }
}

/// The directions the views' registrations found unobserved, each with the number of views that
/// found it. One that two or more views found is the object's (a symmetry: a cylinder's spin),
/// held at the seed wherever it is weak; one that a single view found says that view saw too little
/// of the surface, and the view is rejected as ill-conditioned (its seed may be centimetres off
/// along it).
#[derive(Debug, Default)]
pub(super) struct Symmetries {
    found: Vec<(Unobserved, usize)>,
}

impl Symmetries {
    /// Counts the directions `result` found unobserved.
    pub(super) fn note(&mut self, result: &IcpResult) {
        for u in &result.unobserved {
            match self.found.iter_mut().find(|(s, _)| s.same_as(u)) {
                Some((_, count)) => *count += 1,
                None => self.found.push((u.clone(), 1)),
            }
        }
    }

    /// The directions two or more views found.
    pub(super) fn confirmed(&self) -> Vec<Unobserved> {
        self.found.iter().filter(|(_, count)| *count >= 2).map(|(u, _)| u.clone()).collect()
    }

    /// The first of `result`'s unobserved directions no other view found.
    fn unconfirmed<'a>(&self, result: &'a IcpResult) -> Option<&'a Unobserved> {
        let confirmed = self.confirmed();
        result.unobserved.iter().find(|u| !confirmed.iter().any(|c| c.same_as(u)))
    }
}

/// Writes a merged view's final `pose` and its correction from the seed into its report.
pub(super) fn place(report: &mut ViewReport, view: &PreparedView, pose: &Isometry3<f64>) {
    let (dt, dr) = correction(view, &view.seed, pose);
    report.correction_mm = dt * 1e3;
    report.correction_deg = dr.to_degrees();
    report.pose = Some(rows_from_isometry(pose));
}

/// The merged model of the views in `members` at `poses`, down-sampled.
fn model_of(
    views: &Views,
    poses: &[Option<Isometry3<f64>>],
    members: impl Iterator<Item = usize>,
    voxel: &VoxelParams,
) -> Result<PointCloud> {
    let mut model = PointCloud::default();
    for i in members {
        if let (Ok(view), Some(pose)) = (&views[i], poses[i]) {
            model.extend(&view.cloud.transformed(&pose));
        }
    }
    downsample(&model, voxel)
}

/// The growing model as the ICP sees it: the merged views down-sampled at each ICP level's voxel
/// size (the model's own voxel size for a level that does not down-sample), each kept up to date
/// view by view instead of down-sampling the whole model again for every view and level.
pub(super) struct LevelModel {
    levels: Vec<VoxelAccumulator>,
}

impl LevelModel {
    pub(super) fn new(icp: &IcpParams, voxel: &VoxelParams) -> Result<Self> {
        let at = |v: f64| if v > 0.0 { VoxelParams { voxel_size_m: v } } else { *voxel };
        let levels = icp.levels.iter().map(|l| VoxelAccumulator::new(&at(l.voxel_m))).collect::<Result<_>>()?;
        Ok(Self { levels })
    }

    pub(super) fn add(&mut self, cloud: &PointCloud) -> Result<()> {
        use rayon::prelude::*;
        self.levels.par_iter_mut().try_for_each(|l| l.add(cloud))
    }

    pub(super) fn levels(&self) -> Vec<&PointCloud> {
        self.levels.iter().map(VoxelAccumulator::cloud).collect()
    }
}

/// The position in `remaining` of the unregistered view whose seed camera (`centre` of a view
/// index) is nearest to a merged view's camera (ties: the first).
pub(super) fn next_view(centre: impl Fn(usize) -> Vector3<f64>, remaining: &[usize], merged: &[usize]) -> usize {
    let mut best = (f64::INFINITY, 0);
    for (pos, &i) in remaining.iter().enumerate() {
        let d = merged.iter().map(|&m| (centre(i) - centre(m)).norm()).fold(f64::INFINITY, f64::min);
        if d < best.0 {
            best = (d, pos);
        }
    }
    best.1
}

/// Registers every usable view; see the module docs.
///
/// # Errors
/// [`Error::Invalid`] when no view is usable; errors of the ICP and voxel stages.
pub(crate) fn register_views(views: &Views, config: &RegistrationConfig, voxel: &VoxelParams) -> Result<Registered> {
    let mut reports: Vec<ViewReport> = views.iter().enumerate().map(|(i, v)| blank_report(i, v)).collect();
    let mut poses: Vec<Option<Isometry3<f64>>> = vec![None; views.len()];
    let mut remaining: Vec<usize> = (0..views.len()).filter(|&i| views[i].is_ok()).collect();
    if remaining.is_empty() {
        return Err(Error::invalid("scan", "no usable view (see the per-view reasons)"));
    }
    let anchor = remaining.remove(0);
    let seed_of = |i: usize| views[i].as_ref().map(|v| v.seed).unwrap_or_else(|_| Isometry3::identity());
    poses[anchor] = Some(seed_of(anchor));
    make_anchor(&mut reports[anchor]);
    let mut merged = vec![anchor];
    let mut symmetries = Symmetries::default();
    let mut unconfirmed = Vec::new();
    let mut model = LevelModel::new(&config.icp, voxel)?;
    if let Ok(view) = &views[anchor] {
        model.add(&view.cloud.transformed(&seed_of(anchor)))?;
    }
    while !remaining.is_empty() {
        let centre = |i: usize| views[i].as_ref().map(|v| v.seed.translation.vector).unwrap_or_default();
        let i = remaining.remove(next_view(centre, &remaining, &merged));
        let Ok(view) = &views[i] else { continue };
        let expected = symmetries.confirmed();
        let result = register_levels_expecting(&view.cloud, &model.levels(), &view.seed, &config.icp, &expected)?;
        symmetries.note(&result);
        poses[i] = settle(config, view, &result, &symmetries, &mut reports[i]);
        match poses[i] {
            Some(pose) => {
                model.add(&view.cloud.transformed(&pose))?;
                merged.push(i);
            }
            None if !result.unobserved.is_empty() => unconfirmed.push((i, result.unobserved)),
            None => {}
        }
    }
    // the views left out for directions only they had found, once later views have found them too
    let confirmed = symmetries.confirmed();
    for (i, found) in unconfirmed {
        let Ok(view) = &views[i] else { continue };
        if !found.iter().all(|u| confirmed.iter().any(|c| c.same_as(u))) {
            continue;
        }
        let result = register_levels_expecting(&view.cloud, &model.levels(), &view.seed, &config.icp, &confirmed)?;
        poses[i] = settle(config, view, &result, &symmetries, &mut reports[i]);
        if let Some(pose) = poses[i] {
            model.add(&view.cloud.transformed(&pose))?;
            merged.push(i);
        }
    }
    drop(model); // the sequential pass's targets: not needed by the refinements
    refine(views, config, voxel, anchor, &mut poses, &mut reports)?;
    let mut warnings = Vec::new();
    let joint = refine_joint(views, config, anchor, &mut poses, &reports, &mut warnings)?;
    for (i, report) in reports.iter_mut().enumerate() {
        if let (Some(pose), Ok(view)) = (poses[i], &views[i]) {
            place(report, view, &pose);
        }
    }
    Ok(Registered { poses, reports, joint, warnings })
}

/// Rounds of registering each accepted view against all the other merged views.
fn refine(
    views: &Views,
    config: &RegistrationConfig,
    voxel: &VoxelParams,
    anchor: usize,
    poses: &mut [Option<Isometry3<f64>>],
    reports: &mut [ViewReport],
) -> Result<()> {
    let params = IcpParams { levels: config.refine_levels.clone(), ..config.icp.clone() };
    for _ in 0..config.refine_rounds {
        for i in 0..views.len() {
            let (Ok(view), Some(current)) = (&views[i], poses[i]) else { continue };
            if i == anchor || reports[i].status != ViewStatus::Accepted {
                continue;
            }
            let others = (0..views.len()).filter(|&j| j != i);
            let target = model_of(views, poses, others, voxel)?;
            let result = register(&view.cloud, &target, &current, &params)?;
            if judge(&config.accept, &result, correction(view, &current, &result.target_from_source)).is_ok() {
                record(&mut reports[i], &result);
                poses[i] = Some(result.target_from_source);
            }
        }
    }
    Ok(())
}

/// The joint refinement of the anchor and the accepted views (see `registration::joint`).
fn refine_joint(
    views: &Views,
    config: &RegistrationConfig,
    anchor: usize,
    poses: &mut [Option<Isometry3<f64>>],
    reports: &[ViewReport],
    warnings: &mut Vec<String>,
) -> Result<Vec<JointLevelStats>> {
    if config.joint_levels.is_empty() {
        return Ok(Vec::new());
    }
    // (view index, view, pose) of the anchor and the accepted views
    let members: Vec<(usize, &PreparedView, Isometry3<f64>)> = (0..views.len())
        .filter(|&i| i == anchor || reports[i].status == ViewStatus::Accepted)
        .filter_map(|i| Some((i, views[i].as_ref().ok()?, poses[i]?)))
        .collect();
    let clouds: Vec<&PointCloud> = members.iter().map(|m| &m.1.cloud).collect();
    let mut joint: Vec<Isometry3<f64>> = members.iter().map(|m| m.2).collect();
    let fixed = members.iter().position(|m| m.0 == anchor).unwrap_or(0);
    // each view's unobserved directions stay where the sequential pass held them
    let held: Vec<Vec<Vector6<f64>>> =
        members.iter().map(|m| reports[m.0].unobserved.iter().map(Unobserved::constraint).collect()).collect();
    let stats = refine_jointly(&clouds, &mut joint, fixed, &held, &config.joint_params())?;
    // A view the joint step moved farther than its first gate left the basin it started in:
    // keep the sequential poses.
    let gate = config.joint_levels[0].max_correspondence_m;
    let strayed = members.iter().zip(&joint).find_map(|(&(i, view, before), pose)| {
        let moved = correction(view, &before, pose).0;
        (moved > gate).then_some((i, moved))
    });
    if let Some((i, moved)) = strayed {
        warnings.push(format!(
            "joint refinement moved view {i} by {:.1} mm (more than its {:.1} mm gate): sequential poses kept",
            moved * 1e3,
            gate * 1e3
        ));
        return Ok(stats);
    }
    for (&(i, _, _), pose) in members.iter().zip(joint) {
        poses[i] = Some(pose);
    }
    Ok(stats)
}
