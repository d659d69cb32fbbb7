//! Issue 54's real-data failures, made on purpose in simulation: a symmetric workpiece seen from an
//! arm (a cylinder alone on the floor, `SimParams::bare`: nothing constrains the views' spin about
//! its axis), and a recorded hand-eye 1 deg / 5 mm off.
//!
//! Numbers measured at the commit that added them (seed 1): see each assertion.
#![cfg(feature = "sim")]

mod common;

use awl::io::scan::read_scan;
use awl::pipeline::{FuseConfig, FuseOutput, ViewStatus, fuse};
use awl::registration::MotionKind;
use awl::sim::{SceneKind, SimParams, Simulation, simulate, write_simulation};
use awl::transform::pose_difference;
use nalgebra::{Isometry3, Point3};

fn fuse_with(sim: &Simulation, config: &FuseConfig) -> FuseOutput {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("scan");
    write_simulation(&path, sim, false).expect("write");
    let scan = read_scan(&path).expect("read");
    fuse(&scan, config, &|_, _, _| {}).expect("fuse")
}

fn bare_cylinder() -> Simulation {
    simulate(&SimParams { bare: true, ..SimParams::scan(SceneKind::Cylinder) }).expect("simulate")
}

/// `sim` with its recorded hand-eye replaced by the true one moved 1 deg and 5 mm.
fn with_hand_eye_off(mut sim: Simulation) -> Simulation {
    sim.scan.ee_from_camera = Some(common::hand_eye_off(&sim.truth.ee_from_camera.expect("true hand-eye"), 1.0, 5.0));
    sim
}

/// The hand-eye error of the refined `T_ee_camera` (mm, deg) and the report's sigmas.
fn refined_error(sim: &Simulation, out: &FuseOutput) -> ((f64, f64), f64) {
    let he = out.report.hand_eye.as_ref().expect("hand-eye report");
    let refined = awl::transform::isometry_from_rows(he.refined.as_ref().expect("refined")).expect("rigid");
    let (t, r) = pose_difference(&refined, &sim.truth.ee_from_camera.expect("truth"));
    ((t * 1e3, r.to_degrees()), he.prior_sigmas)
}

#[test]
fn a_cylinder_alone_holds_its_spin_at_the_seed_and_reports_it() {
    let sim = bare_cylinder();
    let out = fuse_with(&sim, &FuseConfig::default());
    let views = &out.report.views;
    let anchor = views.iter().position(|v| v.status == ViewStatus::Anchor).expect("anchor");
    // the model frame in the true world: the anchor view's recorded pose is exact there
    let world_from_model = sim.truth.views[anchor].world_from_camera * out.poses[anchor].expect("anchor").inverse();
    let axis_point = sim.truth.world_from_object * Point3::new(0.15, 0.15, 0.0);
    let mut held = 0;
    for (i, v) in views.iter().enumerate().filter(|(i, _)| *i != anchor) {
        // every view is merged (without the hold: 1 of 11, below)
        assert_eq!(v.status, ViewStatus::Accepted, "view {i}: {}", v.reason);
        // one direction is unobserved: the spin about the cylinder's (vertical) axis
        assert_eq!(v.unobserved.len(), 1, "view {i}: {:?}", v.unobserved);
        let u = &v.unobserved[0];
        assert_eq!(u.kind, MotionKind::Rotation, "view {i}");
        assert!(u.axis[2].abs() > 0.999, "view {i}: axis {:?}", u.axis);
        let on_axis = world_from_model * Point3::from(u.point);
        let off = ((on_axis - axis_point).xy()).norm();
        // measured 0.4-3.6 cm (where a partial view's spin axis falls)
        assert!(off < 0.05, "view {i}: the axis passes {:.1} cm from the cylinder's", off * 100.0);
        // held at the seed: the registered pose turned about the vertical as the seed did
        // (measured: equal to 0.01 deg), while its other rotation errors are gone (< 0.15 deg)
        let seed = v.seed.as_ref().map(|r| awl::transform::isometry_from_rows(r).expect("rigid")).expect("seed");
        let pose = out.poses[i].expect("pose");
        let truth = world_from_model.inverse() * sim.truth.views[i].world_from_camera;
        let spin = |p: &Isometry3<f64>| (p * truth.inverse()).rotation.scaled_axis();
        let (at_seed, registered) = (spin(&seed), spin(&pose));
        assert!((registered.z - at_seed.z).abs().to_degrees() < 0.02, "view {i}: {at_seed:?} -> {registered:?}");
        assert!(registered.xy().norm().to_degrees() < 0.15, "view {i}: tilt error {registered:?}");
        held += 1;
    }
    assert_eq!(held, 11);
    // the hand-eye left the spins out of its evidence
    assert_eq!(out.report.hand_eye.as_ref().expect("hand-eye").unobserved_left_out, 11);
    // without the hold (the rule before issue 54 item 6) the views slide and are rejected
    let mut free = FuseConfig::default();
    free.registration.icp.unobserved_ratio = 0.0;
    let slid = fuse_with(&sim, &free);
    let accepted = slid.report.views.iter().filter(|v| v.status == ViewStatus::Accepted).count();
    assert!(accepted <= 3, "{accepted} views accepted without the hold (measured 0)");
}

