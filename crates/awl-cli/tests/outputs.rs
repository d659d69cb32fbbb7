//! No run damages a user's file (issue 55, damage class): every command's outputs checked against its
//! inputs, the files an input names and each other, symlinks and hard links resolved; `--force` to
//! replace an earlier output in every command; all-or-nothing output folders (a fuse that fails on a
//! full disk, simulated by a file-size limit, leaves nothing). Each case asserts the error names the
//! path and the inputs are byte-identical afterwards.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use common::{awl, ok, s, simulate_shot, text};

/// Every file under `dir` with its bytes.
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut files = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).expect("read_dir") {
            let e = e.expect("entry");
            let t = e.file_type().expect("type");
            if t.is_dir() {
                stack.push(e.path());
            } else if t.is_file() {
                files.insert(e.path(), std::fs::read(e.path()).expect("read"));
            }
        }
    }
    files
}

/// Runs `args`, expecting a refusal whose message holds every one of `wants` and no panic, with
/// everything under `root` byte-identical afterwards (nothing written, nothing removed).
fn refused(root: &Path, args: &[&str], wants: &[&str]) -> String {
    let before = snapshot(root);
    let out = awl(args);
    let t = text(&out);
    assert!(!out.status.success(), "{args:?} must be refused: {t}");
    assert!(!t.contains("panicked"), "{t}");
    for w in wants {
        assert!(t.contains(w), "{args:?}: `{w}` not in: {t}");
    }
    let after = snapshot(root);
    assert_eq!(before.keys().collect::<Vec<_>>(), after.keys().collect::<Vec<_>>(), "{args:?}: files added or removed");
    for (path, bytes) in &before {
        assert!(after[path] == *bytes, "{args:?}: {} changed", path.display());
    }
    t
}

/// A 4-view simulated box scan fused into `fuse/` (model.ply, workpiece.json, ...) and a 1-view shot.
struct Fixture {
    dir: tempfile::TempDir,
    scan: PathBuf,
    fuse: PathBuf,
    shot: PathBuf,
}

fn fixture() -> Fixture {
    let dir = tempfile::tempdir().expect("tempdir");
    let (scan, fuse, shot) = (dir.path().join("scan"), dir.path().join("fuse"), dir.path().join("shot"));
    ok(awl(&["simulate", "--views", "4", "--seed", "2", "-o", s(&scan)]));
    ok(awl(&["fuse", s(&scan), "-o", s(&fuse), "--quiet", "--threads", "2"]));
    simulate_shot(&shot, "box", "flat", 2, Some(1));
    Fixture { dir, scan, fuse, shot }
}

