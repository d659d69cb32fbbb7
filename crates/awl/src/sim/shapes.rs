//! Mesh primitives of the simulated scenes, counter-clockwise seen from outside: cuboids, quads,
//! cylinders, spheres and the free-form dome shell with its groove.

use nalgebra::{Point3, Vector3};

use crate::mesh::TriMesh;

/// Appends the quad `a b c d` (counter-clockwise seen from the side it faces) with its own vertices.
fn push_quad(mesh: &mut TriMesh, corners: [Point3<f64>; 4]) {
    let base = mesh.vertices.len() as u32;
    mesh.vertices.extend_from_slice(&corners);
    mesh.triangles.push([base, base + 1, base + 2]);
    mesh.triangles.push([base, base + 2, base + 3]);
}

/// A single quad (two triangles) with corners `a b c d`, facing where `(b - a) x (c - a)` points.
pub(crate) fn quad(corners: [Point3<f64>; 4]) -> TriMesh {
    let mut mesh = TriMesh::default();
    push_quad(&mut mesh, corners);
    mesh
}

/// The closed axis-aligned box `[min, max]`, each face with its own four vertices (flat normals).
pub(crate) fn cuboid(min: Point3<f64>, max: Point3<f64>) -> TriMesh {
    let (x0, y0, z0) = (min.x, min.y, min.z);
    let (x1, y1, z1) = (max.x, max.y, max.z);
    let p = Point3::new;
    let mut mesh = TriMesh::default();
    push_quad(&mut mesh, [p(x0, y0, z0), p(x0, y1, z0), p(x1, y1, z0), p(x1, y0, z0)]); // -z
    push_quad(&mut mesh, [p(x0, y0, z1), p(x1, y0, z1), p(x1, y1, z1), p(x0, y1, z1)]); // +z
    push_quad(&mut mesh, [p(x0, y0, z0), p(x1, y0, z0), p(x1, y0, z1), p(x0, y0, z1)]); // -y
    push_quad(&mut mesh, [p(x0, y1, z0), p(x0, y1, z1), p(x1, y1, z1), p(x1, y1, z0)]); // +y
    push_quad(&mut mesh, [p(x0, y0, z0), p(x0, y0, z1), p(x0, y1, z1), p(x0, y1, z0)]); // -x
    push_quad(&mut mesh, [p(x1, y0, z0), p(x1, y1, z0), p(x1, y1, z1), p(x1, y0, z1)]); // +x
    mesh
}

/// A closed cylinder standing on z = 0 around the vertical axis through `(cx, cy)`; the side shares
/// vertices around (smooth normals) and is cut into 2.5 cm bands (no long slivers, so the BVH stays
/// tight when the cylinder is tilted); the caps have their own vertices (flat normals).
pub(crate) fn cylinder(cx: f64, cy: f64, radius: f64, height: f64, segments: u32) -> TriMesh {
    let mut mesh = TriMesh::default();
    let ring = |z: f64| {
        (0..segments).map(move |j| {
            let phi = std::f64::consts::TAU * f64::from(j) / f64::from(segments);
            Point3::new(cx + radius * phi.cos(), cy + radius * phi.sin(), z)
        })
    };
    let bands = ((height / 0.025).ceil() as u32).max(1);
    for k in 0..=bands {
        mesh.vertices.extend(ring(height * f64::from(k) / f64::from(bands)));
    }
    for k in 0..bands {
        for j in 0..segments {
            let next = (j + 1) % segments;
            let (b0, b1) = (k * segments + j, k * segments + next);
            let (t0, t1) = ((k + 1) * segments + j, (k + 1) * segments + next);
            mesh.triangles.push([b0, b1, t1]);
            mesh.triangles.push([b0, t1, t0]);
        }
    }
    for (z, up) in [(0.0, false), (height, true)] {
        let centre = mesh.vertices.len() as u32;
        mesh.vertices.push(Point3::new(cx, cy, z));
        mesh.vertices.extend(ring(z));
        for j in 0..segments {
            let (a, b) = (centre + 1 + j, centre + 1 + (j + 1) % segments);
            mesh.triangles.push(if up { [centre, a, b] } else { [centre, b, a] });
        }
    }
    mesh
}

