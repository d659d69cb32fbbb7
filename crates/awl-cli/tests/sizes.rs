//! No input exhausts memory or time (issue 55): sizes and counts are checked before anything is
//! allocated for them, and each refusal names the file or key, the limit and how to raise it.
//! PNG headers (the 640 x (2^31 - 1) and 32768 x 32768, each in a file of a few hundred
//! bytes, refused before a pixel buffer exists: the run's peak memory stays that of a normal run),
//! a scan.json camera of 100000 x 100000, RANSAC and ICP iteration counts in a fuse config,
//! `--threads 10000`, 150 k targets; a NaN point dropped with a warning naming its file (`awl register`,
//! `awl evaluate`, `awl info`).

mod common;

use std::path::Path;
use std::process::{Command, Output};

fn awl_env(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_awl"));
    c.args(args);
    for (k, v) in env {
        c.env(k, v);
    }
    c.output().expect("run awl")
}

fn awl(args: &[&str]) -> Output {
    awl_env(args, &[])
}

fn text(out: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr))
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

fn refused(out: &Output, wants: &[&str]) -> String {
    let t = text(out);
    assert!(!out.status.success() && !t.contains("panicked"), "must be refused: {t}");
    for w in wants {
        assert!(t.contains(w), "`{w}` not in: {t}");
    }
    t
}

/// A PNG whose header claims `width` x `height` (`color` 0 gray / 2 RGB, `depth` bits) and whose
/// one IDAT holds a few bytes of a zlib stream: a valid header over a tiny file.
fn lying_png(width: u32, height: u32, color: u8, depth: u8) -> Vec<u8> {
    common::png_with_header(width, height, depth, color, &[0x78, 0x9c, 0x63, 0x00, 0x00, 0x00, 0x01, 0x00, 0x01])
}

