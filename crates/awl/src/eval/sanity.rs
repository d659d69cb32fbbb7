//! Whether an evaluation's figures mean anything: every number finite (else an error), and the
//! warnings of a model and a CAD (or a start pose) that do not belong together.
//!
//! The checks and their thresholds (all in [`Sanity`], written to `summary.json`):
//! - near the CAD: less than [`MIN_NEAR_FRACTION`] (half) of the model's points within
//!   [`NEAR_CAD_M`] (5 mm, the headline completeness distance) of the CAD after alignment: the
//!   figures over the points that are near describe a fit of the wrong thing (another part's CAD);
//! - size: the model's and the CAD's sizes (each one's bounding-sphere diameter about its centroid,
//!   so the alignment does not matter; the model's from the 99th percentile of its points' distances,
//!   so a few stray points do not count) differ by more than [`MAX_SIZE_RATIO`] (1.5x): another
//!   part, or a CAD in millimetres;
//! - the start pose (`--init`, `--truth`): a translation over [`MAX_START_TRANSLATION_M`] (100 m:
//!   millimetres read as metres), or the model's and the CAD's bounding spheres (at the start pose)
//!   apart: the start places the CAD away from the model (another scan's truth.json, other units).

use nalgebra::{Isometry3, Point3, Vector3};
use serde::{Deserialize, Serialize};

use super::summary::{DistanceStats, EvaluationSummary};
use crate::error::{Error, Result};

/// A model point is near the CAD within this distance, metres (5 mm, the headline completeness).
pub const NEAR_CAD_M: f64 = 0.005;
/// Fewer model points than this share near the CAD: warned.
pub const MIN_NEAR_FRACTION: f64 = 0.5;
/// The model's and the CAD's sizes differ by more than this factor: warned.
pub const MAX_SIZE_RATIO: f64 = 1.5;
/// A start pose translating farther than this, metres: warned (millimetres read as metres).
pub const MAX_START_TRANSLATION_M: f64 = 100.0;

/// The sanity checks' numbers (see the module docs).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Sanity {
    /// [`NEAR_CAD_M`], metres.
    pub near_m: f64,
    /// Share of the model's points within `near_m` of the CAD after alignment.
    pub near_fraction: f64,
    /// The model's size: its bounding-sphere diameter about its centroid (99th percentile), metres.
    pub model_size_m: f64,
    /// The CAD's size: its surface's bounding-sphere diameter about its centroid, metres.
    pub cad_size_m: f64,
    /// The larger size over the smaller (1 = the same).
    pub size_ratio: f64,
    /// With a start pose: the distance between the model's centre and the CAD's, placed by the
    /// start pose, metres.
    pub start_centre_distance_m: Option<f64>,
    /// With a start pose: the sum of the two bounding spheres' radii (half the sizes), metres.
    pub start_reach_m: Option<f64>,
}

/// Centroid of `points` and the diameter of the sphere about it holding them: twice the `q`
/// quantile of the points' distances to it (`q` = 1: the farthest); `None` for no point.
pub fn bounding_sphere(points: &[Point3<f32>], q: f64) -> Option<(Point3<f64>, f64)> {
    if points.is_empty() {
        return None;
    }
    let n = points.len() as f64;
    let centre = Point3::from(points.iter().fold(Vector3::zeros(), |a, p| a + p.coords.cast::<f64>()) / n);
    let mut r: Vec<f64> = points.iter().map(|p| (p.cast::<f64>() - centre).norm()).collect();
    r.sort_by(f64::total_cmp);
    let k = ((q * (r.len() - 1) as f64).round() as usize).min(r.len() - 1);
    Some((centre, 2.0 * r[k]))
}

/// The checks' numbers and warnings: `model` in its own frame, `cad_samples` on the CAD surface
/// (object frame), `distances_m` of the aligned model's points, `start` the given `T_object_model`.
pub fn check(
    model: &[Point3<f32>],
    cad_samples: &[Point3<f32>],
    distances_m: &[f64],
    start: Option<&Isometry3<f64>>,
) -> (Sanity, Vec<String>) {
    let mut warnings = start.map(|s| start_warnings(s).0).unwrap_or_default();
    let near = distances_m.iter().filter(|&&d| d <= NEAR_CAD_M).count() as f64 / distances_m.len().max(1) as f64;
    let model_sphere = bounding_sphere(model, 0.99);
    let cad_sphere = bounding_sphere(cad_samples, 1.0);
    let size = |b: Option<(Point3<f64>, f64)>| b.map_or(f64::NAN, |b| b.1);
    let (model_size, cad_size) = (size(model_sphere), size(cad_sphere));
    let ratio = model_size.max(cad_size) / model_size.min(cad_size);
    let (centre_distance, reach) = match (start, model_sphere, cad_sphere) {
        (Some(s), Some((mc, md)), Some((cc, cd))) => {
            let cad_centre_model = s.inverse_transform_point(&cc);
            (Some((mc - cad_centre_model).norm()), Some(0.5 * (md + cd)))
        }
        _ => (None, None),
    };
    if let (Some(d), Some(r)) = (centre_distance, reach)
        && d > r
    {
        warnings.push(format!(
            "the start pose places the CAD away from the model: their centres are {d:.3} m apart, more than their \
             bounding spheres' radii together ({r:.3} m); the start pose (truth.json, --init) is of another scene or \
             in other units"
        ));
    }
    if near < MIN_NEAR_FRACTION {
        warnings.push(format!(
            "only {:.1} % of the model's points lie within {} mm of the CAD after alignment (less than {:.0} %): the \
             model and the CAD do not match (another part's CAD, another scan's truth?); the figures describe a fit of \
             the wrong thing",
            near * 100.0,
            NEAR_CAD_M * 1e3,
            MIN_NEAR_FRACTION * 100.0
        ));
    }
    if ratio > MAX_SIZE_RATIO {
        warnings.push(format!(
            "the model's size ({model_size:.3} m, its bounding-sphere diameter) and the CAD's ({cad_size:.3} m) \
             differ by {ratio:.2}x (more than {MAX_SIZE_RATIO}x): another part's CAD, or a CAD in other units \
             (millimetres?)"
        ));
    }
    let sanity = Sanity {
        near_m: NEAR_CAD_M,
        near_fraction: near,
        model_size_m: model_size,
        cad_size_m: cad_size,
        size_ratio: ratio,
        start_centre_distance_m: centre_distance,
        start_reach_m: reach,
    };
    (sanity, warnings)
}

