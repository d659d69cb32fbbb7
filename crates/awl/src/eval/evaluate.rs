//! The whole `awl evaluate` job: align a model (point cloud, e.g. a fused `model.ply` in the scan's
//! world frame) to a CAD mesh (object frame), then measure how far it is from the CAD.
//!
//! 1. Start: the caller's `T_object_model`, or the best candidates of [`global_align`].
//! 2. Fine ICP: model -> CAD surface samples (area-uniform, seeded, exact face normals), coarse to
//!    fine, Tukey kernel (floor, clutter and the never-seen bottom get no weight); from several
//!    global candidates the one with the best score (global module docs) wins.
//! 3. Metrics: see [`EvaluationSummary`] and its fields.
//! 4. Sanity ([`super::sanity`]): a figure that is not finite is an error; a model and a CAD (or a
//!    start pose) that do not belong together give warnings in the summary.

use std::time::Instant;

use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::MeshDistance;
use super::global::{GlobalParams, SCORE_SEED, global_align, score_alignment, subset};
use super::heatmap::COLORMAP;
use super::sanity;
use super::summary::{
    AlignmentSummary, CompletenessAt, CompletenessSummary, DistanceStats, DistanceSummary, EvaluationSummary,
    GlobalSummary, HeatmapInfo, SUMMARY_FORMAT, Timings, histogram,
};
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use crate::registration::{IcpLevel, IcpParams, IcpResult, register};
use crate::spatial::KdIndex;
use crate::transform::{pose_difference, rows_from_isometry};

/// Parameters of [`evaluate`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EvaluateParams {
    /// CAD surface samples the model is registered to. Default 200 000.
    pub cad_samples: usize,
    /// Seed of every sampling. Default 1.
    pub seed: u64,
    /// Global search (used without an initial pose).
    pub global: GlobalParams,
    /// Best distinct global candidates refined by the fine ICP. Default 3.
    pub refine_candidates: usize,
    /// Fine ICP. Default: 10 mm voxels / 60 mm gate, 4 / 15, 2 / 5, then the full clouds / 3 mm;
    /// Tukey kernel; at most 20 000 model points per level.
    pub icp: IcpParams,
    /// Use the model's normals (when it has them, oriented outward) to gate correspondences. Default true.
    pub use_model_normals: bool,
    /// On-object threshold, metres. Default 0.01.
    pub on_object_m: f64,
    /// CAD samples drawn for completeness. Default 100 000.
    pub completeness_samples: usize,
    /// Completeness thresholds, metres. Default 2, 5, 10 mm.
    pub completeness_thresholds_m: Vec<f64>,
    /// CAD samples facing within this angle of straight down (model frame) do not count for
    /// completeness, degrees; `None` counts all. Default 30.
    pub facing_down_deg: Option<f64>,
    /// Up in the model frame (a fused model is in the world frame: z up). Default [0, 0, 1].
    pub up_model: [f64; 3],
    /// Histogram bin, millimetres. Default 0.5.
    pub histogram_bin_mm: f64,
    /// Histogram range, millimetres. Default 10.
    pub histogram_max_mm: f64,
    /// Heatmap clamp, millimetres. Default 5.
    pub heatmap_max_mm: f64,
}

impl Default for EvaluateParams {
    fn default() -> Self {
        let mut icp = IcpParams::default();
        icp.levels.push(IcpLevel { voxel_m: 0.0, max_correspondence_m: 0.003, max_iterations: 50 });
        Self {
            cad_samples: 200_000,
            seed: 1,
            global: GlobalParams::default(),
            refine_candidates: 3,
            icp,
            use_model_normals: true,
            on_object_m: 0.01,
            completeness_samples: 100_000,
            completeness_thresholds_m: vec![0.002, 0.005, 0.01],
            facing_down_deg: Some(30.0),
            up_model: [0.0, 0.0, 1.0],
            histogram_bin_mm: 0.5,
            histogram_max_mm: 10.0,
            heatmap_max_mm: 5.0,
        }
    }
}

