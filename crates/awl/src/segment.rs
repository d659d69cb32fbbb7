//! Segmentation: the floor plane under the object.
//!
//! A plane is `n·p + d = 0` with `n` a unit normal pointing along the caller's `up` and `d` =
//! [`PlaneFit::offset_m`]; the signed distance `n·p + d` of a point is positive above the plane.
//!
//! [`fit_plane_ransac`] finds the dominant plane: seeded RANSAC hypotheses (3-point samples, half of them
//! uniform, half local: the 2nd and 3rd point among the first one's nearest neighbours, so planes holding
//! a small share of the points are still sampled) are scored on a random subsample of at most
//! [`SUBSAMPLE_POINTS`] points; the best one is refined on all points by alternating inlier selection and
//! a least-squares (PCA) refit until the inliers stop changing. Hypotheses and the refit must both be
//! within the allowed tilt of `up`. [`remove_floor`] extracts up to `max_planes` such planes in turn (each
//! one from the points the previous ones did not explain; a plane whose refit leaves the tilt is removed
//! but is no candidate), takes the floor among them (the plane with the fewest points below it: a box top
//! has the floor below it) and keeps the points above the floor.
//!
//! Everything is deterministic for a given seed: the random numbers are drawn serially, hypotheses are
//! scored in parallel but compared by (inliers, index), and sums run over fixed chunks in a fixed order,
//! so 1 and N threads give identical results.

use nalgebra::{Matrix3, Point3, SymmetricEigen, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::spatial::KdIndex;

/// At most this many points (drawn at random) score the RANSAC hypotheses.
pub const SUBSAMPLE_POINTS: usize = 16_384;
/// Local hypotheses draw their 2nd and 3rd point among this many nearest subsample points.
const LOCAL_NEIGHBOURS: usize = 16;
/// Inlier selection and refit rounds at most. Usually 2 or 3 are enough; a hypothesis bridging two
/// parallel planes (a floor strip and a strip of the object's top) takes dozens to slide onto one of them.
const REFINE_ROUNDS: usize = 50;
/// Points per chunk of a deterministic parallel sum.
const CHUNK: usize = 4096;

/// Parameters of [`fit_plane_ransac`] (and of each plane in [`remove_floor`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct PlaneParams {
    /// A point is an inlier when its distance to the plane is at most this, metres. Default 0.01
    /// (10 σ of a 1 mm depth noise; also the height of the band [`remove_floor`] cuts off).
    pub distance_m: f64,
    /// RANSAC hypotheses. Default 1000 (a plane holding 10 % of the points is sampled by about 50 of
    /// the local hypotheses).
    pub iterations: usize,
    /// Seed of the ChaCha8 generator. Default 0.
    pub seed: u64,
    /// Only planes whose normal is within this angle of `up` count (hypotheses and refit), radians
    /// (`false`: any plane). Default 15 degrees: floors, not the walls or sides of the object.
    #[serde(with = "crate::off")]
    #[schemars(with = "Option<f64>")]
    pub max_tilt_rad: Option<f64>,
    /// The world's up direction (need not be unit). Normals are returned pointing along it. Default
    /// `[0, 0, 1]`, world z.
    pub up: [f64; 3],
}

impl Default for PlaneParams {
    fn default() -> Self {
        Self {
            distance_m: 0.01,
            iterations: 1000,
            seed: 0,
            max_tilt_rad: Some(15f64.to_radians()),
            up: [0.0, 0.0, 1.0],
        }
    }
}

/// Result of [`fit_plane_ransac`].
#[derive(Debug, Clone, PartialEq)]
pub struct PlaneFit {
    /// Unit normal, pointing along `up` (for a plane perpendicular to `up`, as the fit gave it).
    pub normal: Vector3<f64>,
    /// `d` in `normal·p + d = 0`, metres: minus the height of the plane above the origin along `normal`.
    pub offset_m: f64,
    /// Indices of the points within `distance_m` of the plane, ascending.
    pub inliers: Vec<usize>,
    /// Root mean square distance of the inliers to the plane, metres.
    pub rms_m: f64,
}

impl PlaneFit {
    /// Signed distance of `p` to the plane, metres (positive on the `normal` side).
    pub fn signed_distance(&self, p: &Point3<f64>) -> f64 {
        self.normal.dot(&p.coords) + self.offset_m
    }
}

