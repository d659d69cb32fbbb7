//! Piercing-time shots: world = the robot base. The workpiece lies 0.6-0.9 m in front of the robot,
//! its tag turned partly towards it, flat on the floor or tilted 30 degrees on a support ramp; the arm takes
//! one to three views that see the tag well.

use nalgebra::{Isometry3, Point3, Translation3, Unit, UnitQuaternion, Vector3};
use rand_chacha::ChaCha8Rng;

use crate::camera::DepthCamera;
use crate::error::{Error, Result};
use crate::random::{Stream, normal, rng, uniform};
use crate::sim::LABEL_OTHER;
use crate::sim::ShotPose;
use crate::sim::layout::{FLOOR, FLOOR_HALF_M, WORKPIECE, tag_print, yaw_at};
use crate::sim::rig::{BASE_HEIGHT, RigView, look_at, true_ee_from_camera};
use crate::sim::shapes::quad;
use crate::sim::tagview::observe_tag;
use crate::sim::workpiece::Workpiece;
use crate::sim::world::{Material, Texture, World, WorldBuilder};

const SUPPORT: Material = Material { label: LABEL_OTHER, albedo: [168.0, 146.0, 112.0], texture: Texture::Plain };
/// Tilt of the `tilt30` pose, degrees.
const TILT_DEG: f64 = 30.0;

/// A planned shot.
pub(crate) struct ShotPlan {
    /// The scene.
    pub world: World,
    /// `T_world_object` (world = robot base).
    pub world_from_object: Isometry3<f64>,
    /// True poses of the views.
    pub views: Vec<RigView>,
    /// The horizontal tilt axis (world), for `tilt30`.
    pub tilt_axis: Option<Vector3<f64>>,
}

/// A tilt that keeps the tag facing the robot and not downwards.
fn tilt(
    rng: &mut ChaCha8Rng,
    tag_normal: &Vector3<f64>,
    toward_robot: &Vector3<f64>,
) -> (UnitQuaternion<f64>, Vector3<f64>) {
    let angle = TILT_DEG.to_radians();
    for _ in 0..100 {
        let az = uniform(rng, 0.0, std::f64::consts::TAU);
        let axis = Vector3::new(az.cos(), az.sin(), 0.0);
        let rotation = UnitQuaternion::from_axis_angle(&Unit::new_normalize(axis), angle);
        let n = rotation * tag_normal;
        if n.z >= -0.05 && n.xy().normalize().dot(&toward_robot.xy()) > 0.2 {
            return (rotation, axis);
        }
    }
    let axis = tag_normal.cross(&Vector3::z()).try_normalize(1e-9).unwrap_or_else(Vector3::x);
    (UnitQuaternion::from_axis_angle(&Unit::new_normalize(axis), angle), axis)
}

/// Where the workpiece lies.
struct Placement {
    world_from_object: Isometry3<f64>,
    tilt_axis: Option<Vector3<f64>>,
    /// Corners of the support ramp, object frame.
    ramp: Option<[Point3<f64>; 4]>,
}

/// Places the workpiece, its tag turned 25-65 degrees away from facing the robot (so the arm can
/// put the camera in front of it without hitting the robot's own base).
fn place(wp: &Workpiece, pose: ShotPose, rng: &mut ChaCha8Rng) -> Placement {
    let (x, y) = (uniform(rng, 0.6, 0.9), uniform(rng, -0.15, 0.15));
    let [x0, y0, x1, y1] = wp.footprint;
    let fc = Vector3::new((x0 + x1) / 2.0, (y0 + y1) / 2.0, 0.0);
    let n_obj = wp.object_from_tag.rotation * Vector3::z();
    let side = if uniform(rng, 0.0, 1.0) < 0.5 { -1.0 } else { 1.0 };
    let desired = (-y).atan2(-x) + side * uniform(rng, 25f64, 65.0).to_radians();
    let yawed = yaw_at(Vector3::zeros(), desired - n_obj.y.atan2(n_obj.x)) * yaw_at(-fc, 0.0);
    let toward_robot = Vector3::new(-x, -y, 0.0).normalize();
    let (rotation, axis, ramp) = match pose {
        ShotPose::Flat => (UnitQuaternion::identity(), None, None),
        ShotPose::Tilt30 => {
            let (r, a) = tilt(rng, &(yawed.rotation * n_obj), &toward_robot);
            let m = 0.10;
            let p = |u: f64, v: f64| Point3::new(u, v, -0.002);
            (r, Some(a), Some([p(x0 - m, y0 - m), p(x1 + m, y0 - m), p(x1 + m, y1 + m), p(x0 - m, y1 + m)]))
        }
    };
    let unplaced = Isometry3::from_parts(Translation3::identity(), rotation) * yawed;
    let lowest = wp.cad.vertices.iter().chain(ramp.iter().flatten()).map(|p| (unplaced * p).z).fold(f64::MAX, f64::min);
    let world_from_object = Isometry3::translation(x, y, -BASE_HEIGHT - lowest) * unplaced;
    Placement { world_from_object, tilt_axis: axis, ramp }
}

