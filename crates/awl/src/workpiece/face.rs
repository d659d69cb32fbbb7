//! `face-centre@x,y,z`: the centre of the planar face nearest a point (the paper's method).
//!
//! 1. The local plane at the point ([`SurfaceModel::snap`]) gives the face's approximate normal.
//! 2. RANSAC ([`fit_plane_ransac`], `up` = that normal, within `max_tilt_rad`) among the model points
//!    within `radius_m` of the point; when the point is not on the RANSAC plane (another parallel
//!    face dominates) the local plane is used instead.
//! 3. The face: the plane's inliers (within `distance_m`, model normal within `max_normal_rad` when
//!    the model has normals) connected to the point through steps of at most `link_m`; a
//!    least-squares refit on them.
//! 4. In the plane: the 2D convex hull of the face, its minimum-area enclosing rectangle (rotating
//!    calipers over the hull edges), the 4 corners, their centre.

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
        let rect = min_area_rectangle(&convex_hull(&flat)).ok_or_else(|| Error::invalid(what(), "degenerate face"))?;
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
