//! The PLY/PCD/mesh readers on the real third-party files in `shared/data` (see its SOURCES.md).
//!
//! The folder is `$AWL_SHARED_DATA` when set, else `<workspace>/../shared/data`. These tests fail,
//! not skip, when it is missing.

mod common;
use common::shared_data as data_dir;

use std::path::{Path, PathBuf};
use std::time::Instant;

use awl::PointCloud;
use awl::io::mesh::{read_cloud, read_mesh};
use awl::io::pcd::{read_pcd, read_pcd_organised};
use awl::io::ply::read_ply;

fn file(rel: &str) -> PathBuf {
    let path = data_dir().join(rel);
    assert!(path.is_file(), "shared test file {} is missing", path.display());
    path
}

fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
    let entries = std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    for entry in entries {
        let path = entry.expect("directory entry").path();
        if path.is_dir() {
            walk(&path, out);
        } else if matches!(awl::io::extension(&path).as_str(), "ply" | "pcd") {
            out.push(path);
        }
    }
}

/// The count a file's header states: PLY `element vertex N`, PCD `POINTS N`.
fn header_count(path: &Path) -> usize {
    let bytes = std::fs::read(path).expect("read");
    let head = String::from_utf8_lossy(&bytes[..bytes.len().min(4096)]).into_owned();
    let key = if awl::io::extension(path) == "ply" { "element vertex " } else { "POINTS " };
    let line = head.lines().find(|l| l.starts_with(key)).unwrap_or_else(|| panic!("{}: no `{key}`", path.display()));
    line[key.len()..].trim().parse().expect("count")
}

fn finite(cloud: &PointCloud) -> usize {
    cloud.points.iter().filter(|p| p.coords.iter().all(|c| c.is_finite())).count()
}

#[test]
fn every_ply_and_pcd_loads_with_the_header_count() {
    let mut files = Vec::new();
    walk(&data_dir(), &mut files);
    files.sort();
    let ply = files.iter().filter(|p| awl::io::extension(p) == "ply").count();
    assert!(ply >= 7 && files.len() - ply >= 16, "expected ≥ 7 PLY and ≥ 16 PCD files, found {files:?}");
    for path in &files {
        let stated = header_count(path);
        let t = Instant::now();
        let cloud = read_cloud(path).unwrap_or_else(|e| panic!("{e}"));
        let ms = t.elapsed().as_secs_f64() * 1e3;
        cloud.validate(&path.display().to_string()).unwrap_or_else(|e| panic!("{e}"));
        if awl::io::extension(path) == "ply" {
            assert_eq!(cloud.len(), stated, "{}", path.display());
        } else {
            let grid = read_pcd_organised(path).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(grid.cloud.len(), stated, "{}", path.display());
            assert_eq!(grid.width * grid.height, stated, "{}", path.display());
            assert_eq!(cloud.len(), finite(&grid.cloud), "{}: finite points", path.display());
            assert!(cloud.len() <= stated);
        }
        eprintln!("{:>8} points ({stated:>7} in header) {ms:7.2} ms  {}", cloud.len(), path.display());
    }
}

