//! Arm kinematics (`awl::kinematics`): forward kinematics against roboticstoolbox-python and the
//! vendors' URDF chains (`tests/py/check_kinematics.py`, run with `$AWL_PYTHON`; skipped with a
//! message only when it is unset), FK(IK(T)) = T for every solution, solution counts at generic
//! and singular poses, near-singular refusals, lines crossing limits and singularities, the spin
//! search, and bad input (robot names, arm files).
//! Run in release: `cargo test --release -p awl --test kinematics`.

use std::f64::consts::{FRAC_PI_2, PI};
use std::path::Path;
use std::process::{Command, Stdio};

use awl::Error;
use awl::kinematics::arm_file::{arm_json, parse_arm};
use awl::kinematics::arms::KNOWN;
use awl::kinematics::ik::{inverse, joint_distance};
use awl::kinematics::line::largest_step_rad;
use awl::kinematics::{
    Arm, FailureKind, IkParams, IkSolution, Joints, LineParams, Measure, Reason, SpinParams, best_spin, check_path,
};
use awl::pierce::{Stroke, tool_poses};
use awl::transform::pose_difference;
use nalgebra::{Isometry3, Matrix4, Point3, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::{Value, json};

fn arm(name: &str) -> Arm {
    Arm::by_name(name).expect("built-in arm")
}

fn random_q(arm: &Arm, rng: &mut ChaCha8Rng) -> Joints {
    std::array::from_fn(|j| {
        let [lo, hi] = arm.limits[j];
        rng.random_range(lo..hi)
    })
}

/// Largest element difference of the rotation blocks (rad, small angles) and the translation (m).
fn matrix_error(ours: &Isometry3<f64>, theirs: &Value) -> (f64, f64) {
    let m = ours.to_homogeneous();
    let rows = theirs.as_array().expect("4x4");
    let (mut dt, mut dr) = (0.0f64, 0.0f64);
    for i in 0..4 {
        for j in 0..4 {
            let v = rows[i][j].as_f64().expect("number");
            let d = (m[(i, j)] - v).abs();
            if j == 3 && i < 3 {
                dt = dt.max(d);
            } else {
                dr = dr.max(d);
            }
        }
    }
    (dt, dr)
}

#[test]
fn forward_kinematics_matches_roboticstoolbox_and_the_vendors_urdf_chains() {
    let Ok(python) = std::env::var("AWL_PYTHON") else {
        println!(
            "SKIPPED: AWL_PYTHON is not set (a Python with roboticstoolbox-python, see tests/py/requirements.txt)"
        );
        return;
    };
    let mut rng = ChaCha8Rng::seed_from_u64(58);
    let mut request = Vec::new();
    let mut qs: Vec<Vec<Joints>> = Vec::new();
    for name in KNOWN {
        let a = arm(name);
        let q: Vec<Joints> = (0..1000).map(|_| random_q(&a, &mut rng)).collect();
        let mut doc: Value = serde_json::from_str(&arm_json(&a)).expect("arm json");
        doc["q"] = json!(q);
        request.push(doc);
        qs.push(q);
    }
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/py/check_kinematics.py");
    let mut child = Command::new(&python)
        .arg(script)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot run {python}: {e}"));
    let body = serde_json::to_vec(&json!({ "arms": request })).expect("json");
    std::io::Write::write_all(&mut child.stdin.take().expect("stdin"), &body).expect("write stdin");
    let out = child.wait_with_output().expect("check_kinematics.py");
    assert!(out.status.success(), "check_kinematics.py failed: {}", String::from_utf8_lossy(&out.stderr));
    let reply: Value = serde_json::from_slice(&out.stdout).expect("check_kinematics.py prints JSON");
    println!("roboticstoolbox-python {}", reply["rtb_version"]);
    for (k, name) in KNOWN.iter().enumerate() {
        let a = arm(name);
        let r = &reply["arms"][k];
        assert_eq!(r["name"], *name);
        let (mut rt, mut rr, mut ut, mut ur) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for (i, q) in qs[k].iter().enumerate() {
            let ours = a.base_from_flange(q);
            let (t, rot) = matrix_error(&ours, &r["rtb"][i]);
            rt = rt.max(t);
            rr = rr.max(rot);
            let (t, rot) = matrix_error(&ours, &r["urdf"][i]);
            ut = ut.max(t);
            ur = ur.max(rot);
        }
        println!("{name:8}: vs rtb {rt:.1e} m {rr:.1e} (rotation elements); vs vendor URDF chain {ut:.1e} m {ur:.1e}");
        // measured: <= 4e-16 m and <= 7e-16 against both, every arm
        assert!(rt < 1e-9 && rr < 1e-9, "{name}: rtb {rt:e} m {rr:e}");
        assert!(ut < 1e-9 && ur < 1e-9, "{name}: vendor URDF chain {ut:e} m {ur:e}");
    }
}

#[test]
fn every_inverse_solution_maps_back_to_the_pose() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    for name in KNOWN {
        let a = arm(name);
        let (mut worst_t, mut worst_r, mut total, mut recovered, mut poses) = (0.0f64, 0.0f64, 0, 0, 0);
        for _ in 0..2000 {
            let q = random_q(&a, &mut rng);
            let pose = a.base_from_flange(&q);
            let set = inverse(&a, &pose, &IkParams::no_refusal()).expect("ik");
            assert!(set.solutions.len() <= 8);
            poses += 1;
            for s in &set.solutions {
                let (dt, dr) = pose_difference(&a.base_from_flange(&s.q), &pose);
                worst_t = worst_t.max(dt);
                worst_r = worst_r.max(dr);
                assert!(a.within_limits(&s.q), "{name}: {:?} outside the limits", s.q);
                total += 1;
            }
            // the joints the pose came from are among the solutions (modulo whole turns)
            if set.solutions.iter().any(|s| same_turns(&s.q, &q)) {
                recovered += 1;
            }
        }
        println!(
            "{name:8}: {total} solutions of {poses} poses ({:.2} each), worst FK(IK) {worst_t:.1e} m {worst_r:.1e} rad, \
             the original joints among them at {recovered}",
            total as f64 / poses as f64
        );
        // measured: worst 1.2e-15 m / 3.1e-15 rad (UR20: 2.2e-15 m); every original recovered
        assert!(worst_t < 1e-9 && worst_r < 1e-9, "{name}: {worst_t:e} m {worst_r:e} rad");
        assert_eq!(recovered, poses, "{name}: an original joint vector not among its pose's solutions");
    }
}

