//! Evaluation against ground truth: model-to-CAD distances, completeness, pose errors. The
//! pipeline never uses this module; `awl evaluate` and the tests do.
//!
//! Definitions (model points in the CAD/object frame after alignment):
//! - `rmse_m`, `mean_m`, `median_m`, `p95_m`, `max_m`: over the model points within `on_object_m` of the CAD surface;
//! - `off_object_fraction`: model points farther than `on_object_m` from the CAD (floor, clutter, ghosts) / all;
//! - `completeness`: fraction of the CAD surface samples (those some view could see) with a model
//!   point within each threshold.
//!
//! The whole `awl evaluate` job (global + fine alignment of a model to a CAD, metrics, heatmap) lives
//! in the submodules: [`evaluate()`] is the entry point.

use nalgebra::{Isometry3, Point3};
use parry3d_f64::math::Vector as PVector;
use parry3d_f64::query::PointQuery;
use parry3d_f64::shape::TriMesh as ParryMesh;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use crate::spatial::KdIndex;

pub mod evaluate;
pub mod file;
pub mod global;
pub mod heatmap;
pub mod sanity;
pub mod summary;
pub mod trajectory;

pub use evaluate::{EvaluateParams, Evaluation, evaluate};
pub use global::{GlobalParams, GlobalResult, global_align};
pub use summary::EvaluationSummary;
pub use trajectory::{TrajectoryCorrection, trajectory_correction, trajectory_error_mm};

/// Distances from points to a triangle mesh's surface.
pub struct MeshDistance {
    mesh: ParryMesh,
}

impl MeshDistance {
    /// Builds the BVH of `mesh`.
    ///
    /// # Errors
    /// [`Error::Invalid`] when the mesh has no triangles, or is invalid or degenerate.
    pub fn new(mesh: &TriMesh) -> Result<Self> {
        mesh.validate("CAD mesh")?;
        if mesh.triangles.is_empty() {
            return Err(Error::invalid(
                "CAD mesh",
                format!(
                    "it has no triangles ({} vertices): give a surface mesh (a PLY with a `face` element, an STL with \
                     facets, an OBJ with `f` lines)",
                    mesh.vertices.len()
                ),
            ));
        }
        let vertices = mesh.vertices.iter().map(|p| PVector::new(p.x, p.y, p.z)).collect();
        let mesh = ParryMesh::new(vertices, mesh.triangles.clone())
            .map_err(|e| Error::invalid("CAD mesh", format!("cannot build its BVH: {e:?}")))?;
        Ok(Self { mesh })
    }

    /// Unsigned distance of each point (mesh frame) to the surface, metres.
    pub fn distances(&self, points: &[Point3<f64>]) -> Vec<f64> {
        points.par_iter().map(|p| self.mesh.distance_to_local_point(PVector::new(p.x, p.y, p.z), false)).collect()
    }
}

/// Model-against-CAD numbers; see the module docs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CadMetrics {
    /// Model points evaluated.
    pub points: usize,
    /// Distance below which a model point counts as on the object, metres.
    pub on_object_m: f64,
    /// RMS distance of the on-object points, metres.
    pub rmse_m: f64,
    /// Mean distance of the on-object points, metres.
    pub mean_m: f64,
    /// Median distance of the on-object points, metres.
    pub median_m: f64,
    /// 95th percentile of the on-object points, metres.
    pub p95_m: f64,
    /// Largest distance of the on-object points, metres.
    pub max_m: f64,
    /// Share of model points off the object.
    pub off_object_fraction: f64,
    /// `(threshold_m, fraction of visible CAD samples within it)`.
    pub completeness: Vec<(f64, f64)>,
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let pos = (q * (sorted.len() - 1) as f64).round() as usize;
    sorted[pos.min(sorted.len() - 1)]
}

