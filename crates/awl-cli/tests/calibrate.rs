//! `awl calibrate hand-eye` end to end: simulated poses file -> calibration against its truth, the
//! output JSON, refusing to overwrite the input, errors naming the pose and field, the threshold
//! flags (changing the rejection; bad values named by flag), and inverted poses refused.

use std::path::Path;
use std::process::{Command, Output};

use awl::transform::{Rows, isometry_from_rows, pose_difference};

fn awl(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_awl")).args(args).output().expect("run awl")
}

fn text(out: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr))
}

fn ok(out: &Output) -> String {
    let t = text(out);
    assert!(out.status.success(), "awl failed: {t}");
    t
}

fn read_json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).expect("read")).expect("json")
}

fn matrix(value: &serde_json::Value) -> nalgebra::Isometry3<f64> {
    let rows: Rows = serde_json::from_value(value.clone()).expect("4x4");
    isometry_from_rows(&rows).expect("rigid")
}

#[test]
fn simulated_poses_calibrate_to_the_truth_with_every_method() {
    let dir = tempfile::tempdir().expect("tempdir");
    let poses = dir.path().join("poses.json");
    let truth = dir.path().join("truth.json");
    let (p, t) = (poses.to_str().expect("utf-8"), truth.to_str().expect("utf-8"));
    ok(&awl(&["calibrate", "hand-eye", "--write-simulated", p, "--count", "16", "--seed", "5", "--truth", t]));
    let truth_x = matrix(&read_json(&truth)["T_ee_camera"]);
    for method in ["park", "tsai", "daniilidis"] {
        let out = dir.path().join(format!("T_ee_camera-{method}.json"));
        let o = out.to_str().expect("utf-8");
        let stdout = ok(&awl(&["calibrate", "hand-eye", "--poses", p, "--method", method, "-o", o, "--json"]));
        let doc = read_json(&out);
        let printed: serde_json::Value = serde_json::from_str(&stdout).expect("--json prints the output JSON");
        assert_eq!(printed, doc);
        assert_eq!(doc["format"], "awl-handeye-result/1");
        assert_eq!(doc["method"], method);
        assert_eq!(doc["residuals"].as_array().expect("residuals").len(), 16);
        assert_eq!(doc["rejected"], serde_json::json!([]));
        assert_eq!(doc["warnings"], serde_json::json!([]));
        let (dt, dr) = pose_difference(&matrix(&doc["T_ee_camera"]), &truth_x);
        println!("{method:10}: {:.3} mm {:.4} deg from the truth", dt * 1e3, dr.to_degrees());
        assert!(dt < 1e-3 && dr < 0.2f64.to_radians(), "{method}: {dt} m {dr} rad");
    }
    // atomic writes leave no temporary files behind
    let mut names: Vec<String> = std::fs::read_dir(dir.path())
        .expect("ls")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(
        names,
        ["T_ee_camera-daniilidis.json", "T_ee_camera-park.json", "T_ee_camera-tsai.json", "poses.json", "truth.json"]
    );
}

#[test]
fn refuses_to_overwrite_its_input_and_names_bad_poses() {
    let dir = tempfile::tempdir().expect("tempdir");
    let poses = dir.path().join("poses.json");
    let p = poses.to_str().expect("utf-8");
    ok(&awl(&["calibrate", "hand-eye", "--write-simulated", p, "--count", "6", "--seed", "2"]));
    let before = std::fs::read(&poses).expect("read");
    let out = awl(&["calibrate", "hand-eye", "--poses", p, "-o", p]);
    assert!(!out.status.success() && text(&out).contains("refusing to overwrite"), "{}", text(&out));
    assert_eq!(std::fs::read(&poses).expect("read"), before, "the input must be untouched");

    let bad = dir.path().join("bad.json");
    let out_path = dir.path().join("out.json");
    // calibrates from `doc` written as the poses file: (success, output text)
    let calibrate = |doc: &serde_json::Value| {
        std::fs::write(&bad, doc.to_string()).expect("write");
        let (b, o) = (bad.to_str().expect("utf-8"), out_path.to_str().expect("utf-8"));
        let out = awl(&["calibrate", "hand-eye", "--poses", b, "-o", o]);
        (out.status.success(), text(&out))
    };

    let mut doc = read_json(&poses);
    doc["poses"][2]["T_base_ee"][0][0] = serde_json::json!(2.0);
    let (success, t) = calibrate(&doc);
    assert!(!success && t.contains("poses[2].T_base_ee") && t.contains("orthonormal"), "{t}");
    assert!(!out_path.exists(), "no output on failure");

    let mut doc = read_json(&poses);
    doc["poses"].as_array_mut().expect("array").truncate(2);
    let (success, t) = calibrate(&doc);
    assert!(!success && t.contains("at least 3 poses, got 2"), "{t}");
    println!("{t}");
}