/// Parameters of [`remove_floor`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct FloorParams {
    /// The RANSAC settings of each candidate plane; `distance_m` is also the band above the floor that is
    /// removed with it.
    pub plane: PlaneParams,
    /// Candidate planes extracted at most. Default 4 (floor, object top, a step or two).
    pub max_planes: usize,
    /// A candidate needs at least this share of all points as inliers. Default 0.02.
    pub min_inlier_fraction: f64,
}

impl Default for FloorParams {
    fn default() -> Self {
        Self { plane: PlaneParams::default(), max_planes: 4, min_inlier_fraction: 0.02 }
    }
}

/// One plane [`remove_floor`] considered.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaneCandidate {
    /// Unit normal along `up`.
    pub normal: Vector3<f64>,
    /// `d` in `normal·p + d = 0`, metres.
    pub offset_m: f64,
    /// Inliers among the points earlier candidates left.
    pub inlier_count: usize,
    /// Points more than `distance_m` below the plane, among all points.
    pub below_count: usize,
}

/// Result of [`remove_floor`].
#[derive(Debug, Clone, PartialEq)]
pub struct FloorRemoval {
    /// The floor; its inliers are taken among all points.
    pub floor: PlaneFit,
    /// Indices of the points more than `distance_m` above the floor, ascending.
    pub kept: Vec<usize>,
    /// Points more than `distance_m` below the floor (dropped with the floor's inliers).
    pub below_count: usize,
    /// The candidate planes, in extraction order.
    pub candidates: Vec<PlaneCandidate>,
}

/// A plane `normal·p + offset = 0`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Plane {
    normal: Vector3<f64>,
    offset: f64,
}

impl Plane {
    fn distance(&self, p: &Point3<f32>) -> f64 {
        self.normal.dot(&p.cast::<f64>().coords) + self.offset
    }

    /// The same plane with its normal along `up`.
    fn oriented(self, up: &Vector3<f64>) -> Self {
        if self.normal.dot(up) < 0.0 { Self { normal: -self.normal, offset: -self.offset } } else { self }
    }
}

/// Validated settings.
struct Setup {
    up: Vector3<f64>,
    min_cos_tilt: Option<f64>,
    distance_m: f64,
    iterations: usize,
}

impl Setup {
    fn new(points: &[Point3<f32>], params: &PlaneParams, what: &str) -> Result<Self> {
        if points.len() < 3 {
            return Err(Error::invalid(what, format!("{} points, a plane needs at least 3", points.len())));
        }
        if points.len() > u32::MAX as usize {
            return Err(Error::invalid(what, format!("{} points, at most {}", points.len(), u32::MAX)));
        }
        if let Some(i) = points.iter().position(|p| !p.coords.iter().all(|v| v.is_finite())) {
            return Err(Error::invalid(what, format!("point {i} is not finite")));
        }
        if !(params.distance_m.is_finite() && params.distance_m > 0.0) {
            return Err(Error::invalid("distance_m", format!("must be positive, got {}", params.distance_m)));
        }
        if params.iterations == 0 {
            return Err(Error::invalid("iterations", "must be at least 1"));
        }
        let up = Vector3::from(params.up);
        let norm = up.norm();
        if !(norm.is_finite() && norm > 0.0) {
            return Err(Error::invalid("up", format!("must be a non-zero finite vector, got {:?}", params.up)));
        }
        let min_cos_tilt = match params.max_tilt_rad {
            Some(t) if !(0.0..=std::f64::consts::PI).contains(&t) => {
                return Err(Error::invalid("max_tilt_rad", format!("must be within [0, pi], got {t}")));
            }
            t => t.map(f64::cos),
        };
        Ok(Self { up: up / norm, min_cos_tilt, distance_m: params.distance_m, iterations: params.iterations })
    }

    /// The plane through three points, along `up`, or `None` when degenerate or too tilted.
    fn hypothesis(&self, a: &Vector3<f64>, b: &Vector3<f64>, c: &Vector3<f64>) -> Option<Plane> {
        let cross = (b - a).cross(&(c - a));
        let scale = (b - a).norm_squared().max((c - a).norm_squared());
        if cross.norm_squared() <= 1e-12 * scale * scale || !cross.iter().all(|v| v.is_finite()) {
            return None;
        }
        let normal = cross.normalize();
        let plane = Plane { normal, offset: -normal.dot(a) }.oriented(&self.up);
        self.within_tilt(&plane).then_some(plane)
    }

