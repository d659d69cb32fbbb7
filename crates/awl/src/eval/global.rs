//! Coarse global alignment of a model (a point cloud in any frame) to a CAD mesh (object frame), with
//! no initial guess.
//!
//! Hypotheses: the model's and the CAD's principal frames (eigenvectors of the covariance about the
//! centroid, made right-handed) are matched under each of the 24 proper axis permutations and sign
//! flips, so eigenvalues that come out reordered (a scanned model misses the bottom face) are
//! covered; each is also spun by `±k * spin_deg` (k = 1..=`spins`) about each CAD principal axis,
//! since an eigenvector in a near-degenerate plane (a 48.5 x 48 cm box) is arbitrary. Both frames
//! are placed at their centroids. Every hypothesis is refined by a short coarse ICP on down-sampled
//! clouds (robust kernel: floor and clutter get no weight), then scored on a fixed, seeded random
//! subset of the model points, d = exact distance to the CAD surface, τ = `score_threshold_m`:
//! - `score` = mean of max(0, 1 − (d/τ)²): it rewards closeness, so a near-symmetric wrong pose (that
//!   box turned 90°, sides 2.5 mm off) ranks below the right one;
//! - `inlier_fraction` = share of the subset with d <= τ.
//!
//! Hypotheses that converge to the same pose (within `distinct_m` / `distinct_deg`) count once, so
//! the few candidates refined further are different poses.
//!
//! Deterministic: no randomness; hypotheses run in parallel and are ranked by score, ties by index.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::MeshDistance;
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::filter::voxel::{VoxelParams, downsample};
use crate::registration::{IcpLevel, IcpParams, register};

/// Seed of the scored subset of model points.
pub const SCORE_SEED: u64 = 0x5c0e;

/// Parameters of [`global_align`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GlobalParams {
    /// Spin step about each CAD principal axis, degrees. Default 30.
    pub spin_deg: f64,
    /// Spins each way per axis (0 = PCA hypotheses only). Default 1 (24 x 7 = 168 hypotheses).
    pub spins: usize,
    /// Model and CAD samples are voxel-down-sampled to this before the hypotheses, metres. Default 0.01.
    pub voxel_m: f64,
    /// τ of the score, metres. Default 0.005.
    pub score_threshold_m: f64,
    /// Model points the score is computed on (a seeded random subset). Default 1000.
    pub score_points: usize,
    /// Two results closer than this (model centroid displacement, metres) and `distinct_deg` are
    /// one candidate (the better scored is kept). Default 0.01.
    pub distinct_m: f64,
    /// See `distinct_m`, degrees. Default 5.
    pub distinct_deg: f64,
    /// The coarse ICP run on each hypothesis. Default: 20 mm voxels / 100 mm gate / 10 iterations,
    /// then 10 / 30 / 10; Tukey; at most 1000 source points.
    pub icp: IcpParams,
}

impl Default for GlobalParams {
    fn default() -> Self {
        let icp = IcpParams {
            levels: vec![
                IcpLevel { voxel_m: 0.02, max_correspondence_m: 0.10, max_iterations: 10 },
                IcpLevel { voxel_m: 0.01, max_correspondence_m: 0.03, max_iterations: 10 },
            ],
            max_source_points: 1000,
            ..IcpParams::default()
        };
        Self {
            spin_deg: 30.0,
            spins: 1,
            voxel_m: 0.01,
            score_threshold_m: 0.005,
            score_points: 1000,
            distinct_m: 0.01,
            distinct_deg: 5.0,
            icp,
        }
    }
}

/// One ranked pose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Candidate {
    /// `T_object_model` after the coarse ICP.
    #[serde(skip)]
    pub object_from_model: Isometry3<f64>,
    /// See the module docs.
    pub score: f64,
    /// See the module docs.
    pub inlier_fraction: f64,
}

/// Result of [`global_align`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GlobalResult {
    /// Hypotheses tried.
    pub hypotheses: usize,
    /// The distinct poses the hypotheses converged to after their coarse ICP, best first.
    pub candidates: Vec<Candidate>,
}

/// Centroid and right-handed principal axes (columns, largest variance first).
fn principal_frame(points: &[Point3<f32>]) -> Result<(Vector3<f64>, Matrix3<f64>)> {
    if points.len() < 4 {
        return Err(Error::invalid("global alignment", format!("{} points: too few for a frame", points.len())));
    }
    let n = points.len() as f64;
    let c = points.iter().fold(Vector3::zeros(), |a, p| a + p.coords.cast::<f64>()) / n;
    let cov = points.iter().fold(Matrix3::zeros(), |a, p| {
        let d = p.coords.cast::<f64>() - c;
        a + d * d.transpose()
    }) / n;
    let eig = cov.symmetric_eigen();
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let mut axes = Matrix3::from_columns(&order.map(|i| eig.eigenvectors.column(i).into_owned()));
    if axes.determinant() < 0.0 {
        axes.set_column(2, &(-axes.column(2)));
    }
    Ok((c, axes))
}

/// The 24 rotations that map the coordinate axes onto signed coordinate axes.
fn axis_rotations() -> Vec<Matrix3<f64>> {
    let perms = [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]];
    let mut out = Vec::with_capacity(24);
    for p in perms {
        for signs in 0..8u32 {
            let m = Matrix3::from_fn(|r, c| if p[c] == r { if signs >> c & 1 == 1 { -1.0 } else { 1.0 } } else { 0.0 });
            if m.determinant() > 0.0 {
                out.push(m);
            }
        }
    }
    out
}

