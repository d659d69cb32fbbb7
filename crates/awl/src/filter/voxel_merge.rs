//! [`VoxelMerge`]: the voxel down-sampling of a union of clouds, added one by one, without holding
//! the union: each part is kept sorted by voxel key, and the parts are merged at the end, in
//! chunks of the key range side by side. The output is [`super::voxel::downsample`]'s of the
//! parts concatenated in rank order, bit for bit in its points and colors (same runs in the same
//! point order, same sums), its normals within 0.01 deg: the parts keep their normals in 32 bits
//! (octahedral, [`crate::octahedral`]) instead of 96, so the parts hold 19 bytes a point instead of 27.
//! All in the memory of the parts and the output (the concatenation and the sort of the whole
//! union would add ~2.3x the output).

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use super::voxel::{Grid, VoxelParams, mean_color, mean_normal, mean_point, runs};
use crate::cloud::{Bounds, PointCloud};
use crate::error::Result;
use crate::octahedral::{PackedNormal, pack_normal, unpack_normal};

/// Clouds to down-sample together; see the module docs.
#[derive(Debug, Clone)]
pub struct VoxelMerge {
    params: VoxelParams,
    /// (rank, part sorted by (voxel key, index)), in the order added.
    parts: Vec<(usize, Part)>,
}

/// Points per block of a part: a part is kept in blocks of this many points (48 KB of positions)
/// that fill the holes the pipeline's short-lived buffers leave in the heap, where one block per
/// part (~0.3-0.5 MB per attribute for a view) went on top of them: the fast preset's peak RSS on
/// a 12-view box at 2 threads, medians 36.9-38.0 -> 34.3-35.3 MiB (BENCHMARKS.md 56), same model.
const BLOCK: usize = 4096;

/// A part, in blocks of [`BLOCK`] points (the last one shorter).
#[derive(Debug, Clone, Default)]
struct Part {
    blocks: Vec<Block>,
    len: usize,
}

/// A block of a part: its points and colors, and its normals packed ([`crate::octahedral`]).
#[derive(Debug, Clone, Default)]
struct Block {
    /// Points and colors (no normals).
    cloud: PointCloud,
    normals: Option<Vec<PackedNormal>>,
}

impl Part {
    /// `cloud`'s points at `order` (all of them, in order, when `None`), in blocks.
    fn new(mut cloud: PointCloud, order: Option<&[usize]>) -> Self {
        let all: Vec<usize>;
        let order = match order {
            Some(order) => order,
            None => {
                all = (0..cloud.len()).collect();
                &all
            }
        };
        let normals = cloud.normals.take();
        let block = |run: &[usize]| Block {
            cloud: cloud.select(run),
            normals: normals.as_ref().map(|n| run.iter().map(|&i| pack_normal(&n[i])).collect()),
        };
        Self { blocks: order.chunks(BLOCK).map(block).collect(), len: order.len() }
    }

    /// The block that holds the part's point `i`, and the point's index in it.
    fn at(&self, i: usize) -> (&Block, usize) {
        (&self.blocks[i / BLOCK], i % BLOCK)
    }

    fn point(&self, i: usize) -> &Point3<f32> {
        let (block, j) = self.at(i);
        &block.cloud.points[j]
    }

    /// The index of the part's first point whose voxel key is `key` or past it.
    fn first_at_or_past(&self, grid: &Grid, key: [i64; 3]) -> usize {
        let (mut lo, mut hi) = (0, self.len);
        while lo < hi {
            let mid = lo + (hi - lo) / 2;
            if grid.key(self.point(mid)) < key { lo = mid + 1 } else { hi = mid }
        }
        lo
    }

    fn has_normals(&self) -> bool {
        self.blocks.iter().all(|b| b.normals.is_some())
    }

    fn has_colors(&self) -> bool {
        self.blocks.iter().all(|b| b.cloud.colors.is_some())
    }

