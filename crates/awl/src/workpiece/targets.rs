//! Targets on the model: a picked point snapped onto the surface ([`SurfaceModel::snap`]) or the
//! centre of the planar face nearest a point ([`SurfaceModel::face_centre`], in `face.rs`), each
//! with its outward surface normal and the piercing axis.
//!
//! Snapping is an MLS-style projection: the model points within `radius_m` of the current estimate
//! (Gaussian weights, sigma = `radius_m / 2`) give a weighted least-squares plane; the picked point
//! is projected onto it, and the neighbourhood is re-centred there (3 rounds). The normal at the
//! placed point comes from a weighted quadric height field over the wider
//! `gentle_normal_radius_m` (fitted twice, the second time in the first one's frame):
//! - where the surface turns slowly (that quadric has no radius of curvature below
//!   `min_curvature_radius_m`), it is that quadric's normal: a quadric follows a slowly turning
//!   surface over the patch, and the wide patch averages the model's noise and wiggles out of the
//!   direction. A fixed radius, not one grown while the fit's residual stays low: across six
//!   simulated shells the residual rule stopped on the model's noise (flank normal 0.54 deg mean,
//!   0.92 max, against 0.20 / 0.37 at 30 mm).
//! - where it turns fast one way (a groove, a ridge, a fillet), a round patch either takes in shape
//!   a quadric cannot follow or, kept small, too few points: at the bottom of a groove on a dome the
//!   15 mm plane's normal was 1.3-1.8 deg off on the noiseless surface, as it was on the fused
//!   models. The normal is instead a quadric's over a patch narrow across the fold (the quadric's
//!   sharpest direction; Gaussian sigma `fold_across_sigma_m`) and long along it
//!   (`fold_along_sigma_m`): narrow, the change of curvature across biases it little; long, it
//!   still averages enough points. Where the curvature changes fast across the fold (the other
//!   simulator's groove: its rims lie 17 mm from the bottom), that quadric is still degrees off;
//!   a cubic over the same patch follows it, but on a gentler fold it picks up the model's
//!   sub-millimetre waviness (0.8 deg mean error against the quadric's 0.3 on awl's shells). So
//!   the cubic's normal is taken only when it departs from the quadric's by more than
//!   `fold_cubic_departure_rad`: on six fused shells they departed by at most 1.7 deg, at the other
//!   simulator's groove by 3.7.
//! - without a quadric (too few points), the plane over `normal_radius_m`.
//!
//! The normal's error ([`SurfaceTarget::normal_covariance`]) comes from the patch that gave it: a
//! model surface whose points scatter `s` (weighted rms) about the quadric fitted over the patch is
//! wavy by about that much at the patch's scale, and a patch `l` wide (weighted rms extent along a
//! tangent direction) tilts by about `s / l` that way. The 1-sigma tilt per tangent direction is
//! [`TILT_PER_SCATTER`] `* s / l`; a face centre's uses the face's plane residual and extents.
//!
//! Normals are oriented like the model's own normals there (the fuse pipeline orients them toward
//! the cameras that saw the surface, i.e. outward); a model without normals orients it away from
//! the model's centroid.

use nalgebra::{Isometry3, Matrix2, Matrix3, Point3, SMatrix, SVector, SymmetricEigen, Vector3};
use serde::{Deserialize, Serialize};

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::segment::FloorPlane;
use crate::smooth::{quadric_coefficients, quadric_normal, tangent_frame};
use crate::spatial::KdIndex;
use crate::workpiece::face::FaceParams;
use crate::workpiece::target_spec::TargetSpec;

/// A patch's normal tilts by this many times the scatter of its points about their fitted surface
/// over the patch's extent, 1-sigma per tangent direction (module docs). Measured on 600 targets on
/// the other simulator's three fused models, against their CAD: the error over `s / l` (`l` the
/// patch's radial rms extent) was at most 0.93-1.16 at the 95th percentile; with 0.35 per direction
/// (`l / sqrt(2)` each) the 2-D 95 % bound is 1.22 `s / l` (BENCHMARKS.md, "Normal bounds").
pub const TILT_PER_SCATTER: f64 = 0.35;