/// Every hypothesis `T_object_model`: see the module docs.
fn hypotheses(model: &[Point3<f32>], cad: &[Point3<f32>], params: &GlobalParams) -> Result<Vec<Isometry3<f64>>> {
    let (cm, em) = principal_frame(model)?;
    let (cc, ec) = principal_frame(cad)?;
    let mut spins = vec![UnitQuaternion::identity()];
    for axis in 0..3 {
        let a = nalgebra::Unit::new_normalize(ec.column(axis).into_owned());
        for k in 1..=params.spins {
            for sign in [1.0, -1.0] {
                spins.push(UnitQuaternion::from_axis_angle(&a, sign * k as f64 * params.spin_deg.to_radians()));
            }
        }
    }
    let mut out = Vec::new();
    for s in axis_rotations() {
        let r = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&(ec * s * em.transpose())));
        for spin in &spins {
            let rotation = spin * r;
            let t = cc - rotation * cm;
            out.push(Isometry3::from_parts(Translation3::from(t), rotation));
        }
    }
    Ok(out)
}

/// `n` points of `points` drawn uniformly (with replacement; all of them when there are at most
/// `n`), seeded: a random subset cannot alias with a structured point order the way a stride can.
pub(crate) fn subset(points: &[Point3<f32>], n: usize, seed: u64) -> Vec<Point3<f32>> {
    if points.len() <= n || n == 0 {
        return points.to_vec();
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n).map(|_| points[rng.random_range(0..points.len())]).collect()
}

/// `(score, inlier_fraction)` of `object_from_model` on `points_model`; see the module docs.
pub fn score_alignment(
    points_model: &[Point3<f32>],
    object_from_model: &Isometry3<f64>,
    cad: &MeshDistance,
    threshold_m: f64,
) -> (f64, f64) {
    let moved: Vec<Point3<f64>> = points_model.iter().map(|p| object_from_model * p.cast::<f64>()).collect();
    let d = cad.distances(&moved);
    let n = d.len().max(1) as f64;
    let score = d.iter().map(|&d| (1.0 - (d / threshold_m).powi(2)).max(0.0)).sum::<f64>() / n;
    let inliers = d.iter().filter(|&&d| d <= threshold_m).count() as f64 / n;
    (score, inliers)
}

/// Ranks the global hypotheses of `model` against the CAD (`cad_samples`: surface samples with
/// outward normals, object frame; `cad`: exact distances); see the module docs.
///
/// # Errors
/// [`Error::Invalid`] for bad parameters or too few points after down-sampling.
pub fn global_align(
    model: &PointCloud,
    cad_samples: &PointCloud,
    cad: &MeshDistance,
    params: &GlobalParams,
) -> Result<GlobalResult> {
    if !(params.spin_deg.is_finite() && params.score_threshold_m > 0.0 && params.score_points > 0) {
        return Err(Error::invalid("global alignment parameters", format!("{params:?}")));
    }
    let voxel = VoxelParams { voxel_size_m: params.voxel_m };
    let model_small = downsample(model, &voxel)?;
    let cad_small = downsample(cad_samples, &voxel)?;
    let starts = hypotheses(&model_small.points, &cad_small.points, params)?;
    let scored = subset(&model.points, params.score_points, SCORE_SEED);
    let mut candidates: Vec<(usize, Candidate)> = starts
        .par_iter()
        .enumerate()
        .map(|(i, start)| {
            let t = register(&model_small, &cad_small, start, &params.icp)?.target_from_source;
            let (score, inlier_fraction) = score_alignment(&scored, &t, cad, params.score_threshold_m);
            Ok((i, Candidate { object_from_model: t, score, inlier_fraction }))
        })
        .collect::<Result<_>>()?;
    candidates.sort_by(|a, b| b.1.score.total_cmp(&a.1.score).then(a.0.cmp(&b.0)));
    let n = model_small.len().max(1) as f64;
    let centre = Point3::from(model_small.points.iter().fold(Vector3::zeros(), |a, p| a + p.coords.cast::<f64>()) / n);
    let mut distinct: Vec<Candidate> = Vec::new();
    for (_, c) in candidates {
        let same = |d: &Candidate| {
            let moved = (d.object_from_model * centre - c.object_from_model * centre).norm();
            let turned = (d.object_from_model.rotation.inverse() * c.object_from_model.rotation).angle();
            moved <= params.distinct_m && turned <= params.distinct_deg.to_radians()
        };
        if !distinct.iter().any(same) {
            distinct.push(c);
        }
    }
    Ok(GlobalResult { hypotheses: starts.len(), candidates: distinct })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_24_axis_rotations_are_distinct_and_proper() {
        let r = axis_rotations();
        assert_eq!(r.len(), 24);
        for (i, a) in r.iter().enumerate() {
            assert!((a.determinant() - 1.0).abs() < 1e-12);
            assert!(r[..i].iter().all(|b| (a - b).abs().max() > 0.5), "duplicate {a}");
        }
    }

    #[test]
    fn principal_frame_of_an_elongated_cloud() {
        let pts: Vec<Point3<f32>> = (0..1000)
            .map(|i| {
                let f = i as f32;
                Point3::new((f * 0.37).sin() * 3.0 + 1.0, (f * 0.91).cos() * 2.0, (f * 1.7).sin() * 0.5)
            })
            .collect();
        let (c, axes) = principal_frame(&pts).expect("frame");
        assert!((c.x - 1.0).abs() < 0.05, "{c}");
        assert!(axes.column(0).x.abs() > 0.99 && axes.column(1).y.abs() > 0.99, "{axes}");
        assert!((axes.determinant() - 1.0).abs() < 1e-9);
    }
}
