//! The software rasteriser: z-buffered disc splats of an orthographic, fit-to-bounds view.
//!
//! Each point becomes a disc of radius `1.5 x spacing` in pixels (at least 0.75 px, so every point
//! covers the pixel it falls in), where `spacing` is the typical distance to the nearest neighbour.
//! A pixel shows the nearest disc covering its centre; ties in depth go to the lower point index, so
//! the picture does not depend on the order the discs are drawn in. Rows are split into fixed bands
//! drawn in parallel: the same pixels for any thread count.

use nalgebra::Point3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::view::{Projection, Viewpoint};
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::spatial::KdIndex;

/// Rows per parallel band (fixed, so the split does not depend on the thread count).
const BAND: usize = 16;
/// Splat radius over the point spacing (1.5: closes the gaps of irregular, voxel-thinned clouds).
const SPLAT_FACTOR: f32 = 1.5;
/// Largest splat radius, pixels.
const MAX_RADIUS_PX: f32 = 12.0;
/// No point covers the pixel.
pub(crate) const EMPTY: u32 = u32::MAX;

/// Image size and look of a render.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RenderParams {
    /// Image width, pixels (default 800; 16 to 8192). A scalar render includes its legend in it.
    pub width: u32,
    /// Image height, pixels (default 600; 16 to 8192).
    pub height: u32,
    /// Free border around the cloud, pixels (default 16).
    pub margin_px: u32,
    /// Background color (default white).
    pub background: [u8; 3],
    /// Color of points without colors (default light grey 190).
    pub default_color: [u8; 3],
    /// Point spacing, metres (default: estimated from nearest-neighbour distances).
    pub spacing_m: Option<f32>,
    /// Factor on the splat radius (default 1; positive).
    pub splat_scale: f32,
}

impl Default for RenderParams {
    fn default() -> Self {
        Self {
            width: 800,
            height: 600,
            margin_px: 16,
            background: [255, 255, 255],
            default_color: [190, 190, 190],
            spacing_m: None,
            splat_scale: 1.0,
        }
    }
}

impl RenderParams {
    /// Checks the sizes and factors.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        for (name, v) in [("render.width", self.width), ("render.height", self.height)] {
            if !(16..=8192).contains(&v) {
                return Err(Error::invalid(name, format!("{v} px is outside 16..=8192")));
            }
        }
        if 2 * self.margin_px >= self.width.min(self.height) {
            return Err(Error::invalid("render.margin_px", "leaves no room for the cloud"));
        }
        if !(self.splat_scale > 0.0 && self.splat_scale.is_finite()) {
            return Err(Error::invalid("render.splat_scale", "must be positive and finite"));
        }
        if let Some(s) = self.spacing_m
            && !(s > 0.0 && s.is_finite())
        {
            return Err(Error::invalid("render.spacing_m", "must be positive and finite"));
        }
        Ok(())
    }
}

/// Typical point spacing, metres: the median nearest-neighbour distance of up to 2000 points
/// taken at a fixed stride. 0 for fewer than two points.
///
/// # Errors
/// [`Error::Invalid`] for a non-finite point.
pub fn estimate_spacing(points: &[Point3<f32>]) -> Result<f32> {
    if points.len() < 2 {
        return Ok(0.0);
    }
    let index = KdIndex::new(points)?;
    let stride = points.len().div_ceil(2000);
    let mut d: Vec<f32> = (0..points.len())
        .into_par_iter()
        .step_by(stride)
        .filter_map(|i| index.knn(&points[i], 2).get(1).map(|n| n.dist_sq.sqrt()))
        .collect();
    if d.is_empty() {
        return Ok(0.0);
    }
    let mid = d.len() / 2;
    Ok(*d.select_nth_unstable_by(mid, f32::total_cmp).1)
}

/// The z-buffer of one render: per pixel the winning point (or [`EMPTY`]) and its depth.
pub(crate) struct Splats {
    /// Winning point index per pixel, row-major.
    pub winner: Vec<u32>,
    /// Projected depth of every point, metres along the view direction.
    pub depth: Vec<f32>,
}

/// Splats `cloud` onto a `width` x `height` z-buffer through `proj`.
pub(crate) fn splat(cloud: &PointCloud, proj: &Projection, radius_px: f32) -> Splats {
    let (w, h) = (proj.width as usize, proj.height as usize);
    let projected: Vec<[f32; 3]> = cloud.points.par_iter().map(|p| proj.project(p)).collect();
    let r = radius_px;
    let bands = h.div_ceil(BAND);
    let mut bins: Vec<Vec<u32>> = vec![Vec::new(); bands];
    for (i, [x, y, _]) in projected.iter().enumerate() {
        if *x + r < 0.0 || *x - r > (w - 1) as f32 || *y + r < 0.0 || *y - r > (h - 1) as f32 {
            continue;
        }
        let y0 = (y - r).ceil().max(0.0) as usize;
        let y1 = ((y + r).floor() as usize).min(h - 1);
        for bin in &mut bins[y0 / BAND..=y1 / BAND] {
            bin.push(i as u32);
        }
    }
    let mut zbuf: Vec<(f32, u32)> = vec![(f32::INFINITY, EMPTY); w * h];
    zbuf.par_chunks_mut(BAND * w).zip(bins.par_iter()).enumerate().for_each(|(b, (rows, bin))| {
        let row0 = b * BAND;
        let row1 = row0 + rows.len() / w;
        for &i in bin {
            let [x, y, z] = projected[i as usize];
            let y0 = ((y - r).ceil().max(0.0) as usize).max(row0);
            let y1 = ((y + r).floor().max(0.0) as usize).min(row1 - 1);
            let x0 = (x - r).ceil().max(0.0) as usize;
            let x1 = ((x + r).floor().max(0.0) as usize).min(w - 1);
            for py in y0..=y1 {
                let dy = py as f32 - y;
                for px in x0..=x1 {
                    let dx = px as f32 - x;
                    if dx * dx + dy * dy > r * r {
                        continue;
                    }
                    let cell = &mut rows[(py - row0) * w + px];
                    if z < cell.0 || (z == cell.0 && i < cell.1) {
                        *cell = (z, i);
                    }
                }
            }
        }
    });
    Splats { winner: zbuf.into_iter().map(|(_, i)| i).collect(), depth: projected.into_iter().map(|p| p[2]).collect() }
}

/// The fit-to-bounds projection and splat radius of `cloud` in a `width` x `height` area.
pub(crate) fn setup(
    cloud: &PointCloud,
    view: Viewpoint,
    width: u32,
    params: &RenderParams,
) -> Result<(Projection, f32)> {
    params.validate()?;
    cloud.validate("rendered cloud")?;
    let proj = Projection::fit(&cloud.points, view.basis(), width, params.height, params.margin_px)
        .ok_or_else(|| Error::invalid("rendered cloud", "has no points"))?;
    let spacing = match params.spacing_m {
        Some(s) => s,
        None => estimate_spacing(&cloud.points)?,
    };
    let radius = (SPLAT_FACTOR * spacing * proj.px_per_m * params.splat_scale).clamp(0.75, MAX_RADIUS_PX);
    Ok((proj, radius))
}
