//! PLY point clouds and triangle meshes, read and written by hand.
//!
//! Reading accepts the `ascii`, `binary_little_endian` and `binary_big_endian` encodings, any scalar
//! type for the vertex properties, and skips every element and property it does not use (faces of a
//! cloud, Stanford's `range_grid`, edges, lists). Every error names the file and, where possible, the
//! line (ascii) or the element and record. No input makes the reader panic or allocate more than the
//! file could hold.

use std::path::Path;

use nalgebra::{Point3, Vector3};

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::io::ply_header::{Element, Format, Header, Kind, Scalar, parse_header, scalar_size, walk_body};
use crate::io::{Loaded, read_bytes, write_atomic};
use crate::mesh::TriMesh;

/// Body encoding of a written PLY file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlyEncoding {
    /// Text, one vertex per line; floats printed shortest-round-trip (exact).
    Ascii,
    /// Binary, little-endian (the usual choice).
    BinaryLittleEndian,
    /// Binary, big-endian.
    BinaryBigEndian,
}

/// Reads a PLY point cloud: positions, and normals and colors when the file has them; every point
/// as stored (non-finite ones too: [`crate::io::mesh::read_cloud_checked`] drops them, with a
/// warning).
///
/// # Errors
/// [`Error::Io`] when the file cannot be read; [`Error::Format`] naming the file (and the line or
/// record) when it is not a valid PLY cloud.
pub fn read_ply(path: &Path) -> Result<PointCloud> {
    parse_ply(path, &read_bytes(path)?)
}

/// Parses PLY bytes into a point cloud; `path_for_errors` is only used in error messages. The
/// warnings of [`parse_ply_checked`] are not returned.
///
/// # Errors
/// As [`parse_ply_checked`].
pub fn parse_ply(path_for_errors: &Path, bytes: &[u8]) -> Result<PointCloud> {
    parse_ply_checked(path_for_errors, bytes).map(|loaded| loaded.value)
}

/// Parses PLY bytes into a point cloud (every point as stored), with a warning naming the file
/// when bytes follow the records the header declares (they are ignored).
///
/// Before anything is allocated, the header's element counts are checked against the bytes after
/// the header ([`Header::check_counts_fit`]); a binary body whose coordinates read as garbage in
/// the declared byte order but as numbers in the other one is refused (a wrong `format` line).
///
/// # Errors
/// [`Error::Format`] for a malformed header or body (counts that do not fit the file, truncated,
/// bad tokens, missing `x`/`y`/`z`, the byte order the header declares probably wrong).
pub fn parse_ply_checked(path_for_errors: &Path, bytes: &[u8]) -> Result<Loaded<PointCloud>> {
    let path = path_for_errors;
    let header = parse_header(path, bytes)?;
    let vi = header.element("vertex").ok_or_else(|| Error::format(path, "PLY file has no `vertex` element"))?;
    let vertex = &header.elements[vi];
    let mut slots: Vec<(usize, usize)> = Vec::with_capacity(9);
    for (slot, name) in ["x", "y", "z"].into_iter().enumerate() {
        slots.push((scalar_prop(path, vertex, &[name])?, slot));
    }
    header.check_counts_fit(path, bytes.len().saturating_sub(header.body_offset))?;
    check_byte_order(path, &header, bytes, vi, [slots[0].0, slots[1].0, slots[2].0])?;
    let normal_names: [&[&str]; 3] = [&["nx", "normal_x"], &["ny", "normal_y"], &["nz", "normal_z"]];
    let has_normals = optional_triple(vertex, normal_names, &mut slots, 3);
    let color_names: [&[&str]; 3] = [&["red", "r"], &["green", "g"], &["blue", "b"]];
    let has_colors = optional_triple(vertex, color_names, &mut slots, 6);
    let color_scale: Vec<f64> = (0..3)
        .map(|k| match slots.iter().find(|s| s.1 == 6 + k).map(|s| &vertex.props[s.0].kind) {
            Some(Kind::Scalar(s)) if s.is_float() => 255.0,
            Some(Kind::Scalar(Scalar::U16)) => 1.0 / 257.0,
            _ => 1.0,
        })
        .collect();

    let cap = capacity(&header, vi, bytes.len());
    let mut points = Vec::with_capacity(cap);
    let mut normals = if has_normals { Vec::with_capacity(cap) } else { Vec::new() };
    let mut colors = if has_colors { Vec::with_capacity(cap) } else { Vec::new() };
    let used = walk_body(path, &header, bytes, vi, &slots, None, |v, _| {
        points.push(Point3::new(v[0] as f32, v[1] as f32, v[2] as f32));
        if has_normals {
            normals.push(Vector3::new(v[3] as f32, v[4] as f32, v[5] as f32));
        }
        if has_colors {
            let c = |k: usize| (v[6 + k] * color_scale[k]).round().clamp(0.0, 255.0) as u8;
            colors.push([c(0), c(1), c(2)]);
        }
        Ok(())
    })?;
    let cloud = PointCloud { points, normals: has_normals.then_some(normals), colors: has_colors.then_some(colors) };
    Ok(Loaded { value: cloud, warnings: trailing_bytes(path, &header, bytes.len(), used).into_iter().collect() })
}

