//! Registration of the views, from a [`Feed`] that holds or streams them: the sequential pass
//! (the anchor, the first usable view, at its recorded pose and fixing the model frame; then each
//! view against the growing model, judged by the acceptance rule), then the joint refinement of
//! the anchor and the accepted views at once, which undoes the sequential pass's drift
//! (`registration::joint`; held views only).
//!
//! A view is seeded by its recorded pose, or, once a view of its base stop is merged, by that
//! view's registered pose and the arm's recorded motion between the two ([`StopMates`]): the
//! stop's SLAM error (centimetres) is then corrected, and what is left is the arm's and the
//! hand-eye's (millimetres). A direction the view's surface leaves unobserved is held there.

use std::time::Instant;

use nalgebra::{Isometry3, Point3, Vector3, Vector6};

use super::config::{AcceptanceRule, RegistrationConfig, RejectPolicy};
use super::feed::Feed;
use super::prepare::PreparedView;
use super::report::{ViewReport, ViewStatus};
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::filter::voxel::{VoxelAccumulator, VoxelParams};
use crate::registration::{
    IcpParams, IcpResult, JointLevelStats, Unobserved, refine_jointly, register_levels_expecting,
};
use crate::scan::{Scan, ViewPose};
use crate::transform::rows_from_isometry;

/// The views of each base stop and the arm's recorded camera poses in the base frame
/// (`T_base_ee * T_ee_camera`): within a stop, the recorded motion from one view to another is
/// that of the arm, without the stop's SLAM error.
#[derive(Debug, Clone, Default)]
pub(super) struct StopMates {
    /// `registration.stop_seed_gate_m`: the ICP gate of a view seeded from its stop, metres.
    gate_m: f64,
    /// Per view: its stop and `T_base_camera` (`None`: a view posed directly, or by a chain
    /// without a hand-eye); empty when stop seeds are off.
    views: Vec<Option<(usize, Isometry3<f64>)>>,
}

impl StopMates {
    /// The stops of `scan`'s views (`pipeline::hand_eye::base_stops`) for seeds gated at `gate_m`
    /// (`registration.stop_seed_gate_m`; `None`: no view is seeded from its stop).
    pub(super) fn of(scan: &Scan, gate_m: Option<f64>) -> Self {
        let Some(gate_m) = gate_m else { return Self::default() };
        let stops = super::hand_eye::base_stops(scan);
        let views = (scan.views.iter().zip(stops))
            .map(|(v, stop)| match (v.pose, scan.ee_from_camera, stop) {
                (ViewPose::Chain { base_from_ee, .. }, Some(ee_from_camera), Some(stop)) => {
                    Some((stop, base_from_ee * ee_from_camera))
                }
                _ => None,
            })
            .collect();
        Self { gate_m, views }
    }

    /// Each view's stop (`None`: a view that cannot be seeded from its stop; empty: none can).
    fn stops(&self) -> Vec<Option<usize>> {
        self.views.iter().map(|v| v.map(|(stop, _)| stop)).collect()
    }

    /// View `i`'s seed from the first merged view of its stop (`poses`: the merged views' poses):
    /// `T_world_camera_m * T_base_camera_m^-1 * T_base_camera_i`, and `m`; `None` when no view of
    /// its stop is merged.
    fn seed(&self, i: usize, poses: &[Option<Isometry3<f64>>]) -> Option<(usize, Isometry3<f64>)> {
        let (stop, base_from_camera) = self.views.get(i).copied().flatten()?;
        self.views.iter().enumerate().find_map(|(m, mate)| {
            let (mate_stop, mate_base_from_camera) = (*mate)?;
            let pose = poses.get(m).copied().flatten()?;
            (m != i && mate_stop == stop).then(|| (m, pose * mate_base_from_camera.inverse() * base_from_camera))
        })
    }

    /// The seed of view `i`, the view of its stop that gave it, and the ICP parameters it is
    /// registered with: its stop-mate's seed with every level of `icp` gated at most `gate_m`, else
    /// its `recorded` pose and `icp` as it is.
    fn seed_for(
        &self,
        icp: &IcpParams,
        (i, recorded): (usize, &Isometry3<f64>),
        poses: &[Option<Isometry3<f64>>],
    ) -> (Isometry3<f64>, Option<usize>, IcpParams) {
        let Some((m, seed)) = self.seed(i, poses) else { return (*recorded, None, icp.clone()) };
        let mut icp = icp.clone();
        for level in &mut icp.levels {
            level.max_correspondence_m = level.max_correspondence_m.min(self.gate_m);
        }
        (seed, Some(m), icp)
    }
}

