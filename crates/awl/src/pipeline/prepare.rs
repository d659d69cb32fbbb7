//! Per-view stages: load (depth -> points, range crop; every `pixel_step`-th row and column),
//! region of interest, then voxel down-sampling, statistical outlier removal and normals oriented
//! toward the view's camera (one stage): a depth view's outliers and normals come from its pixel
//! grid (`organized`, a positive `pixel_window`, the default), before the voxel grid (which averages
//! the normals); a cloud view (or any view with `pixel_window = 0`) is down-sampled first, then
//! cleaned with one k-NN pass (`clean`). The views run in parallel, each through all the stages.

use std::time::Instant;

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};
use rayon::prelude::*;

use super::clean::{clean_on_grid, clean_with_normals};
use super::config::FuseConfig;
use super::report::StageReport;
use crate::camera::every_nth_grid;
use crate::cloud::{PointCloud, retain_at};
use crate::error::Result;
use crate::filter::outlier::statistical;
use crate::filter::voxel::downsample;
use crate::io::scan::{LoadedView, Scan, load_view_every_nth};
use crate::organized::PixelGrid;
use crate::segment::{PlaneParams, fit_plane_ransac};

/// A view ready for registration.
pub(crate) struct PreparedView {
    /// Recorded `T_world_camera`.
    pub seed: Isometry3<f64>,
    /// Points in the camera frame with normals facing the camera.
    pub cloud: PointCloud,
    /// Until the voxel grid: for a depth view, the pixel (`v * width + u`) of every point.
    pub pixels: Option<Vec<u32>>,
    /// The measured points (camera frame, down-sampled and cleaned as `cloud`) when `cloud` holds
    /// their smoothed copies for the registration (`registration_smoothing_m`).
    pub measured: Option<PointCloud>,
}

impl PreparedView {
    /// The points the model is made of: the measured ones.
    pub(crate) fn into_measured(self) -> PointCloud {
        self.measured.unwrap_or(self.cloud)
    }
}

/// One entry per scan view: the prepared view, or why it cannot be used.
pub(crate) type Views = Vec<std::result::Result<PreparedView, String>>;

/// The per-view stages, in order (`roi` and `plane normals` only when configured).
const STAGES: [&str; 4] = ["load", "roi", "voxel + outliers + normals", "plane normals"];

/// One view's points in and out and its time, per stage (`None`: the stage did not run on it).
pub(crate) type Tally = [Option<(usize, usize, f64)>; 4];

/// Runs stage `k` on `view`: its points in and out and its time go to `tally`.
fn timed(
    k: usize,
    tally: &mut Tally,
    view: PreparedView,
    f: impl FnOnce(PreparedView) -> Result<PreparedView>,
) -> std::result::Result<PreparedView, String> {
    let (start, points_in) = (Instant::now(), view.cloud.len());
    let out = f(view);
    let points_out = out.as_ref().map_or(0, |v| v.cloud.len());
    tally[k] = Some((points_in, points_out, start.elapsed().as_secs_f64()));
    out.map_err(|e| e.to_string())
}

fn non_empty(view: PreparedView, after: &str) -> Result<PreparedView> {
    if view.cloud.is_empty() {
        return Err(crate::Error::invalid("view", format!("no points left after {after}")));
    }
    Ok(view)
}

/// Voxel down-sampling, outlier removal, normals oriented toward the camera, the incidence filter.
/// A view with pixels (a depth view, `pixel_window` > 0) is cleaned on its pixel grid, then
/// down-sampled; otherwise the view is down-sampled, then cleaned with one k-NN pass (see `clean`),
/// unless it came with its own normals, which are kept.
fn cleaned_and_oriented(view: PreparedView, config: &FuseConfig, width: usize, height: usize) -> Result<PreparedView> {
    let PreparedView { seed, cloud, pixels, .. } = view;
    let mut measured = None;
    let cloud = match pixels {
        Some(pixels) => {
            let grid = PixelGrid::new(width, height, pixels)?;
            let smoothing = config.registration_smoothing_m;
            let (cleaned, m) =
                clean_on_grid(cloud, grid, config.pixel_window, &config.outliers, &config.normals, smoothing)?;
            let thinned = |c| downsample(&without_grazing(c, config.max_incidence_rad), &config.view_voxel);
            measured = m.map(thinned).transpose()?;
            thinned(cleaned)?
        }
        None => {
            let cloud = downsample(&cloud, &config.view_voxel)?;
            let cleaned = if cloud.normals.is_some() {
                let keep = statistical(&cloud, &config.outliers)?;
                cloud.select(&keep)
            } else {
                clean_with_normals(&cloud, &config.outliers, &config.normals, Point3::origin())?
            };
            without_grazing(cleaned, config.max_incidence_rad)
        }
    };
    non_empty(
        PreparedView { seed, cloud, pixels: None, measured },
        "outlier removal, normal estimation and the incidence filter",
    )
}

