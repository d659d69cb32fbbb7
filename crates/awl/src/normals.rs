//! Surface normals from local neighbourhoods, and their orientation toward viewpoints.
//!
//! Input: positions (metres, any frame); neighbourhoods from one all-points k-NN pass (`spatial`).
//! Output, per point: an unoriented unit normal (the direction of least variance of the
//! neighbourhood, Open3D's `EstimateNormals` with `KDTreeSearchParamHybrid`) and the surface
//! variation λ_min / (λ0 + λ1 + λ2) of the neighbourhood covariance (PCL's and Open3D's
//! "curvature": 0 on a plane, at most 1/3). The orientation functions then flip each normal toward
//! the camera that saw the point. Parallel over points; the output does not depend on the number
//! of rayon threads.

use std::f64::consts::PI;

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::spatial::knn_map;

/// Neighbourhoods whose middle covariance eigenvalue is below this fraction of the trace are
/// treated as collinear: the normal is undefined there (see [`NormalsResult`]).
pub const COLLINEAR_RATIO: f64 = 1e-6;

/// How each point's neighbourhood is chosen.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct NormalParams {
    /// At most this many nearest points, the point itself included (default 20, at least 3).
    pub neighbors: usize,
    /// When set, only those of the `neighbors` nearest points within this distance, metres
    /// (default 0.01: Open3D's hybrid search); `false` keeps all `neighbors` points.
    #[serde(with = "crate::off")]
    #[schemars(with = "Option<f64>")]
    pub radius_m: Option<f64>,
}

impl Default for NormalParams {
    fn default() -> Self {
        Self { neighbors: 20, radius_m: Some(0.01) }
    }
}

impl NormalParams {
    /// Checks the parameters.
    ///
    /// # Errors
    /// [`Error::Invalid`] when `neighbors < 3` or `radius_m` is not a positive finite number.
    pub fn validate(&self) -> Result<()> {
        if self.neighbors < 3 {
            return Err(Error::invalid("normals.neighbors", format!("{} < 3: a plane needs 3 points", self.neighbors)));
        }
        if let Some(r) = self.radius_m
            && !(r.is_finite() && r > 0.0)
        {
            return Err(Error::invalid("normals.radius_m", format!("{r} is not a positive distance")));
        }
        Ok(())
    }
}

/// Normals and surface variation, one entry per input point.
///
/// A point is *degenerate* when its neighbourhood has fewer than 3 points, all its neighbours
/// coincide, or they are collinear ([`COLLINEAR_RATIO`]). A degenerate point gets the zero vector
/// as normal and NaN as curvature, so no made-up direction leaks into later stages; filter with
/// [`NormalsResult::valid_indices`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct NormalsResult {
    /// Unoriented unit normals (zero for degenerate points).
    pub normals: Vec<Vector3<f32>>,
    /// Surface variation λ_min / (λ0 + λ1 + λ2), in [0, 1/3] (NaN for degenerate points).
    pub curvature: Vec<f32>,
    /// Number of degenerate points.
    pub degenerate: usize,
}

impl NormalsResult {
    /// True when point `i` got a normal (false for degenerate points and indices out of range).
    pub fn is_valid(&self, i: usize) -> bool {
        self.curvature.get(i).is_some_and(|c| !c.is_nan())
    }

    /// Indices of the points that got a normal, ascending.
    pub fn valid_indices(&self) -> Vec<usize> {
        (0..self.curvature.len()).filter(|&i| self.is_valid(i)).collect()
    }
}