/// Final poses (`None`: left out) and one report per scan view.
pub(super) struct Registered {
    pub poses: Vec<Option<Isometry3<f64>>>,
    pub reports: Vec<ViewReport>,
    /// The joint refinement's levels (empty when off).
    pub joint: Vec<JointLevelStats>,
    pub warnings: Vec<String>,
    /// The time spent registering, seconds (the views' preparation left out).
    pub seconds: f64,
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

fn blank_report(index: usize, view: &std::result::Result<PreparedView, String>) -> ViewReport {
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
        seeded_from_view: None,
        correction_mm: 0.0,
        correction_deg: 0.0,
        iterations: 0,
        fitness: 0.0,
        inlier_rmse_mm: 0.0,
        conditioning: 0.0,
        observed_conditioning: 0.0,
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
    report.observed_conditioning = r.observed_conditioning;
    report.converged = r.converged;
    report.levels = r.levels.clone();
}

/// The error of a scan with no usable view, naming each view's reason (view index, reason).
fn no_usable_view<'a>(reasons: impl IntoIterator<Item = (usize, &'a str)>) -> Error {
    let reasons: Vec<String> = reasons.into_iter().map(|(i, reason)| format!("view {i}: {reason}")).collect();
    Error::invalid("scan", format!("no usable view ({})", reasons.join("; ")))
}

/// Marks the anchor's report.
fn make_anchor(report: &mut ViewReport) {
    report.status = ViewStatus::Anchor;
    report.reason = "first usable view: fixes the model frame".into();
}

/// The pose a view is merged at after its registration `result` (`None`: left out), by the
/// acceptance rule and the reject policy; its report filled in.
fn settle(
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
            report.reason.clear();
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
struct Symmetries {
    found: Vec<(Unobserved, usize)>,
}

impl Symmetries {
    /// Counts the directions `result` found unobserved.
    fn note(&mut self, result: &IcpResult) {
        for u in &result.unobserved {
            match self.found.iter_mut().find(|(s, _)| s.same_as(u)) {
                Some((_, count)) => *count += 1,
                None => self.found.push((u.clone(), 1)),
            }
        }
    }

    /// The directions two or more views found.
    fn confirmed(&self) -> Vec<Unobserved> {
        self.found.iter().filter(|(_, count)| *count >= 2).map(|(u, _)| u.clone()).collect()
    }

    /// The first of `result`'s unobserved directions no other view found.
    fn unconfirmed<'a>(&self, result: &'a IcpResult) -> Option<&'a Unobserved> {
        let confirmed = self.confirmed();
        result.unobserved.iter().find(|u| !confirmed.iter().any(|c| c.same_as(u)))
    }
}

/// Writes a merged view's final `pose` and its correction from the seed into its report.
fn place(report: &mut ViewReport, view: &PreparedView, pose: &Isometry3<f64>) {
    let (dt, dr) = correction(view, &view.seed, pose);
    report.correction_mm = dt * 1e3;
    report.correction_deg = dr.to_degrees();
    report.pose = Some(rows_from_isometry(pose));
}

/// The growing model as the ICP sees it: the merged views down-sampled at each ICP level's voxel
/// size (the model's own voxel size for a level that does not down-sample), each kept up to date
/// view by view instead of down-sampling the whole model again for every view and level.
struct LevelModel {
    levels: Vec<VoxelAccumulator>,
}

impl LevelModel {
    fn new(icp: &IcpParams, voxel: &VoxelParams) -> Result<Self> {
        let at = |v: f64| if v > 0.0 { VoxelParams { voxel_size_m: v } } else { *voxel };
        let levels = icp.levels.iter().map(|l| VoxelAccumulator::new(&at(l.voxel_m))).collect::<Result<_>>()?;
        Ok(Self { levels })
    }

    fn add(&mut self, cloud: &PointCloud) -> Result<()> {
        use rayon::prelude::*;
        self.levels.par_iter_mut().try_for_each(|l| l.add(cloud))
    }