#[test]
fn a_hand_eye_1_deg_5_mm_off_is_detected_and_its_rotation_corrected() {
    // the box: the sim's own recorded hand-eye (about 2.5 mm / 0.3 deg off) raises no warning ...
    let sim = simulate(&SimParams::scan(SceneKind::Box)).expect("simulate");
    let out = fuse_with(&sim, &FuseConfig::default());
    let (_, sigmas) = refined_error(&sim, &out);
    assert!(sigmas < 3.0, "{sigmas:.2} sigma (measured 1.48)");
    assert!(out.report.hand_eye.as_ref().expect("hand-eye").warning.is_empty());
    // ... one 1 deg / 5 mm off is flagged and its rotation brought within a third
    let off = with_hand_eye_off(sim);
    let out = fuse_with(&off, &FuseConfig::default());
    let ((mm, deg), sigmas) = refined_error(&off, &out);
    println!("box seed 1, 12 views: refined {mm:.2} mm {deg:.3} deg from the truth, {sigmas:.2} sigma");
    assert!(sigmas > awl::pipeline::hand_eye::WRONG_PRIOR_SIGMAS, "{sigmas:.2} sigma (measured 4.79)");
    assert!(out.report.warnings.iter().any(|w| w.contains("recalibrate")), "{:?}", out.report.warnings);
    // 12 views, 2 a stop: measured 0.111 deg, and the translation only to 1.87 mm (3.03 mm with a
    // Gaussian prior): six within-stop pairs carry the arm's 0.6 mm / 0.06 deg a view, and even the
    // true camera motions with the recorded flange poses give 3.9 mm (seeds 2-4: 4.1-5.5 mm); the
    // 36-view scans below, like the real sets (28 and 50 views), reach a third
    assert!(deg < 1.0 / 3.0, "rotation {deg:.3} deg");
    assert!(mm < 2.5, "translation {mm:.2} mm");
    // the same on the cylinder alone, from its observed directions only
    let off = with_hand_eye_off(bare_cylinder());
    let out = fuse_with(&off, &FuseConfig::default());
    let ((mm, deg), sigmas) = refined_error(&off, &out);
    println!("cylinder alone, 12 views: refined {mm:.2} mm {deg:.3} deg from the truth, {sigmas:.2} sigma");
    assert!(sigmas > awl::pipeline::hand_eye::WRONG_PRIOR_SIGMAS, "{sigmas:.2} sigma");
    // measured 0.139 deg, 2.62 mm (0.197 deg, 3.53 mm with a Gaussian prior)
    assert!(deg < 1.0 / 3.0 && mm < 3.5, "{mm:.2} mm, {deg:.3} deg");
}

