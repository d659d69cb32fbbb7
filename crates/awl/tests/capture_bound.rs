//! The capture calibration's own predicted error bound (`CaptureCalibration::bound`, a 95 % bound on
//! `T_ee_camera`'s translation and rotation from the views' noise) against its actual error: on
//! awl's simulated captures (`awl simulate --capture`, seeds 1-3 here; seeds 1-10 in the ignored
//! `table_over_ten_seeds`, BENCHMARKS.md "The capture calibration's own bound") and on the other
//! simulator's `sim_reference/calib_seed1` (`AWL_SHARED_DATA`).
//!
//! Run in release: `cargo test --release -p awl --test capture_bound -- --nocapture`.
#![cfg(all(feature = "sim", feature = "apriltag"))]

mod common;

use std::path::Path;

use awl::handeye::{CaptureBound, CaptureCalibration, CaptureParams, calibrate_capture};
use awl::io::capture::read_capture;
use awl::sim::capture::simulate_capture;
use awl::sim::write_simulation;
use awl::transform::{Rows, isometry_from_rows, pose_difference};
use nalgebra::Isometry3;

/// Error against the truth (mm, deg) and the calibration.
fn run(dir: &Path, truth: &Isometry3<f64>, params: &CaptureParams) -> (f64, f64, CaptureCalibration) {
    let capture = read_capture(dir).expect("capture");
    let cal = calibrate_capture(&capture, params).expect("calibrate");
    let (t, r) = pose_difference(&cal.result.ee_from_camera, truth);
    (t * 1e3, r.to_degrees(), cal)
}

fn simulated(seed: u64) -> (tempfile::TempDir, Isometry3<f64>) {
    let sim = simulate_capture(&awl::sim::capture::CaptureParams { seed, ..Default::default() }).expect("capture");
    let dir = tempfile::tempdir().expect("tempdir");
    write_simulation(dir.path(), &sim, false).expect("write");
    (dir, sim.truth.ee_from_camera.expect("true T_ee_camera"))
}

fn line(name: &str, t: f64, r: f64, b: &CaptureBound) -> String {
    format!(
        "{name}: {t:.3} mm / {r:.4} deg, bound {:.3} mm / {:.4} deg ({:.2}x / {:.2}x; RMS {:.3} mm / {:.4} deg, \
         residuals {:.2}x the noise)",
        b.translation_mm,
        b.rotation_deg,
        t / b.translation_mm,
        r / b.rotation_deg,
        b.translation_rms_mm,
        b.rotation_rms_deg,
        b.normalized_cost.sqrt()
    )
}

#[test]
fn simulated_captures_land_within_their_own_bound() {
    // Measured (seeds 1-3, weighted): see BENCHMARKS.md's table; each error within 1.1x its 95 % bound.
    for seed in 1..=3 {
        let (dir, truth) = simulated(seed);
        let (t, r, cal) = run(dir.path(), &truth, &CaptureParams::default());
        let b = cal.bound.expect("a bound");
        println!("{}", line(&format!("seed {seed}"), t, r, &b));
        // (seed 3 rejects one view as an outlier)
        assert!(b.weighted && b.with_corner_bias && b.views >= 19, "{b:?}");
        assert!(t <= 1.1 * b.translation_mm && r <= 1.1 * b.rotation_deg, "seed {seed}: {}", line("", t, r, &b));
        // bench/handeye_bound/bound.py --capture, 0.2 px, awl's 0.6 mm / 0.06 deg: 0.91-0.98 mm / 0.109-0.113
        // deg RMS (κ known); the κ estimated here adds a little
        assert!((0.8..=1.4).contains(&b.translation_rms_mm), "seed {seed}: {b:?}");
        assert!((0.09..=0.14).contains(&b.rotation_rms_deg), "seed {seed}: {b:?}");
        // the residuals are 0.67-0.87x the assumed noise on seeds 1-10 (awl's simulator's corners scatter
        // less than 0.2 px): the bound is not widened
        assert!((0.5..=1.0).contains(&b.normalized_cost.sqrt()) && b.noise_scale == 1.0, "seed {seed}: {b:?}");
        // a bound that says something: under 2 mm / 0.25 deg
        assert!(b.translation_mm < 2.0 && b.rotation_deg < 0.25, "seed {seed}: {b:?}");
    }
}