    fn bounds(&self) -> Option<Bounds> {
        self.blocks.iter().filter_map(|b| b.cloud.bounds()).reduce(joined)
    }
}

impl VoxelMerge {
    /// An empty union.
    ///
    /// # Errors
    /// [`crate::Error::Invalid`] for a bad `voxel_size_m`.
    pub fn new(params: &VoxelParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params: *params, parts: Vec::new() })
    }

    /// Adds `cloud` as the union's part of rank `rank` (the union is the parts in rank order, equal
    /// ranks in the order added).
    ///
    /// # Errors
    /// As [`super::voxel::downsample`] on `cloud`.
    pub fn add(&mut self, rank: usize, cloud: PointCloud) -> Result<()> {
        let order = runs(&cloud, &self.params)?;
        let part = Part::new(cloud, order.as_ref().map(|(order, _)| order.as_slice()));
        self.parts.push((rank, part));
        Ok(())
    }

    /// Adds `other`'s parts, with their ranks (a union built in parallel pieces; `other` at the
    /// same voxel size).
    pub fn append(&mut self, mut other: VoxelMerge) {
        debug_assert_eq!(self.params, other.params);
        self.parts.append(&mut other.parts);
    }

    /// The number of points added.
    pub fn len(&self) -> usize {
        self.parts.iter().map(|(_, p)| p.len).sum()
    }

    /// True when no point was added.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The down-sampled union: one centroid per occupied voxel, in key order. Normals and colors
    /// are kept when every non-empty part has them (as [`PointCloud::extend`] keeps them).
    ///
    /// # Errors
    /// [`crate::Error::Invalid`] for a voxel so small that a voxel coordinate exceeds ±2^62.
    pub fn downsample(mut self) -> Result<PointCloud> {
        self.parts.retain(|(_, p)| p.len > 0);
        self.parts.sort_by_key(|(rank, _)| *rank);
        let parts: Vec<&Part> = self.parts.iter().map(|(_, p)| p).collect();
        let Some(bounds) = parts.iter().filter_map(|p| p.bounds()).reduce(joined) else {
            return Ok(PointCloud::default());
        };
        let grid = Grid::new(&bounds, self.params.voxel_size_m)?;
        let with_normals = parts.iter().all(|p| p.has_normals());
        let with_colors = parts.iter().all(|p| p.has_colors());
        // the key range cut at keys of the largest part into chunks merged side by side (a voxel's
        // points all fall in one chunk: the same voxels, in the same order, as one pass), each
        // counted first, so the output is allocated once, at its size, and filled in place
        let chunks = chunks(&parts, &grid);
        let counts: Vec<usize> = chunks
            .par_windows(2)
            .map(|c| {
                let mut voxels = 0;
                for_each_voxel(&parts, &grid, &c[0], &c[1], |_| voxels += 1);
                voxels
            })
            .collect();
        let voxels = counts.iter().sum();
        let mut out = PointCloud {
            points: vec![Point3::origin(); voxels],
            normals: with_normals.then(|| vec![Vector3::zeros(); voxels]),
            colors: with_colors.then(|| vec![[0; 3]; voxels]),
        };
        let slices = split_at_counts(&mut out, &counts);
        slices
            .into_par_iter()
            .zip(chunks.par_windows(2))
            .for_each(|(slice, c)| merge_chunk(&parts, &grid, &c[0], &c[1], slice));
        Ok(out)
    }
}

/// A chunk's slices of the output.
type ChunkOut<'a> = (&'a mut [Point3<f32>], Option<&'a mut [Vector3<f32>]>, Option<&'a mut [[u8; 3]]>);

