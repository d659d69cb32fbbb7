//! `face-centre@x,y,z`: the centre of the planar face nearest a point (the paper's method).
//!
//! 1. The local plane at the point ([`SurfaceModel::snap`]) gives the face's approximate normal.
//! 2. RANSAC ([`fit_plane_ransac`], `up` = that normal, within `max_tilt_rad`) among the model points
//!    within `radius_m` of the point; when the point is not on the RANSAC plane (another parallel
//!    face dominates) the local plane is used instead.
//! 3. The face: the plane's inliers (within `distance_m`, model normal within `max_normal_rad` when
//!    the model has normals) connected to the point through steps of at most `link_m`; a
//!    least-squares refit on them.
//! 4. In the plane: the 2D convex hull of the face and its minimum-area enclosing rectangle
//!    (rotating calipers over the hull edges) give the rectangle's axes. Its sides are then placed
//!    where the face's point density along each axis falls to half its interior level
//!    ([`half_density_extent`]): the hull itself reaches the few stray points fusion leaves past a
//!    box's edges (measured up to 8 mm on a simulated box), which moved the centre by 1.3 mm.
//!    The 4 corners, their centre.

use nalgebra::{Point2, Point3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::segment::{PlaneParams, fit_plane_ransac};
use crate::workpiece::target_spec::TargetSpec;
use crate::workpiece::targets::{SurfaceModel, SurfaceTarget, TargetParams};

/// Parameters of face extraction.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FaceParams {
    /// Model points within this distance of the point are searched for the face, metres. Default 0.6.
    pub radius_m: f64,
    /// Inlier distance to the face plane, metres. Default 0.003.
    pub distance_m: f64,
    /// RANSAC hypotheses. Default 500.
    pub iterations: usize,
    /// RANSAC seed. Default 0.
    pub seed: u64,
    /// The face plane must be within this angle of the local normal, radians. Default 10 degrees.
    pub max_tilt_rad: f64,
    /// A point whose model normal is farther than this from the face's is not on the face, radians. Default 30 degrees.
    pub max_normal_rad: f64,
    /// Largest step between connected face points, metres. Default 0.01.
    pub link_m: f64,
    /// Fewest points of a face. Default 100.
    pub min_points: usize,
    /// Histogram bin of the face's edge search ([`half_density_extent`]), metres. Default 0.002
    /// (the model's point spacing).
    pub edge_bin_m: f64,
}

impl Default for FaceParams {
    fn default() -> Self {
        Self {
            radius_m: 0.6,
            distance_m: 0.003,
            iterations: 500,
            seed: 0,
            max_tilt_rad: 10f64.to_radians(),
            max_normal_rad: 30f64.to_radians(),
            link_m: 0.01,
            min_points: 100,
            edge_bin_m: 0.002,
        }
    }
}

/// 2D convex hull (Andrew's monotone chain), counter-clockwise, no (nearly) collinear points.
pub fn convex_hull(points: &[Point2<f64>]) -> Vec<Point2<f64>> {
    let mut p: Vec<Point2<f64>> = points.to_vec();
    p.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    p.dedup();
    if p.len() < 3 {
        return p;
    }
    // near-collinear points (rounding) are dropped: a tolerance relative to the extent squared
    let extent = (p[p.len() - 1] - p[0]).norm_squared().max(1e-300);
    let eps = 1e-12 * extent;
    let cross = |o: &Point2<f64>, a: &Point2<f64>, b: &Point2<f64>| (a - o).perp(&(b - o));
    let mut hull: Vec<Point2<f64>> = Vec::with_capacity(2 * p.len());
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &Point2<f64>>> =
            if pass == 0 { Box::new(p.iter()) } else { Box::new(p.iter().rev()) };
        for q in iter {
            while hull.len() >= start + 2 && cross(&hull[hull.len() - 2], &hull[hull.len() - 1], q) <= eps {
                hull.pop();
            }
            hull.push(*q);
        }
        hull.pop();
    }
    hull
}