/// Estimates one unoriented normal per point by PCA of its neighbourhood.
///
/// The neighbourhood is the `params.neighbors` nearest points (the point included), restricted to
/// `params.radius_m` when set. Its covariance about its centroid is computed in f64 and the normal
/// is the eigenvector of the smallest eigenvalue, from a closed-form 3x3 solver that stays accurate
/// on planar, linear and isotropic neighbourhoods (Eberly's, as in Open3D's `FastEigen3x3`).
///
/// # Errors
/// [`Error::Invalid`] for bad parameters or a non-finite point.
pub fn estimate(points: &[Point3<f32>], params: &NormalParams) -> Result<NormalsResult> {
    params.validate()?;
    let r2 = params.radius_m.map_or(f32::INFINITY, |r| (r * r) as f32);
    let fits = knn_map(points, params.neighbors, |i, neighbors| {
        let count = neighbors.iter().take_while(|n| n.dist_sq <= r2).count();
        let fit =
            covariance(points, &points[i], neighbors[..count].iter().map(|n| n.index as usize)).and_then(plane_of);
        fit.map_or(([0.0; 3], f32::NAN), |(n, c)| (n.cast::<f32>().into(), c as f32))
    })?;
    let (normals, curvature): (Vec<Vector3<f32>>, Vec<f32>) =
        fits.into_iter().map(|(n, c)| (Vector3::from(n), c)).unzip();
    let degenerate = curvature.iter().filter(|c| c.is_nan()).count();
    Ok(NormalsResult { normals, curvature, degenerate })
}

/// Flips every normal so that `n · (viewpoint - p) >= 0`: for a single camera whose centre is
/// `viewpoint`, in the points' frame. Zero normals stay zero.
///
/// # Errors
/// [`Error::Invalid`] when `normals` and `points` differ in length.
pub fn orient_towards(points: &[Point3<f32>], normals: &mut [Vector3<f32>], viewpoint: &Point3<f32>) -> Result<()> {
    check_len("orient_towards", points.len(), normals.len(), "normals")?;
    normals.par_iter_mut().zip(points.par_iter()).with_min_len(4096).for_each(|(n, p)| flip_toward(n, p, viewpoint));
    Ok(())
}

/// Like [`orient_towards`] for a cloud merged from several views: point `i` is flipped toward
/// `viewpoints[view_of_point[i]]`, the centre of the camera that saw it (points' frame).
///
/// # Errors
/// [`Error::Invalid`] when the slices differ in length or a view index is out of range.
pub fn orient_towards_views(
    points: &[Point3<f32>],
    normals: &mut [Vector3<f32>],
    view_of_point: &[u32],
    viewpoints: &[Point3<f32>],
) -> Result<()> {
    check_len("orient_towards_views", points.len(), normals.len(), "normals")?;
    check_len("orient_towards_views", points.len(), view_of_point.len(), "view indices")?;
    if let Some(i) = view_of_point.iter().position(|&v| v as usize >= viewpoints.len()) {
        let msg = format!("point {i} names view {} of {}", view_of_point[i], viewpoints.len());
        return Err(Error::invalid("orient_towards_views", msg));
    }
    normals
        .par_iter_mut()
        .zip(points.par_iter().zip(view_of_point.par_iter()))
        .with_min_len(4096)
        .for_each(|(n, (p, &v))| flip_toward(n, p, &viewpoints[v as usize]));
    Ok(())
}

/// The cloud with normals estimated (unless it has them), oriented toward `viewpoint` when given,
/// and without the points whose normal is undefined (see [`NormalsResult`]).
///
/// # Errors
/// [`Error::Invalid`] for bad parameters or a non-finite cloud.
pub fn with_normals(cloud: &PointCloud, params: &NormalParams, viewpoint: Option<Point3<f32>>) -> Result<PointCloud> {
    if cloud.normals.is_some() {
        return Ok(cloud.clone());
    }
    let mut result = estimate(&cloud.points, params)?;
    if let Some(v) = viewpoint {
        orient_towards(&cloud.points, &mut result.normals, &v)?;
    }
    let keep = result.valid_indices();
    let mut out = cloud.clone();
    out.normals = Some(result.normals);
    Ok(out.select(&keep))
}

fn check_len(what: &str, points: usize, other: usize, name: &str) -> Result<()> {
    if points == other { Ok(()) } else { Err(Error::invalid(what, format!("{other} {name} for {points} points"))) }
}

fn flip_toward(n: &mut Vector3<f32>, p: &Point3<f32>, viewpoint: &Point3<f32>) {
    if n.dot(&(viewpoint - p)) < 0.0 {
        *n = -*n;
    }
}

