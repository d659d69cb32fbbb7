//! PCD (Point Cloud Library) clouds, read and written by hand.
//!
//! Reading accepts `VERSION` 0.7, .7 and .5 headers and `DATA ascii`, `binary` (row-major records)
//! and `binary_compressed` (LZF, then column-major fields). Used fields: `x y z`, `normal_x/y/z`,
//! packed `rgb`/`rgba`; every other field is skipped. Errors name the file and the header line or
//! field; no input makes the reader panic or allocate more than the file could hold.

use std::path::Path;

use nalgebra::{Point3, Vector3};

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::io::pcd_header::{Data, Header, parse_header};
use crate::io::{Loaded, read_bytes, write_atomic};

/// Body encoding of a written PCD file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PcdEncoding {
    /// `DATA ascii`: one point per line, floats printed shortest-round-trip (exact).
    Ascii,
    /// `DATA binary`: little-endian records.
    Binary,
}

/// An organised (grid) cloud as stored: non-finite points kept, `width × height` row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct OrganisedCloud {
    /// All `width × height` points, NaN where the sensor had no return.
    pub cloud: PointCloud,
    /// Columns.
    pub width: usize,
    /// Rows (1 for an unorganised cloud).
    pub height: usize,
}

/// Reads a PCD cloud, dropping points whose position is not finite (with their normal and color).
///
/// # Errors
/// [`Error::Io`] when the file cannot be read; [`Error::Format`] naming the file (and header line
/// or field) when it is not a valid PCD cloud.
pub fn read_pcd(path: &Path) -> Result<PointCloud> {
    parse_pcd(path, &read_bytes(path)?)
}

/// Parses PCD bytes, dropping non-finite points; `path_for_errors` is only used in messages.
///
/// # Errors
/// As [`read_pcd`], without the I/O error.
pub fn parse_pcd(path_for_errors: &Path, bytes: &[u8]) -> Result<PointCloud> {
    let cloud = parse_pcd_organised(path_for_errors, bytes)?.cloud;
    let keep: Vec<usize> = (0..cloud.len()).filter(|&i| cloud.points[i].coords.iter().all(|v| v.is_finite())).collect();
    Ok(if keep.len() == cloud.len() { cloud } else { cloud.select(&keep) })
}

/// Reads a PCD cloud keeping every point (NaNs included) and the grid size.
///
/// # Errors
/// As [`read_pcd`].
pub fn read_pcd_organised(path: &Path) -> Result<OrganisedCloud> {
    parse_pcd_organised(path, &read_bytes(path)?)
}

/// Parses PCD bytes keeping every point (NaNs included) and the grid size.
///
/// # Errors
/// As [`parse_pcd`].
pub fn parse_pcd_organised(path_for_errors: &Path, bytes: &[u8]) -> Result<OrganisedCloud> {
    parse_pcd_checked(path_for_errors, bytes).map(|loaded| loaded.value)
}