/// `exp(-|d|² ROUND_PATCH_INV_H2 / radius²)`: a round patch's Gaussian weights, sigma = radius / 2.
const ROUND_PATCH_INV_H2: f64 = 2.0;

/// A point at offset `d` in a fold's patch (frame `across`, `along`, normal `n`; Gaussian sigmas `s1`
/// across, `s2` along): its coordinates in sigmas (the height in across-sigmas) and its weight, or
/// `None` outside the patch (2 sigmas each way, 1 across-sigma off the tangent plane).
fn fold_coordinates(
    d: &Vector3<f64>,
    (across, along, n): (&Vector3<f64>, &Vector3<f64>, &Vector3<f64>),
    (s1, s2): (f64, f64),
) -> Option<(f64, f64, f64, f64)> {
    let (x, y, z) = (d.dot(across) / s1, d.dot(along) / s2, d.dot(n) / s1);
    (x.abs() <= 2.0 && y.abs() <= 2.0 && z.abs() <= 1.0).then(|| (x, y, z, (-0.5 * (x * x + y * y)).exp()))
}

/// The points a normal was fitted to: offsets from the target and weights, and whether a cubic
/// (not a quadric) height field gave it.
struct Patch {
    points: Vec<(Vector3<f64>, f64)>,
    cubic: bool,
}

/// The height field's terms at `(x, y)`: a quadric's 6, then a cubic's 4 more.
fn monomials(x: f64, y: f64) -> SVector<f64, 10> {
    SVector::<f64, 10>::from([1.0, x, y, x * x, x * y, y * y, x * x * x, x * x * y, x * y * y, y * y * y])
}

/// The covariance of a normal's tilt (rotation vector across `n`, rad²) from its patch: the height
/// field it was fitted with (a quadric or a cubic) over the patch in `n`'s frame gives the scatter
/// `s`, the patch's weighted second moment across `n` the extent `l` per direction
/// ([`TILT_PER_SCATTER`]). Infinite along a direction the patch does not extend in.
fn patch_tilt(patch: &Patch, n: &Vector3<f64>) -> Matrix3<f64> {
    let unbounded = Matrix3::from_diagonal_element(f64::INFINITY);
    let points = &patch.points;
    let terms = if patch.cubic { 10 } else { 6 };
    let sw: f64 = points.iter().map(|(_, w)| w).sum();
    if points.len() < 2 * terms || !(sw > 0.0) {
        return unbounded;
    }
    let (u, v) = tangent_frame(n);
    let (mut ata, mut atb) = (SMatrix::<f64, 10, 10>::zeros(), SVector::<f64, 10>::zeros());
    for (d, w) in points {
        let m = monomials(d.dot(&u), d.dot(&v));
        ata += m * m.transpose() * *w;
        atb += m * (w * d.dot(n));
    }
    // the unused cubic terms pinned to 0, and a tiny ridge: a patch too thin for the height field
    // still gives its plane's residual
    let ridge = 1e-12 * (0..10).map(|k| ata[(k, k)]).fold(0.0, f64::max);
    for k in 0..10 {
        if k < terms {
            ata[(k, k)] += ridge;
        } else {
            ata.row_mut(k).fill(0.0);
            ata.column_mut(k).fill(0.0);
            (ata[(k, k)], atb[k]) = (1.0, 0.0);
        }
    }
    let Some(c) = ata.cholesky().map(|ch| ch.solve(&atb)) else { return unbounded };
    let mut sum_r2 = 0.0;
    let mut mean = Vector3::zeros();
    for (d, w) in points {
        let r = d.dot(n) - monomials(d.dot(&u), d.dot(&v)).dot(&c);
        sum_r2 += w * r * r;
        mean += d * *w;
    }
    let (scatter, mean) = ((sum_r2 / sw).sqrt(), mean / sw);
    let across = Matrix3::identity() - n * n.transpose();
    let second = points.iter().fold(Matrix3::zeros(), |m, (d, w)| {
        let t = across * (d - mean);
        m + t * t.transpose() * *w
    }) / sw;
    tilt_covariance(n, &second, scatter)
}

