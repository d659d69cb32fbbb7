//! One writer per output folder: two runs into one folder at once give one complete output and one
//! refusal naming the folder and the first run (its pid); a killed run's lock and staging folder are
//! cleared by the next run, with a note.

mod common;

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::s;

fn spawn(args: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_awl"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn awl")
}

/// Waits until `path` exists (at most 20 s).
fn wait_for(path: &Path) {
    let start = Instant::now();
    while !path.exists() {
        assert!(start.elapsed() < Duration::from_secs(20), "{} never appeared", path.display());
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// The number of views in `dir/scan.json` and of files in `dir/depth`.
fn views(dir: &Path) -> (usize, usize) {
    let scan = common::read_json(&dir.join("scan.json"));
    let listed = scan["views"].as_array().map_or(0, Vec::len);
    let depth = std::fs::read_dir(dir.join("depth")).map_or(0, Iterator::count);
    (listed, depth)
}

/// Nothing of the runs' machinery left beside the output: no lock, no staging folder.
fn no_leftovers(parent: &Path) {
    for e in std::fs::read_dir(parent).expect("ls") {
        let name = e.expect("entry").file_name().to_string_lossy().into_owned();
        assert!(!name.ends_with(".awl-lock") && !name.contains(".tmp-") && !name.contains(".old-"), "left: {name}");
    }
}

#[test]
fn two_simulations_into_one_folder_one_writes_the_other_is_refused_naming_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("scan");
    let lock = dir.path().join(".scan.awl-lock");

    // the second starts while the first holds the folder: refused at once, naming the folder and the first
    let first = spawn(&["simulate", "--views", "12", "--seed", "1", "-o", s(&out)]);
    let first_pid = first.id();
    wait_for(&lock);
    let second = spawn(&["simulate", "--views", "2", "--seed", "2", "-o", s(&out)]).wait_with_output().expect("run");
    let first = first.wait_with_output().expect("run");
    assert!(first.status.success(), "{}", String::from_utf8_lossy(&first.stderr));
    let err = String::from_utf8_lossy(&second.stderr);
    assert!(!second.status.success(), "the second run must fail: {err}");
    assert!(err.contains(s(&out)) && err.contains(&format!("pid {first_pid}")), "{err}");
    assert!(err.contains("another awl run is writing this output") && err.contains("started 20"), "{err}");
    assert_eq!(views(&out), (12, 12), "the first run's output, whole");
    no_leftovers(dir.path());

    // both started together: exactly one succeeds, the other names the folder; the output is the winner's, whole
    let out2 = dir.path().join("scan2");
    let a = spawn(&["simulate", "--views", "3", "--seed", "1", "-o", s(&out2)]);
    let b = spawn(&["simulate", "--views", "4", "--seed", "2", "-o", s(&out2)]);
    let (a, b) = (a.wait_with_output().expect("run"), b.wait_with_output().expect("run"));
    assert_eq!(
        [a.status.success(), b.status.success()].iter().filter(|x| **x).count(),
        1,
        "exactly one run writes: a {:?} {}; b {:?} {}",
        a.status,
        String::from_utf8_lossy(&a.stderr),
        b.status,
        String::from_utf8_lossy(&b.stderr)
    );
    let (winner_views, loser) = if a.status.success() { (3, &b) } else { (4, &a) };
    let err = String::from_utf8_lossy(&loser.stderr);
    assert!(err.contains(s(&out2)), "{err}");
    assert_eq!(views(&out2), (winner_views, winner_views));
    no_leftovers(dir.path());
}

#[test]
fn a_killed_runs_lock_and_staging_folder_are_cleared_by_the_next_run() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("scan");
    let lock = dir.path().join(".scan.awl-lock");
    let mut killed = spawn(&["simulate", "--views", "12", "-o", s(&out)]);
    let pid = killed.id();
    wait_for(&lock);
    killed.kill().expect("kill");
    killed.wait().expect("reap");
    assert!(lock.exists(), "a killed run leaves its lock");
    // the staging folder it would leave when killed while writing
    let staging = dir.path().join(format!(".scan.tmp-{pid}"));
    std::fs::create_dir_all(staging.join("depth")).expect("mkdir");
    std::fs::write(staging.join("scan.json"), b"{").expect("write");
    // not a leftover of this output: kept
    let other = dir.path().join(format!(".scans.tmp-{pid}"));
    std::fs::write(&other, b"mine").expect("write");

    let next = Command::new(env!("CARGO_BIN_EXE_awl"))
        .args(["simulate", "--views", "2", "-o", s(&out)])
        .output()
        .expect("run");
    let err = String::from_utf8_lossy(&next.stderr);
    assert!(next.status.success(), "{err}");
    assert!(err.contains("note: cleared the stale lock") && err.contains(&format!("pid {pid}")), "{err}");
    assert!(err.contains(&format!("removed `{}`", staging.display())), "{err}");
    assert_eq!(views(&out), (2, 2));
    assert_eq!(std::fs::read(&other).expect("kept"), b"mine");
    std::fs::remove_file(&other).expect("rm");
    no_leftovers(dir.path());
}
