//! Tag detection and pose (`awl::tag`) against simulator ground truth: the independent simulator's
//! scans and shots in `shared/data/sim_reference` (truth.json: per view `tag_visible`,
//! `tag_corners_px`, `T_world_camera`; the scan's `T_world_tag` in the spec frame) and awl's own
//! simulator (`truth.extra["tag_observations"]`). Also the depth-based choice between the two
//! planar-ambiguity solutions, and the detection time per 640x480 frame (printed, not asserted).
//!
//! Run in release: `cargo test --release -p awl --test tags_sim -- --nocapture` to see the numbers.
#![cfg(all(feature = "sim", feature = "apriltag"))]

mod common;
mod tags_common;

use std::time::Instant;

use awl::camera::{DepthCamera, depth_to_cloud};
use awl::image::ColorImage;
use awl::io::mesh::read_mesh;
use awl::io::scan::{load_depth_points, load_view, read_scan};
use awl::io::truth::read_truth;
use awl::mesh::TriMesh;
use awl::sim::{SceneKind, ShotPose, SimParams, simulate};
use awl::tag::{TagDetector, TagPose, estimate_tag_pose, score_depth, tag_corners_m};
use nalgebra::{Isometry3, Point3, Vector3};
use parry3d_f64::math::Vector as PVector;
use parry3d_f64::query::{Ray, RayCast};
use serde_json::Value;
use tags_common::{data_dir, detector, stats};

/// One view that sees the tag, with its truth.
struct Case {
    name: String,
    image: ColorImage,
    cloud: Vec<Point3<f32>>,
    camera: DepthCamera,
    tag_id: u32,
    tag_size_m: f64,
    /// truth.json's corners: the planar tag model's corners projected (AprilTag order, integer = pixel centre).
    corners_truth: [[f64; 2]; 4],
    /// Where the printed corners really are: the planar corners projected along the tag's -z onto the
    /// CAD (both simulators print the tag that way), then into the image. Equal to `corners_truth`
    /// on a flat face; on the shell's curved side the corners lie 1.4-1.9 mm (reference) or 5-9 mm
    /// (awl's shell) behind the tag plane.
    corners_printed: [[f64; 2]; 4],
    /// Planar tag (the box) or printed on a curved face (the shell).
    flat: bool,
    camera_from_tag: Isometry3<f64>,
}

/// The printed corners of the tag in the image (see [`Case::corners_printed`]).
fn printed_corners(
    cad: &TriMesh,
    object_from_tag: &Isometry3<f64>,
    camera_from_object: &Isometry3<f64>,
    camera: &DepthCamera,
    size: f64,
) -> [[f64; 2]; 4] {
    let vertices = cad.vertices.iter().map(|p| PVector::new(p.x, p.y, p.z)).collect();
    let mesh = parry3d_f64::shape::TriMesh::new(vertices, cad.triangles.clone()).expect("CAD mesh");
    tag_corners_m(size).map(|c| {
        let start = object_from_tag * Point3::new(c.x, c.y, 0.03);
        let d = object_from_tag.rotation * -Vector3::z();
        let ray = Ray::new(PVector::new(start.x, start.y, start.z), PVector::new(d.x, d.y, d.z));
        let t = mesh.cast_local_ray(&ray, 0.1, false).expect("the tag corner is printed on the workpiece");
        let px = camera.intrinsics.project(&(camera_from_object * (start + d * t))).expect("in front");
        [px.x, px.y]
    })
}

fn corners(v: &Value) -> [[f64; 2]; 4] {
    let c: Vec<[f64; 2]> =
        v.as_array().expect("corners").iter().map(|p| [p[0].as_f64().expect("u"), p[1].as_f64().expect("v")]).collect();
    c.try_into().expect("4 corners")
}