    /// True when the plane's normal is within the allowed tilt of `up`.
    fn within_tilt(&self, plane: &Plane) -> bool {
        self.min_cos_tilt.is_none_or(|min_cos| plane.normal.dot(&self.up) >= min_cos)
    }
}

/// The best RANSAC hypothesis over `candidates`, or `None` when no hypothesis is valid. The subsample
/// coordinates are taken relative to its first point; the returned plane is in world coordinates.
fn ransac(points: &[Point3<f32>], candidates: &[u32], setup: &Setup, rng: &mut ChaCha8Rng) -> Option<Plane> {
    let mut picked: Vec<u32> = if candidates.len() <= SUBSAMPLE_POINTS {
        candidates.to_vec()
    } else {
        (0..SUBSAMPLE_POINTS).map(|_| candidates[rng.random_range(0..candidates.len())]).collect()
    };
    picked.sort_unstable();
    let origin = points[*picked.first()? as usize].cast::<f64>();
    let sub: Vec<Vector3<f64>> = picked.iter().map(|&i| points[i as usize].cast::<f64>() - origin).collect();
    let m = sub.len();
    if m < 3 {
        return None;
    }
    let local: Vec<Point3<f32>> = sub.iter().map(|v| Point3::from(v.cast::<f32>())).collect();
    let index = KdIndex::new(&local).ok()?;
    let hypotheses: Vec<Option<Plane>> = (0..setup.iterations)
        .map(|h| {
            let a = rng.random_range(0..m);
            let (b, c) = if h % 2 == 0 {
                (rng.random_range(0..m), rng.random_range(0..m))
            } else {
                let near = index.knn(&local[a], LOCAL_NEIGHBOURS + 1);
                let pick = |rng: &mut ChaCha8Rng| near[rng.random_range(0..near.len())].index as usize;
                (pick(rng), pick(rng))
            };
            setup.hypothesis(&sub[a], &sub[b], &sub[c])
        })
        .collect();
    let counts: Vec<usize> = hypotheses
        .par_iter()
        .map(|h| h.map_or(0, |p| sub.iter().filter(|v| (p.normal.dot(v) + p.offset).abs() <= setup.distance_m).count()))
        .collect();
    let mut best: Option<(usize, Plane)> = None;
    for (h, &count) in hypotheses.iter().zip(&counts) {
        if let Some(p) = h
            && best.is_none_or(|(c, _)| count > c)
        {
            best = Some((count, *p));
        }
    }
    let (_, p) = best?;
    Some(Plane { normal: p.normal, offset: p.offset - p.normal.dot(&origin.coords) })
}

fn inliers_of(points: &[Point3<f32>], candidates: &[u32], plane: &Plane, distance_m: f64) -> Vec<u32> {
    candidates.par_iter().copied().filter(|&i| plane.distance(&points[i as usize]).abs() <= distance_m).collect()
}

/// Least-squares plane through `inliers` (at least 3): centroid and smallest principal axis.
/// Sums run relative to the first inlier, over fixed chunks in order (deterministic).
fn pca_plane(points: &[Point3<f32>], inliers: &[u32], up: &Vector3<f64>) -> Option<Plane> {
    let origin = points[*inliers.first()? as usize].cast::<f64>();
    let partial: Vec<(Vector3<f64>, Matrix3<f64>)> = inliers
        .par_chunks(CHUNK)
        .map(|chunk| {
            chunk.iter().fold((Vector3::zeros(), Matrix3::zeros()), |(s1, s2), &i| {
                let v = points[i as usize].cast::<f64>() - origin;
                (s1 + v, s2 + v * v.transpose())
            })
        })
        .collect();
    let (s1, s2) = partial.into_iter().fold((Vector3::zeros(), Matrix3::zeros()), |(a, b), (c, d)| (a + c, b + d));
    let n = inliers.len() as f64;
    let mean = s1 / n;
    let cov = s2 / n - mean * mean.transpose();
    let eig = SymmetricEigen::new(cov);
    let normal = eig.eigenvectors.column(eig.eigenvalues.imin()).normalize();
    if !normal.iter().all(|v| v.is_finite()) {
        return None;
    }
    let centroid = origin.coords + mean;
    Some(Plane { normal, offset: -normal.dot(&centroid) }.oriented(up))
}

