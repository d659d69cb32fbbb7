//! `awl send` against loopback listeners written from the vendors' documents
//! (`tests/py/ur_listener.py`, `tests/py/techman_listener.py`, run with `$AWL_PYTHON`; those tests
//! are skipped with a message only when it is unset): the bytes received equal the plan's program,
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

fn awl(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_awl")).args(args).output().expect("run awl")
}

fn text(out: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr))
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

const UR_PROGRAM: &str = "def awl_pierce():\n  # target 0\n  set_tcp(p[0.000000, 0.000000, 0.150000, 0.000000, 0.000000, 0.000000])\n  movej([0.100000, -1.200000, 1.400000, -1.800000, -1.570000, 0.400000], a=1, v=0.5)\n  movel(p[0.450000, 0.150000, 0.110000, 3.141593, 0.000000, 0.000000], a=0.5, v=0.02)\n  movel(p[0.450000, 0.150000, 0.200000, 3.141593, 0.000000, 0.000000], a=0.5, v=0.02)\nend\n";

fn techman() -> String {
    let mut t = awl::pierce::tmsct_packet(
        "awl0",
        "ChangeBase(\"RobotBase\")\r\nPTP(\"JPP\",5,-70,80,-100,-90,20,20,500,0,true)",
    );
    t.push_str(&awl::pierce::tmsct_packet("awl1", "Line(\"CAP\",450,150,110,180,0,0,20,40,0,true)"));
    t.push_str(&awl::pierce::tmsct_packet("awlexit", "ScriptExit()"));
    t
}

/// A plan.json with the programs and one target (`reach`: its reach block, `go`: the gate's key).
fn write_plan(dir: &Path, name: &str, reach: Value, go: Option<bool>) -> PathBuf {
    let mut target = json!({ "target": "0.45,0.15,0.10", "reach": reach });
    if let Some(go) = go {
        target["go"] = json!(go);
        target["why"] = json!("predicted error 3.1 mm over the 2 mm tolerance");
    }
    let plan = json!({
        "format": "awl-plan/1",
        "targets": [target],
        "programs": { "urscript": UR_PROGRAM, "techman": techman() },
    });
    let path = dir.join(name);
    std::fs::write(&path, serde_json::to_string_pretty(&plan).expect("json")).expect("write");
    path
}

fn reachable() -> Value {
    json!({ "reachable": true, "reason": null })
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
    let dir = tempfile::tempdir().expect("tempdir");
    let plan = write_plan(dir.path(), "plan.json", reachable(), None);
    let Some(l) = listener("ur_listener.py", "state", dir.path()) else { return };
    let out = send(&plan, "--ur", l.port, &[]);
    let (verdict, bytes) = finish(l);
    assert!(out.status.success(), "{}", text(&out));
    println!("{}\nlistener: {verdict}", text(&out));
    assert_eq!(bytes, UR_PROGRAM.as_bytes(), "the bytes received are the plan's program");
    assert_eq!(verdict["errors"], json!([]), "the listener's framing check: {verdict}");
    assert!(text(&out).contains("message type 16"), "{}", text(&out));
    // a listener that accepts the program but never streams state: a clear error after 1 s
    let l = listener("ur_listener.py", "silent", dir.path()).expect("listener");
    let out = send(&plan, "--ur", l.port, &[]);
    let (_, bytes) = finish(l);
    assert!(!out.status.success());
    let t = text(&out);
    println!("silent: {t}");
    assert!(t.contains("no robot state within 1.0 s") && t.contains("127.0.0.1"), "{t}");
    assert_eq!(bytes, UR_PROGRAM.as_bytes());
}

