//! PLY header parsing (the `ply` magic, `format`, `element` and `property` lines up to
//! `end_header`) and the body walker that decodes wanted properties and skips everything else.
//!
//! Everything here is crate-internal; the public API is in [`crate::io::ply`].

use std::path::Path;

use crate::error::{Error, Result};

/// A PLY scalar type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    /// Parses a type name in either spelling (`uchar` or `uint8`).
    pub(crate) fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    /// Size in bytes in the binary encodings.
    pub(crate) fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    /// True for the two floating-point types.
    pub(crate) fn is_float(self) -> bool {
        matches!(self, Self::F32 | Self::F64)
    }

    /// Decodes one value from the start of `b` (which must hold at least `size()` bytes).
    #[inline]
    pub(crate) fn decode(self, b: &[u8], big_endian: bool) -> Option<f64> {
        macro_rules! get {
            ($t:ty, $n:literal) => {{
                let a: [u8; $n] = b.get(..$n)?.try_into().ok()?;
                if big_endian { <$t>::from_be_bytes(a) } else { <$t>::from_le_bytes(a) }
            }};
        }
        Some(match self {
            Self::I8 => f64::from(get!(i8, 1)),
            Self::U8 => f64::from(get!(u8, 1)),
            Self::I16 => f64::from(get!(i16, 2)),
            Self::U16 => f64::from(get!(u16, 2)),
            Self::I32 => f64::from(get!(i32, 4)),
            Self::U32 => f64::from(get!(u32, 4)),
            Self::F32 => f64::from(get!(f32, 4)),
            Self::F64 => get!(f64, 8),
        })
    }

    /// Parses one ascii token as this type (f32 tokens are parsed as f32, so they round-trip).
    #[inline]
    pub(crate) fn parse_token(self, token: &str) -> Option<f64> {
        match self {
            Self::F32 => token.parse::<f32>().ok().map(f64::from),
            Self::F64 => token.parse::<f64>().ok(),
            _ => token
                .parse::<i64>()
                .ok()
                .map(|v| v as f64)
                .or_else(|| token.parse::<f64>().ok().filter(|v| v.fract() == 0.0)),
        }
    }
}

/// The type of one property: a scalar or a list (count type, item type).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

/// One `property` line.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Property {
    pub(crate) name: String,
    pub(crate) kind: Kind,
}

/// One `element` line and its properties.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Element {
    pub(crate) name: String,
    pub(crate) count: u64,
    pub(crate) props: Vec<Property>,
    /// 1-based header line of its `element` line.
    pub(crate) line: usize,
}

impl Element {
    /// Index of the first property called any of `names`.
    pub(crate) fn find(&self, names: &[&str]) -> Option<usize> {
        self.props.iter().position(|p| names.contains(&p.name.as_str()))
    }

    /// Record size in bytes when the element has no list property and the size fits.
    pub(crate) fn fixed_size(&self) -> Option<usize> {
        self.props.iter().try_fold(0usize, |acc, p| match p.kind {
            Kind::Scalar(s) => acc.checked_add(s.size()),
            Kind::List { .. } => None,
        })
    }

    /// A lower bound on the size of one record (bytes in binary; characters in ascii: one digit
    /// and one separator a property).
    pub(crate) fn min_record_bytes(&self, ascii: bool) -> usize {
        let binary: usize = self
            .props
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(s) => s.size(),
                Kind::List { count, .. } => count.size(),
            })
            .sum();
        if ascii { 2 * self.props.len() } else { binary }.max(1)
    }
}

/// Body encoding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Format {
    Ascii,
    BinaryLittleEndian,
    BinaryBigEndian,
}

/// A parsed header.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Header {
    pub(crate) format: Format,
    pub(crate) elements: Vec<Element>,
    /// Byte offset of the body.
    pub(crate) body_offset: usize,
    /// 1-based line number of the first body line (meaningful for ascii).
    pub(crate) body_line: usize,
}

impl Header {
    /// Index of the element called `name`.
    pub(crate) fn element(&self, name: &str) -> Option<usize> {
        self.elements.iter().position(|e| e.name == name)
    }

