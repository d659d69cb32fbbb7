//! Target strings and targets files.
//!
//! A target string is `x,y,z` (a point to snap onto the surface) or `face-centre@x,y,z` (the centre
//! of the planar face nearest that point), model frame, metres; numbers may be negative or use
//! exponents (`-0.1,2e-1,0.3`), spaces around them are ignored. A targets file is either one target
//! string per line (blank lines and `#` comments skipped) or JSON: an array of target strings, or an
//! object whose `targets` key holds one.

use std::path::Path;

use nalgebra::Point3;
use serde_json::Value;

use crate::error::{Error, Result};

/// The prefix of a face-centre target.
pub const FACE_CENTRE_PREFIX: &str = "face-centre@";

/// A requested target (model frame, metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TargetSpec {
    /// Snap this point onto the surface.
    Point(Point3<f64>),
    /// The centre of the planar face nearest this point.
    FaceCentre(Point3<f64>),
}

impl std::fmt::Display for TargetSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Point(p) => write!(f, "{},{},{}", p.x, p.y, p.z),
            Self::FaceCentre(p) => write!(f, "{FACE_CENTRE_PREFIX}{},{},{}", p.x, p.y, p.z),
        }
    }
}

fn parse_point(text: &str) -> std::result::Result<Point3<f64>, String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(format!("expected 3 comma-separated numbers x,y,z, got {}", parts.len()));
    }
    let mut v = [0.0; 3];
    for (slot, part) in v.iter_mut().zip(&parts) {
        *slot = part.parse::<f64>().map_err(|_| format!("`{part}` is not a number"))?;
        if !slot.is_finite() {
            return Err(format!("`{part}` is not finite"));
        }
    }
    Ok(Point3::new(v[0], v[1], v[2]))
}

impl TargetSpec {
    /// Parses a target string (module docs).
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the string when it is malformed.
    pub fn parse(text: &str) -> Result<Self> {
        let t = text.trim();
        let parsed = match t.strip_prefix(FACE_CENTRE_PREFIX) {
            Some(rest) => parse_point(rest).map(Self::FaceCentre),
            None if t.contains('@') => {
                Err(format!("unknown target kind (expected `x,y,z` or `{FACE_CENTRE_PREFIX}x,y,z`)"))
            }
            None => parse_point(t).map(Self::Point),
        };
        parsed.map_err(|m| Error::invalid(format!("target `{t}`"), m))
    }

    /// The point given with the target.
    pub fn point(&self) -> Point3<f64> {
        match self {
            Self::Point(p) | Self::FaceCentre(p) => *p,
        }
    }
}

/// Parses the text of a targets file (module docs); `path` is only used to name the file in errors.
///
/// # Errors
/// [`Error::Format`] for invalid JSON; [`Error::Field`] naming `targets[i]` or `line N` for a bad
/// target; [`Error::Field`] when the file holds no target or more than [`MAX_TARGETS`].
pub fn parse_targets(path: &Path, text: &str) -> Result<Vec<TargetSpec>> {
    let trimmed = text.trim_start();
    let targets = if trimmed.starts_with('[') || trimmed.starts_with('{') {
        let json: Value = serde_json::from_str(text).map_err(|e| Error::format(path, format!("invalid JSON: {e}")))?;
        let (list, field) = match &json {
            Value::Array(a) => (a, "targets"),
            Value::Object(o) => match o.get("targets") {
                Some(Value::Array(a)) => (a, "targets"),
                _ => return Err(Error::field(path, "targets", "expected an array of target strings")),
            },
            _ => return Err(Error::format(path, "expected an array or an object")),
        };
        list.iter()
            .enumerate()
            .map(|(i, v)| {
                let s = v.as_str().ok_or_else(|| Error::field(path, format!("{field}[{i}]"), "expected a string"))?;
                TargetSpec::parse(s).map_err(|e| Error::field(path, format!("{field}[{i}]"), e.to_string()))
            })
            .collect::<Result<Vec<_>>>()?
    } else {
        text.lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'))
            .map(|(i, l)| {
                TargetSpec::parse(l).map_err(|e| Error::field(path, format!("line {}", i + 1), e.to_string()))
            })
            .collect::<Result<Vec<_>>>()?
    };
    if targets.is_empty() {
        return Err(Error::field(path, "targets", "no target in the file"));
    }
    check_target_count(targets.len()).map_err(|m| Error::field(path, "targets", m))?;
    Ok(targets)
}