/// Parses PCD bytes keeping every point (NaNs included) and the grid size, with a warning naming
/// the file when bytes follow a binary body's records (they are ignored; after `binary_compressed`
/// data they are usual, PCL's writer leaves some, and not warned about).
///
/// The body's size is checked against the header before anything is allocated: `POINTS` records
/// of the `SIZE` × `COUNT` bytes the fields take (binary), `POINTS` lines of at least two
/// characters a value (ascii); for `binary_compressed`, the declared uncompressed size must be
/// `POINTS` × the record size, the compressed bytes must be in the file, LZF cannot expand them
/// more than 88 times, and above [`MAX_LZF_PLAIN_BYTES`] not more than [`MAX_LZF_RATIO`] times;
/// nothing is decompressed beyond the declared size.
///
/// # Errors
/// As [`parse_pcd`].
pub fn parse_pcd_checked(path_for_errors: &Path, bytes: &[u8]) -> Result<Loaded<OrganisedCloud>> {
    let path = path_for_errors;
    let h = parse_header(path, bytes)?;
    let find = |name: &str| h.fields.iter().position(|f| f.name == name);
    let mut xyz = [0usize; 3];
    for (k, name) in ["x", "y", "z"].into_iter().enumerate() {
        xyz[k] = find(name).ok_or_else(|| Error::format(path, format!("PCD has no field `{name}` (FIELDS line)")))?;
    }
    let normal = match (find("normal_x"), find("normal_y"), find("normal_z")) {
        (Some(a), Some(b), Some(c)) => Some([a, b, c]),
        _ => None,
    };
    let rgb = find("rgb").or_else(|| find("rgba")).filter(|&i| h.fields[i].size == 4);
    let body = bytes.get(h.body_offset..).unwrap_or_default();
    let warnings: Vec<String> = check_body_size(path, &h, body)?.into_iter().collect();
    let n = h.points;
    let record = h.record_size;
    // binary: the body holds the n records; ascii: at least two characters a point; compressed: the
    // point count the decompressed size allows (checked above to follow from the body's size)
    let cap = if h.data == Data::Compressed { n } else { n.min(body.len() / record.max(2)) };
    let mut points = Vec::with_capacity(cap);
    let mut normals = Vec::with_capacity(if normal.is_some() { cap } else { 0 });
    let mut colors = Vec::with_capacity(if rgb.is_some() { cap } else { 0 });
    let pack = |v: u32| [(v >> 16) as u8, (v >> 8) as u8, v as u8];
    match h.data {
        Data::Ascii => {
            let ntok = h.token_field.len();
            let mut vals = vec![0.0f64; ntok];
            let mut rest = body;
            let mut line_no = h.body_line.saturating_sub(1);
            for i in 0..n {
                let line = loop {
                    let len = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
                    if rest.is_empty() {
                        return Err(Error::format(path, format!("PCD body ends after {i} of {n} points (POINTS)")));
                    }
                    let line = rest.get(..len).unwrap_or_default();
                    rest = rest.get(len + 1..).unwrap_or_default();
                    line_no += 1;
                    if !line.iter().all(u8::is_ascii_whitespace) {
                        break line;
                    }
                };
                let bad = |msg: String| Error::format(path, format!("PCD line {line_no} (point {i}): {msg}"));
                let line = std::str::from_utf8(line).map_err(|_| bad("not text".into()))?;
                let mut k = 0usize;
                for token in line.split_ascii_whitespace() {
                    let slot = vals.get_mut(k).ok_or_else(|| bad(format!("more than {ntok} values")))?;
                    *slot = h.fields[h.token_field[k]]
                        .parse_token(token)
                        .ok_or_else(|| bad(format!("`{token}` is not a number")))?;
                    k += 1;
                }
                if k != ntok {
                    return Err(bad(format!("{k} values, expected {ntok}")));
                }
                let v = |f: usize| vals.get(h.fields[f].first_token).copied().unwrap_or(f64::NAN);
                points.push(Point3::new(v(xyz[0]) as f32, v(xyz[1]) as f32, v(xyz[2]) as f32));
                if let Some([a, b, c]) = normal {
                    normals.push(Vector3::new(v(a) as f32, v(b) as f32, v(c) as f32));
                }
                if let Some(c) = rgb {
                    colors.push(pack(v(c) as u32));
                }
            }
            if let Some(extra) = rest.split(|&b| b == b'\n').position(|l| !l.iter().all(u8::is_ascii_whitespace)) {
                return Err(Error::format(
                    path,
                    format!("PCD line {}: more points than POINTS {n}", line_no + 1 + extra),
                ));
            }
        }
        Data::Binary | Data::Compressed => {
            let owned;
            let data: &[u8] = if h.data == Data::Binary {
                // (the size is checked: the n records are in the body)
                body.get(..n.saturating_mul(record)).unwrap_or_default()
            } else {
                owned = decompress(path, body, n, record)?;
                &owned
            };
            let col = h.data == Data::Compressed;
            let at = |f: usize, i: usize| {
                let fd = &h.fields[f];
                if col { fd.offset * n + i * fd.size * fd.count } else { i * record + fd.offset }
            };
            let num = |f: usize, i: usize| h.fields[f].decode(data, at(f, i));
            for i in 0..n {
                points.push(Point3::new(num(xyz[0], i) as f32, num(xyz[1], i) as f32, num(xyz[2], i) as f32));
                if let Some([a, b, c]) = normal {
                    normals.push(Vector3::new(num(a, i) as f32, num(b, i) as f32, num(c, i) as f32));
                }
                if let Some(c) = rgb {
                    let b = data.get(at(c, i)..).and_then(|b| b.get(..4)).and_then(|b| b.try_into().ok());
                    colors.push(pack(u32::from_le_bytes(b.unwrap_or_default())));
                }
            }
        }
    }
    let cloud = PointCloud { points, normals: normal.map(|_| normals), colors: rgb.map(|_| colors) };
    Ok(Loaded { value: OrganisedCloud { cloud, width: h.width, height: h.height }, warnings })
}

