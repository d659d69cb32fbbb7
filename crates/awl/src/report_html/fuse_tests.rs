//! The fuse page on a synthetic report: ids, renders, plots, rejected rows, the viewer.

use super::fuse::*;
use super::rendered::PageParams;
use crate::cloud::PointCloud;
use crate::pipeline::{FuseConfig, StageReport};
use crate::pipeline::{FuseReport, ViewReport, ViewStatus};
use crate::registration::LevelStats;
use crate::render::RenderParams;
use nalgebra::Point3;

fn view(index: usize, status: ViewStatus, correction_mm: f64) -> ViewReport {
    let level = |f: f64| LevelStats {
        source_points: 100,
        target_points: 200,
        iterations: 5,
        converged: true,
        fitness: 0.9,
        inlier_rmse_m: f * 1e-3,
    };
    ViewReport {
        index,
        status,
        reason: String::new(),
        points: 1000,
        seed: None,
        pose: None,
        seeded_from_view: None,
        correction_mm,
        correction_deg: 0.5,
        iterations: 10,
        fitness: 0.9,
        inlier_rmse_mm: 0.7,
        conditioning: 10.0,
        observed_conditioning: 10.0,
        unobserved: Vec::new(),
        converged: true,
        levels: vec![level(3.0), level(1.0)],
    }
}

fn report() -> FuseReport {
    FuseReport {
        format: crate::pipeline::report::REPORT_FORMAT.into(),
        scan: "scan<1>".into(),
        config: FuseConfig::default(),
        focus_world: None,
        stages: vec![StageReport { name: "load".into(), points_in: 10, points_out: 9, seconds: 0.5 }],
        views: vec![
            view(0, ViewStatus::Anchor, 0.0),
            view(1, ViewStatus::Accepted, 12.0),
            view(2, ViewStatus::Excluded, 80.0),
        ],
        joint: Vec::new(),
        floor: None,
        clusters: None,
        hand_eye: None,
        advice: None,
        model_points: 400,
        warnings: vec!["view 2 rejected".into()],
        seconds: 1.5,
    }
}

#[test]
fn fuse_page_has_ids_renders_plots_and_the_viewer() {
    let points = (0..400).map(|k| Point3::new((k % 20) as f32 * 0.01, 0.0, (k / 20) as f32 * 0.01)).collect();
    let model = PointCloud::from_points(points);
    let params = PageParams {
        render: RenderParams { width: 200, height: 150, ..RenderParams::default() },
        ..PageParams::default()
    };
    let out = fuse_page(&report(), &model, Some(0.000_812), &params).expect("page");
    let names: Vec<&str> = out.renders.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["front.png", "side.png", "top.png", "iso.png"]);
    assert!(out.renders.iter().all(|(_, png)| png.starts_with(b"\x89PNG")));
    let html = out.page.to_html().expect("html");
    assert!(html.contains("<td id=\"points\">400</td>"));
    assert!(html.contains("<td id=\"rmse\">0.812</td>"));
    assert!(html.contains("3 (2 registered, 1 rejected, 0 skipped)"));
    assert_eq!(html.matches("<svg").count(), 4, "2 correction + 2 convergence plots");
    assert_eq!(html.matches("<tr class=\"rejected\">").count(), 1);
    assert_eq!(html.matches("data:image/png;base64,").count(), 4);
    assert!(html.contains("data-count=\"400\"") && html.contains("canvas.awl-viewer"));
    assert!(html.contains("scan&lt;1&gt;"));
    let empty = fuse_page(&report(), &PointCloud::default(), None, &params).expect("page");
    assert!(empty.renders.is_empty() && !empty.page.to_html().expect("html").contains("id=\"rmse\""));
}
