//! Issue 73's acceptance, measured: a fixed arm (`SimParams::fixed_base`, one base stop, 30 views
//! over 140 degrees of azimuth) scanning a box, a cylinder and a sphere at realistic noise, fused
//! with `FuseConfig::default()`, with the true hand-eye (every shape) and with the recorded one
//! 1 deg / 5 mm and 2.3 deg / 27 mm off (box and sphere). One line per fuse, then the counts.
//!
//! A measurement tool, not a regression test: it is `#[ignore]`d (50-120 s per fuse in a
//! release build on 2 busy cores) and asserts only what held when it was run. Run it with
//!
//! ```text
//! cargo test --release -p awl --test fixed_arm_sweep -- --ignored --nocapture
//! ```
//!
//! Knobs (environment): `AWL_SWEEP_SEEDS` (seeds 1..=N, default 10), `AWL_SWEEP_FIRST_SEED` (default
//! 1), `AWL_SWEEP_SHAPES` (comma-separated, default `box,cylinder,sphere`), `AWL_SWEEP_CASES`
//! (comma-separated of `true,off1,off2`, default all), `AWL_SWEEP_VIEWS` (default 30),
//! `AWL_SWEEP_NOISE` (`low`, `realistic` or `harsh`, default realistic), `AWL_SWEEP_BARE=1` (the shape alone
//! on the floor, no clutter), `AWL_SWEEP_VERBOSE=1` (each view's status and unobserved directions, for runs
//! that warn or refuse).
//!
//! Each line also gives how far the registered views slid: each view's registered pose against the
//! truth, both taken relative to the anchor view (the world the fuse keeps), the largest rotation
//! (deg) and translation (mm) over the registered views, and how many slid by more than 1 deg.
#![cfg(feature = "sim")]

mod common;

use std::time::Instant;

use awl::pipeline::{FuseConfig, FuseOutput, ViewStatus, fuse};
use awl::sim::{NoiseLevel, SceneKind, SimParams, Simulation, simulate};
use awl::transform::{isometry_from_rows, pose_difference};

/// A hand-eye case: its name, the rotation (deg) and translation (mm) the recorded hand-eye is off by.
#[derive(Clone, Copy)]
struct Case {
    name: &'static str,
    deg: f64,
    mm: f64,
}

const CASES: [Case; 3] = [
    Case { name: "true", deg: 0.0, mm: 0.0 },
    Case { name: "off1", deg: 1.0, mm: 5.0 },
    Case { name: "off2", deg: 2.3, mm: 27.0 },
];