/// Checks the body's size against the header before anything is allocated (see
/// [`parse_pcd_checked`]); returns the warning for bytes after the body.
///
/// # Errors
/// [`Error::Format`] naming the file, the header's `POINTS` (and for `binary_compressed` the
/// body's size words) and the sizes that do not agree.
fn check_body_size(path: &Path, h: &Header, body: &[u8]) -> Result<Option<String>> {
    let (n, record) = (h.points, h.record_size);
    let have = body.len();
    let grid = if h.height > 1 { format!(" (WIDTH {} × HEIGHT {})", h.width, h.height) } else { String::new() };
    let extra = |used: usize, what: &str| {
        (have > used).then(|| {
            format!(
                "{}: {} bytes after the {what} the PCD header declares (POINTS {n}{grid}) were ignored",
                path.display(),
                have - used
            )
        })
    };
    match h.data {
        Data::Ascii => {
            let ntok = h.token_field.len();
            let need = (n as u128 * ntok as u128 * 2).saturating_sub(1);
            if need > have as u128 {
                return Err(Error::format(
                    path,
                    format!(
                        "PCD header POINTS {n}{grid}: {n} lines of {ntok} values need at least {need} characters, \
                         but the file has {have} after its header ({} points at most): the count is wrong or the \
                         file is truncated",
                        (have + 1) / (2 * ntok).max(1)
                    ),
                ));
            }
            Ok(None)
        }
        Data::Binary => {
            let need = n as u128 * record as u128;
            if need > have as u128 {
                return Err(Error::format(
                    path,
                    format!(
                        "PCD header POINTS {n}{grid} needs {need} bytes of binary body ({record}-byte records), \
                         but the file has {have} after its header: it holds {} of {n} points (truncated file, or a \
                         wrong POINTS)",
                        have / record.max(1)
                    ),
                ));
            }
            Ok(extra(n * record, "records"))
        }
        Data::Compressed => {
            let word = |at: usize| body.get(at..at + 4).and_then(|b| b.try_into().ok()).map(u32::from_le_bytes);
            let (Some(packed), Some(unpacked)) = (word(0), word(4)) else {
                return Err(Error::format(
                    path,
                    format!("PCD binary_compressed body ({have} bytes) is shorter than its 8-byte size header"),
                ));
            };
            let (packed, unpacked) = (packed as usize, unpacked as usize);
            let need = n as u128 * record as u128;
            if need != unpacked as u128 {
                return Err(Error::format(
                    path,
                    format!(
                        "PCD binary_compressed: the body's uncompressed size (bytes 4-7) is {unpacked} bytes, but the \
                         header's POINTS {n}{grid} × {record}-byte records is {need}: the header or the body is wrong"
                    ),
                ));
            }
            if packed > have - 8 {
                return Err(Error::format(
                    path,
                    format!(
                        "PCD binary_compressed: {packed} compressed bytes announced (bytes 0-3), {} present (truncated \
                         file?)",
                        have - 8
                    ),
                ));
            }
            // an LZF back-reference (3 bytes) expands to at most 264 bytes
            if unpacked / 88 > packed + 1 {
                return Err(Error::format(
                    path,
                    format!(
                        "PCD binary_compressed: {packed} compressed bytes cannot expand to the {unpacked} bytes of \
                         POINTS {n}{grid} (LZF expands at most 88 times)"
                    ),
                ));
            }
            if unpacked > MAX_LZF_PLAIN_BYTES && unpacked / MAX_LZF_RATIO > packed {
                return Err(Error::format(
                    path,
                    format!(
                        "PCD binary_compressed: {packed} compressed bytes declared to expand to {unpacked} bytes \
                         (POINTS {n}{grid}), more than {MAX_LZF_RATIO} times: point data does not compress so far, \
                         this is a corrupt header or a decompression bomb; if the cloud is real, save it as \
                         `DATA binary` (pcl_convert_pcd_ascii_binary FILE OUT 1)"
                    ),
                ));
            }
            // bytes after the compressed data are not warned about: PCL's own writer leaves ~3.9 KB
            // there (every binary_compressed file of PCL's in shared/data)
            Ok(None)
        }
    }
}

