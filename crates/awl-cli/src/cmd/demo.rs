//! `awl demo`: the whole modeling job on a simulated scan, in one command. Simulates the default
//! scene into DIR/scan, fuses it into DIR/fuse, evaluates the model against the scan's CAD (from the
//! true pose) into DIR/evaluate, and prints the headline: accuracy, completeness, timings, how much
//! registration corrected the recorded poses, and where the two report.html pages are.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use awl::eval::{EvaluateParams, evaluate, trajectory_correction};
use awl::io::mesh::read_mesh;
use awl::io::outputs::OutputCheck;
use awl::io::scan::read_scan;
use awl::io::truth::read_truth;
use awl::pipeline::FuseConfig;
use awl::sim::{SceneKind, SimParams, simulate, write_simulation};

use super::common::{lock_outputs, prepare_output, set_threads};

/// The simulated workpiece.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum DemoScene {
    /// 48.5 x 48 x 30 cm box, tag on a side.
    Box,
    /// 50 x 40 x 35 cm free-form dome shell with a groove over the top.
    Shell,
}

/// Arguments of `awl demo`.
#[derive(clap::Args)]
pub struct DemoArgs {
    /// Output folder: scan/, fuse/ and evaluate/ are written there (must not exist or be empty, unless --force).
    #[arg(short = 'o', long = "output", default_value = "awl-demo")]
    pub output: PathBuf,
    /// Replace the demo's scan/, fuse/ and evaluate/ folders in a non-empty output folder (other files are kept).
    #[arg(long)]
    pub force: bool,
    /// Workpiece.
    #[arg(long, value_enum, default_value = "box")]
    pub scene: DemoScene,
    /// Random seed of the simulation: the same seed gives the same scan.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Number of views.
    #[arg(long, default_value_t = 12)]
    pub views: usize,
    /// No progress lines: only the headline.
    #[arg(long)]
    pub quiet: bool,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// Runs `awl demo`.
pub fn run(args: &DemoArgs) -> anyhow::Result<()> {
    let start = Instant::now();
    set_threads(args.threads)?;
    let (scan_dir, fuse_dir, eval_dir) =
        (args.output.join("scan"), args.output.join("fuse"), args.output.join("evaluate"));
    // DIR locked first (a second demo into it is refused naming this one), held to the end
    let _outputs = lock_outputs(
        OutputCheck::new(args.force)
            .locked_folder(&args.output, "-o")
            .output_folder(&scan_dir, "-o DIR/scan", super::simulate::SIMULATE_OUTPUTS)
            .output_folder(&fuse_dir, "-o DIR/fuse", super::fuse::FUSE_OUTPUTS)
            .output_folder(&eval_dir, "-o DIR/evaluate", super::evaluate::EVALUATE_OUTPUTS),
    )?;
    prepare_output(&args.output, args.force, &[])?;
    let say = |line: String| {
        if !args.quiet {
            println!("{line}");
        }
    };
    let scene = match args.scene {
        DemoScene::Box => SceneKind::Box,
        DemoScene::Shell => SceneKind::Shell,
    };

    let t = Instant::now();
    let params = SimParams { views: args.views, seed: args.seed, ..SimParams::scan(scene) };
    let sim = simulate(&params).context("simulation failed")?;
    write_simulation(&scan_dir, &sim, args.force)
        .with_context(|| format!("cannot write the scan folder {}", scan_dir.display()))?;
    say(format!(
        "[1/3] simulated a {} scan: {} views, seed {}, {} noise -> {} ({:.1} s)",
        scene.name(),
        sim.views.len(),
        args.seed,
        params.noise.name(),
        scan_dir.display(),
        t.elapsed().as_secs_f64()
    ));

    let scan = read_scan(&scan_dir)?;
    let job = super::fuse::fuse_with_progress(&scan, &FuseConfig::default(), args.quiet)?;
    let fused = &job.fused;
    say(format!(
        "[2/3] fused {} views into {} points in {:.2} s",
        fused.report.views.len(),
        fused.report.model_points,
        fused.report.seconds
    ));
    for w in job.warnings() {
        say(format!("      warning: {w}"));
    }

    let t = Instant::now();
    let truth = read_truth(&scan_dir)?;
    let cad_path = scan_dir.join(&truth.cad);
    let cad = read_mesh(&cad_path)?;
    let mut evaluation =
        evaluate(&fused.model, &cad, Some(&truth.world_from_object.inverse()), &EvaluateParams::default())
            .context("evaluating the fused model")?;
    let truth_path = scan_dir.join("truth.json");
    evaluation.summary.alignment.init_source = Some(truth_path.display().to_string());
    let s = &evaluation.summary;
    for w in &s.warnings {
        eprintln!("warning: {w}");
    }
    let rmse_m = s.distances.on_object.as_ref().map_or(f64::NAN, |o| o.rmse_m);
    let fuse_html = super::fuse::write_outputs(&fuse_dir, &job, Some(rmse_m))?;
    let model_path = fuse_dir.join("model.ply");
    let inputs = [model_path.as_path(), cad_path.as_path(), truth_path.as_path()];
    let eval_html = super::evaluate::write_outputs(
        &eval_dir,
        &evaluation,
        &inputs,
        &super::evaluate::subject(&model_path, &cad_path),
    )?;
    say(format!(
        "[3/3] evaluated the model against {} from the true pose in {:.1} s -> {}",
        cad_path.display(),
        t.elapsed().as_secs_f64(),
        eval_dir.display()
    ));

    let seeds = (0..scan.views.len()).map(|i| scan.world_from_camera(i)).collect::<Result<Vec<_>, _>>()?;
    let true_poses: Vec<_> = truth.views.iter().map(|v| v.world_from_camera).collect();
    let trajectory = match trajectory_correction(&seeds, &fused.poses, &true_poses) {
        Ok(c) => format!(
            "trajectory error {:.2} mm -> {:.2} mm (mean camera-centre error against truth.json, seeds -> registered, {} views)",
            c.seed_error_mm, c.registered_error_mm, c.views
        ),
        Err(e) => format!("trajectory error: not measured ({e})"),
    };
    println!(
        "RMSE {:.3} mm, completeness@5mm {:.1} %, off-object {:.2} %, {} points",
        rmse_m * 1e3,
        s.completeness_at(5.0).unwrap_or(f64::NAN) * 100.0,
        s.distances.off_object_fraction * 100.0,
        s.model_points
    );
    println!("fuse {:.2} s, total {:.1} s", fused.report.seconds, start.elapsed().as_secs_f64());
    println!("{trajectory}");
    println!("fuse report: {}", fuse_html.display());
    println!("evaluate report: {}", eval_html.display());
    Ok(())
}
