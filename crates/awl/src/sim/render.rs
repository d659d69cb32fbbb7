//! Ray casting one view: a noiseless pass (one ray per pixel centre), then the noisy depth and label
//! images, then the color image (3x3 supersampled at edges and on the tag). Rows run in parallel,
//! each with its own random stream, so the output does not depend on the thread count.

use nalgebra::{Isometry3, Point2, Point3, Vector3};
use rayon::prelude::*;

use crate::camera::DepthCamera;
use crate::image::{ColorImage, DepthImage};
use crate::random::{Stream, normal, rng};
use crate::sim::LabelImage;
use crate::sim::noise::{CleanView, DepthNoise, RowContext, noisy_row};
use crate::sim::shade::{Gamma, Lighting, radiance};
use crate::sim::world::{Hit, World};

/// Rays farther than this see nothing (color background), metres.
const FAR_M: f64 = 40.0;
/// Supersampling factor per axis for edge and tag pixels.
const SUPERSAMPLE: usize = 3;

/// Everything a view's rendering needs besides its pose.
pub(crate) struct Renderer<'a> {
    /// The scene.
    pub world: &'a World,
    /// The camera.
    pub camera: &'a DepthCamera,
    /// Depth noise settings.
    pub noise: DepthNoise,
    /// Color sensor noise, one sigma in 8-bit levels.
    pub color_sigma: f64,
    /// The scan's seed.
    pub seed: u64,
}

/// The three images of one view.
pub(crate) struct ViewImages {
    /// Depth, raw units.
    pub depth: DepthImage,
    /// Color.
    pub color: ColorImage,
    /// Labels.
    pub labels: LabelImage,
}

struct Frame {
    origin: Point3<f64>,
    pose: Isometry3<f64>,
}

impl Frame {
    /// World direction of the ray through pixel `(u, v)`, scaled so its camera-frame z is 1.
    fn dir(&self, camera: &DepthCamera, u: f64, v: f64) -> Vector3<f64> {
        let n = camera.intrinsics.ray(&Point2::new(u, v));
        self.pose.rotation * Vector3::new(n.x, n.y, 1.0)
    }
}

fn rows<T: Send>(height: usize, f: impl Fn(usize) -> Vec<T> + Sync + Send) -> Vec<T> {
    (0..height).into_par_iter().map(f).collect::<Vec<Vec<T>>>().into_iter().flatten().collect()
}

impl Renderer<'_> {
    /// Renders view `index` from the true pose `world_from_camera`.
    pub(crate) fn render(&self, index: usize, world_from_camera: &Isometry3<f64>) -> ViewImages {
        let (w, h) = (self.camera.intrinsics.width as usize, self.camera.intrinsics.height as usize);
        let frame = Frame { origin: Point3::from(world_from_camera.translation.vector), pose: *world_from_camera };
        let hits: Vec<Option<Hit>> = rows(h, |v| {
            (0..w).map(|u| self.world.cast(&frame.origin, &frame.dir(self.camera, u as f64, v as f64), FAR_M)).collect()
        });
        let max_z = self.camera.depth_max_m * 1.05;
        let mut z = vec![0.0; w * h];
        let mut label = vec![0u8; w * h];
        let mut cos = vec![0.0; w * h];
        for (i, hit) in hits.iter().enumerate() {
            if let Some(hit) = hit.as_ref().filter(|hit| hit.t <= max_z) {
                let dir = frame.dir(self.camera, (i % w) as f64, (i / w) as f64);
                z[i] = hit.t;
                label[i] = self.world.material(hit.triangle).label;
                cos[i] = self.world.face_normal(hit.triangle).dot(&dir).abs() / dir.norm();
            }
        }
        let clean = CleanView { width: w, height: h, z: &z, label: &label, cos: &cos };
        let ctx = RowContext { clean: &clean, camera: self.camera, noise: self.noise };
        let noisy: Vec<(u16, u8)> = rows(h, |v| {
            let mut rng = rng(self.seed, Stream::DepthRow, index as u64, v as u64);
            let (d, l) = noisy_row(&ctx, &mut rng, v);
            d.into_iter().zip(l).collect()
        });
        let color = self.color(index, &frame, &hits, &z);
        let (width, height) = (w as u32, h as u32);
        ViewImages {
            depth: DepthImage { width, height, data: noisy.iter().map(|p| p.0).collect() },
            color: ColorImage { width, height, data: color },
            labels: LabelImage { width, height, data: noisy.iter().map(|p| p.1).collect() },
        }
    }

    /// Whether pixel `i` lies on an edge (different material or a depth jump beside it) or on the tag.
    fn needs_supersampling(&self, hits: &[Option<Hit>], w: usize, i: usize) -> bool {
        let (u, v, h) = (i % w, i / w, hits.len() / w);
        let key = |hit: &Option<Hit>| hit.as_ref().map(|x| (self.world.material(x.triangle).label, x.t));
        let me = key(&hits[i]);
        if let (Some(tag), Some(hit)) = (self.world.tag.as_ref(), hits[i].as_ref())
            && tag.near(&hit.point)
        {
            return true;
        }
        let neighbours =
            [(u > 0).then(|| i - 1), (u + 1 < w).then(|| i + 1), (v > 0).then(|| i - w), (v + 1 < h).then(|| i + w)];
        neighbours.into_iter().flatten().any(|j| match (me, key(&hits[j])) {
            (Some((la, ta)), Some((lb, tb))) => la != lb || (ta - tb).abs() > 0.03 + 0.05 * ta,
            (None, None) => false,
            _ => true,
        })
    }

    fn color(&self, index: usize, frame: &Frame, hits: &[Option<Hit>], z: &[f64]) -> Vec<[u8; 3]> {
        let w = self.camera.intrinsics.width as usize;
        let h = self.camera.intrinsics.height as usize;
        let centre = z.get((h / 2) * w + w / 2).copied().filter(|&c| c > 0.0).unwrap_or(1.0);
        let lighting =
            Lighting { light: frame.pose * Point3::new(0.0, -0.1, 0.0), exposure_distance: centre.clamp(0.5, 2.0) };
        let gamma = Gamma::new();
        rows(h, |v| {
            let mut rng = rng(self.seed, Stream::ColorRow, index as u64, v as u64);
            (0..w)
                .map(|u| {
                    let i = v * w + u;
                    let linear = if self.needs_supersampling(hits, w, i) {
                        self.supersample(frame, &lighting, u as f64, v as f64)
                    } else {
                        radiance(self.world, hits[i].as_ref(), &frame.dir(self.camera, u as f64, v as f64), &lighting)
                    };
                    linear
                        .map(|c| (gamma.srgb(c) + normal(&mut rng) * self.color_sigma).round().clamp(0.0, 255.0) as u8)
                })
                .collect()
        })
    }

    fn supersample(&self, frame: &Frame, lighting: &Lighting, u: f64, v: f64) -> [f64; 3] {
        let k = SUPERSAMPLE as f64;
        let mut sum = [0.0; 3];
        for a in 0..SUPERSAMPLE {
            for b in 0..SUPERSAMPLE {
                let su = u + (a as f64 + 0.5) / k - 0.5;
                let sv = v + (b as f64 + 0.5) / k - 0.5;
                let dir = frame.dir(self.camera, su, sv);
                let hit = self.world.cast(&frame.origin, &dir, FAR_M);
                let c = radiance(self.world, hit.as_ref(), &dir, lighting);
                for (s, c) in sum.iter_mut().zip(c) {
                    *s += c;
                }
            }
        }
        sum.map(|s| s / (k * k))
    }
}
