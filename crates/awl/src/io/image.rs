//! Image files: 16-bit depth PNGs, 8-bit color PNGs, and color JPEGs (baseline and progressive).
//!
//! [`read_color_image`] reads a color image of either kind, told apart by its first bytes (the
//! extension only names the expected kind in the error when neither signature matches).

use std::path::Path;

use crate::camera::every_nth_grid;
use crate::error::{Error, Result};
use crate::image::{ColorImage, DepthImage};
use crate::io::{read_bytes, write_atomic};

/// The PNG at `path`, read and its header decoded.
fn decoder(path: &Path) -> Result<png::Reader<std::io::Cursor<Vec<u8>>>> {
    let bytes = read_bytes(path)?;
    let file_len = bytes.len();
    let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    decoder.set_transformations(png::Transformations::IDENTITY);
    let reader = decoder.read_info().map_err(|e| Error::format(path, format!("not a readable PNG: {e}")))?;
    check_png_size(path, &reader, file_len)?;
    Ok(reader)
}

/// The most pixels an image may have by default: 100 M (10000 x 10000; a depth camera has 1-2 M).
pub const DEFAULT_MAX_IMAGE_PIXELS: u64 = 100_000_000;

/// The environment variable that raises (or lowers) [`max_image_pixels`].
pub const MAX_IMAGE_PIXELS_VAR: &str = "AWL_MAX_IMAGE_PIXELS";

/// The most pixels an image (a PNG or JPEG file, a camera in scan.json) may have before anything is
/// allocated for it: `AWL_MAX_IMAGE_PIXELS` when set to a number, else [`DEFAULT_MAX_IMAGE_PIXELS`].
pub fn max_image_pixels() -> u64 {
    std::env::var(MAX_IMAGE_PIXELS_VAR).ok().and_then(|v| v.trim().parse().ok()).unwrap_or(DEFAULT_MAX_IMAGE_PIXELS)
}

/// Refuses a `width` x `height` image over [`max_image_pixels`], naming `what` (the file, or the
/// scan.json field) and how to raise the limit.
pub(crate) fn check_image_pixels(width: u64, height: u64) -> std::result::Result<(), String> {
    let (pixels, max) = (width.saturating_mul(height), max_image_pixels());
    if pixels > max {
        return Err(format!(
            "{width} x {height} = {pixels} pixels, more than the {max}-pixel limit (set {MAX_IMAGE_PIXELS_VAR} to raise it)"
        ));
    }
    Ok(())
}

/// Refuses a PNG whose header's size is over [`max_image_pixels`] or more than a `file_len`-byte
/// file can hold (deflate packs at most 1032 bytes into one), before anything is allocated for it.
fn check_png_size(path: &Path, reader: &png::Reader<std::io::Cursor<Vec<u8>>>, file_len: usize) -> Result<()> {
    let info = reader.info();
    check_image_pixels(u64::from(info.width), u64::from(info.height))
        .map_err(|m| Error::format(path, format!("PNG header declares {m}")))?;
    let size = output_size(path, reader)?;
    if size as u64 > 1032 * file_len as u64 + 65_536 {
        return Err(Error::format(
            path,
            format!(
                "PNG header declares {} x {} ({size} bytes of pixels), more than a {file_len}-byte file can hold: \
                 the file is truncated or its header is corrupt",
                info.width, info.height
            ),
        ));
    }
    Ok(())
}

/// The decoded image's size in bytes, once known to fit in memory's address space.
fn output_size(path: &Path, reader: &png::Reader<std::io::Cursor<Vec<u8>>>) -> Result<usize> {
    reader.output_buffer_size().ok_or_else(|| Error::format(path, "PNG image is too large to decode"))
}

/// Decodes every `step`-th row of the image (from the first) in order into `row` (each one row of
/// raw samples): row by row, so the whole raw image is never held beside the caller's pixels; an
/// interlaced image is decoded whole first.
fn decode_rows(
    path: &Path,
    reader: &mut png::Reader<std::io::Cursor<Vec<u8>>>,
    step: usize,
    mut row: impl FnMut(&[u8]),
) -> Result<()> {
    let corrupt = |e: png::DecodingError| Error::format(path, format!("corrupt PNG data: {e}"));
    if reader.info().interlaced {
        let mut buf = vec![0; output_size(path, reader)?];
        let frame = reader.next_frame(&mut buf).map_err(corrupt)?;
        buf.truncate(frame.buffer_size());
        let line = frame.line_size.max(1);
        buf.chunks_exact(line).step_by(step).for_each(row);
        return Ok(());
    }
    let mut v = 0;
    while let Some(r) = reader.next_row().map_err(corrupt)? {
        if v % step == 0 {
            row(r.data());
        }
        v += 1;
    }
    Ok(())
}

