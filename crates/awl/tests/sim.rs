//! The simulator (`awl::sim`) checked against its own ground truth: determinism, geometry, the depth
//! and pose noise models, coverage, the tag, shots, the folder writer, and the embedded tag bitmaps
//! against the canonical PNGs in `shared/data` (`$AWL_SHARED_DATA` or `<workspace>/../shared/data`;
//! that test fails, not skips, when the folder is missing).
//!
//! Run in release: `cargo test --release -p awl --test sim`.
#![cfg(feature = "sim")]

mod common;
use common::shared_data;

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::OnceLock;

use awl::camera::DepthCamera;
use awl::io::truth::Truth;
use awl::mesh::TriMesh;
use awl::sim::{
    LABEL_FLOOR, LABEL_WORKPIECE, NoiseLevel, SceneKind, ShotPose, SimParams, SimView, Simulation, TAG_MODULES,
    axial_sigma_m, simulate, tag36h11_bitmap, write_simulation,
};
use nalgebra::{Isometry3, Point2, Point3, Vector3};
use parry3d_f64::math::Vector as PVector;
use parry3d_f64::query::{PointQuery, Ray, RayCast};

fn params(scene: SceneKind, noise: NoiseLevel, seed: u64, views: usize) -> SimParams {
    SimParams { scene, views, seed, noise, shot: None, camera_seed: None, bare: false, fixed_base: false }
}

fn cached(cell: &'static OnceLock<Simulation>, p: SimParams) -> &'static Simulation {
    cell.get_or_init(|| simulate(&p).expect("simulation"))
}

fn box_none() -> &'static Simulation {
    static CELL: OnceLock<Simulation> = OnceLock::new();
    cached(&CELL, params(SceneKind::Box, NoiseLevel::None, 1, 12))
}

fn shell_none() -> &'static Simulation {
    static CELL: OnceLock<Simulation> = OnceLock::new();
    cached(&CELL, params(SceneKind::Shell, NoiseLevel::None, 1, 12))
}

fn box_realistic() -> &'static Simulation {
    static CELL: OnceLock<Simulation> = OnceLock::new();
    cached(&CELL, params(SceneKind::Box, NoiseLevel::Realistic, 1, 12))
}

fn camera(sim: &Simulation) -> DepthCamera {
    sim.scan.camera.expect("simulated scans have a camera")
}

fn parry(mesh: &TriMesh) -> parry3d_f64::shape::TriMesh {
    let vertices = mesh.vertices.iter().map(|p| PVector::new(p.x, p.y, p.z)).collect();
    parry3d_f64::shape::TriMesh::new(vertices, mesh.triangles.clone()).expect("CAD mesh")
}

fn percentile(values: &mut [f64], q: f64) -> f64 {
    values.sort_by(f64::total_cmp);
    values[((values.len() - 1) as f64 * q).round() as usize]
}

/// Points (object frame) of the pixels labelled `label` in view `i`, back-projected with the TRUE pose,
/// every `stride`-th pixel in u and v.
fn labelled_points(sim: &Simulation, i: usize, label: u8, frame: &Isometry3<f64>, stride: usize) -> Vec<Point3<f64>> {
    let cam = camera(sim);
    let view = &sim.views[i];
    let from_camera = frame * sim.truth.views[i].world_from_camera;
    let w = view.depth.width as usize;
    let mut points = Vec::new();
    for (k, (&d, &l)) in view.depth.data.iter().zip(&view.labels.data).enumerate() {
        let (u, v) = (k % w, k / w);
        if d == 0 || l != label || u % stride != 0 || v % stride != 0 {
            continue;
        }
        let p = cam.intrinsics.back_project(&Point2::new(u as f64, v as f64), f64::from(d) * cam.depth_scale);
        points.push(from_camera * p);
    }
    points
}

fn same_images(a: &[SimView], b: &[SimView]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x == y)
}

