//! Hand-eye calibration against the simulator's truth and against OpenCV (`tests/py/check_handeye.py`,
//! run with `AWL_PYTHON`): accuracy per method under noise, exact recovery, outlier rejection,
//! degenerate motion, the typed errors of bad input, and the calibration traps: inverted pose
//! conventions, a tag scale or a translation the motions do not determine, the RMS over all poses,
//! the sigmas against the actual errors, and no diagnosis on normal captures; single inversions named
//! at every lever arm, a wrong target scale, the refinement kept near the closed forms, 5 000 poses.
#![cfg(feature = "sim")]

use std::path::PathBuf;
use std::process::Command;

use awl::Error;
use awl::handeye::poses_file::{parse_poses, poses_json, read_poses, write_poses};
use awl::handeye::{Diagnosis, HandEyeMethod, HandEyeParams, HandEyePose, HandEyeResult, Inversion, calibrate};
use awl::sim::calibration::{CalibrationCapture, CalibrationMotion, CalibrationSimParams, simulate_calibration};
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
            assert!(
                raw.warnings
                    .iter()
                    .any(|w| w.diagnosis == Diagnosis::RejectionCapReached && w.message.contains("outlier")),
                "{:?}",
                raw.warnings
            );
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
                assert!(r.warnings.iter().any(|w| w.diagnosis == Diagnosis::PoorMotionDiversity), "{:?}", r.warnings);
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
        assert!(r.warnings.iter().any(|w| w.diagnosis == Diagnosis::PoorMotionDiversity), "{:?}", r.warnings);
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

/// `poses` with `T_base_ee` (`ee`) and / or `T_camera_target` (`camera`) inverted.
fn inverted(poses: &[HandEyePose], ee: bool, camera: bool) -> Vec<HandEyePose> {
    poses
        .iter()
        .map(|p| HandEyePose {
            base_from_ee: if ee { p.base_from_ee.inverse() } else { p.base_from_ee },
            camera_from_target: if camera { p.camera_from_target.inverse() } else { p.camera_from_target },
        })
        .collect()
}

