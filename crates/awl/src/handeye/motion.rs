//! Relative motions of pose pairs and the small SO(3) helpers the solvers share.

use nalgebra::{Isometry3, Matrix3, Vector3};

use crate::error::{Error, Result};
use crate::handeye::HandEyePose;

/// One relative motion of a pose pair `i < j`: `a * X = X * b`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Motion {
    /// `ee_j_from_ee_i = base_from_ee_j^-1 * base_from_ee_i`.
    pub a: Isometry3<f64>,
    /// `cam_j_from_cam_i = camera_from_target_j * camera_from_target_i^-1`.
    pub b: Isometry3<f64>,
}

/// The most pose pairs the closed forms and the convention check use: up to 447 poses every pair
/// (`N (N - 1) / 2 <= 100 000`), beyond that a bounded set ([`pose_pairs`]).
pub(crate) const MAX_PAIRS: usize = 100_000;

fn motion(pi: &HandEyePose, pj: &HandEyePose) -> Motion {
    Motion {
        a: pj.base_from_ee.inverse() * pi.base_from_ee,
        b: pj.camera_from_target * pi.camera_from_target.inverse(),
    }
}

/// The motions of the pose pairs `i < j` the closed forms use, in lexicographic order (OpenCV's
/// pairs and directions, so the closed forms match `cv2.calibrateHandEye` to rounding).
///
/// Every pair while there are at most [`MAX_PAIRS`] of them. Beyond that (more than 447 poses),
/// each pose `i` is paired with the `k = MAX_PAIRS / N` poses that rotate the flange most among
/// `2k` candidates `i + 1 + m * step` (modulo `N`, `step = max(1, (N - 1) / 2k)`, `m < 2k`): a
/// deterministic set of at most `N k <= MAX_PAIRS` pairs (duplicates removed) in which every pose
/// takes part, so memory and time grow linearly with the count.
pub(crate) fn pose_pairs(poses: &[HandEyePose]) -> Vec<Motion> {
    let n = poses.len();
    let all = n * n.saturating_sub(1) / 2;
    if all <= MAX_PAIRS {
        let mut motions = Vec::with_capacity(all);
        for (i, pi) in poses.iter().enumerate() {
            for pj in &poses[i + 1..] {
                motions.push(motion(pi, pj));
            }
        }
        return motions;
    }
    let k = (MAX_PAIRS / n).max(1);
    let candidates = (2 * k).min(n - 1);
    let step = ((n - 1) / candidates).max(1);
    let mut pairs: Vec<(usize, usize)> = Vec::with_capacity(n * k);
    let mut scored: Vec<(f64, usize)> = Vec::with_capacity(candidates);
    for i in 0..n {
        scored.clear();
        for m in 0..candidates {
            let j = (i + 1 + m * step) % n;
            if j != i {
                let angle = poses[i].base_from_ee.rotation.angle_to(&poses[j].base_from_ee.rotation);
                scored.push((angle, j));
            }
        }
        scored.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        pairs.extend(scored.iter().take(k).map(|&(_, j)| (i.min(j), i.max(j))));
    }
    pairs.sort_unstable();
    pairs.dedup();
    pairs.into_iter().map(|(i, j)| motion(&poses[i], &poses[j])).collect()
}

pub(crate) use crate::transform::skew;

/// The least-squares translation shared by Park-Martin and Tsai-Lenz: `(R_A - I) t = R_X t_B - t_A`
/// over all motions, solved by SVD of the stacked system.
///
/// # Errors
/// [`Error::Invalid`] when the system is rank-deficient (every motion rotates about one axis).
pub(crate) fn translation_least_squares(
    motions: &[Motion],
    rotation: &nalgebra::UnitQuaternion<f64>,
) -> Result<Vector3<f64>> {
    let n = motions.len();
    let mut c = nalgebra::DMatrix::<f64>::zeros(3 * n, 3);
    let mut d = nalgebra::DVector::<f64>::zeros(3 * n);
    for (k, m) in motions.iter().enumerate() {
        let block = m.a.rotation.to_rotation_matrix().into_inner() - Matrix3::identity();
        let rhs = rotation * m.b.translation.vector - m.a.translation.vector;
        c.view_mut((3 * k, 0), (3, 3)).copy_from(&block);
        d.rows_mut(3 * k, 3).copy_from(&rhs);
    }
    let svd = c.svd(true, true);
    let s = &svd.singular_values;
    let (max, min) = (s.max(), s.min());
    if min.is_nan() || min <= 1e-9 * max.max(1e-300) {
        return Err(Error::invalid(
            "poses",
            "degenerate motion: the translation is unobservable (all relative rotations share one axis)",
        ));
    }
    let t = svd.solve(&d, 0.0).map_err(|m| Error::invalid("poses", format!("translation least squares: {m}")))?;
    Ok(Vector3::new(t[0], t[1], t[2]))
}
