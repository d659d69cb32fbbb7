//! Setup shared by the CLI tests (`mod common;` in pierce.rs, robot_limits.rs, outputs.rs,
//! trial_robot.rs, sizes.rs and peak_memory.rs): running the `awl` binary and reading what it prints
//! or writes, PNG files whose header says what the test needs, a simulated piercing-time shot, and
//! the workpiece made from the shot's CAD (sampled in the object frame, so
//! the workpiece's `T_world_tag` is the truth's `T_object_tag`; the fused-model path is tested in
//! crates/awl/tests/fuse_sim.rs and fuse_reference.rs).

// each test file uses its part of these
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use awl::io::mesh::{read_mesh, write_cloud};
use awl::io::scan::read_scan;
use awl::io::truth::{Truth, read_truth};
use awl::workpiece::json::write_workpiece;
use awl::workpiece::{FloorPlane, Workpiece};
use nalgebra::Vector3;

/// Runs the `awl` binary with `args`.
pub fn awl(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_awl")).args(args).output().expect("run awl")
}

/// Its stdout and stderr, one after the other.
pub fn text(out: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr))
}

/// `out` when the run succeeded; otherwise fails the test with what it printed.
pub fn ok(out: Output) -> Output {
    assert!(out.status.success(), "{}", text(&out));
    out
}

/// A path as an argument.
pub fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// A JSON file.
pub fn read_json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).expect("read")).expect("json")
}

/// `awl simulate --scene SCENE --shot POSE --seed SEED [--views N] -o DIR`: a piercing-time shot
/// (world = the robot base).
pub fn simulate_shot(dir: &Path, scene: &str, pose: &str, seed: u64, views: Option<usize>) {
    let seed = seed.to_string();
    let views = views.map(|v| v.to_string());
    let mut args = vec!["simulate", "--scene", scene, "--shot", pose, "--seed", &seed, "-o", s(dir)];
    if let Some(v) = &views {
        args.extend(["--views", v]);
    }
    ok(awl(&args));
}

/// A simulated box shot and the workpiece made from its CAD, in a temporary folder.
pub struct CadWorkpiece {
    /// The temporary folder (removed when dropped).
    pub dir: tempfile::TempDir,
    /// The shot folder (`DIR/shot`).
    pub shot: PathBuf,
    /// `DIR/workpiece.json`, its model `DIR/model.ply`.
    pub workpiece: PathBuf,
    /// The shot's truth.
    pub truth: Truth,
}

/// A box shot in `pose` (`flat`, `tilt30`) with `seed`; its CAD sampled at `samples` points
/// (seed 1) with normals as model.ply, and workpiece.json: `T_world_tag` = the truth's `T_object_tag`,
/// the shot's tag with its id replaced by `tag_id` when given, the floor at the CAD's z = 0 (its
/// footprint, where a fused model would record it).
pub fn cad_workpiece(pose: &str, seed: u64, samples: usize, tag_id: Option<u32>) -> CadWorkpiece {
    let dir = tempfile::tempdir().expect("tempdir");
    let shot = dir.path().join("shot");
    simulate_shot(&shot, "box", pose, seed, None);
    let truth = read_truth(&shot).expect("truth");
    let scan = read_scan(&shot).expect("shot");
    let cad = read_mesh(&shot.join(&truth.cad)).expect("cad");
    let model = awl::normals::with_normals(
        &cad.sample_surface(samples, 1).expect("sample"),
        &awl::normals::NormalParams::default(),
        None,
    )
    .expect("normals");
    write_cloud(&dir.path().join("model.ply"), &model).expect("model");
    let object_from_tag = truth.world_from_object.inverse() * truth.world_from_tag.expect("T_world_tag");
    let mut tag = scan.tag.clone().expect("tag");
    if let Some(id) = tag_id {
        tag.id = id;
    }
    let wp = Workpiece {
        model: "model.ply".into(),
        model_check: Some(awl::workpiece::ModelCheck::of(&model)),
        world_from_tag: Some(object_from_tag),
        tag,
        views_checked: Vec::new(),
        detections: Vec::new(),
        refinement: None,
        floor: FloorPlane::new(Vector3::z(), 0.0),
        hand_eye: None,
        warnings: Vec::new(),
    };
    let workpiece = dir.path().join("workpiece.json");
    write_workpiece(&workpiece, &wp).expect("workpiece");
    CadWorkpiece { dir, shot, workpiece, truth }
}

