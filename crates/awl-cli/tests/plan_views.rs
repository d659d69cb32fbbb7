//! `awl plan-views` end to end on a simulated box shot (the CAD as the model): views chosen among
//! candidates, the bounds they predict, and bad input refused by name with nothing written.

mod common;

use std::path::Path;

use common::{awl, cad_workpiece, ok, read_json, s, text};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// Candidates: each shot view's flange swung about the vertical through `centre` by `degrees`.
fn swings(shot: &Path, centre: &Vector3<f64>, degrees: &[f64]) -> serde_json::Value {
    let scan = read_json(&shot.join("scan.json"));
    let mut out = Vec::new();
    for (i, v) in scan["views"].as_array().expect("views").iter().enumerate() {
        let rows: [[f64; 4]; 4] = serde_json::from_value(v["T_base_ee"].clone()).expect("T_base_ee");
        let flange = awl::transform::isometry_from_rows(&rows).expect("rigid");
        for d in degrees {
            let about = Translation3::from(*centre)
                * UnitQuaternion::from_scaled_axis(Vector3::z() * d.to_radians())
                * Translation3::from(-centre);
            let moved: Isometry3<f64> = Isometry3::from(about) * flange;
            out.push(serde_json::json!({
                "T_base_ee": awl::transform::rows_from_isometry(&moved),
                "why": format!("view {i} swung {d} deg"),
            }));
        }
    }
    serde_json::json!({ "candidates": out })
}

