//! Hand-eye calibration against the simulator's truth and against OpenCV (`tests/py/check_handeye.py`,
//! run with `AWL_PYTHON`): accuracy per method under noise, exact recovery, outlier rejection,
//! degenerate motion, and the typed errors of bad input.

use std::path::PathBuf;
use std::process::Command;

use awl::Error;
use awl::handeye::{HandEyeMethod, HandEyeParams, HandEyePose, HandEyeResult, calibrate};
use awl::io::handeye::{parse_poses, poses_json, read_poses, write_poses};
use awl::sim::calibration::{CalibrationCapture, CalibrationSimParams, simulate_calibration};
use awl::transform::{isometry_from_rows, isometry_from_translation_rotvec, pose_difference};
use nalgebra::{Isometry3, Quaternion, UnitQuaternion, Vector3};

const METHODS: [HandEyeMethod; 3] = [HandEyeMethod::Park, HandEyeMethod::Tsai, HandEyeMethod::Daniilidis];

fn params(method: HandEyeMethod) -> HandEyeParams {
    HandEyeParams { method, ..HandEyeParams::default() }
}

/// (mm, deg) between two transforms.
fn error_mm_deg(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    let (dt, dr) = pose_difference(a, b);
    (dt * 1e3, dr.to_degrees())
}

fn capture(seed: u64, count: usize) -> CalibrationCapture {
    simulate_calibration(&CalibrationSimParams { seed, count, ..CalibrationSimParams::default() }).expect("simulate")
}

#[test]
fn noisy_captures_meet_1_mm_and_0_2_deg_for_every_method() {
    for (seed, count) in [(1, 15), (2, 18), (3, 20), (4, 15), (5, 18), (6, 20)] {
        let cap = capture(seed, count);
        for method in METHODS {
            let r = calibrate(&cap.poses, &params(method)).expect("calibrate");
            let (dt, dr) = error_mm_deg(&r.ee_from_camera, &cap.ee_from_camera);
            let (ct, cr) = error_mm_deg(&r.closed_form_ee_from_camera, &cap.ee_from_camera);
            let (bt, br) = error_mm_deg(&r.base_from_target, &cap.base_from_target);
            println!(
                "seed {seed} n {count} {:10}: refined {dt:.3} mm {dr:.4} deg | closed {ct:.3} mm {cr:.4} deg | \
                 target {bt:.3} mm {br:.4} deg | rms {:.3} mm {:.4} deg | axis angle {:.1} deg | rejected {:?}",
                method.name(),
                r.rms_translation_mm,
                r.rms_rotation_deg,
                r.diversity.axis_angle_deg,
                r.rejected
            );
            assert!(dt < 1.0 && dr < 0.2, "seed {seed} {method:?}: {dt:.3} mm {dr:.4} deg");
            assert!(bt < 1.5 && br < 0.2, "seed {seed} {method:?}: target {bt:.3} mm {br:.4} deg");
            assert!(r.rejected.is_empty(), "seed {seed} {method:?}: rejected {:?} of clean data", r.rejected);
            assert!(r.warnings.is_empty(), "seed {seed} {method:?}: {:?}", r.warnings);
            assert!(r.refinement.converged && r.refinement.final_cost <= r.refinement.initial_cost);
        }
    }
}

#[test]
fn exact_data_recovers_the_truth_to_1e_9() {
    for seed in [1, 7] {
        let sim = CalibrationSimParams {
            seed,
            count: 12,
            camera_noise_mm: 0.0,
            camera_noise_deg: 0.0,
            arm_noise_mm: 0.0,
            arm_noise_deg: 0.0,
            ..CalibrationSimParams::default()
        };
        let cap = simulate_calibration(&sim).expect("simulate");
        for method in METHODS {
            let r = calibrate(&cap.poses, &params(method)).expect("calibrate");
            let (ct, cr) = pose_difference(&r.closed_form_ee_from_camera, &cap.ee_from_camera);
            let (dt, dr) = pose_difference(&r.ee_from_camera, &cap.ee_from_camera);
            let (bt, br) = pose_difference(&r.base_from_target, &cap.base_from_target);
            println!(
                "seed {seed} {:10}: closed {ct:.2e} m {cr:.2e} rad, refined {dt:.2e} m {dr:.2e} rad, target {bt:.2e} m {br:.2e} rad",
                method.name()
            );
            for (what, v) in [
                ("closed t", ct),
                ("closed r", cr),
                ("refined t", dt),
                ("refined r", dr),
                ("target t", bt),
                ("target r", br),
            ] {
                assert!(v < 1e-9, "seed {seed} {method:?} {what}: {v:e}");
            }
            assert!(r.residuals.iter().all(|p| p.translation_mm < 1e-6 && p.rotation_deg < 1e-6));
        }
    }
}

