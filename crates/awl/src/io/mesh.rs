//! Format dispatch on the file extension: meshes (`.ply`, `.stl`, `.obj`) and clouds (`.ply`,
//! `.pcd`).

use std::io::Cursor;
use std::path::Path;

use nalgebra::Point3;

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::io::pcd::{PcdEncoding, parse_pcd_checked, write_pcd};
use crate::io::ply::{PlyEncoding, parse_ply_checked, parse_ply_mesh, write_ply};
use crate::io::{Loaded, extension, read_bytes};
use crate::mesh::TriMesh;

/// Reads a triangle mesh: `.ply` (with a `face` element), `.stl` (ascii or binary) or `.obj`
/// (polygons triangulated, all objects merged). The warnings of [`read_mesh_checked`] are not
/// returned.
///
/// # Errors
/// As [`read_mesh_checked`].
pub fn read_mesh(path: &Path) -> Result<TriMesh> {
    read_mesh_checked(path).map(|loaded| loaded.value)
}

/// Reads a triangle mesh as [`read_mesh`] does, with a warning naming the file when a binary STL
/// has bytes after the facets its header counts (they are ignored).
///
/// # Errors
/// [`Error::Io`] when the file cannot be read; [`Error::Format`] naming the file for an unknown
/// extension, a malformed file (a binary STL whose facet count does not fit the file, a bad
/// index), or a vertex that is not finite (a mesh needs finite vertices; it is refused, not
/// repaired).
pub fn read_mesh_checked(path: &Path) -> Result<Loaded<TriMesh>> {
    check_mesh_extension(path)?;
    parse_mesh_checked(path, &read_bytes(path)?)
}

/// [`read_mesh_checked`] on bytes already read; the format follows `path_for_errors`'s extension.
///
/// # Errors
/// As [`read_mesh_checked`], without the I/O error.
pub fn parse_mesh_checked(path_for_errors: &Path, bytes: &[u8]) -> Result<Loaded<TriMesh>> {
    let path = path_for_errors;
    let loaded = match check_mesh_extension(path)? {
        "ply" => Loaded { value: parse_ply_mesh(path, bytes)?, warnings: Vec::new() },
        "stl" => parse_stl(path, bytes)?,
        _ => Loaded { value: parse_obj(path, bytes)?, warnings: Vec::new() },
    };
    finite_vertices(path, &loaded.value)?;
    Ok(loaded)
}

fn check_mesh_extension(path: &Path) -> Result<&'static str> {
    match extension(path).as_str() {
        "ply" => Ok("ply"),
        "stl" => Ok("stl"),
        "obj" => Ok("obj"),
        other => Err(Error::format(path, format!("unknown mesh extension `{other}` (accepted: .ply, .stl, .obj)"))),
    }
}

/// Reads a point cloud: `.ply` or `.pcd`, the points with a non-finite coordinate dropped (with
/// their normals and colors). The warnings of [`read_cloud_checked`] are not returned.
///
/// # Errors
/// As [`read_cloud_checked`].
pub fn read_cloud(path: &Path) -> Result<PointCloud> {
    read_cloud_checked(path).map(|loaded| loaded.value)
}

/// Reads a point cloud: `.ply` or `.pcd`; the points with a NaN or infinite coordinate are
/// dropped (with their normals and colors: an organised PCD's pixels without a return, or bad
/// data), with a warning naming the file and how many; bytes after the body the header declares
/// are ignored, with a warning.
///
/// # Errors
/// [`Error::Io`] when the file cannot be read; [`Error::Format`] naming the file for an unknown
/// extension or a malformed file.
pub fn read_cloud_checked(path: &Path) -> Result<Loaded<PointCloud>> {
    check_cloud_extension(path)?;
    parse_cloud_checked(path, &read_bytes(path)?)
}

/// [`read_cloud_checked`] on bytes already read; the format follows `path_for_errors`'s
/// extension.
///
/// # Errors
/// As [`read_cloud_checked`], without the I/O error.
pub fn parse_cloud_checked(path_for_errors: &Path, bytes: &[u8]) -> Result<Loaded<PointCloud>> {
    let path = path_for_errors;
    let Loaded { value: cloud, mut warnings } = match check_cloud_extension(path)? {
        "ply" => parse_ply_checked(path, bytes)?,
        _ => {
            let Loaded { value, warnings } = parse_pcd_checked(path, bytes)?;
            Loaded { value: value.cloud, warnings }
        }
    };
    let cloud = drop_non_finite(path, cloud, &mut warnings);
    Ok(Loaded { value: cloud, warnings })
}

fn check_cloud_extension(path: &Path) -> Result<&'static str> {
    match extension(path).as_str() {
        "ply" => Ok("ply"),
        "pcd" => Ok("pcd"),
        other => Err(Error::format(path, format!("unknown point-cloud extension `{other}` (accepted: .ply, .pcd)"))),
    }
}