#[test]
fn deterministic_per_seed_and_independent_of_thread_count() {
    let p = params(SceneKind::Box, NoiseLevel::Realistic, 5, 3);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        pool.install(|| simulate(&p).expect("simulation"))
    };
    let (one, two) = (run(1), run(2));
    assert!(same_images(&one.views, &two.views), "images differ between 1 and 2 threads");
    assert!(one.scan == two.scan && one.truth == two.truth, "poses differ between 1 and 2 threads");
    assert!(one == run(2), "same seed, same output");
    let other = simulate(&SimParams { seed: 6, ..p }).expect("simulation");
    assert!(one.views.iter().zip(&other.views).all(|(a, b)| a.depth != b.depth && a.color != b.color));
    assert_ne!(one.truth.world_from_object, other.truth.world_from_object);
    assert_ne!(one.scan.views[0].pose, other.scan.views[0].pose);
}

#[test]
fn noiseless_depth_lies_on_the_cad_and_the_floor() {
    for (name, sim) in [("box", box_none()), ("shell", shell_none())] {
        let cad = parry(&sim.cad);
        let object_from_world = sim.truth.world_from_object.inverse();
        let mut distances = Vec::new();
        let mut floor_max = 0.0f64;
        for i in 0..sim.views.len() {
            for p in labelled_points(sim, i, LABEL_WORKPIECE, &object_from_world, 2) {
                let q = PVector::new(p.x, p.y, p.z);
                distances.push((cad.project_local_point(q, false).point - q).length());
            }
            for p in labelled_points(sim, i, LABEL_FLOOR, &Isometry3::identity(), 2) {
                floor_max = floor_max.max(p.z.abs());
            }
        }
        let n = distances.len();
        let (median, p95) = (percentile(&mut distances, 0.5), percentile(&mut distances, 0.95));
        println!(
            "{name}: {n} workpiece points, median {:.3} mm, p95 {:.3} mm; floor |z| max {:.3} mm",
            median * 1e3,
            p95 * 1e3,
            floor_max * 1e3
        );
        assert!(n > 50_000, "{name}: only {n} workpiece points");
        assert!(median < 0.0005 && p95 < 0.001, "{name}: median {median} p95 {p95}");
        assert!(floor_max < 0.001, "{name}: floor point {floor_max} m off z = 0");
    }
}

/// |cos| of the incidence of each pixel's ray on the CAD (true poses), `None` when it misses.
fn cad_incidence(sim: &Simulation, cad: &parry3d_f64::shape::TriMesh, i: usize, u: usize, v: usize) -> Option<f64> {
    let cam = camera(sim);
    let object_from_camera = sim.truth.world_from_object.inverse() * sim.truth.views[i].world_from_camera;
    let n = cam.intrinsics.ray(&Point2::new(u as f64, v as f64));
    let d = object_from_camera.rotation * Vector3::new(n.x, n.y, 1.0);
    let o = object_from_camera.translation.vector;
    let hit = cad.cast_local_ray_and_get_normal(
        &Ray::new(PVector::new(o.x, o.y, o.z), PVector::new(d.x, d.y, d.z)),
        10.0,
        false,
    )?;
    Some((hit.normal.x * d.x + hit.normal.y * d.y + hit.normal.z * d.z).abs() / d.norm())
}

