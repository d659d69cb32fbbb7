//! Point-to-plane ICP, coarse to fine, with a robust kernel (IRLS).
//!
//! Each level voxel-downsamples both clouds, gates correspondences by distance (and optionally by
//! normal angle), weights residuals with the kernel at a scale tied to the gate, and iterates
//! Gauss-Newton steps linearised about the moved source's centroid. The metrics are defined once:
//! - `fitness` = source points with a correspondence inside the final gate / source points (of the finest level);
//! - `inlier_rmse_m` = sqrt(mean over those correspondences of the squared point-to-plane residual);
//! - `conditioning` = smallest / largest eigenvalue of the final 6x6 system, rotations scaled by the
//!   cloud's RMS radius (near 0: the geometry does not constrain some direction, e.g. a flat wall).
//!
//! A direction of motion whose final eigenvalue is below `unobserved_ratio` times the largest is
//! unobserved (a cylinder's spin about its axis, a plane's in-plane slide): the registration then
//! runs again from the seed with every step's component along it removed, so the pose keeps the
//! seed's value there instead of sliding on noise (solution remapping, Zhang, Kaess & Singh, ICRA
//! 2016), and the result lists it (`unobserved`).

use std::borrow::Cow;

use nalgebra::{Isometry3, Matrix6, Point3, SymmetricEigen, Vector3, Vector6};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::kernel::Kernel;
use super::solve::{
    Hint, StepParams, System, Target, TargetIndex, hold, keeping, linearise, step_as_twist, step_motion, twist_as_step,
};
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::filter::voxel::{VoxelParams, downsample_cow};
use crate::spatial::LeafTree;

/// One resolution level of the coarse-to-fine schedule.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct IcpLevel {
    /// Voxel size both clouds are down-sampled to at this level, metres (0 = no down-sampling).
    pub voxel_m: f64,
    /// Correspondences farther than this are ignored, metres.
    pub max_correspondence_m: f64,
    /// Gauss-Newton iterations at most.
    pub max_iterations: usize,
}

/// Parameters of [`register`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct IcpParams {
    /// Levels, coarse first. Default: 10 mm voxels / 60 mm gate, then 4 / 15, then 2 / 5.
    pub levels: Vec<IcpLevel>,
    /// Robust kernel. Default Tukey, which gives far correspondences no weight at all.
    pub kernel: Kernel,
    /// Kernel scale as a fraction of the level's gate. Default 0.5.
    pub kernel_scale_ratio: f64,
    /// Reject correspondences whose nearest target point lies farther than this many level voxels
    /// along the target's tangent plane (boundary matches, which drag partially overlapping views
    /// toward the overlap). Used at levels with `voxel_m > 0`. Default 1.5.
    #[serde(with = "crate::off")]
    #[schemars(with = "Option<f64>")]
    pub max_tangential_voxels: Option<f64>,
    /// Reject correspondences whose normals differ by more than this (either sign), radians.
    /// Used only when the source has normals. Default 60 degrees.
    #[serde(with = "crate::off")]
    #[schemars(with = "Option<f64>")]
    pub max_normal_angle_rad: Option<f64>,
    /// The finest level has converged when a step moves less than this, metres; a coarser level
    /// when it moves less than this times its voxel over the finest level's (see
    /// [`IcpParams::level_convergence`]). Default 1e-5.
    pub convergence_translation_m: f64,
    /// Likewise for the rotation of a step, radians. Default 1e-5.
    pub convergence_rotation_rad: f64,
    /// At most this many source points per level (an even, deterministic stride over the
    /// down-sampled source); bounds the cost on dense views. Default 20 000.
    pub max_source_points: usize,
    /// A direction whose eigenvalue of the 6x6 system is below this fraction of the largest
    /// (rotations scaled by the cloud's RMS radius) is unobserved: no step moves the pose along it,
    /// so it keeps the seed's value there. 0 turns this off. Default 0 here; the fuse sets its own.
    pub unobserved_ratio: f64,
}

impl Default for IcpParams {
    fn default() -> Self {
        Self {
            levels: vec![
                IcpLevel { voxel_m: 0.010, max_correspondence_m: 0.060, max_iterations: 40 },
                IcpLevel { voxel_m: 0.004, max_correspondence_m: 0.015, max_iterations: 30 },
                IcpLevel { voxel_m: 0.002, max_correspondence_m: 0.005, max_iterations: 30 },
            ],
            kernel: Kernel::Tukey,
            kernel_scale_ratio: 0.5,
            max_tangential_voxels: Some(1.5),
            max_normal_angle_rad: Some(60f64.to_radians()),
            convergence_translation_m: 1e-5,
            convergence_rotation_rad: 1e-5,
            max_source_points: 20_000,
            unobserved_ratio: 0.0,
        }
    }
}

