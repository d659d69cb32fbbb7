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
        let mut table = Vec::with_capacity(self.width as usize * self.height as usize);
        for v in 0..self.height {
            for u in 0..self.width {
                let n = self.ray(&Point2::new(f64::from(u), f64::from(v)));
                table.push([n.x as f32, n.y as f32]);
            }
        }
        table
    }
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
/// the first), each point's pixel numbered on that coarser grid ([`every_nth_grid`]). `step` 0 is
/// taken as 1.
pub fn depth_to_cloud_every_nth(
    depth: &DepthImage,
    color: Option<&ColorImage>,
    camera: &DepthCamera,
    rays: &[[f32; 2]],
    step: usize,
) -> (PointCloud, Vec<u32>) {
    let step = step.max(1);
    let (width, height) = (depth.width as usize, depth.height as usize);
    let (coarse_width, _) = every_nth_grid(width, height, step);
    let (mut points, mut pixels) = (Vec::new(), Vec::new());
    let mut colors = color.map(|_| Vec::new());
    for v in (0..height).step_by(step) {
        for u in (0..width).step_by(step) {
            let i = v * width + u;
            let (Some(&raw), Some(ray)) = (depth.data.get(i), rays.get(i)) else { continue };
            if raw == 0 {
                continue;
            }
            let z = f64::from(raw) * camera.depth_scale;
            if z < camera.depth_min_m || z > camera.depth_max_m {
                continue;
            }
            let z = z as f32;
            points.push(Point3::new(ray[0] * z, ray[1] * z, z));
            pixels.push(((v / step) * coarse_width + u / step) as u32);
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
        let rays = intrinsics.ray_table();
        let (cloud, coarse) = depth_to_cloud_every_nth(&depth, Some(&color), &cam, &rays, 2);
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
}
