//! The depth noise model of a RealSense-like stereo camera, scaled by the noise level:
//! axial noise `sigma(z) = 1.2 mm + 1.9 mm (z - 0.4 m)^2` grown by `1 / cos(incidence)` (capped at 3),
//! about 0.5 px of lateral jitter, stereo shadows (points the right imager cannot see), dropouts at
//! grazing incidence, 1 % random holes, flying pixels mixing foreground and background at depth
//! edges, 0.02 % outliers, a 0.1 % global depth-scale error, and 1 mm quantisation.

use rand::RngExt;
use rand_chacha::ChaCha8Rng;

use crate::camera::DepthCamera;
use crate::random::{Stream, normal, rng, uniform};

/// The model's axial depth noise (one sigma, metres) at depth `z_m` and incidence cosine
/// `cos_incidence`, for a noise level of scale `level_scale` (none 0, low 0.5, realistic 1, harsh 2).
pub fn axial_sigma_m(z_m: f64, cos_incidence: f64, level_scale: f64) -> f64 {
    let base = 0.0012 + 0.0019 * (z_m - 0.4).powi(2);
    let incidence = (1.0 / cos_incidence.abs().max(1e-9)).min(3.0);
    level_scale * base * incidence
}

/// Distance between the depth (left) imager and the right imager, metres.
pub(crate) const BASELINE_M: f64 = 0.05;

/// Scan-wide depth noise settings.
#[derive(Debug, Clone, Copy)]
pub(crate) struct DepthNoise {
    /// Noise level scale.
    pub scale: f64,
    /// Relative global depth-scale error (recorded depth = true depth * (1 + error)).
    pub scale_error: f64,
}

impl DepthNoise {
    /// The settings of a scan; the scale error is drawn once per seed.
    pub(crate) fn new(seed: u64, scale: f64) -> Self {
        let mut rng = rng(seed, Stream::DepthGlobal, 0, 0);
        Self { scale, scale_error: normal(&mut rng) * 0.001 * scale }
    }

    fn grazing_cos(&self) -> f64 {
        (90.0 - 12.0 * self.scale).max(45.0).to_radians().cos()
    }
}

/// The noiseless render of one view, row-major: depth, label and incidence cosine.
pub(crate) struct CleanView<'a> {
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// Depth along the optical axis, metres, 0 = no return.
    pub z: &'a [f64],
    /// Label of the surface hit.
    pub label: &'a [u8],
    /// |cos| of the incidence angle.
    pub cos: &'a [f64],
}

impl CleanView<'_> {
    fn at(&self, u: i64, v: i64) -> Option<(f64, u8)> {
        if u < 0 || v < 0 || u >= self.width as i64 || v >= self.height as i64 {
            return None;
        }
        let i = v as usize * self.width + u as usize;
        (self.z[i] > 0.0).then(|| (self.z[i], self.label[i]))
    }

    /// Depth sampled at a fractional pixel: bilinear on a smooth patch of one surface, else the
    /// nearest pixel with a return, else `fallback`.
    fn sample(&self, u: f64, v: f64, fallback: f64) -> f64 {
        let (u0, v0) = (u.floor() as i64, v.floor() as i64);
        let corners = [self.at(u0, v0), self.at(u0 + 1, v0), self.at(u0, v0 + 1), self.at(u0 + 1, v0 + 1)];
        if let [Some(a), Some(b), Some(c), Some(d)] = corners {
            let (lo, hi) = [a.0, b.0, c.0, d.0].iter().fold((f64::MAX, f64::MIN), |(l, h), &z| (l.min(z), h.max(z)));
            if a.1 == b.1 && a.1 == c.1 && a.1 == d.1 && hi - lo < 0.02 * lo {
                let (fu, fv) = (u - u0 as f64, v - v0 as f64);
                return (a.0 * (1.0 - fu) + b.0 * fu) * (1.0 - fv) + (c.0 * (1.0 - fu) + d.0 * fu) * fv;
            }
        }
        self.at(u.round() as i64, v.round() as i64).map_or(fallback, |(z, _)| z)
    }

    /// The 4-neighbour depth differing most from `z`, when it differs by a depth edge (> 3 cm + 2 %).
    fn edge_neighbour(&self, u: i64, v: i64, z: f64) -> Option<f64> {
        [(u - 1, v), (u + 1, v), (u, v - 1), (u, v + 1)]
            .iter()
            .filter_map(|&(a, b)| self.at(a, b).map(|(zn, _)| zn))
            .filter(|zn| (zn - z).abs() > 0.03 + 0.02 * z)
            .max_by(|a, b| (a - z).abs().total_cmp(&(b - z).abs()))
    }
}