/// `cloud` without its points that have a non-finite coordinate; a warning naming `path` and
/// the count when there were any.
pub fn drop_non_finite(path: &Path, mut cloud: PointCloud, warnings: &mut Vec<String>) -> PointCloud {
    let keep: Vec<usize> = (0..cloud.len()).filter(|&i| cloud.points[i].coords.iter().all(|v| v.is_finite())).collect();
    if keep.len() < cloud.len() {
        warnings.push(format!(
            "{}: {} of {} points have a NaN or infinite coordinate and were dropped",
            path.display(),
            cloud.len() - keep.len(),
            cloud.len()
        ));
        cloud.retain_indices(&keep);
    }
    cloud
}

/// Refuses a mesh with a vertex that is not finite, naming the file, the vertex and a triangle
/// that uses it.
fn finite_vertices(path: &Path, mesh: &TriMesh) -> Result<()> {
    let Some(v) = mesh.vertices.iter().position(|p| !p.coords.iter().all(|c| c.is_finite())) else { return Ok(()) };
    let p = mesh.vertices[v];
    let used = match mesh.triangles.iter().position(|t| t.contains(&(v as u32))) {
        Some(t) => format!(", a corner of triangle {t},"),
        None => String::new(),
    };
    Err(Error::format(
        path,
        format!(
            "vertex {v} ({}, {}, {}){used} is not finite: a mesh's vertices must be finite numbers; fix or remove it",
            p.x, p.y, p.z
        ),
    ))
}

/// Writes a point cloud atomically: `.ply` as binary little-endian PLY, `.pcd` as binary PCD.
///
/// # Errors
/// [`Error::Invalid`] for an unknown extension or inconsistent normals/colors; [`Error::Io`] when
/// writing fails.
pub fn write_cloud(path: &Path, cloud: &PointCloud) -> Result<()> {
    match extension(path).as_str() {
        "ply" => write_ply(path, cloud, PlyEncoding::BinaryLittleEndian),
        "pcd" => write_pcd(path, cloud, PcdEncoding::Binary),
        other => Err(Error::invalid(
            path.display().to_string(),
            format!("unknown point-cloud extension `{other}` (accepted: .ply, .pcd)"),
        )),
    }
}

/// The facets of a binary STL body (50 bytes each: normal, three vertices, attribute count), for
/// `stl_io`'s indexing (vertices shared by their bits).
struct BinaryFacets<'a>(std::slice::ChunksExact<'a, u8>);

impl Iterator for BinaryFacets<'_> {
    type Item = std::io::Result<stl_io::Triangle>;
    fn next(&mut self) -> Option<Self::Item> {
        let facet = self.0.next()?;
        let f = |k: usize| {
            let b = facet.get(4 * k..4 * k + 4).and_then(|b| b.try_into().ok()).unwrap_or_default();
            f32::from_le_bytes(b)
        };
        let v = |k: usize| stl_io::Vertex::new([f(3 * k), f(3 * k + 1), f(3 * k + 2)]);
        Some(Ok(stl_io::Triangle { normal: v(0), vertices: [v(1), v(2), v(3)] }))
    }
}

impl stl_io::TriangleIterator for BinaryFacets<'_> {}

/// Parses an STL file: ascii (it starts with `solid` and is not exactly the size of a binary STL
/// of its facet count) by `stl_io`, otherwise binary, where the facet count of bytes 80-83 must
/// fit the file (84 + 50 × count bytes, checked before anything is allocated); bytes after those
/// facets are ignored with a warning.
fn parse_stl(path: &Path, bytes: &[u8]) -> Result<Loaded<TriMesh>> {
    let len = bytes.len();
    let count = bytes.get(80..84).and_then(|b| b.try_into().ok()).map(u32::from_le_bytes);
    let binary_size = |n: u32| 84 + 50 * u64::from(n);
    let exact_binary = count.is_some_and(|n| binary_size(n) == len as u64);
    let mut warnings = Vec::new();
    let stl = if bytes.starts_with(b"solid") && !exact_binary {
        stl_io::read_stl(&mut Cursor::new(bytes)).map_err(|e| Error::format(path, format!("ascii STL: {e}")))?
    } else {
        let Some(n) = count else {
            return Err(Error::format(
                path,
                format!(
                    "binary STL: the file has {len} bytes, fewer than the 84 of its header (80 bytes, then the \
                     facet count); an ascii STL starts with `solid `"
                ),
            ));
        };
        let need = binary_size(n);
        if need > len as u64 {
            return Err(Error::format(
                path,
                format!(
                    "binary STL: the header's facet count (bytes 80-83) is {n}, which needs 84 + 50 × {n} = {need} \
                     bytes, but the file has {len}: the count is wrong or the file is truncated"
                ),
            ));
        }
        if need < len as u64 {
            warnings.push(format!(
                "{}: {} bytes after the {n} facets the binary STL header counts were ignored",
                path.display(),
                len as u64 - need
            ));
        }
        let body = bytes.get(84..need as usize).unwrap_or_default();
        stl_io::TriangleIterator::as_indexed_triangles(&mut BinaryFacets(body.chunks_exact(50)))
            .map_err(|e| Error::format(path, format!("binary STL: {e}")))?
    };
    let vertices =
        stl.vertices.iter().map(|v| Point3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]))).collect();
    let mut triangles = Vec::with_capacity(stl.faces.len());
    for (f, face) in stl.faces.iter().enumerate() {
        let mut t = [0u32; 3];
        for (k, &i) in face.vertices.iter().enumerate() {
            t[k] = u32::try_from(i)
                .ok()
                .filter(|&i| (i as usize) < stl.vertices.len())
                .ok_or_else(|| Error::format(path, format!("STL facet {f}: vertex index {i} out of range")))?;
        }
        triangles.push(t);
    }
    Ok(Loaded { value: TriMesh { vertices, triangles }, warnings })
}

