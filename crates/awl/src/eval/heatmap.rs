//! Distance heatmaps: the turbo colormap and the bytes of `errors.ply` (no file access here).

use nalgebra::Point3;

use crate::error::{Error, Result};

/// Name of the colormap used by [`turbo`].
pub const COLORMAP: &str = "turbo";

/// Google's turbo colormap (the published polynomial approximation, Mikhailov 2019) at `x` in
/// [0, 1] (clamped): dark blue at 0, green near 0.5, dark red at 1.
pub fn turbo(x: f64) -> [u8; 3] {
    let x = if x.is_finite() { x.clamp(0.0, 1.0) } else { 1.0 };
    let v = [1.0, x, x * x, x * x * x, x.powi(4), x.powi(5)];
    let red = [0.135_721_38, 4.615_392_60, -42.660_322_58, 132.131_082_34, -152.942_393_96, 59.286_379_43];
    let green = [0.091_402_61, 2.194_188_39, 4.842_966_58, -14.185_033_33, 4.277_298_57, 2.829_566_04];
    let blue = [0.106_673_30, 12.641_946_08, -60.582_048_36, 110.362_767_71, -89.903_109_12, 27.348_249_73];
    let channel = |k: &[f64; 6]| {
        let c: f64 = k.iter().zip(&v).map(|(a, b)| a * b).sum();
        (c.clamp(0.0, 1.0) * 255.0).round() as u8
    };
    [channel(&red), channel(&green), channel(&blue)]
}

/// Binary little-endian PLY of `points_object` colored by `distances_m` (turbo, 0 .. `max_m`
/// clamped), with a float property `distance` (metres to the CAD surface).
///
/// # Errors
/// [`Error::Invalid`] when the lengths differ or `max_m` is not a positive distance.
pub fn errors_ply(points_object: &[Point3<f32>], distances_m: &[f64], max_m: f64) -> Result<Vec<u8>> {
    if points_object.len() != distances_m.len() {
        return Err(Error::invalid(
            "errors.ply",
            format!("{} points but {} distances", points_object.len(), distances_m.len()),
        ));
    }
    if !(max_m.is_finite() && max_m > 0.0) {
        return Err(Error::invalid("heatmap max", format!("{max_m} is not a positive distance")));
    }
    let head = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by awl evaluate: model points in the CAD (object) frame\n\
         comment color: {COLORMAP} colormap of the distance to the CAD surface, 0 to {:.3} mm, clamped\n\
         comment distance: metres to the CAD surface\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\nproperty float distance\nend_header\n",
        max_m * 1e3,
        points_object.len()
    );
    let mut out = head.into_bytes();
    out.reserve(points_object.len() * 19);
    for (p, &d) in points_object.iter().zip(distances_m) {
        for c in [p.x, p.y, p.z] {
            out.extend_from_slice(&c.to_le_bytes());
        }
        out.extend_from_slice(&turbo(d / max_m));
        out.extend_from_slice(&(d as f32).to_le_bytes());
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn turbo_runs_blue_green_red() {
        assert!(turbo(0.0).iter().all(|&c| c < 60), "dark at 0: {:?}", turbo(0.0));
        let [r, g, b] = turbo(0.15);
        assert!(b > 200 && b > r && b > g, "{:?}", turbo(0.15));
        let [r, g, b] = turbo(0.5);
        assert!(g > 200 && g > r && g > b, "{:?}", turbo(0.5));
        let [r, g, b] = turbo(1.0);
        assert!(r > 100 && g < 20 && b < 20, "{:?}", turbo(1.0));
        assert_eq!(turbo(2.0), turbo(1.0));
        assert_eq!(turbo(-1.0), turbo(0.0));
    }

    #[test]
    fn errors_ply_reads_back() {
        let pts = vec![Point3::new(0.0f32, 1.0, 2.0), Point3::new(3.0, 4.0, 5.0)];
        let bytes = errors_ply(&pts, &[0.0, 0.01], 0.005).expect("ply");
        let cloud = crate::io::ply::parse_ply(std::path::Path::new("errors.ply"), &bytes).expect("parse");
        assert_eq!(cloud.points, pts);
        assert_eq!(cloud.colors, Some(vec![turbo(0.0), turbo(1.0)]));
        let tail = &bytes[bytes.len() - 4..];
        assert_eq!(f32::from_le_bytes([tail[0], tail[1], tail[2], tail[3]]), 0.01);
        assert!(errors_ply(&pts, &[0.0], 0.005).is_err());
    }
}