#[test]
fn a_gross_outlier_pose_is_rejected() {
    for seed in [3, 5] {
        let mut cap = capture(seed, 18);
        let mut without = cap.poses.clone();
        without.remove(7);
        let bad = 7;
        let kick = isometry_from_translation_rotvec(
            Vector3::new(0.03, -0.03, 0.0283),
            Vector3::new(0.0, 5f64.to_radians(), 0.0),
        );
        cap.poses[bad].camera_from_target = kick * cap.poses[bad].camera_from_target;
        for method in METHODS {
            let unguarded = HandEyeParams { max_rejected_fraction: 0.0, ..params(method) };
            let raw = calibrate(&cap.poses, &unguarded).expect("calibrate");
            let (ut, ur) = error_mm_deg(&raw.ee_from_camera, &cap.ee_from_camera);
            let r = calibrate(&cap.poses, &params(method)).expect("calibrate");
            let (dt, dr) = error_mm_deg(&r.ee_from_camera, &cap.ee_from_camera);
            let res = &r.residuals[bad];
            println!(
                "seed {seed} {:10}: without rejection {ut:.2} mm {ur:.3} deg (+ warning {:?}); with: {dt:.3} mm {dr:.4} deg, \
                 rejected {:?}, pose {bad} residual {:.1} mm {:.2} deg",
                method.name(),
                raw.warnings.len(),
                r.rejected,
                res.translation_mm,
                res.rotation_deg
            );
            assert_eq!(r.rejected, vec![bad], "seed {seed} {method:?}");
            // rejection leaves exactly the calibration of the other poses
            let clean = calibrate(&without, &params(method)).expect("calibrate");
            let (et, er) = pose_difference(&r.ee_from_camera, &clean.ee_from_camera);
            assert!(
                et < 1e-9 && er < 1e-9,
                "seed {seed} {method:?}: {et:e} m {er:e} rad from the calibration without pose {bad}"
            );
            assert!(!res.inlier && res.translation_mm > 20.0, "seed {seed} {method:?}: {res:?}");
            assert!(dt < 1.0 && dr < 0.2, "seed {seed} {method:?}: {dt:.3} mm {dr:.4} deg");
            assert!(ut > 1.0 || ur > 0.2, "the outlier must matter: {ut:.3} mm {ur:.4} deg without rejection");
            assert!(raw.warnings.iter().any(|w| w.contains("outlier")), "{:?}", raw.warnings);
        }
    }
}

/// Poses whose flange rotations are all about `axes[i % axes.len()]` (flange frame), with the camera
/// measurements implied by the truth of `cap`, plus optional noise from `noisy`.
fn axis_poses(cap: &CalibrationCapture, axes: &[Vector3<f64>], noisy: Option<&CalibrationCapture>) -> Vec<HandEyePose> {
    let e0 = cap.true_poses[0].base_from_ee;
    (0..12)
        .map(|i| {
            let angle = (-30.0 + 5.0 * i as f64).to_radians();
            let t = Vector3::new(0.02 * (i % 3) as f64, -0.015 * (i % 4) as f64, 0.01 * (i % 5) as f64);
            let e = e0 * isometry_from_translation_rotvec(t, axes[i % axes.len()].normalize() * angle);
            let mut pose = HandEyePose {
                base_from_ee: e,
                camera_from_target: (e * cap.ee_from_camera).inverse() * cap.base_from_target,
            };
            if let Some(n) = noisy {
                // the simulator's noise of pose i, applied on the same sides
                let d_arm = n.true_poses[i].base_from_ee.inverse() * n.poses[i].base_from_ee;
                let d_cam = n.true_poses[i].camera_from_target.inverse() * n.poses[i].camera_from_target;
                pose.base_from_ee *= d_arm;
                pose.camera_from_target *= d_cam;
            }
            pose
        })
        .collect()
}