fn rms(points: &[Point3<f32>], inliers: &[u32], plane: &Plane) -> f64 {
    if inliers.is_empty() {
        return 0.0;
    }
    let partial: Vec<f64> = inliers
        .par_chunks(CHUNK)
        .map(|chunk| chunk.iter().map(|&i| plane.distance(&points[i as usize]).powi(2)).sum())
        .collect();
    (partial.iter().sum::<f64>() / inliers.len() as f64).sqrt()
}

/// Alternates inlier selection among `candidates` and a least-squares refit until the inliers stop
/// changing ([`REFINE_ROUNDS`] at most); returns the final plane and its inliers (recomputed after the
/// last refit).
fn refine(points: &[Point3<f32>], candidates: &[u32], mut plane: Plane, setup: &Setup) -> (Plane, Vec<u32>) {
    let mut inliers = inliers_of(points, candidates, &plane, setup.distance_m);
    for _ in 0..REFINE_ROUNDS {
        let Some(refit) = pca_plane(points, &inliers, &setup.up) else { break };
        let next = inliers_of(points, candidates, &refit, setup.distance_m);
        if next.len() < 3 {
            break;
        }
        plane = refit;
        let done = next == inliers;
        inliers = next;
        if done {
            break;
        }
    }
    (plane, inliers)
}

fn plane_fit(points: &[Point3<f32>], plane: Plane, inliers: Vec<u32>) -> PlaneFit {
    let rms_m = rms(points, &inliers, &plane);
    PlaneFit {
        normal: plane.normal,
        offset_m: plane.offset,
        inliers: inliers.into_iter().map(|i| i as usize).collect(),
        rms_m,
    }
}

/// The dominant plane of `points` (among planes within `max_tilt_rad` of `up`), see the module docs.
///
/// # Errors
/// [`Error::Invalid`] for fewer than 3 or non-finite points, invalid parameters, or when no hypothesis
/// is a plane within the allowed tilt (e.g. collinear points), or the best one's least-squares refit is not.
pub fn fit_plane_ransac(points: &[Point3<f32>], params: &PlaneParams) -> Result<PlaneFit> {
    let setup = Setup::new(points, params, "plane fit")?;
    let all: Vec<u32> = (0..points.len() as u32).collect();
    let mut rng = ChaCha8Rng::seed_from_u64(params.seed);
    let hypothesis = ransac(points, &all, &setup, &mut rng)
        .ok_or_else(|| Error::invalid("plane fit", "no plane within the allowed tilt of `up` (degenerate points?)"))?;
    let (plane, inliers) = refine(points, &all, hypothesis, &setup);
    if !setup.within_tilt(&plane) {
        let tilt = plane.normal.dot(&setup.up).clamp(-1.0, 1.0).acos().to_degrees();
        return Err(Error::invalid(
            "plane fit",
            format!("the best plane's refit is {tilt:.1} deg from `up`, beyond max_tilt_rad"),
        ));
    }
    Ok(plane_fit(points, plane, inliers))
}