impl IcpParams {
    /// Level `k`'s convergence thresholds (translation m, rotation rad): the given ones scaled by
    /// the level's voxel over the finest level's (at least 1). A coarse level only has to bring the
    /// source into the next level's reach, and a step far below its voxel is below what its
    /// down-sampled clouds resolve: 15 mm voxels over a 6 mm finest level stop at 2.5x the
    /// thresholds (BENCHMARKS.md 63).
    #[must_use]
    pub fn level_convergence(&self, k: usize) -> (f64, f64) {
        let finest = self.levels.last().map_or(0.0, |l| l.voxel_m);
        let voxel = self.levels.get(k).map_or(0.0, |l| l.voxel_m);
        let scale = if finest > 0.0 { (voxel / finest).max(1.0) } else { 1.0 };
        (scale * self.convergence_translation_m, scale * self.convergence_rotation_rad)
    }

    /// Checks the values that have no meaning out of range: the kernel scale, the gates and the
    /// convergence thresholds (finite, the scale and the tangential gate positive, the rest at least
    /// 0); a NaN threshold would never converge, a NaN gate would drop every correspondence.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the field (`icp.<field>`).
    pub fn validate(&self) -> Result<()> {
        let positive: fn(f64) -> bool = |v| v.is_finite() && v > 0.0;
        let fraction: fn(f64) -> bool = |v| (0.0..1.0).contains(&v);
        let at_least_zero: fn(f64) -> bool = |v| v.is_finite() && v >= 0.0;
        let checks = [
            ("kernel_scale_ratio", Some(self.kernel_scale_ratio), positive, "> 0"),
            ("max_tangential_voxels", self.max_tangential_voxels, positive, "> 0"),
            ("max_normal_angle_rad", self.max_normal_angle_rad, at_least_zero, ">= 0"),
            ("convergence_translation_m", Some(self.convergence_translation_m), at_least_zero, ">= 0"),
            ("convergence_rotation_rad", Some(self.convergence_rotation_rad), at_least_zero, ">= 0"),
            ("unobserved_ratio", Some(self.unobserved_ratio), fraction, "in [0, 1)"),
        ];
        for (name, value, ok, range) in checks {
            if let Some(v) = value.filter(|&v| !ok(v)) {
                return Err(Error::invalid(format!("icp.{name}"), format!("{v} is not a finite number {range}")));
            }
        }
        Ok(())
    }
}

/// What happened at one level.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LevelStats {
    /// Source points at this level.
    pub source_points: usize,
    /// Target points at this level.
    pub target_points: usize,
    /// Iterations run.
    pub iterations: usize,
    /// True when the last step was below the convergence thresholds.
    pub converged: bool,
    /// Fitness at the level's last linearisation (before its final, converged or last, step).
    pub fitness: f64,
    /// Inlier point-to-plane RMSE at the level's last linearisation, metres.
    pub inlier_rmse_m: f64,
}

/// Result of [`register`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IcpResult {
    /// The estimated transform (maps source points into the target frame).
    #[serde(skip)]
    pub target_from_source: Isometry3<f64>,
    /// True when the finest level converged.
    pub converged: bool,
    /// Iterations over all levels.
    pub iterations: usize,
    /// See the module docs.
    pub fitness: f64,
    /// See the module docs, metres.
    pub inlier_rmse_m: f64,
    /// Correspondences inside the final gate.
    pub inliers: usize,
    /// See the module docs.
    pub conditioning: f64,
    /// Smallest / largest eigenvalue over the observed directions (`conditioning` when none is
    /// unobserved).
    pub observed_conditioning: f64,
    /// The unobserved directions (see the module docs), held at the seed, weakest first.
    pub unobserved: Vec<Unobserved>,
    /// Per-level statistics, coarse first.
    pub levels: Vec<LevelStats>,
}

/// What kind of motion an unobserved direction is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MotionKind {
    /// A rotation about `axis` through `point` (a sphere's or a cylinder's spin).
    Rotation,
    /// A translation along `axis` (a plane's or a cylinder's slide).
    Translation,
}

/// A direction of motion the registered surface does not constrain, target frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Unobserved {
    /// A rotation when the motion turns the source's points (`|ω|` times their RMS radius) at
    /// least as much as it moves their centroid, else a translation.
    pub kind: MotionKind,
    /// Unit axis of the rotation, or direction of the translation.
    pub axis: [f64; 3],
    /// The point of the rotation's axis nearest the source's centroid, or for a translation the
    /// centroid, metres.
    pub point: [f64; 3],
    /// Its eigenvalue of the final system over the largest (below `unobserved_ratio`).
    pub eigen_ratio: f64,
    /// The motion as a twist `(ω, v)`: a point `p` moves at `v + ω × p` (rad and m per unit; unit
    /// length with `ω` scaled by the RMS radius and `v` taken at the centroid).
    pub twist: [f64; 6],
}

