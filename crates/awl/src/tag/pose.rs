//! Tag pose from its 4 detected corners: undistort, homography, the two IPPE solutions of the planar
//! ambiguity, each refined by Levenberg-Marquardt on the reprojection error; both are returned.

use nalgebra::{Isometry3, Point2, Point3, SMatrix, SVector, Translation3, UnitQuaternion, Vector2};

use crate::camera::Intrinsics;
use crate::error::{Error, Result};
use crate::tag::ippe::{homography, ippe_rotations, translation_for};

/// Two refined solutions closer than this (rotation, radians) are the same minimum (no ambiguity).
const SAME_ROTATION_RAD: f64 = 1e-3;
/// Levenberg-Marquardt iterations per solution.
const MAX_ITERATIONS: usize = 50;

/// One pose hypothesis of the tag.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TagPoseSolution {
    /// `T_camera_tag`: maps awl tag-frame points (origin at the tag centre, x right, y up as read
    /// upright, z out of the face toward the viewer; metres) into the camera optical frame.
    pub camera_from_tag: Isometry3<f64>,
    /// Root mean square over the 4 corners of the distance between the detected corner and the
    /// corner reprojected through the full camera model (distortion included), pixels.
    pub rmse_px: f64,
}

/// The tag pose: the better of the two planar-ambiguity solutions and, when distinct, the other.
///
/// A small tag seen nearly frontally has two poses that reproject almost equally well (tilted either
/// way about the line of sight). `best` has the lower reprojection RMSE; when the two RMSEs are
/// close ([`TagPose::ambiguity`] near 1) use other evidence to choose: depth points on the tag
/// ([`crate::tag::score_depth`]) or agreement across views; then [`TagPose::swapped`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TagPose {
    /// The solution with the lower reprojection RMSE.
    pub best: TagPoseSolution,
    /// The other local minimum; `None` when both starts converge to the same pose (rotations
    /// within 1e-3 rad), i.e. the view is not ambiguous.
    pub second: Option<TagPoseSolution>,
}

impl TagPose {
    /// `second.rmse_px / best.rmse_px` (>= 1; `None` without a second solution). Near 1 the
    /// corners cannot tell the two apart; above about 3 `best` is reliable on its own.
    pub fn ambiguity(&self) -> Option<f64> {
        self.second.map(|s| s.rmse_px / self.best.rmse_px.max(1e-9))
    }

    /// The same pose with `best` and `second` exchanged (for when other evidence prefers the
    /// second); unchanged without a second solution.
    pub fn swapped(self) -> Self {
        match self.second {
            Some(second) => Self { best: second, second: Some(self.best) },
            None => self,
        }
    }
}

/// The tag model: black-border corners in AprilTag order in awl's tag frame (plane z = 0).
pub fn tag_corners_m(tag_size_m: f64) -> [Point3<f64>; 4] {
    let h = tag_size_m / 2.0;
    [Point3::new(-h, -h, 0.0), Point3::new(h, -h, 0.0), Point3::new(h, h, 0.0), Point3::new(-h, h, 0.0)]
}

/// Estimates `camera_from_tag` from the 4 corners of a detection (AprilTag order, pixels with
/// integer = pixel centre, as in [`crate::tag::TagDetection::corners_px`]), the camera intrinsics
/// (the corners are undistorted first) and the black-border edge length `tag_size_m` (metres).
///
/// # Errors
/// [`Error::Invalid`] for a non-positive tag size, non-finite corners, or a degenerate quad (no
/// homography, or no solution in front of the camera).
pub fn estimate_tag_pose(corners_px: &[[f64; 2]; 4], intrinsics: &Intrinsics, tag_size_m: f64) -> Result<TagPose> {
    if !(tag_size_m.is_finite() && tag_size_m > 0.0) {
        return Err(Error::invalid("tag size", format!("must be a positive length in metres, got {tag_size_m}")));
    }
    if !corners_px.iter().flatten().all(|v| v.is_finite()) {
        return Err(Error::invalid("tag corners", "not finite"));
    }
    let degenerate = || Error::invalid("tag corners", format!("degenerate quad {corners_px:?}"));
    let image = corners_px.map(|[u, v]| intrinsics.ray(&Point2::new(u, v)));
    let model3 = tag_corners_m(tag_size_m);
    let model = model3.map(|p| Vector2::new(p.x, p.y));
    let h = homography(&model, &image).ok_or_else(degenerate)?;
    let rotations = ippe_rotations(&h).ok_or_else(degenerate)?;
    let mut solutions = Vec::with_capacity(2);
    for rotation in &rotations {
        let Some(t) = translation_for(rotation, &model, &image) else { continue };
        let start = Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_rotation_matrix(rotation));
        let pose = refine(start, &model3, &image, intrinsics);
        if model3.iter().all(|p| (pose * p).z > 0.0) {
            let rmse_px = rmse_px(&pose, &model3, corners_px, intrinsics);
            solutions.push(TagPoseSolution { camera_from_tag: pose, rmse_px });
        }
    }
    solutions.sort_by(|a, b| a.rmse_px.total_cmp(&b.rmse_px));
    let mut solutions = solutions.into_iter();
    let best = solutions.next().ok_or_else(degenerate)?;
    let second = solutions
        .next()
        .filter(|s| s.camera_from_tag.rotation.angle_to(&best.camera_from_tag.rotation) > SAME_ROTATION_RAD);
    Ok(TagPose { best, second })
}