/// What [`decode_every_nth`] gives.
struct Pixels<T> {
    /// Row-major on the grid.
    data: Vec<T>,
    /// The grid's `(width, height)`.
    grid: (u32, u32),
    /// The file's `(width, height)`.
    full: (u32, u32),
}

/// Every `step`-th row and column of the image (from the first; `step` 0 is taken as 1), each
/// pixel's `bytes_per_pixel` raw bytes made one pixel by `pixel`, on the grid [`every_nth_grid`]
/// gives.
fn decode_every_nth<T>(
    path: &Path,
    reader: &mut png::Reader<std::io::Cursor<Vec<u8>>>,
    step: usize,
    bytes_per_pixel: usize,
    pixel: impl Fn(&[u8]) -> T,
) -> Result<Pixels<T>> {
    let step = step.max(1);
    output_size(path, reader)?;
    let full = (reader.info().width, reader.info().height);
    let (width, height) = every_nth_grid(full.0 as usize, full.1 as usize, step);
    let mut data = Vec::with_capacity(width * height);
    decode_rows(path, reader, step, |row| data.extend(row.chunks_exact(bytes_per_pixel).step_by(step).map(&pixel)))?;
    if data.len() != width * height {
        return Err(Error::format(path, "PNG pixel data does not match its size"));
    }
    Ok(Pixels { data, grid: (width as u32, height as u32), full })
}

/// Reads a 16-bit single-channel PNG depth image.
///
/// # Errors
/// [`Error::Io`] when unreadable; [`Error::Format`] when it is not a valid PNG or not 16-bit grayscale
/// (an 8-bit depth image would silently lose range, so it is refused).
pub fn read_depth_png(path: &Path) -> Result<DepthImage> {
    Ok(read_depth_png_every_nth(path, 1)?.0)
}

/// [`read_depth_png`] keeping every `step`-th row and column only (from the first; `step` 0 is
/// taken as 1): the image on the grid [`every_nth_grid`] gives, and the file's full `(width,
/// height)`. The other pixels are decoded and dropped row by row, never held.
///
/// # Errors
/// As [`read_depth_png`].
pub fn read_depth_png_every_nth(path: &Path, step: usize) -> Result<(DepthImage, (u32, u32))> {
    let mut reader = decoder(path)?;
    let info = reader.info();
    let (color, depth) = (info.color_type, info.bit_depth);
    if color != png::ColorType::Grayscale || depth != png::BitDepth::Sixteen {
        return Err(Error::format(
            path,
            format!("depth images must be 16-bit grayscale PNG, this one is {depth:?}-bit {color:?}"),
        ));
    }
    let Pixels { data, grid: (width, height), full } =
        decode_every_nth(path, &mut reader, step, 2, |c| u16::from_be_bytes([c[0], c[1]]))?;
    Ok((DepthImage { width, height, data }, full))
}

/// Reads an 8-bit color PNG (RGB, RGBA or grayscale, alpha dropped) as RGB.
///
/// # Errors
/// [`Error::Io`] when unreadable; [`Error::Format`] when it is not a valid 8-bit PNG.
pub fn read_color_png(path: &Path) -> Result<ColorImage> {
    Ok(read_color_png_every_nth(path, 1)?.0)
}

/// [`read_color_png`] keeping every `step`-th row and column only, as
/// [`read_depth_png_every_nth`].
///
/// # Errors
/// As [`read_color_png`].
pub fn read_color_png_every_nth(path: &Path, step: usize) -> Result<(ColorImage, (u32, u32))> {
    let mut reader = decoder(path)?;
    let info = reader.info();
    let (color, depth) = (info.color_type, info.bit_depth);
    if depth != png::BitDepth::Eight {
        return Err(Error::format(path, format!("color images must be 8-bit PNG, this one is {depth:?}-bit")));
    }
    let channels = match color {
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Indexed => {
            return Err(Error::format(path, "indexed-palette PNG is not supported for color images"));
        }
    };
    let Pixels { data, grid: (width, height), full } = decode_every_nth(path, &mut reader, step, channels, |c| {
        if channels < 3 { [c[0], c[0], c[0]] } else { [c[0], c[1], c[2]] }
    })?;
    Ok((ColorImage { width, height, data }, full))
}

