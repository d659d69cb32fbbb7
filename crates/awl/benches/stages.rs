//! One benchmark per pipeline stage, on the peers' inputs and with the peers' parameters
//! (`../shared/bench/peers/bench_stages.py`), each with 1 and 2 rayon threads.
//!
//! ```sh
//! nice -n 19 cargo bench -p awl --bench stages                 # everything
//! nice -n 19 cargo bench -p awl --bench stages -- sim300k      # one input (divan filter)
//! DIVAN_SAMPLE_COUNT=3 nice -n 19 cargo bench -p awl --bench stages
//! ```
//!
//! Groups: `sim300k` and `table_mug` (inputs: see `common`) run voxel (5 mm), SOR (20, 2.0), normals
//! (20 nearest, no radius; k-d tree build included), ICP (point-to-plane, 2 cm gate, exactly 30
//! iterations, on random halves voxelised at 5 mm (`icp_vox`) or at full resolution (`icp_full`),
//! the source moved by 1 cm / 2 deg; target normals precomputed; target k-d tree included), DBSCAN
//! (eps 2 cm, 10 points, on the 5 mm voxelised input; k-d tree build included as in the pipeline) and
//! MLS (`MlsParams::default()`, 6 mm, quadratic, on the input voxelised at 2 mm like the merged
//! model; k-d tree build included). Group `scan` runs the per-view stages of `awl fuse`: PNG decode +
//! back-projection of one 640x480 view (`load_view`: depth and color), back-projection alone,
//! ICP of view 1 against view 0 with the pipeline's default registration parameters, and the joint
//! refinement of all views (`joint`: the fuse's joint levels, from the true poses each moved by
//! 2 mm / 0.2 deg, view 0 fixed).
//!
//! The ICP and DBSCAN benches print their accuracy / cluster count once to stderr (`check:` lines),
//! so speed can be compared at equal result.

mod common;

use awl::PointCloud;
use awl::camera::depth_to_cloud;
use awl::cluster::{DbscanParams, dbscan};
use awl::filter::outlier::{SorParams, statistical};
use awl::filter::voxel::{VoxelParams, downsample};
use awl::io::image::read_depth_png;
use awl::io::scan::load_view;
use awl::io::truth::read_truth;
use awl::normals::{NormalParams, with_normals};
use awl::pipeline::FuseConfig;
use awl::registration::{IcpLevel, IcpParams, refine_jointly, register};
use awl::scan::ViewData;
use awl::smooth::{MlsParams, mls};
use common::{THREADS, input, pool, scan};
use divan::Bencher;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand::seq::SliceRandom;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn main() {
    divan::main();
}

/// The peers' parameters (`bench_stages.py`).
const LEAF_M: f64 = 0.005;
const SOR: SorParams = SorParams { neighbors: 20, std_ratio: 2.0 };
const NORMALS_K: usize = 20;
const ICP_GATE_M: f64 = 0.02;
const ICP_ITERATIONS: usize = 30;
const ICP_ERROR: (f64, f64) = (0.01, 2.0);
const DBSCAN: DbscanParams = DbscanParams { eps_m: 0.02, min_points: 10 };
/// The merged model's voxel in `awl fuse` (`FuseConfig::merge_voxel`): the MLS input.
const MODEL_VOXEL_M: f64 = 0.002;

/// One untimed warm-up run (the peers' protocol in `bench_stages.py`: the first run pays for the
/// thread pool, page faults and cold caches), then the timed samples. The ICP and DBSCAN benches
/// warm up through their accuracy check run.
fn warmed<O>(b: Bencher, run: impl Fn() -> O + Sync) {
    std::hint::black_box(run());
    b.bench(run);
}

fn voxelised(cloud: &PointCloud, voxel_m: f64) -> PointCloud {
    downsample(cloud, &VoxelParams { voxel_size_m: voxel_m }).expect("voxel")
}

fn voxel(b: Bencher, name: &str, threads: usize) {
    let cloud = input(name);
    let params = VoxelParams { voxel_size_m: LEAF_M };
    warmed(b, || pool(threads).install(|| downsample(cloud, &params).expect("voxel")));
}

fn sor(b: Bencher, name: &str, threads: usize) {
    let cloud = input(name);
    warmed(b, || pool(threads).install(|| cloud.select(&statistical(cloud, &SOR).expect("sor"))));
}

fn normals(b: Bencher, name: &str, threads: usize) {
    let cloud = input(name);
    let params = NormalParams { neighbors: NORMALS_K, radius_m: None };
    warmed(b, || pool(threads).install(|| with_normals(cloud, &params, None).expect("normals")));
}