/// The tilt covariance of a normal `n` fitted to a patch whose second moment across `n` is
/// `second` (m²) and whose points scatter `scatter` (m) about the fit ([`TILT_PER_SCATTER`]).
pub(crate) fn tilt_covariance(n: &Vector3<f64>, second: &Matrix3<f64>, scatter: f64) -> Matrix3<f64> {
    let e = SymmetricEigen::new((second + second.transpose()) * 0.5);
    let mut covariance = Matrix3::zeros();
    // the two largest eigenvalues are the tangent extents (the third is ~0 along n)
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| e.eigenvalues[b].total_cmp(&e.eigenvalues[a]));
    for &k in &order[..2] {
        let dir = e.eigenvectors.column(k).into_owned();
        let l2 = e.eigenvalues[k];
        // a tilt along dir turns the normal about n x dir
        let about = n.cross(&dir);
        let sigma2 = if l2 > 0.0 { (TILT_PER_SCATTER * scatter).powi(2) / l2 } else { f64::INFINITY };
        covariance += about * about.transpose() * sigma2;
    }
    if covariance.iter().all(|x| x.is_finite()) { covariance } else { Matrix3::from_diagonal_element(f64::INFINITY) }
}

/// Parameters of target placement.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TargetParams {
    /// A target point farther than this from every model point is refused, metres. Default 0.02.
    pub max_distance_m: f64,
    /// Neighbourhood radius of the local surface fit that places the point, metres. Default 0.008.
    pub radius_m: f64,
    /// Neighbourhood radius of the plane that gives the normal where no quadric fits (module docs),
    /// metres. Default 0.015.
    pub normal_radius_m: f64,
    /// Where the surface turns slowly, the normal's quadric fit spans this radius, metres (module
    /// docs). Default 0.03; 0: the plane over `normal_radius_m` everywhere.
    pub gentle_normal_radius_m: f64,
    /// ... "slowly": every radius of curvature of that quadric is at least this, metres. Default
    /// 0.10.
    pub min_curvature_radius_m: f64,
    /// Where the surface turns fast, the normal's quadric fit spans a patch with this Gaussian
    /// sigma across the fold (module docs), metres. Default 0.010; 0: the plane over
    /// `normal_radius_m` there.
    pub fold_across_sigma_m: f64,
    /// ... and this one along it, metres. Default 0.035.
    pub fold_along_sigma_m: f64,
    /// ... and the cubic fit over that patch replaces the quadric when they differ by more than
    /// this, radians (module docs). Default 2.5 degrees.
    pub fold_cubic_departure_rad: f64,
    /// At least this many neighbours are used (the nearest ones when the radius holds fewer). Default 12.
    pub min_neighbors: usize,
    /// Face extraction for `face-centre@...` targets. Default: [`FaceParams::default`].
    pub face: FaceParams,
}

impl Default for TargetParams {
    fn default() -> Self {
        Self {
            max_distance_m: 0.02,
            radius_m: 0.008,
            normal_radius_m: 0.015,
            gentle_normal_radius_m: 0.03,
            min_curvature_radius_m: 0.10,
            fold_across_sigma_m: 0.010,
            fold_along_sigma_m: 0.035,
            fold_cubic_departure_rad: 2.5f64.to_radians(),
            min_neighbors: 12,
            face: FaceParams::default(),
        }
    }
}

/// A target placed on the model (model frame = the scan's world frame, metres).
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceTarget {
    /// What was asked for.
    pub spec: TargetSpec,
    /// The target point on the surface.
    pub point: Point3<f64>,
    /// Outward unit surface normal there.
    pub normal: Vector3<f64>,
    /// Piercing direction: into the surface, `-normal`.
    pub axis: Vector3<f64>,
    /// RMS distance of the fitted points to the local plane (snap) or face plane, metres.
    pub fit_rms_m: f64,
    /// Model points the fit used.
    pub points: usize,
    /// Covariance of the normal's error as a rotation vector across it (model frame, rad²; module
    /// docs): from the scatter of the patch's points about its fitted surface and the patch's extent.
    pub normal_covariance: Matrix3<f64>,
    /// For a face centre: the 4 corners of the face's minimum-area rectangle, in order.
    pub corners: Option<[Point3<f64>; 4]>,
    /// Angle between `normal` and the tag's z axis, radians (when a tag pose was given).
    pub angle_to_tag_z_rad: Option<f64>,
}

