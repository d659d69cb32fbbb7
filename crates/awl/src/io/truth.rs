//! `truth.json`: what a simulator knows and a rig does not. Read by evaluation and tests only;
//! the pipeline never reads it.

use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Point3, Vector3};
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use crate::error::{Error, Result};
use crate::io::scan::{pose_field, read_json};
use crate::io::write_atomic;
use crate::transform::{Rows, rows_from_isometry};

/// A target on the workpiece, in the object frame (and, in piercing shots, in the world frame).
#[derive(Debug, Clone, PartialEq)]
pub struct TruthTarget {
    /// Name, e.g. `face-centre`.
    pub name: String,
    /// Target point, object frame, metres.
    pub p_object: Point3<f64>,
    /// Outward unit surface normal at the target, object frame.
    pub n_object: Vector3<f64>,
    /// Target point in the world frame, when the file gives it.
    pub p_world: Option<Point3<f64>>,
    /// Outward normal in the world frame, when the file gives it.
    pub n_world: Option<Vector3<f64>>,
}

/// True poses of one view.
#[derive(Debug, Clone, PartialEq)]
pub struct TruthView {
    /// True `T_world_camera`.
    pub world_from_camera: Isometry3<f64>,
    /// True `T_world_base`, when given.
    pub world_from_base: Option<Isometry3<f64>>,
    /// True `T_base_ee`, when given.
    pub base_from_ee: Option<Isometry3<f64>>,
    /// 8-bit PNG labelling each depth pixel (0 none, 1 floor, 2 workpiece, 3 clutter or wall), relative to the scan folder.
    pub label: Option<PathBuf>,
    /// Every other key of the view (e.g. a capture's `tag_corners_px`), kept as is.
    pub extra: Map<String, Value>,
}

/// Ground truth of a simulated or benchmark scan.
#[derive(Debug, Clone, PartialEq)]
pub struct Truth {
    /// The CAD mesh, relative to the scan folder.
    pub cad: PathBuf,
    /// `T_world_object`: the CAD model's pose in the world.
    pub world_from_object: Isometry3<f64>,
    /// `T_world_tag` (x right, y up, z out of the face), when there is a tag.
    pub world_from_tag: Option<Isometry3<f64>>,
    /// The true hand-eye `T_ee_camera`, when given.
    pub ee_from_camera: Option<Isometry3<f64>>,
    /// True poses, one per view of the scan.
    pub views: Vec<TruthView>,
    /// Targets on the workpiece.
    pub targets: Vec<TruthTarget>,
    /// Every other key of the file, kept as is.
    pub extra: Map<String, Value>,
}

#[derive(Deserialize, Serialize)]
struct RawTarget {
    name: String,
    p_object: [f64; 3],
    n_object: [f64; 3],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    p_world: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    n_world: Option<[f64; 3]>,
}

#[derive(Deserialize, Serialize)]
struct RawTruthView {
    #[serde(rename = "T_world_camera")]
    world_camera: Rows,
    #[serde(rename = "T_world_base", default, skip_serializing_if = "Option::is_none")]
    world_base: Option<Rows>,
    #[serde(rename = "T_base_ee", default, skip_serializing_if = "Option::is_none")]
    base_ee: Option<Rows>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    label: Option<PathBuf>,
    #[serde(flatten)]
    extra: Map<String, Value>,
}

#[derive(Deserialize, Serialize)]
struct RawTruth {
    cad: PathBuf,
    #[serde(rename = "T_world_object")]
    world_object: Rows,
    #[serde(rename = "T_world_tag", default, skip_serializing_if = "Option::is_none")]
    world_tag: Option<Rows>,
    #[serde(rename = "T_ee_camera", default, skip_serializing_if = "Option::is_none")]
    ee_camera: Option<Rows>,
    #[serde(default)]
    views: Vec<RawTruthView>,
    #[serde(default)]
    targets: Vec<RawTarget>,
    #[serde(flatten)]
    extra: Map<String, Value>,
}