#[test]
fn a_hand_eye_1_deg_5_mm_off_is_corrected_from_a_36_view_scan() {
    // the real sets that slid held 28 and 50 views; here 36 from 6 stops (6 a stop). Over box,
    // shell and cylinder seeds 1-6 (measured): 16 of 18 within a third (0.57-1.63 mm), shell 3 and
    // cylinder 3 at 1.97 and 1.96 mm; rotation 0.011-0.153 deg. One of each kind here.
    for (scene, seed, within_mm) in [(SceneKind::Box, 3, 5.0 / 3.0), (SceneKind::Shell, 3, 2.2)] {
        let sim = simulate(&SimParams { views: 36, seed, ..SimParams::scan(scene) }).expect("simulate");
        let off = with_hand_eye_off(sim);
        let out = fuse_with(&off, &FuseConfig::default());
        let ((mm, deg), sigmas) = refined_error(&off, &out);
        let he = out.report.hand_eye.as_ref().expect("hand-eye");
        println!(
            "{scene:?} seed {seed}: refined {mm:.2} mm {deg:.3} deg from the truth, {sigmas:.2} sigma, prior weight {:.2}",
            he.prior_weight
        );
        assert!(sigmas > awl::pipeline::hand_eye::WRONG_PRIOR_SIGMAS, "{scene:?} seed {seed}: {sigmas:.2} sigma");
        // the data outweigh the prior they contradict (the t tail; measured 0.36, 0.35)
        assert!(he.prior_weight < 0.6, "{scene:?} seed {seed}: prior weight {}", he.prior_weight);
        // measured: box 3 1.36 mm 0.068 deg, shell 3 1.97 mm 0.153 deg
        assert!(mm < within_mm && deg < 1.0 / 3.0, "{scene:?} seed {seed}: {mm:.2} mm {deg:.3} deg");
    }
}

/// The worst registered view of `out` against the truth, camera position (mm): the model frame
/// placed in the true world by the anchor view.
fn worst_view_mm(sim: &Simulation, out: &FuseOutput) -> (usize, f64) {
    let anchor = out.report.views.iter().position(|v| v.status == ViewStatus::Anchor).expect("anchor");
    let world_from_model = sim.truth.views[anchor].world_from_camera * out.poses[anchor].expect("anchor").inverse();
    (out.poses.iter().enumerate())
        .filter_map(|(i, pose)| {
            let truth = sim.truth.views[i].world_from_camera.translation.vector;
            Some((i, ((world_from_model * (*pose)?).translation.vector - truth).norm() * 1e3))
        })
        .fold((0, 0.0), |worst, v| if v.1 > worst.1 { v } else { worst })
}

#[test]
fn views_seeded_from_their_stop_do_not_split_the_model() {
    // Box seed 7 seeded by the recorded poses alone: view 5's seed (29, 15, -15) mm off, its ICP
    // from there slid 30 mm along a face at the 10 cm gate, and views 6-10 followed: half the
    // model 17.6-20.1 mm from the other half (completeness@5mm 81.9 %, 16.5 % off the object).
    // Seeded from view 4 (same stop) and the arm's motion, view 5 starts 4.3 mm off and stays.
    // Box seed 16: view 3, the first of its stop, slid 27 mm / 1.9 deg from its SLAM seed and
    // views 4-5 followed; the joint refinement brings them back at a 20 mm gate (12 mm: 12.4 mm
    // too far, its poses dropped). Measured (worst view, hand-eye from the truth): seed 7 1.61 mm,
    // 2.77 mm / 0.045 deg (recorded 2.64 mm / 0.319 deg); seed 16 2.82 mm, 0.65 mm / 0.051 deg
    // (recorded 2.56 mm / 0.289 deg). 12 views bound the hand-eye's translation at about 2.2 mm RMS
    // (bench/handeye_bound).
    for (seed, max_view_mm) in [(7, 2.5), (16, 4.0)] {
        let sim = simulate(&SimParams { seed, ..SimParams::scan(SceneKind::Box) }).expect("simulate");
        let out = fuse_with(&sim, &FuseConfig::default());
        let (view, mm) = worst_view_mm(&sim, &out);
        assert!(mm < max_view_mm, "seed {seed}: view {view} {mm:.2} mm from its true pose");
        let seeded: Vec<Option<usize>> = out.report.views.iter().map(|v| v.seeded_from_view).collect();
        // one view of each of the 6 stops of 2 views seeds the other
        assert_eq!(seeded.iter().flatten().count(), 6, "seed {seed}: {seeded:?}");
        let he = out.report.hand_eye.as_ref().expect("hand-eye");
        assert!(he.stops_rejected.is_empty(), "seed {seed}: {:?}", he.stops_rejected);
        let refined = awl::transform::isometry_from_rows(he.refined.as_ref().expect("refined")).expect("rigid");
        let (t, r) = pose_difference(&refined, &sim.truth.ee_from_camera.expect("truth"));
        assert!(t < 0.0035 && r.to_degrees() < 0.1, "seed {seed}: {} mm {} deg", t * 1e3, r.to_degrees());
    }
}