/// A joint vector where the shoulder measure is 0: from `base`, joint 4 bisected until the wrist
/// point lies in the plane through joint 1's axis parallel to joint 2's (frame 1's x = 0); `None`
/// when turning joint 4 never gets it there.
fn shoulder_singular_q(a: &Arm, base: Joints) -> Option<Joints> {
    let x1 = |q: &Joints| {
        let f = a.link_frames(q);
        (f[1].inverse() * Point3::from(f[5].translation.vector)).x
    };
    let at = |v: f64| {
        let mut q = base;
        q[3] = v;
        q
    };
    let n = 720;
    let cell = (0..n)
        .map(|i| -PI + 2.0 * PI * i as f64 / n as f64)
        .find(|&u| x1(&at(u)) * x1(&at(u + 2.0 * PI / n as f64)) <= 0.0)?;
    let (mut lo, mut hi) = (cell, cell + 2.0 * PI / n as f64);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if x1(&at(lo)) * x1(&at(mid)) <= 0.0 { hi = mid } else { lo = mid }
    }
    Some(at(0.5 * (lo + hi)))
}

/// A shoulder-singular joint vector of `a` with the elbow well bent (q3 = 1 rad), q2 searched.
fn shoulder_singular(a: &Arm) -> Joints {
    (0..72)
        .map(|i| -PI + 2.0 * PI * i as f64 / 72.0)
        .find_map(|q2| shoulder_singular_q(a, [0.3, q2, 1.0, 0.0, 1.1, 0.4]))
        .expect("a shoulder-singular pose")
}

