//! Hand-eye calibration captures with images (`awl::sim::capture`, `awl simulate --capture`) against
//! their own truth and against what we did not write: awl's AprilTag detector and pupil-apriltags
//! (`tests/py/check_tags.py` with `$AWL_PYTHON`; skipped with a message only when it is unset) find
//! the tag at truth.json's corners; the board's depth lies on the true board plane; and the detected
//! tag poses (the planar ambiguity resolved by depth, never by the truth) with the recorded
//! `T_base_ee` calibrate `T_ee_camera` to the truth through `awl::handeye::calibrate`.
//!
//! Run in release: `cargo test --release -p awl --test sim_capture -- --nocapture` to see the numbers.
#![cfg(all(feature = "sim", feature = "apriltag"))]

mod common;
mod tags_common;

use std::path::Path;
use std::process::Command;
use std::sync::OnceLock;

use awl::camera::{DepthCamera, depth_to_cloud};
use awl::handeye::{HandEyeParams, HandEyePose, calibrate};
use awl::io::scan::read_scan;
use awl::io::truth::read_truth;
use awl::scan::ViewPose;
use awl::sim::capture::{CaptureParams, simulate_capture};
use awl::sim::{LABEL_WORKPIECE, NoiseLevel, Simulation, axial_sigma_m, rig_ee_from_camera, write_simulation};
use awl::tag::{TagDetector, estimate_tag_pose, score_depth};
use awl::transform::pose_difference;
use nalgebra::{Isometry3, Point2, Point3, Vector3};
use serde_json::Value;
use tags_common::{detector, stats};

/// The default capture: 20 views, tag36h11 id 7 of 14 cm, realistic noise, seed 1.
fn realistic() -> &'static Simulation {
    static CELL: OnceLock<Simulation> = OnceLock::new();
    CELL.get_or_init(|| simulate_capture(&CaptureParams::default()).expect("capture"))
}

fn camera(sim: &Simulation) -> DepthCamera {
    sim.scan.camera.expect("a capture has a camera")
}

/// truth.json's `views[i].tag_corners_px`.
fn truth_corners(sim: &Simulation, i: usize) -> [[f64; 2]; 4] {
    let v = sim.truth.views[i].extra.get("tag_corners_px").expect("tag_corners_px");
    let c: Vec<[f64; 2]> =
        v.as_array().expect("corners").iter().map(|p| [p[0].as_f64().expect("u"), p[1].as_f64().expect("v")]).collect();
    c.try_into().expect("4 corners")
}

/// Half the board's front face less 5 mm, metres (the default 14 cm tag's 28 cm board).
const INNER_HALF_M: f64 = 0.135;

fn recorded_base_from_ee(sim: &Simulation, i: usize) -> Isometry3<f64> {
    match &sim.scan.views[i].pose {
        ViewPose::Chain { base_from_ee, .. } => *base_from_ee,
        ViewPose::Camera { .. } => panic!("view {i}: a capture records T_base_ee"),
    }
}

fn corner_errors(a: &[[f64; 2]; 4], b: &[[f64; 2]; 4]) -> [f64; 4] {
    std::array::from_fn(|k| ((a[k][0] - b[k][0]).powi(2) + (a[k][1] - b[k][1]).powi(2)).sqrt())
}