#[test]
fn realistic_axial_noise_matches_the_model() {
    let (clean, noisy) = (box_none(), box_realistic());
    let cad = parry(&clean.cad);
    let mut bins: HashMap<i64, Vec<f64>> = HashMap::new();
    for i in 0..clean.views.len() {
        let (a, b) = (&clean.views[i], &noisy.views[i]);
        let w = a.depth.width as usize;
        for k in 0..a.depth.data.len() {
            let (dc, dn) = (a.depth.data[k], b.depth.data[k]);
            if dc == 0 || dn == 0 || a.labels.data[k] != LABEL_WORKPIECE || b.labels.data[k] != LABEL_WORKPIECE {
                continue;
            }
            let Some(cos) = cad_incidence(clean, &cad, i, k % w, k / w) else { continue };
            let z = f64::from(dc) * 1e-3;
            let sigma_mm = (axial_sigma_m(z, cos, 1.0) * 1e3).hypot((2.0f64 / 12.0).sqrt());
            let error_mm = f64::from(dn) - f64::from(dc);
            bins.entry((z * 10.0).floor() as i64).or_default().push(error_mm / sigma_mm);
        }
    }
    let mut checked = 0;
    let mut keys: Vec<_> = bins.keys().copied().collect();
    keys.sort();
    for key in keys {
        let mut normalised = bins.remove(&key).unwrap_or_default();
        if normalised.len() < 2000 {
            continue;
        }
        let median = percentile(&mut normalised, 0.5);
        let mut deviations: Vec<f64> = normalised.iter().map(|e| (e - median).abs()).collect();
        let robust_std = 1.4826 * percentile(&mut deviations, 0.5);
        println!(
            "depth {:.1}-{:.1} m: {} px, error std / model sigma = {robust_std:.3}",
            key as f64 / 10.0,
            (key + 1) as f64 / 10.0,
            normalised.len()
        );
        assert!((0.7..=1.3).contains(&robust_std), "bin {key}: ratio {robust_std}");
        checked += 1;
    }
    assert!(checked >= 3, "only {checked} depth bins had enough pixels");
}

fn check_pose_errors(sim: &Simulation, min_m: f64, max_m: f64, max_deg: f64) -> (f64, f64, f64) {
    let (mut lo, mut hi, mut rot) = (f64::MAX, 0.0f64, 0.0f64);
    for i in 0..sim.views.len() {
        let recorded = sim.scan.world_from_camera(i).expect("recorded pose");
        let truth = sim.truth.views[i].world_from_camera;
        let (dt, dr) = awl::transform::pose_difference(&truth, &recorded);
        assert!(dt >= min_m && dt <= max_m && dr.to_degrees() <= max_deg, "view {i}: {dt} m, {} deg", dr.to_degrees());
        (lo, hi, rot) = (lo.min(dt), hi.max(dt), rot.max(dr.to_degrees()));
    }
    (lo, hi, rot)
}

#[test]
fn recorded_poses_carry_the_rig_errors() {
    let (lo, hi, rot) = check_pose_errors(box_realistic(), 0.005, 0.06, 3.0);
    println!("realistic: camera pose error {:.1}-{:.1} cm, up to {rot:.2} deg", lo * 100.0, hi * 100.0);
    let (_, hi, rot) = check_pose_errors(box_none(), 0.0, 1e-9, 1e-9f64.to_degrees());
    println!("none: camera pose error up to {hi:.1e} m, {rot:.1e} deg");
    let truth = &box_realistic().truth;
    for v in &truth.views {
        let chained =
            v.world_from_base.expect("base") * v.base_from_ee.expect("ee") * truth.ee_from_camera.expect("hand-eye");
        assert!(awl::transform::pose_difference(&chained, &v.world_from_camera).0 < 1e-12);
    }
}

fn coverage(sim: &Simulation) -> f64 {
    let object_from_world = sim.truth.world_from_object.inverse();
    let cell = 0.003;
    let key = |p: &Point3<f64>| ((p.x / cell).floor() as i64, (p.y / cell).floor() as i64, (p.z / cell).floor() as i64);
    let mut grid: HashMap<(i64, i64, i64), Vec<Point3<f64>>> = HashMap::new();
    for i in 0..sim.views.len() {
        for p in labelled_points(sim, i, LABEL_WORKPIECE, &object_from_world, 1) {
            grid.entry(key(&p)).or_default().push(p);
        }
    }
    let samples = sim.cad.sample_surface(20_000, 7).expect("samples");
    let normals = samples.normals.as_ref().expect("normals");
    let (mut seen, mut total) = (0usize, 0usize);
    for (p, n) in samples.points.iter().zip(normals) {
        let p = p.cast::<f64>();
        if n.z < -0.9 && p.z < 0.001 {
            continue; // the bottom face rests on the floor: no camera can see it
        }
        total += 1;
        let (x, y, z) = key(&p);
        let near = (-1..=1).any(|a| {
            (-1..=1).any(|b| {
                (-1..=1)
                    .any(|c| grid.get(&(x + a, y + b, z + c)).is_some_and(|v| v.iter().any(|q| (q - p).norm() <= cell)))
            })
        });
        seen += usize::from(near);
    }
    seen as f64 / total as f64
}

