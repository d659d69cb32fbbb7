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

use nalgebra::{DMatrix, DVector, Isometry3, Matrix6, Point3, Translation3, UnitQuaternion, Vector3, Vector6};
use rayon::prelude::*;

use super::icp::{IcpLevel, IcpParams};
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::filter::voxel::{VoxelParams, downsample};
use crate::spatial::KdIndex;

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

/// One view at one level: its down-sampled cloud (camera frame), its tree, its source points.
struct ViewLevel {
    cloud: PointCloud,
    index: KdIndex,
    source: Vec<usize>,
    /// Bounds of the cloud in its camera frame.
    lo: Point3<f32>,
    hi: Point3<f32>,
}

/// One pair's sums.
#[derive(Clone, Copy)]
struct PairSums {
    h: Matrix6<f64>,
    g: Vector6<f64>,
    inliers: usize,
    residual_sq: f64,
}

/// Refines `poses` (`T_world_camera` of each cloud, camera-frame clouds with normals) jointly;
/// `poses[fixed]` does not move. `params` as for pairwise ICP: its levels (each with a voxel size),
/// kernel, gates, convergence thresholds (the largest step over the views) and source points per
/// view and level.
///
/// # Errors
/// [`Error::Invalid`] for fewer than two views, a view without normals, bad levels or `fixed`
/// out of range.
pub fn refine_jointly(
    clouds: &[&PointCloud],
    poses: &mut [Isometry3<f64>],
    fixed: usize,
    params: &IcpParams,
) -> Result<Vec<JointLevelStats>> {
    if clouds.len() != poses.len() || fixed >= clouds.len() {
        return Err(Error::invalid("joint refinement", "one pose per view and a fixed view among them"));
    }
    if let Some(i) = clouds.iter().position(|c| c.normals.as_ref().map(Vec::len) != Some(c.len())) {
        return Err(Error::invalid("joint refinement", format!("view {i} has no normals")));
    }
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
        stats.push(run_level(&views, poses, fixed, level, params));
    }
    Ok(stats)
}

fn view_level(cloud: &PointCloud, voxel_m: f64, max_source: usize) -> Result<ViewLevel> {
    let cloud = downsample(cloud, &VoxelParams { voxel_size_m: voxel_m })?;
    let index = KdIndex::new(&cloud.points)?;
    let n = cloud.len();
    let source = if n <= max_source || max_source == 0 {
        (0..n).collect()
    } else {
        (0..max_source).map(|i| i * n / max_source).collect()
    };
    let inf = f32::INFINITY;
    let (lo, hi) = cloud
        .points
        .iter()
        .fold((Point3::new(inf, inf, inf), Point3::new(-inf, -inf, -inf)), |(lo, hi), p| (lo.inf(p), hi.sup(p)));
    Ok(ViewLevel { cloud, index, source, lo, hi })
}

fn run_level(
    views: &[ViewLevel],
    poses: &mut [Isometry3<f64>],
    fixed: usize,
    level: &IcpLevel,
    params: &IcpParams,
) -> JointLevelStats {
    let n = views.len();
    let pairs: Vec<(usize, usize)> =
        (0..n).flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j))).collect();
    // Common centre and scale of the rotation unknowns: the views' cameras.
    let centre = poses.iter().fold(Vector3::zeros(), |a, p| a + p.translation.vector) / n as f64;
    let length =
        (poses.iter().map(|p| (p.translation.vector - centre).norm_squared()).sum::<f64>() / n as f64).sqrt().max(0.1);
    let mut out = JointLevelStats { iterations: 0, converged: false, pairs: 0, inliers: 0, inlier_rmse_m: 0.0 };
    // Each pair's previous correspondences (see `pair_sums`).
    let mut hints: Vec<Vec<u32>> = pairs.iter().map(|&(i, _)| vec![u32::MAX; views[i].source.len()]).collect();
    while out.iterations < level.max_iterations {
        let sums: Vec<Option<PairSums>> = pairs
            .par_iter()
            .zip(hints.par_iter_mut())
            .map(|(&(i, j), hint)| {
                let poses = (&poses[i], &poses[j]);
                pair_sums(&views[i], &views[j], poses, hint, level, params, (&centre, length))
            })
            .collect();
        out.iterations += 1;
        let dim = 6 * n;
        let mut h = DMatrix::<f64>::zeros(dim, dim);
        let mut g = DVector::<f64>::zeros(dim);
        let (mut inliers, mut residual_sq, mut used) = (0, 0.0, 0);
        for (&(i, j), s) in pairs.iter().zip(&sums) {
            let Some(s) = s else { continue };
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
            let d = delta.fixed_rows::<6>(6 * v);
            let omega = Vector3::new(d[0], d[1], d[2]) / length;
            let t = Vector3::new(d[3], d[4], d[5]);
            let about_centre =
                Translation3::from(centre + t) * UnitQuaternion::from_scaled_axis(omega) * Translation3::from(-centre);
            *pose = about_centre * *pose;
            largest = (largest.0.max(t.norm()), largest.1.max(omega.norm()));
        }
        if largest.0 < params.convergence_translation_m && largest.1 < params.convergence_rotation_rad {
            out.converged = true;
            break;
        }
    }
    out
}