/// The points seen at more than `max_incidence_rad` between their normal and the ray to the
/// camera (at the origin) dropped.
fn without_grazing(mut cloud: PointCloud, max_incidence_rad: Option<f64>) -> PointCloud {
    let (Some(max), Some(normals)) = (max_incidence_rad, cloud.normals.as_ref()) else { return cloud };
    let min_cos = max.cos() as f32;
    let keep: Vec<usize> = (0..cloud.len())
        .filter(|&i| normals[i].dot(&(-cloud.points[i].coords)) >= min_cos * cloud.points[i].coords.norm())
        .collect();
    cloud.retain_indices(&keep);
    cloud
}

/// The point nearest to every view's optical axis (least squares), world frame; `None` when the
/// axes do not pin one down (a single view, parallel axes).
pub(crate) fn focus_point(seeds: &[Isometry3<f64>]) -> Option<Point3<f64>> {
    let (mut a, mut b) = (Matrix3::zeros(), Vector3::zeros());
    for seed in seeds {
        let d = seed.rotation * Vector3::z();
        let m = Matrix3::identity() - d * d.transpose();
        a += m;
        b += m * seed.translation.vector;
    }
    let eig = a.symmetric_eigen().eigenvalues;
    if seeds.len() < 2 || eig.min() < 1e-3 * eig.max().max(1e-12) {
        return None;
    }
    a.try_inverse().map(|inv| Point3::from(inv * b))
}

/// Snaps the normals of the view's dominant horizontal plane (the floor, usually) to the plane's
/// fitted normal. Per-point normals of a noisy plane tilt by a few degrees; on a floor that fills
/// most of a view, those tilts add up to a sideways pull that slides partially overlapping views.
fn snap_plane_normals(view: PreparedView, params: &PlaneParams) -> Result<PreparedView> {
    let world: Vec<Point3<f32>> =
        view.cloud.points.iter().map(|p| (view.seed * p.cast::<f64>()).cast::<f32>()).collect();
    let Ok(plane) = fit_plane_ransac(&world, params) else { return Ok(view) };
    if plane.inliers.len() * 10 < world.len() {
        return Ok(view);
    }
    let n_camera = (view.seed.rotation.inverse() * plane.normal).cast::<f32>();
    let mut cloud = view.cloud;
    if let Some(normals) = cloud.normals.as_mut() {
        for &i in &plane.inliers {
            let facing = n_camera.dot(&(-cloud.points[i].coords)) >= 0.0;
            normals[i] = if facing { n_camera } else { -n_camera };
        }
    }
    Ok(PreparedView { cloud, ..view })
}

/// What the preparation of every view of a scan shares: the ray table, the grid of kept pixels,
/// the region of interest.
pub(crate) struct Preparer<'a> {
    scan: &'a Scan,
    config: &'a FuseConfig,
    rays: Option<Vec<[f32; 2]>>,
    /// The grid of the kept pixels (`pixel_step`), width and height.
    grid: (usize, usize),
    /// The region of interest: radius and focus point (world frame).
    roi: Option<(f64, Point3<f64>)>,
    /// The point the cameras look at (see [`focus_point`]), when a region of interest is asked for.
    pub focus: Option<Point3<f64>>,
}

impl<'a> Preparer<'a> {
    pub(crate) fn new(scan: &'a Scan, config: &'a FuseConfig) -> Self {
        let rays = scan.camera.map(|c| c.intrinsics.ray_table_every_nth(config.pixel_step));
        let grid = scan.camera.map_or((0, 0), |c| {
            every_nth_grid(c.intrinsics.width as usize, c.intrinsics.height as usize, config.pixel_step)
        });
        let seeds: Vec<Isometry3<f64>> = (0..scan.views.len()).filter_map(|i| scan.world_from_camera(i).ok()).collect();
        let focus = config.roi.radius_m.and_then(|_| focus_point(&seeds));
        let roi = config.roi.radius_m.zip(focus);
        Self { scan, config, rays, grid, roi, focus }
    }

    /// The number of views of the scan.
    pub(crate) fn len(&self) -> usize {
        self.scan.views.len()
    }