#[test]
fn twelve_views_cover_the_workpiece() {
    for (name, sim) in [("box", box_none()), ("shell", shell_none())] {
        let c = coverage(sim);
        println!("{name}: {:.1} % of the visible CAD surface within 3 mm of a workpiece pixel", c * 100.0);
        assert!(c >= 0.95, "{name}: coverage {c}");
    }
}

/// Mean gray of the 3x3 pixels around `px`.
fn gray_at(view: &SimView, px: &Point2<f64>) -> f64 {
    let (w, h) = (view.color.width as i64, view.color.height as i64);
    let (u0, v0) = (px.x.round() as i64, px.y.round() as i64);
    let mut sum = 0.0;
    for v in v0 - 1..=v0 + 1 {
        for u in u0 - 1..=u0 + 1 {
            let [r, g, b] = view.color.data[(v.clamp(0, h - 1) * w + u.clamp(0, w - 1)) as usize];
            sum += (f64::from(r) + f64::from(g) + f64::from(b)) / 3.0;
        }
    }
    sum / 9.0
}

/// Projected black-border corners of the true tag in view `i`, if all are in front of the camera.
fn tag_corners(sim: &Simulation, i: usize) -> Option<[Point2<f64>; 4]> {
    let (tag, size) = (sim.truth.world_from_tag?, sim.scan.tag.as_ref()?.size_m);
    let camera_from_tag = sim.truth.views[i].world_from_camera.inverse() * tag;
    let h = size / 2.0;
    let mut out = [Point2::origin(); 4];
    for (o, (x, y)) in out.iter_mut().zip([(-h, -h), (h, -h), (h, h), (-h, h)]) {
        *o = camera(sim).intrinsics.project(&(camera_from_tag * Point3::new(x, y, 0.0)))?;
    }
    Some(out)
}

fn tag_in_image(sim: &Simulation, i: usize) -> bool {
    let cam = camera(sim);
    let (w, h) = (f64::from(cam.intrinsics.width), f64::from(cam.intrinsics.height));
    tag_corners(sim, i).is_some_and(|c| c.iter().all(|p| p.x >= 0.0 && p.y >= 0.0 && p.x <= w - 1.0 && p.y <= h - 1.0))
}

/// Where the tag-plane point `p_tag` is printed: projected along the tag's -z onto the CAD (the
/// simulator prints the tag by planar projection, so on a curved face it lies behind the plane).
fn printed_point(sim: &Simulation, cad: &parry3d_f64::shape::TriMesh, p_tag: &Point3<f64>) -> Point3<f64> {
    let object_from_tag = sim.truth.world_from_object.inverse() * sim.truth.world_from_tag.expect("tag pose");
    let start = object_from_tag * Point3::new(p_tag.x, p_tag.y, 0.03);
    let d = object_from_tag.rotation * -Vector3::z();
    let ray = Ray::new(PVector::new(start.x, start.y, start.z), PVector::new(d.x, d.y, d.z));
    let t = cad.cast_local_ray(&ray, 0.1, false).expect("the tag is printed on the workpiece");
    sim.truth.world_from_object * (start + d * t)
}

