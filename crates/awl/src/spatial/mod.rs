//! Neighbour search over a point set: a k-d tree (kiddo) behind a small API, so the rest of awl
//! never sees the crate's types, and [`ProjectiveGrid`] for one depth view's points. Distances
//! returned are squared, metres².

mod allknn;
mod leaftree;

pub(crate) use leaftree::LeafTree;

pub(crate) use allknn::knn_map;
pub(crate) mod cells;
mod projective;

pub use projective::ProjectiveGrid;

use std::num::NonZeroUsize;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Point3;

use crate::error::{Error, Result};

/// `|a - b|²` in f32, summed x, y, z: every index computes its distances so, and ICP's kept
/// correspondences too, so that a distance is the same bits wherever it is computed.
#[inline(always)]
pub(crate) fn dist_sq(a: [f32; 3], b: [f32; 3]) -> f32 {
    let (dx, dy, dz) = (a[0] - b[0], a[1] - b[1], a[2] - b[2]);
    dx * dx + dy * dy + dz * dz
}

/// A distance or reach a hair longer, against f32 rounding (1e-4 relative and 1e-6 m absolute
/// slack).
#[inline]
pub(crate) fn widen(d: f32) -> f32 {
    d * (1.0 + 1e-4) + 1e-6
}

/// A neighbour: index into the indexed point slice, squared distance (m²).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Neighbor {
    /// Index of the point in the slice the index was built from.
    pub index: u32,
    /// Squared Euclidean distance to the query, m².
    pub dist_sq: f32,
}

/// A static k-d tree over a slice of points.
pub struct KdIndex {
    tree: ImmutableKdTree<f32, 3>,
    len: usize,
}

/// What a tree over `points` needs: every point finite, at most `u32::MAX` of them (indices are
/// u32).
fn check_points(points: &[Point3<f32>]) -> Result<()> {
    if points.len() > u32::MAX as usize {
        return Err(Error::invalid("k-d tree", format!("{} points: at most 2^32 - 1", points.len())));
    }
    if let Some(i) = points.iter().position(|p| !p.coords.iter().all(|v| v.is_finite())) {
        return Err(Error::invalid("k-d tree", format!("point {i} is not finite")));
    }
    Ok(())
}

fn to_array(p: &Point3<f32>) -> [f32; 3] {
    [p.x, p.y, p.z]
}

impl KdIndex {
    /// Builds the index (in parallel on the current rayon pool; the tree is the same either way).
    ///
    /// # Errors
    /// [`Error::Invalid`] when the slice has more than `u32::MAX` points or a non-finite point.
    pub fn new(points: &[Point3<f32>]) -> Result<Self> {
        check_points(points)?;
        // the points as they are (`Point3<f32>` is three packed f32): no copy
        let coords: &[[f32; 3]] = bytemuck::cast_slice(points);
        let tree = ImmutableKdTree::new_from_slice(coords)
            .map_err(|e| Error::invalid("k-d tree", format!("cannot build: {e:?}")))?;
        Ok(Self { tree, len: points.len() })
    }

    /// Number of indexed points.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when no point is indexed.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The `k` nearest points (fewer if the index is smaller), nearest first; the query point itself
    /// is included when it is in the index.
    pub fn knn(&self, query: &Point3<f32>, k: usize) -> Vec<Neighbor> {
        self.knn_within(query, k, f32::INFINITY)
    }

    /// The nearest point, or `None` for an empty index.
    pub fn nearest(&self, query: &Point3<f32>) -> Option<Neighbor> {
        if self.len == 0 {
            return None;
        }
        let r = self.tree.query(&to_array(query)).nearest_one::<SquaredEuclidean<f32>>().execute();
        Some(Neighbor { index: r.item, dist_sq: r.distance })
    }

    /// The nearest point within `radius_m` (inclusive), or `None`. Much faster than [`KdIndex::nearest`]
    /// for queries far from every point, since the radius prunes the search.
    pub fn nearest_within(&self, query: &Point3<f32>, radius_m: f32) -> Option<Neighbor> {
        if self.len == 0 {
            return None;
        }
        self.nearest_n_within(query, NonZeroUsize::MIN, radius_m).next()
    }