#[test]
fn solution_counts_at_generic_and_singular_poses() {
    for (name, generic) in [("ur5e", [0.3, -1.2, 1.4, -0.9, 1.1, 0.4]), ("tm5-700", [0.3, -0.3, 2.0, 0.3, 1.2, 0.4])] {
        let a = arm(name);
        // (all solutions, those with q's shoulder and wrist signs), every one checked by FK; q as
        // the reference picks q6 where the wrist leaves it free
        let count = |q: &Joints| {
            let params = IkParams { reference: Some(*q), ..IkParams::no_refusal() };
            let set = inverse(&a, &a.base_from_flange(q), &params).expect("ik");
            for s in &set.solutions {
                let (dt, dr) = pose_difference(&a.base_from_flange(&s.q), &a.base_from_flange(q));
                assert!(dt < 1e-9 && dr < 1e-9, "{name} {q:?}: {dt:e} m {dr:e} rad");
            }
            let own = set
                .solutions
                .iter()
                .find(|s| same_turns(&s.q, q))
                .unwrap_or_else(|| {
                    panic!("{name} {q:?}: not among {:?}", set.solutions.iter().map(|s| s.q).collect::<Vec<_>>())
                })
                .branch;
            let group = set
                .solutions
                .iter()
                .filter(|s| s.branch.shoulder == own.shoulder && s.branch.wrist == own.wrist)
                .count();
            let minus = set.solutions.iter().filter(|s| s.branch.shoulder < 0).count();
            (set.solutions.len(), group, minus)
        };
        let mut wrist = generic;
        wrist[4] = 0.0;
        let mut elbow = generic;
        elbow[2] = 0.0;
        let mut both = wrist;
        both[2] = 0.0;
        let shoulder = shoulder_singular(&a);
        let shoulder_measure = {
            let set = inverse(&a, &a.base_from_flange(&shoulder), &IkParams::no_refusal()).expect("ik");
            set.solutions.iter().map(|s| s.measures.shoulder_m).fold(0.0, f64::max)
        };
        let [g, w, e, b, s] = [generic, wrist, elbow, both, shoulder].map(|q| count(&q));
        println!(
            "{name}: (all, same shoulder and wrist): generic {g:?} | wrist q5 = 0 {w:?} | elbow q3 = 0 {e:?} | both {b:?} | \
             shoulder (measure {shoulder_measure:.1e} m) {s:?}"
        );
        // generic: 2 shoulders x 2 wrists x 2 elbows
        assert_eq!(g, (8, 2, 4), "{name} generic");
        // q5 = 0 makes this shoulder's two wrist solutions one (the other shoulder keeps 4)
        assert_eq!(w.0, 6, "{name} wrist");
        // q3 = 0: this shoulder and wrist keep one elbow (the others depend on the reach left)
        assert_eq!(e.1, 1, "{name} elbow");
        assert!(e.0 < 8, "{name} elbow");
        assert_eq!(b.1, 1, "{name} both");
        // the wrist point on the shoulder plane: the two shoulder roots are one, so every
        // configuration comes once (shoulder +) where a generic pose has it twice. The measure is
        // sqrt(r^2 - D^2): 1e-16 of rounding in r^2 - D^2 shows as up to 1e-8 m
        assert!(shoulder_measure < 1e-7, "{name}: {shoulder_measure}");
        assert_eq!((s.1, s.2), (2, 0), "{name} shoulder");
        assert!(s.0 == 2 || s.0 == 4, "{name} shoulder: {s:?}");
        // out of reach: 3 m away
        let far = Isometry3::translation(0.3, 0.2, 3.0);
        let set = inverse(&a, &far, &IkParams::default()).expect("ik");
        println!("{name} 3 m away: {}", set.reason());
        assert!(set.solutions.is_empty() && set.reason().contains("between joints 2 and 4"), "{}", set.reason());
        // inside the shoulder offset: the wrist point on joint 1's axis
        let mut on_axis = far;
        on_axis.translation = Translation3::new(0.0, 0.0, 0.5 + a.dh[5].d);
        on_axis.rotation = UnitQuaternion::identity();
        let set = inverse(&a, &on_axis, &IkParams::no_refusal()).expect("ik");
        println!("{name} wrist on joint 1's axis: {}", set.reason());
        assert!(set.solutions.is_empty() && set.reason().contains("shoulder offset"), "{}", set.reason());
    }
}