/// The warnings of a start pose on its own (a translation over [`MAX_START_TRANSLATION_M`]) and its
/// translation, metres.
pub fn start_warnings(start: &Isometry3<f64>) -> (Vec<String>, f64) {
    let t = start.translation.vector.norm();
    let mut warnings = Vec::new();
    if t > MAX_START_TRANSLATION_M {
        warnings.push(format!(
            "the start pose translates by {t:.1} m (more than {MAX_START_TRANSLATION_M} m): its file looks like it is \
             in millimetres, not metres"
        ));
    }
    (warnings, t)
}

/// Refuses a summary with a number that is not finite, naming the first.
///
/// # Errors
/// [`Error::NotFinite`] naming the figure (`RMSE of the on-object points`, `completeness at 5 mm`, ...).
pub fn check_finite(s: &EvaluationSummary) -> Result<()> {
    let mut figures: Vec<(String, f64)> = vec![
        ("the CAD's area".into(), s.cad_area_m2),
        ("the alignment's translation from the start".into(), s.alignment.moved_m),
        ("the alignment's rotation from the start".into(), s.alignment.moved_deg),
        ("the alignment's score".into(), s.alignment.score),
        ("the alignment's inlier fraction".into(), s.alignment.inlier_fraction),
        ("the fine ICP's fitness".into(), s.alignment.icp.fitness),
        ("the share of points off the object".into(), s.distances.off_object_fraction),
        ("the share of points near the CAD".into(), s.sanity.near_fraction),
        ("the model's size".into(), s.sanity.model_size_m),
        ("the CAD's size".into(), s.sanity.cad_size_m),
    ];
    let stats = |figures: &mut Vec<(String, f64)>, over: &str, d: &DistanceStats| {
        for (name, v) in [("RMSE", d.rmse_m), ("mean", d.mean_m), ("median", d.median_m), ("95th percentile", d.p95_m)]
            .into_iter()
            .chain([("max", d.max_m)])
        {
            figures.push((format!("the {name} of {over}"), v));
        }
    };
    stats(&mut figures, "all points", &s.distances.all);
    match &s.distances.on_object {
        Some(d) => stats(&mut figures, "the on-object points", d),
        None => {
            return Err(Error::NotFinite {
                what: "the RMSE of the on-object points".into(),
                message: format!(
                    "no model point lies within {} mm of the CAD after alignment, so there is no RMSE (NaN): the model \
                     and the CAD do not match, or the start pose is wrong (in millimetres? of another scan?)",
                    s.distances.on_object_m * 1e3
                ),
            });
        }
    }
    for c in &s.completeness.thresholds {
        figures.push((format!("the completeness at {} mm", c.threshold_mm), c.fraction));
        figures.push((format!("the completeness at {} mm over all samples", c.threshold_mm), c.fraction_all_samples));
    }
    for (name, rows) in
        [("T_object_model", &s.alignment.object_model), ("T_object_model_start", &s.alignment.object_model_start)]
    {
        for (r, row) in rows.iter().enumerate() {
            for (c, v) in row.iter().enumerate() {
                figures.push((format!("{name}[{r}][{c}]"), *v));
            }
        }
    }
    match figures.into_iter().find(|(_, v)| !v.is_finite()) {
        Some((what, v)) => Err(Error::NotFinite {
            what,
            message: format!("it is {v}: the evaluation means nothing; check the model, the CAD and the start pose"),
        }),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounding_sphere_of_a_cube_and_a_start_in_millimetres() {
        let corners: Vec<Point3<f32>> =
            (0..8u8).map(|i| Point3::new(f32::from(i & 1), f32::from((i >> 1) & 1), f32::from(i >> 2)) * 0.3).collect();
        let (centre, size) = bounding_sphere(&corners, 1.0).expect("sphere");
        assert!((centre - Point3::new(0.15, 0.15, 0.15)).norm() < 1e-6);
        assert!((size - 0.3 * 3f64.sqrt()).abs() < 1e-6, "{size}");
        assert!(bounding_sphere(&[], 1.0).is_none());
        let metres = Isometry3::translation(0.14, 0.26, 0.0);
        assert!(start_warnings(&metres).0.is_empty());
        let mm = Isometry3::translation(140.0, 263.0, 0.0);
        let (w, t) = start_warnings(&mm);
        assert!((t - 297.9).abs() < 0.1 && w.len() == 1 && w[0].contains("millimetres"), "{w:?}");
    }
}
