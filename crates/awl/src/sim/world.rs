//! The renderable world: every mesh of a scene in the world frame, one material per triangle, smooth
//! vertex normals for shading, and one parry BVH built once for all the views.

use nalgebra::{Isometry3, Point3, Vector3};
use parry3d_f64::math::Vector as PVector;
use parry3d_f64::query::{Ray, RayCast};
use parry3d_f64::shape::TriMesh as ParryMesh;

use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use crate::sim::shade::to_linear;
use crate::sim::tag36h11::{TAG_BORDER_MODULES, TAG_MODULES};

/// How a material's albedo varies over its surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Texture {
    /// Constant albedo.
    Plain,
    /// Procedural concrete-like noise.
    Floor,
    /// Constant albedo, except where the tag is printed.
    Tagged,
}

/// Surface properties of a group of triangles.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Material {
    /// Label written to the label image (1 floor, 2 workpiece, 3 clutter or wall).
    pub label: u8,
    /// sRGB albedo, 0..255.
    pub albedo: [f64; 3],
    /// Texture.
    pub texture: Texture,
}

/// The tag printed on the workpiece (planar projection along the tag's z).
#[derive(Debug, Clone, Copy)]
pub(crate) struct TagPrint {
    /// Inverse of `T_world_tag`.
    pub tag_from_world: Isometry3<f64>,
    /// Black-border edge, metres.
    pub size: f64,
    /// `black[row][col]`, row 0 at the top.
    pub black: [[bool; TAG_MODULES]; TAG_MODULES],
}

impl TagPrint {
    /// Whether the tag is black at the world point `p` (`None` outside the printed square or off the
    /// face, more than 3 cm from the tag plane).
    pub(crate) fn black_at(&self, p: &Point3<f64>) -> Option<bool> {
        let q = self.tag_from_world * p;
        let module = self.size / TAG_BORDER_MODULES as f64;
        let half = module * TAG_MODULES as f64 / 2.0;
        if q.z.abs() > 0.03 || q.x.abs() >= half || q.y.abs() >= half {
            return None;
        }
        let col = ((q.x + half) / module).floor() as usize;
        let row = ((half - q.y) / module).floor() as usize;
        Some(self.black[row.min(TAG_MODULES - 1)][col.min(TAG_MODULES - 1)])
    }

    /// Whether `p` is on the printed square or within one module of it (where colors need supersampling).
    pub(crate) fn near(&self, p: &Point3<f64>) -> bool {
        let q = self.tag_from_world * p;
        let module = self.size / TAG_BORDER_MODULES as f64;
        let reach = module * (TAG_MODULES as f64 / 2.0 + 1.0);
        q.z.abs() <= 0.03 && q.x.abs() < reach && q.y.abs() < reach
    }
}

/// A ray hit: distance along the ray (in units of the ray direction), the point and the triangle.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Hit {
    /// Ray parameter.
    pub t: f64,
    /// World point.
    pub point: Point3<f64>,
    /// Triangle index.
    pub triangle: u32,
}

/// The scene ready for ray casting.
pub(crate) struct World {
    vertices: Vec<Point3<f64>>,
    normals: Vec<Vector3<f64>>,
    triangles: Vec<[u32; 3]>,
    face_normals: Vec<Vector3<f64>>,
    tri_material: Vec<u16>,
    materials: Vec<Material>,
    linear_albedo: Vec<[f64; 3]>,
    bvh: ParryMesh,
    floor: Option<Floor>,
    /// The printed tag, if any.
    pub tag: Option<TagPrint>,
    /// Seed of the procedural floor texture.
    pub texture_seed: u64,
}

/// Triangle index reported for hits on the floor (which is a plane, not part of the BVH).
const FLOOR_TRIANGLE: u32 = u32::MAX;

/// The floor: the square `|x - cx|, |y - cy| <= half` of the plane at height `z`, cast analytically so
/// the BVH only holds the objects (most rays end on the floor and never enter the BVH).
#[derive(Debug, Clone, Copy)]
struct Floor {
    z: f64,
    centre: (f64, f64),
    half: f64,
    material: u16,
}

impl Floor {
    fn cast(&self, origin: &Point3<f64>, dir: &Vector3<f64>, max_t: f64) -> Option<f64> {
        let t = (self.z - origin.z) / dir.z;
        if !(t > 0.0 && t < max_t) {
            return None;
        }
        let (x, y) = (origin.x + dir.x * t, origin.y + dir.y * t);
        ((x - self.centre.0).abs() <= self.half && (y - self.centre.1).abs() <= self.half).then_some(t)
    }
}

/// Collects meshes and materials, then builds the [`World`].
#[derive(Default)]
pub(crate) struct WorldBuilder {
    vertices: Vec<Point3<f64>>,
    normals: Vec<Vector3<f64>>,
    triangles: Vec<[u32; 3]>,
    tri_material: Vec<u16>,
    materials: Vec<Material>,
    floor: Option<Floor>,
}

fn vertex_normals(mesh: &TriMesh) -> Vec<Vector3<f64>> {
    let mut normals = vec![Vector3::zeros(); mesh.vertices.len()];
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| mesh.vertices[i as usize]);
        let n = (b - a).cross(&(c - a));
        for &i in t {
            normals[i as usize] += n;
        }
    }
    normals.into_iter().map(|n| n.try_normalize(1e-300).unwrap_or_else(Vector3::z)).collect()
}