#[test]
fn near_singular_poses_are_refused_with_the_measure_named() {
    let a = arm("ur5e");
    let base = [0.3, -1.2, 1.4, -0.9, 1.1, 0.4];
    let mut wrist = base;
    wrist[4] = 0.02;
    let mut elbow = base;
    elbow[2] = 0.03;
    let shoulder = {
        let mut q = shoulder_singular(&a);
        q[3] += 0.005; // half a millimetre off the plane (d5 x 0.005 rad)
        q
    };
    for (what, q, measure, word) in [
        ("wrist", wrist, Measure::Wrist, "wrist"),
        ("elbow", elbow, Measure::Elbow, "elbow"),
        ("shoulder", shoulder, Measure::Shoulder, "shoulder"),
    ] {
        let pose = a.base_from_flange(&q);
        let all = inverse(&a, &pose, &IkParams::no_refusal()).expect("ik");
        let own = all.solutions.iter().find(|s| same_turns(&s.q, &q)).expect("the original joints are a solution");
        let set = inverse(&a, &pose, &IkParams::default()).expect("ik");
        assert!(set.of_branch(own.branch).is_none(), "{what}: the near-singular configuration was returned");
        let refusal = set.refused.iter().find(|r| r.branch == Some(own.branch)).expect("refused");
        let text = refusal.reason.to_string();
        println!("{what}: {} returned, {} refused; {}: {text}", set.solutions.len(), set.refused.len(), own.branch);
        match refusal.reason {
            Reason::Singular { measure: m, value, min } => {
                assert_eq!(m, measure, "{what}");
                assert!(value < min, "{what}: {value} {min}");
            }
            ref other => panic!("{what}: refused for {other:?}"),
        }
        assert!(text.contains(word), "{what}: {text}");
        // with the minimum lowered below the measure it is returned again
        let lowered = IkParams { min_wrist: 0.001, min_elbow: 0.001, min_shoulder_m: 0.0001, reference: None };
        assert!(inverse(&a, &pose, &lowered).expect("ik").of_branch(own.branch).is_some(), "{what}");
    }
}

/// Whether two joint vectors are the same modulo whole turns (1e-6 rad).
fn same_turns(a: &Joints, b: &Joints) -> bool {
    a.iter().zip(b).all(|(x, y)| {
        let d = (x - y).rem_euclid(2.0 * PI);
        d.min(2.0 * PI - d) < 1e-6
    })
}

/// The solution of `a` at `q`'s pose with `q`'s configuration.
fn start_at(a: &Arm, q: &Joints) -> IkSolution {
    let params = IkParams { reference: Some(*q), ..IkParams::no_refusal() };
    let set = inverse(a, &a.base_from_flange(q), &params).expect("ik");
    *set.solutions.iter().find(|s| joint_distance(&s.q, q) < 1e-6).expect("q is a solution")
}

