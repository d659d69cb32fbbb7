//! The four simulated workpieces in their object frame (a corner of the footprint on the floor,
//! x/y along its edges, z up): CAD mesh, tag placement and piercing targets.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::mesh::TriMesh;
use crate::sim::SceneKind;
use crate::sim::shapes::{Dome, cuboid, cylinder, sphere};

/// A piercing target on the workpiece, object frame.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Target {
    /// Name written to truth.json.
    pub name: String,
    /// Point on the surface, metres.
    pub p: Point3<f64>,
    /// Outward unit normal.
    pub n: Vector3<f64>,
}

/// One workpiece: its CAD, where the cameras look, where the tag is, the targets.
#[derive(Debug, Clone)]
pub(crate) struct Workpiece {
    /// The CAD mesh, object frame.
    pub cad: TriMesh,
    /// The point the cameras aim at, object frame.
    pub centre: Point3<f64>,
    /// Footprint rectangle `[x0, y0, x1, y1]` in the object frame.
    pub footprint: [f64; 4],
    /// Horizontal radius around `centre` that encloses the footprint, metres.
    pub radius: f64,
    /// Pose of the tag frame (x right, y up, z out of the face) in the object frame.
    pub object_from_tag: Isometry3<f64>,
    /// The tag's black-border edge, metres.
    pub tag_size: f64,
    /// Targets, object frame.
    pub targets: Vec<Target>,
}

/// The tag frame at `origin` with z along the outward `normal`, y as close to `up` as possible.
pub(crate) fn tag_frame(origin: Point3<f64>, normal: Vector3<f64>, up: Vector3<f64>) -> Isometry3<f64> {
    let z = normal.normalize();
    let y = (up - z * up.dot(&z)).normalize();
    let x = y.cross(&z);
    let rotation = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
    Isometry3::from_parts(Translation3::from(origin.coords), UnitQuaternion::from_rotation_matrix(&rotation))
}

/// The workpiece of `kind`.
pub(crate) fn workpiece(kind: SceneKind) -> Workpiece {
    match kind {
        SceneKind::Box => box_workpiece(),
        SceneKind::Shell => shell_workpiece(),
        SceneKind::Cylinder => cylinder_workpiece(),
        SceneKind::Sphere => sphere_workpiece(),
    }
}

/// The box's size (x, y, z), metres.
const BOX: (f64, f64, f64) = (0.485, 0.48, 0.30);
/// The cylinder's radius and height, metres.
const CYLINDER: (f64, f64) = (0.15, 0.70);
/// The sphere's radius, metres (it rests on the floor: its centre is one radius up).
const SPHERE_RADIUS: f64 = 0.20;
/// Elevation of the sphere's tag centre above its equator, degrees.
const SPHERE_TAG_ELEVATION_DEG: f64 = 15.0;

