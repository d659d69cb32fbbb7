//! The scans and piercing shots of a simulator that is not ours (shared/data/sim_reference: its own
//! noise model, stereo shadows, depth-scale error, SLAM error shared per base stop, clutter 4-8 cm
//! from the workpiece), each scan fused once per test binary and judged against its truth:
//! - issue 3's fuse thresholds. For scale, the reference system's method rebuilt with Open3D gives
//!   22.3 mm RMSE / 62 % / 24 % off-object on the box and 3.9 mm / 96 % / 29 % on the shell;
//! - issue 5: the tag on the model (`T_object_tag` via the model's alignment onto the CAD), face
//!   centres and snapped points against the CAD, and `pierce::plan` from the tilted shots against
//!   the shots' truth targets (robot base frame).
//!
//! Run: `cargo test --release -p awl --test fuse_reference -- --nocapture` (prints every measurement).
#![cfg(feature = "trial")]

mod common;

use std::sync::OnceLock;

use awl::io::image::read_depth_png;
use awl::io::mesh::read_mesh;
use awl::io::scan::read_scan;
use awl::io::truth::{Truth, read_truth};
use awl::mesh::TriMesh;
use awl::pierce::{HandEyePrior, LocateParams, PierceParams, plan};
use awl::pipeline::{FuseConfig, FuseOutput, fuse};
use awl::scan::{Scan, ViewData};
use awl::sim::SceneKind;
use awl::trial::pick_target;
use awl::workpiece::file::floor_of_fuse;
use awl::workpiece::json::{read_workpiece, write_workpiece};
use awl::workpiece::{SurfaceModel, TargetParams, TargetSpec, WorkpieceParams, workpiece_from_fuse};
use common::{Outcome, TruthScene, assert_acceptance, evaluate, shared_data};
use nalgebra::{Isometry3, Vector3};

/// A reference scan, fused and judged.
struct Fused {
    name: &'static str,
    scan: Scan,
    truth: Truth,
    cad: TriMesh,
    out: FuseOutput,
    outcome: Outcome,
}

fn fused(name: &'static str) -> Fused {
    let dir = shared_data().join("sim_reference").join(name);
    let scan = read_scan(&dir).expect("scan");
    let truth = read_truth(&dir).expect("truth");
    let cad = read_mesh(&dir.join(&truth.cad)).expect("cad");
    let depths: Vec<_> = scan
        .views
        .iter()
        .map(|v| match &v.data {
            ViewData::Depth { depth, .. } => read_depth_png(&dir.join(depth)).expect("depth"),
            _ => panic!("sim_reference views are depth images"),
        })
        .collect();
    let out = fuse(&scan, &FuseConfig::default(), &|_, _, _| {}).expect("fuse");
    let scene = TruthScene {
        cad: &cad,
        world_from_object: truth.world_from_object,
        camera: scan.camera.expect("camera"),
        views: truth.views.iter().zip(&depths).map(|(t, d)| (t.world_from_camera, d)).collect(),
        seeds: (0..scan.views.len()).map(|i| scan.world_from_camera(i).expect("seed")).collect(),
    };
    let outcome = evaluate(&scene, &out);
    Fused { name, scan, truth, cad, out, outcome }
}

static BOX: OnceLock<Fused> = OnceLock::new();
static SHELL: OnceLock<Fused> = OnceLock::new();

fn reference_box() -> &'static Fused {
    BOX.get_or_init(|| fused("box_seed1"))
}

fn reference_shell() -> &'static Fused {
    SHELL.get_or_init(|| fused("shell_seed1"))
}

#[test]
fn box_fuse_acceptance() {
    let f = reference_box();
    assert_acceptance(f.name, &f.outcome, &f.out.report);
}

#[test]
fn shell_fuse_acceptance() {
    let f = reference_shell();
    assert_acceptance(f.name, &f.outcome, &f.out.report);
}

/// (origin distance mm, z-axis angle deg, full rotation angle deg).
fn tag_error(estimate: &Isometry3<f64>, truth: &Isometry3<f64>) -> (f64, f64, f64) {
    let centre_mm = (estimate.translation.vector - truth.translation.vector).norm() * 1e3;
    let z_deg = (estimate.rotation * Vector3::z()).angle(&(truth.rotation * Vector3::z())).to_degrees();
    (centre_mm, z_deg, estimate.rotation.angle_to(&truth.rotation).to_degrees())
}

