//! `awl send` against loopback listeners written from the vendors' documents
//! (`tests/py/ur_listener.py`, `tests/py/techman_listener.py`, run with `$AWL_PYTHON`; those tests
//! are skipped with a message only when it is unset), each on a real plan of `awl pierce --robot`
//! (`awl send` verifies a plan before it sends: tests/robot_safety.rs): the bytes received equal the
//! plan's program,
//! the listener verifies the Techman framing and checksums, the listen node's entry message and a
//! script taken with warnings pass, a negative acknowledgement, a script error and a silent
//! controller are clear errors; and without a network: nothing is sent for a
//! plan with an unreachable or no-go target, `--dry-run` prints exactly the bytes, a closed port
//! and bad plans are clear errors.

use std::io::{BufRead, BufReader, Read};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};

use serde_json::{Value, json};

mod common;

use common::{RobotSetup, awl, pierce_for_robot, robot_setup, text};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// A real plan of `awl pierce --robot ur10e` (two targets on a simulated box's top face), with its
/// programs.
struct RealPlan {
    setup: RobotSetup,
    path: PathBuf,
    urscript: String,
    techman: String,
}

fn real_plan() -> RealPlan {
    let setup = robot_setup();
    let (out, path) = pierce_for_robot(&setup, "plan.json", "ur10e", &[]);
    assert!(out.status.success(), "{}", text(&out));
    let j = common::read_json(&path);
    let program = |k: &str| j["programs"][k].as_str().expect("program").to_string();
    let (urscript, techman) = (program("urscript"), program("techman"));
    RealPlan { setup, path, urscript, techman }
}

struct Listener {
    child: Child,
    port: u16,
    received: PathBuf,
}

/// Starts a listener script in `mode`; `None` (with a message) when AWL_PYTHON is unset.
fn listener(script: &str, mode: &str, dir: &Path) -> Option<Listener> {
    let Ok(python) = std::env::var("AWL_PYTHON") else {
        println!("AWL_PYTHON is unset: skipping the {script} check (set it to a Python 3)");
        return None;
    };
    let received = dir.join(format!("{script}-{mode}.bin"));
    let mut child = Command::new(&python)
        .arg(repo().join("tests/py").join(script))
        .args([mode, received.to_str().expect("utf-8")])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot run {python}: {e}"));
    let mut line = String::new();
    BufReader::new(child.stdout.as_mut().expect("stdout")).read_line(&mut line).expect("port line");
    let port = line.trim().parse().unwrap_or_else(|_| panic!("port, got {line:?}"));
    Some(Listener { child, port, received })
}

/// Waits for the listener; returns its verdict (last stdout line) and the bytes it received.
fn finish(mut l: Listener) -> (Value, Vec<u8>) {
    let mut out = String::new();
    l.child.stdout.take().expect("stdout").read_to_string(&mut out).expect("read");
    assert!(l.child.wait().expect("wait").success(), "listener failed: {out}");
    let verdict: Value = serde_json::from_str(out.lines().last().expect("verdict")).expect("json verdict");
    (verdict, std::fs::read(&l.received).expect("received"))
}

fn send(plan: &Path, flag: &str, port: u16, extra: &[&str]) -> Output {
    let port = port.to_string();
    let mut args = vec!["send", plan.to_str().expect("utf-8"), flag, "127.0.0.1", "--port", &port, "--timeout-s", "1"];
    args.extend_from_slice(extra);
    awl(&args)
}

#[test]
fn the_ur_program_arrives_byte_for_byte_and_a_silent_controller_is_an_error() {
    let real = real_plan();
    let (dir, plan) = (real.setup.cad.dir.path(), &real.path);
    let Some(l) = listener("ur_listener.py", "state", dir) else { return };
    let out = send(plan, "--ur", l.port, &[]);
    let (verdict, bytes) = finish(l);
    assert!(out.status.success(), "{}", text(&out));
    println!("{}\nlistener: {verdict}", text(&out));
    assert_eq!(bytes, real.urscript.as_bytes(), "the bytes received are the plan's program");
    assert_eq!(verdict["errors"], json!([]), "the listener's framing check: {verdict}");
    assert!(text(&out).contains("message type 16"), "{}", text(&out));
    // a listener that accepts the program but never streams state: a clear error after 1 s
    let l = listener("ur_listener.py", "silent", dir).expect("listener");
    let out = send(plan, "--ur", l.port, &[]);
    let (_, bytes) = finish(l);
    assert!(!out.status.success());
    let t = text(&out);
    println!("silent: {t}");
    assert!(t.contains("no robot state within 1.0 s") && t.contains("127.0.0.1"), "{t}");
    assert_eq!(bytes, real.urscript.as_bytes());
}