/// The peers' ICP pair: random halves (optionally voxelised), target normals, the source moved by
/// a known error about its centroid. Returns target, moved source and `T_target_source` (truth).
fn icp_pair(cloud: &PointCloud, voxel_m: Option<f64>) -> (PointCloud, PointCloud, Isometry3<f64>) {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut order: Vec<usize> = (0..cloud.len()).collect();
    order.shuffle(&mut rng);
    let (a, b) = order.split_at(cloud.len() / 2);
    let (mut target, mut source) = (cloud.select(a), cloud.select(b));
    if let Some(v) = voxel_m {
        (target, source) = (voxelised(&target, v), voxelised(&source, v));
    }
    let target = with_normals(&target, &NormalParams { neighbors: NORMALS_K, radius_m: None }, None).expect("normals");
    let mut unit = || {
        let v = Vector3::new(rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5);
        v.normalize()
    };
    let (axis, shift) = (unit(), unit());
    let rotation = UnitQuaternion::from_scaled_axis(axis * ICP_ERROR.1.to_radians());
    let centre = source.points.iter().fold(Vector3::zeros(), |s, p| s + p.coords.cast::<f64>()) / source.len() as f64;
    let error = Isometry3::from_parts(Translation3::from(centre - rotation * centre + shift * ICP_ERROR.0), rotation);
    (target, source.transformed(&error), error.inverse())
}

fn icp_params() -> IcpParams {
    IcpParams {
        levels: vec![IcpLevel { voxel_m: 0.0, max_correspondence_m: ICP_GATE_M, max_iterations: ICP_ITERATIONS }],
        convergence_translation_m: 0.0,
        convergence_rotation_rad: 0.0,
        max_source_points: 0,
        ..IcpParams::default()
    }
}

fn pose_error(estimate: &Isometry3<f64>, truth: &Isometry3<f64>) -> (f64, f64) {
    let d = truth.inverse() * estimate;
    (d.translation.vector.norm() * 1e3, d.rotation.angle().to_degrees())
}

fn icp(b: Bencher, name: &str, stage: &str, voxel_m: Option<f64>, threads: usize) {
    let (target, source, truth) = icp_pair(input(name), voxel_m);
    let params = icp_params();
    let run = || register(&source, &target, &Isometry3::identity(), &params).expect("icp");
    let r = pool(threads).install(run);
    let (mm, deg) = pose_error(&r.target_from_source, &truth);
    eprintln!(
        "check: {name} {stage} threads={threads} src={} tgt={} err_mm={mm:.3} err_deg={deg:.4} iterations={}",
        source.len(),
        target.len(),
        r.iterations
    );
    b.bench(|| pool(threads).install(run));
}

fn cluster(b: Bencher, name: &str, threads: usize) {
    let cloud = voxelised(input(name), LEAF_M);
    let run = || dbscan(&cloud.points, &DBSCAN).expect("dbscan");
    let c = pool(threads).install(run);
    eprintln!("check: {name} dbscan threads={threads} n_in={} clusters={}", cloud.len(), c.cluster_count());
    b.bench(|| pool(threads).install(run));
}

fn smooth(b: Bencher, name: &str, threads: usize) {
    let cloud = voxelised(input(name), MODEL_VOXEL_M);
    let params = MlsParams::default();
    warmed(b, || pool(threads).install(|| mls(&cloud, &params).expect("mls")));
}

macro_rules! input_group {
    ($group:ident) => {
        #[divan::bench_group(sample_count = 10)]
        mod $group {
            use super::*;
            const NAME: &str = stringify!($group);

            #[divan::bench(args = THREADS)]
            fn voxel(b: Bencher, threads: usize) {
                super::voxel(b, NAME, threads);
            }

            #[divan::bench(args = THREADS)]
            fn sor(b: Bencher, threads: usize) {
                super::sor(b, NAME, threads);
            }

            #[divan::bench(args = THREADS)]
            fn normals(b: Bencher, threads: usize) {
                super::normals(b, NAME, threads);
            }

            #[divan::bench(args = THREADS, sample_count = 5)]
            fn icp_vox(b: Bencher, threads: usize) {
                super::icp(b, NAME, "icp_vox", Some(LEAF_M), threads);
            }

            #[divan::bench(args = THREADS, sample_count = 3)]
            fn icp_full(b: Bencher, threads: usize) {
                super::icp(b, NAME, "icp_full", None, threads);
            }

            #[divan::bench(args = THREADS, sample_count = 5)]
            fn dbscan(b: Bencher, threads: usize) {
                super::cluster(b, NAME, threads);
            }

            #[divan::bench(args = THREADS, sample_count = 5)]
            fn mls(b: Bencher, threads: usize) {
                super::smooth(b, NAME, threads);
            }
        }
    };
}

input_group!(sim300k);
input_group!(table_mug);

/// View `i` of the bench scan prepared as the fuse prepares views given as clouds (2 mm voxel,
/// SOR, normals toward the camera from a k-d tree; camera frame; not the depth views' pixel-grid
/// cleaning and smoothed copies), and its recorded pose.
fn prepared_view(scan: &awl::scan::Scan, i: usize, config: &FuseConfig) -> (Isometry3<f64>, PointCloud) {
    let rays = scan.camera.map(|c| c.intrinsics.ray_table());
    let v = load_view(scan, i, rays.as_deref()).expect("load");
    let cloud = downsample(&v.cloud_camera, &config.view_voxel).expect("voxel");
    let cloud = cloud.select(&statistical(&cloud, &config.outliers).expect("sor"));
    (v.world_from_camera, with_normals(&cloud, &config.normals, Some(Point3::origin())).expect("normals"))
}

