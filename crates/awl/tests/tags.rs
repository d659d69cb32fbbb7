//! AprilTag detection and tag pose (`awl::tag`) against real photos (`shared/data/dt_apriltags`, with
//! pupil-apriltags as the independent reference), against the truth of the independent simulator
//! (`shared/data/sim_reference`) and of awl's own simulator, plus exact synthetic poses and bad input.
//!
//! Shared data: `$AWL_SHARED_DATA` or `<workspace>/../shared/data` (fails, not skips, when missing).
//! The pupil-apriltags comparison runs `tests/py/check_tags.py` with `$AWL_PYTHON`; it is skipped
//! with a message only when `AWL_PYTHON` is unset. Run in release: `cargo test --release -p awl --test tags`.
#![cfg(feature = "apriltag")]

mod common;
mod tags_common;

use std::process::Command;

use awl::Error;
use awl::camera::Intrinsics;
use awl::image::ColorImage;
use awl::io::image::read_color_png;
use awl::tag::{
    AprilTagDetector, DetectorParams, GrayView, MIN_DEPTH_POINTS, TagDetection, TagDetector, estimate_tag_pose,
    score_depth, tag_corners_m,
};
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::Value;
use tags_common::{data_dir, detect_file, detector, stats};

/// K of a `test_info.yaml` set, row-major 3x3 (no distortion: the images are rectified).
fn k_of(k: [f64; 9], width: u32, height: u32) -> Intrinsics {
    Intrinsics { width, height, fx: k[0], fy: k[4], cx: k[2], cy: k[5], distortion: [0.0; 5] }
}

// From shared/data/dt_apriltags/test_info.yaml.
const K_SAMPLE: [f64; 9] =
    [336.7755634193813, 0.0, 333.3575643300718, 0.0, 336.02729840829176, 212.77376312080065, 0.0, 0.0, 1.0];
const K_ROTATION: [f64; 9] = [329.8729619143081, 0.0, 528.0, 0.0, 332.94611303946357, 396.0, 0.0, 0.0, 1.0];
const K_MULTIPLE: [f64; 9] =
    [338.563277422543, 0.0, 336.45495347495824, 0.0, 338.939280638548, 230.486982216255, 0.0, 0.0, 1.0];
const DT_TAG_SIZE_M: f64 = 0.065;

/// (file, K, size, ids SOURCES.md / the reference detector list for it).
fn dt_images() -> Vec<(&'static str, Intrinsics, Vec<u32>)> {
    vec![
        ("test_image.png", k_of(K_SAMPLE, 640, 480), vec![60, 82, 318, 328, 387]),
        ("test_image_multiple_01.png", k_of(K_MULTIPLE, 640, 480), vec![22, 24, 58, 85, 144, 198]),
        ("test_image_multiple_02.png", k_of(K_MULTIPLE, 640, 480), vec![22, 24, 85, 144, 198]),
        ("test_image_rotation_-30.png", k_of(K_ROTATION, 1056, 792), vec![76]),
        ("test_image_rotation_0.png", k_of(K_ROTATION, 1056, 792), vec![76]),
        ("test_image_rotation_30.png", k_of(K_ROTATION, 1056, 792), vec![76]),
    ]
}

fn dt_detections(file: &str) -> Vec<TagDetection> {
    detect_file(&data_dir().join("dt_apriltags").join(file))
}

#[test]
fn every_listed_tag_in_the_real_photos_is_found_with_its_id() {
    let mut found = 0;
    let mut total = 0;
    for (file, _, ids) in dt_images() {
        let detections = dt_detections(file);
        let got: Vec<u32> = detections.iter().map(|d| d.id).collect();
        println!(
            "{file}: ids {got:?}, hamming {:?}, margins {:?}",
            detections.iter().map(|d| d.hamming).collect::<Vec<_>>(),
            detections.iter().map(|d| d.decision_margin.round()).collect::<Vec<_>>()
        );
        total += ids.len();
        found += ids.iter().filter(|id| got.contains(id)).count();
        assert_eq!(got, ids, "{file}: exactly the listed ids, each once, no false positive");
    }
    println!("recall {found}/{total}");
    // The C detector's worker threads do not change the result.
    let image = read_color_png(&data_dir().join("dt_apriltags/test_image_multiple_01.png")).expect("png");
    let mut two = AprilTagDetector::new(&DetectorParams { threads: 2, ..Default::default() }).expect("detector");
    assert_eq!(two.detect_color(&image).expect("detect"), dt_detections("test_image_multiple_01.png"));
}