/// Compares the rendered modules of the tag in view `i` with the bitmap: returns the fraction of
/// the 100 modules that match, and whether the whole border is dark and the quiet zone light.
fn tag_modules_match(sim: &Simulation, i: usize) -> (f64, bool) {
    let bits = tag36h11_bitmap(sim.scan.tag.as_ref().expect("tag").id).expect("embedded id");
    let size = sim.scan.tag.as_ref().expect("tag").size_m;
    let cad = parry(&sim.cad);
    let camera_from_world = sim.truth.views[i].world_from_camera.inverse();
    let module = size / 8.0;
    let gray = |r: usize, c: usize| {
        let p = Point3::new((c as f64 + 0.5 - 5.0) * module, (5.0 - r as f64 - 0.5) * module, 0.0);
        let world = printed_point(sim, &cad, &p);
        gray_at(&sim.views[i], &camera(sim).intrinsics.project(&(camera_from_world * world)).expect("in front"))
    };
    let ring = |k: usize| {
        (0..TAG_MODULES)
            .flat_map(move |r| (0..TAG_MODULES).map(move |c| (r, c)))
            .filter(move |&(r, c)| r.min(c).min(9 - r).min(9 - c) == k)
    };
    let quiet: Vec<f64> = ring(0).map(|(r, c)| gray(r, c)).collect();
    let border: Vec<f64> = ring(1).map(|(r, c)| gray(r, c)).collect();
    let threshold =
        (quiet.iter().sum::<f64>() / quiet.len() as f64 + border.iter().sum::<f64>() / border.len() as f64) / 2.0;
    let clean = quiet.iter().all(|&g| g > threshold) && border.iter().all(|&g| g < threshold);
    let matches =
        (0..TAG_MODULES * TAG_MODULES).filter(|&k| (gray(k / 10, k % 10) < threshold) == bits[k / 10][k % 10]).count();
    (matches as f64 / 100.0, clean)
}

/// Incidence (degrees) and mean side (pixels) of the true tag in view `i`.
fn tag_quality(sim: &Simulation, i: usize) -> (f64, f64) {
    let tag = sim.truth.world_from_tag.expect("tag pose");
    let to_camera = sim.truth.views[i].world_from_camera.translation.vector - tag.translation.vector;
    let incidence = (tag.rotation * Vector3::z()).dot(&to_camera.normalize()).acos().to_degrees();
    let side = tag_corners(sim, i).map_or(0.0, |c| (0..4).map(|k| (c[k] - c[(k + 1) % 4]).norm()).sum::<f64>() / 4.0);
    (incidence, side)
}

#[test]
fn the_tag_is_seen_and_rendered_from_its_bitmap() {
    let sim = box_realistic();
    let in_image: Vec<usize> = (0..sim.views.len()).filter(|&i| tag_in_image(sim, i)).collect();
    let good: Vec<usize> =
        in_image.iter().copied().filter(|&i| tag_quality(sim, i).0 < 60.0 && tag_quality(sim, i).1 > 30.0).collect();
    println!("tag inside the image in views {in_image:?}, seen well (< 60 deg, > 30 px) in {good:?}");
    assert!(in_image.len() >= 3 && good.len() >= 3);
    for i in good {
        let (fraction, clean) = tag_modules_match(sim, i);
        let (inc, side) = tag_quality(sim, i);
        println!("view {i}: incidence {inc:.0} deg, side {side:.0} px, {:.0} % modules match", fraction * 100.0);
        assert!(clean && fraction >= 0.97, "view {i}: {fraction}, border/quiet zone ok: {clean}");
    }
}

