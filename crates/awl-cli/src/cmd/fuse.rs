//! `awl fuse SCAN_DIR -o OUT_DIR`: the modeling pipeline.

use std::path::{Path, PathBuf};

use anyhow::Context;
use awl::io::mesh::write_cloud;
use awl::io::outputs::{OutputCheck, StagedFolder};
use awl::io::scan::read_scan;
use awl::job::{FuseJob, fuse_job};
use awl::pipeline::{FuseConfig, ViewStatus};
use awl::report_html::write::{REPORT_FILE, write_report};
use awl::report_html::{PageParams, fuse_page};
use awl::scan::Scan;
use awl::workpiece::json::write_workpiece;
use awl::workpiece::{WORKPIECE_FILE, WorkpieceParams};

use super::common::{lock_outputs, set_threads, stage_bar, write_json};

/// Arguments of `awl fuse`.
#[derive(clap::Args)]
pub struct FuseArgs {
    /// The scan folder (awl-scan/1).
    #[arg(required_unless_present = "print_config")]
    pub scan: Option<PathBuf>,
    /// Output folder: model.ply, report.json, report.html and renders/*.png are written there.
    #[arg(short, long, required_unless_present = "print_config")]
    pub output: Option<PathBuf>,
    /// A TOML (or JSON) file overriding parameters of the preset; `false` switches an optional
    /// stage off. `--print-config` prints every key.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Print the resolved config (the preset and `--config`) as TOML, a comment on every key, and
    /// exit: given back as `--config`, it resolves to the same config.
    #[arg(long)]
    pub print_config: bool,
    /// The parameters the config file starts from: `accurate` (sub-millimetre on the simulated
    /// scans, a few seconds) or `fast` (every second pixel, coarser voxels, no joint refinement:
    /// about 6x faster, 0.4-1.6 mm).
    #[arg(long, value_enum, default_value_t = Preset::Accurate)]
    pub preset: Preset,
    /// Worker threads (default: all cores). Results are identical for any count.
    #[arg(long)]
    pub threads: Option<usize>,
    /// No progress bar, no summary.
    #[arg(long)]
    pub quiet: bool,
    /// Print the report as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// Replace an earlier fuse's output folder (the same flag in every command).
    #[arg(long)]
    pub force: bool,
}

/// The entries `awl fuse` writes in its output folder (`--force` replaces a folder holding only these).
pub const FUSE_OUTPUTS: &[&str] = &[MODEL_FILE, "report.json", REPORT_FILE, "renders", WORKPIECE_FILE];

/// The model's file in the output folder.
pub const MODEL_FILE: &str = "model.ply";

/// A starting set of parameters (`--preset`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Preset {
    /// [`FuseConfig::default`].
    Accurate,
    /// [`FuseConfig::fast`].
    Fast,
}

fn load_config(path: Option<&PathBuf>, base: FuseConfig) -> anyhow::Result<FuseConfig> {
    let Some(path) = path else { return Ok(base) };
    let text = awl::io::read_text_at_most(path, awl::io::MAX_JSON_BYTES)?;
    let config = if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("json")) {
        FuseConfig::from_json_on(base, &text)
    } else {
        FuseConfig::from_toml_on(base, &text)
    };
    let context = || format!("{}: invalid fuse config", path.display());
    let config = config.with_context(context)?;
    // the checks across keys too, while the file can still be named
    config.check().with_context(context)?;
    Ok(config)
}

/// Writes `model.ply`, `report.json`, `report.html` (self-contained; its renders also as
/// `renders/*.png`) and, when the scan declares a tag, `workpiece.json` as the folder `out_dir`,
/// whole or not at all (a temporary sibling renamed into place, replacing an earlier one).
/// `rmse_m` (an RMSE against ground truth, when the caller has one) goes on the page. Returns the
/// page's path.
pub fn write_outputs(out_dir: &Path, job: &FuseJob, rmse_m: Option<f64>) -> anyhow::Result<PathBuf> {
    let out = &job.fused;
    // the page is made before anything is written
    let page = fuse_page(&out.report, &out.model, rmse_m, &PageParams::default())?;
    let staged = StagedFolder::begin(out_dir)?;
    let dir = staged.path();
    write_cloud(&dir.join(MODEL_FILE), &out.model)?;
    write_json(&dir.join("report.json"), &out.report)?;
    if let Some(wp) = &job.workpiece {
        write_workpiece(&dir.join(WORKPIECE_FILE), wp)?;
    }
    write_report(dir, &page.page, &page.renders)?;
    staged.commit()?;
    Ok(out_dir.join(REPORT_FILE))
}

/// Runs the fuse job ([`fuse_job`]) with a stage progress bar on stderr (hidden when `quiet`).
pub fn fuse_with_progress(scan: &Scan, config: &FuseConfig, quiet: bool) -> anyhow::Result<FuseJob> {
    if config.view_memory == awl::pipeline::ViewMemory::Stream {
        crate::malloc::map_view_sized_blocks();
    }
    let bar = stage_bar(quiet);
    let progress = |stage: &str, done: usize, total: usize| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
        bar.set_message(stage.to_string());
    };
    let job = fuse_job(scan, config, &WorkpieceParams::default(), MODEL_FILE, &progress);
    bar.finish_and_clear();
    crate::malloc::release_free();
    Ok(job?)
}

/// Runs `awl fuse`.
pub fn run(args: &FuseArgs) -> anyhow::Result<()> {
    set_threads(args.threads)?;
    let base = match args.preset {
        Preset::Accurate => FuseConfig::default(),
        Preset::Fast => FuseConfig::fast(),
    };
    let config = load_config(args.config.as_ref(), base)?;
    if args.print_config {
        config.check()?;
        print!("{}", config.documented_toml()?);
        return Ok(());
    }
    let (Some(scan_dir), Some(output)) = (&args.scan, &args.output) else {
        anyhow::bail!("awl fuse needs SCAN_DIR and -o OUT_DIR (or --print-config)");
    };
    let scan = read_scan(scan_dir)?;
    let mut check = OutputCheck::new(args.force);
    check.input_folder(scan_dir, "the scan folder").input_files(&scan.input_files(), "a file the scan names");
    if let Some(path) = &args.config {
        check.input_file(path, "--config");
    }
    // held until the folder is in place: no other run writes it meanwhile
    let _outputs = lock_outputs(check.output_folder(output, "-o", FUSE_OUTPUTS))?;
    let job = fuse_with_progress(&scan, &config, args.quiet)?;
    // the folder is made only once there is something to put in it
    write_outputs(output, &job, None)?;
    let out = &job.fused;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&out.report)?);
    } else if !args.quiet {
        let r = &out.report;
        let count = |s: ViewStatus| r.views.iter().filter(|v| v.status == s).count();
        println!(
            "fused {} views ({} registered, {} rejected, {} skipped) into {} points in {:.2} s",
            r.views.len(),
            count(ViewStatus::Accepted) + count(ViewStatus::Anchor),
            count(ViewStatus::Excluded) + count(ViewStatus::SeedKept),
            count(ViewStatus::Skipped),
            r.model_points,
            r.seconds
        );
        for w in job.warnings() {
            println!("warning: {w}");
        }
        println!("wrote {}", output.join(MODEL_FILE).display());
    }
    Ok(())
}
