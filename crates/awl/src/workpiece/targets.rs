//! Targets on the model: a picked point snapped onto the surface ([`SurfaceModel::snap`]) or the
//! centre of the planar face nearest a point ([`SurfaceModel::face_centre`], in `face.rs`), each
//! with its outward surface normal and the piercing axis.
//!
//! Snapping is an MLS-style projection: the model points within `radius_m` of the current estimate
//! (Gaussian weights, sigma = `radius_m / 2`) give a weighted least-squares plane; the picked point
//! is projected onto it, and the neighbourhood is re-centred there (3 rounds). The normal is that of
//! a second such plane over `normal_radius_m` at the placed point. Where the surface turns
//! slowly, the normal is instead that of a weighted quadric height field over the wider
//! `gentle_normal_radius_m` (fitted twice, the second time in the first one's frame; "slowly":
//! that quadric has no radius of curvature below `min_curvature_radius_m`): a quadric follows a
//! slowly turning surface over that patch, and the wider patch averages more of the model's noise
//! and wiggles out of the direction. (Where the surface turns fast, e.g. in a
//! groove, a wider patch takes in shape a quadric cannot follow, which biases the normal more than
//! the noise does.) A fixed radius, not one grown while the fit's residual stays low: across six
//! simulated shells the residual rule stopped on the model's noise (flank normal 0.54 deg mean,
//! 0.92 max, against 0.20 / 0.37 at 30 mm). Normals are
//! oriented like the model's own normals there (the fuse pipeline orients them toward the cameras
//! that saw the surface, i.e. outward); a model without normals orients it away from the model's
//! centroid.

use nalgebra::{Isometry3, Matrix3, Point3, SymmetricEigen, Vector3};
use serde::{Deserialize, Serialize};

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::smooth::{quadric_coefficients, quadric_normal};
use crate::spatial::KdIndex;
use crate::workpiece::face::FaceParams;
use crate::workpiece::file::FloorPlane;
use crate::workpiece::target_spec::TargetSpec;

/// Parameters of target placement.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TargetParams {
    /// A target point farther than this from every model point is refused, metres. Default 0.02.
    pub max_distance_m: f64,
    /// Neighbourhood radius of the local surface fit that places the point, metres. Default 0.008.
    pub radius_m: f64,
    /// Neighbourhood radius of the fit that gives the normal (at the placed point), metres. Default
    /// 0.015: wider than `radius_m`, it averages the model's noise out of the direction (on a
    /// symmetric neighbourhood the curvature does not bias it).
    pub normal_radius_m: f64,
    /// Where the surface turns slowly, the normal's quadric fit spans this radius, metres (module
    /// docs). Default 0.03; 0: the plane over `normal_radius_m` everywhere.
    pub gentle_normal_radius_m: f64,
    /// ... "slowly": every radius of curvature of that quadric is at least this, metres. Default
    /// 0.10.
    pub min_curvature_radius_m: f64,
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
        let normal = self.adaptive_normal(&plane.point, params);
        let plane = LocalPlane { normal, ..plane };
        Ok(SurfaceTarget {
            spec: TargetSpec::Point(*p),
            point: plane.point,
            normal: plane.normal,
            axis: -plane.normal,
            fit_rms_m: plane.rms_m,
            points: plane.points,
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

    /// The normal at `q` (module docs: the plane over `normal_radius_m`, or where the surface turns
    /// slowly the quadric over `gentle_normal_radius_m`).
    fn adaptive_normal(&self, q: &Point3<f64>, params: &TargetParams) -> Vector3<f64> {
        let plane = self.fit_at(q, params.normal_radius_m, params.min_neighbors).1;
        if params.gentle_normal_radius_m <= 0.0 {
            return plane;
        }
        let wide = |n: &Vector3<f64>| self.quadric_at(q, n, params.gentle_normal_radius_m);
        match wide(&plane).and_then(|(n, _)| wide(&n)) {
            Some((normal, curvature)) if curvature * params.min_curvature_radius_m <= 1.0 => normal,
            _ => plane,
        }
    }

    /// Weighted quadric height field over the model points within `radius` of `q` and within
    /// `radius` of its tangent plane `n` ([`crate::smooth::quadric_coefficients`]; Gaussian weights,
    /// sigma = radius / 2): its normal at `q` (oriented like `n`) and largest absolute principal
    /// curvature (1/m). `None` with fewer than 12 points or a degenerate patch.
    fn quadric_at(&self, q: &Point3<f64>, n: &Vector3<f64>, radius: f64) -> Option<(Vector3<f64>, f64)> {
        let offsets: Vec<Vector3<f64>> = self
            .index
            .within(&q.cast::<f32>(), radius as f32)
            .iter()
            .map(|nb| self.cloud.points[nb.index as usize].cast::<f64>() - q)
            .filter(|d| d.dot(n).abs() <= radius)
            .collect();
        if offsets.len() < 12 {
            return None;
        }
        // exp(-|d|^2 inv_h2) with sigma = radius / 2
        let inv_h2 = 2.0 / (radius * radius);
        let c = quadric_coefficients(&offsets, &Vector3::zeros(), n, radius, inv_h2)?;
        // the Hessian of the height in metres: [[2 c3, c4], [c4, 2 c5]] / radius^2
        let (a, b, d) = (2.0 * c[3], c[4], 2.0 * c[5]);
        let curvature = ((a + d).abs() / 2.0 + ((a - d) * (a - d) / 4.0 + b * b).sqrt()) / (radius * radius);
        Some((quadric_normal(&c, n, radius)?, curvature))
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