/// Evaluates `model_object` (model points already in the CAD frame) against the CAD.
///
/// `cad_samples` are points on the CAD surface (CAD frame) that count for completeness (e.g. those
/// some view could see).
///
/// # Errors
/// [`Error::Invalid`] for an empty model or sample set.
pub fn cad_metrics(
    model_object: &PointCloud,
    cad: &MeshDistance,
    cad_samples: &[Point3<f32>],
    on_object_m: f64,
    thresholds_m: &[f64],
) -> Result<CadMetrics> {
    if model_object.is_empty() || cad_samples.is_empty() {
        return Err(Error::invalid("evaluation", "empty model or no CAD samples"));
    }
    let points: Vec<Point3<f64>> = model_object.points.iter().map(|p| p.cast::<f64>()).collect();
    let mut on: Vec<f64> = cad.distances(&points).into_iter().filter(|&d| d <= on_object_m).collect();
    on.sort_by(f64::total_cmp);
    let n_on = on.len().max(1) as f64;
    let index = KdIndex::new(&model_object.points)?;
    let nearest: Vec<f64> = cad_samples
        .par_iter()
        .map(|s| index.nearest(s).map_or(f64::INFINITY, |n| f64::from(n.dist_sq).sqrt()))
        .collect();
    let completeness = thresholds_m
        .iter()
        .map(|&t| (t, nearest.iter().filter(|&&d| d <= t).count() as f64 / nearest.len() as f64))
        .collect();
    Ok(CadMetrics {
        points: points.len(),
        on_object_m,
        rmse_m: (on.iter().map(|d| d * d).sum::<f64>() / n_on).sqrt(),
        mean_m: on.iter().sum::<f64>() / n_on,
        median_m: percentile(&on, 0.5),
        p95_m: percentile(&on, 0.95),
        max_m: on.last().copied().unwrap_or(f64::NAN),
        off_object_fraction: (points.len() - on.len()) as f64 / points.len() as f64,
        completeness,
    })
}

/// The rigid transform that best maps the `from` camera centres onto the `to` ones (Kabsch, no
/// scale): used to compare trajectories up to the gauge freedom of the model frame.
///
/// # Errors
/// [`Error::Invalid`] for fewer than 3 pairs or mismatched lengths.
pub fn align_positions(from: &[Point3<f64>], to: &[Point3<f64>]) -> Result<Isometry3<f64>> {
    if from.len() != to.len() || from.len() < 3 {
        return Err(Error::invalid("trajectory alignment", "needs at least 3 matched positions"));
    }
    let n = from.len() as f64;
    let cf = from.iter().fold(nalgebra::Vector3::zeros(), |a, p| a + p.coords) / n;
    let ct = to.iter().fold(nalgebra::Vector3::zeros(), |a, p| a + p.coords) / n;
    let h = from
        .iter()
        .zip(to)
        .fold(nalgebra::Matrix3::zeros(), |h, (f, t)| h + (f.coords - cf) * (t.coords - ct).transpose());
    let svd = h.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err(Error::invalid("trajectory alignment", "SVD failed"));
    };
    let mut d = nalgebra::Matrix3::identity();
    if (v_t.transpose() * u.transpose()).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = v_t.transpose() * d * u.transpose();
    let rotation = nalgebra::UnitQuaternion::from_matrix(&r);
    let t = ct - rotation * cf;
    Ok(Isometry3::from_parts(t.into(), rotation))
}

/// Which surface samples (world frame, with outward normals) some view saw: the sample faces the
/// camera, projects inside its image, and the measured depth there is within `tolerance_m` of it.
pub fn visible_samples(
    samples_world: &PointCloud,
    camera: &crate::camera::Intrinsics,
    depth_scale: f64,
    views: &[(Isometry3<f64>, &crate::image::DepthImage)],
    tolerance_m: f64,
) -> Vec<bool> {
    let normals = samples_world.normals.as_deref();
    (0..samples_world.len())
        .into_par_iter()
        .map(|i| {
            let p = samples_world.points[i].cast::<f64>();
            views.iter().any(|(world_from_camera, depth)| {
                let centre = world_from_camera.translation.vector;
                if let Some(ns) = normals
                    && ns[i].cast::<f64>().dot(&(centre - p.coords)) <= 0.0
                {
                    return false;
                }
                let p_camera = world_from_camera.inverse_transform_point(&p);
                let Some(px) = camera.project(&p_camera) else { return false };
                let (u, v) = (px.x.round(), px.y.round());
                if u < 0.0 || v < 0.0 || u >= f64::from(depth.width) || v >= f64::from(depth.height) {
                    return false;
                }
                let raw = depth.data[v as usize * depth.width as usize + u as usize];
                raw != 0 && (f64::from(raw) * depth_scale - p_camera.z).abs() <= tolerance_m
            })
        })
        .collect()
}
