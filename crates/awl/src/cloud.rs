//! The point cloud: a plain data type (positions, optional normals and colors); algorithms live in
//! their own modules as free functions.

use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

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

/// Items a task of a cheap parallel pass (one test or one store per point, per key) gets at
/// least: such a pass gains nothing from finer tasks.
pub(crate) const SCAN_CHUNK: usize = 1 << 14;

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
        self.validate_lengths(what)?;
        self.validate_finite(what)
    }

    /// The finiteness half of [`PointCloud::validate`]: the first point with a non-finite
    /// coordinate, by index.
    fn validate_finite(&self, what: &str) -> Result<()> {
        let bad = |p: &Point3<f32>| !p.coords.iter().all(|v| v.is_finite());
        // by chunks: rayon's per-item `position_first` costs far more than the test itself
        let chunk = self.points.par_chunks(SCAN_CHUNK).position_first(|c| c.iter().any(bad));
        if let Some(i) =
            chunk.and_then(|c| self.points[c * SCAN_CHUNK..].iter().position(bad).map(|j| c * SCAN_CHUNK + j))
        {
            return Err(Error::invalid(what, format!("point {i} is not finite: {:?}", self.points[i])));
        }
        Ok(())
    }

    /// [`PointCloud::validate`] and [`PointCloud::bounds`] in one pass over the points.
    ///
    /// # Errors
    /// As [`PointCloud::validate`].
    pub fn validated_bounds(&self, what: &str) -> Result<Option<Bounds>> {
        self.validate_lengths(what)?;
        match self.bounds_and_finite() {
            // (a coordinate is not finite: its error names the first such point)
            Some((_, false)) => self.validate_finite(what).map(|()| None),
            found => Ok(found.map(|(bounds, _)| bounds)),
        }
    }

    fn validate_lengths(&self, what: &str) -> Result<()> {
        let n = self.points.len();
        if let Some(normals) = &self.normals
            && normals.len() != n
        {
            return Err(Error::invalid(what, format!("{} normals for {n} points", normals.len())));
        }
        if let Some(colors) = &self.colors
            && colors.len() != n
        {
            return Err(Error::invalid(what, format!("{} colors for {n} points", colors.len())));
        }
        Ok(())
    }

    /// Axis-aligned bounds, or `None` for an empty cloud (of its finite coordinates: a NaN is
    /// skipped). Parallel; min and max do not depend on the order they are taken in.
    pub fn bounds(&self) -> Option<Bounds> {
        self.bounds_and_finite().map(|(bounds, _)| bounds)
    }

    /// The bounds, and whether every coordinate is finite.
    fn bounds_and_finite(&self) -> Option<(Bounds, bool)> {
        type Scan = ([f32; 3], [f32; 3], bool);
        let empty: Scan = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3], true);
        let join = |(lo, hi, finite): Scan, (l, h, f): Scan| -> Scan {
            // compare-and-select (one instruction each; a NaN never wins), not `f32::min`
            let (min, max) = (|a: f32, b: f32| if b < a { b } else { a }, |a: f32, b: f32| if b > a { b } else { a });
            (std::array::from_fn(|a| min(lo[a], l[a])), std::array::from_fn(|a| max(hi[a], h[a])), finite & f)
        };
        let (lo, hi, finite) = self
            .points
            .par_chunks(SCAN_CHUNK)
            .map(|chunk| {
                chunk.iter().fold(empty, |acc, p| {
                    join(acc, ([p.x, p.y, p.z], [p.x, p.y, p.z], p.coords.iter().all(|v| v.is_finite())))
                })
            })
            .reduce(|| empty, join);
        (!self.points.is_empty()).then(|| (Bounds { min: lo.into(), max: hi.into() }, finite))
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

    /// Keeps the points at `indices` (strictly increasing), with their normals and colors, in
    /// place: [`PointCloud::select`] without a second copy of the cloud.
    ///
    /// # Panics
    /// Never for strictly increasing indices below `len()`, those callers obtain from this cloud.
    pub fn retain_indices(&mut self, indices: &[usize]) {
        debug_assert!(indices.windows(2).all(|w| w[0] < w[1]), "indices not strictly increasing");
        retain_at(&mut self.points, indices);
        if let Some(normals) = self.normals.as_mut() {
            retain_at(normals, indices);
        }
        if let Some(colors) = self.colors.as_mut() {
            retain_at(colors, indices);
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

/// `items` at `indices` (strictly increasing), moved to the front in place; the rest dropped.
pub(crate) fn retain_at<T: Copy>(items: &mut Vec<T>, indices: &[usize]) {
    for (j, &i) in indices.iter().enumerate() {
        items[j] = items[i];
    }
    items.truncate(indices.len());
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
    fn retain_indices_is_select_in_place() {
        let points: Vec<Point3<f32>> = (0..9).map(|i| Point3::new(i as f32, 0.0, 1.0)).collect();
        let normals = Some(points.iter().map(|p| Vector3::new(0.0, p.x, 1.0)).collect());
        let colors = Some((0..9u8).map(|i| [i, 2 * i, 3 * i]).collect());
        for cloud in [PointCloud::from_points(points.clone()), PointCloud { points, normals, colors }] {
            for keep in [vec![], vec![0, 1, 2], vec![1, 4, 5, 8], (0..9).collect()] {
                let mut kept = cloud.clone();
                kept.retain_indices(&keep);
                assert_eq!(kept, cloud.select(&keep), "{keep:?}");
            }
        }
    }

    #[test]
    fn validate_names_the_bad_point() {
        let cloud = PointCloud::from_points(vec![Point3::new(0.0, f32::NAN, 0.0)]);
        let err = cloud.validate("model.ply").expect_err("an error").to_string();
        assert!(err.contains("model.ply") && err.contains("point 0"), "{err}");
        // past the first parallel chunk, by both checks; the bounds skip the NaN
        let mut points = vec![Point3::new(1.0, -2.0, 3.0); 40_000];
        points[7] = Point3::new(-1.0, 2.0, 0.5);
        points[40_000 - 2].y = f32::INFINITY;
        points[40_000 - 1].z = f32::NAN;
        let cloud = PointCloud::from_points(points);
        for err in [cloud.validate("c").expect_err("an error"), cloud.validated_bounds("c").expect_err("an error")] {
            assert!(err.to_string().contains("point 39998 is not finite"), "{err}");
        }
        let b = cloud.bounds().expect("bounds");
        assert_eq!((b.min, b.max), (Point3::new(-1.0, -2.0, 0.5), Point3::new(1.0, f32::INFINITY, 3.0)));
        let mut finite = cloud.clone();
        finite.points.truncate(40_000 - 2);
        assert_eq!(
            finite.validated_bounds("c").expect("valid"),
            Some(Bounds { min: b.min, max: Point3::new(1.0, 2.0, 3.0) })
        );
    }
}
