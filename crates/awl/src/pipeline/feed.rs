//! The views as the sequential registration takes them, held or streamed (`view_memory`):
//! - `hold`: every view prepared first, in parallel, and each merged view kept (its registration
//!   copy, and a recipe of its measured points) for the joint refinement; the merge reads the
//!   measured points again;
//! - `stream`: each view prepared when it is taken, the next one guessed and prepared while the
//!   current one registers, and once merged only its measured points kept, in the world frame: the
//!   memory is the model and a view or two in flight.

use std::collections::BTreeMap;
use std::time::Instant;

use nalgebra::Isometry3;
use rayon::prelude::*;

use super::config::ViewMemory;
use super::prepare::{Measured, PreparedView, Preparer, Tally, stage_reports};
use super::report::StageReport;
use crate::cloud::PointCloud;
use crate::error::Result;
use crate::filter::voxel::VoxelParams;
use crate::filter::voxel_merge::VoxelMerge;

/// A view through the per-view stages, or why it cannot be used.
pub(super) type Prepared = std::result::Result<PreparedView, String>;

/// The scan's views for the registration (see the module docs).
pub(super) struct Feed<'p, 'a> {
    preparer: &'p Preparer<'a>,
    /// Prepared views not taken yet: every view when holding, guessed next views when streaming.
    ready: BTreeMap<usize, Prepared>,
    /// Each view's points and times in the per-view stages.
    tallies: Vec<Tally>,
    /// The wall time of preparing every view first (`hold`).
    prepare_seconds: Option<f64>,
    /// The merged views (`hold`).
    held: BTreeMap<usize, PreparedView>,
    /// The merged views' measured points at their poses, world frame (`stream`).
    parts: Option<VoxelMerge>,
}

impl<'p, 'a> Feed<'p, 'a> {
    /// The views of `preparer`'s scan, held or streamed; `voxel` is the merge's.
    ///
    /// # Errors
    /// Voxel errors.
    pub(super) fn new(preparer: &'p Preparer<'a>, memory: ViewMemory, voxel: &VoxelParams) -> Result<Self> {
        let n = preparer.len();
        let mut feed = Self {
            preparer,
            ready: BTreeMap::new(),
            tallies: vec![Tally::default(); n],
            prepare_seconds: None,
            held: BTreeMap::new(),
            parts: None,
        };
        match memory {
            ViewMemory::Hold => {
                // each view through all the stages in one pass, so the raw views never pile up
                let start = Instant::now();
                let (views, tallies): (Vec<Prepared>, Vec<Tally>) =
                    (0..n).into_par_iter().map(|i| preparer.view(i)).unzip();
                feed.ready = views.into_iter().enumerate().collect();
                feed.tallies = tallies;
                feed.prepare_seconds = Some(start.elapsed().as_secs_f64());
            }
            ViewMemory::Stream => feed.parts = Some(VoxelMerge::new(voxel)?),
        }
        Ok(feed)
    }

    /// The number of views of the scan.
    pub(super) fn len(&self) -> usize {
        self.preparer.len()
    }

    /// View `i`'s recorded pose, `None` when it is not usable.
    pub(super) fn seed(&self, i: usize) -> Option<Isometry3<f64>> {
        self.preparer.seed(i)
    }

    /// View `i`, prepared now unless it is ready.
    pub(super) fn take(&mut self, i: usize) -> Prepared {
        self.ready.remove(&i).unwrap_or_else(|| {
            let (view, tally) = self.preparer.view(i);
            self.tallies[i] = tally;
            view
        })
    }

    /// Runs `register` while view `next` is prepared, when it is not ready yet (streaming).
    pub(super) fn while_preparing<R: Send>(&mut self, next: Option<usize>, register: impl FnOnce() -> R + Send) -> R {
        let next = next.filter(|g| !self.ready.contains_key(g));
        let preparer = self.preparer;
        let (prepared, registered) = rayon::join(|| next.map(|g| (g, preparer.view(g))), register);
        if let Some((g, (view, tally))) = prepared {
            self.tallies[g] = tally;
            self.ready.insert(g, view);
        }
        registered
    }

    /// View `i` merged at `pose` (world frame): held, or its measured points kept at `pose`.
    ///
    /// # Errors
    /// When its measured points cannot be read again (see [`Preparer::measured`]); voxel errors.
    pub(super) fn merge(&mut self, i: usize, view: PreparedView, pose: &Isometry3<f64>) -> Result<()> {
        match self.parts.as_mut() {
            Some(parts) => parts.add(i, self.preparer.measured(i, view.into_measured())?.into_transformed(pose)),
            None => {
                self.held.insert(i, view);
                Ok(())
            }
        }
    }

    /// The merged views held, in view order (none when streaming).
    pub(super) fn held(&self) -> impl Iterator<Item = (usize, &PreparedView)> {
        self.held.iter().map(|(&i, view)| (i, view))
    }

    /// The per-view stages' reports: each stage's points summed over the views and its time (when
    /// the views were prepared first, in parallel: that wall time times the stage's share).
    pub(super) fn stage_reports(&self) -> Vec<StageReport> {
        stage_reports(&self.tallies, self.prepare_seconds)
    }

    /// The merge's input: the merged views' measured points at their final `poses` (world frame).
    /// Held views free their registration copies first; measured points not held beside them are
    /// read again by their recipe, the views in parallel.
    ///
    /// # Errors
    /// As [`Feed::merge`].
    pub(super) fn into_parts(self, poses: &[Option<Isometry3<f64>>], voxel: &VoxelParams) -> Result<VoxelMerge> {
        if let Some(parts) = self.parts {
            return Ok(parts);
        }
        let preparer = self.preparer;
        let merged: Vec<(usize, Measured, Isometry3<f64>)> =
            (self.held.into_iter()).filter_map(|(i, view)| Some((i, view.into_measured(), poses[i]?))).collect();
        let empty = VoxelMerge::new(voxel)?;
        merged
            .into_par_iter()
            .map(|(i, measured, pose)| Ok((i, preparer.measured(i, measured)?.into_transformed(&pose))))
            .try_fold(
                || empty.clone(),
                |mut parts, view: Result<(usize, PointCloud)>| {
                    let (i, cloud) = view?;
                    parts.add(i, cloud)?;
                    Ok(parts)
                },
            )
            .try_reduce(
                || empty.clone(),
                |mut a, b| {
                    a.append(b);
                    Ok(a)
                },
            )
    }
}