#[test]
fn images_cameras_configs_threads_and_targets_are_bounded_before_allocating() {
    let dir = tempfile::tempdir().expect("tempdir");
    let scan = dir.path().join("scan");
    let out = awl(&["simulate", "--views", "2", "--seed", "4", "-o", s(&scan)]);
    assert!(out.status.success(), "{}", text(&out));
    let fuse = |scan: &Path, extra: &[&str]| {
        let o = dir.path().join("refused-fuse");
        let mut a = vec!["fuse", s(scan), "-o", s(&o), "--quiet"];
        a.extend(extra);
        let out = awl(&a);
        assert!(!o.exists(), "nothing written");
        out
    };
    // a view whose image is refused is skipped with a warning naming the file and the limit (the
    // other view is the model): the run's output is checked, then removed
    let skipped = |wants: &[&str]| {
        let o = dir.path().join("skipped-fuse");
        let out = awl(&["fuse", s(&scan), "-o", s(&o)]);
        let t = text(&out);
        assert!(out.status.success() && !t.contains("panicked"), "{t}");
        assert!(t.contains("warning: view 0 skipped"), "{t}");
        for w in wants {
            assert!(t.contains(w), "`{w}` not in: {t}");
        }
        std::fs::remove_dir_all(&o).expect("rm");
    };

    // the PNGs: 640 x (2^31 - 1) 16-bit depth, 32768 x 32768 16-bit depth, as view 0's depth
    let depth0 = scan.join("depth/000000.png");
    let original = std::fs::read(&depth0).expect("depth");
    for (w, h, pixels) in [(640u32, (1u32 << 31) - 1, "1374389534080 pixels"), (32768, 32768, "1073741824 pixels")] {
        let png = lying_png(w, h, 0, 16);
        assert!(png.len() < 100, "{} bytes", png.len());
        std::fs::write(&depth0, &png).expect("write");
        skipped(&["depth/000000.png", pixels, "100000000-pixel limit", "AWL_MAX_IMAGE_PIXELS"]);
        // the same header as a color image for `awl tags`
        let color = dir.path().join(format!("color-{w}x{h}.png"));
        std::fs::write(&color, lying_png(w, h, 2, 8)).expect("write");
        refused(&awl(&["tags", s(&color)]), &[s(&color), "pixel limit"]);
    }
    // a header within the pixel limit that the file is far too short to hold: 9000 x 9000 in 70 bytes
    std::fs::write(&depth0, lying_png(9000, 9000, 0, 16)).expect("write");
    skipped(&["depth/000000.png", "9000 x 9000", "more than a", "truncated"]);
    std::fs::write(&depth0, &original).expect("restore");
    // the limit is settable: the simulated 640 x 480 views are refused under a 100 k-pixel limit
    let out = awl_env(
        &["fuse", s(&scan), "-o", s(&dir.path().join("capped")), "--quiet"],
        &[("AWL_MAX_IMAGE_PIXELS", "100000")],
    );
    refused(&out, &["camera.width", "307200 pixels, more than the 100000-pixel limit"]);

    // scan.json's camera of 100000 x 100000
    let manifest = scan.join("scan.json");
    let text0 = std::fs::read_to_string(&manifest).expect("scan.json");
    let mut j: serde_json::Value = serde_json::from_str(&text0).expect("json");
    j["camera"]["width"] = 100_000.into();
    j["camera"]["height"] = 100_000.into();
    std::fs::write(&manifest, j.to_string()).expect("write");
    refused(&fuse(&scan, &[]), &["scan.json", "camera.width", "10000000000 pixels", "AWL_MAX_IMAGE_PIXELS"]);
    std::fs::write(&manifest, &text0).expect("restore");

    // iteration counts in a fuse config: ICP 1e12, RANSAC 4e9 (and a plane snap's), each named
    for (toml, key) in [
        (
            "[registration.icp]\nlevels = [{ voxel_m = 0.01, max_correspondence_m = 0.06, max_iterations = 1000000000000 }]\n",
            "registration.icp.levels[0].max_iterations",
        ),
        ("[isolate.floor.plane]\niterations = 4000000000\n", "isolate.floor.plane.iterations"),
        ("[snap_plane]\niterations = 100001\n", "snap_plane.iterations"),
        (
            "[registration]\njoint_levels = [{ voxel_m = 0.004, max_correspondence_m = 0.012, max_iterations = 1000000 }]\n",
            "registration.joint_levels[0].max_iterations",
        ),
    ] {
        let config = dir.path().join("fuse.toml");
        std::fs::write(&config, toml).expect("write");
        refused(&fuse(&scan, &["--config", s(&config)]), &[key, "more than the 100000"]);
    }

    // --threads 10000
    refused(&fuse(&scan, &["--threads", "10000"]), &["--threads 10000 is more than"]);
    refused(&awl(&["demo", "--threads", "10000", "-o", s(&dir.path().join("demo"))]), &["--threads 10000"]);

    // 150 k targets (a file), and 1001 on the command line
    let targets = dir.path().join("targets.txt");
    std::fs::write(&targets, "0.1,0.1,0.1\n".repeat(150_000)).expect("write");
    let plan = dir.path().join("plan.json");
    let out = awl(&["pierce", "wp.json", "--shot", s(&scan), "--targets-file", s(&targets), "-o", s(&plan)]);
    refused(&out, &[s(&targets), "150000 targets, more than the 1000"]);
    let mut args = vec!["pierce", "wp.json", "--shot", s(&scan), "-o", s(&plan)];
    for _ in 0..1001 {
        args.extend(["--target", "0.1,0.1,0.1"]);
    }
    refused(&awl(&args), &["--target", "1001 targets"]);
    assert!(!plan.exists());

    // a NaN point in a cloud is dropped with a warning naming its file and the count (it used to
    // end as `k-d tree: point 0 is not finite`): the command goes on with the finite points, and
    // whatever it says about them never comes from the k-d tree
    let ply = |rows: &str| {
        format!(
            "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nend_header\n{rows}"
        )
    };
    let (nan, good) = (dir.path().join("nan.ply"), dir.path().join("good.ply"));
    std::fs::write(&nan, ply("0 0 0\n1 0 0\nnan 1 0\n0 0 1\n")).expect("write");
    std::fs::write(&good, ply("0 0 0\n1 0 0\n0 1 0\n0 0 1\n")).expect("write");
    let t = dir.path().join("T.json");
    let dropped = format!("warning: {}: 1 of 4 points have a NaN or infinite coordinate and were dropped", s(&nan));
    for out in [
        awl(&["register", s(&nan), s(&good), "-o", s(&t)]),
        awl(&["evaluate", s(&nan), "--cad", s(&good), "-o", s(&dir.path().join("ev"))]),
        awl(&["info", s(&nan)]),
    ] {
        let t = text(&out);
        assert!(t.contains(&dropped) && !t.contains("panicked") && !t.contains("k-d tree"), "{t}");
    }
}
