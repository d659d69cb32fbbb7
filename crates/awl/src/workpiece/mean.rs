//! A robust mean of poses on SE(3): median-based outlier rejection, then the chordal mean.
//!
//! The reference is the medoid (the pose whose summed rotation angle to all others is least) for
//! the rotation and the component-wise median for the translation; poses farther than the
//! thresholds from it are rejected. The survivors are averaged: translations arithmetically,
//! rotations by the chordal L2 mean (the normalised sum of the unit quaternions, signs aligned with
//! the medoid's; it equals the rotation minimising the summed squared Frobenius distances for small
//! spreads).

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3, Vector4};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// Outlier thresholds of [`robust_mean`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MeanParams {
    /// A pose whose origin is farther than this from the median origin is rejected, metres. Default 0.01.
    pub max_translation_m: f64,
    /// A pose whose rotation differs more than this from the medoid's is rejected, radians. Default 3 degrees.
    pub max_rotation_rad: f64,
}

impl Default for MeanParams {
    fn default() -> Self {
        Self { max_translation_m: 0.01, max_rotation_rad: 3f64.to_radians() }
    }
}

/// Result of [`robust_mean`].
#[derive(Debug, Clone, PartialEq)]
pub struct PoseMean {
    /// The mean of the poses kept.
    pub mean: Isometry3<f64>,
    /// Per input pose: None when kept, else why it was rejected.
    pub rejected: Vec<Option<String>>,
    /// Number of poses kept.
    pub used: usize,
    /// Whether any pose lies within the thresholds of the reference (false: the poses disagree,
    /// every one was rejected, and `mean` is the medoid alone, which nothing confirms).
    pub agreed: bool,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) }
}

/// The robust mean of `poses` (see the module docs).
///
/// # Errors
/// [`Error::Invalid`] for an empty list or non-positive thresholds.
pub fn robust_mean(poses: &[Isometry3<f64>], params: &MeanParams) -> Result<PoseMean> {
    if poses.is_empty() {
        return Err(Error::invalid("pose mean", "no poses"));
    }
    if !(params.max_translation_m > 0.0 && params.max_rotation_rad > 0.0) {
        return Err(Error::invalid("pose mean thresholds", "must be positive"));
    }
    let t_med = Vector3::from_fn(|r, _| median(poses.iter().map(|p| p.translation.vector[r]).collect()));
    let medoid = (0..poses.len())
        .min_by(|&a, &b| {
            let cost = |i: usize| poses.iter().map(|p| p.rotation.angle_to(&poses[i].rotation)).sum::<f64>();
            cost(a).total_cmp(&cost(b)).then(a.cmp(&b))
        })
        .ok_or_else(|| Error::invalid("pose mean", "no poses"))?;
    let reference = poses[medoid].rotation;
    let rejected: Vec<Option<String>> = poses
        .iter()
        .map(|p| {
            let dt = (p.translation.vector - t_med).norm();
            let dr = p.rotation.angle_to(&reference);
            if dt > params.max_translation_m {
                Some(format!("outlier: {:.1} mm from the median tag position", dt * 1e3))
            } else if dr > params.max_rotation_rad {
                Some(format!("outlier: {:.2} deg from the median tag orientation", dr.to_degrees()))
            } else {
                None
            }
        })
        .collect();
    let kept: Vec<&Isometry3<f64>> = poses.iter().zip(&rejected).filter(|(_, r)| r.is_none()).map(|(p, _)| p).collect();
    // the medoid is always within the thresholds of itself, but its translation may not be
    let agreed = !kept.is_empty();
    let kept = if agreed { kept } else { vec![&poses[medoid]] };
    let n = kept.len() as f64;
    let t = kept.iter().map(|p| p.translation.vector).sum::<Vector3<f64>>() / n;
    let q_ref = reference.into_inner().coords;
    let sum: Vector4<f64> = kept
        .iter()
        .map(|p| {
            let q = p.rotation.into_inner().coords;
            if q.dot(&q_ref) < 0.0 { -q } else { q }
        })
        .sum();
    let rotation = UnitQuaternion::from_quaternion(Quaternion::from(sum));
    let used = kept.len();
    Ok(PoseMean { mean: Isometry3::from_parts(Translation3::from(t), rotation), rejected, used, agreed })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_the_outlier_and_averages_the_rest() {
        let truth = Isometry3::new(Vector3::new(0.3, -0.2, 0.1), Vector3::new(0.2, 0.5, -0.3));
        let offsets = [(0.001, 0.002), (-0.001, -0.002), (0.0005, 0.001), (-0.0005, -0.001)];
        let mut poses: Vec<Isometry3<f64>> = offsets
            .iter()
            .map(|&(dt, dr)| truth * Isometry3::new(Vector3::new(dt, -dt, 0.0), Vector3::new(0.0, dr, dr)))
            .collect();
        poses.push(truth * Isometry3::new(Vector3::new(0.05, 0.0, 0.0), Vector3::zeros()));
        poses.push(truth * Isometry3::new(Vector3::zeros(), Vector3::new(0.2, 0.0, 0.0)));
        let m = robust_mean(&poses, &MeanParams::default()).expect("mean");
        assert_eq!(m.used, 4);
        assert!(m.rejected[4].as_deref().is_some_and(|r| r.contains("mm")), "{:?}", m.rejected);
        assert!(m.rejected[5].as_deref().is_some_and(|r| r.contains("deg")), "{:?}", m.rejected);
        let (dt, dr) = crate::transform::pose_difference(&m.mean, &truth);
        // symmetric offsets cancel: the mean is the truth up to second-order terms
        assert!(dt < 1e-6 && dr < 1e-5, "dt {dt} dr {dr}");
    }

    #[test]
    fn two_poses_far_apart_do_not_agree() {
        let a = Isometry3::translation(0.3, 0.0, 0.1);
        let b = Isometry3::translation(0.3, 0.04, 0.1);
        let m = robust_mean(&[a, b], &MeanParams::default()).expect("mean");
        // each is 20 mm from their median: both rejected, and the mean says it rests on nothing
        assert!(!m.agreed && m.rejected.iter().all(Option::is_some), "{m:?}");
        let c = Isometry3::translation(0.3, 0.004, 0.1);
        assert!(robust_mean(&[a, c], &MeanParams::default()).expect("mean").agreed);
    }

    #[test]
    fn empty_input_is_an_error() {
        assert!(robust_mean(&[], &MeanParams::default()).is_err());
    }
}
