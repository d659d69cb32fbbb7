//! `fuse`: a scan folder's views become one model of the object, in the scan's world frame.

use std::time::Instant;

use nalgebra::Isometry3;

use super::config::FuseConfig;
use super::feed::Feed;
use super::hand_eye::refine_hand_eye;
use super::isolate::{drop_floor, keep_object};
use super::prepare::Preparer;
use super::register::{Registered, register_views};
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

fn timed<T>(
    reports: &mut Vec<StageReport>,
    name: &str,
    points_in: usize,
    f: impl FnOnce() -> Result<(T, usize)>,
) -> Result<T> {
    let start = Instant::now();
    let (value, points_out) = f()?;
    reports.push(StageReport { name: name.into(), points_in, points_out, seconds: start.elapsed().as_secs_f64() });
    Ok(value)
}

/// Prepares and registers the views, held or streamed (`view_memory`); the stages' reports go to
/// `stages`. Returns the registration and the views' feed, which gives the merge its input.
fn registered_views<'p, 'a>(
    preparer: &'p Preparer<'a>,
    config: &FuseConfig,
    stages: &mut Vec<StageReport>,
    progress: Progress<'_>,
) -> Result<(Registered, Feed<'p, 'a>)> {
    progress("prepare views", 0, STAGES);
    let mut feed = Feed::new(preparer, config.view_memory, &config.merge_voxel)?;
    progress("register", 4, STAGES);
    let registered = register_views(&mut feed, &config.registration, &config.merge_voxel)?;
    stages.extend(feed.stage_reports());
    let merged = registered.poses.iter().filter(|p| p.is_some()).count();
    stages.push(StageReport { name: "register".into(), points_in: 0, points_out: merged, seconds: registered.seconds });
    Ok((registered, feed))
}

/// Runs the whole modeling pipeline on `scan` (see the module docs of `pipeline`).
///
/// # Errors
/// [`Error::Invalid`] when no view is usable or nothing is left of the model; any stage's error.
/// Views that cannot be used are not errors: they are skipped and reported.
pub fn fuse(scan: &Scan, config: &FuseConfig, progress: Progress<'_>) -> Result<FuseOutput> {
    config.check()?;
    let start = Instant::now();
    let mut stages = Vec::new();
    // what reading the scan fixed (a pose re-orthonormalised) comes first
    let mut warnings = scan.warnings.clone();
    let preparer = Preparer::new(scan, config);
    let focus = preparer.focus;
    if config.roi.radius_m.is_some() && focus.is_none() {
        warnings.push("the views' optical axes do not meet: no region-of-interest crop".into());
    }
    let (registered, feed) = match registered_views(&preparer, config, &mut stages, progress) {
        Ok(registered) => registered,
        // every view emptied by the region-of-interest crop: one error naming the key and the focus
        Err(e) => return Err(preparer.roi_error().unwrap_or(e)),
    };
    // what reading the views' files dropped, after what reading the manifest fixed
    warnings.extend(preparer.load_warnings());
    let skipped = registered.reports.iter().filter(|r| r.status == ViewStatus::Skipped);
    warnings.extend(skipped.map(|r| format!("view {} skipped: {}", r.index, r.reason)));
    if registered.reports.iter().filter(|r| r.status != ViewStatus::Skipped).count() == 1 {
        warnings.push("only one usable view: nothing to register, the model is that view alone".into());
    }
    warnings.extend(registered.warnings.iter().cloned());
    for r in &registered.reports {
        match r.status {
            ViewStatus::Excluded => warnings.push(format!("view {} rejected and left out: {}", r.index, r.reason)),
            ViewStatus::SeedKept => {
                warnings.push(format!("view {} rejected, merged at its seed pose: {}", r.index, r.reason))
            }
            _ => {}
        }
    }
    let hand_eye = match &config.hand_eye {
        Some(c) => timed(&mut stages, "hand-eye", 0, || {
            let unobserved: Vec<Vec<nalgebra::Vector6<f64>>> = (registered.reports.iter())
                .map(|r| r.unobserved.iter().map(|u| nalgebra::Vector6::from(u.twist)).collect())
                .collect();
            let report = refine_hand_eye(scan, &registered.poses, &unobserved, c)?;
            let views = report.as_ref().map_or(0, |r| r.views_used.len());
            Ok((report, views))
        })?,
        None => None,
    };
    if let Some(r) = hand_eye.as_ref().filter(|r| !r.refused.is_empty()) {
        warnings.push(format!("hand-eye not refined from the scan: {}", r.refused));
    }
    if let Some(r) = hand_eye.as_ref().filter(|r| !r.warning.is_empty()) {
        warnings.push(r.warning.clone());
    }
    progress("merge", 5, STAGES);
    let merge_start = Instant::now();
    let parts = feed.into_parts(&registered.poses, &config.merge_voxel)?;
    let points_in = parts.len();
    let merged = parts.downsample()?;
    let seconds = merge_start.elapsed().as_secs_f64();
    stages.push(StageReport { name: "merge".into(), points_in, points_out: merged.len(), seconds });
    progress("isolate object", 6, STAGES);
    let (n_in, mut floor, mut clusters) = (merged.len(), None, None);
    let isolated = timed(&mut stages, "floor + clusters", n_in, || {
        let (rest, f) = drop_floor(merged, &config.isolate, &mut warnings)?;
        let (object, c) = keep_object(rest, &config.isolate, &mut warnings)?;
        (floor, clusters) = (f, c);
        let n = object.len();
        Ok((object, n))
    })?;
    if isolated.is_empty() {
        return Err(Error::invalid("model", "nothing left after floor removal and clustering"));
    }
    progress("smooth", 7, STAGES);
    let model = match &config.smoothing {
        Some(params) => timed(&mut stages, "mls", isolated.len(), || {
            let smoothed = mls(&isolated, params)?.cloud;
            let n = smoothed.len();
            Ok((smoothed, n))
        })?,
        None => isolated,
    };
    progress("done", STAGES, STAGES);
    let report = FuseReport {
        format: REPORT_FORMAT.into(),
        scan: scan.dir.display().to_string(),
        config: config.clone(),
        focus_world: focus.map(|p| [p.x, p.y, p.z]),
        stages,
        views: registered.reports,
        joint: registered.joint,
        floor,
        clusters,
        hand_eye,
        model_points: model.len(),
        warnings,
        seconds: start.elapsed().as_secs_f64(),
    };
    Ok(FuseOutput { model, poses: registered.poses, report })
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