/// `workpiece_from_fuse`: the tag vs the truth in the object frame; workpiece.json round trip.
fn check_fused_tag(f: &Fused, max_mm: f64, max_deg: f64) {
    let wp = workpiece_from_fuse(&f.scan, &f.out, "model.ply", &WorkpieceParams::default())
        .expect("workpiece")
        .expect("the scan declares a tag");
    let world_from_tag = wp.world_from_tag.unwrap_or_else(|| panic!("{}: {:?}", f.name, wp.warnings));
    let truth = f.truth.world_from_object.inverse() * f.truth.world_from_tag.expect("T_world_tag");
    let (c, z, r) = tag_error(&(f.outcome.object_from_model * world_from_tag), &truth);
    let refinement = wp.refinement.as_ref().expect("refinement");
    let used = wp.detections.iter().filter(|d| d.used).count();
    println!(
        "{} (fused): T_object_tag error {c:.2} mm, z {z:.3} deg, rot {r:.3} deg; {used} of {} detections used, \
         refinement on {} points (rms {:.2} mm, tilt {:.3} deg, shift {:.2} mm); warnings {:?}",
        f.name,
        wp.detections.len(),
        refinement.points,
        refinement.rms_m * 1e3,
        refinement.tilt_rad.to_degrees(),
        refinement.shift_m * 1e3,
        wp.warnings
    );
    assert!(refinement.applied && used >= 2, "{}", f.name);
    assert!(c <= max_mm && r <= max_deg, "{}: {c:.2} mm {r:.3} deg", f.name);
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("workpiece.json");
    write_workpiece(&path, &wp).expect("write");
    let back = read_workpiece(&path).expect("read");
    assert_eq!(back.views_checked, wp.views_checked);
    assert_eq!(back.detections.len(), wp.detections.len());
    let (dt, dr) = awl::transform::pose_difference(&back.world_from_tag.expect("T_world_tag"), &world_from_tag);
    assert!(dt < 1e-12 && dr < 1e-9, "round trip {dt} {dr}");
}

/// The face centre of the truth target `name`, picked 5 cm off-centre and 3 mm above the face
/// ([`pick_target`]), on the model with the floor fusion found.
fn check_face_centre(f: &Fused, name: &str, max_mm: f64, max_deg: f64) {
    let object_from_model = f.outcome.object_from_model;
    let target = f.truth.targets.iter().find(|t| t.name == name).expect("truth target");
    let TargetSpec::FaceCentre(pick) = pick_target(SceneKind::Box, target, &object_from_model) else {
        panic!("a box target is a face centre")
    };
    let surface = SurfaceModel::new(&f.out.model).expect("surface model").with_floor(floor_of_fuse(&f.out));
    let placed = surface.place(&TargetSpec::FaceCentre(pick), &TargetParams::default(), None).expect("face centre");
    let p = object_from_model * placed.point;
    let n = object_from_model.rotation * placed.normal;
    let err_mm = (p - target.p_object).norm() * 1e3;
    let err_deg = n.angle(&target.n_object).to_degrees();
    let corners = placed.corners.expect("corners").map(|c| object_from_model * c);
    let sides_mm = [(corners[1] - corners[0]).norm() * 1e3, (corners[2] - corners[1]).norm() * 1e3];
    println!(
        "{} face centre `{name}`: {err_mm:.2} mm ({:?} mm), normal {err_deg:.3} deg; face {} points, rms {:.2} mm, \
         rectangle {:.1} x {:.1} mm",
        f.name,
        (p - target.p_object).map(|v| (v * 1e4).round() / 10.0),
        placed.points,
        placed.fit_rms_m * 1e3,
        sides_mm[0],
        sides_mm[1]
    );
    assert!((placed.axis + placed.normal).norm() < 1e-12);
    assert!(err_mm <= max_mm && err_deg <= max_deg, "{}: {err_mm:.2} mm {err_deg:.3} deg", f.name);
}

#[test]
fn box_tag_on_the_model_and_face_centres() {
    let f = reference_box();
    // measured 0.23 mm / 0.006 deg (1.56 mm with the hull's rectangle, before the half-density edges)
    check_face_centre(f, "top-centre", 1.0, 1.0);
    // measured 1.07 mm (0.9 of it the model's face standing proud of the CAD's); the face
    // meets the floor: 39 mm before the face was grown by refits and its sides taken from the floor
    check_face_centre(f, "side-centre", 2.5, 1.0);
    check_fused_tag(f, 2.0, 0.5);
}

