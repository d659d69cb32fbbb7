//! Clustering (DBSCAN) to isolate the object.
//!
//! [`dbscan`] labels every point with a cluster number or -1 (noise). A point is *core* when at least
//! `min_points` points (itself included, as in Open3D and scikit-learn) lie within `eps_m` of it; core
//! points within `eps_m` of each other share a cluster; a non-core point within `eps_m` of a core point
//! is a *border* point of that core point's cluster; every other point is noise.
//!
//! Memory is O(n) small words (about 13 bytes per point besides the caller's points and k-d tree): no
//! neighbour list is ever stored (Open3D stores them all and runs out of memory on a few million points,
//! Open3D#1600). Instead the radius queries are run in three passes, each parallel on the rayon pool:
//! 1. count the neighbours of every point: core flags (1 byte per point);
//! 2. union-find over the core points: each core point is joined with its lower-index core neighbours.
//!    The forest links the larger root under the smaller one, so every root is the smallest index of its
//!    set and the final sets do not depend on the order in which the unions ran;
//! 3. labels: clusters are numbered 0, 1, ... in increasing order of their smallest *core* point index;
//!    each non-core point takes the lowest cluster number among its core neighbours, or -1.
//!
//! The labels therefore do not depend on the number of threads. The border rule gives the same labels as
//! scikit-learn's and Open3D's `ClusterDBSCAN` (both start clusters from core points in index order and
//! give a border point to the first cluster that reaches it, i.e. the one with the lowest number).

use std::sync::atomic::{AtomicU32, Ordering};

use nalgebra::Point3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::spatial::KdIndex;

/// Parameters of [`dbscan`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DbscanParams {
    /// Neighbourhood radius (inclusive), metres. Default 0.01: a few times the spacing of a cloud
    /// down-sampled to 2-3 mm, so a surface stays connected while separate objects do not touch.
    pub eps_m: f64,
    /// Points within `eps_m` (the point itself included) for a point to be core. Default 10, at least 1.
    pub min_points: usize,
}

impl Default for DbscanParams {
    fn default() -> Self {
        Self { eps_m: 0.01, min_points: 10 }
    }
}

/// Result of [`dbscan`].
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Clustering {
    /// One label per input point: the cluster number, or -1 for noise.
    pub labels: Vec<i32>,
    /// Points in each cluster (core and border), indexed by cluster number.
    pub sizes: Vec<usize>,
}

impl Clustering {
    /// Number of clusters.
    pub fn cluster_count(&self) -> usize {
        self.sizes.len()
    }

    /// Number of noise points.
    pub fn noise_count(&self) -> usize {
        self.labels.len() - self.sizes.iter().sum::<usize>()
    }

    /// The cluster with the most points (the lowest number among equals), or `None` without clusters.
    pub fn largest(&self) -> Option<usize> {
        let mut best: Option<(usize, usize)> = None;
        for (label, &size) in self.sizes.iter().enumerate() {
            if best.is_none_or(|(_, s)| size > s) {
                best = Some((label, size));
            }
        }
        best.map(|(label, _)| label)
    }

    /// Indices of the points of cluster `label`, ascending (empty for an unknown label).
    pub fn members(&self, label: usize) -> Vec<usize> {
        let Ok(label) = i32::try_from(label) else { return Vec::new() };
        self.labels.iter().enumerate().filter(|&(_, &l)| l == label).map(|(i, _)| i).collect()
    }
}

/// A lock-free union-find forest whose roots are always the smallest index of their set.
struct Forest {
    parent: Vec<AtomicU32>,
}

impl Forest {
    fn new(n: u32) -> Self {
        Self { parent: (0..n).map(AtomicU32::new).collect() }
    }

    /// The root of `x`, halving the path on the way. Parents only ever move to smaller indices of the
    /// same set, so relaxed ordering is enough: the sets are final once the parallel pass has joined.
    fn find(&self, mut x: u32) -> u32 {
        loop {
            let p = self.parent[x as usize].load(Ordering::Relaxed);
            if p == x {
                return x;
            }
            let g = self.parent[p as usize].load(Ordering::Relaxed);
            if g != p {
                let _ = self.parent[x as usize].compare_exchange_weak(p, g, Ordering::Relaxed, Ordering::Relaxed);
            }
            x = g;
        }
    }

    fn union(&self, a: u32, b: u32) {
        let (mut a, mut b) = (a, b);
        loop {
            a = self.find(a);
            b = self.find(b);
            if a == b {
                return;
            }
            let (hi, lo) = if a > b { (a, b) } else { (b, a) };
            if self.parent[hi as usize].compare_exchange(hi, lo, Ordering::Relaxed, Ordering::Relaxed).is_ok() {
                return;
            }
        }
    }
}

