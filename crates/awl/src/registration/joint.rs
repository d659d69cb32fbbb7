//! Joint refinement of many views: point-to-plane ICP over every overlapping pair at once.
//!
//! Registering views one after the other against a growing model lets errors pile up: a view
//! placed a few millimetres off carries the views registered after it, and no later view can
//! pull the group back (a sequential pass drifts). Here every view's pose is a variable and
//! every overlapping ordered pair `(i, j)` adds the point-to-plane residuals of view `i`'s
//! source points against view `j`'s surface: `r = n_j·(T_i p − T_j q)`, `q` the nearest point of
//! view `j`, `n_j` its normal, both in the world frame. One Gauss-Newton step solves for all
//! poses together (the first view fixed), so a drifting group moves as a group.
//!
//! A residual depends on the relative pose only: with left perturbations about a common centre
//! `c`, its Jacobian is `a = [(p − c) × n, n]` for view `i` and `−a` for view `j` (the normal
//! turns with view `j`), so each pair contributes one 6x6 block `Σ w a aᵀ` and one vector
//! `Σ w r a` to the `6N` system. Pairs are linearised in parallel and summed in pair order:
//! the result does not depend on the number of threads.

use std::borrow::Cow;

use nalgebra::{DMatrix, DVector, Isometry3, Matrix6, Point3, Vector3, Vector6};
use rayon::prelude::*;

use super::icp::{IcpLevel, IcpParams, move_cloud, thin};
use super::solve::{Hint, StepParams, System, Target, TargetIndex, hold, keeping, linearise, step_motion};
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::filter::voxel::{VoxelParams, downsample_cow};

/// What [`refine_jointly`] did, per level.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct JointLevelStats {
    /// Gauss-Newton steps taken.
    pub iterations: usize,
    /// True when the last step was below the convergence thresholds.
    pub converged: bool,
    /// Ordered view pairs with at least one correspondence at the last step.
    pub pairs: usize,
    /// Correspondences inside the gate at the last step.
    pub inliers: usize,
    /// Their point-to-plane RMSE, metres.
    pub inlier_rmse_m: f64,
}

/// One view at one level: its down-sampled cloud (camera frame; the view's own when it is already
/// at the level's voxel size), its index, its source points.
struct ViewLevel<'a> {
    cloud: Cow<'a, PointCloud>,
    index: TargetIndex,
    source: PointCloud,
}

/// Refines `poses` (`T_world_camera` of each cloud, camera-frame clouds with normals) jointly;
/// `poses[fixed]` does not move, and view `i` moves only by twists `(ω, v)` (world frame: a point
/// `p` moves at `v + ω × p`) that meet its constraints `held[i]` (`(α, β)`: `α·ω + β·v = 0`, as
/// [`super::Unobserved::constraint`] gives; an empty or short `held`: none). `params` as for pairwise ICP: its levels (each with a voxel size),
/// kernel, gates, convergence thresholds (the largest step over the views) and source points per
/// view and level.
///
/// # Errors
/// [`Error::Invalid`] for fewer than two views, a view without normals, bad levels or thresholds
/// (see [`IcpParams::validate`]) or `fixed` out of range.
pub fn refine_jointly(
    clouds: &[&PointCloud],
    poses: &mut [Isometry3<f64>],
    fixed: usize,
    held: &[Vec<Vector6<f64>>],
    params: &IcpParams,
) -> Result<Vec<JointLevelStats>> {
    if clouds.len() != poses.len() || fixed >= clouds.len() {
        return Err(Error::invalid("joint refinement", "one pose per view and a fixed view among them"));
    }
    if let Some(i) = clouds.iter().position(|c| c.normals.as_ref().map(Vec::len) != Some(c.len())) {
        return Err(Error::invalid("joint refinement", format!("view {i} has no normals")));
    }
    params.validate()?;
    if let Some(l) = params.levels.iter().find(|l| !(l.max_correspondence_m > 0.0) || !(l.voxel_m > 0.0)) {
        return Err(Error::invalid("joint refinement", format!("invalid level {l:?}")));
    }
    let mut stats = Vec::new();
    if clouds.len() < 2 {
        return Ok(stats);
    }
    for level in &params.levels {
        let views = clouds
            .par_iter()
            .map(|c| view_level(c, level.voxel_m, params.max_source_points))
            .collect::<Result<Vec<_>>>()?;
        stats.push(run_level(&views, poses, fixed, held, level, params));
    }
    Ok(stats)
}

fn view_level(cloud: &PointCloud, voxel_m: f64, max_source: usize) -> Result<ViewLevel<'_>> {
    let mut cloud = downsample_cow(cloud, &VoxelParams { voxel_size_m: voxel_m })?;
    if let Cow::Owned(c) = &mut cloud {
        c.colors = None; // the targets need points and normals only
    }
    let index = TargetIndex::of_view(&cloud.points)?;
    let source = thin(Cow::Borrowed(&*cloud), max_source);
    Ok(ViewLevel { cloud, index, source })
}