#[test]
fn the_capture_records_what_the_rig_would_and_its_truth() {
    let sim = realistic();
    let tag = sim.scan.tag.clone().expect("scan.json names the tag");
    assert_eq!((tag.family.as_str(), tag.id, tag.size_m), ("tag36h11", 7, 0.14));
    assert_eq!(sim.views.len(), 20);
    let truth_he = sim.truth.ee_from_camera.expect("true T_ee_camera");
    assert_eq!(truth_he, rig_ee_from_camera(), "the rig's hand-eye by default");
    let (dt, dr) = pose_difference(&truth_he, &sim.scan.ee_from_camera.expect("recorded T_ee_camera"));
    println!("recorded T_ee_camera off the truth: {:.2} mm, {:.3} deg", dt * 1e3, dr.to_degrees());
    // rig::hand_eye_error: 3 mm and 0.3 deg, each times 0.8-1.2 (measured 2.47 mm, 0.342 deg)
    assert!((0.0024..=0.0036).contains(&dt) && (0.24..=0.36).contains(&dr.to_degrees()), "{dt} {dr}");
    let (mut arm_mm, mut arm_deg) = (Vec::new(), Vec::new());
    for (i, (spec, truth)) in sim.scan.views.iter().zip(&sim.truth.views).enumerate() {
        let ViewPose::Chain { world_from_base, base_from_ee } = &spec.pose else { panic!("view {i}: chain pose") };
        assert_eq!(*world_from_base, Isometry3::identity(), "world = robot base");
        let true_ee = truth.base_from_ee.expect("true T_base_ee");
        let d = true_ee.inverse() * base_from_ee;
        arm_mm.extend(d.translation.vector.iter().map(|v| v * 1e3));
        arm_deg.extend(d.rotation.scaled_axis().iter().map(|v| v.to_degrees()));
        // the true camera is the true flange times the true hand-eye
        let (t, r) = pose_difference(&truth.world_from_camera, &(true_ee * truth_he));
        assert!(t < 1e-12 && r < 1e-12, "view {i}");
    }
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
    let (rms_mm, rms_deg) = (rms(&arm_mm), rms(&arm_deg));
    println!("arm error per axis: {rms_mm:.3} mm, {rms_deg:.4} deg RMS (model 0.6 mm, 0.06 deg)");
    // 60 draws each: the RMS of 60 normals is within +-25 % of sigma far beyond 3 sigma (measured
    // 0.560 mm, 0.0612 deg)
    assert!((0.45..=0.75).contains(&rms_mm) && (0.045..=0.075).contains(&rms_deg), "{rms_mm} {rms_deg}");
    // the board: a 28 cm square card, 1 cm thick, front face on the tag plane (object = tag frame)
    let world_from_tag = sim.truth.world_from_tag.expect("T_world_tag");
    assert_eq!(sim.truth.world_from_object, world_from_tag);
    let xs: Vec<f64> = sim.cad.vertices.iter().map(|p| p.x).collect();
    let zs: Vec<f64> = sim.cad.vertices.iter().map(|p| p.z).collect();
    let span = |v: &[f64]| v.iter().copied().fold(f64::MIN, f64::max) - v.iter().copied().fold(f64::MAX, f64::min);
    assert!((span(&xs) - 0.28).abs() < 1e-12 && (span(&zs) - 0.01).abs() < 1e-12);
    assert!(zs.iter().all(|z| *z <= 0.0));
    // diverse views: the flange rotates by tens of degrees between views
    let rotations: Vec<f64> = (1..sim.views.len())
        .map(|i| pose_difference(&recorded_base_from_ee(sim, 0), &recorded_base_from_ee(sim, i)).1.to_degrees())
        .collect();
    let max_rotation = rotations.iter().copied().fold(0.0, f64::max);
    println!("flange rotation from view 0: up to {max_rotation:.1} deg");
    assert!(max_rotation > 30.0, "{rotations:?}"); // measured 69.6 deg
}

#[test]
fn a_seed_gives_the_same_capture_and_another_seed_another() {
    let p = CaptureParams { views: 3, noise: NoiseLevel::Low, ..CaptureParams::default() };
    let a = simulate_capture(&p).expect("capture");
    assert_eq!(a, simulate_capture(&p).expect("capture"));
    let b = simulate_capture(&CaptureParams { seed: 2, ..p }).expect("capture");
    assert_ne!(a.truth.views[0].world_from_camera, b.truth.views[0].world_from_camera);
    assert_ne!(a.views[0].color, b.views[0].color);
    let e = simulate_capture(&CaptureParams { tag_id: 10, ..p }).expect_err("id 10 is not embedded").to_string();
    assert!(e.contains("tag id") && e.contains("0 to 9"), "{e}");
}

