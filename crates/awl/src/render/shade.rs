//! Colouring the z-buffer: Lambert shading from normals (or a depth cue without normals) on the
//! points' colors, or a scalar field through a colormap with a legend.

use nalgebra::Vector3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::colormap::Colormap;
use super::legend::{LegendLayout, draw_legend, legend_width};
use super::raster::{EMPTY, RenderParams, setup, splat};
use super::view::Viewpoint;
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::image::ColorImage;

/// Ambient share of the Lambert shading; the rest scales with `|n · light|`.
const AMBIENT: f32 = 0.25;
/// Darkening from the nearest to the farthest point when shading by depth.
const DEPTH_CUE: f32 = 0.55;

/// Direction to the light in view coordinates (right, up, forward): from the upper left, behind
/// the viewer.
pub fn light_view() -> Vector3<f32> {
    Vector3::new(-0.4, 0.5, -1.0).normalize()
}

/// How a scalar field is shown: colormap and the value range mapped onto it, metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ScalarScale {
    /// The colormap.
    pub colormap: Colormap,
    /// Value at the low end, metres.
    pub lo_m: f32,
    /// Value at the high end, metres.
    pub hi_m: f32,
}

fn scale_color(c: [u8; 3], k: f32) -> [u8; 3] {
    c.map(|v| (f32::from(v) * k).round().clamp(0.0, 255.0) as u8)
}

/// Renders `cloud` from `view`: point colors (or `default_color`) shaded by normals (two-sided
/// Lambert, light from [`light_view`]) or, without normals, darkened with depth.
///
/// # Errors
/// [`Error::Invalid`] for bad parameters, an empty cloud, or inconsistent attributes.
pub fn render_cloud(cloud: &PointCloud, view: Viewpoint, params: &RenderParams) -> Result<ColorImage> {
    let (proj, radius) = setup(cloud, view, params.width, params)?;
    let splats = splat(cloud, &proj, radius);
    let basis = proj.basis;
    let light = light_view();
    let (dmin, dmax) = splats.depth.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), d| (a.min(*d), b.max(*d)));
    let dspan = (dmax - dmin).max(1e-9);
    let data = splats
        .winner
        .par_iter()
        .map(|&i| {
            if i == EMPTY {
                return params.background;
            }
            let i = i as usize;
            let base = cloud.colors.as_ref().map_or(params.default_color, |c| c[i]);
            let k = match &cloud.normals {
                Some(ns) => {
                    let n = ns[i];
                    let nv = Vector3::new(n.dot(&basis.right), n.dot(&basis.up), n.dot(&basis.forward));
                    AMBIENT + (1.0 - AMBIENT) * nv.dot(&light).abs().min(1.0)
                }
                None => 1.0 - DEPTH_CUE * (splats.depth[i] - dmin) / dspan,
            };
            scale_color(base, k)
        })
        .collect();
    Ok(ColorImage { width: params.width, height: params.height, data })
}

/// Renders `cloud` from `view` colored flat by `values_m` (one per point, metres) through
/// `scale`, with the legend (in millimetres) in a panel on the right of the image. Non-finite
/// values show in `default_color`.
///
/// # Errors
/// [`Error::Invalid`] for bad parameters, an empty cloud, a value count that differs from the
/// point count, an image too narrow for the legend, or a non-finite range.
pub fn render_scalar(
    cloud: &PointCloud,
    values_m: &[f32],
    scale: &ScalarScale,
    view: Viewpoint,
    params: &RenderParams,
) -> Result<(ColorImage, LegendLayout)> {
    if values_m.len() != cloud.len() {
        return Err(Error::invalid("scalar values", format!("{} values for {} points", values_m.len(), cloud.len())));
    }
    if !(scale.lo_m.is_finite() && scale.hi_m.is_finite()) {
        return Err(Error::invalid("scalar scale", "range must be finite"));
    }
    let legend_w = legend_width(params.height);
    let scene_w = params.width.saturating_sub(legend_w);
    if scene_w < 2 * params.margin_px + 16 {
        return Err(Error::invalid("render.width", format!("{} px leaves no room beside the legend", params.width)));
    }
    let (proj, radius) = setup(cloud, view, scene_w, params)?;
    let splats = splat(cloud, &proj, radius);
    let scene_w = scene_w as usize;
    let mut data = vec![params.background; params.width as usize * params.height as usize];
    data.par_chunks_mut(params.width as usize).zip(splats.winner.par_chunks(scene_w)).for_each(|(row, winners)| {
        for (px, &i) in row.iter_mut().zip(winners) {
            if i != EMPTY {
                let v = values_m[i as usize];
                *px = if v.is_finite() { scale.colormap.map(v, scale.lo_m, scale.hi_m) } else { params.default_color };
            }
        }
    });
    let mut image = ColorImage { width: params.width, height: params.height, data };
    let layout = draw_legend(
        &mut image,
        scene_w as u32,
        params.margin_px,
        scale.colormap,
        f64::from(scale.lo_m) * 1e3,
        f64::from(scale.hi_m) * 1e3,
    );
    Ok((image, layout))
}