/// Finds the floor under the object and keeps the points more than `distance_m` above it.
///
/// Candidate planes are extracted one after the other (see the module docs). Without `object_hint`, the
/// floor is the candidate with the fewest points more than `distance_m` below it (ties: more inliers),
/// i.e. the lowest large plane. With `object_hint`, a point on or in the object (not on its top face),
/// the floor is the highest candidate more than `distance_m` below the hint (the surface the object
/// stands on, e.g. a table rather than the room's floor under it). The floor's inliers and the points
/// below it are dropped.
///
/// # Errors
/// [`Error::Invalid`] for fewer than 3 or non-finite points, invalid parameters, or when no candidate
/// plane (within the tilt, with enough inliers, below the hint) exists.
pub fn remove_floor(
    points: &[Point3<f32>],
    params: &FloorParams,
    object_hint: Option<Point3<f64>>,
) -> Result<FloorRemoval> {
    let setup = Setup::new(points, &params.plane, "floor removal")?;
    if params.max_planes == 0 {
        return Err(Error::invalid("max_planes", "must be at least 1"));
    }
    if !(0.0..=1.0).contains(&params.min_inlier_fraction) {
        return Err(Error::invalid(
            "min_inlier_fraction",
            format!("must be in [0, 1], got {}", params.min_inlier_fraction),
        ));
    }
    let min_inliers = ((params.min_inlier_fraction * points.len() as f64).ceil() as usize).max(3);
    let mut rng = ChaCha8Rng::seed_from_u64(params.plane.seed);
    let mut remaining: Vec<u32> = (0..points.len() as u32).collect();
    let mut planes = Vec::new();
    let mut candidates = Vec::new();
    for _ in 0..params.max_planes {
        if remaining.len() < min_inliers {
            break;
        }
        let Some(hypothesis) = ransac(points, &remaining, &setup, &mut rng) else { break };
        let (plane, inliers) = refine(points, &remaining, hypothesis, &setup);
        if inliers.len() < min_inliers {
            break;
        }
        // A plane whose refit leaves the allowed tilt is not a candidate, but its points go all the same.
        if setup.within_tilt(&plane) {
            let below_count = points.par_iter().filter(|p| plane.distance(p) < -setup.distance_m).count();
            let inlier_count = inliers.len();
            candidates.push(PlaneCandidate { normal: plane.normal, offset_m: plane.offset, inlier_count, below_count });
            planes.push(plane);
        }
        let mut taken = inliers.into_iter().peekable();
        remaining.retain(|&i| {
            let inlier = taken.peek() == Some(&i);
            if inlier {
                taken.next();
            }
            !inlier
        });
    }
    let chosen = match object_hint {
        Some(hint) => (0..planes.len())
            .map(|k| (k, planes[k].normal.dot(&hint.coords) + planes[k].offset))
            .filter(|&(_, h)| h > setup.distance_m)
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(k, _)| k),
        None => {
            (0..candidates.len()).min_by_key(|&k| (candidates[k].below_count, usize::MAX - candidates[k].inlier_count))
        }
    };
    let Some(k) = chosen else {
        return Err(Error::invalid(
            "floor removal",
            format!(
                "no plane within the allowed tilt of `up` with at least {min_inliers} inliers{}",
                match object_hint {
                    Some(_) => " below the object hint",
                    None => "",
                }
            ),
        ));
    };
    let floor = planes[k];
    let all: Vec<u32> = (0..points.len() as u32).collect();
    let inliers = inliers_of(points, &all, &floor, setup.distance_m);
    let kept: Vec<usize> =
        (0..points.len()).into_par_iter().filter(|&i| floor.distance(&points[i]) > setup.distance_m).collect();
    Ok(FloorRemoval {
        floor: plane_fit(points, floor, inliers),
        kept,
        below_count: candidates[k].below_count,
        candidates,
    })
}

/// A plane `normal·p + offset_m = 0` (unit `normal`, pointing up for a floor), model frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FloorPlane {
    /// Unit normal, up.
    pub normal: Vector3<f64>,
    /// `d` in `normal·p + d = 0`, metres.
    pub offset_m: f64,
}

impl FloorPlane {
    /// The plane from a normal of any length; `None` when it is zero or not finite.
    pub fn new(normal: Vector3<f64>, offset_m: f64) -> Option<Self> {
        let n = normal.norm();
        (n.is_finite() && n > 1e-9 && offset_m.is_finite()).then(|| Self { normal: normal / n, offset_m: offset_m / n })
    }

    /// Signed height of `p` above the plane, metres.
    pub fn height(&self, p: &Point3<f64>) -> f64 {
        self.normal.dot(&p.coords) + self.offset_m
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Vector3};
    use rand_distr::{Distribution, Normal};

    const FLOOR_Z: f32 = -0.1;
    const BOX_HALF: f32 = 0.24;
    const BOX_HEIGHT: f32 = 0.30;

    /// What a point of the synthetic scene is.
    #[derive(Debug, Clone, Copy, PartialEq)]
    pub(super) enum Kind {
        Floor,
        /// A box point with its true height above the floor, metres.
        Box(f32),
        Outlier,
    }

