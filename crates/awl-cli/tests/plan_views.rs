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
