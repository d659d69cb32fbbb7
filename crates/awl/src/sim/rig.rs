//! The rig: base stops of the mobile manipulator around the workpiece, arm poses that put the camera
//! on an arc looking at the workpiece, the hand-eye transform, and the pose errors that SLAM,
//! kinematics and calibration add to what the rig records.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector2, Vector3};
use rand_chacha::ChaCha8Rng;

use crate::random::{Stream, normal, normal_perturbation, rng, uniform, unit_vector};
use crate::sim::layout::ScanLayout;

/// Height of the manipulator's base frame above the floor (arm mounted on the mobile platform), metres.
pub(crate) const BASE_HEIGHT: f64 = 0.45;

/// True poses of one view.
#[derive(Debug, Clone, Copy)]
pub(crate) struct RigView {
    /// Base stop the view was taken from.
    pub stop: usize,
    /// True `T_world_base`.
    pub world_from_base: Isometry3<f64>,
    /// True `T_base_ee`.
    pub base_from_ee: Isometry3<f64>,
    /// True `T_world_camera`.
    pub world_from_camera: Isometry3<f64>,
}

/// The true hand-eye `T_ee_camera`: camera 6 cm off the flange, optical axis about 1 degree off the
/// flange z, image x along flange y.
pub(crate) fn true_ee_from_camera() -> Isometry3<f64> {
    let tilt = UnitQuaternion::from_scaled_axis(Vector3::new(0.6, -0.9, 0.4) * std::f64::consts::PI / 180.0);
    let turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2);
    Isometry3::from_parts(Translation3::new(0.032, -0.018, 0.048), turn * tilt)
}

/// `T_world_camera` of a camera at `eye` looking at `target` (image x horizontal), rolled by `roll`.
pub(crate) fn look_at(eye: &Point3<f64>, target: &Point3<f64>, roll: f64) -> Isometry3<f64> {
    let z = (target - eye).normalize();
    let x = z.cross(&Vector3::z()).try_normalize(1e-9).unwrap_or_else(Vector3::x);
    let y = z.cross(&x);
    let rotation = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
    let rolled =
        UnitQuaternion::from_rotation_matrix(&rotation) * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), roll);
    Isometry3::from_parts(Translation3::from(eye.coords), rolled)
}

/// Number of base stops for `n` views: two views per stop, 4 to 6 stops (fewer when there are few views).
pub(crate) fn stop_count(n: usize) -> usize {
    n.div_ceil(2).clamp(n.min(4), 6)
}

/// True when a horizontal offset from the workpiece centre lies within `margin` of the wall's
/// near face and inside its width (or behind it).
fn near_wall(offset: Vector2<f64>, layout: &ScanLayout, margin: f64) -> bool {
    let wall = layout.wall;
    let along = offset.dot(&wall.dir);
    let lateral = (offset.x * wall.dir.y - offset.y * wall.dir.x).abs();
    along > wall.distance - margin && lateral < wall.half_width + margin
}

/// The camera position of a view at azimuth `az`, elevation `el`, distance `d` from the centre,
/// at most 1.2 m high, kept 25 cm in front of the wall.
fn camera_position(layout: &ScanLayout, az: f64, el: f64, d: f64) -> Point3<f64> {
    let c = layout.centre;
    let el = el.min(((1.2 - c.z) / d).clamp(-1.0, 1.0).asin());
    let mut horizontal = Vector2::new(az.cos(), az.sin()) * d * el.cos();
    if near_wall(horizontal, layout, 0.25) {
        let along = horizontal.dot(&layout.wall.dir);
        horizontal *= ((layout.wall.distance - 0.25) / along).clamp(0.3, 1.0);
    }
    Point3::new(c.x + horizontal.x, c.y + horizontal.y, c.z + d * el.sin())
}

/// The base pose of a stop at azimuth `az`, keeping the platform (0.5 m) clear of the wall.
fn base_pose(layout: &ScanLayout, rng: &mut ChaCha8Rng, az: f64, reach: f64) -> Isometry3<f64> {
    let radius = uniform(rng, 1.0, 1.6).max(reach + 0.15).min(1.6);
    let step = 10f64.to_radians();
    let az = (0..19)
        .map(|k| az + step * f64::from((k + 1) / 2) * if k % 2 == 0 { 1.0 } else { -1.0 })
        .find(|a| !near_wall(Vector2::new(a.cos(), a.sin()) * radius, layout, 0.5))
        .unwrap_or(az);
    let at = layout.centre.xy().coords + Vector2::new(az.cos(), az.sin()) * radius;
    let facing = (-az.sin()).atan2(-az.cos()) + uniform(rng, -8.0, 8.0).to_radians();
    Isometry3::from_parts(
        Translation3::new(at.x, at.y, BASE_HEIGHT),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), facing),
    )
}

