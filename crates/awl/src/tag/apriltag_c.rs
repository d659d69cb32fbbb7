//! [`AprilTagDetector`]: the [`TagDetector`] on the AprilTag 3 C library (`apriltag` crate, C
//! sources vendored and compiled by `cc`; the `apriltag` feature, else `no_detector`).

use apriltag::detector::QuadThresholds;
use measurements::Angle;
use noisy_float::types::r32;

use super::detect::{DetectorParams, GrayView, TagDetection, TagDetector};
use crate::error::{Error, Result};

/// Images smaller than this (either side, pixels) cannot hold a decodable tag36h11 and are not searched.
const MIN_SIDE_PX: u32 = 16;

/// Offset the AprilTag C library adds to pixel coordinates (its pixel centres sit at +0.5).
const C_PIXEL_CENTRE: f64 = 0.5;

/// tag36h11 detector on the AprilTag 3 C library (version 3.2, vendored by `apriltag-sys` 0.3).
///
/// Holds the C detector and its decode table (built once: keep one per thread and reuse it). Not
/// `Send`: create it on the thread that uses it.
pub struct AprilTagDetector {
    detector: apriltag::Detector,
}

impl std::fmt::Debug for AprilTagDetector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("AprilTagDetector(tag36h11)")
    }
}

impl AprilTagDetector {
    /// A tag36h11 detector with `params`.
    ///
    /// # Errors
    /// [`Error::Invalid`] for out-of-range parameters or when the C detector cannot be created.
    pub fn new(params: &DetectorParams) -> Result<Self> {
        params.check()?;
        let family = apriltag::Family::tag_36h11();
        let mut detector = apriltag::Detector::builder()
            .add_family_bits(family, params.max_hamming as usize)
            .build()
            .map_err(|e| Error::invalid("AprilTag detector", e.to_string()))?;
        detector.set_decimation(params.quad_decimate);
        detector.set_sigma(params.quad_sigma);
        detector.set_refine_edges(params.refine_edges);
        detector.set_shapening(params.decode_sharpening);
        detector.set_thread_number(params.threads);
        detector.set_thresholds(QuadThresholds {
            min_white_black_diff: params.min_white_black_diff,
            // the C library's defaults for the rest
            min_cluster_pixels: 5,
            max_maxima_number: 10,
            min_angle: Angle::from_degrees(10.0),
            // apriltag 0.4 passes this angle's radians on as the C library's `cos_critical_rad`:
            // the cosine of its default 10 degrees, given as radians
            min_opposite_angle: Angle::from_radians(10f64.to_radians().cos()),
            max_mse: r32(10.0),
            deglitch: false,
        });
        Ok(Self { detector })
    }
}

impl TagDetector for AprilTagDetector {
    fn detect_gray(&mut self, image: GrayView<'_>) -> Result<Vec<TagDetection>> {
        if image.width() < MIN_SIDE_PX || image.height() < MIN_SIDE_PX {
            return Ok(Vec::new());
        }
        let (w, h) = (image.width() as usize, image.height() as usize);
        let mut buffer = apriltag::Image::zeros_with_alignment(w, h, apriltag::image_buf::DEFAULT_ALIGNMENT_U8)
            .map_err(|e| Error::invalid("AprilTag image", e.to_string()))?;
        let stride = buffer.stride();
        let pixels = buffer.as_slice_mut();
        for (row, src) in image.data().chunks_exact(w).enumerate() {
            pixels[row * stride..row * stride + w].copy_from_slice(src);
        }
        let mut detections: Vec<TagDetection> = self
            .detector
            .detect(&buffer)
            .iter()
            .map(|d| TagDetection {
                id: d.id() as u32,
                hamming: d.hamming() as u32,
                decision_margin: f64::from(d.decision_margin()),
                corners_px: d.corners().map(|[u, v]| [u - C_PIXEL_CENTRE, v - C_PIXEL_CENTRE]),
                centre_px: d.center().map(|x| x - C_PIXEL_CENTRE),
            })
            .collect();
        detections.sort_by(|a, b| {
            a.id.cmp(&b.id)
                .then(a.centre_px[0].total_cmp(&b.centre_px[0]))
                .then(a.centre_px[1].total_cmp(&b.centre_px[1]))
        });
        Ok(detections)
    }
}