#[test]
fn known_point_counts_and_attributes() {
    // (file, points after dropping non-finite ones, normals, colors) — from SOURCES.md.
    let table: [(&str, usize, bool, bool); 12] = [
        ("stanford_bunny/bun000.ply", 40_256, false, false),
        ("stanford_bunny/bun045.ply", 40_097, false, false),
        ("stanford_bunny/bun090.ply", 30_379, false, false),
        ("pcl/test/bun0.pcd", 397, true, false),
        ("pcl/test/bun4.pcd", 361, false, false),
        ("pcl/test/milk.pcd", 13_704, false, false),
        ("pcl/correspondence_grouping/milk.pcd", 12_575, false, true),
        ("pcl/correspondence_grouping/milk_cartoon_all_small_clorox.pcd", 241_407, false, true),
        ("pcl/table_scene_mug_stereo_textured.pcd", 209_280, false, true),
        ("pcl/room_scan1.pcd", 112_586, false, false),
        ("pcl/room_scan2.pcd", 112_624, false, false),
        ("open3d_testdata/fragment.pcd", 113_662, true, true),
    ];
    for (rel, n, normals, colors) in table {
        let cloud = read_cloud(&file(rel)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(cloud.len(), n, "{rel}");
        assert_eq!(cloud.normals.is_some(), normals, "{rel}: normals");
        assert_eq!(cloud.colors.is_some(), colors, "{rel}: colors");
    }
    for k in 1..=5 {
        let rel = format!("pcl/pairwise/capture000{k}.pcd");
        let grid = read_pcd_organised(&file(&rel)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((grid.width, grid.height), (640, 480), "{rel}");
        let n = read_pcd(&file(&rel)).expect("read").len();
        assert!((240_000..=252_000).contains(&n), "{rel}: {n} finite points");
    }
}

#[test]
fn bunny_coordinates_and_bounds() {
    let t = Instant::now();
    let bun000 = read_ply(&file("stanford_bunny/bun000.ply")).expect("bun000");
    eprintln!("bun000.ply (ascii, 40,256 vertices + 204,800 range_grid rows): {:?}", t.elapsed());
    // First body line of the file: "-0.06325 0.0359793 0.0420873".
    let p = bun000.points[0];
    assert_eq!((p.x, p.y, p.z), (-0.06325, 0.035_979_3, 0.042_087_3));
    for rel in ["stanford_bunny/bun000.ply", "stanford_bunny/bun045.ply", "stanford_bunny/bun090.ply"] {
        let b = read_ply(&file(rel)).expect("bunny").bounds().expect("non-empty");
        assert!(b.min.y > 0.030 && b.min.y < 0.040 && b.max.y > 0.180 && b.max.y < 0.190, "{rel}: {b:?}");
    }
    let bun0 = read_pcd(&file("pcl/test/bun0.pcd")).expect("bun0");
    let p = bun0.points[0];
    // Its first body line: "0.0054215998 0.11349 0.040748999 -0.16884723 -0.45159745 -0.87609947 ...".
    let f = |s: &str| s.parse::<f32>().expect("number");
    assert_eq!((p.x, p.y, p.z), (f("0.0054215998"), f("0.11349"), f("0.040748999")));
    let n = bun0.normals.as_ref().expect("normals")[0];
    assert_eq!((n.x, n.y, n.z), (f("-0.16884723"), f("-0.45159745"), f("-0.87609947")));
    let bun4 = read_pcd(&file("pcl/test/bun4.pcd")).expect("bun4 (VERSION .5)");
    let p = bun4.points[0];
    assert_eq!((p.x, p.y, p.z), (0.053026, 0.11349, 0.077131));
    // bun0/bun4 are downsampled copies in the frames of bun000/bun045: bounds inside.
    let b000 = bun000.bounds().expect("bounds");
    let b0 = bun0.bounds().expect("bounds");
    for k in 0..3 {
        assert!(b0.min[k] >= b000.min[k] - 2e-3 && b0.max[k] <= b000.max[k] + 2e-3, "axis {k}: {b0:?} vs {b000:?}");
    }
}

#[test]
fn binary_compressed_decodes_to_plausible_geometry() {
    let table = read_pcd(&file("pcl/table_scene_mug_stereo_textured.pcd")).expect("table scene");
    let b = table.bounds().expect("bounds");
    assert!(b.min.z > 0.6 && b.min.z < 0.75 && b.max.z > 2.5 && b.max.z < 2.7, "table z range: {b:?}");
    let colors = table.colors.as_ref().expect("colors");
    assert!(colors.iter().any(|c| c != &colors[0]), "colors vary");
    let room = read_pcd(&file("pcl/room_scan1.pcd")).expect("room");
    let e = room.bounds().expect("bounds").extent();
    assert!(e.x > 5.0 && e.x < 40.0 && e.y > 5.0 && e.y < 40.0, "room extent {e}");
    let milk = read_pcd(&file("pcl/correspondence_grouping/milk.pcd")).expect("milk");
    let e = milk.bounds().expect("bounds").extent();
    assert!(e.max() > 0.05 && e.max() < 0.5, "milk carton extent {e}");
    // Normals of the binary Open3D fragment are unit vectors.
    let fragment = read_pcd(&file("open3d_testdata/fragment.pcd")).expect("fragment");
    let normals = fragment.normals.as_ref().expect("normals");
    assert!(normals.iter().filter(|n| n.iter().all(|c| c.is_finite())).all(|n| (n.norm() - 1.0).abs() < 1e-3));
}

#[test]
fn sim_reference_cad_meshes_load() {
    let dir = data_dir().join("sim_reference");
    let mut found = 0;
    for entry in std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
        let path = entry.expect("entry").path().join("cad.ply");
        if !path.is_file() {
            continue;
        }
        let mesh = read_mesh(&path).unwrap_or_else(|e| panic!("{e}"));
        mesh.validate(&path.display().to_string()).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(mesh.vertices.len(), header_count(&path), "{}", path.display());
        assert!(!mesh.triangles.is_empty() && mesh.area() > 0.0, "{}", path.display());
        let sample = mesh.sample_surface(1000, 1).expect("sample");
        assert_eq!(sample.len(), 1000);
        found += 1;
    }
    assert!(found >= 4, "expected 4 sim_reference/*/cad.ply, found {found}");
}
