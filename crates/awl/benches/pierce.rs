//! `awl pierce` and `awl plan-views` at piercing time (issue 79's speed targets: plan-views under
//! 2 s for 10 targets and 4 views, a pierce on a 6-view shot under 3 s), each with 1 and 2 rayon
//! threads, on the other simulator's box (`../shared/data/sim_reference`, found through
//! `$AWL_SHARED_DATA` like the tests; without it the benches are skipped with a message):
//!
//! - `pierce_6_views`: `awl::pierce::plan` (tag, shot-depth refinement, each view registered onto
//!   the model and combined with the hand-eye, predictions) on `box_seed1_shot_flat_views6`, 10
//!   targets. The workpiece is `awl fuse`'s of `box_seed1` (default configuration), fused once and
//!   kept in `$CARGO_TARGET_TMPDIR/awl-bench/sim_reference-box_seed1` (workpiece.json and model.ply,
//!   read back as `awl pierce` reads them); the model's index (`SurfaceModel::new`) is built once,
//!   outside the timing.
//! - `plan_views_10_targets`: `awl::plan_views::plan_after_pierce` after a pierce of the 2-view shot
//!   `box_seed1_shot_flat` for 10 targets, up to 4 views among awl's own candidates
//!   (`plan_views::sample::candidates_after_pierce`), tolerance 0.5 mm (not met: every round runs).
//!
//! The targets: 10 model points the shot's first view sees facing it (within 60 deg), evenly spaced
//! through the model's order, given as `x,y,z` (snapped onto the surface, as `--target x,y,z`).
//!
//! ```sh
//! AWL_SHARED_DATA=../shared/data nice -n 19 cargo bench -p awl --bench pierce
//! ```
//!
//! Each prints one `check:` line per thread count (the first target's `p_base`, the located pose),
//! so that a faster build can be seen to plan the same.

mod common;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use awl::PointCloud;
use awl::io::mesh::{read_cloud, write_cloud};
use awl::io::scan::read_scan;
use awl::job::fuse_job;
use awl::kinematics::Arm;
use awl::pierce::{HandEyePrior, LocateParams, PierceParams, PiercePlan, Tolerance, plan};
use awl::pipeline::FuseConfig;
use awl::plan_views::reach::ViewRobot;
use awl::plan_views::sample::candidates_after_pierce;
use awl::plan_views::{PlanViewsParams, plan_after_pierce};
use awl::scan::Scan;
use awl::workpiece::json::{read_workpiece, write_workpiece};
use awl::workpiece::{SurfaceModel, TargetSpec, WORKPIECE_FILE, Workpiece, WorkpieceParams};
use common::{THREADS, pool, shared_data};
use divan::Bencher;
use nalgebra::Point3;

/// The number of targets.
const TARGETS: usize = 10;

fn main() {
    let dir = reference_dir();
    if !dir.join("box_seed1/scan.json").is_file() {
        eprintln!(
            "pierce benches skipped: {} has no box_seed1 scan (set AWL_SHARED_DATA to the shared data folder)",
            dir.display()
        );
        return;
    }
    divan::main();
}

fn reference_dir() -> PathBuf {
    shared_data().join("sim_reference")
}

/// The fused box: its workpiece and model, as `awl pierce` reads them.
struct Fused {
    workpiece: Workpiece,
    model: PointCloud,
}

fn fused() -> &'static Fused {
    static FUSED: OnceLock<Fused> = OnceLock::new();
    FUSED.get_or_init(|| {
        let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("awl-bench/sim_reference-box_seed1");
        let (wp_path, model_path) = (out.join(WORKPIECE_FILE), out.join("model.ply"));
        if !wp_path.is_file() || !model_path.is_file() {
            eprintln!("fusing box_seed1 once (default configuration) into {}", out.display());
            let scan = read_scan(&reference_dir().join("box_seed1")).expect("box_seed1 scan");
            let job = fuse_job(&scan, &FuseConfig::default(), &WorkpieceParams::default(), "model.ply", &|_, _, _| {})
                .expect("fuse box_seed1");
            std::fs::create_dir_all(&out).expect("bench cache folder");
            write_cloud(&model_path, &job.fused.model).expect("write model.ply");
            write_workpiece(&wp_path, job.workpiece.as_ref().expect("the scan declares a tag")).expect("workpiece");
        }
        let workpiece = read_workpiece(&wp_path).expect("read workpiece.json");
        let model = read_cloud(&model_path).expect("read model.ply");
        Fused { workpiece, model }
    })
}

/// Pierce parameters as `awl pierce` sets them (refinement on, the workpiece's hand-eye).
fn pierce_params(wp: &Workpiece, shot: &Scan) -> PierceParams {
    PierceParams {
        locate: LocateParams::with_refinement(),
        hand_eye: HandEyePrior::of_workpiece(wp.hand_eye.as_ref(), shot).expect("hand-eye prior"),
        model_disagreement_m: wp.model_disagreement_m(),
        ..PierceParams::default()
    }
}

fn pierce(surface: &SurfaceModel<'_>, wp: &Workpiece, shot: &Scan, specs: &[TargetSpec]) -> (PiercePlan, PierceParams) {
    let params = pierce_params(wp, shot);
    let world_from_tag = wp.world_from_tag.expect("T_world_tag");
    (plan(surface, &wp.tag, &world_from_tag, shot, specs, &params).expect("pierce"), params)
}

