//! `awl demo` end to end on a small run (4 views, for speed): the headline is printed and its
//! numbers agree with the files written; a second run into the same folder without --force is
//! refused and leaves the folder as it was.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Output};
use std::time::SystemTime;

fn awl(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_awl")).args(args).output().expect("run awl")
}

/// The number right after `key` in `text` (e.g. `RMSE 0.812 mm` -> 0.812), as printed.
fn number_after<'a>(text: &'a str, key: &str) -> &'a str {
    let at = text.find(key).unwrap_or_else(|| panic!("`{key}` not in the headline:\n{text}"));
    let rest = text[at + key.len()..].trim_start();
    let end = rest.find(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-')).unwrap_or(rest.len());
    &rest[..end]
}

/// Every file under `dir` with its size and modification time.
fn snapshot(dir: &Path) -> BTreeMap<String, (u64, SystemTime)> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).expect("read dir") {
            let entry = entry.expect("entry");
            let meta = entry.metadata().expect("metadata");
            if meta.is_dir() {
                stack.push(entry.path());
            } else {
                let key = entry.path().strip_prefix(dir).expect("inside").display().to_string();
                out.insert(key, (meta.len(), meta.modified().expect("mtime")));
            }
        }
    }
    out
}

#[test]
fn demo_prints_the_headline_and_writes_both_reports() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("demo");
    let dir_s = dir.to_str().expect("utf-8");
    let out = awl(&["demo", "--views", "4", "-o", dir_s]);
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(out.status.success(), "awl demo failed: {}\n{stdout}", String::from_utf8_lossy(&out.stderr));
    println!("{stdout}");
    for step in ["[1/3] simulated a box scan: 4 views", "[2/3] fused 4 views", "[3/3] evaluated"] {
        assert!(stdout.contains(step), "progress line `{step}` missing:\n{stdout}");
    }

    let rmse_text = number_after(&stdout, "RMSE");
    let rmse_mm: f64 = rmse_text.parse().expect("RMSE number");
    let completeness: f64 = number_after(&stdout, "completeness@5mm").parse::<f64>().expect("completeness") / 100.0;
    let off_object: f64 = number_after(&stdout, "off-object").parse().expect("off-object");
    let headline = stdout.lines().find(|l| l.starts_with("RMSE")).expect("headline");
    let points: usize =
        headline.rsplit(", ").next().expect("points").trim_end_matches(" points").parse().expect("points");
    let fuse_s: f64 = number_after(&stdout, "\nfuse").parse().expect("fuse time");
    let total_s: f64 = number_after(&stdout, "total").parse().expect("total time");
    let seed_mm: f64 = number_after(&stdout, "trajectory error").parse().expect("seed error");
    let registered_mm: f64 = number_after(&stdout, "mm ->").parse().expect("registered error");
    assert!(rmse_mm > 0.0 && rmse_mm < 5.0, "RMSE {rmse_mm} mm");
    assert!(completeness > 0.0 && completeness <= 1.0, "completeness {completeness}");
    assert!((0.0..=100.0).contains(&off_object), "off-object {off_object} %");
    assert!(fuse_s > 0.0 && total_s >= fuse_s, "times {fuse_s} / {total_s}");
    assert!(seed_mm > 0.0 && registered_mm >= 0.0, "trajectory {seed_mm} -> {registered_mm}");

    for file in ["scan/scan.json", "scan/cad.ply", "fuse/model.ply", "fuse/report.json", "evaluate/errors.ply"] {
        assert!(dir.join(file).is_file(), "{file} missing");
    }
    let fuse_html = dir.join("fuse/report.html");
    let eval_html = dir.join("evaluate/report.html");
    assert!(stdout.contains(&format!("fuse report: {}", fuse_html.display())), "{stdout}");
    assert!(stdout.contains(&format!("evaluate report: {}", eval_html.display())), "{stdout}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("evaluate/summary.json")).expect("summary"))
            .expect("json");
    let json_rmse_m = summary["distances"]["on_object"]["rmse_m"].as_f64().expect("rmse_m");
    assert_eq!(rmse_text, format!("{:.3}", json_rmse_m * 1e3), "printed RMSE vs summary.json");
    assert_eq!(summary["model_points"].as_u64(), Some(points as u64));
    assert_eq!(summary["alignment"]["method"], "given");
    let eval_page = std::fs::read_to_string(&eval_html).expect("evaluate report");
    assert!(eval_page.contains(&format!("<td id=\"rmse\">{rmse_text}</td>")), "RMSE on the evaluate page");
    let fuse_page = std::fs::read_to_string(&fuse_html).expect("fuse report");
    assert!(fuse_page.contains(&format!("<td id=\"rmse\">{rmse_text}</td>")), "RMSE on the fuse page");
    let renders = std::fs::read_dir(dir.join("evaluate/renders")).expect("renders").count();
    assert_eq!(renders, 4, "heatmap renders");
    println!("pages: fuse {} bytes, evaluate {} bytes", fuse_page.len(), eval_page.len());

    // Again into the same, now non-empty folder, without --force: refused, nothing touched.
    let before = snapshot(&dir);
    let again = awl(&["demo", "--views", "4", "--quiet", "-o", dir_s]);
    assert!(!again.status.success(), "a second run without --force must fail");
    let err = String::from_utf8_lossy(&again.stderr);
    assert!(err.contains("not empty") && err.contains("--force"), "{err}");
    assert_eq!(snapshot(&dir), before, "the folder was changed");
}
