//! The fuse job (`awl fuse`, `awl demo`, `awl trial`, any front end): the pipeline, the search of
//! the scan's color views for its tag beside it, and the workpiece (the tag and the floor on the
//! model) from the two.

use crate::Result;
use crate::pipeline::{FuseConfig, FuseOutput, Progress, fuse};
use crate::scan::Scan;
use crate::workpiece::{Workpiece, WorkpieceParams, search_tags, workpiece_from_search};

/// What [`fuse_job`] returns.
#[derive(Debug, Clone)]
pub struct FuseJob {
    /// The pipeline's model, poses and report.
    pub fused: FuseOutput,
    /// The tag and the floor on the model, for `awl pierce`; `None` when the scan declares no tag.
    pub workpiece: Option<Workpiece>,
}

impl FuseJob {
    /// The report's warnings, then the workpiece's, each prefixed `workpiece: `.
    #[must_use]
    pub fn warnings(&self) -> Vec<String> {
        let workpiece = self.workpiece.iter().flat_map(|wp| wp.warnings.iter().map(|w| format!("workpiece: {w}")));
        self.fused.report.warnings.iter().cloned().chain(workpiece).collect()
    }
}

/// Fuses `scan` and, beside it (it needs no registered pose; the cores the fuse leaves idle do most
/// of it), searches its color views for its tag, then places the tag and the floor on the model.
/// `model_file` is the name the workpiece gives its model (e.g. `model.ply`).
///
/// # Errors
/// Any error of [`fuse`], of the tag search (an unsupported tag, a view that does not load) or of
/// placing the tag.
pub fn fuse_job(
    scan: &Scan,
    config: &FuseConfig,
    params: &WorkpieceParams,
    model_file: &str,
    progress: Progress<'_>,
) -> Result<FuseJob> {
    let (fused, tags) = rayon::join(|| fuse(scan, config, progress), || search_tags(scan, &params.tag));
    let (fused, tags) = (fused?, tags?);
    let workpiece = workpiece_from_search(tags.as_ref(), &fused, model_file, params)?;
    Ok(FuseJob { fused, workpiece })
}