/// Writes `T_ee_tool` (a tool `tool_m` along the flange's z axis) to `path` for `--tcp`.
pub fn write_tcp(path: &Path, tool_m: f64) {
    let ee_from_tool = nalgebra::Isometry3::translation(0.0, 0.0, tool_m);
    let rows = awl::transform::rows_from_isometry(&ee_from_tool);
    std::fs::write(path, serde_json::json!({ "T_ee_tool": rows }).to_string()).expect("tcp");
}

/// A PNG file of one IHDR (`width` x `height`, `depth` bits, `color` type: 0 gray, 2 RGB), one IDAT
/// holding `idat` as it is, and IEND, each chunk with its CRC: a header claiming anything over a
/// body of any size.
pub fn png_with_header(width: u32, height: u32, depth: u8, color: u8, idat: &[u8]) -> Vec<u8> {
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut chunk = |kind: &[u8], data: &[u8]| {
        out.extend((data.len() as u32).to_be_bytes());
        let body: Vec<u8> = kind.iter().chain(data).copied().collect();
        out.extend(&body);
        out.extend(crc32fast::hash(&body).to_be_bytes());
    };
    let mut ihdr = Vec::new();
    ihdr.extend(width.to_be_bytes());
    ihdr.extend(height.to_be_bytes());
    ihdr.extend([depth, color, 0, 0, 0]);
    chunk(b"IHDR", &ihdr);
    chunk(b"IDAT", idat);
    chunk(b"IEND", &[]);
    out
}

/// A flat box shot with its CAD-sampled workpiece ([`cad_workpiece`], seed 3), a 150 mm tool
/// (`tcp.json`) and two targets on the top face (its centre, and a point 7 cm from it; 3 mm out, so
/// each snaps back onto the surface): what a real plan for an arm is made from.
pub struct RobotSetup {
    /// The workpiece, the shot and their folder.
    pub cad: CadWorkpiece,
    /// The workpiece.json `awl pierce` reads (`cad.workpiece` unless a test moves it).
    pub workpiece: PathBuf,
    /// `--tcp` file.
    pub tcp: PathBuf,
    /// `--target` values.
    pub targets: Vec<String>,
}

/// [`RobotSetup`] on a fresh folder.
pub fn robot_setup() -> RobotSetup {
    let cad = cad_workpiece("flat", 3, 60_000, None);
    let tcp = cad.dir.path().join("tcp.json");
    write_tcp(&tcp, 0.15);
    // the top face's centre, and a point on that face 5 cm off it
    let t = &cad.truth.targets[0];
    let p = t.p_object + t.n_object * 0.003;
    let targets =
        vec![format!("face-centre@{},{},{}", p.x, p.y, p.z), format!("{},{},{}", p.x + 0.05, p.y - 0.05, p.z)];
    let workpiece = cad.workpiece.clone();
    RobotSetup { cad, workpiece, tcp, targets }
}

/// Runs `awl pierce` on `su` for `--robot arm` (or without a robot when `arm` is empty) into
/// `name` (plan.json) in its folder, with `extra` arguments; returns the run and the plan's path.
pub fn pierce_for_robot(su: &RobotSetup, name: &str, arm: &str, extra: &[&str]) -> (Output, PathBuf) {
    let plan = su.cad.dir.path().join(name);
    let mut args = vec!["pierce", s(&su.workpiece), "--shot", s(&su.cad.shot), "-o", s(&plan), "--force"];
    for t in &su.targets {
        args.extend(["--target", t]);
    }
    if !arm.is_empty() {
        args.extend(["--robot", arm, "--tcp", s(&su.tcp)]);
    }
    args.extend(extra);
    (awl(&args), plan)
}
