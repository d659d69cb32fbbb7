//! report.html in a real browser: `awl fuse` on a small simulated scan writes report.html and
//! renders/*.png, then `awl evaluate` (model vs the scan's CAD, from truth.json) writes its
//! report.html and heatmap renders; headless Chromium loads both pages and must show no JavaScript
//! error, the point count and (evaluate) the RMSE of summary.json in their elements, and a 3D view
//! that is not blank.
//!
//! Chromium: `AWL_CHROMIUM` (scripts/test sets it), else `chromium` on PATH; the test is skipped
//! only when neither exists.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use awl::pipeline::FuseReport;

/// The viewer's clear color, 8-bit (0.118, 0.133, 0.157).
const CLEAR: [u8; 3] = [30, 34, 40];

fn chromium() -> Option<PathBuf> {
    if let Some(path) = std::env::var_os("AWL_CHROMIUM").filter(|p| !p.is_empty()) {
        let path = PathBuf::from(path);
        assert!(path.is_file(), "AWL_CHROMIUM={} does not exist", path.display());
        return Some(path);
    }
    std::env::split_paths(&std::env::var_os("PATH")?).map(|d| d.join("chromium")).find(|p| p.is_file())
}

/// Runs headless Chromium on `page` with `args`; returns (stdout, stderr). Killed after 180 s.
fn run_chromium(bin: &Path, page: &Path, args: &[String]) -> (String, String) {
    let profile = tempfile::tempdir().expect("profile dir");
    let out = tempfile::NamedTempFile::new().expect("stdout file");
    let err = tempfile::NamedTempFile::new().expect("stderr file");
    let mut child = Command::new(bin)
        .args(["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run"])
        .args(["--disable-background-networking", "--disable-component-update", "--disable-sync"])
        .args(["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--enable-logging=stderr", "--v=0"])
        .arg(format!("--user-data-dir={}", profile.path().display()))
        .args(args)
        .arg(format!("file://{}", page.display()))
        .stdout(Stdio::from(out.reopen().expect("stdout")))
        .stderr(Stdio::from(err.reopen().expect("stderr")))
        .spawn()
        .expect("start chromium");
    let start = Instant::now();
    loop {
        if child.try_wait().expect("wait chromium").is_some() {
            break;
        }
        if start.elapsed() > Duration::from_secs(180) {
            let _ = child.kill();
            panic!("chromium did not finish on {} in 180 s", page.display());
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let read = |f: &tempfile::NamedTempFile| std::fs::read_to_string(f.path()).expect("read output");
    (read(&out), read(&err))
}

/// Text content of the element with `id` in a DOM dump (elements here hold plain text).
fn element_text(dom: &str, id: &str) -> String {
    let open = format!("id=\"{id}\"");
    let at = dom.find(&open).unwrap_or_else(|| panic!("no element {id} in the DOM"));
    let body = &dom[at..];
    let start = body.find('>').expect("tag end") + 1;
    let end = body[start..].find('<').expect("closing tag") + start;
    body[start..end].to_string()
}

/// Loads `page`: no JS error, viewer drew, returns the DOM.
fn load_without_errors(bin: &Path, page: &Path) -> String {
    let (dom, log) = run_chromium(bin, page, &["--dump-dom".to_string()]);
    let errors = element_text(&dom, "js-errors");
    assert!(errors.trim().is_empty(), "{}: JavaScript errors in the page: {errors}", page.display());
    let uncaught: Vec<&str> = log.lines().filter(|l| l.contains("Uncaught") || l.contains(":ERROR:CONSOLE")).collect();
    assert!(uncaught.is_empty(), "console errors: {uncaught:?}");
    dom
}

/// Screenshot of `page`; asserts that the viewer canvas (found by its clear color) shows points.
fn assert_canvas_not_blank(bin: &Path, page: &Path) -> (usize, f64) {
    let shot = tempfile::Builder::new().suffix(".png").tempfile().expect("png file");
    let args = [
        format!("--screenshot={}", shot.path().display()),
        "--window-size=1280,1800".into(),
        "--hide-scrollbars".into(),
    ];
    run_chromium(bin, page, &args);
    let mut reader = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(shot.path()).expect("screenshot")))
        .read_info()
        .expect("screenshot png");
    let mut buf = vec![0; reader.output_buffer_size().expect("size")];
    let info = reader.next_frame(&mut buf).expect("frame");
    let channels = info.color_type.samples();
    let (w, h) = (info.width as usize, info.height as usize);
    let px = |x: usize, y: usize| {
        let o = (y * w + x) * channels;
        [buf[o], buf[o + 1], buf[o + 2]]
    };
    let is_clear = |p: [u8; 3]| p.iter().zip(CLEAR).all(|(a, b)| a.abs_diff(b) <= 3);
    let (mut x0, mut x1, mut y0, mut y1, mut clear) = (w, 0, h, 0, 0usize);
    for y in 0..h {
        for x in 0..w {
            if is_clear(px(x, y)) {
                (x0, x1, y0, y1, clear) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y), clear + 1);
            }
        }
    }
    assert!(
        clear > 100_000,
        "{}: the viewer canvas is not on the screenshot ({clear} px of its clear color)",
        page.display()
    );
    let inside: Vec<[u8; 3]> = (y0..=y1).flat_map(|y| (x0..=x1).map(move |x| (x, y))).map(|(x, y)| px(x, y)).collect();
    let drawn = inside.iter().filter(|p| !is_clear(**p)).count();
    let luma: Vec<f64> = inside.iter().map(|p| p.iter().map(|&c| f64::from(c)).sum::<f64>() / 3.0).collect();
    let mean = luma.iter().sum::<f64>() / luma.len() as f64;
    let var = luma.iter().map(|l| (l - mean) * (l - mean)).sum::<f64>() / luma.len() as f64;
    let share = drawn as f64 / inside.len() as f64;
    println!(
        "{}: canvas {}x{} px, {:.1} % drawn, luma variance {var:.0}",
        page.display(),
        x1 - x0 + 1,
        y1 - y0 + 1,
        share * 100.0
    );
    assert!(share > 0.03, "the 3D view is blank: {:.2} % of the canvas drawn", share * 100.0);
    assert!(var > 100.0, "the 3D view has no contrast: luma variance {var:.1}");
    (drawn, var)
}