/// A symmetric 3x3 matrix: the upper triangle, row by row.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Sym3 {
    pub(crate) xx: f64,
    pub(crate) xy: f64,
    pub(crate) xz: f64,
    pub(crate) yy: f64,
    pub(crate) yz: f64,
    pub(crate) zz: f64,
}

impl Sym3 {
    /// Adds `w d dᵀ`.
    pub(crate) fn add_outer(&mut self, d: &Vector3<f64>, w: f64) {
        let (x, y, z) = (d.x * w, d.y * w, d.z * w);
        self.xx += x * d.x;
        self.xy += x * d.y;
        self.xz += x * d.z;
        self.yy += y * d.y;
        self.yz += y * d.z;
        self.zz += z * d.z;
    }

    fn trace(&self) -> f64 {
        self.xx + self.yy + self.zz
    }

    fn scaled(&self, s: f64) -> Self {
        Self { xx: self.xx * s, xy: self.xy * s, xz: self.xz * s, yy: self.yy * s, yz: self.yz * s, zz: self.zz * s }
    }

    fn mul(&self, v: &Vector3<f64>) -> Vector3<f64> {
        Vector3::new(
            self.xx * v.x + self.xy * v.y + self.xz * v.z,
            self.xy * v.x + self.yy * v.y + self.yz * v.z,
            self.xz * v.x + self.yz * v.y + self.zz * v.z,
        )
    }
}

/// Covariance (divided by the count) of the points at `indices` about their centroid, in f64;
/// `None` for fewer than 3 points. One pass: moments of the offsets from `query` (a point of the
/// neighbourhood, so the offsets are small and the shift loses nothing in f64).
pub(crate) fn covariance(
    points: &[Point3<f32>],
    query: &Point3<f32>,
    indices: impl Iterator<Item = usize>,
) -> Option<Sym3> {
    covariance_and_mean(points, query, indices).map(|(cov, _)| cov)
}

/// [`covariance`] and the mean of the points.
pub(crate) fn covariance_and_mean(
    points: &[Point3<f32>],
    query: &Point3<f32>,
    indices: impl Iterator<Item = usize>,
) -> Option<(Sym3, Point3<f64>)> {
    let q = query.coords.cast::<f64>();
    let (mut sum, mut second, mut count) = (Vector3::<f64>::zeros(), Sym3::default(), 0usize);
    for i in indices {
        let d = points[i].coords.cast::<f64>() - q;
        sum += d;
        second.add_outer(&d, 1.0);
        count += 1;
    }
    if count < 3 {
        return None;
    }
    let inv = 1.0 / count as f64;
    let mean = sum * inv;
    let mut cov = second.scaled(inv);
    cov.add_outer(&mean, -1.0);
    Some((cov, Point3::from(q + mean)))
}

/// Unit normal and surface variation of a neighbourhood covariance; `None` when it is zero,
/// collinear or not finite.
pub(crate) fn plane_of(cov: Sym3) -> Option<(Vector3<f64>, f64)> {
    let (values, normal) = smallest_eigen(&cov)?;
    let trace = cov.trace();
    if values[1].is_nan() || values[1] <= COLLINEAR_RATIO * trace {
        return None;
    }
    Some((normal, (values[0].max(0.0) / trace).min(1.0 / 3.0)))
}

