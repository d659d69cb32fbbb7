//! Voxel-grid down-sampling: one centroid per occupied voxel.
//!
//! Input: a cloud (metres, any frame). Output: one point per occupied cubic voxel of edge
//! `voxel_size_m`, at the mean of the points it holds (averaged in f64), with the mean normal
//! (re-normalised; a voxel of one point keeps its normal as it is) and the mean color (rounded)
//! when the input has them. Down-sampling an output again at the same size gives it back bit for
//! bit, and costs one pass over the keys (no sort).
//!
//! Voxel `(i, j, k)` holds the points with `floor(x / size) = i`, `floor(y / size) = j`,
//! `floor(z / size) = k` (computed in f64, stored as i64). The grid is sparse: the occupied keys
//! are sorted, no dense grid is allocated, so a 0.5 mm voxel over a 100 m cloud costs no more than
//! over a 10 cm one (PCL's `VoxelGrid` overflows its int32 index there, PCL#585). When the
//! occupied key ranges and the point index fit in 64 bits together (1 M points leave 44 bits:
//! 2^14 voxels per axis, 32 m at 2 mm, or 2^44 along a single axis) they are packed into one u64 and
//! radix-sorted; otherwise (key triple, index) pairs are sorted. Both give the same output.
//!
//! Output order is by voxel key: x, then y, then z. Parallel (rayon); the output does not depend
//! on the number of threads (sort by (key, point index), sums in point-index order).

use std::borrow::Cow;
use std::cmp::Ordering;

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::cloud::{Bounds, PointCloud, SCAN_CHUNK};
use crate::error::{Error, Result};

/// Largest |voxel coordinate| accepted; beyond it a voxel size is absurdly small for the cloud.
const MAX_KEY: f64 = 4_611_686_018_427_387_904.0; // 2^62

/// Relative distance to an integer within which `x * (1 / size)` may floor differently from
/// `x / size` (their relative difference is at most 3 * 2^-53 = 3.3e-16).
const KEY_SLACK: f64 = 1e-15;

/// Summed normals shorter than this fraction of their count are treated as cancelled out.
const NORMAL_CANCEL_RATIO: f64 = 1e-6;

/// Voxel-grid parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct VoxelParams {
    /// Edge of a voxel, metres; positive and finite. Default 0.002: a little under the depth
    /// noise of a structured-light or stereo sensor at 1 m (about 2-3 mm), so merging points
    /// within one voxel averages noise away without erasing detail the sensor resolves.
    pub voxel_size_m: f64,
}

impl Default for VoxelParams {
    fn default() -> Self {
        Self { voxel_size_m: 0.002 }
    }
}

impl VoxelParams {
    /// Checks the parameters.
    ///
    /// # Errors
    /// [`Error::Invalid`] when `voxel_size_m` is not a positive finite number.
    pub fn validate(&self) -> Result<()> {
        let s = self.voxel_size_m;
        if !(s.is_finite() && s > 0.0) {
            return Err(Error::invalid("voxel.voxel_size_m", format!("{s} is not a positive finite size")));
        }
        Ok(())
    }
}

/// A down-sampled cloud and how many input points each output point stands for.
#[derive(Debug, Clone, PartialEq)]
pub struct VoxelResult {
    /// One point per occupied voxel, ordered by voxel key (x, then y, then z).
    pub cloud: PointCloud,
    /// Number of input points merged into each output point (same order; sums to the input size).
    pub points_per_voxel: Vec<usize>,
}

/// One centroid per occupied voxel; see the module docs.
///
/// # Errors
/// [`Error::Invalid`] for a bad `voxel_size_m`, an inconsistent or non-finite cloud, or a voxel so
/// small that a voxel coordinate exceeds ±2^62.
pub fn downsample(cloud: &PointCloud, params: &VoxelParams) -> Result<PointCloud> {
    downsample_cow(cloud, params).map(Cow::into_owned)
}

/// Like [`downsample`], but borrows `cloud` when it is already its own down-sampling (one point per
/// voxel, in key order: e.g. an ICP target or a view at its own voxel size) instead of copying it.
///
/// # Errors
/// As [`downsample`].
pub fn downsample_cow<'a>(cloud: &'a PointCloud, params: &VoxelParams) -> Result<Cow<'a, PointCloud>> {
    Ok(match runs(cloud, params)? {
        Some((order, starts)) => Cow::Owned(centroids(cloud, &order, &starts)),
        None => Cow::Borrowed(cloud),
    })
}

/// Like [`downsample`], also returning the number of points merged into each output point.
///
/// # Errors
/// As [`downsample`].
pub fn downsample_with_counts(cloud: &PointCloud, params: &VoxelParams) -> Result<VoxelResult> {
    Ok(match runs(cloud, params)? {
        Some((order, starts)) => VoxelResult {
            cloud: centroids(cloud, &order, &starts),
            points_per_voxel: starts.windows(2).map(|w| w[1] - w[0]).collect(),
        },
        None => VoxelResult { cloud: cloud.clone(), points_per_voxel: vec![1; cloud.len()] },
    })
}

