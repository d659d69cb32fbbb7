//! Hand-eye calibration from a capture folder of tag images (`awl::handeye::calibrate_capture`) on
//! the independent simulator's capture `shared/data/sim_reference/calib_seed1` (20 views, tag36h11
//! id 7, 14 cm; truth.json holds the true `T_ee_camera`, per view the true `T_world_camera` and
//! `T_base_ee`, and `T_world_tag`): the result against the truth, where its error comes from, the
//! flip by consistency when the depth images are hidden, and OpenCV's `calibrateHandEye` on the
//! same detections (`tests/py/check_handeye.py`, with `AWL_PYTHON`; skipped with a message without).
//!
//! Run in release: `cargo test --release -p awl --test handeye_capture`.
#![cfg(feature = "apriltag")]

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use awl::handeye::poses_file::write_poses;
use awl::handeye::{CaptureParams, FlipChoice, HandEyePose, HandEyeResult, calibrate, calibrate_capture};
use awl::io::capture::read_capture;
use awl::transform::{Rows, isometry_from_rows, pose_difference};
use nalgebra::Isometry3;
use serde_json::Value;

fn calib_dir() -> PathBuf {
    common::shared_data().join("sim_reference/calib_seed1")
}

fn json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).expect("read")).expect("json")
}

fn iso(v: &Value) -> Isometry3<f64> {
    let rows: Rows = serde_json::from_value(v.clone()).expect("4x4");
    isometry_from_rows(&rows).expect("rigid")
}

fn mm_deg(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    let (t, r) = pose_difference(a, b);
    (t * 1e3, r.to_degrees())
}

/// Copies the capture into `dst`; without `depth`, its depth images and `camera.depth_scale` are left out.
fn copy_capture(dst: &Path, depth: bool) {
    let src = calib_dir();
    std::fs::create_dir_all(dst.join("color")).expect("mkdir");
    let mut scan = json(&src.join("scan.json"));
    for view in scan["views"].as_array_mut().expect("views") {
        let color = view["color"].as_str().expect("color").to_string();
        std::fs::copy(src.join(&color), dst.join(&color)).expect("copy color");
        if depth {
            let d = view["depth"].as_str().expect("depth").to_string();
            std::fs::create_dir_all(dst.join("depth")).expect("mkdir");
            std::fs::copy(src.join(&d), dst.join(&d)).expect("copy depth");
        } else {
            view.as_object_mut().expect("view").remove("depth");
        }
    }
    if !depth {
        scan["camera"].as_object_mut().expect("camera").remove("depth_scale");
    }
    std::fs::write(dst.join("scan.json"), serde_json::to_string_pretty(&scan).expect("json")).expect("write");
}

