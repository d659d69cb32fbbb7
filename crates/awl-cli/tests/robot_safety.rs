//! Nothing unchecked reaches the robot (issue 82), on real plans of `awl pierce` (a simulated box
//! shot and its CAD-sampled workpiece, `common::robot_setup`):
//! - words from files, paths and arguments (an arm file's `name`, the workpiece's folder) with line
//!   breaks, NUL, Unicode separators and bidirectional controls reach no program as statements;
//! - `awl send` refuses a plan.json edited in any one number of its programs, tool poses or joints;
//! - tag detections that disagree (the shot's intrinsics 10 % off) are refused, naming them;
//! - a workpiece whose model was replaced is refused; an older one without `model_check` is no-go
//!   on the shot's poor fit;
//! - a target given three times is planned once.

mod common;

use std::path::{Path, PathBuf};

use awl::pierce::verify::verify_plan;
use awl::robot::statements::{check_techman_statements, check_urscript_statements};
use awl::robot::techman::split_packets;
use common::{awl, pierce_for_robot, read_json, robot_setup, s, text};
use serde_json::Value;

/// The characters a hostile or careless name may carry, and what each is.
const HOSTILE: [(&str, &str); 8] = [
    ("\n  movej([0,0,0,0,0,0], a=3, v=3)\n  #", "a newline and a statement"),
    ("\r  movej([0,0,0,0,0,0], a=3, v=3)\r  #", "carriage returns"),
    ("\r\n  movej([0,0,0,0,0,0], a=3, v=3)\r\n  #", "CR LF"),
    ("\u{2028}movej([0,0,0,0,0,0])\u{2029}", "Unicode line and paragraph separators"),
    ("\u{0}movej([0,0,0,0,0,0])", "NUL"),
    ("\u{202e}0=v ,3=a ,)]0,0,0,0,0,0[(jevom", "a right-to-left override"),
    ("\u{2066}x\u{2069}\u{200f}", "bidirectional isolates and marks"),
    ("\u{85}\u{b}\u{c}\u{1b}[2J", "NEL, VT, FF and an escape sequence"),
];

/// Both programs of a plan: every line one of awl's statements, no `movej` beyond one per target
/// that goes, and no character outside printable ASCII but the line ends.
fn programs_are_awls(plan: &Value, targets_going: usize) {
    let ur = plan["programs"]["urscript"].as_str().expect("urscript");
    check_urscript_statements(ur).unwrap_or_else(|e| panic!("{e}\n{ur}"));
    assert_eq!(ur.lines().filter(|l| l.starts_with("  movej(")).count(), targets_going, "{ur}");
    assert!(ur.bytes().all(|b| b == b'\n' || (b' '..=b'~').contains(&b)), "{ur}");
    let tm = plan["programs"]["techman"].as_str().expect("techman");
    check_techman_statements(&split_packets(tm).expect("packets")).expect("techman statements");
}

/// An arm file: the built-in UR10e's table under `name`.
fn arm_file(path: &Path, name: &str) {
    let mut arm = awl::kinematics::Arm::by_name("ur10e").expect("ur10e");
    arm.name = name.to_string();
    std::fs::write(path, awl::kinematics::arm_file::arm_json(&arm)).expect("arm file");
}

