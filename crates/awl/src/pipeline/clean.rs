//! Per-view outlier removal and normals from one k-NN pass.
//!
//! `awl fuse` removes statistical outliers (the `k` nearest points, the point included) and then
//! estimates normals on the points it kept (the `k` nearest kept points within a radius). As two
//! filters that is two k-NN passes. Here one k-NN table over the voxelised view (`k + 1` per point)
//! serves both: SOR reads it (see `statistical_from_knn`), and a kept point's normal neighbourhood
//! is its row with the removed points skipped. The table's rows are the nearest points ordered by
//! (distance, index), and removing points keeps the others' order, so the first `k` kept points
//! of a row are exactly the row a table over the kept points would hold. A row with fewer than `k`
//! kept points is searched again in a tree over the kept points (about 1 % of them). Output: bit
//! for bit that of `statistical` then `with_normals` on the kept cloud.

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::cloud::PointCloud;
use crate::error::Result;
use crate::filter::outlier::{SorParams, statistical_from_knn};
use crate::normals::{NormalParams, covariance, orient_towards, plane_of};
use crate::organized::{self, Cleaned, PixelGrid};
use crate::spatial::{KdIndex, KnnTable, Neighbor};

/// What [`clean_on_grid`] gives.
pub(crate) struct OnGrid {
    /// The points to register: the measured ones, or their smoothed copies (no colors).
    pub cloud: PointCloud,
    /// The measured points when `cloud` holds their smoothed copies.
    pub measured: Option<PointCloud>,
    /// The index in the input cloud of each measured point (ascending).
    pub sources: Vec<usize>,
}

/// A depth view's cloud without its statistical outliers, with unit normals oriented toward the
/// camera (the origin; points whose normal is undefined dropped): both from each point's window of
/// `(2 half + 1)^2` pixels on `grid` (see `organized`). With `smoothing_m`, the points come back
/// moved onto their local planes (at most that far, see `organized::onto_local_planes`; no colors),
/// and the measured ones beside them.
///
/// # Errors
/// Bad parameters, a non-finite cloud, a grid that is not the cloud's. (`smoothing_m` is checked
/// once for the whole fuse, by [`FuseConfig::check`](super::config::FuseConfig::check).)
pub(crate) fn clean_on_grid(
    cloud: PointCloud,
    grid: PixelGrid,
    half: usize,
    sor: &SorParams,
    params: &NormalParams,
    smoothing_m: Option<f64>,
) -> Result<OnGrid> {
    let Cleaned { sor, normals, centroids } = organized::clean(&cloud, &grid, half, sor, params)?;
    drop(grid);
    let mut measured = cloud;
    measured.retain_indices(&sor.kept);
    let valid = defined(&normals);
    let sources = valid.iter().map(|&j| sor.kept[j]).collect();
    let Some(max_shift) = smoothing_m else {
        let cloud = with_oriented_normals(measured, normals, &Point3::origin(), &valid)?;
        return Ok(OnGrid { cloud, measured: None, sources });
    };
    let points = organized::onto_local_planes(&measured.points, &normals, &centroids, max_shift as f32);
    let smoothed = PointCloud { points, normals: None, colors: None };
    Ok(OnGrid {
        cloud: with_oriented_normals(smoothed, normals.clone(), &Point3::origin(), &valid)?,
        measured: Some(with_oriented_normals(measured, normals, &Point3::origin(), &valid)?),
        sources,
    })
}

/// The indices of the normals that are defined (not zero; turning a normal keeps it so).
fn defined(normals: &[Vector3<f32>]) -> Vec<usize> {
    (0..normals.len()).filter(|&j| normals[j] != Vector3::zeros()).collect()
}

/// `cloud` with `normals` (one per point) turned toward `viewpoint`, only its points at `valid`
/// (those whose normal is defined, [`defined`]) kept.
fn with_oriented_normals(
    mut cloud: PointCloud,
    mut normals: Vec<Vector3<f32>>,
    viewpoint: &Point3<f32>,
    valid: &[usize],
) -> Result<PointCloud> {
    orient_towards(&cloud.points, &mut normals, viewpoint)?;
    cloud.normals = Some(normals);
    cloud.retain_indices(valid);
    Ok(cloud)
}

