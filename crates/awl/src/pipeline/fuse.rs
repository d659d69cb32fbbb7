//! `fuse`: a scan folder's views become one model of the object, in the scan's world frame.

use std::time::Instant;

use nalgebra::{Isometry3, Vector6};

use super::advice::{ScanAdvice, advise};
use super::config::FuseConfig;
use super::feed::Feed;
use super::hand_eye::{HandEyeReport, refine_hand_eye};
use super::isolate::{drop_floor, keep_object};
use super::prepare::Preparer;
use super::register::{Registered, StopMates, register_views};
use super::report::{FuseReport, REPORT_FORMAT, StageReport, ViewStatus};
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::scan::Scan;
use crate::smooth::mls;

/// Stage notifications for a progress display: `(stage name, stages done, stages in all)`.
pub type Progress<'a> = &'a (dyn Fn(&str, usize, usize) + Sync);

/// What [`fuse`] returns.
#[derive(Debug, Clone)]
pub struct FuseOutput {
    /// The object's model: world frame, metres, with normals (and colors when the scan has them).
    pub model: PointCloud,
    /// Final `T_world_camera` of every view (`None` for views left out).
    pub poses: Vec<Option<Isometry3<f64>>>,
    /// The report (`report.json`).
    pub report: FuseReport,
}

const STAGES: usize = 8;

/// What the stages have reported so far: their points and times, the warnings.
struct Log {
    stages: Vec<StageReport>,
    warnings: Vec<String>,
}

impl Log {
    /// Runs stage `name` on `points_in` points: `f` gives its result and its points out.
    fn timed<T>(&mut self, name: &str, points_in: usize, f: impl FnOnce(&mut Self) -> Result<(T, usize)>) -> Result<T> {
        let start = Instant::now();
        let (value, points_out) = f(self)?;
        let seconds = start.elapsed().as_secs_f64();
        self.stages.push(StageReport { name: name.into(), points_in, points_out, seconds });
        Ok(value)
    }
}

/// Runs the whole modeling pipeline on `scan` (see the module docs of `pipeline`).
///
/// # Errors
/// [`Error::Invalid`] when no view is usable or nothing is left of the model; any stage's error.
/// Views that cannot be used are not errors: they are skipped and reported.
pub fn fuse(scan: &Scan, config: &FuseConfig, progress: Progress<'_>) -> Result<FuseOutput> {
    config.check()?;
    let start = Instant::now();
    // what reading the scan fixed (a pose re-orthonormalised) comes first
    let mut log = Log { stages: Vec::new(), warnings: scan.warnings.clone() };
    let preparer = Preparer::new(scan, config);
    let (registered, feed) = prepare_and_register(&preparer, config, &mut log, progress)?;
    let (hand_eye, advice) = hand_eye(scan, &registered, config, &mut log)?;
    progress("merge", 5, STAGES);
    let merged = merge(feed, &registered.poses, config, &mut log)?;
    progress("isolate object", 6, STAGES);
    let (object, floor, clusters) = log.timed("floor + clusters", merged.len(), |log| {
        let (rest, floor) = drop_floor(merged, &config.isolate, &mut log.warnings)?;
        let (object, clusters) = keep_object(rest, &config.isolate, &mut log.warnings)?;
        let n = object.len();
        Ok(((object, floor, clusters), n))
    })?;
    if object.is_empty() {
        return Err(Error::invalid("model", "nothing left after floor removal and clustering"));
    }
    progress("smooth", 7, STAGES);
    let model = match &config.smoothing {
        Some(params) => log.timed("mls", object.len(), |_| {
            let smoothed = mls(&object, params)?.cloud;
            let n = smoothed.len();
            Ok((smoothed, n))
        })?,
        None => object,
    };
    progress("done", STAGES, STAGES);
    let report = FuseReport {
        format: REPORT_FORMAT.into(),
        scan: scan.dir.display().to_string(),
        config: config.clone(),
        focus_world: preparer.focus.map(|p| [p.x, p.y, p.z]),
        stages: log.stages,
        views: registered.reports,
        joint: registered.joint,
        floor,
        clusters,
        hand_eye,
        advice,
        model_points: model.len(),
        warnings: log.warnings,
        seconds: start.elapsed().as_secs_f64(),
    };
    Ok(FuseOutput { model, poses: registered.poses, report })
}