#[test]
fn a_clean_piercing_line_passes_with_its_margins() {
    let a = arm("ur5e");
    let q = [0.3, -1.2, 1.4, -1.8, -1.57, 0.4];
    let approach = a.base_from_flange(&q);
    let z = approach.rotation * Vector3::z();
    let at =
        |off: f64| Isometry3::from_parts(Translation3::from(approach.translation.vector + z * off), approach.rotation);
    let poses = [approach, at(0.11), approach];
    let report = check_path(&a, &poses, &start_at(&a, &q), &LineParams::default()).expect("line");
    let step = largest_step_rad(&report);
    println!(
        "{} samples, min margins: limits {:.3} rad, wrist {:.3}, elbow {:.3}, shoulder {:.3} m; largest joint step {step:.4} rad",
        report.samples.len(),
        report.min.limit_rad,
        report.min.wrist,
        report.min.elbow,
        report.min.shoulder_m
    );
    assert!(report.ok(), "{:?}", report.failure);
    // 110 mm in and out at 2 mm steps: 56 + 55 samples
    assert_eq!(report.samples.len(), 111);
    assert!(step < 0.02, "largest joint step {step}"); // measured 0.0049 rad
    let at_poses = report.joints_at_poses();
    assert_eq!(at_poses.len(), 3);
    for (qk, pose) in at_poses.iter().zip(&poses) {
        let (dt, dr) = pose_difference(&a.base_from_flange(qk), pose);
        assert!(dt < 1e-9 && dr < 1e-9, "{dt:e} {dr:e}");
    }
    // in and back out along the same line: the retract ends where it started
    assert!(joint_distance(&at_poses[0], &at_poses[2]) < 1e-9);
}

#[test]
fn lines_crossing_a_joint_limit_are_reported() {
    // TM5-700 elbow (joint 3) limited to +-155 deg: from 150 to 160 deg
    let a = arm("tm5-700");
    let q0 = [0.2, 0.1, 150f64.to_radians(), 0.3, 1.2, 0.2];
    let mut q1 = q0;
    q1[2] = 160f64.to_radians();
    let poses = [a.base_from_flange(&q0), a.base_from_flange(&q1)];
    let report = check_path(&a, &poses, &start_at(&a, &q0), &LineParams::default()).expect("line");
    let f = report.failure.as_ref().expect("the line crosses joint 3's limit");
    println!("tm5-700 elbow: {f}");
    match f.kind {
        FailureKind::Ik(Reason::JointLimit { joint, q_rad, limits }) => {
            assert_eq!(joint, 3);
            assert!(q_rad > limits[1] && q_rad < limits[1] + 0.02, "{q_rad}"); // just past 155 deg
        }
        ref other => panic!("{other:?}"),
    }
    assert!(f.s > 0.3 && f.s < 0.7, "{}", f.s); // 155 deg is half way: measured 0.52
    // UR5e wrist 3 at 355 deg turned by 10 deg about the tool axis: past +360
    let a = arm("ur5e");
    let q0 = [0.3, -1.2, 1.4, -1.8, -1.57, 355f64.to_radians()];
    let start = start_at(&a, &q0);
    assert!((start.q[5] - q0[5]).abs() < 1e-9, "the alias at 355 deg is kept: {}", start.q[5]);
    let turn = Isometry3::rotation(Vector3::z() * 10f64.to_radians());
    let poses = [a.base_from_flange(&q0), a.base_from_flange(&q0) * turn];
    let report = check_path(&a, &poses, &start, &LineParams::default()).expect("line");
    let f = report.failure.as_ref().expect("the line crosses joint 6's limit");
    println!("ur5e wrist 3: {f}");
    assert!(matches!(f.kind, FailureKind::Ik(Reason::JointLimit { joint: 6, .. })), "{:?}", f.kind);
    assert!((f.s - 0.5).abs() < 0.02, "{}", f.s); // 360 deg is half way
}