fn run_level(
    views: &[ViewLevel],
    poses: &mut [Isometry3<f64>],
    fixed: usize,
    held: &[Vec<Vector6<f64>>],
    level: &IcpLevel,
    params: &IcpParams,
) -> JointLevelStats {
    let n = views.len();
    // Ordered pairs grouped by target view (a thread's consecutive pairs search the same view's
    // grid, warm in cache); their sums are added in source-view order: `by_source` lists the
    // position of `(i, j)` in `pairs`, `j (n - 1)` plus `i`'s rank among the views other than `j`.
    let pairs: Vec<(usize, usize)> =
        (0..n).flat_map(|j| (0..n).filter(move |&i| i != j).map(move |i| (i, j))).collect();
    let by_source: Vec<usize> = (0..n)
        .flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| j * (n - 1) + i - usize::from(i > j)))
        .collect();
    // Common centre and scale of the rotation unknowns: the views' cameras.
    let centre = poses.iter().fold(Vector3::zeros(), |a, p| a + p.translation.vector) / n as f64;
    let length =
        (poses.iter().map(|p| (p.translation.vector - centre).norm_squared()).sum::<f64>() / n as f64).sqrt().max(0.1);
    let mut out = JointLevelStats { iterations: 0, converged: false, pairs: 0, inliers: 0, inlier_rmse_m: 0.0 };
    // What each pair's source points found at the previous step (see `Hint`).
    let mut hints: Vec<Vec<Hint>> = pairs.iter().map(|&(i, _)| vec![Hint::NONE; views[i].source.len()]).collect();
    let step = StepParams {
        max_distance_m: level.max_correspondence_m,
        max_tangential_m: params.max_tangential_voxels.map(|k| k * level.voxel_m),
        min_normal_cos: params.max_normal_angle_rad.map(f64::cos),
        kernel: params.kernel,
        kernel_scale_m: params.kernel_scale_ratio * level.max_correspondence_m,
        centre,
        length_m: length,
    };
    while out.iterations < level.max_iterations {
        let sums: Vec<Option<System>> = pairs
            .par_iter()
            .zip(hints.par_iter_mut())
            .map(|(&(i, j), hint)| pair_system(&views[i], &views[j], (&poses[i], &poses[j]), hint, &step))
            .collect();
        out.iterations += 1;
        let dim = 6 * n;
        let mut h = DMatrix::<f64>::zeros(dim, dim);
        let mut g = DVector::<f64>::zeros(dim);
        let (mut inliers, mut residual_sq, mut used) = (0, 0.0, 0);
        for &k in &by_source {
            let ((i, j), Some(s)) = (pairs[k], &sums[k]) else { continue };
            used += 1;
            inliers += s.inliers;
            residual_sq += s.residual_sq;
            for (a, sa) in [(i, 1.0), (j, -1.0)] {
                let mut rows = g.fixed_rows_mut::<6>(6 * a);
                rows += s.g * sa;
                for (b, sb) in [(i, 1.0), (j, -1.0)] {
                    let mut block = h.fixed_view_mut::<6, 6>(6 * a, 6 * b);
                    block += s.h * (sa * sb);
                }
            }
        }
        out.pairs = used;
        out.inliers = inliers;
        out.inlier_rmse_m = if inliers > 0 { (residual_sq / inliers as f64).sqrt() } else { 0.0 };
        // The fixed view: its unknowns pinned to zero.
        for k in 6 * fixed..6 * fixed + 6 {
            h.row_mut(k).fill(0.0);
            h.column_mut(k).fill(0.0);
            h[(k, k)] = 1.0;
            g[k] = 0.0;
        }
        // The held directions: each view's unknowns projected onto the steps that keep them.
        if held.iter().any(|t| !t.is_empty()) {
            let mut p = DMatrix::<f64>::identity(dim, dim);
            for (v, constraints) in held.iter().enumerate().filter(|(v, c)| *v < n && !c.is_empty()) {
                p.fixed_view_mut::<6, 6>(6 * v, 6 * v).copy_from(&keeping(constraints, &centre, length));
            }
            (h, g) = hold(&h, &g, &p);
        }
        let damping = 1e-9 * (h.trace() / dim as f64).max(1e-12);
        for k in 0..dim {
            h[(k, k)] += damping;
        }
        let Some(delta) = h.cholesky().map(|c| c.solve(&(-g))) else { break };
        let mut largest = (0.0f64, 0.0f64);
        for (v, pose) in poses.iter_mut().enumerate() {
            if v == fixed {
                continue;
            }
            let (motion, moved_m, turned_rad) =
                step_motion(&delta.fixed_rows::<6>(6 * v).into_owned(), &centre, length);
            *pose = motion * *pose;
            largest = (largest.0.max(moved_m), largest.1.max(turned_rad));
        }
        if largest.0 < params.convergence_translation_m && largest.1 < params.convergence_rotation_rad {
            out.converged = true;
            break;
        }
    }
    out
}

