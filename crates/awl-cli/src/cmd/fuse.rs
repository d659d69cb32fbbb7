//! `awl fuse SCAN_DIR -o OUT_DIR`: the modeling pipeline.

use std::path::{Path, PathBuf};

use anyhow::Context;
use awl::io::mesh::write_cloud;
use awl::io::outputs::{OutputCheck, StagedFolder};
use awl::io::scan::read_scan;
use awl::pipeline::{FuseConfig, FuseOutput, ViewStatus, fuse};
use awl::report_html::write::{REPORT_FILE, write_report};
use awl::report_html::{PageParams, fuse_page};
use awl::scan::Scan;
use awl::workpiece::json::write_workpiece;
use awl::workpiece::{TagSearch, WORKPIECE_FILE, Workpiece, WorkpieceParams, search_tags, workpiece_from_search};

use super::common::{set_threads, stage_bar, write_json};

/// Arguments of `awl fuse`.
#[derive(clap::Args)]
pub struct FuseArgs {
    /// The scan folder (awl-scan/1).
    pub scan: PathBuf,
    /// Output folder: model.ply, report.json, report.html and renders/*.png are written there.
    #[arg(short, long)]
    pub output: PathBuf,
    /// A TOML (or JSON, where `null` turns an optional stage off) file overriding parameters of
    /// the preset (see report.json's `config` for all keys).
    #[arg(long)]
    pub config: Option<PathBuf>,
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
pub const FUSE_OUTPUTS: &[&str] = &["model.ply", "report.json", REPORT_FILE, "renders", WORKPIECE_FILE];

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
    let text = std::fs::read_to_string(path).with_context(|| format!("{}: cannot read", path.display()))?;
    let invalid = || format!("{}: invalid fuse config", path.display());
    if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("json")) {
        // JSON has `null`, which TOML lacks: it turns an optional stage off
        let document: serde_json::Value = serde_json::from_str(&text).with_context(invalid)?;
        return FuseConfig::with_overrides_on(base, &document).with_context(invalid);
    }
    // parsed once as the config itself for messages with the line and key, then merged key by key
    // over the fuse's defaults (a partial table keeps the fuse's values, not its type's)
    let _: FuseConfig = toml::from_str(&text).with_context(invalid)?;
    let document: toml::Value = toml::from_str(&text).with_context(invalid)?;
    if let Some((key, v)) = non_finite(&document, "") {
        anyhow::bail!("{}: invalid fuse config: {key} = {v} is not a finite number", path.display());
    }
    let document = serde_json::to_value(document).with_context(invalid)?;
    FuseConfig::with_overrides_on(base, &document).with_context(invalid)
}

/// The first number of `value` that is NaN or infinite (JSON, which the merge goes through, has
/// neither), with its dotted key.
fn non_finite(value: &toml::Value, key: &str) -> Option<(String, f64)> {
    let child = |k: &str| if key.is_empty() { k.to_string() } else { format!("{key}.{k}") };
    match value {
        toml::Value::Float(v) if !v.is_finite() => Some((key.to_string(), *v)),
        toml::Value::Table(t) => t.iter().find_map(|(k, v)| non_finite(v, &child(k))),
        toml::Value::Array(a) => a.iter().enumerate().find_map(|(i, v)| non_finite(v, &format!("{key}[{i}]"))),
        _ => None,
    }
}

/// Writes `model.ply`, `report.json`, `report.html` (self-contained; its renders also as
/// `renders/*.png`) and, when the scan declares a tag, `workpiece.json` as the folder `out_dir`,
/// whole or not at all (a temporary sibling renamed into place, replacing an earlier one); `tags` is the scan's tag search ([`fuse_with_progress`]); `rmse_m` (an RMSE against ground
/// truth, when the caller has one) goes on the page. Returns the page's path and the workpiece
/// (see [`workpiece_warnings`]).
pub fn write_outputs(
    out_dir: &Path,
    tags: Option<&TagSearch>,
    out: &FuseOutput,
    rmse_m: Option<f64>,
) -> anyhow::Result<(PathBuf, Option<Workpiece>)> {
    // the tag on the model, for `awl pierce`, and the report page (side by side): both made before
    // anything is written
    let (workpiece, page) = rayon::join(
        || workpiece_from_search(tags, out, "model.ply", &WorkpieceParams::default()),
        || fuse_page(&out.report, &out.model, rmse_m, &PageParams::default()),
    );
    let (workpiece, page) = (workpiece?, page?);
    let staged = StagedFolder::begin(out_dir)?;
    let dir = staged.path();
    write_cloud(&dir.join("model.ply"), &out.model)?;
    write_json(&dir.join("report.json"), &out.report)?;
    if let Some(wp) = &workpiece {
        write_workpiece(&dir.join(WORKPIECE_FILE), wp)?;
    }
    write_report(dir, &page.page, &page.renders)?;
    staged.commit()?;
    Ok((out_dir.join(REPORT_FILE), workpiece))
}

/// The workpiece's warnings, each prefixed for the user.
pub fn workpiece_warnings(workpiece: Option<&Workpiece>) -> Vec<String> {
    workpiece.map_or_else(Vec::new, |wp| wp.warnings.iter().map(|w| format!("workpiece: {w}")).collect())
}

/// Runs the pipeline with a stage progress bar on stderr (hidden when `quiet`) and, beside it (it
/// needs no registered pose; the cores the fuse leaves idle do most of it), the search of the
/// scan's color views for its tag (`None` when the scan declares none).
pub fn fuse_with_progress(
    scan: &Scan,
    config: &FuseConfig,
    quiet: bool,
) -> anyhow::Result<(FuseOutput, Option<TagSearch>)> {
    if config.streams_views() {
        crate::malloc::map_view_sized_blocks();
    }
    let bar = stage_bar(quiet);
    let progress = |stage: &str, done: usize, total: usize| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
        bar.set_message(stage.to_string());
    };
    let (out, tags) =
        rayon::join(|| fuse(scan, config, &progress), || search_tags(scan, &WorkpieceParams::default().tag));
    bar.finish_and_clear();
    crate::malloc::release_free();
    Ok((out?, tags.context("searching the scan's color views for its tag")?))
}

/// Runs `awl fuse`.
pub fn run(args: &FuseArgs) -> anyhow::Result<()> {
    set_threads(args.threads)?;
    let base = match args.preset {
        Preset::Accurate => FuseConfig::default(),
        Preset::Fast => FuseConfig::fast(),
    };
    let config = load_config(args.config.as_ref(), base)?;
    let scan = read_scan(&args.scan)?;
    let mut check = OutputCheck::new(args.force);
    check.input_folder(&args.scan, "the scan folder").input_files(&scan.input_files(), "a file the scan names");
    if let Some(path) = &args.config {
        check.input_file(path, "--config");
    }
    check.output_folder(&args.output, "-o", FUSE_OUTPUTS).check()?;
    let (out, tags) = fuse_with_progress(&scan, &config, args.quiet)?;
    // the folder is made only once there is something to put in it
    let (_, workpiece) = write_outputs(&args.output, tags.as_ref(), &out, None)?;
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
        for w in r.warnings.iter().chain(&workpiece_warnings(workpiece.as_ref())) {
            println!("warning: {w}");
        }
        println!("wrote {}", args.output.join("model.ply").display());
    }
    Ok(())
}