/// Views of a `sim_reference` folder whose truth says `tag_visible`.
fn reference_cases(folder: &str) -> Vec<Case> {
    let dir = data_dir().join("sim_reference").join(folder);
    let scan = read_scan(&dir).unwrap_or_else(|e| panic!("{e}"));
    let truth = read_truth(&dir).unwrap_or_else(|e| panic!("{e}"));
    let tag = scan.tag.clone().expect("scan.json tag");
    let world_from_tag = truth.world_from_tag.expect("T_world_tag");
    let camera = scan.camera.expect("camera");
    let cad = read_mesh(&dir.join(&truth.cad)).unwrap_or_else(|e| panic!("{e}"));
    let object_from_tag = truth.world_from_object.inverse() * world_from_tag;
    let mut cases = Vec::new();
    for (i, view) in truth.views.iter().enumerate() {
        let extra = |key: &str| view_extra(&dir.join("truth.json"), i, key);
        if extra("tag_visible") != Value::Bool(true) {
            continue;
        }
        let loaded = load_view(&scan, i, None).unwrap_or_else(|e| panic!("{e}"));
        // the tag search's depth-only load: the same points, the color image not read
        let depth = load_depth_points(&scan, i, None).unwrap_or_else(|e| panic!("{e}")).expect("a depth view");
        assert!(!depth.is_empty(), "{folder}/{i}");
        assert_eq!(depth, loaded.cloud_camera.points, "{folder}/{i}");
        cases.push(Case {
            name: format!("{folder}/{i}"),
            image: loaded.color.expect("color image"),
            cloud: loaded.cloud_camera.points,
            camera,
            tag_id: tag.id,
            tag_size_m: tag.size_m,
            corners_truth: corners(&extra("tag_corners_px")),
            corners_printed: printed_corners(
                &cad,
                &object_from_tag,
                &(view.world_from_camera.inverse() * truth.world_from_object),
                &camera,
                tag.size_m,
            ),
            flat: folder.starts_with("box"),
            camera_from_tag: view.world_from_camera.inverse() * world_from_tag,
        });
    }
    cases
}

/// A per-view key of truth.json that `awl::io::truth` does not model.
fn view_extra(path: &std::path::Path, i: usize, key: &str) -> Value {
    let text = std::fs::read_to_string(path).expect("truth.json");
    let json: Value = serde_json::from_str(&text).expect("JSON");
    json["views"][i][key].clone()
}

/// Views of an awl simulation that see the tag well (visible, incidence < 60 deg, side > 30 px).
fn own_cases(params: SimParams, label: &str) -> Vec<Case> {
    let sim = simulate(&params).unwrap_or_else(|e| panic!("{e}"));
    let object_from_tag = sim.truth.world_from_object.inverse() * sim.truth.world_from_tag.expect("tag pose");
    let camera = sim.scan.camera.expect("camera");
    let rays = camera.intrinsics.ray_table();
    let tag = sim.scan.tag.clone().expect("tag");
    let world_from_tag = sim.truth.world_from_tag.expect("tag pose");
    let observations = sim.truth.extra["tag_observations"].as_array().expect("tag_observations").clone();
    let mut cases = Vec::new();
    for (i, obs) in observations.iter().enumerate() {
        let good = obs["visible"] == Value::Bool(true)
            && obs["incidence_deg"].as_f64().expect("incidence") < 60.0
            && obs["side_px"].as_f64().expect("side") > 30.0;
        if !good {
            continue;
        }
        let view = &sim.views[i];
        cases.push(Case {
            name: format!("awl-sim {label}/{i}"),
            image: view.color.clone(),
            cloud: depth_to_cloud(&view.depth, None, &camera, &rays).points,
            camera,
            tag_id: tag.id,
            tag_size_m: tag.size_m,
            corners_truth: corners(&obs["corners_px"]),
            corners_printed: printed_corners(
                &sim.cad,
                &object_from_tag,
                &(sim.truth.views[i].world_from_camera.inverse() * sim.truth.world_from_object),
                &camera,
                tag.size_m,
            ),
            flat: params.scene == SceneKind::Box,
            camera_from_tag: sim.truth.views[i].world_from_camera.inverse() * world_from_tag,
        });
    }
    cases
}

/// (rotation angle deg, centre distance mm) of a solution against the truth.
fn pose_error(estimate: &Isometry3<f64>, truth: &Isometry3<f64>) -> (f64, f64, f64) {
    let centre_mm = (estimate.translation.vector - truth.translation.vector).norm() * 1e3;
    let z_deg = (estimate.rotation * Vector3::z()).angle(&(truth.rotation * Vector3::z())).to_degrees();
    let rot_deg = estimate.rotation.angle_to(&truth.rotation).to_degrees();
    (centre_mm, z_deg, rot_deg)
}

/// Measurements over the cases of one kind (flat or curved tags).
#[derive(Default)]
struct Tally {
    views: usize,
    missed: Vec<String>,
    /// Detected corner vs truth.json's corner, pixels.
    corner_truth_px: Vec<f64>,
    /// Detected corner vs the printed corner, pixels.
    corner_printed_px: Vec<f64>,
    centre_mm: Vec<f64>,
    z_deg: Vec<f64>,
    /// (depth chose the solution nearer the truth, views with two solutions).
    depth_choices: (usize, usize),
}

/// (median, max) of each measurement, printed with `label`.
struct Summary {
    corner_truth_px: (f64, f64),
    corner_printed_px: (f64, f64),
    centre_mm: (f64, f64),
    z_deg: (f64, f64),
}

