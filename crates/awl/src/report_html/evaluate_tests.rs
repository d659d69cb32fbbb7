//! The evaluate page on a known case: a 30 cm cube's surface samples pushed 2.5 mm out along their
//! normals, so every model point is 2.5 mm from the CAD (the middle of the 0-5 mm heatmap).

use nalgebra::{Isometry3, Point3};

use super::evaluate::*;
use super::rendered::PageParams;
use crate::cloud::PointCloud;
use crate::eval::{EvaluateParams, Evaluation, evaluate};
use crate::mesh::TriMesh;
use crate::render::{Colormap, RenderParams};

/// A cube of side `a` at the origin's corner, triangles counter-clockwise from outside.
fn cube(a: f64) -> TriMesh {
    let vertices: Vec<Point3<f64>> = (0..8u32)
        .map(|i| Point3::new(f64::from(i & 1) * a, f64::from((i >> 1) & 1) * a, f64::from((i >> 2) & 1) * a))
        .collect();
    let centre = Point3::new(a / 2.0, a / 2.0, a / 2.0);
    let mut triangles = Vec::new();
    for axis in 0..3 {
        for side in 0..2u32 {
            let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
            let corner = |u: u32, v: u32| (side << axis) | (u << b) | (v << c);
            let quad = [corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1)];
            for mut t in [[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]] {
                let p = t.map(|i| vertices[i as usize]);
                let n = (p[1] - p[0]).cross(&(p[2] - p[0]));
                if n.dot(&(p[0] - centre)) < 0.0 {
                    t.swap(1, 2);
                }
                triangles.push(t);
            }
        }
    }
    TriMesh { vertices, triangles }
}

fn offset_evaluation() -> Evaluation {
    let cad = cube(0.3);
    let samples = cad.sample_surface(6000, 3).expect("samples");
    let normals = samples.normals.clone().expect("normals");
    let points = samples.points.iter().zip(&normals).map(|(p, n)| p + n * 0.0025).collect();
    let model = PointCloud { points, normals: Some(normals), colors: None };
    let mut params = EvaluateParams { cad_samples: 20_000, completeness_samples: 5_000, ..EvaluateParams::default() };
    // Keep the given pose: a rigid shift would fit three faces and push the other three off.
    params.icp.levels.iter_mut().for_each(|l| l.max_iterations = 0);
    evaluate(&model, &cad, Some(&Isometry3::identity()), &params).expect("evaluate")
}

fn text_of<'a>(html: &'a str, id: &str) -> &'a str {
    let at = html.find(&format!("id=\"{id}\">")).unwrap_or_else(|| panic!("no element {id}"));
    let body = &html[at + id.len() + 6..];
    &body[..body.find('<').expect("closing tag")]
}