/// The model with its search index, ready to place targets.
pub struct SurfaceModel<'a> {
    pub(crate) cloud: &'a PointCloud,
    pub(crate) index: KdIndex,
    centroid: Point3<f64>,
    pub(crate) floor: Option<FloorPlane>,
}

impl std::fmt::Debug for SurfaceModel<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "SurfaceModel({} points)", self.cloud.len())
    }
}

/// The wide quadric at a target ([`SurfaceModel::quadric_at`]).
struct WideQuadric {
    /// Its unit normal at the target, oriented like the plane's.
    normal: Vector3<f64>,
    /// Its largest absolute principal curvature, 1/m.
    curvature: f64,
    /// That curvature's direction (unit, tangent).
    sharpest: Vector3<f64>,
}

/// A local plane: point on it, unit normal (oriented outward), rms, neighbours used.
pub(crate) struct LocalPlane {
    pub(crate) point: Point3<f64>,
    pub(crate) normal: Vector3<f64>,
    pub(crate) rms_m: f64,
    pub(crate) points: usize,
}

impl<'a> SurfaceModel<'a> {
    /// Indexes `model` (world frame; normals used for orientation when present).
    ///
    /// # Errors
    /// [`Error::Invalid`] for an empty model or non-finite points.
    pub fn new(model: &'a PointCloud) -> Result<Self> {
        if model.len() < 3 {
            return Err(Error::invalid("model", format!("{} points: too few to place targets", model.len())));
        }
        let index = KdIndex::new(&model.points)?;
        let n = model.len() as f64;
        let centroid = Point3::from(model.points.iter().map(|p| p.coords.cast::<f64>()).sum::<Vector3<f64>>() / n);
        Ok(Self { cloud: model, index, centroid, floor: None })
    }

    /// The floor the model stood on (e.g. [`crate::workpiece::Workpiece::floor`]): a face standing on
    /// it ends there ([`SurfaceModel::face_centre`]).
    pub fn with_floor(self, floor: Option<FloorPlane>) -> Self {
        Self { floor, ..self }
    }

    /// Places one target (see [`TargetSpec`]); with `world_from_tag`, also the angle to the tag's z.
    ///
    /// # Errors
    /// [`Error::Invalid`] when the point is farther than `max_distance_m` from the model, or no
    /// plane (face) fits there.
    pub fn place(
        &self,
        spec: &TargetSpec,
        params: &TargetParams,
        world_from_tag: Option<&Isometry3<f64>>,
    ) -> Result<SurfaceTarget> {
        let mut target = match spec {
            TargetSpec::Point(p) => self.snap(p, params)?,
            TargetSpec::FaceCentre(p) => self.face_centre(p, params)?,
        };
        target.angle_to_tag_z_rad = world_from_tag.map(|t| target.normal.angle(&(t.rotation * Vector3::z())));
        Ok(target)
    }

    /// Snaps `p` onto the surface (module docs).
    ///
    /// # Errors
    /// [`Error::Invalid`] when `p` is farther than `max_distance_m` from the model.
    pub fn snap(&self, p: &Point3<f64>, params: &TargetParams) -> Result<SurfaceTarget> {
        let plane = self.local_plane(p, params)?;
        let (normal, patch) = self.adaptive_normal(&plane.point, params);
        let normal_covariance = patch_tilt(&patch, &normal);
        let plane = LocalPlane { normal, ..plane };
        Ok(SurfaceTarget {
            spec: TargetSpec::Point(*p),
            point: plane.point,
            normal: plane.normal,
            axis: -plane.normal,
            fit_rms_m: plane.rms_m,
            points: plane.points,
            normal_covariance,
            corners: None,
            angle_to_tag_z_rad: None,
        })
    }