#[test]
fn shots_are_in_the_robot_frame_and_see_the_tag() {
    for (scene, pose) in [
        (SceneKind::Box, ShotPose::Tilt30),
        (SceneKind::Shell, ShotPose::Flat),
        (SceneKind::Cylinder, ShotPose::Tilt30),
        (SceneKind::Sphere, ShotPose::Flat),
    ] {
        let sim = simulate(&SimParams::shot(scene, pose)).expect("shot");
        assert_eq!(sim.views.len(), 2);
        for (i, view) in sim.scan.views.iter().enumerate() {
            let awl::scan::ViewPose::Chain { world_from_base, .. } = view.pose else { panic!("chain poses") };
            assert_eq!(world_from_base, Isometry3::identity());
            assert!(tag_in_image(&sim, i), "{scene:?} {pose:?}: tag outside view {i}");
            let (fraction, clean) = tag_modules_match(&sim, i);
            let (inc, side) = tag_quality(&sim, i);
            println!(
                "{scene:?} {pose:?} view {i}: incidence {inc:.0} deg, side {side:.0} px, {:.0} % modules, border/quiet ok {clean}",
                fraction * 100.0
            );
            assert!(clean && fraction >= 0.97 && inc < 60.0 && side > 30.0);
        }
        let target = &sim.truth.targets[0];
        let p = target.p_world.expect("shots give p_world");
        assert!((sim.truth.world_from_object * target.p_object - p).norm() < 1e-12);
        assert!((0.4..1.2).contains(&p.coords.xy().norm()), "target {p:?} is in front of the robot");
    }
}

/// The depth-scale error of a simulation measured against the CAD: the median over workpiece pixels
/// of recorded depth / ray-cast true depth, minus 1.
fn measured_depth_scale_error(sim: &Simulation) -> f64 {
    let cad = parry(&sim.cad);
    let cam = camera(sim);
    let mut ratios = Vec::new();
    for (i, view) in sim.views.iter().enumerate() {
        let object_from_camera = sim.truth.world_from_object.inverse() * sim.truth.views[i].world_from_camera;
        let o = object_from_camera.translation.vector;
        let w = view.depth.width as usize;
        for k in (0..view.depth.data.len()).step_by(3) {
            if view.depth.data[k] == 0 || view.labels.data[k] != LABEL_WORKPIECE {
                continue;
            }
            let n = cam.intrinsics.ray(&Point2::new((k % w) as f64, (k / w) as f64));
            let d = object_from_camera.rotation * Vector3::new(n.x, n.y, 1.0);
            let ray = Ray::new(PVector::new(o.x, o.y, o.z), PVector::new(d.x, d.y, d.z));
            // the ray's parameter along (x, y, 1) is the depth z
            if let Some(z) = cad.cast_local_ray(&ray, 10.0, false) {
                ratios.push(f64::from(view.depth.data[k]) * 1e-3 / z - 1.0);
            }
        }
    }
    assert!(ratios.len() > 5_000, "{} workpiece pixels", ratios.len());
    percentile(&mut ratios, 0.5)
}

#[test]
fn a_shot_taken_with_the_scans_camera_shares_its_intrinsics_and_depth_scale() {
    let scan = box_realistic();
    let scan_error = measured_depth_scale_error(scan);
    let shot = |camera_seed| {
        simulate(&SimParams { seed: 1003, camera_seed, ..SimParams::shot(SceneKind::Box, ShotPose::Flat) })
            .expect("shot")
    };
    let (same, other) = (shot(Some(1)), shot(None));
    let (same_error, other_error) = (measured_depth_scale_error(&same), measured_depth_scale_error(&other));
    println!(
        "depth-scale error measured: scan {scan_error:.5}, shot with its camera {same_error:.5}, other camera {other_error:.5}"
    );
    assert_eq!(camera(&same), camera(scan));
    assert_ne!(camera(&other), camera(scan));
    // the median of ~1 mm-quantised, noisy ratios resolves the scale to about 1e-4
    assert!((same_error - scan_error).abs() < 2e-4, "scan {scan_error} vs shot {same_error}");
    // and it tells another camera apart (measured 0.00071 vs 0.00021)
    assert!((other_error - scan_error).abs() > 3e-4, "scan {scan_error} vs other camera {other_error}");
}