/// Simulated poses (`count`, `seed`) in `dir`: the path and the document.
fn simulated(dir: &Path, name: &str, count: usize, seed: u64) -> (std::path::PathBuf, serde_json::Value) {
    let path = dir.join(name);
    let (c, s) = (count.to_string(), seed.to_string());
    ok(&awl(&[
        "calibrate",
        "hand-eye",
        "--write-simulated",
        path.to_str().expect("utf-8"),
        "--count",
        &c,
        "--seed",
        &s,
    ]));
    let doc = read_json(&path);
    (path, doc)
}

#[test]
fn thresholds_from_the_command_line_change_the_rejection_and_bad_values_name_the_flag() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_, mut doc) = simulated(dir.path(), "clean.json", 18, 3);
    // pose 7's tag seen 30 mm off along x in the camera: a gross outlier
    let x = doc["poses"][7]["T_camera_target"][0][3].as_f64().expect("number");
    doc["poses"][7]["T_camera_target"][0][3] = serde_json::json!(x + 0.03);
    let poses = dir.path().join("poses.json");
    std::fs::write(&poses, doc.to_string()).expect("write");
    let p = poses.to_str().expect("utf-8");
    let out = dir.path().join("out.json");
    let o = out.to_str().expect("utf-8");

    let t = ok(&awl(&["calibrate", "hand-eye", "--poses", p, "-o", o]));
    let d = read_json(&out);
    let (inliers, all) =
        (d["rms_translation_mm"].as_f64().expect("rms"), d["rms_all_translation_mm"].as_f64().expect("rms"));
    println!("default: rejected {} RMS inliers {inliers:.3} mm, all {all:.3} mm\n{t}", d["rejected"]);
    assert_eq!(d["rejected"], serde_json::json!([7]));
    // measured: 0.77 mm over the inliers, 7.1 mm over all 18 poses; both printed
    assert!(inliers < 1.2 && all > 5.0, "{inliers} {all}");
    assert!(t.contains("(inliers)") && t.contains("(all poses)") && t.contains("1-sigma: translation"), "{t}");
    assert_eq!(d["params"]["outlier_floor_mm"], serde_json::json!(2.0));
    // the refinement kept, its shift from the closed form and the 95 % bound reported
    assert_eq!(d["refinement_check"]["kept_refined"], serde_json::json!(true), "{}", d["refinement_check"]);
    assert!(d["T_ee_camera_refined"].is_array() && d["uncertainty"]["translation_bound_95_mm"].as_f64().is_some());
    assert!(t.contains("95 % bound") && t.contains("refined vs park closed form"), "{t}");

    let t = ok(&awl(&["calibrate", "hand-eye", "--poses", p, "-o", o, "--outlier-floor-mm", "100", "--force"]));
    let d = read_json(&out);
    let (inliers, all) =
        (d["rms_translation_mm"].as_f64().expect("rms"), d["rms_all_translation_mm"].as_f64().expect("rms"));
    println!("--outlier-floor-mm 100: rejected {}, RMS {inliers:.3} / {all:.3} mm\n{t}", d["rejected"]);
    assert_eq!(d["rejected"], serde_json::json!([]));
    assert_eq!(d["params"]["outlier_floor_mm"], serde_json::json!(100.0));
    // measured 6.9 mm: the kept outlier also inflates the noise estimate, so the translation's 1-sigma
    // (2.5 mm) now draws the translation_undetermined warning
    assert!(inliers == all && all > 5.0, "{inliers} {all}");
    let warned =
        d["warnings"].as_array().expect("warnings").iter().any(|w| w["diagnosis"] == "translation_undetermined");
    assert!(warned && t.contains("warning: translation not determined"), "{t}");
    // a tolerance above the predicted bound: no such warning
    let bound = d["uncertainty"]["translation_bound_95_mm"].as_f64().expect("bound");
    let tol = format!("--tolerance-mm={}", bound + 1.0);
    ok(&awl(&["calibrate", "hand-eye", "--poses", p, "-o", o, "--outlier-floor-mm", "100", &tol, "--force"]));
    let d = read_json(&out);
    let warned =
        d["warnings"].as_array().expect("warnings").iter().any(|w| w["diagnosis"] == "translation_undetermined");
    assert!(!warned, "{}", d["warnings"]);
    // the factor alone: 100x the median keeps it too
    ok(&awl(&["calibrate", "hand-eye", "--poses", p, "-o", o, "--outlier-factor", "100", "--force"]));
    assert_eq!(read_json(&out)["rejected"], serde_json::json!([]));

    std::fs::remove_file(&out).expect("rm");
    for (flag, value, says) in [
        ("--outlier-floor-mm", "-1", "positive"),
        ("--outlier-factor", "0", "positive"),
        ("--max-rejected-fraction", "1.5", "at most 1"),
        ("--max-scale-sigma-percent", "nan", "positive"),
        ("--inverted-fit-factor", "0.5", ">= 1"),
        ("--tolerance-mm", "0", "positive"),
        ("--scale-mismatch-percent", "-1", "positive"),
    ] {
        let arg = format!("{flag}={value}");
        let r = awl(&["calibrate", "hand-eye", "--poses", p, "-o", o, &arg, "--force"]);
        let t = text(&r);
        assert!(!r.status.success() && t.contains(&format!("{flag}: ")) && t.contains(says), "{arg}: {t}");
        assert!(!out.exists(), "{arg}: no output on a bad flag");
    }
}