    /// Checks that `p` is near the model.
    pub(crate) fn check_near(&self, p: &Point3<f64>, params: &TargetParams) -> Result<()> {
        let what = || format!("target {:.4},{:.4},{:.4}", p.x, p.y, p.z);
        if !p.coords.iter().all(|v| v.is_finite()) {
            return Err(Error::invalid(what(), "not finite"));
        }
        let nearest = self.index.nearest(&p.cast::<f32>()).ok_or_else(|| Error::invalid(what(), "empty model"))?;
        let d = f64::from(nearest.dist_sq).sqrt();
        if d > params.max_distance_m {
            return Err(Error::invalid(
                what(),
                format!(
                    "{:.1} mm from the nearest model point (at most {:.1} mm)",
                    d * 1e3,
                    params.max_distance_m * 1e3
                ),
            ));
        }
        Ok(())
    }

    /// The MLS-style local plane at `p` (module docs).
    pub(crate) fn local_plane(&self, p: &Point3<f64>, params: &TargetParams) -> Result<LocalPlane> {
        if !(params.radius_m > 0.0
            && params.normal_radius_m > 0.0
            && params.min_neighbors >= 3
            && params.max_distance_m > 0.0)
        {
            return Err(Error::invalid(
                "target parameters",
                "radius and distance must be positive, min_neighbors >= 3",
            ));
        }
        self.check_near(p, params)?;
        let mut q = *p;
        let mut result = None;
        for _ in 0..3 {
            let (c, normal, rms_m, points) = self.fit_at(&q, params.radius_m, params.min_neighbors);
            q = p - normal * (p - c).dot(&normal);
            result = Some(LocalPlane { point: q, normal, rms_m, points });
        }
        result.ok_or_else(|| Error::invalid("target", "no local plane"))
    }

    /// Weighted plane fit at `q` (Gaussian weights, sigma = radius / 2; at least `min_neighbors`
    /// points): (weighted centroid, outward normal, rms, points).
    fn fit_at(&self, q: &Point3<f64>, radius_m: f64, min_neighbors: usize) -> (Point3<f64>, Vector3<f64>, f64, usize) {
        let sigma2 = (radius_m / 2.0).powi(2);
        let q32 = q.cast::<f32>();
        let mut near = self.index.within(&q32, radius_m as f32);
        if near.len() < min_neighbors {
            near = self.index.knn(&q32, min_neighbors);
        }
        let w: Vec<f64> = near.iter().map(|n| (-f64::from(n.dist_sq) / (2.0 * sigma2)).exp().max(1e-12)).collect();
        let sw: f64 = w.iter().sum();
        let pts: Vec<Point3<f64>> = near.iter().map(|n| self.cloud.points[n.index as usize].cast::<f64>()).collect();
        let c = pts.iter().zip(&w).map(|(x, wi)| x.coords * *wi).sum::<Vector3<f64>>() / sw;
        let cov = pts
            .iter()
            .zip(&w)
            .fold(Matrix3::zeros(), |m, (x, wi)| m + (x.coords - c) * (x.coords - c).transpose() * *wi)
            / sw;
        let eig = SymmetricEigen::new(cov);
        let k = eig.eigenvalues.imin();
        let mut normal = eig.eigenvectors.column(k).into_owned();
        if normal.dot(&self.outward_hint(&near, &Point3::from(c))) < 0.0 {
            normal = -normal;
        }
        (Point3::from(c), normal, eig.eigenvalues[k].max(0.0).sqrt(), near.len())
    }

