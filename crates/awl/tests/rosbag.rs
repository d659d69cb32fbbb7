//! `awl import rosbag` against bags written by an independent library: `tests/py/write_rosbag.py`
//! replays an awl-simulated scan folder as a ROS 2 recording with the Python `rosbags` package
//! (rosbag2 MCAP and sqlite3, real CDR): stills at the scan's views, the arm and the base moving
//! between them, TF at 50 Hz, the hand-eye on /tf_static, image stamps between TF samples, color
//! 15 ms after depth. Run with `AWL_PYTHON` (a Python with `rosbags`, numpy and Pillow); skipped,
//! saying so, when it is unset.
//!
//! Checked: the import finds exactly the scan's views, their poses equal the folder's within 1e-6,
//! the depth (16UC1 and 32FC1) and lossless color images equal the folder's pixel for pixel, the
//! fuse of the imported scan equals the folder's bit for bit, TF interpolation between samples
//! while moving is within 0.1 mm of the true motion, and the bad inputs (missing topic,
//! unsupported encoding, TF gap, truncated bag, no still period) are clear errors that write nothing.
#![cfg(feature = "sim")]

use std::path::{Path, PathBuf};
use std::process::Command;

use awl::io::image::{read_color_image, read_depth_png};
use awl::io::scan::read_scan;
use awl::pipeline::config::FuseConfig;
use awl::pipeline::fuse;
use awl::rosbag::cdr::decode_tf_message;
use awl::rosbag::tf::TfBuffer;
use awl::rosbag::{Bag, ImportParams, ImportReport, import_rosbag};
use awl::scan::{Scan, ViewData, ViewPose};
use awl::sim::{SceneKind, SimParams, simulate, write_simulation};
use awl::transform::{isometry_from_rows, pose_difference};
use nalgebra::Isometry3;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn python() -> Option<String> {
    let python = std::env::var("AWL_PYTHON").ok();
    if python.is_none() {
        eprintln!("AWL_PYTHON is unset: skipping the rosbag tests (they need a Python with rosbags, numpy, Pillow)");
    }
    python
}

/// A 4-view simulated box scan (realistic noise), written once per test into `dir/scan`.
fn scan_folder(dir: &Path) -> PathBuf {
    let sim = simulate(&SimParams { views: 4, seed: 3, ..SimParams::scan(SceneKind::Box) }).expect("simulate");
    let path = dir.join("scan");
    write_simulation(&path, &sim, false).expect("write the scan");
    path
}

/// Runs `write_rosbag.py` on `scan` into `bag` with `args`: 1.5 s stills, images at 2 Hz (the
/// moves take the 2-8 s a real base and arm need; a higher rate only makes the bags larger).
fn write_bag(python: &str, scan: &Path, bag: &Path, args: &[&str]) {
    let run = Command::new(python)
        .arg(repo().join("tests/py/write_rosbag.py"))
        .args([scan, bag])
        .args(["--image-hz", "2", "--still-s", "1.5"])
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {python}: {e}"));
    let text = format!("{}{}", String::from_utf8_lossy(&run.stdout), String::from_utf8_lossy(&run.stderr));
    assert!(run.status.success(), "write_rosbag.py {args:?} failed:\n{text}");
}

fn params(depth_min_m: f64, depth_max_m: f64) -> ImportParams {
    ImportParams { depth_min_m, depth_max_m, ..ImportParams::default() }
}

/// The scan's own depth range, so that the fuse of the import sees the same points.
fn scan_params(scan: &Scan) -> ImportParams {
    let camera = scan.camera.expect("camera");
    params(camera.depth_min_m, camera.depth_max_m)
}

fn chain(view: &ViewPose) -> (Isometry3<f64>, Isometry3<f64>) {
    match view {
        ViewPose::Chain { world_from_base, base_from_ee } => (*world_from_base, *base_from_ee),
        ViewPose::Camera { .. } => panic!("a chain pose"),
    }
}