#[test]
fn fuse_and_pierce_refuse_every_output_that_is_an_input_and_fail_whole() {
    let f = fixture();
    let root = f.dir.path();
    let wp = f.fuse.join("workpiece.json");
    let model = f.fuse.join("model.ply");
    let pierce = |extra: &[&str]| -> Vec<String> {
        let mut a: Vec<String> =
            ["pierce", s(&wp), "--shot", s(&f.shot), "--target", "0.1,0.1,0.3"].iter().map(|x| x.to_string()).collect();
        a.extend(extra.iter().map(|x| x.to_string()));
        a
    };
    let run = |a: &[String], wants: &[&str]| refused(root, &a.iter().map(String::as_str).collect::<Vec<_>>(), wants);

    // the cases
    // `awl pierce -o <workpiece folder>/model.ply` would replace the model workpiece.json names
    run(&pierce(&["-o", s(&model)]), &[s(&model), "refusing to overwrite an input file", "the workpiece's model"]);
    // `awl fuse -o` at the scan folder
    refused(root, &["fuse", s(&f.scan), "-o", s(&f.scan)], &[s(&f.scan), "refusing to overwrite an input file"]);
    // `-o` and `--urscript` naming the same file
    let plan = root.join("plan.json");
    run(&pierce(&["-o", s(&plan), "--urscript", s(&plan)]), &["the same file as --urscript", s(&plan)]);
    // `awl fuse -o` over an earlier fuse's folder without --force
    refused(root, &["fuse", s(&f.scan), "-o", s(&f.fuse)], &[s(&f.fuse), "pass --force"]);

    // our own cases
    // the model by a symlink and by a hard link
    let link = root.join("link.ply");
    std::os::unix::fs::symlink(&model, &link).expect("symlink");
    run(&pierce(&["-o", s(&link)]), &[s(&link), "refusing to overwrite an input file"]);
    let hard = root.join("hard.ply");
    std::fs::hard_link(&model, &hard).expect("hard link");
    run(&pierce(&["-o", s(&plan), "--techman", s(&hard)]), &["--techman", s(&hard), "refusing to overwrite"]);
    // a plan written into the shot folder, and over a shot image by a `..` path
    let into_shot = f.shot.join("plan.json");
    run(&pierce(&["-o", s(&into_shot)]), &[s(&into_shot), "refusing to write into the input folder"]);
    let color = f.shot.join("depth/../color/000000.png");
    run(&pierce(&["-o", s(&plan), "--urscript", s(&color)]), &["--urscript", s(&color), "refusing"]);
    // `-o` at the same file as `--techman` through `./`
    let dotted = root.join("./plan.json");
    run(&pierce(&["-o", s(&plan), "--techman", s(&dotted)]), &["the same file as --techman"]);
    // an output folder that holds the scan
    refused(root, &["fuse", s(&f.scan), "-o", s(root)], &["the output folder holds", s(&f.scan)]);
    // the fuse config as the output folder's parent... and a fuse into the scan folder
    let inside = f.scan.join("fused");
    refused(root, &["fuse", s(&f.scan), "-o", s(&inside)], &[s(&inside), "refusing to write into the input folder"]);
    // a view whose depth file lies outside the scan folder, inside the output folder
    let outside = root.join("outside");
    std::fs::create_dir(&outside).expect("mkdir");
    std::fs::copy(f.scan.join("depth/000000.png"), outside.join("d.png")).expect("copy");
    let manifest = f.scan.join("scan.json");
    let original = std::fs::read_to_string(&manifest).expect("scan.json");
    let moved = original.replacen("depth/000000.png", "../outside/d.png", 1);
    assert_ne!(moved, original, "the manifest names depth/000000.png");
    std::fs::write(&manifest, &moved).expect("write");
    refused(root, &["fuse", s(&f.scan), "-o", s(&outside)], &["the output folder holds", "outside/d.png"]);
    std::fs::write(&manifest, &original).expect("write");
    // --force replaces an earlier fuse's folder, but not one that holds a user's own file
    std::fs::write(f.fuse.join("notes.txt"), b"mine").expect("write");
    refused(root, &["fuse", s(&f.scan), "-o", s(&f.fuse), "--force"], &[s(&f.fuse), "holds `notes.txt`"]);
    std::fs::remove_file(f.fuse.join("notes.txt")).expect("rm");

    // --force: the earlier fuse replaced; the folder then holds only the fuse's own files
    let fresh = root.join("fresh");
    ok(awl(&["fuse", s(&f.scan), "-o", s(&fresh), "--quiet", "--threads", "2"]));
    ok(awl(&["fuse", s(&f.scan), "-o", s(&fresh), "--quiet", "--threads", "2", "--force"]));
    let mut names: Vec<String> =
        std::fs::read_dir(&fresh).expect("ls").map(|e| e.expect("e").file_name().to_string_lossy().into()).collect();
    names.sort();
    assert_eq!(names, ["model.ply", "renders", "report.html", "report.json", "workpiece.json"]);
    let siblings: Vec<String> =
        std::fs::read_dir(root).expect("ls").map(|e| e.expect("e").file_name().to_string_lossy().into()).collect();
    assert!(siblings.iter().all(|n| !n.starts_with('.')), "no temporary folder left: {siblings:?}");

    // a full disk: a file-size limit between model.ply's size and report.html's (both measured
    // here: 4.9 MB and 6.0 MB) lets model.ply and report.json be written, then report.html fails;
    // the run leaves no output folder and no temporary one
    let model_len = std::fs::metadata(fresh.join("model.ply")).expect("model").len();
    let html_len = std::fs::metadata(fresh.join("report.html")).expect("html").len();
    assert!(model_len < html_len, "model {model_len} B, report {html_len} B");
    let limit_kib = (model_len + html_len) / 2 / 1024;
    let full = root.join("full");
    let before = snapshot(&f.scan);
    let out = Command::new("bash")
        .arg("-c")
        .arg(format!("trap '' XFSZ; ulimit -f {limit_kib}; exec \"$0\" \"$@\""))
        .arg(env!("CARGO_BIN_EXE_awl"))
        .args(["fuse", s(&f.scan), "-o", s(&full), "--quiet", "--threads", "2"])
        .output()
        .expect("run awl");
    let t = text(&out);
    assert!(!out.status.success() && t.contains("report.html") && !t.contains("panicked"), "{t}");
    assert!(!full.exists(), "a failed fuse leaves no output folder: {t}");
    let siblings: Vec<String> =
        std::fs::read_dir(root).expect("ls").map(|e| e.expect("e").file_name().to_string_lossy().into()).collect();
    assert!(siblings.iter().all(|n| !n.starts_with('.')), "no temporary folder left: {siblings:?}");
    assert!(snapshot(&f.scan) == before, "the scan is untouched");
}