#[test]
fn calib_seed1_lands_within_its_own_bound() {
    let dir = common::shared_data().join("sim_reference/calib_seed1");
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("truth.json")).expect("truth")).expect("json");
    let rows: Rows = serde_json::from_value(truth["T_ee_camera"].clone()).expect("4x4");
    let truth = isometry_from_rows(&rows).expect("rigid");
    let (t, r, cal) = run(&dir, &truth, &CaptureParams::default());
    let b = cal.bound.expect("a bound");
    println!("{}", line("calib_seed1", t, r, &b));
    let unweighted = CaptureParams { view_weights: false, ..CaptureParams::default() };
    let (t0, r0, cal0) = run(&dir, &truth, &unweighted);
    let b0 = cal0.bound.expect("a bound");
    println!("{}", line("calib_seed1 unweighted", t0, r0, &b0));
    // Measured: weighted 1.709 mm / 0.127 deg against a bound of 2.33 mm / 0.385 deg; alike 1.534 mm /
    // 0.125 deg against 3.01 mm / 0.536 deg. The weights, at the default 0.2 px, do not bring it nearer
    // the truth here (at 0.05 px, near this simulator's corner scatter: 1.321 mm / 0.089 deg, bound
    // 1.94 mm / 0.165 deg; BENCHMARKS.md)
    assert!(t <= 1.1 * b.translation_mm && r <= 1.1 * b.rotation_deg, "{}", line("", t, r, &b));
    assert!(t0 <= 1.1 * b0.translation_mm && r0 <= 1.1 * b0.rotation_deg, "{}", line("", t0, r0, &b0));
    assert!((1.4..=2.0).contains(&t) && r < 0.16, "{}", line("", t, r, &b));
    assert!((1.9..=2.8).contains(&b.translation_mm) && (0.3..=0.47).contains(&b.rotation_deg), "{b:?}");
    // the weighted bound is the tighter one (the estimate the better, as predicted, when the noise is as assumed)
    assert!(b.translation_mm < 0.9 * b0.translation_mm && b.rotation_deg < 0.8 * b0.rotation_deg, "{b:?} vs {b0:?}");
    // bench/handeye_bound/bound.py --capture (true poses, κ known, this arm noise per axis and 0.2 px): 2.09 mm /
    // 0.251 deg RMS at 1 mm / 0.1 deg; the same model here, with the corner bias left alone
    let nominal =
        CaptureParams { arm_sigma_mm: 1.0, arm_sigma_deg: 0.1, corner_bias: false, ..CaptureParams::default() };
    let (_, _, cal1) = run(&dir, &truth, &nominal);
    let b1 = cal1.bound.expect("a bound");
    println!(
        "calib_seed1 at 1 mm / 0.1 deg, κ known: RMS {:.3} mm / {:.4} deg",
        b1.translation_rms_mm, b1.rotation_rms_deg
    );
    assert!((b1.translation_rms_mm / 2.09 - 1.0).abs() < 0.03, "{b1:?}");
    assert!((b1.rotation_rms_deg / 0.251 - 1.0).abs() < 0.03, "{b1:?}");
    // Refusals: a corner noise that is not positive, a negative arm noise
    let capture = read_capture(&dir).expect("capture");
    let bad = CaptureParams { corner_sigma_px: 0.0, ..CaptureParams::default() };
    let e = calibrate_capture(&capture, &bad).expect_err("0 px").to_string();
    assert!(e.contains("corner_sigma_px"), "{e}");
    let bad = CaptureParams { arm_sigma_mm: -1.0, ..CaptureParams::default() };
    let e = calibrate_capture(&capture, &bad).expect_err("negative").to_string();
    assert!(e.contains("arm_sigma_mm"), "{e}");
}

#[test]
#[ignore = "the benchmark table: ten simulated captures, weighted and not (~2 min in release)"]
fn table_over_ten_seeds() {
    println!(
        "| seed | weighted: error mm / deg | bound mm / deg | error / bound | unweighted: error mm / deg | bound mm / deg | error / bound |"
    );
    println!("|---|---|---|---|---|---|---|");
    let (mut within, mut within0) = (0, 0);
    for seed in 1..=10 {
        let (dir, truth) = simulated(seed);
        let (t, r, cal) = run(dir.path(), &truth, &CaptureParams::default());
        let unweighted = CaptureParams { view_weights: false, ..CaptureParams::default() };
        let (t0, r0, cal0) = run(dir.path(), &truth, &unweighted);
        let (b, b0) = (cal.bound.expect("bound"), cal0.bound.expect("bound"));
        within += usize::from(t <= 1.1 * b.translation_mm && r <= 1.1 * b.rotation_deg);
        within0 += usize::from(t0 <= 1.1 * b0.translation_mm && r0 <= 1.1 * b0.rotation_deg);
        println!(
            "| {seed} | {t:.3} / {r:.4} | {:.3} / {:.4} | {:.2} / {:.2} | {t0:.3} / {r0:.4} | {:.3} / {:.4} | {:.2} / {:.2} | chi {:.2} / {:.2}, bias {:.3} / {:.3} px",
            b.translation_mm,
            b.rotation_deg,
            t / b.translation_mm,
            r / b.rotation_deg,
            b0.translation_mm,
            b0.rotation_deg,
            t0 / b0.translation_mm,
            r0 / b0.rotation_deg,
            b.normalized_cost.sqrt(),
            b0.normalized_cost.sqrt(),
            cal.corner_bias_px.unwrap_or(f64::NAN),
            cal0.corner_bias_px.unwrap_or(f64::NAN),
        );
    }
    println!("within 1.1x the bound: weighted {within} of 10, unweighted {within0} of 10");
}
