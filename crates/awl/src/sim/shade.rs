//! Color: albedo (plain, procedural floor, printed tag), Lambertian shading from a light beside the
//! camera plus room light, and the sRGB gamma.

use nalgebra::{Point3, Vector3};

use crate::random::hash4;
use crate::sim::world::{Hit, Texture, World};

/// sRGB value (0..255) of the tag's black modules before shading.
pub(crate) const TAG_BLACK: f64 = 30.0;
/// sRGB value (0..255) of the tag's white modules before shading.
pub(crate) const TAG_WHITE: f64 = 220.0;
/// Linear color of rays that hit nothing (far background).
const BACKGROUND: [f64; 3] = [0.045, 0.048, 0.058];

/// sRGB 0..255 -> linear 0..1.
pub(crate) fn to_linear(srgb: f64) -> f64 {
    (srgb / 255.0).clamp(0.0, 1.0).powf(2.2)
}

/// Linear 0..1 -> sRGB 0..255 (not rounded).
pub(crate) fn to_srgb(linear: f64) -> f64 {
    255.0 * linear.clamp(0.0, 1.0).powf(1.0 / 2.2)
}

fn lattice(ix: i64, iy: i64, key: u64) -> f64 {
    let mut x = key ^ (ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((x ^ (x >> 31)) >> 11) as f64 / (1u64 << 53) as f64
}

/// Smooth value noise in [0, 1] with cells of `cell` metres.
fn value_noise(x: f64, y: f64, cell: f64, octave: u64, seed: u64) -> f64 {
    let key = hash4(seed, octave, 0, 0);
    let (fx, fy) = (x / cell, y / cell);
    let (ix, iy) = (fx.floor() as i64, fy.floor() as i64);
    let smooth = |t: f64| t * t * (3.0 - 2.0 * t);
    let (sx, sy) = (smooth(fx - fx.floor()), smooth(fy - fy.floor()));
    let a = lattice(ix, iy, key) * (1.0 - sx) + lattice(ix + 1, iy, key) * sx;
    let b = lattice(ix, iy + 1, key) * (1.0 - sx) + lattice(ix + 1, iy + 1, key) * sx;
    a * (1.0 - sy) + b * sy
}

/// Albedo multiplier (in sRGB terms) of the concrete-like floor at a world point, about 0.6 to 1.35.
fn floor_pattern(p: &Point3<f64>, seed: u64) -> f64 {
    let n = 0.5 * value_noise(p.x, p.y, 0.35, 0, seed)
        + 0.3 * value_noise(p.x, p.y, 0.09, 1, seed)
        + 0.2 * value_noise(p.x, p.y, 0.022, 2, seed);
    0.6 + 0.75 * n
}

/// Lighting of one view: a light 10 cm above the camera and the distance the exposure is set for.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Lighting {
    /// Light position, world frame.
    pub light: Point3<f64>,
    /// Distance at which the camera light gives full brightness, metres.
    pub exposure_distance: f64,
}

/// Linear RGB of the ray `dir` (unit or not) hitting `hit` (or nothing).
pub(crate) fn radiance(world: &World, hit: Option<&Hit>, dir: &Vector3<f64>, lighting: &Lighting) -> [f64; 3] {
    let Some(hit) = hit else { return BACKGROUND };
    let material = world.material(hit.triangle);
    let albedo = world.linear_albedo(hit.triangle);
    let linear = match material.texture {
        Texture::Plain => albedo,
        Texture::Floor => {
            let k = floor_pattern(&hit.point, world.texture_seed);
            albedo.map(|c| c * k * k * k.sqrt())
        }
        Texture::Tagged => match world.tag.as_ref().and_then(|t| t.black_at(&hit.point)) {
            Some(true) => [to_linear(TAG_BLACK); 3],
            Some(false) => [to_linear(TAG_WHITE); 3],
            None => albedo,
        },
    };
    let mut n = world.shading_normal(hit);
    if n.dot(dir) > 0.0 {
        n = -n;
    }
    let to_light = lighting.light - hit.point;
    let distance = to_light.norm().max(1e-6);
    let falloff = (lighting.exposure_distance / distance).powi(2).min(1.6);
    let lambert = n.dot(&to_light).max(0.0) / distance;
    let shade = 0.22 + 0.25 * n.z.max(0.0) + 0.7 * lambert * falloff;
    linear.map(|c| c * shade)
}

/// A lookup table for [`to_srgb`], indexed by the square root of the linear value.
pub(crate) struct Gamma {
    table: Vec<f32>,
}

impl Gamma {
    const SIZE: usize = 1 << 14;

    /// Builds the table.
    pub(crate) fn new() -> Self {
        let n = (Self::SIZE - 1) as f64;
        Self { table: (0..Self::SIZE).map(|i| to_srgb((i as f64 / n).powi(2)) as f32).collect() }
    }

    /// sRGB 0..255 of a linear value (within 0.02 levels of [`to_srgb`]).
    pub(crate) fn srgb(&self, linear: f64) -> f64 {
        let x = linear.clamp(0.0, 1.0).sqrt() * (Self::SIZE - 1) as f64;
        let i = (x as usize).min(Self::SIZE - 2);
        let f = x - i as f64;
        f64::from(self.table[i]) * (1.0 - f) + f64::from(self.table[i + 1]) * f
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gamma_round_trips_and_floor_varies() {
        let gamma = Gamma::new();
        for v in [0.0, 1.0, 30.0, 128.0, 220.0, 255.0] {
            assert!((to_srgb(to_linear(v)) - v).abs() < 1e-9);
            assert!((gamma.srgb(to_linear(v)) - v).abs() < 0.02, "{v}: {}", gamma.srgb(to_linear(v)));
        }
        let values: Vec<f64> =
            (0..200).map(|i| floor_pattern(&Point3::new(f64::from(i) * 0.013, 0.3, 0.0), 7)).collect();
        let (lo, hi) = values.iter().fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        assert!(lo >= 0.6 && hi <= 1.35 && hi - lo > 0.1, "{lo} {hi}");
    }
}
