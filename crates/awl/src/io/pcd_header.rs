//! PCD header parsing: the lines from the first one to `DATA`, checked for consistency.
//!
//! Everything here is crate-internal; the public API is in [`crate::io::pcd`].

use std::path::Path;

use crate::error::{Error, Result};

/// Body encoding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Data {
    Ascii,
    Binary,
    Compressed,
}

/// One field of the `FIELDS`/`SIZE`/`TYPE`/`COUNT` lines.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Field {
    pub(crate) name: String,
    /// Bytes per value: 1, 2, 4 or 8.
    pub(crate) size: usize,
    /// `b'F'`, `b'U'` or `b'I'`.
    pub(crate) kind: u8,
    /// Values per point.
    pub(crate) count: usize,
    /// Byte offset in a binary record; `offset × POINTS` is the start of its column in
    /// `binary_compressed` data.
    pub(crate) offset: usize,
    /// Index of its first token on an ascii line.
    pub(crate) first_token: usize,
}

impl Field {
    /// A packed 32-bit color (`rgb`, `rgba`).
    fn is_color(&self) -> bool {
        self.name == "rgb" || self.name == "rgba"
    }

    /// The value at byte `at` of `data` (little-endian), NaN when out of range.
    #[inline]
    pub(crate) fn decode(&self, data: &[u8], at: usize) -> f64 {
        let Some(b) = data.get(at..).and_then(|b| b.get(..self.size)) else { return f64::NAN };
        let mut a = [0u8; 8];
        a[..b.len()].copy_from_slice(b);
        match (self.kind, self.size) {
            (b'F', 4) => f64::from(f32::from_le_bytes([a[0], a[1], a[2], a[3]])),
            (b'F', _) => f64::from_le_bytes(a),
            (b'U', _) => u64::from_le_bytes(a) as f64,
            (_, 1) => f64::from(a[0] as i8),
            (_, 2) => f64::from(i16::from_le_bytes([a[0], a[1]])),
            (_, 4) => f64::from(i32::from_le_bytes([a[0], a[1], a[2], a[3]])),
            _ => i64::from_le_bytes(a) as f64,
        }
    }

    /// Parses one ascii token; a packed color becomes its 32-bit pattern (written by PCL either as
    /// an unsigned integer or as the float with those bits).
    #[inline]
    pub(crate) fn parse_token(&self, token: &str) -> Option<f64> {
        if self.is_color() {
            return token
                .parse::<u32>()
                .ok()
                .or_else(|| token.parse::<i32>().ok().map(|v| v as u32))
                .or_else(|| token.parse::<f32>().ok().map(f32::to_bits))
                .map(f64::from);
        }
        if self.kind == b'F' && self.size == 4 {
            token.parse::<f32>().ok().map(f64::from)
        } else {
            token.parse::<f64>().ok()
        }
    }
}

/// A parsed, consistent header.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Header {
    pub(crate) fields: Vec<Field>,
    /// Field index of each ascii token.
    pub(crate) token_field: Vec<usize>,
    pub(crate) width: usize,
    pub(crate) height: usize,
    pub(crate) points: usize,
    pub(crate) data: Data,
    /// Bytes per point.
    pub(crate) record_size: usize,
    pub(crate) body_offset: usize,
    /// 1-based number of the first body line.
    pub(crate) body_line: usize,
}

