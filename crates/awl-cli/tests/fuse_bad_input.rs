//! `awl fuse` on damaged scans and configs: a view with all-zero depth, a single-view scan, nothing
//! left after the depth crop, a NaN pose, out-of-range config values. Clear messages; the pipeline
//! goes on with the remaining views where that makes sense and says so in the report; nothing is
//! written when it cannot go on.

use std::path::Path;
use std::process::{Command, Output};

use awl::image::DepthImage;
use awl::io::image::{read_depth_png, write_depth_png};

fn awl(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_awl")).args(args).output().expect("run awl")
}

fn text(out: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr))
}

/// A small simulated scan (4 views, low noise) in `dir/name`.
fn scan(dir: &Path, name: &str) -> std::path::PathBuf {
    let path = dir.join(name);
    let out = awl(&["simulate", "--views", "4", "--noise", "low", "--seed", "5", "-o", path.to_str().expect("utf-8")]);
    assert!(out.status.success(), "simulate: {}", text(&out));
    path
}

fn edit_manifest(scan: &Path, edit: impl FnOnce(&mut serde_json::Value)) {
    let path = scan.join("scan.json");
    let mut manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).expect("read scan.json")).expect("json");
    edit(&mut manifest);
    std::fs::write(&path, serde_json::to_string_pretty(&manifest).expect("json")).expect("write scan.json");
}

fn fuse(scan: &Path, out: &Path) -> Output {
    awl(&["fuse", scan.to_str().expect("utf-8"), "-o", out.to_str().expect("utf-8"), "--quiet", "--json"])
}

fn report(out: &Output) -> serde_json::Value {
    assert!(out.status.success(), "fuse failed: {}", text(out));
    serde_json::from_slice(&out.stdout).expect("report JSON on stdout")
}

#[test]
fn a_view_with_all_zero_depth_is_skipped_and_reported() {
    let dir = tempfile::tempdir().expect("tempdir");
    let scan = scan(dir.path(), "scan");
    let depth = scan.join("depth/000002.png");
    let image = read_depth_png(&depth).expect("depth");
    let zeros = DepthImage { data: vec![0; image.data.len()], ..image };
    write_depth_png(&depth, &zeros).expect("write zeros");
    let out = dir.path().join("out");
    let r = report(&fuse(&scan, &out));
    let view = &r["views"][2];
    assert_eq!(view["status"], "skipped", "{view}");
    assert!(view["reason"].as_str().unwrap_or("").contains("no points"), "{view}");
    let warnings = r["warnings"].to_string();
    assert!(warnings.contains("view 2 skipped"), "{warnings}");
    let merged = r["views"].as_array().expect("views").iter().filter(|v| v["T_world_camera"].is_array()).count();
    assert_eq!(merged, 3, "the other three views are merged");
    assert!(r["model_points"].as_u64().unwrap_or(0) > 10_000 && out.join("model.ply").is_file());
}

#[test]
fn a_single_view_scan_gives_that_view_with_a_warning() {
    let dir = tempfile::tempdir().expect("tempdir");
    let scan = scan(dir.path(), "scan");
    edit_manifest(&scan, |m| {
        let views = m["views"].as_array_mut().expect("views");
        views.truncate(1);
    });
    let r = report(&fuse(&scan, &dir.path().join("out")));
    assert_eq!(r["views"].as_array().map(Vec::len), Some(1));
    assert_eq!(r["views"][0]["status"], "anchor");
    assert!(r["warnings"].to_string().contains("only one usable view"), "{}", r["warnings"]);
    assert!(r["model_points"].as_u64().unwrap_or(0) > 1_000);
}