fn run_pupil(files: &[&str], k: &Intrinsics) -> Option<Value> {
    let Ok(python) = std::env::var("AWL_PYTHON") else {
        println!("SKIPPED: AWL_PYTHON is not set (a Python with pupil-apriltags, see tests/py/requirements.txt)");
        return None;
    };
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/py/check_tags.py");
    let mut cmd = Command::new(&python);
    cmd.arg(script).args(["--decimate", "1"]);
    for (name, v) in [("--fx", k.fx), ("--fy", k.fy), ("--cx", k.cx), ("--cy", k.cy), ("--tag-size", DT_TAG_SIZE_M)] {
        cmd.arg(name).arg(v.to_string());
    }
    cmd.args(files.iter().map(|f| data_dir().join("dt_apriltags").join(f)));
    let out = cmd.output().unwrap_or_else(|e| panic!("cannot run {python}: {e}"));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "check_tags.py failed ({}): {stderr}", out.status);
    Some(serde_json::from_slice(&out.stdout).expect("check_tags.py prints JSON"))
}

fn array<const N: usize>(v: &Value) -> [f64; N] {
    let values: Vec<f64> = v.as_array().expect("array").iter().map(|x| x.as_f64().expect("number")).collect();
    values.try_into().expect("length")
}

#[test]
fn corners_and_poses_match_pupil_apriltags_on_the_real_photos() {
    let mut corner_err = Vec::new();
    let (mut t_err_mm, mut r_err_deg) = (Vec::new(), Vec::new());
    for (file, k, ids) in dt_images() {
        let Some(reference) = run_pupil(&[file], &k) else { return };
        let theirs = reference["images"].as_object().expect("images").values().next().expect("one image");
        let theirs = theirs.as_array().expect("detections");
        let ours = dt_detections(file);
        assert_eq!(theirs.len(), ids.len(), "{file}: the reference finds every listed tag too");
        for t in theirs {
            let id = t["id"].as_u64().expect("id") as u32;
            let ours = ours.iter().find(|d| d.id == id).unwrap_or_else(|| panic!("{file}: we miss id {id}"));
            let corners = t["corners"].as_array().expect("corners");
            for (c, o) in corners.iter().zip(&ours.corners_px) {
                // The C library's pixel centres are at +0.5; ours at integers.
                let [u, v] = array::<2>(c);
                let e = ((u - 0.5 - o[0]).powi(2) + (v - 0.5 - o[1]).powi(2)).sqrt();
                assert!(e < 0.5, "{file} id {id}: corner {o:?} vs reference ({u}, {v}) - 0.5: {e:.3} px");
                corner_err.push(e);
            }
            // Pose: the reference's AprilTag frame (y down, z into the face) is ours turned 180 deg about x.
            // It sees pixel centres at +0.5 with the same K: shift our corners to compare like with like.
            let shifted = ours.corners_px.map(|[u, v]| [u + 0.5, v + 0.5]);
            let pose = estimate_tag_pose(&shifted, &k, DT_TAG_SIZE_M).expect("pose");
            let rows: Vec<[f64; 3]> = t["pose_R"].as_array().expect("R").iter().map(array::<3>).collect();
            let r = Matrix3::from_fn(|i, j| rows[i][j]);
            let flip = Rotation3::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
            let theirs_pose = Isometry3::from_parts(
                Vector3::from(array::<3>(&t["pose_t"])).into(),
                UnitQuaternion::from_matrix(&r) * UnitQuaternion::from_rotation_matrix(&flip).inverse(),
            );
            let ours_pose = pose.best.camera_from_tag;
            let dt = (ours_pose.translation.vector - theirs_pose.translation.vector).norm() * 1e3;
            let dr = ours_pose.rotation.angle_to(&theirs_pose.rotation).to_degrees();
            println!("{file} id {id}: pose vs reference {dt:.2} mm, {dr:.2} deg; ambiguity {:?}", pose.ambiguity());
            t_err_mm.push(dt);
            r_err_deg.push(dr);
        }
    }
    let (median, max) = stats(&mut corner_err);
    println!("corners vs pupil-apriltags (-0.5 px): median {median:.4} px, max {max:.4} px over {}", corner_err.len());
    let (tm, tx) = stats(&mut t_err_mm);
    let (rm, rx) = stats(&mut r_err_deg);
    println!(
        "pose vs pupil-apriltags: translation median {tm:.2} mm max {tx:.2}; rotation median {rm:.2} deg max {rx:.2}"
    );
    // Measured: median 0.16 mm / 0.11 deg, max 2.9 mm / 3.5 deg (id 24 of multiple_02, 60 px wide at
    // 0.5 m). The reference minimises object-space error by orthogonal iteration, we minimise image
    // error: on small, nearly frontal tags the two optima differ by a few degrees.
    assert!(tx < 5.0 && rx < 5.0, "pose vs pupil-apriltags: {tx:.2} mm, {rx:.2} deg");
    assert!(tm < 0.5 && rm < 0.5, "pose vs pupil-apriltags, medians: {tm:.2} mm, {rm:.2} deg");
}