/// The point of `kind`'s true surface nearest `p` and the outward normal there (object frame):
/// exact for the box's faces, the cylinder's side and top and the sphere; on the dome, the top surface's
/// nearest point by Gauss-Newton on its height field (good away from the rim).
pub(crate) fn nearest_surface(kind: SceneKind, p: &Point3<f64>) -> (Point3<f64>, Vector3<f64>) {
    match kind {
        SceneKind::Box => {
            let (w, d, h) = BOX;
            let clamp = |q: Point3<f64>| Point3::new(q.x.clamp(0.0, w), q.y.clamp(0.0, d), q.z.clamp(0.0, h));
            let faces = [
                (Point3::new(0.0, p.y, p.z), -Vector3::x()),
                (Point3::new(w, p.y, p.z), Vector3::x()),
                (Point3::new(p.x, 0.0, p.z), -Vector3::y()),
                (Point3::new(p.x, d, p.z), Vector3::y()),
                (Point3::new(p.x, p.y, h), Vector3::z()),
            ];
            faces
                .into_iter()
                .map(|(q, n)| (clamp(q), n))
                .min_by(|a, b| (a.0 - p).norm().total_cmp(&(b.0 - p).norm()))
                .unwrap_or((*p, Vector3::z()))
        }
        SceneKind::Shell => {
            let s = SHELL;
            let surface = |x: f64, y: f64| Point3::new(s.a + x, s.b + y, s.height(x, y));
            let (mut x, mut y) = (p.x - s.a, p.y - s.b);
            for _ in 0..20 {
                let e = 1e-6;
                let q = surface(x, y);
                let tx = (surface(x + e, y) - surface(x - e, y)) / (2.0 * e);
                let ty = (surface(x, y + e) - surface(x, y - e)) / (2.0 * e);
                let j = nalgebra::Matrix3x2::from_columns(&[tx, ty]);
                let Some(step) = (j.transpose() * j).try_inverse().map(|m| m * j.transpose() * (p - q)) else { break };
                (x, y) = (x + step.x, y + step.y);
            }
            (surface(x, y), s.normal(x, y))
        }
        SceneKind::Cylinder => {
            let (r, h) = CYLINDER;
            let radial = Vector3::new(p.x - r, p.y - r, 0.0).try_normalize(1e-12).unwrap_or_else(Vector3::x);
            let side = Point3::new(r + radial.x * r, r + radial.y * r, p.z.clamp(0.0, h));
            let top = Point3::new(p.x, p.y, h);
            if (side - p).norm() <= (top - p).norm() { (side, radial) } else { (top, Vector3::z()) }
        }
        SceneKind::Sphere => {
            let r = SPHERE_RADIUS;
            let centre = Point3::new(r, r, r);
            let radial = (p - centre).try_normalize(1e-12).unwrap_or_else(Vector3::z);
            (centre + radial * r, radial)
        }
    }
}

fn box_workpiece() -> Workpiece {
    let (w, d, h) = BOX;
    Workpiece {
        cad: cuboid(Point3::origin(), Point3::new(w, d, h)),
        centre: Point3::new(w / 2.0, d / 2.0, h / 2.0),
        footprint: [0.0, 0.0, w, d],
        radius: (w * w + d * d).sqrt() / 2.0,
        object_from_tag: tag_frame(Point3::new(w / 2.0, 0.0, h / 2.0), -Vector3::y(), Vector3::z()),
        tag_size: 0.08,
        targets: vec![Target { name: "top-centre".into(), p: Point3::new(w / 2.0, d / 2.0, h), n: Vector3::z() }],
    }
}

/// The shell's shape (also used by tests through the CAD only).
pub(crate) const SHELL: Dome =
    Dome { a: 0.25, b: 0.20, h: 0.35, groove_x: -0.06, groove_depth: 0.02, groove_sigma: 0.017 };

fn shell_workpiece() -> Workpiece {
    let s = SHELL;
    let on_surface = |xc: f64, yc: f64| Point3::new(s.a + xc, s.b + yc, s.height(xc, yc));
    let tag_at = (0.0, -0.8 * s.b);
    Workpiece {
        cad: s.mesh(440, 512),
        centre: Point3::new(s.a, s.b, 0.15),
        footprint: [0.0, 0.0, 2.0 * s.a, 2.0 * s.b],
        radius: s.a,
        object_from_tag: tag_frame(on_surface(tag_at.0, tag_at.1), s.normal(tag_at.0, tag_at.1), Vector3::z()),
        tag_size: 0.09,
        // the groove's bottom turns 4 degrees per mm; the flank, 0.35 degrees per mm (radius ~0.16 m)
        targets: vec![
            Target { name: "groove".into(), p: on_surface(s.groove_x, 0.0), n: s.normal(s.groove_x, 0.0) },
            Target { name: "flank".into(), p: on_surface(0.08, 0.04), n: s.normal(0.08, 0.04) },
        ],
    }
}