#[test]
fn inverted_poses_are_refused_unless_allowed_and_normal_captures_warn_of_nothing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("out.json");
    let o = out.to_str().expect("utf-8");
    // normal captures, the --write-simulated default of 15 poses: no warning on seeds 1-4
    for seed in 1..=4 {
        let (path, _) = simulated(dir.path(), &format!("clean-{seed}.json"), 15, seed);
        let r = awl(&["calibrate", "hand-eye", "--poses", path.to_str().expect("utf-8"), "-o", o, "--force"]);
        let t = ok(&r);
        assert!(!t.contains("warning"), "seed {seed}: {t}");
        let d = read_json(&out);
        assert_eq!(d["warnings"], serde_json::json!([]));
        let sigma = d["uncertainty"]["worst_translation_sigma_mm"].as_f64().expect("sigma");
        let scale = d["uncertainty"]["scale_sigma_percent"].as_f64().expect("scale");
        // measured: 0.47-0.49 mm, 0.16-0.19 %
        println!("seed {seed}: worst translation 1-sigma {sigma:.2} mm, scale {scale:.2} %");
        assert!(sigma < 0.8 && scale < 0.4, "seed {seed}: {sigma} {scale}");
    }
    let (_, mut doc) = simulated(dir.path(), "clean.json", 15, 2);
    for pose in doc["poses"].as_array_mut().expect("poses") {
        let m = matrix(&pose["T_base_ee"]);
        pose["T_base_ee"] = serde_json::to_value(awl::transform::rows_from_isometry(&m.inverse())).expect("rows");
    }
    let poses = dir.path().join("inverted.json");
    std::fs::write(&poses, doc.to_string()).expect("write");
    let p = poses.to_str().expect("utf-8");
    std::fs::remove_file(&out).expect("rm");
    let r = awl(&["calibrate", "hand-eye", "--poses", p, "-o", o, "--force"]);
    let t = text(&r);
    println!("{t}");
    assert!(!r.status.success(), "{t}");
    assert!(t.contains("poses[*].T_base_ee") && t.contains("T_ee_base") && t.contains("--allow-inverted-fit"), "{t}");
    assert!(!out.exists(), "no output on refusal");
    let r = awl(&["calibrate", "hand-eye", "--poses", p, "-o", o, "--allow-inverted-fit", "--force"]);
    let t = ok(&r);
    let d = read_json(&out);
    assert_eq!(d["warnings"][0]["diagnosis"], "inverted_convention", "{}", d["warnings"]);
    assert!(t.contains("warning: the poses fit") && t.contains("(inverted_convention)"), "{t}");
    // measured: as given 37.6 mm median and 51.9 mm RMS over all poses; T_base_ee inverted 0.93 mm (seed 2)
    let fit =
        d["inversion_fits"].as_array().expect("fits").iter().find(|f| f["inversion"] == "base_from_ee").expect("fit");
    let inverted_mm = fit["median_translation_mm"].as_f64().expect("mm");
    let rms_all = d["rms_all_translation_mm"].as_f64().expect("rms");
    println!("allowed: RMS all {rms_all:.1} mm, T_base_ee inverted fits at {inverted_mm:.2} mm median");
    assert!(inverted_mm < 1.5 && rms_all > 20.0, "{inverted_mm} {rms_all}");
}