#[test]
fn detected_corners_are_the_truth_corners_in_every_view() {
    let sim = realistic();
    let mut detector = detector();
    let mut errors = Vec::new();
    for i in 0..sim.views.len() {
        let found = detector.detect_color(&sim.views[i].color).expect("detect");
        let ids: Vec<u32> = found.iter().map(|d| d.id).collect();
        assert_eq!(ids, vec![7], "view {i}: the board's tag, once, nothing else");
        assert_eq!(found[0].hamming, 0, "view {i}");
        let e = corner_errors(&found[0].corners_px, &truth_corners(sim, i));
        // measured: max 0.408 px over the 80 corners
        assert!(e.iter().all(|e| *e < 1.0), "view {i}: corner errors {e:?} px");
        errors.extend(e);
    }
    let (median, max) = stats(&mut errors);
    println!("awl detector vs truth corners over {} corners: median {median:.3} px, max {max:.3} px", errors.len());
    assert!(median < 0.3, "{median}"); // measured 0.225 px
}

#[test]
fn the_board_depth_lies_on_the_true_board_plane() {
    // noiseless: only the 1 mm quantisation along z is left
    let exact = simulate_capture(&CaptureParams { views: 4, noise: NoiseLevel::None, ..CaptureParams::default() })
        .expect("capture");
    for (name, sim) in [("none", &exact), ("realistic", realistic())] {
        let cam = camera(sim);
        let world_from_tag = sim.truth.world_from_tag.expect("T_world_tag");
        let (mut offsets, mut model) = (Vec::new(), Vec::new());
        let mut board_pixels = 0;
        for (i, view) in sim.views.iter().enumerate() {
            let tag_from_camera = world_from_tag.inverse() * sim.truth.views[i].world_from_camera;
            let normal_camera = tag_from_camera.inverse().rotation * Vector3::z();
            let (w, h) = (view.depth.width as usize, view.depth.height as usize);
            for v in 0..h {
                for u in 0..w {
                    let k = v * w + u;
                    if view.labels.data[k] != LABEL_WORKPIECE {
                        continue;
                    }
                    board_pixels += 1;
                    let z = f64::from(view.depth.data[k]) * cam.depth_scale;
                    let n = cam.intrinsics.ray(&Point2::new(u as f64, v as f64));
                    let p = Point3::new(n.x * z, n.y * z, z);
                    let q = tag_from_camera * p;
                    // the front face only (the board's 1 cm edges are labelled board too)
                    if q.x.abs() > INNER_HALF_M || q.y.abs() > INNER_HALF_M {
                        continue;
                    }
                    offsets.push(q.z);
                    let cos = normal_camera.dot(&p.coords.normalize()).abs();
                    model.push(axial_sigma_m(z, cos, 1.0) * cos);
                }
            }
        }
        assert!(board_pixels > 20 * 10_000 * sim.views.len() / 20, "{name}: {board_pixels} board pixels");
        let (median, max) = stats(&mut offsets.iter().map(|d| d.abs()).collect::<Vec<_>>());
        let mut signed = offsets.clone();
        signed.sort_by(f64::total_cmp);
        let centre = signed[signed.len() / 2];
        let mut deviation: Vec<f64> = offsets.iter().map(|d| (d - centre).abs()).collect();
        let sigma = 1.4826 * stats(&mut deviation).0;
        let expected = stats(&mut model).0;
        println!(
            "{name}: {} board points, |distance to the board plane| median {:.3} mm, max {:.2} mm; signed median {:.3} mm, robust sigma {:.3} mm (model median {:.3} mm)",
            offsets.len(),
            median * 1e3,
            max * 1e3,
            centre * 1e3,
            sigma * 1e3,
            expected * 1e3
        );
        if name == "none" {
            // 0.5 mm along z is at most 0.5 mm * |(x/z, y/z, 1)| <= 0.63 mm from the plane in a 640x480, f 615 image
            assert!(max <= 0.00063, "{name}: {max}"); // measured 0.53 mm
        } else {
            // the 0.1 % depth-scale error moves the median by under 1 mm at 0.35-0.7 m
            assert!(centre.abs() < 0.001, "{name}: {centre}"); // measured -0.29 mm
            // measured 1.303 mm against the model's 1.207 mm (lateral jitter on the tilted board adds a little)
            assert!(sigma > 0.7 * expected && sigma < 1.4 * expected, "{name}: {sigma} vs {expected}");
        }
    }
}

