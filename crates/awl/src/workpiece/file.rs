//! The workpiece record `awl fuse` leaves beside the model (`workpiece.json`, format
//! `awl-workpiece/1`, read and written by [`crate::workpiece::json`]): the model file, where the tag
//! is on it (`T_world_tag`, world = the model's frame), the tag spec and every detection.

use nalgebra::{Isometry3, Vector3};
use serde::{Deserialize, Serialize};

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::pipeline::FuseOutput;
use crate::scan::{Scan, TagSpec};
pub use crate::segment::FloorPlane;
use crate::workpiece::refine::{RefineParams, Refinement, refine_on_model};
use crate::workpiece::tag_pose::{TagEstimateParams, TagSearch, ViewTagDetection, search_tags};

/// The format string of `workpiece.json`.
pub const WORKPIECE_FORMAT: &str = "awl-workpiece/1";
/// The file name `awl fuse` writes.
pub const WORKPIECE_FILE: &str = "workpiece.json";

/// Parameters of [`workpiece_from_fuse`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WorkpieceParams {
    /// Tag detection and averaging. Default: [`TagEstimateParams::default`].
    pub tag: TagEstimateParams,
    /// Refinement of the tag plane on the model (`None`: the averaged detections as they are).
    /// Default: `Some(RefineParams::default())`.
    pub refine: Option<RefineParams>,
}

impl Default for WorkpieceParams {
    fn default() -> Self {
        Self { tag: TagEstimateParams::default(), refine: Some(RefineParams::default()) }
    }
}

/// The content of `workpiece.json`.
#[derive(Debug, Clone, PartialEq)]
pub struct Workpiece {
    /// The model's file name, relative to `workpiece.json`'s folder (e.g. `model.ply`).
    pub model: String,
    /// The model's fingerprint (`None`: not recorded, as by awl before it had one: the model is
    /// then not checked, and `awl pierce` warns).
    pub model_check: Option<crate::workpiece::ModelCheck>,
    /// `T_world_tag`: the tag in the model's frame; None when no view saw the tag.
    pub world_from_tag: Option<Isometry3<f64>>,
    /// The tag (scan.json's `tag`).
    pub tag: TagSpec,
    /// The views searched for the tag.
    pub views_checked: Vec<usize>,
    /// Every tag detection in those views, used or not and why.
    pub detections: Vec<ViewTagDetection>,
    /// The plane refinement on the model, when run.
    pub refinement: Option<Refinement>,
    /// The floor the workpiece stood on while modeled (model frame), when fusion found one: faces
    /// standing on it end there ([`crate::workpiece::face`]).
    pub floor: Option<FloorPlane>,
    /// The hand-eye refined from the scan's base stops (`awl fuse`'s `hand_eye`), when the scan
    /// records one: the prior of `awl pierce`.
    pub hand_eye: Option<crate::pipeline::HandEyeReport>,
    /// Warnings for the user.
    pub warnings: Vec<String>,
}

/// The floor `fuse` removed (its report), if it found one, model frame.
pub fn floor_of_fuse(out: &FuseOutput) -> Option<FloorPlane> {
    out.report.floor.as_ref().and_then(|f| FloorPlane::new(Vector3::from(f.normal), f.offset_m))
}

impl Workpiece {
    /// How far apart the fuse found parts of the model (`hand_eye.rejected_disagreement_mm`), metres;
    /// 0 without a hand-eye record ([`crate::pierce::PierceParams::model_disagreement_m`]).
    pub fn model_disagreement_m(&self) -> f64 {
        self.hand_eye.as_ref().map_or(0.0, crate::pipeline::HandEyeReport::model_disagreement_m)
    }

    /// `T_world_tag`, or an error naming `path` and the field when no view saw the tag.
    ///
    /// # Errors
    /// [`Error::Field`] `T_world_tag` when it is missing.
    pub fn require_world_from_tag(&self, path: &std::path::Path) -> Result<Isometry3<f64>> {
        self.world_from_tag.ok_or_else(|| {
            Error::field(path, "T_world_tag", "missing: no view of the scan saw the tag (see `warnings`)")
        })
    }
}

/// Builds the workpiece record of a fused scan: the tag seen from the views with their registered
/// poses (`out.poses`), refined on the model, and the floor fusion removed. `None` when the scan
/// declares no tag. A tag that no view sees is not an error: `world_from_tag` is None and a warning
/// names the views checked.
///
/// # Errors
/// [`Error::Invalid`] for an unsupported tag; any error of loading a view.
pub fn workpiece_from_fuse(
    scan: &Scan,
    out: &FuseOutput,
    model_file: &str,
    params: &WorkpieceParams,
) -> Result<Option<Workpiece>> {
    workpiece_from_search(search_tags(scan, &params.tag)?.as_ref(), out, model_file, params)
}

/// [`workpiece_from_fuse`] from the scan's tag search, run beforehand (e.g. beside the fuse: it
/// needs no registered pose); `None` when there is no search (the scan declares no tag).
///
/// # Errors
/// [`Error::Invalid`] when the search has a view `out.poses` does not.
pub fn workpiece_from_search(
    search: Option<&TagSearch>,
    out: &FuseOutput,
    model_file: &str,
    params: &WorkpieceParams,
) -> Result<Option<Workpiece>> {
    let Some(search) = search else { return Ok(None) };
    let tag = search.tag.clone();
    let estimate = search.place(&out.poses, &params.tag)?;
    let model: &PointCloud = &out.model;
    let mut warnings = estimate.warnings;
    let mut world_from_tag = estimate.world_from_tag;
    let mut refinement = None;
    if let (Some(pose), Some(refine)) = (world_from_tag, &params.refine) {
        let r = refine_on_model(&pose, tag.size_m, model, &estimate.sightings, refine)?;
        if r.applied {
            world_from_tag = Some(r.world_from_tag);
        } else {
            warnings.push(format!("tag plane not refined on the model: {}", r.note));
        }
        refinement = Some(r);
    }
    Ok(Some(Workpiece {
        model: model_file.into(),
        model_check: Some(crate::workpiece::ModelCheck::of(model)),
        world_from_tag,
        tag,
        views_checked: estimate.views_checked,
        detections: estimate.detections,
        refinement,
        floor: floor_of_fuse(out),
        hand_eye: out.report.hand_eye.clone(),
        warnings,
    }))
}
