//! `awl evaluate MODEL --cad CAD -o OUT_DIR`: align a model to its CAD and measure it.

use std::path::{Path, PathBuf};

use anyhow::Context;
use awl::eval::file::{read_transform, write_evaluation};
use awl::eval::{EvaluateParams, Evaluation, evaluate};
use awl::io::outputs::{OutputCheck, StagedFolder};
use awl::io::truth::read_truth;
use awl::report_html::write::{REPORT_FILE, write_report};
use awl::report_html::{PageParams, evaluate_page};

use super::common::{lock_outputs, set_threads};

/// Arguments of `awl evaluate`.
#[derive(clap::Args)]
pub struct EvaluateArgs {
    /// The model: a point cloud (.ply or .pcd), e.g. `awl fuse`'s model.ply (scan's world frame).
    pub model: PathBuf,
    /// The CAD mesh (.ply, .stl or .obj), object frame, metres.
    #[arg(long)]
    pub cad: PathBuf,
    /// Initial `T_object_model`: JSON, a 4x4 row-major matrix, bare or under "T_object_model".
    #[arg(long, conflicts_with = "truth")]
    pub init: Option<PathBuf>,
    /// A truth.json: start from inverse(T_world_object) (the model is in the world frame).
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Output folder: summary.json, errors.ply, T_object_model.json, report.html (+ renders/*.png).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Print summary.json on stdout instead of the one-line headline.
    #[arg(long)]
    pub json: bool,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Replace an earlier evaluation's output folder (the same flag in every command).
    #[arg(long)]
    pub force: bool,
}

/// The entries `awl evaluate` writes in its output folder (`--force` replaces a folder holding only these).
pub const EVALUATE_OUTPUTS: &[&str] = &["summary.json", "errors.ply", "T_object_model.json", REPORT_FILE, "renders"];

/// `MODEL vs CAD` with the files' names, for the page's title.
pub fn subject(model: &Path, cad: &Path) -> String {
    let name = |p: &Path| p.file_name().map_or_else(|| p.display().to_string(), |n| n.to_string_lossy().into_owned());
    format!("{} vs {}", name(model), name(cad))
}

/// Writes `summary.json`, `errors.ply`, `T_object_model.json`, `report.html` and its
/// `renders/*.png` as the folder `out_dir`, whole or not at all (a temporary sibling renamed into
/// place); returns the page's path. The caller has checked `out_dir` against its inputs
/// ([`OutputCheck`]).
pub fn write_outputs(
    out_dir: &Path,
    evaluation: &Evaluation,
    inputs: &[&Path],
    subject: &str,
) -> anyhow::Result<PathBuf> {
    let page = evaluate_page(evaluation, subject, &PageParams::default())?;
    let staged = StagedFolder::begin(out_dir)?;
    write_evaluation(staged.path(), evaluation, inputs)?;
    write_report(staged.path(), &page.page, &page.renders)?;
    staged.commit()?;
    Ok(out_dir.join(REPORT_FILE))
}

/// Runs `awl evaluate`.
pub fn run(args: &EvaluateArgs) -> anyhow::Result<()> {
    set_threads(args.threads)?;
    let mut check = OutputCheck::new(args.force);
    check.input_file(&args.model, "MODEL").input_file(&args.cad, "--cad");
    if let Some(init) = &args.init {
        check.input_file(init, "--init");
    }
    if let Some(truth) = &args.truth {
        check.input_file(truth, "--truth");
    }
    // held until the folder is in place: no other run writes it meanwhile
    let _outputs = lock_outputs(check.output_folder(&args.output, "-o", EVALUATE_OUTPUTS))?;
    let model = super::common::read_cloud_warned(&args.model)?;
    anyhow::ensure!(!model.is_empty(), "{}: the model has no points", args.model.display());
    model.validate(&args.model.display().to_string()).context("remove or fix the model's non-finite points")?;
    let cad = super::common::read_mesh_warned(&args.cad)?;
    anyhow::ensure!(
        !cad.triangles.is_empty(),
        "{}: --cad: the mesh has no triangles ({} vertices): give a surface mesh (a PLY with a `face` element, an STL \
         with facets, an OBJ with `f` lines)",
        args.cad.display(),
        cad.vertices.len()
    );
    let (init, source) = match (&args.init, &args.truth) {
        (Some(path), _) => (Some(read_transform(path, "T_object_model")?), Some(path)),
        (None, Some(path)) => (Some(read_truth(path)?.world_from_object.inverse()), Some(path)),
        (None, None) => (None, None),
    };
    let mut evaluation = evaluate(&model, &cad, init.as_ref(), &EvaluateParams::default())
        .with_context(|| format!("evaluating {} against {}", args.model.display(), args.cad.display()))?;
    evaluation.summary.alignment.init_source = source.map(|p| p.display().to_string());
    let mut inputs = vec![args.model.as_path(), args.cad.as_path()];
    inputs.extend(args.init.as_deref());
    inputs.extend(args.truth.as_deref());
    write_outputs(&args.output, &evaluation, &inputs, &subject(&args.model, &args.cad))?;
    let s = &evaluation.summary;
    for w in &s.warnings {
        eprintln!("warning: {w}");
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(s)?);
    } else {
        // (evaluate refuses a summary with no on-object point: the RMSE is there)
        let rmse = s.distances.on_object.as_ref().map_or(f64::NAN, |o| o.rmse_m * 1e3);
        println!(
            "RMSE {rmse:.3} mm (points within {:.0} mm of the CAD; all points {:.3} mm), completeness@5mm {:.1} %, {} points, {:.1} % off the object; alignment {}; wrote {}",
            s.distances.on_object_m * 1e3,
            s.distances.all.rmse_m * 1e3,
            s.completeness_at(5.0).unwrap_or(f64::NAN) * 100.0,
            s.model_points,
            s.distances.off_object_fraction * 100.0,
            s.alignment.method,
            args.output.display()
        );
    }
    Ok(())
}
