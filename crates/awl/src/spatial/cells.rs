//! A uniform grid of cells over a point set, for radius searches at one fixed radius (DBSCAN,
//! MLS): the points sorted by cell, cells looked up by binary search; every point of a cell checks
//! the points of the 27 cells around it. At these radii (a few times the point spacing) it is
//! several times faster than k-d tree radius queries, and the neighbours come in grid order, so
//! sums over them do not depend on the number of threads.

use std::ops::Range;

use nalgebra::Point3;
use rayon::prelude::*;

use crate::error::{Error, Result};

/// Cells per axis at most (21 bits of the sort key each).
const MAX_CELLS: f64 = (1u64 << 21) as f64 - 4.0;

/// The points sorted by cell: grid positions `s` index `points` and `perm` (the input index).
pub(crate) struct CellGrid {
    pub points: Vec<[f32; 3]>,
    pub perm: Vec<u32>,
    /// Cell keys `x << 42 | y << 21 | z`, ascending, one per non-empty cell.
    pub keys: Vec<u64>,
    /// Positions of the first point of each cell, then the number of points.
    starts: Vec<u32>,
}

impl CellGrid {
    /// Cells of side `eps_m * (1 + 1e-6)` over a non-empty slice (`field` names the radius in
    /// errors): two points whose f32 squared distance passes `<= eps²` are at
    /// most one cell apart on every axis (cell coordinates are computed in f64).
    pub fn new(points: &[Point3<f32>], eps_m: f32, field: &str) -> Result<Self> {
        let min = points.iter().fold(points[0], |m, p| m.inf(p)).cast::<f64>();
        let max = points.iter().fold(points[0], |m, p| m.sup(p)).cast::<f64>();
        let cell_m = eps_m as f64 * (1.0 + 1e-6);
        let extent = (max - min).max() / cell_m;
        if extent.is_nan() || extent >= MAX_CELLS {
            return Err(Error::invalid(
                field,
                format!("{eps_m} m is too small for a cloud {} m across (2 M cells per axis at most)", extent * cell_m),
            ));
        }
        // Cell coordinates start at 1, so the cells around any point have non-negative coordinates.
        let coord = |v: f32, lo: f64| ((v as f64 - lo) / cell_m) as u64 + 1;
        let mut keyed: Vec<(u64, u32)> = points
            .par_iter()
            .enumerate()
            .map(|(i, p)| (coord(p.x, min.x) << 42 | coord(p.y, min.y) << 21 | coord(p.z, min.z), i as u32))
            .collect();
        keyed.par_sort_unstable();
        let mut keys = Vec::new();
        let mut starts = Vec::new();
        for (s, &(key, _)) in keyed.iter().enumerate() {
            if keys.last() != Some(&key) {
                keys.push(key);
                starts.push(s as u32);
            }
        }
        starts.push(keyed.len() as u32);
        let sorted = keyed.par_iter().map(|&(_, i)| points[i as usize].coords.into()).collect();
        let perm = keyed.into_iter().map(|(_, i)| i).collect();
        Ok(Self { points: sorted, perm, keys, starts })
    }

    pub fn cell(&self, c: usize) -> Range<usize> {
        self.starts[c] as usize..self.starts[c + 1] as usize
    }

    /// Position ranges of the 27 cells around cell `c`, as up to 9 runs of 3 consecutive keys.
    pub fn around(&self, c: usize) -> ([Range<usize>; 9], usize) {
        let key = self.keys[c];
        let mut runs: [Range<usize>; 9] = Default::default();
        let mut count = 0;
        for dx in [0, 1, 2] {
            for dy in [0, 1, 2] {
                let mid = (key + (dx << 42) + (dy << 21)) - (1 << 42) - (1 << 21);
                let lo = self.keys.partition_point(|&k| k < mid - 1);
                let hi = lo + self.keys[lo..].partition_point(|&k| k <= mid + 1);
                if lo < hi {
                    runs[count] = self.starts[lo] as usize..self.starts[hi] as usize;
                    count += 1;
                }
            }
        }
        (runs, count)
    }

    /// Sets `near` to the positions of the points within `eps` (squared: `r2`) of position `s`, itself
    /// included, given the runs around its cell (branch-free: every candidate is written, the length
    /// advances only on a hit).
    pub fn within(&self, runs: &[Range<usize>], s: usize, r2: f32, near: &mut Vec<u32>) {
        let q = self.points[s];
        near.resize(runs.iter().map(ExactSizeIterator::len).sum(), 0);
        let mut len = 0;
        for run in runs {
            for (t, p) in self.points[run.clone()].iter().enumerate() {
                let d = [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
                near[len] = (run.start + t) as u32;
                len += usize::from(d[0] * d[0] + d[1] * d[1] + d[2] * d[2] <= r2);
            }
        }
        near.truncate(len);
    }
}