#[test]
fn the_30_degree_steps_between_the_rotation_photos_are_recovered() {
    let k = k_of(K_ROTATION, 1056, 792);
    let poses: Vec<Isometry3<f64>> = [
        "test_image_rotation_-30.png",
        "test_image_rotation_0.png",
        "test_image_rotation_30.png",
    ]
    .iter()
    .map(|file| {
        let d = dt_detections(file);
        assert_eq!(d.len(), 1, "{file}: one tag");
        let pose = estimate_tag_pose(&d[0].corners_px, &k, DT_TAG_SIZE_M).expect("pose");
        let p = pose.best.camera_from_tag;
        let z = p.rotation * Vector3::z();
        println!(
            "{file}: tag at {:.1} mm, normal {z:.3?}, yaw about camera y {:.1} deg, rmse {:.3} px, ambiguity {:?}",
            p.translation.vector.norm() * 1e3,
            (-z.x).atan2(-z.z).to_degrees(),
            pose.best.rmse_px,
            pose.ambiguity()
        );
        // The tag faces the camera: its z axis (out of the face) points back toward the camera.
        assert!(z.z < -0.8, "{file}: tag z axis {z:?} must point toward the camera");
        p
    })
    .collect();
    for (a, b) in [(0, 1), (1, 2)] {
        let relative = poses[a].rotation.inverse() * poses[b].rotation;
        let step = relative.angle().to_degrees();
        let axis = relative.axis().map_or(Vector3::zeros(), |a| a.into_inner());
        println!("step {a}->{b}: {step:.2} deg about tag-frame axis {axis:.3?}");
        // The stand turns about its vertical axis: the tag's y axis (x right, y up, z out).
        assert!(axis.y.abs() > 0.98, "step {a}->{b}: rotation axis {axis:?} should be the tag's vertical y axis");
        // Measured 28.0 and 27.2 deg; pupil-apriltags gives the same within 1.6 deg, and SOURCES.md
        // measured yaws of +30.0 / +1.2 / -26.6 deg: the stand's angles are nominal (+-3 deg each),
        // so a step is 30 +- 3.5 deg here, not +-2.
        assert!((step - 30.0).abs() < 3.5, "rotation step {a}->{b}: {step:.2} deg, want 30 +- 3.5");
    }
}

