//! `face-centre@x,y,z`: the centre of the planar face nearest a point (the paper's method).
//!
//! 1. The local plane at the point ([`SurfaceModel::snap`]) gives the face's approximate normal.
//! 2. RANSAC ([`fit_plane_ransac`], `up` = that normal, within `max_tilt_rad`) among the model points
//!    within `radius_m` of the point; when the point is not on the RANSAC plane (another parallel
//!    face dominates) the local plane is used instead.
//! 3. The face: the plane's inliers (within `distance_m`, model normal within `max_normal_rad` when
//!    the model has normals) connected to the point through steps of at most `link_m`; a
//!    least-squares refit on them, and again while the face grows (a plane from the local
//!    neighbourhood alone was 3 degrees off on a 30 cm face, and its band held a strip of it).
//! 4. In the plane, the rectangle's axes: for a face standing on the model's floor (known from
//!    fusion, [`SurfaceModel::with_floor`]; face within `max_tilt_rad` of vertical) the floor's line
//!    and the vertical; otherwise the minimum-area rectangle of the hull when it agrees within 1
//!    degree with the direction whose projections of the face are sharpest, else the latter
//!    ([`sharpest_axis`]: least entropy of the two histograms). The minimum-area rectangle of the
//!    hull, the textbook choice, turns with the outline: a face partly hidden by clutter or cut by
//!    the floor removal gave a rectangle turned 40 degrees (39 mm off on the reference box's side).
//! 5. The rectangle's sides are placed where the face's point density along each axis falls to half
//!    its interior level ([`half_density_extent`]): the hull itself reaches the few stray points
//!    fusion leaves past a box's edges (measured up to 8 mm on a simulated box), which moved the
//!    centre by 1.3 mm. A bottom side within `floor_gap_m` of the floor is moved onto it: fusion
//!    removes a band above the floor (10 mm by default), and with it the face's lowest part.
//!    The 4 corners, their centre.