impl Unobserved {
    /// Names the twist `(ω, v)` of a source whose points have their centroid at `centroid` and an
    /// RMS radius `radius_m` about it.
    pub(crate) fn describe(twist: &Vector6<f64>, eigen_ratio: f64, centroid: &Vector3<f64>, radius_m: f64) -> Self {
        let omega = Vector3::new(twist[0], twist[1], twist[2]);
        let v = Vector3::new(twist[3], twist[4], twist[5]);
        let at_centroid = v + omega.cross(centroid);
        let array = |a: Vector3<f64>| [a.x, a.y, a.z];
        let (kind, axis, point) = match omega.try_normalize(1e-12) {
            Some(axis) if omega.norm() * radius_m >= at_centroid.norm() => {
                // the axis: the points moving along ω; the one nearest the centroid
                let on_axis = omega.cross(&v) / omega.norm_squared();
                (MotionKind::Rotation, axis, on_axis + axis * axis.dot(&(centroid - on_axis)))
            }
            _ => (MotionKind::Translation, at_centroid.try_normalize(1e-12).unwrap_or_else(Vector3::x), *centroid),
        };
        Self { kind, axis: array(axis), point: array(point), eigen_ratio, twist: std::array::from_fn(|k| twist[k]) }
    }

    /// Whether `other` is the same motion (the same kind, axes within 5 degrees, rotation axes
    /// within 5 cm of each other at this one's point: where a spin's axis is put varies by a few
    /// centimetres from view to view).
    #[must_use]
    pub fn same_as(&self, other: &Unobserved) -> bool {
        let (a, b) = (Vector3::from(self.axis), Vector3::from(other.axis));
        if self.kind != other.kind || a.dot(&b).abs() < 5f64.to_radians().cos() {
            return false;
        }
        let offset = Vector3::from(other.point) - Vector3::from(self.point);
        self.kind == MotionKind::Translation || (offset - b * b.dot(&offset)).norm() < 0.05
    }

    /// The motions that keep this direction where it is, as a constraint `(α, β)` on twists
    /// `(ω, v)`: `α·ω + β·v = 0`. A rotation keeps its angle about `axis` (`ω·axis = 0`); a
    /// translation keeps the centroid's position along `axis`.
    #[must_use]
    pub fn constraint(&self) -> Vector6<f64> {
        let axis = Vector3::from(self.axis);
        match self.kind {
            MotionKind::Rotation => Vector6::new(axis.x, axis.y, axis.z, 0.0, 0.0, 0.0),
            MotionKind::Translation => {
                let alpha = Vector3::from(self.point).cross(&axis);
                Vector6::new(alpha.x, alpha.y, alpha.z, axis.x, axis.y, axis.z)
            }
        }
    }
}

fn level_cloud(cloud: &PointCloud, voxel_m: f64) -> Result<Cow<'_, PointCloud>> {
    if voxel_m > 0.0 { downsample_cow(cloud, &VoxelParams { voxel_size_m: voxel_m }) } else { Ok(Cow::Borrowed(cloud)) }
}

/// At most `max` points of `cloud`, taken at an even stride (all of them when it has fewer).
pub(super) fn thin(cloud: Cow<'_, PointCloud>, max: usize) -> PointCloud {
    if cloud.len() <= max || max == 0 {
        return cloud.into_owned();
    }
    let picks: Vec<usize> = (0..max).map(|i| i * cloud.len() / max).collect();
    cloud.select(&picks)
}

fn check(params: &IcpParams, source: &PointCloud, target: &PointCloud) -> Result<()> {
    params.validate()?;
    if params.levels.is_empty() {
        return Err(Error::invalid("ICP parameters", "no levels"));
    }
    if let Some(l) = params.levels.iter().find(|l| !(l.max_correspondence_m > 0.0) || !(l.voxel_m >= 0.0)) {
        return Err(Error::invalid("ICP parameters", format!("invalid level {l:?}")));
    }
    if source.len() < 6 || target.len() < 6 {
        return Err(Error::invalid(
            "ICP input",
            format!("too few points (source {}, target {})", source.len(), target.len()),
        ));
    }
    match &target.normals {
        Some(n) if n.len() == target.len() => Ok(()),
        _ => Err(Error::invalid("ICP target", "point-to-plane ICP needs target normals")),
    }
}

