//! The point data of the page's interactive 3D view: a subsample of the cloud as little-endian
//! Float32 positions (metres, relative to the bounds' centre) and Uint8 RGB colors, embedded as
//! base64 and drawn by `viewer.js` (WebGL 1, no library).

use std::fmt::Write;

use super::base64;
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::render::colormap::Colormap;
use crate::render::plot::xml_escape;
use crate::render::shade::ScalarScale;

/// Default cap on the points embedded in a page (about 4 MB of base64).
pub const DEFAULT_MAX_POINTS: usize = 200_000;

/// The viewer's JavaScript (included in every page that has a cloud).
pub const VIEWER_JS: &str = include_str!("viewer.js");

/// Points for the interactive view.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewerCloud {
    /// x, y, z per point, metres, relative to `center_m`.
    pub positions: Vec<f32>,
    /// r, g, b per point.
    pub colors: Vec<u8>,
    /// Centre of the cloud's bounds, world frame, metres.
    pub center_m: [f64; 3],
    /// Largest distance of an embedded point from the centre, metres.
    pub radius_m: f32,
    /// Points of the full cloud (the embedded ones are a subsample when it is larger than the cap).
    pub total_points: usize,
}

/// `max` indices spread evenly over `0..n` (all of them when `n <= max`).
fn subsample(n: usize, max: usize) -> Vec<usize> {
    if n <= max {
        return (0..n).collect();
    }
    (0..max).map(|k| (k as u128 * n as u128 / max as u128) as usize).collect()
}

impl ViewerCloud {
    /// Up to `max_points` points of `cloud` with their colors; a cloud without colors is colored by
    /// height (turbo over its z range).
    ///
    /// # Errors
    /// [`Error::Invalid`] for an empty or inconsistent cloud, or `max_points == 0`.
    pub fn from_cloud(cloud: &PointCloud, max_points: usize) -> Result<Self> {
        let bounds = Self::check(cloud, max_points)?;
        let (z0, z1) = (bounds.min.z, bounds.max.z);
        let color = |i: usize| match &cloud.colors {
            Some(c) => c[i],
            None => Colormap::Turbo.map(cloud.points[i].z, z0, z1),
        };
        Ok(Self::build(cloud, &subsample(cloud.len(), max_points), color))
    }

    /// Up to `max_points` points of `cloud` colored by `values_m` (one per point, metres) through
    /// `scale`; non-finite values are grey.
    ///
    /// # Errors
    /// As [`ViewerCloud::from_cloud`], and when the value count differs from the point count.
    pub fn from_scalar(cloud: &PointCloud, values_m: &[f32], scale: &ScalarScale, max_points: usize) -> Result<Self> {
        Self::check(cloud, max_points)?;
        if values_m.len() != cloud.len() {
            return Err(Error::invalid(
                "viewer values",
                format!("{} values for {} points", values_m.len(), cloud.len()),
            ));
        }
        let color = |i: usize| {
            let v = values_m[i];
            if v.is_finite() { scale.colormap.map(v, scale.lo_m, scale.hi_m) } else { [160, 160, 160] }
        };
        Ok(Self::build(cloud, &subsample(cloud.len(), max_points), color))
    }

    fn check(cloud: &PointCloud, max_points: usize) -> Result<crate::cloud::Bounds> {
        cloud.validate("viewer cloud")?;
        if max_points == 0 {
            return Err(Error::invalid("viewer max_points", "must be at least 1"));
        }
        cloud.bounds().ok_or_else(|| Error::invalid("viewer cloud", "has no points"))
    }