/// The warning for bytes after the binary records the header declares, naming the file, the
/// counts and the bytes left over.
fn trailing_bytes(path: &Path, header: &Header, file_len: usize, used: usize) -> Option<String> {
    let extra = file_len.saturating_sub(header.body_offset).saturating_sub(used);
    if header.format == Format::Ascii || extra == 0 {
        return None;
    }
    let counts: Vec<String> = header.elements.iter().map(|e| format!("`element {} {}`", e.name, e.count)).collect();
    Some(format!(
        "{}: {extra} bytes after the records the PLY header declares ({}) were ignored: a count in the header \
         may be too small",
        path.display(),
        counts.join(", ")
    ))
}

/// Whether a coordinate read from a binary body looks like garbage: finite, not zero, and beyond
/// 1e12 or under 1e-30 in magnitude (what a float read in the wrong byte order usually is).
fn implausible(v: f64) -> bool {
    v.is_finite() && v != 0.0 && !(1e-30..=1e12).contains(&v.abs())
}

/// Refuses a binary body read in the wrong byte order: up to 1024 vertices, evenly spread, are
/// decoded both ways; when more than half of them have an implausible coordinate ([`implausible`])
/// as declared and at most a tenth in the other byte order, the header's `format` line is
/// probably wrong. Only float coordinates in fixed-size records are checked (the usual layout);
/// an element with lists before the vertices leaves the check out.
fn check_byte_order(path: &Path, header: &Header, bytes: &[u8], vi: usize, xyz: [usize; 3]) -> Result<()> {
    if header.format == Format::Ascii {
        return Ok(());
    }
    let vertex = &header.elements[vi];
    let Some(stride) = vertex.fixed_size() else { return Ok(()) };
    let mut start = header.body_offset;
    for e in header.elements[..vi].iter().filter(|e| !e.props.is_empty()) {
        let Some(size) = e.fixed_size().and_then(|s| usize::try_from(e.count).ok()?.checked_mul(s)) else {
            return Ok(());
        };
        start = start.saturating_add(size);
    }
    let mut fields = [(0usize, Scalar::F32); 3];
    for (k, &pi) in xyz.iter().enumerate() {
        let Kind::Scalar(s) = vertex.props[pi].kind else { return Ok(()) };
        if !s.is_float() {
            return Ok(());
        }
        let offset: usize = vertex.props[..pi].iter().map(|p| scalar_size(p.kind)).sum();
        fields[k] = (offset, s);
    }
    let n = usize::try_from(vertex.count).unwrap_or(usize::MAX).min(bytes.len().saturating_sub(start) / stride);
    let samples = n.min(1024);
    let declared_be = header.format == Format::BinaryBigEndian;
    let (mut bad_declared, mut bad_other, mut example) = (0usize, 0usize, None);
    for k in 0..samples {
        let i = k * n / samples;
        let Some(record) = bytes.get(start + i * stride..).and_then(|b| b.get(..stride)) else { break };
        let read = |be: bool| fields.map(|(off, s)| record.get(off..).and_then(|b| s.decode(b, be)).unwrap_or(0.0));
        let (declared, other) = (read(declared_be), read(!declared_be));
        if declared.iter().any(|&v| implausible(v)) {
            bad_declared += 1;
            example = example.or(Some((i, declared)));
        }
        bad_other += usize::from(other.iter().any(|&v| implausible(v)));
    }
    if samples == 0 || 2 * bad_declared <= samples || 10 * bad_other > samples {
        return Ok(());
    }
    let (i, v) = example.unwrap_or_default();
    let other = if declared_be { "binary_little_endian" } else { "binary_big_endian" };
    Err(Error::format(
        path,
        format!(
            "PLY header says `format {}`, but read that way {bad_declared} of {samples} sampled vertices have \
             implausible coordinates (vertex {i}: x {:.3e}, y {:.3e}, z {:.3e}), and in the other byte order {bad_other} do: \
             the header's format is probably wrong (`format {other} 1.0`?)",
            header.format_name(),
            v[0],
            v[1],
            v[2]
        ),
    ))
}