/// Writes a cloud as PCD v0.7: `x y z`, `normal_x normal_y normal_z` when present, `rgb` (packed,
/// F4) when present; `WIDTH` = number of points, `HEIGHT 1`. Atomic.
///
/// # Errors
/// [`Error::Invalid`] when normals or colors do not have one entry per point; [`Error::Io`] when
/// writing fails.
pub fn write_pcd(path: &Path, cloud: &PointCloud, encoding: PcdEncoding) -> Result<()> {
    let n = cloud.points.len();
    let normals = cloud.normals.as_deref();
    let colors = cloud.colors.as_deref();
    if normals.is_some_and(|v| v.len() != n) || colors.is_some_and(|v| v.len() != n) {
        return Err(Error::invalid(path.display().to_string(), "normals or colors do not have one entry per point"));
    }
    let mut names = vec!["x", "y", "z"];
    if normals.is_some() {
        names.extend(["normal_x", "normal_y", "normal_z"]);
    }
    if colors.is_some() {
        names.push("rgb");
    }
    let k = names.len();
    let rep = |s: &str| vec![s; k].join(" ");
    let data = match encoding {
        PcdEncoding::Ascii => "ascii",
        PcdEncoding::Binary => "binary",
    };
    let mut out = format!(
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {}\nSIZE {}\nTYPE {}\nCOUNT {}\n\
         WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n",
        names.join(" "),
        rep("4"),
        rep("F"),
        rep("1")
    )
    .into_bytes();
    let packed = |c: &[u8; 3]| (u32::from(c[0]) << 16) | (u32::from(c[1]) << 8) | u32::from(c[2]);
    match encoding {
        PcdEncoding::Ascii => {
            use std::fmt::Write as _;
            let mut text = String::with_capacity(n.saturating_mul(12 * k));
            for (i, p) in cloud.points.iter().enumerate() {
                let _ = write!(text, "{} {} {}", p.x, p.y, p.z);
                if let Some(nv) = normals.and_then(|v| v.get(i)) {
                    let _ = write!(text, " {} {} {}", nv.x, nv.y, nv.z);
                }
                // As PCL does: the packed color as an unsigned integer (its float may be NaN).
                if let Some(c) = colors.and_then(|v| v.get(i)) {
                    let _ = write!(text, " {}", packed(c));
                }
                text.push('\n');
            }
            out.extend_from_slice(text.as_bytes());
        }
        PcdEncoding::Binary => {
            out.reserve(n.saturating_mul(4 * k));
            for (i, p) in cloud.points.iter().enumerate() {
                let mut put = |v: f32| out.extend_from_slice(&v.to_le_bytes());
                put(p.x);
                put(p.y);
                put(p.z);
                if let Some(nv) = normals.and_then(|v| v.get(i)) {
                    put(nv.x);
                    put(nv.y);
                    put(nv.z);
                }
                if let Some(c) = colors.and_then(|v| v.get(i)) {
                    out.extend_from_slice(&packed(c).to_le_bytes());
                }
            }
        }
    }
    write_atomic(path, &out)
}

/// A `binary_compressed` body may declare more than [`MAX_LZF_RATIO`] times its compressed size
/// only below this many bytes (64 MiB): above it, a high ratio is a decompression bomb, refused
/// before anything is allocated.
pub const MAX_LZF_PLAIN_BYTES: usize = 64 << 20;

/// How far a large `binary_compressed` body may expand (32 times: PCL's LZF packs real clouds 1.5-4
/// times; only constant data, such as an organised cloud of NaNs, packs further).
pub const MAX_LZF_RATIO: usize = 32;

