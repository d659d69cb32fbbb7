//! The trials as the paper's Tables I-IV: per trial the true and estimated point (mm, robot base
//! frame), the per-axis error and the distance; then the average and standard deviation (of the
//! absolute per-axis errors and of the distance), plus the tool-axis error, its two sources and the tag-only figures;
//! with an arm, a reach column and per trial its margins and clearance or why it is not reachable.

use std::fmt::Write as _;

use super::TrialRow;

/// Statistics of a set of trials.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrialSummary {
    /// Trials.
    pub trials: usize,
    /// Mean distance, metres.
    pub mean_m: f64,
    /// Sample standard deviation of the distance, metres.
    pub std_m: f64,
    /// Largest distance, metres.
    pub max_m: f64,
    /// Mean absolute error per axis, metres.
    pub mean_abs_axis_m: [f64; 3],
    /// Largest tool-axis error, radians.
    pub max_axis_error_rad: f64,
    /// Mean tool-axis error, radians.
    pub mean_axis_error_rad: f64,
    /// Largest rotation error of the located workpiece, radians.
    pub max_locate_rotation_rad: f64,
    /// Largest error of the model's normal at the planned point, radians.
    pub max_model_normal_error_rad: f64,
    /// Mean distance from the tag pose alone, metres.
    pub mean_tag_only_m: f64,
    /// Trials where the shot-depth refinement was applied.
    pub refined: usize,
    /// Mean axis error against the true normal where the tool meets the surface, radians.
    pub mean_axis_error_at_point_rad: f64,
    /// Largest such error, radians.
    pub max_axis_error_at_point_rad: f64,
    /// Fraction of the trials whose distance is within its predicted 95 % bound.
    pub within_bound: f64,
    /// ... whose axis error is within its predicted bound.
    pub axis_within_bound: f64,
    /// Median predicted position bound, metres.
    pub median_bound_m: f64,
    /// Median distance, metres.
    pub median_m: f64,
    /// Trials whose reach was checked (`awl trial --robot`) ...
    pub reach_checked: usize,
    /// ... and of those, the reachable ones.
    pub reachable: usize,
}

