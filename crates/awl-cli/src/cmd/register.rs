//! `awl register SOURCE TARGET -o T.json`: pairwise registration alone.

use std::path::{Path, PathBuf};

use anyhow::Context;
use awl::PointCloud;
use awl::io::outputs::OutputCheck;
use awl::normals::{NormalParams, with_normals};
use awl::registration::{IcpParams, register};
use awl::transform::{Rows, isometry_from_rows, rows_from_isometry};
use nalgebra::Isometry3;
use serde_json::json;

use super::common::{lock_outputs, set_threads, write_json};

/// Arguments of `awl register`.
#[derive(clap::Args)]
pub struct RegisterArgs {
    /// The cloud to move (.ply or .pcd).
    pub source: PathBuf,
    /// The cloud it is aligned to (.ply or .pcd); normals are estimated when it has none.
    pub target: PathBuf,
    /// Initial `T_target_source`: a JSON file with a 4x4 row-major matrix, bare or under "T_target_source".
    #[arg(long)]
    pub init: Option<PathBuf>,
    /// Output JSON: `T_target_source` and the registration's statistics.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Replace an earlier output file (the same flag in every command).
    #[arg(long)]
    pub force: bool,
}

fn read_init(path: &Path) -> anyhow::Result<Isometry3<f64>> {
    let text = awl::io::read_text_at_most(path, awl::io::MAX_JSON_BYTES)?;
    let value: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{}: invalid JSON", path.display()))?;
    let field = if value.get("T_target_source").is_some() { "T_target_source" } else { "(top level)" };
    let matrix = value.get("T_target_source").unwrap_or(&value);
    let rows: Rows = serde_json::from_value(matrix.clone())
        .with_context(|| format!("{}: field `{field}`: expected a 4x4 array of numbers", path.display()))?;
    isometry_from_rows(&rows).map_err(|m| anyhow::anyhow!("{}: field `{field}`: {m}", path.display()))
}

fn prepared(path: &Path) -> anyhow::Result<PointCloud> {
    let cloud = super::common::read_cloud_warned(path)?;
    anyhow::ensure!(!cloud.is_empty(), "{}: the cloud is empty", path.display());
    // a NaN or infinite point is named here, with the file, not deep in the k-d tree
    cloud.validate(&path.display().to_string()).context("remove or fix the non-finite points")?;
    Ok(with_normals(&cloud, &NormalParams::default(), None)?)
}

/// Runs `awl register`.
pub fn run(args: &RegisterArgs) -> anyhow::Result<()> {
    set_threads(args.threads)?;
    let mut check = OutputCheck::new(args.force);
    check.input_file(&args.source, "SOURCE").input_file(&args.target, "TARGET");
    if let Some(init) = &args.init {
        check.input_file(init, "--init");
    }
    let _outputs = lock_outputs(check.output_file(&args.output, "-o"))?;
    let init = args.init.as_deref().map(read_init).transpose()?.unwrap_or_else(Isometry3::identity);
    let (source, target) = (prepared(&args.source)?, prepared(&args.target)?);
    let result = register(&source, &target, &init, &IcpParams::default())?;
    let out = json!({
        "T_target_source": rows_from_isometry(&result.target_from_source),
        "converged": result.converged,
        "fitness": result.fitness,
        "inlier_rmse_m": result.inlier_rmse_m,
        "conditioning": result.conditioning,
        "iterations": result.iterations,
        "levels": result.levels,
    });
    write_json(&args.output, &out)?;
    println!(
        "registered {} -> {}: fitness {:.3}, inlier RMSE {:.3} mm, {} iterations{}; wrote {}",
        args.source.display(),
        args.target.display(),
        result.fitness,
        result.inlier_rmse_m * 1e3,
        result.iterations,
        if result.converged { "" } else { " (NOT converged)" },
        args.output.display()
    );
    Ok(())
}
