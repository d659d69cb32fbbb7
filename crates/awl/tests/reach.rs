//! Reach of piercing targets (`awl::pierce::reach`, `awl::kinematics::collision`): a target on an
//! open plate is reachable with its clearance measured; the same target under an overhang of the
//! model (the tool would pass through it) is refused with the link named; the floor is checked;
//! the configuration of the shot's joint state is preferred; the capsules sit where forward
//! kinematics puts the links.
//! Run in release: `cargo test --release -p awl --test reach`.

use awl::kinematics::collision::{Against, BodyParams, CollisionParams, Link, Obstacles, SWEEP_MARGIN_M, capsules};
use awl::kinematics::{Arm, Branch};
use awl::pierce::reach::{ReachParams, branch_of, reach_target, reach_target_from};
use awl::pierce::{Stroke, tool_poses};
use awl::workpiece::file::FloorPlane;
use nalgebra::{Isometry3, Point3, Vector3};

/// A square plate of points, `half` metres half-width, every `step` metres, at height `z`
/// centred on (`cx`, `cy`), base frame.
fn plate(cx: f64, cy: f64, z: f64, half: f64, step: f64) -> Vec<Point3<f32>> {
    let n = (half / step).round() as i32;
    let mut out = Vec::new();
    for i in -n..=n {
        for j in -n..=n {
            out.push(Point3::new((cx + f64::from(i) * step) as f32, (cy + f64::from(j) * step) as f32, z as f32));
        }
    }
    out
}

const TARGET: [f64; 3] = [0.45, 0.15, 0.10];

fn setup() -> (Arm, Isometry3<f64>, Point3<f64>, awl::pierce::ToolPoses, ReachParams) {
    let arm = Arm::by_name("ur5e").expect("ur5e");
    // a 150 mm straight tool on the flange, its tip the TCP
    let ee_from_tool = Isometry3::translation(0.0, 0.0, 0.15);
    let target = Point3::from(Vector3::from(TARGET));
    let poses = tool_poses(&target, &-Vector3::z(), &Stroke::default()).expect("poses");
    let mut params = ReachParams::default();
    // a camera 70 mm beside the flange axis, 30 mm forward, looking along the tool
    params.body.ee_from_camera = Some(Isometry3::translation(0.0, 0.07, 0.03));
    (arm, ee_from_tool, target, poses, params)
}