/// The rotation photos' setup rendered exactly (an independent ray caster, not awl's simulator):
/// tag36h11 id 0 (the canonical bitmap from `shared/data/apriltag_tag36h11`), 6.5 cm, on a white
/// 12 cm board 0.205 m in front of the photos' camera (K_ROTATION, 1056 x 792), turned -30, 0 and
/// +30 deg about its vertical axis; 4 x 4 samples per pixel, grey beyond the board.
fn render_turned_tag(yaw_deg: f64) -> (ColorImage, Isometry3<f64>) {
    let k = k_of(K_ROTATION, 1056, 792);
    let bitmap = read_color_png(&data_dir().join("apriltag_tag36h11/tag36_11_00000.png")).expect("tag bitmap");
    let module = DT_TAG_SIZE_M / 8.0;
    // tag x right, y up, z toward the camera (camera x right, y down, z forward), then the turn
    let facing = Rotation3::from_matrix_unchecked(Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0));
    let turn = Rotation3::from_axis_angle(&Vector3::y_axis(), yaw_deg.to_radians());
    let camera_from_tag = Isometry3::from_parts(
        Vector3::new(0.0, 0.0, 0.205).into(),
        UnitQuaternion::from_rotation_matrix(&(facing * turn)),
    );
    let tag_from_camera = camera_from_tag.inverse();
    let origin = tag_from_camera.translation.vector;
    let shade = |u: f64, v: f64| {
        let d = tag_from_camera.rotation * Vector3::new((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0);
        let t = -origin.z / d.z;
        let (x, y) = (origin.x + t * d.x, origin.y + t * d.y);
        if t <= 0.0 || x.abs() > 0.06 || y.abs() > 0.06 {
            return 128.0;
        }
        let (col, row) = ((x / module + 5.0).floor(), (5.0 - y / module).floor());
        if (0.0..10.0).contains(&col) && (0.0..10.0).contains(&row) {
            f64::from(bitmap.data[row as usize * 10 + col as usize][0])
        } else {
            255.0
        }
    };
    let mut data = Vec::with_capacity(1056 * 792);
    for v in 0..792 {
        for u in 0..1056 {
            let mut sum = 0.0;
            for i in 0..4 {
                for j in 0..4 {
                    sum += shade(u as f64 + (i as f64 + 0.5) / 4.0 - 0.5, v as f64 + (j as f64 + 0.5) / 4.0 - 0.5);
                }
            }
            let g = (sum / 16.0).round() as u8;
            data.push([g, g, g]);
        }
    }
    (ColorImage { width: 1056, height: 792, data }, camera_from_tag)
}

#[test]
fn the_30_degree_steps_are_recovered_on_rendered_photos() {
    // The photos' angles are nominal (see the test above): the same setup rendered with exact
    // angles checks the 2 deg of the issue.
    let k = k_of(K_ROTATION, 1056, 792);
    let mut detector = detector();
    let poses: Vec<(Isometry3<f64>, Isometry3<f64>)> = [-30.0, 0.0, 30.0]
        .iter()
        .map(|&yaw| {
            let (image, truth) = render_turned_tag(yaw);
            let d = detector.detect_color(&image).expect("detect");
            assert!(d.len() == 1 && d[0].id == 0, "yaw {yaw}: {} detections", d.len());
            let pose = estimate_tag_pose(&d[0].corners_px, &k, DT_TAG_SIZE_M).expect("pose").best.camera_from_tag;
            let (dt, dr) = awl::transform::pose_difference(&pose, &truth);
            println!("rendered yaw {yaw}: pose error {:.2} mm, {:.3} deg", dt * 1e3, dr.to_degrees());
            // measured 0.35 / 0.88 / 0.38 deg at -30 / 0 / +30: the frontal tag's tilt is the least
            // determined; steps 30.36 and 28.96 deg
            assert!(dt < 1e-3 && dr.to_degrees() < 1.5, "yaw {yaw}: {:.2} mm {:.3} deg", dt * 1e3, dr.to_degrees());
            (pose, truth)
        })
        .collect();
    for (a, b) in [(0, 1), (1, 2)] {
        let step = (poses[a].0.rotation.inverse() * poses[b].0.rotation).angle().to_degrees();
        println!("rendered step {a}->{b}: {step:.3} deg (truth 30)");
        assert!((step - 30.0).abs() < 2.0, "rendered step {a}->{b}: {step:.3} deg");
    }
}

