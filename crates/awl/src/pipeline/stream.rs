//! Registration as the views are prepared, for a registration whose poses are final once each view
//! is judged (no refinement rounds, no joint refinement): each view is prepared while the one
//! before it registers, and once merged only its measured points are kept, in the world frame.
//! The views never pile up, so the memory is the model and the merged points, not every prepared
//! view. Same views in the same order as the sequential pass of `multiview` (the next view is
//! guessed as if the current one were merged; a wrong guess is kept for later), same poses.

use std::collections::BTreeMap;
use std::time::Instant;

use nalgebra::Isometry3;

use super::config::RegistrationConfig;
use super::multiview::{
    LevelModel, Registered, Symmetries, blank_report, make_anchor, next_view, no_usable_view, place, settle,
};
use super::prepare::{PreparedView, Preparer, Tally};
use super::report::ViewReport;
use crate::error::Result;
use crate::filter::voxel::VoxelParams;
use crate::filter::voxel_merge::VoxelMerge;
use crate::registration::register_levels_expecting;

/// What [`register_as_prepared`] gives.
pub(crate) struct Streamed {
    pub registered: Registered,
    /// The merged views' measured points at their poses (world frame), to be merged.
    pub parts: VoxelMerge,
    /// Each view's points and times in the per-view stages.
    pub tallies: Vec<Tally>,
    /// The time spent registering (the per-view stages excluded).
    pub register_seconds: f64,
}

/// The views as the registration takes them: each prepared once, from the stash of earlier
/// guesses or now, its report started when it is taken.
struct Feed<'p, 'a> {
    preparer: &'p Preparer<'a>,
    stash: BTreeMap<usize, std::result::Result<PreparedView, String>>,
    tallies: Vec<Tally>,
    reports: Vec<ViewReport>,
}

impl Feed<'_, '_> {
    fn take(&mut self, i: usize) -> std::result::Result<PreparedView, String> {
        let view = self.stash.remove(&i).unwrap_or_else(|| {
            let (view, tally) = self.preparer.view(i);
            self.tallies[i] = tally;
            view
        });
        self.reports[i] = blank_report(i, &view);
        view
    }
}