fn worst(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    let (t, r) = pose_difference(a, b);
    t.max(r)
}

/// The imported scan against the folder: views, poses, hand-eye, intrinsics, base stops, pixels.
/// Returns the largest pose difference (metres or radians).
fn check_against_folder(original: &Scan, imported: &Scan, report: &ImportReport, lossless_color: bool) -> f64 {
    assert_eq!(imported.views.len(), original.views.len(), "exactly the still views");
    assert_eq!(report.views.len(), original.views.len());
    let mut largest =
        worst(&imported.ee_from_camera.expect("T_ee_camera"), &original.ee_from_camera.expect("T_ee_camera"));
    let (a, b) = (imported.camera.expect("camera"), original.camera.expect("camera"));
    assert_eq!(a.intrinsics, b.intrinsics, "CameraInfo K and D carry the intrinsics exactly");
    for (i, (got, want)) in imported.views.iter().zip(&original.views).enumerate() {
        let ((gw, ge), (ww, we)) = (chain(&got.pose), chain(&want.pose));
        largest = largest.max(worst(&gw, &ww)).max(worst(&ge, &we));
        let stop = |v: &awl::scan::ViewSpec| v.extra.get("base_stop").and_then(serde_json::Value::as_u64);
        assert_eq!(stop(got), stop(want), "view {i}: base_stop");
        let (ViewData::Depth { depth: gd, color: gc }, ViewData::Depth { depth: wd, color: wc }) =
            (&got.data, &want.data)
        else {
            panic!("depth views")
        };
        let depth = read_depth_png(&imported.dir.join(gd)).expect("imported depth");
        assert!(depth == read_depth_png(&original.dir.join(wd)).expect("depth"), "view {i}: the depth pixels");
        let color = read_color_image(&imported.dir.join(gc.as_ref().expect("color"))).expect("imported color");
        let want_color = read_color_image(&original.dir.join(wc.as_ref().expect("color"))).expect("color");
        if lossless_color {
            assert!(color == want_color, "view {i}: the color pixels");
        } else {
            let diff: f64 =
                color.data.iter().zip(&want_color.data).map(|(a, b)| f64::from(a[1].abs_diff(b[1]))).sum::<f64>()
                    / color.data.len() as f64;
            println!("view {i}: JPEG color {diff:.2} levels mean absolute difference (green)");
            // JPEG quality 95: measured 0.9-1.0 levels
            assert!(diff < 3.0, "view {i}: JPEG color {diff} levels off");
        }
        let offset = report.views[i].color_offset_ms.expect("color paired");
        assert!((offset - 15.0).abs() < 1e-3, "view {i}: color {offset} ms after depth");
    }
    largest
}