/// The 8 bytes every PNG starts with.
const PNG_SIGNATURE: [u8; 8] = *b"\x89PNG\r\n\x1a\n";
/// A JPEG starts with its start-of-image marker and the first marker's `0xFF`.
const JPEG_SIGNATURE: [u8; 3] = [0xFF, 0xD8, 0xFF];
/// Largest JPEG side accepted, pixels (the decoder refuses a larger header before allocating).
pub const MAX_JPEG_SIDE_PX: usize = 16_384;

/// The kind of a color image file, by its first bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColorFileKind {
    /// Portable Network Graphics.
    Png,
    /// JPEG (JFIF / Exif).
    Jpeg,
}

/// The kind of color image `bytes` hold, by their signature; `None` when neither PNG nor JPEG.
pub fn color_file_kind(bytes: &[u8]) -> Option<ColorFileKind> {
    if bytes.starts_with(&PNG_SIGNATURE) {
        Some(ColorFileKind::Png)
    } else if bytes.starts_with(&JPEG_SIGNATURE) {
        Some(ColorFileKind::Jpeg)
    } else {
        None
    }
}

/// Reads an 8-bit color image, PNG or JPEG (by its signature, whatever its extension), as RGB:
/// PNG as [`read_color_png`]; JPEG baseline or progressive, gray JPEGs expanded to RGB.
///
/// # Errors
/// [`Error::Io`] when unreadable; [`Error::Format`] naming the file when it is neither PNG nor
/// JPEG, or does not decode (a truncated or corrupt JPEG is refused, never half-filled), or a JPEG
/// side exceeds [`MAX_JPEG_SIDE_PX`].
pub fn read_color_image(path: &Path) -> Result<ColorImage> {
    Ok(read_color_image_every_nth(path, 1)?.0)
}

/// [`read_color_image`] keeping every `step`-th row and column only (from the first; `step` 0 is
/// taken as 1), and the file's full `(width, height)`, as [`read_color_png_every_nth`]. A JPEG is
/// decoded whole, then thinned.
///
/// # Errors
/// As [`read_color_image`].
pub fn read_color_image_every_nth(path: &Path, step: usize) -> Result<(ColorImage, (u32, u32))> {
    let bytes = read_bytes(path)?;
    match color_file_kind(&bytes) {
        Some(ColorFileKind::Png) => read_color_png_every_nth(path, step),
        Some(ColorFileKind::Jpeg) => {
            let (image, full) = decode_jpeg(path, bytes)?;
            Ok((every_nth_color(image, step), full))
        }
        None => {
            let ext = crate::io::extension(path);
            let expected = match ext.as_str() {
                "jpg" | "jpeg" => "a JPEG (no FF D8 FF start-of-image marker)",
                "png" => "a PNG (no PNG signature)",
                _ => "a PNG or JPEG color image",
            };
            Err(Error::format(path, format!("not {expected}")))
        }
    }
}

