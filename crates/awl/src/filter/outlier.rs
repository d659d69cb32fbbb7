//! Outlier removal: statistical (mean distance to the k nearest points) and radius (neighbour count).
//!
//! Input: a cloud (metres, any frame). Output: the indices of the points KEPT, ascending; pass them
//! to [`PointCloud::select`]. Both filters follow Open3D 0.20's `remove_statistical_outlier` and
//! `remove_radius_outlier` rule for rule (see each function; `tests/outlier_open3d.rs` checks the
//! statistical one against Open3D on a real 209 k-point stereo cloud). Neighbour distances are
//! recomputed in f64 from the f32 positions, as Open3D does on its double copies. Parallel over
//! points (rayon); the result does not depend on the number of threads (per-point values are
//! independent, the cloud statistics are summed serially in index order).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use nalgebra::Point3;

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::spatial::{KdIndex, KnnTable, Neighbor, knn_map};

/// Statistical outlier removal parameters (Open3D's `nb_neighbors`, `std_ratio`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct SorParams {
    /// Nearest points per point, the point itself INCLUDED (default 20, at least 2: with 1 every
    /// mean distance is 0 and Open3D removes every point).
    pub neighbors: usize,
    /// Keep points whose mean neighbour distance is below mean + `std_ratio` × standard deviation
    /// (default 2.0; positive and finite).
    pub std_ratio: f64,
}

impl Default for SorParams {
    fn default() -> Self {
        Self { neighbors: 20, std_ratio: 2.0 }
    }
}

impl SorParams {
    /// Checks the parameters.
    ///
    /// # Errors
    /// [`Error::Invalid`] when `neighbors < 2` or `std_ratio` is not a positive finite number.
    pub fn validate(&self) -> Result<()> {
        if self.neighbors < 2 {
            return Err(Error::invalid(
                "sor.neighbors",
                format!("{} < 2: the count includes the point itself, so nothing would be kept", self.neighbors),
            ));
        }
        if !(self.std_ratio.is_finite() && self.std_ratio > 0.0) {
            return Err(Error::invalid("sor.std_ratio", format!("{} is not a positive finite ratio", self.std_ratio)));
        }
        Ok(())
    }
}

/// What [`statistical_detailed`] computed.
#[derive(Debug, Clone, PartialEq)]
pub struct SorResult {
    /// Indices of the kept points, ascending.
    pub kept: Vec<usize>,
    /// Cloud mean of the per-point mean neighbour distances, metres (see [`statistical`]).
    pub mean_distance_m: f64,
    /// Their standard deviation (Bessel-corrected), metres.
    pub std_distance_m: f64,
    /// `mean_distance_m + std_ratio * std_distance_m`, metres.
    pub threshold_m: f64,
}

/// Statistical outlier removal; returns the kept indices, ascending.
///
/// The rule, exactly Open3D 0.20's `PointCloud::RemoveStatisticalOutliers`:
/// 1. for each point i, `d_i` = mean of the Euclidean distances to its `k = neighbors` nearest
///    points, the point itself (distance 0) included (fewer when the cloud has fewer points);
/// 2. `mean = Σ_{d_i > 0} d_i / n` — the sum skips points whose neighbours all coincide with them,
///    but the divisor is the number `n` of ALL points (Open3D counts every point with a neighbour);
/// 3. `std = sqrt(Σ_{d_i > 0} (d_i − mean)² / (n − 1))`;
/// 4. keep i when `0 < d_i < mean + std_ratio · std`.
///
/// So a point that coincides with all of its k − 1 nearest neighbours is always removed, as in
/// Open3D. A single-point cloud keeps nothing. Neighbours tied at equal distance may be chosen
/// differently than Open3D's k-d tree does; `d_i` is unaffected unless the tie is only equal in f32.
///
/// # Errors
/// [`Error::Invalid`] for bad parameters (see [`SorParams::validate`]) or a cloud with
/// inconsistent attributes or non-finite points. An empty cloud gives `Ok(vec![])`.
pub fn statistical(cloud: &PointCloud, params: &SorParams) -> Result<Vec<usize>> {
    statistical_detailed(cloud, params).map(|r| r.kept)
}