/// Moves the source points (and normals) by `t`, in f64.
pub(super) fn move_cloud(cloud: &PointCloud, t: &Isometry3<f64>) -> (Vec<Point3<f64>>, Option<Vec<Vector3<f64>>>) {
    let mut moved = (Vec::new(), None);
    move_cloud_into(cloud, t, &mut moved);
    moved
}

/// [`move_cloud`] into `moved`'s buffers (an ICP level's iterations reuse them).
fn move_cloud_into(cloud: &PointCloud, t: &Isometry3<f64>, moved: &mut (Vec<Point3<f64>>, Option<Vec<Vector3<f64>>>)) {
    let (points, normals) = moved;
    points.clear();
    points.extend(cloud.points.iter().map(|p| t * p.cast::<f64>()));
    match cloud.normals.as_ref() {
        Some(ns) => {
            let out = normals.get_or_insert_with(Vec::new);
            out.clear();
            out.extend(ns.iter().map(|n| t.rotation * n.cast::<f64>()));
        }
        None => *normals = None,
    }
}

fn centre_and_length(points: &[Point3<f64>]) -> (Vector3<f64>, f64) {
    let n = points.len().max(1) as f64;
    let centre = points.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let rms = (points.iter().map(|p| (p.coords - centre).norm_squared()).sum::<f64>() / n).sqrt();
    (centre, rms.max(1e-3))
}

/// Solves the damped normal equations, with no component along the directions `held` projects
/// out (a [`keeping`] projection); `None` when the system is singular.
fn solve_step(sys: &System, held: Option<&Matrix6<f64>>) -> Option<Vector6<f64>> {
    let (h, g) = match held {
        Some(p) => hold(&sys.h, &sys.g, p),
        None => (sys.h, sys.g),
    };
    let damping = 1e-9 * h.trace().max(1e-12);
    let h = h + Matrix6::identity() * damping;
    h.cholesky().map(|c| c.solve(&(-g)))
}

/// A direction unobserved in other views is unobserved in this one too when its information here
/// is below this many times `unobserved_ratio`.
const EXPECTED_FACTOR: f64 = 10.0;

/// `conditioning`, `observed_conditioning` and the unobserved directions (see [`IcpResult`]) of
/// the final system `sys`, linearised about `centre` with rotations scaled by `1/length`, when
/// `held` were held; without `held`, also each of `expected` whose information is below
/// [`EXPECTED_FACTOR`] times `ratio` (see [`register_levels_expecting`]).
fn spectrum(
    sys: &System,
    centre: &Vector3<f64>,
    length: f64,
    ratio: f64,
    held: &[Unobserved],
    held_constraints: &[Vector6<f64>],
    expected: &[Unobserved],
) -> (f64, f64, Vec<Unobserved>) {
    let eig = SymmetricEigen::new(sys.h);
    let hi = eig.eigenvalues.max();
    if !(hi > 0.0) {
        return (0.0, 0.0, held.to_vec());
    }
    let ratio_of = |l: f64| (l / hi).max(0.0);
    let conditioning = ratio_of(eig.eigenvalues.min());
    if !held.is_empty() {
        // the smallest eigenvalue over the steps that meet the held constraints
        // (the projection's rank deficit: constraints that repeat others add none)
        let p = keeping(held_constraints, centre, length);
        let removed = (6.0 - p.trace()).round().max(0.0) as usize;
        let mut kept: Vec<f64> = SymmetricEigen::new(p * sys.h * p).eigenvalues.iter().copied().collect();
        kept.sort_by(f64::total_cmp);
        return (conditioning, ratio_of(kept.get(removed).copied().unwrap_or(0.0)), held.to_vec());
    }
    let mut observed = f64::INFINITY;
    let mut unobserved = Vec::new();
    for (k, &l) in eig.eigenvalues.iter().enumerate() {
        if l < ratio * hi {
            let twist = step_as_twist(&eig.eigenvectors.column(k).into_owned(), centre, length);
            unobserved.push(Unobserved::describe(&twist, ratio_of(l), centre, length));
        } else {
            observed = observed.min(l);
        }
    }
    // a direction `expected` (unobserved in other views) that is weak here too: this view adds
    // too little to tell it apart from their noise
    for e in expected {
        let twist = Vector6::from(e.twist);
        let Some(u) = twist_as_step(&twist, centre, length).try_normalize(1e-12) else { continue };
        let weak = ratio_of(u.dot(&(sys.h * u)));
        if weak < EXPECTED_FACTOR * ratio && !unobserved.iter().any(|o| o.same_as(e)) {
            unobserved.push(Unobserved::describe(&twist, weak, centre, length));
        }
    }
    unobserved.sort_by(|a, b| a.eigen_ratio.total_cmp(&b.eigen_ratio));
    (conditioning, ratio_of(observed), unobserved)
}

