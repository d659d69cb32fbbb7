//! Neighbourhoods on the pixel grid of the depth image a cloud came from (PCL's "organized"
//! clouds): a point's neighbour candidates are the points of the pixels in a small window around
//! its own, so outlier removal and normals need no k-d tree.
//!
//! Within a window the neighbours are still chosen by 3D distance (the `k` nearest of the window's
//! points), so a window that straddles a depth edge keeps the points of the point's own surface.
//! What differs from a k-d tree's k-NN: a neighbour outside the window is never found. With a
//! 7 x 7 window and 20 neighbours that only matters where the surface is seen nearly
//! edge-on (few points per window on it), which the incidence filter removes anyway.

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::filter::outlier::{SorParams, SorResult, from_mean_distances};
use crate::normals::{NormalParams, covariance_and_mean, plane_of};

const NONE: u32 = u32::MAX;

/// The points of a cloud on the `width x height` pixel grid they were back-projected from.
#[derive(Debug, Clone)]
pub struct PixelGrid {
    width: usize,
    height: usize,
    /// Row-major pixel -> point index, `NONE` for pixels without a point.
    at: Vec<u32>,
    /// Point -> pixel index (`v * width + u`).
    pixels: Vec<u32>,
}

impl PixelGrid {
    /// The grid of a cloud whose point `i` came from pixel `pixels[i]` (`v * width + u`).
    ///
    /// # Errors
    /// [`Error::Invalid`] when a pixel is outside the image or holds two points.
    pub fn new(width: usize, height: usize, pixels: Vec<u32>) -> Result<Self> {
        let size = width * height;
        if size >= NONE as usize || pixels.len() >= NONE as usize {
            return Err(Error::invalid("pixel grid", format!("{width} x {height} pixels is too large")));
        }
        let mut at = vec![NONE; size];
        for (i, &p) in pixels.iter().enumerate() {
            let slot = at.get_mut(p as usize).ok_or_else(|| {
                Error::invalid("pixel grid", format!("point {i}: pixel {p} is outside the {width} x {height} image"))
            })?;
            if *slot != NONE {
                return Err(Error::invalid("pixel grid", format!("points {} and {i} share pixel {p}", *slot)));
            }
            *slot = i as u32;
        }
        Ok(Self { width, height, at, pixels })
    }

    /// Number of points on the grid.
    pub fn len(&self) -> usize {
        self.pixels.len()
    }

    /// True when no pixel holds a point.
    pub fn is_empty(&self) -> bool {
        self.pixels.is_empty()
    }

    /// Calls `f` with every other point in the `(2 half + 1)^2` window centred on point `i`'s pixel.
    fn for_window(&self, i: usize, half: usize, mut f: impl FnMut(usize)) {
        let p = self.pixels[i] as usize;
        let (u, v) = (p % self.width, p / self.width);
        let (u0, u1) = (u.saturating_sub(half), (u + half).min(self.width - 1));
        for row in v.saturating_sub(half)..=(v + half).min(self.height - 1) {
            for &j in &self.at[row * self.width + u0..=row * self.width + u1] {
                if j != NONE && j as usize != i {
                    f(j as usize);
                }
            }
        }
    }
}

/// The `k` nearest of the points in point `i`'s window for which `keep` holds, into `near`, in no
/// particular order (but always the same), each as `squared distance bits << 32 | index`: a
/// non-negative f32's bits order like the f32, so one integer comparison orders by distance, then
/// by index.
fn window_knn(
    points: &[Point3<f32>],
    grid: &PixelGrid,
    i: usize,
    half: usize,
    k: usize,
    keep: impl Fn(usize) -> bool,
    near: &mut Vec<u64>,
) {
    near.clear();
    let p = points[i];
    grid.for_window(i, half, |j| {
        if keep(j) {
            near.push(u64::from((points[j] - p).norm_squared().to_bits()) << 32 | j as u64);
        }
    });
    if near.len() > k {
        near.select_nth_unstable(k);
        near.truncate(k);
    }
}

/// The squared distance and the index packed by [`window_knn`].
fn unpack(key: u64) -> (f32, usize) {
    (f32::from_bits((key >> 32) as u32), (key & 0xffff_ffff) as usize)
}

