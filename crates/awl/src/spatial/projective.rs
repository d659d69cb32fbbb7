//! Neighbour search over one depth view's points by where they project: PCL's "organized" search,
//! made exact.
//!
//! The points are in the camera frame (z forward, all in front of the camera) and are binned by
//! their normalised image coordinates `(x/z, y/z)` on a 2D grid, stored cell by cell, a grid row
//! being one contiguous run. A point `q` within `r` of `p` projects close to `p`: with
//! `z_q >= max(z_p - r, z_min)`,
//!
//! `|x_q/z_q - x_p/z_p| <= |x_q - x_p| / z_q + |x_p| |z_q - z_p| / (z_q z_p) <= r (1 + |x_p/z_p|) / z_q`
//!
//! (and the same for y), so the cells of that window hold every point within `r`. A nearest-within
//! query scans that window: the k-d tree's answer (the same squared distance, computed in the same
//! order; equal distances broken by index). Points outside the view's frustum are answered at once
//! (the window is off the grid), and a close correspondence bound (ICP) makes a window of a few
//! cells, adjacent in memory, with no tree to descend. (For k-NN with k = 21 on a view the tree is
//! faster: at grazing angles the window holds many points far away in depth.)

use nalgebra::Point3;

use super::{Neighbor, dist_sq};
use crate::error::{Error, Result};

/// Grid cells per axis at most.
const MAX_CELLS_PER_AXIS: f32 = 4096.0;

/// Points of one view binned by their projection.
pub struct ProjectiveGrid {
    /// Points in cell order, each with its index in the slice the grid was built from (side by
    /// side: one cache line read per point, not two).
    sorted: Vec<([f32; 3], u32)>,
    /// Row-major cells: the first sorted point of each, then the number of points.
    starts: Vec<u32>,
    origin: [f32; 2],
    cell: f32,
    dims: [usize; 2],
    z_min: f32,
}

/// Inclusive cell ranges `[x0, x1] x [y0, y1]`.
#[derive(Clone, Copy)]
struct Window {
    x: (usize, usize),
    y: (usize, usize),
}

impl ProjectiveGrid {
    /// Bins `points` (camera frame).
    ///
    /// # Errors
    /// [`Error::Invalid`] for a non-finite point, a point not in front of the camera (z <= 0) or
    /// more than `u32::MAX` points.
    pub fn new(points: &[Point3<f32>]) -> Result<Self> {
        if points.len() >= u32::MAX as usize {
            return Err(Error::invalid("projective grid", format!("{} points: too many", points.len())));
        }
        if let Some(i) = points.iter().position(|p| !(p.coords.iter().all(|v| v.is_finite()) && p.z > 0.0)) {
            return Err(Error::invalid("projective grid", format!("point {i} is not finite or not in front (z > 0)")));
        }
        let uv: Vec<[f32; 2]> = points.iter().map(|p| [p.x / p.z, p.y / p.z]).collect();
        let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
        for q in &uv {
            for a in 0..2 {
                lo[a] = lo[a].min(q[a]);
                hi[a] = hi[a].max(q[a]);
            }
        }
        if points.is_empty() {
            (lo, hi) = ([0.0; 2], [0.0; 2]);
        }
        let extent = [hi[0] - lo[0], hi[1] - lo[1]];
        // about two points per cell where the view is covered
        let spacing = (extent[0] * extent[1] / points.len().max(1) as f32).sqrt();
        let cell = (1.5 * spacing).max(extent[0].max(extent[1]) / MAX_CELLS_PER_AXIS).max(1e-6);
        let dims = [(extent[0] / cell) as usize + 1, (extent[1] / cell) as usize + 1];
        let mut grid = Self {
            sorted: Vec::new(),
            starts: vec![0; dims[0] * dims[1] + 1],
            origin: lo,
            cell,
            dims,
            z_min: points.iter().map(|p| p.z).fold(f32::INFINITY, f32::min),
        };
        // counting sort by cell; a cell keeps its points in index order
        let cells: Vec<u32> = uv.iter().map(|q| (grid.bin(q[1], 1) * dims[0] + grid.bin(q[0], 0)) as u32).collect();
        for &c in &cells {
            grid.starts[c as usize + 1] += 1;
        }
        for c in 1..grid.starts.len() {
            grid.starts[c] += grid.starts[c - 1];
        }
        let mut next = grid.starts.clone();
        grid.sorted = vec![([0.0; 3], 0); points.len()];
        for (i, &c) in cells.iter().enumerate() {
            let at = next[c as usize] as usize;
            next[c as usize] += 1;
            grid.sorted[at] = ([points[i].x, points[i].y, points[i].z], i as u32);
        }
        Ok(grid)
    }

    /// The cell of a normalised coordinate on axis `a`, clamped to the grid.
    #[inline]
    fn bin(&self, c: f32, a: usize) -> usize {
        (((c - self.origin[a]) / self.cell).floor().max(0.0) as usize).min(self.dims[a] - 1)
    }

    fn all(&self) -> Window {
        Window { x: (0, self.dims[0] - 1), y: (0, self.dims[1] - 1) }
    }