/// Reads a PLY triangle mesh: `vertex` x, y, z (kept in f64) and the `face` element's
/// `vertex_indices` (or `vertex_index`) lists; polygons are fan-triangulated, faces with fewer than
/// three corners are dropped.
///
/// # Errors
/// [`Error::Io`] when the file cannot be read; [`Error::Format`] for a malformed file, a missing
/// `face` element or an out-of-range vertex index (naming the face).
pub fn read_ply_mesh(path: &Path) -> Result<TriMesh> {
    parse_ply_mesh(path, &read_bytes(path)?)
}

/// Parses PLY bytes into a triangle mesh; see [`read_ply_mesh`].
///
/// # Errors
/// As [`read_ply_mesh`], without the I/O error.
pub fn parse_ply_mesh(path_for_errors: &Path, bytes: &[u8]) -> Result<TriMesh> {
    let path = path_for_errors;
    let header = parse_header(path, bytes)?;
    header.check_counts_fit(path, bytes.len().saturating_sub(header.body_offset))?;
    let vi = header.element("vertex").ok_or_else(|| Error::format(path, "PLY file has no `vertex` element"))?;
    let fi = header.element("face").ok_or_else(|| Error::format(path, "PLY mesh has no `face` element"))?;
    let vertex = &header.elements[vi];
    let face = &header.elements[fi];
    let mut xyz = Vec::with_capacity(3);
    for (slot, name) in ["x", "y", "z"].into_iter().enumerate() {
        xyz.push((scalar_prop(path, vertex, &[name])?, slot));
    }
    let list = face
        .find(&["vertex_indices", "vertex_index"])
        .filter(|&i| matches!(face.props[i].kind, Kind::List { .. }))
        .ok_or_else(|| Error::format(path, "PLY element `face` has no `vertex_indices` list"))?;
    let mut vertices = Vec::with_capacity(capacity(&header, vi, bytes.len()));
    let mut triangles = Vec::with_capacity(capacity(&header, fi, bytes.len()));
    let n_vertices = vertex.count;
    let mut record = 0u64;
    walk_body(path, &header, bytes, vi, &xyz, Some((fi, list)), |v, corners| {
        if let Some(corners) = corners {
            let mut idx = [0u32; 3];
            let as_index = |k: usize| -> Result<u32> {
                let c = corners.get(k).copied().unwrap_or(-1.0);
                if c >= 0.0 && c < n_vertices as f64 && c.fract() == 0.0 && c <= f64::from(u32::MAX) {
                    Ok(c as u32)
                } else {
                    Err(Error::format(
                        path,
                        format!("face {record}: vertex index {c} out of range ({n_vertices} vertices)"),
                    ))
                }
            };
            if corners.len() >= 3 {
                idx[0] = as_index(0)?;
                for k in 1..corners.len() - 1 {
                    idx[1] = as_index(k)?;
                    idx[2] = as_index(k + 1)?;
                    triangles.push(idx);
                }
            }
            record += 1;
        } else {
            vertices.push(Point3::new(v[0], v[1], v[2]));
        }
        Ok(())
    })?;
    Ok(TriMesh { vertices, triangles })
}

