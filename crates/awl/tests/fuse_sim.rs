//! Issue 3's acceptance tests on awl's own simulator.
//!
//! `fuse` on simulated scans, judged against the simulator's ground truth: model RMSE against the
//! CAD, completeness, floor and clutter left, and registered poses against the seeds.

mod common;

use awl::io::scan::read_scan;
use awl::pipeline::{FuseConfig, ViewStatus, fuse};
use awl::sim::{NoiseLevel, SceneKind, SimParams, simulate, write_simulation};
use common::{Outcome, TruthScene, assert_acceptance, evaluate};
use nalgebra::Isometry3;

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
    let truth = TruthScene {
        cad: &sim.cad,
        world_from_object: sim.truth.world_from_object,
        camera: scan.camera.expect("camera"),
        views: sim.truth.views.iter().zip(&sim.views).map(|(t, v)| (t.world_from_camera, &v.depth)).collect(),
        seeds: (0..scan.views.len()).map(|i| scan.world_from_camera(i).expect("seed")).collect(),
    };
    (evaluate(&truth, &out), out.report)
}

fn check(scene: SceneKind) {
    for seed in 1..=3 {
        let (o, report) = run(scene, seed, None);
        assert_acceptance(&format!("{scene:?} seed {seed}"), &o, &report);
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
