//! The hand-eye poses file `awl-handeye/1` (format in [`crate::handeye`]'s docs): read with every
//! error naming the file, the pose index and the field; written atomically.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::handeye::HandEyePose;
use crate::io::scan::{parse_json, pose_field};
use crate::io::write_atomic;
use crate::transform::{Rows, rows_from_isometry};

/// The `format` value of a poses file.
pub const HANDEYE_FORMAT: &str = "awl-handeye/1";

#[derive(Deserialize, Serialize)]
struct RawPose {
    #[serde(rename = "T_base_ee")]
    base_ee: Rows,
    #[serde(rename = "T_camera_target")]
    camera_target: Rows,
}

/// The most poses a poses file may hold (the default [`crate::handeye::HandEyeParams::max_poses`]);
/// a longer list is refused while it is read, before its poses are stored.
pub const MAX_FILE_POSES: usize = 100_000;

/// The largest poses file read, bytes: 4 kB a pose (a pretty-printed pose with 17-digit numbers
/// takes about 1.5 kB).
pub const MAX_FILE_BYTES: u64 = 4096 * MAX_FILE_POSES as u64;

#[derive(Deserialize, Serialize)]
struct RawPoses {
    format: String,
    #[serde(deserialize_with = "bounded_poses")]
    poses: Vec<RawPose>,
}

/// The `poses` list, refused once it holds more than [`MAX_FILE_POSES`] entries (as it is parsed).
fn bounded_poses<'de, D: serde::Deserializer<'de>>(deserializer: D) -> std::result::Result<Vec<RawPose>, D::Error> {
    crate::io::scan::at_most(deserializer, MAX_FILE_POSES, || {
        format!("more than {MAX_FILE_POSES} poses: split the capture, or calibrate from a subset")
    })
}

/// For an error at 1-based (line, column): the field `poses[i].KEY` whose matrix holds it, found by
/// counting the pose keys before that point (each pose has each key once).
fn locate(text: &str, line: usize, column: usize) -> Option<(usize, &'static str)> {
    let offset = text.split_inclusive('\n').take(line.saturating_sub(1)).map(str::len).sum::<usize>() + column;
    let before = text.get(..offset.min(text.len()))?;
    ["T_base_ee", "T_camera_target"]
        .iter()
        .filter_map(|key| {
            let quoted = format!("\"{key}\"");
            before.rfind(&quoted).map(|at| (at, *key, before.matches(&quoted).count()))
        })
        .max_by_key(|(at, _, _)| *at)
        .map(|(_, key, count)| (count - 1, key))
}

/// Parses the text of a poses file (`path` only names it in errors).
///
/// # Errors
/// [`Error::Format`] for invalid JSON or more than [`MAX_FILE_POSES`] poses; [`Error::Field`] naming `format`, `poses` or
/// `poses[i].T_base_ee` / `poses[i].T_camera_target` for a wrong format tag, a non-finite number
/// (located by pose and field), a malformed or non-rigid matrix.
pub fn parse_poses(path: &Path, bytes: &[u8]) -> Result<Vec<HandEyePose>> {
    let raw: RawPoses = match serde_json::from_slice(bytes) {
        Ok(raw) => raw,
        Err(e) => {
            let text = String::from_utf8_lossy(bytes);
            let general = parse_json::<serde_json::Value>(path, bytes).err();
            let message = match general {
                Some(Error::Format { message, .. }) => message,
                _ => e.to_string(),
            };
            if message.contains(&format!("more than {MAX_FILE_POSES} poses")) {
                return Err(Error::field(path, "poses", message));
            }
            return Err(match locate(&text, e.line(), e.column()) {
                Some((i, _)) if message.starts_with("missing field") => {
                    Error::field(path, format!("poses[{i}]"), message)
                }
                Some((i, key)) => Error::field(path, format!("poses[{i}].{key}"), message),
                None => Error::format(path, message),
            });
        }
    };
    if raw.format != HANDEYE_FORMAT {
        return Err(Error::field(path, "format", format!("expected \"{HANDEYE_FORMAT}\", got \"{}\"", raw.format)));
    }
    raw.poses
        .iter()
        .enumerate()
        .map(|(i, p)| {
            Ok(HandEyePose {
                base_from_ee: pose_field(path, &format!("poses[{i}].T_base_ee"), &p.base_ee)?,
                camera_from_target: pose_field(path, &format!("poses[{i}].T_camera_target"), &p.camera_target)?,
            })
        })
        .collect()
}

/// Reads a poses file.
///
/// # Errors
/// [`Error::Io`] when it cannot be read; [`Error::Format`] when it is larger than
/// [`MAX_FILE_BYTES`] (checked before reading); else as [`parse_poses`].
pub fn read_poses(path: &Path) -> Result<Vec<HandEyePose>> {
    parse_poses(path, &crate::io::read_bytes_at_most(path, MAX_FILE_BYTES)?)
}

/// The JSON text of a poses file.
pub fn poses_json(poses: &[HandEyePose]) -> String {
    let raw = RawPoses {
        format: HANDEYE_FORMAT.into(),
        poses: poses
            .iter()
            .map(|p| RawPose {
                base_ee: rows_from_isometry(&p.base_from_ee),
                camera_target: rows_from_isometry(&p.camera_from_target),
            })
            .collect(),
    };
    serde_json::to_string_pretty(&raw).unwrap_or_default()
}

/// Writes a poses file atomically.
///
/// # Errors
/// [`Error::Io`] when it cannot be written.
pub fn write_poses(path: &Path, poses: &[HandEyePose]) -> Result<()> {
    write_atomic(path, poses_json(poses).as_bytes())
}

/// Reads `T_ee_camera` from a JSON file holding that key at its top level (what
/// `awl calibrate hand-eye -o` writes, or a hand-written `{"T_ee_camera": [[...4x4 rows...]]}`).
///
/// # Errors
/// [`Error::Io`] when unreadable; [`Error::Format`] for invalid JSON; [`Error::Field`] naming
/// `T_ee_camera` when missing or not a rigid transform.
pub fn read_ee_from_camera(path: &Path) -> Result<nalgebra::Isometry3<f64>> {
    #[derive(Deserialize)]
    struct Raw {
        #[serde(rename = "T_ee_camera")]
        ee_camera: Option<Rows>,
    }
    let raw: Raw = crate::io::scan::read_json(path)?;
    let rows = raw.ee_camera.ok_or_else(|| Error::field(path, "T_ee_camera", "missing"))?;
    pose_field(path, "T_ee_camera", &rows)
}