#[test]
fn no_word_from_a_file_a_path_or_an_argument_becomes_a_statement() {
    let mut su = robot_setup();
    let dir = su.cad.dir.path().to_path_buf();
    for (k, (hostile, what)) in HOSTILE.iter().enumerate() {
        // the arm file's name
        let arm = dir.join(format!("arm{k}.json"));
        arm_file(&arm, &format!("x{hostile}"));
        let (out, plan) =
            pierce_for_robot(&su, &format!("arm{k}.plan.json"), "", &["--robot-file", s(&arm), "--tcp", s(&su.tcp)]);
        assert!(out.status.success(), "{what}: {}", text(&out));
        let j = read_json(&plan);
        programs_are_awls(&j, 2);
        assert!(j["programs"]["urscript"].as_str().expect("ur").contains("# reach checked for x"), "{what}");
        // awl send verifies it, and prints it as it is
        let out = awl(&["send", s(&plan), "--ur", "127.0.0.1", "--dry-run"]);
        assert!(out.status.success(), "{what}: {}", text(&out));
        assert_eq!(out.stdout, j["programs"]["urscript"].as_str().expect("ur").as_bytes());

        // the workpiece's folder (a NUL cannot be in a path: the rest can)
        if hostile.contains('\0') {
            continue;
        }
        let folder = dir.join(format!("w{k}{hostile}"));
        std::fs::create_dir_all(&folder).expect("folder");
        for f in ["workpiece.json", "model.ply"] {
            std::fs::copy(dir.join(f), folder.join(f)).expect("copy");
        }
        su.workpiece = folder.join("workpiece.json");
        let (out, plan) = pierce_for_robot(&su, &format!("w{k}.plan.json"), "ur10e", &[]);
        su.workpiece = su.cad.workpiece.clone();
        assert!(out.status.success(), "{what}: {}", text(&out));
        let j = read_json(&plan);
        programs_are_awls(&j, 2);
        let out = awl(&["send", s(&plan), "--techman", "127.0.0.1", "--dry-run"]);
        assert!(out.status.success(), "{what}: {}", text(&out));
        println!("{what}: the programs hold awl's statements only; awl send verifies them");
    }
}

/// Every number of `v` under `path`, with its JSON pointer.
fn numbers(v: &Value, pointer: String, out: &mut Vec<String>) {
    match v {
        Value::Number(_) => out.push(pointer),
        Value::Array(a) => a.iter().enumerate().for_each(|(i, x)| numbers(x, format!("{pointer}/{i}"), out)),
        Value::Object(o) => o.iter().for_each(|(k, x)| numbers(x, format!("{pointer}/{k}"), out)),
        _ => {}
    }
}

/// The number tokens of a program: (byte offset, length).
fn number_tokens(program: &str) -> Vec<(usize, usize)> {
    let b = program.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let starts = b[i].is_ascii_digit() || (b[i] == b'-' && b.get(i + 1).is_some_and(u8::is_ascii_digit));
        // a digit inside a word (`awl0`, `$TMSCT,63`'s header) is not a number of a statement
        let in_word = i > 0 && (b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_' || b[i - 1] == b'$');
        if starts && !in_word {
            let end = (i + 1..b.len()).find(|&j| !(b[j].is_ascii_digit() || b[j] == b'.')).unwrap_or(b.len());
            out.push((i, end - i));
            i = end;
        } else {
            i += 1;
        }
    }
    out
}

