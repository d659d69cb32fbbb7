//! Issue 3's acceptance tests, IGNORED until the pipeline meets them (last run: box seed 1 RMSE 2.15 mm,
//! completeness 95.2 %, off-object 22.9 % (fails), trajectory 26.3 -> 3.56 mm). Run with `--ignored`.
//!
//! `fuse` on simulated scans, judged against the simulator's ground truth: model RMSE against the
//! CAD, completeness, floor and clutter left, and registered poses against the seeds.

use awl::PointCloud;
use awl::eval::{MeshDistance, align_positions, cad_metrics, visible_samples};
use awl::io::scan::read_scan;
use awl::normals::{NormalParams, with_normals};
use awl::pipeline::{FuseConfig, ViewStatus, fuse};
use awl::registration::{IcpLevel, IcpParams, register};
use awl::sim::{NoiseLevel, SceneKind, SimParams, Simulation, simulate, write_simulation};
use nalgebra::{Isometry3, Point3};

struct Outcome {
    rmse_mm: f64,
    completeness_5mm: f64,
    off_object: f64,
    seed_error_mm: f64,
    registered_error_mm: f64,
}

/// Mean camera-centre error after the best rigid alignment of the trajectory onto the truth.
fn trajectory_error(poses: &[Isometry3<f64>], truth: &[Isometry3<f64>]) -> f64 {
    let from: Vec<Point3<f64>> = poses.iter().map(|p| Point3::from(p.translation.vector)).collect();
    let to: Vec<Point3<f64>> = truth.iter().map(|p| Point3::from(p.translation.vector)).collect();
    let align = align_positions(&from, &to).expect("alignment");
    from.iter().zip(&to).map(|(f, t)| (align * f - t).norm()).sum::<f64>() / from.len() as f64 * 1e3
}

fn run(scene: SceneKind, seed: u64, perturb: Option<(usize, Isometry3<f64>)>) -> (Outcome, awl::pipeline::FuseReport) {
    let sim =
        simulate(&SimParams { scene, views: 12, seed, noise: NoiseLevel::Realistic, shot: None }).expect("simulate");
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("scan");
    write_simulation(&path, &sim, false).expect("write");
    let mut scan = read_scan(&path).expect("read");
    if let Some((view, delta)) = perturb {
        let seed_pose = scan.world_from_camera(view).expect("pose");
        scan.views[view].pose = awl::io::scan::ViewPose::Camera { world_from_camera: seed_pose * delta };
    }
    let out = fuse(&scan, &FuseConfig::default(), &|_, _, _| {}).expect("fuse");
    (evaluate(&sim, &scan, &out), out.report)
}

