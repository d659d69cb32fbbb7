//! Seeded structured-mutation fuzzing of every parser (issue 55): PLY (ascii, binary LE / BE, mesh),
//! PCD (ascii, binary, binary_compressed), STL (ascii, binary), OBJ, PNG depth and color, scan.json,
//! workpiece.json, the hand-eye poses file and the fuse config. Each valid seed file is mutated
//! (bytes flipped, runs deleted or duplicated, truncated, header numbers replaced by huge, negative
//! or non-finite values) and parsed: no panic, no allocation larger than 8 MB + 64 x the file (a
//! counting allocator; the seeds are a few KB), and every error names the file. `AWL_FUZZ_ITERS`
//! (default 150 per parser and seed, about a minute in all) sets the count; `AWL_FUZZ_SEED` the
//! seed. A failing input is written to the temp folder and its path printed: make it a fixture test.
#![cfg(feature = "sim")]
#![allow(unsafe_code)]

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use awl::PointCloud;
use awl::image::{ColorImage, DepthImage};
use awl::io::image::{read_color_png, read_depth_png, write_color_png, write_depth_png};
use awl::io::mesh::{read_cloud, read_mesh};
use awl::io::pcd::{PcdEncoding, write_pcd};
use awl::io::ply::{PlyEncoding, write_ply};
use awl::pipeline::FuseConfig;
use nalgebra::Point3;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The system allocator, recording the largest single request since the last reset.
struct Counting;

static LARGEST: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards to the system allocator unchanged; only records the request's size.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        LARGEST.fetch_max(layout.size(), Ordering::Relaxed);
        // SAFETY: the caller's layout, passed on.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: a block this allocator (the system's) gave.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        LARGEST.fetch_max(new_size, Ordering::Relaxed);
        // SAFETY: as `alloc`.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// One mutation of `seed`, chosen and placed by `rng`.
fn mutate(seed: &[u8], rng: &mut ChaCha8Rng) -> Vec<u8> {
    let mut b = seed.to_vec();
    let rounds = rng.random_range(1..=4);
    for _ in 0..rounds {
        if b.is_empty() {
            b.push(b'0');
        }
        let at = rng.random_range(0..b.len());
        match rng.random_range(0..7) {
            0 => b[at] ^= 1 << rng.random_range(0..8),
            1 => b[at] = rng.random(),
            2 => b.truncate(at),
            3 => {
                let end = (at + rng.random_range(1..64)).min(b.len());
                b.drain(at..end);
            }
            4 => {
                let end = (at + rng.random_range(1..256)).min(b.len());
                let run: Vec<u8> = b[at..end].to_vec();
                b.splice(at..at, run);
            }
            _ => {
                // a number token (as text) replaced by an absurd one
                let is_num = |c: u8| c.is_ascii_digit() || c == b'.' || c == b'-' || c == b'e';
                if let Some(start) = (at..b.len()).find(|&i| b[i].is_ascii_digit()) {
                    let end = (start..b.len()).find(|&i| !is_num(b[i])).unwrap_or(b.len());
                    let absurd =
                        ["4294967295", "18446744073709551615", "-1", "1e300", "NaN", "inf", "0", "99999999999"];
                    let pick = absurd[rng.random_range(0..absurd.len())].as_bytes();
                    b.splice(start..end, pick.iter().copied());
                }
            }
        }
    }
    b
}

type Parser = fn(&Path) -> Result<(), String>;

fn ok_or_message<T>(r: awl::Result<T>) -> Result<(), String> {
    r.map(|_| ()).map_err(|e| e.to_string())
}

