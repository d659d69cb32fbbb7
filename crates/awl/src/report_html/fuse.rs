//! The page of `awl fuse`: summary, renders of the model, the interactive view, per-view
//! registration (correction plots and table) and ICP convergence per level.

use rayon::prelude::*;

use super::page::{Block, KeyValue, Page, Picture, Section, Table};
use super::rendered::{PageParams, RenderedPage};
use super::viewer::ViewerCloud;
use crate::cloud::PointCloud;
use crate::error::Result;
use crate::pipeline::{FuseReport, ViewReport, ViewStatus};
use crate::render::plot::{Bar, Chart, Series, bar_chart, line_chart};
use crate::render::{estimate_spacing, png_bytes, render_cloud};

fn status_name(s: ViewStatus) -> &'static str {
    match s {
        ViewStatus::Anchor => "anchor",
        ViewStatus::Accepted => "accepted",
        ViewStatus::SeedKept => "seed-kept",
        ViewStatus::Excluded => "excluded",
        ViewStatus::Skipped => "skipped",
    }
}

/// Plot color and table row class of a status.
fn status_style(s: ViewStatus) -> (&'static str, &'static str) {
    match s {
        ViewStatus::Anchor => ("#3366cc", "accepted"),
        ViewStatus::Accepted => ("#2e9e44", "accepted"),
        ViewStatus::SeedKept => ("#e69500", "rejected"),
        ViewStatus::Excluded => ("#cc3333", "rejected"),
        ViewStatus::Skipped => ("#999999", "skipped"),
    }
}

const PALETTE: [&str; 10] =
    ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf"];

fn summary(report: &FuseReport, rmse_m: Option<f64>) -> Vec<KeyValue> {
    let count = |f: &dyn Fn(ViewStatus) -> bool| report.views.iter().filter(|v| f(v.status)).count();
    let registered = count(&|s| matches!(s, ViewStatus::Anchor | ViewStatus::Accepted));
    let rejected = count(&|s| matches!(s, ViewStatus::SeedKept | ViewStatus::Excluded));
    let mut rows = vec![
        KeyValue::new("scan", report.scan.clone()),
        KeyValue::with_id("model points", report.model_points.to_string(), "points"),
    ];
    if let Some(r) = rmse_m {
        rows.push(KeyValue::with_id("RMSE (mm)", format!("{:.3}", r * 1e3), "rmse"));
    }
    rows.push(KeyValue::with_id(
        "views",
        format!(
            "{} ({registered} registered, {rejected} rejected, {} skipped)",
            report.views.len(),
            count(&|s| s == ViewStatus::Skipped)
        ),
        "views",
    ));
    rows.push(KeyValue::new("total time (s)", format!("{:.2}", report.seconds)));
    if let Some(f) = &report.floor {
        rows.push(KeyValue::new("floor removed (points)", f.removed.to_string()));
    }
    if let Some(c) = &report.clusters {
        rows.push(KeyValue::new(
            "clusters",
            format!(
                "{} found; kept {}, removed {} in others and {} noise",
                c.clusters, c.kept, c.removed_clusters, c.noise
            ),
        ));
    }
    rows
}

fn view_table(views: &[ViewReport]) -> Table {
    let header =
        ["view", "status", "points", "correction mm", "correction deg", "iterations", "fitness", "inlier RMSE mm"];
    let rows = views
        .iter()
        .map(|v| {
            let cells = vec![
                v.index.to_string(),
                if v.reason.is_empty() {
                    status_name(v.status).to_string()
                } else {
                    format!("{}: {}", status_name(v.status), v.reason)
                },
                v.points.to_string(),
                format!("{:.2}", v.correction_mm),
                format!("{:.3}", v.correction_deg),
                v.iterations.to_string(),
                format!("{:.3}", v.fitness),
                format!("{:.3}", v.inlier_rmse_mm),
            ];
            (cells, Some(status_style(v.status).1.to_string()))
        })
        .collect();
    Table { header: header.map(String::from).to_vec(), rows, id: Some("view-table".into()) }
}