fn env_usize(name: &str, default: usize) -> usize {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn env_list(name: &str, default: &str) -> Vec<String> {
    std::env::var(name).unwrap_or_else(|_| default.into()).split(',').map(|s| s.trim().to_owned()).collect()
}

fn scene(name: &str) -> SceneKind {
    let kinds = [SceneKind::Box, SceneKind::Shell, SceneKind::Cylinder, SceneKind::Sphere];
    kinds.into_iter().find(|k| k.name() == name).unwrap_or_else(|| panic!("unknown shape {name}"))
}

/// What one fuse gave.
struct Run {
    shape: String,
    seed: u64,
    case: Case,
    warned: bool,
    refused: bool,
    /// The refined hand-eye's error vs the truth (mm, deg); `None` when refused.
    error: Option<(f64, f64)>,
}

impl Run {
    fn within_a_third(&self) -> bool {
        self.error.is_some_and(|(mm, deg)| mm < self.case.mm / 3.0 && deg < self.case.deg / 3.0)
    }
}

/// Each registered view's slide: its registered pose against the truth, relative to the anchor's
/// (rotation deg, translation mm), `None` for views not registered.
fn slides(sim: &Simulation, out: &FuseOutput) -> Vec<Option<(f64, f64)>> {
    let anchor = out.report.views.iter().position(|v| v.status == ViewStatus::Anchor);
    let Some((Some(anchor_pose), Some(anchor_truth))) =
        anchor.map(|a| (out.poses[a], sim.truth.views.get(a).map(|t| t.world_from_camera)))
    else {
        return vec![None; out.poses.len()];
    };
    // the fused world -> the true world, as the anchor puts it
    let truth_from_fused = anchor_truth * anchor_pose.inverse();
    (out.poses.iter().zip(&sim.truth.views))
        .map(|(pose, truth)| {
            let (t, r) = pose_difference(&(truth_from_fused * (*pose)?), &truth.world_from_camera);
            Some((r.to_degrees(), t * 1e3))
        })
        .collect()
}

fn short(s: &str, n: usize) -> String {
    let s = s.replace('\n', " ");
    if s.chars().count() <= n { s } else { format!("{}...", s.chars().take(n).collect::<String>()) }
}

fn describe(
    sim: &Simulation,
    out: &FuseOutput,
    shape: &str,
    seed: u64,
    case: Case,
    seconds: f64,
    verbose: bool,
) -> Run {
    let views = &out.report.views;
    let registered = views.iter().filter(|v| matches!(v.status, ViewStatus::Accepted | ViewStatus::Anchor)).count();
    let with_unobserved = views.iter().filter(|v| !v.unobserved.is_empty()).count();
    let he = out.report.hand_eye.as_ref();
    let truth = sim.truth.ee_from_camera.expect("true hand-eye");
    let error = he.and_then(|h| h.refined.as_ref()).map(|rows| {
        let (t, r) = pose_difference(&isometry_from_rows(rows).expect("rigid"), &truth);
        (t * 1e3, r.to_degrees())
    });
    let warning = he.map_or("", |h| h.warning.as_str());
    let refused = he.map_or("no hand-eye report", |h| h.refused.as_str());
    let warned = warning.contains("recalibrate");
    let slid = slides(sim, out);
    let max_deg = slid.iter().flatten().map(|s| s.0).fold(0.0, f64::max);
    let max_mm = slid.iter().flatten().map(|s| s.1).fold(0.0, f64::max);
    let over_1deg = slid.iter().flatten().filter(|s| s.0 > 1.0).count();
    let run = Run { shape: shape.into(), seed, case, warned, refused: !refused.is_empty(), error };
    println!(
        "{shape:8} seed {seed:2} {:4}: views {}/{} registered, hand-eye used {} rejected {:?}, unobserved: {} views ({} left out) | \
         slid max {max_deg:.2} deg {max_mm:.1} mm, {over_1deg} over 1 deg | \
         warn {} (other warning: {}) | refused {:?} | scale {:.2} prior {:.1} sigma | refined {} | {seconds:.0} s",
        case.name,
        registered,
        views.len(),
        he.map_or(0, |h| h.views_used.len()),
        he.map_or(&[][..], |h| h.views_rejected.as_slice()),
        with_unobserved,
        he.map_or(0, |h| h.unobserved_left_out),
        if warned { "YES" } else { "no" },
        if !warning.is_empty() && !warned { short(warning, 60) } else { "-".into() },
        short(refused, 70),
        he.map_or(f64::NAN, |h| h.residual_scale),
        he.map_or(f64::NAN, |h| h.prior_sigmas),
        error.map_or("-".into(), |(mm, deg)| format!("{mm:.2} mm {deg:.3} deg")),
    );
    if verbose && (warned || run.refused || over_1deg > 0 || case.deg == 0.0 && !warning.is_empty()) {
        for (i, v) in views.iter().enumerate() {
            let u: Vec<String> = v
                .unobserved
                .iter()
                .map(|u| {
                    format!(
                        "{:?} axis [{:.2} {:.2} {:.2}] ratio {:.1e}",
                        u.kind, u.axis[0], u.axis[1], u.axis[2], u.eigen_ratio
                    )
                })
                .collect();
            println!(
                "    view {i:2}: {:?} slid {} corr {:.1} mm {:.2} deg fit {:.2} cond {:.1e} observed {:.1e} {} {}",
                v.status,
                slid[i].map_or("-".into(), |(deg, mm)| format!("{deg:.2} deg {mm:.1} mm")),
                v.correction_mm,
                v.correction_deg,
                v.fitness,
                v.conditioning,
                v.observed_conditioning,
                u.join("; "),
                short(&v.reason, 60)
            );
        }
    }
    run
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 { v[n / 2] } else { (v[n / 2 - 1] + v[n / 2]) / 2.0 }
}

#[test]
#[ignore = "a measurement sweep: 50-120 s per fuse"]
fn fixed_arm_hand_eye_sweep() {
    let seeds = env_usize("AWL_SWEEP_SEEDS", 10) as u64;
    let first = env_usize("AWL_SWEEP_FIRST_SEED", 1) as u64;
    let shapes = env_list("AWL_SWEEP_SHAPES", "box,cylinder,sphere");
    let cases: Vec<Case> = env_list("AWL_SWEEP_CASES", "true,off1,off2")
        .iter()
        .map(|n| *CASES.iter().find(|c| c.name == n).unwrap_or_else(|| panic!("unknown case {n}")))
        .collect();
    let views = env_usize("AWL_SWEEP_VIEWS", 30);
    let verbose = std::env::var("AWL_SWEEP_VERBOSE").is_ok_and(|v| v == "1");
    let bare = std::env::var("AWL_SWEEP_BARE").is_ok_and(|v| v == "1");
    let noise = match std::env::var("AWL_SWEEP_NOISE").as_deref().unwrap_or("realistic") {
        "low" => NoiseLevel::Low,
        "realistic" => NoiseLevel::Realistic,
        "harsh" => NoiseLevel::Harsh,
        other => panic!("AWL_SWEEP_NOISE: {other} is not low, realistic or harsh"),
    };
    let mut runs = Vec::new();
    let mut fuse_seconds = Vec::new();
    for seed in first..first + seeds {
        for shape in &shapes {
            let kind = scene(shape);
            let started = Instant::now();
            let sim = simulate(&SimParams { views, seed, noise, bare, fixed_base: true, ..SimParams::scan(kind) })
                .expect("simulate");
            println!("simulated {shape} seed {seed} ({views} views) in {:.0} s", started.elapsed().as_secs_f64());
            let truth = sim.truth.ee_from_camera.expect("true hand-eye");
            for &case in &cases {
                // the issue asks for the wrong hand-eyes on the box and the sphere; the cylinder gets
                // the true one only (the false-warning count)
                if case.deg > 0.0 && kind == SceneKind::Cylinder {
                    continue;
                }
                let mut this = sim.clone();
                this.scan.ee_from_camera = Some(common::hand_eye_off(&truth, case.deg, case.mm));
                let started = Instant::now();
                let out = fuse(&this.in_memory_scan(), &FuseConfig::default(), &|_, _, _| {}).expect("fuse");
                let seconds = started.elapsed().as_secs_f64();
                fuse_seconds.push(seconds);
                runs.push(describe(&this, &out, shape, seed, case, seconds, verbose));
            }
        }
    }
    println!("\nsummary ({} fuses, median {:.0} s each):", runs.len(), median(fuse_seconds));
    println!("shape    case runs warned within-1/3 refused refined mm (median/max) deg (median/max)");
    for shape in &shapes {
        for case in &cases {
            let mine: Vec<&Run> = runs.iter().filter(|r| &r.shape == shape && r.case.name == case.name).collect();
            if mine.is_empty() {
                continue;
            }
            let mm: Vec<f64> = mine.iter().filter_map(|r| r.error.map(|e| e.0)).collect();
            let deg: Vec<f64> = mine.iter().filter_map(|r| r.error.map(|e| e.1)).collect();
            let max = |v: &[f64]| v.iter().copied().fold(f64::NAN, f64::max);
            println!(
                "{shape:8} {:4} {:4} {:6} {:10} {:7} {:6.2} / {:6.2}      {:5.3} / {:5.3}{}",
                case.name,
                mine.len(),
                mine.iter().filter(|r| r.warned).count(),
                if case.deg > 0.0 {
                    mine.iter().filter(|r| r.within_a_third()).count().to_string()
                } else {
                    "-".into()
                },
                mine.iter().filter(|r| r.refused).count(),
                median(mm.clone()),
                max(&mm),
                median(deg.clone()),
                max(&deg),
                if case.deg == 0.0 { "   (warned = false warnings)" } else { "" },
            );
        }
    }
    // what held over the runs measured (see the commit that added this sweep): no false warning on
    // any shape, every wrong hand-eye warned. Not asserted: refined within a third (box seed 8,
    // 2.3 deg / 27 mm off: 17 of 30 views left out, refined 25 mm from the truth)
    let failed: Vec<String> = runs
        .iter()
        .filter(|r| if r.case.deg == 0.0 { r.warned } else { !r.warned })
        .map(|r| format!("{} seed {} {}", r.shape, r.seed, r.case.name))
        .collect();
    assert!(failed.is_empty(), "{failed:?}");
}