fn evaluate(sim: &Simulation, scan: &awl::io::scan::Scan, out: &awl::pipeline::FuseOutput) -> Outcome {
    let cad = MeshDistance::new(&sim.cad).expect("cad");
    let cad_cloud = with_normals(&sim.cad.sample_surface(200_000, 1).expect("sample"), &NormalParams::default(), None)
        .expect("cad normals");
    // model -> object frame: the true pose, then a fine alignment to the CAD (as the reference system did)
    let object_from_world = sim.truth.world_from_object.inverse();
    // the model lives in the scan's world frame, which inherits the anchor view's seed error (~1-2 cm,
    // ~1 deg): coarse-to-fine alignment from the true pose, then a fine level
    let mut fine = IcpParams::default();
    fine.levels.push(IcpLevel { voxel_m: 0.002, max_correspondence_m: 0.01, max_iterations: 50 });
    let aligned = register(&out.model, &cad_cloud, &object_from_world, &fine).expect("align");
    let model_object = out.model.transformed(&aligned.target_from_source);
    let samples = sim.cad.sample_surface(30_000, 2).expect("samples");
    let samples_world = samples.transformed(&sim.truth.world_from_object);
    let camera = scan.camera.expect("camera");
    let views: Vec<_> = sim.truth.views.iter().zip(&sim.views).map(|(t, v)| (t.world_from_camera, &v.depth)).collect();
    let visible = visible_samples(&samples_world, &camera.intrinsics, camera.depth_scale, &views, 0.01);
    let keep: Vec<usize> = (0..samples.len()).filter(|&i| visible[i]).collect();
    let visible_samples: PointCloud = samples.select(&keep);
    let m = cad_metrics(&model_object, &cad, &visible_samples.points, 0.01, &[0.005]).expect("metrics");
    let merged: Vec<usize> = (0..out.poses.len()).filter(|&i| out.poses[i].is_some()).collect();
    let truth: Vec<Isometry3<f64>> = merged.iter().map(|&i| sim.truth.views[i].world_from_camera).collect();
    let seeds: Vec<Isometry3<f64>> = merged.iter().map(|&i| scan.world_from_camera(i).expect("seed")).collect();
    let registered: Vec<Isometry3<f64>> = merged.iter().filter_map(|&i| out.poses[i]).collect();
    Outcome {
        rmse_mm: m.rmse_m * 1e3,
        completeness_5mm: m.completeness[0].1,
        off_object: m.off_object_fraction,
        seed_error_mm: trajectory_error(&seeds, &truth),
        registered_error_mm: trajectory_error(&registered, &truth),
    }
}

fn check(scene: SceneKind) {
    for seed in 1..=3 {
        let (o, report) = run(scene, seed, None);
        let summary = format!(
            "{scene:?} seed {seed}: RMSE {:.2} mm, completeness@5mm {:.1} %, off-object {:.2} %, trajectory error seeds {:.1} mm -> registered {:.2} mm; warnings {:?}",
            o.rmse_mm,
            o.completeness_5mm * 100.0,
            o.off_object * 100.0,
            o.seed_error_mm,
            o.registered_error_mm,
            report.warnings
        );
        println!("{summary}");
        assert!(o.rmse_mm <= 2.0, "{summary}");
        assert!(o.completeness_5mm >= 0.95, "{summary}");
        assert!(o.off_object < 0.005, "{summary}");
        assert!(o.registered_error_mm * 5.0 <= o.seed_error_mm, "{summary}");
    }
}

#[test]
fn box_realistic_three_seeds() {
    check(SceneKind::Box);
}

#[test]
fn shell_realistic_three_seeds() {
    check(SceneKind::Shell);
}

#[test]
fn a_seed_off_by_10cm_10deg_is_rejected() {
    let delta = Isometry3::new(
        nalgebra::Vector3::new(0.06, -0.06, 0.05),
        nalgebra::Vector3::new(0.1, 0.1, 0.1).normalize() * 10f64.to_radians(),
    );
    let (o, report) = run(SceneKind::Box, 4, Some((5, delta)));
    let view = &report.views[5];
    assert_eq!(view.status, ViewStatus::Excluded, "view 5: {view:?}");
    assert!(report.warnings.iter().any(|w| w.contains("view 5")), "{:?}", report.warnings);
    assert!(o.rmse_mm <= 2.0, "model still accurate: {:.2} mm", o.rmse_mm);
}

#[test]
fn one_and_two_threads_give_the_same_model_bit_for_bit() {
    let sim =
        simulate(&SimParams { scene: SceneKind::Box, views: 4, seed: 5, noise: NoiseLevel::Realistic, shot: None })
            .expect("simulate");
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("scan");
    write_simulation(&path, &sim, false).expect("write");
    let scan = read_scan(&path).expect("read");
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        pool.install(|| fuse(&scan, &FuseConfig::default(), &|_, _, _| {}).expect("fuse"))
    };
    let (one, two) = (run(1), run(2));
    assert!(one.model.len() > 10_000, "model has {} points", one.model.len());
    assert_eq!(one.model, two.model, "model differs between 1 and 2 threads");
    assert_eq!(one.poses, two.poses);
}
