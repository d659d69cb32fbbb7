//! A TF buffer: the transforms of `/tf` (timed samples per parent -> child link) and `/tf_static`,
//! and lookups of `target_from_source` at a stamp through the tree, each link interpolated between
//! its two samples around the stamp (translation linearly, rotation by slerp).

use std::collections::HashMap;

use nalgebra::{Isometry3, Translation3};

/// One parent -> child link of the tree.
#[derive(Debug, Clone, Default)]
struct Link {
    parent: String,
    /// `parent_from_child` from `/tf_static`.
    fixed: Option<Isometry3<f64>>,
    /// Timed `parent_from_child` samples from `/tf`, sorted by stamp (ns) once [`TfBuffer::finish`] ran.
    samples: Vec<(i64, Isometry3<f64>)>,
}

/// Why a lookup failed.
#[derive(Debug, Clone, PartialEq)]
pub enum LookupError {
    /// The two frames are not connected in the tree (a frame unknown, or in another tree).
    NoPath {
        /// The frame looked up from.
        source: String,
        /// The frame looked up in.
        target: String,
        /// The frames the buffer knows.
        known: Vec<String>,
    },
    /// The stamp is before the first or after the last sample of a link.
    Outside {
        /// The link's parent frame.
        parent: String,
        /// The link's child frame.
        child: String,
        /// The first and last sample stamps of the link, ns.
        range_ns: (i64, i64),
    },
    /// The two samples around the stamp are farther apart than the buffer's largest gap.
    Gap {
        /// The link's parent frame.
        parent: String,
        /// The link's child frame.
        child: String,
        /// The samples before and after the stamp, ns.
        between_ns: (i64, i64),
    },
}

impl std::fmt::Display for LookupError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = |ns: i64| ns as f64 * 1e-9;
        match self {
            Self::NoPath { source, target, known } => {
                write!(f, "no TF path from `{source}` to `{target}` (frames in the bag: {})", known.join(", "))
            }
            Self::Outside { parent, child, range_ns } => write!(
                f,
                "the TF link `{parent}` -> `{child}` has samples from {:.3} s to {:.3} s only",
                s(range_ns.0),
                s(range_ns.1)
            ),
            Self::Gap { parent, child, between_ns } => write!(
                f,
                "TF gap: the link `{parent}` -> `{child}` has no sample between {:.3} s and {:.3} s ({:.0} ms)",
                s(between_ns.0),
                s(between_ns.1),
                (between_ns.1 - between_ns.0) as f64 * 1e-6
            ),
        }
    }
}

/// The TF tree of a recording.
#[derive(Debug, Clone)]
pub struct TfBuffer {
    /// Links by child frame.
    links: HashMap<String, Link>,
    /// The largest interval between two samples of a link that is interpolated, ns.
    max_gap_ns: i64,
}

/// Translation interpolated linearly, rotation by slerp (the shorter way), at `s` in [0, 1].
pub fn interpolate(a: &Isometry3<f64>, b: &Isometry3<f64>, s: f64) -> Isometry3<f64> {
    let t = a.translation.vector.lerp(&b.translation.vector, s);
    let (qa, mut qb) = (a.rotation, b.rotation);
    if qa.coords.dot(&qb.coords) < 0.0 {
        qb = nalgebra::UnitQuaternion::new_unchecked(-qb.into_inner());
    }
    let r = qa.try_slerp(&qb, s, 1e-12).unwrap_or_else(|| qa.nlerp(&qb, s));
    Isometry3::from_parts(Translation3::from(t), r)
}

impl TfBuffer {
    /// An empty buffer interpolating across sample intervals up to `max_gap_s` seconds.
    pub fn new(max_gap_s: f64) -> Self {
        Self { links: HashMap::new(), max_gap_ns: (max_gap_s * 1e9) as i64 }
    }

    /// Adds `parent_from_child` at `stamp_ns` (`/tf`), or for all times when `fixed` (`/tf_static`).
    /// A child is kept under its first parent; a later different parent returns that parent.
    pub fn add(
        &mut self,
        parent: &str,
        child: &str,
        stamp_ns: i64,
        parent_from_child: Isometry3<f64>,
        fixed: bool,
    ) -> Option<String> {
        let link = self
            .links
            .entry(child.to_string())
            .or_insert_with(|| Link { parent: parent.to_string(), ..Link::default() });
        if link.parent != parent {
            return Some(parent.to_string());
        }
        if fixed {
            link.fixed = Some(parent_from_child);
        } else {
            link.samples.push((stamp_ns, parent_from_child));
        }
        None
    }

    /// Sorts every link's samples by stamp (a bag's file order need not be the stamps' order).
    pub fn finish(&mut self) {
        for link in self.links.values_mut() {
            link.samples.sort_by_key(|s| s.0);
        }
    }

    /// The frames the buffer knows, sorted.
    pub fn frames(&self) -> Vec<String> {
        let mut frames: Vec<String> = self.links.iter().flat_map(|(c, l)| [c.clone(), l.parent.clone()]).collect();
        frames.sort();
        frames.dedup();
        frames
    }

    /// Whether the link `parent` -> `child` exists only in `/tf_static`.
    pub fn is_static(&self, child: &str) -> bool {
        self.links.get(child).is_some_and(|l| l.fixed.is_some() && l.samples.is_empty())
    }