/// Decodes a whole JPEG file's `bytes` to RGB: the image and its `(width, height)`; a header that
/// declares more pixels than the file's bytes can code is refused before anything is allocated.
fn decode_jpeg(path: &Path, bytes: Vec<u8>) -> Result<(ColorImage, (u32, u32))> {
    let file_len = bytes.len();
    use zune_jpeg::zune_core::bytestream::ZCursor;
    use zune_jpeg::zune_core::colorspace::ColorSpace;
    use zune_jpeg::zune_core::options::DecoderOptions;
    let options = DecoderOptions::default()
        .set_max_width(MAX_JPEG_SIDE_PX)
        .set_max_height(MAX_JPEG_SIDE_PX)
        // a premature end or a corrupt entropy stream is an error, not a gray-filled image
        .set_strict_mode(true)
        .jpeg_set_out_colorspace(ColorSpace::RGB);
    let mut decoder = zune_jpeg::JpegDecoder::new_with_options(ZCursor::new(bytes), options);
    let bad = |e: zune_jpeg::errors::DecodeErrors| Error::format(path, format!("not a decodable JPEG: {e}"));
    decoder.decode_headers().map_err(bad)?;
    let (width, height) = decoder.dimensions().ok_or_else(|| Error::format(path, "JPEG header without a size"))?;
    // every 8 x 8 block of the first component takes at least one bit of entropy-coded data (its DC
    // code; in a progressive JPEG, in the first DC scan): at most 512 pixels a byte of the file
    let pixels = width as u64 * height as u64;
    if pixels > 512 * file_len as u64 + 65_536 {
        return Err(Error::format(
            path,
            format!(
                "JPEG header declares {width} x {height} ({pixels} pixels), more than a {file_len}-byte file can hold \
                 (every 8 x 8 block takes at least a bit): the file is truncated or its header is corrupt"
            ),
        ));
    }
    let size = decoder.output_buffer_size().ok_or_else(|| Error::format(path, "JPEG image is too large to decode"))?;
    let mut raw = vec![0u8; size];
    decoder.decode_into(&mut raw).map_err(bad)?;
    let channels = decoder.output_colorspace().map_or(3, |c| c.num_components());
    let (width, height) = (width as u32, height as u32);
    let pixels = width as usize * height as usize;
    if channels == 0 || raw.len() != pixels * channels {
        return Err(Error::format(path, format!("JPEG decoded to {} bytes for {width}x{height}", raw.len())));
    }
    let data = raw.chunks_exact(channels).map(|c| if channels < 3 { [c[0]; 3] } else { [c[0], c[1], c[2]] }).collect();
    Ok((ColorImage { width, height, data }, (width, height)))
}

/// Every `step`-th row and column of `image` (from the first; `step` 0 is taken as 1), on the grid
/// [`every_nth_grid`] gives.
fn every_nth_color(image: ColorImage, step: usize) -> ColorImage {
    let step = step.max(1);
    if step == 1 {
        return image;
    }
    let (w, h) = (image.width as usize, image.height as usize);
    let (width, height) = every_nth_grid(w, h, step);
    let data = image.data.chunks_exact(w).step_by(step).flat_map(|row| row.iter().step_by(step).copied()).collect();
    ColorImage { width: width as u32, height: height as u32, data }
}

fn encode(width: u32, height: u32, color: png::ColorType, depth: png::BitDepth, data: &[u8]) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, width, height);
    encoder.set_color(color);
    encoder.set_depth(depth);
    encoder.set_compression(png::Compression::Fast);
    let encoded = encoder.write_header().and_then(|mut w| w.write_image_data(data));
    encoded.map_err(|e| Error::invalid("PNG encoder", e.to_string()))?;
    Ok(out)
}

/// Writes a 16-bit grayscale PNG depth image (atomically).
///
/// # Errors
/// [`Error::Io`] naming `path` when it cannot be written.
pub fn write_depth_png(path: &Path, image: &DepthImage) -> Result<()> {
    let bytes: Vec<u8> = image.data.iter().flat_map(|v| v.to_be_bytes()).collect();
    let png = encode(image.width, image.height, png::ColorType::Grayscale, png::BitDepth::Sixteen, &bytes)?;
    write_atomic(path, &png)
}