/// (median, p95, max).
fn stats(v: &mut [f64]) -> (f64, f64, f64) {
    v.sort_by(f64::total_cmp);
    let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    (at(0.5), at(0.95), at(1.0))
}

#[test]
fn shell_tag_on_the_model_and_snapped_points() {
    let f = reference_shell();
    let object_from_model = f.outcome.object_from_model;
    let model_from_object = object_from_model.inverse();
    let surface = SurfaceModel::new(&f.out.model).expect("surface model");
    let cad = awl::eval::MeshDistance::new(&f.cad).expect("cad");
    let samples = f.cad.sample_surface(4000, 7).expect("samples");
    let normals = samples.normals.as_ref().expect("sample normals");
    let index = awl::spatial::KdIndex::new(&f.out.model.points).expect("index");
    let (mut dist_mm, mut angle_deg) = (Vec::new(), Vec::new());
    for (p, n) in samples.points.iter().zip(normals) {
        let (p, n) = (p.cast::<f64>(), n.cast::<f64>());
        let p_model = model_from_object * p;
        // a point the model covers (a model point within 2 mm)
        let covered = index.nearest(&p_model.cast::<f32>()).is_some_and(|nb| nb.dist_sq < 4e-6);
        if !covered || dist_mm.len() >= 300 {
            continue;
        }
        let pick = p_model + model_from_object.rotation * n * 0.004;
        let Ok(placed) = surface.snap(&pick, &TargetParams::default()) else { continue };
        let q = object_from_model * placed.point;
        dist_mm.push(cad.distances(&[q])[0] * 1e3);
        angle_deg.push((object_from_model.rotation * placed.normal).angle(&n).to_degrees());
    }
    let (d, a) = (stats(&mut dist_mm), stats(&mut angle_deg));
    println!(
        "{}: {} snapped points: distance to CAD median {:.3} p95 {:.3} max {:.3} mm; normal vs CAD median {:.2} p95 {:.2} max {:.2} deg",
        f.name,
        dist_mm.len(),
        d.0,
        d.1,
        d.2,
        a.0,
        a.1,
        a.2
    );
    assert!(dist_mm.len() >= 200, "{} points", dist_mm.len());
    // measured: median 0.49 mm / 0.92 deg, p95 1.28 mm / 4.06 deg, max 1.66 mm / 27.9 deg (the
    // model's own error vs the CAD's 4 mm facets, and rims where the normal turns fast; the 15 mm
    // plane in folds instead of the fold's patch: median 0.97 deg, p95 6.56 deg)
    assert!(d.0 <= 1.0 && a.0 <= 1.5, "median {:.3} mm, {:.2} deg", d.0, a.0);
    assert!(d.1 <= 1.5 && a.1 <= 6.0, "p95 {:.3} mm, {:.2} deg", d.1, a.1);
    // measured 2.64 mm / 0.19 deg: the tag is printed on a curved side, its corners lie 1.4-1.9 mm behind
    // the tag plane (see tests/tags_sim.rs), which biases the detected origin
    check_fused_tag(f, 3.0, 1.0);
}

