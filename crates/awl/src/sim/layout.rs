//! Placing a scan's scene: the workpiece at a random pose near the origin, one or two clutter boxes
//! 3-8 cm from it (never on the tag's side, never touching it), a wall piece behind it, the floor.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector2, Vector3};
use rand_chacha::ChaCha8Rng;

use crate::error::Result;
use crate::mesh::TriMesh;
use crate::random::{Stream, rng, uniform};
use crate::sim::shapes::cuboid;
use crate::sim::tag36h11::tag36h11_bitmap;
use crate::sim::workpiece::Workpiece;
use crate::sim::world::{Material, TagPrint, Texture, World, WorldBuilder};
use crate::sim::{LABEL_FLOOR, LABEL_OTHER, LABEL_WORKPIECE, TAG_ID};

/// The workpiece's material.
pub(crate) const WORKPIECE: Material =
    Material { label: LABEL_WORKPIECE, albedo: [198.0, 198.0, 194.0], texture: Texture::Tagged };
/// The floor's material.
pub(crate) const FLOOR: Material =
    Material { label: LABEL_FLOOR, albedo: [128.0, 124.0, 118.0], texture: Texture::Floor };
const WALL: Material = Material { label: LABEL_OTHER, albedo: [214.0, 204.0, 184.0], texture: Texture::Plain };

/// The wall piece, seen from the workpiece's centre (world frame, horizontal).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Wall {
    /// Unit direction from the workpiece's centre towards the wall.
    pub dir: Vector2<f64>,
    /// Distance from the centre to the wall's near face, metres.
    pub distance: f64,
    /// Half the wall's width, metres.
    pub half_width: f64,
}

/// Where things are in a scan's world.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ScanLayout {
    /// `T_world_object`.
    pub world_from_object: Isometry3<f64>,
    /// The point the cameras aim at, world frame.
    pub centre: Point3<f64>,
    /// The wall piece.
    pub wall: Wall,
}

/// A yaw rotation (about z) as an isometry with translation `t`.
pub(crate) fn yaw_at(t: Vector3<f64>, yaw: f64) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw))
}

/// A muted random color (sRGB 0..255) for clutter.
pub(crate) fn clutter_material(rng: &mut ChaCha8Rng) -> Material {
    let hue = uniform(rng, 0.0, 6.0);
    let (s, v) = (uniform(rng, 0.3, 0.55), uniform(rng, 0.55, 0.8));
    let x = 1.0 - (hue % 2.0 - 1.0).abs();
    let (r, g, b) = match hue as u32 {
        0 => (1.0, x, 0.0),
        1 => (x, 1.0, 0.0),
        2 => (0.0, 1.0, x),
        3 => (0.0, x, 1.0),
        4 => (x, 0.0, 1.0),
        _ => (1.0, 0.0, x),
    };
    let c = |k: f64| 255.0 * v * (1.0 - s + s * k);
    Material { label: LABEL_OTHER, albedo: [c(r), c(g), c(b)], texture: Texture::Plain }
}

/// The printed tag of a workpiece at `world_from_object`.
pub(crate) fn tag_print(wp: &Workpiece, world_from_object: &Isometry3<f64>) -> Option<TagPrint> {
    let black = tag36h11_bitmap(TAG_ID)?;
    let world_from_tag = world_from_object * wp.object_from_tag;
    Some(TagPrint { tag_from_world: world_from_tag.inverse(), size: wp.tag_size, black })
}

/// Half the edge of the square floor, metres.
pub(crate) const FLOOR_HALF_M: f64 = 6.0;