/// Fuzzes `parse` on mutations of the seed file `seed_path` (named `file` inside `dir`).
fn fuzz(name: &str, dir: &Path, seed_path: &Path, parse: Parser, iterations: usize, rng: &mut ChaCha8Rng) -> usize {
    let seed = std::fs::read(seed_path).expect("seed");
    assert!(parse(seed_path).is_ok(), "{name}: the seed itself must parse: {:?}", parse(seed_path));
    let mut errors = 0;
    for k in 0..iterations {
        let bytes = mutate(&seed, rng);
        std::fs::write(seed_path, &bytes).expect("write");
        LARGEST.store(0, Ordering::Relaxed);
        let result = std::panic::catch_unwind(|| parse(seed_path));
        let largest = LARGEST.load(Ordering::Relaxed);
        let keep = || {
            let kept = std::env::temp_dir().join(format!("awl-fuzz-{name}-{k}.bin"));
            std::fs::write(&kept, &bytes).expect("keep");
            kept
        };
        match result {
            Err(_) => panic!("{name}: panic on mutation {k}: input kept at {}", keep().display()),
            Ok(Err(message)) => {
                errors += 1;
                let file = seed_path.file_name().and_then(|n| n.to_str()).unwrap_or_default();
                assert!(
                    message.contains(file) || message.contains(&dir.display().to_string()),
                    "{name}: mutation {k}: the error does not name the file: {message} (input {})",
                    keep().display()
                );
            }
            Ok(Ok(())) => {}
        }
        let bound = 8 << 20 | (64 * bytes.len());
        assert!(
            largest <= bound.max(64 * seed.len() + (8 << 20)),
            "{name}: mutation {k} allocated {largest} bytes at once for a {}-byte file (input {})",
            bytes.len(),
            keep().display()
        );
    }
    std::fs::write(seed_path, &seed).expect("restore");
    errors
}

fn small_cloud() -> PointCloud {
    let points = (0..60).map(|i| Point3::new(i as f32 * 0.01, (i % 7) as f32 * 0.02, (i % 5) as f32 * 0.03)).collect();
    PointCloud::from_points(points)
}

const ASCII_STL: &str = "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\nfacet normal 0 0 1\nouter loop\nvertex 1 0 0\nvertex 1 1 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid t\n";
const OBJ: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\nf 2//1 4//1 3//1\n";

fn binary_stl() -> Vec<u8> {
    let mut b = vec![0u8; 80];
    b.extend(2u32.to_le_bytes());
    for tri in [[[0f32, 0., 0.], [1., 0., 0.], [0., 1., 0.]], [[1., 0., 0.], [1., 1., 0.], [0., 1., 0.]]] {
        for v in [0f32, 0., 1.] {
            b.extend(v.to_le_bytes());
        }
        for p in tri {
            for v in p {
                b.extend(v.to_le_bytes());
            }
        }
        b.extend([0, 0]);
    }
    b
}