    fn levels(&self) -> Vec<&PointCloud> {
        self.levels.iter().map(VoxelAccumulator::cloud).collect()
    }
}

/// The position in `remaining` of the next view to register: of the unregistered views a merged
/// view of whose stop can seed (`stops`, by view index; empty: none can), else of them all, the
/// one whose seed camera (`centres`, by view index) is nearest to a merged view's camera (ties: the
/// first).
fn next_view(centres: &[Vector3<f64>], stops: &[Option<usize>], remaining: &[usize], merged: &[usize]) -> usize {
    let stop = |i: usize| stops.get(i).copied().flatten();
    let seedable = |i: usize| stop(i).is_some_and(|s| merged.iter().any(|&m| stop(m) == Some(s)));
    let mut best = (true, f64::INFINITY, 0);
    for (pos, &i) in remaining.iter().enumerate() {
        let d = merged.iter().map(|&m| (centres[i] - centres[m]).norm()).fold(f64::INFINITY, f64::min);
        let key = (!seedable(i), d, pos);
        if (key.0, key.1) < (best.0, best.1) {
            best = key;
        }
    }
    best.2
}

/// Registers the views of `feed`: the sequential pass, then the joint refinement of the held views
/// (see the module docs).
///
/// # Errors
/// [`Error::Invalid`] when no view is usable (naming each view's reason); errors of the ICP and
/// voxel stages.
pub(super) fn register_views(
    feed: &mut Feed<'_, '_>,
    mates: &StopMates,
    config: &RegistrationConfig,
    voxel: &VoxelParams,
) -> Result<Registered> {
    let mut registered = register_sequentially(feed, mates, config, voxel)?;
    let start = Instant::now();
    let Registered { poses, reports, joint, warnings, .. } = &mut registered;
    *joint = refine_joint(feed, config, poses, reports, warnings)?;
    for (i, view) in feed.held() {
        if let Some(pose) = poses[i] {
            place(&mut reports[i], view, &pose);
        }
    }
    registered.seconds += start.elapsed().as_secs_f64();
    Ok(registered)
}