#[test]
fn nothing_left_after_the_depth_crop_is_a_clear_error_and_writes_nothing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let scan = scan(dir.path(), "scan");
    edit_manifest(&scan, |m| {
        m["camera"]["depth_min"] = serde_json::json!(5.0);
        m["camera"]["depth_max"] = serde_json::json!(6.0);
    });
    let out_dir = dir.path().join("out");
    let out = fuse(&scan, &out_dir);
    let message = text(&out);
    assert!(!out.status.success(), "{message}");
    assert!(message.contains("no usable view"), "{message}");
    assert!(message.contains("depth range crop"), "the per-view reason is given: {message}");
    assert!(!out_dir.exists(), "nothing is written");
}

#[test]
fn a_nan_pose_names_the_file_view_and_field() {
    let dir = tempfile::tempdir().expect("tempdir");
    let scan = scan(dir.path(), "scan");
    let manifest = scan.join("scan.json");
    let original = std::fs::read_to_string(&manifest).expect("read");
    // JSON has no NaN: writers that emit one produce the bare token, which must be named as such
    let damaged =
        original.replacen("\"T_base_ee\": [\n        [\n          ", "\"T_base_ee\": [\n        [\n          NaN, ", 1);
    assert_ne!(damaged, original, "the edit applies");
    std::fs::write(&manifest, damaged).expect("write");
    let out_dir = dir.path().join("out");
    let out = fuse(&scan, &out_dir);
    let message = text(&out);
    assert!(!out.status.success(), "{message}");
    assert!(message.contains("scan.json") && message.contains("NaN"), "{message}");
    assert!(!out_dir.exists(), "nothing is written");
    // a pose that is a number but not a rotation names the view and field
    let mut m: serde_json::Value = serde_json::from_str(&original).expect("json");
    m["views"][1]["T_base_ee"][0][0] = serde_json::json!(2.0);
    std::fs::write(&manifest, serde_json::to_string(&m).expect("json")).expect("write");
    let message = text(&fuse(&scan, &out_dir));
    assert!(message.contains("views[1].T_base_ee") && message.contains("rigid"), "{message}");
    assert!(!out_dir.exists(), "nothing is written");
}

#[test]
fn bad_config_values_name_their_key_and_write_nothing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let scan = scan(dir.path(), "scan");
    for (toml, key) in [
        ("[registration.icp]\nconvergence_translation_m = nan\n", "registration.icp.convergence_translation_m"),
        ("[registration]\njoint_convergence_rotation_rad = inf\n", "registration.joint_convergence_rotation_rad"),
        ("[registration.icp]\nkernel_scale_ratio = -1.0\n", "registration.icp.kernel_scale_ratio"),
        ("[registration.icp]\nmax_tangential_voxels = 0.0\n", "registration.icp.max_tangential_voxels"),
    ] {
        let config = dir.path().join("fuse.toml");
        std::fs::write(&config, toml).expect("write config");
        let out_dir = dir.path().join("out");
        let out = awl(&[
            "fuse",
            scan.to_str().expect("utf-8"),
            "-o",
            out_dir.to_str().expect("utf-8"),
            "--config",
            config.to_str().expect("utf-8"),
            "--quiet",
        ]);
        let message = text(&out);
        assert!(!out.status.success(), "{toml}: {message}");
        assert!(message.contains(key), "{toml}: the key is named: {message}");
        assert!(!out_dir.exists(), "nothing is written");
    }
}