    /// The normal at `q` (module docs: the quadric over `gentle_normal_radius_m` where the surface
    /// turns slowly, else the quadric over the fold's patch, else the plane over `normal_radius_m`),
    /// and the patch that gave it.
    fn adaptive_normal(&self, q: &Point3<f64>, params: &TargetParams) -> (Vector3<f64>, Patch) {
        let plane = self.fit_at(q, params.normal_radius_m, params.min_neighbors).1;
        let round = |radius: f64, n: &Vector3<f64>| Patch { points: self.round_patch(q, n, radius), cubic: false };
        if params.gentle_normal_radius_m <= 0.0 {
            return (plane, round(params.normal_radius_m, &plane));
        }
        let wide = |n: &Vector3<f64>| self.quadric_at(q, n, params.gentle_normal_radius_m);
        match wide(&plane).and_then(|w| wide(&w.normal)) {
            Some(w) if w.curvature * params.min_curvature_radius_m <= 1.0 => {
                (w.normal, round(params.gentle_normal_radius_m, &w.normal))
            }
            Some(w) if params.fold_across_sigma_m > 0.0 => match self.fold_normal(q, &w, params) {
                Some((n, cubic)) => (n, Patch { points: self.fold_patch(q, &w, &n, params), cubic }),
                None => (plane, round(params.normal_radius_m, &plane)),
            },
            _ => (plane, round(params.normal_radius_m, &plane)),
        }
    }

    /// The points within `radius` of `q` and of its tangent plane `n`, with Gaussian weights (sigma
    /// = radius / 2): offsets from `q` and weights.
    fn round_patch(&self, q: &Point3<f64>, n: &Vector3<f64>, radius: f64) -> Vec<(Vector3<f64>, f64)> {
        let inv_h2 = ROUND_PATCH_INV_H2 / (radius * radius);
        (self.index.within(&q.cast::<f32>(), radius as f32).iter())
            .map(|nb| self.cloud.points[nb.index as usize].cast::<f64>() - q)
            .filter(|d| d.dot(n).abs() <= radius)
            .map(|d| (d, (-d.norm_squared() * inv_h2).exp()))
            .collect()
    }

    /// The fold's patch at `q` ([`SurfaceModel::fold_fit`]'s points and weights, in the frame of
    /// the normal `n` found there).
    fn fold_patch(
        &self,
        q: &Point3<f64>,
        wide: &WideQuadric,
        n: &Vector3<f64>,
        params: &TargetParams,
    ) -> Vec<(Vector3<f64>, f64)> {
        let (s1, s2) = (params.fold_across_sigma_m, params.fold_along_sigma_m.max(params.fold_across_sigma_m));
        let Some(across) = (wide.sharpest - n * wide.sharpest.dot(n)).try_normalize(1e-9) else { return Vec::new() };
        let along = n.cross(&across);
        (self.index.within(&q.cast::<f32>(), (2.0 * s1.hypot(s2)) as f32).iter())
            .map(|nb| self.cloud.points[nb.index as usize].cast::<f64>() - q)
            .filter_map(|d| fold_coordinates(&d, (&across, &along, n), (s1, s2)).map(|(.., w)| (d, w)))
            .collect()
    }

    /// Weighted quadric height field over the model points within `radius` of `q` and within
    /// `radius` of its tangent plane `n` ([`crate::smooth::quadric_coefficients`]; Gaussian weights,
    /// sigma = radius / 2): its normal at `q` (oriented like `n`), largest absolute principal
    /// curvature and that curvature's direction. `None` with fewer than 12 points or a degenerate
    /// patch.
    fn quadric_at(&self, q: &Point3<f64>, n: &Vector3<f64>, radius: f64) -> Option<WideQuadric> {
        let offsets: Vec<Vector3<f64>> = self.round_patch(q, n, radius).into_iter().map(|(d, _)| d).collect();
        if offsets.len() < 12 {
            return None;
        }
        // exp(-|d|^2 inv_h2) with sigma = radius / 2, round_patch's weights
        let inv_h2 = ROUND_PATCH_INV_H2 / (radius * radius);
        let c = quadric_coefficients(&offsets, &Vector3::zeros(), n, radius, inv_h2)?;
        // the Hessian of the height (in units of the radius): [[2 c3, c4], [c4, 2 c5]]
        let hessian = SymmetricEigen::new(Matrix2::new(2.0 * c[3], c[4], c[4], 2.0 * c[5]));
        let k = hessian.eigenvalues.iamax();
        let (u, v) = tangent_frame(n);
        let sharp = hessian.eigenvectors.column(k);
        Some(WideQuadric {
            normal: quadric_normal(&c, n, radius)?,
            curvature: hessian.eigenvalues[k].abs() / (radius * radius),
            sharpest: u * sharp[0] + v * sharp[1],
        })
    }

