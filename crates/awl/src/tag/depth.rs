//! Resolving the planar ambiguity with depth: the correct pose puts the depth points that fall on the
//! tag onto its plane; the flipped one tilts the plane away from them.

use nalgebra::{Point2, Point3};

use crate::camera::Intrinsics;
use crate::tag::pose::{TagPose, TagPoseSolution};

/// Fraction of the detected quad (scaled about its centre) whose depth points are used: keeps the
/// border pixels, where depth mixes tag and background, out.
const INNER_FRACTION: f64 = 0.8;
/// Fewer points than this on the tag cannot decide between the two solutions.
pub const MIN_DEPTH_POINTS: usize = 10;

/// How well the depth points on the tag fit one solution's tag plane.
///
/// The two solutions differ mainly in the plane's tilt; both share the distance along the line of
/// sight, which for a small tag is the least certain part of the pose (0.1 px on a 20 px tag is
/// 0.5 % of the range), and a depth camera adds its own scale error. So the decision uses
/// `spread_m`, the scatter of the points about the plane once its offset is removed, not the raw
/// distances.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthScore {
    /// Number of depth points that project inside the inner 80 % of the detected quad.
    pub points: usize,
    /// Median signed distance of those points from the solution's tag plane along its z axis
    /// (positive: in front of the face, toward the camera), metres; NaN without points.
    pub offset_m: f64,
    /// Median absolute deviation of the signed distances from `offset_m`, metres: small when the
    /// plane's tilt matches the points; infinite without points.
    pub spread_m: f64,
}

/// [`DepthScore`]s of both solutions of a [`TagPose`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthScores {
    /// Score of `pose.best`.
    pub best: DepthScore,
    /// Score of `pose.second`, when there is one.
    pub second: Option<DepthScore>,
}

impl DepthScores {
    /// True when the depth points (at least [`MIN_DEPTH_POINTS`]) fit the second solution's plane
    /// better (lower `spread_m`) than the best one's: then use [`TagPose::swapped`].
    pub fn prefers_second(&self) -> bool {
        match self.second {
            Some(second) => self.best.points >= MIN_DEPTH_POINTS && second.spread_m < self.best.spread_m,
            None => false,
        }
    }
}

/// True when `p` lies inside the convex quad `q` (either winding).
fn inside_quad(q: &[Point2<f64>; 4], p: &Point2<f64>) -> bool {
    let mut sign = 0.0_f64;
    for i in 0..4 {
        let (a, b) = (q[i], q[(i + 1) % 4]);
        let cross = (b - a).perp(&(p - a));
        if cross * sign < 0.0 {
            return false;
        }
        if cross != 0.0 {
            sign = cross.signum();
        }
    }
    true
}

fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

fn score(solution: &TagPoseSolution, on_tag: &[Point3<f64>]) -> DepthScore {
    if on_tag.is_empty() {
        return DepthScore { points: 0, offset_m: f64::NAN, spread_m: f64::INFINITY };
    }
    let tag_from_camera = solution.camera_from_tag.inverse();
    let mut d: Vec<f64> = on_tag.iter().map(|p| (tag_from_camera * p).z).collect();
    let offset_m = median(&mut d);
    let mut deviation: Vec<f64> = d.iter().map(|x| (x - offset_m).abs()).collect();
    DepthScore { points: d.len(), offset_m, spread_m: median(&mut deviation) }
}

/// Scores both solutions of `pose` by the plane distance of the camera-frame depth points
/// (`points_camera`, metres, e.g. a view's depth cloud) that project inside the detected quad
/// `corners_px` (its inner 80 %).
pub fn score_depth(
    pose: &TagPose,
    corners_px: &[[f64; 2]; 4],
    intrinsics: &Intrinsics,
    points_camera: &[Point3<f32>],
) -> DepthScores {
    let quad = corners_px.map(|[u, v]| Point2::new(u, v));
    let centre = Point2::from(quad.iter().map(|p| p.coords).sum::<nalgebra::Vector2<f64>>() / 4.0);
    let inner = quad.map(|p| centre + (p - centre) * INNER_FRACTION);
    let on_tag: Vec<Point3<f64>> = points_camera
        .iter()
        .map(|p| p.cast::<f64>())
        .filter(|p| intrinsics.project(p).is_some_and(|px| inside_quad(&inner, &px)))
        .collect();
    DepthScores { best: score(&pose.best, &on_tag), second: pose.second.as_ref().map(|s| score(s, &on_tag)) }
}