/// Writes a point cloud as PLY: float x y z, float nx ny nz when present, uchar red green blue
/// when present. Atomic.
///
/// # Errors
/// [`Error::Invalid`] when normals or colors do not have one entry per point; [`Error::Io`] when
/// writing fails.
pub fn write_ply(path: &Path, cloud: &PointCloud, encoding: PlyEncoding) -> Result<()> {
    let what = path.display().to_string();
    let n = cloud.points.len();
    let normals = cloud.normals.as_deref();
    let colors = cloud.colors.as_deref();
    if normals.is_some_and(|v| v.len() != n) || colors.is_some_and(|v| v.len() != n) {
        return Err(Error::invalid(what, "normals or colors do not have one entry per point"));
    }
    let format = match encoding {
        PlyEncoding::Ascii => "ascii",
        PlyEncoding::BinaryLittleEndian => "binary_little_endian",
        PlyEncoding::BinaryBigEndian => "binary_big_endian",
    };
    let mut head = format!("ply\nformat {format} 1.0\ncomment written by awl\nelement vertex {n}\n");
    head.push_str("property float x\nproperty float y\nproperty float z\n");
    if normals.is_some() {
        head.push_str("property float nx\nproperty float ny\nproperty float nz\n");
    }
    if colors.is_some() {
        head.push_str("property uchar red\nproperty uchar green\nproperty uchar blue\n");
    }
    head.push_str("end_header\n");
    let per_point = 12 + if normals.is_some() { 12 } else { 0 } + if colors.is_some() { 3 } else { 0 };
    let mut out = head.into_bytes();
    if encoding == PlyEncoding::Ascii {
        use std::fmt::Write as _;
        let mut text = String::with_capacity(n.saturating_mul(per_point * 3));
        for i in 0..n {
            let p = &cloud.points[i];
            let _ = write!(text, "{} {} {}", p.x, p.y, p.z);
            if let Some(nv) = normals.and_then(|v| v.get(i)) {
                let _ = write!(text, " {} {} {}", nv.x, nv.y, nv.z);
            }
            if let Some(c) = colors.and_then(|v| v.get(i)) {
                let _ = write!(text, " {} {} {}", c[0], c[1], c[2]);
            }
            text.push('\n');
        }
        out.extend_from_slice(text.as_bytes());
    } else {
        let be = encoding == PlyEncoding::BinaryBigEndian;
        let put =
            |out: &mut Vec<u8>, v: f32| out.extend_from_slice(&if be { v.to_be_bytes() } else { v.to_le_bytes() });
        out.reserve(n.saturating_mul(per_point));
        for i in 0..n {
            let p = &cloud.points[i];
            put(&mut out, p.x);
            put(&mut out, p.y);
            put(&mut out, p.z);
            if let Some(nv) = normals.and_then(|v| v.get(i)) {
                put(&mut out, nv.x);
                put(&mut out, nv.y);
                put(&mut out, nv.z);
            }
            if let Some(c) = colors.and_then(|v| v.get(i)) {
                out.extend_from_slice(c);
            }
        }
    }
    write_atomic(path, &out)
}