/// The sums of view `i`'s source points against view `j`; `None` without correspondences.
///
/// `previous` holds each source point's correspondence at the previous step (`u32::MAX`: none);
/// the poses move little between steps, so the distance to it bounds the search (a hair wider,
/// so that it stays inside): the nearest point is the same, found sooner.
fn pair_sums(
    vi: &ViewLevel,
    vj: &ViewLevel,
    (world_from_i, world_from_j): (&Isometry3<f64>, &Isometry3<f64>),
    previous: &mut [u32],
    level: &IcpLevel,
    params: &IcpParams,
    (centre, length): (&Vector3<f64>, f64),
) -> Option<PairSums> {
    let gate = level.max_correspondence_m;
    let gate_f = gate as f32;
    let j_from_i = world_from_j.inverse() * world_from_i;
    let max_tangential = params.max_tangential_voxels.map(|k| k * level.voxel_m);
    let min_cos = params.max_normal_angle_rad.map(f64::cos);
    let scale = params.kernel_scale_ratio * gate;
    let (ni, nj) = (vi.cloud.normals.as_deref()?, vj.cloud.normals.as_deref()?);
    let mut s = PairSums { h: Matrix6::zeros(), g: Vector6::zeros(), inliers: 0, residual_sq: 0.0 };
    for (&k, hint) in vi.source.iter().zip(previous.iter_mut()) {
        let p_j = j_from_i * vi.cloud.points[k].cast::<f64>();
        let q = p_j.cast::<f32>();
        let outside = (0..3).any(|a| q[a] < vj.lo[a] - gate_f || q[a] > vj.hi[a] + gate_f);
        let radius = match vj.cloud.points.get(*hint as usize) {
            Some(prev) => ((prev - q).norm() * (1.0 + 1e-4) + 1e-6).min(gate_f),
            None => gate_f,
        };
        let found = if outside { None } else { vj.index.nearest_within(&q, radius) };
        *hint = found.map_or(u32::MAX, |nb| nb.index);
        let Some(nb) = found else { continue };
        let t = vj.cloud.points[nb.index as usize].cast::<f64>();
        let n = nj[nb.index as usize].cast::<f64>();
        if let Some(cos) = min_cos {
            if (j_from_i.rotation * ni[k].cast::<f64>()).dot(&n) < cos {
                continue;
            }
        }
        let offset = p_j - t;
        let r = n.dot(&offset);
        if let Some(max) = max_tangential {
            if (offset - n * r).norm_squared() > max * max {
                continue;
            }
        }
        s.inliers += 1;
        s.residual_sq += r * r;
        let w = params.kernel.weight(r, scale);
        if w <= 0.0 {
            continue;
        }
        // World-frame arm and normal.
        let p_w = world_from_j * p_j;
        let n_w = world_from_j.rotation * n;
        let arm = (p_w.coords - centre) / length;
        let rot = arm.cross(&n_w);
        let a = Vector6::new(rot.x, rot.y, rot.z, n_w.x, n_w.y, n_w.z);
        s.h += w * a * a.transpose();
        s.g += w * r * a;
    }
    (s.inliers > 0).then_some(s)
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
        let stats = refine_jointly(&refs, &mut poses, 0, &params).expect("refine");
        assert!(stats[0].converged, "{stats:?}");
        assert_eq!(poses[0], truth[0]);
        for (k, (p, t)) in poses.iter().zip(&truth).enumerate() {
            let d = p.inverse() * t;
            assert!(d.translation.vector.norm() < 1e-4 && d.rotation.angle() < 1e-4, "view {k}: {d:?}");
        }
    }
}