/// Parses the header of `bytes`; errors name `path` and the header line.
pub(crate) fn parse_header(path: &Path, bytes: &[u8]) -> Result<Header> {
    let mut pos = 0usize;
    let mut line_no = 0usize;
    let mut names: Option<Vec<String>> = None;
    let mut sizes: Option<Vec<usize>> = None;
    let mut kinds: Option<Vec<u8>> = None;
    let mut counts: Option<Vec<usize>> = None;
    let (mut width, mut height, mut points) = (None, None, None);
    let data = loop {
        if pos >= bytes.len() {
            return Err(Error::format(path, "PCD header has no `DATA` line (not a PCD file, or truncated)"));
        }
        let rest = bytes.get(pos..).unwrap_or_default();
        let len = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
        pos = pos.saturating_add(len + 1).min(bytes.len());
        line_no += 1;
        let bad = |msg: String| Error::format(path, format!("PCD header line {line_no}: {msg}"));
        let line = std::str::from_utf8(rest.get(..len).unwrap_or_default()).map_err(|_| bad("not text".into()))?;
        let mut words = line.split_ascii_whitespace();
        let Some(key) = words.next().filter(|k| !k.starts_with('#')) else { continue };
        let values: Vec<&str> = words.collect();
        let nums = |what: &str| -> Result<Vec<usize>> {
            values
                .iter()
                .map(|v| v.parse::<usize>().map_err(|_| bad(format!("{what}: `{v}` is not a count"))))
                .collect()
        };
        let one = |what: &str| -> Result<usize> {
            match nums(what)?.as_slice() {
                [v] => Ok(*v),
                _ => Err(bad(format!("{what} needs exactly one number"))),
            }
        };
        match key {
            "VERSION" | "VIEWPOINT" => {}
            "FIELDS" => names = Some(values.iter().map(|s| (*s).to_owned()).collect()),
            "SIZE" => sizes = Some(nums("SIZE")?),
            "COUNT" => counts = Some(nums("COUNT")?),
            "TYPE" => {
                let parsed = values.iter().map(|t| match *t {
                    "F" | "U" | "I" => Ok(t.as_bytes()[0]),
                    other => Err(bad(format!("TYPE `{other}` (expected F, U or I)"))),
                });
                kinds = Some(parsed.collect::<Result<_>>()?);
            }
            "WIDTH" => width = Some(one("WIDTH")?),
            "HEIGHT" => height = Some(one("HEIGHT")?),
            "POINTS" => points = Some(one("POINTS")?),
            "DATA" => {
                break match values.first().copied() {
                    Some("ascii") => Data::Ascii,
                    Some("binary") => Data::Binary,
                    Some("binary_compressed") => Data::Compressed,
                    other => return Err(bad(format!("unknown DATA {other:?}"))),
                };
            }
            other => return Err(bad(format!("unknown keyword `{other}`"))),
        }
    };
    let missing = |what: &str| Error::format(path, format!("PCD header has no {what} line"));
    let names = names.ok_or_else(|| missing("FIELDS"))?;
    let sizes = sizes.ok_or_else(|| missing("SIZE"))?;
    let kinds = kinds.ok_or_else(|| missing("TYPE"))?;
    let counts = counts.unwrap_or_else(|| vec![1; names.len()]);
    let width = width.ok_or_else(|| missing("WIDTH"))?;
    let height = height.unwrap_or(1);
    let grid = width.checked_mul(height);
    let points = points.or(grid).ok_or_else(|| Error::format(path, "PCD WIDTH × HEIGHT overflows"))?;
    if grid != Some(points) {
        return Err(Error::format(path, format!("PCD POINTS {points} but WIDTH {width} × HEIGHT {height}")));
    }
    for (what, len) in [("SIZE", sizes.len()), ("TYPE", kinds.len()), ("COUNT", counts.len())] {
        if len != names.len() {
            return Err(Error::format(path, format!("PCD {what} has {len} entries for {} FIELDS", names.len())));
        }
    }
    let bytes_len = bytes.len();
    let mut fields = Vec::with_capacity(names.len());
    let mut token_field = Vec::new();
    let (mut offset, mut first_token) = (0usize, 0usize);
    for (i, name) in names.into_iter().enumerate() {
        let (size, kind, count) = (sizes[i], kinds[i], counts[i]);
        let bad = |msg: &str| Error::field(path, format!("FIELDS[{i}] `{name}`"), msg.to_owned());
        if !matches!(size, 1 | 2 | 4 | 8) || (kind == b'F' && !matches!(size, 4 | 8)) {
            return Err(bad(&format!("SIZE {size} is invalid for TYPE {}", char::from(kind))));
        }
        if count == 0 {
            return Err(bad("COUNT 0"));
        }
        let bytes = size.checked_mul(count).ok_or_else(|| bad("COUNT too large"))?;
        let field_index = fields.len();
        if first_token.saturating_add(count) > bytes_len {
            return Err(bad("COUNT is larger than the file could hold"));
        }
        token_field.extend(std::iter::repeat_n(field_index, count));
        fields.push(Field { name, size, kind, count, offset, first_token });
        offset = offset.checked_add(bytes).ok_or_else(|| Error::format(path, "PCD record size overflows"))?;
        first_token = first_token.saturating_add(count);
    }
    if offset == 0 {
        return Err(Error::format(path, "PCD header has no FIELDS"));
    }
    Ok(Header {
        fields,
        token_field,
        width,
        height,
        points,
        data,
        record_size: offset,
        body_offset: pos,
        body_line: line_no + 1,
    })
}
