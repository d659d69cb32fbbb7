//! One Gauss-Newton step of point-to-plane ICP: correspondences, robust weights, the 6x6 system.
//!
//! The sums are taken per fixed-size chunk in parallel and then added in chunk order, so the
//! result is bit-identical whatever the number of threads.

use nalgebra::{Isometry3, Matrix6, Point3, Translation3, UnitQuaternion, Vector3, Vector6};
use rayon::prelude::*;

use super::kernel::Kernel;
use crate::spatial::{KdIndex, Neighbor, ProjectiveGrid};

const CHUNK: usize = 2048;

/// The target of a registration level: points with unit normals and their index.
pub(crate) struct Target<'a> {
    pub points: &'a [Point3<f32>],
    pub normals: &'a [nalgebra::Vector3<f32>],
    pub index: &'a TargetIndex,
}

/// A target's nearest-neighbour search: a k-d tree, or the projective grid of a view kept in its
/// camera frame (faster for ICP's bounded queries, and instant for points outside the view).
pub(crate) enum TargetIndex {
    Tree(KdIndex),
    Grid(ProjectiveGrid),
}

impl TargetIndex {
    /// The grid when every point is in front of the camera (z > 0), else the tree.
    pub fn of_view(points: &[Point3<f32>]) -> crate::error::Result<Self> {
        if points.iter().all(|p| p.z > 0.0) {
            ProjectiveGrid::new(points).map(Self::Grid)
        } else {
            KdIndex::new(points).map(Self::Tree)
        }
    }

    fn nearest_within(&self, q: &Point3<f32>, radius_m: f32) -> Option<Neighbor> {
        match self {
            Self::Tree(t) => t.nearest_within(q, radius_m),
            Self::Grid(g) => g.nearest_within(q, radius_m),
        }
    }
}

/// Sums of one linearisation (about `centre`, rotation scaled by `1/length`).
#[derive(Clone, Copy)]
pub(crate) struct System {
    pub h: Matrix6<f64>,
    pub g: Vector6<f64>,
    /// Correspondences within the distance gate (and normal gate).
    pub inliers: usize,
    /// Sum of squared point-to-plane residuals of the inliers, m².
    pub residual_sq: f64,
    /// Sum of weights.
    pub weight: f64,
}

impl System {
    /// A system with no correspondence.
    pub fn zero() -> Self {
        Self { h: Matrix6::zeros(), g: Vector6::zeros(), inliers: 0, residual_sq: 0.0, weight: 0.0 }
    }

    fn add(mut self, o: &System) -> Self {
        self.h += o.h;
        self.g += o.g;
        self.inliers += o.inliers;
        self.residual_sq += o.residual_sq;
        self.weight += o.weight;
        self
    }
}

/// Gates and robust kernel of one step.
#[derive(Clone, Copy)]
pub(crate) struct StepParams {
    pub max_distance_m: f64,
    /// Correspondences whose offset along the target's tangent plane exceeds this are dropped:
    /// the nearest target point is then on the target's boundary, not under the source point.
    pub max_tangential_m: Option<f64>,
    pub min_normal_cos: Option<f64>,
    pub kernel: Kernel,
    pub kernel_scale_m: f64,
    pub centre: Vector3<f64>,
    pub length_m: f64,
}

/// The motion a solved step stands for: `delta` = (rotation scaled by `length`, translation),
/// about `centre`; also its translation length (m) and rotation angle (rad).
pub(crate) fn step_motion(delta: &Vector6<f64>, centre: &Vector3<f64>, length: f64) -> (Isometry3<f64>, f64, f64) {
    let omega = Vector3::new(delta[0], delta[1], delta[2]) / length;
    let v = Vector3::new(delta[3], delta[4], delta[5]);
    let rotation = UnitQuaternion::from_scaled_axis(omega);
    let about_centre = Translation3::from(centre + v) * rotation * Translation3::from(-centre);
    (about_centre, v.norm(), omega.norm())
}

/// Builds the weighted normal equations for moved source points (`moved`, in the target frame,
/// with optional moved normals).
///
/// `previous` holds each source point's correspondence of the previous iteration (`u32::MAX`:
/// none) and is updated. The pose moves little between iterations, so the distance to the previous
/// correspondence bounds the search radius: the nearest target point is the same (it is at most
/// that far), found with far fewer tree nodes visited.
pub(crate) fn linearise(
    moved: &[Point3<f64>],
    moved_normals: Option<&[Vector3<f64>]>,
    target: &Target<'_>,
    p: &StepParams,
    previous: &mut [u32],
) -> System {
    let max_m = p.max_distance_m as f32;
    let partial: Vec<System> = moved
        .par_chunks(CHUNK)
        .zip(previous.par_chunks_mut(CHUNK))
        .enumerate()
        .map(|(c, (chunk, hints))| {
            let mut sys = System::zero();
            for (j, (s, hint)) in chunk.iter().zip(hints.iter_mut()).enumerate() {
                let q = s.cast::<f32>();
                let radius = match target.points.get(*hint as usize) {
                    // a hair wider than the previous correspondence, so that it stays inside
                    Some(prev) => ((prev - q).norm() * (1.0 + 1e-4) + 1e-6).min(max_m),
                    None => max_m,
                };
                let found = target.index.nearest_within(&q, radius);
                *hint = found.map_or(u32::MAX, |nb| nb.index);
                let Some(nb) = found else { continue };
                let t = target.points[nb.index as usize].cast::<f64>();
                let n = target.normals[nb.index as usize].cast::<f64>();
                if let (Some(cos), Some(ns)) = (p.min_normal_cos, moved_normals) {
                    if ns[c * CHUNK + j].dot(&n) < cos {
                        continue;
                    }
                }
                let offset = s - t;
                let r = n.dot(&offset);
                if let Some(max) = p.max_tangential_m {
                    if (offset - n * r).norm_squared() > max * max {
                        continue;
                    }
                }
                let w = p.kernel.weight(r, p.kernel_scale_m);
                sys.inliers += 1;
                sys.residual_sq += r * r;
                if w <= 0.0 {
                    continue;
                }
                let arm = (s.coords - p.centre) / p.length_m;
                let rot = arm.cross(&n);
                let jac = Vector6::new(rot.x, rot.y, rot.z, n.x, n.y, n.z);
                sys.h += w * jac * jac.transpose();
                sys.g += w * r * jac;
                sys.weight += w;
            }
            sys
        })
        .collect();
    partial.iter().fold(System::zero(), |acc, s| acc.add(s))
}