    /// The `k` nearest points within `radius_m` (inclusive), nearest first: [`KdIndex::knn`]'s
    /// distances when at least `k` points lie that close, found with fewer tree nodes visited
    /// (`knn` is this with no bound).
    pub fn knn_within(&self, query: &Point3<f32>, k: usize, radius_m: f32) -> Vec<Neighbor> {
        let Some(k) = NonZeroUsize::new(k.min(self.len)) else { return Vec::new() };
        self.nearest_n_within(query, k, radius_m).collect()
    }

    /// The tree's bounded `k`-nearest query, nearest first (`nearest_within` takes the first,
    /// `knn_within` all).
    fn nearest_n_within(
        &self,
        query: &Point3<f32>,
        k: NonZeroUsize,
        radius_m: f32,
    ) -> impl Iterator<Item = Neighbor> + use<> {
        self.tree
            .query(&to_array(query))
            .nearest_n::<SquaredEuclidean<f32>>(k)
            .within(radius_m * radius_m)
            .execute()
            .into_iter()
            .map(|r| Neighbor { index: r.item, dist_sq: r.distance })
    }

    /// Every point within `radius_m` (inclusive), in no particular order.
    pub fn within(&self, query: &Point3<f32>, radius_m: f32) -> Vec<Neighbor> {
        if self.len == 0 {
            return Vec::new();
        }
        self.tree
            .query(&to_array(query))
            .within::<SquaredEuclidean<f32>>(radius_m * radius_m)
            .unsorted()
            .execute()
            .into_iter()
            .map(|r| Neighbor { index: r.item, dist_sq: r.distance })
            .collect()
    }
}

/// The `k` nearest points of every point of a set (the point itself included), nearest first, in
/// one table (see `allknn`): the distances [`KdIndex::knn`] gives, and of points tied at equal
/// distance the lowest indices first, so a row's first `j` entries are the `j`-row. One k-NN pass
/// whose rows several stages can share (SOR and normals in `awl fuse`). Built in parallel; the
/// table does not depend on the number of threads.
pub struct KnnTable {
    k: usize,
    /// Rows in the order of the search's tree.
    rows: Vec<Neighbor>,
    /// The row of each point.
    position: Vec<u32>,
}

impl KnnTable {
    /// The `k` nearest points of each of `points` (fewer when there are fewer points).
    ///
    /// # Errors
    /// [`Error::Invalid`] for a non-finite point.
    pub fn new(points: &[Point3<f32>], k: usize) -> Result<Self> {
        let (k, rows, position) = allknn::knn_rows(points, k)?;
        Ok(Self { k, rows, position })
    }

    /// Neighbours per row (`min(k, points)`).
    pub fn k(&self) -> usize {
        self.k
    }

    /// Number of rows (the points the table was built over; 0 when `k` is 0).
    pub fn row_count(&self) -> usize {
        self.position.len()
    }

    /// The neighbours of point `i`, nearest first.
    ///
    /// # Panics
    /// When `i` is not an index of the points the table was built over.
    pub fn row(&self, i: usize) -> &[Neighbor] {
        let j = self.position[i] as usize;
        &self.rows[j * self.k..(j + 1) * self.k]
    }
}

/// Brute-force neighbour search: the oracle the k-d tree is tested against, and a single query
/// where building a tree would cost more than the scan.
pub mod brute {
    use super::Neighbor;
    use nalgebra::Point3;

    /// The nearest point (the lowest index of equals); `None` for no points.
    pub fn nearest(points: &[Point3<f32>], query: &Point3<f32>) -> Option<Neighbor> {
        points
            .iter()
            .enumerate()
            .map(|(i, p)| Neighbor { index: i as u32, dist_sq: (p - query).norm_squared() })
            .min_by(|a, b| a.dist_sq.total_cmp(&b.dist_sq))
    }

    /// The `k` nearest points, nearest first (ties by index).
    pub fn knn(points: &[Point3<f32>], query: &Point3<f32>, k: usize) -> Vec<Neighbor> {
        let mut all: Vec<Neighbor> = points
            .iter()
            .enumerate()
            .map(|(i, p)| Neighbor { index: i as u32, dist_sq: (p - query).norm_squared() })
            .collect();
        all.sort_by(|a, b| a.dist_sq.total_cmp(&b.dist_sq).then(a.index.cmp(&b.index)));
        all.truncate(k);
        all
    }