/// The point indices sorted by voxel and the start of each voxel's run (plus the end), or `None`
/// when the cloud is already its own down-sampling: every point alone in its voxel, in key order
/// (then the output would be the input, point for point and bit for bit).
pub(super) fn runs(cloud: &PointCloud, params: &VoxelParams) -> Result<Option<(Vec<usize>, Vec<usize>)>> {
    params.validate()?;
    let Some(bounds) = cloud.validated_bounds("voxel downsample input")? else {
        return Ok(Some((Vec::new(), vec![0])));
    };
    let grid = Grid::new(&bounds, params.voxel_size_m)?;
    Ok((!grid.one_per_voxel_in_order(&cloud.points)).then(|| grid.sorted_runs(&cloud.points)))
}

/// One centroid (mean normal, mean color) per run of `order`.
fn centroids(cloud: &PointCloud, order: &[usize], starts: &[usize]) -> PointCloud {
    let run = |w: &[usize]| &order[w[0]..w[1]];
    let points = starts.par_windows(2).map(|w| mean_point(&cloud.points, run(w))).collect();
    let normals = cloud.normals.as_ref().map(|ns| starts.par_windows(2).map(|w| mean_normal(ns, run(w))).collect());
    let colors = cloud.colors.as_ref().map(|cs| starts.par_windows(2).map(|w| mean_color(cs, run(w))).collect());
    PointCloud { points, normals, colors }
}

/// A voxel down-sampling that grows: adding a cloud gives what down-sampling the accumulated
/// centroids together with the cloud's points would (each accumulated voxel counting as one point,
/// so recent clouds weigh more where they overlap, as re-down-sampling a growing model does),
/// without going over the accumulated voxels again: the added cloud is down-sampled on its own
/// (one sort of its points), then merged in one pass over both key-ordered lists. Positions match
/// that down-sampling to f32 rounding; a voxel's normal weighs the added points' unit mean normal by
/// their count (their sum's direction, not its length). Colors are not kept. Output order is by
/// voxel key, as [`downsample`]'s.
///
/// Voxel keys are not stored: a centroid lies in its voxel (the f32 mean of f32 points lies between
/// the smallest and the largest of them, per axis, and so does a weighted mean of two centroids),
/// so its key is recomputed from it.
#[derive(Debug, Clone)]
pub struct VoxelAccumulator {
    params: VoxelParams,
    cloud: PointCloud,
}

impl VoxelAccumulator {
    /// An empty accumulator.
    ///
    /// # Errors
    /// [`Error::Invalid`] for a bad `voxel_size_m`.
    pub fn new(params: &VoxelParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params: *params, cloud: PointCloud::default() })
    }

    /// The accumulated voxels: one centroid per occupied voxel, in key order.
    pub fn cloud(&self) -> &PointCloud {
        &self.cloud
    }

    /// Adds `cloud`'s points. Normals are kept when every added cloud has them.
    ///
    /// # Errors
    /// As [`downsample`].
    pub fn add(&mut self, cloud: &PointCloud) -> Result<()> {
        let mut added = downsample_with_counts(cloud, &self.params)?;
        added.cloud.colors = None;
        if self.cloud.is_empty() {
            self.cloud = added.cloud;
            return Ok(());
        }
        let (new, counts) = (&added.cloud, &added.points_per_voxel);
        let with_normals = self.cloud.normals.is_some() && new.normals.is_some();
        if !with_normals {
            self.cloud.normals = None;
        }
        let size = self.params.voxel_size_m;
        // the voxel of a centroid; in range: the down-sampling above checked the added points
        let key = |p: &Point3<f32>| [0, 1, 2].map(|a| floor_i64(f64::from(p[a]) / size));
        // Merged in place, from the back: the accumulated lists grow by the added voxels, and the
        // merge writes from the end down. The next write never lands on an unread accumulated
        // voxel (it stays at or above the unread voxels of both lists together), so the memory is
        // the accumulated voxels plus the added ones, not two copies of the model. The lists grow
        // by the added voxels exactly and are cut to the merged ones after (no spare capacity: the
        // finest level's lists are the sequential pass's largest).
        let (old_len, total) = (self.cloud.len(), self.cloud.len() + new.len());
        let points = &mut self.cloud.points;
        points.reserve_exact(new.len());
        points.resize(total, Point3::origin());
        let mut normals = self.cloud.normals.as_mut();
        if let Some(ns) = normals.as_deref_mut() {
            ns.reserve_exact(new.len());
            ns.resize(total, Vector3::zeros());
        }
        let new_normal = |i: usize| new.normals.as_ref().map_or_else(Vector3::zeros, |n| n[i]);
        let (mut a, mut b, mut w) = (old_len, new.len(), total);
        while a > 0 || b > 0 {
            let order = match (a.checked_sub(1), b.checked_sub(1)) {
                (Some(ia), Some(ib)) => key(&points[ia]).cmp(&key(&new.points[ib])),
                (Some(_), None) => Ordering::Greater,
                _ => Ordering::Less,
            };
            w -= 1;
            match order {
                Ordering::Greater => {
                    points[w] = points[a - 1];
                    if let Some(ns) = normals.as_deref_mut() {
                        ns[w] = ns[a - 1];
                    }
                }
                Ordering::Less => {
                    points[w] = new.points[b - 1];
                    if let Some(ns) = normals.as_deref_mut() {
                        ns[w] = new_normal(b - 1);
                    }
                }
                Ordering::Equal => {
                    // the accumulated centroid as one point, the added voxel as its points
                    let nb = counts[b - 1] as f64;
                    let p =
                        (points[a - 1].coords.cast::<f64>() + new.points[b - 1].coords.cast::<f64>() * nb) / (1.0 + nb);
                    points[w] = Point3::from(p.cast::<f32>());
                    if let Some(ns) = normals.as_deref_mut() {
                        let (ua, ub) = (ns[a - 1], new_normal(b - 1));
                        let sum = ua.cast::<f64>() + ub.cast::<f64>() * nb;
                        let norm = sum.norm();
                        ns[w] = if norm > NORMAL_CANCEL_RATIO * (1.0 + nb) { (sum / norm).cast::<f32>() } else { ua };
                    }
                }
            }
            a -= usize::from(order != Ordering::Less);
            b -= usize::from(order != Ordering::Greater);
        }
        // the merged voxels are [w, total): moved to the front
        points.copy_within(w.., 0);
        points.truncate(total - w);
        points.shrink_to_fit();
        if let Some(ns) = normals {
            ns.copy_within(w.., 0);
            ns.truncate(total - w);
            ns.shrink_to_fit();
        }
        Ok(())
    }
}