#[test]
fn writes_a_complete_scan_folder_atomically() {
    let sim = simulate(&params(SceneKind::Cylinder, NoiseLevel::Low, 3, 2)).expect("simulation");
    let parent = tempfile::tempdir().expect("tempdir");
    let dir = parent.path().join("scan");
    write_simulation(&dir, &sim, false).expect("write");
    let scan = awl::io::scan::read_scan(&dir).expect("scan.json");
    assert_eq!(scan.views.len(), 2);
    assert_eq!(scan.tag, sim.scan.tag);
    let truth: Truth = awl::io::truth::read_truth(&dir).expect("truth.json");
    assert_eq!(truth.views.len(), 2);
    assert_eq!(truth.targets[0].name, "side");
    let label: PathBuf = truth.views[1].label.clone().expect("label path");
    assert!(dir.join(label).is_file());
    let depth = awl::io::image::read_depth_png(&dir.join("depth/000001.png")).expect("depth");
    assert_eq!(depth, sim.views[1].depth);
    let cad = awl::io::ply::read_ply_mesh(&dir.join("cad.ply")).expect("cad.ply");
    assert_eq!(cad.triangles, sim.cad.triangles);
    let err = write_simulation(&dir, &sim, false).expect_err("refuses a non-empty folder").to_string();
    assert!(err.contains("--force"), "{err}");
    write_simulation(&dir, &sim, true).expect("overwrite");
    let names: Vec<_> =
        std::fs::read_dir(parent.path()).expect("list").map(|e| e.expect("entry").file_name()).collect();
    assert_eq!(names, vec![std::ffi::OsString::from("scan")], "no temporary folder left behind");
}