#[test]
fn an_open_target_is_reachable_and_an_overhang_is_refused_naming_the_link() {
    let (arm, ee_from_tool, target, poses, params) = setup();
    let base = Isometry3::identity();
    // the part's top: a 300 mm plate at the target's height
    let open = plate(TARGET[0], TARGET[1], TARGET[2], 0.15, 0.004);
    let obstacles = Obstacles::new(&open, None, &base).expect("obstacles");
    let r = reach_target(&arm, &ee_from_tool, &poses, &target, Some(&obstacles), None, None, &params).expect("reach");
    println!("open: reachable {} ({}), clearance {:?}, margins {:?}", r.reachable, r.reason, r.clearance, r.margins);
    assert!(r.reachable, "{}", r.reason);
    let c = r.clearance.expect("the plate is within the reach");
    // the tool is vertical over a flat plate: its capsule is exclude_radius - tool radius = 21 mm
    // from the nearest kept point at the pierce pose (measured 21.0 mm), the other links farther
    assert_eq!(c.link, Link::Tool, "{c:?}");
    assert_eq!(c.against, Against::Model);
    assert!((c.distance_m - 0.021).abs() < 0.002, "{c:?}");
    let j = r.joints.expect("joints");
    for q in [j.approach, j.pierce, j.retract] {
        assert!(arm.within_limits(&q));
    }
    // the joints put the tool where the plan's (spun) tool poses are: 1e-9 m
    let tools = r.tool_poses.expect("tool poses");
    for (q, t) in [(j.approach, tools.approach), (j.pierce, tools.pierce), (j.retract, tools.retract)] {
        let (dt, dr) = awl::transform::pose_difference(&(arm.base_from_flange(&q) * ee_from_tool), &t);
        assert!(dt < 1e-9 && dr < 1e-9, "{dt} {dr}");
    }

    // an overhang 50 mm above the target, 200 mm across: the straight approach passes through it
    let mut covered = open.clone();
    covered.extend(plate(TARGET[0], TARGET[1], TARGET[2] + 0.05, 0.10, 0.004));
    let obstacles = Obstacles::new(&covered, None, &base).expect("obstacles");
    let r = reach_target(&arm, &ee_from_tool, &poses, &target, Some(&obstacles), None, None, &params).expect("reach");
    println!("overhang: reachable {}: {}", r.reachable, r.reason);
    assert!(!r.reachable);
    assert!(r.candidates_passed > 0, "the kinematics alone pass: only the collision refuses");
    assert!(r.reason.contains("collision: the tool is") && r.reason.contains("from the model"), "{}", r.reason);

    // the same open target with the floor 12 mm below the surface: the tool's tip (10 mm in)
    // comes 2 mm above it: refused by the floor at the 3 mm minimum clearance, passed at 1 mm
    let floor = FloorPlane::new(Vector3::z(), -(TARGET[2] - 0.012)).expect("floor");
    let obstacles = Obstacles::new(&open, Some(floor), &base).expect("obstacles");
    let r = reach_target(&arm, &ee_from_tool, &poses, &target, Some(&obstacles), None, None, &params).expect("reach");
    println!("floor: reachable {}: {}", r.reachable, r.reason);
    assert!(!r.reachable);
    assert!(r.reason.contains("the tool is 2.0 mm from the floor"), "{}", r.reason);
    let mut close = params;
    close.collision.min_clearance_m = 0.001;
    let r = reach_target(&arm, &ee_from_tool, &poses, &target, Some(&obstacles), None, None, &close).expect("reach");
    let c = r.clearance.expect("clearance");
    println!("floor, 1 mm minimum: reachable {}, clearance {c:?}", r.reachable);
    assert!(r.reachable, "{}", r.reason);
    assert_eq!((c.link, c.against), (Link::Tool, Against::Floor));
    assert!((c.distance_m - 0.002).abs() < 1e-9, "{c:?}"); // 12 - 10 mm
}

#[test]
fn the_shot_configuration_is_preferred_when_it_passes() {
    let (arm, ee_from_tool, target, poses, params) = setup();
    let mut chosen: Vec<(Branch, Option<Branch>)> = Vec::new();
    for shoulder in [1i8, -1] {
        for elbow in [1i8, -1] {
            for wrist in [1i8, -1] {
                let b = Branch { shoulder, elbow, wrist };
                let r = reach_target(&arm, &ee_from_tool, &poses, &target, None, None, Some(b), &params).expect("r");
                assert!(r.reachable, "{}", r.reason);
                chosen.push((b, r.branch));
            }
        }
    }
    let reachable: Vec<Branch> = chosen.iter().filter_map(|(_, c)| *c).collect();
    for (asked, got) in &chosen {
        // a configuration any run used has a passing path: preferring it must choose it
        if reachable.contains(asked) {
            assert_eq!(Some(*asked), *got);
        }
    }
    let mut distinct = reachable.clone();
    distinct.sort_by_key(|b| (b.shoulder, b.elbow, b.wrist));
    distinct.dedup();
    println!("configurations chosen: {distinct:?}");
    assert_eq!(distinct.len(), 8, "the preference changes the choice: {distinct:?}"); // every one passes here
}