/// Like [`statistical`], also returning the cloud statistics and the threshold used.
///
/// # Errors
/// As [`statistical`].
pub fn statistical_detailed(cloud: &PointCloud, params: &SorParams) -> Result<SorResult> {
    params.validate()?;
    cloud.validate("statistical outlier removal input")?;
    if cloud.is_empty() {
        return Ok(SorResult { kept: Vec::new(), mean_distance_m: 0.0, std_distance_m: 0.0, threshold_m: 0.0 });
    }
    let points = &cloud.points;
    let mean_dist = knn_map(points, params.neighbors, |i, row| mean_distance(points, i, row))?;
    Ok(from_mean_distances(&mean_dist, params))
}

/// Like [`statistical_detailed`], with k-NN lists already computed: `table`, over exactly the
/// cloud's points, with at least `params.neighbors` per row unless the cloud is smaller (a row's
/// first `params.neighbors` entries are the `params.neighbors`-row). Same result as
/// [`statistical_detailed`], bit for bit. This is how `awl fuse` shares one k-NN pass between
/// outlier removal and normals.
///
/// # Errors
/// As [`statistical`]; also [`Error::Invalid`] when the table does not match the cloud.
pub fn statistical_from_knn(cloud: &PointCloud, table: &KnnTable, params: &SorParams) -> Result<SorResult> {
    params.validate()?;
    cloud.validate("statistical outlier removal input")?;
    let k = params.neighbors.min(cloud.len());
    if table.k() < k || (k > 0 && table.row_count() != cloud.len()) {
        let msg = format!(
            "k-NN table of {} x {} for {} points and {} neighbours",
            table.row_count(),
            table.k(),
            cloud.len(),
            k
        );
        return Err(Error::invalid("statistical outlier removal", msg));
    }
    if cloud.is_empty() {
        return Ok(SorResult { kept: Vec::new(), mean_distance_m: 0.0, std_distance_m: 0.0, threshold_m: 0.0 });
    }
    let points = &cloud.points;
    let mean_dist: Vec<f64> = (0..points.len())
        .into_par_iter()
        .with_min_len(256)
        .map(|i| mean_distance(points, i, &table.row(i)[..k]))
        .collect();
    Ok(from_mean_distances(&mean_dist, params))
}

/// Point `i`'s mean distance to the points of its row (f64, summed nearest first as Open3D does).
fn mean_distance(points: &[Point3<f32>], i: usize, row: &[Neighbor]) -> f64 {
    let q = points[i].cast::<f64>();
    let (mut stack, mut heap) = ([0.0f64; 64], Vec::new());
    let d: &mut [f64] = if row.len() <= stack.len() {
        &mut stack[..row.len()]
    } else {
        heap.resize(row.len(), 0.0);
        &mut heap
    };
    for (x, nb) in d.iter_mut().zip(row) {
        *x = (points[nb.index as usize].cast::<f64>() - q).norm();
    }
    d.sort_unstable_by(f64::total_cmp);
    d.iter().sum::<f64>() / d.len() as f64
}

/// Open3D's rule on per-point mean neighbour distances (`0` = no neighbour: removed, left out of
/// the statistics): keep the points below mean + `std_ratio` x standard deviation.
pub(crate) fn from_mean_distances(mean_dist: &[f64], params: &SorParams) -> SorResult {
    let n = mean_dist.len() as f64;
    let mean = mean_dist.iter().filter(|&&d| d > 0.0).sum::<f64>() / n;
    let sq_sum: f64 = mean_dist.iter().filter(|&&d| d > 0.0).map(|&d| (d - mean) * (d - mean)).sum();
    let std = (sq_sum / (n - 1.0)).sqrt();
    let threshold = mean + params.std_ratio * std;
    let kept = (0..mean_dist.len()).filter(|&i| mean_dist[i] > 0.0 && mean_dist[i] < threshold).collect();
    SorResult { kept, mean_distance_m: mean, std_distance_m: std, threshold_m: threshold }
}

/// Radius outlier removal parameters (Open3D's `radius`, `nb_points`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RadiusParams {
    /// Neighbourhood radius, metres (default 0.01: 5 voxels of the default 2 mm grid, where a
    /// surface disc holds about 75 points). Positive and finite.
    pub radius_m: f64,
    /// Keep a point when at least this many OTHER points lie closer than `radius_m` (default 8:
    /// removes isolated specks and small floating clusters, keeps surface edges and thin parts,
    /// which still hold a half disc). At least 1.
    pub min_neighbors: usize,
}

impl Default for RadiusParams {
    fn default() -> Self {
        Self { radius_m: 0.01, min_neighbors: 8 }
    }
}