/// A level's target index: built for one registration, or shared by a [`PreparedTarget`].
enum LevelIndex<'a> {
    Own(TargetIndex),
    Shared(&'a TargetIndex),
}

impl std::ops::Deref for LevelIndex<'_> {
    type Target = TargetIndex;
    fn deref(&self) -> &TargetIndex {
        match self {
            Self::Own(index) => index,
            Self::Shared(index) => index,
        }
    }
}

/// One level's target cloud, with its index when one is already built.
type LevelTarget<'a> = (Cow<'a, PointCloud>, Option<&'a TargetIndex>);

/// One level's down-sampled source, target and target index.
struct LevelData<'a> {
    src: PointCloud,
    tgt: Cow<'a, PointCloud>,
    index: LevelIndex<'a>,
}

/// Gauss-Newton iterations of one level from `t`: the moved pose, the level's statistics and its
/// last linear system.
fn run_level(
    data: &LevelData,
    k: usize,
    params: &IcpParams,
    mut t: Isometry3<f64>,
    held: &[Vector6<f64>],
) -> (Isometry3<f64>, LevelStats, Linearised) {
    let level = &params.levels[k];
    let (converged_m, converged_rad) = params.level_convergence(k);
    let LevelData { src, tgt, index } = data;
    let normals = tgt.normals.as_deref().unwrap_or_default();
    let target_l = Target { points: &tgt.points, normals, index };
    let min_cos = params.max_normal_angle_rad.map(f64::cos);
    let (mut iterations, mut converged) = (0, false);
    let mut buffers = move_cloud(src, &t);
    let length = centre_and_length(&buffers.0).1;
    let mut sys = None;
    let mut about = Vector3::zeros();
    let mut hints = vec![Hint::NONE; src.len()];
    while iterations < level.max_iterations {
        move_cloud_into(src, &t, &mut buffers);
        let (moved, moved_normals) = &buffers;
        let centre = centre_and_length(moved).0;
        let step = StepParams {
            max_distance_m: level.max_correspondence_m,
            max_tangential_m: params.max_tangential_voxels.filter(|_| level.voxel_m > 0.0).map(|k| k * level.voxel_m),
            min_normal_cos: min_cos,
            kernel: params.kernel,
            kernel_scale_m: params.kernel_scale_ratio * level.max_correspondence_m,
            centre,
            length_m: length,
        };
        let s = linearise(moved, moved_normals.as_deref(), &target_l, &step, &mut hints);
        iterations += 1;
        sys = Some(s);
        about = centre;
        let held = (!held.is_empty()).then(|| keeping(held, &centre, length));
        let Some(delta) = (s.inliers >= 6).then(|| solve_step(&s, held.as_ref())).flatten() else { break };
        let (motion, moved_m, turned_rad) = step_motion(&delta, &centre, length);
        t = motion * t;
        if turned_rad < converged_rad && moved_m < converged_m {
            converged = true;
            break;
        }
    }
    let s = sys.unwrap_or_else(System::zero);
    let n = src.len();
    let stats = LevelStats {
        source_points: n,
        target_points: tgt.len(),
        iterations,
        converged,
        fitness: s.inliers as f64 / n.max(1) as f64,
        inlier_rmse_m: if s.inliers > 0 { (s.residual_sq / s.inliers as f64).sqrt() } else { f64::INFINITY },
    };
    (t, stats, Linearised { system: s, centre: about, length })
}

/// A level's last linear system and what it was linearised about.
struct Linearised {
    system: System,
    centre: Vector3<f64>,
    length: f64,
}

/// Registers `source` to `target` (which must have normals), starting from `init`.
///
/// # Errors
/// [`Error::Invalid`] for empty levels, fewer than 6 points, or a target without normals.
pub fn register(
    source: &PointCloud,
    target: &PointCloud,
    init: &Isometry3<f64>,
    params: &IcpParams,
) -> Result<IcpResult> {
    check(params, source, target)?;
    run(source, init, params, |level| Ok((level_cloud(target, params.levels[level].voxel_m)?, None)), &[])
}

/// A target prepared for many registrations with the same levels ([`register_prepared`]): each
/// level's down-sampled cloud and its k-d tree, built once (the levels in parallel). Registering
/// onto it gives exactly what [`register`] onto the target gives, without rebuilding them.
pub struct PreparedTarget<'a> {
    /// Each level's voxel size, the cloud at it and its index.
    levels: Vec<(f64, Cow<'a, PointCloud>, TargetIndex)>,
}