#[test]
fn techman_packets_are_checked_by_the_listener_and_its_negative_answers_are_errors() {
    let real = real_plan();
    let (dir, plan) = (real.setup.cad.dir.path(), &real.path);
    let techman = || real.techman.clone();
    let Some(l) = listener("techman_listener.py", "ok", dir) else { return };
    let out = send(plan, "--techman", l.port, &[]);
    let (verdict, bytes) = finish(l);
    assert!(out.status.success(), "{}", text(&out));
    println!("{}\nlistener: {verdict}", text(&out));
    assert_eq!(bytes, techman().as_bytes());
    assert_eq!(verdict["packets"], 3);
    assert_eq!(verdict["checksums_verified"], 3, "{verdict}");
    assert_eq!(verdict["ids"], json!(["awl0", "awl1", "awlexit"]));
    assert!(text(&out).contains("sent 3 listen-node packets"), "{}", text(&out));
    // the listen node's message on entering it (id 0) before the first answer, and a script taken
    // with a warning (`OK;1`, the manual's `OK;<lines>`): sent whole, both reported
    let l = listener("techman_listener.py", "listen1_warn", dir).expect("listener");
    let out = send(plan, "--techman", l.port, &[]);
    let (verdict, bytes) = finish(l);
    let t = text(&out);
    println!("listen1_warn: {t}");
    assert!(out.status.success(), "{t}");
    assert_eq!(bytes, techman().as_bytes());
    assert_eq!(verdict["checksums_verified"], 3, "{verdict}");
    assert!(t.contains("said `Listen1` on entering it"), "{t}");
    assert!(t.contains("took packet id awl0 with warnings on its script lines 1\n"), "{t}");
    // a negative acknowledgement of packet 2: an error naming it, and nothing sent after it
    let l = listener("techman_listener.py", "nack2", dir).expect("listener");
    let out = send(plan, "--techman", l.port, &[]);
    let (verdict, _) = finish(l);
    let t = text(&out);
    println!("nack2: {t}");
    assert!(!out.status.success());
    assert!(
        t.contains("negative acknowledgement of packet 2 of 3") && t.contains("$CPERR 04 (packet data error)"),
        "{t}"
    );
    assert_eq!(verdict["packets"], 2, "stopped at the NACK: {verdict}");
    // a script error
    let l = listener("techman_listener.py", "error1", dir).expect("listener");
    let out = send(plan, "--techman", l.port, &[]);
    let (verdict, _) = finish(l);
    let t = text(&out);
    println!("error1: {t}");
    assert!(!out.status.success());
    assert!(t.contains("negative acknowledgement of packet 1 of 3 (TMSCT id awl0): ERROR;1"), "{t}");
    assert_eq!(verdict["packets"], 1);
    // no answer: a timeout after 1 s, nothing more sent
    let l = listener("techman_listener.py", "silent", dir).expect("listener");
    let out = send(plan, "--techman", l.port, &[]);
    let (verdict, _) = finish(l);
    let t = text(&out);
    println!("silent: {t}");
    assert!(!out.status.success());
    assert!(t.contains("no answer to packet 1 of 3 (TMSCT id awl0) within 1.0 s"), "{t}");
    assert_eq!(verdict["packets"], 1);
}

#[test]
fn nothing_is_sent_for_a_no_go_plan_and_a_dry_run_prints_the_bytes() {
    let real = real_plan();
    let dir = real.setup.cad.dir.path();
    // a port that is listening but never accepted from: any connection attempt would queue there
    let probe = TcpListener::bind("127.0.0.1:0").expect("bind");
    probe.set_nonblocking(true).expect("nonblocking");
    let port = probe.local_addr().expect("addr").port();
    // a UR3e reaches neither target; a 0.01 mm tolerance refuses both for the UR10e
    for (name, arm, extra, expect) in [
        ("unreachable.json", "ur3e", vec![], "not reachable: "),
        ("nogo.json", "ur10e", vec!["--tolerance-mm", "0.01"], "exceeds the tolerance 0.01 mm"),
    ] {
        let (out, plan) = pierce_for_robot(&real.setup, name, arm, &extra);
        assert_eq!(out.status.code(), Some(3), "{}", text(&out));
        for flag in ["--ur", "--techman"] {
            let out = send(&plan, flag, port, &[]);
            let t = text(&out);
            assert!(!out.status.success(), "{t}");
            assert!(t.contains("nothing sent") && t.contains(expect) && t.contains("--allow-no-go"), "{t}");
            let out = send(&plan, flag, port, &["--dry-run"]);
            assert!(!out.status.success(), "a dry run is refused the same: {}", text(&out));
        }
        assert!(probe.accept().is_err(), "no connection was made for {name}");
        // --allow-no-go: the dry run prints the bytes, a program that moves nowhere
        let out = send(&plan, "--ur", port, &["--dry-run", "--allow-no-go"]);
        assert!(out.status.success(), "{}", text(&out));
        let program = String::from_utf8(out.stdout).expect("utf-8");
        assert!(!program.contains("move") && program.matches("# left out: ").count() == 2, "{program}");
    }
    let plan = &real.path;
    let out = send(plan, "--techman", port, &["--dry-run"]);
    assert!(out.status.success(), "{}", text(&out));
    assert_eq!(out.stdout, real.techman.as_bytes(), "exactly the bytes");
    assert!(probe.accept().is_err(), "a dry run connects to nothing");
    // a closed port: a clear error naming the address
    drop(probe);
    let out = send(plan, "--ur", port, &[]);
    let t = text(&out);
    println!("closed: {t}");
    assert!(!out.status.success());
    assert!(t.contains(&format!("robot controller 127.0.0.1:{port}: no connection within 1.0 s")), "{t}");
    // bad plans
    let bad = dir.join("bad.json");
    std::fs::write(&bad, json!({ "format": "awl-plan/1", "targets": [] }).to_string()).expect("write");
    let t = text(&send(&bad, "--ur", port, &["--dry-run"]));
    assert!(t.contains("programs.urscript") && t.contains("missing"), "{t}");
    std::fs::write(&bad, json!({ "format": "awl-scan/1" }).to_string()).expect("write");
    let t = text(&send(&bad, "--ur", port, &["--dry-run"]));
    assert!(t.contains("field `format`"), "{t}");
    let t = text(&awl(&["send", plan.to_str().expect("utf-8")]));
    assert!(t.contains("--ur") && t.contains("--techman"), "one controller is required: {t}");
}
