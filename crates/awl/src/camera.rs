//! Pinhole camera with Brown-Conrady distortion, and depth image -> points in the camera frame.
//!
//! Pixels: integer (u, v) are pixel centres (OpenCV); u right, v down. Camera frame: x right,
//! y down, z forward, metres. `u = fx * x_d + cx` where `x_d` is the distorted normalised coordinate.

use nalgebra::{Matrix2, Point2, Point3, Vector2};
use serde::{Deserialize, Serialize};

use crate::cloud::PointCloud;
use crate::image::{ColorImage, DepthImage};

/// Intrinsics of a pinhole camera, pixels; `distortion` is `[k1, k2, p1, p2, k3]` (OpenCV order).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Focal length along u, pixels.
    pub fx: f64,
    /// Focal length along v, pixels.
    pub fy: f64,
    /// Principal point u, pixels.
    pub cx: f64,
    /// Principal point v, pixels.
    pub cy: f64,
    /// Brown-Conrady `[k1, k2, p1, p2, k3]`.
    #[serde(default)]
    pub distortion: [f64; 5],
}

/// A depth camera: intrinsics plus how depth values map to metres and which range is kept.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthCamera {
    /// Intrinsics shared by the depth and the registered color image.
    pub intrinsics: Intrinsics,
    /// Metres per depth unit (0.001 for millimetre PNGs).
    pub depth_scale: f64,
    /// Returns nearer than this are dropped, metres.
    pub depth_min_m: f64,
    /// Returns farther than this are dropped, metres.
    pub depth_max_m: f64,
}

impl DepthCamera {
    /// The depth of a raw depth pixel, metres; `None` for no return (0) or outside
    /// `[depth_min_m, depth_max_m]`.
    pub fn depth_m(&self, raw: u16) -> Option<f32> {
        let z = f64::from(raw) * self.depth_scale;
        (raw != 0 && z >= self.depth_min_m && z <= self.depth_max_m).then_some(z as f32)
    }
}

impl Intrinsics {
    /// True when every distortion coefficient is zero.
    pub fn is_pinhole(&self) -> bool {
        self.distortion.iter().all(|&k| k == 0.0)
    }

    /// Applies the distortion model to a normalised coordinate `(x, y) = (X/Z, Y/Z)`.
    pub fn distort(&self, n: Vector2<f64>) -> Vector2<f64> {
        let [k1, k2, p1, p2, k3] = self.distortion;
        let (x, y) = (n.x, n.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        Vector2::new(
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )
    }

    /// Inverts [`Intrinsics::distort`] by Gauss-Newton (a few iterations reach 1e-12 for real lenses).
    pub fn undistort(&self, d: Vector2<f64>) -> Vector2<f64> {
        if self.is_pinhole() {
            return d;
        }
        let mut n = d;
        for _ in 0..20 {
            let residual = self.distort(n) - d;
            if residual.norm() < 1e-14 {
                break;
            }
            let h = 1e-7;
            let jx = (self.distort(n + Vector2::new(h, 0.0)) - self.distort(n - Vector2::new(h, 0.0))) / (2.0 * h);
            let jy = (self.distort(n + Vector2::new(0.0, h)) - self.distort(n - Vector2::new(0.0, h))) / (2.0 * h);
            let j = Matrix2::from_columns(&[jx, jy]);
            match j.try_inverse() {
                Some(inv) => n -= inv * residual,
                None => break,
            }
        }
        n
    }

    /// Projects a camera-frame point to pixel coordinates; `None` behind the camera (z <= 0).
    pub fn project(&self, p_camera: &Point3<f64>) -> Option<Point2<f64>> {
        if p_camera.z <= 0.0 {
            return None;
        }
        let d = self.distort(Vector2::new(p_camera.x / p_camera.z, p_camera.y / p_camera.z));
        Some(Point2::new(self.fx * d.x + self.cx, self.fy * d.y + self.cy))
    }

    /// The camera-frame point at depth `z_m` (along the optical axis) seen at pixel `px`.
    pub fn back_project(&self, px: &Point2<f64>, z_m: f64) -> Point3<f64> {
        let n = self.ray(px);
        Point3::new(n.x * z_m, n.y * z_m, z_m)
    }

    /// Undistorted normalised coordinate `(X/Z, Y/Z)` of the ray through pixel `px`.
    pub fn ray(&self, px: &Point2<f64>) -> Vector2<f64> {
        self.undistort(Vector2::new((px.x - self.cx) / self.fx, (px.y - self.cy) / self.fy))
    }

    /// Normalised ray of every pixel centre, row-major (`v * width + u`), for fast back-projection.
    pub fn ray_table(&self) -> Vec<[f32; 2]> {
        self.ray_table_every_nth(1)
    }

    /// [`Intrinsics::ray_table`] of the pixels on every `step`-th row and column (from the first),
    /// row-major on that coarser grid ([`every_nth_grid`]): the table
    /// [`depth_to_cloud_every_nth`] takes for `step`. `step` 0 is taken as 1.
    pub fn ray_table_every_nth(&self, step: usize) -> Vec<[f32; 2]> {
        let step = step.max(1);
        let (w, h) = every_nth_grid(self.width as usize, self.height as usize, step);
        let mut table = Vec::with_capacity(w * h);
        for v in (0..self.height).step_by(step) {
            for u in (0..self.width).step_by(step) {
                table.push(self.ray_f32(u, v));
            }
        }
        table
    }

    /// [`Intrinsics::ray`] of the centre of pixel `(u, v)`, as stored in a ray table.
    fn ray_f32(&self, u: u32, v: u32) -> [f32; 2] {
        let n = self.ray(&Point2::new(f64::from(u), f64::from(v)));
        [n.x as f32, n.y as f32]
    }
}

/// A rectangle of pixels: columns `u` and rows `v` (half-open ranges).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PixelRect {
    /// Columns.
    pub u: std::ops::Range<u32>,
    /// Rows.
    pub v: std::ops::Range<u32>,
}