#[test]
fn lines_through_a_singularity_are_reported() {
    let a = arm("ur5e");
    // the arm stretched toward a pose with the elbow almost straight (q3 = 0.3 -> 0.02 rad),
    // within reach all along
    let q0 = [0.3, -0.6, 0.3, -1.2, 1.3, 0.4];
    let mut q1 = q0;
    q1[2] = 0.02;
    let poses = [a.base_from_flange(&q0), a.base_from_flange(&q1)];
    let report = check_path(&a, &poses, &start_at(&a, &q0), &LineParams::default()).expect("line");
    let f = report.failure.as_ref().expect("the line stretches the elbow");
    println!("elbow: {f}; min elbow measure before it {:.4}", report.min.elbow);
    assert!(matches!(f.kind, FailureKind::Ik(Reason::Singular { measure: Measure::Elbow, .. })), "{:?}", f.kind);
    // beyond the reach: 0.3 m further out along the arm, out of reach after the elbow singularity
    let pose0 = a.base_from_flange(&q0);
    let f = a.link_frames(&q0);
    let outward = (f[3].translation.vector - f[1].translation.vector).normalize();
    let poses =
        [pose0, Isometry3::from_parts(Translation3::from(pose0.translation.vector + outward * 0.3), pose0.rotation)];
    let report = check_path(&a, &poses, &start_at(&a, &q0), &LineParams::default()).expect("line");
    let f = report.failure.as_ref().expect("the line leaves the reach");
    println!("outward: {f}; min elbow measure before it {:.4}", report.min.elbow);
    assert!(
        matches!(f.kind, FailureKind::Ik(Reason::Singular { measure: Measure::Elbow, .. } | Reason::OutOfReach(_))),
        "{:?}",
        f.kind
    );
    // the wrist flipped through q5 = 0: from +0.3 to -0.3 rad with the other joints kept
    let q0 = [0.3, -1.2, 1.4, -1.8, 0.3, 0.4];
    let mut q1 = q0;
    q1[4] = -0.3;
    let poses = [a.base_from_flange(&q0), a.base_from_flange(&q1)];
    let report = check_path(&a, &poses, &start_at(&a, &q0), &LineParams::default()).expect("line");
    let f = report.failure.as_ref().expect("the line passes the wrist singularity");
    println!("wrist: {f}; min wrist measure before it {:.4}", report.min.wrist);
    assert!(matches!(f.kind, FailureKind::Ik(Reason::Singular { measure: Measure::Wrist, .. })), "{:?}", f.kind);
    // with the refusal off the same line shows as a jump of joints 4 / 6 where the wrist flips
    let off = LineParams { ik: IkParams::no_refusal(), ..LineParams::default() };
    let report = check_path(&a, &poses, &start_at(&a, &q0), &off).expect("line");
    let f = report.failure.as_ref().expect("a jump");
    println!("wrist, no refusal: {f}");
    assert!(matches!(f.kind, FailureKind::Jump { joint: 4 | 6, .. }), "{:?}", f.kind);
}