/// MCAP and sqlite3, 16UC1 and 32FC1 depth, raw rgb8 / bgr8 and compressed JPEG / PNG color: the
/// scan's views and poses, the same depth pixels; the fuse of the MCAP 16UC1 import bit for bit
/// the folder's; TF interpolation while moving within 0.1 mm.
#[test]
fn imports_bags_written_by_rosbags() {
    let Some(python) = python() else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    let scan_dir = scan_folder(dir.path());
    let original = read_scan(&scan_dir).expect("read the scan");
    let variants = [
        ("mcap", "16UC1", "rgb8", true),
        ("sqlite3", "32FC1", "bgr8", true),
        ("mcap", "32FC1", "jpeg", false),
        ("sqlite3", "16UC1", "png", true),
    ];
    let mut imported_dirs = Vec::new();
    for (storage, depth, color, lossless) in variants {
        let name = format!("{storage}-{depth}-{color}");
        let bag = dir.path().join(format!("bag-{name}"));
        let truth = dir.path().join(format!("truth-{name}.json"));
        write_bag(
            &python,
            &scan_dir,
            &bag,
            &["--storage", storage, "--depth", depth, "--color", color, "--truth", truth.to_str().expect("utf-8")],
        );
        let out = dir.path().join(format!("imported-{name}"));
        // the bag folder for the first two, the bare file for the others
        let input = if imported_dirs.len() < 2 {
            bag.clone()
        } else {
            let file = std::fs::read_dir(&bag)
                .expect("bag")
                .filter_map(|e| e.ok().map(|e| e.path()))
                .find(|p| matches!(p.extension().and_then(|e| e.to_str()), Some("mcap" | "db3")));
            file.expect("a bag file")
        };
        let report =
            import_rosbag(&input, &out, &scan_params(&original), &mut |_| {}).unwrap_or_else(|e| panic!("{name}: {e}"));
        let imported = read_scan(&out).expect("read the import");
        let largest = check_against_folder(&original, &imported, &report, lossless);
        println!("{name}: {} views, poses within {largest:.2e} of the folder's", imported.views.len());
        // measured 3.3e-16 on all four (the quaternion round trip through TF)
        assert!(largest < 1e-6, "{name}: poses {largest} off");
        let skipped: usize = report.depth_skipped.values().sum();
        assert_eq!(skipped + report.views.len(), report.depth_images, "{name}: every depth image counted");
        if storage == "mcap" && depth == "16UC1" {
            check_interpolation(&input, &truth, original.ee_from_camera.expect("hand-eye"));
        }
        imported_dirs.push(out);
    }
    // the fuse of the import and of the folder: the same model, bit for bit
    let config = FuseConfig::fast();
    let want = fuse(&original, &config, &|_, _, _| {}).expect("fuse the folder");
    for out in &imported_dirs[..2] {
        let got = fuse(&read_scan(out).expect("import"), &config, &|_, _, _| {}).expect("fuse the import");
        println!("fuse: {} points from the folder, {} from {}", want.model.len(), got.model.len(), out.display());
        // measured 7667 points (FuseConfig::fast, 4 views)
        assert!(want.model.len() > 5_000, "{} model points", want.model.len());
        assert!(got.model.points == want.model.points, "{}: the fused points differ", out.display());
        assert!(got.model.colors == want.model.colors, "{}: the fused colors differ", out.display());
    }
}

/// The bag's TF, looked up at stamps between its 50 Hz samples while the base and the arm move,
/// against the writer's true motion there: the camera within 0.1 mm.
fn check_interpolation(bag: &Path, truth: &Path, ee_from_camera: Isometry3<f64>) {
    let bag = Bag::open(bag).expect("open");
    let mut tf = TfBuffer::new(0.5);
    bag.for_each(&|t| t == "/tf" || t == "/tf_static", &mut |_| {}, &mut |m| {
        for t in decode_tf_message(m.data).expect("TF") {
            tf.add(
                &t.header.frame_id,
                &t.child_frame_id,
                t.header.stamp_ns,
                t.parent_from_child().expect("rigid"),
                m.topic == "/tf_static",
            );
        }
        Ok(())
    })
    .expect("read TF");
    tf.finish();
    let doc: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(truth).expect("truth")).expect("json");
    let moving = doc["moving"].as_array().expect("moving");
    assert!(moving.len() >= 20, "{} moving stamps", moving.len());
    let rows =
        |v: &serde_json::Value| isometry_from_rows(&serde_json::from_value(v.clone()).expect("4x4")).expect("rigid");
    let mut worst_mm: f64 = 0.0;
    for m in moving {
        let t = m["stamp_ns"].as_i64().expect("stamp");
        assert!(t % 20_000_000 != 0, "a stamp between TF samples");
        let want = rows(&m["T_world_base"]) * rows(&m["T_base_ee"]) * ee_from_camera;
        let got = tf.lookup("map", "camera_color_optical_frame", t).expect("lookup");
        worst_mm = worst_mm.max((got.translation.vector - want.translation.vector).norm() * 1e3);
    }
    println!("TF interpolation while moving: camera within {worst_mm:.4} mm of the true motion");
    // measured 0.0150 mm (TF at 50 Hz; moves of 5-8 s at up to 0.5 m/s and 45 deg/s)
    assert!(worst_mm < 0.1, "interpolation error {worst_mm} mm");
}