/// View `i`'s source points against view `j`: `linearise` in view `j`'s frame (so `hints`, what
/// each source point found at the previous step, bound or skip its search as in pairwise ICP),
/// then turned into the world frame (`a_world = diag(R_j, R_j) a_j`); `None` without
/// correspondences. `step.centre` is in the world frame.
fn pair_system(
    vi: &ViewLevel,
    vj: &ViewLevel,
    (world_from_i, world_from_j): (&Isometry3<f64>, &Isometry3<f64>),
    hints: &mut [Hint],
    step: &StepParams,
) -> Option<System> {
    let j_from_world = world_from_j.inverse();
    let (moved, moved_normals) = move_cloud(&vi.source, &(j_from_world * world_from_i));
    let target = Target { points: &vj.cloud.points, normals: vj.cloud.normals.as_deref()?, index: &vj.index };
    let centre = (j_from_world * Point3::from(step.centre)).coords;
    let s = linearise(&moved, moved_normals.as_deref(), &target, &StepParams { centre, ..*step }, hints);
    if s.inliers == 0 {
        return None;
    }
    let r = world_from_j.rotation.to_rotation_matrix().into_inner();
    let mut b = Matrix6::zeros();
    b.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    b.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    Some(System { h: b * s.h * b.transpose(), g: b * s.g, ..s })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    /// Three faces of a box and a floor, seen from four sides: points in the world frame.
    fn scene() -> Vec<Point3<f32>> {
        let mut pts = Vec::new();
        let step = 0.004;
        for a in 0..100 {
            for b in 0..100 {
                let (u, v) = (a as f32 * step - 0.2, b as f32 * step - 0.2);
                pts.push(Point3::new(u * 2.0, v * 2.0, 0.0)); // floor
                if (0.0..0.3).contains(&(v + 0.2)) {
                    pts.push(Point3::new(u, -0.2, v + 0.2)); // front
                    pts.push(Point3::new(-0.2, u, v + 0.2)); // left
                    pts.push(Point3::new(0.2, u, v + 0.2)); // right
                    pts.push(Point3::new(u, 0.2, v + 0.2)); // back
                }
                pts.push(Point3::new(u, v, 0.3)); // top
            }
        }
        pts
    }

    #[test]
    fn recovers_perturbed_views_and_keeps_the_fixed_one() {
        let world = scene();
        let truth: Vec<Isometry3<f64>> = (0..4)
            .map(|k| {
                let yaw = k as f64 * std::f64::consts::FRAC_PI_2;
                Isometry3::new(Vector3::new(0.05 * k as f64, 0.0, 0.1), Vector3::new(0.1, 0.0, yaw))
            })
            .collect();
        // Each view sees the whole scene (in its own frame), with normals from the scene's faces.
        let clouds: Vec<PointCloud> = truth
            .iter()
            .map(|t| {
                let inv = t.inverse();
                let mut c = PointCloud::from_points(world.iter().map(|p| (inv * p.cast::<f64>()).cast()).collect());
                let normals = world
                    .iter()
                    .map(|p| {
                        let n = if p.z == 0.0 || (p.z - 0.3).abs() < 1e-6 {
                            Vector3::z()
                        } else if (p.y.abs() - 0.2).abs() < 1e-6 {
                            Vector3::y() * p.y.signum() as f64
                        } else {
                            Vector3::x() * p.x.signum() as f64
                        };
                        (inv.rotation * n).cast()
                    })
                    .collect();
                c.normals = Some(normals);
                c
            })
            .collect();
        let refs: Vec<&PointCloud> = clouds.iter().collect();
        let mut poses: Vec<Isometry3<f64>> = truth
            .iter()
            .enumerate()
            .map(|(k, t)| {
                if k == 0 {
                    *t
                } else {
                    Isometry3::new(Vector3::new(0.003, -0.002, 0.002) * k as f64, Vector3::new(0.002, -0.001, 0.003))
                        * t
                }
            })
            .collect();
        let params = IcpParams {
            levels: vec![IcpLevel { voxel_m: 0.004, max_correspondence_m: 0.03, max_iterations: 50 }],
            convergence_translation_m: 1e-7,
            convergence_rotation_rad: 1e-7,
            max_source_points: 5000,
            ..IcpParams::default()
        };
        let stats = refine_jointly(&refs, &mut poses, 0, &[], &params).expect("refine");
        assert!(stats[0].converged, "{stats:?}");
        assert_eq!(poses[0], truth[0]);
        for (k, (p, t)) in poses.iter().zip(&truth).enumerate() {
            let d = p.inverse() * t;
            assert!(d.translation.vector.norm() < 1e-4 && d.rotation.angle() < 1e-4, "view {k}: {d:?}");
        }
    }
}