fn view_corners_pupil(python: &str, dir: &Path, sim: &Simulation) -> Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/py/check_tags.py");
    let mut cmd = Command::new(python);
    cmd.arg(script).args(["--decimate", "1"]);
    for i in 0..sim.views.len() {
        cmd.arg(dir.join(format!("color/{i:06}.png")));
    }
    let out = cmd.output().unwrap_or_else(|e| panic!("cannot run {python}: {e}"));
    assert!(out.status.success(), "check_tags.py failed: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("check_tags.py prints JSON")
}

#[test]
fn pupil_apriltags_finds_the_tag_at_the_truth_corners_in_the_written_pngs() {
    let Ok(python) = std::env::var("AWL_PYTHON") else {
        println!("SKIPPED: AWL_PYTHON is not set (a Python with pupil-apriltags, see tests/py/requirements.txt)");
        return;
    };
    let sim = realistic();
    let parent = tempfile::tempdir().expect("tempdir");
    let dir = parent.path().join("capture");
    write_simulation(&dir, sim, false).expect("write");
    // the folder reads back: scan.json's tag and poses, truth.json's per-view corners
    let scan = read_scan(&dir).expect("scan.json");
    assert_eq!(scan.tag, sim.scan.tag);
    assert_eq!(scan.views.len(), 20);
    let truth = read_truth(&dir).expect("truth.json");
    assert_eq!(truth.views[3].extra.get("tag_corners_px"), sim.truth.views[3].extra.get("tag_corners_px"));
    let reference = view_corners_pupil(&python, &dir, sim);
    let images = reference["images"].as_object().expect("images");
    let mut errors = Vec::new();
    for i in 0..sim.views.len() {
        let path = dir.join(format!("color/{i:06}.png"));
        let found = images[path.to_str().expect("utf-8 path")].as_array().expect("detections");
        assert_eq!(found.len(), 1, "view {i}: {found:?}");
        assert_eq!(found[0]["id"].as_u64(), Some(7), "view {i}");
        let corners = found[0]["corners"].as_array().expect("corners");
        // the C library's pixel centres are at +0.5, truth's at integers
        let theirs: [[f64; 2]; 4] = std::array::from_fn(|k| {
            [corners[k][0].as_f64().expect("u") - 0.5, corners[k][1].as_f64().expect("v") - 0.5]
        });
        let e = corner_errors(&theirs, &truth_corners(sim, i));
        // measured: max 0.408 px over the 80 corners
        assert!(e.iter().all(|e| *e < 1.0), "view {i}: pupil-apriltags corner errors {e:?} px");
        errors.extend(e);
    }
    let (median, max) = stats(&mut errors);
    println!("pupil-apriltags vs truth corners over {} corners: median {median:.3} px, max {max:.3} px", errors.len());
    assert!(median < 0.3, "{median}"); // measured 0.225 px
}