/// The per-view stages of `awl fuse` on the bench scan (views 0 and 1), and the joint refinement.
#[divan::bench_group(sample_count = 10)]
mod scan {
    use super::*;

    /// PNG decode (16-bit depth + RGB color) and back-projection of view 0, as `awl fuse` loads it.
    #[divan::bench(args = THREADS, sample_count = 20)]
    fn load_view(b: Bencher, threads: usize) {
        let scan = scan();
        let rays = scan.camera.map(|c| c.intrinsics.ray_table());
        warmed(b, || pool(threads).install(|| super::load_view(scan, 0, rays.as_deref()).expect("load")));
    }

    /// Back-projection of view 0 alone (depth already decoded, no color).
    #[divan::bench(args = THREADS, sample_count = 20)]
    fn back_project(b: Bencher, threads: usize) {
        let scan = scan();
        let camera = scan.camera.expect("camera");
        let rays = camera.intrinsics.ray_table();
        let ViewData::Depth { depth, .. } = &scan.views[0].data else { panic!("view 0 has no depth image") };
        let image = read_depth_png(&scan.dir.join(depth)).expect("depth png");
        warmed(b, || pool(threads).install(|| depth_to_cloud(&image, None, &camera, &rays)));
    }

    /// View 1 registered against view 0 (world frame) from its recorded pose, with the pipeline's
    /// default per-view preparation (2 mm voxel, SOR, normals toward the camera) and registration
    /// parameters (three levels, 15 mm to 3 mm).
    #[divan::bench(args = THREADS, sample_count = 5)]
    fn icp_views(b: Bencher, threads: usize) {
        let config = FuseConfig::default();
        let scan = scan();
        let (seed0, view0) = prepared_view(scan, 0, &config);
        let (seed1, view1) = prepared_view(scan, 1, &config);
        let model = downsample(&view0.transformed(&seed0), &config.merge_voxel).expect("voxel");
        let params = &config.registration.icp;
        let run = || register(&view1, &model, &seed1, params).expect("icp");
        let r = pool(threads).install(run);
        eprintln!(
            "check: scan icp_views threads={threads} src={} tgt={} iterations={} fitness={:.3} rmse_mm={:.3} converged={}",
            view1.len(),
            model.len(),
            r.iterations,
            r.fitness,
            r.inlier_rmse_m * 1e3,
            r.converged
        );
        b.bench(|| pool(threads).install(run));
    }

    /// Joint refinement of all views with the fuse's joint parameters (4 mm / 12 mm, then 2 mm /
    /// 5 mm; 2500 source points a view), the views prepared as in `icp_views`, from their true
    /// poses each moved by 2 mm and turned by 0.2 deg about seeded random axes (view 0 fixed). The
    /// check line gives the camera centres' error against the truth before and after; with the
    /// simulator's depth-scale error and depth noise the truth is not the refinement's optimum.
    #[divan::bench(args = THREADS, sample_count = 3)]
    fn joint(b: Bencher, threads: usize) {
        let config = FuseConfig::default();
        let scan = scan();
        let truth = read_truth(&scan.dir).expect("the bench scan's truth.json");
        let views: Vec<PointCloud> = (0..scan.views.len()).map(|i| prepared_view(scan, i, &config).1).collect();
        let clouds: Vec<&PointCloud> = views.iter().collect();
        let true_poses: Vec<Isometry3<f64>> = truth.views.iter().map(|v| v.world_from_camera).collect();
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let mut axis = || {
            let v = Vector3::new(rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5);
            v.normalize()
        };
        let start: Vec<Isometry3<f64>> = true_poses
            .iter()
            .enumerate()
            .map(|(i, pose)| {
                if i == 0 {
                    return *pose;
                }
                let turn = UnitQuaternion::from_scaled_axis(axis() * 0.2f64.to_radians());
                Isometry3::from_parts(Translation3::from(axis() * 0.002), turn) * pose
            })
            .collect();
        let params = config.registration.joint_params();
        let run = || {
            let mut poses = start.clone();
            let stats = refine_jointly(&clouds, &mut poses, 0, &[], &params).expect("joint");
            (poses, stats)
        };
        let (poses, stats) = pool(threads).install(run);
        let centre_error_mm = |poses: &[Isometry3<f64>]| {
            let e: Vec<f64> = poses
                .iter()
                .zip(&true_poses)
                .map(|(p, t)| (p.translation.vector - t.translation.vector).norm() * 1e3)
                .collect();
            (e.iter().sum::<f64>() / e.len() as f64, e.iter().fold(0.0f64, |a, &b| a.max(b)))
        };
        let (before, after) = (centre_error_mm(&start), centre_error_mm(&poses));
        eprintln!(
            "check: scan joint threads={threads} views={} iterations={:?} camera error mean/max mm {:.3}/{:.3} -> {:.3}/{:.3}",
            clouds.len(),
            stats.iter().map(|s| s.iterations).collect::<Vec<_>>(),
            before.0,
            before.1,
            after.0,
            after.1
        );
        b.bench(|| pool(threads).install(run));
    }
}