/// Plans the shot folder's truth targets from the fused scan (`T_ee_camera` from scan.json, as a
/// user without a better calibration would, and the true one, which isolates awl's own error) and
/// returns the largest distance and axis error of each, per target name.
fn pierce_shot(f: &Fused, shot_folder: &str, face_centres: bool) -> Vec<(String, [f64; 4])> {
    let shot_dir = shared_data().join("sim_reference").join(shot_folder);
    let shot = read_scan(&shot_dir).expect("shot");
    let shot_truth = read_truth(&shot_dir).expect("shot truth");
    let wp = workpiece_from_fuse(&f.scan, &f.out, "model.ply", &WorkpieceParams::default())
        .expect("workpiece")
        .expect("tag");
    let world_from_tag = wp.world_from_tag.expect("T_world_tag");
    let specs: Vec<TargetSpec> = shot_truth
        .targets
        .iter()
        .map(|t| {
            pick_target(if face_centres { SceneKind::Box } else { SceneKind::Shell }, t, &f.outcome.object_from_model)
        })
        .collect();
    let mut errors: Vec<(String, [f64; 4])> = shot_truth.targets.iter().map(|t| (t.name.clone(), [0.0; 4])).collect();
    for (k, hand_eye) in [shot.ee_from_camera, shot_truth.ee_from_camera].into_iter().enumerate() {
        let mut s = shot.clone();
        s.ee_from_camera = hand_eye;
        let prior = HandEyePrior::of_workpiece(wp.hand_eye.as_ref(), &s).expect("prior");
        if let (0, Some(he), Some(truth)) = (k, &prior, shot_truth.ee_from_camera) {
            let (before, after) = (
                awl::transform::pose_difference(&hand_eye.expect("recorded"), &truth),
                awl::transform::pose_difference(&he.prior.ee_from_camera, &truth),
            );
            println!(
                "{shot_folder}: hand-eye recorded {:.2} mm {:.3} deg, refined from the scan {:.2} mm {:.3} deg",
                before.0 * 1e3,
                before.1.to_degrees(),
                after.0 * 1e3,
                after.1.to_degrees()
            );
        }
        let params =
            PierceParams { locate: LocateParams::with_refinement(), hand_eye: prior, ..PierceParams::default() };
        let surface = SurfaceModel::new(&f.out.model).expect("index").with_floor(wp.floor);
        let planned = plan(&surface, &wp.tag, &world_from_tag, &s, &specs, &params).expect("plan");
        let r = planned.located.refinement.as_ref().expect("refinement");
        for ((t, p), e) in shot_truth.targets.iter().zip(&planned.targets).zip(&mut errors) {
            let d = (p.p_base - t.p_world.expect("p_world")).norm() * 1e3;
            let tag_only =
                (planned.located.base_from_model_tag * p.surface.point - t.p_world.expect("p_world")).norm() * 1e3;
            let a = p.axis_base.angle(&-t.n_world.expect("n_world")).to_degrees();
            if let (Some(h), Some(truth)) = (&planned.located.hand_eye, shot_truth.ee_from_camera) {
                let (dt, dr) = awl::transform::pose_difference(&h.ee_from_camera, &truth);
                println!(
                    "  hand-eye used {dt:.4} m {:.3} deg from the truth (prior: {})",
                    dr.to_degrees(),
                    h.prior_source
                );
            }
            println!(
                "{shot_folder} `{}` with the {} hand-eye: {d:.2} mm (tag pose alone {tag_only:.2} mm), axis {a:.2} deg; \
                 shot depth {} points, fitness {:.2}, moved the tag {:.2} mm / {:.3} deg",
                t.name,
                if k == 0 { "recorded" } else { "true" },
                r.points,
                r.fitness,
                r.correction_m * 1e3,
                r.correction_rad.to_degrees()
            );
            assert!(r.applied, "{}", r.note);
            // nothing that worked is refused (issue 82): a shot that fits its model goes
            assert!(p.go() && r.fitness >= awl::pierce::MIN_SHOT_FITNESS, "{:?} {}", p.no_go_reason(), r.fitness);
            e.1[2 * k] = d;
            e.1[2 * k + 1] = a;
        }
    }
    errors
}

/// workpiece.json binds its model (issue 82): the fused box's `model_check` accepts the model as
/// written and read back, and refuses the shell's; a box shot planned on the shell's model (as an
/// older workpiece.json without `model_check` would allow) makes every target no-go.
#[test]
fn a_workpiece_is_bound_to_its_model() {
    let (b, sh) = (reference_box(), reference_shell());
    let wp = workpiece_from_fuse(&b.scan, &b.out, "model.ply", &WorkpieceParams::default())
        .expect("workpiece")
        .expect("tag");
    let dir = tempfile::tempdir().expect("tempdir");
    let (path, model_path) = (dir.path().join("workpiece.json"), dir.path().join("model.ply"));
    write_workpiece(&path, &wp).expect("write");
    awl::io::mesh::write_cloud(&model_path, &b.out.model).expect("model");
    let back = read_workpiece(&path).expect("read");
    let check = back.model_check.as_ref().expect("model_check");
    assert_eq!(check.points, b.out.model.len());
    check.verify(&path, &model_path, &awl::io::mesh::read_cloud(&model_path).expect("read")).expect("its own model");
    let e = check.verify(&path, &model_path, &sh.out.model).expect_err("the shell's model").to_string();
    assert!(e.contains("model_check") && e.contains("points"), "{e}");
    // the shell's model behind the box's tag: the shot does not fit it
    let shot_dir = shared_data().join("sim_reference").join("box_seed1_shot_flat");
    let shot = read_scan(&shot_dir).expect("shot");
    let p = sh.out.model.points[sh.out.model.len() / 2];
    let specs = [TargetSpec::Point(nalgebra::Point3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z)))];
    let params = PierceParams { locate: LocateParams::with_refinement(), ..PierceParams::default() };
    let surface = SurfaceModel::new(&sh.out.model).expect("index");
    let planned = plan(&surface, &wp.tag, &wp.world_from_tag.expect("tag"), &shot, &specs, &params).expect("plan");
    let r = planned.located.refinement.as_ref().expect("refinement");
    println!("box shot on the shell's model: fitness {:.2}, {:?}", r.fitness, planned.targets[0].no_go_reason());
    assert!(!planned.targets[0].go(), "a shot that does not fit its model must not go");
}

