//! Still periods: runs of depth frames over which the base (`T_world_base`) and the flange
//! (`T_base_ee`) both moved slower than a threshold, lasting at least `min_still_s`; one view per
//! period (its middle frame, or the frame nearest it that has a color image within the sync
//! window), and the base stops (a new one whenever the base moved between two views).

use nalgebra::Isometry3;
use serde::Serialize;

use crate::transform::pose_difference;

/// The rules that make a still period.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StillParams {
    /// Shortest still period, seconds (`--still-s`).
    pub min_still_s: f64,
    /// Largest speed of the base or the flange that counts as still, metres per second.
    pub max_speed_m_s: f64,
    /// Largest rotation rate of the base or the flange that counts as still, radians per second.
    pub max_rate_rad_s: f64,
    /// Largest time between a view's depth and color images, seconds (`--sync-ms`).
    pub sync_s: f64,
}

impl Default for StillParams {
    fn default() -> Self {
        Self { min_still_s: 0.5, max_speed_m_s: 0.005, max_rate_rad_s: 0.5_f64.to_radians(), sync_s: 0.025 }
    }
}

/// The rig's pose at a depth frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FramePose {
    /// The frame's stamp, ns.
    pub stamp_ns: i64,
    /// `T_world_base`.
    pub world_from_base: Isometry3<f64>,
    /// `T_base_ee`.
    pub base_from_ee: Isometry3<f64>,
}

/// Why a depth frame did not become a view.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SkipReason {
    /// The base or the arm moved on both sides of the frame.
    Moving,
    /// The frame is in a still run shorter than `min_still_s`.
    StillTooShort,
    /// Another frame of the same still period was taken.
    SamePeriod,
    /// No color image within the sync window, for any frame of its still period.
    NoColorInSync,
    /// The TF tree has no samples at the frame's stamp (before the first or after the last).
    OutsideTf,
}

impl SkipReason {
    /// A short text for reports.
    pub fn describe(self) -> &'static str {
        match self {
            Self::Moving => "the base or the arm was moving",
            Self::StillTooShort => "still for less than --still-s",
            Self::SamePeriod => "another frame of the same still period was used",
            Self::NoColorInSync => "no color image within --sync-ms in its still period",
            Self::OutsideTf => "outside the TF recording (before its first or after its last sample)",
        }
    }
}

/// A still period's view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StillView {
    /// Index of the depth frame taken (into the frames given).
    pub frame: usize,
    /// Index of the paired color image, when there are color images.
    pub color: Option<usize>,
    /// The base stop (0, 1, ...): views with the same value saw the base stand still between them.
    pub base_stop: u32,
    /// The still period: its first and last frame indices.
    pub period: (usize, usize),
}

/// Speeds of the base and the flange between two frame poses: (m/s, rad/s), the larger of the two.
fn speeds(a: &FramePose, b: &FramePose) -> (f64, f64, bool) {
    let dt = (b.stamp_ns - a.stamp_ns) as f64 * 1e-9;
    let (base_t, base_r) = pose_difference(&a.world_from_base, &b.world_from_base);
    let (ee_t, ee_r) = pose_difference(&a.base_from_ee, &b.base_from_ee);
    if dt <= 0.0 {
        return (0.0, 0.0, base_t > 0.0 || base_r > 0.0 || ee_t > 0.0 || ee_r > 0.0);
    }
    (base_t.max(ee_t) / dt, base_r.max(ee_r) / dt, false)
}

/// Whether the base moved between two frames, by the same thresholds.
fn base_moved(a: &FramePose, b: &FramePose, params: &StillParams) -> bool {
    let dt = ((b.stamp_ns - a.stamp_ns) as f64 * 1e-9).max(1e-9);
    let (t, r) = pose_difference(&a.world_from_base, &b.world_from_base);
    t / dt > params.max_speed_m_s || r / dt > params.max_rate_rad_s
}

