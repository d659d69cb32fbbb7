//! Triangle meshes (CAD models, simulator scenes) and area-weighted surface sampling.

use nalgebra::{Point3, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::cloud::PointCloud;
use crate::error::{Error, Result};

/// An indexed triangle mesh, metres.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions.
    pub vertices: Vec<Point3<f64>>,
    /// Triangles as indices into `vertices`, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
}

impl TriMesh {
    /// Total surface area, square metres (triangles with an out-of-range index count as zero).
    pub fn area(&self) -> f64 {
        (0..self.triangles.len()).map(|t| self.triangle_cross(t).map_or(0.0, |c| 0.5 * c.norm())).sum()
    }

    /// Checks that every index is in range and every vertex is finite.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming `what` and the first offending triangle or vertex.
    pub fn validate(&self, what: &str) -> Result<()> {
        let n = self.vertices.len();
        if let Some(v) = self.vertices.iter().position(|p| !p.coords.iter().all(|c| c.is_finite())) {
            return Err(Error::invalid(what, format!("vertex {v} is not finite: {:?}", self.vertices[v])));
        }
        for (t, tri) in self.triangles.iter().enumerate() {
            if let Some(&i) = tri.iter().find(|&&i| i as usize >= n) {
                return Err(Error::invalid(
                    what,
                    format!("triangle {t}: vertex index {i} out of range ({n} vertices)"),
                ));
            }
        }
        Ok(())
    }

    /// `n` points drawn uniformly over the surface (area-weighted), each with the unit face normal of
    /// its triangle (counter-clockwise winding). Deterministic for a given `seed` (ChaCha8).
    ///
    /// # Errors
    /// [`Error::Invalid`] when the mesh fails [`TriMesh::validate`] or has zero total area.
    pub fn sample_surface(&self, n: usize, seed: u64) -> Result<PointCloud> {
        self.validate("mesh")?;
        let mut cumulative = Vec::with_capacity(self.triangles.len());
        let mut total = 0.0f64;
        let mut last_positive = None;
        for t in 0..self.triangles.len() {
            let a = self.triangle_cross(t).map_or(0.0, |c| 0.5 * c.norm());
            if a > 0.0 {
                last_positive = Some(t);
            }
            total += a;
            cumulative.push(total);
        }
        let (Some(last), true) = (last_positive, total.is_finite() && total > 0.0) else {
            return Err(Error::invalid("mesh", format!("cannot sample a surface of area {total}")));
        };
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut points = Vec::with_capacity(n);
        let mut normals = Vec::with_capacity(n);
        for _ in 0..n {
            let u = rng.random::<f64>() * total;
            let t = cumulative.partition_point(|&c| c <= u).min(last);
            let [a, b, c] = self.triangles[t].map(|i| self.vertices[i as usize]);
            let s = rng.random::<f64>().sqrt();
            let r = rng.random::<f64>();
            // Barycentric (1 - s, s (1 - r), s r): uniform over the triangle.
            let p = a + (b - a) * (s * (1.0 - r)) + (c - a) * (s * r);
            let normal = (b - a).cross(&(c - a)).normalize();
            points.push(p.cast::<f32>());
            normals.push(normal.cast::<f32>());
        }
        Ok(PointCloud { points, normals: Some(normals), colors: None })
    }

    /// `(b - a) × (c - a)` of triangle `t`, or `None` when an index is out of range.
    fn triangle_cross(&self, t: usize) -> Option<Vector3<f64>> {
        let [a, b, c] = self.triangles.get(t)?.map(|i| self.vertices.get(i as usize));
        let (a, b, c) = (a?, b?, c?);
        Some((b - a).cross(&(c - a)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_cube() -> TriMesh {
        let vertices = (0..8u32)
            .map(|i| Point3::new(f64::from(i & 1), f64::from((i >> 1) & 1), f64::from((i >> 2) & 1)))
            .collect();
        // Counter-clockwise seen from outside.
        let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
        let triangles = quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
        TriMesh { vertices, triangles }
    }

    #[test]
    fn cube_sampling_is_on_the_surface_and_uniform() {
        let cube = unit_cube();
        assert!((cube.area() - 6.0).abs() < 1e-12);
        let cloud = cube.sample_surface(100_000, 7).expect("sample");
        let normals = cloud.normals.as_ref().expect("normals");
        let mut per_face = [0usize; 6];
        for (p, n) in cloud.points.iter().zip(normals) {
            let p = p.cast::<f64>();
            assert!(p.coords.iter().all(|&c| (-1e-9..=1.0 + 1e-9).contains(&c)), "{p}");
            let d = p.coords.iter().map(|&c| c.abs().min((c - 1.0).abs())).fold(f64::INFINITY, f64::min);
            assert!(d <= 1e-9, "{p} is {d} off the surface");
            let axis = n.iamax();
            assert!((n[axis].abs() - 1.0).abs() < 1e-6);
            assert!(f64::from(n[axis]) * (p[axis] - 0.5) > 0.0, "normal {n} points inward at {p}");
            per_face[axis * 2 + usize::from(n[axis] > 0.0)] += 1;
        }
        for count in per_face {
            let fraction = count as f64 / 100_000.0;
            assert!((fraction - 1.0 / 6.0).abs() < 0.01, "{per_face:?}");
        }
        assert_eq!(cube.sample_surface(1000, 7).expect("again").points, cloud.points[..1000].to_vec());
    }

    #[test]
    fn bad_meshes_are_errors() {
        let mut cube = unit_cube();
        cube.triangles.push([0, 1, 8]);
        assert!(cube.validate("cube").expect_err("must fail").to_string().contains("triangle 12"));
        assert!(cube.sample_surface(10, 0).is_err());
        let flat = TriMesh { vertices: vec![Point3::origin(); 3], triangles: vec![[0, 1, 2]] };
        assert!(flat.sample_surface(10, 0).expect_err("must fail").to_string().contains("area"));
        let empty = TriMesh::default();
        assert!(empty.sample_surface(10, 0).is_err());
        assert_eq!(empty.area(), 0.0);
    }
}