/// Eigenvalues (ascending) of a symmetric 3x3 matrix and a unit eigenvector of the smallest one,
/// or `None` for a zero or non-finite matrix.
///
/// Closed form after D. Eberly, "A Robust Eigensolver for 3x3 Symmetric Matrices" (Geometric
/// Tools, 2014), the solver behind Open3D's `FastEigen3x3`: the matrix is scaled by its largest
/// entry, the eigenvalues come from the trigonometric solution of the characteristic cubic, and
/// the eigenvector of the better separated extreme eigenvalue is computed first from cross products
/// of the rows of `A - λI`, so repeated eigenvalues (planes, lines, spheres) stay well defined.
pub(crate) fn smallest_eigen(a: &Sym3) -> Option<([f64; 3], Vector3<f64>)> {
    let max_abs = [a.xx, a.xy, a.xz, a.yy, a.yz, a.zz].iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if !(max_abs > 0.0 && max_abs.is_finite()) {
        return None;
    }
    let s = a.scaled(1.0 / max_abs);
    let off = s.xy * s.xy + s.xz * s.xz + s.yz * s.yz;
    let (values, vector) = if off > 0.0 {
        let q = s.trace() / 3.0;
        let (b00, b11, b22) = (s.xx - q, s.yy - q, s.zz - q);
        let p = ((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * off) / 6.0).sqrt();
        let c00 = b11 * b22 - s.yz * s.yz;
        let c01 = s.xy * b22 - s.yz * s.xz;
        let c02 = s.xy * s.yz - b11 * s.xz;
        let half_det = (0.5 * (b00 * c00 - s.xy * c01 + s.xz * c02) / (p * p * p)).clamp(-1.0, 1.0);
        let angle = half_det.acos() / 3.0;
        let beta2 = 2.0 * angle.cos();
        let beta0 = 2.0 * (angle + 2.0 * PI / 3.0).cos();
        let beta1 = -(beta0 + beta2);
        let values = [q + p * beta0, q + p * beta1, q + p * beta2];
        let vector = if half_det >= 0.0 {
            // The largest eigenvalue is the better separated one: solve for it first.
            let v2 = eigenvector_from_rows(&s, values[2]);
            eigenvector_in_complement(&s, &v2, values[1]).cross(&v2)
        } else {
            eigenvector_from_rows(&s, values[0])
        };
        (values.map(|v| v * max_abs), vector)
    } else {
        let d = [s.xx, s.yy, s.zz];
        let min = (0..3).fold(0, |m, i| if d[i] < d[m] { i } else { m });
        let mut values = [a.xx, a.yy, a.zz];
        values.sort_by(f64::total_cmp);
        let mut vector = Vector3::zeros();
        vector[min] = 1.0;
        (values, vector)
    };
    let norm = vector.norm();
    (norm > 0.0 && norm.is_finite()).then(|| (values, vector / norm))
}

/// A unit eigenvector for the simple eigenvalue `value`: the largest cross product of two rows of
/// `A - value·I`.
fn eigenvector_from_rows(a: &Sym3, value: f64) -> Vector3<f64> {
    let r0 = Vector3::new(a.xx - value, a.xy, a.xz);
    let r1 = Vector3::new(a.xy, a.yy - value, a.yz);
    let r2 = Vector3::new(a.xz, a.yz, a.zz - value);
    let candidates = [r0.cross(&r1), r0.cross(&r2), r1.cross(&r2)];
    let best = candidates.iter().max_by(|x, y| x.norm_squared().total_cmp(&y.norm_squared())).copied();
    let v = best.unwrap_or_else(Vector3::zeros);
    let n = v.norm();
    if n > 0.0 { v / n } else { v }
}