/// One shot view: the camera 0.45-0.65 m from the tag, 20-45 degrees above its normal and turned by
/// `spread` about the vertical, aimed between the tag and the workpiece's centre.
fn shot_view(rng: &mut ChaCha8Rng, wp: &Workpiece, world_from_object: &Isometry3<f64>, spread: f64) -> Isometry3<f64> {
    let world_from_tag = world_from_object * wp.object_from_tag;
    let tag_centre = Point3::from(world_from_tag.translation.vector);
    let n = world_from_tag.rotation * Vector3::z();
    let az = n.y.atan2(n.x) + spread + uniform(rng, -5f64, 5.0).to_radians();
    let el = (n.z.clamp(-1.0, 1.0).asin() + uniform(rng, 20f64, 45.0).to_radians()).clamp(0.15, 1.3);
    let eye = tag_centre + Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin()) * uniform(rng, 0.45, 0.65);
    let centre = world_from_object * wp.centre;
    let aim = tag_centre + (centre - tag_centre) * 0.4;
    let jitter = Vector3::new(normal(rng), normal(rng), normal(rng)) * 0.01;
    look_at(&eye, &(aim + jitter), normal(rng) * 3f64.to_radians())
}

/// Plans a shot of `n` views for seed `seed`.
///
/// # Errors
/// [`Error::Invalid`] when the scene cannot be built or no reachable camera pose sees the tag.
pub(crate) fn plan_shot(wp: &Workpiece, pose: ShotPose, n: usize, seed: u64, camera: &DepthCamera) -> Result<ShotPlan> {
    let mut rng = rng(seed, Stream::Shot, 0, 0);
    let Placement { world_from_object, tilt_axis, ramp } = place(wp, pose, &mut rng);
    let mut builder = WorldBuilder::default();
    builder.add(&wp.cad, &world_from_object, WORKPIECE);
    let centre = world_from_object * wp.centre;
    builder.floor((centre.x, centre.y, -BASE_HEIGHT), FLOOR_HALF_M, FLOOR);
    if let Some(corners) = ramp {
        builder.add(&quad(corners), &world_from_object, SUPPORT);
    }
    let world = builder.build(tag_print(wp, &world_from_object), seed)?;
    let world_from_tag = world_from_object * wp.object_from_tag;
    let ee_from_camera = true_ee_from_camera();
    let mut views = Vec::with_capacity(n);
    for k in 0..n {
        let spread = (k as f64 - (n as f64 - 1.0) / 2.0) * 25f64.to_radians();
        let pose = (0..300)
            .map(|_| shot_view(&mut rng, wp, &world_from_object, spread))
            .find(|c| {
                let p = c.translation.vector;
                let reachable = p.z > 0.25 - BASE_HEIGHT && (0.3..1.1).contains(&p.norm());
                reachable && {
                    let seen = observe_tag(&world, camera, &world_from_tag, wp.tag_size, c);
                    seen.good() && seen.incidence_deg < 55.0
                }
            })
            .ok_or_else(|| Error::invalid("shot", format!("no reachable camera pose sees the tag well (view {k})")))?;
        let base_from_ee = pose * ee_from_camera.inverse();
        views.push(RigView { stop: 0, world_from_base: Isometry3::identity(), base_from_ee, world_from_camera: pose });
    }
    Ok(ShotPlan { world, world_from_object, views, tilt_axis })
}
