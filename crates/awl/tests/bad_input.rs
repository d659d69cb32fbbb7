//! Bad input never panics: every case gives an error that names the file (and the field, for
//! manifests) and says what is wrong.

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
    let err = read_scan(&dir).and_then(|s| load_view(&s, 0, None)).unwrap_err().to_string();
    assert_mentions(&err, &["depth/000000.png", "No such file"]);

    let cases: Vec<(&str, Box<dyn Fn(&Path)>, Vec<&str>)> = vec![
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
        let err = read_scan(&dir).and_then(|s| load_view(&s, 0, None)).unwrap_err().to_string();
        assert!(err.contains("000000.png"), "{name}: `{err}`");
        assert_mentions(&err, needles);
        // the tag search's depth-only load fails the same way
        let depth_only =
            read_scan(&dir).and_then(|s| load_depth_points(&s, 0, None)).expect_err("depth-only load").to_string();
        assert_eq!(depth_only, err, "{name}");
    }
    let err = read_scan(&root.path().join("nowhere")).unwrap_err().to_string();
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