impl std::fmt::Debug for PreparedTarget<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let sizes: Vec<(f64, usize)> = self.levels.iter().map(|(v, c, _)| (*v, c.len())).collect();
        f.debug_struct("PreparedTarget").field("levels (voxel_m, points)", &sizes).finish()
    }
}

impl<'a> PreparedTarget<'a> {
    /// `target` (with normals) at each of `params.levels`.
    ///
    /// # Errors
    /// As [`register`]'s checks of the target and the levels.
    pub fn new(target: &'a PointCloud, params: &IcpParams) -> Result<Self> {
        params.validate()?;
        if params.levels.is_empty() {
            return Err(Error::invalid("ICP parameters", "no levels"));
        }
        let levels = params
            .levels
            .par_iter()
            .map(|level| {
                let cloud = level_cloud(target, level.voxel_m)?;
                let index = TargetIndex::Tree(LeafTree::new(&cloud.points)?);
                Ok((level.voxel_m, cloud, index))
            })
            .collect::<Result<_>>()?;
        Ok(Self { levels })
    }

    /// The level at `voxel_m`, when prepared.
    fn level(&self, voxel_m: f64) -> Option<&(f64, Cow<'a, PointCloud>, TargetIndex)> {
        self.levels.iter().find(|(v, _, _)| *v == voxel_m)
    }
}

/// [`register`] onto a [`PreparedTarget`] (whose levels must include `params`' voxel sizes): the
/// same result, without down-sampling the target and building its index again.
///
/// # Errors
/// As [`register`]; [`Error::Invalid`] when a level of `params` was not prepared.
pub fn register_prepared(
    source: &PointCloud,
    target: &PreparedTarget<'_>,
    init: &Isometry3<f64>,
    params: &IcpParams,
) -> Result<IcpResult> {
    let mut levels = Vec::with_capacity(params.levels.len());
    for l in &params.levels {
        let Some(level) = target.level(l.voxel_m) else {
            return Err(Error::invalid("ICP target", format!("no level prepared at voxel {} m", l.voxel_m)));
        };
        check(params, source, &level.1)?;
        levels.push(level);
    }
    run(source, init, params, |k| Ok((Cow::Borrowed(levels[k].1.as_ref()), Some(&levels[k].2))), &[])
}

/// [`register`] to a target given already down-sampled at each level (`target_levels[k]` at
/// `params.levels[k].voxel_m`, with normals), e.g. kept up to date while a model grows.
///
/// # Errors
/// As [`register`]; [`Error::Invalid`] when there is not one target cloud per level.
pub fn register_levels(
    source: &PointCloud,
    target_levels: &[&PointCloud],
    init: &Isometry3<f64>,
    params: &IcpParams,
) -> Result<IcpResult> {
    register_levels_expecting(source, target_levels, init, params, &[])
}

/// [`register_levels`] where the directions `expected` were unobserved in other views of the same
/// object (a symmetry): each is unobserved here too when its information is below 10 times
/// `unobserved_ratio` (a view's own noise can make a symmetry look observed).
///
/// # Errors
/// As [`register_levels`].
pub fn register_levels_expecting(
    source: &PointCloud,
    target_levels: &[&PointCloud],
    init: &Isometry3<f64>,
    params: &IcpParams,
    expected: &[Unobserved],
) -> Result<IcpResult> {
    if target_levels.len() != params.levels.len() {
        return Err(Error::invalid(
            "ICP target levels",
            format!("{} target clouds for {} levels", target_levels.len(), params.levels.len()),
        ));
    }
    for target in target_levels {
        check(params, source, target)?;
    }
    run(source, init, params, |level| Ok((Cow::Borrowed(target_levels[level]), None)), expected)
}

/// The coarse-to-fine loop; `target_at(k)` gives level `k`'s target cloud. A result with
/// unobserved directions (`params.unobserved_ratio`) is run again from `init` with them held.
fn run<'a>(
    source: &PointCloud,
    init: &Isometry3<f64>,
    params: &IcpParams,
    target_at: impl Fn(usize) -> Result<LevelTarget<'a>> + Sync,
    expected: &[Unobserved],
) -> Result<IcpResult> {
    let free = run_holding(source, init, params, &target_at, &[], expected)?;
    if params.unobserved_ratio > 0.0 && !free.unobserved.is_empty() {
        let mut again = run_holding(source, init, params, &target_at, &free.unobserved, &[])?;
        again.iterations += free.iterations;
        return Ok(again);
    }
    Ok(free)
}