use nalgebra::{Point2, Point3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::cluster::{DbscanParams, dbscan};
use crate::error::{Error, Result};
use crate::segment::{PlaneParams, fit_plane_ransac};
use crate::workpiece::target_spec::TargetSpec;
use crate::workpiece::targets::{SurfaceModel, SurfaceTarget, TargetParams, tilt_covariance};

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
    /// A standing face whose bottom side is at most this far above the floor ends on the floor,
    /// metres. Default 0.03 (fusion removes 10 mm above it; its edge is found 10-20 mm up).
    pub floor_gap_m: f64,
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
            floor_gap_m: 0.03,
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
    // linear binning (a value shares its weight between the two nearest bin centres): plain
    // binning of points on a lattice (the model's voxel grid) aliases, and the edge bins flicker
    let mut counts = vec![0f64; bins];
    for v in &x {
        add_linear(&mut counts, ((v - lo) / bin_m - 0.5).clamp(0.0, (bins - 1) as f64));
    }
    let q = |f: f64| x[((x.len() - 1) as f64 * f) as usize];
    let (a, b) = (q(0.05), q(0.95));
    let (m0, m1) = (a + (b - a) * 0.25, a + (b - a) * 0.75);
    let mut interior: Vec<f64> = (0..bins)
        .filter(|&i| {
            let c = lo + (i as f64 + 0.5) * bin_m;
            c >= m0 && c <= m1
        })
        .map(|i| counts[i])
        .collect();
    if interior.is_empty() {
        return None;
    }
    interior.sort_by(f64::total_cmp);
    let level = interior[interior.len() / 2];
    if level <= 0.0 {
        return None;
    }
    let full = |i: usize| counts[i] >= level / 2.0;
    let first = (0..bins).find(|&i| full(i))?;
    let last = (0..bins).rev().find(|&i| full(i))?;
    let frac = |i: Option<usize>| i.map_or(0.0, |i| (counts[i] / level).min(1.0));
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

/// Adds a unit weight at fractional bin position `at` (>= 0) to `weights`, shared between bins
/// `floor(at)` and the next in proportion to the distance (linear binning); the next bin is touched
/// only when `at` is not an integer.
fn add_linear(weights: &mut [f64], at: f64) {
    let i = at as usize;
    let frac = at - i as f64;
    weights[i] += 1.0 - frac;
    if frac > 0.0 {
        weights[i + 1] += frac;
    }
}

/// Shannon entropy of the histogram of `x` (bins of `bin_m`, linear binning: a value shares its
/// weight between the two nearest bins, so the entropy varies smoothly as the values move): small
/// when the values pile up.
fn histogram_entropy(x: impl Iterator<Item = f64> + Clone, bin_m: f64) -> f64 {
    let lo = x.clone().fold(f64::INFINITY, f64::min);
    let mut weights: Vec<f64> = Vec::new();
    let mut total = 0.0;
    for v in x {
        let at = (v - lo) / bin_m;
        if at as usize + 1 >= weights.len() {
            weights.resize(at as usize + 2, 0.0);
        }
        add_linear(&mut weights, at);
        total += 1.0;
    }
    weights.iter().filter(|&&w| w > 0.0).map(|&w| w / total).map(|p| -p * p.ln()).sum()
}

/// The in-plane direction (mod 90 degrees) along which a rectangular face's outline is sharpest:
/// the axis `u` minimising the entropy of the histograms of the points projected on `u` and on its
/// perpendicular (a 0.5 degree sweep, then 0.02 degree steps around the best; at most 20 000 points,
/// evenly strided). Aligned with the sides, both histograms are boxes with sharp ends; turned, their
/// ends ramp and spread. Robust to a missing corner or a cut side, unlike the minimum-area rectangle.
pub fn sharpest_axis(flat: &[Point2<f64>], bin_m: f64) -> Vector2<f64> {
    let stride = flat.len().div_ceil(20_000).max(1);
    let pts: Vec<Point2<f64>> = flat.iter().step_by(stride).copied().collect();
    let score = |angle: f64| {
        let (u, v) = (Vector2::new(angle.cos(), angle.sin()), Vector2::new(-angle.sin(), angle.cos()));
        histogram_entropy(pts.iter().map(|p| p.coords.dot(&u)), bin_m)
            + histogram_entropy(pts.iter().map(|p| p.coords.dot(&v)), bin_m)
    };
    let best = |angles: &mut dyn Iterator<Item = f64>| {
        angles.map(|a| (score(a), a)).min_by(|x, y| x.0.total_cmp(&y.0)).map_or(0.0, |(_, a)| a)
    };
    let coarse = best(&mut (0..180).map(|i| (i as f64 * 0.5).to_radians()));
    let fine = best(&mut (-25..=25).map(|i| coarse + (i as f64 * 0.02).to_radians()));
    Vector2::new(fine.cos(), fine.sin())
}

/// The face's rectangle axis: the minimum-area rectangle's when it is within 1 degree of the
/// sharpest axis (mod 90 degrees; the hull's extreme points on straight sides fix it more finely:
/// top-centre of the reference box 0.45 mm vs 1.16 mm), else the sharpest axis (the outline is
/// not a clean rectangle).
fn rectangle_axis(flat: &[Point2<f64>], bin_m: f64) -> Vector2<f64> {
    let sharp = sharpest_axis(flat, bin_m);
    let hull_axis = min_area_rectangle(&convex_hull(flat)).and_then(|r| (r[1] - r[0]).try_normalize(1e-12));
    match hull_axis {
        Some(h) => {
            let turn = (h.perp(&sharp).atan2(h.dot(&sharp))).to_degrees().rem_euclid(90.0);
            if turn.min(90.0 - turn) < 1.0 { h } else { sharp }
        }
        None => sharp,
    }
}

/// The rectangle with axes `u` and its perpendicular whose sides are the half-density edges of
/// `flat`, as (low u, high u, low v, high v); `None` when an axis has too few bins.
fn density_extents(flat: &[Point2<f64>], u: &Vector2<f64>, bin_m: f64) -> Option<[f64; 4]> {
    let v = Vector2::new(-u.y, u.x);
    let along = |d: &Vector2<f64>| flat.iter().map(|p| p.coords.dot(d)).collect::<Vec<f64>>();
    let (lu, hu) = half_density_extent(&along(u), bin_m)?;
    let (lv, hv) = half_density_extent(&along(&v), bin_m)?;
    Some([lu, hu, lv, hv])
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
        // grow the face on the plane, refit the plane on the face, until the face stops growing: a
        // plane from a small neighbourhood (the local fallback) is off by a few degrees, and its band
        // holds a strip of the face only
        let (mut face, mut fit, mut largest) = (Vec::new(), None, 0);
        for _ in 0..8 {
            let grown = self.grow_face(&near, &normal, offset, &local.point, fp)?;
            largest = largest.max(grown.len());
            if grown.len() < fp.min_points.max(3) || grown.len() <= face.len() {
                break;
            }
            let (c, n, rms) = self.plane_through(&grown, &local.normal);
            (normal, offset, face, fit) = (n, -n.dot(&c.coords), grown, Some((c, n, rms)));
        }
        let Some((c, refit, fit_rms_m)) = fit.filter(|_| face.len() >= fp.min_points) else {
            return Err(Error::invalid(what(), format!("no planar face there ({largest} points < {})", fp.min_points)));
        };
        let c = c.coords;
        // the plane's frame: for a face standing on the floor, u along the floor and v up
        let floor = self.floor.filter(|f| f.normal.dot(&refit).abs() < fp.max_tilt_rad.sin());
        let u = match &floor {
            Some(f) => f.normal.cross(&refit).normalize(),
            None => refit.cross(&if refit.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() }).normalize(),
        };
        let v = refit.cross(&u);
        let flat: Vec<Point2<f64>> = face
            .iter()
            .map(|&i| self.cloud.points[i].coords.cast::<f64>() - c)
            .map(|d| Point2::new(d.dot(&u), d.dot(&v)))
            .collect();
        let axis = if floor.is_some() { Vector2::x() } else { rectangle_axis(&flat, fp.edge_bin_m) };
        let perp = Vector2::new(-axis.y, axis.x);
        let extents = density_extents(&flat, &axis, fp.edge_bin_m).or_else(|| {
            // too few bins for densities: the hull's extents along the axis
            let hull = convex_hull(&flat);
            let range = |d: &Vector2<f64>| {
                hull.iter().map(|p| p.coords.dot(d)).fold((f64::MAX, f64::MIN), |(a, b), x| (a.min(x), b.max(x)))
            };
            let ((lu, hu), (lv, hv)) = (range(&axis), range(&perp));
            (hu > lu && hv > lv).then_some([lu, hu, lv, hv])
        });
        let [lu, hu, mut lv, hv] = extents.ok_or_else(|| Error::invalid(what(), "degenerate face"))?;
        if let Some(f) = &floor {
            // v is up (f·v > 0 for the frame above); the floor's line in the face plane is v = b
            let b = -f.height(&Point3::from(c)) / f.normal.dot(&v);
            if b.is_finite() && lv >= b && lv - b <= fp.floor_gap_m {
                lv = b;
            }
        }
        let corner = |a: f64, b: f64| axis * a + perp * b;
        let rect = [corner(lu, lv), corner(hu, lv), corner(hu, hv), corner(lu, hv)];
        let corners = rect.map(|q| Point3::from(c + u * q.x + v * q.y));
        let centre = Point3::from(corners.iter().map(|x| x.coords).sum::<Vector3<f64>>() / 4.0);
        let second = flat.iter().fold(nalgebra::Matrix3::zeros(), |m, q| {
            let d = u * q.x + v * q.y;
            m + d * d.transpose()
        }) / flat.len().max(1) as f64;
        let normal_covariance = tilt_covariance(&refit, &second, fit_rms_m);
        Ok(SurfaceTarget {
            spec: TargetSpec::FaceCentre(*p),
            point: centre,
            normal: refit,
            axis: -refit,
            fit_rms_m,
            points: face.len(),
            normal_covariance,
            corners: Some(corners),
            angle_to_tag_z_rad: None,
        })
    }

    /// Least-squares plane through the model points `idx`: centroid, unit normal on `side`'s side,
    /// rms distance.
    fn plane_through(&self, idx: &[usize], side: &Vector3<f64>) -> (Point3<f64>, Vector3<f64>, f64) {
        let pts: Vec<Vector3<f64>> = idx.iter().map(|&i| self.cloud.points[i].coords.cast::<f64>()).collect();
        let c = pts.iter().sum::<Vector3<f64>>() / pts.len() as f64;
        let cov =
            pts.iter().fold(nalgebra::Matrix3::zeros(), |m, x| m + (x - c) * (x - c).transpose()) / pts.len() as f64;
        let eig = nalgebra::SymmetricEigen::new(cov);
        let k = eig.eigenvalues.imin();
        let mut n = eig.eigenvectors.column(k).into_owned();
        if n.dot(side) < 0.0 {
            n = -n;
        }
        (Point3::from(c), n, eig.eigenvalues[k].max(0.0).sqrt())
    }

    /// The plane's inliers among `near` connected to `seed` (module docs, step 3): of the inliers'
    /// clusters at `link_m` (DBSCAN with every point core: the connected parts), the one holding the
    /// inlier nearest `seed`.
    fn grow_face(
        &self,
        near: &[usize],
        normal: &Vector3<f64>,
        offset: f64,
        seed: &Point3<f64>,
        fp: &FaceParams,
    ) -> Result<Vec<usize>> {
        let cos_max = fp.max_normal_rad.cos();
        let on_plane = |i: usize| {
            let x = self.cloud.points[i].cast::<f64>();
            let close = (normal.dot(&x.coords) + offset).abs() <= fp.distance_m;
            let agrees = self.cloud.normals.as_ref().is_none_or(|ns| ns[i].cast::<f64>().dot(normal).abs() >= cos_max);
            close && agrees
        };
        let members: Vec<usize> = near.iter().copied().filter(|&i| on_plane(i)).collect();
        let start = (0..members.len()).min_by(|&a, &b| {
            let d = |k: usize| (self.cloud.points[members[k]].cast::<f64>() - seed).norm_squared();
            d(a).total_cmp(&d(b)).then(members[a].cmp(&members[b]))
        });
        let Some(start) = start else { return Ok(Vec::new()) };
        let points: Vec<Point3<f32>> = members.iter().map(|&i| self.cloud.points[i]).collect();
        let parts = dbscan(&points, &DbscanParams { eps_m: fp.link_m, min_points: 1 })?;
        let part = parts.labels[start];
        let mut face: Vec<usize> =
            members.iter().zip(&parts.labels).filter(|&(_, &l)| l == part).map(|(&i, _)| i).collect();
        face.sort_unstable();
        Ok(face)
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
    fn sharpest_axis_finds_the_sides_of_a_rectangle_with_a_corner_missing() {
        // a 0.48 x 0.28 m face on a 2 mm grid turned by 23 degrees, jittered by up to 0.5 mm, with a
        // 0.2 x 0.12 m corner hidden (clutter) and its lowest 15 mm cut (floor removal): the
        // minimum-area rectangle of such an outline turns with it
        let (angle, mut seed) = (23f64.to_radians(), 12345u64);
        let mut jitter = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((seed >> 33) as f64 / (1u64 << 31) as f64 - 0.5) * 0.001
        };
        let (c, s) = (angle.cos(), angle.sin());
        let mut pts = Vec::new();
        for i in 0..240 {
            for j in 8..140 {
                let (x, y) = (i as f64 * 0.002, j as f64 * 0.002);
                if x > 0.28 && y < 0.12 {
                    continue;
                }
                let (x, y) = (x + jitter(), y + jitter());
                pts.push(Point2::new(c * x - s * y, s * x + c * y));
            }
        }
        let u = sharpest_axis(&pts, 0.002);
        let found = u.y.atan2(u.x).to_degrees().rem_euclid(90.0);
        assert!((found - 23.0).abs() < 0.1, "axis at {found} deg, want 23");
        let hull = convex_hull(&pts);
        assert!(hull.len() >= 5, "the outline is not a rectangle: {} hull points", hull.len());
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