/// Asserts `result` failed with a message holding every one of `needles`, and nothing was written.
fn assert_refused(result: awl::Result<ImportReport>, out: &Path, needles: &[&str]) {
    let message = match result {
        Ok(_) => panic!("expected an error with {needles:?}"),
        Err(e) => e.to_string(),
    };
    println!("refused: {message}");
    for needle in needles {
        assert!(message.contains(needle), "`{needle}` not in: {message}");
    }
    assert!(!out.exists(), "{} was written", out.display());
    let parent = out.parent().expect("parent");
    let leftovers: Vec<_> = std::fs::read_dir(parent)
        .expect("dir")
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains(".tmp-"))
        .collect();
    assert!(leftovers.is_empty(), "temporary folders left: {leftovers:?}");
}

/// Missing topic, unsupported encoding, TF gap, truncated MCAP and sqlite3, no still period.
#[test]
fn bad_bags_are_refused_naming_the_topic_frame_or_file() {
    let Some(python) = python() else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    let sim = simulate(&SimParams { views: 2, seed: 5, ..SimParams::scan(SceneKind::Box) }).expect("simulate");
    let scan = dir.path().join("scan");
    write_simulation(&scan, &sim, false).expect("write");
    let out = dir.path().join("out");
    let base = params(0.2, 3.0);

    let good = dir.path().join("good");
    write_bag(&python, &scan, &good, &["--storage", "mcap"]);
    let missing = ImportParams { depth_topic: Some("/camera/nope".into()), ..base.clone() };
    assert_refused(
        import_rosbag(&good, &out, &missing, &mut |_| {}),
        &out,
        &["--depth-topic /camera/nope", "no such topic", "/camera/depth/image_rect_raw (sensor_msgs/msg/Image"],
    );
    let wrong = ImportParams { ee_frame: "flange".into(), ..base.clone() };
    assert_refused(
        import_rosbag(&good, &out, &wrong, &mut |_| {}),
        &out,
        &["`base_link` -> `flange`", "no TF path", "tool0"],
    );

    let yuv = dir.path().join("yuv");
    write_bag(&python, &scan, &yuv, &["--storage", "sqlite3", "--color", "yuv422"]);
    assert_refused(
        import_rosbag(&yuv, &out, &base, &mut |_| {}),
        &out,
        &["/camera/color/image_raw", "unsupported color encoding `yuv422`"],
    );

    let gap = dir.path().join("gap");
    write_bag(&python, &scan, &gap, &["--bad", "tf-gap"]);
    assert_refused(
        import_rosbag(&gap, &out, &base, &mut |_| {}),
        &out,
        &["TF gap", "`map` -> `base_link`", "no sample between"],
    );

    let moving = dir.path().join("moving");
    write_bag(&python, &scan, &moving, &["--bad", "no-still", "--storage", "sqlite3"]);
    assert_refused(
        import_rosbag(&moving, &out, &base, &mut |_| {}),
        &out,
        &["no still period", "--still-s 0.5", "base_link` -> `tool0"],
    );

    for (storage, ext) in [("mcap", "mcap"), ("sqlite3", "db3")] {
        let bag = dir.path().join(format!("whole-{storage}"));
        write_bag(&python, &scan, &bag, &["--storage", storage]);
        let file = bag.join(format!("whole-{storage}.{ext}"));
        let bytes = std::fs::read(&file).expect("bag file");
        let cut = dir.path().join(format!("cut.{ext}"));
        std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).expect("write the cut file");
        assert_refused(import_rosbag(&cut, &out, &base, &mut |_| {}), &out, &["cut.", "truncated or damaged"]);
    }
    // and the good bag imports, for contrast
    let report = import_rosbag(&good, &out, &base, &mut |_| {}).expect("the good bag");
    assert_eq!(report.views.len(), 2);
}