/// The occupied key range of a cloud: `lo` is the smallest key per axis, `bits` the bits each
/// axis's offset `key - lo` needs.
pub(super) struct Grid {
    size: f64,
    /// `1 / size`: see [`Grid::key`].
    inv: f64,
    lo: [i64; 3],
    bits: [u32; 3],
}

/// `x.floor() as i64` for finite `|x| <= 2^62`, without the libm call `f64::floor` compiles to on
/// the baseline x86-64 target (no SSE4.1 `roundsd`): the truncation is exact, and one less when it
/// rounded a negative non-integer up. Same value bit for bit.
#[inline]
fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    t - i64::from((t as f64) > x)
}

/// `v << s`, or 0 when `s >= 64`.
fn shl(v: u64, s: u32) -> u64 {
    v.checked_shl(s).unwrap_or(0)
}

impl Grid {
    pub(super) fn new(bounds: &Bounds, size: f64) -> Result<Self> {
        let floor = |v: f32| -> Result<i64> {
            let f = (f64::from(v) / size).floor();
            if f.abs() <= MAX_KEY {
                Ok(f as i64)
            } else {
                Err(Error::invalid(
                    "voxel.voxel_size_m",
                    format!("{size} m is too small for a coordinate of {v} m: voxel coordinate beyond ±2^62"),
                ))
            }
        };
        let (mut lo, mut bits) = ([0i64; 3], [0u32; 3]);
        for a in 0..3 {
            lo[a] = floor(bounds.min[a])?;
            // floor is monotonic, so these are the extreme keys; within ±2^62 the span fits in u64.
            bits[a] = 64 - floor(bounds.max[a])?.abs_diff(lo[a]).leading_zeros();
        }
        Ok(Self { size, inv: 1.0 / size, lo, bits })
    }

    /// `floor(x / size)` per axis (in range: every coordinate lies within the bounds checked in
    /// `new`), computed as `floor(x * (1 / size))`: that product is within 3.3e-16 (relative) of
    /// `x / size` (three roundings of at most 2^-53 each), so the two floors agree unless the
    /// product lies that close to an integer, and only then is the division done. Same keys, bit
    /// for bit, without a division per coordinate.
    #[inline]
    pub(super) fn key(&self, p: &Point3<f32>) -> [i64; 3] {
        let mut clear = true;
        let keys = [p.x, p.y, p.z].map(|x| {
            let q = f64::from(x) * self.inv;
            let f = q.floor();
            let (frac, slack) = (q - f, q.abs() * KEY_SLACK);
            clear &= frac > slack && frac < 1.0 - slack;
            f as i64
        });
        if clear { keys } else { self.key_by_division(p) }
    }

    /// [`Grid::key`] by division: for a coordinate next to a voxel boundary (kept out of line, so
    /// that the common case has no division at all).
    #[cold]
    #[inline(never)]
    fn key_by_division(&self, p: &Point3<f32>) -> [i64; 3] {
        [p.x, p.y, p.z].map(|x| floor_i64(f64::from(x) / self.size))
    }

    /// True when every point has its own voxel and the points are in key order: the cloud is its
    /// own down-sampling (a centroid lies in its voxel, and a voxel of one point keeps its normal
    /// and color as they are). Stops at the first point out of order.
    fn one_per_voxel_in_order(&self, points: &[Point3<f32>]) -> bool {
        let mut previous: Option<[i64; 3]> = None;
        for p in points {
            let k = self.key(p);
            if previous.is_some_and(|q| q >= k) {
                return false;
            }
            previous = Some(k);
        }
        true
    }

