//! Per-view stages: load (depth -> points, range crop; every `pixel_step`-th row and column),
//! region of interest, then voxel down-sampling, statistical outlier removal and normals oriented
//! toward the view's camera (one stage): a depth view's outliers and normals come from its pixel
//! grid (`organized`, a positive `pixel_window`, the default), before the voxel grid (which averages
//! the normals); a cloud view (or any view with `pixel_window = 0`) is down-sampled first, then
//! cleaned with one k-NN pass (`clean`). Each view goes through all the stages in one call
//! ([`Preparer::view`]).
//!
//! A depth view registered on smoothed copies of its points (`registration_smoothing_m`) has two
//! copies: the registration's and the measured points the model is made of. A fuse that holds
//! every view for its joint refinement keeps only a [`Recipe`] of the measured ones (which loaded
//! points, their normals packed: ~4 bytes a point instead of 27) and loads the view again for the
//! merge (the memory saved: BENCHMARKS.md 64).

use std::collections::{BTreeMap, BTreeSet};
use std::sync::{Mutex, PoisonError};
use std::time::Instant;

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};

use super::clean::{OnGrid, clean_on_grid, clean_with_normals};
use super::config::{FuseConfig, ViewMemory};
use super::report::StageReport;
use crate::camera::every_nth_grid;
use crate::cloud::{PointCloud, retain_at};
use crate::error::Result;
use crate::filter::outlier::statistical;
use crate::filter::voxel::downsample;
use crate::io::scan::load_view_every_nth;
use crate::octahedral::{PackedNormal, pack_all, unpack_normal};
use crate::organized::PixelGrid;
use crate::scan::{LoadedView, Scan};
use crate::segment::{PlaneParams, fit_plane_ransac};

/// A view ready for registration.
pub(crate) struct PreparedView {
    /// Recorded `T_world_camera`.
    pub seed: Isometry3<f64>,
    /// Points in the camera frame with normals facing the camera.
    pub cloud: PointCloud,
    /// Until the voxel grid: for a depth view, the pixel (`v * width + u`) of every point.
    pub pixels: Option<Vec<u32>>,
    /// The measured points (camera frame, cleaned and down-sampled as `cloud`), or how to read
    /// them again, when `cloud` holds their smoothed copies for the registration
    /// (`registration_smoothing_m`); `None`: `cloud` holds them.
    pub measured: Option<Measured>,
}

/// A prepared view's measured points, or what reads them again.
pub(crate) enum Measured {
    Points(PointCloud),
    Recipe(Recipe),
}

/// Which of a view's loaded points (those of [`Preparer::loaded`]) are its measured points, and
/// their normals (packed): enough to read them again ([`Preparer::measured`]), in ~4 bytes a point
/// instead of 27.
pub(crate) struct Recipe {
    /// Points the view loads.
    loaded: usize,
    /// Bit `k % 64` of word `k / 64` set: loaded point `k` is a measured point.
    kept: Vec<u64>,
    /// The measured points' normals (before the voxel grid), in order.
    normals: Vec<PackedNormal>,
}

impl Recipe {
    fn new(loaded: usize, sources: &[usize], normals: &[Vector3<f32>]) -> Self {
        let mut kept = vec![0u64; loaded.div_ceil(64)];
        for &k in sources {
            kept[k / 64] |= 1 << (k % 64);
        }
        Self { loaded, kept, normals: pack_all(normals) }
    }

    /// The measured points of `cloud`, the view loaded again, with their normals.
    fn apply(&self, mut cloud: PointCloud) -> Option<PointCloud> {
        if cloud.len() != self.loaded {
            return None;
        }
        let keep: Vec<usize> = (0..self.loaded).filter(|&k| self.kept[k / 64] >> (k % 64) & 1 == 1).collect();
        cloud.retain_indices(&keep);
        (keep.len() == self.normals.len()).then(|| {
            cloud.normals = Some(self.normals.iter().map(|&n| unpack_normal(n)).collect());
            cloud
        })
    }
}

