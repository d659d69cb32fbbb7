//! Standard viewpoints and the orthographic fit-to-bounds projection of the renderer.
//!
//! The world is z-up (the floor's normal). A view is an orthonormal basis: `right` and `up` span the
//! image plane, `forward` points from the viewer into the scene; pixel x grows along `right`, pixel
//! y grows downward (against `up`).

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

/// A standard viewpoint around the cloud (world z up).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Viewpoint {
    /// From -y looking along +y; x to the right, z up.
    Front,
    /// From +x looking along -x; y to the right, z up.
    Side,
    /// From +z looking down; x to the right, y up in the image.
    Top,
    /// From (-1, -1, 1) toward the centre (isometric-like); z up.
    Iso,
}

impl Viewpoint {
    /// The four standard viewpoints, in the order reports show them.
    pub const ALL: [Viewpoint; 4] = [Viewpoint::Front, Viewpoint::Side, Viewpoint::Top, Viewpoint::Iso];

    /// Lower-case name, used for file names (`front`, `side`, `top`, `iso`).
    pub fn name(self) -> &'static str {
        match self {
            Viewpoint::Front => "front",
            Viewpoint::Side => "side",
            Viewpoint::Top => "top",
            Viewpoint::Iso => "iso",
        }
    }

    /// The view basis `(right, up, forward)`, orthonormal and right-handed (`right × up = -forward`).
    pub fn basis(self) -> ViewBasis {
        let (forward, up_hint) = match self {
            Viewpoint::Front => (Vector3::new(0.0, 1.0, 0.0), Vector3::z()),
            Viewpoint::Side => (Vector3::new(-1.0, 0.0, 0.0), Vector3::z()),
            Viewpoint::Top => (Vector3::new(0.0, 0.0, -1.0), Vector3::y()),
            Viewpoint::Iso => (Vector3::new(1.0, 1.0, -1.0).normalize(), Vector3::z()),
        };
        ViewBasis::looking(forward, up_hint)
    }
}

/// An orthonormal camera basis in world coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewBasis {
    /// Image x direction.
    pub right: Vector3<f32>,
    /// Image up direction (pixel rows grow against it).
    pub up: Vector3<f32>,
    /// Viewing direction, into the scene (depth grows along it).
    pub forward: Vector3<f32>,
}

impl ViewBasis {
    /// The basis looking along `forward` with `up_hint` projected to the image's up direction.
    /// `forward` and `up_hint` must not be parallel (the standard viewpoints never are).
    pub fn looking(forward: Vector3<f32>, up_hint: Vector3<f32>) -> Self {
        let forward = forward.normalize();
        let right = forward.cross(&up_hint).normalize();
        let up = right.cross(&forward);
        Self { right, up, forward }
    }
}

/// Orthographic projection of world points onto an image, scaled to fit the points' extent.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Projection {
    /// The view basis.
    pub basis: ViewBasis,
    /// Pixels per metre.
    pub px_per_m: f32,
    /// World-space coordinates `(right, up)` of the image centre.
    pub center: [f32; 2],
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
}

impl Projection {
    /// The projection that fits every point of `points` into a `width` x `height` image with
    /// `margin_px` free on each side, or `None` for an empty slice.
    pub fn fit(points: &[Point3<f32>], basis: ViewBasis, width: u32, height: u32, margin_px: u32) -> Option<Self> {
        let first = points.first()?;
        let init = {
            let (x, y) = (first.coords.dot(&basis.right), first.coords.dot(&basis.up));
            [x, x, y, y]
        };
        let [x0, x1, y0, y1] = points.iter().fold(init, |[x0, x1, y0, y1], p| {
            let (x, y) = (p.coords.dot(&basis.right), p.coords.dot(&basis.up));
            [x0.min(x), x1.max(x), y0.min(y), y1.max(y)]
        });
        let free_w = (width.saturating_sub(2 * margin_px)).max(1) as f32;
        let free_h = (height.saturating_sub(2 * margin_px)).max(1) as f32;
        let span_x = (x1 - x0).max(1e-9);
        let span_y = (y1 - y0).max(1e-9);
        let px_per_m = (free_w / span_x).min(free_h / span_y);
        Some(Self { basis, px_per_m, center: [(x0 + x1) / 2.0, (y0 + y1) / 2.0], width, height })
    }

    /// Pixel coordinates `(x, y)` (pixel centres at integers) and depth along `forward`, metres.
    pub fn project(&self, p: &Point3<f32>) -> [f32; 3] {
        let x = p.coords.dot(&self.basis.right) - self.center[0];
        let y = p.coords.dot(&self.basis.up) - self.center[1];
        [
            (self.width as f32 - 1.0) / 2.0 + x * self.px_per_m,
            (self.height as f32 - 1.0) / 2.0 - y * self.px_per_m,
            p.coords.dot(&self.basis.forward),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bases_are_orthonormal_and_look_the_right_way() {
        for v in Viewpoint::ALL {
            let b = v.basis();
            assert!((b.right.norm() - 1.0).abs() < 1e-6 && (b.up.norm() - 1.0).abs() < 1e-6);
            assert!(b.right.dot(&b.up).abs() < 1e-6 && b.up.dot(&b.forward).abs() < 1e-6);
            assert!((b.right.cross(&b.up) + b.forward).norm() < 1e-6, "{v:?} right-handed");
        }
        let front = Viewpoint::Front.basis();
        assert!((front.right - Vector3::x()).norm() < 1e-6 && (front.up - Vector3::z()).norm() < 1e-6);
        let top = Viewpoint::Top.basis();
        assert!((top.right - Vector3::x()).norm() < 1e-6 && (top.up - Vector3::y()).norm() < 1e-6);
        assert!(Viewpoint::Iso.basis().up.z > 0.5, "iso keeps z up");
    }

    #[test]
    fn fit_maps_the_extent_onto_the_free_area() {
        // A 2 m (x) by 1 m (z) rectangle seen from the front in a 210 x 110 image, margin 5:
        // 200 px for 2 m across, 100 px for 1 m up -> 100 px/m, corners on the margins.
        let pts = [Point3::new(-1.0, 0.0, 0.0), Point3::new(1.0, 3.0, 1.0)];
        let proj = Projection::fit(&pts, Viewpoint::Front.basis(), 210, 110, 5).expect("points");
        assert!((proj.px_per_m - 100.0).abs() < 1e-3);
        let [x0, y0, d0] = proj.project(&pts[0]);
        let [x1, y1, d1] = proj.project(&pts[1]);
        assert!((x0 - 4.5).abs() < 1e-3 && (x1 - 204.5).abs() < 1e-3, "{x0} {x1}");
        assert!((y0 - 104.5).abs() < 1e-3 && (y1 - 4.5).abs() < 1e-3, "{y0} {y1}");
        assert!((d1 - d0 - 3.0).abs() < 1e-5, "depth along +y");
        assert!(Projection::fit(&[], Viewpoint::Top.basis(), 10, 10, 0).is_none());
    }
}
