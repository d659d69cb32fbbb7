//! No command sends a robot somewhere absurd (issue 55, robot-facing values): `awl pierce`'s stroke
//! options range-checked (`--depth-m` at most 5 cm unless `--allow-long-moves`, stand-offs within an
//! arm's 2 m reach), `awl::pierce::check_for_robot` in front of every robot-facing writer (plan.json,
//! URScript, Techman: a plan with a non-finite or out-of-reach pose is refused by each), and the
//! hand-eye's absurd poses and settings refused naming the pose or flag. Nothing is written on a
//! refusal.

mod common;

use std::path::{Path, PathBuf};

use awl::handeye::poses_file::{parse_poses, poses_json};
use awl::io::mesh::read_cloud;
use awl::io::scan::read_scan;
use awl::pierce::plan_file::{PlanSources, plan_text};
use awl::pierce::{PierceParams, ScriptSpeeds, Stroke, check_for_robot, plan, techman_packets, urscript};
use awl::workpiece::json::read_workpiece;
use awl::workpiece::{SurfaceModel, TargetSpec};
use common::{awl, cad_workpiece, s, text};
use nalgebra::Vector3;

/// A simulated flat box shot and the CAD-sampled model with its workpiece.json (`common`).
struct Setup {
    dir: tempfile::TempDir,
    shot: PathBuf,
    workpiece: PathBuf,
    target: String,
}

fn setup() -> Setup {
    let common::CadWorkpiece { dir, shot, workpiece, truth } = cad_workpiece("flat", 3, 60_000, None);
    let p = truth.targets[0].p_object + truth.targets[0].n_object * 0.003;
    Setup { dir, shot, workpiece, target: format!("{},{},{}", p.x, p.y, p.z) }
}

/// Runs `awl pierce` with `extra`, expecting a refusal holding every one of `wants`; nothing written.
fn refused(su: &Setup, extra: &[&str], wants: &[&str]) {
    let plan = su.dir.path().join("refused.json");
    let script = su.dir.path().join("refused.script");
    let mut args = vec!["pierce", s(&su.workpiece), "--shot", s(&su.shot), "--target", &su.target];
    args.extend(["-o", s(&plan), "--urscript", s(&script)]);
    args.extend(extra);
    let out = awl(&args);
    let t = text(&out);
    assert!(!out.status.success() && !t.contains("panicked"), "{extra:?} must be refused: {t}");
    for w in wants {
        assert!(t.contains(w), "{extra:?}: `{w}` not in {t}");
    }
    assert!(!plan.exists() && !script.exists(), "{extra:?}: nothing written");
}

