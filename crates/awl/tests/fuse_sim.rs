//! Acceptance tests on awl's own simulator: issue 3's (`fuse` judged against the simulator's ground
//! truth: model RMSE against the CAD, completeness, floor and clutter left, registered poses against
//! the seeds) and issue 5's piercing trials (the paper's Tables I-IV: box and shell, flat and tilted
//! 30 degrees) on the same seed-1 scans, each fused once per test binary.
//!
//! Run: `cargo test --release -p awl --test fuse_sim -- --nocapture` (prints the trial tables).
#![cfg(feature = "trial")]

mod common;

use std::sync::OnceLock;

use awl::io::scan::read_scan;
use awl::pierce::{HandEyePrior, LocateParams, PierceParams};
use awl::pipeline::{FuseConfig, FuseOutput, ViewStatus, fuse};
use awl::scan::Scan;
use awl::sim::{SceneKind, ShotPose, SimParams, Simulation, simulate, write_simulation};
use awl::trial::{ShotSetup, TrialSummary, TrialWorkpiece, calibrate_rig, format_table, prepare_workpiece, run_shot};
use awl::workpiece::{WorkpieceParams, workpiece_from_fuse};
use common::{Outcome, TruthScene, assert_acceptance, evaluate};
use nalgebra::Isometry3;

/// A simulated scan, fused.
struct Fused {
    sim: Simulation,
    scan: Scan,
    out: FuseOutput,
}

fn fused(scene: SceneKind, seed: u64, perturb: Option<(usize, Isometry3<f64>)>) -> Fused {
    fuse_simulation(simulate(&SimParams { seed, ..SimParams::scan(scene) }).expect("simulate"), perturb)
}

/// The scan of `fused(scene, seed, None)` without view `view`.
fn fused_without(scene: SceneKind, seed: u64, view: usize) -> Fused {
    let mut sim = simulate(&SimParams { seed, ..SimParams::scan(scene) }).expect("simulate");
    sim.scan.views.remove(view);
    sim.truth.views.remove(view);
    sim.views.remove(view);
    fuse_simulation(sim, None)
}

fn fuse_simulation(sim: Simulation, perturb: Option<(usize, Isometry3<f64>)>) -> Fused {
    fuse_simulation_with(sim, perturb, &FuseConfig::default())
}

/// Fuses the simulation in memory (its images held by the scan, no files written).
fn fuse_simulation_with(sim: Simulation, perturb: Option<(usize, Isometry3<f64>)>, config: &FuseConfig) -> Fused {
    let mut scan = sim.in_memory_scan();
    if let Some((view, delta)) = perturb {
        let seed_pose = scan.world_from_camera(view).expect("pose");
        scan.views[view].pose = awl::scan::ViewPose::Camera { world_from_camera: seed_pose * delta };
    }
    let out = fuse(&scan, config, &|_, _, _| {}).expect("fuse");
    Fused { sim, scan, out }
}

static BOX_SEED1: OnceLock<Fused> = OnceLock::new();
static SHELL_SEED1: OnceLock<Fused> = OnceLock::new();

/// The seed-1 scan of `scene`, fused once per test binary.
fn seed1(scene: SceneKind) -> &'static Fused {
    let cell = if scene == SceneKind::Box { &BOX_SEED1 } else { &SHELL_SEED1 };
    cell.get_or_init(|| fused(scene, 1, None))
}

fn judge(f: &Fused) -> Outcome {
    let truth = TruthScene {
        cad: &f.sim.cad,
        world_from_object: f.sim.truth.world_from_object,
        camera: f.scan.camera.expect("camera"),
        views: f.sim.truth.views.iter().zip(&f.sim.views).map(|(t, v)| (t.world_from_camera, &v.depth)).collect(),
        seeds: (0..f.scan.views.len()).map(|i| f.scan.world_from_camera(i).expect("seed")).collect(),
    };
    evaluate(&truth, &f.out)
}

fn check(scene: SceneKind) {
    let f = seed1(scene);
    assert_acceptance(&format!("{scene:?} seed 1"), &judge(f), &f.out.report);
    assert_advice(&format!("{scene:?} seed 1"), f);
    for seed in 2..=3 {
        let f = fused(scene, seed, None);
        assert_acceptance(&format!("{scene:?} seed {seed}"), &judge(&f), &f.out.report);
        assert_advice(&format!("{scene:?} seed {seed}"), &f);
    }
}