/// The most targets one plan takes (each is snapped onto the model and fitted, a few milliseconds
/// each; a robot program of more moves than this is a mistake): split a longer list into plans.
pub const MAX_TARGETS: usize = 1000;

/// Refuses more than [`MAX_TARGETS`] targets; the message says the limit and what to do.
///
/// # Errors
/// The message, for the caller to name the file or option.
pub fn check_target_count(count: usize) -> std::result::Result<(), String> {
    if count > MAX_TARGETS {
        return Err(format!(
            "{count} targets, more than the {MAX_TARGETS} one plan takes: split them into several plans"
        ));
    }
    Ok(())
}

/// `specs` with each target once, in the order first asked, and a warning for each one dropped
/// (a target given twice would be pierced twice).
pub fn unique_targets(specs: &[TargetSpec]) -> (Vec<TargetSpec>, Vec<String>) {
    let mut unique: Vec<TargetSpec> = Vec::with_capacity(specs.len());
    let mut warnings = Vec::new();
    for (i, s) in specs.iter().enumerate() {
        if unique.contains(s) {
            warnings.push(format!("target {i} ({s}) was given before: planned once, pierced once"));
        } else {
            unique.push(*s);
        }
    }
    (unique, warnings)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_target_given_three_times_is_planned_once_with_warnings() {
        let a = TargetSpec::parse("0.1,0.2,0.3").expect("a");
        let b = TargetSpec::parse("face-centre@0.1,0.2,0.3").expect("b");
        let (unique, warnings) = unique_targets(&[a, b, a, a]);
        assert_eq!(unique, vec![a, b]);
        assert_eq!(warnings.len(), 2);
        assert!(warnings[0].starts_with("target 2 (") && warnings[0].contains("planned once"), "{warnings:?}");
    }

    #[test]
    fn parses_points_faces_and_negative_numbers() {
        assert_eq!(TargetSpec::parse("-0.1,0.2,0.3").ok(), Some(TargetSpec::Point(Point3::new(-0.1, 0.2, 0.3))));
        assert_eq!(
            TargetSpec::parse(" face-centre@ 0.5 , -2e-1,-0.25 ").ok(),
            Some(TargetSpec::FaceCentre(Point3::new(0.5, -0.2, -0.25)))
        );
        for bad in ["0.1,0.2", "0.1,x,0.3", "edge@0,0,0", "nan,0,0", "0,0,0,0"] {
            let e = TargetSpec::parse(bad).expect_err(bad).to_string();
            assert!(e.contains(bad.trim()), "{e}");
        }
    }

    #[test]
    fn parses_line_and_json_files_with_located_errors() {
        let path = Path::new("t.txt");
        let lines = parse_targets(path, "# picks\n0,0,0.3\n\nface-centre@-0.1,0,0.3\n").expect("lines");
        assert_eq!(lines.len(), 2);
        let json = parse_targets(Path::new("t.json"), r#"{"targets": ["1,2,3", "face-centre@0,0,-1"]}"#).expect("json");
        assert_eq!(json[1], TargetSpec::FaceCentre(Point3::new(0.0, 0.0, -1.0)));
        let e = parse_targets(path, "0,0,0\n0,0\n").expect_err("line 2").to_string();
        assert!(e.contains("t.txt") && e.contains("line 2"), "{e}");
        let e = parse_targets(Path::new("t.json"), r#"["0,0,0", 5]"#).expect_err("number").to_string();
        assert!(e.contains("targets[1]"), "{e}");
        assert!(parse_targets(path, "# nothing\n").is_err());
    }
}