impl Tally {
    fn summary(&mut self, label: &str) -> Summary {
        let s = Summary {
            corner_truth_px: stats(&mut self.corner_truth_px),
            corner_printed_px: stats(&mut self.corner_printed_px),
            centre_mm: stats(&mut self.centre_mm),
            z_deg: stats(&mut self.z_deg),
        };
        println!(
            "{label}: found {}/{} (missed {:?}); corners vs truth.json median {:.3} max {:.3} px, vs printed median {:.3} max {:.3} px; \
             tag centre median {:.2} max {:.2} mm; z axis median {:.2} max {:.2} deg; depth chose the true solution {}/{}",
            self.views - self.missed.len(),
            self.views,
            self.missed,
            s.corner_truth_px.0,
            s.corner_truth_px.1,
            s.corner_printed_px.0,
            s.corner_printed_px.1,
            s.centre_mm.0,
            s.centre_mm.1,
            s.z_deg.0,
            s.z_deg.1,
            self.depth_choices.0,
            self.depth_choices.1
        );
        s
    }
}

fn distance(a: &[f64; 2], b: &[f64; 2]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

fn check_case(case: &Case, tally: &mut Tally) {
    tally.views += 1;
    let detections = detector().detect_color(&case.image).expect("detect");
    let found: Vec<_> = detections.iter().filter(|d| d.id == case.tag_id).collect();
    assert!(found.len() <= 1, "{}: tag {} found {} times", case.name, case.tag_id, found.len());
    let Some(d) = found.first() else {
        println!("{}: tag {} NOT found", case.name, case.tag_id);
        tally.missed.push(case.name.clone());
        return;
    };
    for ((o, t), p) in d.corners_px.iter().zip(&case.corners_truth).zip(&case.corners_printed) {
        tally.corner_truth_px.push(distance(o, t));
        tally.corner_printed_px.push(distance(o, p));
    }
    let k = &case.camera.intrinsics;
    let pose: TagPose = estimate_tag_pose(&d.corners_px, k, case.tag_size_m).expect("pose");
    let (centre_mm, z_deg, rot_deg) = pose_error(&pose.best.camera_from_tag, &case.camera_from_tag);
    println!(
        "{}: pose {centre_mm:.2} mm, z {z_deg:.2} deg, rot {rot_deg:.2} deg at {:.2} m; rmse {:.3} px, ambiguity {:?}",
        case.name,
        case.camera_from_tag.translation.vector.norm(),
        pose.best.rmse_px,
        pose.ambiguity().map(|a| (a * 100.0).round() / 100.0)
    );
    tally.centre_mm.push(centre_mm);
    tally.z_deg.push(z_deg);
    if let Some(second) = pose.second {
        // Depth decides: the solution whose plane holds the depth points must be the one nearer the truth.
        let scores = score_depth(&pose, &d.corners_px, k, &case.cloud);
        let second_is_true = pose_error(&second.camera_from_tag, &case.camera_from_tag).2 < rot_deg;
        println!(
            "  depth: {} points, offset / spread about the plane: best {:.2} / {:.2} mm, second {:.2} / {:.2} mm; truth is {}",
            scores.best.points,
            scores.best.offset_m * 1e3,
            scores.best.spread_m * 1e3,
            scores.second.map_or(f64::NAN, |s| s.offset_m * 1e3),
            scores.second.map_or(f64::NAN, |s| s.spread_m * 1e3),
            if second_is_true { "second" } else { "best" }
        );
        tally.depth_choices.1 += 1;
        if scores.prefers_second() == second_is_true {
            tally.depth_choices.0 += 1;
        }
    }
}

/// Checks every case; returns the tallies of flat and curved tags.
fn run(cases: &[Case]) -> (Tally, Tally) {
    let (mut flat, mut curved) = (Tally::default(), Tally::default());
    for case in cases {
        check_case(case, if case.flat { &mut flat } else { &mut curved });
    }
    (flat, curved)
}

/// The assertions common to both simulators. Tolerances sit above the measured numbers (in the
/// report) with room for a different seed's noise; the reasons are inline.
///
/// `curved_corner_px`: the bound on curved-tag corners against the printed corners. A bent tag's
/// edges are curves in the image; the detector fits straight lines and intersects them, so its
/// corners cannot reach the printed corner points there: the bound only catches gross failures.
fn assert_common(flat: &Summary, curved: &Summary, flat_t: &Tally, curved_t: &Tally, curved_corner_px: f64) {
    // Sub-half-pixel corners on a flat tag, against truth.json.
    assert!(flat.corner_truth_px.1 < 0.5, "flat tag corners vs truth: max {:.3} px", flat.corner_truth_px.1);
    let max = curved.corner_printed_px.1;
    assert!(max < curved_corner_px, "curved tag corners vs printed: max {max:.3} px");
    // The correct plane always fits the depth points on the tag better.
    for t in [flat_t, curved_t] {
        assert_eq!(t.depth_choices.0, t.depth_choices.1, "depth picked the wrong solution");
    }
}

#[test]
fn reference_simulator_tags_are_found_with_accurate_corners_and_poses() {
    let mut cases = Vec::new();
    for folder in ["box_seed1_shot_tilt30", "shell_seed1_shot_tilt30", "box_seed1", "shell_seed1"] {
        cases.extend(reference_cases(folder));
    }
    assert_eq!(cases.len(), 10, "views with tag_visible in the 4 reference folders");
    let (mut flat_t, mut curved_t) = run(&cases);
    let (flat, curved) =
        (flat_t.summary("reference sim, flat tag (box)"), curved_t.summary("reference sim, curved tag (shell)"));
    assert!(flat_t.missed.is_empty() && curved_t.missed.is_empty(), "every visible tag is found");
    // Curved: measured max 0.63 px against the printed corners (0.89 px against truth.json's planar
    // corners; the reference shell bends its tag 1.4-1.9 mm behind the plane at the corners).
    assert_common(&flat, &curved, &flat_t, &curved_t, 1.0);
    // Measured max 3.8 mm / 0.08 deg (box) and 3.7 mm / 0.20 deg (shell) at 0.5-1.05 m: the distance
    // along the line of sight comes from the apparent size, and 0.1 px on a 60 px tag is 0.3 % of 1 m.
    for s in [&flat, &curved] {
        assert!(s.centre_mm.1 < 6.0, "tag centre error max {:.2} mm", s.centre_mm.1);
        assert!(s.z_deg.1 < 0.5, "tag z axis error max {:.2} deg", s.z_deg.1);
    }
}

#[test]
fn own_simulator_tags_are_found_with_accurate_corners_and_poses() {
    let mut cases = own_cases(SimParams::shot(SceneKind::Box, ShotPose::Tilt30), "box shot tilt30");
    cases.extend(own_cases(SimParams::shot(SceneKind::Shell, ShotPose::Tilt30), "shell shot tilt30"));
    cases.extend(own_cases(SimParams::scan(SceneKind::Box), "box scan"));
    cases.extend(own_cases(SimParams::scan(SceneKind::Shell), "shell scan"));
    let (mut flat_t, mut curved_t) = run(&cases);
    let (flat, curved) = (flat_t.summary("awl sim, flat tag (box)"), curved_t.summary("awl sim, curved tag (shell)"));
    assert!(
        flat_t.views >= 5 && curved_t.views >= 5,
        "views that see the tag well: {} flat, {} curved",
        flat_t.views,
        curved_t.views
    );
    assert!(flat_t.missed.is_empty(), "every well-seen flat tag is found");
    // awl's shell bends its tag 5-9 mm out of plane at the corners; at 53 deg incidence (shell scan
    // view 10) the C detector (pupil-apriltags as well) finds no quad. One miss is tolerated.
    assert!(curved_t.missed.len() <= 1, "curved tags missed: {:?}", curved_t.missed);
    // Curved: measured max 3.95 px against the printed corners (awl's shell bends the tag 5-9 mm).
    assert_common(&flat, &curved, &flat_t, &curved_t, 5.0);
    // Flat: measured max 5.9 mm / 0.31 deg at 0.6-1 m (see the reference test for why mm).
    assert!(
        flat.centre_mm.1 < 8.0 && flat.z_deg.1 < 0.6,
        "flat tag pose: {:?} mm, {:?} deg",
        flat.centre_mm,
        flat.z_deg
    );
    // Curved: the planar pose of a bent tag sits behind its tangent plane (measured max 17.6 mm /
    // 1.5 deg); asserted only to catch gross failures.
    assert!(
        curved.centre_mm.1 < 25.0 && curved.z_deg.1 < 2.5,
        "curved tag pose: {:?} mm, {:?} deg",
        curved.centre_mm,
        curved.z_deg
    );
    let image = &cases[0].image;
    let mut detector = detector();
    let start = Instant::now();
    let runs = 10;
    for _ in 0..runs {
        detector.detect_color(image).expect("detect");
    }
    println!(
        "detection time per {}x{} frame (gray conversion included, 1 thread): {:.1} ms",
        image.width,
        image.height,
        start.elapsed().as_secs_f64() * 1e3 / f64::from(runs)
    );
}
