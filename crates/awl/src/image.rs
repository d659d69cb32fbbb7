//! In-memory images: 16-bit depth and 8-bit RGB color, row-major, (u, v) = (column, row).

/// A depth image in raw sensor units (multiply by the camera's `depth_scale` for metres); 0 = no return.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DepthImage {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Row-major depth values.
    pub data: Vec<u16>,
}

/// An 8-bit RGB image registered to the depth image.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ColorImage {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Row-major RGB pixels.
    pub data: Vec<[u8; 3]>,
}

impl ColorImage {
    /// Luma (ITU-R BT.601) of every pixel, row-major.
    pub fn to_gray(&self) -> Vec<u8> {
        self.data
            .iter()
            .map(|[r, g, b]| ((299 * u32::from(*r) + 587 * u32::from(*g) + 114 * u32::from(*b) + 500) / 1000) as u8)
            .collect()
    }
}

/// The pixels of every `step`-th row and column (from the first) of a row-major `width` x `height`
/// image; `step` 0 is taken as 1.
fn every_nth<T: Copy>(width: u32, height: u32, data: &[T], step: usize) -> (u32, u32, Vec<T>) {
    let step = step.max(1);
    let (w, h) = (width as usize, height as usize);
    let rows = data.chunks(w.max(1)).take(h).step_by(step);
    let data: Vec<T> = rows.flat_map(|row| row.iter().step_by(step).copied()).collect();
    (w.div_ceil(step) as u32, h.div_ceil(step) as u32, data)
}

impl DepthImage {
    /// The image of every `step`-th row and column (from the first), as the PNG reader decodes it
    /// with a step (`io::image::read_depth_png_every_nth`); `step` 0 is taken as 1.
    pub fn every_nth(&self, step: usize) -> DepthImage {
        let (width, height, data) = every_nth(self.width, self.height, &self.data, step);
        DepthImage { width, height, data }
    }
}

impl ColorImage {
    /// The image of every `step`-th row and column (from the first), as the readers decode it
    /// with a step; `step` 0 is taken as 1.
    pub fn every_nth(&self, step: usize) -> ColorImage {
        let (width, height, data) = every_nth(self.width, self.height, &self.data, step);
        ColorImage { width, height, data }
    }
}