/// Where a face ends along one axis: `proj` are its points' coordinates on that axis. A histogram of
/// `bin_m` bins; the interior level is the median count of the bins in the middle half (between the
/// 5th and 95th percentiles); each end is the outermost bin at or above half that level, moved out by
/// the covered fraction of the bin beyond it (count / interior level). `None` with fewer than 8 bins
/// or an empty interior.
pub fn half_density_extent(proj: &[f64], bin_m: f64) -> Option<(f64, f64)> {
    let mut x: Vec<f64> = proj.iter().copied().filter(|v| v.is_finite()).collect();
    if x.len() < 16 || !(bin_m > 0.0) {
        return None;
    }
    x.sort_by(f64::total_cmp);
    let (lo, hi) = (x[0], x[x.len() - 1]);
    let bins = ((hi - lo) / bin_m).ceil() as usize + 1;
    if bins < 8 {
        return None;
    }
    let mut counts = vec![0usize; bins];
    for v in &x {
        counts[(((v - lo) / bin_m) as usize).min(bins - 1)] += 1;
    }
    let q = |f: f64| x[((x.len() - 1) as f64 * f) as usize];
    let (a, b) = (q(0.05), q(0.95));
    let (m0, m1) = (a + (b - a) * 0.25, a + (b - a) * 0.75);
    let mut interior: Vec<usize> = (0..bins)
        .filter(|&i| {
            let c = lo + (i as f64 + 0.5) * bin_m;
            c >= m0 && c <= m1
        })
        .map(|i| counts[i])
        .collect();
    if interior.is_empty() {
        return None;
    }
    interior.sort_unstable();
    let level = interior[interior.len() / 2] as f64;
    if level <= 0.0 {
        return None;
    }
    let full = |i: usize| counts[i] as f64 >= level / 2.0;
    let first = (0..bins).find(|&i| full(i))?;
    let last = (0..bins).rev().find(|&i| full(i))?;
    let frac = |i: Option<usize>| i.map_or(0.0, |i| (counts[i] as f64 / level).min(1.0));
    let left = lo + first as f64 * bin_m - bin_m * frac(first.checked_sub(1));
    let right = lo + (last + 1) as f64 * bin_m + bin_m * frac((last + 1 < bins).then_some(last + 1));
    Some((left, right))
}

/// The minimum-area rectangle enclosing a convex hull: its 4 corners (counter-clockwise).
pub fn min_area_rectangle(hull: &[Point2<f64>]) -> Option<[Point2<f64>; 4]> {
    if hull.len() < 3 {
        return None;
    }
    let mut best: Option<(f64, [Point2<f64>; 4])> = None;
    for i in 0..hull.len() {
        let e = hull[(i + 1) % hull.len()] - hull[i];
        if e.norm() < 1e-12 {
            continue;
        }
        let u = e.normalize();
        let v = Vector2::new(-u.y, u.x);
        let (mut lo_u, mut hi_u, mut lo_v, mut hi_v) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for p in hull {
            let (a, b) = (p.coords.dot(&u), p.coords.dot(&v));
            (lo_u, hi_u, lo_v, hi_v) = (lo_u.min(a), hi_u.max(a), lo_v.min(b), hi_v.max(b));
        }
        let area = (hi_u - lo_u) * (hi_v - lo_v);
        if best.as_ref().is_none_or(|(a, _)| area < *a) {
            let corner = |a: f64, b: f64| Point2::from(u * a + v * b);
            best = Some((area, [corner(lo_u, lo_v), corner(hi_u, lo_v), corner(hi_u, hi_v), corner(lo_u, hi_v)]));
        }
    }
    best.map(|(_, c)| c)
}