/// The scan-time advice on the simulator's 6 stops of 2 views: every stop named, and 2 more views
/// at each predicted to cut the hand-eye's 95 % bound by more than a quarter (measured on seeds
/// 1-3 of box and shell: see BENCHMARKS.md, "Scan-time advice").
fn assert_advice(name: &str, f: &Fused) {
    let a = f.out.report.advice.as_ref().expect("advice");
    let (now, together) = (a.stops[0].hand_eye_mm[0], a.together.expect("together")[0]);
    println!("{name}: advice names stops {:?}: hand-eye {now:.2} -> {together:.2} mm", a.not_enough);
    assert_eq!(a.not_enough.len(), a.stops.len(), "{name}: {a:?}");
    assert!(together < 0.75 * now, "{name}: {now:.2} -> {together:.2} mm");
    assert!(f.out.report.warnings.iter().any(|w| w.starts_with("scan advice")), "{name}");
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
fn registration_on_smoothed_views_beats_registration_on_the_measured_points() {
    // the default registers smoothed copies of the views with a fine joint threshold; before, it
    // registered the measured points with the sequential ICP's threshold
    let mut measured = FuseConfig { registration_smoothing_m: None, ..FuseConfig::default() };
    measured.registration.joint_convergence_translation_m = 1e-4;
    measured.registration.joint_convergence_rotation_rad = 1e-4;
    let sim = simulate(&SimParams { seed: 1, ..SimParams::scan(SceneKind::Box) }).expect("simulate");
    let on_measured = fuse_simulation_with(sim, None, &measured);
    let default = seed1(SceneKind::Box);
    let (d, m) = (judge(default), judge(&on_measured));
    println!(
        "box seed 1: {:.3} mm, {:.1} % complete (registered on the measured points: {:.3} mm, {:.1} %)",
        d.rmse_mm,
        d.completeness_5mm * 100.0,
        m.rmse_mm,
        m.completeness_5mm * 100.0,
    );
    // measured: 0.60 mm against 0.71 mm (BENCHMARKS.md 43)
    assert!(d.rmse_mm <= m.rmse_mm - 0.05 && d.rmse_mm <= 0.8, "{:.3} vs {:.3} mm", d.rmse_mm, m.rmse_mm);
    assert!(d.completeness_5mm >= m.completeness_5mm - 0.01, "{} vs {}", d.completeness_5mm, m.completeness_5mm);
}

#[test]
fn fast_preset_beats_the_open3d_pipeline_on_accuracy_and_keeps_the_object_whole() {
    // the Open3D pipeline on box seed 1: 2.85 mm on-object, 62.7 % complete at 5 mm, 58 % of its
    // points off the object (BENCHMARKS.md); the fast preset measured 1.04 / 0.45 mm, 98.0 / 97.6 % (box / shell;
    // 1.87 / 1.53 mm with the default's 6 mm MLS radius on its 4 mm model: BENCHMARKS.md 65)
    for scene in [SceneKind::Box, SceneKind::Shell] {
        let sim = simulate(&SimParams { seed: 1, ..SimParams::scan(scene) }).expect("simulate");
        let f = fuse_simulation_with(sim, None, &FuseConfig::fast());
        let o = judge(&f);
        let accepted = f.out.report.views.iter().filter(|v| v.status == ViewStatus::Accepted).count();
        println!(
            "{scene:?} seed 1, fast: {:.3} mm, {:.1} % complete, {:.2} % off, {accepted} views accepted",
            o.rmse_mm,
            o.completeness_5mm * 100.0,
            o.off_object * 100.0
        );
        assert!(o.rmse_mm < 1.5, "{scene:?}: {:.3} mm", o.rmse_mm);
        assert!(o.completeness_5mm > 0.95, "{scene:?}: {:.3} complete", o.completeness_5mm);
        assert!(o.off_object < 0.005, "{scene:?}: {:.4} off", o.off_object);
        assert!(accepted >= 9, "{scene:?}: {accepted} views accepted");
        // every second pixel: a quarter of the default's points, give or take the voxel grids
        let loaded = f.out.report.stages[0].points_out as f64;
        let ratio = seed1(scene).out.report.stages[0].points_out as f64 / loaded;
        assert!((ratio - 4.0).abs() < 0.04, "{scene:?}: {ratio:.3} x fewer points loaded");
    }
}

#[test]
fn a_seed_off_by_10cm_10deg_is_rejected() {
    let delta = Isometry3::new(
        nalgebra::Vector3::new(0.06, -0.06, 0.05),
        nalgebra::Vector3::new(0.1, 0.1, 0.1).normalize() * 10f64.to_radians(),
    );
    let f = fused(SceneKind::Box, 4, Some((5, delta)));
    let (o, report) = (judge(&f), &f.out.report);
    let view = &report.views[5];
    assert_eq!(view.status, ViewStatus::Excluded, "view 5: {view:?}");
    assert!(report.warnings.iter().any(|w| w.contains("view 5")), "{:?}", report.warnings);
    // The rejected view costs the model nothing: it is as accurate as the same scan fused without
    // that view, to 0.3 mm (its seed still moves the region of interest, found from every seed's
    // optical axis, so the inputs differ a little). Against all 12 views as recorded it may be
    // worse: 0.91 mm against 0.57 mm here.
    let without = judge(&fused_without(SceneKind::Box, 4, 5)).rmse_mm;
    println!("seed 4 with view 5 rejected: {:.2} mm; fused without view 5: {without:.2} mm", o.rmse_mm);
    assert!(
        o.rmse_mm <= without + 0.3 && o.rmse_mm <= 3.0,
        "model {:.2} mm vs {without:.2} mm without view 5",
        o.rmse_mm
    );
}

/// The scan written to files and read back fuses to the model of the same scan held in memory,
/// with 1 thread as with 2.
#[test]
fn one_and_two_threads_and_files_or_memory_give_the_same_model_bit_for_bit() {
    let sim = simulate(&SimParams { views: 4, seed: 5, ..SimParams::scan(SceneKind::Box) }).expect("simulate");
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("scan");
    write_simulation(&path, &sim, false).expect("write");
    let from_files = read_scan(&path).expect("read");
    let in_memory = sim.in_memory_scan();
    let run = |scan: &Scan, threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        pool.install(|| fuse(scan, &FuseConfig::default(), &|_, _, _| {}).expect("fuse"))
    };
    let (one, two, memory) = (run(&from_files, 1), run(&from_files, 2), run(&in_memory, 2));
    assert!(one.model.len() > 10_000, "model has {} points", one.model.len());
    assert_eq!(one.model, two.model, "model differs between 1 and 2 threads");
    assert_eq!(one.poses, two.poses);
    // the manifest's poses are rounded to its decimal text, about 1e-16 apart from the simulation's
    assert!(memory.model == two.model, "the in-memory scan fuses to another model");
    assert_eq!(memory.poses.iter().flatten().count(), two.poses.iter().flatten().count(), "views merged");
    for (i, (a, b)) in memory.poses.iter().flatten().zip(two.poses.iter().flatten()).enumerate() {
        let (dt, dr) = awl::transform::pose_difference(a, b);
        assert!(dt < 1e-12 && dr < 1e-12, "view {i}: poses {dt} m / {dr} rad apart");
    }
}

