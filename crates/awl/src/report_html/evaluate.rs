//! The page of `awl evaluate`: summary (RMSE, distance statistics, completeness, point count),
//! how the alignment was found, heatmap renders of the distance to the CAD with a legend in
//! millimetres, the distance histogram and a 3D view colored by the distance.
//!
//! Renders and the 3D view show the model in its own frame (a fused model: the world, z up), turned
//! so that the summary's `up_model` points up, since the standard viewpoints assume z up.

use super::page::{Block, KeyValue, Page, Picture, Section, Table};
use super::rendered::{PageParams, RenderedPage};
use super::viewer::ViewerCloud;
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::eval::Evaluation;
use crate::eval::summary::{AlignmentSummary, EvaluationSummary};
use crate::render::plot::{Chart, histogram};
use crate::render::{Colormap, ScalarScale, estimate_spacing, png_bytes, render_scalar};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// Millimetres with 3 decimals, or `-` when not finite.
fn mm(m: f64) -> String {
    if m.is_finite() { format!("{:.3}", m * 1e3) } else { "-".into() }
}

/// Element id of the completeness at `threshold_mm` (`completeness-5mm`, `completeness-2_5mm`).
pub fn completeness_id(threshold_mm: f64) -> String {
    format!("completeness-{}mm", format!("{threshold_mm}").replace('.', "_"))
}

fn summary_rows(s: &EvaluationSummary) -> Vec<KeyValue> {
    let d = &s.distances;
    let on = d.on_object.as_ref();
    let stat = |f: &dyn Fn(&crate::eval::summary::DistanceStats) -> f64| mm(on.map_or(f64::NAN, f));
    let mut rows = vec![
        KeyValue::with_id("model points", s.model_points.to_string(), "points"),
        KeyValue::with_id("RMSE (mm)", stat(&|o| o.rmse_m), "rmse"),
        KeyValue::with_id("mean (mm)", stat(&|o| o.mean_m), "mean"),
        KeyValue::with_id("median (mm)", stat(&|o| o.median_m), "median"),
        KeyValue::with_id("95th percentile (mm)", stat(&|o| o.p95_m), "p95"),
        KeyValue::with_id("max (mm)", stat(&|o| o.max_m), "max"),
        KeyValue::new(
            "statistics over",
            format!(
                "the {} points within {} mm of the CAD (on the object)",
                on.map_or(0, |o| o.points),
                d.on_object_m * 1e3
            ),
        ),
        KeyValue::with_id("off the object (%)", format!("{:.2}", d.off_object_fraction * 100.0), "off-object"),
        KeyValue::with_id("RMSE of all points (mm)", mm(d.all.rmse_m), "rmse-all"),
    ];
    for c in &s.completeness.thresholds {
        rows.push(KeyValue::with_id(
            &format!("completeness at {} mm (%)", c.threshold_mm),
            format!("{:.2}", c.fraction * 100.0),
            &completeness_id(c.threshold_mm),
        ));
    }
    let facing = s.completeness.facing_down_deg.map_or("every sample counts".to_string(), |a| {
        format!("samples facing within {a} deg of down do not count (never seen on the floor)")
    });
    rows.push(KeyValue::new(
        "completeness samples",
        format!("{} of {} CAD surface samples; {facing}", s.completeness.samples_counted, s.completeness.samples),
    ));
    rows.push(KeyValue::new("CAD", format!("{} triangles, {:.4} m²", s.cad_triangles, s.cad_area_m2)));
    let c = &s.sanity;
    rows.push(KeyValue::with_id(
        &format!("near the CAD (within {} mm, %)", c.near_m * 1e3),
        format!("{:.2}", c.near_fraction * 100.0),
        "near-cad",
    ));
    rows.push(KeyValue::new(
        "sizes (bounding-sphere diameters)",
        format!("model {:.3} m, CAD {:.3} m ({:.2}x)", c.model_size_m, c.cad_size_m, c.size_ratio),
    ));
    rows.push(KeyValue::new(
        "time (s)",
        format!(
            "{:.2} (prepare {:.2}, alignment {:.2}, metrics {:.2})",
            s.timings_s.total_s, s.timings_s.prepare_s, s.timings_s.alignment_s, s.timings_s.metrics_s
        ),
    ));
    rows
}

