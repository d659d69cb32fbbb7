//! Format dispatch on the file extension: meshes (`.ply`, `.stl`, `.obj`) and clouds (`.ply`,
//! `.pcd`).

use std::io::Cursor;
use std::path::Path;

use nalgebra::Point3;

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::io::pcd::{PcdEncoding, read_pcd, write_pcd};
use crate::io::ply::{PlyEncoding, read_ply, read_ply_mesh, write_ply};
use crate::io::{extension, read_bytes};
use crate::mesh::TriMesh;

/// Reads a triangle mesh: `.ply` (with a `face` element), `.stl` (ascii or binary) or `.obj`
/// (polygons triangulated, all objects merged).
///
/// # Errors
/// [`Error::Io`] when the file cannot be read; [`Error::Format`] naming the file for an unknown
/// extension or a malformed file.
pub fn read_mesh(path: &Path) -> Result<TriMesh> {
    match extension(path).as_str() {
        "ply" => read_ply_mesh(path),
        "stl" => read_stl(path),
        "obj" => read_obj(path),
        other => Err(Error::format(path, format!("unknown mesh extension `{other}` (accepted: .ply, .stl, .obj)"))),
    }
}

/// Reads a point cloud: `.ply` or `.pcd` (organised PCD clouds lose their non-finite points).
///
/// # Errors
/// [`Error::Io`] when the file cannot be read; [`Error::Format`] naming the file for an unknown
/// extension or a malformed file.
pub fn read_cloud(path: &Path) -> Result<PointCloud> {
    match extension(path).as_str() {
        "ply" => read_ply(path),
        "pcd" => read_pcd(path),
        other => Err(Error::format(path, format!("unknown point-cloud extension `{other}` (accepted: .ply, .pcd)"))),
    }
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

fn read_stl(path: &Path) -> Result<TriMesh> {
    let bytes = read_bytes(path)?;
    let stl = stl_io::read_stl(&mut Cursor::new(bytes)).map_err(|e| Error::format(path, format!("STL: {e}")))?;
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
    Ok(TriMesh { vertices, triangles })
}

fn read_obj(path: &Path) -> Result<TriMesh> {
    let bytes = read_bytes(path)?;
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