/// Clutter boxes in the object frame: one or two, each on a side of the footprint other than the
/// tag's, `3-8 cm` from the footprint rectangle, slightly rotated.
fn clutter(wp: &Workpiece, rng: &mut ChaCha8Rng, builder: &mut WorldBuilder, world_from_object: &Isometry3<f64>) {
    let [x0, y0, x1, y1] = wp.footprint;
    let (mx, my) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    let tag_normal = wp.object_from_tag.rotation * Vector3::z();
    let mut sides: Vec<Vector2<f64>> = [Vector2::x(), -Vector2::x(), Vector2::y(), -Vector2::y()]
        .into_iter()
        .filter(|s| s.dot(&tag_normal.xy()) < 0.7)
        .collect();
    let count = if uniform(rng, 0.0, 1.0) < 0.6 { 2 } else { 1 };
    for _ in 0..count.min(sides.len()) {
        let side = sides.remove((uniform(rng, 0.0, sides.len() as f64) as usize).min(sides.len() - 1));
        let (sx, sy, sz) = (uniform(rng, 0.06, 0.16), uniform(rng, 0.06, 0.16), uniform(rng, 0.08, 0.25));
        let yaw = uniform(rng, -0.4, 0.4);
        let gap = uniform(rng, 0.03, 0.08);
        let (c, s) = (yaw.cos().abs(), yaw.sin().abs());
        let (ex, ey) = (sx / 2.0 * c + sy / 2.0 * s, sx / 2.0 * s + sy / 2.0 * c);
        let along = uniform(rng, -0.3, 0.3);
        let centre = if side.x.abs() > 0.5 {
            let x = if side.x > 0.0 { x1 + gap + ex } else { x0 - gap - ex };
            Vector3::new(x, my + along * (y1 - y0) / 2.0, 0.0)
        } else {
            let y = if side.y > 0.0 { y1 + gap + ey } else { y0 - gap - ey };
            Vector3::new(mx + along * (x1 - x0) / 2.0, y, 0.0)
        };
        let mesh = cuboid(Point3::new(-sx / 2.0, -sy / 2.0, 0.0), Point3::new(sx / 2.0, sy / 2.0, sz));
        let material = clutter_material(rng);
        builder.add(&mesh, &(world_from_object * yaw_at(centre, yaw)), material);
    }
}

/// The wall: 1.5 m wide, 1 m tall, 10 cm thick, 0.5-1 m beyond the workpiece's extent, on the side
/// away from the tag (within 60 degrees of straight behind).
fn wall(
    wp: &Workpiece,
    rng: &mut ChaCha8Rng,
    world_from_object: &Isometry3<f64>,
    centre: &Point3<f64>,
) -> (TriMesh, Isometry3<f64>, Wall) {
    let tag_normal = world_from_object.rotation * wp.object_from_tag.rotation * Vector3::z();
    let behind = (-tag_normal.y).atan2(-tag_normal.x) + uniform(rng, -1.05, 1.05);
    let dir = Vector2::new(behind.cos(), behind.sin());
    let distance = wp.radius + uniform(rng, 0.5, 1.0);
    let (half_width, thickness, height) = (0.75, 0.10, 1.0);
    let mesh = cuboid(Point3::new(0.0, -half_width, 0.0), Point3::new(thickness, half_width, height));
    let at = Vector3::new(centre.x + dir.x * distance, centre.y + dir.y * distance, 0.0);
    (mesh, yaw_at(at, behind), Wall { dir, distance, half_width })
}

/// Builds a scan's world for `wp`, random per `seed`; `bare`: no clutter and no wall (the same
/// workpiece placement, wall side and views as without).
///
/// # Errors
/// [`crate::Error::Invalid`] when the ray-casting mesh cannot be built.
pub(crate) fn scan_world(wp: &Workpiece, seed: u64, bare: bool) -> Result<(World, ScanLayout)> {
    let mut rng = rng(seed, Stream::Scene, 0, 0);
    let (tx, ty) = (uniform(&mut rng, -0.2, 0.2), uniform(&mut rng, -0.2, 0.2));
    let yaw = uniform(&mut rng, 0.0, std::f64::consts::TAU);
    let footprint_centre =
        Vector3::new((wp.footprint[0] + wp.footprint[2]) / 2.0, (wp.footprint[1] + wp.footprint[3]) / 2.0, 0.0);
    let world_from_object = yaw_at(Vector3::new(tx, ty, 0.0), yaw) * yaw_at(-footprint_centre, 0.0);
    let centre = world_from_object * wp.centre;
    let mut builder = WorldBuilder::default();
    builder.add(&wp.cad, &world_from_object, WORKPIECE);
    builder.floor((0.0, 0.0, 0.0), FLOOR_HALF_M, FLOOR);
    let mut crowd = WorldBuilder::default();
    clutter(wp, &mut rng, if bare { &mut crowd } else { &mut builder }, &world_from_object);
    let (wall_mesh, world_from_wall, wall) = wall(wp, &mut rng, &world_from_object, &centre);
    if !bare {
        builder.add(&wall_mesh, &world_from_wall, WALL);
    }
    let world = builder.build(tag_print(wp, &world_from_object), seed)?;
    Ok((world, ScanLayout { world_from_object, centre, wall }))
}