fn alignment_blocks(a: &AlignmentSummary) -> Vec<Block> {
    let how = match (&a.global, a.method.as_str()) {
        (Some(g), _) => format!(
            "global search: {} hypotheses, the {} best refined by the fine ICP, the best score kept",
            g.hypotheses,
            g.refined.len()
        ),
        (None, "given") => "given start pose, refined by the fine ICP".to_string(),
        (None, other) => other.to_string(),
    };
    let icp = &a.icp;
    let rows = vec![
        KeyValue::with_id("method", how, "alignment-method"),
        KeyValue::new("start from", a.init_source.clone().unwrap_or_else(|| "-".into())),
        KeyValue::new("moved from the start", format!("{:.2} mm, {:.3} deg", a.moved_m * 1e3, a.moved_deg)),
        KeyValue::new(
            "fine ICP",
            format!(
                "{} after {} iterations; fitness {:.3}, inlier RMSE {} mm, conditioning {:.1}",
                if icp.converged { "converged" } else { "not converged" },
                icp.iterations,
                icp.fitness,
                mm(icp.inlier_rmse_m),
                icp.conditioning
            ),
        ),
        KeyValue::new(
            "score",
            format!(
                "{:.4}; {:.2} % of the scored points within {} mm of the CAD",
                a.score,
                a.inlier_fraction * 100.0,
                a.score_threshold_m * 1e3
            ),
        ),
    ];
    let matrix = Table {
        header: ["T_object_model", "", "", ""].map(String::from).to_vec(),
        rows: a.object_model.iter().map(|r| (r.iter().map(|v| format!("{v:.6}")).collect(), None)).collect(),
        id: Some("T_object_model".into()),
    };
    let mut blocks = vec![Block::KeyValues(rows), Block::Table(matrix)];
    if let Some(g) = &a.global {
        let rows = g
            .refined
            .iter()
            .enumerate()
            .map(|(k, c)| {
                let fine = g.refined_scores.get(k).map_or("-".into(), |s| format!("{s:.4}"));
                (vec![(k + 1).to_string(), format!("{:.4}", c.score), format!("{:.3}", c.inlier_fraction), fine], None)
            })
            .collect();
        let header = ["candidate", "coarse score", "coarse inlier fraction", "fine score"];
        blocks.push(Block::Table(Table {
            header: header.map(String::from).to_vec(),
            rows,
            id: Some("candidates".into()),
        }));
    }
    blocks
}

/// The model in its own frame, turned so that `up_model` is +z.
fn model_upright(e: &Evaluation) -> PointCloud {
    let up = Vector3::from(e.summary.completeness.up_model);
    let level = UnitQuaternion::rotation_between(&up, &Vector3::z())
        .unwrap_or_else(|| UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI));
    let upright_from_object = Isometry3::from_parts(Translation3::identity(), level) * e.object_from_model.inverse();
    e.model_object.transformed(&upright_from_object)
}

fn histogram_svg(s: &EvaluationSummary) -> Result<String> {
    let h = &s.histogram;
    let edges: Vec<f64> = (0..=h.counts.len()).map(|k| k as f64 * h.bin_mm).collect();
    let counts: Vec<u64> = h.counts.iter().map(|&c| c as u64).collect();
    histogram(&Chart::new("distance to the CAD (all model points)", "mm", "points"), &edges, &counts, "#3366cc")
}

/// Builds the page of an evaluation; `subject` names what was evaluated (e.g. `model.ply vs cad.ply`)
/// in the title.
///
/// # Errors
/// [`Error::Invalid`] for bad render parameters, an evaluation whose distances do not match its
/// points, or an empty histogram.
pub fn evaluate_page(evaluation: &Evaluation, subject: &str, params: &PageParams) -> Result<RenderedPage> {
    let s = &evaluation.summary;
    if evaluation.distances_m.len() != evaluation.model_object.len() {
        return Err(Error::invalid(
            "evaluation",
            format!("{} distances for {} points", evaluation.distances_m.len(), evaluation.model_object.len()),
        ));
    }
    let mut sections = Vec::new();
    if !s.warnings.is_empty() {
        // first, before any figure: they may mean nothing
        sections.push(Section {
            heading: "WARNING: these figures may mean nothing".into(),
            blocks: vec![Block::Alert(s.warnings.clone())],
        });
    }
    sections.extend([
        Section { heading: "Summary".into(), blocks: vec![Block::KeyValues(summary_rows(s))] },
        Section { heading: "Alignment".into(), blocks: alignment_blocks(&s.alignment) },
    ]);
    let max_m = s.heatmap.max_mm * 1e-3;
    let scale = ScalarScale { colormap: Colormap::Turbo, lo_m: 0.0, hi_m: max_m as f32 };
    let values: Vec<f32> = evaluation.distances_m.iter().map(|&d| d as f32).collect();
    let model = model_upright(evaluation);
    let mut renders = Vec::new();
    if !model.is_empty() {
        let legend = format!(
            "Distance of each model point to the CAD surface: turbo colormap from 0 (blue) to {} mm (red) and beyond.",
            s.heatmap.max_mm
        );
        let cloud = ViewerCloud::from_scalar(&model, &values, &scale, params.max_viewer_points)?;
        sections.push(Section {
            heading: "3D view".into(),
            blocks: vec![Block::Text(legend.clone()), Block::Cloud(cloud)],
        });
        let mut render = params.render.clone();
        if render.spacing_m.is_none() {
            render.spacing_m = Some(estimate_spacing(&model.points)?).filter(|v| *v > 0.0);
        }
        let mut pictures = Vec::new();
        for view in &params.views {
            let (image, _) = render_scalar(&model, &values, &scale, *view, &render)?;
            let png = png_bytes(&image)?;
            pictures.push(Picture { caption: format!("{}: distance to the CAD, mm", view.name()), png: png.clone() });
            renders.push((format!("heatmap-{}.png", view.name()), png));
        }
        sections
            .push(Section { heading: "Heatmap".into(), blocks: vec![Block::Text(legend), Block::Pictures(pictures)] });
    }
    let overflow = format!(
        "{} bins of {} mm; {} points at or beyond {} mm are not shown.",
        s.histogram.counts.len(),
        s.histogram.bin_mm,
        s.histogram.overflow,
        s.histogram.max_mm
    );
    sections.push(Section {
        heading: "Distance histogram".into(),
        blocks: vec![Block::Svg(histogram_svg(s)?), Block::Text(overflow)],
    });
    Ok(RenderedPage { page: Page { title: format!("awl evaluate report: {subject}"), sections }, renders })
}