    /// A 48 x 48 x 30 cm box (top and sides, `box_density` and `top_density` points per m²) centred on a
    /// square floor of side `floor_side_m` (`floor_density` per m², not under the box) at z = -0.1 m,
    /// 1 mm Gaussian noise on every axis, 1 % outliers uniform in the floor's extent, 0.3 m below the
    /// floor to 0.7 m above it; shuffled.
    pub(super) fn scene(
        floor_side_m: f32,
        floor_density: f32,
        box_density: f32,
        top_density: f32,
    ) -> (Vec<Point3<f32>>, Vec<Kind>) {
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        let noise = Normal::new(0.0f32, 0.001).expect("normal");
        let mut out: Vec<(Point3<f32>, Kind)> = Vec::new();
        let half = floor_side_m / 2.0;
        let floor_n = (floor_side_m * floor_side_m - 4.0 * BOX_HALF * BOX_HALF) * floor_density;
        while out.len() < floor_n as usize {
            let (x, y) = (rng.random_range(-half..half), rng.random_range(-half..half));
            if x.abs() > BOX_HALF || y.abs() > BOX_HALF {
                out.push((Point3::new(x, y, FLOOR_Z), Kind::Floor));
            }
        }
        let side = 2.0 * BOX_HALF;
        for _ in 0..(side * side * top_density) as usize {
            let (x, y) = (rng.random_range(-BOX_HALF..BOX_HALF), rng.random_range(-BOX_HALF..BOX_HALF));
            out.push((Point3::new(x, y, FLOOR_Z + BOX_HEIGHT), Kind::Box(BOX_HEIGHT)));
        }
        for _ in 0..(4.0 * side * BOX_HEIGHT * box_density) as usize {
            let (s, h) = (rng.random_range(-BOX_HALF..BOX_HALF), rng.random_range(0.0..BOX_HEIGHT));
            let (x, y) = match rng.random_range(0..4) {
                0 => (s, -BOX_HALF),
                1 => (s, BOX_HALF),
                2 => (-BOX_HALF, s),
                _ => (BOX_HALF, s),
            };
            out.push((Point3::new(x, y, FLOOR_Z + h), Kind::Box(h)));
        }
        for (p, _) in &mut out {
            *p += Vector3::new(noise.sample(&mut rng), noise.sample(&mut rng), noise.sample(&mut rng));
        }
        for _ in 0..out.len() / 99 {
            let z = FLOOR_Z + rng.random_range(-0.3..0.7);
            out.push((Point3::new(rng.random_range(-half..half), rng.random_range(-half..half), z), Kind::Outlier));
        }
        for i in (1..out.len()).rev() {
            let j = rng.random_range(0..=i);
            out.swap(i, j);
        }
        out.into_iter().unzip()
    }