#[test]
fn a_scan_whose_registration_split_leaves_the_split_stops_out_of_the_hand_eye() {
    // box seed 7 registered as before the stop seeds (`registration.stop_seed_gate_m = false`, the
    // joint refinement's first gate 12 mm and its levels stopped at 30 iterations): half the views
    // (5-10) registered 17.6-20.1 mm from where the others put them (a slide between two groups of
    // views); stops 2 and 5 hold a view on each side. Measured: they are left out (views'
    // residuals 3.6x the noise model with them), the refined hand-eye 2.43 mm / 0.053 deg from the
    // truth (9.42 mm / 0.137 deg with them; recorded 2.64 mm / 0.319 deg), the disagreement 18.5-19 mm
    let sim = simulate(&SimParams { seed: 7, ..SimParams::scan(SceneKind::Box) }).expect("simulate");
    let mut config = FuseConfig::default();
    config.registration.stop_seed_gate_m = None;
    for level in &mut config.registration.joint_levels {
        level.max_iterations = 30;
    }
    config.registration.joint_levels[0].max_correspondence_m = 0.012;
    let out = fuse_with(&sim, &config);
    assert!(worst_view_mm(&sim, &out).1 > 15.0, "the split: {:?}", worst_view_mm(&sim, &out));
    let he = out.report.hand_eye.as_ref().expect("hand-eye");
    assert_eq!(he.stops_rejected, vec![5, 2], "{:?}", he.stops_rejected);
    assert!(
        he.rejected_disagreement_mm > 15.0 && he.rejected_disagreement_mm < 25.0,
        "{}",
        he.rejected_disagreement_mm
    );
    assert!(
        out.report.warnings.iter().any(|w| w.contains("left out") && w.contains("[5, 2]")),
        "{:?}",
        out.report.warnings
    );
    let refined = awl::transform::isometry_from_rows(he.refined.as_ref().expect("refined")).expect("rigid");
    let (t, r) = pose_difference(&refined, &sim.truth.ee_from_camera.expect("truth"));
    println!(
        "box seed 7: refined {:.2} mm {:.3} deg, disagreement {:.1} mm",
        t * 1e3,
        r.to_degrees(),
        he.rejected_disagreement_mm
    );
    assert!(t < 0.003 && r.to_degrees() < 0.1, "{} mm {} deg", t * 1e3, r.to_degrees());
    assert!(he.warning.is_empty(), "{}", he.warning);
}

/// Issue 73: a fixed arm's scan is one base stop; every pair of its views is an `A X = X B` equation
/// all the same. A box seen by a fixed arm (`SimParams::fixed_base`, 30 views over 140 deg): with the
/// true hand-eye no warning; with the recorded one 1 deg / 5 mm off, a warning and the refined one
/// within a third of that error.
#[test]
fn a_fixed_arm_s_hand_eye_is_checked_from_its_one_stop() {
    let sim =
        simulate(&SimParams { views: 30, fixed_base: true, ..SimParams::scan(SceneKind::Box) }).expect("simulate");
    // the hand-eye report of a fuse of `sim` and the refined hand-eye's error (mm, deg)
    let refine = |sim: &Simulation, name: &str| {
        let out = fuse_with(sim, &FuseConfig::default());
        let ((mm, deg), sigmas) = refined_error(sim, &out);
        let he = out.report.hand_eye.expect("hand-eye");
        println!(
            "fixed arm, {name}: refined {mm:.2} mm {deg:.3} deg, {sigmas:.2} sigma, scale {:.2}",
            he.residual_scale
        );
        (he, mm, deg)
    };
    let mut exact = sim.clone();
    exact.scan.ee_from_camera = sim.truth.ee_from_camera;
    let (he, _, _) = refine(&exact, "true hand-eye");
    assert!(he.refused.is_empty() && he.warning.is_empty(), "{} {}", he.refused, he.warning);
    assert_eq!(he.stops_used.len(), 1);
    let (he, mm, deg) = refine(&with_hand_eye_off(sim), "1 deg / 5 mm off");
    assert!(he.warning.contains("recalibrate"), "{}", he.warning);
    assert!(mm < 5.0 / 3.0 && deg < 1.0 / 3.0, "{mm:.2} mm {deg:.3} deg");
}
