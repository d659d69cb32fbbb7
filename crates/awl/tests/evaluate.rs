//! `awl::eval::evaluate` (the `awl evaluate` job) against known answers:
//! - clouds sampled from CAD meshes, misplaced by 7 deg / 4 cm, aligned with no initial pose:
//!   the pose is recovered (modulo the CAD's own symmetries) and the distances equal an independent
//!   brute-force point-triangle computation;
//! - the same with 0.5 mm noise and 10 % floor / outlier points;
//! - a simulated 4-view fused box, checked by `tests/py/check_evaluate.py` (Open3D) within 5 %;
//! - bad input gives typed errors naming the file or field.
#![cfg(all(feature = "sim", feature = "eval"))]

mod common;
use common::shared_data;

use std::path::{Path, PathBuf};
use std::process::Command;

use awl::eval::file::{read_transform, write_evaluation};
use awl::eval::{EvaluateParams, Evaluation, evaluate};
use awl::io::mesh::{read_mesh, write_cloud};
use awl::mesh::TriMesh;
use awl::{Error, PointCloud};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn reference_cad(name: &str) -> TriMesh {
    read_mesh(&shared_data().join("sim_reference").join(name).join("cad.ply")).expect("cad")
}

/// Closest point on triangle abc to p (Ericson, Real-Time Collision Detection, 5.1.5).
fn closest_on_triangle(p: Vector3<f64>, a: Vector3<f64>, b: Vector3<f64>, c: Vector3<f64>) -> Vector3<f64> {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(&ap), ac.dot(&ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(&bp), ac.dot(&bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(&cp), ac.dot(&cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

/// Distance of each point to the mesh by trying every triangle.
fn brute_force_distances(mesh: &TriMesh, points: &[Point3<f32>]) -> Vec<f64> {
    points
        .par_iter()
        .map(|p| {
            let p = p.coords.cast::<f64>();
            mesh.triangles
                .iter()
                .map(|t| {
                    let [a, b, c] = t.map(|i| mesh.vertices[i as usize].coords);
                    (closest_on_triangle(p, a, b, c) - p).norm_squared()
                })
                .fold(f64::INFINITY, f64::min)
                .sqrt()
        })
        .collect()
}

/// The rotation by `angle` about `axis` through the centre of the CAD's bounding box.
fn turn_about_centre(mesh: &TriMesh, axis: &nalgebra::Unit<Vector3<f64>>, angle: f64) -> Isometry3<f64> {
    let lo = mesh.vertices.iter().fold(Vector3::repeat(f64::INFINITY), |a, p| a.inf(&p.coords));
    let hi = mesh.vertices.iter().fold(Vector3::repeat(f64::NEG_INFINITY), |a, p| a.sup(&p.coords));
    let c = (lo + hi) / 2.0;
    Translation3::from(c) * UnitQuaternion::from_axis_angle(axis, angle) * Translation3::from(-c)
}

/// Rotations by 180 deg about the axes of the CAD's bounding box through its centre (the
/// symmetries of a box), or the identity alone.
fn symmetries(mesh: &TriMesh, boxy: bool) -> Vec<Isometry3<f64>> {
    let mut out = vec![Isometry3::identity()];
    if boxy {
        for axis in [Vector3::x_axis(), Vector3::y_axis(), Vector3::z_axis()] {
            out.push(turn_about_centre(mesh, &axis, std::f64::consts::PI));
        }
    }
    out
}

/// (largest displacement of a model point, rotation angle in degrees) between the estimate and the
/// truth, the smallest over the CAD's symmetries.
fn pose_error(model: &PointCloud, est: &Isometry3<f64>, truth: &Isometry3<f64>, sym: &[Isometry3<f64>]) -> (f64, f64) {
    sym.iter()
        .map(|g| {
            let t = g * truth;
            let d =
                model.points.iter().map(|p| (est * p.cast::<f64>() - t * p.cast::<f64>()).norm()).fold(0.0, f64::max);
            (d, (est.rotation.inverse() * t.rotation).angle().to_degrees())
        })
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .expect("identity is always there")
}

/// The 7 deg / 4 cm misplacement: `T_object_model` of a model made by moving CAD samples by its inverse.
fn truth_pose() -> Isometry3<f64> {
    let axis = nalgebra::Unit::new_normalize(Vector3::new(0.3, -0.5, 0.8));
    let delta = Isometry3::from_parts(
        Translation3::from(Vector3::new(0.6, 0.64, -0.48).normalize() * 0.04),
        UnitQuaternion::from_axis_angle(&axis, 7f64.to_radians()),
    );
    delta.inverse()
}

fn sampled_model(cad: &TriMesh, n: usize, seed: u64) -> PointCloud {
    cad.sample_surface(n, seed).expect("sample").transformed(&truth_pose().inverse())
}

fn run(model: &PointCloud, cad: &TriMesh, init: Option<&Isometry3<f64>>) -> Evaluation {
    evaluate(model, cad, init, &EvaluateParams::default()).expect("evaluate")
}

#[test]
fn sampled_cads_are_recovered_without_an_initial_pose() {
    let sim = awl::sim::simulate(&awl::sim::SimParams {
        views: 1,
        noise: awl::sim::NoiseLevel::None,
        ..awl::sim::SimParams::scan(awl::sim::SceneKind::Shell)
    })
    .expect("simulate");
    let cases = [
        ("sim_reference box", reference_cad("box_seed1"), 20_000, true),
        ("sim_reference shell", reference_cad("shell_seed1"), 4_000, false),
        ("awl simulator shell", sim.cad, 4_000, false),
    ];
    for (name, cad, n, boxy) in cases {
        let model = sampled_model(&cad, n, 11);
        let e = run(&model, &cad, None);
        let (d, deg) = pose_error(&model, &e.object_from_model, &truth_pose(), &symmetries(&cad, boxy));
        let brute = brute_force_distances(&cad, &e.model_object.points);
        let worst = brute.iter().zip(&e.distances_m).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        let rmse = (brute.iter().map(|d| d * d).sum::<f64>() / brute.len() as f64).sqrt();
        let s = &e.summary;
        println!(
            "{name}: {} points, pose error {:.2e} mm / {:.2e} deg, RMSE {:.3e} mm (brute force {:.3e} mm), worst per-point difference {worst:.1e} m, score {:.4}, {} hypotheses, {:.1} s",
            n,
            d * 1e3,
            deg,
            s.distances.all.rmse_m * 1e3,
            rmse * 1e3,
            s.alignment.score,
            s.alignment.global.as_ref().map_or(0, |g| g.hypotheses),
            s.timings_s.total_s
        );
        assert_eq!(s.alignment.method, "global");
        assert!(d < 1e-4 && deg < 0.01, "{name}: pose error {d} m / {deg} deg");
        assert!(worst < 1e-9, "{name}: parry vs brute-force distances differ by {worst} m");
        assert!((s.distances.all.rmse_m - rmse).abs() < 1e-9, "{name}: RMSE {} vs {rmse}", s.distances.all.rmse_m);
        assert!(rmse < 1e-5, "{name}: noise-free samples must sit on the CAD (RMSE {rmse} m)");
        assert_eq!(s.distances.off_object_fraction, 0.0);
    }
}

/// Samples with 0.5 mm gaussian noise per coordinate; 5 % replaced by a floor patch (object z = 0,
/// 15 cm around the footprint) and 5 % by uniform outliers 10 cm around the CAD; no normals.
fn noisy_model(cad: &TriMesh, n: usize) -> PointCloud {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut floor_rng = ChaCha8Rng::seed_from_u64(6);
    let noise = Normal::new(0.0, 0.0005).expect("normal");
    let clean = cad.sample_surface(n, 12).expect("sample");
    let lo = clean.bounds().expect("bounds").min.cast::<f64>();
    let hi = clean.bounds().expect("bounds").max.cast::<f64>();
    let mut u = |a: f64, b: f64| a + (b - a) * floor_rng.random::<f64>();
    let points = clean
        .points
        .iter()
        .enumerate()
        .map(|(i, p)| match i % 20 {
            0 => Point3::new(u(lo.x - 0.15, hi.x + 0.15), u(lo.y - 0.15, hi.y + 0.15), lo.z),
            10 => Point3::new(u(lo.x - 0.1, hi.x + 0.1), u(lo.y - 0.1, hi.y + 0.1), u(lo.z - 0.1, hi.z + 0.1)),
            _ => p.cast::<f64>() + Vector3::from_fn(|_, _| noise.sample(&mut rng)),
        })
        .map(|p| p.cast::<f32>())
        .collect();
    PointCloud::from_points(points).transformed(&truth_pose().inverse())
}

#[test]
fn noise_floor_and_outliers_do_not_move_the_alignment() {
    for (name, cad, boxy) in [("box", reference_cad("box_seed1"), true), ("shell", reference_cad("shell_seed1"), false)]
    {
        let model = noisy_model(&cad, 20_000);
        let e = run(&model, &cad, None);
        let (d, deg) = pose_error(&model, &e.object_from_model, &truth_pose(), &symmetries(&cad, boxy));
        let s = &e.summary;
        let on = s.distances.on_object.as_ref().expect("on-object points");
        // the noisy surface samples alone (not floor, not outliers): the distance of an isotropic
        // 0.5 mm gaussian offset to a plane has an RMS of 0.5 mm (a little more or less at edges)
        let samples: Vec<f64> =
            (0..e.distances_m.len()).filter(|i| i % 20 != 0 && i % 20 != 10).map(|i| e.distances_m[i]).collect();
        let samples_rmse = (samples.iter().map(|d| d * d).sum::<f64>() / samples.len() as f64).sqrt();
        println!(
            "{name} + noise 0.5 mm + 10 % floor/outliers: pose error {:.3} mm / {:.4} deg, RMSE of the noisy samples {:.3} mm, on-object RMSE {:.3} mm over {} points, off-object {:.1} %, completeness@5mm {:.1} %, {:.1} s",
            d * 1e3,
            deg,
            samples_rmse * 1e3,
            on.rmse_m * 1e3,
            on.points,
            s.distances.off_object_fraction * 100.0,
            s.completeness_at(5.0).unwrap_or(f64::NAN) * 100.0,
            s.timings_s.total_s
        );
        assert!(d < 5e-4 && deg < 0.05, "{name}: pose error {d} m / {deg} deg");
        assert!((0.45e-3..0.55e-3).contains(&samples_rmse), "{name}: RMSE of the noisy samples {samples_rmse}");
        // at most the 5 % floor + 5 % outliers are off the object (floor under the box is on its bottom face)
        assert!(s.distances.off_object_fraction < 0.1, "{name}: {}", s.distances.off_object_fraction);
    }
}

#[test]
fn a_fused_box_agrees_with_open3d() {
    use awl::sim::{SceneKind, SimParams, simulate, write_simulation};
    let sim = simulate(&SimParams { views: 4, seed: 2, ..SimParams::scan(SceneKind::Box) }).expect("simulate");
    let dir = tempfile::tempdir().expect("tempdir");
    let scan_dir = dir.path().join("scan");
    write_simulation(&scan_dir, &sim, false).expect("write");
    let scan = awl::io::scan::read_scan(&scan_dir).expect("read");
    let fused = awl::pipeline::fuse(&scan, &awl::pipeline::FuseConfig::default(), &|_, _, _| {}).expect("fuse");
    let model_path = dir.path().join("model.ply");
    write_cloud(&model_path, &fused.model).expect("write model");
    let model = awl::io::mesh::read_cloud(&model_path).expect("read model");
    let cad = read_mesh(&scan_dir.join("cad.ply")).expect("cad");
    let from_truth = sim.truth.world_from_object.inverse();
    let given = run(&model, &cad, Some(&from_truth));
    let global = run(&model, &cad, None);
    let (d, deg) = pose_error(&model, &global.object_from_model, &given.object_from_model, &symmetries(&cad, true));
    // The box is 48.5 x 48 cm: turned 90 degrees about z, its sides move 2.5 mm. A 4-view model
    // (61 % complete) fits both ways equally (scores within 1e-5): then the global pose is the
    // truth-started one turned a quarter about the box's axis, to the 2.5 mm the sides differ, and
    // the model's errors against the CAD are the same.
    let quarter_turn = turn_about_centre(&cad, &Vector3::z_axis(), std::f64::consts::FRAC_PI_2);
    let quarter: Vec<Isometry3<f64>> = symmetries(&cad, true).iter().map(|g| quarter_turn * g).collect();
    let (d_turned, deg_turned) = pose_error(&model, &global.object_from_model, &given.object_from_model, &quarter);
    let s = &given.summary;
    let on = s.distances.on_object.as_ref().expect("on-object");
    println!(
        "fused 4-view box: {} points; from truth: moved {:.2} mm / {:.3} deg by the fine ICP, RMSE on-object {:.3} mm (all {:.3} mm), completeness@2/5/10mm {:.1}/{:.1}/{:.1} %; global vs truth-started: {:.3} mm / {:.4} deg",
        model.len(),
        s.alignment.moved_m * 1e3,
        s.alignment.moved_deg,
        on.rmse_m * 1e3,
        s.distances.all.rmse_m * 1e3,
        s.completeness.thresholds[0].fraction * 100.0,
        s.completeness.thresholds[1].fraction * 100.0,
        s.completeness.thresholds[2].fraction * 100.0,
        d * 1e3,
        deg
    );
    let (global_rmse, given_rmse) = (global.summary.distances.all.rmse_m, s.distances.all.rmse_m);
    println!(
        "global: {:.3} mm / {:.4} deg from the truth-started pose, {:.3} mm / {:.4} deg from it turned a quarter; RMSE {:.3} vs {:.3} mm",
        d * 1e3,
        deg,
        d_turned * 1e3,
        deg_turned,
        global_rmse * 1e3,
        given_rmse * 1e3
    );
    assert!(
        (d < 5e-4 && deg < 0.05)
            || (d_turned < 4e-3 && deg_turned < 0.2 && (global_rmse - given_rmse).abs() < 0.05 * given_rmse),
        "global and truth-started alignments differ: {d} m / {deg} deg (turned a quarter: {d_turned} m / {deg_turned} deg)"
    );
    let out = dir.path().join("eval");
    write_evaluation(&out, &given, &[&model_path]).expect("write evaluation");
    let written = read_transform(&out.join("T_object_model.json"), "T_object_model").expect("T");
    let (dt, dr) = awl::transform::pose_difference(&written, &given.object_from_model);
    assert!(dt < 1e-12 && dr < 1e-9, "T_object_model.json reads back {dt} m / {dr} rad off");
    let python = std::env::var("AWL_PYTHON").unwrap_or_else(|_| "python3".into());
    let run = Command::new(&python)
        .arg(repo().join("tests/py/check_evaluate.py"))
        .args([&out, &model_path, &scan_dir.join("cad.ply")])
        .output()
        .unwrap_or_else(|e| panic!("cannot run {python} (set AWL_PYTHON to a Python with numpy and open3d): {e}"));
    let text = format!("{}{}", String::from_utf8_lossy(&run.stdout), String::from_utf8_lossy(&run.stderr));
    println!("{text}");
    assert!(run.status.success(), "Open3D cross-check failed:\n{text}");
}

#[test]
fn bad_input_gives_typed_errors_naming_the_file_or_field() {
    let dir = tempfile::tempdir().expect("tempdir");
    let missing = dir.path().join("nope.stl");
    match read_mesh(&missing) {
        Err(Error::Io { path, .. }) => assert_eq!(path, missing),
        other => panic!("missing CAD: {other:?}"),
    }
    let cad = reference_cad("box_seed1");
    let empty = evaluate(&PointCloud::default(), &cad, None, &EvaluateParams::default()).expect_err("empty");
    assert!(matches!(&empty, Error::Invalid { what, .. } if what == "model"), "{empty}");
    let model = sampled_model(&cad, 500, 3);
    let mut nan = Isometry3::identity();
    nan.translation.vector.y = f64::NAN;
    let err = evaluate(&model, &cad, Some(&nan), &EvaluateParams::default()).expect_err("NaN init");
    assert!(matches!(&err, Error::Invalid { what, .. } if what.contains("init")), "{err}");
    let file = dir.path().join("T.json");
    std::fs::write(&file, r#"{"T_object_model": [[1,0,0,NaN],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}"#).expect("write");
    let err = read_transform(&file, "T_object_model").expect_err("NaN in file");
    assert!(matches!(&err, Error::Format { path, message } if path == &file && message.contains("NaN")), "{err}");
    std::fs::write(&file, r#"{"T_object_model": [[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}"#).expect("write");
    let err = read_transform(&file, "T_object_model").expect_err("scaled");
    assert!(matches!(&err, Error::Field { field, .. } if field == "T_object_model"), "{err}");
    // outputs never replace inputs
    let e = run(&model, &cad, Some(&truth_pose()));
    let out = dir.path().join("out");
    write_evaluation(&out, &e, &[]).expect("first write");
    let err = write_evaluation(&out, &e, &[&out.join("errors.ply")]).expect_err("overwrite input");
    assert!(err.to_string().contains("errors.ply"), "{err}");
    assert!(Path::new(&out.join("summary.json")).is_file());
}

/// The box of `sim_reference/box_seed1` as a model: 30 000 samples of its CAD with 0.5 mm noise,
/// placed in the world by its truth.json; and the truth's `T_world_object`.
fn box_model() -> (PointCloud, Isometry3<f64>) {
    let truth = awl::io::truth::read_truth(&shared_data().join("sim_reference/box_seed1")).expect("truth");
    let samples = reference_cad("box_seed1").sample_surface(30_000, 5).expect("samples");
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let noise = Normal::new(0.0f32, 0.0005).expect("normal");
    let points = samples
        .points
        .iter()
        .map(|p| {
            let q = Point3::from(p.coords + Vector3::from_fn(|_, _| noise.sample(&mut rng)));
            truth.world_from_object.cast::<f32>() * q
        })
        .collect();
    (PointCloud::from_points(points), truth.world_from_object)
}

/// The sanity checks (`eval::sanity`): the right CAD from the right truth gives no warning; a truth
/// in millimetres is an error naming the units, never a NaN; another part's CAD warns.
#[test]
fn a_wrong_cad_warns_a_truth_in_millimetres_is_refused_the_right_pair_is_quiet() {
    let (model, world_from_object) = box_model();
    let (box_cad, shell_cad) = (reference_cad("box_seed1"), reference_cad("shell_seed1"));
    let params = EvaluateParams::default();

    let right = evaluate(&model, &box_cad, Some(&world_from_object.inverse()), &params).expect("evaluate");
    let s = &right.summary;
    println!("right pair: sanity {:?}", s.sanity);
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    assert!(s.sanity.near_fraction > 0.99, "{}", s.sanity.near_fraction);
    assert!(s.sanity.size_ratio < 1.1, "{}", s.sanity.size_ratio);
    let rmse = s.distances.on_object.as_ref().expect("on object").rmse_m;
    // the distance to a face is the noise's normal component: 0.5 mm RMS (30 000 samples: within 10 %)
    assert!((rmse - 0.0005).abs() < 0.00005, "RMSE {rmse} m");

    // truth.json in millimetres: the translation 1000x
    let mut mm = world_from_object.inverse();
    mm.translation.vector *= 1000.0;
    match evaluate(&model, &box_cad, Some(&mm), &params) {
        Ok(e) => {
            panic!("a start in millimetres must be refused, got {:?} / {:?}", e.summary.distances, e.summary.warnings)
        }
        Err(e) => {
            let m = e.to_string();
            println!("millimetres: {m}");
            assert!(matches!(e, Error::NotFinite { .. } | Error::Invalid { .. }), "{e:?}");
            assert!(m.contains("millimetres"), "{m}");
        }
    }

    // another part's CAD, no start: aligned as well as it goes, and warned
    let wrong = evaluate(&model, &shell_cad, None, &params).expect("evaluate");
    let s = &wrong.summary;
    let rmse = s.distances.on_object.as_ref().map_or(f64::NAN, |o| o.rmse_m);
    println!(
        "box model vs shell CAD: RMSE {:.3} mm, near {:.1} %, sizes {:.3} / {:.3} m; warnings {:?}",
        rmse * 1e3,
        s.sanity.near_fraction * 100.0,
        s.sanity.model_size_m,
        s.sanity.cad_size_m,
        s.warnings
    );
    assert!(s.sanity.near_fraction < 0.5, "{}", s.sanity.near_fraction);
    assert!(s.warnings.iter().any(|w| w.contains("within 5 mm of the CAD")), "{:?}", s.warnings);

    // the CAD in millimetres (1000x): the sizes differ, warned (or refused, naming the sizes)
    let mut big = box_cad.clone();
    big.vertices.iter_mut().for_each(|v| v.coords *= 1000.0);
    let said = match evaluate(&model, &big, Some(&world_from_object.inverse()), &params) {
        Ok(e) => e.summary.warnings.join("; "),
        Err(e) => e.to_string(),
    };
    println!("CAD in millimetres: {said}");
    assert!(said.contains("differ by") && said.contains("millimetres"), "{said}");
}