static BOX_WORKPIECE: OnceLock<TrialWorkpiece> = OnceLock::new();
static SHELL_WORKPIECE: OnceLock<TrialWorkpiece> = OnceLock::new();
static FLANK_WORKPIECE: OnceLock<TrialWorkpiece> = OnceLock::new();

/// Trials of the piercing workflow (`awl::trial`) on the seed-1 scan of `scene`: a hand-eye
/// calibrated from 20 simulated poses, `n` shots in random placements, each planned from its tag
/// and depth. Issue 5: mean distance at most 2 mm, max at most 4 mm, tool axis within 1 degree of
/// the true normal (the reference system: about 8 mm). CI runs 5 trials per table to keep the suite
/// short; `awl trial --trials 10` prints the full tables.
fn trials(scene: SceneKind, pose: ShotPose, n: usize) {
    trials_at(scene, None, pose, n);
}

/// [`trials`] on the truth target `target` (the first when `None`).
/// The seed-1 fused workpiece of `scene` with its `target`, prepared once per test binary.
fn trial_workpiece(scene: SceneKind, target: Option<&str>) -> &'static TrialWorkpiece {
    let f = seed1(scene);
    let cell = match (scene, target) {
        (SceneKind::Box, _) => &BOX_WORKPIECE,
        (_, Some("flank")) => &FLANK_WORKPIECE,
        _ => &SHELL_WORKPIECE,
    };
    cell.get_or_init(|| {
        let tag = workpiece_from_fuse(&f.scan, &f.out, "model.ply", &WorkpieceParams::default())
            .expect("workpiece")
            .expect("the scan declares a tag");
        prepare_workpiece(scene, &tag, &f.sim.truth, &f.sim.cad, &f.out.model, target).unwrap_or_else(|e| panic!("{e}"))
    })
}

