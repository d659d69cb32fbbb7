//! End-to-end tests of the `awl` binary: `simulate` checked by an independent Python reader
//! (tests/py/check_scan.py: numpy + Pillow + scipy, no awl code), `info`, and bad command lines.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn awl(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_awl")).args(args).output().expect("run awl")
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn shared_data() -> PathBuf {
    let dir = std::env::var_os("AWL_SHARED_DATA").map(PathBuf::from).unwrap_or_else(|| repo().join("../shared/data"));
    assert!(dir.is_dir(), "{}: shared test data missing (set AWL_SHARED_DATA)", dir.display());
    dir
}

/// Runs the independent checker; fails with its output when it rejects the scan.
fn independent_check(scan: &Path, noise: &str) -> String {
    let python = std::env::var("AWL_PYTHON").unwrap_or_else(|_| "python3".into());
    let out = Command::new(&python)
        .arg(repo().join("tests/py/check_scan.py"))
        .arg(scan)
        .args(["--noise", noise])
        .output()
        .unwrap_or_else(|e| panic!("cannot run {python} (set AWL_PYTHON to a Python with numpy, Pillow, scipy): {e}"));
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "independent check of {} at noise {noise} failed:\n{text}", scan.display());
    text
}

fn ok(out: &Output) -> String {
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "awl failed: {text}");
    text
}

#[test]
fn simulated_scans_pass_the_independent_check() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (scene, noise) in [("box", "none"), ("shell", "none"), ("box", "realistic"), ("shell", "realistic")] {
        let scan = dir.path().join(format!("{scene}-{noise}"));
        let s = scan.to_str().expect("utf-8 path");
        ok(&awl(&["simulate", "--scene", scene, "--noise", noise, "--seed", "3", "-o", s]));
        let report = independent_check(&scan, noise);
        println!("{scene} {noise}:\n{report}");
    }
    // a shot taken with the camera of the box scan (seed 3): same intrinsics and depth-scale error
    let shot = dir.path().join("shot");
    let s = shot.to_str().expect("utf-8");
    ok(&awl(&["simulate", "--shot", "tilt30", "--noise", "realistic", "--camera-seed", "3", "-o", s]));
    independent_check(&shot, "realistic");
    let json = |dir: &std::path::Path, file: &str| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(dir.join(file)).expect("json")).expect("json")
    };
    let scan = dir.path().join("box-realistic");
    assert_eq!(json(&shot, "scan.json")["camera"], json(&scan, "scan.json")["camera"]);
    let scale = |dir: &std::path::Path| json(dir, "truth.json")["depth_scale_error"].as_f64().expect("scale");
    assert_eq!(scale(&shot), scale(&scan));
    assert!(scale(&scan) != 0.0);
}

#[test]
fn the_checker_accepts_the_other_simulator_and_rejects_a_shifted_truth() {
    let reference = shared_data().join("sim_reference/box_seed1");
    independent_check(&reference, "realistic");
    // a copy whose truth puts the workpiece 5 mm off must fail
    let dir = tempfile::tempdir().expect("tempdir");
    let copy = dir.path().join("shifted");
    ok(&awl(&["simulate", "--noise", "none", "--views", "4", "-o", copy.to_str().expect("utf-8")]));
    let truth_path = copy.join("truth.json");
    let mut truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&truth_path).expect("truth")).expect("json");
    let x = truth["T_world_object"][0][3].as_f64().expect("number");
    truth["T_world_object"][0][3] = serde_json::json!(x + 0.005);
    std::fs::write(&truth_path, serde_json::to_string(&truth).expect("json")).expect("write");
    let python = std::env::var("AWL_PYTHON").unwrap_or_else(|_| "python3".into());
    let status = Command::new(python)
        .arg(repo().join("tests/py/check_scan.py"))
        .arg(&copy)
        .args(["--noise", "none"])
        .output()
        .expect("run checker")
        .status;
    assert_eq!(status.code(), Some(1), "a 5 mm shifted truth must be rejected");
}