/// Writes a triangle mesh as binary little-endian PLY: double x y z (full precision) and a `face`
/// element with `list uchar int vertex_indices`. Atomic.
///
/// # Errors
/// [`Error::Invalid`] when a vertex index does not fit a PLY `int`; [`Error::Io`] when writing
/// fails.
pub fn write_ply_mesh(path: &Path, mesh: &TriMesh) -> Result<()> {
    let (nv, nf) = (mesh.vertices.len(), mesh.triangles.len());
    let head = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by awl\nelement vertex {nv}\n\
         property double x\nproperty double y\nproperty double z\nelement face {nf}\n\
         property list uchar int vertex_indices\nend_header\n"
    );
    let mut out = head.into_bytes();
    out.reserve(nv.saturating_mul(24).saturating_add(nf.saturating_mul(13)));
    for v in &mesh.vertices {
        for c in [v.x, v.y, v.z] {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    for (f, t) in mesh.triangles.iter().enumerate() {
        out.push(3);
        for &i in t {
            let i = i32::try_from(i).map_err(|_| {
                Error::invalid(path.display().to_string(), format!("triangle {f}: index {i} too large for PLY"))
            })?;
            out.extend_from_slice(&i.to_le_bytes());
        }
    }
    write_atomic(path, &out)
}

/// Index of the scalar property called one of `names`, or a format error.
fn scalar_prop(path: &Path, element: &Element, names: &[&str]) -> Result<usize> {
    let i = element
        .find(names)
        .ok_or_else(|| Error::format(path, format!("PLY element `{}` has no property `{}`", element.name, names[0])))?;
    match element.props[i].kind {
        Kind::Scalar(_) => Ok(i),
        Kind::List { .. } => {
            Err(Error::format(path, format!("PLY property `{}` is a list, expected a scalar", names[0])))
        }
    }
}

/// Adds slots `first..first+3` for three scalar properties when all three exist.
fn optional_triple(element: &Element, names: [&[&str]; 3], slots: &mut Vec<(usize, usize)>, first: usize) -> bool {
    let found: Vec<usize> = names
        .iter()
        .filter_map(|n| element.find(n).filter(|&i| matches!(element.props[i].kind, Kind::Scalar(_))))
        .collect();
    if found.len() != 3 {
        return false;
    }
    slots.extend(found.into_iter().zip(first..first + 3));
    true
}

/// How many records of element `ei` to preallocate: the header's count, capped by what the file
/// could hold.
fn capacity(header: &Header, ei: usize, file_len: usize) -> usize {
    let e = &header.elements[ei];
    let fit = file_len / e.min_record_bytes(header.format == Format::Ascii);
    usize::try_from(e.count).unwrap_or(usize::MAX).min(fit)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    fn sample_cloud(n: usize, seed: u64) -> PointCloud {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let special = [0.0, -0.0, 1e-45, f32::MIN_POSITIVE, f32::MAX, -f32::MAX, f32::INFINITY, 0.1, 1.0 / 3.0];
        let mut f =
            |i: usize| special.get(i).copied().unwrap_or_else(|| f32::from_bits(rng.random::<u32>() & 0xbf7f_ffff));
        let points = (0..n).map(|i| Point3::new(f(i), f(i + 1), f(3 * i))).collect();
        let normals = (0..n).map(|i| Vector3::new(f(2 * i), f(n + i), f(n * 2 + i))).collect();
        let colors = (0..n).map(|i| [i as u8, (i * 7) as u8, 255 - i as u8]).collect();
        PointCloud { points, normals: Some(normals), colors: Some(colors) }
    }

    fn bits(c: &PointCloud) -> Vec<u32> {
        let normals = c.normals.iter().flatten().flat_map(|n| n.iter().copied());
        c.points.iter().flat_map(|p| p.iter().copied()).chain(normals).map(f32::to_bits).collect()
    }

    #[test]
    fn write_then_read_is_bit_exact_in_every_encoding() {
        let dir = tempfile::tempdir().expect("tempdir");
        let cloud = sample_cloud(500, 1);
        for enc in [PlyEncoding::BinaryLittleEndian, PlyEncoding::BinaryBigEndian, PlyEncoding::Ascii] {
            let path = dir.path().join(format!("{enc:?}.ply"));
            write_ply(&path, &cloud, enc).expect("write");
            let back = read_ply(&path).expect("read");
            assert_eq!(bits(&back), bits(&cloud), "{enc:?}");
            assert_eq!(back.colors, cloud.colors, "{enc:?}");
            let bare = PointCloud::from_points(cloud.points[..3].to_vec());
            write_ply(&path, &bare, enc).expect("write bare");
            assert_eq!(read_ply(&path).expect("read bare"), bare);
        }
    }

    #[test]
    fn mesh_write_then_read_keeps_f64_and_faces() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("m.ply");
        let vertices =
            vec![Point3::new(0.1, 1e-300, -7.0), Point3::new(1.0 / 3.0, 2.0, 3.0), Point3::new(5.0, 6.0, 0.7)];
        let mesh = TriMesh { vertices, triangles: vec![[0, 1, 2], [2, 1, 0]] };
        write_ply_mesh(&path, &mesh).expect("write");
        assert_eq!(read_ply_mesh(&path).expect("read"), mesh);
        assert_eq!(read_ply(&path).expect("as cloud").len(), 3);
    }

    const ASCII: &str = "ply\r\nformat ascii 1.0\ncomment hand made\nobj_info scanner 1\nelement vertex 4\n\
        property float x\nproperty float y\nproperty float z\nproperty list uchar int extra\nproperty uchar intensity\n\
        property float32 nx\nproperty float32 ny\nproperty float32 nz\nproperty float red\nproperty float green\n\
        property float blue\nelement range_grid 3\nproperty list uchar int vertex_indices\nelement face 2\n\
        property list uint8 uint32 vertex_indices\nelement material 1\nproperty double shine\nend_header\n\
        0 0 0 2 7 8 1 0 0 1 1 0 0.5\n1 0 0 0 2 0 0 1 0 1 0\n1 1 0 1 5 3 0 0 1 0.2 0.2 0.2\n\n0 1 0 0 4 0 0 1 1 1 1\n\
        0\n1 3\n0\n4 0 1 2 3\n2 0 1\n0.25\n";

    #[test]
    fn ascii_with_lists_faces_and_unknown_elements() {
        let cloud = parse_ply(Path::new("hand.ply"), ASCII.as_bytes()).expect("parse");
        assert_eq!(
            cloud.points,
            vec![Point3::new(0., 0., 0.), Point3::new(1., 0., 0.), Point3::new(1., 1., 0.), Point3::new(0., 1., 0.)]
        );
        assert_eq!(cloud.normals.as_ref().expect("normals")[2], Vector3::new(0.0, 0.0, 1.0));
        assert_eq!(cloud.colors.expect("colors"), vec![[255, 0, 128], [0, 255, 0], [51, 51, 51], [255, 255, 255]]);
        let mesh = parse_ply_mesh(Path::new("hand.ply"), ASCII.as_bytes()).expect("mesh");
        assert_eq!(mesh.triangles, vec![[0, 1, 2], [0, 2, 3]], "quad fanned, 2-gon dropped");
        let bad = ASCII.replace("4 0 1 2 3", "3 0 1 4");
        let err = parse_ply_mesh(Path::new("hand.ply"), bad.as_bytes()).expect_err("must fail").to_string();
        assert!(err.contains("face 0") && err.contains("out of range"), "{err}");
    }

    #[test]
    fn big_endian_doubles_by_hand() {
        let mut b = b"ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty double x\nproperty double y\n\
            property double z\nproperty int16 quality\nproperty uchar r\nproperty uchar g\nproperty uchar b\n\
            element face 1\nproperty list uchar int vertex_index\nend_header\n"
            .to_vec();
        for (i, v) in [[1.5, -2.25, 1e10], [0.1, 0.2, 0.3], [-1.0, 0.0, 4.0]].iter().enumerate() {
            v.iter().for_each(|c: &f64| b.extend_from_slice(&c.to_be_bytes()));
            b.extend_from_slice(&(-7i16).to_be_bytes());
            b.extend_from_slice(&[i as u8, 2, 3]);
        }
        b.push(3);
        [2i32, 1, 0].iter().for_each(|i| b.extend_from_slice(&i.to_be_bytes()));
        let cloud = parse_ply(Path::new("be.ply"), &b).expect("parse");
        assert_eq!(cloud.points[0], Point3::new(1.5, -2.25, 1e10));
        assert_eq!(cloud.points[1], Point3::new(0.1f64 as f32, 0.2f64 as f32, 0.3f64 as f32));
        assert_eq!(cloud.colors.expect("colors")[2], [2, 2, 3]);
        let mesh = parse_ply_mesh(Path::new("be.ply"), &b).expect("mesh");
        assert_eq!((mesh.vertices[1].x, mesh.triangles.clone()), (0.1, vec![[2, 1, 0]]));
    }

    fn format_err(bytes: &[u8]) -> String {
        match parse_ply(Path::new("/data/scan.ply"), bytes) {
            Err(e @ Error::Format { .. }) => e.to_string(),
            other => panic!("expected a format error, got {other:?}"),
        }
    }

    #[test]
    fn truncated_and_mismatched_bodies_are_format_errors() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("t.ply");
        write_ply(&path, &sample_cloud(10, 2), PlyEncoding::BinaryLittleEndian).expect("write");
        let bytes = std::fs::read(&path).expect("read");
        // the count against the body, before anything is read: 10 records of 27 bytes
        let err = format_err(&bytes[..bytes.len() - 5]);
        let want =
            "header line 4: `element vertex 10` needs 270 bytes of binary_little_endian body (27 bytes a record)";
        assert!(err.contains("/data/scan.ply") && err.contains(want) && err.contains("has 265 bytes"), "{err}");
        let head = "ply\nformat ascii 1.0\nelement vertex 1000\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
        // ascii: at least a digit and a separator a value, the last newline optional
        let err = format_err(format!("{head}1 2 3\n4 5 6\n").as_bytes());
        assert!(
            err.contains("`element vertex 1000` needs at least 5999 characters") && err.contains("has 12 bytes"),
            "{err}"
        );
        let body = "1.5 2.5 3.5\n".repeat(999);
        let err = format_err(format!("{head}{body}").as_bytes());
        assert!(err.contains("record 999") && err.contains("1000 records"), "{err}");
        let err = format_err(format!("{}1 2 3\n4 5 6\n", head.replace("1000", "1")).as_bytes());
        assert!(err.contains("line 9") && err.contains("after the last element"), "{err}");
        let head = head.replace("1000", "2");
        let err = format_err(format!("{head}1 2 3\n4 five 6\n").as_bytes());
        assert!(err.contains("line 9") && err.contains("`five`"), "{err}");
        let err = format_err(format!("{head}1 2 3\n4 5   \n").as_bytes());
        assert!(err.contains("line 9") && err.contains("`z`"), "{err}");
        let err = format_err(head.replace("property float y\n", "").as_bytes());
        assert!(err.contains("no property `y`"), "{err}");
        let err = format_err(head.replace("float y", "flaot y").as_bytes());
        assert!(err.contains("header line 5") && err.contains("flaot"), "{err}");
        let huge = head.replace("vertex 2", "vertex 1000000000000000").replace("ascii", "binary_little_endian");
        let err = format_err(format!("{huge}0123456789ab").as_bytes());
        assert!(err.contains("needs 12000000000000000 bytes") && err.contains("has 12 bytes"), "{err}");
        let huge = format!("{}0 0 0\n", head.replace("vertex 2", "vertex 1000000000000000"));
        assert!(format_err(huge.as_bytes()).contains("needs at least 5999999999999999 characters"));
        // a face count that cannot fit after the vertex: named with its line and what the vertex took
        let face = "element face 99999999999999999\nproperty list uint int vertex_indices\nend_header";
        let huge = head.replace("vertex 2", "vertex 1").replace("ascii", "binary_big_endian");
        let mut huge = format!("{}0123456789ab", huge.replace("end_header", face)).into_bytes();
        huge.extend([0x7f, 0xff, 0xff, 0xff]);
        let err = format_err(&huge);
        assert!(err.contains("header line 7: `element face 99999999999999999` needs at least"), "{err}");
        assert!(err.contains("(at least 4 bytes a record, after 12 for the elements before it)"), "{err}");
        // the counts fit, a list's length does not: the record is named
        let face = "element face 1\nproperty list uint int vertex_indices\nend_header";
        let mut short = (head.replace("vertex 2", "vertex 1").replace("ascii", "binary_big_endian"))
            .replace("end_header", face)
            .into_bytes();
        short.extend([0u8; 12]);
        short.extend(1000u32.to_be_bytes());
        let err = format_err(&short);
        assert!(err.contains("element `face` record 0") && err.contains("truncated"), "{err}");
    }

    /// Bytes after the body the header declares: kept out of the cloud, with a warning naming the
    /// file and the count; a body in the other byte order than the header's: refused.
    #[test]
    fn trailing_bytes_warn_and_a_wrong_byte_order_is_refused() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("t.ply");
        let points: Vec<Point3<f32>> =
            (0..200).map(|i| Point3::new(0.001 * i as f32, -0.25 + 0.002 * i as f32, 0.4 + 1e-4 * i as f32)).collect();
        let cloud = PointCloud::from_points(points);
        for (enc, other) in [
            (PlyEncoding::BinaryLittleEndian, "binary_big_endian"),
            (PlyEncoding::BinaryBigEndian, "binary_little_endian"),
        ] {
            write_ply(&path, &cloud, enc).expect("write");
            let mut bytes = std::fs::read(&path).expect("read");
            let clean = parse_ply_checked(Path::new("/d/t.ply"), &bytes).expect("parse");
            assert_eq!((&clean.value, clean.warnings.len()), (&cloud, 0), "{enc:?}");
            bytes.extend([0u8; 37]);
            let longer = parse_ply_checked(Path::new("/d/t.ply"), &bytes).expect("parse");
            assert_eq!(longer.value, cloud, "{enc:?}");
            assert_eq!(
                longer.warnings,
                vec![
                    "/d/t.ply: 37 bytes after the records the PLY header declares (`element vertex 200`) were \
                     ignored: a count in the header may be too small"
                        .to_string()
                ]
            );
            // the header's format line swapped: the same bytes read the other way
            let text = String::from_utf8_lossy(&bytes[..60]).into_owned();
            let declared = if other == "binary_big_endian" { "binary_little_endian" } else { "binary_big_endian" };
            let swapped = [text.replacen(declared, other, 1).as_bytes(), &bytes[60..]].concat();
            assert_eq!(swapped.len(), bytes.len() + other.len() - declared.len());
            let err = format_err(&swapped);
            assert!(err.contains(&format!("says `format {other}`")), "{err}");
            assert!(err.contains("the header's format is probably wrong") && err.contains(declared), "{err}");
            assert!(err.contains(" of 200 sampled vertices") && err.contains("in the other byte order 0 do"), "{err}");
        }
        // garbage in both byte orders (random bits) is not called a wrong format: it is read as is
        let noisy = sample_cloud(300, 9);
        write_ply(&path, &noisy, PlyEncoding::BinaryLittleEndian).expect("write");
        assert_eq!(bits(&read_ply(&path).expect("read")), bits(&noisy));
    }

    #[test]
    fn no_byte_string_panics() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut valid = vec![ASCII.as_bytes().to_vec()];
        for enc in [PlyEncoding::BinaryLittleEndian, PlyEncoding::BinaryBigEndian] {
            let path = dir.path().join("f.ply");
            write_ply(&path, &sample_cloud(4, 3), enc).expect("write");
            valid.push(std::fs::read(&path).expect("read"));
        }
        let mesh = TriMesh { vertices: vec![Point3::origin(); 3], triangles: vec![[0, 1, 2]] };
        write_ply_mesh(&dir.path().join("m.ply"), &mesh).expect("write");
        valid.push(std::fs::read(dir.path().join("m.ply")).expect("read"));
        let path = Path::new("fuzz.ply");
        for v in &valid {
            for cut in 0..=v.len() {
                let _ = (parse_ply(path, &v[..cut]), parse_ply_mesh(path, &v[..cut]));
            }
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        for i in 0..2000 {
            let mut bytes = valid[i % valid.len()].clone();
            let header_end = bytes.windows(10).position(|w| w == b"end_header").unwrap_or(0);
            if i % 3 == 0 {
                bytes = (0..rng.random_range(0..200)).map(|_| rng.random::<u8>()).collect();
            } else {
                for _ in 0..rng.random_range(1..8) {
                    let at = rng.random_range(0..bytes.len());
                    bytes[at] = if at < header_end && i % 2 == 0 { b"0123456789 \n"[at % 12] } else { rng.random() };
                }
            }
            let _ = (parse_ply(path, &bytes), parse_ply_mesh(path, &bytes));
        }
    }
}