fn assert_render_not_blank(path: &Path) {
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).expect("render")));
    let mut reader = decoder.read_info().expect("png");
    let mut buf = vec![0; reader.output_buffer_size().expect("size")];
    let info = reader.next_frame(&mut buf).expect("frame");
    assert_eq!((info.width, info.height), (800, 600), "{}", path.display());
    let covered = buf.chunks_exact(3).filter(|p| *p != [255, 255, 255]).count();
    assert!(covered > 48_000, "{}: only {covered} of 480000 pixels show the model", path.display());
}

#[test]
fn fuse_and_evaluate_reports_work_in_headless_chromium() {
    let Some(bin) = chromium() else {
        eprintln!("SKIPPED: no chromium (set AWL_CHROMIUM or install Debian's chromium)");
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let (scan, out) = (dir.path().join("scan"), dir.path().join("out"));
    let awl = |args: &[&str]| {
        let o = Command::new(env!("CARGO_BIN_EXE_awl")).args(args).output().expect("run awl");
        assert!(o.status.success(), "awl {args:?}: {}", String::from_utf8_lossy(&o.stderr));
    };
    awl(&["simulate", "--views", "4", "--noise", "low", "--seed", "2", "-o", scan.to_str().expect("utf-8")]);
    awl(&["fuse", scan.to_str().expect("utf-8"), "-o", out.to_str().expect("utf-8"), "--quiet"]);
    for view in ["front", "side", "top", "iso"] {
        assert_render_not_blank(&out.join(format!("renders/{view}.png")));
    }
    let report: FuseReport =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).expect("report")).expect("json");
    let page = out.join("report.html");
    let size = std::fs::metadata(&page).expect("report.html").len();
    println!("report.html: {size} bytes for {} model points", report.model_points);
    let dom = load_without_errors(&bin, &page);
    assert_eq!(element_text(&dom, "points"), report.model_points.to_string());
    let shown = report.model_points.min(200_000);
    assert_eq!(element_text(&dom, "viewer-status-0"), format!("ok {shown} points"));
    assert_canvas_not_blank(&bin, &page);

    let eval_dir = dir.path().join("eval");
    let model = out.join("model.ply");
    let (cad, truth) = (scan.join("cad.ply"), scan.join("truth.json"));
    let arg = |p: &Path| p.to_str().expect("utf-8").to_string();
    awl(&["evaluate", &arg(&model), "--cad", &arg(&cad), "--truth", &arg(&truth), "-o", &arg(&eval_dir)]);
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(eval_dir.join("summary.json")).expect("summary")).expect("json");
    let rmse_m = summary["distances"]["on_object"]["rmse_m"].as_f64().expect("rmse_m");
    assert!(rmse_m > 0.0 && rmse_m < 0.005, "RMSE {rmse_m} m");
    let renders: Vec<String> = ["front", "side", "top", "iso"].iter().map(|v| format!("heatmap-{v}.png")).collect();
    for name in &renders {
        assert_render_not_blank(&eval_dir.join("renders").join(name));
    }
    let eval_page = eval_dir.join("report.html");
    println!("evaluate report.html: {} bytes", std::fs::metadata(&eval_page).expect("report.html").len());
    let dom = load_without_errors(&bin, &eval_page);
    assert_eq!(element_text(&dom, "rmse"), format!("{:.3}", rmse_m * 1e3));
    assert_eq!(element_text(&dom, "points"), report.model_points.to_string());
    assert_eq!(element_text(&dom, "viewer-status-0"), format!("ok {shown} points"));
    assert_canvas_not_blank(&bin, &eval_page);
}