    fn angle_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
        a.normalize().dot(&b.normalize()).clamp(-1.0, 1.0).acos().to_degrees()
    }

    fn with_threads<T: Send>(n: usize, f: impl FnOnce() -> T + Send) -> T {
        rayon::ThreadPoolBuilder::new().num_threads(n).build().expect("pool").install(f)
    }

    #[test]
    fn box_on_floor() {
        // 3 x 3 m floor, about 200 000 floor and 18 000 box points.
        let (points, kinds) = scene(3.0, 22_800.0, 22_800.0, 22_800.0);
        let params = FloorParams::default();
        let r = remove_floor(&points, &params, None).expect("floor");
        let z = Vector3::z();
        let tilt = angle_deg(&r.floor.normal, &z);
        assert!(tilt < 0.2, "floor tilt {tilt} deg");
        // n·p + d = 0 with n = z and the floor at z = -0.1: d = 0.1.
        assert!((r.floor.offset_m - 0.1).abs() < 0.001, "offset {}", r.floor.offset_m);
        assert!(r.floor.rms_m < 0.002, "rms {}", r.floor.rms_m);
        assert!(r.candidates.len() >= 2, "{:?}", r.candidates);
        let kept_kind = |pred: &dyn Fn(Kind) -> bool| r.kept.iter().filter(|&&i| pred(kinds[i])).count();
        let count = |pred: &dyn Fn(Kind) -> bool| kinds.iter().filter(|&&k| pred(k)).count();
        let floor_left = kept_kind(&|k| k == Kind::Floor) as f64 / count(&|k| k == Kind::Floor) as f64;
        assert!(floor_left < 0.001, "floor left {floor_left}");
        let is_box = |k| matches!(k, Kind::Box(_));
        let high = |k| matches!(k, Kind::Box(h) if h > 0.015);
        let box_kept = kept_kind(&is_box) as f64 / count(&is_box) as f64;
        let high_kept = kept_kind(&high) as f64 / count(&high) as f64;
        // The 1 cm band holds 4 x 0.48 x 0.01 m² of the 0.806 m² box surface: 2.4 % of the box points.
        assert!(high_kept > 0.999, "box points above 15 mm kept {high_kept}");
        assert!((0.97..0.985).contains(&box_kept), "box points kept {box_kept}");
        println!(
            "box on floor: {} points, tilt {tilt:.4} deg, offset error {:.2e} m, rms {:.2e} m, floor left {floor_left:.2e}, \
             box kept {box_kept:.4}, box above 15 mm kept {high_kept:.5}, candidates {:?}",
            points.len(),
            r.floor.offset_m - 0.1,
            r.floor.rms_m,
            r.candidates.iter().map(|c| (c.offset_m, c.inlier_count, c.below_count)).collect::<Vec<_>>()
        );
    }

    #[test]
    fn box_top_larger_than_floor() {
        // Seen from above: the top is sampled 10x denser than a 1 x 1 m floor ring, so it is the dominant plane.
        let (points, kinds) = scene(1.0, 10_000.0, 10_000.0, 100_000.0);
        let floor_count = kinds.iter().filter(|&&k| k == Kind::Floor).count();
        let dominant = fit_plane_ransac(&points, &PlaneParams::default()).expect("plane");
        assert!((dominant.offset_m - (0.1 - 0.3)).abs() < 0.001, "dominant offset {}", dominant.offset_m);
        assert!(dominant.inliers.len() > 2 * floor_count);
        let r = remove_floor(&points, &FloorParams::default(), None).expect("floor");
        assert!(
            (r.floor.offset_m - 0.1).abs() < 0.001,
            "offset {}, {:?}, {} points, {floor_count} floor",
            r.floor.offset_m,
            r.candidates,
            points.len()
        );
        assert!(angle_deg(&r.floor.normal, &Vector3::z()) < 0.2);
        // A hint inside the box picks the floor; one above the box picks its top.
        let inside = remove_floor(&points, &FloorParams::default(), Some(Point3::new(0.0, 0.0, 0.05))).expect("inside");
        assert_eq!(inside, r);
        let above = remove_floor(&points, &FloorParams::default(), Some(Point3::new(0.0, 0.0, 0.5))).expect("above");
        assert!((above.floor.offset_m + 0.2).abs() < 0.001, "offset {}", above.floor.offset_m);
        assert!(remove_floor(&points, &FloorParams::default(), Some(Point3::new(0.0, 0.0, -0.5))).is_err());
    }

    #[test]
    fn tilted_floor() {
        let (points, _) = scene(3.0, 5_000.0, 5_000.0, 5_000.0);
        let rotation = Rotation3::from_axis_angle(&Vector3::x_axis(), 10f32.to_radians());
        let points: Vec<Point3<f32>> = points.iter().map(|p| rotation * p).collect();
        let truth = rotation.cast::<f64>() * Vector3::z();
        let r = remove_floor(&points, &FloorParams::default(), None).expect("15 deg allowed");
        let tilt = angle_deg(&r.floor.normal, &truth);
        assert!(tilt < 0.2, "normal off by {tilt} deg");
        assert!((r.floor.offset_m - 0.1).abs() < 0.001, "offset {}", r.floor.offset_m);
        println!("tilted floor: normal off by {tilt:.4} deg, offset error {:.2e} m", r.floor.offset_m - 0.1);
        let strict = FloorParams {
            plane: PlaneParams { max_tilt_rad: Some(5f64.to_radians()), ..Default::default() },
            ..Default::default()
        };
        let r = remove_floor(&points, &strict, None);
        assert!(r.is_err(), "{:?}", r.map(|r| (r.floor.normal, r.floor.offset_m, r.floor.inliers.len(), r.candidates)));
        let fit = fit_plane_ransac(&points, &strict.plane);
        assert!(fit.is_err(), "{:?}", fit.map(|f| f.normal));
    }

    #[test]
    fn deterministic_across_threads_and_seeds() {
        let (points, _) = scene(3.0, 5_000.0, 5_000.0, 5_000.0);
        let params = FloorParams::default();
        let one = with_threads(1, || remove_floor(&points, &params, None).expect("1 thread"));
        let two = with_threads(2, || remove_floor(&points, &params, None).expect("2 threads"));
        assert_eq!(one, two);
        let fit1 = with_threads(1, || fit_plane_ransac(&points, &params.plane).expect("1 thread"));
        let fit2 = with_threads(2, || fit_plane_ransac(&points, &params.plane).expect("2 threads"));
        assert_eq!(fit1, fit2);
        let other = PlaneParams { seed: 99, ..params.plane };
        let fit3 = fit_plane_ransac(&points, &other).expect("seed 99");
        assert!(angle_deg(&fit3.normal, &fit1.normal) < 0.01 && (fit3.offset_m - fit1.offset_m).abs() < 1e-4);
    }

    #[test]
    fn plane_fit_on_300k_points() {
        let (points, _) = scene(3.0, 33_000.0, 33_000.0, 33_000.0);
        assert!(points.len() > 300_000, "{}", points.len());
        let start = std::time::Instant::now();
        let fit = fit_plane_ransac(&points, &PlaneParams::default()).expect("plane");
        let fit_s = start.elapsed().as_secs_f64();
        let start = std::time::Instant::now();
        let r = remove_floor(&points, &FloorParams::default(), None).expect("floor");
        let floor_s = start.elapsed().as_secs_f64();
        assert!((fit.offset_m - 0.1).abs() < 0.001 && (r.floor.offset_m - 0.1).abs() < 0.001);
        println!(
            "{} points on {} threads: fit_plane_ransac {:.1} ms, remove_floor {:.1} ms ({} candidates)",
            points.len(),
            rayon::current_num_threads(),
            fit_s * 1e3,
            floor_s * 1e3,
            r.candidates.len()
        );
    }

    #[test]
    fn bad_input() {
        let params = PlaneParams::default();
        assert!(matches!(fit_plane_ransac(&[], &params), Err(Error::Invalid { .. })));
        let two = [Point3::origin(), Point3::new(1.0, 0.0, 0.0)];
        assert!(matches!(fit_plane_ransac(&two, &params), Err(Error::Invalid { .. })));
        assert!(matches!(remove_floor(&two, &FloorParams::default(), None), Err(Error::Invalid { .. })));
        let line: Vec<Point3<f32>> = (0..100).map(|i| Point3::new(i as f32 * 0.01, 0.0, 0.0)).collect();
        assert!(fit_plane_ransac(&line, &PlaneParams { max_tilt_rad: None, ..params }).is_err());
        let mut square: Vec<Point3<f32>> =
            (0..100).map(|i| Point3::new((i % 10) as f32, (i / 10) as f32, 1.0)).collect();
        let fit = fit_plane_ransac(&square, &params).expect("square");
        assert_eq!((fit.inliers.len(), fit.normal, fit.offset_m), (100, Vector3::z(), -1.0));
        assert_eq!(fit.signed_distance(&Point3::new(0.0, 0.0, 3.0)), 2.0);
        let flipped = fit_plane_ransac(&square, &PlaneParams { up: [0.0, 0.0, -2.0], ..params }).expect("down");
        assert_eq!((flipped.normal, flipped.offset_m), (-Vector3::z(), 1.0));
        for bad in [
            PlaneParams { distance_m: 0.0, ..params },
            PlaneParams { iterations: 0, ..params },
            PlaneParams { up: [0.0; 3], ..params },
            PlaneParams { max_tilt_rad: Some(-0.1), ..params },
        ] {
            assert!(fit_plane_ransac(&square, &bad).is_err(), "{bad:?}");
        }
        assert!(remove_floor(&square, &FloorParams { max_planes: 0, ..Default::default() }, None).is_err());
        square[7].x = f32::NAN;
        assert!(fit_plane_ransac(&square, &params).is_err());
        let p: FloorParams = serde_json::from_str(r#"{"plane": {"distance_m": 0.005}}"#).expect("json");
        assert_eq!((p.plane.distance_m, p.plane.iterations, p.max_planes), (0.005, 1000, 4));
        assert!(serde_json::from_str::<PlaneParams>(r#"{"distance": 0.005}"#).is_err());
    }
}