#[test]
fn box_pierce_from_the_tilted_shot() {
    let errors = pierce_shot(reference_box(), "box_seed1_shot_tilt30", true);
    // [recorded hand-eye mm, deg, true hand-eye mm, deg]; the recorded hand-eye is about 3 mm / 0.3 deg off
    let top = errors[0].1;
    assert!(top[2] <= 2.5 && top[3] <= 1.0, "top-centre with the true hand-eye: {top:?}");
    // the recorded hand-eye, refined from the scan and the shot's views: measured 1.71 mm (before the
    // refinement: up to 4 mm)
    assert!(top[0] <= 2.5 && top[1] <= 1.0, "top-centre with the recorded hand-eye: {top:?}");
    let side = errors[1].1;
    assert_eq!(errors[1].0, "side-centre");
    // measured 2.16 (true) / 1.79 mm (recorded hand-eye, refined); 36-39 mm before the floor edge
    assert!(side[2] <= 2.5 && side[3] <= 1.0, "side-centre with the true hand-eye: {side:?}");
    assert!(side[0] <= 2.5 && side[1] <= 1.0, "side-centre with the recorded hand-eye: {side:?}");
}

#[test]
fn shell_pierce_from_the_tilted_shot() {
    let errors = pierce_shot(reference_shell(), "shell_seed1_shot_tilt30", false);
    // the groove: measured 1.45 mm / 0.08 deg (true hand-eye); 2.46 mm / 0.42 deg with the recorded one
    // (2.55 mm / 0.49 deg before the hand-eye work): a shot view's own registration moves it more than
    // the refined hand-eye's gate allows, so the merged shot's fit is kept (0.91 mm / 0.07 deg when the
    // views are combined without the gate)
    for (name, e) in &errors {
        assert!(e[2] <= 3.0 && e[3] <= 1.0, "{name} with the true hand-eye: {e:?}");
        assert!(e[0] <= 3.0 && e[1] <= 1.0, "{name} with the recorded hand-eye: {e:?}");
    }
}

/// `shot` with only the views `keep` (in that order).
fn shot_views(shot: &Scan, keep: &[usize]) -> Scan {
    Scan { views: keep.iter().map(|&i| shot.views[i].clone()).collect(), ..shot.clone() }
}

/// Position and axis errors (mm, deg) and 95 % bounds of each target of `planned` against the shot's truth.
fn plan_errors(planned: &awl::pierce::PiercePlan, shot_truth: &Truth) -> Vec<[f64; 4]> {
    shot_truth
        .targets
        .iter()
        .zip(&planned.targets)
        .map(|(t, p)| {
            [
                (p.p_base - t.p_world.expect("p_world")).norm() * 1e3,
                p.prediction.position_bound_m * 1e3,
                p.axis_base.angle(&-t.n_world.expect("n_world")).to_degrees(),
                p.prediction.axis_bound_rad.to_degrees(),
            ]
        })
        .collect()
}