#[test]
fn rotations_about_one_axis_are_refused_or_flagged() {
    let cap = capture(2, 12);
    let z = [Vector3::new(0.2, -0.1, 1.0)];
    for method in METHODS {
        let err = calibrate(&axis_poses(&cap, &z, None), &params(method)).expect_err("exact one-axis motion");
        println!("{:10} exact one axis: {err}", method.name());
        assert!(
            matches!(&err, Error::Invalid { what, message } if what == "poses" && message.contains("degenerate motion"))
        );
        match calibrate(&axis_poses(&cap, &z, Some(&cap)), &params(method)) {
            Err(e) => {
                println!("{:10} noisy one axis: {e}", method.name());
                assert!(e.to_string().contains("degenerate motion"));
            }
            Ok(r) => {
                println!(
                    "{:10} noisy one axis: axis angle {:.2} deg, {:?}",
                    method.name(),
                    r.diversity.axis_angle_deg,
                    r.warnings
                );
                assert!(r.warnings.iter().any(|w| w.contains("poor motion diversity")), "{:?}", r.warnings);
            }
        }
        // two axes 4 deg apart: solvable, but flagged; 60 deg apart: no warning
        let near = [Vector3::new(0.0, 0.0, 1.0), Vector3::new(4f64.to_radians().sin(), 0.0, 4f64.to_radians().cos())];
        let r = calibrate(&axis_poses(&cap, &near, None), &params(method)).expect("two close axes");
        let (nt, nr) = pose_difference(&r.ee_from_camera, &cap.ee_from_camera);
        println!(
            "{:10} axes 4 deg apart: axis angle {:.2} deg, exact data error {nt:.1e} m {nr:.1e} rad",
            method.name(),
            r.diversity.axis_angle_deg
        );
        assert!(nt < 1e-6 && nr < 1e-6, "{nt:e} {nr:e}");
        assert!(r.diversity.axis_angle_deg > 2.0 && r.diversity.axis_angle_deg < 20.0, "{:?}", r.diversity);
        assert!(r.warnings.iter().any(|w| w.contains("poor motion diversity")), "{:?}", r.warnings);
        let wide = [Vector3::new(0.0, 0.0, 1.0), Vector3::new(60f64.to_radians().sin(), 0.0, 60f64.to_radians().cos())];
        let r = calibrate(&axis_poses(&cap, &wide, None), &params(method)).expect("two wide axes");
        let (dt, dr) = pose_difference(&r.ee_from_camera, &cap.ee_from_camera);
        assert!(r.warnings.is_empty() && dt < 1e-9 && dr < 1e-9, "{:?} {dt:e} {dr:e}", r.warnings);
    }
}