/// A sphere of `radius` around `centre`: `rings` latitude rings between the poles (which lie on the
/// vertical through the centre) and `segments` longitudes, vertices shared (smooth normals).
pub(crate) fn sphere(centre: Point3<f64>, radius: f64, rings: u32, segments: u32) -> TriMesh {
    let mut mesh = TriMesh::default();
    let pi = std::f64::consts::PI;
    mesh.vertices.push(centre - Vector3::z() * radius);
    for i in 1..rings {
        let polar = pi * f64::from(i) / f64::from(rings);
        let (z, rho) = (-polar.cos() * radius, polar.sin() * radius);
        mesh.vertices.extend((0..segments).map(|j| {
            let phi = std::f64::consts::TAU * f64::from(j) / f64::from(segments);
            centre + Vector3::new(rho * phi.cos(), rho * phi.sin(), z)
        }));
    }
    let top = mesh.vertices.len() as u32;
    mesh.vertices.push(centre + Vector3::z() * radius);
    let v = |i: u32, j: u32| 1 + (i - 1) * segments + (j % segments);
    for j in 0..segments {
        mesh.triangles.push([0, v(1, j + 1), v(1, j)]);
        mesh.triangles.push([top, v(rings - 1, j), v(rings - 1, j + 1)]);
    }
    for i in 1..rings - 1 {
        for j in 0..segments {
            mesh.triangles.push([v(i, j), v(i, j + 1), v(i + 1, j + 1)]);
            mesh.triangles.push([v(i, j), v(i + 1, j + 1), v(i + 1, j)]);
        }
    }
    mesh
}

/// The dome shell: an elliptic footprint `2a x 2b` on z = 0, height `h`, a superellipsoid-like
/// profile `z = h (1 - rho^2)^0.6`, and a groove of depth `groove_depth` and width sigma
/// `groove_sigma` across the top along y at `x' = groove_x` (x' measured from the footprint centre).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Dome {
    /// Footprint half-length along x, metres.
    pub a: f64,
    /// Footprint half-width along y, metres.
    pub b: f64,
    /// Height, metres.
    pub h: f64,
    /// Groove centre line, x' (from the footprint centre), metres.
    pub groove_x: f64,
    /// Groove depth at the top, metres.
    pub groove_depth: f64,
    /// Groove Gaussian sigma across, metres.
    pub groove_sigma: f64,
}

impl Dome {
    /// Surface height at `(x', y')` relative to the footprint centre; 0 outside the footprint.
    pub(crate) fn height(&self, xc: f64, yc: f64) -> f64 {
        let rho2 = (xc / self.a).powi(2) + (yc / self.b).powi(2);
        if rho2 >= 1.0 {
            return 0.0;
        }
        let dome = self.h * (1.0 - rho2).powf(0.6);
        let across = (xc - self.groove_x) / self.groove_sigma;
        dome - self.groove_depth * (-0.5 * across * across).exp() * (dome / self.h).powi(2)
    }

    /// Outward unit normal of the top surface at `(x', y')` (central differences).
    pub(crate) fn normal(&self, xc: f64, yc: f64) -> Vector3<f64> {
        let e = 1e-6;
        let dx = (self.height(xc + e, yc) - self.height(xc - e, yc)) / (2.0 * e);
        let dy = (self.height(xc, yc + e) - self.height(xc, yc - e)) / (2.0 * e);
        Vector3::new(-dx, -dy, 1.0).normalize()
    }