    /// Cells `[c - rho, c + rho]` on axis `a`, `None` when off the grid.
    fn range(&self, c: f32, rho: f32, a: usize) -> Option<(usize, usize)> {
        let (lo, hi) = ((c - rho - self.origin[a]) / self.cell, (c + rho - self.origin[a]) / self.cell);
        if !(hi >= 0.0 && lo < self.dims[a] as f32) {
            return None;
        }
        Some((self.bin(c - rho, a), self.bin(c + rho, a)))
    }

    /// The cells holding every point within `r` of `p` (see the module docs); `None` when no point
    /// can be that close.
    fn window(&self, p: &Point3<f32>, r: f32) -> Option<Window> {
        if p.z + r < self.z_min {
            return None;
        }
        if p.z <= 0.0 {
            return Some(self.all());
        }
        let depth = (p.z - r).max(self.z_min);
        let (u, v) = (p.x / p.z, p.y / p.z);
        // relative and absolute slack for f32 rounding of the projections and distances
        let reach = |c: f32| r * (1.0 + c.abs()) / depth * (1.0 + 1e-4) + 1e-6;
        Some(Window { x: self.range(u, reach(u), 0)?, y: self.range(v, reach(v), 1)? })
    }

    fn scan(&self, p: &Point3<f32>, w: Window, mut visit: impl FnMut(f32, u32)) {
        for y in w.y.0..=w.y.1 {
            let row = y * self.dims[0];
            let (a, b) = (self.starts[row + w.x.0] as usize, self.starts[row + w.x.1 + 1] as usize);
            for &(q, id) in &self.sorted[a..b] {
                visit(dist_sq([p.x, p.y, p.z], q), id);
            }
        }
    }

    /// The nearest point within `radius_m` (inclusive), ties by index, or `None`.
    pub fn nearest_within(&self, p: &Point3<f32>, radius_m: f32) -> Option<Neighbor> {
        let w = self.window(p, radius_m)?;
        let r2 = radius_m * radius_m;
        let mut best: Option<Neighbor> = None;
        self.scan(p, w, |d, i| {
            if d <= r2 && best.is_none_or(|b| (d, i) < (b.dist_sq, b.index)) {
                best = Some(Neighbor { index: i, dist_sq: d });
            }
        });
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spatial::brute;
    use rand::{RngExt, SeedableRng};

    /// A view-like cloud: a wavy surface and a slanted floor seen from the origin, a lattice part
    /// (equal distances), scattered points, and a few points far from everything.
    fn view() -> Vec<Point3<f32>> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut points = Vec::new();
        for a in 0..120 {
            for b in 0..90 {
                let (u, v) = ((a as f32 - 60.0) / 150.0, (b as f32 - 45.0) / 150.0);
                let z = if b < 40 { 0.7 + 0.03 * (u * 30.0).sin() } else { 0.5 + 0.8 * v };
                let jitter = if a < 30 { 0.0 } else { (rng.random::<f32>() - 0.5) * 0.002 };
                points.push(Point3::new(u * z, v * z, z + jitter));
            }
        }
        for _ in 0..300 {
            let (x, y, z): (f32, f32, f32) = (rng.random(), rng.random(), rng.random());
            points.push(Point3::new(x - 0.5, y - 0.5, 0.2 + z));
        }
        points.extend([Point3::new(3.0, 0.0, 0.5), Point3::new(-2.0, 1.0, 9.0), Point3::new(0.0, 0.0, 0.05)]);
        points
    }

    #[test]
    fn nearest_within_is_brute_force() {
        let points = view();
        let grid = ProjectiveGrid::new(&points).expect("grid");
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for _ in 0..3000 {
            let (x, y, z): (f32, f32, f32) = (rng.random(), rng.random(), rng.random());
            let q = Point3::new(x - 0.5, y - 0.5, 1.2 * z - 0.1);
            for r in [0.001, 0.005, 0.03, 0.3] {
                let want = brute::knn(&points, &q, 1).into_iter().find(|n| n.dist_sq <= r * r);
                assert_eq!(grid.nearest_within(&q, r), want, "{q:?} {r}");
            }
        }
    }

    #[test]
    fn bad_and_empty_input() {
        assert!(ProjectiveGrid::new(&[Point3::new(0.0, 0.0, -1.0)]).is_err());
        assert!(ProjectiveGrid::new(&[Point3::new(f32::NAN, 0.0, 1.0)]).is_err());
        let empty = ProjectiveGrid::new(&[]).expect("empty");
        assert_eq!(empty.nearest_within(&Point3::new(0.0, 0.0, 1.0), 1.0), None);
        let one = ProjectiveGrid::new(&[Point3::new(0.1, 0.0, 1.0)]).expect("one");
        assert_eq!(one.nearest_within(&Point3::new(0.1, 0.0, -3.0), 1.0), None);
        assert_eq!(one.nearest_within(&Point3::new(0.1, 0.0, 0.5), 0.5).map(|n| n.index), Some(0));
    }
}