#[test]
fn detected_tag_poses_calibrate_the_true_hand_eye() {
    let sim = realistic();
    let cam = camera(sim);
    let rays = cam.intrinsics.ray_table();
    let tag = sim.scan.tag.clone().expect("tag");
    let world_from_tag = sim.truth.world_from_tag.expect("T_world_tag");
    let mut detector = detector();
    let mut poses = Vec::new();
    // the same detections with the true T_base_ee: what the tag poses alone leave
    let mut true_arm = Vec::new();
    let (mut radial_px, mut range_mm) = (Vec::new(), Vec::new());
    let (mut flipped, mut pose_mm, mut pose_deg) = (0, Vec::new(), Vec::new());
    for (i, view) in sim.views.iter().enumerate() {
        let found = detector.detect_color(&view.color).expect("detect");
        let d = found.iter().find(|d| d.id == tag.id).unwrap_or_else(|| panic!("view {i}: tag not found"));
        let mut pose = estimate_tag_pose(&d.corners_px, &cam.intrinsics, tag.size_m).expect("tag pose");
        let cloud = depth_to_cloud(&view.depth, None, &cam, &rays);
        let scores = score_depth(&pose, &d.corners_px, &cam.intrinsics, &cloud.points);
        if scores.prefers_second() {
            pose = pose.swapped();
            flipped += 1;
        }
        // checked against the truth afterwards, never chosen by it
        let true_pose = sim.truth.views[i].world_from_camera.inverse() * world_from_tag;
        let (t, r) = pose_difference(&pose.best.camera_from_tag, &true_pose);
        pose_mm.push(t * 1e3);
        pose_deg.push(r.to_degrees());
        let truth_c = truth_corners(sim, i);
        let centre = [0, 1].map(|a| truth_c.iter().map(|c| c[a]).sum::<f64>() / 4.0);
        radial_px.extend((0..4).map(|k| {
            let (dx, dy) = (truth_c[k][0] - centre[0], truth_c[k][1] - centre[1]);
            ((d.corners_px[k][0] - truth_c[k][0]) * dx + (d.corners_px[k][1] - truth_c[k][1]) * dy)
                / (dx * dx + dy * dy).sqrt()
        }));
        range_mm
            .push((pose.best.camera_from_tag.translation.vector.norm() - true_pose.translation.vector.norm()) * 1e3);
        true_arm.push(HandEyePose {
            base_from_ee: sim.truth.views[i].base_from_ee.expect("true"),
            camera_from_target: pose.best.camera_from_tag,
        });
        poses.push(HandEyePose {
            base_from_ee: recorded_base_from_ee(sim, i),
            camera_from_target: pose.best.camera_from_tag,
        });
    }
    let (mm_median, mm_max) = stats(&mut pose_mm);
    let (deg_median, deg_max) = stats(&mut pose_deg);
    println!(
        "tag pose vs truth: median {mm_median:.2} mm / {deg_median:.3} deg, max {mm_max:.2} mm / {deg_max:.3} deg; {flipped} views flipped by depth"
    );
    // measured max 0.308 deg (the flipped solution would be tens of degrees off)
    assert!(deg_max < 2.0, "every view on the right side of the planar ambiguity: {deg_max} deg");
    let result = calibrate(&poses, &HandEyeParams::default()).expect("calibrate");
    let truth = sim.truth.ee_from_camera.expect("true T_ee_camera");
    let (t, r) = pose_difference(&result.ee_from_camera, &truth);
    let (t0, r0) = pose_difference(&sim.scan.ee_from_camera.expect("recorded"), &truth);
    println!(
        "calibrated T_ee_camera vs truth: {:.3} mm, {:.4} deg (recorded one: {:.2} mm, {:.3} deg); residual RMS {:.2} mm, {:.3} deg; rejected {:?}; warnings {:?}",
        t * 1e3,
        r.to_degrees(),
        t0 * 1e3,
        r0.to_degrees(),
        result.rms_translation_mm,
        result.rms_rotation_deg,
        result.rejected,
        result.warnings
    );
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let (radial, range) = (mean(&radial_px), mean(&range_mm));
    let only_tags = calibrate(&true_arm, &HandEyeParams::default()).expect("calibrate");
    let (ta, ra) = pose_difference(&only_tags.ee_from_camera, &truth);
    println!(
        "detected corners {radial:+.3} px radially from the truth on average (the tag seen small), tag range {range:+.2} mm; with the true T_base_ee: {:.3} mm, {:.4} deg",
        ta * 1e3,
        ra.to_degrees()
    );
    // Measured 1.21 mm, 0.122 deg (seeds 2 and 3: 1.07 mm / 0.034 deg, 1.21 mm / 0.071 deg): over the
    // issue's 1 mm. The rotation is well inside 0.2 deg; the translation is set by a bias of the tag
    // poses, not by the solver or the arm noise: the detected corners sit 0.21 px inside the true
    // ones (as expected where light is integrated over a pixel before the gamma: a half-covered edge
    // pixel is brighter than the mid-grey, so the black square looks small; not isolated here, but
    // the other simulator's calib_seed1 gives -0.16 px with pupil-apriltags too), so every tag range is
    // 0.98 mm long on average and the true T_base_ee still leave 0.97 mm (seeds 2, 3: 1.26, 1.20 mm).
    assert!(t < 0.0015 && r.to_degrees() < 0.2, "{} mm {} deg", t * 1e3, r.to_degrees());
    // the capture corrects the user's old calibration (2.47 mm, 0.342 deg off)
    assert!(t < 0.6 * t0 && r < 0.6 * r0, "{t} vs {t0}, {r} vs {r0}");
    assert!((-0.3..=-0.1).contains(&radial) && range > 0.0, "{radial} px, {range} mm"); // -0.213 px, +0.98 mm
    assert!(ta < 0.0015 && ra.to_degrees() < 0.1, "{ta} {ra}"); // 0.970 mm, 0.045 deg
    let (bt, br) = pose_difference(&result.base_from_target, &world_from_tag);
    println!("T_base_target vs truth: {:.2} mm, {:.3} deg", bt * 1e3, br.to_degrees());
}

