//! `awl trial --robot` (issue 58's trials): each trial's plan checked for the arm at the simulated
//! rig's robot base. One trial of the box flat and one of the box tilted 30 degrees with a UR5e
//! and a 150 mm tool: the flat box's top centre reachable with margins, the tilted one (its top
//! 0.92 m out and turned away) not, with the reason and the distance printed; the reach column,
//! trial.json's reach blocks and the count; an unreachable target is a report (exit 0). Bad robot
//! input is refused before anything is simulated.

mod common;

use std::path::Path;
use std::process::{Command, Stdio};

use common::{awl, read_json, s, text, write_tcp};

/// Starts `awl trial --scene box --tilt TILT --trials 1 --robot ARM --tcp TCP -o OUT` on one thread
/// (the two runs go side by side).
fn start_trial(tilt: &str, arm: &str, tcp: &Path, out: &Path) -> std::process::Child {
    Command::new(env!("CARGO_BIN_EXE_awl"))
        .args(["trial", "--scene", "box", "--tilt", tilt, "--trials", "1", "--threads", "1", "--quiet"])
        .args(["--robot", arm, "--tcp", s(tcp), "-o", s(out)])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run awl trial")
}

#[test]
fn the_trials_report_each_targets_reach_for_the_arm_at_the_rigs_base() {
    let dir = tempfile::tempdir().expect("tempdir");
    let tcp = dir.path().join("tcp.json");
    write_tcp(&tcp, 0.15);
    let (flat_dir, tilted_dir) = (dir.path().join("flat"), dir.path().join("tilted"));
    let flat = start_trial("0", "ur5e", &tcp, &flat_dir);
    let tilted = start_trial("30", "ur5e", &tcp, &tilted_dir);
    let (flat, tilted) = (flat.wait_with_output().expect("flat"), tilted.wait_with_output().expect("tilted"));
    println!("{}\n{}", text(&flat), text(&tilted));
    // an unreachable target is reported, not an error
    assert!(flat.status.success() && tilted.status.success(), "{}{}", text(&flat), text(&tilted));

    // the flat box: reachable, its margins and clearance measured (UR5e, seed 1, trial 1: limits
    // 118.8 deg, wrist sin 1.00, elbow sin 0.87, shoulder 803 mm; the tool 21.0 mm from the model at
    // the edge of the zone left out around the target; the top 0.814 m from joint 1's axis)
    let t = text(&flat);
    assert!(t.contains("reach for ur5e with the TCP 150 mm from the flange"), "{t}");
    assert!(t.contains("| reach\n") && t.contains("| yes\n"), "the reach column: {t}");
    assert!(t.contains("reach: 1 of 1 trial targets reachable"), "{t}");
    let j = read_json(&flat_dir.join("trial.json"));
    assert_eq!(j["robot"]["arm"], "ur5e");
    assert_eq!(j["summary"]["reachable"], 1);
    assert_eq!(j["summary"]["reach_checked"], 1);
    let row = &j["rows"][0];
    let r = &row["reach"];
    assert_eq!(r["reachable"], true, "{r}");
    assert!(r["reason"].is_null());
    let m = &r["margins"];
    let num = |v: &serde_json::Value| v.as_f64().unwrap_or_else(|| panic!("a number: {v}"));
    assert!(num(&m["limit_deg"]) > 90.0, "{m}");
    assert!(num(&m["wrist_sin"]) > 0.9 && num(&m["elbow_sin"]) > 0.7, "{m}");
    assert!(num(&m["shoulder_m"]) > 0.6, "{m}");
    let clearance_mm = num(&r["clearance"]["m"]) * 1e3;
    assert!((15.0..30.0).contains(&clearance_mm), "{}", r["clearance"]);
    assert_eq!(r["clearance"]["link"], "tool");
    for pose in ["approach", "pierce", "retract"] {
        let q: [f64; 6] = serde_json::from_value(r["q_rad"][pose].clone()).expect("6 joints");
        assert!(q.iter().all(|v| v.is_finite()), "{pose}: {q:?}");
    }
    let out_m = num(&row["base_horizontal_m"]);
    assert!((0.6..0.9).contains(&out_m), "the rig places the box 0.6-0.9 m out: {out_m}");

    // tilted 30 degrees: out of the UR5e's reach, the reason and the distance printed (measured:
    // the top 0.924 m from the base, the wrist needing 0.979 m between joints 2 and 4, the arm
    // spanning 0.817 m)
    let t = text(&tilted);
    assert!(t.contains("| NO\n") && t.contains("reach: 0 of 1 trial targets reachable"), "{t}");
    let j = read_json(&tilted_dir.join("trial.json"));
    assert_eq!(j["summary"]["reachable"], 0);
    let row = &j["rows"][0];
    let r = &row["reach"];
    assert_eq!(r["reachable"], false, "{r}");
    let reason = r["reason"].as_str().expect("reason");
    assert!(
        reason.contains("out of reach: the wrist needs") && reason.contains("the arm spans 0.0328-0.8172 m"),
        "{reason}"
    );
    let distance_m = num(&row["base_distance_m"]);
    assert!((distance_m - 0.924).abs() < 0.01, "{distance_m}");
    assert!(t.contains("NOT reachable (target 0.92") && t.contains("m from the base origin"), "{t}");
    assert!(r["q_rad"].is_null() && r["margins"].is_null());
}

#[test]
fn bad_robot_input_is_refused_before_the_trial_runs() {
    let dir = tempfile::tempdir().expect("tempdir");
    let tcp = dir.path().join("tcp.json");
    write_tcp(&tcp, 0.15);
    let out_dir = dir.path().join("out");
    let fail = |extra: &[&str]| {
        let mut args = vec!["trial", "--trials", "1", "-o", s(&out_dir)];
        args.extend_from_slice(extra);
        let out = awl(&args);
        let t = text(&out);
        assert!(!out.status.success() && !t.contains("panicked"), "{extra:?}: {t}");
        assert!(!out_dir.join("scan").exists(), "{extra:?}: nothing simulated");
        t
    };
    let t = fail(&["--robot", "ur6", "--tcp", s(&tcp)]);
    assert!(t.contains("unknown arm `ur6`") && t.contains("ur5e"), "{t}");
    let t = fail(&["--robot", "ur5e"]);
    assert!(t.contains("--tcp"), "{t}");
    let t = fail(&["--tcp", s(&tcp)]);
    assert!(t.contains("need --robot"), "{t}");
    let t = fail(&["--robot", "ur5e", "--tcp", s(&tcp), "--tool-radius-m=-1"]);
    assert!(t.contains("--tool-radius-m"), "{t}");
    // a TCP file the run would delete (inside the output folder's shots/)
    std::fs::create_dir_all(out_dir.join("shots")).expect("mkdir");
    let inside = out_dir.join("shots/tcp.json");
    write_tcp(&inside, 0.15);
    let t = fail(&["--robot", "ur5e", "--tcp", s(&inside), "--force"]);
    assert!(t.contains("--tcp") && t.contains("refusing to use an input the trial replaces"), "{t}");
    assert!(inside.exists(), "the input is kept");
}
