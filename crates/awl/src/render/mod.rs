//! Pictures of point clouds without a GPU: a small software rasteriser (orthographic views fitted
//! to the cloud, z-buffered splats), colormaps, a legend with an embedded bitmap font, and SVG
//! plots for reports. Everything returns in-memory images or text; writing files is the caller's.

pub mod colormap;
pub mod font;
pub mod legend;
pub mod plot;
pub mod raster;
pub mod shade;
pub mod view;

#[cfg(test)]
mod tests;

pub use colormap::Colormap;
pub use raster::{RenderParams, estimate_spacing};
pub use shade::{ScalarScale, render_cloud, render_scalar};
pub use view::Viewpoint;

use crate::error::{Error, Result};
use crate::image::ColorImage;

/// The image as an 8-bit RGB PNG file's bytes.
///
/// # Errors
/// [`Error::Invalid`] when the pixel count does not match the size or the encoder fails.
pub fn png_bytes(image: &ColorImage) -> Result<Vec<u8>> {
    if image.data.len() != image.width as usize * image.height as usize {
        return Err(Error::invalid("image", "pixel count does not match its size"));
    }
    let bytes: Vec<u8> = image.data.iter().flatten().copied().collect();
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, image.width, image.height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.set_compression(png::Compression::Fast);
    let written = encoder.write_header().and_then(|mut w| w.write_image_data(&bytes));
    written.map_err(|e| Error::invalid("PNG encoder", e.to_string()))?;
    Ok(out)
}