    /// The header's name of the encoding (`ascii`, `binary_little_endian`, `binary_big_endian`).
    pub(crate) fn format_name(&self) -> &'static str {
        match self.format {
            Format::Ascii => "ascii",
            Format::BinaryLittleEndian => "binary_little_endian",
            Format::BinaryBigEndian => "binary_big_endian",
        }
    }

    /// Checks the header's element counts against the `body_len` bytes after the header, before
    /// anything is allocated for them: every record needs at least
    /// [`Element::min_record_bytes`] (exact for a binary element without lists), so the counts
    /// together must fit the body. Elements without properties take no room.
    ///
    /// # Errors
    /// [`Error::Format`] naming the file, the first `element` line whose records no longer fit,
    /// the bytes they need and the bytes there are.
    pub(crate) fn check_counts_fit(&self, path: &Path, body_len: usize) -> Result<()> {
        let ascii = self.format == Format::Ascii;
        let mut before: u128 = 0;
        for e in self.elements.iter().filter(|e| !e.props.is_empty()) {
            let per = e.min_record_bytes(ascii) as u128;
            let need = u128::from(e.count) * per;
            // the last ascii line may lack its newline
            let slack = u128::from(ascii && e.count > 0);
            if before + need > body_len as u128 + slack {
                let exact = !ascii && e.fixed_size().is_some();
                let unit = if ascii { "characters" } else { "bytes" };
                let at_least = if exact { "" } else { "at least " };
                let per_text =
                    if exact { format!("{per} bytes a record") } else { format!("at least {per} {unit} a record") };
                let after =
                    if before > 0 { format!(", after {before} for the elements before it") } else { String::new() };
                return Err(Error::format(
                    path,
                    format!(
                        "PLY header line {}: `element {} {}` needs {at_least}{} {unit} of {} body ({per_text}{after}), \
                         but the file has {body_len} bytes after its header: the count is wrong or the file is truncated",
                        e.line,
                        e.name,
                        e.count,
                        need - slack,
                        self.format_name(),
                    ),
                ));
            }
            before += need;
        }
        Ok(())
    }
}

/// Parses the header of `bytes`; errors name `path` and the header line.
pub(crate) fn parse_header(path: &Path, bytes: &[u8]) -> Result<Header> {
    let mut pos = 0usize;
    let mut line_no = 0usize;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    loop {
        if pos >= bytes.len() {
            return Err(Error::format(path, "PLY header has no `end_header` line (truncated file?)"));
        }
        let rest = bytes.get(pos..).unwrap_or_default();
        let len = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
        let raw = rest.get(..len).unwrap_or_default();
        pos = pos.saturating_add(len).saturating_add(1).min(bytes.len());
        line_no += 1;
        let bad = |msg: String| Error::format(path, format!("PLY header line {line_no}: {msg}"));
        let line = std::str::from_utf8(raw).map_err(|_| bad("not text".into()))?;
        let line = line.trim_end_matches('\r');
        let mut words = line.split_ascii_whitespace();
        let keyword = words.next().unwrap_or("");
        if line_no == 1 {
            if line.trim() != "ply" {
                return Err(bad("not a PLY file (the first line must be `ply`)".into()));
            }
            continue;
        }
        match keyword {
            "" | "comment" | "obj_info" => {}
            "format" => {
                let f = match words.next() {
                    Some("ascii") => Format::Ascii,
                    Some("binary_little_endian") => Format::BinaryLittleEndian,
                    Some("binary_big_endian") => Format::BinaryBigEndian,
                    other => return Err(bad(format!("unknown format {other:?}"))),
                };
                format = Some(f);
            }
            "element" => {
                let (Some(name), Some(count)) = (words.next(), words.next()) else {
                    return Err(bad("expected `element <name> <count>`".into()));
                };
                let count = count.parse::<u64>().map_err(|_| bad(format!("bad element count `{count}`")))?;
                elements.push(Element { name: name.to_owned(), count, props: Vec::new(), line: line_no });
            }
            "property" => {
                let Some(element) = elements.last_mut() else {
                    return Err(bad("`property` before any `element`".into()));
                };
                let words: Vec<&str> = words.collect();
                let ty = |w: &str| Scalar::parse(w).ok_or_else(|| bad(format!("unknown property type `{w}`")));
                let prop = match words.as_slice() {
                    ["list", count, item, name] => {
                        let count = ty(count)?;
                        if count.is_float() {
                            return Err(bad(format!("list `{name}` has a floating-point count type")));
                        }
                        Property { name: (*name).to_owned(), kind: Kind::List { count, item: ty(item)? } }
                    }
                    [t, name] => Property { name: (*name).to_owned(), kind: Kind::Scalar(ty(t)?) },
                    _ => return Err(bad("expected `property <type> <name>` or `property list <t> <t> <name>`".into())),
                };
                element.props.push(prop);
            }
            "end_header" => break,
            other => return Err(bad(format!("unknown keyword `{other}`"))),
        }
    }
    let format = format.ok_or_else(|| Error::format(path, "PLY header has no `format` line"))?;
    Ok(Header { format, elements, body_offset: pos, body_line: line_no + 1 })
}

