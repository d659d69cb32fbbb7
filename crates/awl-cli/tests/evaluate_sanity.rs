//! `awl evaluate` refuses figures that mean nothing and warns about a mismatched pair
//! (`awl::eval::sanity`): a truth.json in millimetres exits 1 with nothing written (never
//! "RMSE NaN" with exit 0); another part's CAD warns on stderr, in summary.json and at the top of
//! report.html; the right CAD from the right truth says no warning. The model: 30 000 samples of
//! `sim_reference/box_seed1/cad.ply` placed by its truth.json.

mod common;

use std::path::{Path, PathBuf};

use awl::PointCloud;
use awl::io::mesh::{read_mesh, write_cloud};
use awl::io::truth::read_truth;
use common::{awl, read_json, s, text};

fn shared_data() -> PathBuf {
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let dir = std::env::var_os("AWL_SHARED_DATA").map(PathBuf::from).unwrap_or_else(|| repo.join("../shared/data"));
    assert!(dir.is_dir(), "{}: shared test data missing (set AWL_SHARED_DATA)", dir.display());
    dir
}

/// The box's CAD samples in the world (its truth's `T_world_object`), as `dir/model.ply`.
fn box_model(dir: &Path) -> PathBuf {
    let scan = shared_data().join("sim_reference/box_seed1");
    let truth = read_truth(&scan).expect("truth");
    let samples = read_mesh(&scan.join("cad.ply")).expect("cad").sample_surface(30_000, 5).expect("samples");
    let pose = truth.world_from_object.cast::<f32>();
    let model = PointCloud::from_points(samples.points.iter().map(|p| pose * p).collect());
    let path = dir.join("model.ply");
    write_cloud(&path, &model).expect("write");
    path
}

#[test]
fn millimetres_are_refused_a_wrong_cad_warns_the_right_pair_is_quiet() {
    let dir = tempfile::tempdir().expect("tempdir");
    let model = box_model(dir.path());
    let data = shared_data().join("sim_reference");
    let (box_cad, shell_cad, truth) =
        (data.join("box_seed1/cad.ply"), data.join("shell_seed1/cad.ply"), data.join("box_seed1/truth.json"));

    // the right pair: no warning anywhere
    let out_ok = dir.path().join("ok");
    let run =
        awl(&["evaluate", s(&model), "--cad", s(&box_cad), "--truth", s(&truth), "-o", s(&out_ok), "--threads", "2"]);
    let t = text(&run);
    assert!(run.status.success(), "{t}");
    assert!(!t.contains("warning"), "{t}");
    let summary = read_json(&out_ok.join("summary.json"));
    assert_eq!(summary["warnings"].as_array().map(Vec::len), Some(0), "{}", summary["warnings"]);
    let near = summary["sanity"]["near_fraction"].as_f64().expect("near_fraction");
    assert!(near > 0.99, "{near}");
    let html = std::fs::read_to_string(out_ok.join("report.html")).expect("page");
    assert!(!html.contains("id=\"warnings\""));

    // the truth in millimetres: exit 1, the figure and the units named, nothing written
    let mut value = read_json(&truth);
    for r in 0..3 {
        value["T_world_object"][r][3] = serde_json::json!(value["T_world_object"][r][3].as_f64().expect("t") * 1000.0);
    }
    let truth_mm = dir.path().join("truth_mm.json");
    std::fs::write(&truth_mm, value.to_string()).expect("write");
    let out_mm = dir.path().join("mm");
    let run = awl(&[
        "evaluate",
        s(&model),
        "--cad",
        s(&box_cad),
        "--truth",
        s(&truth_mm),
        "-o",
        s(&out_mm),
        "--threads",
        "2",
    ]);
    let t = text(&run);
    assert_eq!(run.status.code(), Some(1), "{t}");
    assert!(t.contains("the RMSE of the on-object points is not finite") && t.contains("millimetres"), "{t}");
    assert!(!t.contains("RMSE NaN"), "{t}");
    assert!(!out_mm.exists(), "nothing written");

    // another part's CAD (the shell), no start: figures written, and warned everywhere
    let out_wrong = dir.path().join("wrong");
    let run = awl(&["evaluate", s(&model), "--cad", s(&shell_cad), "-o", s(&out_wrong), "--threads", "2"]);
    let t = text(&run);
    println!("{t}");
    assert!(run.status.success(), "{t}");
    assert!(t.contains("warning: only") && t.contains("within 5 mm of the CAD"), "{t}");
    let summary = read_json(&out_wrong.join("summary.json"));
    let near = summary["sanity"]["near_fraction"].as_f64().expect("near_fraction");
    assert!(near < 0.5, "{near}");
    assert!(summary["warnings"][0].as_str().is_some_and(|w| w.contains("within 5 mm")), "{}", summary["warnings"]);
    let html = std::fs::read_to_string(out_wrong.join("report.html")).expect("page");
    let alert = html.find("id=\"warnings\"").expect("the alert");
    assert!(alert < html.find("<h2>Summary</h2>").expect("summary"), "the warning before the figures");
}