fn finite3(path: &Path, field: &str, v: [f64; 3]) -> Result<[f64; 3]> {
    if v.iter().all(|x| x.is_finite()) { Ok(v) } else { Err(Error::field(path, field, "not finite")) }
}

/// Reads `truth.json` from a scan folder (or the file itself).
///
/// # Errors
/// [`Error::Io`], [`Error::Format`] for invalid JSON, [`Error::Field`] for a non-rigid pose or a
/// non-finite or zero-length target normal.
pub fn read_truth(dir_or_file: &Path) -> Result<Truth> {
    let path = if dir_or_file.is_dir() { dir_or_file.join("truth.json") } else { dir_or_file.to_path_buf() };
    let raw: RawTruth = read_json(&path)?;
    let views = raw
        .views
        .iter()
        .enumerate()
        .map(|(i, v)| {
            Ok(TruthView {
                world_from_camera: pose_field(&path, &format!("views[{i}].T_world_camera"), &v.world_camera)?,
                world_from_base: v
                    .world_base
                    .map(|r| pose_field(&path, &format!("views[{i}].T_world_base"), &r))
                    .transpose()?,
                base_from_ee: v.base_ee.map(|r| pose_field(&path, &format!("views[{i}].T_base_ee"), &r)).transpose()?,
                label: v.label.clone(),
                extra: v.extra.clone(),
            })
        })
        .collect::<Result<Vec<_>>>()?;
    let targets = raw
        .targets
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let n = Vector3::from(finite3(&path, &format!("targets[{i}].n_object"), t.n_object)?);
            if n.norm() < 1e-9 {
                return Err(Error::field(&path, format!("targets[{i}].n_object"), "zero-length normal"));
            }
            Ok(TruthTarget {
                name: t.name.clone(),
                p_object: Point3::from(finite3(&path, &format!("targets[{i}].p_object"), t.p_object)?),
                n_object: n.normalize(),
                p_world: t.p_world.map(Point3::from),
                n_world: t.n_world.map(|n| Vector3::from(n).normalize()),
            })
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(Truth {
        cad: raw.cad,
        world_from_object: pose_field(&path, "T_world_object", &raw.world_object)?,
        world_from_tag: raw.world_tag.map(|r| pose_field(&path, "T_world_tag", &r)).transpose()?,
        ee_from_camera: raw.ee_camera.map(|r| pose_field(&path, "T_ee_camera", &r)).transpose()?,
        views,
        targets,
        extra: raw.extra,
    })
}

/// Writes `dir/truth.json` atomically.
///
/// # Errors
/// [`Error::Io`] when it cannot be written.
pub fn write_truth(dir: &Path, truth: &Truth) -> Result<()> {
    let raw = RawTruth {
        cad: truth.cad.clone(),
        world_object: rows_from_isometry(&truth.world_from_object),
        world_tag: truth.world_from_tag.as_ref().map(rows_from_isometry),
        ee_camera: truth.ee_from_camera.as_ref().map(rows_from_isometry),
        views: truth
            .views
            .iter()
            .map(|v| RawTruthView {
                world_camera: rows_from_isometry(&v.world_from_camera),
                world_base: v.world_from_base.as_ref().map(rows_from_isometry),
                base_ee: v.base_from_ee.as_ref().map(rows_from_isometry),
                label: v.label.clone(),
                extra: v.extra.clone(),
            })
            .collect(),
        targets: truth
            .targets
            .iter()
            .map(|t| RawTarget {
                name: t.name.clone(),
                p_object: t.p_object.coords.into(),
                n_object: t.n_object.into(),
                p_world: t.p_world.map(|p| p.coords.into()),
                n_world: t.n_world.map(Into::into),
            })
            .collect(),
        extra: truth.extra.clone(),
    };
    let text = serde_json::to_string_pretty(&raw).map_err(|e| Error::invalid("truth.json", e.to_string()))?;
    write_atomic(&dir.join("truth.json"), text.as_bytes())
}