/// Prepares and registers every view of `preparer` (see the module docs): the registration of
/// `multiview::register_views` with `config`'s rounds and joint levels empty, the merge's input
/// kept instead of the views.
///
/// # Errors
/// [`crate::Error::Invalid`] when no view is usable (with each view's reason); errors of the ICP
/// and voxel stages.
pub(crate) fn register_as_prepared(
    preparer: &Preparer<'_>,
    config: &RegistrationConfig,
    voxel: &VoxelParams,
) -> Result<Streamed> {
    let n = preparer.len();
    // every view's report, filled in as it is prepared (each one is)
    let reports = (0..n).map(|i| blank_report(i, &Err(String::new()))).collect();
    let mut feed = Feed { preparer, stash: BTreeMap::new(), tallies: vec![Tally::default(); n], reports };
    let mut poses: Vec<Option<Isometry3<f64>>> = vec![None; n];
    let mut parts = VoxelMerge::new(voxel)?;
    let mut remaining: Vec<usize> = (0..n).collect();
    let mut register_seconds = 0.0;
    // the anchor: the first usable view
    let mut anchor = None;
    while anchor.is_none() && !remaining.is_empty() {
        let i = remaining.remove(0);
        anchor = feed.take(i).ok().map(|view| (i, view));
    }
    let Some((a, view)) = anchor else {
        return Err(no_usable_view(feed.reports.iter().map(|r| (r.index, r.reason.as_str()))));
    };
    let start = Instant::now();
    let mut model = LevelModel::new(&config.icp, voxel)?;
    let mut merge =
        |i: usize, view: PreparedView, pose: Isometry3<f64>, model: &mut LevelModel, report: &mut ViewReport| {
            model.add(&view.cloud.transformed(&pose))?;
            place(report, &view, &pose);
            parts.add(i, preparer.measured(i, view.into_measured())?.into_transformed(&pose))?;
            poses[i] = Some(pose);
            Ok::<_, crate::Error>(())
        };
    make_anchor(&mut feed.reports[a]);
    let seed = view.seed;
    merge(a, view, seed, &mut model, &mut feed.reports[a])?;
    let mut merged = vec![a];
    let mut symmetries = Symmetries::default();
    register_seconds += start.elapsed().as_secs_f64();
    let centre = |i: usize| preparer.seed(i).map(|s| s.translation.vector).unwrap_or_default();
    while !remaining.is_empty() {
        let i = remaining.remove(next_view(centre, &remaining, &merged));
        let Ok(view) = feed.take(i) else { continue };
        // the next view, guessed as if this one joins the model, prepared while this one registers
        merged.push(i);
        let guess = (!remaining.is_empty()).then(|| remaining[next_view(centre, &remaining, &merged)]);
        merged.pop();
        let guess = guess.filter(|g| !feed.stash.contains_key(g));
        let levels = model.levels();
        let expected = symmetries.confirmed();
        let (prepared, registered) = rayon::join(
            || guess.map(|g| (g, preparer.view(g))),
            || {
                let start = Instant::now();
                let r = register_levels_expecting(&view.cloud, &levels, &view.seed, &config.icp, &expected);
                (r, start.elapsed().as_secs_f64())
            },
        );
        drop(levels);
        if let Some((g, (view, tally))) = prepared {
            feed.tallies[g] = tally;
            feed.stash.insert(g, view);
        }
        let start = Instant::now();
        let (result, seconds) = registered;
        let result = result?;
        symmetries.note(&result);
        if let Some(pose) = settle(config, &view, &result, &symmetries, &mut feed.reports[i]) {
            merge(i, view, pose, &mut model, &mut feed.reports[i])?;
            merged.push(i);
        }
        register_seconds += seconds + start.elapsed().as_secs_f64();
    }
    Ok(Streamed {
        registered: Registered { poses, reports: feed.reports, joint: Vec::new(), warnings: Vec::new() },
        parts,
        tallies: feed.tallies,
        register_seconds,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::scan::read_scan;
    use crate::pipeline::config::FuseConfig;
    use crate::pipeline::fuse::world_parts;
    use crate::pipeline::multiview::register_views;
    use crate::pipeline::prepare::prepare;
    use crate::pipeline::report::ViewStatus;
    use crate::scan::ViewData;
    use crate::sim::{SceneKind, SimParams, simulate, write_simulation};

    /// The same views, order, poses and reports as registering all the prepared views, with a view
    /// that cannot be read and with views rejected (the guessed next view is then wrong).
    #[test]
    fn same_registration_as_all_views_first() {
        let sim = simulate(&SimParams { views: 6, seed: 3, ..SimParams::scan(SceneKind::Box) }).expect("simulate");
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("scan");
        write_simulation(&path, &sim, false).expect("write");
        let scan = read_scan(&path).expect("read");
        let ViewData::Depth { depth, .. } = &scan.views[1].data else { panic!("a depth view") };
        std::fs::write(scan.dir.join(depth), b"not a png").expect("corrupt view 1");
        let fast = FuseConfig::fast();
        let mut strict = FuseConfig::fast();
        strict.registration.accept.max_correction_m = 0.012;
        for config in [fast, strict] {
            let preparer = Preparer::new(&scan, &config);
            let all = prepare(&preparer, &mut Vec::new());
            let want = register_views(&all, &config.registration, &config.merge_voxel).expect("all first");
            let got = register_as_prepared(&preparer, &config.registration, &config.merge_voxel).expect("streamed");
            assert_eq!(got.registered.poses, want.poses);
            assert_eq!(got.registered.reports, want.reports);
            let count = |s: ViewStatus| want.reports.iter().filter(|r| r.status == s).count();
            assert_eq!(count(ViewStatus::Skipped), 1);
            // the same model: the merge of the same views' measured points at the same poses
            let want_model = world_parts(&preparer, all, &want.poses, &config.merge_voxel).expect("parts").downsample();
            let got_model = got.parts.downsample().expect("merged");
            assert!(got_model.len() > 20_000, "{} points", got_model.len());
            assert_eq!(got_model, want_model.expect("merged"));
            // rejected views (the guess of the next view was wrong, and kept for later), and with the
            // fast config's rule registered ones too
            let strict = config.registration.accept.max_correction_m < 0.05;
            assert_eq!(count(ViewStatus::Accepted) + count(ViewStatus::Excluded), 4);
            assert!(count(ViewStatus::Excluded) >= 1 && (strict || count(ViewStatus::Accepted) >= 2));
        }
    }
}