/// The sequential pass: the anchor (the first usable view) at its recorded pose, then each view
/// against the growing model, a view its stop can seed first, then the view nearest a merged one,
/// each judged by the acceptance rule; a view left out for an unobserved direction only it had
/// found, or before a view of its stop was merged, is tried again at the end, once later views have
/// found it too or from its stop's seed. The next view is guessed as if the current one were
/// merged, for a streaming feed to prepare it meanwhile (a wrong guess is kept for later).
fn register_sequentially(
    feed: &mut Feed<'_, '_>,
    mates: &StopMates,
    config: &RegistrationConfig,
    voxel: &VoxelParams,
) -> Result<Registered> {
    let n = feed.len();
    let mut reports: Vec<ViewReport> = (0..n).map(|i| blank_report(i, &Err(String::new()))).collect();
    let take = |feed: &mut Feed<'_, '_>, reports: &mut [ViewReport], i: usize| {
        let view = feed.take(i);
        reports[i] = blank_report(i, &view);
        view.ok()
    };
    let mut remaining: Vec<usize> = (0..n).collect();
    let mut anchor = None;
    while anchor.is_none() && !remaining.is_empty() {
        let i = remaining.remove(0);
        anchor = take(feed, &mut reports, i).map(|view| (i, view));
    }
    let Some((a, view)) = anchor else {
        return Err(no_usable_view(reports.iter().map(|r| (r.index, r.reason.as_str()))));
    };
    let start = Instant::now();
    let mut poses: Vec<Option<Isometry3<f64>>> = vec![None; n];
    let mut model = LevelModel::new(&config.icp, voxel)?;
    let merge = |feed: &mut Feed<'_, '_>,
                 model: &mut LevelModel,
                 (poses, report): (&mut [Option<Isometry3<f64>>], &mut ViewReport),
                 i: usize,
                 view: PreparedView,
                 pose: Isometry3<f64>| {
        model.add(&view.cloud.transformed(&pose))?;
        place(report, &view, &pose);
        feed.merge(i, view, &pose)?;
        poses[i] = Some(pose);
        Ok::<_, Error>(())
    };
    make_anchor(&mut reports[a]);
    let seed = view.seed;
    merge(feed, &mut model, (&mut poses, &mut reports[a]), a, view, seed)?;
    let mut merged = vec![a];
    let mut symmetries = Symmetries::default();
    let mut left_out = Vec::new();
    let mut seconds = start.elapsed().as_secs_f64();
    let stops = mates.stops();
    // each view's recorded camera position, once (the origin for a view without a usable pose)
    let centres: Vec<Vector3<f64>> =
        (0..n).map(|i| feed.seed(i).map(|s| s.translation.vector).unwrap_or_default()).collect();
    while !remaining.is_empty() {
        let i = remaining.remove(next_view(&centres, &stops, &remaining, &merged));
        let Some(view) = take(feed, &mut reports, i) else { continue };
        merged.push(i);
        let guess = (!remaining.is_empty()).then(|| remaining[next_view(&centres, &stops, &remaining, &merged)]);
        merged.pop();
        let (levels, expected) = (model.levels(), symmetries.confirmed());
        let (seed, mate, icp) = mates.seed_for(&config.icp, (i, &view.seed), &poses);
        reports[i].seeded_from_view = mate;
        let (result, icp_seconds) = feed.while_preparing(guess, || {
            let start = Instant::now();
            let r = register_levels_expecting(&view.cloud, &levels, &seed, &icp, &expected);
            (r, start.elapsed().as_secs_f64())
        });
        drop(levels);
        let start = Instant::now();
        let result = result?;
        symmetries.note(&result);
        match settle(config, &view, &result, &symmetries, &mut reports[i]) {
            Some(pose) => {
                merge(feed, &mut model, (&mut poses, &mut reports[i]), i, view, pose)?;
                merged.push(i);
            }
            None if !result.unobserved.is_empty() || mate.is_none() => left_out.push((i, view, result.unobserved)),
            None => {}
        }
        seconds += icp_seconds + start.elapsed().as_secs_f64();
    }
    let start = Instant::now();
    let confirmed = symmetries.confirmed();
    for (i, view, found) in left_out {
        let (seed, mate, icp) = mates.seed_for(&config.icp, (i, &view.seed), &poses);
        let now_confirmed = !found.is_empty() && found.iter().all(|u| confirmed.iter().any(|c| c.same_as(u)));
        let now_seeded = reports[i].seeded_from_view.is_none() && mate.is_some();
        if !now_confirmed && !now_seeded {
            continue;
        }
        reports[i].seeded_from_view = mate;
        let result = register_levels_expecting(&view.cloud, &model.levels(), &seed, &icp, &confirmed)?;
        if let Some(pose) = settle(config, &view, &result, &symmetries, &mut reports[i]) {
            merge(feed, &mut model, (&mut poses, &mut reports[i]), i, view, pose)?;
        }
    }
    seconds += start.elapsed().as_secs_f64();
    Ok(Registered { poses, reports, joint: Vec::new(), warnings: Vec::new(), seconds })
}