#[test]
fn send_refuses_a_plan_edited_in_any_one_number_of_its_programs_poses_or_joints() {
    let su = robot_setup();
    let (out, path) = pierce_for_robot(&su, "plan.json", "ur10e", &[]);
    assert!(out.status.success(), "{}", text(&out));
    let plan = read_json(&path);
    verify_plan(&path, &plan).expect("the plan as written verifies");
    // the joint move to the second target comes from the first one's retract and is checked; the
    // first one's start is not known (the shot records no joints), which the plan says
    assert!(plan["targets"][0]["reach"]["transfer"].is_null(), "{}", plan["targets"][0]["reach"]);
    let transfer = &plan["targets"][1]["reach"]["transfer"];
    println!("transfer to target 1: {transfer}");
    assert_eq!(transfer["from"], "target 0", "{transfer}");
    assert_eq!(transfer["from_q_rad"], plan["targets"][0]["reach"]["q_rad"]["retract"]);
    assert!(transfer["samples"].as_u64().expect("samples") >= 2, "{transfer}");
    assert!(transfer["largest_joint_deg"].as_f64().expect("deg") < 90.0, "a consistent configuration: {transfer}");
    let warned = plan["warnings"]
        .as_array()
        .expect("warnings")
        .iter()
        .any(|w| w.as_str().is_some_and(|w| w.contains("first joint move")));
    assert!(warned, "{}", plan["warnings"]);
    // every number of the tool poses, the reach's joints, tool and flange poses and spin, T_ee_tool,
    // the surface points and axes and the stroke
    let mut pointers = Vec::new();
    for (i, _) in plan["targets"].as_array().expect("targets").iter().enumerate() {
        for key in ["approach", "pierce", "retract", "p_base", "axis_base"] {
            numbers(&plan["targets"][i][key], format!("/targets/{i}/{key}"), &mut pointers);
        }
        for key in ["q_rad", "tool", "flange", "spin_deg"] {
            numbers(&plan["targets"][i]["reach"][key], format!("/targets/{i}/reach/{key}"), &mut pointers);
        }
    }
    numbers(&plan["robot"]["T_ee_tool"], "/robot/T_ee_tool".into(), &mut pointers);
    for key in ["approach_m", "depth_m", "retract_m"] {
        pointers.push(format!("/{key}"));
    }
    for p in &pointers {
        for delta in [1e-3, -1e-5] {
            let mut edited = plan.clone();
            let v = edited.pointer_mut(p).expect("pointer");
            *v = serde_json::json!(v.as_f64().expect("number") + delta);
            let e = verify_plan(&path, &edited).expect_err(&format!("{p} edited by {delta} must be refused"));
            assert!(e.to_string().contains("plan.json"), "{p}: {e}");
        }
    }
    // every number of both programs, one at a time, by one in its last digit
    let mut edits = 0;
    for key in ["urscript", "techman"] {
        let program = plan["programs"][key].as_str().expect("program").to_string();
        for (at, len) in number_tokens(&program) {
            let token = &program[at..at + len];
            let last = token.as_bytes()[len - 1];
            let bumped = format!("{}{}", &token[..len - 1], if last == b'9' { '8' } else { (last + 1) as char });
            let mut edited = plan.clone();
            edited["programs"][key] = Value::String(format!("{}{bumped}{}", &program[..at], &program[at + len..]));
            let e = verify_plan(&path, &edited).expect_err(&format!("{key} `{token}` edited must be refused"));
            assert!(e.to_string().contains(&format!("programs.{key}")) && e.to_string().contains("line"), "{e}");
            edits += 1;
        }
    }
    println!("refused: {} pose / joint numbers edited two ways, {edits} program numbers edited", pointers.len());
    assert!(pointers.len() > 300 && edits > 40, "{} {edits}", pointers.len());
    // a go without a finite bound, a go with a why, and an unreachable go are refused too
    for (pointer, value) in [
        ("/targets/0/predicted_error_mm", Value::Null),
        ("/targets/1/predicted_axis_error_deg", serde_json::json!(1e308 * 10.0)),
        ("/targets/0/why", Value::String("edited".into())),
        ("/targets/1/reach/reachable", Value::Bool(false)),
    ] {
        let mut edited = plan.clone();
        *edited.pointer_mut(pointer).expect("pointer") = value;
        verify_plan(&path, &edited).expect_err(pointer);
    }
    // and through the CLI: one edited number, nothing sent, the line named
    let mut edited = plan.clone();
    let ur = edited["programs"]["urscript"].as_str().expect("ur").replacen("movel(p[0.", "movel(p[1.", 1);
    edited["programs"]["urscript"] = Value::String(ur);
    let bad = su.cad.dir.path().join("edited.json");
    std::fs::write(&bad, serde_json::to_string_pretty(&edited).expect("json")).expect("write");
    let out = awl(&["send", s(&bad), "--ur", "127.0.0.1", "--dry-run"]);
    let t = text(&out);
    assert_eq!(out.status.code(), Some(1), "{t}");
    assert!(t.contains("programs.urscript") && t.contains("line 8 is `  movel(p[1.") && out.stdout.is_empty(), "{t}");
}

