//! The result of `awl evaluate` as written to `summary.json`: what each number means is said on its
//! field. Distances are from model points (in the CAD frame, after alignment) to the CAD surface.

use serde::{Deserialize, Serialize};

use super::global::Candidate;
use super::sanity::Sanity;
use crate::registration::IcpResult;
use crate::transform::Rows;

/// Format tag of `summary.json`.
pub const SUMMARY_FORMAT: &str = "awl-evaluate/1";

/// Statistics of a set of distances, metres.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DistanceStats {
    /// Number of distances.
    pub points: usize,
    /// Root mean square.
    pub rmse_m: f64,
    /// Mean.
    pub mean_m: f64,
    /// Median (nearest rank: the value at index round(0.5 (n − 1)) of the sorted list).
    pub median_m: f64,
    /// 95th percentile (nearest rank, index round(0.95 (n − 1))).
    pub p95_m: f64,
    /// Largest.
    pub max_m: f64,
}

impl DistanceStats {
    /// Statistics of `distances_m`, or `None` when it is empty.
    pub fn of(distances_m: &[f64]) -> Option<Self> {
        if distances_m.is_empty() {
            return None;
        }
        let mut sorted = distances_m.to_vec();
        sorted.sort_by(f64::total_cmp);
        let n = sorted.len();
        let at = |q: f64| sorted[((q * (n - 1) as f64).round() as usize).min(n - 1)];
        Some(Self {
            points: n,
            rmse_m: (sorted.iter().map(|d| d * d).sum::<f64>() / n as f64).sqrt(),
            mean_m: sorted.iter().sum::<f64>() / n as f64,
            median_m: at(0.5),
            p95_m: at(0.95),
            max_m: sorted[n - 1],
        })
    }
}

/// Model-to-CAD distances.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DistanceSummary {
    /// A model point is on the object when its distance is at most this, metres.
    pub on_object_m: f64,
    /// Over every model point.
    pub all: DistanceStats,
    /// Over the on-object points (`None` when there is none).
    pub on_object: Option<DistanceStats>,
    /// Model points farther than `on_object_m` (floor, clutter, ghosts) / all model points.
    pub off_object_fraction: f64,
}

/// Completeness at one threshold.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CompletenessAt {
    /// Threshold, millimetres.
    pub threshold_mm: f64,
    /// Share of the counted CAD samples (see [`CompletenessSummary`]) with a model point within the threshold.
    pub fraction: f64,
    /// The same over every CAD sample, bottom included.
    pub fraction_all_samples: f64,
}

/// How much of the CAD surface the model covers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CompletenessSummary {
    /// CAD surface samples drawn (area-uniform, seeded).
    pub samples: usize,
    /// Samples counted: those whose outward normal, turned into the model frame, is NOT within
    /// `facing_down_deg` of `-up_model` (faces resting on the floor are never seen).
    pub samples_counted: usize,
    /// See `samples_counted`; `None` counts every sample.
    pub facing_down_deg: Option<f64>,
    /// The model frame's up direction (the world's, for a fused model).
    pub up_model: [f64; 3],
    /// One entry per threshold.
    pub thresholds: Vec<CompletenessAt>,
}

/// Histogram of the distances of all model points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Histogram {
    /// Bin width, millimetres; bin k holds distances in [k bin_mm, (k + 1) bin_mm).
    pub bin_mm: f64,
    /// Counts per bin, from 0 up to `max_mm`.
    pub counts: Vec<usize>,
    /// Points at or beyond `max_mm`.
    pub overflow: usize,
    /// Upper end of the last bin, millimetres.
    pub max_mm: f64,
}

/// What the global search found (when there was no initial pose).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GlobalSummary {
    /// Hypotheses tried.
    pub hypotheses: usize,
    /// The best candidates after the coarse ICP (then refined by the fine ICP), best first.
    pub refined: Vec<Candidate>,
    /// Fine-ICP score of each refined candidate, same order; the best is kept.
    pub refined_scores: Vec<f64>,
}

