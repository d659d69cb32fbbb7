//! Trajectory error against the truth: how far the recorded (seed) and the registered camera poses
//! are from the true ones. The model frame is the anchor view's seed frame (it carries that view's
//! seed error), so each trajectory is first fitted rigidly onto the truth ([`align_positions`]);
//! the error is then the mean distance between matched camera centres.

use nalgebra::{Isometry3, Point3};
use serde::{Deserialize, Serialize};

use super::align_positions;
use crate::error::{Error, Result};

/// Seed and registered trajectories against the truth.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TrajectoryCorrection {
    /// Views compared: those with a registered pose.
    pub views: usize,
    /// Mean camera-centre error of the seeds (recorded poses), millimetres.
    pub seed_error_mm: f64,
    /// Mean camera-centre error of the registered poses, millimetres.
    pub registered_error_mm: f64,
}

/// Mean camera-centre distance, millimetres, between `poses` and `truth` after the best rigid fit
/// of the centres of `poses` onto those of `truth`.
///
/// # Errors
/// [`Error::Invalid`] for fewer than 3 poses or mismatched lengths.
pub fn trajectory_error_mm(poses: &[Isometry3<f64>], truth: &[Isometry3<f64>]) -> Result<f64> {
    let centres =
        |p: &[Isometry3<f64>]| -> Vec<Point3<f64>> { p.iter().map(|t| Point3::from(t.translation.vector)).collect() };
    let (from, to) = (centres(poses), centres(truth));
    let fit = align_positions(&from, &to)?;
    Ok(from.iter().zip(&to).map(|(f, t)| (fit * f - t).norm()).sum::<f64>() / from.len() as f64 * 1e3)
}

/// Compares the seed and registered trajectories (one entry per view; `registered[i]` is `None` for
/// a view left out) with the true `T_world_camera` of each view, over the views with a registered pose.
///
/// # Errors
/// [`Error::Invalid`] when the three lists differ in length or fewer than 3 views were registered.
pub fn trajectory_correction(
    seeds: &[Isometry3<f64>],
    registered: &[Option<Isometry3<f64>>],
    truth: &[Isometry3<f64>],
) -> Result<TrajectoryCorrection> {
    if seeds.len() != registered.len() || seeds.len() != truth.len() {
        return Err(Error::invalid(
            "trajectory",
            format!("{} seeds, {} registered poses, {} true poses", seeds.len(), registered.len(), truth.len()),
        ));
    }
    let merged: Vec<usize> = (0..seeds.len()).filter(|&i| registered[i].is_some()).collect();
    let pick = |poses: &[Isometry3<f64>]| -> Vec<Isometry3<f64>> { merged.iter().map(|&i| poses[i]).collect() };
    let reg: Vec<Isometry3<f64>> = registered.iter().flatten().copied().collect();
    let true_merged = pick(truth);
    Ok(TrajectoryCorrection {
        views: merged.len(),
        seed_error_mm: trajectory_error_mm(&pick(seeds), &true_merged)?,
        registered_error_mm: trajectory_error_mm(&reg, &true_merged)?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn pose(x: f64, y: f64, z: f64) -> Isometry3<f64> {
        Isometry3::translation(x, y, z)
    }

    #[test]
    fn a_rigid_offset_costs_nothing_and_a_single_shift_is_averaged() {
        let truth = vec![pose(0.0, 0.0, 0.0), pose(1.0, 0.0, 0.0), pose(0.0, 1.0, 0.0), pose(0.0, 0.0, 1.0)];
        // The whole trajectory moved and turned: no error after the fit.
        let gauge = Isometry3::new(Vector3::new(0.3, -0.2, 0.1), Vector3::new(0.0, 0.0, 0.4));
        let moved: Vec<_> = truth.iter().map(|t| gauge * t).collect();
        assert!(trajectory_error_mm(&moved, &truth).expect("fit") < 1e-9);
        // Only view 3 is off, by 4 mm along z; view 1 is left out of the registered trajectory.
        let mut seeds = truth.clone();
        seeds[3] = pose(0.0, 0.0, 1.004);
        let registered = vec![Some(truth[0]), None, Some(truth[2]), Some(truth[3])];
        let c = trajectory_correction(&seeds, &registered, &truth).expect("compare");
        assert_eq!(c.views, 3);
        assert!(c.registered_error_mm < 1e-9, "{c:?}");
        // One of 3 views off by 4 mm: the fit shares the shift, the mean residual is below 4 mm.
        assert!(c.seed_error_mm > 1.0 && c.seed_error_mm < 4.0, "{c:?}");
        // Hand-computed: a regular tetrahedron (centroid 0, radius sqrt 3 m) scaled by 1.001 about its
        // centroid fits best unturned (sum t t^T = 4 I), leaving sqrt(3) mm at every vertex.
        let tetra = [pose(1.0, 1.0, 1.0), pose(1.0, -1.0, -1.0), pose(-1.0, 1.0, -1.0), pose(-1.0, -1.0, 1.0)];
        let scaled: Vec<_> = tetra.iter().map(|t| Isometry3::from(t.translation.vector * 1.001)).collect();
        let e = trajectory_error_mm(&scaled, &tetra).expect("fit");
        assert!((e - 3f64.sqrt()).abs() < 1e-6, "{e}");
        assert!(trajectory_correction(&seeds[..3], &registered, &truth).is_err());
        assert!(trajectory_correction(&seeds, &[None, None, Some(truth[2]), Some(truth[3])], &truth).is_err());
    }
}