impl PreparedView {
    /// The points the model is made of: the measured ones, or what reads them again.
    pub(crate) fn into_measured(self) -> Measured {
        self.measured.unwrap_or(Measured::Points(self.cloud))
    }
}

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
fn cleaned_and_oriented(
    view: PreparedView,
    config: &FuseConfig,
    (width, height): (usize, usize),
    memory: ViewMemory,
) -> Result<PreparedView> {
    let PreparedView { seed, cloud, pixels, .. } = view;
    let mut measured = None;
    let cloud = match pixels {
        Some(pixels) => {
            let (loaded, grid) = (cloud.len(), PixelGrid::new(width, height, pixels)?);
            let smoothing = config.registration_smoothing_m;
            let on_grid =
                clean_on_grid(cloud, grid, config.pixel_window, &config.outliers, &config.normals, smoothing)?;
            let OnGrid { cloud: cleaned, measured: m, mut sources } = on_grid;
            let thinned = |c| downsample(&without_grazing(c, config.max_incidence_rad), &config.view_voxel);
            measured = match (m, memory) {
                (None, _) => None,
                (Some(m), ViewMemory::Stream) => Some(Measured::Points(thinned(m)?)),
                (Some(mut m), ViewMemory::Hold) => {
                    if let Some(keep) = grazing_keep(&m, config.max_incidence_rad) {
                        m.retain_indices(&keep);
                        retain_at(&mut sources, &keep);
                    }
                    Some(Measured::Recipe(Recipe::new(loaded, &sources, m.normals.as_deref().unwrap_or_default())))
                }
            };
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
    if let Some(keep) = grazing_keep(&cloud, max_incidence_rad) {
        cloud.retain_indices(&keep);
    }
    cloud
}

/// The points [`without_grazing`] keeps; `None`: all of them (no limit, or no normals).
fn grazing_keep(cloud: &PointCloud, max_incidence_rad: Option<f64>) -> Option<Vec<usize>> {
    let (Some(max), Some(normals)) = (max_incidence_rad, cloud.normals.as_ref()) else { return None };
    let min_cos = max.cos() as f32;
    let p = &cloud.points;
    Some((0..cloud.len()).filter(|&i| normals[i].dot(&(-p[i].coords)) >= min_cos * p[i].coords.norm()).collect())
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

/// What preparing the views noticed, by view index (so the views, prepared in parallel, report in
/// view order).
#[derive(Default)]
struct Notes {
    /// Each view's load warnings (a point file's non-finite points dropped, ...), from its first load.
    warnings: BTreeMap<usize, Vec<String>>,
    /// The views the region-of-interest crop left without points.
    roi_emptied: BTreeSet<usize>,
    /// The views that could not be prepared, and why.
    failed: BTreeMap<usize, String>,
}

/// What the preparation of every view of a scan shares: the ray table, the grid of kept pixels,
/// the region of interest.
pub(crate) struct Preparer<'a> {
    scan: &'a Scan,
    config: &'a FuseConfig,
    rays: Option<Vec<[f32; 2]>>,
    /// The grid of the kept pixels (`pixel_step`), width and height.
    grid: (usize, usize),
    /// How the fuse holds its views: a view prepared for one that streams them holds its measured
    /// points beside their smoothed copies, one for a fuse that holds them a [`Recipe`] of them.
    memory: ViewMemory,
    /// The region of interest: radius and focus point (world frame).
    roi: Option<(f64, Point3<f64>)>,
    /// The point the cameras look at (see [`focus_point`]), when a region of interest is asked for.
    pub focus: Option<Point3<f64>>,
    notes: Mutex<Notes>,
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
        Self { scan, config, rays, grid, memory: config.view_memory, roi, focus, notes: Mutex::default() }
    }

    fn note(&self, f: impl FnOnce(&mut Notes)) {
        f(&mut self.notes.lock().unwrap_or_else(PoisonError::into_inner));
    }

    /// The views' load warnings (each naming its file), in view order.
    pub(crate) fn load_warnings(&self) -> Vec<String> {
        let notes = self.notes.lock().unwrap_or_else(PoisonError::into_inner);
        notes.warnings.values().flatten().cloned().collect()
    }

    /// When no view could be prepared and the region-of-interest crop emptied some of them: one
    /// error naming `roi.radius_m`, the focus point it used and the views, instead of one reason
    /// per view; the other views' reasons follow.
    pub(crate) fn roi_error(&self) -> Option<crate::Error> {
        let notes = self.notes.lock().unwrap_or_else(PoisonError::into_inner);
        let (radius, focus) = self.roi?;
        if notes.roi_emptied.is_empty() || notes.failed.len() < self.len() {
            return None;
        }
        let emptied: Vec<String> = notes.roi_emptied.iter().map(usize::to_string).collect();
        let others: Vec<String> = (notes.failed.iter())
            .filter(|(i, _)| !notes.roi_emptied.contains(i))
            .map(|(i, reason)| format!("; view {i}: {reason}"))
            .collect();
        Some(crate::Error::invalid(
            "scan",
            format!(
                "no usable view: the region-of-interest crop left no points in {} of {} views ({}): none is within \
                 `roi.radius_m` = {radius} m of the focus point ({:.3}, {:.3}, {:.3}) m (world frame, where the views' \
                 optical axes meet, from the recorded poses); raise `roi.radius_m` in the fuse config, or set it to \
                 null (JSON) to crop nothing{}",
                emptied.len(),
                self.len(),
                emptied.join(", "),
                focus.x,
                focus.y,
                focus.z,
                others.concat()
            ),
        ))
    }

    /// The number of views of the scan.
    pub(crate) fn len(&self) -> usize {
        self.scan.views.len()
    }

    /// The scan the views come from.
    pub(crate) fn scan(&self) -> &'a Scan {
        self.scan
    }

    /// View `i`'s recorded pose, `None` when it is not usable.
    pub(crate) fn seed(&self, i: usize) -> Option<Isometry3<f64>> {
        self.scan.world_from_camera(i).ok()
    }

    /// View `i` through the per-view stages, and its points and time per stage. Its measured
    /// points are held only when the fuse streams its views (`view_memory`); otherwise, when they
    /// differ from the registration's copies, the view holds their [`Recipe`], for
    /// [`Preparer::measured`].
    pub(crate) fn view(&self, i: usize) -> (std::result::Result<PreparedView, String>, Tally) {
        let mut tally = Tally::default();
        let view = self.prepare(i, self.memory, &mut tally);
        if let Err(reason) = &view {
            self.note(|n| {
                n.failed.insert(i, reason.clone());
            });
        }
        (view, tally)
    }

    /// View `i`'s measured points (camera frame): held, or read again by their recipe (the view
    /// loaded again, its measured points taken and down-sampled: the same points bit for bit, the
    /// normals within 0.005 deg).
    ///
    /// # Errors
    /// [`crate::Error::Invalid`] naming the view when it can no longer be read as it was (its files
    /// changed during the fuse); voxel errors.
    pub(crate) fn measured(&self, i: usize, measured: Measured) -> Result<PointCloud> {
        let recipe = match measured {
            Measured::Points(points) => return Ok(points),
            Measured::Recipe(recipe) => recipe,
        };
        let changed = |e: String| crate::Error::invalid(format!("view {i}"), format!("read again: {e}"));
        let view = self.loaded(i, &mut Tally::default());
        let cloud = recipe.apply(view.map_err(changed)?.cloud).ok_or_else(|| changed("its points changed".into()))?;
        downsample(&cloud, &self.config.view_voxel)
    }

    /// View `i` through the per-view stages: load and region of interest ([`Preparer::loaded`]),
    /// cleaning on the grid of the kept pixels, plane-normal snap.
    fn prepare(&self, i: usize, memory: ViewMemory, tally: &mut Tally) -> std::result::Result<PreparedView, String> {
        let mut view = self.loaded(i, tally)?;
        view = timed(2, tally, view, |v| cleaned_and_oriented(v, self.config, self.grid, memory))?;
        if let Some(params) = &self.config.snap_plane {
            view = timed(3, tally, view, |v| snap_plane_normals(v, params))?;
        }
        Ok(view)
    }

    /// View `i` loaded (depth -> points, range crop; every `pixel_step`-th row and column), then
    /// cropped to the region of interest.
    fn loaded(&self, i: usize, tally: &mut Tally) -> std::result::Result<PreparedView, String> {
        let load_start = Instant::now();
        let loaded = load_view_every_nth(self.scan, i, self.rays.as_deref(), self.config.pixel_step)
            .map_err(|e| e.to_string())?;
        // the points carry their colors: the color image is not kept
        let LoadedView { world_from_camera: seed, cloud_camera: cloud, pixels, color, warnings } = loaded;
        drop(color);
        if !warnings.is_empty() {
            self.note(|n| {
                n.warnings.entry(i).or_insert(warnings);
            });
        }
        let pixels = pixels.filter(|_| self.config.pixel_window > 0);
        let view = PreparedView { seed, cloud, pixels, measured: None };
        let n = view.cloud.len();
        tally[0] = Some((n, n, load_start.elapsed().as_secs_f64()));
        let mut view = non_empty(view, "the depth range crop").map_err(|e| e.to_string())?;
        if let Some((radius, focus)) = self.roi {
            view = timed(1, tally, view, |v| within(v, radius, focus)).inspect_err(|_| {
                self.note(|n| {
                    n.roi_emptied.insert(i);
                })
            })?;
        }
        Ok(view)
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

/// The view's points within `radius` of `focus` (world frame).
fn within(mut v: PreparedView, radius: f64, focus: Point3<f64>) -> Result<PreparedView> {
    let r2 = (radius * radius) as f32;
    let centre = (v.seed.inverse() * focus).cast::<f32>();
    let keep: Vec<usize> = (0..v.cloud.len()).filter(|&i| (v.cloud.points[i] - centre).norm_squared() <= r2).collect();
    v.cloud.retain_indices(&keep);
    if let Some(pixels) = v.pixels.as_mut() {
        retain_at(pixels, &keep);
    }
    if v.cloud.is_empty() {
        return Err(crate::Error::invalid(
            "view",
            format!(
                "no points within `roi.radius_m` = {radius} m of the focus point ({:.3}, {:.3}, {:.3}) m (world frame)",
                focus.x, focus.y, focus.z
            ),
        ));
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::scan::read_scan;
    use crate::scan::ViewData;
    use crate::sim::{SceneKind, SimParams, simulate, write_simulation};

    /// A view's measured points read again by their recipe are those the view would hold: the
    /// same points and colors bit for bit, the normals within 0.01 deg; a view whose files changed
    /// since is an error naming it.
    #[test]
    fn measured_points_read_again_are_the_held_ones() {
        let sim = simulate(&SimParams { views: 3, seed: 5, ..SimParams::scan(SceneKind::Box) }).expect("simulate");
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("scan");
        write_simulation(&path, &sim, false).expect("write");
        let scan = read_scan(&path).expect("read");
        let config = FuseConfig::default();
        let preparer = Preparer::new(&scan, &config);
        assert_eq!(preparer.memory, ViewMemory::Hold, "the default holds every view");
        let prepare =
            |i, copies| preparer.prepare(i, copies, &mut Tally::default()).unwrap_or_else(|e| panic!("view {i}: {e}"));
        let mut recipes = Vec::new();
        for i in 0..3 {
            let (held, registered) = (prepare(i, ViewMemory::Stream), prepare(i, ViewMemory::Hold));
            assert_eq!(held.cloud, registered.cloud, "view {i}: the registration's copies");
            let Some(Measured::Points(want)) = held.measured else { panic!("view {i}: measured points held") };
            let Some(recipe @ Measured::Recipe(_)) = registered.measured else { panic!("view {i}: a recipe") };
            let got = preparer.measured(i, recipe).expect("read again");
            assert!(want.len() > 10_000, "view {i}: {} points", want.len());
            assert_eq!((&got.points, &got.colors), (&want.points, &want.colors), "view {i}");
            let (got, want) = (got.normals.expect("normals"), want.normals.expect("normals"));
            let worst =
                got.iter().zip(&want).map(|(a, b)| a.cast::<f64>().angle(&b.cast()).to_degrees()).fold(0.0, f64::max);
            assert!(worst < 0.01, "view {i}: normals {worst} deg apart");
            recipes.push(prepare(i, ViewMemory::Hold).measured);
        }
        // view 2's depth image replaced by view 0's: its points are no longer those of its recipe
        let depth = |i: usize| match &scan.views[i].data {
            ViewData::Depth { depth, .. } => scan.dir.join(depth),
            _ => panic!("a depth view"),
        };
        std::fs::copy(depth(0), depth(2)).expect("replace view 2's depth");
        let Some(recipe) = recipes.pop().flatten() else { panic!("a recipe") };
        let err = preparer.measured(2, recipe).expect_err("changed").to_string();
        assert!(err.contains("view 2") && err.contains("read again"), "{err}");
    }
}