impl PixelRect {
    /// The pixels within `margin` pixels of the bounding box of `points` (pixel coordinates,
    /// integer = pixel centre), clipped to a `width` x `height` image; empty for no point or a
    /// non-finite one.
    pub fn around(points: &[[f64; 2]], margin: f64, width: u32, height: u32) -> Self {
        let range = |axis: usize, size: u32| {
            let (lo, hi) = points
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| (lo.min(p[axis]), hi.max(p[axis])));
            if !(lo.is_finite() && hi.is_finite() && margin.is_finite()) {
                return 0..0;
            }
            // the integer pixels in [lo - margin, hi + margin], clipped to the image
            let size = f64::from(size);
            let start = (lo - margin).ceil().clamp(0.0, size);
            let end = ((hi + margin).floor() + 1.0).clamp(start, size);
            start as u32..end as u32
        };
        Self { u: range(0, width), v: range(1, height) }
    }
}

/// The camera-frame points of the depth pixels in `rect` inside `[depth_min_m, depth_max_m]`, row
/// by row: the points [`depth_to_cloud`] gives for those pixels, their rays computed here (no
/// table: for a small part of the image).
pub fn depth_points_in(depth: &DepthImage, camera: &DepthCamera, rect: &PixelRect) -> Vec<Point3<f32>> {
    let width = depth.width as usize;
    let mut points = Vec::new();
    for v in rect.v.clone() {
        for u in rect.u.clone() {
            let Some(z) = depth.data.get(v as usize * width + u as usize).and_then(|&raw| camera.depth_m(raw)) else {
                continue;
            };
            let ray = camera.intrinsics.ray_f32(u, v);
            points.push(Point3::new(ray[0] * z, ray[1] * z, z));
        }
    }
    points
}

/// Back-projects every depth pixel inside `[depth_min_m, depth_max_m]` into the camera frame, with
/// the registered color attached when given. Zero depth means no return and is skipped.
///
/// `rays` is `camera.intrinsics.ray_table()`, passed in so many views share one table.
pub fn depth_to_cloud(
    depth: &DepthImage,
    color: Option<&ColorImage>,
    camera: &DepthCamera,
    rays: &[[f32; 2]],
) -> PointCloud {
    depth_to_cloud_with_pixels(depth, color, camera, rays).0
}

/// Like [`depth_to_cloud`], also returning the pixel (`v * width + u`) of every point.
pub fn depth_to_cloud_with_pixels(
    depth: &DepthImage,
    color: Option<&ColorImage>,
    camera: &DepthCamera,
    rays: &[[f32; 2]],
) -> (PointCloud, Vec<u32>) {
    depth_to_cloud_every_nth(depth, color, camera, rays, 1)
}