/// Decompresses a `binary_compressed` body to exactly `n × record` bytes (its sizes checked by
/// [`check_body_size`]).
fn decompress(path: &Path, body: &[u8], n: usize, record: usize) -> Result<Vec<u8>> {
    let word = |at: usize| body.get(at..at + 4).and_then(|b| b.try_into().ok()).map(u32::from_le_bytes);
    let packed = word(0).unwrap_or_default() as usize;
    let unpacked = n.saturating_mul(record);
    if unpacked == 0 {
        return Ok(Vec::new());
    }
    let data = body.get(8..).and_then(|b| b.get(..packed)).unwrap_or_default();
    let out =
        lzf::decompress(data, unpacked).map_err(|e| Error::format(path, format!("PCD binary_compressed: LZF: {e}")))?;
    if out.len() != unpacked {
        return Err(Error::format(
            path,
            format!("PCD binary_compressed: decompressed {} of {unpacked} bytes", out.len()),
        ));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    fn sample_cloud(n: usize) -> PointCloud {
        let f = |i: usize| f32::from_bits((i as u32).wrapping_mul(2_654_435_761) & 0xbf7f_ffff);
        PointCloud {
            points: (0..n).map(|i| Point3::new(f(3 * i), f(3 * i + 1), 0.1 * i as f32)).collect(),
            normals: Some((0..n).map(|i| Vector3::new(f(n + i), -0.0, 1.0 / 3.0)).collect()),
            colors: Some((0..n).map(|i| [i as u8, 255, 255 - i as u8]).collect()),
        }
    }

    /// LZF with literal runs only: a control byte `len - 1` (0..=31), then `len` bytes.
    fn lzf_literals(data: &[u8]) -> Vec<u8> {
        data.chunks(32).flat_map(|c| std::iter::once(c.len() as u8 - 1).chain(c.iter().copied())).collect()
    }

    fn compressed_file(header: &str, data: &[u8], lzf: &[u8]) -> Vec<u8> {
        let mut out = header.as_bytes().to_vec();
        out.extend((lzf.len() as u32).to_le_bytes());
        out.extend((data.len() as u32).to_le_bytes());
        out.extend(lzf);
        out
    }

    #[test]
    fn ascii_and_binary_round_trip_bit_exact() {
        let dir = tempfile::tempdir().expect("tempdir");
        let cloud = sample_cloud(300);
        for enc in [PcdEncoding::Ascii, PcdEncoding::Binary] {
            let path = dir.path().join(format!("{enc:?}.pcd"));
            write_pcd(&path, &cloud, enc).expect("write");
            let back = read_pcd_organised(&path).expect("read");
            assert_eq!((back.width, back.height), (300, 1));
            let bits = |c: &PointCloud| -> Vec<u32> {
                let ns = c.normals.iter().flatten().flat_map(|n| n.iter().copied());
                c.points.iter().flat_map(|p| p.iter().copied()).chain(ns).map(f32::to_bits).collect()
            };
            assert_eq!(bits(&back.cloud), bits(&cloud), "{enc:?}");
            assert_eq!(back.cloud.colors, cloud.colors, "{enc:?}");
        }
    }

    #[test]
    fn version_5_header_and_ascii_colors() {
        let v5 = "# .PCD v.5 - Point Cloud Data file format\nVERSION .5\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\n\
                  COUNT 1 1 1 1\nWIDTH 3\nHEIGHT 1\nPOINTS 3\nDATA ascii\n1 2 3 16711680\n4 5 6 4.2108e+06\nnan 0 0 255\n";
        let cloud = parse_pcd(Path::new("v5.pcd"), v5.as_bytes()).expect("parse");
        assert_eq!(cloud.points, vec![Point3::new(1.0, 2.0, 3.0), Point3::new(4.0, 5.0, 6.0)]);
        let packed = 4.2108e6f32.to_bits();
        let expected = [(packed >> 16) as u8, (packed >> 8) as u8, packed as u8];
        assert_eq!(cloud.colors.expect("colors"), vec![[255, 0, 0], expected]);
        let grid = parse_pcd_organised(Path::new("v5.pcd"), v5.as_bytes()).expect("organised");
        assert!(grid.cloud.points[2].x.is_nan() && grid.cloud.colors.expect("colors")[2] == [0, 0, 255]);
    }

    #[test]
    fn binary_compressed_by_hand_is_column_major() {
        let header = "VERSION 0.7\nFIELDS x y z _ rgba hist\nSIZE 4 4 4 1 4 4\nTYPE F F F U U F\nCOUNT 1 1 1 2 1 3\n\
                      WIDTH 2\nHEIGHT 2\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 4\nDATA binary_compressed\n";
        let xs = [1.0f32, f32::NAN, 3.0, 4.0];
        let mut data = Vec::new();
        for column in [xs, [10.0, 20.0, 30.0, 40.0], [0.5, 0.5, 0.25, -1.0]] {
            column.iter().for_each(|v| data.extend(v.to_le_bytes()));
        }
        data.extend([0xee; 8]);
        for argb in [0xff10_2030u32, 0xff00_0000, 0x80ff_0001, 0x0000_00ff] {
            data.extend(argb.to_le_bytes());
        }
        data.extend(std::iter::repeat_n(0x42, 48));
        let bytes = compressed_file(header, &data, &lzf_literals(&data));
        let grid = parse_pcd_organised(Path::new("c.pcd"), &bytes).expect("organised");
        assert_eq!((grid.width, grid.height, grid.cloud.len()), (2, 2, 4));
        let cloud = parse_pcd(Path::new("c.pcd"), &bytes).expect("parse");
        assert_eq!(
            cloud.points,
            vec![Point3::new(1.0, 10.0, 0.5), Point3::new(3.0, 30.0, 0.25), Point3::new(4.0, 40.0, -1.0)]
        );
        assert_eq!(cloud.colors.expect("colors"), vec![[0x10, 0x20, 0x30], [0xff, 0x00, 0x01], [0, 0, 0xff]]);
        // A real LZF stream with back-references decodes too.
        let real = lzf::compress(&data).expect("compressible");
        assert!(real.len() < data.len());
        assert_eq!(parse_pcd(Path::new("c.pcd"), &compressed_file(header, &data, &real)).expect("lzf").len(), 3);
        let mut short = compressed_file(header, &data, &lzf_literals(&data));
        short.truncate(short.len() - 3);
        let err = parse_pcd(Path::new("/x/c.pcd"), &short).expect_err("must fail").to_string();
        assert!(err.contains("/x/c.pcd") && err.contains("compressed bytes announced"), "{err}");
    }

    fn format_err(bytes: &[u8]) -> String {
        match parse_pcd(Path::new("/data/scan.pcd"), bytes) {
            Err(e @ (Error::Format { .. } | Error::Field { .. })) => e.to_string(),
            other => panic!("expected a format error, got {other:?}"),
        }
    }

    #[test]
    fn malformed_files_are_errors_naming_the_place() {
        let head = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA binary\n";
        let err = format_err(format!("{head}0123456789ab0123").as_bytes());
        assert!(err.contains("/data/scan.pcd") && err.contains("1 of 2 points"), "{err}");
        let ascii = head.replace("binary", "ascii");
        let err = format_err(format!("{ascii}1 2 3\n4 x 6\n").as_bytes());
        assert!(err.contains("line 11") && err.contains("`x`"), "{err}");
        let err = format_err(format!("{ascii}1 2 3\n").as_bytes());
        assert!(
            err.contains("POINTS 2: 2 lines of 3 values need at least 11 characters") && err.contains("has 6"),
            "{err}"
        );
        assert!(format_err(format!("{ascii}1 2 3\n         \n").as_bytes()).contains("1 of 2"));
        assert!(format_err(format!("{ascii}1 2 3\n4 5 6\n7 8 9\n").as_bytes()).contains("line 12"));
        assert!(format_err(format!("{ascii}1 2 3\n4 5   \n").as_bytes()).contains("2 values, expected 3"));
        assert!(format_err(ascii.replace("POINTS 2", "POINTS 3").as_bytes()).contains("POINTS 3"));
        assert!(format_err(ascii.replace(" z", " w").as_bytes()).contains("`z`"));
        assert!(format_err(ascii.replace("SIZE 4 4 4", "SIZE 4 4 3").as_bytes()).contains("`z`"));
        assert!(format_err(ascii.replace("TYPE F F F", "TYPE F F").as_bytes()).contains("TYPE has 2"));
        assert!(format_err(ascii.replace("WIDTH", "WIDE").as_bytes()).contains("header line 6"));
        let huge = head.replace(" 2\n", " 1000000000000000\n");
        let err = format_err(format!("{huge}0123456789ab").as_bytes());
        assert!(
            err.contains("POINTS 1000000000000000 needs 12000000000000000 bytes") && err.contains("truncated"),
            "{err}"
        );
        let huge = huge.replace("binary", "binary_compressed");
        let err = format_err(&compressed_file(&huge, &[0; 12], &[11; 13]));
        assert!(
            err.contains("uncompressed size (bytes 4-7) is 12 bytes") && err.contains("12000000000000000"),
            "{err}"
        );
        // compressed: the sizes against each other and the file, before anything is decompressed
        let packed = head.replace("binary", "binary_compressed");
        let mut lie = compressed_file(&packed, &[0; 24], &[11; 13]);
        lie[packed.len()..packed.len() + 4].copy_from_slice(&2_000_000_000u32.to_le_bytes());
        let err = format_err(&lie);
        assert!(err.contains("2000000000 compressed bytes announced (bytes 0-3), 13 present"), "{err}");
        let grid = packed
            .replace("WIDTH 2", "WIDTH 100000")
            .replace("HEIGHT 1", "HEIGHT 1000")
            .replace("POINTS 2", "POINTS 100000000");
        let mut expands = compressed_file(&grid, &[], &[11; 13]);
        expands[grid.len() + 4..grid.len() + 8].copy_from_slice(&1_200_000_000u32.to_le_bytes());
        let err = format_err(&expands);
        let want = "13 compressed bytes cannot expand to the 1200000000 bytes of POINTS 100000000 (WIDTH 100000 × HEIGHT 1000)";
        assert!(err.contains(want), "{err}");
        let huge = ascii.replace("COUNT 1 1 1", "COUNT 1 1 1000000000000");
        assert!(format_err(huge.as_bytes()).contains("COUNT"));
    }

    /// Bytes after a binary body's records are ignored with a warning naming the file and the
    /// count; after binary_compressed data silently.
    #[test]
    fn bytes_after_the_body_warn() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("b.pcd");
        write_pcd(&path, &sample_cloud(5), PcdEncoding::Binary).expect("write");
        let mut bytes = std::fs::read(&path).expect("read");
        assert!(parse_pcd_checked(Path::new("/d/b.pcd"), &bytes).expect("parse").warnings.is_empty());
        bytes.extend([7u8; 5]);
        let loaded = parse_pcd_checked(Path::new("/d/b.pcd"), &bytes).expect("parse");
        assert_eq!(loaded.value.cloud, read_pcd_organised(&path).expect("read").cloud);
        assert_eq!(
            loaded.warnings,
            vec!["/d/b.pcd: 5 bytes after the records the PCD header declares (POINTS 5) were ignored"]
        );
        // after compressed data: usual (PCL's writer leaves some), no warning
        let header = "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 2\nHEIGHT 2\nDATA binary_compressed\n";
        let data: Vec<u8> = (0..48u8).collect();
        let mut file = compressed_file(header, &data, &lzf_literals(&data));
        file.extend([0u8; 3900]);
        let loaded = parse_pcd_checked(Path::new("/d/c.pcd"), &file).expect("parse");
        assert_eq!((loaded.value.cloud.len(), loaded.warnings.len()), (4, 0));
    }

    #[test]
    fn no_byte_string_panics() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut valid = Vec::new();
        for enc in [PcdEncoding::Ascii, PcdEncoding::Binary] {
            write_pcd(&dir.path().join("f.pcd"), &sample_cloud(3), enc).expect("write");
            valid.push(std::fs::read(dir.path().join("f.pcd")).expect("read"));
        }
        let data: Vec<u8> = (0..48u8).collect();
        let header = "FIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F U\nWIDTH 3\nDATA binary_compressed\n";
        valid.push(compressed_file(header, &data, &lzf_literals(&data)));
        let path = Path::new("fuzz.pcd");
        for v in &valid {
            for cut in 0..=v.len() {
                let _ = parse_pcd(path, &v[..cut]);
            }
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for i in 0..2000 {
            let mut bytes = valid[i % valid.len()].clone();
            if i % 3 == 0 {
                bytes = (0..rng.random_range(0..200)).map(|_| rng.random::<u8>()).collect();
            } else {
                for _ in 0..rng.random_range(1..8) {
                    let at = rng.random_range(0..bytes.len());
                    bytes[at] = if i % 2 == 0 { b"0123456789 \n"[at % 12] } else { rng.random() };
                }
            }
            let _ = parse_pcd(path, &bytes);
        }
    }
}