#[test]
fn the_capture_calibration_corrects_the_corner_bias_to_within_1_mm() {
    // `awl calibrate hand-eye --capture` on simulated captures of 20 views, seeds 1-3: the detector's
    // corner bias (0.21 px inward, measured above) is estimated from the views' spread of depths
    // and taken out of the tag translations. Measured 0.908 / 0.743 / 0.435 mm and 0.117 / 0.036 /
    // 0.071 deg from the truth, biases 0.173 / 0.165 / 0.168 px (without: 1.208 / 1.068 / 1.205 mm)
    for seed in 1..=3 {
        let sim = simulate_capture(&CaptureParams { seed, ..CaptureParams::default() }).expect("capture");
        let dir = tempfile::tempdir().expect("tempdir");
        write_simulation(dir.path(), &sim, false).expect("write");
        let capture = awl::io::capture::read_capture(dir.path()).expect("read");
        let truth = sim.truth.ee_from_camera.expect("true T_ee_camera");
        // the views weighted alike, as when these were measured (weighted by their covariance:
        // tests/capture_bound.rs)
        let run = |corner_bias| {
            let params = awl::handeye::CaptureParams {
                corner_bias,
                view_weights: false,
                ..awl::handeye::CaptureParams::default()
            };
            awl::handeye::calibrate_capture(&capture, &params).expect("calibrate")
        };
        let (with, without) = (run(true), run(false));
        let (t, r) = pose_difference(&with.result.ee_from_camera, &truth);
        let (t0, _) = pose_difference(&without.result.ee_from_camera, &truth);
        let bias = with.corner_bias_px.expect("estimated");
        println!(
            "seed {seed}: {:.3} mm {:.4} deg from the truth, corner bias {bias:.3} px (without the correction {:.3} mm)",
            t * 1e3,
            r.to_degrees(),
            t0 * 1e3
        );
        assert!(t < 0.001 && r.to_degrees() < 0.2, "seed {seed}: {} mm {} deg", t * 1e3, r.to_degrees());
        assert!(t < t0, "seed {seed}: the correction moved it away from the truth: {t} vs {t0}");
        assert!((0.1..=0.25).contains(&bias), "seed {seed}: bias {bias} px (measured radially: 0.21 px)");
        assert!(without.corner_bias_px.is_none() && without.corner_bias_note.contains("off"));
        // depths that do not spread enough (here: a ratio asked for that the 0.36-0.69 m views lack)
        let params = awl::handeye::CaptureParams {
            corner_bias_min_depth_ratio: 3.0,
            view_weights: false,
            ..awl::handeye::CaptureParams::default()
        };
        let alike = awl::handeye::calibrate_capture(&capture, &params).expect("calibrate");
        assert!(alike.corner_bias_px.is_none(), "{:?}", alike.corner_bias_px);
        assert!(alike.corner_bias_note.contains("depths span"), "{}", alike.corner_bias_note);
        assert_eq!(alike.result.ee_from_camera, without.result.ee_from_camera);
        let nan =
            awl::handeye::CaptureParams { corner_bias_max_px: f64::NAN, ..awl::handeye::CaptureParams::default() };
        let e = awl::handeye::calibrate_capture(&capture, &nan).expect_err("a NaN search range");
        assert!(e.to_string().contains("corner_bias_max_px"), "{e}");
    }
}
