//! One Gauss-Newton step of point-to-plane ICP: correspondences, robust weights, the 6x6 system.
//!
//! The sums are taken per fixed-size chunk in parallel and then added in chunk order, so the
//! result is bit-identical whatever the number of threads.

use nalgebra::allocator::Allocator;
use nalgebra::{
    DefaultAllocator, Dim, Isometry3, Matrix6, OMatrix, OVector, Point3, Translation3, UnitQuaternion, Vector3, Vector6,
};
use rayon::prelude::*;

use super::kernel::Kernel;
use crate::spatial::{LeafTree, Neighbor, ProjectiveGrid, dist_sq, widen};

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
    Tree(LeafTree),
    Grid(ProjectiveGrid),
}

impl TargetIndex {
    /// The grid when every point is in front of the camera (z > 0), else the tree.
    pub fn of_view(points: &[Point3<f32>]) -> crate::error::Result<Self> {
        if points.iter().all(|p| p.z > 0.0) {
            ProjectiveGrid::new(points).map(Self::Grid)
        } else {
            LeafTree::new(points).map(Self::Tree)
        }
    }

    /// The nearest point within `radius_m`, and a squared distance no other point is nearer than:
    /// the tree's runner-up (or `radius_m²`), 0 for the grid (not known).
    fn nearest_two_within(&self, q: &Point3<f32>, radius_m: f32) -> (Option<Neighbor>, f32) {
        match self {
            Self::Tree(t) => t.nearest_two_within(q, radius_m),
            Self::Grid(g) => (g.nearest_within(q, radius_m), 0.0),
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

/// A constraint on twists `(ω, v)` (a point `p` moves at `v + ω × p`), `(α, β)`: the twists with
/// `α·ω + β·v = 0`, as a constraint on the steps of a system linearised about `centre` with
/// rotations scaled by `1/length` (`(ω length, v + ω × centre)`).
pub(crate) fn constraint_on_steps(constraint: &Vector6<f64>, centre: &Vector3<f64>, length: f64) -> Vector6<f64> {
    let alpha = Vector3::new(constraint[0], constraint[1], constraint[2]);
    let beta = Vector3::new(constraint[3], constraint[4], constraint[5]);
    let a = (alpha - centre.cross(&beta)) / length;
    Vector6::new(a.x, a.y, a.z, beta.x, beta.y, beta.z)
}

/// The projection onto the steps (about `centre`, rotations scaled by `1/length`) whose twists meet
/// each of `constraints` (see [`constraint_on_steps`], [`complement`]).
pub(crate) fn keeping(constraints: &[Vector6<f64>], centre: &Vector3<f64>, length: f64) -> Matrix6<f64> {
    complement(&constraints.iter().map(|c| constraint_on_steps(c, centre, length)).collect::<Vec<_>>())
}

/// A twist `(ω, v)` as a step of a system linearised about `centre` with rotations scaled by
/// `1/length`: `(ω length, v + ω × centre)`.
pub(crate) fn twist_as_step(twist: &Vector6<f64>, centre: &Vector3<f64>, length: f64) -> Vector6<f64> {
    let omega = Vector3::new(twist[0], twist[1], twist[2]);
    let v = Vector3::new(twist[3], twist[4], twist[5]) + omega.cross(centre);
    Vector6::new(omega.x * length, omega.y * length, omega.z * length, v.x, v.y, v.z)
}

/// The inverse of [`twist_as_step`].
pub(crate) fn step_as_twist(step: &Vector6<f64>, centre: &Vector3<f64>, length: f64) -> Vector6<f64> {
    let omega = Vector3::new(step[0], step[1], step[2]) / length;
    let v = Vector3::new(step[3], step[4], step[5]) - omega.cross(centre);
    Vector6::new(omega.x, omega.y, omega.z, v.x, v.y, v.z)
}

/// The orthogonal projection onto the steps `δ` with `c·δ = 0` for each of `constraints`; a
/// constraint within about 6 degrees of the span of those before it adds nothing (two views' axes of
/// one spin differ by that much).
pub(crate) fn complement(constraints: &[Vector6<f64>]) -> Matrix6<f64> {
    let mut basis: Vec<Vector6<f64>> = Vec::new();
    for c in constraints {
        let Some(mut u) = c.try_normalize(1e-12) else { continue };
        for b in &basis {
            u -= b * b.dot(&u);
        }
        if u.norm() > 0.1 {
            basis.push(u.normalize());
        }
    }
    basis.iter().fold(Matrix6::identity(), |p, b| p - b * b.transpose())
}

/// The normal equations `(h, g)` restricted to the steps `p` (a projection, [`keeping`]) keeps:
/// the constrained directions decouple with unit stiffness (scaled to `h`) and no gradient, so the
/// solved step meets the constraints. Any size: one view's 6x6 system or the joint `6N` one.
pub(crate) fn hold<D: Dim>(
    h: &OMatrix<f64, D, D>,
    g: &OVector<f64, D>,
    p: &OMatrix<f64, D, D>,
) -> (OMatrix<f64, D, D>, OVector<f64, D>)
where
    DefaultAllocator: Allocator<D, D> + Allocator<D>,
{
    let (rows, cols) = h.shape_generic();
    let scale = (h.trace() / rows.value() as f64).max(1e-12);
    (p * h * p + (OMatrix::<f64, D, D>::identity_generic(rows, cols) - p) * scale, p * g)
}

/// What the last search of one source point found: its correspondence, or for a miss how far the
/// nearest target point was known to be and where the source point was then. The pose moves
/// little between iterations, so a point that has not moved past a miss's clearance is a miss
/// again without a search, and in a tree a correspondence is kept without a search while the point
/// stays nearer to it than to the runner-up (the next nearest target point when it was searched);
/// otherwise the next search is bounded by the previous correspondence (the nearest target point
/// is at most that far: far fewer cells or tree nodes visited). All exact: the correspondences are
/// the ones a full search would find.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Hint {
    /// Index of the correspondence, `u32::MAX` for none.
    index: u32,
    /// For a miss: no target point was closer than this (m) to `at`. For a correspondence found
    /// in a tree: no other target point was. 0 when unknown.
    clear_m: f32,
    at: Point3<f32>,
}

impl Hint {
    /// Nothing known yet.
    pub const NONE: Hint = Hint { index: u32::MAX, clear_m: 0.0, at: Point3::new(0.0, 0.0, 0.0) };
}

/// A miss searches this much farther than the gate, to learn a clearance that lets the next
/// iterations skip the point while it moves less than the extra reach.
const MISS_REACH: f32 = 1.5;

/// The nearest target point within `max_m` of `q`, searched as `hint` allows (see [`Hint`]); the
/// hint is updated. A tree's search learns the runner-up's distance too, so that a point that has
/// moved by `δ` since its search, `d` from its correspondence and with no other target point nearer
/// than `c` then, keeps it without a search while `d + δ < c - δ` (every other point is at least
/// `c - δ` away now). In a grid the next search is bounded by the previous correspondence instead.
fn correspondence(
    index: &TargetIndex,
    points: &[Point3<f32>],
    q: &Point3<f32>,
    max_m: f32,
    hint: &mut Hint,
) -> Option<Neighbor> {
    if let Some(prev) = points.get(hint.index as usize) {
        match index {
            TargetIndex::Tree(_) => {
                // summed as the indexes sum it: the distance and gate test are bit for bit a search's
                let d_sq = dist_sq(prev.coords.into(), q.coords.into());
                if widen(d_sq.sqrt()) + 2.0 * widen((q - hint.at).norm()) < hint.clear_m * (1.0 - 1e-4) {
                    // still the nearest, and every other target point is farther than it
                    return (d_sq <= max_m * max_m).then_some(Neighbor { index: hint.index, dist_sq: d_sq });
                }
            }
            TargetIndex::Grid(grid) => {
                // a hair wider than the previous correspondence, so that it stays inside
                let found = grid.nearest_within(q, widen((prev - q).norm()).min(max_m));
                *hint = Hint { index: found.map_or(u32::MAX, |nb| nb.index), ..Hint::NONE };
                return found;
            }
        }
    } else if hint.clear_m > 0.0 && widen((q - hint.at).norm()) + widen(max_m) < hint.clear_m {
        return None; // still farther than the gate from every target point
    }
    let reach = MISS_REACH * max_m;
    let (found, next_sq) = index.nearest_two_within(q, reach);
    match found {
        Some(nb) if nb.dist_sq <= max_m * max_m => {
            *hint = Hint { index: nb.index, clear_m: next_sq.sqrt(), at: *q };
            found
        }
        _ => {
            let clear_m = found.map_or(reach, |nb| nb.dist_sq.sqrt());
            *hint = Hint { index: u32::MAX, clear_m, at: *q };
            None
        }
    }
}

/// Builds the weighted normal equations for moved source points (`moved`, in the target frame,
/// with optional moved normals).
///
/// `hints` holds what each source point's search found at the previous iteration (see [`Hint`])
/// and is updated.
pub(crate) fn linearise(
    moved: &[Point3<f64>],
    moved_normals: Option<&[Vector3<f64>]>,
    target: &Target<'_>,
    p: &StepParams,
    hints: &mut [Hint],
) -> System {
    let max_m = p.max_distance_m as f32;
    let partial: Vec<System> = moved
        .par_chunks(CHUNK)
        .zip(hints.par_chunks_mut(CHUNK))
        .enumerate()
        .map(|(c, (chunk, hints))| {
            let mut sys = System::zero();
            for (j, (s, hint)) in chunk.iter().zip(hints.iter_mut()).enumerate() {
                let q = s.cast::<f32>();
                let Some(nb) = correspondence(target.index, target.points, &q, max_m, hint) else { continue };
                let t = target.points[nb.index as usize].cast::<f64>();
                let n = target.normals[nb.index as usize].cast::<f64>();
                if let (Some(cos), Some(ns)) = (p.min_normal_cos, moved_normals)
                    && ns[c * CHUNK + j].dot(&n) < cos
                {
                    continue;
                }
                let offset = s - t;
                let r = n.dot(&offset);
                if let Some(max) = p.max_tangential_m
                    && (offset - n * r).norm_squared() > max * max
                {
                    continue;
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    /// A source drifting in small steps (and one large jump) over a target seen from the origin:
    /// the hinted searches (bounded by the previous correspondence, misses skipped within their
    /// clearance) find what a fresh search within the gate finds, with both indexes.
    #[test]
    fn hinted_searches_find_the_fresh_searchs_correspondences() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        // a wavy sheet at ~1 m and a sparse cloud nearer the camera
        let mut target = Vec::new();
        for a in 0..80 {
            for b in 0..60 {
                let (x, y) = (a as f32 * 0.004 - 0.16, b as f32 * 0.004 - 0.12);
                target.push(Point3::new(x, y, 1.0 + 0.02 * (x * 40.0).sin() + 0.002 * rng.random::<f32>()));
            }
        }
        for _ in 0..200 {
            target.push(Point3::new(rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5, 0.4 + rng.random::<f32>()));
        }
        // source points near the sheet, and far from everything (misses)
        let mut source: Vec<Point3<f32>> = (0..1500)
            .map(|i| {
                let far = if i % 3 == 0 { 0.05 + 0.1 * rng.random::<f32>() } else { 0.0 };
                Point3::new(
                    0.4 * rng.random::<f32>() - 0.2,
                    0.3 * rng.random::<f32>() - 0.15,
                    1.0 + far + 0.01 * (rng.random::<f32>() - 0.5),
                )
            })
            .collect();
        let max_m = 0.012;
        let indexes = [
            TargetIndex::Tree(LeafTree::new(&target).expect("tree")),
            TargetIndex::Grid(ProjectiveGrid::new(&target).expect("grid")),
        ];
        for index in &indexes {
            let mut hints = vec![Hint::NONE; source.len()];
            let (mut hits, mut misses) = (0, 0);
            for step in 0..40 {
                let shift = if step == 20 { 0.02 } else { 0.0004 };
                let d = Vector3::new(shift, -0.5 * shift, 0.3 * shift);
                for p in source.iter_mut() {
                    *p += d;
                }
                for (q, hint) in source.iter().zip(hints.iter_mut()) {
                    let got = correspondence(index, &target, q, max_m, hint);
                    let nearest = target.iter().map(|t| (t - q).norm_squared()).fold(f32::INFINITY, f32::min);
                    let want = (nearest <= max_m * max_m).then_some(nearest);
                    assert_eq!(got.map(|n| n.dist_sq), want, "step {step}, {q:?}");
                    if got.is_some() { hits += 1 } else { misses += 1 }
                }
            }
            assert!(hits > 10_000 && misses > 10_000, "{hits} hits, {misses} misses");
        }
    }
}