/// The canonical tag36h11 bitmaps (10 x 10 modules, `shared/data/apriltag_tag36h11`) scaled 20x
/// onto a white 400 x 300 canvas at offset (100, 50): the black border's outer corners are then at
/// exact pixel edges, e.g. u = 100 + 20 - 0.5 in the pixel-centre convention. Returns the worst
/// corner or centre coordinate error over the 10 ids.
fn canonical_bitmap_error(params: &DetectorParams) -> f64 {
    let (scale, ox, oy, w, h) = (20usize, 100usize, 50usize, 400u32, 300u32);
    let mut worst = 0.0_f64;
    let mut detector = AprilTagDetector::new(params).expect("detector");
    for id in 0..10u32 {
        let bitmap =
            read_color_png(&data_dir().join(format!("apriltag_tag36h11/tag36_11_{id:05}.png"))).expect("bitmap");
        let mut data = vec![[255u8; 3]; (w * h) as usize];
        for v in 0..10 * scale {
            for u in 0..10 * scale {
                data[(oy + v) * w as usize + ox + u] = bitmap.data[(v / scale) * 10 + u / scale];
            }
        }
        let image = ColorImage { width: w, height: h, data };
        let found = detector.detect_color(&image).expect("detect");
        assert_eq!(found.len(), 1, "bitmap {id}: one tag");
        assert_eq!((found[0].id, found[0].hamming), (id, 0), "bitmap {id}");
        // Outer corners of the black border (modules 1..9), AprilTag order: bottom-left, bottom-right,
        // top-right, top-left as read upright (v grows downward).
        let (lo_u, hi_u) = ((ox + scale) as f64 - 0.5, (ox + 9 * scale) as f64 - 0.5);
        let (lo_v, hi_v) = ((oy + scale) as f64 - 0.5, (oy + 9 * scale) as f64 - 0.5);
        let expected = [[lo_u, hi_v], [hi_u, hi_v], [hi_u, lo_v], [lo_u, lo_v]];
        for (got, want) in found[0].corners_px.iter().zip(&expected) {
            worst = worst.max((got[0] - want[0]).abs().max((got[1] - want[1]).abs()));
        }
        let c = found[0].centre_px;
        worst = worst.max((c[0] - (lo_u + hi_u) / 2.0).abs().max((c[1] - (lo_v + hi_v) / 2.0).abs()));
    }
    worst
}

#[test]
fn canonical_bitmaps_decode_with_corners_on_the_exact_pixel_edges() {
    // Without edge refinement the quad fit lands on the exact edges (measured 0.02 px): this pins the
    // pixel-centre convention, which would be 0.5 px off if the C library's +0.5 were not removed.
    let plain = canonical_bitmap_error(&DetectorParams { refine_edges: false, ..Default::default() });
    // With it (the default), the gradient sampling is biased on a perfectly sharp step: measured
    // 0.21 px. On blurred camera-like edges it is the more accurate of the two (sim_reference box
    // views: median 0.17 vs 0.21 px, no mean offset vs -0.05 px), hence the default.
    let refined = canonical_bitmap_error(&DetectorParams::default());
    println!(
        "canonical bitmaps, worst coordinate error: {plain:.4} px without edge refinement, {refined:.4} px with it"
    );
    assert!(plain < 0.05, "unrefined corners {plain:.4} px from the exact pixel edges");
    assert!(refined < 0.25, "refined corners {refined:.4} px from the exact pixel edges");
}