/// [`run`] with the directions `held` held at `init`.
fn run_holding<'a>(
    source: &PointCloud,
    init: &Isometry3<f64>,
    params: &IcpParams,
    target_at: &(impl Fn(usize) -> Result<LevelTarget<'a>> + Sync),
    held: &[Unobserved],
    expected: &[Unobserved],
) -> Result<IcpResult> {
    let mut t = *init;
    let mut levels = Vec::new();
    let mut last = None;
    let constraints: Vec<Vector6<f64>> = held.iter().map(Unobserved::constraint).collect();
    // A level's clouds and target index do not depend on the pose: the next level's are built
    // while this level iterates (two levels in memory at most).
    let build = |k: usize| -> Result<LevelData<'a>> {
        let src = thin(level_cloud(source, params.levels[k].voxel_m)?, params.max_source_points);
        let (tgt, built) = target_at(k)?;
        let index = match built {
            Some(index) => LevelIndex::Shared(index),
            None => LevelIndex::Own(TargetIndex::Tree(LeafTree::new(&tgt.points)?)),
        };
        Ok(LevelData { src, tgt, index })
    };
    let mut next = (!params.levels.is_empty()).then(|| build(0)).transpose()?;
    for k in 0..params.levels.len() {
        let Some(data) = next.take() else { break };
        let ((moved_to, stats, s), built) = rayon::join(
            || run_level(&data, k, params, t, &constraints),
            || (k + 1 < params.levels.len()).then(|| build(k + 1)).transpose(),
        );
        next = built?;
        t = moved_to;
        levels.push(stats);
        last = Some(s);
    }
    let last = last.unwrap_or(Linearised { system: System::zero(), centre: Vector3::zeros(), length: 1.0 });
    let s = last.system;
    let (conditioning, observed_conditioning, unobserved) =
        spectrum(&s, &last.centre, last.length, params.unobserved_ratio, held, &constraints, expected);
    let fin = levels.last().copied().ok_or_else(|| Error::invalid("ICP parameters", "no levels"))?;
    Ok(IcpResult {
        target_from_source: t,
        converged: fin.converged,
        iterations: levels.iter().map(|l| l.iterations).sum(),
        fitness: fin.fitness,
        inlier_rmse_m: fin.inlier_rmse_m,
        inliers: s.inliers,
        conditioning,
        observed_conditioning,
        unobserved,
        levels,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    /// A cylinder's side (radius 0.15 m about the z axis through (0.3, -0.2)) over a 0.6 m floor
    /// disc, exact normals, 5 mm apart: nothing constrains the spin about the axis.
    fn cylinder_on_floor() -> PointCloud {
        let (axis, r) = (Vector3::new(0.3, -0.2, 0.0), 0.15);
        let (mut points, mut normals) = (Vec::new(), Vec::new());
        for k in 0..190 {
            let a = k as f64 * std::f64::consts::TAU / 190.0;
            for h in 1..100 {
                let n = Vector3::new(a.cos(), a.sin(), 0.0);
                points.push(Point3::from(axis + n * r + Vector3::z() * (h as f64 * 0.005)).cast());
                normals.push(n.cast());
            }
        }
        for i in -60..=60 {
            for j in -60..=60 {
                let p = Vector3::new(i as f64 * 0.005, j as f64 * 0.005, 0.0);
                if p.norm() < 0.3 && p.norm() > r {
                    points.push(Point3::from(axis + p).cast());
                    normals.push(Vector3::z());
                }
            }
        }
        PointCloud { points, normals: Some(normals), colors: None }
    }

    #[test]
    fn a_spin_nothing_constrains_stays_at_the_seed_and_is_named() {
        let target = cylinder_on_floor();
        let level = |voxel_m, max_correspondence_m| IcpLevel { voxel_m, max_correspondence_m, max_iterations: 30 };
        let params = IcpParams {
            levels: vec![level(0.01, 0.05), level(0.005, 0.01)],
            unobserved_ratio: 1e-3,
            ..IcpParams::default()
        };
        // the seed: 2 cm and 1 cm off in x and y, and turned 3 deg about the cylinder's axis
        let about_axis = Translation3::new(0.3, -0.2, 0.0)
            * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 3f64.to_radians())
            * Translation3::new(-0.3, 0.2, 0.0);
        let seed = Isometry3::from_parts(Translation3::new(0.02, 0.01, 0.0), UnitQuaternion::identity()) * about_axis;
        let r = register(&target, &target, &seed, &params).expect("register");
        // onto the target prepared once: the same registration, bit for bit (its run again with
        // the spin held too)
        let prepared = PreparedTarget::new(&target, &params).expect("prepare");
        let again = register_prepared(&target, &prepared, &seed, &params).expect("register prepared");
        assert_eq!(format!("{again:?}"), format!("{r:?}"));
        let other = IcpParams { levels: vec![level(0.02, 0.05)], ..params.clone() };
        let e = register_prepared(&target, &prepared, &seed, &other).expect_err("a level not prepared");
        assert!(e.to_string().contains("no level prepared"), "{e}");
        // the slide is corrected, the spin kept: the cylinder's points land on themselves turned 3 deg
        assert_eq!(r.unobserved.len(), 1, "{:?}", r.unobserved);
        let u = &r.unobserved[0];
        assert_eq!(u.kind, MotionKind::Rotation);
        assert!(u.axis[2].abs() > 0.9999, "{:?}", u.axis);
        assert!((u.point[0] - 0.3).abs() < 1e-3 && (u.point[1] + 0.2).abs() < 1e-3, "{:?}", u.point);
        let d = r.target_from_source * about_axis.inverse();
        assert!(d.translation.vector.norm() < 1e-4 && d.rotation.angle() < 1e-4, "{d:?}");
        assert!(r.observed_conditioning > 1e-2 && r.conditioning < 1e-3, "{r:?}"); // measured 0.47, 1.1e-4
        // without the hold the spin is free: the result reports nothing unobserved
        let free = register(&target, &target, &seed, &IcpParams { unobserved_ratio: 0.0, ..params }).expect("register");
        assert!(free.unobserved.is_empty() && free.observed_conditioning == free.conditioning);
    }

    #[test]
    fn a_coarse_level_converges_at_thresholds_scaled_by_its_voxel() {
        let level = |voxel_m| IcpLevel { voxel_m, max_correspondence_m: 0.03, max_iterations: 30 };
        let params = IcpParams {
            levels: vec![level(0.015), level(0.006), level(0.003)],
            convergence_translation_m: 1e-4,
            convergence_rotation_rad: 2e-4,
            ..IcpParams::default()
        };
        let close = |(m, rad): (f64, f64), want: (f64, f64)| (m - want.0).abs() < 1e-12 && (rad - want.1).abs() < 1e-12;
        assert!(close(params.level_convergence(0), (5e-4, 1e-3)), "{:?}", params.level_convergence(0));
        assert!(close(params.level_convergence(1), (2e-4, 4e-4)), "{:?}", params.level_convergence(1));
        assert!(close(params.level_convergence(2), (1e-4, 2e-4)), "{:?}", params.level_convergence(2));
        // a level finer than the last, or a last level without down-sampling: the thresholds as given
        let odd = IcpParams { levels: vec![level(0.002), level(0.004)], ..params.clone() };
        assert!(close(odd.level_convergence(0), (1e-4, 2e-4)));
        let raw = IcpParams { levels: vec![level(0.01), level(0.0)], ..params };
        assert!(close(raw.level_convergence(0), (1e-4, 2e-4)));
    }

    #[test]
    fn out_of_range_thresholds_and_gates_are_refused_by_name() {
        assert!(IcpParams::default().validate().is_ok());
        let gates_off = IcpParams { max_tangential_voxels: None, max_normal_angle_rad: None, ..IcpParams::default() };
        assert!(gates_off.validate().is_ok());
        let cloud = PointCloud {
            points: (0..8).map(|i| Point3::new(i as f32 * 0.01, (i % 3) as f32 * 0.01, 0.0)).collect(),
            normals: Some(vec![Vector3::z(); 8]),
            colors: None,
        };
        type Set = fn(&mut IcpParams, f64);
        let cases: [(&str, Set); 4] = [
            ("icp.convergence_translation_m", |p, v| p.convergence_translation_m = v),
            ("icp.convergence_rotation_rad", |p, v| p.convergence_rotation_rad = v),
            ("icp.kernel_scale_ratio", |p, v| p.kernel_scale_ratio = v),
            ("icp.max_tangential_voxels", |p, v| p.max_tangential_voxels = Some(v)),
        ];
        for (name, set) in cases {
            for bad in [f64::NAN, f64::INFINITY, -1.0] {
                let mut params = IcpParams::default();
                set(&mut params, bad);
                let e = register(&cloud, &cloud, &Isometry3::identity(), &params).expect_err(name).to_string();
                assert!(e.contains(name), "{e}");
            }
        }
        let params = IcpParams { max_normal_angle_rad: Some(f64::NAN), ..IcpParams::default() };
        assert!(params.validate().expect_err("NaN angle").to_string().contains("icp.max_normal_angle_rad"));
        // a fraction of the largest eigenvalue: [0, 1)
        for bad in [f64::NAN, -0.1, 1.0, 5.0] {
            let params = IcpParams { unobserved_ratio: bad, ..IcpParams::default() };
            assert!(params.validate().expect_err("ratio").to_string().contains("icp.unobserved_ratio"), "{bad}");
        }
        assert!(IcpParams { unobserved_ratio: 1e-3, ..IcpParams::default() }.validate().is_ok());
    }
}
