//! Candidate views of awl's own, when none are given: the shot's first camera swung about the
//! targets' centre (azimuth about the base's vertical ±15 / ±30 deg, elevation ±10 / ±20 deg), and
//! close views of each target (0.40 m along its normal, 0.45 m tilted ±20 deg, 0.55 m tilted 25
//! deg): the view bank the other simulator offers, made for any shot. Each is a flange pose
//! (`T_base_ee = T_base_camera * T_ee_camera^-1`). Only the flange's distance from the base is checked
//! here ([`MIN_REACH_M`]-[`MAX_REACH_M`]); the arm's inverse kinematics is not yet.

use nalgebra::{Isometry3, Point3, Rotation3, Translation3, Unit, UnitQuaternion, Vector3};

use crate::plan_views::Candidate;

/// A flange nearer the base's origin than this is left out, metres.
pub const MIN_REACH_M: f64 = 0.3;
/// ... or farther than this.
pub const MAX_REACH_M: f64 = 1.1;

/// A camera at `eye` looking at `at`, its image's down direction toward the base's -z (x right, y
/// down, z forward); `None` when `eye` is `at`.
fn look_at(eye: &Point3<f64>, at: &Point3<f64>) -> Option<Isometry3<f64>> {
    let z = (at - eye).try_normalize(1e-9)?;
    let hint = if z.z.abs() > 0.999 { Vector3::x() } else { -Vector3::z() };
    let y = (hint - z * hint.dot(&z)).normalize();
    let x = y.cross(&z);
    let r = Rotation3::from_basis_unchecked(&[x, y, z]);
    Some(Isometry3::from_parts(Translation3::from(eye.coords), UnitQuaternion::from_rotation_matrix(&r)))
}

/// `camera` turned by `angle` about `axis` through `centre`.
fn turned(camera: &Isometry3<f64>, centre: &Point3<f64>, axis: &Vector3<f64>, angle: f64) -> Option<Isometry3<f64>> {
    let axis = Unit::try_new(*axis, 1e-9)?;
    let about = Translation3::from(centre.coords)
        * UnitQuaternion::from_axis_angle(&axis, angle)
        * Translation3::from(-centre.coords);
    Some(Isometry3::from(about) * camera)
}

/// The candidates for a shot whose first camera is at `base_from_camera`, with the hand-eye
/// `ee_from_camera`, for targets at `targets` (point and outward normal, base frame).
pub fn sample_candidates(
    base_from_camera: &Isometry3<f64>,
    ee_from_camera: &Isometry3<f64>,
    targets: &[(Point3<f64>, Vector3<f64>)],
) -> Vec<Candidate> {
    if targets.is_empty() {
        return Vec::new();
    }
    let centre = Point3::from(targets.iter().map(|(p, _)| p.coords).sum::<Vector3<f64>>() / targets.len() as f64);
    let eye = Point3::from(base_from_camera.translation.vector);
    let across = (centre - eye).cross(&Vector3::z());
    let mut cameras: Vec<(Isometry3<f64>, String)> = Vec::new();
    for deg in [-30.0f64, -15.0, 15.0, 30.0] {
        if let Some(c) = turned(base_from_camera, &centre, &Vector3::z(), deg.to_radians()) {
            cameras.push((c, format!("swing about the targets' centre: azimuth {deg:+.0} deg")));
        }
    }
    for deg in [-20.0f64, -10.0, 10.0, 20.0] {
        if let Some(c) = turned(base_from_camera, &centre, &across, deg.to_radians()) {
            cameras.push((c, format!("swing about the targets' centre: elevation {deg:+.0} deg")));
        }
    }
    for (k, (p, n)) in targets.iter().enumerate() {
        let tilt_axis = n.cross(&Vector3::z()).try_normalize(1e-6).unwrap_or_else(Vector3::x);
        for (distance, deg) in [(0.40, 0.0f64), (0.45, -20.0), (0.45, 20.0), (0.55, 25.0)] {
            let along = UnitQuaternion::from_axis_angle(&Unit::new_normalize(tilt_axis), deg.to_radians()) * n;
            if let Some(c) = look_at(&(p + along * distance), p) {
                cameras.push((c, format!("close view of target {k}: {distance:.2} m, {deg:+.0} deg from its normal")));
            }
        }
    }
    let ee_from_camera_inv = ee_from_camera.inverse();
    cameras
        .into_iter()
        .map(|(c, why)| (c * ee_from_camera_inv, why))
        .filter(|(f, _)| (MIN_REACH_M..=MAX_REACH_M).contains(&f.translation.vector.norm()))
        .map(|(base_from_ee, why)| Candidate { base_from_ee, why, view: None })
        .collect()
}

/// [`sample_candidates`] after a pierce of `shot`: around its first view (placed with the hand-eye
/// the pierce used) and its targets; none when the shot's views were not combined with the hand-eye.
///
/// # Errors
/// When the shot's first view has no pose.
pub fn candidates_after_pierce(
    pierce: &crate::pierce::PiercePlan,
    shot: &crate::scan::Scan,
) -> crate::error::Result<Vec<Candidate>> {
    let Some(h) = &pierce.located.hand_eye else { return Ok(Vec::new()) };
    let first = match shot.views.first().map(|v| v.pose) {
        Some(crate::scan::ViewPose::Chain { world_from_base, base_from_ee }) => {
            world_from_base * base_from_ee * h.ee_from_camera
        }
        _ => shot.world_from_camera(0)?,
    };
    let targets: Vec<_> = pierce.targets.iter().map(|t| (t.p_base, t.normal_base)).collect();
    Ok(sample_candidates(&first, &h.ee_from_camera, &targets))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn candidates_look_at_their_targets_from_their_distances() {
        let camera = look_at(&Point3::new(0.3, 0.0, 0.4), &Point3::new(0.7, 0.0, -0.1)).expect("camera");
        let x = Isometry3::translation(0.03, -0.07, 0.06);
        let target = (Point3::new(0.7, 0.05, -0.1), Vector3::new(-0.6, 0.0, 0.8).normalize());
        let c = sample_candidates(&camera, &x, &[target]);
        // 12 made; the elevation +20 deg swing and the close view tilted -20 deg put the flange beyond
        // 1.1 m from the base
        assert_eq!(c.len(), 10, "{:?}", c.iter().map(|c| &c.why).collect::<Vec<_>>());
        for cand in &c {
            assert!((MIN_REACH_M..=MAX_REACH_M).contains(&cand.base_from_ee.translation.vector.norm()));
            let cam = cand.base_from_ee * x;
            let forward = cam.rotation * Vector3::z();
            let to = (target.0 - Point3::from(cam.translation.vector)).normalize();
            // the swings keep the first camera's aim (0.09 m from the target); the close views aim at it
            if cand.why.contains("close") {
                assert!(forward.angle(&to) < 1e-9, "{}", cand.why);
                let d = (target.0 - Point3::from(cam.translation.vector)).norm();
                assert!((0.39..=0.56).contains(&d), "{} at {d}", cand.why);
            } else {
                assert!(forward.angle(&to) < 0.2, "{}", cand.why);
            }
            // the image's down direction does not point up (level when the camera looks straight down)
            assert!((cam.rotation * Vector3::y()).z <= 1e-9, "{}", cand.why);
        }
    }
}