#[test]
fn bad_input_gives_typed_errors_naming_the_pose_and_field() {
    let cap = capture(4, 6);
    let p = HandEyeParams::default();
    let e = calibrate(&cap.poses[..2], &p).expect_err("two poses");
    assert!(matches!(&e, Error::Invalid { what, message } if what == "poses" && message.contains("at least 3")), "{e}");
    let mut poses = cap.poses.clone();
    poses[2].camera_from_target.translation.vector.y = f64::NAN;
    let e = calibrate(&poses, &p).expect_err("NaN");
    assert!(
        matches!(&e, Error::Invalid { what, message } if what == "poses[2].T_camera_target" && message.contains("non-finite")),
        "{e}"
    );
    let mut poses = cap.poses.clone();
    poses[1].base_from_ee.rotation = UnitQuaternion::new_unchecked(Quaternion::new(1.0, 0.2, 0.0, 0.0));
    let e = calibrate(&poses, &p).expect_err("non-rigid");
    assert!(
        matches!(&e, Error::Invalid { what, message } if what == "poses[1].T_base_ee" && message.contains("rigid")),
        "{e}"
    );

    // the file: round trip, then a scaled matrix, a NaN, a wrong tag, a missing field
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("poses.json");
    write_poses(&path, &cap.poses).expect("write");
    let back = read_poses(&path).expect("read");
    for (a, b) in cap.poses.iter().zip(&back) {
        let (t1, r1) = pose_difference(&a.base_from_ee, &b.base_from_ee);
        let (t2, r2) = pose_difference(&a.camera_from_target, &b.camera_from_target);
        assert!(t1.max(r1).max(t2).max(r2) < 1e-12, "{t1:e} {r1:e} {t2:e} {r2:e}");
    }
    let mut doc: serde_json::Value = serde_json::from_str(&poses_json(&cap.poses)).expect("json");
    doc["poses"][4]["T_base_ee"][1][1] = serde_json::json!(1.01);
    let e = parse_poses(&path, doc.to_string().as_bytes()).expect_err("scaled");
    assert!(
        matches!(&e, Error::Field { field, message, .. } if field == "poses[4].T_base_ee" && message.contains("orthonormal")),
        "{e}"
    );
    let text = poses_json(&cap.poses);
    let at = text.match_indices("\"T_camera_target\"").nth(2).expect("third pose").0;
    let (head, tail) = text.split_at(at);
    let number_start = tail.find(|c: char| c == '-' || c.is_ascii_digit()).expect("a number");
    let number_end = number_start + tail[number_start..].find([',', '\n', ']']).expect("end");
    let nan_text = format!("{head}{}NaN{}", &tail[..number_start], &tail[number_end..]);
    let e = parse_poses(&path, nan_text.as_bytes()).expect_err("NaN in file");
    assert!(
        matches!(&e, Error::Field { field, message, .. } if field == "poses[2].T_camera_target" && message.contains("non-finite")),
        "{e}"
    );
    let e = parse_poses(&path, text.replace("awl-handeye/1", "awl-handeye/9").as_bytes()).expect_err("tag");
    assert!(matches!(&e, Error::Field { field, .. } if field == "format"), "{e}");
    doc = serde_json::from_str(&text).expect("json");
    doc["poses"][3].as_object_mut().expect("object").remove("T_camera_target");
    let e = parse_poses(&path, serde_json::to_string_pretty(&doc).expect("json").as_bytes()).expect_err("missing");
    assert!(
        matches!(&e, Error::Field { field, message, .. } if field == "poses[3]" && message.contains("missing field")),
        "{e}"
    );
    println!("errors name the pose and field, e.g. {e}");
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// OpenCV's `T_ee_camera` for the poses file `poses` with `method`.
fn opencv(poses: &std::path::Path, method: &str) -> Isometry3<f64> {
    let python = std::env::var("AWL_PYTHON").unwrap_or_else(|_| "python3".into());
    let out = poses.with_file_name(format!("opencv-{method}.json"));
    let run = Command::new(&python)
        .arg(repo().join("tests/py/check_handeye.py"))
        .args([poses, out.as_path()])
        .args(["--method", method])
        .output()
        .unwrap_or_else(|e| {
            panic!("cannot run {python} (set AWL_PYTHON to a Python with opencv-python-headless): {e}")
        });
    let text = format!("{}{}", String::from_utf8_lossy(&run.stdout), String::from_utf8_lossy(&run.stderr));
    assert!(run.status.success(), "check_handeye.py failed:\n{text}");
    let doc: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&out).expect("read")).expect("json");
    let rows: awl::transform::Rows = serde_json::from_value(doc["T_ee_camera"].clone()).expect("4x4");
    isometry_from_rows(&rows).expect("OpenCV returns a rigid transform")
}

#[test]
fn agrees_with_opencv_calibrate_hand_eye() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (seed, count) in [(1, 15), (2, 18), (3, 20)] {
        let cap = capture(seed, count);
        let path = dir.path().join(format!("poses-{seed}.json"));
        write_poses(&path, &cap.poses).expect("write");
        let poses = read_poses(&path).expect("read back");
        for method in METHODS {
            let cv = opencv(&path, method.name());
            let r: HandEyeResult = calibrate(&poses, &params(method)).expect("calibrate");
            let (ct, cr) = error_mm_deg(&r.closed_form_ee_from_camera, &cv);
            let (dt, dr) = error_mm_deg(&r.ee_from_camera, &cv);
            let (ot, or) = error_mm_deg(&cv, &cap.ee_from_camera);
            println!(
                "seed {seed} {:10}: ours closed vs OpenCV {ct:.2e} mm {cr:.2e} deg; refined vs OpenCV {dt:.3} mm {dr:.4} deg; \
                 OpenCV vs truth {ot:.3} mm {or:.4} deg",
                method.name()
            );
            // the refinement moves toward the truth, away from OpenCV's pair-based closed form: both
            // stay within their error budgets (OpenCV's closed form alone is up to ~1.3 mm off the truth)
            assert!(dt < 2.0 && dr < 0.3, "seed {seed} {method:?}: refined vs OpenCV {dt:.3} mm {dr:.4} deg");
            // same equations over the same pairs: Park and Daniilidis agree to rounding (< 1e-10 mm);
            // OpenCV's Tsai differs from ours by up to 0.012 mm / 0.0014 deg (cause not isolated)
            let (lt, lr) = if method == HandEyeMethod::Tsai { (0.05, 0.01) } else { (1e-6, 1e-6) };
            assert!(ct < lt && cr < lr, "seed {seed} {method:?}: closed form vs OpenCV {ct:e} mm {cr:e} deg");
        }
    }
}