#[test]
fn calib_seed1_calibrates_near_the_truth_and_the_error_is_the_arms() {
    let dir = calib_dir();
    let truth = json(&dir.join("truth.json"));
    let true_x = iso(&truth["T_ee_camera"]);
    let world_from_tag = iso(&truth["T_world_tag"]);
    let capture = read_capture(&dir).expect("capture");
    assert_eq!(capture.views.len(), 20);
    let cal = calibrate_capture(&capture, &CaptureParams::default()).expect("calibrate");
    let (dt, dr) = mm_deg(&cal.result.ee_from_camera, &true_x);
    let recorded = iso(&json(&dir.join("scan.json"))["T_ee_camera"]);
    let (rt, rr) = mm_deg(&recorded, &true_x);
    println!(
        "calib_seed1: {dt:.3} mm {dr:.4} deg from the truth (the recorded T_ee_camera: {rt:.3} mm {rr:.4} deg); \
         RMS {:.3} mm {:.4} deg; rejected {:?}",
        cal.result.rms_translation_mm, cal.result.rms_rotation_deg, cal.result.rejected
    );
    assert_eq!(cal.poses.len(), 20, "the tag is found in every view");
    assert!(cal.views.iter().all(|v| v.found && v.why_not.is_none() && v.residual.is_some()));
    // Where the error comes from: the detections against the true T_camera_tag, and the solver on
    // the true flange poses (truth.json) with the detections, or on the recorded ones with the true tag poses.
    let (mut det_t, mut det_r) = (0.0f64, 0.0f64);
    let (mut with_true_arm, mut with_true_tag) = (Vec::new(), Vec::new());
    for (k, v) in cal.views.iter().enumerate() {
        let tv = &truth["views"][v.index];
        let true_camera_from_tag = iso(&tv["T_world_camera"]).inverse() * world_from_tag;
        let (t, r) = mm_deg(&cal.poses[k].camera_from_target, &true_camera_from_tag);
        (det_t, det_r) = (det_t.max(t), det_r.max(r));
        with_true_arm.push(HandEyePose { base_from_ee: iso(&tv["T_base_ee"]), ..cal.poses[k] });
        with_true_tag.push(HandEyePose { camera_from_target: true_camera_from_tag, ..cal.poses[k] });
    }
    let params = CaptureParams::default().handeye;
    let arm_exact = calibrate(&with_true_arm, &params).expect("true arm");
    let tag_exact = calibrate(&with_true_tag, &params).expect("true tags");
    let (at, ar) = mm_deg(&arm_exact.ee_from_camera, &true_x);
    let (tt, tr) = mm_deg(&tag_exact.ee_from_camera, &true_x);
    println!(
        "detections vs the true T_camera_tag: worst {det_t:.3} mm {det_r:.4} deg; with the true T_base_ee: \
         {at:.3} mm {ar:.4} deg; with the true T_camera_tag and the recorded T_base_ee: {tt:.3} mm {tr:.4} deg"
    );
    // Measured: 1.709 mm / 0.127 deg from the truth with the views weighted by their covariance
    // (0.2 px corners, 0.6 mm / 0.06 deg arm; tests/capture_bound.rs), 1.534 mm / 0.125 deg weighted
    // alike (2.235 mm / 0.128 deg before the corner bias was corrected: 0.125 px estimated alike,
    // 0.151 px weighted; the detections sit 0.16 px inside the true corners): the
    // issue's 1 mm is missed by 0.5 mm (the 0.2 deg is met). What is left is the arm's: the recorded
    // T_base_ee carry the simulator's 1 mm / 0.1 deg a view (README); with the exact tag poses and
    // them the solver lands 1.660 mm / 0.115 deg off, while the corrected detections with the true
    // flange poses land 0.435 mm / 0.013 deg off (0.195 mm with the bias estimated alike, 1.102 mm
    // uncorrected); the worst corrected detection is 1.094 mm / 0.343 deg from the true T_camera_tag
    // (0.742 mm alike, 2.139 mm uncorrected). The weighted cost estimates the bias less well here: it
    // gives the tags' depths, which the bias moves, less weight.
    assert!(dt < 1.8 && dr < 0.2, "calib_seed1: {dt:.3} mm {dr:.4} deg from the truth");
    assert!(at < 0.5 && ar < 0.03, "detections with the true arm poses: {at:.3} mm {ar:.4} deg");
    assert!(tt < 2.0 && tr < 0.15, "true tag poses with the recorded arm poses: {tt:.3} mm {tr:.4} deg");
    assert!(det_t < 1.2 && det_r < 0.4, "worst detection: {det_t:.3} mm {det_r:.4} deg");
    assert!(cal.corner_bias_px.is_some_and(|b| (0.05..=0.25).contains(&b)), "{:?}", cal.corner_bias_px);
    // And it is closer to the truth than the recorded hand-eye (3.048 mm / 0.377 deg, truth.json).
    assert!(dt < rt && dr < rr, "{dt:.3} mm {dr:.4} deg vs the recorded {rt:.3} mm {rr:.4} deg");
    // OpenCV on the same detections
    let Ok(python) = std::env::var("AWL_PYTHON") else {
        println!("SKIPPED the OpenCV check: AWL_PYTHON is not set (a Python with opencv-python-headless)");
        return;
    };
    let tmp = tempfile::tempdir().expect("tempdir");
    let poses = tmp.path().join("poses.json");
    write_poses(&poses, &cal.poses).expect("write poses");
    let out = tmp.path().join("opencv.json");
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/py/check_handeye.py");
    let run =
        Command::new(&python).arg(script).args([&poses, &out]).args(["--method", "park"]).output().expect("python");
    assert!(run.status.success(), "check_handeye.py: {}", String::from_utf8_lossy(&run.stderr));
    let cv = iso(&json(&out)["T_ee_camera"]);
    let (ct, cr) = mm_deg(&cv, &cal.result.closed_form_ee_from_camera);
    let (ot, or) = mm_deg(&cv, &true_x);
    println!(
        "OpenCV (Park) on the same detections: {ct:.2e} mm {cr:.2e} deg from our closed form; {ot:.3} mm {or:.4} deg from the truth"
    );
    // same equations over the same pairs: measured 3.0e-8 mm / 1.4e-14 deg (OpenCV 4.13); its closed form is
    // 1.712 mm / 0.028 deg from the truth (1.924 mm on the detections corrected alike, 3.080 mm on the
    // uncorrected ones), our refined result 1.709 mm / 0.127 deg (1.534 mm / 0.125 deg alike)
    assert!(ct < 1e-3 && cr < 1e-4, "OpenCV vs our closed form: {ct} mm {cr} deg");
}

fn result_of(dir: &Path) -> (awl::handeye::CaptureCalibration, HandEyeResult) {
    let cal = calibrate_capture(&read_capture(dir).expect("capture"), &CaptureParams::default()).expect("calibrate");
    let result = cal.result.clone();
    (cal, result)
}