/// The cloud without its statistical outliers, with unit normals oriented toward `viewpoint`
/// (the points whose normal is undefined dropped): `statistical` then `with_normals`.
///
/// # Errors
/// Bad parameters or a non-finite cloud.
pub(crate) fn clean_with_normals(
    cloud: &PointCloud,
    sor: &SorParams,
    params: &NormalParams,
    viewpoint: Point3<f32>,
) -> Result<PointCloud> {
    sor.validate()?;
    params.validate()?;
    let table = KnnTable::new(&cloud.points, sor.neighbors.max(params.neighbors + 1))?;
    let kept = statistical_from_knn(cloud, &table, sor)?.kept;
    let out = cloud.select(&kept);
    let mut position = vec![u32::MAX; cloud.len()]; // index in `out` of each kept point
    for (j, &i) in kept.iter().enumerate() {
        position[i] = j as u32;
    }
    let kept_index = KdIndex::new(&out.points)?;
    let k = params.neighbors.min(kept.len());
    let r2 = params.radius_m.map_or(f32::INFINITY, |r| (r * r) as f32);
    let points = &out.points;
    let normals: Vec<Vector3<f32>> = (0..points.len())
        .into_par_iter()
        .with_min_len(256)
        .map_init(Vec::new, |buf: &mut Vec<Neighbor>, j| {
            let p = &points[j];
            if !from_row(table.row(kept[j]), &position, k, buf) {
                // the k nearest by (distance, index): every point as near as the k-th (the reach
                // widened so that squaring its root cannot drop the k-th)
                let reach = kept_index.knn(p, k).last().map_or(0.0, |n| n.dist_sq.sqrt() * (1.0 + 1e-6) + 1e-9);
                *buf = kept_index.within(p, reach);
                buf.sort_unstable_by(|a, b| a.dist_sq.total_cmp(&b.dist_sq).then(a.index.cmp(&b.index)));
                buf.truncate(k);
            }
            let count = buf.iter().take_while(|n| n.dist_sq <= r2).count();
            let fit = covariance(points, p, buf[..count].iter().map(|n| n.index as usize)).and_then(plane_of);
            fit.map_or_else(Vector3::zeros, |(n, _)| n.cast::<f32>())
        })
        .collect();
    let valid = defined(&normals);
    with_oriented_normals(out, normals, &viewpoint, &valid)
}

/// The `k` nearest kept points (indices in the kept cloud) from a row of the full table, into `buf`;
/// false when the row holds fewer than `k` kept points (see the module docs).
fn from_row(row: &[Neighbor], position: &[u32], k: usize, buf: &mut Vec<Neighbor>) -> bool {
    buf.clear();
    for n in row {
        if buf.len() == k {
            break;
        }
        let j = position[n.index as usize];
        if j != u32::MAX {
            buf.push(Neighbor { index: j, dist_sq: n.dist_sq });
        }
    }
    buf.len() == k
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::outlier::statistical;
    use crate::normals::with_normals;
    use rand::{RngExt, SeedableRng};

    /// A wavy surface in front of the camera: half of it on an exact lattice (ties at equal
    /// distance everywhere), half jittered, plus scattered outliers.
    fn view_like_cloud() -> PointCloud {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut points = Vec::new();
        for a in 0..160 {
            for b in 0..120 {
                let (x, y) = (a as f32 * 0.002 - 0.16, b as f32 * 0.002 - 0.12);
                let jitter = if a < 80 { 0.0 } else { (rng.random::<f32>() - 0.5) * 0.001 };
                points.push(Point3::new(x + jitter, y, 0.8 + 0.02 * (x * 20.0).sin() + jitter));
            }
        }
        for _ in 0..300 {
            let (x, y, z): (f32, f32, f32) = (rng.random(), rng.random(), rng.random());
            points.push(Point3::new(x - 0.5, y - 0.5, 0.3 + z));
        }
        PointCloud::from_points(points)
    }

    #[test]
    fn same_as_sor_then_normals_bit_for_bit() {
        let cloud = view_like_cloud();
        for (sor, normals) in [
            (SorParams::default(), NormalParams::default()),
            (SorParams { neighbors: 8, std_ratio: 1.0 }, NormalParams { neighbors: 12, radius_m: None }),
            (SorParams { neighbors: 30, std_ratio: 0.5 }, NormalParams { neighbors: 5, radius_m: Some(0.003) }),
        ] {
            let kept = cloud.select(&statistical(&cloud, &sor).expect("sor"));
            let want = with_normals(&kept, &normals, Some(Point3::origin())).expect("normals");
            let got = clean_with_normals(&cloud, &sor, &normals, Point3::origin()).expect("shared");
            assert!(want.len() > 15_000, "{}", want.len());
            assert_eq!(got, want, "{sor:?} {normals:?}");
        }
    }

    #[test]
    fn tiny_clouds() {
        let cloud = PointCloud::from_points(
            (0..5).map(|i| Point3::new(i as f32 * 0.001, (i * i) as f32 * 1e-4, 1.0)).collect(),
        );
        let (sor, normals) = (SorParams::default(), NormalParams::default());
        let kept = cloud.select(&statistical(&cloud, &sor).expect("sor"));
        let want = with_normals(&kept, &normals, Some(Point3::origin())).expect("normals");
        assert_eq!(clean_with_normals(&cloud, &sor, &normals, Point3::origin()).expect("shared"), want);
        let empty = clean_with_normals(&PointCloud::default(), &sor, &normals, Point3::origin()).expect("empty");
        assert!(empty.is_empty());
    }
}
