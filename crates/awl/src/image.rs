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
