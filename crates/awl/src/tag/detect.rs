//! tag36h11 detection: our result type and the [`TagDetector`] trait (its implementation on the
//! AprilTag 3 C library: [`super::AprilTagDetector`]).
//!
//! Conventions of every [`TagDetection`]:
//! - pixels in the OpenCV convention: integer `(u, v)` are pixel centres, u right, v down (the C
//!   library puts pixel centres at +0.5; the 0.5 is subtracted here, at the boundary);
//! - corners in AprilTag order: the black-border corners bottom-left, bottom-right, top-right,
//!   top-left as the tag is read upright, i.e. tag-frame `(-s/2, -s/2)`, `(s/2, -s/2)`, `(s/2, s/2)`,
//!   `(-s/2, s/2)` in awl's tag frame (x right, y up, z out of the face; see [`crate::tag`]).

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::image::ColorImage;

/// One detected tag.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TagDetection {
    /// Tag id within the family (tag36h11: 0..=586).
    pub id: u32,
    /// Number of bits corrected to decode it (0 = exact code word).
    pub hamming: u32,
    /// AprilTag's decision margin: mean difference between the bit intensities and the threshold
    /// (higher is more confident; clean detections are typically above 50).
    pub decision_margin: f64,
    /// Black-border corners in AprilTag order (bottom-left, bottom-right, top-right, top-left as
    /// read upright), pixels, integer = pixel centre.
    pub corners_px: [[f64; 2]; 4],
    /// Image of the tag centre (intersection of the diagonals), pixels, integer = pixel centre.
    pub centre_px: [f64; 2],
}

/// A borrowed 8-bit grayscale image, row-major, `width * height` bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GrayView<'a> {
    width: u32,
    height: u32,
    data: &'a [u8],
}

impl<'a> GrayView<'a> {
    /// Wraps `data` as a `width x height` image.
    ///
    /// # Errors
    /// [`Error::Invalid`] when a side is zero or `data` is not `width * height` bytes.
    pub fn new(width: u32, height: u32, data: &'a [u8]) -> Result<Self> {
        check_size("gray image", width, height, data.len())?;
        Ok(Self { width, height, data })
    }

    /// Width, pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height, pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Row-major pixels.
    pub fn data(&self) -> &'a [u8] {
        self.data
    }
}

fn check_size(what: &str, width: u32, height: u32, len: usize) -> Result<()> {
    if width == 0 || height == 0 {
        return Err(Error::invalid(what, format!("empty image ({width} x {height})")));
    }
    let expected = width as usize * height as usize;
    if len != expected {
        return Err(Error::invalid(what, format!("{width} x {height} image needs {expected} pixels, got {len}")));
    }
    Ok(())
}

/// A tag36h11 detector. Implementations differ in speed and build cost, not in the result's
/// conventions (see the module docs); swap them behind this trait.
pub trait TagDetector {
    /// Every tag36h11 tag found in `image`; an image without tags gives an empty list. Sorted by id,
    /// then by centre (u, v).
    ///
    /// # Errors
    /// [`Error::Invalid`] when the detector cannot run on this image.
    fn detect_gray(&mut self, image: GrayView<'_>) -> Result<Vec<TagDetection>>;

    /// [`TagDetector::detect_gray`] on the luma of an RGB image.
    ///
    /// # Errors
    /// [`Error::Invalid`] when the image's pixel count does not match its size.
    fn detect_color(&mut self, image: &ColorImage) -> Result<Vec<TagDetection>> {
        check_size("color image", image.width, image.height, image.data.len())?;
        let gray = image.to_gray();
        self.detect_gray(GrayView::new(image.width, image.height, &gray)?)
    }
}

/// Settings of the AprilTag C detector. Defaults are the C library's own except `quad_decimate`,
/// `max_hamming` and `min_white_black_diff`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DetectorParams {
    /// Quads are searched on the image decimated by this factor (corners are then refined on the
    /// full image when `refine_edges`). Default 1.0 (the C library's 2.0 misses 3 of the 16 small
    /// tags in `shared/data/dt_apriltags`; 1.0 finds all of them).
    pub quad_decimate: f32,
    /// Gaussian blur (sigma, pixels) before the quad search; 0 = none. Default 0.0.
    pub quad_sigma: f32,
    /// Snap quad edges to the strong gradients of the full-resolution image. Default true.
    pub refine_edges: bool,
    /// Sharpening of the decoded bit samples. Default 0.25.
    pub decode_sharpening: f64,
    /// Most bit errors corrected when decoding (0..=3). Default 1 (the C library's 2 builds a
    /// 44 MB decode table per detector, 1 a 1 MB one: every tag36h11 detection in the real photos
    /// and the simulated views of `shared/data` and of awl's simulator decodes with 0 errors).
    pub max_hamming: u32,
    /// Worker threads of the C detector. Default 1 (results do not depend on it).
    pub threads: u8,
    /// Pixels whose neighbourhood (3 x 3 tiles of 4 x 4 pixels) spans fewer gray levels than this
    /// are not segmented into quads. Default 20: the C library's 5 segments every faint texture (a
    /// floor, a wall) and its detections in the views of `shared/data`, of both simulators and of
    /// the real photos are the same, to the bit, at 20, found 2.9x faster. A tag whose black and
    /// white differ by less than ~25 levels (a very dim one) is found only below it: see
    /// [`DetectorParams::thorough`].
    pub min_white_black_diff: u8,
}

/// The C library's `min_white_black_diff`.
const C_MIN_WHITE_BLACK_DIFF: u8 = 5;

impl Default for DetectorParams {
    fn default() -> Self {
        Self {
            quad_decimate: 1.0,
            quad_sigma: 0.0,
            refine_edges: true,
            decode_sharpening: 0.25,
            max_hamming: 1,
            threads: 1,
            min_white_black_diff: 20,
        }
    }
}

impl DetectorParams {
    /// These settings with the C library's `min_white_black_diff` (5), for a second search when
    /// these found nothing (a very dim tag); `None` when they already segment that faint.
    #[must_use]
    pub fn thorough(&self) -> Option<Self> {
        (self.min_white_black_diff > C_MIN_WHITE_BLACK_DIFF)
            .then_some(Self { min_white_black_diff: C_MIN_WHITE_BLACK_DIFF, ..*self })
    }

    /// Checks the parameters without building a detector (its decode table takes ~15 ms).
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the out-of-range parameter.
    pub fn check(&self) -> Result<()> {
        let params = self;
        if !(params.quad_decimate >= 1.0 && params.quad_decimate <= 8.0) {
            return Err(Error::invalid("quad_decimate", format!("must be 1 to 8, got {}", params.quad_decimate)));
        }
        if !(params.quad_sigma.is_finite() && params.quad_sigma.abs() <= 10.0) {
            return Err(Error::invalid("quad_sigma", format!("must be within +-10, got {}", params.quad_sigma)));
        }
        if !(0.0..=2.0).contains(&params.decode_sharpening) {
            return Err(Error::invalid(
                "decode_sharpening",
                format!("must be 0 to 2, got {}", params.decode_sharpening),
            ));
        }
        if params.max_hamming > 3 {
            return Err(Error::invalid("max_hamming", format!("must be 0 to 3, got {}", params.max_hamming)));
        }
        if params.threads == 0 {
            return Err(Error::invalid("threads", "must be at least 1"));
        }
        Ok(())
    }
}