/// The joint refinement of the anchor and the accepted views (see `registration::joint`).
fn refine_joint(
    feed: &Feed<'_, '_>,
    config: &RegistrationConfig,
    poses: &mut [Option<Isometry3<f64>>],
    reports: &[ViewReport],
    warnings: &mut Vec<String>,
) -> Result<Vec<JointLevelStats>> {
    if config.joint_levels.is_empty() {
        return Ok(Vec::new());
    }
    // (view index, view, pose) of the anchor and the accepted views
    let joins = |i: usize| matches!(reports[i].status, ViewStatus::Anchor | ViewStatus::Accepted);
    let members: Vec<(usize, &PreparedView, Isometry3<f64>)> =
        feed.held().filter(|&(i, _)| joins(i)).filter_map(|(i, view)| Some((i, view, poses[i]?))).collect();
    let clouds: Vec<&PointCloud> = members.iter().map(|m| &m.1.cloud).collect();
    let mut joint: Vec<Isometry3<f64>> = members.iter().map(|m| m.2).collect();
    let fixed = members.iter().position(|m| reports[m.0].status == ViewStatus::Anchor).unwrap_or(0);
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

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::*;
    use crate::image::DepthImage;
    use crate::pipeline::config::{FuseConfig, ViewMemory};
    use crate::pipeline::prepare::Preparer;
    use crate::scan::{Scan, ViewData};
    use crate::sim::{SceneKind, SimParams, simulate};

    /// A simulated 6-view box held in memory, view 1's depth image zeroed (no points: skipped).
    fn scan_with_an_empty_view() -> Scan {
        let sim = simulate(&SimParams { views: 6, seed: 3, ..SimParams::scan(SceneKind::Box) }).expect("simulate");
        let mut scan = sim.in_memory_scan();
        let ViewData::Images { depth, .. } = &mut scan.views[1].data else { panic!("an in-memory view") };
        let (width, height) = (depth.width, depth.height);
        *depth = Arc::new(DepthImage { width, height, data: vec![0; (width * height) as usize] });
        scan
    }

    /// Registers and merges `scan`'s views as `config` says: the registration and the merged points.
    fn registered(scan: &Scan, config: &FuseConfig) -> (Registered, PointCloud) {
        let preparer = Preparer::new(scan, config);
        let mut feed = Feed::new(&preparer, config.view_memory, &config.merge_voxel).expect("feed");
        let mates = StopMates::of(scan, config.registration.stop_seed_gate_m);
        let registered =
            register_views(&mut feed, &mates, &config.registration, &config.merge_voxel).expect("register");
        let parts = feed.into_parts(&registered.poses, &config.merge_voxel).expect("parts");
        (registered, parts.downsample().expect("merged"))
    }

    /// Held or streamed, the same views in the same order, the same poses and reports and the same
    /// merged points (normals within 0.05 deg: a held view's are read again packed, within 0.005 deg
    /// a point, and a voxel's average of diverging normals spreads that), with a view
    /// that has no points and with views rejected (then the streamed feed's guess of the next view
    /// was wrong).
    #[test]
    fn held_and_streamed_views_register_alike() {
        let scan = scan_with_an_empty_view();
        let mut strict = FuseConfig::fast();
        strict.registration.accept.max_correction_m = 0.012;
        for streamed in [FuseConfig::fast(), strict] {
            let held = FuseConfig { view_memory: ViewMemory::Hold, ..streamed.clone() };
            let (want, want_model) = registered(&scan, &held);
            let (got, got_model) = registered(&scan, &streamed);
            assert_eq!(got.poses, want.poses);
            assert_eq!(got.reports, want.reports);
            assert!(got_model.len() > 20_000, "{} points", got_model.len());
            assert_eq!((&got_model.points, &got_model.colors), (&want_model.points, &want_model.colors));
            let (a, b) = (got_model.normals.expect("normals"), want_model.normals.expect("normals"));
            let worst =
                a.iter().zip(&b).map(|(a, b)| a.cast::<f64>().angle(&b.cast()).to_degrees()).fold(0.0, f64::max);
            assert!(worst < 0.05, "normals {worst} deg apart");
            let count = |s: ViewStatus| want.reports.iter().filter(|r| r.status == s).count();
            assert_eq!(count(ViewStatus::Skipped), 1);
            assert!(want.reports[1].reason.contains("no points"), "{}", want.reports[1].reason);
            // rejected views, and with the fast config's rule registered ones too
            let strict = streamed.registration.accept.max_correction_m < 0.05;
            assert_eq!(count(ViewStatus::Accepted) + count(ViewStatus::Excluded), 4);
            assert!(count(ViewStatus::Excluded) >= 1 && (strict || count(ViewStatus::Accepted) >= 2));
        }
    }

    /// A view's seed from a view of its stop placed at its true pose is within the arm's and the
    /// hand-eye's error of its own true pose (realistic noise: 0.6 mm / 0.06 deg a view, the
    /// hand-eye 3 mm / 0.3 deg), where its recorded pose carries the stop's SLAM error too; a view
    /// alone at its stop, or whose mate is not merged, has none.
    #[test]
    fn a_stop_mate_seeds_a_view_within_the_arm_and_hand_eye_error() {
        let sim = simulate(&SimParams { views: 6, seed: 4, ..SimParams::scan(SceneKind::Box) }).expect("simulate");
        let scan = sim.in_memory_scan();
        let mates = StopMates::of(&scan, Some(0.03));
        let view_0_merged = [Some(sim.truth.views[0].world_from_camera)];
        assert!(
            mates.seed(1, &view_0_merged).is_some() && StopMates::of(&scan, None).seed(1, &view_0_merged).is_none()
        );
        let stops = mates.stops();
        // the simulator's 6 views: stops of 2, 1, 2, 1 views
        assert_eq!(stops, vec![Some(0), Some(0), Some(1), Some(2), Some(2), Some(3)]);
        let truth: Vec<Isometry3<f64>> = sim.truth.views.iter().map(|v| v.world_from_camera).collect();
        let (mut worst_mate, mut worst_recorded) = (0.0f64, 0.0f64);
        for i in 0..6 {
            let mut poses = vec![None; 6];
            assert!(mates.seed(i, &poses).is_none(), "view {i}: no mate merged");
            let Some(m) = (0..6).find(|&m| m != i && stops[m] == stops[i]) else {
                let others: Vec<_> = (0..6).map(|m| (m != i).then_some(truth[m])).collect();
                assert!(mates.seed(i, &others).is_none(), "view {i} is alone at its stop");
                continue;
            };
            poses[m] = Some(truth[m]);
            let (from, seed) = mates.seed(i, &poses).expect("seed");
            assert_eq!(from, m);
            let (dt, dr) = crate::transform::pose_difference(&seed, &truth[i]);
            // at 0.5 m from the camera, where the object is
            let at_object = |pose: &Isometry3<f64>| {
                (pose * Point3::new(0.0, 0.0, 0.5) - truth[i] * Point3::new(0.0, 0.0, 0.5)).norm()
            };
            assert!(dt < 0.006 && dr.to_degrees() < 0.5, "view {i}: {:.2} mm {:.3} deg", dt * 1e3, dr.to_degrees());
            worst_mate = worst_mate.max(at_object(&seed));
            worst_recorded = worst_recorded.max(at_object(&scan.world_from_camera(i).expect("pose")));
        }
        println!("at the object: {:.2} mm from the mate, {:.2} mm recorded", worst_mate * 1e3, worst_recorded * 1e3);
        // measured: 4.11 mm from the mate, 34.36 mm from the recorded poses
        assert!(worst_mate < 0.007 && worst_recorded > 3.0 * worst_mate, "{worst_mate} {worst_recorded}");
    }

    /// `on_reject = "keep-seed"`: a rejected view is merged at its recorded pose, its report says so
    /// with the reason and a zero correction, and its points are in the model; the joint refinement
    /// leaves it there. Excluded, the same view's points are not merged.
    #[test]
    fn a_rejected_view_is_kept_at_its_seed_when_asked() {
        let scan = scan_with_an_empty_view();
        let mut exclude = FuseConfig::default();
        exclude.registration.accept.max_correction_m = 0.012;
        let keep = FuseConfig {
            registration: RegistrationConfig { on_reject: RejectPolicy::KeepSeed, ..exclude.registration.clone() },
            ..exclude.clone()
        };
        let (excluded, excluded_model) = registered(&scan, &exclude);
        let (kept, kept_model) = registered(&scan, &keep);
        let count = |r: &Registered, s: ViewStatus| r.reports.iter().filter(|v| v.status == s).count();
        assert!(count(&excluded, ViewStatus::Excluded) >= 1, "the 12 mm rule rejects a view");
        assert_eq!((count(&excluded, ViewStatus::SeedKept), count(&kept, ViewStatus::Excluded)), (0, 0));
        let rejected: Vec<usize> =
            (kept.reports.iter()).filter(|r| r.status == ViewStatus::SeedKept).map(|r| r.index).collect();
        assert!(!rejected.is_empty(), "a view kept at its seed");
        for &i in &rejected {
            let report = &kept.reports[i];
            assert!(!report.reason.is_empty(), "view {i}: the rule's reason");
            assert_eq!(kept.poses[i], scan.world_from_camera(i).ok(), "view {i} at its recorded pose");
            assert_eq!(report.pose, kept.poses[i].as_ref().map(rows_from_isometry), "view {i}");
            assert_eq!(report.correction_mm, 0.0, "view {i}");
        }
        // the kept views' points: at least 20 % more model points (each view sees ~1/6 of the box)
        let more = kept_model.len() as f64 / excluded_model.len() as f64 - 1.0;
        assert!(
            more > 0.2 * rejected.len() as f64 / 5.0,
            "{} -> {} model points",
            excluded_model.len(),
            kept_model.len()
        );
    }
}