/// Reprojection RMSE through the full camera model, pixels.
fn rmse_px(pose: &Isometry3<f64>, model: &[Point3<f64>; 4], corners_px: &[[f64; 2]; 4], k: &Intrinsics) -> f64 {
    let sum: f64 = model
        .iter()
        .zip(corners_px)
        .map(|(p, c)| k.project(&(pose * p)).map_or(f64::INFINITY, |q| (q.x - c[0]).powi(2) + (q.y - c[1]).powi(2)))
        .sum();
    (sum / 4.0).sqrt()
}

/// Residuals (undistorted pixels: focal length times the normalised error) and their Jacobian with
/// respect to `(omega, dt)` of the update `R <- exp(omega) R`, `t <- t + dt`.
fn linearise(
    pose: &Isometry3<f64>,
    model: &[Point3<f64>; 4],
    image: &[Vector2<f64>; 4],
    k: &Intrinsics,
) -> Option<(SVector<f64, 8>, SMatrix<f64, 8, 6>)> {
    let mut r = SVector::<f64, 8>::zeros();
    let mut jac = SMatrix::<f64, 8, 6>::zeros();
    for (i, (p, obs)) in model.iter().zip(image).enumerate() {
        let rotated = pose.rotation * p.coords;
        let x = rotated + pose.translation.vector;
        if x.z <= 1e-9 {
            return None;
        }
        let (iz, iz2) = (1.0 / x.z, 1.0 / (x.z * x.z));
        r[2 * i] = k.fx * (x.x * iz - obs.x);
        r[2 * i + 1] = k.fy * (x.y * iz - obs.y);
        let dproj = SMatrix::<f64, 2, 3>::new(k.fx * iz, 0.0, -k.fx * x.x * iz2, 0.0, k.fy * iz, -k.fy * x.y * iz2);
        let d_omega = -rotated.cross_matrix();
        jac.fixed_view_mut::<2, 3>(2 * i, 0).copy_from(&(dproj * d_omega));
        jac.fixed_view_mut::<2, 3>(2 * i, 3).copy_from(&dproj);
    }
    Some((r, jac))
}

fn apply(pose: &Isometry3<f64>, delta: &SVector<f64, 6>) -> Isometry3<f64> {
    let omega = delta.fixed_rows::<3>(0).into_owned();
    let rotation = UnitQuaternion::from_scaled_axis(omega) * pose.rotation;
    Isometry3::from_parts(Translation3::from(pose.translation.vector + delta.fixed_rows::<3>(3)), rotation)
}

/// Levenberg-Marquardt on the reprojection error of the 4 corners.
fn refine(
    start: Isometry3<f64>,
    model: &[Point3<f64>; 4],
    image: &[Vector2<f64>; 4],
    k: &Intrinsics,
) -> Isometry3<f64> {
    let mut pose = start;
    let Some((mut r, mut jac)) = linearise(&pose, model, image, k) else { return pose };
    let mut cost = r.norm_squared();
    let mut lambda = 1e-3;
    for _ in 0..MAX_ITERATIONS {
        let jtj = jac.transpose() * jac;
        let jtr = jac.transpose() * r;
        let mut improved = false;
        while lambda < 1e12 {
            let mut a = jtj;
            for d in 0..6 {
                a[(d, d)] += lambda * jtj[(d, d)].max(1e-12);
            }
            let Some(delta) = a.cholesky().map(|c| -c.solve(&jtr)) else {
                lambda *= 10.0;
                continue;
            };
            let candidate = apply(&pose, &delta);
            match linearise(&candidate, model, image, k) {
                Some((r2, j2)) if r2.norm_squared() < cost => {
                    let gain = cost - r2.norm_squared();
                    (pose, r, jac, cost) = (candidate, r2, j2, r2.norm_squared());
                    lambda = (lambda / 10.0).max(1e-12);
                    improved = gain > 1e-14 * (1.0 + cost) && delta.norm() > 1e-13;
                    break;
                }
                _ => lambda *= 10.0,
            }
        }
        if !improved {
            break;
        }
    }
    pose
}