/// Plans `n` views around the workpiece (attempt `attempt` of the seed): azimuths spread evenly
/// around 360 degrees, a low (18-30 deg) and a high (40-52 deg) elevation at each base stop, the camera
/// `0.75 + centre height/2` to `+0.35` m from the centre, aimed at it with a little jitter.
///
/// With `fixed_base` (a fixed arm): one stop, the azimuths spread over the 140 degrees facing the
/// base, the elevations over 15 to 55 degrees.
pub(crate) fn plan_scan(
    layout: &ScanLayout,
    centre_height: f64,
    n: usize,
    seed: u64,
    attempt: u64,
    fixed_base: bool,
) -> Vec<RigView> {
    let mut rng = rng(seed, Stream::Rig, attempt, 0);
    if fixed_base {
        return plan_fixed(layout, centre_height, n, &mut rng);
    }
    let stops = stop_count(n);
    let phase = uniform(&mut rng, 0.0, std::f64::consts::TAU);
    let d_lo = 0.75 + 0.5 * centre_height;
    let cameras: Vec<(usize, Isometry3<f64>)> = (0..n)
        .map(|k| {
            let stop = k * stops / n;
            let first = (0..n).find(|&j| j * stops / n == stop).unwrap_or(k);
            let az = phase + std::f64::consts::TAU * k as f64 / n as f64 + uniform(&mut rng, -4.0, 4.0).to_radians();
            let el = if (k - first) % 2 == 0 { uniform(&mut rng, 18.0, 30.0) } else { uniform(&mut rng, 40.0, 52.0) };
            (stop, aimed_camera(layout, &mut rng, az, el.to_radians(), d_lo, 2.0))
        })
        .collect();
    let ee_from_camera = true_ee_from_camera();
    let mut views = Vec::with_capacity(n);
    for stop in 0..stops {
        let mine: Vec<&Isometry3<f64>> = cameras.iter().filter(|(s, _)| *s == stop).map(|(_, c)| c).collect();
        let mean = mine
            .iter()
            .fold(Vector2::zeros(), |acc, c| acc + (c.translation.vector.xy() - layout.centre.xy().coords).normalize());
        let reach =
            mine.iter().map(|c| (c.translation.vector.xy() - layout.centre.xy().coords).norm()).fold(0.0, f64::max);
        let world_from_base = base_pose(layout, &mut rng, mean.y.atan2(mean.x), reach);
        for world_from_camera in mine {
            let base_from_ee = world_from_base.inverse() * world_from_camera * ee_from_camera.inverse();
            views.push(RigView { stop, world_from_base, base_from_ee, world_from_camera: *world_from_camera });
        }
    }
    views
}

/// `T_world_camera` of a view at azimuth `az` and elevation `el` (radians), `d_lo` to `d_lo + 0.35` m
/// from the centre, aimed at the centre with 2 cm of jitter and a roll of `roll_sigma_deg` (the draws:
/// distance, jitter, roll).
fn aimed_camera(
    layout: &ScanLayout,
    rng: &mut ChaCha8Rng,
    az: f64,
    el: f64,
    d_lo: f64,
    roll_sigma_deg: f64,
) -> Isometry3<f64> {
    let eye = camera_position(layout, az, el, uniform(rng, d_lo, d_lo + 0.35));
    let jitter = Vector3::new(normal(rng), normal(rng), normal(rng)) * 0.02;
    let roll = normal(rng) * roll_sigma_deg.to_radians();
    look_at(&eye, &(layout.centre + jitter), roll)
}