#[test]
fn the_spin_search_keeps_the_most_margin() {
    let a = arm("ur5e");
    // an angled tool (40 deg off the flange axis, 5 cm aside): the spin moves the whole wrist
    let ee_from_tool = Isometry3::from_parts(
        Translation3::new(0.0, 0.05, 0.12),
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 40f64.to_radians()),
    );
    // near the edge of the reach, so that some spins cannot be reached at all
    let target = Point3::new(0.75, 0.0, 0.1);
    let down = Vector3::new(0.0, 0.0, -1.0);
    let tool = tool_poses(&target, &down, &Stroke::default()).expect("tool poses");
    let line = LineParams::default();
    let spin = SpinParams { count: 12, ..SpinParams::default() };
    let search = best_spin(&a, &tool, &ee_from_tool, &line, &spin).expect("search");
    let best = search.best.as_ref().expect("a comfortable target passes");
    println!(
        "best spin {:.0} deg, {}, score {:.3}, margins {:?}; {} passed, {} failed",
        best.spin_rad.to_degrees(),
        best.start.branch,
        best.score,
        best.report.min,
        search.passed,
        search.failures.len()
    );
    assert!(best.score > 1.5, "{}", best.score); // measured 1.92
    // the tool tip lands on the target at the pierce pose, 10 mm deep
    let tip = best.flange_poses[1] * ee_from_tool * Point3::origin();
    assert!((tip - (target + down * 0.01)).norm() < 1e-12);
    // no other (spin, configuration) passing scores higher: checked by brute force, spin by spin
    let mut scores = Vec::new();
    for k in 0..12 {
        let s = 2.0 * PI * k as f64 / 12.0;
        let fixed = SpinParams { fixed_rad: Some(s), ..spin };
        let b = best_spin(&a, &tool, &ee_from_tool, &line, &fixed).expect("fixed").best;
        if let Some(b) = &b {
            assert!((b.spin_rad - s).abs() < 1e-15);
        }
        scores.push(b.map_or(-1.0, |b| b.score));
    }
    println!(
        "best score per spin (-1: none passed): {:?}",
        scores.iter().map(|v| format!("{v:.3}")).collect::<Vec<_>>()
    );
    let brute = scores.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let worst = scores.iter().copied().fold(f64::INFINITY, f64::min);
    assert!((brute - best.score).abs() < 1e-12, "brute force {brute} vs {}", best.score);
    // the spin matters here: spins 60-120 deg have no passing configuration (measured: 3 of 12)
    assert_eq!(worst, -1.0);
    let unreachable = search.failures.iter().filter(|(_, branch, _)| branch.is_none()).count();
    assert_eq!(unreachable, 3, "{:?}", search.failures);
    // out of reach: 2 m away
    let far = tool_poses(&Point3::new(2.0, 0.0, 0.1), &down, &Stroke::default()).expect("tool poses");
    let search = best_spin(&a, &far, &ee_from_tool, &line, &spin).expect("search");
    println!("2 m away: {}", search.reason());
    assert!(search.best.is_none() && search.reason().contains("out of reach"), "{}", search.reason());
}