#[test]
fn without_depth_the_flip_by_consistency_chooses_as_depth_did() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (with, without) = (tmp.path().join("with"), tmp.path().join("without"));
    copy_capture(&with, true);
    copy_capture(&without, false);
    let (cal_depth, r_depth) = result_of(&with);
    let (cal_none, r_none) = result_of(&without);
    let mut ambiguous = 0;
    for (a, b) in cal_depth.views.iter().zip(&cal_none.views) {
        assert_eq!(a.ambiguity.is_some(), b.ambiguity.is_some());
        if a.ambiguity.is_none() {
            assert_eq!((a.chosen_by, b.chosen_by), (Some(FlipChoice::Unambiguous), Some(FlipChoice::Unambiguous)));
            continue;
        }
        ambiguous += 1;
        assert_eq!(a.chosen_by, Some(FlipChoice::Depth), "view {}", a.index);
        assert_eq!(b.chosen_by, Some(FlipChoice::Consistency), "view {}", b.index);
        assert_eq!(
            a.solution, b.solution,
            "view {}: depth chose {:?}, consistency {:?}",
            a.index, a.solution, b.solution
        );
    }
    let (dt, dr) = mm_deg(&r_depth.ee_from_camera, &r_none.ee_from_camera);
    println!(
        "{ambiguous} two-solution views (ambiguity 56-769); depth and consistency give results {dt:.2e} mm {dr:.2e} deg apart"
    );
    // measured: 4 views (8, 12, 13, 18), the same choices, the same poses, so the same result
    assert!(ambiguous >= 3, "the capture must exercise the choice: {ambiguous} two-solution views");
    assert!(dt < 1e-9 && dr < 1e-9, "{dt} mm {dr} deg");
}

#[test]
fn the_unchosen_solutions_do_not_fit_so_the_choice_matters() {
    // Each two-solution view calibrated on the solution not chosen (depth hidden: chosen by
    // consistency): those views must stand out as outliers (or degrees off), and the chosen ones fit.
    let tmp = tempfile::tempdir().expect("tempdir");
    let without = tmp.path().join("without");
    copy_capture(&without, false);
    let (cal, result) = result_of(&without);
    let truth = json(&calib_dir().join("truth.json"));
    let true_x = iso(&truth["T_ee_camera"]);
    let capture = read_capture(&without).expect("capture");
    let mut flipped = cal.poses.clone();
    let mut count = 0;
    for v in cal.views.iter().filter(|v| v.ambiguity.is_some()) {
        let image = capture.read_color(v.index).expect("color");
        let mut detector = awl::tag::AprilTagDetector::new(&Default::default()).expect("detector");
        let d = awl::tag::TagDetector::detect_color(&mut detector, &image).expect("detect");
        let d = d.iter().find(|d| d.id == 7).expect("tag 7");
        let pose = awl::tag::estimate_tag_pose(&d.corners_px, &capture.intrinsics, 0.14).expect("pose");
        let other = if v.solution == Some(1) { pose.second.expect("two") } else { pose.best };
        let k = v.pose.expect("pose index");
        let (t, r) = mm_deg(&other.camera_from_tag, &cal.poses[k].camera_from_target);
        println!("view {}: the other solution is {t:.1} mm {r:.2} deg from the chosen one", v.index);
        flipped[k].camera_from_target = other.camera_from_tag;
        count += 1;
    }
    let wrong = calibrate(&flipped, &CaptureParams::default().handeye).expect("calibrate flipped");
    let (wt, wr) = mm_deg(&wrong.ee_from_camera, &true_x);
    let (ct, cr) = mm_deg(&result.ee_from_camera, &true_x);
    println!(
        "{count} views on the other solution: {wt:.3} mm {wr:.4} deg from the truth, RMS {:.3} mm {:.4} deg; \
         as chosen: {ct:.3} mm {cr:.4} deg, RMS {:.3} mm {:.4} deg",
        wrong.rms_translation_mm, wrong.rms_rotation_deg, result.rms_translation_mm, result.rms_rotation_deg
    );
    // measured: the other solutions are 43-51 deg from the chosen ones; calibrated on them, the 4
    // views are rejected as outliers (or would sit degrees off), the result 2.769 mm / 0.256 deg
    assert!(count >= 3);
    for v in cal.views.iter().filter(|v| v.ambiguity.is_some()) {
        let k = v.pose.expect("pose index");
        let r = wrong.residuals[k];
        println!(
            "view {}: on the other solution residual {:.2} mm {:.2} deg, inlier {}",
            v.index, r.translation_mm, r.rotation_deg, r.inlier
        );
        assert!(!r.inlier || r.rotation_deg > 5.0, "view {}: the other solution must not fit: {r:?}", v.index);
        let chosen = result.residuals[k];
        assert!(chosen.inlier && chosen.rotation_deg < 0.5, "view {}: the chosen solution fits: {chosen:?}", v.index);
    }
}