    /// View `i`'s recorded pose, `None` when it is not usable.
    pub(crate) fn seed(&self, i: usize) -> Option<Isometry3<f64>> {
        self.scan.world_from_camera(i).ok()
    }

    /// View `i` through the per-view stages, and its points and time per stage.
    pub(crate) fn view(&self, i: usize) -> (std::result::Result<PreparedView, String>, Tally) {
        let mut tally = Tally::default();
        let view = prepare_view(self.scan, i, self.rays.as_deref(), self.config, self.roi, self.grid, &mut tally);
        (view, tally)
    }
}

/// The per-view stages' reports from the views' tallies: each stage's points summed over the views
/// and its time, the views' time in it summed, or when `wall` is given (the views prepared in
/// parallel), that wall time times the stage's share of the per-view work.
pub(crate) fn stage_reports(tallies: &[Tally], wall: Option<f64>) -> Vec<StageReport> {
    let per_view: f64 = tallies.iter().flatten().flatten().map(|t| t.2).sum();
    let scale = match wall {
        Some(wall) if per_view > 0.0 => wall / per_view,
        Some(_) => 0.0,
        None => 1.0,
    };
    let mut reports = Vec::new();
    for (k, name) in STAGES.iter().enumerate() {
        let ran: Vec<_> = tallies.iter().filter_map(|t| t[k]).collect();
        if ran.is_empty() && k != 0 {
            continue;
        }
        reports.push(StageReport {
            name: (*name).into(),
            points_in: ran.iter().map(|t| t.0).sum(),
            points_out: ran.iter().map(|t| t.1).sum(),
            seconds: scale * ran.iter().map(|t| t.2).sum::<f64>(),
        });
    }
    reports
}

/// Prepares every view in parallel (each through all the stages in one pass, so the raw views
/// never pile up); failures are kept per view as messages. A stage's reported time is the
/// prepare's wall time times the stage's share of the per-view work.
pub(crate) fn prepare(preparer: &Preparer<'_>, reports: &mut Vec<StageReport>) -> Views {
    let start = Instant::now();
    let (views, tallies): (Views, Vec<Tally>) = (0..preparer.len()).into_par_iter().map(|i| preparer.view(i)).unzip();
    reports.extend(stage_reports(&tallies, Some(start.elapsed().as_secs_f64())));
    views
}

/// View `i` through the per-view stages: load, region of interest (`roi`: radius and focus point,
/// world frame), cleaning on the `width` x `height` grid of the kept pixels, plane-normal snap.
fn prepare_view(
    scan: &Scan,
    i: usize,
    rays: Option<&[[f32; 2]]>,
    config: &FuseConfig,
    roi: Option<(f64, Point3<f64>)>,
    (width, height): (usize, usize),
    tally: &mut Tally,
) -> std::result::Result<PreparedView, String> {
    let load_start = Instant::now();
    let loaded = load_view_every_nth(scan, i, rays, config.pixel_step).map_err(|e| e.to_string())?;
    // the points carry their colors: the color image is not kept
    let LoadedView { world_from_camera: seed, cloud_camera: cloud, pixels, color } = loaded;
    drop(color);
    let pixels = pixels.filter(|_| config.pixel_window > 0);
    let view = PreparedView { seed, cloud, pixels, measured: None };
    let n = view.cloud.len();
    tally[0] = Some((n, n, load_start.elapsed().as_secs_f64()));
    let mut view = non_empty(view, "the depth range crop").map_err(|e| e.to_string())?;
    if let Some((radius, focus)) = roi {
        view = timed(1, tally, view, |v| within(v, radius, focus))?;
    }
    view = timed(2, tally, view, |v| cleaned_and_oriented(v, config, width, height))?;
    if let Some(params) = &config.snap_plane {
        view = timed(3, tally, view, |v| snap_plane_normals(v, params))?;
    }
    Ok(view)
}

/// The view's points within `radius` of `focus` (world frame).
fn within(mut v: PreparedView, radius: f64, focus: Point3<f64>) -> Result<PreparedView> {
    let r2 = (radius * radius) as f32;
    let centre = (v.seed.inverse() * focus).cast::<f32>();
    let keep: Vec<usize> = (0..v.cloud.len()).filter(|&i| (v.cloud.points[i] - centre).norm_squared() <= r2).collect();
    v.cloud.retain_indices(&keep);
    if let Some(pixels) = v.pixels.as_mut() {
        retain_at(pixels, &keep);
    }
    non_empty(v, "the region-of-interest crop")
}