#[test]
fn print_config_round_trips_through_config() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (preset, other) in [("fast", "accurate"), ("accurate", "fast")] {
        let printed = awl(&["fuse", "--print-config", "--preset", preset]);
        assert!(printed.status.success(), "{}", String::from_utf8_lossy(&printed.stderr));
        let text = String::from_utf8(printed.stdout).expect("utf-8");
        assert!(text.contains("# Per-view voxel down-sampling.\n[view_voxel]"), "a comment per table:\n{text}");
        let path = dir.path().join(format!("{preset}.toml"));
        std::fs::write(&path, &text).expect("write config");
        // given back over the other preset, every key comes from the file
        let again = awl(&["fuse", "--print-config", "--preset", other, "--config", path.to_str().expect("utf-8")]);
        assert!(again.status.success(), "{}", String::from_utf8_lossy(&again.stderr));
        assert!(again.stdout == text.as_bytes(), "{preset}: the printed config read back resolves to another config");
    }
    // an optional stage switched off in TOML, and the error for `true`
    let path = dir.path().join("off.toml");
    std::fs::write(&path, "smoothing = false\n").expect("write config");
    let out = awl(&["fuse", "--print-config", "--config", path.to_str().expect("utf-8")]);
    assert!(String::from_utf8_lossy(&out.stdout).contains("\nsmoothing = false\n"), "smoothing off");
    std::fs::write(&path, "smoothing = true\n").expect("write config");
    let out = awl(&["fuse", "--print-config", "--config", path.to_str().expect("utf-8")]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("off.toml") && e.contains("false to switch it off"), "{e}");
    // a check across keys (streaming with a joint step) names the file and the key too
    std::fs::write(&path, "view_memory = \"stream\"\n").expect("write config");
    let out = awl(&["fuse", "--print-config", "--config", path.to_str().expect("utf-8")]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("off.toml") && e.contains("view_memory"), "{e}");
    // without --print-config the scan and the output folder are required
    let out = awl(&["fuse"]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("SCAN"), "scan required");
}