/// Parses an OBJ file with `tobj` (no header counts: what it holds grows with the file).
fn parse_obj(path: &Path, bytes: &[u8]) -> Result<TriMesh> {
    let options = tobj::LoadOptions { triangulate: true, single_index: true, ..Default::default() };
    let (models, _materials) =
        tobj::load_obj_buf(&mut Cursor::new(bytes), &options, |_| Err(tobj::LoadError::OpenFileFailed))
            .map_err(|e| Error::format(path, format!("OBJ: {e}")))?;
    let mut mesh = TriMesh::default();
    for model in &models {
        let m = &model.mesh;
        let offset = u32::try_from(mesh.vertices.len()).map_err(|_| Error::format(path, "OBJ: too many vertices"))?;
        let count = m.positions.len() / 3;
        mesh.vertices.extend(
            m.positions.chunks_exact(3).map(|c| Point3::new(f64::from(c[0]), f64::from(c[1]), f64::from(c[2]))),
        );
        for (f, tri) in m.indices.chunks_exact(3).enumerate() {
            let mut t = [0u32; 3];
            for (k, &i) in tri.iter().enumerate() {
                if i as usize >= count {
                    return Err(Error::format(
                        path,
                        format!("OBJ object `{}` triangle {f}: vertex index {i} out of range", model.name),
                    ));
                }
                t[k] = offset.checked_add(i).ok_or_else(|| Error::format(path, "OBJ: too many vertices"))?;
            }
            mesh.triangles.push(t);
        }
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stl_obj_ply_and_clouds_dispatch_on_the_extension() {
        let dir = tempfile::tempdir().expect("tempdir");
        let ascii = "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\n\
                     facet normal 0 0 1\nouter loop\nvertex 1 0 0\nvertex 1 1 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid t\n";
        std::fs::write(dir.path().join("a.stl"), ascii).expect("write");
        let mut binary = vec![b'x'; 80];
        binary.extend(1u32.to_le_bytes());
        for v in [0.0f32, 0.0, 1.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 2.0, 0.0] {
            binary.extend(v.to_le_bytes());
        }
        binary.extend([0, 0]);
        std::fs::write(dir.path().join("b.STL"), binary).expect("write");
        let obj =
            "o quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\no tri\nv 0 0 1\nv 1 0 1\nv 0 1 1\nf 1/1 2/2 3/3\n";
        std::fs::write(dir.path().join("c.obj"), obj.replace("f 1/1 2/2 3/3", "f 5 6 7")).expect("write");
        let a = read_mesh(&dir.path().join("a.stl")).expect("ascii stl");
        assert_eq!((a.vertices.len(), a.triangles.len(), a.area()), (4, 2, 1.0));
        let b = read_mesh(&dir.path().join("b.STL")).expect("binary stl");
        assert_eq!((b.triangles.len(), b.area()), (1, 2.0));
        let c = read_mesh(&dir.path().join("c.obj")).expect("obj");
        assert_eq!((c.vertices.len(), c.triangles.len()), (7, 3));
        assert!((c.area() - 1.5).abs() < 1e-12);
        c.validate("c.obj").expect("valid");
        crate::io::ply::write_ply_mesh(&dir.path().join("c.ply"), &c).expect("write ply");
        assert_eq!(read_mesh(&dir.path().join("c.ply")).expect("ply"), c);
        let err = read_mesh(&dir.path().join("d.off")).expect_err("unknown").to_string();
        assert!(err.contains("d.off") && err.contains(".ply, .stl, .obj"), "{err}");
        let cloud = c.sample_surface(50, 3).expect("sample");
        for name in ["e.ply", "e.pcd"] {
            write_cloud(&dir.path().join(name), &cloud).expect("write cloud");
            assert_eq!(read_cloud(&dir.path().join(name)).expect("read cloud"), cloud, "{name}");
        }
        assert!(write_cloud(&dir.path().join("e.xyz"), &cloud).is_err());
        assert!(read_cloud(&dir.path().join("e.xyz")).expect_err("unknown").to_string().contains(".ply, .pcd"));
    }
}
