//! Peak memory on large malformed inputs (issue 55): at most twice that of the same command on a
//! file holding only the input's valid part, and a clear refusal. Each case runs `awl` under GNU
//! `/usr/bin/time`, which reads the child's own peak resident set (`%M`). (`wait4` on a child of
//! this process would not do: a child's `ru_maxrss` starts from the parent's resident set, copied
//! at the fork; the `time` process in between is small.)
//!
//! The cases: a binary PLY whose header claims 2^31 vertices over a 1 MB body (the valid part: the
//! 87381 vertices the body holds); a binary_compressed PCD announcing 4 GB of compressed data over a
//! 1 MB body (the valid part: the same file with its true size); PNGs whose headers declare
//! 640 x (2^31 - 1) in 70 bytes, 32768 x 32768 over 2 MB of data, and 10000 x 10000 over the few
//! kilobytes that hold 100 of its rows (the valid part: a 640 x 480 PNG); a JPEG whose header
//! declares 16384 x 16384 over a 64 x 64 image's data (the valid part: that 64 x 64 JPEG).

mod common;

use std::process::Command;

/// GNU time, which reports its child's peak resident set.
const TIME: &str = "/usr/bin/time";

/// Runs `awl args` under [`TIME`]; returns (exit success, stdout + stderr, awl's peak RSS in MB).
fn awl_peak(args: &[&str]) -> (bool, String, f64) {
    assert!(std::path::Path::new(TIME).is_file(), "{TIME} (GNU time) is needed to read a child's peak memory");
    let out = Command::new(TIME)
        .args(["-f", "awl-peak-kb %M"])
        .arg(env!("CARGO_BIN_EXE_awl"))
        .args(args)
        .output()
        .expect("run awl under time");
    peak_of(&out)
}

/// (exit success, stdout + stderr, peak RSS in MB) of a run under [`TIME`].
fn peak_of(out: &std::process::Output) -> (bool, String, f64) {
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    let kb: f64 = stderr
        .lines()
        .filter_map(|l| l.strip_prefix("awl-peak-kb "))
        .next_back()
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or_else(|| panic!("no peak from {TIME}: {stderr}"));
    let text = format!("{}{stderr}", String::from_utf8_lossy(&out.stdout));
    (out.status.success(), text, kb / 1024.0)
}

/// A PNG's chunks rebuilt with its IHDR's height replaced (the CRC recomputed).
fn with_height(png: &[u8], width: u32, height: u32) -> Vec<u8> {
    let mut out = png.to_vec();
    // signature (8), IHDR length (4) and type (4): width at 16, height at 20, CRC at 29
    out[16..20].copy_from_slice(&width.to_be_bytes());
    out[20..24].copy_from_slice(&height.to_be_bytes());
    let crc = crc32fast::hash(&out[12..29]);
    out[29..33].copy_from_slice(&crc.to_be_bytes());
    out
}

/// A PNG whose header declares `width` x `height` RGB and whose IDAT holds `idat` bytes of zeros.
fn lying_png(width: u32, height: u32, idat: usize) -> Vec<u8> {
    let mut data = vec![0x78, 0x9c];
    data.resize(idat.max(2), 0);
    common::png_with_header(width, height, 8, 2, &data)
}

fn rgb_png(width: u32, height: u32) -> Vec<u8> {
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, width, height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let data: Vec<u8> = (0..width * height * 3).map(|i| (i % 251) as u8).collect();
    encoder.write_header().and_then(|mut w| w.write_image_data(&data)).expect("png");
    out
}

/// LZF literal runs only: a control byte `len - 1` (0..=31), then `len` bytes.
fn lzf_literals(data: &[u8]) -> Vec<u8> {
    data.chunks(32).flat_map(|c| std::iter::once(c.len() as u8 - 1).chain(c.iter().copied())).collect()
}

fn args(v: &[String]) -> Vec<&str> {
    v.iter().map(String::as_str).collect()
}

struct Case {
    name: &'static str,
    /// The malformed input's command and what its refusal must say.
    malformed: Vec<String>,
    wants: Vec<String>,
    /// The same command on the input's valid part.
    valid: Vec<String>,
}