/// Stages 1-3: the views prepared and registered, held or streamed (`view_memory`), and what
/// they said. Returns the registration and the views' feed, which gives the merge its input.
///
/// # Errors
/// No usable view (one error naming `roi.radius_m` when its crop emptied them); the ICP's and
/// voxel errors.
fn prepare_and_register<'p, 'a>(
    preparer: &'p Preparer<'a>,
    config: &FuseConfig,
    log: &mut Log,
    progress: Progress<'_>,
) -> Result<(Registered, Feed<'p, 'a>)> {
    if config.roi.radius_m.is_some() && preparer.focus.is_none() {
        log.warnings.push("the views' optical axes do not meet: no region-of-interest crop".into());
    }
    progress("prepare views", 0, STAGES);
    let mut feed = Feed::new(preparer, config.view_memory, &config.merge_voxel)?;
    progress("register", 4, STAGES);
    let mates = StopMates::of(preparer.scan(), config.registration.stop_seed_gate_m);
    let registered = match register_views(&mut feed, &mates, &config.registration, &config.merge_voxel) {
        Ok(registered) => registered,
        // every view emptied by the region-of-interest crop: one error naming the key and the focus
        Err(e) => return Err(preparer.roi_error().unwrap_or(e)),
    };
    log.stages.extend(feed.stage_reports());
    let merged = registered.poses.iter().filter(|p| p.is_some()).count();
    let seconds = registered.seconds;
    log.stages.push(StageReport { name: "register".into(), points_in: 0, points_out: merged, seconds });
    // what reading the views' files dropped, after what reading the manifest fixed
    log.warnings.extend(preparer.load_warnings());
    let skipped = registered.reports.iter().filter(|r| r.status == ViewStatus::Skipped);
    log.warnings.extend(skipped.map(|r| format!("view {} skipped: {}", r.index, r.reason)));
    if registered.reports.iter().filter(|r| r.status != ViewStatus::Skipped).count() == 1 {
        log.warnings.push("only one usable view: nothing to register, the model is that view alone".into());
    }
    log.warnings.extend(registered.warnings.iter().cloned());
    for r in &registered.reports {
        match r.status {
            ViewStatus::Excluded => log.warnings.push(format!("view {} rejected and left out: {}", r.index, r.reason)),
            ViewStatus::SeedKept => {
                log.warnings.push(format!("view {} rejected, merged at its seed pose: {}", r.index, r.reason))
            }
            _ => {}
        }
    }
    Ok((registered, feed))
}

/// Stage 5: the merged views' measured points at their `poses`, on one voxel grid.
fn merge(
    feed: Feed<'_, '_>,
    poses: &[Option<Isometry3<f64>>],
    config: &FuseConfig,
    log: &mut Log,
) -> Result<PointCloud> {
    let start = Instant::now();
    let parts = feed.into_parts(poses, &config.merge_voxel)?;
    let points_in = parts.len();
    let merged = parts.downsample()?;
    let seconds = start.elapsed().as_secs_f64();
    log.stages.push(StageReport { name: "merge".into(), points_in, points_out: merged.len(), seconds });
    Ok(merged)
}