    fn build(cloud: &PointCloud, keep: &[usize], color: impl Fn(usize) -> [u8; 3]) -> Self {
        let (lo, hi) = keep
            .iter()
            .map(|&i| cloud.points[i].cast::<f64>())
            .fold(([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]), |(lo, hi), p| {
                (std::array::from_fn(|k| lo[k].min(p[k])), std::array::from_fn(|k| hi[k].max(p[k])))
            });
        let center_m: [f64; 3] = std::array::from_fn(|k| (lo[k] + hi[k]) / 2.0);
        let mut positions = Vec::with_capacity(3 * keep.len());
        let mut colors = Vec::with_capacity(3 * keep.len());
        let mut radius_m = 0f32;
        for &i in keep {
            let p = cloud.points[i];
            let rel = [0, 1, 2].map(|k| (f64::from(p[k]) - center_m[k]) as f32);
            radius_m = radius_m.max((rel[0] * rel[0] + rel[1] * rel[1] + rel[2] * rel[2]).sqrt());
            positions.extend_from_slice(&rel);
            colors.extend_from_slice(&color(i));
        }
        Self { positions, colors, center_m, radius_m, total_points: cloud.len() }
    }

    /// Embedded points.
    pub fn len(&self) -> usize {
        self.positions.len() / 3
    }

    /// True when no point is embedded.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// The HTML of viewer number `k`: canvas, controls, status line and the base64 data.
    pub fn html(&self, k: usize) -> String {
        let pos: Vec<u8> = self.positions.iter().flat_map(|v| v.to_le_bytes()).collect();
        let mut s = String::new();
        let _ = write!(
            s,
            "<div class=\"viewer\"><canvas id=\"viewer-{k}\" class=\"awl-viewer\" width=\"960\" height=\"600\" \
             data-count=\"{}\" data-radius=\"{}\" data-pos=\"cloud-{k}-pos\" data-col=\"cloud-{k}-col\" \
             data-status=\"viewer-status-{k}\"></canvas>\n<div class=\"hint\">drag: rotate &middot; shift+drag: pan \
             &middot; wheel: zoom &middot; double-click: reset &middot; point size \
             <input type=\"range\" min=\"1\" max=\"8\" value=\"2\" id=\"viewer-{k}-size\"> &middot; \
             <span id=\"viewer-status-{k}\">loading</span> ({} of {} points shown; centre {})</div></div>\n",
            self.len(),
            self.radius_m,
            self.len(),
            self.total_points,
            xml_escape(&format!("{:.3}, {:.3}, {:.3} m", self.center_m[0], self.center_m[1], self.center_m[2]))
        );
        let _ = writeln!(s, "<script type=\"text/plain\" id=\"cloud-{k}-pos\">{}</script>", base64::encode(&pos));
        let _ =
            writeln!(s, "<script type=\"text/plain\" id=\"cloud-{k}-col\">{}</script>", base64::encode(&self.colors));
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    #[test]
    fn subsample_is_even_and_capped() {
        assert_eq!(subsample(5, 10), vec![0, 1, 2, 3, 4]);
        assert_eq!(subsample(10, 4), vec![0, 2, 5, 7]);
    }

    #[test]
    fn positions_are_centred_and_colored_by_height() {
        let cloud = PointCloud::from_points(vec![Point3::new(1.0, 2.0, 0.0), Point3::new(3.0, 2.0, 2.0)]);
        let v = ViewerCloud::from_cloud(&cloud, 10).expect("valid");
        assert_eq!(v.center_m, [2.0, 2.0, 1.0]);
        assert_eq!(v.positions, vec![-1.0, 0.0, -1.0, 1.0, 0.0, 1.0]);
        assert!((v.radius_m - 2f32.sqrt()).abs() < 1e-6);
        assert_eq!(&v.colors[..3], &Colormap::Turbo.rgb(0.0));
        assert_eq!(&v.colors[3..], &Colormap::Turbo.rgb(1.0));
        let html = v.html(0);
        // 2 points x 12 bytes = 24 bytes -> 32 base64 characters.
        let start = html.find("cloud-0-pos\">").expect("data") + 13;
        assert_eq!(html[start..].find('<'), Some(32));
        assert!(ViewerCloud::from_cloud(&PointCloud::default(), 10).is_err());
        let scale = ScalarScale { colormap: Colormap::Viridis, lo_m: 0.0, hi_m: 1.0 };
        let s = ViewerCloud::from_scalar(&cloud, &[1.0, f32::NAN], &scale, 1).expect("valid");
        assert_eq!((s.len(), s.total_points), (1, 2));
        assert_eq!(s.colors, Colormap::Viridis.rgb(1.0).to_vec());
    }
}