/// The `(width, height)` of the grid of every `step`-th row and column (from the first) of a
/// `width` x `height` image: the grid [`depth_to_cloud_every_nth`] numbers its pixels on. `step` 0
/// is taken as 1.
pub fn every_nth_grid(width: usize, height: usize, step: usize) -> (usize, usize) {
    let step = step.max(1);
    (width.div_ceil(step), height.div_ceil(step))
}

/// Like [`depth_to_cloud_with_pixels`] on the pixels of every `step`-th row and column only (from
/// the first), each point's pixel numbered on that coarser grid ([`every_nth_grid`]); `rays` is
/// `camera.intrinsics.ray_table_every_nth(step)`, on that grid too. `step` 0 is taken as 1.
pub fn depth_to_cloud_every_nth(
    depth: &DepthImage,
    color: Option<&ColorImage>,
    camera: &DepthCamera,
    rays: &[[f32; 2]],
    step: usize,
) -> (PointCloud, Vec<u32>) {
    let step = step.max(1);
    let (width, height) = (depth.width as usize, depth.height as usize);
    let (coarse_width, coarse_height) = every_nth_grid(width, height, step);
    let capacity = coarse_width * coarse_height;
    let (mut points, mut pixels) = (Vec::with_capacity(capacity), Vec::with_capacity(capacity));
    let mut colors = color.map(|_| Vec::with_capacity(capacity));
    for v in (0..height).step_by(step) {
        for u in (0..width).step_by(step) {
            let (i, coarse) = (v * width + u, (v / step) * coarse_width + u / step);
            let (Some(&raw), Some(ray)) = (depth.data.get(i), rays.get(coarse)) else { continue };
            let Some(z) = camera.depth_m(raw) else { continue };
            points.push(Point3::new(ray[0] * z, ray[1] * z, z));
            pixels.push(coarse as u32);
            if let (Some(colors), Some(image)) = (colors.as_mut(), color) {
                colors.push(image.data.get(i).copied().unwrap_or_default());
            }
        }
    }
    (PointCloud { points, normals: None, colors }, pixels)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn d435(distortion: [f64; 5]) -> Intrinsics {
        Intrinsics { width: 640, height: 480, fx: 615.0, fy: 615.5, cx: 320.5, cy: 239.5, distortion }
    }

    proptest! {
        #[test]
        fn project_back_project_round_trip(u in 0.0f64..640.0, v in 0.0f64..480.0, z in 0.2f64..3.0,
                                           k1 in -0.1f64..0.1, k2 in -0.05f64..0.05, p1 in -0.002f64..0.002,
                                           p2 in -0.002f64..0.002, k3 in -0.01f64..0.01) {
            for cam in [d435([0.0; 5]), d435([k1, k2, p1, p2, k3])] {
                let px = Point2::new(u, v);
                let p = cam.back_project(&px, z);
                prop_assert!((p.z - z).abs() < 1e-12);
                let back = cam.project(&p).expect("in front");
                prop_assert!((back - px).norm() < 1e-6, "{:?} -> {:?}", px, back);
            }
        }
    }

    #[test]
    fn pixel_centre_convention() {
        let cam = d435([0.0; 5]);
        let p = cam.back_project(&Point2::new(320.5, 239.5), 1.0);
        assert!(p.x.abs() < 1e-15 && p.y.abs() < 1e-15, "principal point looks along z");
        let p = cam.back_project(&Point2::new(320.5 + 615.0, 239.5), 2.0);
        assert!((p.x - 2.0).abs() < 1e-12, "one focal length right is 45 degrees");
    }

    #[test]
    fn depth_to_cloud_crops_and_scales() {
        let cam = DepthCamera { intrinsics: d435([0.0; 5]), depth_scale: 0.001, depth_min_m: 0.2, depth_max_m: 3.0 };
        let mut data = vec![0u16; 640 * 480];
        data[0] = 100; // 0.1 m: cropped
        data[1] = 1000; // 1 m: kept
        data[2] = 3500; // 3.5 m: cropped
        let depth = DepthImage { width: 640, height: 480, data };
        let cloud = depth_to_cloud(&depth, None, &cam, &cam.intrinsics.ray_table());
        assert_eq!(cloud.len(), 1);
        let p = cloud.points[0];
        assert!((p.z - 1.0).abs() < 1e-6);
        assert!((f64::from(p.x) - (1.0 - 320.5) / 615.0).abs() < 1e-6);
    }

    #[test]
    fn every_nth_pixel_keeps_the_pixels_of_every_nth_row_and_column_on_the_coarser_grid() {
        // a 5 x 3 image with depth on every pixel but (1, 0) and (4, 2)
        let intrinsics = Intrinsics { width: 5, height: 3, ..d435([0.0; 5]) };
        let cam = DepthCamera { intrinsics, depth_scale: 0.001, depth_min_m: 0.2, depth_max_m: 3.0 };
        let data: Vec<u16> = (0..15).map(|p| if p == 1 || p == 14 { 0 } else { 1000 + p }).collect();
        let depth = DepthImage { width: 5, height: 3, data };
        let color = ColorImage { width: 5, height: 3, data: (0..15).map(|p| [p, 0, 0]).collect() };
        let (rays, coarse_rays) = (intrinsics.ray_table(), intrinsics.ray_table_every_nth(2));
        assert_eq!(coarse_rays, [0, 2, 4, 10, 12, 14].map(|i| rays[i]));
        let (cloud, coarse) = depth_to_cloud_every_nth(&depth, Some(&color), &cam, &coarse_rays, 2);
        // (u, v) in {0, 2, 4} x {0, 2}: pixels 0, 2, 4, 10, 12 (14 has no depth), on a 3-wide grid
        let depth_mm: Vec<u16> = cloud.points.iter().map(|p| (p.z * 1000.0).round() as u16).collect();
        assert_eq!(depth_mm, vec![1000, 1002, 1004, 1010, 1012]);
        assert_eq!(cloud.colors.expect("colors").iter().map(|c| c[0]).collect::<Vec<_>>(), vec![0, 2, 4, 10, 12]);
        assert_eq!(coarse, vec![0, 1, 2, 3, 4]);
        // step 1 is the full back-projection
        let (all, pixels) = depth_to_cloud_every_nth(&depth, None, &cam, &rays, 1);
        let (full, full_pixels) = depth_to_cloud_with_pixels(&depth, None, &cam, &rays);
        assert_eq!(full.len(), 13);
        assert_eq!((all.points, pixels), (full.points, full_pixels));
    }

    #[test]
    fn a_pixel_rectangle_back_projects_as_the_whole_image_does_there() {
        let intrinsics = d435([0.08, -0.03, 0.001, -0.0015, 0.005]);
        let cam = DepthCamera { intrinsics, depth_scale: 0.001, depth_min_m: 0.2, depth_max_m: 3.0 };
        let data: Vec<u16> = (0..640 * 480).map(|p| if p % 7 == 0 { 0 } else { 500 + (p % 1999) as u16 }).collect();
        let depth = DepthImage { width: 640, height: 480, data };
        let (all, pixels) = depth_to_cloud_with_pixels(&depth, None, &cam, &intrinsics.ray_table());
        // corners near the image's corner: the rectangle is clipped there
        let rect = PixelRect::around(&[[3.2, 470.4], [30.0, 478.9], [10.5, 455.0]], 2.0, 640, 480);
        assert_eq!(rect, PixelRect { u: 2..33, v: 453..480 });
        let want: Vec<Point3<f32>> = pixels
            .iter()
            .zip(&all.points)
            .filter(|&(&i, _)| rect.u.contains(&(i % 640)) && rect.v.contains(&(i / 640)))
            .map(|(_, p)| *p)
            .collect();
        assert!(want.len() > 600, "{}", want.len());
        assert_eq!(depth_points_in(&depth, &cam, &rect), want);
        assert!(PixelRect::around(&[], 2.0, 640, 480).u.is_empty());
        assert!(PixelRect::around(&[[f64::NAN, 1.0]], 2.0, 640, 480).u.is_empty());
        let outside = PixelRect::around(&[[700.0, -50.0]], 2.0, 640, 480);
        assert!(outside.u.is_empty() && outside.v.is_empty(), "{outside:?}");
    }
}