fn validate(points: &[Point3<f32>], index: &KdIndex, params: &DbscanParams) -> Result<f32> {
    let eps = params.eps_m as f32;
    if !(params.eps_m.is_finite() && eps > 0.0 && eps.is_finite()) {
        return Err(Error::invalid("dbscan eps_m", format!("must be positive and finite, got {}", params.eps_m)));
    }
    if params.min_points == 0 {
        return Err(Error::invalid("dbscan min_points", "must be at least 1 (it counts the point itself)"));
    }
    if index.len() != points.len() {
        return Err(Error::invalid(
            "dbscan index",
            format!("indexes {} points but {} points were given", index.len(), points.len()),
        ));
    }
    if points.len() > i32::MAX as usize {
        return Err(Error::invalid("dbscan points", format!("{} points, at most {}", points.len(), i32::MAX)));
    }
    Ok(eps)
}

/// DBSCAN over `points`, with `index` built from the same slice (see the module docs for the passes,
/// the label order and the border rule).
///
/// # Errors
/// [`Error::Invalid`] when `eps_m` is not positive and finite, `min_points` is 0, or `index` does not
/// hold as many points as `points`.
pub fn dbscan(points: &[Point3<f32>], index: &KdIndex, params: &DbscanParams) -> Result<Clustering> {
    let eps = validate(points, index, params)?;
    let n = points.len();
    let min_points = params.min_points;

    // Pass 1: core flags.
    let core: Vec<bool> = points.par_iter().map(|p| index.within(p, eps).len() >= min_points).collect();

    // Pass 2: join core neighbours (each pair once, from its higher index).
    let forest = Forest::new(n as u32);
    (0..n).into_par_iter().filter(|&i| core[i]).for_each(|i| {
        for nb in index.within(&points[i], eps) {
            let j = nb.index as usize;
            if j < i && core[j] {
                forest.union(i as u32, nb.index);
            }
        }
    });

    // Pass 3a: number the clusters by their root (= smallest core index), in index order.
    let mut core_labels = vec![-1i32; n];
    let mut clusters = 0i32;
    for i in 0..n {
        if core[i] {
            let root = forest.find(i as u32) as usize;
            if root == i {
                core_labels[i] = clusters;
                clusters += 1;
            } else {
                core_labels[i] = core_labels[root];
            }
        }
    }
    drop(forest);

    // Pass 3b: border points take the lowest label among their core neighbours.
    let labels: Vec<i32> = (0..n)
        .into_par_iter()
        .map(|i| {
            if core[i] {
                return core_labels[i];
            }
            index
                .within(&points[i], eps)
                .iter()
                .map(|nb| core_labels[nb.index as usize])
                .filter(|&l| l >= 0)
                .min()
                .unwrap_or(-1)
        })
        .collect();

    let mut sizes = vec![0usize; clusters as usize];
    for &l in &labels {
        if l >= 0 {
            sizes[l as usize] += 1;
        }
    }
    Ok(Clustering { labels, sizes })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn run(points: &[Point3<f32>], eps_m: f64, min_points: usize) -> Clustering {
        let index = KdIndex::new(points).expect("index");
        dbscan(points, &index, &DbscanParams { eps_m, min_points }).expect("dbscan")
    }

    fn with_threads<T: Send>(n: usize, f: impl FnOnce() -> T + Send) -> T {
        rayon::ThreadPoolBuilder::new().num_threads(n).build().expect("pool").install(f)
    }

    /// Classic O(n²) DBSCAN in the scikit-learn order: clusters grown from core points in index order,
    /// a border point keeps the first cluster that reaches it.
    fn brute_force(points: &[Point3<f32>], eps_m: f32, min_points: usize) -> Vec<i32> {
        let r2 = eps_m * eps_m;
        let near = |a: &Point3<f32>, b: &Point3<f32>| {
            let d = a - b;
            d.x * d.x + d.y * d.y + d.z * d.z <= r2
        };
        let neighbours: Vec<Vec<usize>> =
            points.iter().map(|p| (0..points.len()).filter(|&j| near(p, &points[j])).collect()).collect();
        let core: Vec<bool> = neighbours.iter().map(|v| v.len() >= min_points).collect();
        let mut labels = vec![-1i32; points.len()];
        let mut next = 0;
        for i in 0..points.len() {
            if labels[i] != -1 || !core[i] {
                continue;
            }
            let mut stack = vec![i];
            while let Some(p) = stack.pop() {
                if labels[p] != -1 {
                    continue;
                }
                labels[p] = next;
                if core[p] {
                    stack.extend(neighbours[p].iter().copied().filter(|&q| labels[q] == -1));
                }
            }
            next += 1;
        }
        labels
    }

    /// Random points on a sphere of radius `r` around `c`.
    fn shell(rng: &mut ChaCha8Rng, c: [f32; 3], r: f32, n: usize) -> Vec<Point3<f32>> {
        (0..n)
            .map(|_| {
                loop {
                    let v = nalgebra::Vector3::new(
                        rng.random_range(-1.0f32..1.0),
                        rng.random_range(-1.0f32..1.0),
                        rng.random_range(-1.0f32..1.0),
                    );
                    let norm = v.norm();
                    if norm > 0.1 && norm <= 1.0 {
                        break Point3::new(c[0], c[1], c[2]) + v * (r / norm);
                    }
                }
            })
            .collect()
    }

    /// Two sphere shells of 100 000 points (r 0.2 m, about 63 neighbours within 1 cm) 10 cm apart, and
    /// noise points on a 3 cm grid at least 3 cm from both shells, shuffled together.
    fn blobs_and_noise() -> (Vec<Point3<f32>>, Vec<u8>) {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let (ca, cb) = ([0.0f32, 0.0, 0.0], [0.5f32, 0.0, 0.0]);
        let mut tagged: Vec<(Point3<f32>, u8)> =
            shell(&mut rng, ca, 0.2, 100_000).into_iter().map(|p| (p, 0)).collect();
        tagged.extend(shell(&mut rng, cb, 0.2, 100_000).into_iter().map(|p| (p, 1)));
        for ix in -10..27 {
            for iy in -10..10 {
                for iz in [-0.3f32, 0.0, 0.3] {
                    let p = Point3::new(ix as f32 * 0.03, iy as f32 * 0.03, iz);
                    let gap = |c: [f32; 3]| ((p - Point3::new(c[0], c[1], c[2])).norm() - 0.2).abs();
                    if gap(ca) > 0.03 && gap(cb) > 0.03 {
                        tagged.push((p, 2));
                    }
                }
            }
        }
        // Fisher-Yates with the seeded generator, so the clusters are interleaved in index order.
        for i in (1..tagged.len()).rev() {
            let j = rng.random_range(0..=i);
            tagged.swap(i, j);
        }
        tagged.into_iter().unzip()
    }

    #[test]
    fn two_blobs_and_noise() {
        let (points, truth) = blobs_and_noise();
        let noise = truth.iter().filter(|&&t| t == 2).count();
        assert!(noise > 1000, "{noise} noise points");
        let c = run(&points, 0.01, 10);
        assert_eq!(c.sizes, vec![100_000, 100_000]);
        assert_eq!(c.noise_count(), noise);
        // Labels follow the smallest index of each cluster; each shell is exactly one cluster.
        let first_a = truth.iter().position(|&t| t == 0).expect("shell a");
        let first_b = truth.iter().position(|&t| t == 1).expect("shell b");
        let (la, lb) = if first_a < first_b { (0, 1) } else { (1, 0) };
        for (label, t) in c.labels.iter().zip(&truth) {
            assert_eq!(*label, [la, lb, -1][*t as usize]);
        }
        assert_eq!(c.largest(), Some(0));
        assert_eq!(c.members(1).len(), 100_000);
        assert!(c.members(2).is_empty());
    }

    #[test]
    fn one_and_two_threads_agree() {
        let (points, _) = blobs_and_noise();
        let index = KdIndex::new(&points).expect("index");
        // Low min_points and a large eps make many border points and near-touching clusters.
        for params in [DbscanParams::default(), DbscanParams { eps_m: 0.004, min_points: 4 }] {
            let one = with_threads(1, || dbscan(&points, &index, &params).expect("1 thread"));
            let two = with_threads(2, || dbscan(&points, &index, &params).expect("2 threads"));
            assert_eq!(one, two);
        }
        let small = with_threads(2, || run(&points, 0.004, 4));
        assert!(small.cluster_count() > 100, "{} clusters", small.cluster_count());
    }

    #[test]
    fn matches_brute_force() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        // Uniform points near the percolation threshold (many small clusters and border points), then
        // Gaussian blobs with a uniform background.
        let uniform: Vec<Point3<f32>> =
            (0..2000).map(|_| Point3::new(rng.random::<f32>(), rng.random::<f32>(), rng.random::<f32>())).collect();
        let normal = rand_distr::Normal::new(0.0f32, 0.05).expect("normal");
        let mut blobs: Vec<Point3<f32>> = (0..1600)
            .map(|i| {
                let c = [0.2f32, 0.45, 0.7][i % 3];
                let mut d = || rng.sample(normal);
                Point3::new(c + d(), c + d(), 0.5 + d())
            })
            .collect();
        blobs.extend((0..400).map(|_| Point3::new(rng.random::<f32>(), rng.random::<f32>(), rng.random::<f32>())));
        let mut checked = 0;
        for (points, eps, min_points) in [
            (&uniform, 0.1f32, 8),
            (&uniform, 0.08, 4),
            (&uniform, 0.12, 15),
            (&blobs, 0.03, 10),
            (&blobs, 0.05, 30),
            (&blobs, 0.02, 1),
        ] {
            let want = brute_force(points, eps, min_points);
            let got = run(points, eps as f64, min_points);
            assert_eq!(got.labels, want, "eps {eps}, min_points {min_points}");
            let clusters = got.cluster_count();
            assert!(clusters >= 2, "eps {eps}, min_points {min_points}: {clusters} clusters");
            checked += clusters;
        }
        assert!(checked > 50, "{checked} clusters checked");
    }

    #[test]
    fn border_point_takes_the_lowest_label() {
        // b (index 0) is within 9 mm of one core point of each cluster and has only 3 neighbours; cluster A
        // (indices 1..5) has the smaller core index, so it is cluster 0 and gets b.
        let x = |v: f32| Point3::new(v, 0.0, 0.0);
        let mut points = vec![x(0.015)];
        points.extend([0.024, 0.026, 0.028, 0.030].map(x));
        points.extend([0.0, 0.002, 0.004, 0.006].map(x));
        let c = run(&points, 0.01, 4);
        assert_eq!(c.labels, vec![0, 0, 0, 0, 0, 1, 1, 1, 1]);
        assert_eq!(c.sizes, vec![5, 4]);
        assert_eq!(brute_force(&points, 0.01, 4), c.labels);
        // With min_points 5 only the inner points stay core.
        assert_eq!(run(&points, 0.01, 6).labels, vec![-1; 9]);
    }

    #[test]
    fn empty_and_bad_input() {
        let c = run(&[], 0.01, 10);
        assert!(c.labels.is_empty() && c.sizes.is_empty() && c.largest().is_none());
        let points = vec![Point3::origin(); 3];
        let index = KdIndex::new(&points).expect("index");
        for params in [
            DbscanParams { eps_m: 0.0, min_points: 3 },
            DbscanParams { eps_m: f64::NAN, min_points: 3 },
            DbscanParams { eps_m: 0.01, min_points: 0 },
        ] {
            assert!(dbscan(&points, &index, &params).is_err(), "{params:?}");
        }
        assert!(dbscan(&points[..2], &index, &DbscanParams::default()).is_err());
        let c = dbscan(&points, &index, &DbscanParams { eps_m: 0.01, min_points: 3 }).expect("dbscan");
        assert_eq!((c.labels, c.sizes), (vec![0, 0, 0], vec![3]));
    }

    #[test]
    fn params_serde_defaults() {
        let p: DbscanParams = serde_json::from_str(r#"{"eps_m": 0.02}"#).expect("json");
        assert_eq!(p, DbscanParams { eps_m: 0.02, min_points: 10 });
        assert!(serde_json::from_str::<DbscanParams>(r#"{"eps": 0.02}"#).is_err());
    }

    /// Peak memory on 5 M points: five 2.5 x 2.5 m sheets 5 cm apart (about 50 neighbours within 1 cm)
    /// plus 1 % uniform noise. Run with `cargo test --release -p awl --lib cluster::tests::five_million -- --ignored --nocapture`.
    #[test]
    #[ignore = "5 M points: about a minute, reads /proc/self/status"]
    fn five_million_points_under_2_gb() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let n = 5_000_000;
        let points: Vec<Point3<f32>> = (0..n)
            .map(|i| {
                if i % 100 == 0 {
                    Point3::new(rng.random::<f32>() * 2.5, rng.random::<f32>() * 2.5, rng.random::<f32>() * 0.25)
                } else {
                    let sheet = (i % 5) as f32 * 0.05;
                    Point3::new(rng.random::<f32>() * 2.5, rng.random::<f32>() * 2.5, sheet)
                }
            })
            .collect();
        let start = std::time::Instant::now();
        let index = KdIndex::new(&points).expect("index");
        let built = start.elapsed();
        let c = dbscan(&points, &index, &DbscanParams::default()).expect("dbscan");
        let total = start.elapsed();
        let status = std::fs::read_to_string("/proc/self/status").expect("status");
        let hwm_kb: u64 = status
            .lines()
            .find_map(|l| l.strip_prefix("VmHWM:"))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
            .expect("VmHWM");
        println!(
            "5M dbscan: index {:.2} s, dbscan {:.2} s, VmHWM {} MB, {} clusters, sizes {:?}, noise {}",
            built.as_secs_f64(),
            (total - built).as_secs_f64(),
            hwm_kb / 1024,
            c.cluster_count(),
            &c.sizes[..c.sizes.len().min(8)],
            c.noise_count()
        );
        assert!(hwm_kb < 2 * 1024 * 1024, "VmHWM {hwm_kb} kB");
        assert!(c.sizes.iter().filter(|&&s| s > 900_000).count() == 5);
    }
}