#[test]
fn malformed_inputs_peak_at_most_twice_their_valid_part() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let path = |name: &str| d.join(name).to_str().expect("utf-8").to_string();
    let mut cases = Vec::new();

    // PLY: 2^31 vertices claimed over 1 MB of body; the valid part is the 87381 vertices it holds
    let body: Vec<u8> = (0..(1u32 << 20) / 4).flat_map(|i| (0.001 * (i % 997) as f32).to_le_bytes()).collect();
    let ply = |n: u64| {
        let head = format!(
            "ply\nformat binary_little_endian 1.0\nelement vertex {n}\nproperty float x\nproperty float y\n\
             property float z\nend_header\n"
        );
        [head.as_bytes(), &body].concat()
    };
    std::fs::write(d.join("claims.ply"), ply(1 << 31)).expect("write");
    std::fs::write(d.join("valid.ply"), ply(body.len() as u64 / 12)).expect("write");
    cases.push(Case {
        name: "PLY claiming 2^31 vertices over a 1 MB body",
        malformed: vec!["info".into(), path("claims.ply")],
        wants: vec!["claims.ply".into(), "`element vertex 2147483648` needs 25769803776 bytes".into()],
        valid: vec!["info".into(), path("valid.ply")],
    });

    // PCD: binary_compressed announcing 4 GB of compressed data over a 1 MB body
    let n = (1usize << 20) / 12;
    let data: Vec<u8> = (0..3 * n).flat_map(|i| (0.001 * (i % 991) as f32).to_le_bytes()).collect();
    let packed = lzf_literals(&data);
    let pcd = |announced: u32| {
        let head = format!(
            "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {n}\nHEIGHT 1\nPOINTS {n}\n\
             DATA binary_compressed\n"
        );
        let mut out = head.into_bytes();
        out.extend(announced.to_le_bytes());
        out.extend((data.len() as u32).to_le_bytes());
        out.extend(&packed);
        out
    };
    std::fs::write(d.join("claims.pcd"), pcd(0xFFFF_FFF0)).expect("write");
    std::fs::write(d.join("valid.pcd"), pcd(packed.len() as u32)).expect("write");
    cases.push(Case {
        name: "binary_compressed PCD announcing 4 GB of compressed data over a 1 MB body",
        malformed: vec!["info".into(), path("claims.pcd")],
        wants: vec![
            "claims.pcd".into(),
            format!("4294967280 compressed bytes announced (bytes 0-3), {} present", packed.len()),
        ],
        valid: vec!["info".into(), path("valid.pcd")],
    });

    // PNGs with huge headers; the valid part: a 640 x 480 color PNG through the same command
    std::fs::write(d.join("valid.png"), rgb_png(640, 480)).expect("write");
    let pngs = [
        ("640x2147483647.png", lying_png(640, (1 << 31) - 1, 9), "1374389534080 pixels"),
        ("32768x32768.png", lying_png(32768, 32768, 2 << 20), "1073741824 pixels"),
        ("10000x10000.png", with_height(&rgb_png(10000, 100), 10000, 10000), "more than a"),
    ];
    for (name, bytes, want) in pngs {
        std::fs::write(d.join(name), bytes).expect("write");
        cases.push(Case {
            name: "PNG with a huge header",
            malformed: vec!["tags".into(), path(name)],
            wants: vec![name.into(), want.into()],
            valid: vec!["tags".into(), path("valid.png")],
        });
    }

    // JPEG: a 64 x 64 image's data under a header declaring 16384 x 16384
    let mut jpeg = Vec::new();
    let pixels: Vec<u8> = (0..64 * 64 * 3).map(|i| (i * 7 % 256) as u8).collect();
    jpeg_encoder::Encoder::new(&mut jpeg, 90).encode(&pixels, 64, 64, jpeg_encoder::ColorType::Rgb).expect("jpeg");
    std::fs::write(d.join("valid.jpg"), &jpeg).expect("write");
    let sof = jpeg.windows(2).position(|w| w == [0xFF, 0xC0]).expect("SOF0");
    jpeg[sof + 5..sof + 9].copy_from_slice(&[0x40, 0x00, 0x40, 0x00]);
    std::fs::write(d.join("16384x16384.jpg"), &jpeg).expect("write");
    cases.push(Case {
        name: "JPEG with a huge header",
        malformed: vec!["tags".into(), path("16384x16384.jpg")],
        wants: vec!["16384x16384.jpg".into(), "declares 16384 x 16384 (268435456 pixels), more than a".into()],
        valid: vec!["tags".into(), path("valid.jpg")],
    });

    let mut report = Vec::new();
    for case in &cases {
        let (ok, text, peak) = awl_peak(&args(&case.malformed));
        assert!(!ok && !text.contains("panicked"), "{}: must be refused: {text}", case.name);
        for w in &case.wants {
            assert!(text.contains(w.as_str()), "{}: `{w}` not in: {text}", case.name);
        }
        let (valid_ok, valid_text, valid_peak) = awl_peak(&args(&case.valid));
        assert!(valid_ok, "{}: the valid part must be read: {valid_text}", case.name);
        report.push(format!(
            "{}: {peak:.1} MB peak, its valid part {valid_peak:.1} MB ({})",
            case.name,
            case.malformed[1].rsplit('/').next().unwrap_or_default()
        ));
        assert!(
            peak <= 2.0 * valid_peak,
            "{}: {peak:.1} MB, more than twice the valid part's {valid_peak:.1} MB",
            case.name
        );
    }
    println!("{}", report.join("\n"));
}