impl EvaluateParams {
    fn validate(&self) -> Result<()> {
        let bad = |what: &str, msg: String| Err(Error::invalid(format!("evaluate.{what}"), msg));
        if self.cad_samples < 100 || self.completeness_samples == 0 {
            return bad("cad_samples", "too few CAD samples".into());
        }
        for (name, v) in [
            ("on_object_m", self.on_object_m),
            ("histogram_bin_mm", self.histogram_bin_mm),
            ("histogram_max_mm", self.histogram_max_mm),
            ("heatmap_max_mm", self.heatmap_max_mm),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(name, format!("{v} is not a positive number"));
            }
        }
        if self.completeness_thresholds_m.iter().any(|t| !(t.is_finite() && *t > 0.0)) {
            return bad("completeness_thresholds_m", format!("{:?}", self.completeness_thresholds_m));
        }
        if !(Vector3::from(self.up_model).norm() > 0.0 && self.up_model.iter().all(|v| v.is_finite())) {
            return bad("up_model", format!("{:?} is not a direction", self.up_model));
        }
        Ok(())
    }
}

/// The result of [`evaluate`].
#[derive(Debug, Clone)]
pub struct Evaluation {
    /// `T_object_model`: maps model points into the CAD frame.
    pub object_from_model: Isometry3<f64>,
    /// The model moved into the CAD frame (same points, order, normals and colors as the input).
    pub model_object: PointCloud,
    /// Distance of each point of `model_object` to the CAD surface, metres.
    pub distances_m: Vec<f64>,
    /// The numbers of `summary.json`.
    pub summary: EvaluationSummary,
}

/// Aligns `model` to `cad` (from `init` = `T_object_model` when given, else by a global search) and
/// measures it; see the module docs.
///
/// # Errors
/// [`Error::Invalid`] naming the input: a model with fewer than 6 points or a non-finite point, a
/// degenerate CAD, a non-finite `init`, bad parameters, or an ICP failure (with the start pose's
/// warnings: millimetres?). [`Error::NotFinite`] naming a figure of the summary that is not finite
/// (no model point on the object: no RMSE), with the warnings so far.
pub fn evaluate(
    model: &PointCloud,
    cad: &TriMesh,
    init: Option<&Isometry3<f64>>,
    params: &EvaluateParams,
) -> Result<Evaluation> {
    let t0 = Instant::now();
    params.validate()?;
    model.validate("model")?;
    if model.len() < 6 {
        return Err(Error::invalid("model", format!("{} points: at least 6 are needed", model.len())));
    }
    if let Some(t) = init
        && !(t.translation.vector.iter().chain(t.rotation.coords.iter()).all(|v| v.is_finite()))
    {
        return Err(Error::invalid("init T_object_model", format!("not finite: {t:?}")));
    }
    let mesh = MeshDistance::new(cad)?;
    let cad_cloud = cad.sample_surface(params.cad_samples, params.seed)?;
    let source = if params.use_model_normals { model.clone() } else { PointCloud { normals: None, ..model.clone() } };
    let t_prepare = t0.elapsed().as_secs_f64();

    let tau = params.global.score_threshold_m;
    let scored = subset(&model.points, params.global.score_points, SCORE_SEED);
    let (starts, mut global) = match init {
        Some(t) => (vec![*t], None),
        None => {
            let g = global_align(&source, &cad_cloud, &mesh, &params.global)?;
            let refined: Vec<_> = g.candidates.iter().take(params.refine_candidates.max(1)).cloned().collect();
            let starts = refined.iter().map(|c| c.object_from_model).collect();
            (starts, Some(GlobalSummary { hypotheses: g.hypotheses, refined, refined_scores: Vec::new() }))
        }
    };
    let start_warnings = init.map(|t| sanity::start_warnings(t).0).unwrap_or_default();
    let mut best: Option<(IcpResult, Isometry3<f64>, f64, f64)> = None;
    for start in &starts {
        let icp = register(&source, &cad_cloud, start, &params.icp).map_err(|e| with_warnings(e, &start_warnings))?;
        let (score, inliers) = score_alignment(&scored, &icp.target_from_source, &mesh, tau);
        if let Some(g) = global.as_mut() {
            g.refined_scores.push(score);
        }
        if best.as_ref().is_none_or(|b| score > b.2) {
            best = Some((icp, *start, score, inliers));
        }
    }
    let (icp, start, score, inlier_fraction) =
        best.ok_or_else(|| Error::invalid("alignment", "no starting pose to refine"))?;
    let object_from_model = icp.target_from_source;
    let t_align = t0.elapsed().as_secs_f64();

    let model_object = model.transformed(&object_from_model);
    let points: Vec<Point3<f64>> = model_object.points.iter().map(|p| p.cast::<f64>()).collect();
    let distances_m = mesh.distances(&points);
    let on: Vec<f64> = distances_m.iter().copied().filter(|&d| d <= params.on_object_m).collect();
    let all = DistanceStats::of(&distances_m).ok_or_else(|| Error::invalid("model", "no points"))?;
    let distances = DistanceSummary {
        on_object_m: params.on_object_m,
        all,
        on_object: DistanceStats::of(&on),
        off_object_fraction: (distances_m.len() - on.len()) as f64 / distances_m.len() as f64,
    };
    let completeness = completeness(cad, &model_object, &object_from_model, params)?;
    let (moved_m, moved_rad) = pose_difference(&start, &object_from_model);
    let alignment = AlignmentSummary {
        object_model: rows_from_isometry(&object_from_model),
        method: if init.is_some() { "given" } else { "global" }.into(),
        init_source: None,
        object_model_start: rows_from_isometry(&start),
        moved_m,
        moved_deg: moved_rad.to_degrees(),
        global,
        icp,
        score,
        inlier_fraction,
        score_threshold_m: tau,
    };
    let (sanity, warnings) = sanity::check(&model.points, &cad_cloud.points, &distances_m, init);
    let t_total = t0.elapsed().as_secs_f64();
    let summary = EvaluationSummary {
        format: SUMMARY_FORMAT.into(),
        model_points: model.len(),
        cad_triangles: cad.triangles.len(),
        cad_area_m2: cad.area(),
        alignment,
        distances,
        completeness,
        histogram: histogram(&distances_m, params.histogram_bin_mm, params.histogram_max_mm),
        heatmap: HeatmapInfo { colormap: COLORMAP.into(), max_mm: params.heatmap_max_mm },
        timings_s: Timings {
            prepare_s: t_prepare,
            alignment_s: t_align - t_prepare,
            metrics_s: t_total - t_align,
            total_s: t_total,
        },
        sanity,
        warnings,
    };
    sanity::check_finite(&summary).map_err(|e| with_warnings(e, &summary.warnings))?;
    Ok(Evaluation { object_from_model, model_object, distances_m, summary })
}