    /// The closed mesh in the object frame (footprint corner at the origin, so the footprint spans
    /// `[0, 2a] x [0, 2b]`): `rings` rings from the apex to the rim (denser near the steep rim),
    /// `segments` around, and a flat bottom with its own vertices.
    pub(crate) fn mesh(&self, rings: u32, segments: u32) -> TriMesh {
        let mut mesh = TriMesh::default();
        let at = |r: f64, phi: f64| {
            let (xc, yc) = (self.a * r * phi.cos(), self.b * r * phi.sin());
            let z = if r >= 1.0 { 0.0 } else { self.height(xc, yc) };
            Point3::new(self.a + xc, self.b + yc, z)
        };
        let angle = |j: u32| std::f64::consts::TAU * f64::from(j) / f64::from(segments);
        mesh.vertices.push(at(0.0, 0.0));
        for i in 1..=rings {
            let r = (std::f64::consts::FRAC_PI_2 * f64::from(i) / f64::from(rings)).sin();
            mesh.vertices.extend((0..segments).map(|j| at(r, angle(j))));
        }
        let v = |i: u32, j: u32| 1 + (i - 1) * segments + (j % segments);
        for j in 0..segments {
            mesh.triangles.push([0, v(1, j), v(1, j + 1)]);
        }
        for i in 1..rings {
            for j in 0..segments {
                mesh.triangles.push([v(i, j), v(i + 1, j), v(i + 1, j + 1)]);
                mesh.triangles.push([v(i, j), v(i + 1, j + 1), v(i, j + 1)]);
            }
        }
        let centre = mesh.vertices.len() as u32;
        mesh.vertices.push(Point3::new(self.a, self.b, 0.0));
        mesh.vertices.extend((0..segments).map(|j| at(1.0, angle(j))));
        for j in 0..segments {
            let (a, b) = (centre + 1 + j, centre + 1 + (j + 1) % segments);
            mesh.triangles.push([centre, b, a]);
        }
        mesh
    }
}

/// Signed volume enclosed by a closed mesh (positive when its triangles face outward).
#[cfg(test)]
pub(crate) fn signed_volume(mesh: &TriMesh) -> f64 {
    mesh.triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| mesh.vertices[i as usize].coords);
            a.dot(&b.cross(&c)) / 6.0
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closed_primitives_face_outward_with_the_right_volume() {
        let cube = cuboid(Point3::new(0.0, 0.0, 0.0), Point3::new(0.485, 0.48, 0.30));
        assert!((signed_volume(&cube) - 0.485 * 0.48 * 0.30).abs() < 1e-12);
        let cyl = cylinder(0.15, 0.15, 0.15, 0.7, 256);
        let expected = std::f64::consts::PI * 0.15 * 0.15 * 0.7;
        assert!((signed_volume(&cyl) / expected - 1.0).abs() < 1e-3, "{}", signed_volume(&cyl));
        let dome = Dome { a: 0.25, b: 0.2, h: 0.35, groove_x: -0.06, groove_depth: 0.0, groove_sigma: 0.017 };
        let v = signed_volume(&dome.mesh(120, 240));
        assert!(v > 0.0 && v < std::f64::consts::PI * 0.25 * 0.2 * 0.35, "{v}");
        let ball = sphere(Point3::new(0.2, 0.2, 0.2), 0.2, 128, 256);
        let expected = 4.0 / 3.0 * std::f64::consts::PI * 0.2f64.powi(3);
        assert!((signed_volume(&ball) / expected - 1.0).abs() < 1e-3, "{}", signed_volume(&ball));
        assert!(ball.vertices.iter().all(|p| ((p - Point3::new(0.2, 0.2, 0.2)).norm() - 0.2).abs() < 1e-12));
    }

    #[test]
    fn groove_is_two_centimetres_deep_on_top() {
        let dome = Dome { a: 0.25, b: 0.2, h: 0.35, groove_x: -0.06, groove_depth: 0.02, groove_sigma: 0.017 };
        let plain = Dome { groove_depth: 0.0, ..dome };
        let dip = plain.height(-0.06, 0.0) - dome.height(-0.06, 0.0);
        assert!(dip > 0.018 && dip < 0.02, "{dip}");
        assert!(plain.height(0.1, 0.0) - dome.height(0.1, 0.0) < 0.001);
        let n = dome.normal(0.0, -0.16);
        assert!(n.y < -0.8 && n.z > 0.2, "{n:?}");
    }
}