/// What one noisy row needs besides its RNG.
pub(crate) struct RowContext<'a> {
    /// The noiseless render.
    pub clean: &'a CleanView<'a>,
    /// The camera (focal length, depth range and scale).
    pub camera: &'a DepthCamera,
    /// Noise settings.
    pub noise: DepthNoise,
}

/// Stereo shadows of row `v`: pixels the right imager (at `+BASELINE_M` along x, rectified) cannot
/// see because a nearer surface to their right in the image covers them in the right image.
/// A pixel at column `u` and depth `z` lands at column `u - fx * b / z` of the right image; it is
/// hidden when some pixel further right lands at or left of it.
fn stereo_shadows(clean: &CleanView<'_>, fx: f64, v: usize) -> Vec<bool> {
    let w = clean.width;
    let mut shadow = vec![false; w];
    let mut min_right = f64::INFINITY;
    for u in (0..w).rev() {
        let z = clean.z[v * w + u];
        if z <= 0.0 {
            continue;
        }
        let x_right = u as f64 - fx * BASELINE_M / z;
        shadow[u] = min_right < x_right - 0.25;
        min_right = min_right.min(x_right);
    }
    shadow
}

/// The noisy depth (metres, 0 = dropped) of pixel `(u, v)` with a clean return.
fn noisy_depth(ctx: &RowContext<'_>, rng: &mut ChaCha8Rng, (u, v, i): (usize, usize, usize), shadow: bool) -> f64 {
    let (clean, noise) = (ctx.clean, ctx.noise);
    let (z, cos) = (clean.z[i], clean.cos[i]);
    let s = noise.scale;
    if s <= 0.0 {
        return z;
    }
    let dropped = shadow || cos < noise.grazing_cos() || rng.random_bool((0.01 * s).min(1.0));
    if dropped {
        return 0.0;
    }
    let (du, dv) = (normal(rng) * 0.5 * s, normal(rng) * 0.5 * s);
    let mut depth = clean.sample(u as f64 + du, v as f64 + dv, z);
    if let Some(other) = clean.edge_neighbour(u as i64, v as i64, z)
        && rng.random_bool((0.3 * s).min(0.6))
    {
        let alpha = uniform(rng, 0.15, 0.85);
        depth = alpha * depth + (1.0 - alpha) * other;
    }
    depth += normal(rng) * axial_sigma_m(depth, cos, s);
    depth *= 1.0 + noise.scale_error;
    if rng.random_bool((0.0002 * s).min(1.0)) {
        depth = uniform(rng, 0.3, 3.0);
    }
    depth
}

/// Depth (raw units) and label of row `v`.
pub(crate) fn noisy_row(ctx: &RowContext<'_>, rng: &mut ChaCha8Rng, v: usize) -> (Vec<u16>, Vec<u8>) {
    let width = ctx.clean.width;
    let mut depth = vec![0u16; width];
    let mut labels = vec![0u8; width];
    let shadows =
        if ctx.noise.scale > 0.0 { stereo_shadows(ctx.clean, ctx.camera.intrinsics.fx, v) } else { vec![false; width] };
    for u in 0..width {
        let i = v * width + u;
        if ctx.clean.z[i] <= 0.0 {
            continue;
        }
        let z = noisy_depth(ctx, rng, (u, v, i), shadows[u]);
        if z < ctx.camera.depth_min_m || z > ctx.camera.depth_max_m {
            continue;
        }
        let raw = (z / ctx.camera.depth_scale).round();
        if raw >= 1.0 && raw <= f64::from(u16::MAX) {
            depth[u] = raw as u16;
            labels[u] = ctx.clean.label[i];
        }
    }
    (depth, labels)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axial_sigma_follows_the_model() {
        assert!((axial_sigma_m(0.4, 1.0, 1.0) - 0.0012).abs() < 1e-15);
        assert!((axial_sigma_m(1.4, 1.0, 1.0) - 0.0031).abs() < 1e-15);
        assert!((axial_sigma_m(1.4, 0.5, 2.0) - 4.0 * 0.0031).abs() < 1e-15);
        assert!((axial_sigma_m(1.0, 0.01, 1.0) / axial_sigma_m(1.0, 1.0, 1.0) - 3.0).abs() < 1e-12);
        assert_eq!(axial_sigma_m(2.0, 1.0, 0.0), 0.0);
    }
}