fn check(cloud: &PointCloud, grid: &PixelGrid, half: usize) -> Result<()> {
    cloud.validate("pixel-grid input")?;
    if grid.len() != cloud.len() {
        let msg = format!("{} pixels for {} points", grid.len(), cloud.len());
        return Err(Error::invalid("pixel grid", msg));
    }
    if half == 0 {
        return Err(Error::invalid("pixel_window", "0 pixels: the window holds no neighbour"));
    }
    Ok(())
}

/// Statistical outlier removal (Open3D's rule, see `filter::outlier::statistical`) with each
/// point's `params.neighbors` nearest points (itself included) taken from its window of
/// `(2 half + 1)^2` pixels.
///
/// # Errors
/// Bad parameters, a non-finite cloud, a grid of another size, `half == 0`.
pub fn statistical(cloud: &PointCloud, grid: &PixelGrid, half: usize, params: &SorParams) -> Result<SorResult> {
    params.validate()?;
    check(cloud, grid, half)?;
    let points = &cloud.points;
    let mean_dist: Vec<f64> = (0..points.len())
        .into_par_iter()
        .with_min_len(1024)
        .map_init(Vec::new, |near, i| {
            window_knn(points, grid, i, half, params.neighbors - 1, |_| true, near);
            mean_distance(near)
        })
        .collect();
    Ok(from_mean_distances(&mean_dist, params))
}

/// Mean distance to the neighbours `near` and the point itself (at 0); 0 without neighbours.
fn mean_distance(near: &[u64]) -> f64 {
    let sum: f64 = near.iter().map(|&key| f64::from(unpack(key).0).sqrt()).sum();
    if near.is_empty() { 0.0 } else { sum / (near.len() + 1) as f64 }
}

/// A unit normal (zero when undefined) and the centroid of its neighbourhood.
type Fit = (Vector3<f32>, Point3<f32>);

/// Unit normal of point `i` and its neighbours `near` within `r2` (squared), zero when undefined,
/// and their centroid (the point itself when undefined).
fn normal_of(points: &[Point3<f32>], i: usize, near: &[u64], r2: f32) -> Fit {
    let within = near.iter().map(|&key| unpack(key)).filter(|n| n.0 <= r2).map(|n| n.1);
    let fit = covariance_and_mean(points, &points[i], std::iter::once(i).chain(within))
        .and_then(|(cov, mean)| Some((plane_of(cov)?.0, mean)));
    fit.map_or_else(|| (Vector3::zeros(), points[i]), |(n, mean)| (n.cast::<f32>(), mean.cast::<f32>()))
}

/// What [`clean`] returns.
#[derive(Debug, Clone, PartialEq)]
pub struct Cleaned {
    /// The outlier removal.
    pub sor: SorResult,
    /// Unit normals (unoriented; zero where undefined) of the kept points.
    pub normals: Vec<Vector3<f32>>,
    /// The centroid of each kept point's normal neighbourhood (the point itself where its normal
    /// is undefined).
    pub centroids: Vec<Point3<f32>>,
}

/// Each point moved along its ray from the camera (the origin) onto the plane through its
/// neighbourhood's centroid with its normal: the depth noise of a smooth surface averaged over the
/// neighbourhood, the pixel kept. A point whose move would exceed `max_shift_m` (a normal nearly
/// across the ray, a neighbourhood across an edge) or whose normal is zero stays where it is.
pub fn onto_local_planes(
    points: &[Point3<f32>],
    normals: &[Vector3<f32>],
    centroids: &[Point3<f32>],
    max_shift_m: f32,
) -> Vec<Point3<f32>> {
    points
        .par_iter()
        .zip(normals.par_iter().zip(centroids.par_iter()))
        .with_min_len(4096)
        .map(|(p, (n, c))| {
            let along = n.dot(&p.coords);
            if along == 0.0 {
                return *p;
            }
            let moved = p * (n.dot(&c.coords) / along);
            if (moved - p).norm() <= max_shift_m { moved } else { *p }
        })
        .collect()
}