fn cylinder_workpiece() -> Workpiece {
    let (r, h) = CYLINDER;
    Workpiece {
        cad: cylinder(r, r, r, h, 256),
        centre: Point3::new(r, r, 0.35),
        footprint: [0.0, 0.0, 2.0 * r, 2.0 * r],
        radius: r,
        object_from_tag: tag_frame(Point3::new(r, 0.0, 0.45), -Vector3::y(), Vector3::z()),
        tag_size: 0.08,
        targets: vec![Target { name: "side".into(), p: Point3::new(r, 0.0, 0.25), n: -Vector3::y() }],
    }
}

/// A sphere of radius 20 cm resting on the floor (touching it at one point under its centre),
/// tag (8 cm) on its -y side 15 degrees above the equator, facing out along the sphere's normal there.
fn sphere_workpiece() -> Workpiece {
    let r = SPHERE_RADIUS;
    let centre = Point3::new(r, r, r);
    let el = SPHERE_TAG_ELEVATION_DEG.to_radians();
    let tag_normal = Vector3::new(0.0, -el.cos(), el.sin());
    let upper = Vector3::new(1.0, 0.0, 1.0).normalize();
    Workpiece {
        cad: sphere(centre, r, 128, 256),
        centre,
        footprint: [0.0, 0.0, 2.0 * r, 2.0 * r],
        radius: r,
        object_from_tag: tag_frame(centre + tag_normal * r, tag_normal, Vector3::z()),
        tag_size: 0.08,
        // 45 degrees up on the +x side (turned 90 degrees about the vertical from the tag)
        targets: vec![Target { name: "upper".into(), p: centre + upper * r, n: upper }],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_surface_points_lie_on_the_surface_along_their_normal() {
        // a point 3 mm off each target along its normal and 1 mm aside comes back to the surface
        for kind in [SceneKind::Box, SceneKind::Shell, SceneKind::Cylinder, SceneKind::Sphere] {
            let wp = workpiece(kind);
            for t in &wp.targets {
                let aside = t.n.cross(&Vector3::new(0.3, 0.5, 0.8)).normalize() * 0.001;
                let p = t.p + t.n * 0.003 + aside;
                let (q, n) = nearest_surface(kind, &p);
                // p - q is along the normal at q, 3 mm (to first order), and q is 1 mm from the target
                assert!((p - q).normalize().angle(&n) < 0.01, "{kind:?}: {:.4} rad", (p - q).normalize().angle(&n));
                assert!(((p - q).norm() - 0.003).abs() < 2e-4, "{kind:?}: {:.5} m", (p - q).norm());
                assert!(((q - t.p).norm() - 0.001).abs() < 3e-4, "{kind:?}: {:.5} m", (q - t.p).norm());
                // the point on the surface is its own nearest, with the target's normal at the target
                let (q0, n0) = nearest_surface(kind, &t.p);
                assert!((q0 - t.p).norm() < 1e-7 && n0.angle(&t.n) < 1e-6, "{kind:?}");
            }
        }
    }

    #[test]
    fn tag_frames_are_right_handed_with_y_up() {
        for kind in [SceneKind::Box, SceneKind::Shell, SceneKind::Cylinder, SceneKind::Sphere] {
            let wp = workpiece(kind);
            let r = wp.object_from_tag.rotation;
            let (x, y, z) = (r * Vector3::x(), r * Vector3::y(), r * Vector3::z());
            assert!((x.cross(&y) - z).norm() < 1e-12);
            assert!(y.z > 0.4, "{kind:?}: y must point up, {y:?}");
            assert!(z.y < -0.8, "{kind:?}: the tag faces -y, {z:?}");
            assert!(x.z.abs() < 1e-12, "{kind:?}: x is horizontal");
        }
        let bx = workpiece(SceneKind::Box);
        assert_eq!(bx.object_from_tag.translation.vector, Vector3::new(0.2425, 0.0, 0.15));
    }
}