#[test]
fn evaluate_page_has_ids_heatmaps_histogram_and_the_viewer() {
    let e = offset_evaluation();
    let on = e.summary.distances.on_object.as_ref().expect("on object");
    // Every point is 2.5 mm out (f32 coordinates of a 30 cm cube: within 1e-6 m).
    assert!((on.rmse_m - 0.0025).abs() < 1e-6 && (on.max_m - 0.0025).abs() < 1e-6, "{on:?}");
    let params = PageParams {
        render: RenderParams { width: 320, height: 240, ..RenderParams::default() },
        ..PageParams::default()
    };
    let out = evaluate_page(&e, "offset <cube>", &params).expect("page");
    let names: Vec<&str> = out.renders.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["heatmap-front.png", "heatmap-side.png", "heatmap-top.png", "heatmap-iso.png"]);
    let html = out.page.to_html().expect("html");
    assert_eq!(html.matches("data:image/png;base64,").count(), 4, "one picture per render");
    assert_eq!(html.matches("<svg").count(), 1, "the histogram");
    assert!(html.contains(">distance to the CAD (all model points)</text>"));
    assert_eq!(text_of(&html, "rmse"), format!("{:.3}", on.rmse_m * 1e3));
    assert_eq!(text_of(&html, "points"), "6000");
    assert_eq!(text_of(&html, "p95"), format!("{:.3}", on.p95_m * 1e3));
    assert_eq!(text_of(&html, "off-object"), "0.00");
    for id in ["mean", "median", "max", "rmse-all", "completeness-2mm", "completeness-5mm", "completeness-10mm"] {
        assert!(html.contains(&format!("id=\"{id}\"")), "{id}");
    }
    assert!(text_of(&html, "alignment-method").starts_with("given start pose"));
    assert!(html.contains("<table id=\"T_object_model\">") && html.contains("data-count=\"6000\""));
    assert!(html.contains("offset &lt;cube&gt;"));
    assert_eq!(completeness_id(2.5), "completeness-2_5mm");

    // The top view shows the cube's top face: 2.5 mm of 0-5 mm is the colormap's middle.
    let (_, png) = &out.renders[2];
    let mut reader = png::Decoder::new(std::io::Cursor::new(png)).read_info().expect("png");
    let mut buf = vec![0; reader.output_buffer_size().expect("size")];
    let info = reader.next_frame(&mut buf).expect("frame");
    assert_eq!((info.width, info.height), (320, 240));
    let mid = Colormap::Turbo.rgb(0.5);
    let near = |p: &[u8]| p.iter().zip(mid).all(|(a, b)| a.abs_diff(b) <= 6);
    let middle = buf.chunks_exact(3).filter(|p| near(p)).count();
    let drawn = buf.chunks_exact(3).filter(|p| *p != [255, 255, 255]).count();
    // The legend's bar holds a few rows of that colour too; the face fills most of the scene.
    assert!(middle * 2 > drawn, "{middle} of {drawn} drawn pixels at the middle colour");

    let mut short = e;
    short.distances_m.pop();
    assert!(evaluate_page(&short, "x", &params).is_err(), "one distance per point");
}

/// The sanity checks on the page: a quiet case has no alert; warnings come first, in the red box,
/// before any figure. A NaN figure is refused naming it.
#[test]
fn warnings_are_the_first_thing_on_the_page_and_a_nan_is_refused_by_name() {
    let mut e = offset_evaluation();
    // every point 2.5 mm out: all within the 5 mm of the near check; the sizes: the CAD's farthest
    // sample at the cube's half diagonal (0.3 sqrt 3 = 0.520 m), the model's 99th percentile below it
    // (0.499 m): within 5 %
    assert!(e.summary.warnings.is_empty(), "{:?}", e.summary.warnings);
    assert_eq!(e.summary.sanity.near_fraction, 1.0);
    assert!((e.summary.sanity.cad_size_m - 0.3 * 3f64.sqrt()).abs() < 0.002, "{:?}", e.summary.sanity);
    assert!((1.0..1.05).contains(&e.summary.sanity.size_ratio), "{:?}", e.summary.sanity);
    let page =
        |e: &Evaluation| evaluate_page(e, "x", &PageParams::default()).expect("page").page.to_html().expect("html");
    assert!(!page(&e).contains("id=\"warnings\""));
    e.summary.warnings = vec!["only 1.0 % of the model's points lie within 5 mm of the CAD".into()];
    let html = page(&e);
    let (alert, summary) =
        (html.find("id=\"warnings\"").expect("alert"), html.find("<h2>Summary</h2>").expect("summary"));
    assert!(alert < summary, "the warnings come before the figures");
    assert!(html.contains("<h2>WARNING: these figures may mean nothing</h2>"));
    assert!(html.contains("<li>only 1.0 % of the model&#39;s points") || html.contains("<li>only 1.0 % of the model"));

    crate::eval::sanity::check_finite(&e.summary).expect("finite");
    e.summary.completeness.thresholds[1].fraction = f64::NAN;
    let err = crate::eval::sanity::check_finite(&e.summary).err().map(|e| e.to_string()).unwrap_or_default();
    assert_eq!(
        err,
        "the completeness at 5 mm is not finite: it is NaN: the evaluation means nothing; check the model, the CAD and the start pose"
    );
    e.summary.distances.on_object = None;
    let err = crate::eval::sanity::check_finite(&e.summary).err().map(|e| e.to_string()).unwrap_or_default();
    assert!(
        err.starts_with("the RMSE of the on-object points is not finite: no model point lies within 10 mm"),
        "{err}"
    );
}