/// [`statistical`], then [`normals`] of the kept points, in one pass over the windows: every
/// point's neighbours are chosen once, for its mean distance and a provisional normal; only the
/// kept points with a removed point in their window (whose kept neighbours may differ) are searched
/// again. Same kept points and normals as the two calls; bit for bit when the two neighbour counts
/// are equal (the default: otherwise a mean distance may sum in another order). Returns the kept
/// points, their normals and their neighbourhoods' centroids.
///
/// # Errors
/// As [`statistical`] and [`normals`].
pub fn clean(
    cloud: &PointCloud,
    grid: &PixelGrid,
    half: usize,
    sor: &SorParams,
    params: &NormalParams,
) -> Result<Cleaned> {
    sor.validate()?;
    params.validate()?;
    check(cloud, grid, half)?;
    let points = &cloud.points;
    let (k_sor, k_normal) = (sor.neighbors - 1, params.neighbors - 1);
    let (k_min, k_max) = (k_sor.min(k_normal), k_sor.max(k_normal));
    let r2 = params.radius_m.map_or(f32::INFINITY, |r| (r * r) as f32);
    let (mean_dist, provisional): (Vec<f64>, Vec<Fit>) = (0..points.len())
        .into_par_iter()
        .with_min_len(1024)
        .map_init(Vec::new, |near: &mut Vec<u64>, i| {
            window_knn(points, grid, i, half, k_max, |_| true, near);
            if near.len() > k_min {
                near.select_nth_unstable(k_min); // the smaller set first, then the rest
            }
            let mean = mean_distance(&near[..k_sor.min(near.len())]);
            (mean, normal_of(points, i, &near[..k_normal.min(near.len())], r2))
        })
        .unzip();
    let result = from_mean_distances(&mean_dist, sor);
    let mut removed = vec![true; points.len()];
    for &i in &result.kept {
        removed[i] = false;
    }
    let mut dirty = vec![false; points.len()];
    for i in (0..points.len()).filter(|&i| removed[i]) {
        grid.for_window(i, half, |j| dirty[j] = true);
    }
    let (normals, centroids) = result
        .kept
        .par_iter()
        .with_min_len(1024)
        .map_init(Vec::new, |near, &i| {
            if !dirty[i] {
                return provisional[i];
            }
            window_knn(points, grid, i, half, k_normal, |j| !removed[j], near);
            normal_of(points, i, near, r2)
        })
        .unzip();
    Ok(Cleaned { sor: result, normals, centroids })
}