    /// Point indices sorted by (voxel key, index), and the start of each run of equal keys (plus
    /// one final entry, `points.len()`).
    fn sorted_runs(&self, points: &[Point3<f32>]) -> (Vec<usize>, Vec<usize>) {
        let idx_bits = 64 - (points.len().saturating_sub(1) as u64).leading_zeros();
        if self.bits.iter().sum::<u32>() + idx_bits <= 64 {
            self.runs_packed(points, idx_bits)
        } else {
            self.runs_triples(points)
        }
    }

    /// The fast path: key offsets (x, y, z, most significant first) above the point index in one
    /// u64, and a stable LSD radix sort on the key bits, which keeps equal keys in index order.
    fn runs_packed(&self, points: &[Point3<f32>], idx_bits: u32) -> (Vec<usize>, Vec<usize>) {
        let [bx, by, bz] = self.bits;
        let shifts = [by + bz + idx_bits, bz + idx_bits, idx_bits];
        let mut packed = vec![0u64; points.len()];
        packed.par_chunks_mut(SCAN_CHUNK).zip(points.par_chunks(SCAN_CHUNK)).enumerate().for_each(
            |(c, (out, chunk))| {
                for (i, (o, p)) in (c * SCAN_CHUNK..).zip(out.iter_mut().zip(chunk)) {
                    let k = self.key(p);
                    *o = (0..3).fold(i as u64, |v, a| v | shl(k[a].abs_diff(self.lo[a]), shifts[a]));
                }
            },
        );
        radix_sort(&mut packed, idx_bits, idx_bits + bx + by + bz);
        let idx_mask = shl(1, idx_bits).wrapping_sub(1);
        // By chunks, each a sequential scan (rayon's per-item `filter` costs more than the test),
        // each starting from the key before it.
        let before: Vec<Option<u64>> = (0..packed.len().div_ceil(SCAN_CHUNK))
            .map(|c| (c * SCAN_CHUNK).checked_sub(1).map(|p| packed[p] & !idx_mask))
            .collect();
        let mut starts = packed
            .par_chunks_mut(SCAN_CHUNK)
            .zip(before)
            .enumerate()
            .map(|(c, (chunk, previous))| {
                // branch-free: every position is written, and kept when its key is new
                let mut starts = vec![0; chunk.len()];
                // (the first chunk's first key differs from its complement)
                let mut previous = previous.unwrap_or(!(chunk[0] & !idx_mask));
                let mut kept = 0;
                for (pos, v) in (c * SCAN_CHUNK..).zip(chunk) {
                    let key = *v & !idx_mask;
                    starts[kept] = pos;
                    kept += usize::from(key != previous);
                    previous = key;
                    *v &= idx_mask;
                }
                starts.truncate(kept);
                starts
            })
            .collect::<Vec<_>>()
            .concat();
        starts.push(points.len());
        // Same size and alignment: collected in place, no second buffer.
        (packed.into_iter().map(|i| i as usize).collect(), starts)
    }

    /// The general path for key ranges too wide to pack: sort (key triple, index) pairs.
    fn runs_triples(&self, points: &[Point3<f32>]) -> (Vec<usize>, Vec<usize>) {
        let mut full: Vec<([i64; 3], usize)> = points.par_iter().enumerate().map(|(i, p)| (self.key(p), i)).collect();
        full.par_sort_unstable();
        let mut order = Vec::with_capacity(points.len());
        let mut starts = Vec::new();
        for (pos, &(k, i)) in full.iter().enumerate() {
            if pos == 0 || k != full[pos - 1].0 {
                starts.push(pos);
            }
            order.push(i);
        }
        starts.push(points.len());
        (order, starts)
    }
}

/// Values a chunk of a parallel radix pass gets at least; fewer values sort in one chunk.
const RADIX_MIN_CHUNK: usize = 1 << 16;

/// Stable LSD radix sort of `values` by their bits `lo_bit..hi_bit` (digits of at most 13 bits).
/// In one chunk (one thread, or few values) the histograms of every digit are counted in one pass
/// over the input, then each digit is one scatter pass. In several chunks each pass counts its
/// digit per chunk, then every chunk scatters into its own slices of the output, in parallel. The
/// result is the one stable order either way.
fn radix_sort(values: &mut Vec<u64>, lo_bit: u32, hi_bit: u32) {
    let total = hi_bit.saturating_sub(lo_bit);
    if total == 0 || values.len() < 2 {
        return;
    }
    let passes = total.div_ceil(13) as usize;
    let digit = total.div_ceil(passes as u32);
    let shifts: Vec<u32> = (0..passes as u32).map(|k| lo_bit + k * digit).collect();
    let masks: Vec<u64> = shifts.iter().map(|&s| (1u64 << digit.min(hi_bit - s)) - 1).collect();
    let width = 1usize << digit;
    let chunks = rayon::current_num_threads().min(values.len() / RADIX_MIN_CHUNK).max(1);
    let mut buffer = vec![0u64; values.len()];
    if chunks > 1 {
        for (&shift, &mask) in shifts.iter().zip(&masks) {
            if radix_pass_chunked(values, &mut buffer, chunks, width, |v| ((v >> shift) & mask) as usize) {
                std::mem::swap(values, &mut buffer);
            }
        }
        return;
    }
    let mut counts = vec![0usize; width * passes];
    for &v in values.iter() {
        for (k, (&s, &m)) in shifts.iter().zip(&masks).enumerate() {
            counts[k * width + ((v >> s) & m) as usize] += 1;
        }
    }
    for (k, (&shift, &mask)) in shifts.iter().zip(&masks).enumerate() {
        let counts = &mut counts[k * width..(k + 1) * width];
        if counts.contains(&values.len()) {
            continue; // every value has the same digit: this pass would not move anything
        }
        let mut sum = 0;
        for c in counts.iter_mut() {
            (*c, sum) = (sum, sum + *c);
        }
        for &v in values.iter() {
            let d = ((v >> shift) & mask) as usize;
            buffer[counts[d]] = v;
            counts[d] += 1;
        }
        std::mem::swap(values, &mut buffer);
    }
}