/// A unit eigenvector for `value` orthogonal to the unit eigenvector `w` (Eberly's
/// `ComputeEigenvector1`: a 2x2 problem in the plane orthogonal to `w`).
fn eigenvector_in_complement(a: &Sym3, w: &Vector3<f64>, value: f64) -> Vector3<f64> {
    let u = if w.x.abs() > w.y.abs() {
        Vector3::new(-w.z, 0.0, w.x) / (w.x * w.x + w.z * w.z).sqrt()
    } else {
        Vector3::new(0.0, w.z, -w.y) / (w.y * w.y + w.z * w.z).sqrt()
    };
    let v = w.cross(&u);
    let (au, av) = (a.mul(&u), a.mul(&v));
    let (mut m00, mut m01, mut m11) = (u.dot(&au) - value, u.dot(&av), v.dot(&av) - value);
    let (abs00, abs01, abs11) = (m00.abs(), m01.abs(), m11.abs());
    if abs00 >= abs11 {
        if abs00.max(abs01) <= 0.0 {
            return u;
        }
        if abs00 >= abs01 {
            m01 /= m00;
            m00 = 1.0 / (1.0 + m01 * m01).sqrt();
            m01 *= m00;
        } else {
            m00 /= m01;
            m01 = 1.0 / (1.0 + m00 * m00).sqrt();
            m00 *= m01;
        }
        u * m01 - v * m00
    } else {
        if abs11.max(abs01) <= 0.0 {
            return u;
        }
        if abs11 >= abs01 {
            m01 /= m11;
            m11 = 1.0 / (1.0 + m01 * m01).sqrt();
            m01 *= m11;
        } else {
            m11 /= m01;
            m01 = 1.0 / (1.0 + m11 * m11).sqrt();
            m11 *= m01;
        }
        u * m11 - v * m01
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, Rotation3, SymmetricEigen};
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    /// Unoriented angle between two directions, degrees.
    fn angle_deg(a: &Vector3<f32>, b: &Vector3<f64>) -> f64 {
        let c = a.cast::<f64>().normalize().dot(&b.normalize()).abs().min(1.0);
        c.acos().to_degrees()
    }

    fn gauss(rng: &mut ChaCha8Rng) -> f64 {
        rng.sample(StandardNormal)
    }

    /// `n` points uniform on a 0.2 m square of the plane through (0.1, -0.2, 0.6) with unit normal
    /// `normal`, with Gaussian noise `sigma_m` along the normal.
    fn noisy_plane(n: usize, normal: &Vector3<f64>, sigma_m: f64, seed: u64) -> Vec<Point3<f32>> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let rot = Rotation3::rotation_between(&Vector3::z(), normal).expect("not antiparallel");
        let origin = Vector3::new(0.1, -0.2, 0.6);
        (0..n)
            .map(|_| {
                let local = Vector3::new(rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5, 0.0) * 0.2
                    + Vector3::z() * (sigma_m * gauss(&mut rng));
                Point3::from((rot * local + origin).cast::<f32>())
            })
            .collect()
    }

    const SPHERE_CENTER: Vector3<f64> = Vector3::new(0.05, 0.02, 0.7);

    /// `n` points uniform on a sphere of `radius_m` around [`SPHERE_CENTER`], radial noise `sigma_m`.
    fn noisy_sphere(n: usize, radius_m: f64, sigma_m: f64, seed: u64) -> Vec<Point3<f32>> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                let d = Vector3::new(gauss(&mut rng), gauss(&mut rng), gauss(&mut rng)).normalize();
                Point3::from((SPHERE_CENTER + d * (radius_m + sigma_m * gauss(&mut rng))).cast::<f32>())
            })
            .collect()
    }

    fn stats(errors: &[f64]) -> (f64, f64) {
        (errors.iter().sum::<f64>() / errors.len() as f64, errors.iter().fold(0.0, |m, &e| m.max(e)))
    }

    #[test]
    fn plane_normals_within_one_degree() {
        let normal = Vector3::new(0.3, -0.2, 1.0).normalize();
        let points = noisy_plane(5_000, &normal, 0.03e-3, 1);
        let result = estimate(&points, &NormalParams::default()).expect("normals");
        assert_eq!(result.degenerate, 0);
        let errors: Vec<f64> = result.normals.iter().map(|n| angle_deg(n, &normal)).collect();
        let (mean, max) = stats(&errors);
        println!(
            "plane, 5000 points on 0.2 m square, sigma 0.03 mm, k 20: angle error mean {mean:.3} deg, max {max:.3} deg"
        );
        assert!(max < 1.0, "max {max} deg");
        let (cmean, cmax) = stats(&result.curvature.iter().map(|&c| c as f64).collect::<Vec<_>>());
        println!("plane curvature: mean {cmean:.2e}, max {cmax:.2e}");
        assert!(result.normals.iter().all(|n| (n.norm() - 1.0).abs() < 1e-6));
    }

    #[test]
    fn sphere_normals_are_radial_and_orient_inward_or_outward() {
        let points = noisy_sphere(50_000, 0.2, 0.05e-3, 2);
        let mut result = estimate(&points, &NormalParams::default()).expect("normals");
        assert_eq!(result.degenerate, 0);
        let radial = |p: &Point3<f32>| p.coords.cast::<f64>() - SPHERE_CENTER;
        let errors: Vec<f64> = points.iter().zip(&result.normals).map(|(p, n)| angle_deg(n, &radial(p))).collect();
        let (mean, max) = stats(&errors);
        println!("sphere r 0.2 m, 50k points, sigma 0.05 mm, k 20: angle error mean {mean:.3} deg, max {max:.3} deg");
        assert!(max < 2.0, "max {max} deg");

        // Toward the centre: every normal points inward.
        let centre = Point3::from(SPHERE_CENTER.cast::<f32>());
        orient_towards(&points, &mut result.normals, &centre).expect("orient");
        assert!(points.iter().zip(&result.normals).all(|(p, n)| n.cast::<f64>().dot(&radial(p)) < 0.0));

        // Six cameras 1 m from the centre along ±x, ±y, ±z; each point was seen by the camera whose
        // axis is closest to its radial direction. Every normal ends up outward.
        let axes: Vec<Vector3<f32>> = (0..6).map(|i| Vector3::ith(i % 3, if i < 3 { 1.0 } else { -1.0 })).collect();
        let viewpoints: Vec<Point3<f32>> = axes.iter().map(|a| centre + a).collect();
        let view_of_point: Vec<u32> = points
            .iter()
            .map(|p| {
                let r = (p - centre).normalize();
                (0..6u32).max_by(|&a, &b| r.dot(&axes[a as usize]).total_cmp(&r.dot(&axes[b as usize]))).unwrap_or(0)
            })
            .collect();
        orient_towards_views(&points, &mut result.normals, &view_of_point, &viewpoints).expect("orient");
        assert!(points.iter().zip(&result.normals).all(|(p, n)| n.cast::<f64>().dot(&radial(p)) > 0.0));
        for ((p, n), &v) in points.iter().zip(&result.normals).zip(&view_of_point) {
            assert!(n.dot(&(viewpoints[v as usize] - p)) >= 0.0);
        }
        let bad = orient_towards_views(&points, &mut result.normals, &vec![6; points.len()], &viewpoints);
        assert!(bad.is_err());
        assert!(orient_towards(&points[1..], &mut result.normals, &centre).is_err());
    }

    #[test]
    fn curvature_is_zero_on_a_plane_and_large_at_a_corner() {
        // Three faces of a cube corner at the origin, 1 mm grid, 40 mm per side.
        let mut points = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                let (a, b) = (i as f32 * 1e-3, j as f32 * 1e-3);
                points.push(Point3::new(a, b, 0.0));
                if j > 0 {
                    points.push(Point3::new(0.0, a, b));
                }
                if i > 0 && j > 0 {
                    points.push(Point3::new(b, 0.0, a));
                }
            }
        }
        let result = estimate(&points, &NormalParams::default()).expect("normals");
        let corner = result.curvature[0];
        let far = points.iter().position(|p| (p - Point3::new(0.03, 0.03, 0.0)).norm() < 1e-6).expect("grid point");
        println!("curvature: corner {corner:.4}, plane {:.2e}", result.curvature[far]);
        assert!(corner > 0.1, "{corner}");
        assert!(result.curvature[far] < 1e-6, "{}", result.curvature[far]);
        assert!(angle_deg(&result.normals[far], &Vector3::z()) < 1e-3);
    }

    #[test]
    fn same_output_with_one_and_two_threads() {
        let points = noisy_sphere(5_000, 0.2, 0.5e-3, 3);
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
            pool.install(|| estimate(&points, &NormalParams::default()).expect("normals"))
        };
        let (one, two) = (run(1), run(2));
        let bits = |r: &NormalsResult| {
            let n = r.normals.iter().flat_map(|n| n.iter().map(|v| v.to_bits())).collect::<Vec<_>>();
            (n, r.curvature.iter().map(|c| c.to_bits()).collect::<Vec<_>>())
        };
        assert_eq!(bits(&one), bits(&two));
    }

    #[test]
    fn degenerate_inputs() {
        let empty = estimate(&[], &NormalParams::default()).expect("empty");
        assert!(empty.normals.is_empty() && empty.curvature.is_empty() && empty.degenerate == 0);

        // Two isolated points, a collinear run, a coincident triple.
        let mut points = vec![Point3::new(1.0, 0.0, 0.0), Point3::new(-1.0, 0.0, 0.0)];
        points.extend((0..10).map(|i| Point3::new(0.0, i as f32 * 1e-3, 0.0)));
        points.extend([Point3::new(0.0, 0.0, 0.5); 3]);
        let result = estimate(&points, &NormalParams::default()).expect("normals");
        assert_eq!(result.degenerate, points.len());
        assert!(result.normals.iter().all(|n| *n == Vector3::zeros()));
        assert!(result.valid_indices().is_empty() && !result.is_valid(0) && !result.is_valid(99));

        for params in [
            NormalParams { neighbors: 2, ..Default::default() },
            NormalParams { radius_m: Some(0.0), ..Default::default() },
            NormalParams { radius_m: Some(f64::NAN), ..Default::default() },
        ] {
            let err = estimate(&points, &params).expect_err("invalid params");
            assert!(matches!(err, Error::Invalid { .. }), "{err}");
        }
        assert!(estimate(&[Point3::new(0.0, f32::NAN, 0.0)], &NormalParams::default()).is_err());
        let json: NormalParams = serde_json::from_str(r#"{"neighbors": 30}"#).expect("json");
        assert_eq!(json, NormalParams { neighbors: 30, radius_m: Some(0.01) });
        assert!(serde_json::from_str::<NormalParams>(r#"{"neighbours": 30}"#).is_err());
    }

    fn sym(m: &Matrix3<f64>) -> Sym3 {
        Sym3 { xx: m[(0, 0)], xy: m[(0, 1)], xz: m[(0, 2)], yy: m[(1, 1)], yz: m[(1, 2)], zz: m[(2, 2)] }
    }

    #[test]
    fn eigen_solver_matches_nalgebra_including_degenerate_spectra() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let mut cases = Vec::new();
        let spectra = [
            [0.0, 1.0, 2.0],
            [0.0, 1.0, 1.0],
            [0.0, 0.0, 1.0],
            [1e-12, 1.0, 1.0],
            [1e-9, 1e-3, 1.0],
            [1.0, 1.0, 1.0 + 1e-9],
            [1.0, 2.0, 2.0],
            [3e-7, 2e-6, 2.1e-6],
        ];
        for _ in 0..300 {
            let axis = Vector3::new(gauss(&mut rng), gauss(&mut rng), gauss(&mut rng)).normalize();
            let rot = Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), rng.random::<f64>() * 3.0);
            let spectrum: [f64; 3] = if cases.len() < 8 * 30 {
                spectra[cases.len() % 8]
            } else {
                [rng.random(), rng.random(), rng.random()]
            };
            let d = Matrix3::from_diagonal(&Vector3::from(spectrum));
            let m = rot.matrix() * d * rot.matrix().transpose();
            cases.push((0.5 * (m + m.transpose()), spectrum));
        }
        cases.push((Matrix3::from_diagonal(&Vector3::new(2.0, 0.5, 1.0)), [2.0, 0.5, 1.0]));
        for (m, spectrum) in cases {
            let (values, v) = smallest_eigen(&sym(&m)).expect("non-zero");
            let scale = m.abs().max();
            let mut want = spectrum;
            want.sort_by(f64::total_cmp);
            for (got, want) in values.iter().zip(want) {
                // Nearly repeated eigenvalues are only split to ~sqrt(eps) by the trigonometric solution.
                assert!((got - want).abs() < 1e-7 * scale, "{values:?} vs {want:?}");
            }
            assert!((v.norm() - 1.0).abs() < 1e-12);
            let residual = (m * v - v * values[0]).norm();
            assert!(residual < 1e-7 * scale, "residual {residual} for {m}");
            let eig = SymmetricEigen::new(m);
            let imin = eig.eigenvalues.imin();
            if want[1] - want[0] > 1e-6 * scale {
                let reference = eig.eigenvectors.column(imin).into_owned();
                let angle = v.dot(&reference).abs().min(1.0).acos();
                assert!(angle < 1e-6, "angle {angle} for {m}");
            }
        }
        assert!(smallest_eigen(&Sym3::default()).is_none());
        assert!(smallest_eigen(&Sym3 { xx: f64::NAN, ..Default::default() }).is_none());
    }
}
