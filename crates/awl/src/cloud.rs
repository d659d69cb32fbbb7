//! The point cloud: a plain data type (positions, optional normals and colors); algorithms live in
//! their own modules as free functions.

use nalgebra::{Isometry3, Point3, Vector3};

use crate::error::{Error, Result};

/// Points in one frame (the frame is the caller's to name: `cloud_world`, `cloud_camera`), metres.
///
/// `normals` and `colors`, when present, have one entry per point.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointCloud {
    /// Positions, metres.
    pub points: Vec<Point3<f32>>,
    /// Unit normals, one per point.
    pub normals: Option<Vec<Vector3<f32>>>,
    /// 8-bit RGB colors, one per point.
    pub colors: Option<Vec<[u8; 3]>>,
}

/// Axis-aligned bounds of a cloud, metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounds {
    /// Smallest x, y, z.
    pub min: Point3<f32>,
    /// Largest x, y, z.
    pub max: Point3<f32>,
}

impl Bounds {
    /// Edge lengths along x, y, z.
    pub fn extent(&self) -> Vector3<f32> {
        self.max - self.min
    }
}

impl PointCloud {
    /// A cloud of bare positions.
    pub fn from_points(points: Vec<Point3<f32>>) -> Self {
        Self { points, normals: None, colors: None }
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// True when the cloud has no point.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Checks that normals and colors have one entry per point and every position is finite.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming `what` and the first offending index.
    pub fn validate(&self, what: &str) -> Result<()> {
        let n = self.points.len();
        if let Some(normals) = &self.normals {
            if normals.len() != n {
                return Err(Error::invalid(what, format!("{} normals for {n} points", normals.len())));
            }
        }
        if let Some(colors) = &self.colors {
            if colors.len() != n {
                return Err(Error::invalid(what, format!("{} colors for {n} points", colors.len())));
            }
        }
        if let Some(i) = self.points.iter().position(|p| !p.coords.iter().all(|v| v.is_finite())) {
            return Err(Error::invalid(what, format!("point {i} is not finite: {:?}", self.points[i])));
        }
        Ok(())
    }

    /// Axis-aligned bounds, or `None` for an empty cloud.
    pub fn bounds(&self) -> Option<Bounds> {
        let first = *self.points.first()?;
        let (min, max) = self.points.iter().fold((first, first), |(lo, hi), p| (lo.inf(p), hi.sup(p)));
        Some(Bounds { min, max })
    }

    /// The cloud moved by `to_from_from` (positions and normals), computed in f64.
    pub fn transformed(&self, to_from_from: &Isometry3<f64>) -> PointCloud {
        self.clone().into_transformed(to_from_from)
    }

    /// [`PointCloud::transformed`] in place: no second copy of the cloud.
    pub fn into_transformed(mut self, to_from_from: &Isometry3<f64>) -> PointCloud {
        for p in &mut self.points {
            *p = (to_from_from * p.cast::<f64>()).cast::<f32>();
        }
        for n in self.normals.iter_mut().flatten() {
            *n = (to_from_from.rotation * n.cast::<f64>()).cast::<f32>();
        }
        self
    }

    /// The points at `indices`, in that order, with their normals and colors.
    ///
    /// # Panics
    /// Never for indices below `len()`; callers pass indices they obtained from this cloud.
    pub fn select(&self, indices: &[usize]) -> PointCloud {
        PointCloud {
            points: indices.iter().map(|&i| self.points[i]).collect(),
            normals: self.normals.as_ref().map(|ns| indices.iter().map(|&i| ns[i]).collect()),
            colors: self.colors.as_ref().map(|cs| indices.iter().map(|&i| cs[i]).collect()),
        }
    }

    /// Appends `other`; normals or colors are kept only when both clouds have them.
    pub fn extend(&mut self, other: &PointCloud) {
        let had_points = !self.points.is_empty();
        self.points.extend_from_slice(&other.points);
        merge_attribute(&mut self.normals, other.normals.as_ref(), had_points);
        merge_attribute(&mut self.colors, other.colors.as_ref(), had_points);
    }
}

fn merge_attribute<T: Clone>(mine: &mut Option<Vec<T>>, theirs: Option<&Vec<T>>, had_points: bool) {
    match (mine.as_mut(), theirs) {
        (Some(m), Some(t)) => m.extend_from_slice(t),
        (None, Some(t)) if !had_points => *mine = Some(t.clone()),
        _ => *mine = None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    #[test]
    fn bounds_transform_and_extend() {
        let mut cloud = PointCloud::from_points(vec![Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 2.0, 3.0)]);
        let b = cloud.bounds().expect("non-empty");
        assert_eq!(b.extent(), Vector3::new(1.0, 2.0, 3.0));
        let shift = Isometry3::from_parts(Translation3::new(1.0, 0.0, 0.0), UnitQuaternion::identity());
        let moved = cloud.transformed(&shift);
        assert_eq!(moved.points[1], Point3::new(2.0, 2.0, 3.0));
        cloud.colors = Some(vec![[1, 2, 3], [4, 5, 6]]);
        cloud.extend(&moved);
        assert_eq!(cloud.len(), 4);
        assert!(cloud.colors.is_none(), "colors dropped when one side has none");
        assert!(PointCloud::default().bounds().is_none());
    }

    #[test]
    fn validate_names_the_bad_point() {
        let cloud = PointCloud::from_points(vec![Point3::new(0.0, f32::NAN, 0.0)]);
        let err = cloud.validate("model.ply").unwrap_err().to_string();
        assert!(err.contains("model.ply") && err.contains("point 0"), "{err}");
    }
}