/// One stable scatter of `values` into `out` by `digit` (below `width`), the values cut into
/// `chunks` runs scattered in parallel: run `c`'s values of digit `d` go to the slice of `out`
/// after every digit below `d` and after the earlier runs' values of digit `d`. Returns false (and
/// writes nothing) when every value has the same digit.
fn radix_pass_chunked(
    values: &[u64],
    out: &mut [u64],
    chunks: usize,
    width: usize,
    digit: impl Fn(u64) -> usize + Sync,
) -> bool {
    let chunk_len = values.len().div_ceil(chunks);
    let counts: Vec<Vec<usize>> = values
        .par_chunks(chunk_len)
        .map(|run| {
            let mut c = vec![0usize; width];
            run.iter().for_each(|&v| c[digit(v)] += 1);
            c
        })
        .collect();
    if (0..width).any(|d| counts.iter().map(|c| c[d]).sum::<usize>() == values.len()) {
        return false;
    }
    let mut slices: Vec<Vec<&mut [u64]>> = counts.iter().map(|_| Vec::with_capacity(width)).collect();
    let mut rest = out;
    for d in 0..width {
        for (c, run) in counts.iter().enumerate() {
            let (slice, tail) = std::mem::take(&mut rest).split_at_mut(run[d]);
            slices[c].push(slice);
            rest = tail;
        }
    }
    values.par_chunks(chunk_len).zip(slices).for_each(|(run, mut slots)| {
        for &v in run {
            let slot = &mut slots[digit(v)];
            if let Some((first, tail)) = std::mem::take(slot).split_first_mut() {
                *first = v;
                *slot = tail;
            }
        }
    });
    true
}

pub(super) fn mean_point(points: &[Point3<f32>], run: &[usize]) -> Point3<f32> {
    let sum = run.iter().fold(Vector3::<f64>::zeros(), |acc, &i| acc + points[i].coords.cast::<f64>());
    Point3::from(sum / run.len() as f64).cast::<f32>()
}

pub(super) fn mean_normal(normals: &[Vector3<f32>], run: &[usize]) -> Vector3<f32> {
    if let [one] = run {
        // Kept as it is (not re-normalised): so a down-sampled cloud is its own down-sampling.
        return normals[*one];
    }
    let sum = run.iter().fold(Vector3::<f64>::zeros(), |acc, &i| acc + normals[i].cast::<f64>());
    let norm = sum.norm();
    if norm > NORMAL_CANCEL_RATIO * run.len() as f64 {
        (sum / norm).cast::<f32>()
    } else {
        // Opposing normals cancelled out: keep the first point's (runs are in index order).
        normals[run[0]]
    }
}

