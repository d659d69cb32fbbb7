//! `awl calibrate hand-eye` end to end: simulated poses file -> calibration against its truth, the
//! output JSON, refusing to overwrite the input, and errors naming the pose and field.

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
