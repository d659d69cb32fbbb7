//! Files of `awl evaluate`: the initial pose it reads, and the folder it writes (`summary.json`,
//! `errors.ply`, `T_object_model.json`), each written atomically.

use std::path::{Path, PathBuf};

use nalgebra::Isometry3;
use serde_json::Value;

use crate::error::{Error, Result};
use crate::eval::Evaluation;
use crate::eval::heatmap::errors_ply;
use crate::io::scan::{pose_field, read_json};
use crate::io::write_atomic;
use crate::transform::{Rows, rows_from_isometry};

/// Names of the files [`write_evaluation`] writes.
pub const OUTPUT_FILES: [&str; 3] = ["summary.json", "errors.ply", "T_object_model.json"];

/// Reads a rigid transform from a JSON file: a bare 4x4 row-major matrix, or one under `key`
/// (e.g. `T_object_model`).
///
/// # Errors
/// [`Error::Io`]; [`Error::Format`] for invalid JSON (a NaN or infinity is named);
/// [`Error::Field`] naming the field for a value that is not a rigid 4x4 matrix.
pub fn read_transform(path: &Path, key: &str) -> Result<Isometry3<f64>> {
    let value: Value = read_json(path)?;
    let (field, matrix) = match value.get(key) {
        Some(m) => (key, m.clone()),
        None => ("(top level)", value),
    };
    let rows: Rows = serde_json::from_value(matrix)
        .map_err(|e| Error::field(path, field, format!("expected a 4x4 array of numbers: {e}")))?;
    pose_field(path, field, &rows)
}

/// Writes `dir/summary.json`, `dir/errors.ply` (heatmap clamped at the summary's `heatmap.max_mm`)
/// and `dir/T_object_model.json` (`{"T_object_model": 4x4}`), creating `dir`. Refuses to replace
/// any of `inputs`.
///
/// # Errors
/// [`Error::Invalid`] when an output is one of `inputs`; [`Error::Io`] when writing fails.
pub fn write_evaluation(dir: &Path, evaluation: &Evaluation, inputs: &[&Path]) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let outputs: Vec<PathBuf> = OUTPUT_FILES.iter().map(|f| dir.join(f)).collect();
    let resolve = |p: &Path| std::fs::canonicalize(p).ok();
    for out in &outputs {
        let Some(resolved) = resolve(out) else { continue };
        if inputs.iter().any(|i| resolve(i).as_deref() == Some(resolved.as_path())) {
            return Err(Error::invalid(out.display().to_string(), "refusing to overwrite an input file"));
        }
    }
    write_atomic(&outputs[0], pretty(&evaluation.summary)?.as_bytes())?;
    let max_m = evaluation.summary.heatmap.max_mm * 1e-3;
    write_atomic(&outputs[1], &errors_ply(&evaluation.model_object.points, &evaluation.distances_m, max_m)?)?;
    let t = serde_json::json!({ "T_object_model": rows_from_isometry(&evaluation.object_from_model) });
    write_atomic(&outputs[2], pretty(&t)?.as_bytes())
}

fn pretty<T: serde::Serialize>(value: &T) -> Result<String> {
    serde_json::to_string_pretty(value).map_err(|e| Error::invalid("evaluation JSON", e.to_string()))
}
