//! Unit normals in 32 bits instead of 96: octahedral coordinates (the normal over its L1 norm, the
//! lower half folded over the upper) in steps of 1/32767, within 0.005 deg. For normals held in
//! bulk: the merge's parts, the measured points of the views the registration holds.

use nalgebra::Vector3;

/// A unit normal in 32 bits: its octahedral coordinates (the normal over its L1 norm, the lower
/// half folded over the upper) in steps of 1/32767, within 0.005 deg of the normal; a normal
/// without a direction (zero, non-finite) packs to [`NO_NORMAL`].
pub type PackedNormal = [i16; 2];

/// The packed zero normal (no octahedral coordinate reaches -32768).
pub const NO_NORMAL: PackedNormal = [i16::MIN; 2];

fn sign(a: f32) -> f32 {
    if a < 0.0 { -1.0 } else { 1.0 }
}

/// The octahedral fold of the lower half (z < 0) onto the square's corners; its own inverse.
fn fold(u: f32, v: f32) -> (f32, f32) {
    ((1.0 - v.abs()) * sign(u), (1.0 - u.abs()) * sign(v))
}

/// `n` packed; [`NO_NORMAL`] for a zero or non-finite `n`.
#[must_use]
pub fn pack_normal(n: &Vector3<f32>) -> PackedNormal {
    let l1 = n.x.abs() + n.y.abs() + n.z.abs();
    if !(l1 > 0.0 && l1.is_finite()) {
        return NO_NORMAL;
    }
    let (u, v) = if n.z < 0.0 { fold(n.x / l1, n.y / l1) } else { (n.x / l1, n.y / l1) };
    let q = |a: f32| (a.clamp(-1.0, 1.0) * 32767.0).round() as i16;
    [q(u), q(v)]
}

/// The unit normal `p` stands for; zero for [`NO_NORMAL`].
#[must_use]
pub fn unpack_normal(p: PackedNormal) -> Vector3<f32> {
    if p == NO_NORMAL {
        return Vector3::zeros();
    }
    let (u, v) = (f32::from(p[0]) / 32767.0, f32::from(p[1]) / 32767.0);
    let z = 1.0 - u.abs() - v.abs();
    let (x, y) = if z < 0.0 { fold(u, v) } else { (u, v) };
    Vector3::new(x, y, z).normalize()
}

/// Packs each normal (see [`pack_normal`]).
#[must_use]
pub fn pack_all(normals: &[Vector3<f32>]) -> Vec<PackedNormal> {
    normals.iter().map(pack_normal).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    #[test]
    fn normals_pack_into_32_bits() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let mut normals: Vec<Vector3<f32>> = (0..200_000)
            .map(|_| Vector3::new(rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5))
            .filter(|n| n.norm() > 1e-3)
            .map(|n| n.normalize())
            .collect();
        for (x, y, z) in [(1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0)] {
            normals.push(Vector3::new(x, y, z));
        }
        normals.extend([Vector3::new(0.0, 0.0, -1.0), Vector3::new(0.6, 0.8, -0.0), Vector3::new(0.6, -0.8, -1e-7)]);
        let worst = normals
            .iter()
            .map(|n| {
                let back = unpack_normal(pack_normal(n));
                assert!((back.norm() - 1.0).abs() < 1e-6, "{n:?} -> {back:?}");
                back.cast::<f64>().angle(&n.cast()).to_degrees()
            })
            .fold(0.0, f64::max);
        assert!(worst < 0.005, "{worst} deg");
        for bad in [Vector3::zeros(), Vector3::new(f32::NAN, 0.0, 1.0), Vector3::new(f32::INFINITY, 0.0, 0.0)] {
            assert_eq!(unpack_normal(pack_normal(&bad)), Vector3::zeros());
        }
    }
}