#[test]
fn capsules_follow_the_link_frames() {
    let arm = Arm::by_name("ur5e").expect("ur5e");
    let q = [0.3, -1.2, 1.4, -1.8, -1.57, 0.4];
    let ee_from_tool = Isometry3::translation(0.0, 0.0, 0.15);
    let body = BodyParams { ee_from_camera: Some(Isometry3::translation(0.0, 0.07, 0.03)), ..BodyParams::default() };
    let caps = capsules(&arm, &q, &ee_from_tool, &body);
    let frames = arm.link_frames(&q);
    let flange = arm.base_from_flange(&q);
    let find = |l: Link| caps.iter().find(|c| c.link == l).expect("capsule");
    let tool = find(Link::Tool);
    // the tool runs from its tip (less its radius) back to the flange's origin
    assert!((tool.a - flange * Point3::new(0.0, 0.0, 0.15 - 0.004)).norm() < 1e-12);
    assert!((tool.b - flange * Point3::origin()).norm() < 1e-12);
    let w3 = find(Link::Wrist3);
    assert!((w3.a - frames[5] * Point3::origin()).norm() < 1e-12);
    assert!((w3.b - flange * Point3::origin()).norm() < 1e-12);
    // UR5e: wrist 3 is d6 = 99.6 mm long, wrist 2 d5 = 99.7 mm, wrist 1 d4 = 133.3 mm (the DH table)
    assert!(((w3.b - w3.a).norm() - 0.0996).abs() < 1e-9);
    assert!(((find(Link::Wrist2).b - find(Link::Wrist2).a).norm() - 0.0997).abs() < 1e-9);
    assert!(((find(Link::Wrist1).b - find(Link::Wrist1).a).norm() - 0.1333).abs() < 1e-9);
    let cam = find(Link::Camera);
    let centre = flange * Point3::new(0.0, 0.07, 0.03 - body.camera_behind_m);
    assert!((nalgebra::center(&cam.a, &cam.b) - centre).norm() < 1e-12);
    // a bad size is named
    let bad = BodyParams { tool_radius_m: -0.001, ..BodyParams::default() };
    assert!(bad.validate().expect_err("refused").to_string().contains("tool_radius_m"));
    let bad = CollisionParams { reach_m: 0.0, ..CollisionParams::default() };
    assert!(bad.validate().expect_err("refused").to_string().contains("reach_m"));
}

/// A wall of points in the plane `y = 0`, `x` from `x0` to `x1`, `z` from `z0` to `z1`, every 7.5 mm.
fn wall(x0: f64, x1: f64, z0: f64, z1: f64) -> Vec<Point3<f32>> {
    let (nx, nz) = (((x1 - x0) / 0.0075) as i32, ((z1 - z0) / 0.0075) as i32);
    (0..=nx)
        .flat_map(|i| {
            (0..=nz).map(move |k| {
                Point3::new((x0 + 0.0075 * f64::from(i)) as f32, 0.0, (z0 + 0.0075 * f64::from(k)) as f32)
            })
        })
        .collect()
}