#[test]
fn robot_names_and_arm_files() {
    for name in ["UR5e", "ur5e", "TM5-700", "tm12", " UR30 "] {
        assert!(Arm::by_name(name).is_ok(), "{name}");
    }
    let e = Arm::by_name("ur5").expect_err("unknown");
    let text = e.to_string();
    println!("{text}");
    assert!(matches!(e, Error::Invalid { ref what, .. } if what == "robot"));
    for known in KNOWN {
        assert!(text.contains(known), "{text}");
    }
    let path = Path::new("my-arm.json");
    // round trip of every built-in
    for name in KNOWN {
        let a = arm(name);
        assert_eq!(parse_arm(path, arm_json(&a).as_bytes()).expect("parse"), a, "{name}");
    }
    let good: Value = serde_json::from_str(&arm_json(&arm("ur5e"))).expect("json");
    let bad = |edit: &dyn Fn(&mut Value)| {
        let mut doc = good.clone();
        edit(&mut doc);
        parse_arm(path, serde_json::to_string(&doc).expect("json").as_bytes()).expect_err("bad arm file")
    };
    let field_of = |e: &Error| match e {
        Error::Field { path: p, field, .. } => {
            assert_eq!(p, path);
            field.clone()
        }
        other => panic!("not a field error: {other}"),
    };
    type Edit = Box<dyn Fn(&mut Value)>;
    let cases: Vec<(&str, Edit, &str)> = vec![
        ("five rows", Box::new(|d| drop(d["dh"].as_array_mut().expect("dh").pop())), "dh"),
        ("seven limits", Box::new(|d| d["limits"].as_array_mut().expect("limits").push(json!([-1, 1]))), "limits"),
        ("reversed limits", Box::new(|d| d["limits"][2] = json!([1.0, -1.0])), "limits[2]"),
        ("degrees as radians", Box::new(|d| d["limits"][0] = json!([-360, 360])), "limits[0]"),
        ("missing d", Box::new(|d| drop(d["dh"][3].as_object_mut().expect("row").remove("d"))), "dh[3].d"),
        ("a string", Box::new(|d| d["dh"][1]["a"] = json!("0.4")), "dh[1].a"),
        ("unknown key", Box::new(|d| d["dh"][0]["offset"] = json!(0)), "dh[0].offset"),
        ("wrong format", Box::new(|d| d["format"] = json!("arm")), "format"),
        ("not rigid", Box::new(|d| d["T_dh6_flange"][0][0] = json!(2.0)), "T_dh6_flange"),
    ];
    for (what, edit, field) in cases {
        let e = bad(&*edit);
        println!("{what}: {e}");
        assert_eq!(field_of(&e), field, "{what}: {e}");
    }
    // non-finite numbers: a JSON NaN literal and an overflowing number name the file
    let text = arm_json(&arm("ur5e"));
    for (what, replaced) in [("NaN", text.replacen("0.1625", "NaN", 1)), ("1e999", text.replacen("0.1625", "1e999", 1))]
    {
        let e = parse_arm(path, replaced.as_bytes()).expect_err(what);
        println!("{what}: {e}");
        assert!(
            matches!(e, Error::Format { ref path, .. } | Error::Field { ref path, .. } if path == Path::new("my-arm.json")),
            "{e}"
        );
    }
    // in memory: a NaN in a table, and a table the closed form cannot solve
    let mut dh = arm("ur5e").dh;
    dh[1].d = f64::NAN;
    let e = Arm::new("nan-arm", dh, arm("ur5e").limits, Isometry3::identity()).expect_err("nan");
    println!("{e}");
    assert!(e.to_string().contains("dh[1].d"), "{e}");
    let mut dh = arm("ur5e").dh;
    dh[1].alpha = 0.3;
    let odd = Arm::new("odd", dh, arm("ur5e").limits, Isometry3::identity()).expect("a valid table");
    let e = inverse(&odd, &Isometry3::identity(), &IkParams::default()).expect_err("no closed form");
    println!("{e}");
    assert!(e.to_string().contains("dh[1].alpha"), "{e}");
    let e =
        inverse(&arm("ur5e"), &Isometry3::translation(f64::NAN, 0.0, 0.0), &IkParams::default()).expect_err("nan pose");
    assert!(e.to_string().contains("non-finite"), "{e}");
}

#[test]
fn an_arm_file_flange_offset_moves_forward_and_inverse_alike() {
    let ur = arm("ur5e");
    let dh6_from_flange = Isometry3::from_parts(
        Translation3::new(0.01, -0.02, 0.03),
        UnitQuaternion::from_euler_angles(0.1, -0.2, FRAC_PI_2),
    );
    let rows: Vec<Vec<f64>> = {
        let m: Matrix4<f64> = dh6_from_flange.to_homogeneous();
        (0..4).map(|i| (0..4).map(|j| m[(i, j)]).collect()).collect()
    };
    let mut doc: Value = serde_json::from_str(&arm_json(&ur)).expect("json");
    doc["name"] = json!("ur5e-with-adapter");
    doc["T_dh6_flange"] = json!(rows);
    let a = parse_arm(Path::new("adapter.json"), doc.to_string().as_bytes()).expect("parse");
    let q = [0.3, -1.2, 1.4, -0.9, 1.1, 0.4];
    let (dt, dr) = pose_difference(&a.base_from_flange(&q), &(ur.base_from_flange(&q) * dh6_from_flange));
    assert!(dt < 1e-12 && dr < 1e-12);
    let set = inverse(&a, &a.base_from_flange(&q), &IkParams::default()).expect("ik");
    assert_eq!(set.solutions.len(), 8);
    assert!(set.solutions.iter().any(|s| joint_distance(&s.q, &q) < 1e-9));
}