/// Unit normals (unoriented; zero where undefined) of the points `kept`, from the
/// `params.neighbors` nearest kept points (the point included) of each one's window within
/// `params.radius_m`.
///
/// # Errors
/// Bad parameters, a non-finite cloud, a grid of another size, `half == 0`, a kept index out of range.
pub fn normals(
    cloud: &PointCloud,
    grid: &PixelGrid,
    half: usize,
    kept: &[usize],
    params: &NormalParams,
) -> Result<Vec<Vector3<f32>>> {
    params.validate()?;
    check(cloud, grid, half)?;
    let points = &cloud.points;
    let mut is_kept = vec![false; points.len()];
    for &i in kept {
        *is_kept.get_mut(i).ok_or_else(|| Error::invalid("normals", format!("kept point {i} out of range")))? = true;
    }
    let r2 = params.radius_m.map_or(f32::INFINITY, |r| (r * r) as f32);
    Ok(kept
        .par_iter()
        .with_min_len(1024)
        .map_init(Vec::new, |near, &i| {
            window_knn(points, grid, i, half, params.neighbors - 1, |j| is_kept[j], near);
            normal_of(points, i, near, r2).0
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::outlier::statistical_detailed;
    use crate::normals::with_normals;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A 120 x 90 view of a plane tilted 30 degrees, 1 m away, with depth noise and `flying`
    /// points pushed 5-20 cm off the surface: (cloud, pixels, plane normal, the flying points).
    fn tilted_plane(flying: usize, seed: u64) -> (PointCloud, Vec<u32>, Vector3<f32>, Vec<usize>) {
        let (w, h, f) = (120usize, 90usize, 300.0f32);
        let normal = Vector3::new(0.0, 30f32.to_radians().sin(), -30f32.to_radians().cos());
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (mut points, mut pixels, mut outliers) = (Vec::new(), Vec::new(), Vec::new());
        for v in 0..h {
            for u in 0..w {
                if rng.random::<f32>() < 0.05 {
                    continue; // a hole
                }
                let ray = Vector3::new((u as f32 - 60.0) / f, (v as f32 - 45.0) / f, 1.0);
                // plane: normal . p = normal . (0, 0, 1)
                let mut z = normal.z / normal.dot(&ray);
                z += rng.random_range(-0.001..0.001);
                if pixels.len() % 97 == 0 && outliers.len() < flying {
                    outliers.push(points.len());
                    z += rng.random_range(0.05..0.2);
                }
                points.push(Point3::from(ray * z));
                pixels.push((v * w + u) as u32);
            }
        }
        (PointCloud { points, normals: None, colors: None }, pixels, normal, outliers)
    }

    #[test]
    fn grid_rejects_bad_pixels() {
        assert!(PixelGrid::new(4, 3, vec![0, 11]).is_ok());
        let out = PixelGrid::new(4, 3, vec![0, 12]).expect_err("an error").to_string();
        assert!(out.contains("pixel 12 is outside"), "{out}");
        let twice = PixelGrid::new(4, 3, vec![5, 5]).expect_err("an error").to_string();
        assert!(twice.contains("share pixel 5"), "{twice}");
    }

    #[test]
    fn window_stays_inside_the_image() {
        let grid = PixelGrid::new(3, 2, (0..6).collect()).expect("ok");
        let mut seen = Vec::new();
        grid.for_window(0, 1, |j| seen.push(j));
        assert_eq!(seen, vec![1, 3, 4]);
        seen.clear();
        grid.for_window(5, 5, |j| seen.push(j));
        assert_eq!(seen, vec![0, 1, 2, 3, 4]);
    }

    #[test]
    fn removes_flying_points_like_the_tree_and_keeps_the_surface() {
        let (cloud, pixels, _, outliers) = tilted_plane(60, 1);
        let grid = PixelGrid::new(120, 90, pixels).expect("ok");
        let sor = SorParams::default();
        let ours = statistical(&cloud, &grid, 3, &sor).expect("ok");
        let tree = statistical_detailed(&cloud, &sor).expect("ok");
        // Every pushed point is removed, and nearly nothing else (the tree removes the same).
        for &o in &outliers {
            assert!(ours.kept.binary_search(&o).is_err(), "flying point {o} kept");
        }
        let removed = cloud.len() - ours.kept.len();
        assert!(removed >= outliers.len() && removed <= outliers.len() + cloud.len() / 100, "removed {removed}");
        let common = ours.kept.iter().filter(|i| tree.kept.binary_search(i).is_ok()).count();
        assert!(common as f64 >= 0.99 * tree.kept.len() as f64, "{common} of {}", tree.kept.len());
        // The window's neighbours are the tree's on a plane seen head-on: same mean distance to 5 %.
        assert!((ours.mean_distance_m / tree.mean_distance_m - 1.0).abs() < 0.05, "{ours:?} vs {tree:?}");
    }

    #[test]
    fn normals_match_the_plane_and_the_tree() {
        let (cloud, pixels, normal, _) = tilted_plane(0, 2);
        let grid = PixelGrid::new(120, 90, pixels).expect("ok");
        let all: Vec<usize> = (0..cloud.len()).collect();
        let params = NormalParams::default();
        let ours = normals(&cloud, &grid, 3, &all, &params).expect("ok");
        let tree = with_normals(&cloud, &params, None).expect("ok").normals.expect("ok");
        let angle = |a: &Vector3<f32>, b: &Vector3<f32>| a.dot(b).abs().min(1.0).acos().to_degrees();
        let mut ours_err: Vec<f32> = ours.iter().map(|n| angle(n, &normal)).collect();
        let mut tree_err: Vec<f32> = tree.iter().map(|n| angle(n, &normal)).collect();
        ours_err.sort_by(f32::total_cmp);
        tree_err.sort_by(f32::total_cmp);
        let (ours_med, tree_med) = (ours_err[ours_err.len() / 2], tree_err[tree_err.len() / 2]);
        assert!(ours_med < 3.0 && ours_med < 1.2 * tree_med, "median {ours_med} deg vs tree {tree_med} deg");
    }

    #[test]
    fn one_pass_equals_the_two_passes() {
        let (cloud, pixels, _, _) = tilted_plane(80, 5);
        let grid = PixelGrid::new(120, 90, pixels).expect("ok");
        for (sor_k, normal_k, radius) in [(20, 20, Some(0.01)), (12, 30, Some(0.004)), (30, 8, None)] {
            let sor = SorParams { neighbors: sor_k, ..SorParams::default() };
            let params = NormalParams { neighbors: normal_k, radius_m: radius };
            let Cleaned { sor: result, normals: ours, .. } = clean(&cloud, &grid, 3, &sor, &params).expect("ok");
            let reference = statistical(&cloud, &grid, 3, &sor).expect("ok");
            assert_eq!(result.kept, reference.kept);
            assert!(reference.kept.len() <= cloud.len() - 80, "{} of {}", reference.kept.len(), cloud.len());
            let theirs = normals(&cloud, &grid, 3, &reference.kept, &params).expect("ok");
            if sor_k == normal_k {
                assert_eq!((result.mean_distance_m, ours.clone()), (reference.mean_distance_m, theirs.clone()));
            }
            let worst = ours.iter().zip(&theirs).map(|(a, b)| (a - b).norm()).fold(0.0f32, f32::max);
            assert!(worst < 1e-6, "{sor_k} {normal_k}: {worst}");
        }
    }

    #[test]
    fn points_onto_their_local_planes_lose_most_of_the_depth_noise_and_keep_their_rays() {
        let (cloud, pixels, normal, _) = tilted_plane(0, 6);
        let grid = PixelGrid::new(120, 90, pixels).expect("ok");
        let c = clean(&cloud, &grid, 3, &SorParams::default(), &NormalParams::default()).expect("ok");
        let kept = cloud.select(&c.sor.kept).points;
        let moved = onto_local_planes(&kept, &c.normals, &c.centroids, 0.005);
        let rms = |ps: &[Point3<f32>]| {
            let sum: f64 = ps.iter().map(|p| f64::from(normal.dot(&p.coords) - normal.z).powi(2)).sum();
            (sum / ps.len() as f64).sqrt()
        };
        // +-1 mm uniform depth noise: ~0.5 mm off the plane; 20 neighbours average it to ~0.15 mm
        let (before, after) = (rms(&kept), rms(&moved));
        assert!(before > 4e-4 && after < 0.35 * before, "rms {before} -> {after} m");
        for (p, q) in kept.iter().zip(&moved) {
            assert!(p.coords.cross(&q.coords).norm() <= 1e-6 * p.coords.norm() * q.coords.norm(), "{p} -> {q}");
        }
        // a move over the limit leaves the point where it was
        assert_eq!(onto_local_planes(&kept, &c.normals, &c.centroids, 0.0), kept);
    }

    #[test]
    fn same_result_on_one_and_two_threads() {
        let (cloud, pixels, _, _) = tilted_plane(30, 3);
        let grid = PixelGrid::new(120, 90, pixels).expect("ok");
        let run = |threads| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("ok");
            pool.install(|| {
                let c = clean(&cloud, &grid, 3, &SorParams::default(), &NormalParams::default()).expect("ok");
                (c.normals, c.centroids, c.sor.kept)
            })
        };
        assert_eq!(run(1), run(2));
    }

    #[test]
    fn bad_input_is_an_error() {
        let (cloud, pixels, _, _) = tilted_plane(0, 4);
        let grid = PixelGrid::new(120, 90, pixels).expect("ok");
        let sor = SorParams::default();
        assert!(statistical(&cloud, &grid, 0, &sor).expect_err("an error").to_string().contains("pixel_window"));
        let fewer = cloud.select(&[0, 1, 2]);
        assert!(statistical(&fewer, &grid, 3, &sor).expect_err("an error").to_string().contains("pixels for 3 points"));
        let mut nan = cloud.clone();
        nan.points[7].x = f32::NAN;
        assert!(statistical(&nan, &grid, 3, &sor).is_err());
        assert!(normals(&cloud, &grid, 3, &[cloud.len()], &NormalParams::default()).is_err());
    }
}