/// Issue 73: the program's joint move from one target's retract to the next one's approach. Two
/// targets 0.7 m apart on either side of a wall (0.7 m tall, between them): each alone is reachable,
/// but the joint move that the configurations chosen alone would make passes through the wall; from
/// the first target, the second is re-routed through another spin or configuration whose move is
/// clear, or refused naming the move. Every move taken is checked along its whole swept motion: 20 000 configurations along it, brute force, keep the capsules 2.5 mm
/// (3 mm less the sweep margin) clear. On the UR10e and the TM12.
#[test]
fn a_transfer_through_a_wall_is_refused_and_a_clear_one_is_checked_along_its_sweep() {
    for name in ["ur10e", "tm12"] {
        let arm = Arm::by_name(name).expect("arm");
        let ee_from_tool = Isometry3::translation(0.0, 0.0, 0.15);
        let params = ReachParams::default();
        let (a, b) = (Point3::new(0.7, -0.35, 0.1), Point3::new(0.7, 0.35, 0.1));
        let stroke = Stroke::default();
        let (pa, pb) = (
            tool_poses(&a, &-Vector3::z(), &stroke).expect("poses"),
            tool_poses(&b, &-Vector3::z(), &stroke).expect("poses"),
        );
        let mut model = plate(a.x, a.y, a.z, 0.1, 0.005);
        model.extend(plate(b.x, b.y, b.z, 0.1, 0.005));
        let open = Obstacles::new(&model, None, &Isometry3::identity()).expect("obstacles");
        model.extend(wall(0.45, 1.0, 0.1, 0.8));
        let walled = Obstacles::new(&model, None, &Isometry3::identity()).expect("obstacles");
        // as `plan_reach` does: coming from joints, their configuration preferred and the nearest joints
        let reach = |t: &Point3<f64>, poses, obstacles: &Obstacles, from: Option<(Option<usize>, [f64; 6])>| {
            let reference = from.map(|(_, q)| q);
            let prefer = reference.and_then(|q| branch_of(&arm, &q).expect("branch"));
            reach_target_from(&arm, &ee_from_tool, poses, t, Some(obstacles), reference, prefer, from, &params)
                .expect("reach")
        };

        let first = reach(&a, &pa, &walled, None);
        assert!(first.reachable, "{name}: {}", first.reason);
        let retract = first.joints.expect("joints").retract;
        // alone, the second target is reachable; the move to it from the first passes through the wall
        let alone = reach(&b, &pb, &walled, None);
        assert!(alone.reachable, "{name}: {}", alone.reason);
        let to = alone.joints.expect("joints").approach;
        let swing = walled.check_joint_move(&arm, &retract, &to, &ee_from_tool, &params.body, &params.collision);
        let hit = swing.collision.expect("the move the targets alone make crosses the wall");
        println!("{name}: alone, the move hits the {} at {:.0} %", hit.clearance.link.name(), hit.s * 100.0);
        // the swept motion of a move, brute force: its smallest clearance over 20 000 configurations
        let brute = |obstacles: &Obstacles, to: &[f64; 6]| {
            let mut closest = f64::INFINITY;
            for i in 0..=20_000 {
                let s = f64::from(i) / 20_000.0;
                let q: [f64; 6] = std::array::from_fn(|k| retract[k] + (to[k] - retract[k]) * s);
                let capsules = capsules(&arm, &q, &ee_from_tool, &params.body);
                if let Some(c) = obstacles.clearance(&capsules, None, &params.collision) {
                    closest = closest.min(c.distance_m);
                }
            }
            closest
        };
        let keeps = params.collision.min_clearance_m - SWEEP_MARGIN_M;
        // coming from the first target, every candidate's move is checked: re-routed through another
        // spin or configuration whose whole sweep is clear, or refused naming the move
        let second = reach(&b, &pb, &walled, Some((Some(0), retract)));
        if second.reachable {
            let m = second.transfer.expect("the move is checked");
            let to = second.joints.expect("joints").approach;
            assert_ne!(to, alone.joints.expect("joints").approach, "{name}: another candidate");
            let closest = brute(&walled, &to);
            println!(
                "{name}: from target 0, re-routed: {} spin {:.0} deg (alone: {} {:.0} deg), {:.0} deg of the largest \
                 joint, {} samples, clearance {:.4} m; brute force {closest:.4} m",
                second.branch.expect("branch"),
                second.spin_rad.to_degrees(),
                alone.branch.expect("branch"),
                alone.spin_rad.to_degrees(),
                m.largest_joint_rad.to_degrees(),
                m.samples,
                m.clearance.map_or(f64::NAN, |c| c.distance_m),
            );
            assert!(closest >= keeps, "{name}: the re-routed move comes {closest} m from the wall");
        } else {
            println!("{name}: from target 0, refused: {}", second.reason);
            assert!(
                second.reason.contains("the joint move from target 0's retract to the approach brings the"),
                "{}",
                second.reason
            );
        }

        // without the wall: the move is checked and clear along its whole sweep
        let second = reach(&b, &pb, &open, Some((Some(0), retract)));
        assert!(second.reachable, "{name}: {}", second.reason);
        let m = second.transfer.expect("the move is checked");
        assert_eq!(m.from_target, Some(0));
        let closest = brute(&open, &second.joints.expect("joints").approach);
        println!(
            "{name}: no wall, {:.0} deg of the largest joint, {} samples checked, clearance {:?}; brute force {closest:.4} m",
            m.largest_joint_rad.to_degrees(),
            m.samples,
            m.clearance.map(|c| c.distance_m)
        );
        assert!(closest >= keeps, "{name}: {closest}");
        assert!(m.largest_joint_rad > 0.5, "{name}: the move turns the arm: {}", m.largest_joint_rad);
    }
}
