//! `workpiece.json` (`awl-workpiece/1`, see [`crate::workpiece::file`]) read and write, and the
//! targets file reader.
//!
//! ```json
//! { "format": "awl-workpiece/1", "model": "model.ply",
//!   "model_check": { "points": 41000, "bounds_min_m": [x,y,z], "bounds_max_m": [x,y,z], "sha256": "..." }
//!                  (absent when written by an older awl; see `workpiece::model_check`),
//!   "T_world_tag": [[...4x4 rows...]] | null,
//!   "tag": { "family": "tag36h11", "id": 0, "size": 0.1 },
//!   "views_checked": [0, 1, 3],
//!   "detections": [ { "view": 0, "id": 0, "corners_px": [[u, v] x4], "rmse_px": 0.2,
//!                     "flipped_by_depth": false, "T_world_tag": [[...]] | null, "used": true, "reason": "" } ],
//!   "refinement": { "applied": true, "points": 812, "rms_m": 0.0004, "tilt_rad": 0.003, "shift_m": 0.0008,
//!                   "note": "", "T_world_tag": [[...]] } | null,
//!   "floor": { "normal": [nx, ny, nz], "offset_m": d } | null,
//!   "hand_eye": { "T_ee_camera_recorded", "T_ee_camera_refined", "covariance", ... } (absent when
//!               the scan records no hand-eye; see `pipeline::HandEyeReport`),
//!   "warnings": [] }
//! ```

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::io::scan::{pose_field, read_json};
use crate::io::{read_bytes, write_atomic};
use crate::pipeline::HandEyeReport;
use crate::scan::TagSpec;
use crate::segment::FloorPlane;
use crate::transform::{Rows, rows_from_isometry};
use crate::workpiece::ModelCheck;
use crate::workpiece::file::{WORKPIECE_FORMAT, Workpiece};
use crate::workpiece::refine::Refinement;
use crate::workpiece::tag_pose::ViewTagDetection;
use crate::workpiece::target_spec::{TargetSpec, parse_targets};

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDetection {
    view: usize,
    id: u32,
    corners_px: [[f64; 2]; 4],
    rmse_px: Option<f64>,
    flipped_by_depth: bool,
    #[serde(rename = "T_world_tag")]
    world_tag: Option<Rows>,
    used: bool,
    reason: String,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRefinement {
    applied: bool,
    points: usize,
    rms_m: Option<f64>,
    tilt_rad: f64,
    shift_m: f64,
    note: String,
    #[serde(rename = "T_world_tag")]
    world_tag: Rows,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFloor {
    normal: [f64; 3],
    offset_m: f64,
}

#[derive(Serialize, Deserialize)]
struct RawWorkpiece {
    format: String,
    model: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    model_check: Option<ModelCheck>,
    #[serde(rename = "T_world_tag")]
    world_tag: Option<Rows>,
    tag: TagSpec,
    #[serde(default)]
    views_checked: Vec<usize>,
    #[serde(default)]
    detections: Vec<RawDetection>,
    #[serde(default)]
    refinement: Option<RawRefinement>,
    #[serde(default)]
    floor: Option<RawFloor>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    hand_eye: Option<HandEyeReport>,
    #[serde(default)]
    warnings: Vec<String>,
}

fn finite(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

/// Writes `workpiece` to `path` atomically (pretty JSON).
///
/// # Errors
/// [`Error::Io`] when the file cannot be written.
pub fn write_workpiece(path: &Path, workpiece: &Workpiece) -> Result<()> {
    let raw = RawWorkpiece {
        format: WORKPIECE_FORMAT.into(),
        model: workpiece.model.clone(),
        model_check: workpiece.model_check.clone(),
        world_tag: workpiece.world_from_tag.as_ref().map(rows_from_isometry),
        tag: workpiece.tag.clone(),
        views_checked: workpiece.views_checked.clone(),
        detections: workpiece
            .detections
            .iter()
            .map(|d| RawDetection {
                view: d.view,
                id: d.id,
                corners_px: d.corners_px,
                rmse_px: finite(d.rmse_px),
                flipped_by_depth: d.flipped_by_depth,
                world_tag: d.world_from_tag.as_ref().map(rows_from_isometry),
                used: d.used,
                reason: d.reason.clone(),
            })
            .collect(),
        refinement: workpiece.refinement.as_ref().map(|r| RawRefinement {
            applied: r.applied,
            points: r.points,
            rms_m: finite(r.rms_m),
            tilt_rad: r.tilt_rad,
            shift_m: r.shift_m,
            note: r.note.clone(),
            world_tag: rows_from_isometry(&r.world_from_tag),
        }),
        floor: workpiece.floor.map(|f| RawFloor { normal: f.normal.into(), offset_m: f.offset_m }),
        hand_eye: workpiece.hand_eye.clone(),
        warnings: workpiece.warnings.clone(),
    };
    let text = serde_json::to_string_pretty(&raw).map_err(|e| Error::invalid("workpiece.json", e.to_string()))?;
    write_atomic(path, text.as_bytes())
}

/// Reads and validates a `workpiece.json`.
///
/// # Errors
/// [`Error::Io`] when it cannot be read; [`Error::Format`] for invalid JSON or a missing key;
/// [`Error::Field`] naming the field for a wrong `format`, a non-rigid matrix
/// (`T_world_tag`, `detections[i].T_world_tag`, `refinement.T_world_tag`) or a bad tag size.
pub fn read_workpiece(path: &Path) -> Result<Workpiece> {
    let raw: RawWorkpiece = read_json(path)?;
    if raw.format != WORKPIECE_FORMAT {
        return Err(Error::field(path, "format", format!("expected \"{WORKPIECE_FORMAT}\", got \"{}\"", raw.format)));
    }
    if !(raw.tag.size_m.is_finite() && raw.tag.size_m > 0.0) {
        return Err(Error::field(path, "tag.size", format!("must be a positive number, got {}", raw.tag.size_m)));
    }
    if raw.model.trim().is_empty() {
        return Err(Error::field(path, "model", "empty file name"));
    }
    let world_from_tag = raw.world_tag.map(|r| pose_field(path, "T_world_tag", &r)).transpose()?;
    let detections = raw
        .detections
        .into_iter()
        .enumerate()
        .map(|(i, d)| {
            let field = format!("detections[{i}].T_world_tag");
            Ok(ViewTagDetection {
                view: d.view,
                id: d.id,
                corners_px: d.corners_px,
                rmse_px: d.rmse_px.unwrap_or(f64::NAN),
                flipped_by_depth: d.flipped_by_depth,
                world_from_tag: d.world_tag.map(|r| pose_field(path, &field, &r)).transpose()?,
                used: d.used,
                reason: d.reason,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    let refinement = raw
        .refinement
        .map(|r| {
            Ok::<_, Error>(Refinement {
                world_from_tag: pose_field(path, "refinement.T_world_tag", &r.world_tag)?,
                applied: r.applied,
                points: r.points,
                rms_m: r.rms_m.unwrap_or(f64::NAN),
                tilt_rad: r.tilt_rad,
                shift_m: r.shift_m,
                note: r.note,
            })
        })
        .transpose()?;
    let floor = raw
        .floor
        .map(|f| {
            FloorPlane::new(f.normal.into(), f.offset_m).ok_or_else(|| {
                Error::field(path, "floor", "normal must be a non-zero finite vector and offset_m finite")
            })
        })
        .transpose()?;
    if let Some(c) = &raw.model_check {
        let finite = c.bounds_min_m.iter().chain(&c.bounds_max_m).all(|v| v.is_finite());
        if !finite || c.sha256.len() != 64 || !c.sha256.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err(Error::field(
                path,
                "model_check",
                "needs finite bounds and a 64-digit hex sha256 (as awl fuse writes it)",
            ));
        }
    }
    Ok(Workpiece {
        model: raw.model,
        model_check: raw.model_check,
        world_from_tag,
        tag: raw.tag,
        views_checked: raw.views_checked,
        detections,
        refinement,
        floor,
        hand_eye: match raw.hand_eye {
            Some(h) => {
                h.used().map_err(|e| Error::field(path, "hand_eye", e.to_string()))?;
                Some(h)
            }
            None => None,
        },
        warnings: raw.warnings,
    })
}

/// Reads a targets file (see [`crate::workpiece::target_spec`]).
///
/// # Errors
/// [`Error::Io`] when it cannot be read; the errors of [`parse_targets`].
pub fn read_targets(path: &Path) -> Result<Vec<TargetSpec>> {
    let bytes = read_bytes(path)?;
    let text = String::from_utf8(bytes).map_err(|_| Error::format(path, "not UTF-8 text"))?;
    parse_targets(path, &text)
}