pub(super) fn mean_color(colors: &[[u8; 3]], run: &[usize]) -> [u8; 3] {
    let n = run.len() as u64;
    let mut sum = [0u64; 3];
    for &i in run {
        for (s, &c) in sum.iter_mut().zip(&colors[i]) {
            *s += u64::from(c);
        }
    }
    // Round half up; the mean of u8 values is at most 255.
    sum.map(|s| ((s + n / 2) / n).min(255) as u8)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool").install(f)
    }

    #[test]
    fn known_grid_gives_exact_centroids() {
        // 10 voxels of 1 cm along x; 100 points in each, on a 10x10 lattice centred in the voxel's
        // y-z face at x offsets 2.5 mm and 7.5 mm (50 each): centroid at the voxel centre.
        let size = 0.01;
        let mut points = Vec::new();
        for v in (0..10).rev() {
            for a in 0..10 {
                for b in 0..10 {
                    let x = v as f32 * 0.01 + if (a + b) % 2 == 0 { 0.0025 } else { 0.0075 };
                    points.push(Point3::new(x, 0.0005 + a as f32 * 0.001, 0.0005 + b as f32 * 0.001));
                }
            }
        }
        assert_eq!(points.len(), 1000);
        let out = downsample_with_counts(&PointCloud::from_points(points), &VoxelParams { voxel_size_m: size })
            .expect("downsample");
        assert_eq!(out.cloud.len(), 10);
        assert_eq!(out.points_per_voxel, vec![100; 10]);
        for (v, p) in out.cloud.points.iter().enumerate() {
            let want = Point3::new(v as f32 * 0.01 + 0.005, 0.005, 0.005);
            assert!((p - want).norm() < 1e-6, "voxel {v}: {p} vs {want}");
        }
    }

    #[test]
    fn order_is_x_then_y_then_z_with_negative_keys() {
        let pts = [(0.5, -0.5, 0.5), (-0.5, 0.5, 0.5), (-0.5, -0.5, 0.5), (-0.5, -0.5, -0.5), (0.5, 0.5, -0.5)];
        let cloud = PointCloud::from_points(pts.iter().map(|&(x, y, z)| Point3::new(x, y, z)).collect());
        let out = downsample(&cloud, &VoxelParams { voxel_size_m: 1.0 }).expect("downsample");
        let got: Vec<(f32, f32, f32)> = out.points.iter().map(|p| (p.x, p.y, p.z)).collect();
        let want = [(-0.5, -0.5, -0.5), (-0.5, -0.5, 0.5), (-0.5, 0.5, 0.5), (0.5, -0.5, 0.5), (0.5, 0.5, -0.5)];
        assert_eq!(got, want);
    }

    #[test]
    fn normals_and_colors_are_averaged() {
        let cloud = PointCloud {
            points: vec![
                Point3::new(0.1, 0.1, 0.1),
                Point3::new(0.2, 0.2, 0.2),
                Point3::new(0.3, 0.3, 0.3),
                Point3::new(1.1, 0.1, 0.1),
                Point3::new(1.2, 0.1, 0.1),
            ],
            normals: Some(vec![
                Vector3::x(),
                Vector3::y(),
                Vector3::y(),
                Vector3::z(), // these two cancel: the first is kept
                -Vector3::z(),
            ]),
            colors: Some(vec![[0, 10, 255], [1, 20, 255], [1, 31, 254], [7, 7, 7], [8, 8, 8]]),
        };
        let out = downsample_with_counts(&cloud, &VoxelParams { voxel_size_m: 1.0 }).expect("downsample");
        assert_eq!(out.points_per_voxel, vec![3, 2]);
        assert!((out.cloud.points[0] - Point3::new(0.2, 0.2, 0.2)).norm() < 1e-6);
        assert!((out.cloud.points[1] - Point3::new(1.15, 0.1, 0.1)).norm() < 1e-6);
        let normals = out.cloud.normals.expect("normals");
        let s = 5f32.sqrt();
        assert!((normals[0] - Vector3::new(1.0 / s, 2.0 / s, 0.0)).norm() < 1e-6, "{}", normals[0]);
        assert_eq!(normals[1], Vector3::z());
        // (0+1+1)/3 = 0.667 -> 1, (10+20+31)/3 = 20.33 -> 20, (255+255+254)/3 = 254.67 -> 255;
        // (7+8)/2 = 7.5 -> 8 (half up).
        assert_eq!(out.cloud.colors.expect("colors"), vec![[1, 20, 255], [8, 8, 8]]);
    }

    #[test]
    fn half_millimetre_over_a_hundred_metres() {
        // A 100 m line along x from -50 m, one point every 0.3 mm starting 0.05 mm past a voxel
        // boundary: every point is at least 0.05 mm from a boundary (f32 error at 50 m: 0.004 mm)
        // and every 0.5 mm voxel from key -100000 to 99999 holds one or two points.
        let size = 0.0005;
        let n = 333_333;
        let points: Vec<Point3<f32>> =
            (0..n).map(|i| Point3::new((-50.0 + 0.00005 + i as f64 * 0.0003) as f32, 3.0, -2.0)).collect();
        assert!(points[n - 1].x - points[0].x > 99.999);
        let out = downsample_with_counts(&PointCloud::from_points(points), &VoxelParams { voxel_size_m: size })
            .expect("downsample");
        assert_eq!(out.cloud.len(), 200_000);
        assert_eq!(out.points_per_voxel.iter().sum::<usize>(), n);
        assert!(out.points_per_voxel.iter().all(|&c| c == 1 || c == 2));
        let key = |p: &Point3<f32>| (f64::from(p.x) / size).floor() as i64;
        assert_eq!((key(&out.cloud.points[0]), key(&out.cloud.points[199_999])), (-100_000, 99_999));
        assert!(out.cloud.points.windows(2).all(|w| key(&w[1]) == key(&w[0]) + 1));
        assert!(out.cloud.points.iter().all(|p| p.y == 3.0 && p.z == -2.0));
    }

    #[test]
    fn wide_keys_fall_back_to_triples() {
        // 1e-9 m voxels over ±1e6 m: 2^51 voxels per axis, more than 64 packed bits.
        let pts = vec![Point3::new(1e6, -1e6, 1e6), Point3::new(-1e6, 1e6, -1e6), Point3::new(-1e6, 1e6, -1e6)];
        let out = downsample_with_counts(&PointCloud::from_points(pts), &VoxelParams { voxel_size_m: 1e-9 })
            .expect("downsample");
        assert_eq!(out.points_per_voxel, vec![2, 1]);
        assert_eq!(out.cloud.points[0], Point3::new(-1e6, 1e6, -1e6));
        let tiny = downsample(
            &PointCloud::from_points(vec![Point3::new(1e30, 0.0, 0.0)]),
            &VoxelParams { voxel_size_m: 1e-20 },
        );
        assert!(matches!(tiny, Err(Error::Invalid { .. })));
    }

    #[test]
    fn packed_and_triple_paths_agree() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let points: Vec<Point3<f32>> = (0..30_000)
            .map(|_| Point3::new(rng.random::<f32>() - 0.5, rng.random::<f32>() * 2.0, -rng.random::<f32>()))
            .collect();
        let bounds = PointCloud::from_points(points.clone()).bounds().expect("bounds");
        // runs of about 15 points, and of about one (so runs start on the scan's chunk boundaries)
        for (size, voxels) in [(0.1, Some(10 * 20 * 10)), (0.001, None)] {
            let grid = Grid::new(&bounds, size).expect("grid");
            let (order, starts) = grid.runs_packed(&points, 15);
            assert_eq!((order.clone(), starts.clone()), grid.runs_triples(&points), "{size} m");
            assert!(voxels.is_none_or(|v| starts.len() - 1 == v));
            for w in starts.windows(2) {
                let run = &order[w[0]..w[1]];
                assert!(run.windows(2).all(|r| r[0] < r[1] && grid.key(&points[r[0]]) == grid.key(&points[r[1]])));
            }
        }
    }

    /// `n` points uniform in the unit cube moved by `offset`, random normals (z in [0, `normal_z`]
    /// before normalising) and colors.
    fn random_cloud(seed: u64, n: usize, offset: Vector3<f32>, normal_z: f32) -> PointCloud {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let points = (0..n).map(|_| Point3::new(rng.random(), rng.random(), rng.random()) + offset).collect();
        let normals = (0..n)
            .map(|_| Vector3::new(rng.random(), rng.random(), rng.random::<f32>() * normal_z).normalize())
            .collect();
        let colors = (0..n).map(|_| [rng.random(), rng.random(), rng.random()]).collect();
        PointCloud { points, normals: Some(normals), colors: Some(colors) }
    }

    #[test]
    fn one_and_two_threads_agree_bitwise() {
        let cloud = random_cloud(42, 200_000, Vector3::zeros(), 1.0);
        let params = VoxelParams { voxel_size_m: 0.05 };
        let one = in_pool(1, || downsample_with_counts(&cloud, &params).expect("1 thread"));
        let two = in_pool(2, || downsample_with_counts(&cloud, &params).expect("2 threads"));
        assert_eq!(one, two);
        assert_eq!(one.cloud.len(), 20 * 20 * 20);
    }

    #[test]
    fn fast_floor_and_radix_sort_match_std() {
        let edges = [0.0, -0.0, 0.5, -0.5, 1.0, -1.0, 2.0 - 1e-16, -1e-300, 1e-300, 4.6e18, -4.6e18, 123456.999];
        for x in edges {
            assert_eq!(floor_i64(x), x.floor() as i64, "{x}");
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for _ in 0..100_000 {
            let x = (rng.random::<f64>() - 0.5) * 10f64.powi(rng.random_range(-3..12));
            assert_eq!(floor_i64(x), x.floor() as i64, "{x}");
        }
        for bits in [1u32, 11, 12, 23, 33, 40] {
            let mut values: Vec<u64> = (0..5000).map(|_| rng.random::<u64>() & ((1u64 << (bits + 7)) - 1)).collect();
            values.push(values[0]);
            let mut want = values.clone();
            want.sort_by_key(|v| (v >> 7, v & 0x7f)); // stable on the key: equal keys keep input order
            let order: Vec<u64> = values.clone();
            radix_sort(&mut values, 7, 7 + bits);
            let mut stable = order.clone();
            stable.sort_by_key(|v| v >> 7);
            assert_eq!(values, stable, "{bits} bits");
            assert_eq!(
                values.iter().map(|v| v >> 7).collect::<Vec<_>>(),
                want.iter().map(|v| v >> 7).collect::<Vec<_>>()
            );
        }
    }

    #[test]
    fn keys_by_reciprocal_match_division() {
        // random coordinates, and coordinates on and next to voxel boundaries (where x * (1 / size)
        // and x / size may floor differently), for sizes whose reciprocal is inexact
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        for size in [0.005, 0.002, 0.003, 0.0007, 0.1, 1.0 / 3.0, 1e-6] {
            let bounds = Bounds { min: Point3::new(-100.0, -100.0, -100.0), max: Point3::new(100.0, 100.0, 100.0) };
            let grid = Grid::new(&bounds, size).expect("grid");
            let mut xs: Vec<f32> = (0..20_000).map(|_| (rng.random::<f32>() - 0.5) * 20.0).collect();
            for k in -2000i32..2000 {
                let on = (f64::from(k) * size) as f32;
                xs.extend([on, on.next_up(), on.next_down()]);
            }
            for x in xs.chunks(3).filter(|c| c.len() == 3) {
                let p = Point3::new(x[0], x[1], x[2]);
                let want = [0, 1, 2].map(|a| (f64::from(p[a]) / size).floor() as i64);
                assert_eq!(grid.key(&p), want, "{p} at {size} m");
            }
        }
    }

    #[test]
    fn chunked_radix_passes_match_the_serial_sort() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        // 300 000 values: 19 index bits under 25 key bits (two passes); few distinct keys
        let values: Vec<u64> = (0..300_000u64).map(|i| (rng.random_range(0..1u64 << 25) << 19) | i).collect();
        let few: Vec<u64> = (0..300_000u64).map(|i| (rng.random_range(0..3u64) << 19) | i).collect();
        for input in [values, few] {
            let mut want = input.clone();
            want.sort_unstable(); // the index bits make every value distinct: the stable order
            for threads in [1, 2, 3] {
                let mut got = input.clone();
                in_pool(threads, || radix_sort(&mut got, 19, 19 + 25));
                assert!(got == want, "{threads} threads");
            }
        }
    }

    #[test]
    fn down_sampled_cloud_is_its_own_down_sampling() {
        let cloud = random_cloud(9, 50_000, Vector3::new(-0.5, 0.0, -1.0), 0.3);
        let params = VoxelParams { voxel_size_m: 0.02 };
        let once = downsample(&cloud, &params).expect("once");
        let bounds = once.bounds().expect("bounds");
        assert!(Grid::new(&bounds, 0.02).expect("grid").one_per_voxel_in_order(&once.points));
        assert!(!Grid::new(&bounds, 0.04).expect("grid").one_per_voxel_in_order(&once.points));
        let twice = downsample_with_counts(&once, &params).expect("twice");
        assert_eq!(twice.cloud, once);
        assert_eq!(twice.points_per_voxel, vec![1; once.len()]);
        // The same cloud in another order takes the sorting path and gives the same output.
        let reversed: Vec<usize> = (0..once.len()).rev().collect();
        assert_eq!(downsample(&once.select(&reversed), &params).expect("reversed"), once);
    }

    #[test]
    fn bad_input() {
        let cloud = PointCloud::from_points(vec![Point3::origin()]);
        for size in [0.0, -0.001, f64::NAN, f64::INFINITY] {
            let err = downsample(&cloud, &VoxelParams { voxel_size_m: size });
            assert!(matches!(err, Err(Error::Invalid { .. })), "{size}: {err:?}");
        }
        let empty = downsample_with_counts(&PointCloud::default(), &VoxelParams::default()).expect("empty");
        assert!(empty.cloud.is_empty() && empty.points_per_voxel.is_empty());
        let bad = PointCloud::from_points(vec![Point3::new(f32::NAN, 0.0, 0.0)]);
        assert!(downsample(&bad, &VoxelParams::default()).is_err());
    }

    #[test]
    fn accumulator_matches_down_sampling_the_centroids_with_the_new_points() {
        // three overlapping clouds with normals: after each add, the accumulator holds
        // downsample(previous centroids + new points), to f32 rounding, in the same order
        let params = VoxelParams { voxel_size_m: 0.01 };
        let clouds: Vec<PointCloud> = (0..3)
            .map(|i| random_cloud(20 + i, 20_000, Vector3::new(0.03 * i as f32, -0.02, 0.0), 0.5 - 0.3 * i as f32))
            .collect();
        let mut acc = VoxelAccumulator::new(&params).expect("accumulator");
        let mut reference = PointCloud::default();
        for cloud in &clouds {
            acc.add(cloud).expect("add");
            let mut merged = reference.clone();
            merged.extend(&PointCloud { colors: None, ..cloud.clone() });
            reference = downsample(&merged, &params).expect("reference");
            let got = acc.cloud();
            assert_eq!(got.len(), reference.len());
            let worst = got.points.iter().zip(&reference.points).map(|(a, b)| (a - b).norm()).fold(0.0, f32::max);
            assert!(worst < 1e-6, "centroids differ by {worst} m");
            let (gn, rn) = (got.normals.as_ref().expect("normals"), reference.normals.as_ref().expect("normals"));
            let worst = gn.iter().zip(rn).map(|(a, b)| (a - b).norm()).fold(0.0, f32::max);
            let mean = gn.iter().zip(rn).map(|(a, b)| (a - b).norm()).sum::<f32>() / gn.len() as f32;
            // the added voxel's normals enter as their (unit) mean times their count, not their
            // sum: the same direction, a little more weight when they disagree (these spread widely)
            assert!(worst < 0.03 && mean < 0.003, "normals differ by {worst} at most, {mean} on average");
        }
        // thread count does not matter
        let accumulate = || {
            let mut a = VoxelAccumulator::new(&params).expect("accumulator");
            clouds.iter().for_each(|c| a.add(c).expect("add"));
            a.cloud().clone()
        };
        assert_eq!(in_pool(1, accumulate), in_pool(2, accumulate));
        assert!(VoxelAccumulator::new(&VoxelParams { voxel_size_m: 0.0 }).is_err());
    }
}