#[test]
fn embedded_tag_bitmaps_match_the_canonical_pngs() {
    for id in 0..awl::sim::TAG36H11_EMBEDDED {
        let path = shared_data().join(format!("apriltag_tag36h11/tag36_11_{id:05}.png"));
        let image = awl::io::image::read_color_png(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((image.width, image.height), (10, 10), "{}", path.display());
        let bits = tag36h11_bitmap(id).expect("embedded");
        for (k, [r, _, _]) in image.data.iter().enumerate() {
            assert_eq!(*r < 128, bits[k / 10][k % 10], "tag {id}, module ({}, {})", k / 10, k % 10);
        }
    }
}

/// A shot taken again with views at commanded flange poses (`awl trial --plan-views`): its own
/// views, scene and truth unchanged, the extra views rendered where the arm was sent (the truth's
/// flange is the commanded one; scan.json reports it with the arm's noise); extra views in a scan,
/// or a pose that is not finite, are refused.
#[test]
fn a_shot_takes_extra_views_where_the_arm_is_sent() {
    let p = SimParams { seed: 4, ..SimParams::shot(SceneKind::Box, awl::sim::ShotPose::Flat) };
    let plain = simulate(&p).expect("shot");
    let first = plain.truth.views[0].base_from_ee.expect("flange");
    let sent = [first * Isometry3::translation(0.03, 0.0, -0.02), first * Isometry3::rotation(Vector3::x() * 0.1)];
    let more = awl::sim::simulate_with_views(&p, &sent).expect("shot with extra views");
    assert_eq!(more.views.len(), 4);
    assert!(same_images(&plain.views, &more.views[..2]), "the shot's own views changed");
    assert_eq!(plain.truth.world_from_object, more.truth.world_from_object);
    assert_eq!(plain.scan.views[..2], more.scan.views[..2], "the shot's own recorded poses changed");
    for (k, f) in sent.iter().enumerate() {
        let t = &more.truth.views[2 + k];
        assert_eq!(t.base_from_ee, Some(*f));
        assert_eq!(t.world_from_camera, f * awl::sim::rig_ee_from_camera());
        // the arm's noise: within 5 mm / 0.5 deg, not zero
        let awl::scan::ViewPose::Chain { base_from_ee, .. } = more.scan.views[2 + k].pose else { panic!("chain") };
        let (dt, dr) = awl::transform::pose_difference(&base_from_ee, f);
        assert!(dt > 0.0 && dt < 0.005 && dr < 0.5f64.to_radians(), "{dt} {dr}");
        assert!(more.views[2 + k].depth.data.iter().filter(|&&d| d > 0).count() > 10_000, "view {} is empty", 2 + k);
    }
    let scan = SimParams::scan(SceneKind::Box);
    assert!(awl::sim::simulate_with_views(&scan, &sent).expect_err("a scan").to_string().contains("shot"));
    let mut bad = sent;
    bad[1].translation.vector.x = f64::NAN;
    let e = awl::sim::simulate_with_views(&p, &bad).expect_err("NaN").to_string();
    assert!(e.contains("views[1].T_base_ee") && e.contains("not finite"), "{e}");
}

/// A fixed arm (`fixed_base`): every view from one base stop, recorded without SLAM error, the
/// cameras spread over about 140 degrees of azimuth around the workpiece on the base's side, 12 to
/// 58 degrees up, within 1.3 m of the base (a UR10e's reach), each looking at the workpiece (its
/// centre within 0.1 m of the optical axis).
#[test]
fn a_fixed_arm_takes_every_view_from_one_base_pose() {
    let sim = simulate(&SimParams { fixed_base: true, ..params(SceneKind::Box, NoiseLevel::Realistic, 3, 20) })
        .expect("simulate");
    // the centre of the CAD's bounding box, world frame
    let (lo, hi) =
        sim.cad.vertices.iter().fold((Vector3::repeat(f64::MAX), Vector3::repeat(f64::MIN)), |(lo, hi), p| {
            (lo.inf(&p.coords), hi.sup(&p.coords))
        });
    let centre = sim.truth.world_from_object * Point3::from((lo + hi) * 0.5);
    let base = sim.truth.views[0].world_from_base.expect("a base pose");
    let mut azimuths = Vec::new();
    for (i, (v, t)) in sim.scan.views.iter().zip(&sim.truth.views).enumerate() {
        assert_eq!(v.extra.get("base_stop").and_then(serde_json::Value::as_u64), Some(0), "view {i}");
        let awl::scan::ViewPose::Chain { world_from_base, .. } = v.pose else { panic!("view {i}: a chain pose") };
        // no SLAM error: the recorded base is the true one, the same for every view
        assert!((world_from_base.to_homogeneous() - base.to_homogeneous()).abs().max() < 1e-12, "view {i}");
        assert_eq!(t.world_from_base, Some(base));
        let eye = t.world_from_camera * Point3::origin();
        let axis = t.world_from_camera.rotation * Vector3::z();
        let to_centre = centre - eye;
        let off_axis = (to_centre - axis * to_centre.dot(&axis)).norm();
        assert!(off_axis < 0.1, "view {i} looks {off_axis} m beside the centre");
        let el = (eye.z - centre.z).atan2((eye - centre).xy().norm()).to_degrees();
        assert!((5.0..=60.0).contains(&el), "view {i}: elevation {el} deg");
        let reach = (eye - Point3::from(base.translation.vector)).norm();
        assert!(reach < 1.3, "view {i}: the camera is {reach} m from the base");
        azimuths.push((eye.y - centre.y).atan2(eye.x - centre.x));
    }
    // the spread of azimuths about the base's direction
    let towards = (base.translation.y - centre.y).atan2(base.translation.x - centre.x);
    let rel: Vec<f64> = azimuths
        .iter()
        .map(|a| (a - towards + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI)
        .collect();
    let span = rel.iter().copied().fold(f64::MIN, f64::max) - rel.iter().copied().fold(f64::MAX, f64::min);
    println!("fixed arm: {} views over {:.0} deg of azimuth", rel.len(), span.to_degrees());
    assert!(span.to_degrees() > 120.0 && span.to_degrees() < 155.0, "{}", span.to_degrees());
}
