//! How well a camera sees the tag: projected corners, incidence, apparent size, occlusion.

use nalgebra::{Isometry3, Point3, Vector3};
use serde_json::{Value, json};

use crate::camera::DepthCamera;
use crate::sim::world::World;

/// The tag as one view sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct TagObservation {
    /// All four corners project inside the image, in front of the camera, unoccluded, facing it.
    pub visible: bool,
    /// Angle between the tag normal and the direction to the camera, degrees.
    pub incidence_deg: f64,
    /// Mean projected edge length of the black border, pixels.
    pub side_px: f64,
    /// Black-border corners in AprilTag order (bottom-left, bottom-right, top-right, top-left as read
    /// upright), pixel centres at integer coordinates.
    pub corners_px: [[f64; 2]; 4],
}

impl TagObservation {
    /// Seen well enough to detect and decode: visible, incidence under 60 degrees, larger than 30 px.
    pub(crate) fn good(&self) -> bool {
        self.visible && self.incidence_deg < 60.0 && self.side_px > 30.0
    }

    /// The observation as written to truth.json.
    pub(crate) fn to_json(self, view: usize) -> Value {
        let round = |v: f64| (v * 1000.0).round() / 1000.0;
        json!({
            "view": view,
            "visible": self.visible,
            "incidence_deg": round(self.incidence_deg),
            "side_px": round(self.side_px),
            "corners_px": self.corners_px.map(|c| c.map(round)),
        })
    }
}

/// True when the ray from `eye` to `target` first meets the scene within 2 cm of it (or beyond it).
fn unoccluded(world: &World, eye: &Point3<f64>, target: &Point3<f64>) -> bool {
    let dir: Vector3<f64> = target - eye;
    let length = dir.norm();
    match world.cast(eye, &(dir / length.max(1e-12)), length + 1.0) {
        Some(hit) => hit.t > length - 0.02,
        None => true,
    }
}

/// What camera `world_from_camera` sees of the tag `world_from_tag` of black-border edge `size`.
pub(crate) fn observe_tag(
    world: &World,
    camera: &DepthCamera,
    world_from_tag: &Isometry3<f64>,
    size: f64,
    world_from_camera: &Isometry3<f64>,
) -> TagObservation {
    let h = size / 2.0;
    let corners_tag =
        [Point3::new(-h, -h, 0.0), Point3::new(h, -h, 0.0), Point3::new(h, h, 0.0), Point3::new(-h, h, 0.0)];
    let eye = Point3::from(world_from_camera.translation.vector);
    let centre = Point3::from(world_from_tag.translation.vector);
    let normal = world_from_tag.rotation * Vector3::z();
    let cos = normal.dot(&(eye - centre).normalize());
    let incidence_deg = cos.clamp(-1.0, 1.0).acos().to_degrees();
    let camera_from_world = world_from_camera.inverse();
    let mut corners_px = [[f64::NAN; 2]; 4];
    let mut visible = cos > 0.05 && unoccluded(world, &eye, &centre);
    let (w, hgt) = (f64::from(camera.intrinsics.width), f64::from(camera.intrinsics.height));
    for (out, corner) in corners_px.iter_mut().zip(&corners_tag) {
        let world_point = world_from_tag * corner;
        match camera.intrinsics.project(&(camera_from_world * world_point)) {
            Some(px) => {
                *out = [px.x, px.y];
                let inside = px.x >= 2.0 && px.y >= 2.0 && px.x <= w - 3.0 && px.y <= hgt - 3.0;
                visible &= inside && unoccluded(world, &eye, &world_point);
            }
            None => visible = false,
        }
    }
    let side_px = (0..4)
        .map(|i| {
            let (a, b) = (corners_px[i], corners_px[(i + 1) % 4]);
            ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
        })
        .sum::<f64>()
        / 4.0;
    TagObservation { visible, incidence_deg, side_px: if side_px.is_finite() { side_px } else { 0.0 }, corners_px }
}