#[test]
fn techman_packets_are_checked_by_the_listener_and_its_negative_answers_are_errors() {
    let dir = tempfile::tempdir().expect("tempdir");
    let plan = write_plan(dir.path(), "plan.json", reachable(), None);
    let Some(l) = listener("techman_listener.py", "ok", dir.path()) else { return };
    let out = send(&plan, "--techman", l.port, &[]);
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
    let l = listener("techman_listener.py", "listen1_warn", dir.path()).expect("listener");
    let out = send(&plan, "--techman", l.port, &[]);
    let (verdict, bytes) = finish(l);
    let t = text(&out);
    println!("listen1_warn: {t}");
    assert!(out.status.success(), "{t}");
    assert_eq!(bytes, techman().as_bytes());
    assert_eq!(verdict["checksums_verified"], 3, "{verdict}");
    assert!(t.contains("said `Listen1` on entering it"), "{t}");
    assert!(t.contains("took packet id awl0 with warnings on its script lines 1\n"), "{t}");
    // a negative acknowledgement of packet 2: an error naming it, and nothing sent after it
    let l = listener("techman_listener.py", "nack2", dir.path()).expect("listener");
    let out = send(&plan, "--techman", l.port, &[]);
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
    let l = listener("techman_listener.py", "error1", dir.path()).expect("listener");
    let out = send(&plan, "--techman", l.port, &[]);
    let (verdict, _) = finish(l);
    let t = text(&out);
    println!("error1: {t}");
    assert!(!out.status.success());
    assert!(t.contains("negative acknowledgement of packet 1 of 3 (TMSCT id awl0): ERROR;1"), "{t}");
    assert_eq!(verdict["packets"], 1);
    // no answer: a timeout after 1 s, nothing more sent
    let l = listener("techman_listener.py", "silent", dir.path()).expect("listener");
    let out = send(&plan, "--techman", l.port, &[]);
    let (verdict, _) = finish(l);
    let t = text(&out);
    println!("silent: {t}");
    assert!(!out.status.success());
    assert!(t.contains("no answer to packet 1 of 3 (TMSCT id awl0) within 1.0 s"), "{t}");
    assert_eq!(verdict["packets"], 1);
}

#[test]
fn nothing_is_sent_for_a_no_go_plan_and_a_dry_run_prints_the_bytes() {
    let dir = tempfile::tempdir().expect("tempdir");
    // a port that is listening but never accepted from: any connection attempt would queue there
    let probe = TcpListener::bind("127.0.0.1:0").expect("bind");
    probe.set_nonblocking(true).expect("nonblocking");
    let port = probe.local_addr().expect("addr").port();
    let unreachable = json!({ "reachable": false, "reason": "36 x collision: the tool is 0.0 mm from the model" });
    for (name, reach, go, expect) in [
        ("unreachable.json", unreachable.clone(), None, "not reachable: 36 x collision"),
        ("nogo.json", reachable(), Some(false), "no-go: predicted error 3.1 mm"),
    ] {
        let plan = write_plan(dir.path(), name, reach, go);
        for flag in ["--ur", "--techman"] {
            let out = send(&plan, flag, port, &[]);
            let t = text(&out);
            assert!(!out.status.success(), "{t}");
            assert!(t.contains("nothing sent") && t.contains(expect) && t.contains("--allow-no-go"), "{t}");
            let out = send(&plan, flag, port, &["--dry-run"]);
            assert!(!out.status.success(), "a dry run is refused the same: {}", text(&out));
        }
        assert!(probe.accept().is_err(), "no connection was made for {name}");
        // --allow-no-go: the dry run prints the bytes
        let out = send(&plan, "--ur", port, &["--dry-run", "--allow-no-go"]);
        assert!(out.status.success(), "{}", text(&out));
        assert_eq!(out.stdout, UR_PROGRAM.as_bytes());
    }
    let plan = write_plan(dir.path(), "plan.json", reachable(), None);
    let out = send(&plan, "--techman", port, &["--dry-run"]);
    assert!(out.status.success(), "{}", text(&out));
    assert_eq!(out.stdout, techman().as_bytes(), "exactly the bytes");
    assert!(probe.accept().is_err(), "a dry run connects to nothing");
    // a closed port: a clear error naming the address
    drop(probe);
    let out = send(&plan, "--ur", port, &[]);
    let t = text(&out);
    println!("closed: {t}");
    assert!(!out.status.success());
    assert!(t.contains(&format!("robot controller 127.0.0.1:{port}: no connection within 1.0 s")), "{t}");
    // bad plans
    let bad = dir.path().join("bad.json");
    std::fs::write(&bad, json!({ "format": "awl-plan/1", "targets": [] }).to_string()).expect("write");
    let t = text(&send(&bad, "--ur", port, &["--dry-run"]));
    assert!(t.contains("programs.urscript") && t.contains("missing"), "{t}");
    std::fs::write(&bad, json!({ "format": "awl-scan/1" }).to_string()).expect("write");
    let t = text(&send(&bad, "--ur", port, &["--dry-run"]));
    assert!(t.contains("field `format`"), "{t}");
    let t = text(&awl(&["send", plan.to_str().expect("utf-8")]));
    assert!(t.contains("--ur") && t.contains("--techman"), "one controller is required: {t}");
}