/// The views of `frames` (sorted by stamp): one per still period, each paired with the color stamp
/// (`color_ns`, sorted) nearest its depth frame within the sync window (tried from the period's
/// middle outwards) when `color_ns` is given; and every frame's skip reason (`None` for a view).
pub fn find_views(
    frames: &[FramePose],
    color_ns: Option<&[i64]>,
    params: &StillParams,
) -> (Vec<StillView>, Vec<Option<SkipReason>>) {
    let n = frames.len();
    let still: Vec<bool> = frames
        .windows(2)
        .map(|w| {
            let (v, omega, jump) = speeds(&w[0], &w[1]);
            !jump && v <= params.max_speed_m_s && omega <= params.max_rate_rad_s
        })
        .collect();
    let mut reasons = vec![Some(SkipReason::Moving); n];
    let mut views: Vec<StillView> = Vec::new();
    let sync_ns = (params.sync_s * 1e9) as i64;
    let nearest_color = |t: i64| -> Option<usize> {
        let colors = color_ns?;
        let i = colors.partition_point(|&c| c < t);
        [i.checked_sub(1), (i < colors.len()).then_some(i)]
            .into_iter()
            .flatten()
            .min_by_key(|&j| (colors[j] - t).abs())
            .filter(|&j| (colors[j] - t).abs() <= sync_ns)
    };
    let mut k = 0;
    while k < still.len() {
        if !still[k] {
            k += 1;
            continue;
        }
        let first = k;
        while k < still.len() && still[k] {
            k += 1;
        }
        let last = k; // frames first..=last are still with respect to their neighbours in the run
        let duration_s = (frames[last].stamp_ns - frames[first].stamp_ns) as f64 * 1e-9;
        if duration_s + 1e-9 < params.min_still_s {
            reasons[first..=last].fill(Some(SkipReason::StillTooShort));
            continue;
        }
        reasons[first..=last].fill(Some(SkipReason::SamePeriod));
        let middle = (first + last) / 2;
        let mut order: Vec<usize> = (first..=last).collect();
        order.sort_by_key(|&f| (f.abs_diff(middle), f));
        let pick = if color_ns.is_some() {
            order.iter().find_map(|&f| nearest_color(frames[f].stamp_ns).map(|c| (f, Some(c))))
        } else {
            Some((middle, None))
        };
        let Some((frame, color)) = pick else {
            reasons[first..=last].fill(Some(SkipReason::NoColorInSync));
            continue;
        };
        reasons[frame] = None;
        let base_stop = match views.last() {
            None => 0,
            Some(prev) => {
                let moved = (prev.frame..frame).any(|f| base_moved(&frames[f], &frames[f + 1], params));
                prev.base_stop + u32::from(moved)
            }
        };
        views.push(StillView { frame, color, base_stop, period: (first, last) });
    }
    (views, reasons)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(t_s: f64, base_x: f64, ee_x: f64) -> FramePose {
        FramePose {
            stamp_ns: (t_s * 1e9) as i64,
            world_from_base: Isometry3::translation(base_x, 0.0, 0.0),
            base_from_ee: Isometry3::translation(ee_x, 0.0, 0.0),
        }
    }

    /// Three stills (the base moving before the third), one too short, color 15 ms late.
    #[test]
    fn one_view_per_still_period_and_base_stops() {
        let mut frames = Vec::new();
        let mut t = 0.0;
        for (base, ee, count) in [(0.0, 0.0, 8), (0.0, 0.3, 8), (0.0, 0.5, 2), (1.0, 0.5, 8)] {
            for _ in 0..count {
                frames.push(frame(t, base, ee));
                t += 0.1;
            }
        }
        let colors: Vec<i64> = frames.iter().map(|f| f.stamp_ns + 15_000_000).collect();
        let (views, reasons) = find_views(&frames, Some(&colors), &StillParams::default());
        let picked: Vec<(usize, Option<usize>, u32)> = views.iter().map(|v| (v.frame, v.color, v.base_stop)).collect();
        assert_eq!(picked, vec![(3, Some(3), 0), (11, Some(11), 0), (21, Some(21), 1)]);
        assert_eq!(reasons[17], Some(SkipReason::StillTooShort));
        assert_eq!(reasons[0], Some(SkipReason::SamePeriod));
        let late: Vec<i64> = colors.iter().map(|c| c + 20_000_000).collect();
        let (views, reasons) = find_views(&frames, Some(&late), &StillParams::default());
        assert!(views.is_empty());
        assert_eq!(reasons[3], Some(SkipReason::NoColorInSync));
    }
}