/// Stage 4: the hand-eye refined from the registered base stops (`None`: off), and why not; the
/// scan-time advice on where more views would gain.
fn hand_eye(
    scan: &Scan,
    registered: &Registered,
    config: &FuseConfig,
    log: &mut Log,
) -> Result<(Option<HandEyeReport>, Option<ScanAdvice>)> {
    let Some(c) = &config.hand_eye else { return Ok((None, None)) };
    let (report, advice) = log.timed("hand-eye", 0, |_| {
        let unobserved: Vec<Vec<Vector6<f64>>> = (registered.reports.iter())
            .map(|r| r.unobserved.iter().map(|u| Vector6::from(u.twist)).collect())
            .collect();
        let report = refine_hand_eye(scan, &registered.poses, &unobserved, c)?;
        let advice = match &report {
            Some(r) => advise(scan, r, &registered.poses, &unobserved, c)?,
            None => None,
        };
        let views = report.as_ref().map_or(0, |r| r.views_used.len());
        Ok(((report, advice), views))
    })?;
    if let Some(r) = report.as_ref().filter(|r| !r.refused.is_empty()) {
        log.warnings.push(format!("hand-eye not refined from the scan: {}", r.refused));
    }
    if let Some(r) = report.as_ref().filter(|r| !r.stops_rejected.is_empty()) {
        log.warnings.push(format!(
            "hand-eye: base stop(s) {:?} left out: their views' registered motion disagrees with the arm's and the \
             other stops' (more than {} times the noise model): a registration that slid along a face?",
            r.stops_rejected,
            super::hand_eye::MAX_RESIDUAL_SCALE
        ));
    }
    if let Some(r) = report.as_ref().filter(|r| !r.warning.is_empty()) {
        log.warnings.push(r.warning.clone());
    }
    log.warnings.extend(advice.as_ref().and_then(ScanAdvice::summary));
    Ok((report, advice))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::normals::{NormalParams, with_normals};
    use crate::registration::{IcpLevel, IcpParams, register};
    use crate::sim::{SceneKind, SimParams, simulate};
    use crate::spatial::KdIndex;

    /// The whole pipeline on a simulated scan held in memory (no file written, no feature needed):
    /// five or six of six views registered, and the model, fitted onto the object's CAD from the
    /// true world frame (as `eval` does), lies on it: under 1.5 mm RMS, under 1 % beyond 5 mm.
    #[test]
    fn fuses_a_simulated_scan_in_memory_onto_the_cad() {
        let sim = simulate(&SimParams { views: 6, seed: 2, ..SimParams::scan(SceneKind::Box) }).expect("simulate");
        let out = fuse(&sim.in_memory_scan(), &FuseConfig::default(), &|_, _, _| {}).expect("fuse");
        assert!(
            out.poses.iter().flatten().count() >= 5,
            "{} of 6 views registered",
            out.poses.iter().flatten().count()
        );
        assert!(out.model.len() > 10_000, "{} model points", out.model.len());
        let cad = with_normals(&sim.cad.sample_surface(200_000, 1).expect("sample"), &NormalParams::default(), None)
            .expect("normals");
        let object_from_world = sim.truth.world_from_object.inverse();
        let mut fine = IcpParams::default();
        fine.levels.push(IcpLevel { voxel_m: 0.002, max_correspondence_m: 0.01, max_iterations: 50 });
        let fit = register(&out.model, &cad, &object_from_world, &fine).expect("fit").target_from_source;
        let moved_mm = (object_from_world.inverse() * fit).translation.vector.norm() * 1e3;
        assert!(moved_mm < 20.0, "the model lies {moved_mm:.1} mm from the true world frame");
        let index = KdIndex::new(&cad.points).expect("index");
        let off: Vec<f64> = out
            .model
            .points
            .iter()
            .map(|p| {
                // to the plane of the nearest CAD sample: the samples' spacing left out
                let q = (fit * p.cast::<f64>()).cast::<f32>();
                let n = index.nearest(&q).expect("nearest").index as usize;
                let normal = cad.normals.as_ref().expect("normals")[n];
                f64::from((q - cad.points[n]).dot(&normal).abs())
            })
            .collect();
        let rms_mm = (off.iter().map(|d| d * d).sum::<f64>() / off.len() as f64).sqrt() * 1e3;
        let far = off.iter().filter(|d| **d > 0.005).count() as f64 / off.len() as f64;
        assert!(rms_mm < 1.5 && far < 0.01, "model {rms_mm:.2} mm RMS from the CAD, {:.2} % beyond 5 mm", far * 100.0);
    }
}
