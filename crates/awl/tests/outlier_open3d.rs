//! Parity of `filter::outlier::statistical` with Open3D 0.20's `remove_statistical_outlier` on a
//! real stereo cloud (PCL's table_scene_mug_stereo_textured.pcd, 209,280 finite points).
//!
//! The fixture `tests/data/sor_table_mug_open3d.json` was written by `tests/py/gen_sor_golden.py`
//! (open3d-cpu 0.20.0). The shared data folder is `$AWL_SHARED_DATA` when set, else
//! `<workspace>/../shared/data`; this test fails, not skips, when it is missing.

mod common;
use common::shared_data as data_dir;

use std::collections::BTreeSet;
use std::path::Path;

use awl::filter::outlier::{SorParams, statistical};
use awl::io::mesh::read_cloud;

const PCD: &str = "pcl/table_scene_mug_stereo_textured.pcd";

#[test]
fn statistical_matches_open3d_on_table_mug() {
    let fixture_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/sor_table_mug_open3d.json");
    let text = std::fs::read_to_string(&fixture_path).unwrap_or_else(|e| panic!("{}: {e}", fixture_path.display()));
    let fixture: serde_json::Value = serde_json::from_str(&text).expect("fixture JSON");
    let points = fixture["points"].as_u64().expect("points") as usize;
    let open3d_kept = fixture["kept"].as_u64().expect("kept") as usize;
    let removed: BTreeSet<usize> = fixture["removed_indices"]
        .as_array()
        .expect("removed_indices")
        .iter()
        .map(|v| v.as_u64().expect("index") as usize)
        .collect();
    assert_eq!(removed.len() + open3d_kept, points, "fixture is inconsistent");
    let params = SorParams {
        neighbors: fixture["nb_neighbors"].as_u64().expect("nb_neighbors") as usize,
        std_ratio: fixture["std_ratio"].as_f64().expect("std_ratio"),
    };
    assert_eq!(params, SorParams { neighbors: 20, std_ratio: 2.0 });

    let path = data_dir().join(PCD);
    let cloud = read_cloud(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(cloud.len(), points, "{}: finite point count", path.display());

    let kept = statistical(&cloud, &params).expect("statistical");
    assert!(kept.windows(2).all(|w| w[0] < w[1]), "kept indices are not ascending");
    // Symmetric difference of the removed sets = symmetric difference of the kept sets.
    let kept_set: BTreeSet<usize> = kept.iter().copied().collect();
    let removed_only_by_awl = (0..points).filter(|i| !kept_set.contains(i) && !removed.contains(i)).count();
    let removed_only_by_open3d = removed.iter().filter(|i| kept_set.contains(i)).count();
    let diff = removed_only_by_awl + removed_only_by_open3d;
    assert!(
        diff as f64 <= 0.001 * points as f64,
        "awl kept {} of {points}, Open3D {open3d_kept}: {diff} points differ ({removed_only_by_awl} removed only by \
         awl, {removed_only_by_open3d} only by Open3D), more than 0.1 %",
        kept.len()
    );
    // Also report the measured agreement when the test passes (visible with --nocapture).
    println!(
        "SOR parity: awl kept {}, Open3D kept {open3d_kept} of {points}; {diff} differ \
         ({removed_only_by_awl} awl-only removals, {removed_only_by_open3d} Open3D-only)",
        kept.len()
    );
}