/// A fixed arm's views (see [`plan_scan`]): the base 0.9 m from the workpiece's centre at a random
/// azimuth, the cameras within 70 degrees of azimuth of it (within a UR10e's 1.3 m of the base), 15 to
/// 55 degrees up, `0.75 + centre height/2` to `+0.35` m from the centre (as a mobile base's: nearer,
/// a view sees the top and the floor only).
fn plan_fixed(layout: &ScanLayout, centre_height: f64, n: usize, rng: &mut ChaCha8Rng) -> Vec<RigView> {
    let base_az = uniform(rng, 0.0, std::f64::consts::TAU);
    let c = layout.centre;
    let at = c.xy().coords + Vector2::new(base_az.cos(), base_az.sin()) * 0.9;
    let facing = (-base_az.sin()).atan2(-base_az.cos());
    let world_from_base = Isometry3::from_parts(
        Translation3::new(at.x, at.y, BASE_HEIGHT),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), facing),
    );
    let d_lo = 0.75 + 0.5 * centre_height;
    let ee_from_camera = true_ee_from_camera();
    (0..n)
        .map(|k| {
            let f = if n > 1 { k as f64 / (n - 1) as f64 } else { 0.5 };
            let az = base_az + (f - 0.5) * 140f64.to_radians() + uniform(rng, -3.0, 3.0).to_radians();
            let rise = ((k * 7) % n.max(1)) as f64 / n.max(1) as f64;
            let el = (15.0 + 40.0 * rise + uniform(rng, -3.0, 3.0)).to_radians();
            let world_from_camera = aimed_camera(layout, rng, az, el, d_lo, 10.0);
            let base_from_ee = world_from_base.inverse() * world_from_camera * ee_from_camera.inverse();
            RigView { stop: 0, world_from_base, base_from_ee, world_from_camera }
        })
        .collect()
}

/// Pose errors of a scan, scaled by the noise level: one SLAM error per base stop (1-3 cm in xy,
/// 3 mm sigma in z, 0.4-1.2 deg yaw, 0.15 deg sigma roll and pitch), one arm error per view (0.6 mm and
/// 0.06 deg sigma per axis). Each recorded pose is `true * error`.
pub(crate) struct PoseErrors {
    /// `base_from_recorded_base` per stop.
    pub slam: Vec<Isometry3<f64>>,
    /// `ee_from_recorded_ee` per view.
    pub arm: Vec<Isometry3<f64>>,
}

/// Draws the pose errors (the draws do not depend on `scale`, only their size does).
pub(crate) fn pose_errors(seed: u64, stops: usize, views: usize, scale: f64, with_slam: bool) -> PoseErrors {
    let mut rng = rng(seed, Stream::PoseNoise, 0, 0);
    let deg = std::f64::consts::PI / 180.0;
    let slam = (0..stops)
        .map(|_| {
            let (r, a) = (uniform(&mut rng, 0.01, 0.03), uniform(&mut rng, 0.0, std::f64::consts::TAU));
            let z = normal(&mut rng) * 0.003;
            let sign = if uniform(&mut rng, 0.0, 1.0) < 0.5 { -1.0 } else { 1.0 };
            let yaw = sign * uniform(&mut rng, 0.4, 1.2) * deg;
            let (roll, pitch) = (normal(&mut rng) * 0.15 * deg, normal(&mut rng) * 0.15 * deg);
            let s = if with_slam { scale } else { 0.0 };
            Isometry3::from_parts(
                Translation3::new(r * a.cos() * s, r * a.sin() * s, z * s),
                UnitQuaternion::from_scaled_axis(Vector3::new(roll, pitch, yaw) * s),
            )
        })
        .collect();
    let arm = (0..views).map(|_| normal_perturbation(&mut rng, 0.0006 * scale, 0.06 * deg * scale)).collect();
    PoseErrors { slam, arm }
}

/// The hand-eye calibration error (`ee_from_camera_true^-1 * ee_from_camera_recorded`): about 3 mm and
/// 0.3 deg at scale 1, the same for a seed's scan and its shots.
pub(crate) fn hand_eye_error(seed: u64, scale: f64) -> Isometry3<f64> {
    let mut rng = rng(seed, Stream::HandEye, 0, 0);
    let t = unit_vector(&mut rng) * 0.003 * uniform(&mut rng, 0.8, 1.2) * scale;
    let r = unit_vector(&mut rng) * 0.3f64.to_radians() * uniform(&mut rng, 0.8, 1.2) * scale;
    Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_scaled_axis(r))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn look_at_aims_the_optical_axis_with_image_x_horizontal() {
        let eye = Point3::new(1.0, 0.0, 1.0);
        let pose = look_at(&eye, &Point3::origin(), 0.0);
        let z = pose.rotation * Vector3::z();
        assert!((z - (Point3::origin() - eye).normalize()).norm() < 1e-12);
        let x = pose.rotation * Vector3::x();
        assert!(x.z.abs() < 1e-12);
        assert!((pose.rotation * Vector3::y()).z < 0.0, "image y points down");
        let he = true_ee_from_camera();
        let d = he.translation.vector.norm();
        assert!(d > 0.05 && d < 0.07 && (he.rotation * Vector3::z()).z > 0.99, "{d}");
        assert_eq!((stop_count(12), stop_count(8), stop_count(5), stop_count(2), stop_count(30)), (6, 4, 4, 2, 6));
    }
}
