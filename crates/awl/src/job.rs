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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{SceneKind, SimParams, simulate};

    /// A simulated scan in memory: the job's workpiece places the tag where the truth has it (the
    /// model's frame is the world as the anchor's recorded pose places it, within a few centimetres);
    /// built without tag detection, the job refuses the scan, naming the feature.
    #[test]
    fn the_job_places_the_tag_or_names_the_missing_feature() {
        let sim = simulate(&SimParams { views: 6, seed: 2, ..SimParams::scan(SceneKind::Box) }).expect("simulate");
        let scan = sim.in_memory_scan();
        let job = fuse_job(&scan, &FuseConfig::default(), &WorkpieceParams::default(), "model.ply", &|_, _, _| {});
        if cfg!(feature = "apriltag") {
            let job = job.expect("job");
            let workpiece = job.workpiece.as_ref().expect("the scan declares a tag");
            let world_from_tag = workpiece.world_from_tag.expect("the tag seen");
            let truth = sim.truth.world_from_tag.expect("true tag");
            let apart_mm = (world_from_tag.translation.vector - truth.translation.vector).norm() * 1e3;
            assert!(apart_mm < 30.0, "tag {apart_mm:.1} mm from the truth; warnings {:?}", job.warnings());
            assert_eq!(workpiece.model, "model.ply");
        } else {
            let e = job.expect_err("no tag detection").to_string();
            assert!(e.contains("`apriltag` feature"), "{e}");
        }
    }
}