    /// Indices of every point within `radius_m`, ascending.
    pub fn within(points: &[Point3<f32>], query: &Point3<f32>, radius_m: f32) -> Vec<u32> {
        let r2 = radius_m * radius_m;
        (0..points.len() as u32).filter(|&i| (points[i as usize] - query).norm_squared() <= r2).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    fn random_points(n: usize, seed: u64) -> Vec<Point3<f32>> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..n).map(|_| Point3::new(rng.random::<f32>(), rng.random::<f32>(), rng.random::<f32>())).collect()
    }

    #[test]
    fn the_table_gives_the_trees_distances_and_ties_by_index() {
        // random points and a noisy surface with a pixel-like lattice (many equal distances), a
        // coarser sheet and far stragglers
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut surface: Vec<Point3<f32>> = (0..20_000)
            .map(|i| {
                let (u, v) = ((i % 200) as f32 * 0.002, (i / 200) as f32 * 0.002);
                Point3::new(u, v, 0.05 * (u * 9.0).sin() + rng.random::<f32>() * 0.001)
            })
            .collect();
        surface.extend((0..3000).map(|i| Point3::new((i % 60) as f32 * 0.004, (i / 60) as f32 * 0.004, 0.6)));
        surface.extend((0..20).map(|i| Point3::new(3.0 + i as f32, -2.0, 1.0)));
        for (points, k) in [(random_points(6000, 3), 20), (surface, 21), (random_points(50, 4), 60)] {
            let index = KdIndex::new(&points).expect("index");
            let table = KnnTable::new(&points, k).expect("table");
            assert_eq!((table.k(), table.row_count()), (k.min(points.len()), points.len()));
            for i in 0..points.len() {
                // the k-d tree's distances; every 7th row against brute force (ties by index)
                let row = table.row(i);
                let tree: Vec<f32> = index.knn(&points[i], k).iter().map(|n| n.dist_sq).collect();
                assert_eq!(row.iter().map(|n| n.dist_sq).collect::<Vec<_>>(), tree, "point {i}");
                if i % 7 == 0 {
                    assert_eq!(row, brute::knn(&points, &points[i], k).as_slice(), "point {i}");
                }
            }
        }
    }

    #[test]
    fn matches_brute_force() {
        let points = random_points(5000, 7);
        let index = KdIndex::new(&points).expect("index");
        for q in random_points(200, 8) {
            let got = index.knn(&q, 10);
            let want = brute::knn(&points, &q, 10);
            let d = |v: &[Neighbor]| v.iter().map(|n| n.dist_sq).collect::<Vec<_>>();
            assert_eq!(d(&got), d(&want));
            let mut within: Vec<u32> = index.within(&q, 0.08).iter().map(|n| n.index).collect();
            within.sort_unstable();
            assert_eq!(within, brute::within(&points, &q, 0.08));
            assert_eq!(index.nearest(&q).map(|n| n.dist_sq), Some(want[0].dist_sq));
            assert_eq!(brute::nearest(&points, &q), Some(want[0]));
            let bounded = index.nearest_within(&q, 0.05).map(|n| n.dist_sq);
            assert_eq!(bounded, (want[0].dist_sq <= 0.0025).then_some(want[0].dist_sq));
        }
    }

    #[test]
    fn empty_and_bad_input() {
        let index = KdIndex::new(&[]).expect("empty index");
        assert!(index.knn(&Point3::origin(), 3).is_empty() && index.nearest(&Point3::origin()).is_none());
        assert!(brute::nearest(&[], &Point3::origin()).is_none());
        // equal distances: the lowest index
        let pair = [Point3::new(1.0, 0.0, 0.0), Point3::new(-1.0, 0.0, 0.0)];
        assert_eq!(brute::nearest(&pair, &Point3::origin()).map(|n| n.index), Some(0));
        assert!(KdIndex::new(&[Point3::new(f32::NAN, 0.0, 0.0)]).is_err());
    }
}
