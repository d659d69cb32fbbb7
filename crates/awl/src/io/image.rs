//! PNG files: 16-bit depth images and 8-bit color images.

use std::path::Path;

use crate::error::{Error, Result};
use crate::image::{ColorImage, DepthImage};
use crate::io::{read_bytes, write_atomic};

fn decoder(path: &Path, bytes: &[u8]) -> Result<png::Reader<std::io::Cursor<Vec<u8>>>> {
    let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes.to_vec()));
    decoder.set_transformations(png::Transformations::IDENTITY);
    decoder.read_info().map_err(|e| Error::format(path, format!("not a readable PNG: {e}")))
}

fn decode_frame(path: &Path, reader: &mut png::Reader<std::io::Cursor<Vec<u8>>>) -> Result<Vec<u8>> {
    let size = reader.output_buffer_size().ok_or_else(|| Error::format(path, "PNG image is too large to decode"))?;
    let mut buf = vec![0; size];
    let frame = reader.next_frame(&mut buf).map_err(|e| Error::format(path, format!("corrupt PNG data: {e}")))?;
    buf.truncate(frame.buffer_size());
    Ok(buf)
}

/// Reads a 16-bit single-channel PNG depth image.
///
/// # Errors
/// [`Error::Io`] when unreadable; [`Error::Format`] when it is not a valid PNG or not 16-bit grayscale
/// (an 8-bit depth image would silently lose range, so it is refused).
pub fn read_depth_png(path: &Path) -> Result<DepthImage> {
    let bytes = read_bytes(path)?;
    let mut reader = decoder(path, &bytes)?;
    let info = reader.info();
    let (width, height) = (info.width, info.height);
    let (color, depth) = (info.color_type, info.bit_depth);
    if color != png::ColorType::Grayscale || depth != png::BitDepth::Sixteen {
        return Err(Error::format(
            path,
            format!("depth images must be 16-bit grayscale PNG, this one is {depth:?}-bit {color:?}"),
        ));
    }
    let buf = decode_frame(path, &mut reader)?;
    let data = buf.chunks_exact(2).map(|c| u16::from_be_bytes([c[0], c[1]])).collect::<Vec<_>>();
    if data.len() != width as usize * height as usize {
        return Err(Error::format(path, "PNG pixel data does not match its size"));
    }
    Ok(DepthImage { width, height, data })
}

/// Reads an 8-bit color PNG (RGB, RGBA or grayscale, alpha dropped) as RGB.
///
/// # Errors
/// [`Error::Io`] when unreadable; [`Error::Format`] when it is not a valid 8-bit PNG.
pub fn read_color_png(path: &Path) -> Result<ColorImage> {
    let bytes = read_bytes(path)?;
    let mut reader = decoder(path, &bytes)?;
    let info = reader.info();
    let (width, height, color, depth) = (info.width, info.height, info.color_type, info.bit_depth);
    if depth != png::BitDepth::Eight {
        return Err(Error::format(path, format!("color images must be 8-bit PNG, this one is {depth:?}-bit")));
    }
    let buf = decode_frame(path, &mut reader)?;
    let data: Vec<[u8; 3]> = match color {
        png::ColorType::Rgb => buf.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        png::ColorType::Rgba => buf.chunks_exact(4).map(|c| [c[0], c[1], c[2]]).collect(),
        png::ColorType::Grayscale => buf.iter().map(|&g| [g, g, g]).collect(),
        png::ColorType::GrayscaleAlpha => buf.chunks_exact(2).map(|c| [c[0], c[0], c[0]]).collect(),
        png::ColorType::Indexed => {
            return Err(Error::format(path, "indexed-palette PNG is not supported for color images"));
        }
    };
    if data.len() != width as usize * height as usize {
        return Err(Error::format(path, "PNG pixel data does not match its size"));
    }
    Ok(ColorImage { width, height, data })
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
        let err = read_depth_png(&path).unwrap_err().to_string();
        assert!(err.contains("c.png") && err.contains("16-bit"), "{err}");
    }
}