#[test]
fn views_are_chosen_among_candidates_and_bad_input_is_refused() {
    let wp = cad_workpiece("flat", 3, 60_000, None);
    let dir = wp.dir.path();
    let centre = wp.truth.world_from_object.translation.vector + Vector3::new(0.0, 0.0, 0.15);
    let candidates = dir.join("candidates.json");
    std::fs::write(&candidates, swings(&wp.shot, &centre, &[-20.0, -10.0, 10.0, 20.0]).to_string()).expect("write");
    let out = dir.join("views.json");
    let target = "face-centre@0.24,0.24,0.31";
    let base = |extra: &[&str]| {
        let mut a = vec![
            "plan-views",
            s(&wp.workpiece),
            "--shot",
            s(&wp.shot),
            "--target",
            target,
            "--candidates",
            s(&candidates),
            "-o",
            s(&out),
        ];
        a.extend_from_slice(extra);
        awl(&a)
    };
    let run = ok(base(&["--tolerance-mm", "0.5", "--max-views", "3", "--quiet"]));
    assert!(run.status.success());
    let v = read_json(&out);
    assert_eq!(v["format"], "awl-views/1");
    let views = v["views"].as_array().expect("views");
    assert!(!views.is_empty() && views.len() <= 3, "{v}");
    let bound = |b: &serde_json::Value| b[0]["position_bound_mm"].as_f64().expect("bound");
    let (before, after) = (bound(&v["bounds_before"]), bound(&v["bounds_after"]));
    println!("{} views: worst bound {before:.2} -> {after:.2} mm; {}", views.len(), v["stop"]);
    // each proposed view lowers the bound; the poses are rigid 4x4 flange poses
    assert!(after < 0.8 * before, "{before} -> {after}");
    for view in views {
        let rows: [[f64; 4]; 4] = serde_json::from_value(view["T_base_ee"].clone()).expect("T_base_ee");
        awl::transform::isometry_from_rows(&rows).expect("rigid");
        assert!(view["why"].as_str().expect("why").contains("swung"), "{view}");
    }
    // the shot taken again with the arm sent to the proposed flange poses, then pierced from all
    let again = dir.join("shot_planned");
    ok(awl(&[
        "simulate",
        "--scene",
        "box",
        "--shot",
        "flat",
        "--seed",
        "3",
        "--extra-views",
        s(&out),
        "-o",
        s(&again),
    ]));
    let scan = read_json(&again.join("scan.json"));
    assert_eq!(scan["views"].as_array().expect("views").len(), 2 + views.len());
    let plan = dir.join("plan.json");
    for (shot, name) in [(&wp.shot, "2 views"), (&again, "with the planned")] {
        let o = awl(&[
            "pierce",
            s(&wp.workpiece),
            "--shot",
            s(shot),
            "--target",
            target,
            "-o",
            s(&plan),
            "--force",
            "--quiet",
        ]);
        assert!(o.status.success(), "{}", text(&o));
        let p = read_json(&plan);
        let t = &p["targets"][0];
        let truth = wp.truth.targets.iter().find(|t| t.name == "top-centre").expect("top-centre");
        let e: f64 = (0..3)
            .map(|k| (t["p_base"][k].as_f64().expect("p") - truth.p_world.expect("p_world")[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        let b = t["predicted_error_mm"].as_f64().expect("bound");
        println!("{name}: {:.2} mm (bound {b:.2} mm)", e * 1e3);
        assert!(e * 1e3 <= b, "{name}: outside its bound");
        if shot == &again {
            // the pierce's bound is the one plan-views predicted (within 25 %)
            assert!(b <= 1.25 * after && b < before, "{b} vs predicted {after} (before {before})");
        }
    }
    // without candidates: awl's own, swings about the targets and close views of them
    std::fs::remove_file(&out).expect("rm");
    let own = ok(awl(&[
        "plan-views",
        s(&wp.workpiece),
        "--shot",
        s(&wp.shot),
        "--target",
        target,
        "--tolerance-mm",
        "0.5",
        "-o",
        s(&out),
    ]));
    assert!(own.status.success());
    let v = read_json(&out);
    let whys: Vec<&str> =
        v["views"].as_array().expect("views").iter().map(|x| x["why"].as_str().expect("why")).collect();
    println!("own candidates: {whys:?}; worst bound {:.2} mm", bound(&v["bounds_after"]));
    assert!(!whys.is_empty() && whys.iter().all(|w| w.contains("swing") || w.contains("close view")), "{whys:?}");
    assert!(bound(&v["bounds_after"]) < 0.8 * before);
    // a tolerance the shot's views already meet: no view, said so
    std::fs::remove_file(&out).expect("rm");
    ok(base(&["--tolerance-mm", "50", "--quiet"]));
    let v = read_json(&out);
    assert!(v["views"].as_array().expect("views").is_empty() && v["met"] == true, "{v}");
    assert!(v["stop"].as_str().expect("stop").contains("already meet"), "{v}");
    std::fs::remove_file(&out).expect("rm");

    // bad input: each named, nothing written
    let refused = |extra: &[&str], words: &[&str]| {
        let o = base(extra);
        let t = text(&o);
        assert!(!o.status.success(), "{extra:?} was accepted");
        for w in words {
            assert!(t.contains(w), "{extra:?}: {t}");
        }
        assert!(!out.exists(), "{extra:?} wrote {}", out.display());
    };
    refused(&["--tolerance-mm", "1", "--max-views", "0"], &["--max-views"]);
    refused(&["--tolerance-mm", "1", "--max-views", "-2"], &["--max-views"]);
    refused(&["--tolerance-mm", "-1"], &["--tolerance-mm", "positive"]);
    refused(&["--tolerance-mm", "NaN"], &["--tolerance-mm"]);
    refused(&["--tolerance-deg", "inf"], &["--tolerance-deg"]);
    refused(&[], &["tolerance"]);
    // a candidate that is not rigid (scaled by 2)
    let mut c = swings(&wp.shot, &centre, &[10.0]);
    for r in 0..3 {
        for k in 0..3 {
            let x = c["candidates"][1]["T_base_ee"][r][k].as_f64().expect("entry");
            c["candidates"][1]["T_base_ee"][r][k] = serde_json::json!(2.0 * x);
        }
    }
    std::fs::write(&candidates, c.to_string()).expect("write");
    refused(&["--tolerance-mm", "1"], &["candidates.json", "candidates[1].T_base_ee", "orthonormal"]);
    std::fs::write(&candidates, swings(&wp.shot, &centre, &[10.0]).to_string()).expect("write");
    // a shot whose views disagree on the base pose
    let scan_path = wp.shot.join("scan.json");
    let mut scan = read_json(&scan_path);
    scan["views"][1]["T_world_base"][0][3] = serde_json::json!(0.05);
    std::fs::write(&scan_path, scan.to_string()).expect("write");
    refused(&["--tolerance-mm", "1"], &["views[1].T_world_base", "one base pose"]);
}

/// The largest rotation (deg) and translation (mm) difference of two poses.
fn pose_gap(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    let d = a.inverse() * b;
    (d.rotation.angle().to_degrees(), d.translation.vector.norm() * 1e3)
}

/// The distance from `p` to the segment `a`-`b`.
fn segment_distance(p: &Vector3<f64>, a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    let ab = b - a;
    let t = if ab.norm_squared() > 0.0 { ((p - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0) } else { 0.0 };
    (p - (a + ab * t)).norm()
}

#[test]
fn views_are_checked_for_the_arm_and_visited_by_checked_programs() {
    let su = common::robot_setup();
    let dir = su.cad.dir.path();
    let out = dir.join("views.json");
    let (ur, tm) = (dir.join("views.script"), dir.join("views.tm"));
    let target = su.targets[0].as_str();
    let run = |arm_args: &[&str], extra: &[&str]| {
        let mut a = vec!["plan-views", s(&su.workpiece), "--shot", s(&su.cad.shot), "--target", target];
        a.extend_from_slice(&["--tolerance-mm", "0.5", "--max-views", "3", "-o", s(&out), "--quiet"]);
        a.extend_from_slice(arm_args);
        a.extend_from_slice(extra);
        awl(&a)
    };
    // the CAD's surface points (model frame = object frame) at the truth, robot base frame
    let model = awl::io::mesh::read_cloud(&dir.join("model.ply")).expect("model");
    let placed: Vec<Vector3<f64>> =
        (model.points.iter()).map(|p| (su.cad.truth.world_from_object * p.cast::<f64>()).coords).collect();
    for arm_name in ["ur5e", "tm12"] {
        let arm = awl::kinematics::Arm::by_name(arm_name).expect("arm");
        let refused = |extra: &[&str], words: &[&str]| {
            let o = run(&["--robot", arm_name, "--tcp", s(&su.tcp)], extra);
            let t = text(&o);
            assert!(!o.status.success(), "{extra:?} was accepted");
            for w in words {
                assert!(t.contains(w), "{extra:?}: {t}");
            }
            for p in [&out, &ur, &tm] {
                assert!(!p.exists(), "{extra:?} wrote {}", p.display());
            }
        };
        // the shot records no joints: views.json is planned from awl's choice, a program is refused
        refused(&["--urscript", s(&ur)], &["q", "records no joints"]);
        ok(run(&["--robot", arm_name, "--tcp", s(&su.tcp)], &[]));
        let v = read_json(&out);
        assert_eq!(v["start_q"]["recorded"], false, "{v}");
        let views = v["views"].as_array().expect("views").clone();
        assert!(!views.is_empty(), "{arm_name}: {v}");
        let left_out = v["left_out"].as_array().expect("left out");
        println!(
            "{arm_name}: {} views, worst bound {:.2} -> {:.2} mm; {} candidates left out, e.g. {:?}",
            views.len(),
            v["bounds_before"][0]["position_bound_mm"],
            v["bounds_after"][0]["position_bound_mm"],
            left_out.len(),
            left_out.iter().take(2).map(|x| x["why"].as_str().unwrap_or("")).collect::<Vec<_>>()
        );
        let shot = awl::io::scan::read_scan(&su.cad.shot).expect("shot");
        let body = awl::kinematics::collision::BodyParams {
            ee_from_camera: Some(shot.ee_from_camera.expect("the shot's hand-eye")),
            ..Default::default()
        };
        let ee_from_tool = Isometry3::translation(0.0, 0.0, 0.15);
        for view in &views {
            let rows: [[f64; 4]; 4] = serde_json::from_value(view["T_base_ee"].clone()).expect("T_base_ee");
            let flange = awl::transform::isometry_from_rows(&rows).expect("rigid");
            let q: [f64; 6] = serde_json::from_value(view["q"].clone()).expect("q");
            // FK(q) is the proposed flange pose within 0.1 mm / 0.01 deg
            let (deg, mm) = pose_gap(&arm.base_from_flange(&q), &flange);
            assert!(deg < 0.01 && mm < 0.1, "{arm_name}: FK(q) is {mm} mm / {deg} deg off");
            assert!(arm.within_limits(&q), "{arm_name}: {q:?}");
            assert_eq!(view["reach"]["arm"], arm_name);
            // every capsule of the tool end clear of the workpiece by the 3 mm minimum (with 2 mm for
            // the located pose's error against the truth), brute force
            for c in awl::kinematics::collision::capsules(&arm, &q, &ee_from_tool, &body) {
                let d =
                    placed.iter().map(|p| segment_distance(p, &c.a.coords, &c.b.coords)).fold(f64::INFINITY, f64::min)
                        - c.radius_m;
                assert!(d > 0.001, "{arm_name}: the {:?} is {:.1} mm from the model", c.link, d * 1e3);
                // the floor: the CAD's z = 0 (workpiece.json's floor) at the truth
                let height = |p: &nalgebra::Point3<f64>| (su.cad.truth.world_from_object.inverse() * p).z;
                assert!(
                    height(&c.a).min(height(&c.b)) - c.radius_m > 0.001,
                    "{arm_name}: the {:?} is below the floor",
                    c.link
                );
            }
            if let Some(m) = view["reach"]["clearance"]["mm"].as_f64() {
                assert!(m >= 3.0, "{view}");
            }
            if let Some(m) = view["reach"]["move_clearance"]["mm"].as_f64() {
                assert!(m >= 3.0, "{view}");
            }
        }
        // the joints recorded in the shot (each view's own, the configuration awl chose): programs
        let start: [f64; 6] = serde_json::from_value(v["start_q"]["q"].clone()).expect("start q");
        let scan_path = su.cad.shot.join("scan.json");
        let original = std::fs::read(&scan_path).expect("scan");
        let mut scan = read_json(&scan_path);
        for (i, view) in scan["views"].as_array_mut().expect("views").iter_mut().enumerate() {
            let rows: [[f64; 4]; 4] = serde_json::from_value(view["T_base_ee"].clone()).expect("T_base_ee");
            let flange = awl::transform::isometry_from_rows(&rows).expect("rigid");
            let params = awl::kinematics::IkParams { reference: Some(start), ..Default::default() };
            let s = awl::kinematics::ik::inverse(&arm, &flange, &params).expect("ik");
            let q = s.solutions.first().unwrap_or_else(|| panic!("{arm_name}: view {i} unreachable")).q;
            view["q"] = serde_json::json!(q);
        }
        std::fs::write(&scan_path, scan.to_string()).expect("write");
        std::fs::remove_file(&out).expect("rm");
        ok(run(&["--robot", arm_name, "--tcp", s(&su.tcp)], &["--urscript", s(&ur), "--techman", s(&tm)]));
        let v = read_json(&out);
        assert_eq!(v["start_q"]["recorded"], true, "{v}");
        let views = v["views"].as_array().expect("views");
        let program = std::fs::read_to_string(&ur).expect("urscript");
        awl::robot::statements::check_urscript_statements(&program).expect("awl's statements");
        let moves: Vec<&str> = program.lines().filter(|l| l.trim_start().starts_with("movej(")).collect();
        assert_eq!(moves.len(), views.len(), "{program}");
        for (m, view) in moves.iter().zip(views) {
            let q: Vec<f64> = serde_json::from_value(view["q"].clone()).expect("q");
            let inside = m.split_once("[").and_then(|(_, r)| r.split_once("]")).expect("joints").0;
            let written: Vec<f64> = inside.split(", ").map(|x| x.parse().expect("number")).collect();
            assert!(written.iter().zip(&q).all(|(a, b)| (a - b).abs() < 1e-6), "{m} vs {q:?}");
        }
        assert_eq!(program.matches("sleep(2.000)").count(), views.len(), "{program}");
        let packets = std::fs::read_to_string(&tm).expect("techman");
        let split = awl::robot::techman::split_packets(&packets).expect("packets");
        assert_eq!(split.len(), views.len() + 1);
        awl::robot::statements::check_techman_statements(&split).expect("awl's statements");
        assert_eq!(packets.matches("PTP(\"JPP\"").count(), views.len());
        for p in [&out, &ur, &tm] {
            std::fs::remove_file(p).expect("rm");
        }
        std::fs::write(&scan_path, original).expect("restore");
    }
    // a 0.5 m tool reaches into the workpiece from the close views, and a camera pulled back 0.6 m
    // puts the flange beyond the arm: left out, each with its reason; what is chosen stays clear
    let long_tcp = dir.join("long_tcp.json");
    common::write_tcp(&long_tcp, 0.5);
    ok(run(&["--robot", "ur5e", "--tcp", s(&long_tcp)], &[]));
    let v = read_json(&out);
    let whys: Vec<&str> =
        v["left_out"].as_array().expect("left out").iter().map(|x| x["why"].as_str().expect("why")).collect();
    println!("0.5 m tool: {} views; left out: {whys:?}", v["views"].as_array().expect("views").len());
    assert!(whys.iter().any(|w| w.contains("every configuration collides: the tool")), "{whys:?}");
    std::fs::remove_file(&out).expect("rm");
    let centre = su.cad.truth.world_from_object.translation.vector + Vector3::new(0.0, 0.0, 0.15);
    let mut c = swings(&su.cad.shot, &centre, &[-10.0, 10.0]);
    let near = c["candidates"].as_array().expect("candidates").clone();
    for mut far in near {
        let rows: [[f64; 4]; 4] = serde_json::from_value(far["T_base_ee"].clone()).expect("T_base_ee");
        let flange = awl::transform::isometry_from_rows(&rows).expect("rigid");
        let back = flange * Isometry3::translation(0.0, 0.0, -0.6);
        far["T_base_ee"] = serde_json::json!(awl::transform::rows_from_isometry(&back));
        far["why"] = serde_json::json!("pulled back 0.6 m");
        c["candidates"].as_array_mut().expect("candidates").push(far);
    }
    let candidates = dir.join("candidates.json");
    std::fs::write(&candidates, c.to_string()).expect("write");
    ok(run(&["--robot", "ur5e", "--tcp", s(&su.tcp)], &["--candidates", s(&candidates)]));
    let v = read_json(&out);
    let left: Vec<(u64, &str)> = (v["left_out"].as_array().expect("left out").iter())
        .map(|x| (x["candidate"].as_u64().expect("index"), x["why"].as_str().expect("why")))
        .collect();
    println!("pulled back: left out {left:?}");
    let pulled = c["candidates"].as_array().expect("candidates").len() as u64 / 2;
    assert!(left.iter().filter(|(i, w)| *i >= pulled && w.contains("cannot reach")).count() >= 2, "{left:?}");
    for view in v["views"].as_array().expect("views") {
        assert!(view["candidate"].as_u64().expect("index") < pulled, "{view}");
    }
    std::fs::remove_file(&out).expect("rm");

    // bad input: named, nothing written
    let no_limits = dir.join("arm.json");
    let mut arm_doc: serde_json::Value = serde_json::from_str(&awl::kinematics::arm_file::arm_json(
        &awl::kinematics::Arm::by_name("ur5e").expect("arm"),
    ))
    .expect("arm json");
    arm_doc.as_object_mut().expect("object").remove("limits");
    std::fs::write(&no_limits, arm_doc.to_string()).expect("write");
    for (args, words) in [
        (vec!["--robot-file", s(&no_limits), "--tcp", s(&su.tcp)], vec!["arm.json", "limits"]),
        (vec!["--urscript", s(&ur)], vec!["--urscript", "--robot"]),
        (vec!["--robot", "ur5e"], vec!["--tcp"]),
        (vec!["--robot", "ur5e", "--tcp", s(&su.tcp), "--dwell-s", "-1"], vec!["--dwell-s"]),
        (vec!["--robot", "ur5e", "--tcp", s(&su.tcp), "--fixed-spin", "10"], vec!["--fixed-spin"]),
    ] {
        let o = run(&args, &[]);
        let t = text(&o);
        assert!(!o.status.success(), "{args:?} was accepted");
        assert!(words.iter().all(|w| t.contains(w)), "{args:?}: {t}");
        assert!(!out.exists() && !ur.exists(), "{args:?} wrote");
    }
}