/// `awl plan-views --candidates` on the other simulator's view banks (issue 79): from the 2-view
/// shot, at most 4 of the bank's candidates; a pierce on views 0-1 and the picked ones is then more
/// accurate, as predicted, and its bounds hold. The candidate inside a clutter object (box flat, view
/// 16: its depth is empty) is left out by the shot's own depth.
#[test]
fn views_planned_from_a_bank_lower_the_error_as_predicted() {
    use awl::plan_views::file::read_candidates;
    use awl::plan_views::{PlanViewsParams, plan_after_pierce};
    let mut planned_errors = Vec::new();
    for (f, folder, face_centres) in [
        (reference_box(), "box_seed1_shot_flat_bank", true),
        (reference_shell(), "shell_seed1_shot_tilt30_bank", false),
    ] {
        let dir = shared_data().join("sim_reference").join(folder);
        let (bank, bank_truth) = (read_scan(&dir).expect("shot"), read_truth(&dir).expect("truth"));
        let candidates = read_candidates(&dir.join("bank.json")).expect("bank.json");
        let wp = workpiece_from_fuse(&f.scan, &f.out, "model.ply", &WorkpieceParams::default())
            .expect("workpiece")
            .expect("tag");
        let world_from_tag = wp.world_from_tag.expect("T_world_tag");
        let kind = if face_centres { SceneKind::Box } else { SceneKind::Shell };
        let specs: Vec<TargetSpec> =
            bank_truth.targets.iter().map(|t| pick_target(kind, t, &f.outcome.object_from_model)).collect();
        let surface = SurfaceModel::new(&f.out.model).expect("index").with_floor(wp.floor);
        let pierce = |shot: &Scan| {
            let prior = HandEyePrior::of_workpiece(wp.hand_eye.as_ref(), shot).expect("prior");
            let params =
                PierceParams { locate: LocateParams::with_refinement(), hand_eye: prior, ..PierceParams::default() };
            (plan(&surface, &wp.tag, &world_from_tag, shot, &specs, &params).expect("plan"), params)
        };
        let two = shot_views(&bank, &[0, 1]);
        let (first, params) = pierce(&two);
        let tolerance = awl::pierce::Tolerance { position_m: Some(0.0015), axis_rad: None };
        let views = plan_after_pierce(
            &first,
            &params,
            &two,
            &f.out.model,
            None,
            &candidates,
            &PlanViewsParams { tolerance, ..PlanViewsParams::default() },
        )
        .expect("plan views");
        let picked: Vec<usize> =
            views.chosen.iter().map(|c| candidates[c.candidate].view.expect("bank view")).collect();
        let worst = |b: &[(f64, f64)]| b.iter().map(|x| x.0 * 1e3).fold(0.0, f64::max);
        let after = views.chosen.last().map_or(&views.before, |c| &c.bounds);
        println!(
            "{folder}: picked {picked:?} ({}); predicted worst {:.2} -> {:.2} mm; left out {:?}",
            views.stop,
            worst(&views.before),
            worst(after),
            views.left_out
        );
        assert!(!picked.is_empty() && picked.len() <= 4, "{picked:?}");
        // measured 4.29 -> 1.72 mm (box), 4.10 -> 1.78 mm (shell)
        assert!(worst(after) < 0.5 * worst(&views.before), "{:?} -> {after:?}", views.before);
        if face_centres {
            let inside = candidates.iter().position(|c| c.view == Some(16)).expect("view 16");
            let why = views.left_out.iter().find(|(i, _)| *i == inside).map(|(_, w)| w.as_str()).unwrap_or("");
            assert!(why.contains("something is there"), "bank view 16 (inside clutter) must be left out: {why:?}");
        }
        let keep: Vec<usize> = [0, 1].into_iter().chain(picked.iter().copied()).collect();
        let (before, after) =
            (plan_errors(&first, &bank_truth), plan_errors(&pierce(&shot_views(&bank, &keep)).0, &bank_truth));
        for (b, a) in before.iter().zip(&after) {
            println!(
                "  2 views: {:.2} mm (bound {:.2}), axis {:.2} deg ({:.2}); with the planned: {:.2} mm ({:.2}), {:.2} deg ({:.2})",
                b[0], b[1], b[2], b[3], a[0], a[1], a[2], a[3]
            );
            // the bounds hold, and the planned views' bound is the one plan-views predicted (within 25 %)
            assert!(a[0] <= a[1] && a[2] <= a[3] && b[0] <= b[1] && b[2] <= b[3], "{b:?} {a:?}");
            assert!(a[1] <= 1.25 * worst(views.chosen.last().map_or(&views.before, |c| &c.bounds)), "{a:?}");
        }
        planned_errors.extend(after.iter().map(|a| a[0]));
    }
    let mean = planned_errors.iter().sum::<f64>() / planned_errors.len() as f64;
    let max = planned_errors.iter().copied().fold(0.0, f64::max);
    println!("with the planned views: {mean:.2} mm mean, {max:.2} mm max");
    // issue 79's acceptance: mean <= 1.2 mm, max <= 2.5 mm (measured 0.77 / 0.82 mm; from the 2 views: 1.03 / 1.16)
    assert!(mean <= 1.2 && max <= 2.5, "{planned_errors:?}");
}