fn trials_at(scene: SceneKind, target: Option<&str>, pose: ShotPose, n: usize) {
    let (mean_mm, max_mm, axis_deg) = (2.0, 4.0, 1.0f64);
    let wp = trial_workpiece(scene, target);
    let hand_eye = calibrate_rig(1, 20).expect("calibration");
    let setup = ShotSetup {
        scene,
        pose,
        seed: 1,
        camera_seed: 1,
        ee_from_camera: hand_eye.ee_from_camera,
        // a fresh calibration, as `awl trial --calibrate` and `awl pierce --hand-eye` take it
        params: PierceParams {
            locate: LocateParams::with_refinement(),
            hand_eye: Some(HandEyePrior::calibrated(hand_eye.ee_from_camera, "calibrate_rig")),
            ..PierceParams::default()
        },
        robot: None,
        plan_views: 0,
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let rows: Vec<_> = (1..=n)
        .map(|k| {
            run_shot(wp, &setup, k, &dir.path().join(format!("{k:02}"))).unwrap_or_else(|e| panic!("trial {k}: {e}"))
        })
        .collect();
    let title = format!(
        "{scene:?} {} (hand-eye {:.2} mm / {:.3} deg off), target `{}` as {}",
        pose.name(),
        hand_eye.error_m * 1e3,
        hand_eye.error_rad.to_degrees(),
        wp.target.name,
        wp.spec
    );
    println!("{}", format_table(&title, &rows));
    let s = TrialSummary::of(&rows);
    let name = format!("{scene:?} {}", pose.name());
    assert!(s.mean_m <= mean_mm * 1e-3, "{name}: mean {:.2} mm > {mean_mm} mm", s.mean_m * 1e3);
    assert!(s.max_m <= max_mm * 1e-3, "{name}: max {:.2} mm > {max_mm} mm", s.max_m * 1e3);
    assert!(
        s.max_axis_error_rad <= axis_deg.to_radians(),
        "{name}: axis {:.2} deg > {axis_deg} deg",
        s.max_axis_error_rad.to_degrees()
    );
    // The axis error's two sources, in their own frames: their sum bounds it when both are right.
    for r in &rows {
        let sources = r.locate_rotation_rad + r.model_normal_error_rad;
        assert!(
            r.axis_error_rad <= sources + 1e-9,
            "{name} trial {}: axis {:.3} deg > locate rotation + model normal {:.3} deg",
            r.trial,
            r.axis_error_rad.to_degrees(),
            sources.to_degrees()
        );
    }
    // Where the tool meets the box's top, the true normal is the target's: both axis errors agree
    // (the true surface's nearest point is found on the right face).
    if scene == SceneKind::Box {
        for r in &rows {
            assert!(
                (r.axis_error_at_point_rad - r.axis_error_rad).abs() < 1e-4,
                "{name} trial {}: axis error at the pierced point {:.4} deg, at the target {:.4} deg",
                r.trial,
                r.axis_error_at_point_rad.to_degrees(),
                r.axis_error_rad.to_degrees()
            );
        }
    }
    assert!(
        s.max_locate_rotation_rad <= 1f64.to_radians(),
        "{name}: located rotation {:.2} deg off",
        s.max_locate_rotation_rad.to_degrees()
    );
}

#[test]
fn trials_box_flat() {
    // measured mean 1.47 mm, max 2.28 mm, axis 0.26 deg
    trials(SceneKind::Box, ShotPose::Flat, 5);
}

#[test]
fn trials_box_tilted_30() {
    // measured mean 1.58 mm, max 2.32 mm, axis 0.16 deg
    trials(SceneKind::Box, ShotPose::Tilt30, 5);
}

#[test]
fn trials_shell_flat() {
    // The groove's bottom, where the surface turns 4 deg per mm: issue 5's bounds, axis included
    // (10 trials: mean 1.26 mm, max 2.10 mm, axis mean 0.32 deg, max 0.40 deg; the model's normal
    // there 0.27 deg off, from 1.52 deg with the 15 mm plane before the fold's patch)
    trials(SceneKind::Shell, ShotPose::Flat, 5);
}

#[test]
fn trials_shell_tilted_30() {
    // the groove: 10 trials: mean 1.22 mm, max 2.05 mm, axis mean 0.35 deg, max 0.53 deg
    trials(SceneKind::Shell, ShotPose::Tilt30, 5);
}

#[test]
fn trials_shell_flank_flat() {
    // a gently curved point (0.35 deg per mm): issue 5's bounds, axis included (10 trials: mean
    // 1.70 mm, max 2.85 mm, axis max 0.87 deg)
    trials_at(SceneKind::Shell, Some("flank"), ShotPose::Flat, 5);
}

#[test]
fn trials_shell_flank_tilted_30() {
    // 10 trials: mean 1.56 mm, max 3.13 mm, axis max 0.86 deg
    trials_at(SceneKind::Shell, Some("flank"), ShotPose::Tilt30, 5);
}

/// Issue 79 on awl's simulator: the hand-eye recorded in the scan (refined by the fuse, as a user
/// without a fresh calibration has it), each tilted box shot pierced from its 2 views and again from
/// them plus up to 4 views `awl plan-views` proposed among its own candidates (the shot simulated
/// again with the arm sent there): the planned views lower the error, and the bounds hold.
#[test]
fn planned_views_lower_the_error_with_the_recorded_hand_eye() {
    let scene = SceneKind::Box;
    let f = seed1(scene);
    let wp = trial_workpiece(scene, None);
    let tag = workpiece_from_fuse(&f.scan, &f.out, "model.ply", &WorkpieceParams::default())
        .expect("workpiece")
        .expect("tag");
    let prior = HandEyePrior::of_report(tag.hand_eye.as_ref().expect("the fuse's hand-eye")).expect("prior");
    let dir = tempfile::tempdir().expect("tempdir");
    let run = |plan_views: usize| {
        let setup = ShotSetup {
            scene,
            pose: ShotPose::Tilt30,
            seed: 1,
            camera_seed: 1,
            ee_from_camera: f.scan.ee_from_camera.expect("recorded"),
            params: PierceParams {
                locate: LocateParams::with_refinement(),
                hand_eye: Some(prior.clone()),
                ..PierceParams::default()
            },
            robot: None,
            plan_views,
        };
        (1..=3)
            .map(|k| {
                run_shot(wp, &setup, k, &dir.path().join(format!("{plan_views}-{k}")))
                    .unwrap_or_else(|e| panic!("trial {k}: {e}"))
            })
            .collect::<Vec<_>>()
    };
    let (before, after) = (run(0), run(4));
    println!("{}", format_table("2 views", &before));
    println!("{}", format_table("2 views + planned", &after));
    let (b, a) = (TrialSummary::of(&before), TrialSummary::of(&after));
    assert!(
        after.iter().all(|r| r.planned_views >= 1 && r.planned_views <= 4),
        "{:?}",
        after.iter().map(|r| r.planned_views).collect::<Vec<_>>()
    );
    for r in &after {
        assert!(r.error().norm() <= r.prediction.position_bound_m, "trial {}: outside its bound", r.trial);
        assert!(r.axis_error_rad <= r.prediction.axis_bound_rad, "trial {}: axis outside its bound", r.trial);
    }
    // measured 1.19 mm mean / 1.49 max (from the 2 views: 2.63 / 2.99); issue 79 asks mean <= 1.2 mm and
    // max <= 2.5 mm over seeds 1-8 (BENCHMARKS.md): here, 3 shots, the error at most 0.6 times the 2 views'
    assert!(a.mean_m <= 0.6 * b.mean_m, "planned {:.2} mm vs {:.2} mm", a.mean_m * 1e3, b.mean_m * 1e3);
    assert!(a.max_m <= 0.0025, "planned: max {:.2} mm", a.max_m * 1e3);
}
