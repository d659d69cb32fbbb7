//! Bad input never panics: every case gives an error that names the file (and the field, for
//! manifests) and says what is wrong.
#![cfg(all(feature = "sim", feature = "eval"))]

use std::fs;
use std::path::Path;

use awl::image::{ColorImage, DepthImage};
use awl::io::image::{write_color_png, write_depth_png};
use awl::io::scan::{load_depth_points, load_view, read_scan};
use awl::io::{mesh, ply};

const IDENTITY: &str = "[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]";

fn manifest(views: &str, extra: &str) -> String {
    format!(
        r#"{{"format": "awl-scan/1",
  "camera": {{"width": 4, "height": 3, "fx": 615.0, "fy": 615.0, "cx": 2.0, "cy": 1.5,
             "depth_scale": 0.001, "depth_min": 0.15, "depth_max": 3.0}}{extra},
  "views": {views}}}"#
    )
}

fn depth_view(pose: &str) -> String {
    format!(r#"[{{"depth": "depth/000000.png", "T_world_camera": {pose}}}]"#)
}

/// Writes a scan folder with the given manifest and a valid 4x3 depth image; returns its error on read+load.
fn scan_error(dir: &Path, manifest_text: &str) -> String {
    fs::create_dir_all(dir.join("depth")).expect("mkdir");
    let depth = DepthImage { width: 4, height: 3, data: vec![1000; 12] };
    write_depth_png(&dir.join("depth/000000.png"), &depth).expect("depth");
    fs::write(dir.join("scan.json"), manifest_text).expect("manifest");
    match read_scan(dir).and_then(|scan| load_view(&scan, 0, None)) {
        Ok(_) => panic!("expected an error for manifest:\n{manifest_text}"),
        Err(e) => e.to_string(),
    }
}

fn assert_mentions(err: &str, needles: &[&str]) {
    for n in needles {
        assert!(err.contains(n), "error `{err}` does not mention `{n}`");
    }
}

#[test]
fn bad_manifests_name_the_file_and_field() {
    let not_rigid = "[[1.01,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]";
    let reflection = "[[1,0,0,0],[0,1,0,0],[0,0,-1,0],[0,0,0,1]]";
    let bad_last_row = "[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0.5,0,1]]";
    let nan_pose = "[[1,0,0,NaN],[0,1,0,0],[0,0,1,0],[0,0,0,1]]";
    let three_rows = "[[1,0,0,0],[0,1,0,0],[0,0,1,0]]";
    let chain = format!(r#"[{{"depth": "depth/000000.png", "T_world_base": {IDENTITY}, "T_base_ee": {IDENTITY}}}]"#);
    let both = format!(r#"[{{"depth": "depth/000000.png", "points": "p.ply", "T_world_camera": {IDENTITY}}}]"#);
    let half_chain = format!(r#"[{{"depth": "depth/000000.png", "T_world_base": {IDENTITY}}}]"#);
    let neg_fx = manifest(&depth_view(IDENTITY), "").replace("\"fx\": 615.0", "\"fx\": -615.0");
    let bad_range = manifest(&depth_view(IDENTITY), "").replace("\"depth_min\": 0.15", "\"depth_min\": 5.0");
    let cases: Vec<(&str, String, Vec<&str>)> = vec![
        ("non-rigid matrix", manifest(&depth_view(not_rigid), ""), vec!["views[0].T_world_camera", "orthonormal"]),
        ("reflection", manifest(&depth_view(reflection), ""), vec!["views[0].T_world_camera", "determinant"]),
        ("bad last row", manifest(&depth_view(bad_last_row), ""), vec!["views[0].T_world_camera", "last row"]),
        ("NaN in a pose", manifest(&depth_view(nan_pose), ""), vec!["scan.json", "NaN", "line"]),
        ("3x4 matrix", manifest(&depth_view(three_rows), ""), vec!["scan.json", "line"]),
        ("empty views", manifest("[]", ""), vec!["scan.json", "views", "no views"]),
        (
            "wrong format",
            manifest(&depth_view(IDENTITY), "").replace("awl-scan/1", "awl-scan/9"),
            vec!["format", "awl-scan/9"],
        ),
        ("chain without hand-eye", manifest(&chain, ""), vec!["T_ee_camera", "missing"]),
        ("depth and points", manifest(&both, ""), vec!["views[0].points", "not both"]),
        ("half a chain", manifest(&half_chain, ""), vec!["views[0].T_base_ee", "missing"]),
        ("negative fx", neg_fx, vec!["camera.fx", "positive"]),
        ("empty depth range", bad_range, vec!["camera.depth_max", "range"]),
        ("truncated JSON", manifest(&depth_view(IDENTITY), "")[..60].to_string(), vec!["scan.json", "JSON"]),
        (
            "non-rigid hand-eye",
            manifest(&chain, &format!(r#", "T_ee_camera": {not_rigid}"#)),
            vec!["T_ee_camera", "orthonormal"],
        ),
    ];
    let root = tempfile::tempdir().expect("tempdir");
    for (i, (name, text, needles)) in cases.iter().enumerate() {
        let err = scan_error(&root.path().join(format!("case{i}")), text);
        assert!(err.contains("scan.json"), "{name}: error `{err}` does not name scan.json");
        assert_mentions(&err, needles);
    }
}

#[test]
fn bad_view_files_name_the_file() {
    let root = tempfile::tempdir().expect("tempdir");
    let good = manifest(&depth_view(IDENTITY), "");
    let dir = root.path().join("missing");
    fs::create_dir_all(&dir).expect("mkdir");
    fs::write(dir.join("scan.json"), &good).expect("write");
    let err = read_scan(&dir).and_then(|s| load_view(&s, 0, None)).expect_err("an error").to_string();
    assert_mentions(&err, &["depth/000000.png", "No such file"]);

    // what is broken, how (the view's file given), what the error must name
    type Case<'a> = (&'a str, Box<dyn Fn(&Path)>, Vec<&'a str>);
    let cases: Vec<Case> = vec![
        (
            "corrupt PNG",
            Box::new(|p: &Path| fs::write(p, b"\x89PNG\r\n\x1a\nthis is not a png").expect("w")),
            vec!["PNG"],
        ),
        (
            "8-bit depth",
            Box::new(|p: &Path| {
                let img = ColorImage { width: 4, height: 3, data: vec![[9, 9, 9]; 12] };
                write_color_png(p, &img).expect("w")
            }),
            vec!["16-bit"],
        ),
        (
            "wrong size",
            Box::new(|p: &Path| write_depth_png(p, &DepthImage { width: 5, height: 3, data: vec![1; 15] }).expect("w")),
            vec!["5x3", "4x3"],
        ),
        ("empty file", Box::new(|p: &Path| fs::write(p, b"").expect("w")), vec!["PNG"]),
    ];
    for (i, (name, make, needles)) in cases.iter().enumerate() {
        let dir = root.path().join(format!("img{i}"));
        fs::create_dir_all(dir.join("depth")).expect("mkdir");
        fs::write(dir.join("scan.json"), &good).expect("write");
        make(&dir.join("depth/000000.png"));
        let err = read_scan(&dir).and_then(|s| load_view(&s, 0, None)).expect_err("an error").to_string();
        assert!(err.contains("000000.png"), "{name}: `{err}`");
        assert_mentions(&err, needles);
        // the tag search's depth-only load fails the same way
        let depth_only =
            read_scan(&dir).and_then(|s| load_depth_points(&s, 0, None)).expect_err("depth-only load").to_string();
        assert_eq!(depth_only, err, "{name}");
    }
    let err = read_scan(&root.path().join("nowhere")).expect_err("an error").to_string();
    assert_mentions(&err, &["nowhere", "scan.json"]);
}

#[test]
fn bad_cloud_and_mesh_files_name_the_file() {
    let root = tempfile::tempdir().expect("tempdir");
    let p = |name: &str| root.path().join(name);
    let header =
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
    fs::write(p("short.ply"), format!("{header}0 0 0\n1 1 1\n")).expect("w");
    fs::write(p("word.ply"), format!("{header}0 0 0\n1 one 1\n2 2 2\n")).expect("w");
    fs::write(p("nox.ply"), "ply\nformat ascii 1.0\nelement vertex 1\nproperty float y\nend_header\n1\n").expect("w");
    let bin = "ply\nformat binary_little_endian 1.0\nelement vertex 100\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
    let mut truncated = bin.as_bytes().to_vec();
    truncated.extend_from_slice(&[0u8; 100]);
    fs::write(p("truncated.ply"), truncated).expect("w");
    fs::write(p("notply.ply"), "hello world\n").expect("w");
    fs::write(p("bad.pcd"), "VERSION 0.7\nFIELDS x y z\nSIZE 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2 3\n").expect("w");
    fs::write(
        p("short.pcd"),
        "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 5\nHEIGHT 1\nPOINTS 5\nDATA binary\n",
    )
    .expect("w");
    fs::write(p("cloud.xyz"), "1 2 3\n").expect("w");
    let mesh_bad = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n";
    fs::write(p("badindex.ply"), mesh_bad).expect("w");
    let cloud_cases = [
        ("short.ply", "vertex"),
        ("word.ply", "one"),
        ("nox.ply", "x"),
        ("truncated.ply", "truncated"),
        ("notply.ply", "ply"),
        ("bad.pcd", "SIZE"),
        ("short.pcd", "truncated"),
        ("cloud.xyz", "xyz"),
        ("absent.ply", "No such file"),
    ];
    for (name, needle) in cloud_cases {
        let err = mesh::read_cloud(&p(name)).expect_err(name).to_string();
        assert!(err.contains(name), "{name}: `{err}` does not name the file");
        assert!(err.to_lowercase().contains(&needle.to_lowercase()), "{name}: `{err}` does not mention `{needle}`");
    }
    let err = ply::read_ply_mesh(&p("badindex.ply")).expect_err("bad index").to_string();
    assert_mentions(&err, &["badindex.ply", "7"]);
    let err = mesh::read_mesh(&p("model.step")).expect_err("unknown mesh format").to_string();
    assert_mentions(&err, &["model.step", "stl"]);
}

/// Issue 55's vague errors, each now naming the file, field or key and what to change: a binary STL
/// cut short (was `failed to fill whole buffer`), a CAD without triangles (was `EmptyIndices`), a
/// NaN point in a cloud file (was `k-d tree: point 0 is not finite` further on: now dropped with a
/// warning naming the file, a mesh's refused naming the vertex), the region-of-interest crop that
/// empties every view (was once per view, without the key or the focus point).
#[test]
fn issue_55_vague_errors_name_the_place_and_the_fix() {
    let root = tempfile::tempdir().expect("tempdir");
    let p = |name: &str| root.path().join(name);
    // a binary STL of 3 facets cut short
    let mut stl = vec![b' '; 80];
    stl.extend(3u32.to_le_bytes());
    for _ in 0..3 {
        for v in [0f32, 0., 1., 0., 0., 0., 1., 0., 0., 0., 1., 0.] {
            stl.extend(v.to_le_bytes());
        }
        stl.extend([0, 0]);
    }
    fs::write(p("cut.stl"), &stl[..200]).expect("w");
    let err = mesh::read_mesh(&p("cut.stl")).expect_err("cut").to_string();
    assert_mentions(&err, &["cut.stl", "facet count (bytes 80-83) is 3", "84 + 50 × 3 = 234 bytes", "has 200"]);
    assert!(!err.contains("fill whole buffer"), "{err}");
    // bytes after the facets: read, with a warning
    fs::write(p("long.stl"), [stl.as_slice(), b"trailer"].concat()).expect("w");
    let long = mesh::read_mesh_checked(&p("long.stl")).expect("long");
    assert_eq!((long.value.triangles.len(), long.value.vertices.len()), (3, 3));
    assert_eq!(long.warnings.len(), 1);
    assert_mentions(&long.warnings[0], &["long.stl", "7 bytes after the 3 facets"]);
    // a binary STL whose header starts with `solid` is still binary when its size says so
    fs::write(p("solid.stl"), [b"solid by name".as_slice(), &stl[13..]].concat()).expect("w");
    assert_eq!(mesh::read_mesh(&p("solid.stl")).expect("binary named solid").triangles.len(), 3);
    // a mesh with a NaN vertex is refused, naming the vertex and a triangle using it
    let mut nan = stl.clone();
    nan[84 + 12..84 + 16].copy_from_slice(&f32::NAN.to_le_bytes());
    fs::write(p("nan.stl"), &nan).expect("w");
    let err = mesh::read_mesh(&p("nan.stl")).expect_err("nan").to_string();
    assert_mentions(&err, &["nan.stl", "vertex 0 (NaN, 0, 0), a corner of triangle 0, is not finite", "fix or remove"]);
    // a CAD without triangles: named before any BVH is built
    fs::write(p("verts.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\n").expect("w");
    let cad = mesh::read_mesh(&p("verts.obj")).expect("vertices only");
    let err = awl::eval::MeshDistance::new(&cad).err().expect("no triangles").to_string();
    assert_mentions(&err, &["CAD mesh", "no triangles (0 vertices)", "`face` element"]);
    assert!(!err.contains("EmptyIndices"), "{err}");
    // NaN and infinite points in clouds: dropped, the warning names the file and the count
    let header = |n: usize| {
        format!(
            "ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
        )
    };
    let rows = "0 0 0\n1 0 0\nnan 1 0\n0 0 1\n0 inf 2\n";
    fs::write(p("nan.ply"), format!("{}{rows}", header(5))).expect("w");
    let cloud = mesh::read_cloud_checked(&p("nan.ply")).expect("nan cloud");
    assert_eq!(cloud.value.len(), 3);
    let bounds = cloud.value.bounds().expect("the finite points' bounds");
    assert_eq!((bounds.min.x, bounds.max.x, bounds.max.z), (0.0, 1.0, 1.0));
    assert_eq!(cloud.warnings.len(), 1);
    assert_mentions(
        &cloud.warnings[0],
        &["nan.ply", "2 of 5 points have a NaN or infinite coordinate and were dropped"],
    );
    let pcd = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 3\nHEIGHT 1\nPOINTS 3\nDATA ascii\n\
               1 2 3\nnan nan nan\n4 5 6\n";
    fs::write(p("nan.pcd"), pcd).expect("w");
    let cloud = mesh::read_cloud_checked(&p("nan.pcd")).expect("nan pcd");
    assert_eq!(cloud.value.len(), 2);
    assert_mentions(&cloud.warnings.join(" "), &["nan.pcd", "1 of 3 points"]);
    // the region of interest that empties every view: one error, the key, its value, the focus point
    let sim = awl::sim::simulate(&awl::sim::SimParams {
        views: 2,
        seed: 3,
        ..awl::sim::SimParams::scan(awl::sim::SceneKind::Box)
    })
    .expect("simulate");
    let scan_dir = p("scan");
    awl::sim::write_simulation(&scan_dir, &sim, false).expect("scan");
    let scan = read_scan(&scan_dir).expect("read");
    let mut config = awl::pipeline::FuseConfig::fast();
    config.roi.radius_m = Some(1e-4);
    let err = awl::pipeline::fuse(&scan, &config, &|_, _, _| {}).expect_err("every view emptied").to_string();
    assert_mentions(
        &err,
        &["in 2 of 2 views (0, 1)", "`roi.radius_m` = 0.0001 m of the focus point (", "raise `roi.radius_m`"],
    );
    assert_eq!(err.matches("focus point").count(), 1, "once, not per view: {err}");
}