fn median_translation_mm(r: &HandEyeResult) -> f64 {
    let mut t: Vec<f64> = r.residuals.iter().map(|p| p.translation_mm).collect();
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

/// Robot and camera poses not from the same moments: every camera pose moved to the next pose
/// (a one-stop lag) or the order of the camera poses reversed. The refusal names mismatched pairs
/// (seeds 1 and 2: 87-127 mm median residual as given, 151-194 mm with a single field inverted).
/// Not yet caught: seed 3 with the lag is accepted with warnings only (114 mm RMS, translation
/// undetermined), since no rule refuses a large residual that every convention shares.
#[test]
fn shuffled_pose_pairs_are_named_as_a_cause() {
    for (seed, count) in [(1, 15), (2, 18)] {
        let cap = capture(seed, count);
        let n = cap.poses.len();
        for (how, k_of) in [
            ("lag", Box::new(move |i: usize| (i + 1) % n) as Box<dyn Fn(usize) -> usize>),
            ("reversed", Box::new(move |i: usize| n - 1 - i)),
        ] {
            let poses: Vec<HandEyePose> = (0..n)
                .map(|i| HandEyePose {
                    base_from_ee: cap.poses[i].base_from_ee,
                    camera_from_target: cap.poses[k_of(i)].camera_from_target,
                })
                .collect();
            match calibrate(&poses, &HandEyeParams::default()) {
                Err(e) => {
                    println!("seed {seed} {how}: {e}");
                    let m = e.to_string();
                    assert!(m.contains("not pairs taken at the same moments") && m.contains("shuffled"), "{m}");
                }
                Ok(r) => panic!(
                    "seed {seed} {how}: mismatched pairs accepted: RMS {:.1} mm, warnings {:?}",
                    r.rms_all_translation_mm, r.warnings
                ),
            }
        }
    }
}

#[test]
fn inverted_pose_conventions_are_refused_naming_the_field() {
    for (seed, count) in [(1, 15), (2, 18), (3, 20), (4, 15)] {
        let cap = capture(seed, count);
        // the right convention: the single inversions fit far worse (seeds 1-8: 55-250 mm median against
        // 0.56-0.90 mm); both inverted fits as well (0.88-1.48 mm), the case the plausibility rule takes
        let right = calibrate(&cap.poses, &HandEyeParams::default()).expect("the right convention");
        let given = median_translation_mm(&right);
        for fit in &right.inversion_fits {
            println!(
                "seed {seed}: as given {given:.2} mm; {:?} inverted {:.2} mm",
                fit.inversion, fit.median_translation_mm
            );
            if fit.inversion != Inversion::Both {
                assert!(fit.median_translation_mm > 30.0 && given < 1.0, "seed {seed}: {fit:?} against {given}");
            }
        }
        for (ee, camera, what, holds) in [
            (true, false, "poses[*].T_base_ee", "T_ee_base"),
            (false, true, "poses[*].T_camera_target", "T_target_camera"),
            (true, true, "poses[*].T_base_ee and T_camera_target", "T_ee_base and T_target_camera"),
        ] {
            let poses = inverted(&cap.poses, ee, camera);
            let e = calibrate(&poses, &HandEyeParams::default()).expect_err("inverted poses");
            println!("seed {seed} {what}: {e}");
            assert!(
                matches!(&e, Error::Invalid { what: w, message } if w == what && message.contains(holds)
                    && message.contains("allow_inverted_fit")),
                "seed {seed}: {e}"
            );
            // accepted as given on request, with the warning and the numbers behind the refusal
            let allow = HandEyeParams { allow_inverted_fit: true, ..HandEyeParams::default() };
            let r = calibrate(&poses, &allow).expect("allowed");
            let (dt, _) = error_mm_deg(&r.ee_from_camera, &cap.ee_from_camera);
            let med = median_translation_mm(&r);
            let best = r
                .inversion_fits
                .iter()
                .filter(|f| f.inversion != Inversion::Both)
                .map(|f| f.median_translation_mm)
                .fold(f64::INFINITY, f64::min);
            println!(
                "   allowed: median {med:.1} mm as given, best single inversion {best:.2} mm, RMS all {:.1} mm, \
                 T_ee_camera {dt:.0} mm off",
                r.rms_all_translation_mm
            );
            assert!(r.warnings.iter().any(|w| w.diagnosis == Diagnosis::InvertedConvention), "{:?}", r.warnings);
            if ee != camera {
                // seeds 1-8: 28-170 mm as given against 0.55-0.93 mm inverted (30-226x)
                assert!(med > 20.0 && best < 1.5 && med > 20.0 * best, "seed {seed}: {med} against {best}");
            } else {
                // both inverted: as good a fit, but T_ee_camera is T_base_target (0.55 m from the flange)
                assert!(med < 1.5 && r.ee_from_camera.translation.vector.norm() > 0.5, "seed {seed}: {med}");
            }
        }
    }
}

#[test]
fn pure_rotations_about_the_target_leave_the_tag_scale_undetermined() {
    for (seed, count) in [(1, 15), (2, 18), (3, 20), (4, 15)] {
        let sim = |motion| {
            simulate_calibration(&CalibrationSimParams { seed, count, motion, ..CalibrationSimParams::default() })
                .expect("simulate")
        };
        for (motion, name) in [(CalibrationMotion::OrbitTarget, "orbit"), (CalibrationMotion::Spread, "spread")] {
            let cap = sim(motion);
            if motion == CalibrationMotion::OrbitTarget {
                // every true view 0.45 m from the tag, its centre on the optical axis
                for p in &cap.true_poses {
                    let t = p.camera_from_target.translation.vector;
                    assert!((t.norm() - 0.45).abs() < 1e-9 && t.x.hypot(t.y) < 1e-9, "{t:?}");
                }
            }
            // a tag 3 % larger than its declared size: every T_camera_target translation 3 % too long
            let mut poses = cap.poses.clone();
            for p in &mut poses {
                p.camera_from_target.translation.vector *= 1.03;
            }
            let right = calibrate(&cap.poses, &HandEyeParams::default()).expect("calibrate");
            let r = calibrate(&poses, &HandEyeParams::default()).expect("calibrate");
            let (dt, _) = error_mm_deg(&r.ee_from_camera, &cap.ee_from_camera);
            let u = &r.uncertainty;
            let scale_warned =
                |r: &HandEyeResult| r.warnings.iter().any(|w| w.diagnosis == Diagnosis::ScaleUndetermined);
            println!(
                "seed {seed} {name:6}: 3 % scale -> {dt:.2} mm off, RMS all {:.3} mm (right size {:.3} mm), scale \
                 1-sigma {:.2} % (right size {:.2} %), {:.2} mm per %, warnings {:?}",
                r.rms_all_translation_mm,
                right.rms_all_translation_mm,
                u.scale_sigma_percent,
                right.uncertainty.scale_sigma_percent,
                u.translation_mm_per_scale_percent,
                r.warnings.iter().map(|w| w.diagnosis).collect::<Vec<_>>()
            );
            // 3 % of the camera-to-target distance (0.3-0.6 m) moves the translation either way (measured
            // 12.0-15.1 mm, 4.1-5.0 mm per %)
            assert!(dt > 10.0 && dt < 17.0, "seed {seed} {name}: {dt}");
            assert!(u.translation_mm_per_scale_percent > 3.5 && u.translation_mm_per_scale_percent < 5.5, "{u:?}");
            if motion == CalibrationMotion::OrbitTarget {
                // nothing in the residuals (0.73-1.08 mm with or without the error) betrays it; the scale's
                // 1-sigma does (13.8-19.8 %), with or without the error
                assert!(
                    r.rms_all_translation_mm < 1.3 && r.rms_all_translation_mm < right.rms_all_translation_mm + 0.1
                );
                assert!(u.scale_sigma_percent > 10.0 && right.uncertainty.scale_sigma_percent > 10.0, "{u:?}");
                assert!(scale_warned(&r) && scale_warned(&right), "seed {seed}: {:?}", r.warnings);
                let w = r.warnings.iter().find(|w| w.diagnosis == Diagnosis::ScaleUndetermined).expect("warning");
                assert!(w.message.contains("3 % size error would move") && w.message.contains("other distances"));
                // the translation itself is determined (0.45-0.56 mm worst 1-sigma): not that warning
                assert!(u.worst_translation_sigma_mm < 0.8, "{u:?}");
            } else {
                // distances over 0.3-0.6 m determine the scale (0.30-0.40 % with the error, 0.14-0.19 % without)
                // and the error shows in the residuals (2.0-2.9 mm against 0.72-0.97 mm)
                assert!(u.scale_sigma_percent < 0.5 && right.uncertainty.scale_sigma_percent < 0.25, "{u:?}");
                assert!(!scale_warned(&r) && right.warnings.is_empty(), "seed {seed}: {:?}", r.warnings);
                assert!(
                    r.rms_all_translation_mm > 1.8 && r.rms_all_translation_mm > 2.0 * right.rms_all_translation_mm
                );
            }
        }
    }
}

#[test]
fn small_rotations_leave_the_translation_undetermined() {
    for (seed, count) in [(1, 15), (2, 18), (3, 20), (4, 15)] {
        let wide = capture(seed, count);
        let narrow = simulate_calibration(&CalibrationSimParams {
            seed,
            count,
            spread_deg: 8.0,
            ..CalibrationSimParams::default()
        })
        .expect("simulate");
        let rw = calibrate(&wide.poses, &HandEyeParams::default()).expect("calibrate");
        let rn = calibrate(&narrow.poses, &HandEyeParams::default()).expect("calibrate");
        let (wt, _) = error_mm_deg(&rw.ee_from_camera, &wide.ee_from_camera);
        let (nt, _) = error_mm_deg(&rn.ee_from_camera, &narrow.ee_from_camera);
        println!(
            "seed {seed}: tilts to 40 deg: {wt:.2} mm off, 1-sigma {:.2} mm; to 8 deg: {nt:.2} mm off, 1-sigma {:.2} mm \
             along {:?}, per axis {:?} mm, rotation {:?} deg",
            rw.uncertainty.worst_translation_sigma_mm,
            rn.uncertainty.worst_translation_sigma_mm,
            rn.uncertainty.worst_translation_direction,
            rn.uncertainty.translation_sigma_mm,
            rn.uncertainty.rotation_sigma_deg,
        );
        // measured: 40 deg 0.43-0.53 mm 1-sigma (errors 0.34-0.76 mm); 8 deg 1.3-2.0 mm (errors 0.8-3.0 mm).
        // The warning compares the 95 % bound with tolerance_mm (2 mm)
        let (bw, bn) = (rw.uncertainty.translation_bound_95_mm, rn.uncertainty.translation_bound_95_mm);
        println!("   95 % bounds: 40 deg {bw:.2} mm, 8 deg {bn:.2} mm");
        assert!(rw.uncertainty.worst_translation_sigma_mm < 0.6 && rw.warnings.is_empty(), "{:?}", rw.warnings);
        assert!(bw < 2.0 && bn > 2.0 && rn.uncertainty.worst_translation_sigma_mm > 1.2, "{:?}", rn.uncertainty);
        let w = rn.warnings.iter().find(|w| w.diagnosis == Diagnosis::TranslationUndetermined).expect("the warning");
        assert!(w.message.contains("translation not determined") && w.message.contains("rotate the flange more"));
        // a looser tolerance above the bound: no warning
        let loose = HandEyeParams { tolerance_mm: bn + 0.1, ..HandEyeParams::default() };
        let rl = calibrate(&narrow.poses, &loose).expect("calibrate");
        assert!(!rl.warnings.iter().any(|w| w.diagnosis == Diagnosis::TranslationUndetermined), "{:?}", rl.warnings);
        // the warning is about the translation, not the scale (0.13-0.21 %)
        assert!(
            rn.uncertainty.scale_sigma_percent < 0.5
                && !rn.warnings.iter().any(|w| w.diagnosis == Diagnosis::ScaleUndetermined)
        );
    }
}

#[test]
fn translation_sigmas_cover_the_actual_errors() {
    // per-axis error of T_ee_camera's translation over its 1-sigma, 20 seeds x 3 axes
    let mut ratios = Vec::new();
    for seed in 1..=20 {
        let cap = capture(seed, 15);
        let r = calibrate(&cap.poses, &HandEyeParams::default()).expect("calibrate");
        let e = (r.ee_from_camera.translation.vector - cap.ee_from_camera.translation.vector) * 1e3;
        for k in 0..3 {
            ratios.push(e[k].abs() / r.uncertainty.translation_sigma_mm[k]);
        }
    }
    ratios.sort_by(f64::total_cmp);
    let within = |k: f64| ratios.iter().filter(|&&r| r <= k).count() as f64 / ratios.len() as f64;
    println!(
        "|error| / sigma over {} axes: median {:.2}, within 1 sigma {:.0} %, 2 sigma {:.0} %, 3 sigma {:.0} %, max {:.2}",
        ratios.len(),
        ratios[ratios.len() / 2],
        100.0 * within(1.0),
        100.0 * within(2.0),
        100.0 * within(3.0),
        ratios[ratios.len() - 1]
    );
    // measured: median 0.55, 73 % within 1 sigma, 93 % within 2, 100 % within 3 (max 2.72): neither
    // overconfident nor padded (a normal error would give 68 / 95 / 99.7 %)
    let (one, two, three) = (within(1.0), within(2.0), within(3.0));
    assert!(one > 0.55 && one < 0.85 && two > 0.85 && three > 0.96, "{one} {two} {three}: {ratios:?}");
}

#[test]
fn rms_over_all_poses_counts_the_rejected_outlier_and_the_floors_can_keep_it() {
    let mut cap = capture(3, 18);
    let kick = isometry_from_translation_rotvec(Vector3::new(0.03, -0.03, 0.0283), Vector3::zeros());
    cap.poses[7].camera_from_target = kick * cap.poses[7].camera_from_target;
    let r = calibrate(&cap.poses, &HandEyeParams::default()).expect("calibrate");
    let all = (r.residuals.iter().map(|p| p.translation_mm.powi(2)).sum::<f64>() / 18.0).sqrt();
    println!(
        "rejected {:?}: RMS inliers {:.3} mm / {:.4} deg, all {:.3} mm / {:.4} deg",
        r.rejected, r.rms_translation_mm, r.rms_rotation_deg, r.rms_all_translation_mm, r.rms_all_rotation_deg
    );
    assert_eq!(r.rejected, vec![7]);
    assert!((r.rms_all_translation_mm - all).abs() < 1e-9);
    // one 52 mm pose among 18: 12.2 mm over all poses against 0.77 mm over the inliers (the rotation RMS
    // barely moves, 0.176 against 0.179 deg: the kick is a translation)
    assert!(r.rms_translation_mm < 1.2 && r.rms_all_translation_mm > 10.0, "{r:?}");
    let all_deg = (r.residuals.iter().map(|p| p.rotation_deg.powi(2)).sum::<f64>() / 18.0).sqrt();
    assert!((r.rms_all_rotation_deg - all_deg).abs() < 1e-9);
    let kept = calibrate(&cap.poses, &HandEyeParams { outlier_floor_mm: 100.0, ..HandEyeParams::default() })
        .expect("calibrate");
    println!("floor 100 mm: rejected {:?}, RMS {:.3} mm", kept.rejected, kept.rms_translation_mm);
    assert!(kept.rejected.is_empty() && kept.rms_translation_mm == kept.rms_all_translation_mm);
    for (params, what) in [
        (HandEyeParams { outlier_floor_mm: -1.0, ..HandEyeParams::default() }, "outlier_floor_mm"),
        (HandEyeParams { max_rejected_fraction: 1.5, ..HandEyeParams::default() }, "max_rejected_fraction"),
        (HandEyeParams { inverted_fit_factor: 0.5, ..HandEyeParams::default() }, "inverted_fit_factor"),
        (HandEyeParams { max_scale_sigma_percent: f64::NAN, ..HandEyeParams::default() }, "max_scale_sigma_percent"),
    ] {
        let e = calibrate(&cap.poses, &params).expect_err("bad parameter");
        assert!(matches!(&e, Error::Invalid { what: w, .. } if w == what), "{e}");
    }
}

#[test]
fn normal_simulated_captures_raise_no_diagnosis() {
    // the CLI's --write-simulated default (15 poses) and the trials' rig camera (20 poses), seeds 1-20:
    // no warning, no refusal; the largest worst-direction sigma and scale sigma stay well under the limits
    let (mut worst_t, mut worst_s, mut worst_ratio) = (0.0f64, 0.0f64, f64::INFINITY);
    for seed in 1..=20 {
        for (count, ee_from_camera) in [(15, None), (20, Some(awl::sim::rig_ee_from_camera()))] {
            let sim = CalibrationSimParams { seed, count, ee_from_camera, ..CalibrationSimParams::default() };
            let cap = simulate_calibration(&sim).expect("simulate");
            let r = calibrate(&cap.poses, &HandEyeParams::default()).expect("a normal capture calibrates");
            assert!(r.warnings.is_empty(), "seed {seed} n {count}: {:?}", r.warnings);
            worst_t = worst_t.max(r.uncertainty.worst_translation_sigma_mm);
            worst_s = worst_s.max(r.uncertainty.scale_sigma_percent);
            let given = median_translation_mm(&r);
            for f in r.inversion_fits.iter().filter(|f| f.inversion != Inversion::Both) {
                worst_ratio = worst_ratio.min(f.median_translation_mm / given);
            }
        }
    }
    println!(
        "40 captures: worst translation 1-sigma {worst_t:.2} mm (limit 1), scale {worst_s:.2} % (limit 1), \
         single inversions fit at least {worst_ratio:.0}x worse"
    );
    // measured: 0.57 mm, 0.21 %, 95x
    assert!(worst_t < 0.8 && worst_s < 0.4 && worst_ratio > 20.0, "{worst_t} {worst_s} {worst_ratio}");
}

/// A capture with the camera `offset_m` along the flange's z (and a fixed tilt), cameras `near_m` to
/// `far_m` from the tag, the robot base moved so the target is `target_m` from it.
fn lever_capture(seed: u64, offset_m: f64, near_m: f64, far_m: f64, target_m: f64) -> CalibrationCapture {
    let x = isometry_from_translation_rotvec(Vector3::new(0.02, -0.015, offset_m), Vector3::new(0.3, -0.8, 0.2));
    let sim = CalibrationSimParams {
        seed,
        count: 18,
        ee_from_camera: Some(x),
        min_distance_m: near_m,
        max_distance_m: far_m,
        ..CalibrationSimParams::default()
    };
    let mut cap = simulate_calibration(&sim).expect("simulate");
    let t = cap.base_from_target.translation.vector;
    let moved = isometry_from_translation_rotvec(t / t.norm() * target_m - t, Vector3::zeros());
    for p in cap.poses.iter_mut().chain(cap.true_poses.iter_mut()) {
        p.base_from_ee = moved * p.base_from_ee;
    }
    cap.base_from_target = moved * cap.base_from_target;
    cap
}

/// The lever arms of the single-inversion test: (seed, camera offset from the flange, nearest and
/// farthest camera-to-tag distance, target distance from the base), metres.
const LEVERS: [(u64, f64, f64, f64, f64); 8] = [
    (1, 0.05, 0.2, 0.35, 0.5),
    (2, 0.10, 0.6, 1.0, 1.2),
    (3, 0.20, 0.3, 0.6, 0.6),
    (4, 0.40, 0.3, 0.6, 0.8),
    (5, 0.40, 0.6, 1.0, 1.5),
    (6, 0.05, 0.6, 1.0, 0.45),
    (7, 0.25, 0.2, 0.35, 1.0),
    (8, 0.15, 0.3, 0.6, 2.0),
];

#[test]
fn single_inversions_are_named_at_every_lever_arm() {
    for (seed, offset, near, far, target) in LEVERS {
        let cap = lever_capture(seed, offset, near, far, target);
        for (ee, what, other) in
            [(true, "poses[*].T_base_ee", "T_camera_target"), (false, "poses[*].T_camera_target", "T_base_ee")]
        {
            let poses = inverted(&cap.poses, ee, !ee);
            let e = calibrate(&poses, &HandEyeParams::default()).expect_err("inverted poses");
            let fits = {
                let allow = HandEyeParams { allow_inverted_fit: true, ..HandEyeParams::default() };
                calibrate(&poses, &allow).expect("allowed").inversion_fits
            };
            let line: Vec<String> = fits
                .iter()
                .map(|f| {
                    format!(
                        "{:?} {:.2} mm (camera {:.3} m, target {:.3} m)",
                        f.inversion, f.median_translation_mm, f.camera_from_flange_m, f.target_from_base_m
                    )
                })
                .collect();
            println!("seed {seed} offset {offset} d {near}-{far} target {target} {what}: {line:?}");
            assert!(
                matches!(&e, Error::Invalid { what: w, message } if w == what && message.contains(other)),
                "seed {seed} offset {offset} target {target}: {e}"
            );
        }
    }
}

fn scaled_translations(poses: &[HandEyePose], s: f64) -> Vec<HandEyePose> {
    let mut poses = poses.to_vec();
    for p in &mut poses {
        p.camera_from_target.translation.vector *= s;
    }
    poses
}

#[test]
fn a_wrong_target_scale_is_named_and_the_right_one_is_not() {
    let mismatch = |r: &HandEyeResult| r.warnings.iter().find(|w| w.diagnosis == Diagnosis::ScaleMismatch).cloned();
    let mut fitted = Vec::new();
    for seed in 1..=10 {
        let cap = capture(seed, 18);
        let right = calibrate(&cap.poses, &HandEyeParams::default()).expect("calibrate");
        assert!(mismatch(&right).is_none(), "seed {seed}: {:?}", right.warnings);
        let (s0, sig0) = (right.uncertainty.fitted_scale, right.uncertainty.scale_sigma_percent);
        for s in [1.03, 0.97] {
            let r = calibrate(&scaled_translations(&cap.poses, s), &HandEyeParams::default()).expect("calibrate");
            let (dt, _) = error_mm_deg(&r.ee_from_camera, &cap.ee_from_camera);
            let u = &r.uncertainty;
            println!(
                "seed {seed}: right size fits {s0:.4} +- {sig0:.2} %; x{s}: fits {:.4} +- {:.2} % ({dt:.1} mm off), \
                 warnings {:?}",
                u.fitted_scale,
                u.scale_sigma_percent,
                r.warnings.iter().map(|w| w.diagnosis).collect::<Vec<_>>()
            );
            let w = mismatch(&r).expect("a scale_mismatch warning");
            assert!(w.message.contains("tag or board size wrong") && w.message.contains("true size"), "{}", w.message);
            // the fitted factor undoes the applied one: fitted x applied equals the right size's fit
            // (which is 1 within its noise: 0.9961-1.0051, 0.13-0.20 % sigma) to 0.03 % (measured)
            assert!((u.fitted_scale * s - s0).abs() < 0.002, "seed {seed} x{s}: {} against {s0}", u.fitted_scale);
            fitted.push((u.fitted_scale * s - s0).abs());
        }
        assert!((s0 - 1.0).abs() < 3.0 * sig0 / 100.0, "seed {seed}: {s0} +- {sig0} %");
    }
    println!("largest |fitted x applied - right size's fit|: {:.5}", fitted.iter().copied().fold(0.0, f64::max));
}

#[test]
fn the_refinement_stays_near_the_closed_forms_unless_the_data_hold_an_error() {
    let mut largest = 0.0f64;
    for (seed, offset, near, far, target) in LEVERS {
        let cap = lever_capture(seed, offset, near, far, target);
        let r = calibrate(&cap.poses, &HandEyeParams::default()).expect("calibrate");
        let c = r.refinement_check.expect("a check");
        let (rt, _) = error_mm_deg(&r.ee_from_camera, &cap.ee_from_camera);
        let (ct, _) = error_mm_deg(&r.closed_form_ee_from_camera, &cap.ee_from_camera);
        println!(
            "clean seed {seed} offset {offset} d {near}-{far}: refined {rt:.2} mm off, closed {ct:.2} mm off; shift \
             {:.2} mm / {:.3} deg, limit {:.2} mm / {:.3} deg (spread {:.2} mm, closed sigma {:.2} mm)",
            c.shift_mm, c.shift_deg, c.limit_mm, c.limit_deg, c.closed_form_spread_mm, c.closed_form_sigma_mm
        );
        assert!(c.kept_refined && r.ee_from_camera == r.refined_ee_from_camera, "seed {seed}: {c:?}");
        assert!(!r.warnings.iter().any(|w| w.diagnosis == Diagnosis::RefinementDisagrees));
        largest = largest.max(c.shift_mm);
        let closed: Vec<_> = [HandEyeMethod::Park, HandEyeMethod::Tsai, HandEyeMethod::Daniilidis]
            .into_iter()
            .map(|method| {
                calibrate(&cap.poses, &HandEyeParams { method, refine: false, ..HandEyeParams::default() })
                    .expect("closed")
                    .ee_from_camera
                    .translation
                    .vector
            })
            .collect();
        // the closed forms' agreement: the nearest of the three (measured 0.22-0.98 mm over the 8
        // sets; from the method's own closed form 0.24-1.16 mm), while the refined one is nearer
        // the truth than the closed form on every set
        let rv = r.refined_ee_from_camera.translation.vector;
        let nearest = closed.iter().map(|c| (rv - c).norm() * 1e3).fold(f64::INFINITY, f64::min);
        println!("   nearest closed form {nearest:.2} mm from the refined");
        assert!(nearest <= 1.0 && rt <= ct, "seed {seed}: {nearest:.2} mm; refined {rt:.2} closed {ct:.2} mm off");
    }
    println!("clean: largest refined-vs-closed shift {largest:.2} mm");
    // systematic errors: a 3 % tag size, a principal point 2 % of the focal length off (every
    // T_camera_target translation's x moved by 0.02 z), a rotation noise of 0.5 deg on the tag
    for seed in 1..=6 {
        let cap = capture(seed, 18);
        let mut lateral = cap.poses.clone();
        for p in &mut lateral {
            let t = &mut p.camera_from_target.translation.vector;
            t.x += 0.02 * t.z;
        }
        let rough = simulate_calibration(&CalibrationSimParams {
            seed,
            count: 18,
            camera_noise_deg: 0.5,
            ..CalibrationSimParams::default()
        })
        .expect("simulate");
        for (name, poses, truth) in [
            ("scale 1.03", scaled_translations(&cap.poses, 1.03), cap.ee_from_camera),
            ("principal point", lateral, cap.ee_from_camera),
            ("0.5 deg tag noise", rough.poses.clone(), rough.ee_from_camera),
        ] {
            let r = calibrate(&poses, &HandEyeParams::default()).expect("calibrate");
            let c = r.refinement_check.expect("a check");
            let (et, _) = error_mm_deg(&r.ee_from_camera, &truth);
            // the same data with the rotations weighted 100x too much (30 m/rad)
            let heavy = calibrate(&poses, &HandEyeParams { rotation_weight_m: 30.0, ..HandEyeParams::default() })
                .expect("calibrate");
            let hc = heavy.refinement_check.expect("a check");
            let (ht, _) = error_mm_deg(&heavy.ee_from_camera, &truth);
            let (hr, _) = error_mm_deg(&heavy.refined_ee_from_camera, &truth);
            println!(
                "   30 m/rad: result {ht:.2} mm off (refined {hr:.2}); shift {:.2} mm, limit {:.2} mm, kept {}",
                hc.shift_mm, hc.limit_mm, hc.kept_refined
            );
            let (hcf, _) = error_mm_deg(&heavy.closed_form_ee_from_camera, &truth);
            assert!(ht <= hr.min(hcf) + 1.0, "seed {seed} {name} 30 m/rad: {ht} against {hr} / {hcf}");
            let (rt, _) = error_mm_deg(&r.refined_ee_from_camera, &truth);
            let (ct, _) = error_mm_deg(&r.closed_form_ee_from_camera, &truth);
            println!(
                "seed {seed} {name}: result {et:.2} mm off (refined {rt:.2}, closed {ct:.2}); shift {:.2} mm / {:.3} \
                 deg, limit {:.2} mm / {:.3} deg, kept refined {}",
                c.shift_mm, c.shift_deg, c.limit_mm, c.limit_deg, c.kept_refined
            );
            assert!(et <= rt.min(ct) + 1.0, "seed {seed} {name}: {et} against {rt} / {ct}");
        }
    }
}

#[test]
fn five_thousand_poses_calibrate_in_bounded_pairs() {
    let cap = capture(11, 5000);
    let dir = std::env::temp_dir().join(format!("awl-handeye-5000-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let path = dir.join("poses.json");
    write_poses(&path, &cap.poses).expect("write");
    let read = read_poses(&path).expect("a 5000-pose file reads");
    let _ = std::fs::remove_dir_all(&dir);
    assert_eq!(read.len(), 5000);
    let start = std::time::Instant::now();
    let r = calibrate(&read, &HandEyeParams::default()).expect("5000 poses calibrate");
    let seconds = start.elapsed().as_secs_f64();
    let (dt, dr) = error_mm_deg(&r.ee_from_camera, &cap.ee_from_camera);
    let (ct, cr) = error_mm_deg(&r.closed_form_ee_from_camera, &cap.ee_from_camera);
    println!(
        "5000 poses: {seconds:.2} s, {} pairs, refined {dt:.3} mm / {dr:.4} deg, closed {ct:.3} mm / {cr:.4} deg, \
         rejected {}, warnings {:?}",
        r.diversity.pairs,
        r.rejected.len(),
        r.warnings
    );
    assert!(r.diversity.pairs <= 100_000 && r.diversity.pairs > 50_000, "{}", r.diversity.pairs);
    assert!(dt < 1.0 && dr < 0.2 && ct < 1.0 && cr < 0.2, "{dt} {dr} {ct} {cr}");
    assert!(r.warnings.is_empty(), "{:?}", r.warnings);
}

#[test]
fn a_poses_file_of_more_than_100000_poses_is_refused_while_read() {
    let pose = r#"{"T_base_ee":[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]],"T_camera_target":[[1,0,0,0],[0,1,0,0],[0,0,1,0.5],[0,0,0,1]]}"#;
    let text = format!(r#"{{"format":"awl-handeye/1","poses":[{}]}}"#, vec![pose; 100_001].join(","));
    let e = parse_poses(std::path::Path::new("big.json"), text.as_bytes()).expect_err("too many poses");
    println!("{e}");
    assert!(e.to_string().contains("more than 100000 poses") && e.to_string().contains("poses"), "{e}");
}