/// Writes an 8-bit RGB PNG (atomically).
///
/// # Errors
/// [`Error::Io`] naming `path` when it cannot be written.
pub fn write_color_png(path: &Path, image: &ColorImage) -> Result<()> {
    let bytes: Vec<u8> = image.data.iter().flatten().copied().collect();
    let png = encode(image.width, image.height, png::ColorType::Rgb, png::BitDepth::Eight, &bytes)?;
    write_atomic(path, &png)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_and_color_round_trip_bit_exact() {
        let dir = tempfile::tempdir().expect("tempdir");
        let depth = DepthImage { width: 3, height: 2, data: vec![0, 1, 256, 65535, 1234, 42] };
        let path = dir.path().join("d.png");
        write_depth_png(&path, &depth).expect("write");
        assert_eq!(read_depth_png(&path).expect("read"), depth);
        let color = ColorImage { width: 2, height: 1, data: vec![[1, 2, 3], [250, 128, 0]] };
        let path = dir.path().join("c.png");
        write_color_png(&path, &color).expect("write");
        assert_eq!(read_color_png(&path).expect("read"), color);
        let err = read_depth_png(&path).expect_err("an error").to_string();
        assert!(err.contains("c.png") && err.contains("16-bit"), "{err}");
    }

    /// A PNG with Adam7 interlacing, written here by hand (the encoder writes none): `samples` is
    /// the image row-major, `bytes_per_pixel` bytes a pixel, stored (uncompressed) deflate blocks.
    fn adam7_png(
        width: usize,
        height: usize,
        color_type: u8,
        bit_depth: u8,
        bytes_per_pixel: usize,
        samples: &[u8],
    ) -> Vec<u8> {
        fn crc32(bytes: &[u8]) -> u32 {
            let mut crc = !0u32;
            for &b in bytes {
                crc ^= u32::from(b);
                for _ in 0..8 {
                    crc = if crc & 1 == 1 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
                }
            }
            !crc
        }
        fn chunk(out: &mut Vec<u8>, kind: &[u8], data: &[u8]) {
            out.extend((data.len() as u32).to_be_bytes());
            let body: Vec<u8> = kind.iter().chain(data).copied().collect();
            out.extend(&body);
            out.extend(crc32(&body).to_be_bytes());
        }
        let mut raw = Vec::new();
        for (x0, y0, dx, dy) in
            [(0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2), (0, 1, 1, 2)]
        {
            if x0 >= width || y0 >= height {
                continue;
            }
            for y in (y0..height).step_by(dy) {
                raw.push(0); // filter: none
                for x in (x0..width).step_by(dx) {
                    let i = (y * width + x) * bytes_per_pixel;
                    raw.extend(&samples[i..i + bytes_per_pixel]);
                }
            }
        }
        let (mut zlib, mut adler) = (vec![0x78, 0x01], (1u32, 0u32));
        for &b in &raw {
            adler.0 = (adler.0 + u32::from(b)) % 65521;
            adler.1 = (adler.1 + adler.0) % 65521;
        }
        let blocks: Vec<&[u8]> = raw.chunks(65535).collect();
        for (k, block) in blocks.iter().enumerate() {
            zlib.push(u8::from(k + 1 == blocks.len()));
            let len = block.len() as u16;
            zlib.extend(len.to_le_bytes());
            zlib.extend((!len).to_le_bytes());
            zlib.extend(*block);
        }
        zlib.extend(((adler.1 << 16) | adler.0).to_be_bytes());
        let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
        let mut header: Vec<u8> = Vec::new();
        header.extend((width as u32).to_be_bytes());
        header.extend((height as u32).to_be_bytes());
        header.extend([bit_depth, color_type, 0, 0, 1]);
        chunk(&mut out, b"IHDR", &header);
        chunk(&mut out, b"IDAT", &zlib);
        chunk(&mut out, b"IEND", &[]);
        out
    }

    #[test]
    fn interlaced_images_read_as_the_plain_ones() {
        let dir = tempfile::tempdir().expect("tempdir");
        let (w, h) = (13, 10);
        let depth =
            DepthImage { width: w as u32, height: h as u32, data: (0..w * h).map(|i| (i * 517) as u16).collect() };
        let samples: Vec<u8> = depth.data.iter().flat_map(|v| v.to_be_bytes()).collect();
        let path = dir.path().join("d.png");
        std::fs::write(&path, adam7_png(w, h, 0, 16, 2, &samples)).expect("write");
        assert_eq!(read_depth_png(&path).expect("interlaced depth"), depth);
        let rgba: Vec<u8> = (0..w * h * 4).map(|i| (i * 7 % 251) as u8).collect();
        let color = ColorImage {
            width: w as u32,
            height: h as u32,
            data: rgba.chunks_exact(4).map(|c| [c[0], c[1], c[2]]).collect(),
        };
        let path = dir.path().join("c.png");
        std::fs::write(&path, adam7_png(w, h, 6, 8, 4, &rgba)).expect("write");
        assert_eq!(read_color_png(&path).expect("interlaced color"), color);
    }

    /// Every `step`-th row and column of the full image, from the first.
    fn every_nth<T: Copy>(data: &[T], width: usize, step: usize) -> Vec<T> {
        let rows = data.chunks_exact(width).step_by(step);
        rows.flat_map(|row| row.iter().step_by(step).copied()).collect()
    }

    #[test]
    fn every_nth_pixel_reads_as_the_full_image_thinned() {
        let dir = tempfile::tempdir().expect("tempdir");
        let (w, h) = (13usize, 10usize);
        let depth =
            DepthImage { width: w as u32, height: h as u32, data: (0..w * h).map(|i| (i * 517) as u16).collect() };
        let color = ColorImage {
            width: w as u32,
            height: h as u32,
            data: (0..w * h).map(|i| [(i % 251) as u8, (i * 3 % 251) as u8, (i * 7 % 251) as u8]).collect(),
        };
        let (plain_depth, plain_color) = (dir.path().join("d.png"), dir.path().join("c.png"));
        write_depth_png(&plain_depth, &depth).expect("write depth");
        write_color_png(&plain_color, &color).expect("write color");
        let samples: Vec<u8> = depth.data.iter().flat_map(|v| v.to_be_bytes()).collect();
        let adam7_depth = dir.path().join("d7.png");
        std::fs::write(&adam7_depth, adam7_png(w, h, 0, 16, 2, &samples)).expect("write");
        let rgb: Vec<u8> = color.data.iter().flatten().copied().collect();
        let adam7_color = dir.path().join("c7.png");
        std::fs::write(&adam7_color, adam7_png(w, h, 2, 8, 3, &rgb)).expect("write");
        for step in [0, 1, 2, 3, 4, 13, 20] {
            let s = step.max(1);
            let (cw, ch) = (w.div_ceil(s) as u32, h.div_ceil(s) as u32);
            let want_depth = DepthImage { width: cw, height: ch, data: every_nth(&depth.data, w, s) };
            let want_color = ColorImage { width: cw, height: ch, data: every_nth(&color.data, w, s) };
            for path in [&plain_depth, &adam7_depth] {
                let got = read_depth_png_every_nth(path, step).expect("depth");
                assert_eq!(got, (want_depth.clone(), (w as u32, h as u32)), "step {step}, {}", path.display());
            }
            for path in [&plain_color, &adam7_color] {
                let got = read_color_png_every_nth(path, step).expect("color");
                assert_eq!(got, (want_color.clone(), (w as u32, h as u32)), "step {step}, {}", path.display());
            }
        }
        let err = read_depth_png_every_nth(&plain_color, 2).expect_err("not 16-bit").to_string();
        assert!(err.contains("c.png") && err.contains("16-bit"), "{err}");
    }

    /// `image` as a JPEG (quality 95, 4:2:0 chroma as cameras write it), baseline or progressive,
    /// RGB or (`gray`) its luma.
    fn jpeg(image: &ColorImage, progressive: bool, gray: bool) -> Vec<u8> {
        let mut out = Vec::new();
        let mut encoder = jpeg_encoder::Encoder::new(&mut out, 95);
        encoder.set_progressive(progressive);
        let (w, h) = (image.width as u16, image.height as u16);
        let encoded = if gray {
            encoder.encode(&image.to_gray(), w, h, jpeg_encoder::ColorType::Luma)
        } else {
            let rgb: Vec<u8> = image.data.iter().flatten().copied().collect();
            encoder.encode(&rgb, w, h, jpeg_encoder::ColorType::Rgb)
        };
        encoded.expect("encode JPEG");
        out
    }

    /// A smooth 64 x 48 test card (JPEG keeps it within a few levels).
    fn card() -> ColorImage {
        let (w, h) = (64u32, 48u32);
        let data = (0..w * h)
            .map(|i| {
                let (u, v) = (i % w, i / w);
                [(u * 4) as u8, (v * 5) as u8, (128 + u + v) as u8]
            })
            .collect();
        ColorImage { width: w, height: h, data }
    }

    fn max_difference(a: &ColorImage, b: &ColorImage) -> u8 {
        assert_eq!((a.width, a.height), (b.width, b.height));
        a.data.iter().zip(&b.data).flat_map(|(p, q)| (0..3).map(move |c| p[c].abs_diff(q[c]))).max().unwrap_or(0)
    }

    #[test]
    fn baseline_progressive_and_gray_jpegs_read_as_rgb() {
        let dir = tempfile::tempdir().expect("tempdir");
        let card = card();
        let gray: Vec<[u8; 3]> = card.to_gray().into_iter().map(|g| [g; 3]).collect();
        let gray = ColorImage { data: gray, ..card };
        for (name, progressive, is_gray) in
            [("b.jpg", false, false), ("p.jpg", true, false), ("g.jpeg", false, true), ("gp.JPG", true, true)]
        {
            let path = dir.path().join(name);
            std::fs::write(&path, jpeg(&card, progressive, is_gray)).expect("write");
            let got = read_color_image(&path).expect(name);
            let want = if is_gray { &gray } else { &card };
            // measured: 3 (baseline), 3 (progressive), 1 (gray) levels at quality 95, 4:2:0
            let diff = max_difference(&got, want);
            println!("{name}: {diff} levels off");
            assert!(diff <= 8, "{name}: {diff} levels off");
            if is_gray {
                assert!(got.data.iter().all(|p| p[0] == p[1] && p[1] == p[2]), "{name}: gray expanded to RGB");
            }
            for step in [2, 3, 7] {
                let (thin, full) = read_color_image_every_nth(&path, step).expect("every nth");
                assert_eq!(full, (64, 48));
                assert_eq!(thin.data, every_nth(&got.data, 64, step), "{name} step {step}");
                assert_eq!((thin.width, thin.height), (64u32.div_ceil(step as u32), 48u32.div_ceil(step as u32)));
            }
        }
        // a PNG named .jpg, and a JPEG named .png, are read by what they hold
        let png_named_jpg = dir.path().join("really_png.jpg");
        write_color_png(&png_named_jpg, &card).expect("png");
        assert_eq!(read_color_image(&png_named_jpg).expect("png by signature"), card);
        let jpg_named_png = dir.path().join("really_jpeg.png");
        std::fs::write(&jpg_named_png, jpeg(&card, false, false)).expect("write");
        assert!(max_difference(&read_color_image(&jpg_named_png).expect("jpeg by signature"), &card) <= 8);
    }

    #[test]
    fn corrupt_truncated_and_oversized_jpegs_are_refused_naming_the_file() {
        let dir = tempfile::tempdir().expect("tempdir");
        let bytes = jpeg(&card(), false, false);
        let progressive = jpeg(&card(), true, false);
        let cases: Vec<(&str, Vec<u8>, &str)> = vec![
            ("truncated.jpg", bytes[..bytes.len() / 2].to_vec(), "not a decodable JPEG"),
            ("truncated_progressive.jpg", progressive[..progressive.len() / 2].to_vec(), "not a decodable JPEG"),
            ("header_only.jpg", bytes[..4].to_vec(), "not a decodable JPEG"),
            ("text.jpg", b"this is not an image".to_vec(), "not a JPEG"),
            ("empty.jpeg", Vec::new(), "not a JPEG"),
            ("noise.bin", vec![7; 100], "not a PNG or JPEG"),
        ];
        // a 20000 x 20000 frame header: refused before its 1.2 GB are allocated
        let mut huge = bytes.clone();
        let sof = huge.windows(2).position(|w| w == [0xFF, 0xC0]).expect("SOF0 marker");
        huge[sof + 5..sof + 9].copy_from_slice(&[0x4E, 0x20, 0x4E, 0x20]);
        let mut cases = cases;
        cases.push(("huge.jpg", huge, "not a decodable JPEG"));
        // 16384 x 16384 (the largest side accepted) over a small image's data: more pixels than its
        // bytes can code, refused before decoding (zune-jpeg fills the missing blocks)
        let mut lying = bytes.clone();
        lying[sof + 5..sof + 9].copy_from_slice(&[0x40, 0x00, 0x40, 0x00]);
        cases.push(("lying.jpg", lying, "declares 16384 x 16384 (268435456 pixels), more than a"));
        for (name, content, want) in cases {
            let path = dir.path().join(name);
            std::fs::write(&path, content).expect("write");
            let err = read_color_image(&path).expect_err(name);
            let text = err.to_string();
            assert!(matches!(err, Error::Format { .. }) && text.contains(name) && text.contains(want), "{text}");
        }
    }
}