/// Walks the body of a PLY file element by element.
///
/// For each record of element `vertex_element`, the scalar properties listed in `slots` as
/// `(property index, slot)` are decoded into a value array and `visit(values, None)` is called. For
/// each record of the element named in `list` as `(element index, property index)`, that list is
/// decoded and `visit(&[], Some(items))` is called. Every other element and property is skipped.
/// Returns how many bytes of the body the records took (binary; the whole body for ascii, where
/// anything after the last record is an error).
pub(crate) fn walk_body(
    path: &Path,
    header: &Header,
    bytes: &[u8],
    vertex_element: usize,
    slots: &[(usize, usize)],
    list: Option<(usize, usize)>,
    mut visit: impl FnMut(&[f64], Option<&[f64]>) -> Result<()>,
) -> Result<usize> {
    let body = bytes.get(header.body_offset..).unwrap_or_default();
    let mut values = vec![0.0f64; slots.iter().map(|s| s.1 + 1).max().unwrap_or(0)];
    let mut items: Vec<f64> = Vec::new();
    let big_endian = header.format == Format::BinaryBigEndian;
    let mut pos = 0usize;
    let mut lines = Lines { bytes: body, pos: 0, line: header.body_line.saturating_sub(1) };
    for (ei, e) in header.elements.iter().enumerate() {
        if e.props.is_empty() || e.count == 0 {
            continue;
        }
        let slot_of: Vec<Option<usize>> = (0..e.props.len())
            .map(|pi| if ei == vertex_element { slots.iter().find(|s| s.0 == pi).map(|s| s.1) } else { None })
            .collect();
        let want_list = list.filter(|l| l.0 == ei).map(|l| l.1);
        let wanted = ei == vertex_element || want_list.is_some();
        let truncated = |record: u64| {
            Error::format(
                path,
                format!(
                    "PLY body ends in element `{}` record {record} (header says {} records; truncated file?)",
                    e.name, e.count
                ),
            )
        };
        if header.format == Format::Ascii {
            for r in 0..e.count {
                let (line_no, line) = lines.next_nonblank().ok_or_else(|| truncated(r))?;
                let bad = |msg: String| {
                    Error::format(path, format!("PLY line {line_no} (element `{}` record {r}): {msg}", e.name))
                };
                let line = std::str::from_utf8(line).map_err(|_| bad("not text".into()))?;
                let mut tokens = line.split_ascii_whitespace();
                for (pi, p) in e.props.iter().enumerate() {
                    let mut next = || tokens.next().ok_or_else(|| bad(format!("no value for property `{}`", p.name)));
                    match p.kind {
                        Kind::Scalar(s) => {
                            let token = next()?;
                            if let Some(slot) = slot_of[pi] {
                                values[slot] = s
                                    .parse_token(token)
                                    .ok_or_else(|| bad(format!("`{token}` is not a valid value for `{}`", p.name)))?;
                            }
                        }
                        Kind::List { item, .. } => {
                            let token = next()?;
                            let n = token
                                .parse::<usize>()
                                .map_err(|_| bad(format!("`{token}` is not a valid count for list `{}`", p.name)))?;
                            let keep = want_list == Some(pi);
                            items.clear();
                            for _ in 0..n {
                                let token = next()?;
                                if keep {
                                    items.push(item.parse_token(token).ok_or_else(|| {
                                        bad(format!("`{token}` is not a valid item of list `{}`", p.name))
                                    })?);
                                }
                            }
                        }
                    }
                }
                if tokens.next().is_some() {
                    return Err(bad(format!("more values than the {} properties", e.props.len())));
                }
                if wanted {
                    visit(&values, want_list.map(|_| items.as_slice()))?;
                }
            }
            continue;
        }
        let rest = body.get(pos..).unwrap_or_default();
        if let Some(stride) = e.fixed_size().filter(|&s| s > 0) {
            let total = usize::try_from(e.count).ok().and_then(|c| c.checked_mul(stride));
            let total = total.filter(|&t| t <= rest.len()).ok_or_else(|| truncated((rest.len() / stride) as u64))?;
            if ei == vertex_element {
                let mut offsets = Vec::with_capacity(slots.len());
                let mut off = 0usize;
                for (pi, p) in e.props.iter().enumerate() {
                    if let (Kind::Scalar(s), Some(slot)) = (p.kind, slot_of[pi]) {
                        offsets.push((off, s, slot));
                    }
                    off += scalar_size(p.kind);
                }
                for record in rest.get(..total).unwrap_or_default().chunks_exact(stride) {
                    for &(off, s, slot) in &offsets {
                        values[slot] = record.get(off..).and_then(|b| s.decode(b, big_endian)).unwrap_or(0.0);
                    }
                    visit(&values, None)?;
                }
            }
            pos += total;
            continue;
        }
        for r in 0..e.count {
            for (pi, p) in e.props.iter().enumerate() {
                match p.kind {
                    Kind::Scalar(s) => {
                        let v = body.get(pos..).and_then(|b| s.decode(b, big_endian)).ok_or_else(|| truncated(r))?;
                        if let Some(slot) = slot_of[pi] {
                            values[slot] = v;
                        }
                        pos += s.size();
                    }
                    Kind::List { count, item } => {
                        let n =
                            body.get(pos..).and_then(|b| count.decode(b, big_endian)).ok_or_else(|| truncated(r))?;
                        pos += count.size();
                        if !(n >= 0.0 && n.fract() == 0.0) {
                            return Err(Error::format(
                                path,
                                format!("PLY element `{}` record {r}: list `{}` has count {n}", e.name, p.name),
                            ));
                        }
                        let len = (n as usize).checked_mul(item.size()).ok_or_else(|| truncated(r))?;
                        let data =
                            pos.checked_add(len).and_then(|end| body.get(pos..end)).ok_or_else(|| truncated(r))?;
                        if want_list == Some(pi) {
                            items.clear();
                            items.extend(
                                data.chunks_exact(item.size()).map(|b| item.decode(b, big_endian).unwrap_or(0.0)),
                            );
                        }
                        pos += len;
                    }
                }
            }
            if wanted {
                visit(&values, want_list.map(|_| items.as_slice()))?;
            }
        }
    }
    if header.format == Format::Ascii
        && let Some((line_no, _)) = lines.next_nonblank()
    {
        return Err(Error::format(
            path,
            format!("PLY line {line_no}: data after the last element (header counts too small?)"),
        ));
    }
    Ok(if header.format == Format::Ascii { body.len() } else { pos })
}

/// Size in bytes of a scalar property in a binary record (0 for a list).
pub(crate) fn scalar_size(kind: Kind) -> usize {
    match kind {
        Kind::Scalar(s) => s.size(),
        Kind::List { .. } => 0,
    }
}

/// Lines of an ascii body with their 1-based line numbers.
struct Lines<'a> {
    bytes: &'a [u8],
    pos: usize,
    line: usize,
}

impl<'a> Lines<'a> {
    /// The next line that is not only whitespace, with its number.
    fn next_nonblank(&mut self) -> Option<(usize, &'a [u8])> {
        loop {
            let rest = self.bytes.get(self.pos..).filter(|r| !r.is_empty())?;
            let len = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
            self.pos += len + 1;
            self.line += 1;
            let line = rest.get(..len).unwrap_or_default();
            if !line.iter().all(u8::is_ascii_whitespace) {
                return Some((self.line, line));
            }
        }
    }
}