fn text_of(out: &std::process::Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Runs `awl args` under [`TIME`] and `timeout 30`; returns (exit success, text, peak RSS in MB),
/// with a failure when it is still running after 30 s (a hang).
fn awl_peak_no_hang(args: &[&str]) -> (bool, String, f64) {
    let out = Command::new(TIME)
        .args(["-f", "awl-peak-kb %M", "timeout", "30"])
        .arg(env!("CARGO_BIN_EXE_awl"))
        .args(args)
        .output()
        .expect("run awl under time and timeout");
    assert_ne!(out.status.code(), Some(124), "awl {args:?} still ran after 30 s (a hang): {}", text_of(&out));
    peak_of(&out)
}

/// The length an LZF stream of literal runs and back-references decodes to.
fn lzf_plain_len(lzf: &[u8]) -> usize {
    let (mut at, mut len) = (0, 0);
    while at < lzf.len() {
        let ctrl = usize::from(lzf[at]);
        if ctrl < 32 {
            (at, len) = (at + 2 + ctrl, len + ctrl + 1);
        } else if ctrl >> 5 == 7 {
            (at, len) = (at + 3, len + 9 + usize::from(lzf[at + 1]));
        } else {
            (at, len) = (at + 2, len + 2 + (ctrl >> 5));
        }
    }
    len
}

/// Issue 73's hostile inputs: a FIFO and a symlink to `/dev/zero` given as files, a scan.json listing
/// 5 M views, a binary_compressed PCD whose (valid) LZF stream expands 13.6 MB to 1.2 GB. Each is
/// refused naming the file and what it is, in under 100 MB, without hanging.
#[test]
fn hostile_files_are_refused_in_bounded_memory_without_hanging() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let path = |name: &str| d.join(name).to_str().expect("utf-8").to_string();
    let fifo = Command::new("mkfifo").arg(d.join("fifo.ply")).status().expect("mkfifo");
    assert!(fifo.success());
    std::os::unix::fs::symlink("/dev/zero", d.join("zero.pcd")).expect("symlink");
    std::fs::create_dir(d.join("views")).expect("mkdir");
    let views = vec!["{}"; 5_000_000].join(",");
    std::fs::write(d.join("views/scan.json"), format!("{{\"format\": \"awl-scan/1\", \"views\": [{views}]}}"))
        .expect("write");
    // 100 M points of x y z zeros: one literal zero, then back-references of 264 bytes at distance 1
    let (n, record) = (100_000_000usize, 12usize);
    let unpacked = n * record;
    let mut lzf = vec![0u8, 0];
    let full = (unpacked - 1) / 264;
    for _ in 0..full {
        lzf.extend([7 << 5, 255, 0]);
    }
    let rest = vec![0u8; unpacked - 1 - full * 264];
    lzf.extend(lzf_literals(&rest));
    let head = format!(
        "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {n}\nHEIGHT 1\nPOINTS {n}\n\
         DATA binary_compressed\n"
    );
    let mut pcd = head.into_bytes();
    pcd.extend((lzf.len() as u32).to_le_bytes());
    pcd.extend((unpacked as u32).to_le_bytes());
    pcd.extend(&lzf);
    std::fs::write(d.join("bomb.pcd"), pcd).expect("write");
    assert_eq!(lzf_plain_len(&lzf), unpacked, "the bomb is LZF of the declared size");

    let cases: [(&str, Vec<String>, Vec<&str>); 5] = [
        ("a FIFO", vec!["info".into(), path("fifo.ply")], vec!["fifo.ply", "a FIFO", "not a regular file"]),
        ("a symlink to /dev/zero", vec!["info".into(), path("zero.pcd")], vec!["zero.pcd", "a device"]),
        ("5 M views", vec!["info".into(), path("views")], vec!["scan.json", "more than 100000 views"]),
        (
            "5 M views, fused",
            vec!["fuse".into(), path("views"), "-o".into(), path("out")],
            vec!["scan.json", "more than 100000 views"],
        ),
        (
            "a PCD expanding to 1.2 GB",
            vec!["info".into(), path("bomb.pcd")],
            vec!["bomb.pcd", "1200000000 bytes", "decompression bomb"],
        ),
    ];
    for (name, args, wants) in &cases {
        let (ok, text, peak) = awl_peak_no_hang(&args.iter().map(String::as_str).collect::<Vec<_>>());
        assert!(!ok && !text.contains("panicked"), "{name}: must be refused: {text}");
        for w in wants {
            assert!(text.contains(w), "{name}: `{w}` not in: {text}");
        }
        println!("{name}: refused, {peak:.1} MB peak");
        assert!(peak < 100.0, "{name}: {peak:.1} MB peak, over 100 MB");
    }
    assert!(!d.join("out").exists(), "a refused fuse writes nothing");
}