fn median(v: &[f64]) -> f64 {
    let mut v: Vec<f64> = v.to_vec();
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

fn mean(v: &[f64]) -> f64 {
    if v.is_empty() { f64::NAN } else { v.iter().sum::<f64>() / v.len() as f64 }
}

fn std(v: &[f64]) -> f64 {
    if v.len() < 2 {
        return 0.0;
    }
    let m = mean(v);
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
}

impl TrialSummary {
    /// Summarises `rows`.
    pub fn of(rows: &[TrialRow]) -> Self {
        let d: Vec<f64> = rows.iter().map(|r| r.error().norm()).collect();
        let a: Vec<f64> = rows.iter().map(|r| r.axis_error_rad).collect();
        let tag: Vec<f64> = rows.iter().map(|r| (r.estimate_tag_only - r.truth).norm()).collect();
        let axis = |i: usize| mean(&rows.iter().map(|r| r.error()[i].abs()).collect::<Vec<_>>());
        Self {
            trials: rows.len(),
            mean_m: mean(&d),
            std_m: std(&d),
            max_m: d.iter().copied().fold(0.0, f64::max),
            mean_abs_axis_m: [axis(0), axis(1), axis(2)],
            max_axis_error_rad: a.iter().copied().fold(0.0, f64::max),
            mean_axis_error_rad: mean(&a),
            max_locate_rotation_rad: rows.iter().map(|r| r.locate_rotation_rad).fold(0.0, f64::max),
            max_model_normal_error_rad: rows.iter().map(|r| r.model_normal_error_rad).fold(0.0, f64::max),
            mean_tag_only_m: mean(&tag),
            refined: rows.iter().filter(|r| r.refined).count(),
            mean_axis_error_at_point_rad: mean(&rows.iter().map(|r| r.axis_error_at_point_rad).collect::<Vec<_>>()),
            max_axis_error_at_point_rad: rows.iter().map(|r| r.axis_error_at_point_rad).fold(0.0, f64::max),
            within_bound: fraction(rows, |r| r.error().norm() <= r.prediction.position_bound_m),
            axis_within_bound: fraction(rows, |r| r.axis_error_rad <= r.prediction.axis_bound_rad),
            median_bound_m: median(&rows.iter().map(|r| r.prediction.position_bound_m).collect::<Vec<_>>()),
            median_m: median(&d),
            reach_checked: rows.iter().filter(|r| r.reach.is_some()).count(),
            reachable: rows.iter().filter(|r| r.reach.as_ref().is_some_and(|x| x.reachable)).count(),
        }
    }
}

fn fraction(rows: &[TrialRow], within: impl Fn(&TrialRow) -> bool) -> f64 {
    if rows.is_empty() { f64::NAN } else { rows.iter().filter(|r| within(r)).count() as f64 / rows.len() as f64 }
}

/// The table (module docs), `title` above it, as monospaced text.
pub fn format_table(title: &str, rows: &[TrialRow]) -> String {
    let mm = |v: f64| v * 1e3;
    let with_reach = rows.iter().any(|r| r.reach.is_some());
    let reach_cell = |r: &TrialRow| match &r.reach {
        Some(x) if x.reachable => " | yes".to_string(),
        Some(_) => " | NO".to_string(),
        None if with_reach => " | -".to_string(),
        None => String::new(),
    };
    let rule = if with_reach { 140 } else { 132 };
    let mut s = String::new();
    let _ = writeln!(s, "{title}");
    let _ = writeln!(
        s,
        "{:>5} | {:>26} | {:>26} | {:>22} | {:>8} | {:>8} | {:>8} | {:>8}{}",
        "trial",
        "GT x, y, z (mm)",
        "estimate x, y, z (mm)",
        "error x, y, z (mm)",
        "dist mm",
        "bound mm",
        "axis deg",
        "bound",
        if with_reach { " | reach" } else { "" }
    );
    let _ = writeln!(s, "{}", "-".repeat(rule));
    for r in rows {
        let (g, e, d) = (r.truth, r.estimate, r.error());
        let _ = writeln!(
            s,
            "{:>5} | {:>8.1} {:>8.1} {:>8.1} | {:>8.1} {:>8.1} {:>8.1} | {:>6.2} {:>6.2} {:>6.2}  | {:>8.2} | {:>8.2} | {:>8.2} | {:>8.2}{}",
            r.trial,
            mm(g.x),
            mm(g.y),
            mm(g.z),
            mm(e.x),
            mm(e.y),
            mm(e.z),
            mm(d.x),
            mm(d.y),
            mm(d.z),
            mm(d.norm()),
            mm(r.prediction.position_bound_m),
            r.axis_error_rad.to_degrees(),
            r.prediction.axis_bound_rad.to_degrees(),
            reach_cell(r)
        );
    }
    let sum = TrialSummary::of(rows);
    let axis_std = |i: usize| {
        let v: Vec<f64> = rows.iter().map(|r| r.error()[i].abs()).collect();
        std(&v)
    };
    let _ = writeln!(s, "{}", "-".repeat(rule));
    let a = sum.mean_abs_axis_m;
    let _ = writeln!(
        s,
        "{:>5} | {:>26} | {:>26} | {:>6.2} {:>6.2} {:>6.2}  | {:>8.2} | {:>8} | {:>8.2} |",
        "avg",
        "",
        "",
        mm(a[0]),
        mm(a[1]),
        mm(a[2]),
        mm(sum.mean_m),
        "",
        sum.mean_axis_error_rad.to_degrees()
    );
    let _ = writeln!(
        s,
        "{:>5} | {:>26} | {:>26} | {:>6.2} {:>6.2} {:>6.2}  | {:>8.2} |",
        "std",
        "",
        "",
        mm(axis_std(0)),
        mm(axis_std(1)),
        mm(axis_std(2)),
        mm(sum.std_m)
    );
    let _ = writeln!(
        s,
        "max distance {:.2} mm, max axis error {:.2} deg; tag pose alone: mean {:.2} mm; shot-depth refinement applied in {} of {}",
        mm(sum.max_m),
        sum.max_axis_error_rad.to_degrees(),
        mm(sum.mean_tag_only_m),
        sum.refined,
        sum.trials
    );
    let _ = writeln!(
        s,
        "axis error sources (max): located workpiece rotation {:.2} deg, model normal at the planned point {:.2} deg",
        sum.max_locate_rotation_rad.to_degrees(),
        sum.max_model_normal_error_rad.to_degrees()
    );
    let _ = writeln!(
        s,
        "axis error against the true normal where the tool meets the surface: mean {:.2} deg, max {:.2} deg",
        sum.mean_axis_error_at_point_rad.to_degrees(),
        sum.max_axis_error_at_point_rad.to_degrees()
    );
    let _ = writeln!(
        s,
        "predicted 95 % bounds: the distance within its bound in {:.0} % of the trials, the axis in {:.0} %; median bound {:.2} mm for a median distance of {:.2} mm",
        100.0 * sum.within_bound,
        100.0 * sum.axis_within_bound,
        mm(sum.median_bound_m),
        mm(sum.median_m)
    );
    if with_reach {
        let _ = writeln!(s, "reach: {} of {} trial targets reachable", sum.reachable, sum.reach_checked);
        for r in rows {
            if let Some(line) = reach_line(r) {
                let _ = writeln!(s, "  trial {}: {line}", r.trial);
            }
        }
    }
    s
}

/// A row's reach in words: reachable with its configuration, spin, margins and clearance, or not
/// and why; with the target's distance from the base (`None`: not checked).
pub fn reach_line(r: &TrialRow) -> Option<String> {
    let x = r.reach.as_ref()?;
    let distance = format!(
        "target {:.3} m from the base origin, {:.3} m from joint 1's axis, z {:+.3} m",
        r.base_distance_m(),
        r.base_horizontal_m(),
        r.estimate.z
    );
    if !x.reachable {
        return Some(format!("NOT reachable ({distance}): {}", x.reason));
    }
    let margins = x.margins.map_or(String::from("margins not recorded"), |m| {
        format!(
            "margins: limits {:.1} deg, wrist {:.2}, elbow {:.2}, shoulder {:.0} mm",
            m.limit_rad.to_degrees(),
            m.wrist,
            m.elbow,
            m.shoulder_m * 1e3
        )
    });
    let clearance = x.clearance.map_or(String::from("nothing near"), |c| {
        format!("{:.1} mm ({} to the {})", c.distance_m * 1e3, c.link.name(), c.against.name())
    });
    Some(format!(
        "reachable, {}, spin {:.0} deg; {margins}; clearance {clearance} ({distance})",
        x.branch.map_or(String::from("configuration not recorded"), |b| b.to_string()),
        x.spin_rad.to_degrees()
    ))
}