#[test]
fn info_summarises_scans_and_files() {
    let dir = tempfile::tempdir().expect("tempdir");
    let scan = dir.path().join("scan");
    ok(&awl(&["simulate", "--views", "3", "-o", scan.to_str().expect("utf-8")]));
    let out = awl(&["info", scan.to_str().expect("utf-8"), "--json"]);
    let info: serde_json::Value = serde_json::from_slice(&out.stdout).expect("info --json prints JSON");
    assert_eq!(info["views"].as_array().map(Vec::len), Some(3));
    assert!(info["points"].as_u64().expect("points") > 300_000, "{info}");
    assert_eq!(info["tag"]["family"], "tag36h11");
    let bunny = shared_data().join("stanford_bunny/bun000.ply");
    let text = ok(&awl(&["info", bunny.to_str().expect("utf-8")]));
    assert!(text.contains("40256"), "{text}");
    let cad = scan.join("cad.ply");
    let out = awl(&["info", cad.to_str().expect("utf-8"), "--json"]);
    let cad_info: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    let area = cad_info["area_m2"].as_f64().expect("area");
    let expected = 2.0 * (0.485 * 0.48 + 0.485 * 0.30 + 0.48 * 0.30);
    assert!((area - expected).abs() < 1e-6, "box CAD area {area} vs {expected}");
}

#[test]
fn bad_command_lines_fail_clearly_and_never_overwrite() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = awl(&["simulate", "--noise", "extreme", "-o", dir.path().join("x").to_str().expect("utf-8")]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("extreme"));
    let existing = dir.path().join("mine");
    std::fs::create_dir_all(&existing).expect("mkdir");
    std::fs::write(existing.join("notes.txt"), "user data").expect("write");
    let out = awl(&["simulate", "-o", existing.to_str().expect("utf-8")]);
    assert!(!out.status.success(), "must refuse a non-empty folder");
    assert_eq!(std::fs::read_to_string(existing.join("notes.txt")).expect("still there"), "user data");
    let out = awl(&["info", dir.path().join("absent.ply").to_str().expect("utf-8")]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("absent.ply"));
}

#[test]
fn simulate_capture_writes_a_calibration_capture_and_refuses_scan_options() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out_dir = dir.path().join("capture");
    let out = out_dir.to_str().expect("utf-8");
    let text = ok(&awl(&["simulate", "--capture", "--views", "3", "--seed", "2", "--noise", "low", "-o", out]));
    assert!(text.contains("calibration capture: 3 views of tag36h11 id 7"), "{text}");
    let read = |name: &str| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(out_dir.join(name)).expect(name)).expect("JSON")
    };
    let (scan, truth) = (read("scan.json"), read("truth.json"));
    assert_eq!(scan["tag"]["id"], 7);
    assert_eq!(scan["tag"]["size"], 0.14);
    let views = scan["views"].as_array().expect("views");
    assert_eq!(views.len(), 3);
    for (i, v) in views.iter().enumerate() {
        assert!(v["T_base_ee"].is_array() && v["T_world_base"].is_array(), "view {i}: {v}");
        assert!(out_dir.join(v["color"].as_str().expect("color")).is_file(), "view {i}");
        assert!(out_dir.join(v["depth"].as_str().expect("depth")).is_file(), "view {i}");
        assert_eq!(truth["views"][i]["tag_corners_px"].as_array().map(Vec::len), Some(4), "view {i}");
    }
    assert!(truth["T_ee_camera"].is_array() && out_dir.join("cad.ply").is_file());
    let refused = dir.path().join("refused");
    let refused = refused.to_str().expect("utf-8");
    for (args, says) in [
        (vec!["--capture", "--scene", "shell"], "--scene"),
        (vec!["--capture", "--shot", "flat"], "--shot"),
        (vec!["--tag-id", "3"], "--capture"),
        (vec!["--capture", "--tag-id", "12"], "0 to 9"),
        (vec!["--capture", "--tag-size", "0.9"], "0.02 to 0.3 m"),
        (vec!["--capture", "--views", "2"], "3 to 1000 views"),
    ] {
        let out = awl(&[&["simulate"], args.as_slice(), &["-o", refused]].concat());
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && stderr.contains(says), "{args:?}: {stderr}");
        assert!(!Path::new(refused).exists(), "{args:?}: nothing written");
    }
}