#[test]
fn a_json_config_goes_over_the_preset_and_null_turns_a_stage_off() {
    let dir = tempfile::tempdir().expect("tempdir");
    let scan = scan(dir.path(), "scan");
    let config = dir.path().join("fuse.json");
    std::fs::write(&config, r#"{"smoothing": null, "merge_voxel": {"voxel_size_m": 0.005}}"#).expect("write config");
    let run = |name: &str, extra: &[&str]| {
        let out_dir = dir.path().join(name);
        let mut args = vec!["fuse", scan.to_str().expect("utf-8"), "-o", out_dir.to_str().expect("utf-8")];
        args.extend_from_slice(&["--quiet", "--json"]);
        args.extend_from_slice(extra);
        (awl(&args), out_dir)
    };
    let (out, _) = run("fast", &["--preset", "fast", "--config", config.to_str().expect("utf-8")]);
    let r = report(&out);
    let c = &r["config"];
    assert_eq!(c["pixel_step"], 2, "the preset's own keys stay");
    assert_eq!(c["registration"]["joint_levels"], serde_json::json!([]));
    assert_eq!(c["merge_voxel"]["voxel_size_m"], 0.005, "the file's key");
    assert_eq!(c["smoothing"], false, "null turned MLS off, written `false` as TOML writes it");
    let stages: Vec<&str> = r["stages"].as_array().expect("stages").iter().filter_map(|s| s["name"].as_str()).collect();
    assert!(!stages.contains(&"mls"), "{stages:?}");
    // the same file over the default preset keeps the default's keys
    let r = report(&run("accurate", &["--config", config.to_str().expect("utf-8")]).0);
    assert_eq!(r["config"]["pixel_step"], 1);
    assert_eq!(r["config"]["registration"]["joint_levels"].as_array().map(Vec::len), Some(2));
    // a broken JSON file or an unknown key names the file and writes nothing
    for (bad, needle) in [(r#"{"smoothing": "#, "fuse.json"), (r#"{"smoothnig": null}"#, "smoothnig")] {
        std::fs::write(&config, bad).expect("write config");
        let (out, out_dir) = run("bad", &["--config", config.to_str().expect("utf-8")]);
        let message = text(&out);
        assert!(!out.status.success(), "{bad}: {message}");
        assert!(message.contains(needle), "{bad}: {message}");
        assert!(!out_dir.exists(), "nothing is written");
    }
}

/// Issue 55: a region-of-interest crop that leaves no view any points is one error, naming
/// `roi.radius_m`, its value and the focus point it used, not one message per view; nothing is
/// written.
#[test]
fn an_empty_region_of_interest_is_one_error_naming_the_key_and_the_focus() {
    let dir = tempfile::tempdir().expect("tempdir");
    let scan = scan(dir.path(), "scan");
    let config = dir.path().join("tiny_roi.json");
    std::fs::write(&config, r#"{"roi": {"radius_m": 0.0001}}"#).expect("config");
    let out_dir = dir.path().join("out");
    let s = |p: &Path| p.to_str().expect("utf-8").to_string();
    let out = awl(&["fuse", &s(&scan), "-o", &s(&out_dir), "--quiet", "--config", &s(&config)]);
    let t = text(&out);
    assert!(!out.status.success() && !t.contains("panicked"), "{t}");
    assert_eq!(t.matches("roi.radius_m").count(), 2, "the key once, in the message and its fix: {t}");
    for want in
        ["in 4 of 4 views (0, 1, 2, 3)", "`roi.radius_m` = 0.0001 m of the focus point (", "raise `roi.radius_m`"]
    {
        assert!(t.contains(want), "`{want}` not in: {t}");
    }
    assert!(!t.contains("view 1:"), "no reason per view: {t}");
    assert!(!out_dir.exists(), "nothing written");
}

/// Issue 55: NaN and infinite points in a view's cloud file are dropped with a warning naming the
/// file and how many (the fuse goes on with the finite ones).
#[test]
fn non_finite_points_in_a_cloud_view_are_dropped_with_a_warning() {
    let dir = tempfile::tempdir().expect("tempdir");
    let scan = dir.path().join("clouds");
    std::fs::create_dir_all(scan.join("clouds")).expect("mkdir");
    let mut rows = String::new();
    let mut count = 0;
    for i in 0..60 {
        for j in 0..60 {
            let (x, y) = ((i - 30) as f64 * 0.004, (j - 30) as f64 * 0.004);
            rows.push_str(&format!("{x} {y} {}\n", 0.5 + 0.02 * (x * 20.0).sin() * (y * 15.0).cos()));
            count += 1;
        }
    }
    let bad = format!("{rows}nan 0 0.5\n0 inf 0.5\n");
    let ply = |rows: &str, n: usize| {
        format!(
            "ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\n\
             end_header\n{rows}"
        )
    };
    std::fs::write(scan.join("clouds/000000.ply"), ply(&bad, count + 2)).expect("write");
    std::fs::write(scan.join("clouds/000001.ply"), ply(&rows, count)).expect("write");
    let id = "[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]";
    let moved = "[[1,0,0,0.002],[0,1,0,0],[0,0,1,0],[0,0,0,1]]";
    let manifest = format!(
        r#"{{"format": "awl-scan/1", "views": [{{"points": "clouds/000000.ply", "T_world_camera": {id}}},
            {{"points": "clouds/000001.ply", "T_world_camera": {moved}}}]}}"#
    );
    std::fs::write(scan.join("scan.json"), manifest).expect("write");
    let r = report(&fuse(&scan, &dir.path().join("out")));
    let warnings = r["warnings"].to_string();
    assert!(
        warnings.contains("clouds/000000.ply: 2 of 3602 points have a NaN or infinite coordinate and were dropped"),
        "{warnings}"
    );
    assert_eq!(r["views"][0]["status"], "anchor", "{}", r["views"]);
    // `awl info` on the file: the finite points' bounds, the warning on stderr
    let out = awl(&["info", scan.join("clouds/000000.ply").to_str().expect("utf-8")]);
    let t = text(&out);
    assert!(out.status.success(), "{t}");
    assert!(t.contains("points: 3600") && t.contains("bounds: x [-0.120, 0.116]") && !t.contains("empty"), "{t}");
    assert!(String::from_utf8_lossy(&out.stderr).contains("warning: ") && t.contains("2 of 3602 points"), "{t}");
}
