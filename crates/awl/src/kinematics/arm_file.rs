//! The arm file `awl-arm/1`: a 6R arm's standard DH table (see [`crate::kinematics`]), joint
//! limits and flange, for an arm that is not built in.
//!
//! ```json
//! {
//!   "format": "awl-arm/1",
//!   "name": "my-ur5e",
//!   "dh": [
//!     {"a": 0, "alpha": 1.5707963267948966, "d": 0.1625, "theta_offset": 0},
//!     ... six rows, joint 1 first ...
//!   ],
//!   "limits": [[-6.283185307179586, 6.283185307179586], ... six [lower, upper] pairs ...],
//!   "T_dh6_flange": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
//! }
//! ```
//!
//! Metres and radians; `theta_offset` may be left out (0), as may `T_dh6_flange` (identity; a
//! row-major rigid 4x4). Twists and offsets within 1e-6 rad of a multiple of pi/2 are taken as
//! exact. Every error names the file and the field (`dh[2].alpha`, `limits[4]`).

use std::path::Path;

use nalgebra::Isometry3;
use serde_json::Value;

use crate::error::{Error, Result};
use crate::io::scan::{parse_json, pose_field};
use crate::kinematics::{Arm, DhJoint};
use crate::transform::{Rows, rows_from_isometry};

/// The `format` value of an arm file.
pub const ARM_FORMAT: &str = "awl-arm/1";

fn number(path: &Path, field: &str, v: Option<&Value>) -> Result<f64> {
    let v = v.ok_or_else(|| Error::field(path, field, "missing"))?;
    let x = v.as_f64().ok_or_else(|| Error::field(path, field, format!("must be a number, got {v}")))?;
    if !x.is_finite() {
        return Err(Error::field(path, field, format!("must be finite, got {x}")));
    }
    Ok(x)
}

/// Parses the text of an arm file (`path` only names it in errors).
///
/// # Errors
/// [`Error::Format`] for invalid JSON (a non-finite number included); [`Error::Field`] naming
/// `format`, `name`, `dh` (not 6 rows), `dh[i].a` / `alpha` / `d` / `theta_offset` (missing, not
/// a number), `limits` (not 6 pairs), `limits[i]` (not finite, reversed, beyond +-4 pi) or
/// `T_dh6_flange` (not rigid).
pub fn parse_arm(path: &Path, bytes: &[u8]) -> Result<Arm> {
    let doc: Value = parse_json(path, bytes)?;
    let obj = doc.as_object().ok_or_else(|| Error::format(path, "an arm file is a JSON object"))?;
    match obj.get("format").and_then(Value::as_str) {
        Some(ARM_FORMAT) => {}
        other => {
            return Err(Error::field(path, "format", format!("expected \"{ARM_FORMAT}\", got {other:?}")));
        }
    }
    let name = match obj.get("name") {
        Some(Value::String(s)) if !s.trim().is_empty() => s.trim().to_string(),
        Some(v) => return Err(Error::field(path, "name", format!("must be a non-empty string, got {v}"))),
        None => return Err(Error::field(path, "name", "missing")),
    };
    let rows =
        obj.get("dh").and_then(Value::as_array).ok_or_else(|| Error::field(path, "dh", "missing or not a list"))?;
    if rows.len() != 6 {
        return Err(Error::field(path, "dh", format!("has {} rows; a 6-joint arm needs exactly 6", rows.len())));
    }
    let mut dh = [DhJoint { a: 0.0, alpha: 0.0, d: 0.0, theta_offset: 0.0 }; 6];
    for (i, row) in rows.iter().enumerate() {
        let field = |k: &str| format!("dh[{i}].{k}");
        let row = row.as_object().ok_or_else(|| {
            Error::field(path, format!("dh[{i}]"), "must be an object {\"a\", \"alpha\", \"d\", \"theta_offset\"}")
        })?;
        if let Some(k) = row.keys().find(|k| !["a", "alpha", "d", "theta_offset"].contains(&k.as_str())) {
            return Err(Error::field(path, field(k), "unknown key (expected a, alpha, d, theta_offset)"));
        }
        dh[i] = DhJoint {
            a: number(path, &field("a"), row.get("a"))?,
            alpha: number(path, &field("alpha"), row.get("alpha"))?,
            d: number(path, &field("d"), row.get("d"))?,
            theta_offset: match row.get("theta_offset") {
                None => 0.0,
                v => number(path, &field("theta_offset"), v)?,
            },
        };
    }
    let pairs = obj
        .get("limits")
        .and_then(Value::as_array)
        .ok_or_else(|| Error::field(path, "limits", "missing or not a list"))?;
    if pairs.len() != 6 {
        return Err(Error::field(path, "limits", format!("has {} pairs; a 6-joint arm needs exactly 6", pairs.len())));
    }
    let mut limits = [[0.0; 2]; 6];
    for (i, pair) in pairs.iter().enumerate() {
        let field = format!("limits[{i}]");
        let values = pair.as_array().filter(|p| p.len() == 2).ok_or_else(|| {
            Error::field(path, &field, format!("must be a pair [lower, upper] in radians, got {pair}"))
        })?;
        limits[i] = [number(path, &field, values.first())?, number(path, &field, values.get(1))?];
    }
    let dh6_from_flange = match obj.get("T_dh6_flange") {
        None => Isometry3::identity(),
        Some(v) => {
            let rows: Rows = serde_json::from_value(v.clone())
                .map_err(|e| Error::field(path, "T_dh6_flange", format!("must be a 4x4 row-major matrix: {e}")))?;
            pose_field(path, "T_dh6_flange", &rows)?
        }
    };
    Arm::new(&name, dh, limits, dh6_from_flange).map_err(|e| match e {
        Error::Invalid { what, message } => {
            let field = what.rsplit_once(": ").map_or(what.as_str(), |(_, f)| f).to_string();
            Error::field(path, field, message)
        }
        other => other,
    })
}

/// Reads an arm file.
///
/// # Errors
/// [`Error::Io`] when it cannot be read, else as [`parse_arm`].
pub fn read_arm(path: &Path) -> Result<Arm> {
    parse_arm(path, &crate::io::read_bytes_at_most(path, crate::io::MAX_JSON_BYTES)?)
}

/// The JSON text of an arm file for `arm` (what [`parse_arm`] reads back to the same arm).
pub fn arm_json(arm: &Arm) -> String {
    let dh: Vec<Value> = arm
        .dh
        .iter()
        .map(|j| serde_json::json!({"a": j.a, "alpha": j.alpha, "d": j.d, "theta_offset": j.theta_offset}))
        .collect();
    let doc = serde_json::json!({
        "format": ARM_FORMAT,
        "name": arm.name,
        "dh": dh,
        "limits": arm.limits,
        "T_dh6_flange": rows_from_isometry(&arm.dh6_from_flange),
    });
    serde_json::to_string_pretty(&doc).unwrap_or_default()
}
