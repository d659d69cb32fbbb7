//! Seeded inputs shared by the benches; they mirror the peers' inputs (`../shared/bench/peers`).
//!
//! - The scan: `awl simulate` with its defaults (box, 12 views, seed 1, realistic noise), written once
//!   to `$CARGO_TARGET_TMPDIR/awl-bench/box-12-seed1` (or `$AWL_BENCH_SCAN`, e.g. the scan
//!   `bench/compare` simulated, which is the peers' `PEERS_SCAN`).
//! - `sim300k`: views 0 and 1 of that scan, depth -> camera frame -> world frame at the recorded poses,
//!   300 000 points drawn without replacement (ChaCha8, seed 0). The peers draw their subset with
//!   numpy, so the points differ; `$AWL_BENCH_SIM300K` (a `.ply`/`.pcd`) makes the benches use the
//!   peers' exact subset (`bench/compare` writes it).
//! - `table_mug`: `table_scene_mug_stereo_textured.pcd` from the shared data (`$AWL_SHARED_DATA` or
//!   `../shared/data`), NaNs dropped as the peers do.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use awl::PointCloud;
use awl::io::mesh::read_cloud;
use awl::io::pcd::read_pcd;
use awl::io::scan::{load_view, read_scan};
use awl::scan::Scan;
use awl::sim::{SceneKind, SimParams, simulate, write_simulation};
use rand::SeedableRng;
use rand::seq::index::sample;
use rand_chacha::ChaCha8Rng;
use rayon::ThreadPool;

/// Thread counts every stage bench runs with.
pub const THREADS: [usize; 2] = [1, 2];

/// Points of the `sim300k` input.
pub const SIM_POINTS: usize = 300_000;

/// A rayon pool with `threads` workers (built once per count); stages run inside `install`.
pub fn pool(threads: usize) -> &'static ThreadPool {
    static POOLS: [OnceLock<ThreadPool>; 2] = [OnceLock::new(), OnceLock::new()];
    let slot = &POOLS[threads.clamp(1, 2) - 1];
    slot.get_or_init(|| rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("rayon pool"))
}

fn env_path(name: &str) -> Option<PathBuf> {
    std::env::var_os(name).filter(|v| !v.is_empty()).map(PathBuf::from)
}

/// The shared data folder: `$AWL_SHARED_DATA`, else `<workspace>/../shared/data`.
pub fn shared_data() -> PathBuf {
    env_path("AWL_SHARED_DATA")
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"))
}

/// The 12-view box scan of seed 1 on disk (simulated on first use), read back as `awl fuse` reads it.
pub fn scan() -> &'static Scan {
    static SCAN: OnceLock<Scan> = OnceLock::new();
    SCAN.get_or_init(|| {
        let dir = env_path("AWL_BENCH_SCAN").unwrap_or_else(|| {
            let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("awl-bench/box-12-seed1");
            if !dir.join("scan.json").is_file() {
                let sim = simulate(&SimParams::scan(SceneKind::Box)).expect("simulate the bench scan");
                write_simulation(&dir, &sim, true).expect("write the bench scan");
            }
            dir
        });
        read_scan(&dir).unwrap_or_else(|e| panic!("bench scan {}: {e}", dir.display()))
    })
}

/// Views `views` of the scan in the world frame (recorded poses), concatenated, positions only.
pub fn world_points(views: &[usize]) -> PointCloud {
    let scan = scan();
    let rays = scan.camera.map(|c| c.intrinsics.ray_table());
    let mut all = Vec::new();
    for &i in views {
        let v = load_view(scan, i, rays.as_deref()).expect("load a bench view");
        all.extend(v.cloud_camera.transformed(&v.world_from_camera).points);
    }
    PointCloud::from_points(all)
}

/// The `sim300k` input (see the module docs).
pub fn sim300k() -> &'static PointCloud {
    static CLOUD: OnceLock<PointCloud> = OnceLock::new();
    CLOUD.get_or_init(|| {
        if let Some(path) = env_path("AWL_BENCH_SIM300K") {
            let c = read_cloud(&path).unwrap_or_else(|e| panic!("AWL_BENCH_SIM300K {}: {e}", path.display()));
            return PointCloud::from_points(c.points);
        }
        let all = world_points(&[0, 1]);
        let mut picks = sample(&mut ChaCha8Rng::seed_from_u64(0), all.len(), SIM_POINTS.min(all.len())).into_vec();
        picks.sort_unstable();
        PointCloud::from_points(picks.iter().map(|&i| all.points[i]).collect())
    })
}

/// The `table_mug` input (see the module docs).
pub fn table_mug() -> &'static PointCloud {
    static CLOUD: OnceLock<PointCloud> = OnceLock::new();
    CLOUD.get_or_init(|| {
        let path = shared_data().join("pcl/table_scene_mug_stereo_textured.pcd");
        let c = read_pcd(&path).unwrap_or_else(|e| panic!("table_mug input {}: {e}", path.display()));
        PointCloud::from_points(c.points)
    })
}

/// An input by name (`sim300k` or `table_mug`).
pub fn input(name: &str) -> &'static PointCloud {
    match name {
        "sim300k" => sim300k(),
        "table_mug" => table_mug(),
        other => panic!("unknown bench input {other}"),
    }
}