/// `out`'s points, normals and colors cut into consecutive slices of `counts` entries.
fn split_at_counts<'a>(out: &'a mut PointCloud, counts: &[usize]) -> Vec<ChunkOut<'a>> {
    let (mut points, mut normals, mut colors) =
        (&mut out.points[..], out.normals.as_deref_mut(), out.colors.as_deref_mut());
    let mut slices = Vec::with_capacity(counts.len());
    for &n in counts {
        let (p, rest) = std::mem::take(&mut points).split_at_mut(n);
        points = rest;
        let (n_chunk, n_rest) = normals.take().map(|x| x.split_at_mut(n)).unzip();
        normals = n_rest;
        let (c_chunk, c_rest) = colors.take().map(|x| x.split_at_mut(n)).unzip();
        colors = c_rest;
        slices.push((p, n_chunk, c_chunk));
    }
    slices
}

/// The voxels of `parts` between the cuts `from` and `to`, one a slot of `out`.
fn merge_chunk(parts: &[&Part], grid: &Grid, from: &[usize], to: &[usize], out: ChunkOut<'_>) {
    let (points_out, mut normals_out, mut colors_out) = out;
    // one voxel's points, normals and colors in union order, and the indices 0.. over them
    let (mut points, mut normals, mut colors) = (Vec::<Point3<f32>>::new(), Vec::<Vector3<f32>>::new(), Vec::new());
    let mut run: Vec<usize> = Vec::new();
    let mut v = 0;
    for_each_voxel(parts, grid, from, to, |members| {
        points.clear();
        points.extend(members.iter().map(|&(k, i)| *parts[k].point(i)));
        run.extend(run.len()..members.len());
        let run = &run[..members.len()];
        points_out[v] = mean_point(&points, run);
        if let Some(out) = normals_out.as_deref_mut() {
            normals.clear();
            normals.extend(members.iter().filter_map(|&(k, i)| {
                let (block, j) = parts[k].at(i);
                Some(unpack_normal(block.normals.as_ref()?[j]))
            }));
            out[v] = mean_normal(&normals, run);
        }
        if let Some(out) = colors_out.as_deref_mut() {
            colors.clear();
            colors.extend(members.iter().filter_map(|&(k, i)| {
                let (block, j) = parts[k].at(i);
                Some(block.cloud.colors.as_ref()?[j])
            }));
            out[v] = mean_color(&colors, run);
        }
        v += 1;
    });
}

/// Chunks of the merge: [`CHUNKS`] + 1 cuts, each the index in every part of its first point at or
/// past a key of the largest part (the first cut all 0, the last every part's length).
fn chunks(parts: &[&Part], grid: &Grid) -> Vec<Vec<usize>> {
    let Some(largest) = parts.iter().max_by_key(|p| p.len) else { return Vec::new() };
    let mut cuts = vec![vec![0; parts.len()]];
    for c in 1..CHUNKS {
        let key = grid.key(largest.point(largest.len * c / CHUNKS));
        cuts.push(parts.iter().map(|p| p.first_at_or_past(grid, key)).collect());
    }
    cuts.push(parts.iter().map(|p| p.len).collect());
    cuts
}

/// Chunks the merge is cut into (any number gives the same output).
const CHUNKS: usize = 16;

/// The box around both boxes.
fn joined(a: Bounds, b: Bounds) -> Bounds {
    Bounds { min: a.min.inf(&b.min), max: a.max.sup(&b.max) }
}