/// `e` with `warnings` (what the sanity checks saw so far) appended to its message.
fn with_warnings(e: Error, warnings: &[String]) -> Error {
    if warnings.is_empty() {
        return e;
    }
    let also = format!(" (and: {})", warnings.join("; "));
    match e {
        Error::Invalid { what, message } => Error::Invalid { what, message: message + &also },
        Error::NotFinite { what, message } => Error::NotFinite { what, message: message + &also },
        other => other,
    }
}

/// Completeness of `model_object` (CAD frame): see [`CompletenessSummary`].
fn completeness(
    cad: &TriMesh,
    model_object: &PointCloud,
    object_from_model: &Isometry3<f64>,
    params: &EvaluateParams,
) -> Result<CompletenessSummary> {
    let samples = cad.sample_surface(params.completeness_samples, params.seed.wrapping_add(1))?;
    let normals = samples.normals.as_deref().unwrap_or_default();
    let up = Vector3::from(params.up_model).normalize();
    let min_cos = params.facing_down_deg.map(|a| a.to_radians().cos());
    let counted: Vec<bool> = (0..samples.len())
        .map(|i| {
            let n_model = object_from_model.inverse_transform_vector(&normals[i].cast::<f64>());
            min_cos.is_none_or(|c| -n_model.dot(&up) < c)
        })
        .collect();
    let index = KdIndex::new(&model_object.points)?;
    let nearest: Vec<f64> = samples
        .points
        .par_iter()
        .map(|s| index.nearest(s).map_or(f64::INFINITY, |n| f64::from(n.dist_sq).sqrt()))
        .collect();
    let n_counted = counted.iter().filter(|&&c| c).count();
    let thresholds = params
        .completeness_thresholds_m
        .iter()
        .map(|&t| {
            let within = |only_counted: bool| {
                nearest.iter().zip(&counted).filter(|&(&d, &c)| d <= t && (c || !only_counted)).count()
            };
            CompletenessAt {
                threshold_mm: t * 1e3,
                fraction: within(true) as f64 / n_counted.max(1) as f64,
                fraction_all_samples: within(false) as f64 / nearest.len().max(1) as f64,
            }
        })
        .collect();
    Ok(CompletenessSummary {
        samples: samples.len(),
        samples_counted: n_counted,
        facing_down_deg: params.facing_down_deg,
        up_model: params.up_model,
        thresholds,
    })
}
