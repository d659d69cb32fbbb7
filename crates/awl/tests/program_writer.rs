//! The robot-program writers under hostile words (issue 82): seeded random plans whose source, arm
//! name, target names and no-go reasons are drawn from line breaks, NUL, Unicode separators,
//! bidirectional controls, statements and plain text, and whose poses and joints are random
//! (finite and in range, or not). Every program made has only awl's statements
//! (`awl::robot::statements`, a parser written apart from the writers); every refusal names the
//! value. The coverage-guided version is fuzz/fuzz_targets/program_writer.rs.

use awl::kinematics::Joints;
use awl::pierce::{ProgramPlan, ProgramTarget, ScriptSpeeds, ToolPoses, techman_packets_of, urscript_of};
use awl::robot::statements::{check_techman_statements, check_urscript_statements};
use awl::robot::techman::split_packets;
use nalgebra::{Isometry3, Point3, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

const PIECES: [&str; 16] = [
    "\n",
    "\r",
    "\r\n",
    "\u{2028}",
    "\u{2029}",
    "\u{0}",
    "\u{202e}",
    "\u{2066}",
    "\u{85}",
    "\u{1b}[2J",
    "  movej([0,0,0,0,0,0], a=3, v=3)",
    "end",
    "def x():",
    "# ",
    "plain words 0.5 m",
    "é漢字🦀",
];

fn word(rng: &mut ChaCha8Rng) -> String {
    let n = rng.random_range(0..6);
    let mut w: String = (0..n).map(|_| PIECES[rng.random_range(0..PIECES.len())]).collect();
    if rng.random_bool(0.05) {
        w = "x".repeat(rng.random_range(150..400));
    }
    w
}

fn pose(rng: &mut ChaCha8Rng, scale_m: f64) -> Isometry3<f64> {
    let t = Vector3::from_fn(|_, _| rng.random_range(-scale_m..scale_m));
    let r = Vector3::from_fn(|_, _| rng.random_range(-3.0..3.0));
    let mut p = Isometry3::new(t, r);
    if rng.random_bool(0.03) {
        p.translation.vector.x = [f64::NAN, f64::INFINITY, 1e300][rng.random_range(0..3)];
    }
    p
}

fn plan(rng: &mut ChaCha8Rng) -> ProgramPlan {
    let targets = (0..rng.random_range(0..4))
        .map(|_| {
            let q: Joints = std::array::from_fn(|_| rng.random_range(-7.0..7.0));
            ProgramTarget {
                spec: word(rng),
                p_base: Point3::from(Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0))),
                left_out: rng.random_bool(0.3).then(|| word(rng)),
                approach_q: rng.random_bool(0.5).then_some(q),
                poses: ToolPoses { approach: pose(rng, 1.2), pierce: pose(rng, 1.2), retract: pose(rng, 1.2) },
            }
        })
        .collect();
    ProgramPlan { source: word(rng), tcp: rng.random_bool(0.5).then(|| (word(rng), pose(rng, 0.6))), targets }
}

#[test]
fn every_program_made_has_only_awls_statements() {
    let mut rng = ChaCha8Rng::seed_from_u64(82);
    let speeds = ScriptSpeeds::default();
    let (mut made, mut refused) = (0, 0);
    for _ in 0..3000 {
        let p = plan(&mut rng);
        match (urscript_of(&p, &speeds), techman_packets_of(&p, &speeds)) {
            (Ok(ur), Ok(tm)) => {
                check_urscript_statements(&ur).unwrap_or_else(|e| panic!("{e}\n{ur}"));
                check_techman_statements(&split_packets(&tm).expect("packets")).expect("techman statements");
                assert!(ur.bytes().all(|b| b == b'\n' || (b' '..=b'~').contains(&b)));
                made += 1;
            }
            (Err(e), Err(_)) => {
                let e = e.to_string();
                assert!(e.contains("targets[") || e.contains("T_ee_tool"), "a refusal names the value: {e}");
                refused += 1;
            }
            (a, b) => panic!("the writers disagree: {:?} / {:?}", a.map(|_| ()), b.map(|_| ())),
        }
    }
    println!("3000 random plans: {made} programs made, each of awl's statements only; {refused} refused");
    assert!(made > 300 && refused > 300, "{made} / {refused}");
}