#[test]
fn every_parser_survives_seeded_mutations_naming_the_file() {
    let iterations: usize = std::env::var("AWL_FUZZ_ITERS").ok().and_then(|v| v.parse().ok()).unwrap_or(150);
    let seed: u64 = std::env::var("AWL_FUZZ_SEED").ok().and_then(|v| v.parse().ok()).unwrap_or(55);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let at = |name: &str| -> PathBuf { d.join(name) };
    let cloud = small_cloud();
    let mut seeds: Vec<(&str, PathBuf, Parser)> = Vec::new();
    let read_cloud_p: Parser = |p| ok_or_message(read_cloud(p));
    let read_mesh_p: Parser = |p| ok_or_message(read_mesh(p));
    for (name, enc) in [
        ("ply-ascii", PlyEncoding::Ascii),
        ("ply-le", PlyEncoding::BinaryLittleEndian),
        ("ply-be", PlyEncoding::BinaryBigEndian),
    ] {
        let p = at(&format!("{name}.ply"));
        write_ply(&p, &cloud, enc).expect("ply");
        seeds.push((name, p, read_cloud_p));
    }
    for (name, enc) in [("pcd-ascii", PcdEncoding::Ascii), ("pcd-binary", PcdEncoding::Binary)] {
        let p = at(&format!("{name}.pcd"));
        write_pcd(&p, &cloud, enc).expect("pcd");
        seeds.push((name, p, read_cloud_p));
    }
    let compressed = common::shared_data().join("pcl/test/milk.pcd");
    let p = at("pcd-compressed.pcd");
    std::fs::copy(&compressed, &p).expect("milk.pcd");
    seeds.push(("pcd-compressed", p, read_cloud_p));
    let mesh = awl::mesh::TriMesh {
        vertices: vec![Point3::origin(), Point3::new(1.0, 0.0, 0.0), Point3::new(0.0, 1.0, 0.0)],
        triangles: vec![[0, 1, 2]],
    };
    let p = at("mesh.ply");
    awl::io::ply::write_ply_mesh(&p, &mesh).expect("ply mesh");
    seeds.push(("ply-mesh", p, read_mesh_p));
    let p = at("ascii.stl");
    std::fs::write(&p, ASCII_STL).expect("stl");
    seeds.push(("stl-ascii", p, read_mesh_p));
    let p = at("binary.stl");
    std::fs::write(&p, binary_stl()).expect("stl");
    seeds.push(("stl-binary", p, read_mesh_p));
    let p = at("mesh.obj");
    std::fs::write(&p, OBJ).expect("obj");
    seeds.push(("obj", p, read_mesh_p));
    let depth = DepthImage { width: 32, height: 24, data: (0..32 * 24).map(|i| (i * 37 % 4000) as u16).collect() };
    let p = at("depth.png");
    write_depth_png(&p, &depth).expect("depth png");
    seeds.push(("png-depth", p, |p| ok_or_message(read_depth_png(p))));
    let color = ColorImage { width: 32, height: 24, data: (0..32 * 24).map(|i| [i as u8, (i * 3) as u8, 7]).collect() };
    let p = at("color.png");
    write_color_png(&p, &color).expect("color png");
    seeds.push(("png-color", p, |p| ok_or_message(read_color_png(p))));
    // scan.json, workpiece.json and the poses file from the simulator and the writers
    let sim = awl::sim::simulate(&awl::sim::SimParams {
        views: 2,
        seed: 3,
        ..awl::sim::SimParams::scan(awl::sim::SceneKind::Box)
    })
    .expect("simulate");
    let scan_dir = at("scan");
    awl::sim::write_simulation(&scan_dir, &sim, false).expect("scan");
    seeds.push(("scan-json", scan_dir.join("scan.json"), |p| {
        ok_or_message(awl::io::scan::read_scan(p.parent().unwrap_or(p)))
    }));
    let cal = awl::sim::calibration::simulate_calibration(&awl::sim::calibration::CalibrationSimParams::default())
        .expect("calibration");
    let p = at("poses.json");
    awl::handeye::poses_file::write_poses(&p, &cal.poses).expect("poses");
    seeds.push(("handeye-poses", p, |p| ok_or_message(awl::handeye::poses_file::read_poses(p))));
    let p = at("workpiece.json");
    let wp = awl::workpiece::Workpiece {
        model: "model.ply".into(),
        model_check: None,
        world_from_tag: Some(nalgebra::Isometry3::translation(0.1, 0.2, 0.3)),
        tag: sim.scan.tag.clone().expect("tag"),
        views_checked: vec![0, 1],
        detections: Vec::new(),
        refinement: None,
        floor: awl::workpiece::FloorPlane::new(nalgebra::Vector3::z(), 0.0),
        hand_eye: None,
        warnings: Vec::new(),
    };
    awl::workpiece::json::write_workpiece(&p, &wp).expect("workpiece");
    seeds.push(("workpiece-json", p, |p| ok_or_message(awl::workpiece::json::read_workpiece(p))));
    let p = at("fuse.json");
    std::fs::write(&p, r#"{"pixel_step": 2, "registration": {"icp": {"kernel": "huber"}}, "smoothing": null}"#)
        .expect("config");
    seeds.push(("fuse-config", p, |p| {
        // as `awl fuse --config x.json`: the JSON merged over the defaults, then checked; the file named
        let text = std::fs::read_to_string(p).map_err(|e| format!("{}: {e}", p.display()))?;
        let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| format!("{}: {e}", p.display()))?;
        let c = FuseConfig::with_overrides(&v).map_err(|e| format!("{}: {e}", p.display()))?;
        c.check().map_err(|e| format!("{}: {e}", p.display()))
    }));
    let mut summary = Vec::new();
    for (name, path, parse) in &seeds {
        let errors = fuzz(name, d, path, *parse, iterations, &mut rng);
        summary.push(format!("{name}: {iterations} mutations, {errors} refused, 0 panics"));
    }
    println!("{}", summary.join("\n"));
}