/// [`TARGETS`] model points that the shot's first view sees facing it (module docs), from a pierce
/// of `shot` at the model's first point.
fn targets(surface: &SurfaceModel<'_>, wp: &Workpiece, model: &PointCloud, shot: &Scan) -> Vec<TargetSpec> {
    let p0 = model.points[0].cast::<f64>();
    let (first, _) = pierce(surface, wp, shot, &[TargetSpec::Point(p0)]);
    let camera = shot.camera.expect("camera").intrinsics;
    let base_from_camera = shot.world_from_camera(0).expect("view 0 pose");
    let camera_from_model = base_from_camera.inverse() * first.located.base_from_model;
    let eye = camera_from_model.inverse().translation.vector;
    let normals = model.normals.as_ref().expect("model normals");
    let seen: Vec<usize> = (0..model.len())
        .filter(|&i| {
            let p = model.points[i].cast::<f64>();
            let Some(px) = camera.project(&(camera_from_model * p)) else { return false };
            let inside =
                px.x >= 0.0 && px.y >= 0.0 && px.x < f64::from(camera.width) && px.y < f64::from(camera.height);
            let facing = normals[i].cast::<f64>().dot(&(eye - p.coords).normalize()) > 60f64.to_radians().cos();
            inside && facing
        })
        .collect();
    assert!(seen.len() >= TARGETS, "view 0 sees {} model points", seen.len());
    let specs: Vec<TargetSpec> = (0..TARGETS)
        .map(|k| {
            let p = model.points[seen[(2 * k + 1) * seen.len() / (2 * TARGETS)]];
            TargetSpec::Point(Point3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z)))
        })
        .collect();
    let args: Vec<String> = specs.iter().map(|s| format!("--target {s}")).collect();
    eprintln!("targets (for the CLI): {}", args.join(" "));
    specs
}

fn check_line(what: &str, threads: usize, p: &PiercePlan) {
    let t = p.located.base_from_model.translation.vector;
    let q = p.targets[0].p_base;
    eprintln!(
        "check: {what}, {threads} threads: T_base_model t ({:.9}, {:.9}, {:.9}); target 0 p_base ({:.9}, {:.9}, {:.9})",
        t.x, t.y, t.z, q.x, q.y, q.z
    );
}

#[divan::bench(args = THREADS, sample_count = 3, sample_size = 1)]
fn pierce_6_views(b: Bencher, threads: usize) {
    let f = fused();
    let shot = read_scan(&reference_dir().join("box_seed1_shot_flat_views6")).expect("6-view shot");
    let surface = SurfaceModel::new(&f.model).expect("model index").with_floor(f.workpiece.floor);
    let specs = targets(&surface, &f.workpiece, &f.model, &shot);
    let run = || pool(threads).install(|| pierce(&surface, &f.workpiece, &shot, &specs).0);
    check_line("pierce_6_views", threads, &run());
    b.bench(run);
}

/// With an arm (`awl plan-views --robot`): a UR10e (the simulated rig's shot poses are beyond a
/// UR5e), a 150 mm tool; `None` without.
fn bench_robot(with_arm: bool, floor: Option<awl::segment::FloorPlane>) -> Option<ViewRobot> {
    with_arm.then(|| ViewRobot {
        floor,
        ..ViewRobot::new(Arm::by_name("ur10e").expect("ur10e"), nalgebra::Isometry3::translation(0.0, 0.0, 0.15))
    })
}

#[divan::bench(args = [false, true], sample_count = 3, sample_size = 1)]
fn plan_views_10_targets(b: Bencher, with_arm: bool) {
    let threads = 2;
    let f = fused();
    let shot = read_scan(&reference_dir().join("box_seed1_shot_flat")).expect("2-view shot");
    let surface = SurfaceModel::new(&f.model).expect("model index").with_floor(f.workpiece.floor);
    let specs = targets(&surface, &f.workpiece, &f.model, &shot);
    let (first, params) = pierce(&surface, &f.workpiece, &shot, &specs);
    let candidates = candidates_after_pierce(&first, &shot).expect("candidates");
    let robot = bench_robot(with_arm, f.workpiece.floor);
    let plan_params = PlanViewsParams {
        tolerance: Tolerance { position_m: Some(0.0005), axis_rad: None },
        ..PlanViewsParams::default()
    };
    let run = || {
        pool(threads).install(|| {
            plan_after_pierce(&first, &params, &shot, &f.model, robot.as_ref(), &candidates, &plan_params)
                .expect("plan views")
        })
    };
    let views = run();
    eprintln!(
        "check: plan_views_10_targets, arm {with_arm}: {} candidates, {} left out, chosen {:?}, worst bound {:.6} mm ({})",
        candidates.len(),
        views.left_out.len(),
        views.chosen.iter().map(|c| c.candidate).collect::<Vec<_>>(),
        views.chosen.last().map_or(&views.before, |c| &c.bounds).iter().map(|x| x.0 * 1e3).fold(0.0, f64::max),
        views.stop
    );
    b.bench(run);
}