/// The default contrast floor (`min_white_black_diff` 20) finds what the C library's 5 finds, bit
/// for bit, in the real photos and the other simulator's views (scan and shots); in the same views
/// dimmed to 10 % only the C library's floor (`DetectorParams::thorough`) still finds the tags.
#[test]
fn the_default_contrast_floor_finds_what_the_c_librarys_finds() {
    let default = DetectorParams::default();
    let thorough = default.thorough().expect("a higher floor than the C library's");
    assert_eq!(thorough.min_white_black_diff, 5);
    assert_eq!(thorough.thorough(), None);
    let (mut fast, mut c_floor) = (detector(), AprilTagDetector::new(&thorough).expect("detector"));
    let reference = data_dir().join("sim_reference");
    let mut files: Vec<std::path::PathBuf> =
        dt_images().iter().map(|(f, ..)| data_dir().join("dt_apriltags").join(f)).collect();
    for folder in ["box_seed1", "shell_seed1", "box_seed1_shot_tilt30"] {
        let dir = reference.join(folder).join("color");
        let mut pngs: Vec<_> = std::fs::read_dir(&dir).expect("color dir").map(|e| e.expect("entry").path()).collect();
        pngs.sort();
        files.extend(pngs);
    }
    let (mut found, mut dim_fast, mut dim_c) = (0, 0, 0);
    for path in &files {
        let image = read_color_png(path).expect("png");
        let want = c_floor.detect_color(&image).expect("detect");
        assert_eq!(fast.detect_color(&image).expect("detect"), want, "{}", path.display());
        found += want.len();
        if path.starts_with(&reference) {
            let dim = common::dimmed(&image, 0.1);
            dim_fast += fast.detect_color(&dim).expect("detect").len();
            dim_c += c_floor.detect_color(&dim).expect("detect").len();
        }
    }
    println!(
        "{} images, {found} detections; dimmed to 10 %: {dim_fast} at the default floor, {dim_c} at 5",
        files.len()
    );
    assert!(files.len() >= 30 && found >= 25, "{} images, {found} detections", files.len());
    assert!(dim_fast == 0 && dim_c >= 5, "dimmed: {dim_fast} at the default floor, {dim_c} at the C library's");
}

#[test]
fn images_without_tags_give_an_empty_list() {
    let mut detector = tags_common::detector();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let noise: Vec<u8> = (0..640 * 480).map(|_| rng.random_range(100..156)).collect();
    assert!(detector.detect_gray(GrayView::new(640, 480, &noise).expect("view")).expect("detect").is_empty());
    let flat = ColorImage { width: 640, height: 480, data: vec![[128, 128, 128]; 640 * 480] };
    assert!(detector.detect_color(&flat).expect("detect").is_empty());
    let tiny = ColorImage { width: 4, height: 3, data: vec![[0, 0, 0]; 12] };
    assert!(detector.detect_color(&tiny).expect("detect").is_empty());
    // A real photo without tags (TUM RGB-D, Kinect).
    let tum = read_color_png(&data_dir().join("open3d_testdata/RGBD/other_formats/TUM_color.png")).expect("TUM");
    assert!(detector.detect_color(&tum).expect("detect").is_empty());
}

