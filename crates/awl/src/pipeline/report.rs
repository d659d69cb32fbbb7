//! `report.json` of `awl fuse`: the resolved config, per-stage counts and times, per-view registration.

use serde::{Deserialize, Serialize};

use super::config::FuseConfig;
use crate::transform::Rows;

/// Format string of the report.
pub const REPORT_FORMAT: &str = "awl-fuse-report/1";

/// One pipeline stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageReport {
    /// Stage name.
    pub name: String,
    /// Points going in (summed over views for per-view stages).
    pub points_in: usize,
    /// Points coming out.
    pub points_out: usize,
    /// Wall time, seconds. Per-view stages: the prepare's wall time split by the stages' shares
    /// of the work when the views are prepared first, or the views' times summed when each is
    /// prepared while the one before it registers (no refinement rounds, no joint step; then the
    /// per-view stages overlap `register` at 2 threads or more).
    pub seconds: f64,
}

/// Outcome of one view.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ViewStatus {
    /// The view that fixes the model frame: merged at its seed pose.
    Anchor,
    /// Registered and merged at the registered pose.
    Accepted,
    /// The rule rejected the registration; merged at the seed pose (policy keep-seed).
    SeedKept,
    /// The rule rejected the registration; left out of the model (policy exclude).
    Excluded,
    /// Unusable (unreadable, no points after cropping, non-finite pose): left out.
    Skipped,
}

/// Registration of one view.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ViewReport {
    /// View index in scan.json.
    pub index: usize,
    /// What became of the view.
    pub status: ViewStatus,
    /// Why (the failing check of the rule, or the load error).
    pub reason: String,
    /// Points after the per-view stages.
    pub points: usize,
    /// Recorded pose `T_world_camera` (the seed).
    #[serde(rename = "T_world_camera_seed")]
    pub seed: Option<Rows>,
    /// Final pose `T_world_camera` used for merging (absent for views left out).
    #[serde(rename = "T_world_camera")]
    pub pose: Option<Rows>,
    /// The view of the same base stop whose registered pose seeded this one's ICP, through the
    /// arm's recorded motion (`registration.stop_seed_gate_m`); absent: the recorded pose did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seeded_from_view: Option<usize>,
    /// Move of the view's centroid from the seed pose to the registered pose, millimetres.
    pub correction_mm: f64,
    /// Rotation from the seed pose to the registered pose, degrees.
    pub correction_deg: f64,
    /// ICP iterations (all levels, all passes).
    pub iterations: usize,
    /// ICP fitness at the finest level (see registration::icp).
    pub fitness: f64,
    /// ICP inlier point-to-plane RMSE, millimetres.
    pub inlier_rmse_mm: f64,
    /// Conditioning of the final ICP system.
    pub conditioning: f64,
    /// The smallest eigenvalue of the final ICP system over the directions it observed, over the
    /// largest (`conditioning` when none is unobserved): how near the view came to leaving one more
    /// direction unobserved (`registration.icp.unobserved_ratio`).
    #[serde(default)]
    pub observed_conditioning: f64,
    /// The directions of motion the view's surface left unobserved against the model, held at the
    /// seed (see `registration::icp`); empty when every direction is observed.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub unobserved: Vec<crate::registration::Unobserved>,
    /// Whether the finest ICP level converged.
    pub converged: bool,
    /// Per-level statistics of the last ICP run on this view.
    pub levels: Vec<crate::registration::LevelStats>,
}

/// The whole report.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FuseReport {
    /// [`REPORT_FORMAT`].
    pub format: String,
    /// The scan folder.
    pub scan: String,
    /// The configuration used, every derived value resolved.
    pub config: FuseConfig,
    /// The point the cameras look at (centre of the region of interest), world frame, metres.
    pub focus_world: Option<[f64; 3]>,
    /// Stages in order.
    pub stages: Vec<StageReport>,
    /// Views in scan order.
    pub views: Vec<ViewReport>,
    /// The joint refinement of the registered views, per level (empty when off).
    #[serde(default)]
    pub joint: Vec<crate::registration::JointLevelStats>,
    /// The floor plane removed: unit normal and offset (`n·p + d = 0`), and the points removed.
    pub floor: Option<FloorReport>,
    /// Clusters found and the one kept.
    pub clusters: Option<ClusterReport>,
    /// The hand-eye refined from the registered base stops (absent when the scan records none or
    /// the stage is off).
    #[serde(default)]
    pub hand_eye: Option<super::hand_eye::HandEyeReport>,
    /// Where more views would gain (see `pipeline::advice`); absent without a hand-eye report.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub advice: Option<super::advice::ScanAdvice>,
    /// Points in the final model.
    pub model_points: usize,
    /// Non-fatal events, in order (views skipped or rejected, stages that found nothing).
    pub warnings: Vec<String>,
    /// Total wall time, seconds.
    pub seconds: f64,
}

/// The floor found by the isolation stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FloorReport {
    /// Unit normal (world), pointing up.
    pub normal: [f64; 3],
    /// `d` in `n·p + d = 0`, metres.
    pub offset_m: f64,
    /// Points removed with it (floor band and below).
    pub removed: usize,
}

/// The clustering of the isolation stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClusterReport {
    /// Number of clusters.
    pub clusters: usize,
    /// Points of the kept cluster.
    pub kept: usize,
    /// Points of other clusters (clutter, walls) removed.
    pub removed_clusters: usize,
    /// Noise points removed.
    pub noise: usize,
}