impl WorldBuilder {
    fn material_index(&mut self, material: Material) -> u16 {
        let index = self.materials.iter().position(|m| *m == material).unwrap_or_else(|| {
            self.materials.push(material);
            self.materials.len() - 1
        });
        index as u16
    }

    /// Sets the floor: the square of half-size `half` centred under `(x, y)` at height `z`.
    pub(crate) fn floor(&mut self, (x, y, z): (f64, f64, f64), half: f64, material: Material) {
        let material = self.material_index(material);
        self.floor = Some(Floor { z, centre: (x, y), half, material });
    }

    /// Adds `mesh` moved by `world_from_local`, with `material`.
    pub(crate) fn add(&mut self, mesh: &TriMesh, world_from_local: &Isometry3<f64>, material: Material) {
        let index = self.material_index(material);
        let base = self.vertices.len() as u32;
        self.vertices.extend(mesh.vertices.iter().map(|p| world_from_local * p));
        self.normals.extend(vertex_normals(mesh).iter().map(|n| world_from_local.rotation * n));
        self.triangles.extend(mesh.triangles.iter().map(|t| t.map(|i| i + base)));
        self.tri_material.extend(std::iter::repeat_n(index, mesh.triangles.len()));
    }

    /// Builds the BVH.
    ///
    /// # Errors
    /// [`Error::Invalid`] when the scene is empty or parry refuses the mesh.
    pub(crate) fn build(self, tag: Option<TagPrint>, texture_seed: u64) -> Result<World> {
        if self.triangles.is_empty() {
            return Err(Error::invalid("simulated scene", "the scene has no mesh"));
        }
        let points: Vec<PVector> = self.vertices.iter().map(|p| PVector::new(p.x, p.y, p.z)).collect();
        let bvh = ParryMesh::new(points, self.triangles.clone())
            .map_err(|e| Error::invalid("simulated scene", format!("cannot build the ray-casting mesh: {e:?}")))?;
        let face_normals = self
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.vertices[i as usize]);
                (b - a).cross(&(c - a)).try_normalize(1e-300).unwrap_or_else(Vector3::z)
            })
            .collect();
        Ok(World {
            vertices: self.vertices,
            normals: self.normals,
            triangles: self.triangles,
            face_normals,
            tri_material: self.tri_material,
            linear_albedo: self.materials.iter().map(|m| m.albedo.map(to_linear)).collect(),
            materials: self.materials,
            bvh,
            floor: self.floor,
            tag,
            texture_seed,
        })
    }
}

impl World {
    /// The first hit of the ray `origin + t * dir` with `t < max_t`.
    pub(crate) fn cast(&self, origin: &Point3<f64>, dir: &Vector3<f64>, max_t: f64) -> Option<Hit> {
        let floor_t = self.floor.as_ref().and_then(|f| f.cast(origin, dir, max_t));
        let ray = Ray::new(PVector::new(origin.x, origin.y, origin.z), PVector::new(dir.x, dir.y, dir.z));
        match self.bvh.cast_local_ray_and_get_normal(&ray, floor_t.unwrap_or(max_t), false) {
            Some(hit) => {
                let t = hit.time_of_impact;
                Some(Hit { t, point: origin + dir * t, triangle: hit.subshape })
            }
            None => floor_t.map(|t| Hit { t, point: origin + dir * t, triangle: FLOOR_TRIANGLE }),
        }
    }

    fn material_index(&self, triangle: u32) -> usize {
        let index = match (triangle, self.floor) {
            (FLOOR_TRIANGLE, Some(floor)) => floor.material,
            _ => self.tri_material.get(triangle as usize).copied().unwrap_or(0),
        };
        usize::from(index).min(self.materials.len() - 1)
    }

    /// The material of a triangle.
    pub(crate) fn material(&self, triangle: u32) -> &Material {
        &self.materials[self.material_index(triangle)]
    }

    /// The linear albedo of a triangle's material.
    pub(crate) fn linear_albedo(&self, triangle: u32) -> [f64; 3] {
        self.linear_albedo[self.material_index(triangle)]
    }

    /// The geometric (flat) unit normal of a triangle.
    pub(crate) fn face_normal(&self, triangle: u32) -> Vector3<f64> {
        self.face_normals.get(triangle as usize).copied().unwrap_or_else(Vector3::z)
    }

    /// The smooth shading normal at a hit (vertex normals interpolated barycentrically).
    pub(crate) fn shading_normal(&self, hit: &Hit) -> Vector3<f64> {
        let Some(t) = self.triangles.get(hit.triangle as usize) else { return self.face_normal(hit.triangle) };
        let [a, b, c] = t.map(|i| self.vertices[i as usize]);
        let (v0, v1, v2) = (b - a, c - a, hit.point - a);
        let (d00, d01, d11) = (v0.dot(&v0), v0.dot(&v1), v1.dot(&v1));
        let (d20, d21) = (v2.dot(&v0), v2.dot(&v1));
        let denom = d00 * d11 - d01 * d01;
        if denom.abs() < 1e-300 {
            return self.face_normal(hit.triangle);
        }
        let v = ((d11 * d20 - d01 * d21) / denom).clamp(0.0, 1.0);
        let w = ((d00 * d21 - d01 * d20) / denom).clamp(0.0, 1.0);
        let u = (1.0 - v - w).max(0.0);
        let [na, nb, nc] = t.map(|i| self.normals[i as usize]);
        (na * u + nb * v + nc * w).try_normalize(1e-300).unwrap_or_else(|| self.face_normal(hit.triangle))
    }
}
