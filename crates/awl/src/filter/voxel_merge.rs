//! [`VoxelMerge`]: the voxel down-sampling of a union of clouds, added one by one, without holding
//! the union: each part is kept sorted by voxel key, and the parts are merged in one pass at the
//! end. The output is [`super::voxel::downsample`]'s of the parts concatenated in rank order, bit
//! for bit (same runs in the same point order, same sums), in the memory of the parts and the
//! output (the concatenation and the sort of the whole union would add ~2.3x the output).

use nalgebra::{Point3, Vector3};

use super::voxel::{Grid, VoxelParams, mean_color, mean_normal, mean_point, runs};
use crate::cloud::{Bounds, PointCloud};
use crate::error::Result;

/// Clouds to down-sample together; see the module docs.
#[derive(Debug, Clone)]
pub struct VoxelMerge {
    params: VoxelParams,
    /// (rank, part sorted by (voxel key, index)), in the order added.
    parts: Vec<(usize, PointCloud)>,
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
        let sorted = match runs(&cloud, &self.params)? {
            Some((order, _)) => cloud.select(&order),
            None => cloud,
        };
        self.parts.push((rank, sorted));
        Ok(())
    }

    /// The number of points added.
    pub fn len(&self) -> usize {
        self.parts.iter().map(|(_, p)| p.len()).sum()
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
        self.parts.retain(|(_, p)| !p.is_empty());
        self.parts.sort_by_key(|(rank, _)| *rank);
        let parts: Vec<&PointCloud> = self.parts.iter().map(|(_, p)| p).collect();
        let Some(bounds) = parts
            .iter()
            .filter_map(|p| p.bounds())
            .reduce(|a, b| Bounds { min: a.min.inf(&b.min), max: a.max.sup(&b.max) })
        else {
            return Ok(PointCloud::default());
        };
        let grid = Grid::new(&bounds, self.params.voxel_size_m)?;
        let with_normals = parts.iter().all(|p| p.normals.is_some());
        let with_colors = parts.iter().all(|p| p.colors.is_some());
        // a first pass counts the voxels, so the output is allocated once, at its size
        let mut voxels = 0;
        for_each_voxel(&parts, &grid, |_| voxels += 1);
        let mut out = PointCloud {
            points: Vec::with_capacity(voxels),
            normals: with_normals.then(|| Vec::with_capacity(voxels)),
            colors: with_colors.then(|| Vec::with_capacity(voxels)),
        };
        // one voxel's points, normals and colors in union order, and the indices 0.. over them
        let (mut points, mut normals, mut colors) = (Vec::<Point3<f32>>::new(), Vec::<Vector3<f32>>::new(), Vec::new());
        let mut run: Vec<usize> = Vec::new();
        for_each_voxel(&parts, &grid, |members| {
            points.clear();
            points.extend(members.iter().map(|&(k, i)| parts[k].points[i]));
            run.extend(run.len()..members.len());
            let run = &run[..members.len()];
            out.points.push(mean_point(&points, run));
            if let Some(out) = out.normals.as_mut() {
                normals.clear();
                normals.extend(members.iter().filter_map(|&(k, i)| Some(parts[k].normals.as_ref()?[i])));
                out.push(mean_normal(&normals, run));
            }
            if let Some(out) = out.colors.as_mut() {
                colors.clear();
                colors.extend(members.iter().filter_map(|&(k, i)| Some(parts[k].colors.as_ref()?[i])));
                out.push(mean_color(&colors, run));
            }
        });
        Ok(out)
    }
}

/// Walks the union of `parts` (each sorted by (voxel key, index)) voxel by voxel in key order,
/// giving `voxel` each voxel's points as (part, index) in union order (parts in order, then index).
fn for_each_voxel(parts: &[&PointCloud], grid: &Grid, mut voxel: impl FnMut(&[(usize, usize)])) {
    let mut heads = vec![0; parts.len()];
    // each part's next point's key
    let mut keys: Vec<Option<[i64; 3]>> = parts.iter().map(|p| p.points.first().map(|q| grid.key(q))).collect();
    let mut members = Vec::new();
    while let Some(key) = keys.iter().flatten().min().copied() {
        members.clear();
        for (k, part) in parts.iter().enumerate() {
            while keys[k] == Some(key) {
                members.push((k, heads[k]));
                heads[k] += 1;
                keys[k] = part.points.get(heads[k]).map(|q| grid.key(q));
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
    fn equals_the_down_sampling_of_the_concatenation_bit_for_bit() {
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
            assert_eq!(merge.downsample().expect("merged"), want);
        }
    }

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