    /// The normal at `q` where the surface turns fast one way (a groove, a ridge, a fillet; module
    /// docs): the quadric over the fold's patch, or the cubic when it departs from the quadric by
    /// more than `fold_cubic_departure_rad` (then `true`). `None` with fewer than 12 points in the
    /// patch or a degenerate fit.
    fn fold_normal(&self, q: &Point3<f64>, wide: &WideQuadric, params: &TargetParams) -> Option<(Vector3<f64>, bool)> {
        let (s1, s2) = (params.fold_across_sigma_m, params.fold_along_sigma_m.max(params.fold_across_sigma_m));
        let near = self.index.within(&q.cast::<f32>(), (2.0 * s1.hypot(s2)) as f32);
        let quadric = self.fold_fit(q, &near, wide, (s1, s2), false)?;
        match self.fold_fit(q, &near, wide, (s1, s2), true) {
            Some(cubic) if cubic.angle(&quadric) > params.fold_cubic_departure_rad => Some((cubic, true)),
            _ => Some((quadric, false)),
        }
    }

    /// A weighted quadric (or cubic) height field over the points of `near` in the patch at `q`
    /// with Gaussian sigmas `s1` across the fold (along `wide.sharpest`) and `s2` along it, cut at
    /// 2 sigmas and within `s1` of the tangent plane; fitted twice, the second time in the first
    /// one's frame: its normal at `q`.
    fn fold_fit(
        &self,
        q: &Point3<f64>,
        near: &[crate::spatial::Neighbor],
        wide: &WideQuadric,
        (s1, s2): (f64, f64),
        cubic: bool,
    ) -> Option<Vector3<f64>> {
        let mut n = wide.normal;
        for _ in 0..2 {
            let across = (wide.sharpest - n * wide.sharpest.dot(&n)).try_normalize(1e-9)?;
            let along = n.cross(&across);
            let (mut ata, mut atb, mut count) = (SMatrix::<f64, 10, 10>::zeros(), SVector::<f64, 10>::zeros(), 0usize);
            for nb in near {
                let d = self.cloud.points[nb.index as usize].cast::<f64>() - q;
                let Some((x, y, z, w)) = fold_coordinates(&d, (&across, &along, &n), (s1, s2)) else { continue };
                let m = SVector::<f64, 10>::from([
                    1.0,
                    x,
                    y,
                    x * x,
                    x * y,
                    y * y,
                    x * x * x,
                    x * x * y,
                    x * y * y,
                    y * y * y,
                ]);
                ata += m * m.transpose() * w;
                atb += m * (w * z);
                count += 1;
            }
            if count < 12 {
                return None;
            }
            let (c1, c2) = if cubic {
                let c = ata.cholesky()?.solve(&atb);
                (c[1], c[2])
            } else {
                let c =
                    ata.fixed_view::<6, 6>(0, 0).into_owned().cholesky()?.solve(&atb.fixed_rows::<6>(0).into_owned());
                (c[1], c[2])
            };
            // the height's slopes in metres per metre: dz/dx = c1, dz/dy = c2 s1 / s2
            n = (n - across * c1 - along * (c2 * s1 / s2)).try_normalize(1e-12)?;
        }
        n.iter().all(|x| x.is_finite()).then_some(n)
    }

    /// The direction the model says is outward near `c`: its normals' mean, or away from the centroid.
    fn outward_hint(&self, near: &[crate::spatial::Neighbor], c: &Point3<f64>) -> Vector3<f64> {
        if let Some(normals) = &self.cloud.normals {
            let sum: Vector3<f64> = near.iter().map(|n| normals[n.index as usize].cast::<f64>()).sum();
            if sum.norm() > 1e-9 {
                return sum;
            }
        }
        c - self.centroid
    }
}
