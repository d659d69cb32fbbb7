//! `fuse`: a scan folder's views become one model of the object, in the scan's world frame.

use std::time::Instant;

use nalgebra::Isometry3;

use super::config::FuseConfig;
use super::isolate::{drop_floor, keep_object};
use super::multiview::register_views;
use super::prepare::{PreparedView, Views, prepare};
use super::report::{FuseReport, REPORT_FORMAT, StageReport, ViewStatus};
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::filter::voxel::downsample;
use crate::io::scan::Scan;
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

/// The views' measured points at their registered poses, one world-frame cloud of `points` points.
/// Each view is moved in place and freed once copied, so the views and their merge are never held
/// twice.
fn world_cloud(views: Views, poses: &[Option<Isometry3<f64>>], points: usize) -> PointCloud {
    // The registration's copies (smoothed, when `registration_smoothing_m` is set) freed first.
    let measured: Vec<(PointCloud, Isometry3<f64>)> =
        views.into_iter().zip(poses).filter_map(|(view, pose)| Some((view.ok()?.into_measured(), (*pose)?))).collect();
    let mut clouds = measured.into_iter().map(|(cloud, pose)| cloud.into_transformed(&pose));
    // The first view's buffers, grown once to hold them all.
    let Some(mut all) = clouds.next() else { return PointCloud::default() };
    let more = points.saturating_sub(all.len());
    all.points.reserve_exact(more);
    all.normals.iter_mut().for_each(|n| n.reserve_exact(more));
    all.colors.iter_mut().for_each(|c| c.reserve_exact(more));
    for cloud in clouds {
        all.extend(&cloud);
    }
    all
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
    let mut warnings = Vec::new();
    progress("prepare views", 0, STAGES);
    let (views, focus) = prepare(scan, config, &mut stages);
    if config.roi.radius_m.is_some() && focus.is_none() {
        warnings.push("the views' optical axes do not meet: no region-of-interest crop".into());
    }
    for (i, v) in views.iter().enumerate() {
        if let Err(e) = v {
            warnings.push(format!("view {i} skipped: {e}"));
        }
    }
    if views.iter().all(|v| v.is_err()) {
        let reasons: Vec<String> =
            views.iter().enumerate().filter_map(|(i, v)| v.as_ref().err().map(|e| format!("view {i}: {e}"))).collect();
        return Err(Error::invalid("scan", format!("no usable view ({})", reasons.join("; "))));
    }
    if views.iter().filter(|v| v.is_ok()).count() == 1 {
        warnings.push("only one usable view: nothing to register, the model is that view alone".into());
    }
    progress("register", 4, STAGES);
    let registered = timed(&mut stages, "register", 0, || {
        let r = register_views(&views, &config.registration, &config.merge_voxel)?;
        let merged = r.poses.iter().filter(|p| p.is_some()).count();
        Ok((r, merged))
    })?;
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
    progress("merge", 5, STAGES);
    let merged_in: usize = views
        .iter()
        .zip(&registered.poses)
        .filter_map(|(v, p)| p.and(v.as_ref().ok()))
        .map(PreparedView::measured_len)
        .sum();
    let merged = timed(&mut stages, "merge", merged_in, || {
        let model = downsample(&world_cloud(views, &registered.poses, merged_in), &config.merge_voxel)?;
        let n = model.len();
        Ok((model, n))
    })?;
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
        model_points: model.len(),
        warnings,
        seconds: start.elapsed().as_secs_f64(),
    };
    Ok(FuseOutput { model, poses: registered.poses, report })
}
