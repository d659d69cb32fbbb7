//! Color: albedo (plain, procedural floor, printed tag), Lambertian shading from a light beside the
//! camera plus room light, and the sRGB gamma.

use nalgebra::{Point3, Vector3};

use crate::sim::random::hash4;
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

fn lattice(ix: i64, iy: i64, octave: u64, seed: u64) -> f64 {
    (hash4(seed, octave, ix as u64, iy as u64) >> 11) as f64 / (1u64 << 53) as f64
}

/// Smooth value noise in [0, 1] with cells of `cell` metres.
fn value_noise(x: f64, y: f64, cell: f64, octave: u64, seed: u64) -> f64 {
    let (fx, fy) = (x / cell, y / cell);
    let (ix, iy) = (fx.floor() as i64, fy.floor() as i64);
    let smooth = |t: f64| t * t * (3.0 - 2.0 * t);
    let (sx, sy) = (smooth(fx - fx.floor()), smooth(fy - fy.floor()));
    let a = lattice(ix, iy, octave, seed) * (1.0 - sx) + lattice(ix + 1, iy, octave, seed) * sx;
    let b = lattice(ix, iy + 1, octave, seed) * (1.0 - sx) + lattice(ix + 1, iy + 1, octave, seed) * sx;
    a * (1.0 - sy) + b * sy
}

/// Albedo multiplier of the concrete-like floor at a world point, about 0.6 to 1.35.
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
    let srgb = match material.texture {
        Texture::Plain => material.albedo,
        Texture::Floor => material.albedo.map(|c| c * floor_pattern(&hit.point, world.texture_seed)),
        Texture::Tagged => match world.tag.as_ref().and_then(|t| t.black_at(&hit.point)) {
            Some(true) => [TAG_BLACK; 3],
            Some(false) => [TAG_WHITE; 3],
            None => material.albedo,
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
    srgb.map(|c| to_linear(c) * shade)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gamma_round_trips_and_floor_varies() {
        for v in [0.0, 30.0, 128.0, 220.0, 255.0] {
            assert!((to_srgb(to_linear(v)) - v).abs() < 1e-9);
        }
        let values: Vec<f64> = (0..200).map(|i| floor_pattern(&Point3::new(f64::from(i) * 0.013, 0.3, 0.0), 7)).collect();
        let (lo, hi) = values.iter().fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        assert!(lo >= 0.6 && hi <= 1.35 && hi - lo > 0.1, "{lo} {hi}");
    }
}
