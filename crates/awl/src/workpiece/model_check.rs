//! What `workpiece.json` records of its model (`model_check`): the point count, the bounds and a
//! SHA-256 of the points and normals, so that `awl pierce` plans on the model the workpiece was
//! fused with and refuses another one ([`ModelCheck::verify`]).

use std::path::Path;

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::cloud::PointCloud;
use crate::error::{Error, Result};

/// The fingerprint of a model point cloud.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelCheck {
    /// Number of points.
    pub points: usize,
    /// The smallest x, y, z of the points, metres (model frame).
    pub bounds_min_m: [f64; 3],
    /// The largest x, y, z, metres.
    pub bounds_max_m: [f64; 3],
    /// SHA-256 (lower-case hex) of the points' coordinates as little-endian `f32` (x, y, z per
    /// point, in order), then, when the model has normals, theirs the same way.
    pub sha256: String,
}

impl ModelCheck {
    /// The fingerprint of `model` (the cloud as written to, and read back from, its file: `f32`
    /// coordinates, so both give the same bytes).
    pub fn of(model: &PointCloud) -> Self {
        let mut hash = Sha256::new();
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in &model.points {
            for k in 0..3 {
                hash.update(p[k].to_le_bytes());
                lo[k] = lo[k].min(f64::from(p[k]));
                hi[k] = hi[k].max(f64::from(p[k]));
            }
        }
        for n in model.normals.iter().flatten() {
            for k in 0..3 {
                hash.update(n[k].to_le_bytes());
            }
        }
        let digest = hash.finalize();
        let sha256 = digest.iter().map(|b| format!("{b:02x}")).collect();
        if model.points.is_empty() {
            (lo, hi) = ([0.0; 3], [0.0; 3]);
        }
        Self { points: model.points.len(), bounds_min_m: lo, bounds_max_m: hi, sha256 }
    }

    /// Refuses `model` (read from `model_path`) unless it is the one this fingerprint was taken of.
    ///
    /// # Errors
    /// [`Error::Field`] about `workpiece`'s `model_check` naming what differs (the point count,
    /// the bounds, or the checksum) and both values.
    pub fn verify(&self, workpiece: &Path, model_path: &Path, model: &PointCloud) -> Result<()> {
        let found = Self::of(model);
        let what = if found.points != self.points {
            format!("{} points, workpiece.json records {}", found.points, self.points)
        } else if !same_bounds(&found, self) {
            format!(
                "bounds {:?} .. {:?} m, workpiece.json records {:?} .. {:?} m",
                found.bounds_min_m, found.bounds_max_m, self.bounds_min_m, self.bounds_max_m
            )
        } else if found.sha256 != self.sha256 {
            format!("SHA-256 {}, workpiece.json records {}", found.sha256, self.sha256)
        } else {
            return Ok(());
        };
        Err(Error::field(
            workpiece,
            "model_check",
            format!(
                "the model {} is not the one this workpiece was fused with ({what}): it was replaced or changed; \
                 use the model.ply awl fuse wrote beside this workpiece.json, or fuse again",
                model_path.display()
            ),
        ))
    }
}

/// The bounds agree within [`BOUNDS_SAME_M`] (JSON's decimal numbers read back within an ulp; the
/// checksum is exact).
fn same_bounds(a: &ModelCheck, b: &ModelCheck) -> bool {
    let pairs = a.bounds_min_m.iter().zip(&b.bounds_min_m).chain(a.bounds_max_m.iter().zip(&b.bounds_max_m));
    pairs.into_iter().all(|(x, y)| (x - y).abs() <= BOUNDS_SAME_M)
}

/// How far the recorded and the found bounds may differ, metres.
pub const BOUNDS_SAME_M: f64 = 1e-9;

#[cfg(test)]
mod tests {
    use nalgebra::{Point3, Vector3};

    use super::*;

    fn cloud(n: usize) -> PointCloud {
        let points: Vec<Point3<f32>> = (0..n).map(|i| Point3::new(i as f32 * 0.01, -(i as f32) * 0.02, 0.5)).collect();
        PointCloud { normals: Some(vec![Vector3::z(); n]), colors: None, points }
    }

    #[test]
    fn any_change_to_the_model_is_named() {
        let model = cloud(100);
        let check = ModelCheck::of(&model);
        assert_eq!(check.points, 100);
        assert_eq!(check.bounds_min_m, [0.0, f64::from(-99.0f32 * 0.02), 0.5]);
        assert_eq!(check.sha256.len(), 64);
        let (wp, m) = (Path::new("w/workpiece.json"), Path::new("w/model.ply"));
        assert!(check.verify(wp, m, &model).is_ok());
        let fewer = cloud(99);
        let e = check.verify(wp, m, &fewer).expect_err("fewer points").to_string();
        assert!(e.contains("workpiece.json") && e.contains("99 points") && e.contains("records 100"), "{e}");
        // two points swapped: the same count and bounds, only the checksum sees it
        let mut moved = model.clone();
        moved.points.swap(50, 51);
        let e = check.verify(wp, m, &moved).expect_err("moved").to_string();
        assert!(e.contains("SHA-256") && e.contains("model_check"), "{e}");
        // a normal flipped
        let mut flipped = model.clone();
        if let Some(n) = flipped.normals.as_mut() {
            n[3] = -n[3];
        }
        assert!(check.verify(wp, m, &flipped).expect_err("flipped").to_string().contains("SHA-256"));
        let mut wider = model;
        wider.points[0].y = 1.0;
        assert!(check.verify(wp, m, &wider).expect_err("wider").to_string().contains("bounds"));
    }
}