#[test]
fn pierce_refuses_absurd_strokes_and_every_writer_refuses_an_absurd_pose() {
    let su = setup();
    // the three
    refused(&su, &["--depth-m", "5"], &["--depth-m", "5 m is deeper than the 0.05 m", "--allow-long-moves"]);
    refused(&su, &["--approach-m", "1e6"], &["--approach-m", "1000000 m is beyond an arm's 2 m reach"]);
    refused(&su, &["--retract-m", "1e9"], &["--retract-m", "beyond an arm's 2 m reach"]);
    // ours: just past the limit, past the reach even with --allow-long-moves, NaN, negative, inf
    refused(&su, &["--depth-m", "0.051"], &["--depth-m", "0.051 m is deeper"]);
    refused(&su, &["--depth-m", "2.5", "--allow-long-moves"], &["--depth-m", "2.5 m is deeper than the 2 m"]);
    refused(&su, &["--depth-m", "NaN"], &["--depth-m", "non-negative length"]);
    refused(&su, &["--approach-m=-0.1"], &["--approach-m", "non-negative length"]);
    refused(&su, &["--retract-m", "inf"], &["--retract-m", "non-negative length"]);

    // --allow-long-moves lets a 30 cm stroke through: the pierce pose is 0.30 m past the point
    let plan_path = su.dir.path().join("long.json");
    let out = awl(&[
        "pierce",
        s(&su.workpiece),
        "--shot",
        s(&su.shot),
        "--target",
        &su.target,
        "--depth-m",
        "0.3",
        "--allow-long-moves",
        "-o",
        s(&plan_path),
    ]);
    assert!(out.status.success(), "{}", text(&out));
    let j: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&plan_path).expect("plan")).expect("json");
    let t = &j["targets"][0];
    let v = |x: &serde_json::Value| Vector3::from(serde_json::from_value::<[f64; 3]>(x.clone()).expect("3"));
    let stroke_m = (v(&t["pierce"]["xyz"]) - v(&t["p_base"])).dot(&v(&t["axis_base"]));
    assert!((stroke_m - 0.3).abs() < 1e-9, "pierce {stroke_m} m past the surface");

    // the library's check in front of every writer, on a real plan made absurd
    let wp = read_workpiece(&su.workpiece).expect("workpiece");
    let model = read_cloud(&su.dir.path().join("model.ply")).expect("model");
    let shot = read_scan(&su.shot).expect("shot");
    let surface = SurfaceModel::new(&model).expect("surface").with_floor(wp.floor);
    let specs = [TargetSpec::parse(&su.target).expect("target")];
    let good = plan(&surface, &wp.tag, &wp.world_from_tag.expect("tag"), &shot, &specs, &PierceParams::default())
        .expect("plan");
    check_for_robot(&good).expect("a normal plan passes");
    let sources = PlanSources { workpiece: &su.workpiece, shot: &su.shot, hand_eye: "scan.json" };
    let speeds = ScriptSpeeds::default();
    let mut far = good.clone();
    far.targets[0].poses.approach.translation.vector.x = 1e300;
    let mut nan = good.clone();
    nan.targets[0].poses.retract.translation.vector.z = f64::NAN;
    let mut deep = good.clone();
    deep.stroke = Stroke { depth_m: 0.5, ..Stroke::default() };
    let mut lost = good.clone();
    lost.located.base_from_model.translation.vector.y = 50.0;
    for (name, bad, want) in [
        ("far", &far, "targets[0]"),
        ("nan", &nan, "the tool pose is not finite"),
        ("deep", &deep, "depth_m"),
        ("lost", &lost, "T_base_model"),
    ] {
        for (writer, result) in [
            ("plan.json", plan_text(bad, &sources).map(|_| ())),
            ("URScript", urscript(bad, &speeds, "test").map(|_| ())),
            ("Techman", techman_packets(bad, &speeds).map(|_| ())),
        ] {
            let e = result.err().map(|e| e.to_string()).unwrap_or_default();
            assert!(e.contains(want), "{name} via {writer}: `{e}`");
        }
    }
    let fast = ScriptSpeeds { travel_m_s: 5.0, ..speeds };
    assert!(urscript(&good, &fast, "t").expect_err("5 m/s refused").to_string().contains("travel_m_s"));
}

#[test]
fn hand_eye_refuses_far_poses_and_absurd_settings_naming_them() {
    let dir = tempfile::tempdir().expect("tempdir");
    let poses = dir.path().join("poses.json");
    let out = awl(&["calibrate", "hand-eye", "--write-simulated", s(&poses), "--count", "8", "--seed", "2"]);
    assert!(out.status.success(), "{}", text(&out));
    let good = parse_poses(&poses, &std::fs::read(&poses).expect("read")).expect("poses");
    let result = dir.path().join("T.json");
    let run = |file: &Path, extra: &[&str]| {
        let mut a = vec!["calibrate", "hand-eye", "--poses", s(file), "-o", s(&result)];
        a.extend(extra);
        let out = awl(&a);
        assert!(!out.status.success() && !result.exists(), "must be refused: {}", text(&out));
        text(&out)
    };
    // the case: one pose 1e300 m away (it used to give a NaN residual and exit 0)
    let mut far = good.clone();
    far[3].camera_from_target.translation.vector.z = 1e300;
    let far_path = dir.path().join("far.json");
    std::fs::write(&far_path, poses_json(&far)).expect("write");
    let t = run(&far_path, &[]);
    assert!(t.contains("poses[3].T_camera_target") && t.contains("1.000e300 m"), "{t}");
    // ours: a flange 1e300 m away, poses in millimetres (500 m), and the settings
    for (k, (value, want)) in [(1e300, "poses[5].T_base_ee"), (500.0, "not millimetres")].into_iter().enumerate() {
        let mut bad = good.clone();
        bad[5].base_from_ee.translation.vector.x = value;
        let path = dir.path().join(format!("bad-{k}.json"));
        std::fs::write(&path, poses_json(&bad)).expect("write");
        let t = run(&path, &[]);
        assert!(t.contains(want), "T_base_ee x = {value}: {t}");
    }
    let t = run(&poses, &["--max-iterations", "1000000000000"]);
    assert!(t.contains("--max-iterations") && t.contains("at most 10000"), "{t}");
    let t = run(&poses, &["--max-poses", "5"]);
    assert!(t.contains("8 poses, more than max_poses 5") && t.contains("--max-poses"), "{t}");
}