impl RadiusParams {
    /// Checks the parameters.
    ///
    /// # Errors
    /// [`Error::Invalid`] when `radius_m` is not a positive finite number or `min_neighbors` is 0.
    pub fn validate(&self) -> Result<()> {
        if !(self.radius_m.is_finite() && self.radius_m > 0.0) {
            return Err(Error::invalid(
                "radius_outlier.radius_m",
                format!("{} is not a positive radius", self.radius_m),
            ));
        }
        if self.min_neighbors == 0 {
            return Err(Error::invalid("radius_outlier.min_neighbors", "0 would keep every point"));
        }
        Ok(())
    }
}

/// Radius outlier removal; returns the kept indices, ascending.
///
/// The rule, exactly Open3D 0.20's `PointCloud::RemoveRadiusOutliers(nb_points = min_neighbors,
/// search_radius = radius_m)`: count the points at distance strictly less than `radius_m` (in f64),
/// the point itself included, and keep the point when that count is GREATER than `min_neighbors`,
/// i.e. when at least `min_neighbors` other points are that close. A point exactly `radius_m` away
/// does not count (Open3D's nanoflann search is strict; checked on Open3D 0.20.0).
///
/// # Errors
/// [`Error::Invalid`] for bad parameters (see [`RadiusParams::validate`]) or a cloud with
/// inconsistent attributes or non-finite points. An empty cloud gives `Ok(vec![])`.
pub fn radius(cloud: &PointCloud, params: &RadiusParams) -> Result<Vec<usize>> {
    params.validate()?;
    cloud.validate("radius outlier removal input")?;
    if cloud.is_empty() {
        return Ok(Vec::new());
    }
    let points = &cloud.points;
    let index = KdIndex::new(points)?;
    let r2 = params.radius_m * params.radius_m;
    // A slightly larger f32 search, then the exact f64 test.
    let search_m = (params.radius_m * (1.0 + 1e-5)) as f32;
    let keep: Vec<bool> = points
        .par_iter()
        .map(|p| {
            let q = p.cast::<f64>();
            let close = index
                .within(p, search_m)
                .iter()
                .filter(|nb| (points[nb.index as usize].cast::<f64>() - q).norm_squared() < r2)
                .count();
            close > params.min_neighbors
        })
        .collect();
    Ok((0..keep.len()).filter(|&i| keep[i]).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;
    use rand::{RngExt, SeedableRng};

    fn line(xs: &[f32]) -> PointCloud {
        PointCloud::from_points(xs.iter().map(|&x| Point3::new(x, 0.0, 0.0)).collect())
    }

    fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool").install(f)
    }

    #[test]
    fn hand_computed_threshold() {
        // x = 0 0 0 0 1 2 4 8, k = 2 (self + nearest): d = 0 0 0 0 .5 .5 1 2.
        // mean = (0.5 + 0.5 + 1 + 2) / 8 = 0.5 (divisor: all 8 points, as Open3D);
        // std = sqrt((0 + 0 + 0.25 + 2.25) / 7) = sqrt(2.5 / 7) = 0.5976143;
        // ratio 0.5: threshold 0.7988 keeps {4, 5}; ratio 1.0: 1.0976 keeps {4, 5, 6}.
        // (Averaging over the 4 points with d > 0 instead would keep {4, 5, 6} at ratio 0.5.)
        // Open3D 0.20.0 returns [4, 5] and [4, 5, 6] on this cloud.
        let cloud = line(&[0.0, 0.0, 0.0, 0.0, 1.0, 2.0, 4.0, 8.0]);
        let r = statistical_detailed(&cloud, &SorParams { neighbors: 2, std_ratio: 0.5 }).expect("sor");
        assert_eq!(r.kept, vec![4, 5]);
        assert!((r.mean_distance_m - 0.5).abs() < 1e-15);
        assert!((r.std_distance_m - (2.5f64 / 7.0).sqrt()).abs() < 1e-15);
        assert!((r.threshold_m - (0.5 + 0.5 * (2.5f64 / 7.0).sqrt())).abs() < 1e-15);
        assert_eq!(statistical(&cloud, &SorParams { neighbors: 2, std_ratio: 1.0 }).expect("sor"), vec![4, 5, 6]);
    }

    #[test]
    fn plane_with_far_outliers() {
        // A 100 x 100 grid at 1 cm on z = 0 with 0.5 mm jitter, plus 10 points 0.2-1.1 m above it.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut points = Vec::new();
        for i in 0..100 {
            for j in 0..100 {
                let jitter = |rng: &mut rand_chacha::ChaCha8Rng| (rng.random::<f32>() - 0.5) * 0.001;
                points.push(Point3::new(i as f32 * 0.01 + jitter(&mut rng), j as f32 * 0.01 + jitter(&mut rng), 0.0));
            }
        }
        let outliers: Vec<usize> = (0..10).map(|o| o * 997 + 5).collect();
        for (o, &at) in outliers.iter().enumerate() {
            let p = Point3::new(0.1 * o as f32, 0.05 * o as f32, 0.2 + 0.1 * o as f32);
            points.insert(at, p);
        }
        let cloud = PointCloud::from_points(points);
        let kept = statistical(&cloud, &SorParams::default()).expect("sor");
        let removed: Vec<usize> = (0..cloud.len()).filter(|i| kept.binary_search(i).is_err()).collect();
        assert_eq!(removed, outliers);
    }

    #[test]
    fn one_and_two_threads_agree() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let points: Vec<Point3<f32>> = (0..20_000)
            .map(|_| {
                let r = if rng.random::<f32>() < 0.02 { 1.0 } else { 0.1 };
                Point3::new(rng.random::<f32>() * r, rng.random::<f32>() * r, rng.random::<f32>() * 0.01)
            })
            .collect();
        let cloud = PointCloud::from_points(points);
        let sor = SorParams::default();
        let rad = RadiusParams::default();
        let one = in_pool(1, || (statistical_detailed(&cloud, &sor).expect("sor"), radius(&cloud, &rad).expect("r")));
        let two = in_pool(2, || (statistical_detailed(&cloud, &sor).expect("sor"), radius(&cloud, &rad).expect("r")));
        assert_eq!(one, two);
        assert!(one.0.kept.len() < cloud.len() && one.1.len() < cloud.len());
    }

    #[test]
    fn radius_hand_made() {
        // x = 0 1 2 5 5.5: at radius 1 the pairs 0-1 and 1-2 are exactly 1 apart and do not count.
        // Open3D 0.20.0: radius 1, nb_points 1 -> [3, 4]; radius 1.0000001 -> all; nb_points 2 -> [1].
        let cloud = line(&[0.0, 1.0, 2.0, 5.0, 5.5]);
        let run = |radius_m: f64, min_neighbors: usize| radius(&cloud, &RadiusParams { radius_m, min_neighbors });
        assert_eq!(run(1.0, 1).expect("r"), vec![3, 4]);
        assert_eq!(run(1.000_000_1, 1).expect("r"), vec![0, 1, 2, 3, 4]);
        assert_eq!(run(1.000_000_1, 2).expect("r"), vec![1]);
        assert_eq!(run(0.5, 1).expect("r"), Vec::<usize>::new());
        assert_eq!(run(0.500_01, 1).expect("r"), vec![3, 4]);
    }

    #[test]
    fn edge_cases() {
        let empty = PointCloud::default();
        assert_eq!(statistical(&empty, &SorParams::default()).expect("empty"), Vec::<usize>::new());
        assert_eq!(radius(&empty, &RadiusParams::default()).expect("empty"), Vec::<usize>::new());
        assert!(statistical(&line(&[1.0]), &SorParams::default()).expect("one").is_empty());
        let cloud = line(&[0.0, 1.0, 2.0]);
        for neighbors in [0, 1] {
            let err = statistical(&cloud, &SorParams { neighbors, std_ratio: 2.0 });
            assert!(matches!(err, Err(Error::Invalid { .. })), "{neighbors}: {err:?}");
        }
        for std_ratio in [0.0, -1.0, f64::NAN] {
            assert!(statistical(&cloud, &SorParams { neighbors: 2, std_ratio }).is_err());
        }
        for (radius_m, min_neighbors) in [(0.0, 1), (-1.0, 1), (f64::INFINITY, 1), (1.0, 0)] {
            assert!(radius(&cloud, &RadiusParams { radius_m, min_neighbors }).is_err());
        }
        // More neighbours than points: each point uses all 3.
        // d = (0+1+2)/3 = 1, (0+1+1)/3 = 2/3, 1; mean 8/9, std = sqrt((1/81+4/81+1/81)/2) = 0.1925;
        // threshold at ratio 0.1: 0.908 keeps only the middle point.
        assert_eq!(statistical(&cloud, &SorParams { neighbors: 50, std_ratio: 0.1 }).expect("sor"), vec![1]);
    }
}