/// How `T_object_model` was found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AlignmentSummary {
    /// The result: maps model points into the CAD (object) frame.
    #[serde(rename = "T_object_model")]
    pub object_model: Rows,
    /// `given` (an initial pose, see `init_source`) or `global` (no initial pose).
    pub method: String,
    /// Where the initial pose came from (a file), when the caller says.
    pub init_source: Option<String>,
    /// The pose the fine ICP started from.
    #[serde(rename = "T_object_model_start")]
    pub object_model_start: Rows,
    /// Translation from the start to the result, metres (of the model-frame origin).
    pub moved_m: f64,
    /// Rotation from the start to the result, degrees.
    pub moved_deg: f64,
    /// Global search details (`method` = `global`).
    pub global: Option<GlobalSummary>,
    /// The fine ICP (model -> CAD samples) that gave the result.
    pub icp: IcpResult,
    /// Score of the result (global module docs), at `score_threshold_m`.
    pub score: f64,
    /// Share of the scored model points within `score_threshold_m` of the CAD.
    pub inlier_fraction: f64,
    /// τ of `score` and `inlier_fraction`, metres.
    pub score_threshold_m: f64,
}

/// Heatmap of `errors.ply`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HeatmapInfo {
    /// Colormap name.
    pub colormap: String,
    /// Distances at or beyond this get the last color, millimetres (0 gets the first).
    pub max_mm: f64,
}

/// Wall-clock seconds per stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Timings {
    /// CAD sampling and BVH.
    pub prepare_s: f64,
    /// Global search (0 with an initial pose) and fine ICP.
    pub alignment_s: f64,
    /// Distances, completeness, histogram.
    pub metrics_s: f64,
    /// Everything.
    pub total_s: f64,
}

/// Everything `summary.json` holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvaluationSummary {
    /// [`SUMMARY_FORMAT`].
    pub format: String,
    /// Model points evaluated.
    pub model_points: usize,
    /// CAD triangles.
    pub cad_triangles: usize,
    /// CAD surface area, m².
    pub cad_area_m2: f64,
    /// The alignment.
    pub alignment: AlignmentSummary,
    /// Model-to-CAD distances.
    pub distances: DistanceSummary,
    /// CAD-to-model coverage.
    pub completeness: CompletenessSummary,
    /// Distance histogram (all model points).
    pub histogram: Histogram,
    /// Colors of `errors.ply`.
    pub heatmap: HeatmapInfo,
    /// Timings.
    pub timings_s: Timings,
    /// The sanity checks' numbers (see `eval::sanity`).
    #[serde(default)]
    pub sanity: Sanity,
    /// Why the figures may mean nothing (a model and a CAD that do not match, a start pose of other
    /// units or another scene), one sentence each; empty when every check passes.
    #[serde(default)]
    pub warnings: Vec<String>,
}

impl EvaluationSummary {
    /// Completeness at `threshold_mm` (within 1e-9 mm), if it was computed.
    pub fn completeness_at(&self, threshold_mm: f64) -> Option<f64> {
        self.completeness.thresholds.iter().find(|c| (c.threshold_mm - threshold_mm).abs() < 1e-9).map(|c| c.fraction)
    }
}

/// Histogram of `distances_m` with `bin_mm` bins up to `max_mm`.
pub fn histogram(distances_m: &[f64], bin_mm: f64, max_mm: f64) -> Histogram {
    let bins = (max_mm / bin_mm).ceil().max(1.0) as usize;
    let mut counts = vec![0usize; bins];
    let mut overflow = 0;
    for &d in distances_m {
        let k = (d * 1e3 / bin_mm).floor();
        if k >= 0.0 && (k as usize) < bins && d * 1e3 < max_mm {
            counts[k as usize] += 1;
        } else {
            overflow += 1;
        }
    }
    Histogram { bin_mm, counts, overflow, max_mm }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_and_histogram_on_a_hand_computed_case() {
        let d = [0.004, 0.001, 0.002, 0.003, 0.0];
        let s = DistanceStats::of(&d).expect("stats");
        assert_eq!((s.points, s.median_m, s.max_m), (5, 0.002, 0.004));
        assert!((s.mean_m - 0.002).abs() < 1e-15);
        assert!((s.rmse_m - (0.00003f64 / 5.0).sqrt()).abs() < 1e-15);
        assert_eq!(s.p95_m, 0.004);
        assert!(DistanceStats::of(&[]).is_none());
        let h = histogram(&[0.0, 0.0004, 0.0006, 0.0019, 0.002, 0.5], 1.0, 2.0);
        assert_eq!((h.counts, h.overflow), (vec![3, 1], 2));
    }
}