/// Walks the union of `parts` (each sorted by (voxel key, index)) between the cuts `from` and `to`
/// (an index per part) voxel by voxel in key order, giving `voxel` each voxel's points as (part,
/// index) in union order (parts in order, then index).
fn for_each_voxel(
    parts: &[&Part],
    grid: &Grid,
    from: &[usize],
    to: &[usize],
    mut voxel: impl FnMut(&[(usize, usize)]),
) {
    let mut heads = from.to_vec();
    // each part's next point's key
    let next = |k: usize, head: usize| (head < to[k]).then(|| grid.key(parts[k].point(head)));
    let mut keys: Vec<Option<[i64; 3]>> = (0..parts.len()).map(|k| next(k, heads[k])).collect();
    let mut members = Vec::new();
    while let Some(key) = keys.iter().flatten().min().copied() {
        members.clear();
        for k in 0..parts.len() {
            while keys[k] == Some(key) {
                members.push((k, heads[k]));
                heads[k] += 1;
                keys[k] = next(k, heads[k]);
            }
        }
        voxel(&members);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::voxel::downsample;
    use rand::{RngExt, SeedableRng};

    /// `n` points in a `side` m cube at `offset`, with normals and colors; coarse coordinates so
    /// that parts share voxels and voxels hold many points.
    fn part(seed: u64, n: usize, offset: f32, side: f32) -> PointCloud {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let points = (0..n).map(|_| Point3::new(rng.random(), rng.random(), rng.random()) * side).collect::<Vec<_>>();
        let points = points.into_iter().map(|p: Point3<f32>| p + Vector3::repeat(offset)).collect();
        let normals =
            (0..n).map(|_| Vector3::new(rng.random(), rng.random(), rng.random::<f32>() - 0.5).normalize()).collect();
        let colors = (0..n).map(|_| [rng.random(), rng.random(), rng.random()]).collect();
        PointCloud { points, normals: Some(normals), colors: Some(colors) }
    }

    #[test]
    fn equals_the_down_sampling_of_the_concatenation_its_normals_within_0_01_deg() {
        let params = VoxelParams { voxel_size_m: 0.01 };
        let parts =
            [part(1, 20_000, 0.0, 0.2), part(2, 5_000, 0.05, 0.1), part(3, 30_000, -0.1, 0.3), part(4, 1, 0.0, 0.0)];
        // added out of rank order; one part without colors drops them, as the concatenation does
        for drop_colors in [false, true] {
            let mut merge = VoxelMerge::new(&params).expect("merge");
            let mut all = PointCloud::default();
            for (rank, p) in parts.iter().enumerate() {
                let mut p = p.clone();
                if drop_colors && rank == 2 {
                    p.colors = None;
                }
                all.extend(&p);
            }
            for rank in [2, 0, 3, 1] {
                let mut p = parts[rank].clone();
                if drop_colors && rank == 2 {
                    p.colors = None;
                }
                merge.add(rank, p).expect("add");
            }
            merge.add(7, PointCloud::default()).expect("an empty part");
            assert_eq!(merge.len(), all.len());
            let want = downsample(&all, &params).expect("downsample");
            assert!(want.len() > 5_000 && want.len() < all.len() / 2, "{} voxels", want.len());
            assert_eq!(want.colors.is_some(), !drop_colors);
            let got = merge.downsample().expect("merged");
            assert_eq!((&got.points, &got.colors), (&want.points, &want.colors));
            let (got, want) = (got.normals.expect("normals"), want.normals.expect("normals"));
            assert_eq!(got.len(), want.len());
            // angles in f64 (f32's acos cannot tell angles under ~0.02 deg apart)
            let worst =
                got.iter().zip(&want).map(|(a, b)| a.cast::<f64>().angle(&b.cast()).to_degrees()).fold(0.0, f64::max);
            assert!(worst < 0.01, "normals {worst} deg apart");
        }
    }

    /// Packed normals come back within 0.005 deg, on both halves, the axes and the fold's edges;
    /// a normal without a direction comes back zero.
    #[test]
    fn empty_and_bad_input() {
        let params = VoxelParams { voxel_size_m: 0.01 };
        let merge = VoxelMerge::new(&params).expect("merge");
        assert!(merge.is_empty());
        assert_eq!(merge.downsample().expect("empty"), PointCloud::default());
        assert!(VoxelMerge::new(&VoxelParams { voxel_size_m: -1.0 }).is_err());
        let mut merge = VoxelMerge::new(&params).expect("merge");
        let bad = PointCloud::from_points(vec![Point3::new(0.0, f32::NAN, 0.0)]);
        let err = merge.add(0, bad).expect_err("NaN").to_string();
        assert!(err.contains("voxel downsample input"), "{err}");
    }
}