#[test]
fn bad_images_and_parameters_are_typed_errors() {
    let mut detector = tags_common::detector();
    let short = ColorImage { width: 640, height: 480, data: vec![[0, 0, 0]; 640 * 479] };
    let err = detector.detect_color(&short).expect_err("wrong size");
    assert!(matches!(err, Error::Invalid { .. }) && err.to_string().contains("307200"), "{err}");
    assert!(matches!(GrayView::new(10, 10, &[0; 99]), Err(Error::Invalid { .. })));
    assert!(matches!(GrayView::new(0, 10, &[]), Err(Error::Invalid { .. })));
    let dir = tempfile::tempdir().expect("tempdir");
    let bytes = std::fs::read(data_dir().join("dt_apriltags/test_image.png")).expect("png");
    let corrupt = dir.path().join("corrupt.png");
    std::fs::write(&corrupt, &bytes[..bytes.len() / 2]).expect("write");
    let err = read_color_png(&corrupt).expect_err("truncated PNG");
    assert!(matches!(err, Error::Format { .. }) && err.to_string().contains("corrupt.png"), "{err}");
    for params in [
        DetectorParams { quad_decimate: 0.0, ..Default::default() },
        DetectorParams { max_hamming: 4, ..Default::default() },
        DetectorParams { threads: 0, ..Default::default() },
    ] {
        assert!(matches!(AprilTagDetector::new(&params), Err(Error::Invalid { .. })), "{params:?}");
    }
    let k = k_of(K_SAMPLE, 640, 480);
    let square = [[100.0, 200.0], [200.0, 200.0], [200.0, 100.0], [100.0, 100.0]];
    for size in [0.0, -0.1, f64::NAN] {
        assert!(matches!(estimate_tag_pose(&square, &k, size), Err(Error::Invalid { .. })), "size {size}");
    }
    let collinear = [[100.0, 100.0], [150.0, 100.0], [200.0, 100.0], [250.0, 100.0]];
    assert!(matches!(estimate_tag_pose(&collinear, &k, 0.1), Err(Error::Invalid { .. })));
    let nan = [[f64::NAN, 100.0], [150.0, 100.0], [200.0, 150.0], [250.0, 100.0]];
    assert!(matches!(estimate_tag_pose(&nan, &k, 0.1), Err(Error::Invalid { .. })));
}

/// Exact corners of seeded random poses through a distorting lens: the best solution is the truth
/// (to 1e-7) in awl's tag frame, and with 0.2 px of corner noise it stays within a few mm / degrees.
#[test]
fn synthetic_poses_through_a_distorting_lens_are_recovered() {
    let k = Intrinsics {
        width: 640,
        height: 480,
        fx: 610.0,
        fy: 612.0,
        cx: 318.0,
        cy: 242.0,
        distortion: [-0.12, 0.06, 0.001, -0.0008, -0.01],
    };
    let size = 0.08;
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut noisy_errors = Vec::new();
    for case in 0..200 {
        // Tag 0.3-1.0 m ahead, facing the camera within 60 degrees, any roll.
        let z_toward_camera = -Vector3::new(rng.random_range(-0.8..0.8), rng.random_range(-0.8..0.8), 1.0).normalize();
        let tilt = UnitQuaternion::rotation_between(&Vector3::z(), &z_toward_camera).expect("tilt");
        let roll = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), rng.random_range(-3.1..3.1));
        let t = Vector3::new(rng.random_range(-0.1..0.1), rng.random_range(-0.08..0.08), rng.random_range(0.3..1.0));
        let truth = Isometry3::from_parts(t.into(), tilt * roll);
        let corners = tag_corners_m(size).map(|p| {
            let px = k.project(&(truth * p)).expect("in front");
            [px.x, px.y]
        });
        let pose = estimate_tag_pose(&corners, &k, size).expect("pose");
        let dt = (pose.best.camera_from_tag.translation.vector - t).norm();
        let dr = pose.best.camera_from_tag.rotation.angle_to(&truth.rotation);
        assert!(dt < 1e-7 && dr < 1e-7 && pose.best.rmse_px < 1e-6, "case {case}: {dt:e} m, {dr:e} rad, {pose:?}");
        let noisy = corners.map(|[u, v]| [u + rng.random_range(-0.2..0.2), v + rng.random_range(-0.2..0.2)]);
        let pose = estimate_tag_pose(&noisy, &k, size).expect("pose");
        // Compare the solution nearer the truth: with noise, near-frontal views may rank them either way.
        let err = |p: &Isometry3<f64>| {
            ((p.translation.vector - t).norm() * 1e3, p.rotation.angle_to(&truth.rotation).to_degrees())
        };
        let mut candidates = vec![err(&pose.best.camera_from_tag)];
        candidates.extend(pose.second.map(|s| err(&s.camera_from_tag)));
        noisy_errors.push(candidates.into_iter().min_by(|a, b| a.1.total_cmp(&b.1)).expect("one"));
    }
    let (mut mm, mut deg): (Vec<f64>, Vec<f64>) = noisy_errors.into_iter().unzip();
    let ((mm_med, mm_max), (deg_med, deg_max)) = (stats(&mut mm), stats(&mut deg));
    println!(
        "0.2 px corner noise, 200 poses at 0.3-1 m: {mm_med:.2} / {mm_max:.2} mm, {deg_med:.2} / {deg_max:.2} deg (median / max)"
    );
    assert!(mm_max < 15.0 && deg_max < 5.0, "noisy poses: {mm_max:.2} mm, {deg_max:.2} deg");
}