fn correction_plots(views: &[ViewReport]) -> Vec<Block> {
    let bars = |value: &dyn Fn(&ViewReport) -> f64| -> Vec<Bar> {
        views
            .iter()
            .map(|v| Bar {
                label: v.index.to_string(),
                value: if v.status == ViewStatus::Skipped { f64::NAN } else { value(v) },
                color: status_style(v.status).0.to_string(),
            })
            .collect()
    };
    vec![
        Block::Svg(bar_chart(
            &Chart::new("registration correction: translation", "view", "mm"),
            &bars(&|v| v.correction_mm),
        )),
        Block::Svg(bar_chart(
            &Chart::new("registration correction: rotation", "view", "deg"),
            &bars(&|v| v.correction_deg),
        )),
        Block::Text(
            "Bars: blue anchor, green accepted, orange rejected (seed pose kept), red rejected (excluded); skipped \
             views have no bar."
                .into(),
        ),
    ]
}

fn convergence_plots(views: &[ViewReport]) -> Vec<Block> {
    let series = |value: &dyn Fn(&crate::registration::LevelStats) -> f64| -> Vec<Series> {
        views
            .iter()
            .filter(|v| !v.levels.is_empty())
            .enumerate()
            .map(|(k, v)| Series {
                name: format!("view {}", v.index),
                color: PALETTE[k % PALETTE.len()].to_string(),
                points: v.levels.iter().enumerate().map(|(l, s)| ((l + 1) as f64, value(s))).collect(),
            })
            .collect()
    };
    let mut rmse = Chart::new("ICP inlier RMSE per level (coarse to fine)", "level", "mm");
    let mut fitness = Chart::new("ICP fitness per level", "level", "fitness");
    rmse.height = 340;
    fitness.height = 340;
    vec![
        Block::Svg(line_chart(&rmse, &series(&|s| s.inlier_rmse_m * 1e3))),
        Block::Svg(line_chart(&fitness, &series(&|s| s.fitness))),
    ]
}

/// Builds the page of a fuse run: `model` is the fused cloud, `rmse_m` an RMSE against ground
/// truth when the caller has one (shown as `id="rmse"`, in millimetres).
///
/// # Errors
/// [`crate::Error::Invalid`] for bad render parameters or an inconsistent model cloud.
pub fn fuse_page(
    report: &FuseReport,
    model: &PointCloud,
    rmse_m: Option<f64>,
    params: &PageParams,
) -> Result<RenderedPage> {
    let mut sections =
        vec![Section { heading: "Summary".into(), blocks: vec![Block::KeyValues(summary(report, rmse_m))] }];
    if !report.warnings.is_empty() {
        sections.push(Section { heading: "Warnings".into(), blocks: vec![Block::List(report.warnings.clone())] });
    }
    let mut renders = Vec::new();
    if model.is_empty() {
        sections.push(Section { heading: "Model".into(), blocks: vec![Block::Text("The model is empty.".into())] });
    } else {
        let cloud = ViewerCloud::from_cloud(model, params.max_viewer_points)?;
        sections.push(Section { heading: "3D view".into(), blocks: vec![Block::Cloud(cloud)] });
        let mut render = params.render.clone();
        if render.spacing_m.is_none() {
            render.spacing_m = Some(estimate_spacing(&model.points)?).filter(|s| *s > 0.0);
        }
        // the views side by side (each a raster and a PNG encoding)
        let pngs: Vec<Vec<u8>> = params
            .views
            .par_iter()
            .map(|view| png_bytes(&render_cloud(model, *view, &render)?))
            .collect::<Result<_>>()?;
        let mut pictures = Vec::new();
        for (view, png) in params.views.iter().zip(pngs) {
            pictures.push(Picture { caption: view.name().into(), png: png.clone() });
            renders.push((format!("{}.png", view.name()), png));
        }
        sections.push(Section { heading: "Model".into(), blocks: vec![Block::Pictures(pictures)] });
    }
    let mut registration = correction_plots(&report.views);
    registration.push(Block::Table(view_table(&report.views)));
    sections.push(Section { heading: "Registration per view".into(), blocks: registration });
    sections.push(Section {
        heading: "ICP convergence (last run of each view)".into(),
        blocks: convergence_plots(&report.views),
    });
    let stages = Table {
        header: ["stage", "points in", "points out", "seconds"].map(String::from).to_vec(),
        rows: report
            .stages
            .iter()
            .map(|s| {
                (
                    vec![
                        s.name.clone(),
                        s.points_in.to_string(),
                        s.points_out.to_string(),
                        format!("{:.3}", s.seconds),
                    ],
                    None,
                )
            })
            .collect(),
        id: Some("stage-table".into()),
    };
    sections.push(Section { heading: "Stages".into(), blocks: vec![Block::Table(stages)] });
    let page = Page { title: format!("awl fuse report: {}", report.scan), sections };
    Ok(RenderedPage { page, renders })
}