    /// `parent_from_child` of the link above `child` at `t_ns`.
    fn link_at(&self, child: &str, link: &Link, t_ns: i64) -> Result<Isometry3<f64>, LookupError> {
        if link.samples.is_empty() {
            return link.fixed.ok_or_else(|| LookupError::Outside {
                parent: link.parent.clone(),
                child: child.to_string(),
                range_ns: (0, 0),
            });
        }
        let samples = &link.samples;
        let (first, last) = (samples[0].0, samples[samples.len() - 1].0);
        let outside =
            || LookupError::Outside { parent: link.parent.clone(), child: child.to_string(), range_ns: (first, last) };
        if t_ns < first || t_ns > last {
            return Err(outside());
        }
        let after = samples.partition_point(|s| s.0 < t_ns);
        let (tb, b) = samples[after];
        if tb == t_ns {
            return Ok(b);
        }
        let (ta, a) = samples[after - 1];
        if tb - ta > self.max_gap_ns {
            return Err(LookupError::Gap {
                parent: link.parent.clone(),
                child: child.to_string(),
                between_ns: (ta, tb),
            });
        }
        Ok(interpolate(&a, &b, (t_ns - ta) as f64 / (tb - ta) as f64))
    }

    /// `target_from_source` at `t_ns`: through the two frames' lowest common ancestor.
    ///
    /// # Errors
    /// [`LookupError`]: no path between the frames, a stamp outside a link's samples, or a gap.
    pub fn lookup(&self, target: &str, source: &str, t_ns: i64) -> Result<Isometry3<f64>, LookupError> {
        let no_path =
            || LookupError::NoPath { source: source.to_string(), target: target.to_string(), known: self.frames() };
        if !self.frames().iter().any(|f| f == source) || !self.frames().iter().any(|f| f == target) {
            return Err(no_path());
        }
        // walk the names first (no interpolation), so that an unconnected pair is reported as such
        let names = |frame: &str| {
            let mut names = vec![frame.to_string()];
            while let Some(link) = self.links.get(&names[names.len() - 1]) {
                if names.len() > self.links.len() + 1 {
                    break;
                }
                names.push(link.parent.clone());
            }
            names
        };
        let (up_source, up_target) = (names(source), names(target));
        let Some(common) = up_source.iter().find(|f| up_target.contains(f)).cloned() else { return Err(no_path()) };
        let common_from_source = self.up_to_ancestor(source, &common, t_ns)?;
        let common_from_target = self.up_to_ancestor(target, &common, t_ns)?;
        Ok(common_from_target.inverse() * common_from_source)
    }

    /// `ancestor_from_frame` at `t_ns` (`ancestor` on `frame`'s chain to the root).
    fn up_to_ancestor(&self, frame: &str, ancestor: &str, t_ns: i64) -> Result<Isometry3<f64>, LookupError> {
        let mut pose = Isometry3::identity();
        let mut current = frame.to_string();
        let mut steps = 0;
        while current != ancestor {
            let Some(link) = self.links.get(&current) else { break };
            pose = self.link_at(&current, link, t_ns)? * pose;
            current = link.parent.clone();
            steps += 1;
            if steps > self.links.len() {
                break;
            }
        }
        Ok(pose)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};

    /// A smooth motion sampled at 50 Hz: lookups between samples within 0.1 mm of the motion itself
    /// (the interpolation's error), a chain of a dynamic and a static link, and the failures named.
    #[test]
    fn interpolates_between_samples_and_names_gaps() {
        let motion = |t: f64| {
            let r = UnitQuaternion::from_scaled_axis(Vector3::new(0.3 * t, 0.2 * t.sin(), 0.1));
            Isometry3::from_parts(Translation3::new(0.25 * t, 0.1 * (2.0 * t).sin(), 0.5), r)
        };
        let fixed = Isometry3::translation(0.0, 0.0, 0.1);
        let mut tf = TfBuffer::new(0.1);
        for k in 0..=100 {
            let t_ns = k * 20_000_000;
            assert_eq!(tf.add("base", "ee", t_ns, motion(t_ns as f64 * 1e-9), false), None);
        }
        tf.add("ee", "camera", 0, fixed, true);
        tf.finish();
        let mut worst_mm: f64 = 0.0;
        for k in 0..1000 {
            let t_ns = 7_000_000 + k * 1_993_000;
            let got = tf.lookup("base", "camera", t_ns).expect("lookup");
            let want = motion(t_ns as f64 * 1e-9) * fixed;
            worst_mm = worst_mm.max((got.translation.vector - want.translation.vector).norm() * 1e3);
        }
        // measured 0.006 mm (0.25 m/s, 20 ms between samples)
        assert!(worst_mm < 0.1, "interpolation error {worst_mm} mm");
        let exact = tf.lookup("camera", "base", 40_000_000).expect("at a sample");
        assert!((exact * motion(0.04) * fixed).translation.vector.norm() < 1e-12);
        assert!(matches!(tf.lookup("base", "camera", 2_100_000_000), Err(LookupError::Outside { .. })));
        assert!(matches!(tf.lookup("base", "map", 0), Err(LookupError::NoPath { .. })));
        let mut gap = TfBuffer::new(0.1);
        gap.add("base", "ee", 0, motion(0.0), false);
        gap.add("base", "ee", 500_000_000, motion(0.5), false);
        let err = gap.lookup("base", "ee", 250_000_000).expect_err("gap");
        assert!(err.to_string().contains("`base` -> `ee` has no sample between 0.000 s and 0.500 s"), "{err}");
    }
}