/// The rectangle with `hull_rect`'s axes whose sides are the half-density edges of `flat`; `None`
/// when an axis has too few bins (then the hull's rectangle is used).
fn density_rectangle(flat: &[Point2<f64>], hull_rect: &[Point2<f64>; 4], bin_m: f64) -> Option<[Point2<f64>; 4]> {
    let u = (hull_rect[1] - hull_rect[0]).try_normalize(1e-12)?;
    let v = Vector2::new(-u.y, u.x);
    let along = |d: &Vector2<f64>| flat.iter().map(|p| p.coords.dot(d)).collect::<Vec<f64>>();
    let (lu, hu) = half_density_extent(&along(&u), bin_m)?;
    let (lv, hv) = half_density_extent(&along(&v), bin_m)?;
    let corner = |a: f64, b: f64| Point2::from(u * a + v * b);
    Some([corner(lu, lv), corner(hu, lv), corner(hu, hv), corner(lu, hv)])
}

impl SurfaceModel<'_> {
    /// The centre of the planar face nearest `p` (module docs).
    ///
    /// # Errors
    /// [`Error::Invalid`] when `p` is far from the model or no face of `min_points` is found there.
    pub fn face_centre(&self, p: &Point3<f64>, params: &TargetParams) -> Result<SurfaceTarget> {
        let fp = &params.face;
        let what = || format!("face-centre@{:.4},{:.4},{:.4}", p.x, p.y, p.z);
        let local = self.local_plane(p, params)?;
        let near: Vec<usize> = self
            .index
            .within(&local.point.cast::<f32>(), fp.radius_m as f32)
            .iter()
            .map(|n| n.index as usize)
            .collect();
        let pts: Vec<Point3<f32>> = near.iter().map(|&i| self.cloud.points[i]).collect();
        let ransac = PlaneParams {
            distance_m: fp.distance_m,
            iterations: fp.iterations,
            seed: fp.seed,
            max_tilt_rad: Some(fp.max_tilt_rad),
            up: local.normal.into(),
        };
        let (mut normal, mut offset) = (local.normal, -local.normal.dot(&local.point.coords));
        if let Ok(fit) = fit_plane_ransac(&pts, &ransac)
            && fit.signed_distance(&local.point).abs() <= fp.distance_m
        {
            (normal, offset) = (fit.normal, fit.offset_m);
        }
        let face = self.grow_face(&near, &normal, offset, &local.point, fp);
        if face.len() < fp.min_points {
            return Err(Error::invalid(
                what(),
                format!("no planar face there ({} points < {})", face.len(), fp.min_points),
            ));
        }
        let face_pts: Vec<Point3<f64>> = face.iter().map(|&i| self.cloud.points[i].cast::<f64>()).collect();
        let n = face_pts.len() as f64;
        let c = face_pts.iter().map(|x| x.coords).sum::<Vector3<f64>>() / n;
        let cov =
            face_pts.iter().fold(nalgebra::Matrix3::zeros(), |m, x| m + (x.coords - c) * (x.coords - c).transpose())
                / n;
        let eig = nalgebra::SymmetricEigen::new(cov);
        let k = eig.eigenvalues.imin();
        let mut refit = eig.eigenvectors.column(k).into_owned();
        if refit.dot(&local.normal) < 0.0 {
            refit = -refit;
        }
        let u = refit.cross(&if refit.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() }).normalize();
        let v = refit.cross(&u);
        let flat: Vec<Point2<f64>> =
            face_pts.iter().map(|x| Point2::new((x.coords - c).dot(&u), (x.coords - c).dot(&v))).collect();
        let hull_rect =
            min_area_rectangle(&convex_hull(&flat)).ok_or_else(|| Error::invalid(what(), "degenerate face"))?;
        let rect = density_rectangle(&flat, &hull_rect, fp.edge_bin_m).unwrap_or(hull_rect);
        let lift = |q: &Point2<f64>| Point3::from(c + u * q.x + v * q.y);
        let corners = rect.map(|q| lift(&q));
        let centre = Point3::from(corners.iter().map(|x| x.coords).sum::<Vector3<f64>>() / 4.0);
        Ok(SurfaceTarget {
            spec: TargetSpec::FaceCentre(*p),
            point: centre,
            normal: refit,
            axis: -refit,
            fit_rms_m: eig.eigenvalues[k].max(0.0).sqrt(),
            points: face.len(),
            corners: Some(corners),
            angle_to_tag_z_rad: None,
        })
    }

    /// The plane's inliers among `near` connected to `seed` (module docs, step 3).
    fn grow_face(
        &self,
        near: &[usize],
        normal: &Vector3<f64>,
        offset: f64,
        seed: &Point3<f64>,
        fp: &FaceParams,
    ) -> Vec<usize> {
        let cos_max = fp.max_normal_rad.cos();
        let on_plane = |i: usize| {
            let x = self.cloud.points[i].cast::<f64>();
            let close = (normal.dot(&x.coords) + offset).abs() <= fp.distance_m;
            let agrees = self.cloud.normals.as_ref().is_none_or(|ns| ns[i].cast::<f64>().dot(normal).abs() >= cos_max);
            close && agrees
        };
        let mut member = vec![false; self.cloud.len()];
        for &i in near {
            member[i] = on_plane(i);
        }
        let mut visited = vec![false; self.cloud.len()];
        let start = near.iter().copied().filter(|&i| member[i]).min_by(|&a, &b| {
            let d = |i: usize| (self.cloud.points[i].cast::<f64>() - seed).norm_squared();
            d(a).total_cmp(&d(b)).then(a.cmp(&b))
        });
        let Some(start) = start else { return Vec::new() };
        let (mut stack, mut face) = (vec![start], Vec::new());
        visited[start] = true;
        while let Some(i) = stack.pop() {
            face.push(i);
            for n in self.index.within(&self.cloud.points[i], fp.link_m as f32) {
                let j = n.index as usize;
                if member[j] && !visited[j] {
                    visited[j] = true;
                    stack.push(j);
                }
            }
        }
        face.sort_unstable();
        face
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_density_edges_ignore_stray_points_and_find_the_ends() {
        // a 2 mm grid of cell centres over [0, 0.4] x [0, 0.2], plus stray points 8 mm past one end
        let mut x = Vec::new();
        for i in 0..200 {
            for _ in 0..100 {
                x.push((i as f64 + 0.5) * 0.002);
            }
        }
        x.extend([-0.008, -0.0075, -0.006, 0.407]);
        let (l, r) = half_density_extent(&x, 0.002).expect("extent");
        assert!(l.abs() < 1.5e-3 && (r - 0.4).abs() < 1.5e-3, "{l} {r}");
        assert!(((l + r) / 2.0 - 0.2).abs() < 5e-4, "centre {}", (l + r) / 2.0);
        assert!(half_density_extent(&[0.0, 0.001, 0.002], 0.002).is_none());
    }

    #[test]
    fn min_area_rectangle_of_a_rotated_rectangle_is_itself() {
        let (a, b, angle) = (0.3, 0.1, 0.4_f64);
        let (c, s) = (angle.cos(), angle.sin());
        let mut pts = Vec::new();
        for i in 0..=30 {
            for j in 0..=10 {
                let (x, y) = (a * (i as f64 / 30.0 - 0.5), b * (j as f64 / 10.0 - 0.5));
                pts.push(Point2::new(1.0 + c * x - s * y, -2.0 + s * x + c * y));
            }
        }
        let hull = convex_hull(&pts);
        assert_eq!(hull.len(), 4, "{hull:?}");
        let r = min_area_rectangle(&hull).expect("rectangle");
        let centre = r.iter().map(|p| p.coords).sum::<Vector2<f64>>() / 4.0;
        assert!((centre - Vector2::new(1.0, -2.0)).norm() < 1e-12, "{centre:?}");
        let sides = [(r[1] - r[0]).norm(), (r[2] - r[1]).norm()];
        let (lo, hi) = (sides[0].min(sides[1]), sides[0].max(sides[1]));
        assert!((lo - b).abs() < 1e-12 && (hi - a).abs() < 1e-12, "{sides:?}");
    }
}