/// Small, distant, nearly frontal tags with noisy corners: the corners often rank the wrong
/// solution first. Depth points on the true tag plane (1 mm noise) must pick the right one.
#[test]
fn depth_points_resolve_the_planar_ambiguity() {
    let k = Intrinsics { width: 640, height: 480, fx: 615.0, fy: 615.0, cx: 320.0, cy: 240.0, distortion: [0.0; 5] };
    let size = 0.05;
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let (mut ambiguous, mut flipped, mut corners_right, mut decisive, mut depth_right) = (0, 0, 0, 0, 0);
    for case in 0..300 {
        let z_toward_camera = -Vector3::new(rng.random_range(-0.3..0.3), rng.random_range(-0.3..0.3), 1.0).normalize();
        let tilt = UnitQuaternion::rotation_between(&Vector3::z(), &z_toward_camera).expect("tilt");
        let roll = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), rng.random_range(-3.1..3.1));
        let t = Vector3::new(rng.random_range(-0.2..0.2), rng.random_range(-0.15..0.15), rng.random_range(1.0..2.0));
        let truth = Isometry3::from_parts(t.into(), tilt * roll);
        let corners = tag_corners_m(size).map(|p| {
            let px = k.project(&(truth * p)).expect("in front");
            [px.x + rng.random_range(-0.3..0.3), px.y + rng.random_range(-0.3..0.3)]
        });
        let pose = estimate_tag_pose(&corners, &k, size).expect("pose");
        let Some(second) = pose.second else { continue };
        ambiguous += 1;
        let angle = |p: &Isometry3<f64>| p.rotation.angle_to(&truth.rotation);
        let second_is_true = angle(&second.camera_from_tag) < angle(&pose.best.camera_from_tag);
        flipped += usize::from(second_is_true);
        corners_right += usize::from(!second_is_true);
        // A depth camera's points on the tag: a 12 x 12 grid on the true face, 1 mm noise along the ray.
        let points: Vec<Point3<f32>> = (0..144)
            .map(|i| {
                let (x, y) = ((i % 12) as f64 / 11.0 - 0.5, (i / 12) as f64 / 11.0 - 0.5);
                let p = truth * Point3::new(x * size, y * size, 0.0);
                (p * (1.0 + rng.random_range(-0.001..0.001) / p.z)).cast::<f32>()
            })
            .collect();
        let scores = score_depth(&pose, &corners, &k, &points);
        assert!(scores.best.points >= MIN_DEPTH_POINTS, "case {case}: {} points on the tag", scores.best.points);
        let chosen = if scores.prefers_second() { pose.swapped() } else { pose };
        // Decisive when one solution is clearly (> 3 deg) nearer the truth; otherwise both are about
        // equally wrong (noise tilted the true pose between them) and either choice is as good.
        let (a_best, a_second) = (angle(&pose.best.camera_from_tag), angle(&second.camera_from_tag));
        if (a_best - a_second).abs().to_degrees() > 3.0 {
            decisive += 1;
            depth_right += usize::from(angle(&chosen.best.camera_from_tag) == a_best.min(a_second));
        }
    }
    println!(
        "{ambiguous} ambiguous of 300: corners ranked the true solution first {corners_right} times (flipped {flipped}); \
         {decisive} decisive (one solution > 3 deg nearer the truth): depth chose the nearer {depth_right} times"
    );
    assert!(flipped >= 10, "the test must exercise flips: {flipped}");
    assert_eq!(depth_right, decisive, "depth must pick the nearer solution whenever one is clearly nearer");
}