#[test]
fn the_other_commands_refuse_outputs_that_are_inputs_and_want_force() {
    let dir = tempfile::tempdir().expect("tempdir");
    let root = dir.path();
    let poses = root.join("poses.json");
    // the case: `--write-simulated P.json` over an existing poses file
    ok(awl(&["calibrate", "hand-eye", "--write-simulated", s(&poses), "--count", "6", "--seed", "2"]));
    refused(
        root,
        &["calibrate", "hand-eye", "--write-simulated", s(&poses), "--count", "6", "--seed", "3"],
        &["--write-simulated", s(&poses), "pass --force"],
    );
    // our own: --truth at the same file as --write-simulated; -o at --poses by a symlink
    let fresh = root.join("fresh.json");
    refused(
        root,
        &["calibrate", "hand-eye", "--write-simulated", s(&fresh), "--truth", s(&fresh)],
        &["the same file as --truth", s(&fresh)],
    );
    let link = root.join("poses-link.json");
    std::os::unix::fs::symlink(&poses, &link).expect("symlink");
    refused(
        root,
        &["calibrate", "hand-eye", "--poses", s(&poses), "-o", s(&link)],
        &[s(&link), "refusing to overwrite"],
    );
    // an existing result file wants --force, then is replaced
    let result = root.join("T_ee_camera.json");
    ok(awl(&["calibrate", "hand-eye", "--poses", s(&poses), "-o", s(&result)]));
    refused(root, &["calibrate", "hand-eye", "--poses", s(&poses), "-o", s(&result)], &[s(&result), "--force"]);
    ok(awl(&["calibrate", "hand-eye", "--poses", s(&poses), "-o", s(&result), "--force"]));
    // --write-simulated --force replaces the poses file
    ok(awl(&["calibrate", "hand-eye", "--write-simulated", s(&poses), "--count", "6", "--seed", "3", "--force"]));

    // register: -o at TARGET through `..`, and at --init
    let (a, b) = (root.join("a.ply"), root.join("b.ply"));
    std::fs::write(&a, b"ply a").expect("write");
    std::fs::write(&b, b"ply b").expect("write");
    std::fs::create_dir(root.join("sub")).expect("mkdir");
    let via = root.join("sub/../b.ply");
    refused(
        root,
        &["register", s(&a), s(&b), "-o", s(&via)],
        &[s(&via), "refusing to overwrite an input file", "TARGET"],
    );
    let init = root.join("init.json");
    std::fs::write(&init, b"{}").expect("write");
    refused(
        root,
        &["register", s(&a), s(&b), "--init", s(&init), "-o", s(&init)],
        &["--init", "refusing to overwrite"],
    );
    // evaluate: an output folder that holds the model, and one at the CAD file
    refused(root, &["evaluate", s(&a), "--cad", s(&b), "-o", s(root)], &["the output folder holds", s(&a)]);
    refused(root, &["evaluate", s(&a), "--cad", s(&b), "-o", s(&b)], &[s(&b), "refusing to overwrite"]);
    // simulate --force over a folder that is not a simulation: refused naming the user's file
    let mine = root.join("mine");
    std::fs::create_dir(&mine).expect("mkdir");
    std::fs::write(mine.join("thesis.tex"), b"precious").expect("write");
    refused(root, &["simulate", "--views", "2", "-o", s(&mine), "--force"], &["holds `thesis.tex`"]);
    // demo --force with a user's file in DIR/fuse
    let demo = root.join("demo");
    std::fs::create_dir_all(demo.join("fuse")).expect("mkdir");
    std::fs::write(demo.join("fuse/thesis.tex"), b"precious").expect("write");
    refused(root, &["demo", "--views", "2", "-o", s(&demo), "--force"], &["DIR/fuse", "holds `thesis.tex`"]);
}