#[test]
fn detections_that_disagree_are_refused_and_named() {
    let su = robot_setup();
    // the shot's intrinsics 10 % off: each view's tag pose lands elsewhere
    let scan_json = su.cad.shot.join("scan.json");
    let mut scan: Value = read_json(&scan_json);
    for k in ["fx", "fy"] {
        let v = scan["camera"][k].as_f64().expect(k);
        scan["camera"][k] = serde_json::json!(v * 1.1);
    }
    std::fs::write(&scan_json, serde_json::to_string_pretty(&scan).expect("json")).expect("write");
    let (out, plan) = pierce_for_robot(&su, "plan.json", "", &[]);
    let t = text(&out);
    println!("{t}");
    assert_eq!(out.status.code(), Some(1), "{t}");
    assert!(!plan.exists(), "nothing written");
    assert!(
        t.contains("disagree") && t.contains("view 0 at") && t.contains("view 1 at") && t.contains("intrinsics"),
        "{t}"
    );
}

#[test]
fn a_replaced_model_is_refused_and_an_unchecked_one_that_does_not_fit_is_no_go() {
    let su = robot_setup();
    let dir = su.cad.dir.path();
    let (out, _) = pierce_for_robot(&su, "plan.json", "", &[]);
    assert!(out.status.success(), "{}", text(&out));
    // another part's model: the simulated shell's CAD, sampled
    let shell = dir.join("shell");
    common::simulate_shot(&shell, "shell", "flat", 3, None);
    let truth = awl::io::truth::read_truth(&shell).expect("truth");
    let cad = awl::io::mesh::read_mesh(&shell.join(&truth.cad)).expect("cad");
    let model = awl::normals::with_normals(
        &cad.sample_surface(60_000, 1).expect("sample"),
        &awl::normals::NormalParams::default(),
        None,
    )
    .expect("normals");
    awl::io::mesh::write_cloud(&dir.join("model.ply"), &model).expect("model");
    let (out, plan) = pierce_for_robot(&su, "swapped.json", "", &[]);
    let t = text(&out);
    println!("{t}");
    assert_eq!(out.status.code(), Some(1), "{t}");
    assert!(t.contains("model_check") && t.contains("not the one this workpiece was fused with"), "{t}");
    assert!(!plan.exists());
    // an older workpiece.json without model_check: the shot does not fit the model, nothing goes
    let mut wp: Value = read_json(&su.cad.workpiece);
    wp.as_object_mut().expect("object").remove("model_check");
    std::fs::write(&su.cad.workpiece, serde_json::to_string_pretty(&wp).expect("json")).expect("write");
    let target = {
        let p = model.points[model.points.len() / 2];
        format!("{},{},{}", p.x, p.y, p.z)
    };
    let plan = dir.join("unchecked.json");
    let out = awl(&["pierce", s(&su.cad.workpiece), "--shot", s(&su.cad.shot), "--target", &target, "-o", s(&plan)]);
    let t = text(&out);
    println!("{t}");
    assert_eq!(out.status.code(), Some(3), "{t}");
    let j = read_json(&plan);
    let fitness = j["refinement"]["fitness"].as_f64().expect("fitness");
    assert!(fitness < awl::pierce::MIN_SHOT_FITNESS, "{fitness}");
    assert_eq!(j["targets"][0]["go"], false);
    let why = j["targets"][0]["why"].as_str().expect("why");
    assert!(why.contains("fits the model poorly") || why.contains("does not confirm"), "{why}");
    assert!(t.contains("records no model_check"), "{t}");
    programs_are_awls(&j, 0);
}

#[test]
fn a_target_given_three_times_is_planned_once() {
    let mut su = robot_setup();
    let first = su.targets[0].clone();
    su.targets = vec![first.clone(), first.clone(), first];
    let (out, plan) = pierce_for_robot(&su, "plan.json", "", &[]);
    let t = text(&out);
    assert!(out.status.success(), "{t}");
    let j = read_json(&plan);
    assert_eq!(j["targets"].as_array().expect("targets").len(), 1);
    let warnings: Vec<&str> = j["warnings"].as_array().expect("warnings").iter().filter_map(Value::as_str).collect();
    assert_eq!(warnings.iter().filter(|w| w.contains("planned once")).count(), 2, "{warnings:?}");
    assert_eq!(j["programs"]["urscript"].as_str().expect("ur").matches("movel(").count(), 3);
    let _: PathBuf = plan;
}
