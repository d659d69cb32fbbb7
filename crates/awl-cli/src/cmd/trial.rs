//! `awl trial --scene box|shell --tilt 0|30 --trials 10`: the reference paper's piercing trials in
//! simulation (calibrate, simulate + fuse, then shots in random placements, then pierce), printed as
//! its Tables I-IV. See `awl::trial`. With `--robot NAME --tcp T_ee_tool.json` (the arguments of
//! `awl pierce`), each trial's plan is checked for the arm at the rig's robot base: a reach column,
//! per trial the margins and clearance or why not, and trial.json's `reach` per row. An unreachable
//! target is reported, not an error.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use awl::io::scan::read_scan;
use awl::pierce::{HandEyePrior, LocateParams, PierceParams};
use awl::pipeline::FuseConfig;
use awl::sim::rig_ee_from_camera;
use awl::sim::{SceneKind, ShotPose, SimParams, simulate, write_simulation};
use awl::transform::pose_difference;
use awl::trial::{
    ShotSetup, TrialRobot, TrialRow, TrialSummary, calibrate_rig, format_table, prepare_workpiece, run_shot,
};
use serde_json::json;

use super::common::{lock_outputs, prepare_output, set_threads, stage_bar, write_json};
use super::demo::DemoScene;
use super::pierce::{RobotArgs, robot_setup};

/// Arguments of `awl trial`.
#[derive(clap::Args)]
pub struct TrialArgs {
    /// Workpiece.
    #[arg(long, value_enum, default_value = "box")]
    pub scene: DemoScene,
    /// How the workpiece lies at piercing time: flat (0) or tilted 30 degrees (30).
    #[arg(long, default_value_t = 0)]
    pub tilt: u32,
    /// The truth target to pierce, by name (box: top-centre; shell: groove, flank). Default: the first.
    #[arg(long)]
    pub target: Option<String>,
    /// Number of trials (shots in new random placements).
    #[arg(long, default_value_t = 10)]
    pub trials: usize,
    /// Seed of the scan, the calibration and (with the trial number) the shots.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Poses of the simulated hand-eye calibration capture.
    #[arg(long, default_value_t = 20)]
    pub calibration_poses: usize,
    /// Calibrate the hand-eye from simulated poses first and pierce with it (a fresh calibration);
    /// without it the shots use the scan's recorded T_ee_camera (about 3 mm / 0.3 deg off), refined
    /// by the fuse from the scan's base stops and by each shot's views, as a user without a fresh
    /// calibration would.
    #[arg(long)]
    pub calibrate: bool,
    /// Output folder: scan/, fuse/, shots/NN/, table.txt and trial.json (must not exist or be empty, unless --force).
    #[arg(short = 'o', long = "output", default_value = "awl-trial")]
    pub output: PathBuf,
    /// Replace the trial's results in a non-empty output folder.
    #[arg(long)]
    pub force: bool,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Only the table.
    #[arg(long)]
    pub quiet: bool,
    /// After each 2-view shot, plan up to this many more views (`awl plan-views` among candidates
    /// sampled around the shot), take the shot again with them and pierce from all.
    #[arg(long, default_value_t = 0)]
    pub plan_views: usize,
    #[command(flatten)]
    pub robot: RobotArgs,
}

fn row_json(r: &TrialRow) -> serde_json::Value {
    let e = r.error();
    json!({
        "trial": r.trial, "shot_seed": r.shot_seed,
        "truth_m": [r.truth.x, r.truth.y, r.truth.z], "estimate_m": [r.estimate.x, r.estimate.y, r.estimate.z],
        "error_m": [e.x, e.y, e.z], "distance_m": e.norm(),
        "tag_only_distance_m": (r.estimate_tag_only - r.truth).norm(),
        "axis_error_deg": r.axis_error_rad.to_degrees(), "refined": r.refined, "planned_views": r.planned_views,
        "locate_rotation_deg": r.locate_rotation_rad.to_degrees(),
        "model_normal_error_deg": r.model_normal_error_rad.to_degrees(),
        "axis_error_at_point_deg": r.axis_error_at_point_rad.to_degrees(),
        "hand_eye_error_m": r.hand_eye_error.map(|e| e.0),
        "hand_eye_error_deg": r.hand_eye_error.map(|e| e.1.to_degrees()),
        "predicted_error_mm": finite(r.prediction.position_bound_m * 1e3),
        "predicted_axis_error_deg": finite(r.prediction.axis_bound_rad.to_degrees()),
        "position_covariance_m2": rows3(&r.prediction.position_covariance),
        "axis_covariance_rad2": rows3(&r.prediction.axis_covariance),
        "located_position_covariance_m2": rows3(&r.located_position_covariance),
        "normal_base": [r.normal_base.x, r.normal_base.y, r.normal_base.z],
        "face_centre": r.face_centre,
        "base_distance_m": r.base_distance_m(),
        "base_horizontal_m": r.base_horizontal_m(),
        "reach": r.reach.as_ref().map(awl::pierce::plan_file::reach_json),
    })
}

/// Refuses a `--tcp` / `--robot-file` that the run would remove or replace (inside `scan/`,
/// `fuse/` or `shots/` of the output folder, or its table.txt / trial.json).
fn check_robot_inputs(args: &TrialArgs) -> anyhow::Result<()> {
    let out = awl::io::outputs::resolve_path(&args.output);
    for (path, what) in [(&args.robot.tcp, "--tcp"), (&args.robot.robot_file, "--robot-file")] {
        let Some(p) = path else { continue };
        let p = awl::io::outputs::resolve_path(p);
        let replaced = ["scan", "fuse", "shots"].iter().any(|sub| p.starts_with(out.join(sub)))
            || ["table.txt", "trial.json"].iter().any(|f| p == out.join(f));
        anyhow::ensure!(
            !replaced,
            "{what} `{}`: refusing to use an input the trial replaces (it lies in the output folder's scan/, fuse/ or \
             shots/, or is its table.txt or trial.json); move it out of `{}`",
            p.display(),
            args.output.display()
        );
    }
    Ok(())
}

fn finite(v: f64) -> serde_json::Value {
    if v.is_finite() { json!(v) } else { serde_json::Value::Null }
}

fn rows3(m: &nalgebra::Matrix3<f64>) -> Vec<Vec<serde_json::Value>> {
    (0..3).map(|a| (0..3).map(|b| finite(m[(a, b)])).collect()).collect()
}

/// Runs `awl trial`.
pub fn run(args: &TrialArgs) -> anyhow::Result<()> {
    let start = Instant::now();
    set_threads(args.threads)?;
    anyhow::ensure!(args.tilt == 0 || args.tilt == 30, "--tilt must be 0 or 30, got {}", args.tilt);
    anyhow::ensure!((1..=1000).contains(&args.trials), "--trials must be 1 to 1000, got {}", args.trials);
    anyhow::ensure!(args.plan_views <= 16, "--plan-views must be 0 to 16, got {}", args.plan_views);
    // the arm and the tool are read and checked before the scan is simulated
    let robot = robot_setup(&args.robot)?.map(|(arm, ee_from_tool, params)| TrialRobot { arm, ee_from_tool, params });
    check_robot_inputs(args)?;
    // the output folder locked to the end: a second trial into it is refused naming this one
    let _outputs = lock_outputs(awl::io::outputs::OutputCheck::new(args.force).locked_folder(&args.output, "-o"))?;
    prepare_output(&args.output, args.force, &["scan", "fuse", "shots"])?;
    let say = |line: String| {
        if !args.quiet {
            println!("{line}");
        }
    };
    let scene = match args.scene {
        DemoScene::Box => SceneKind::Box,
        DemoScene::Shell => SceneKind::Shell,
    };
    let pose = if args.tilt == 30 { ShotPose::Tilt30 } else { ShotPose::Flat };

    let calibrated = if args.calibrate {
        let hand_eye = calibrate_rig(args.seed, args.calibration_poses).context("hand-eye calibration")?;
        say(format!(
            "[1/3] hand-eye calibrated from {} simulated poses: {:.2} mm / {:.3} deg from the true T_ee_camera",
            hand_eye.poses,
            hand_eye.error_m * 1e3,
            hand_eye.error_rad.to_degrees()
        ));
        Some(hand_eye)
    } else {
        None
    };

    let t = Instant::now();
    let sim = simulate(&SimParams { seed: args.seed, ..SimParams::scan(scene) }).context("simulating the scan")?;
    let scan_dir = args.output.join("scan");
    write_simulation(&scan_dir, &sim, args.force)?;
    let scan = read_scan(&scan_dir)?;
    let job = super::fuse::fuse_with_progress(&scan, &FuseConfig::default(), args.quiet)?;
    super::fuse::write_outputs(&args.output.join("fuse"), &job, None)?;
    let (fused, workpiece) = (&job.fused, job.workpiece.as_ref().context("the simulated scan declares no tag")?);
    let wp = prepare_workpiece(scene, workpiece, &sim.truth, &sim.cad, &fused.model, args.target.as_deref())
        .context("the workpiece on the model")?;
    say(format!(
        "[2/3] scanned and fused the {} ({} views, {} points, {:.1} s); target `{}` picked as {}",
        scene.name(),
        scan.views.len(),
        fused.model.len(),
        t.elapsed().as_secs_f64(),
        wp.target.name,
        wp.spec
    ));

    let truth_he = rig_ee_from_camera();
    let off = |x: &nalgebra::Isometry3<f64>| {
        let (dt, dr) = pose_difference(x, &truth_he);
        format!("{:.2} mm / {:.3} deg", dt * 1e3, dr.to_degrees())
    };
    let (ee_from_camera, prior) = match &calibrated {
        Some(c) => (c.ee_from_camera, HandEyePrior::calibrated(c.ee_from_camera, "calibrated (--calibrate)")),
        None => {
            let recorded = scan.ee_from_camera.context("the simulated scan records no T_ee_camera")?;
            let report = workpiece.hand_eye.as_ref().context("the fuse left no hand-eye estimate")?;
            let prior = HandEyePrior::of_report(report)?;
            say(format!(
                "[1/3] hand-eye: the scan's recorded T_ee_camera is {} from the truth; refined from the scan's {} base \
                 stops: {}{}",
                off(&recorded),
                report.stops_used.len(),
                off(&prior.prior.ee_from_camera),
                if report.refused.is_empty() { String::new() } else { format!(" (not refined: {})", report.refused) }
            ));
            (recorded, prior)
        }
    };
    let setup = ShotSetup {
        scene,
        pose,
        seed: args.seed,
        camera_seed: args.seed,
        ee_from_camera,
        params: PierceParams {
            locate: LocateParams::with_refinement(),
            hand_eye: Some(prior),
            model_disagreement_m: workpiece.model_disagreement_m(),
            ..PierceParams::default()
        },
        robot,
        plan_views: args.plan_views,
    };
    let bar = stage_bar(args.quiet);
    bar.set_length(args.trials as u64);
    bar.set_message("shots");
    let mut rows = Vec::with_capacity(args.trials);
    for k in 1..=args.trials {
        let dir = args.output.join("shots").join(format!("{k:02}"));
        rows.push(run_shot(&wp, &setup, k, &dir).with_context(|| format!("trial {k} ({})", dir.display()))?);
        bar.set_position(k as u64);
    }
    bar.finish_and_clear();
    let arm = setup.robot.as_ref().map_or(String::new(), |r| {
        format!(
            ", reach for {} with the TCP {:.0} mm from the flange",
            r.arm.name,
            r.ee_from_tool.translation.vector.norm() * 1e3
        )
    });
    let title = format!(
        "{} {} (tilt {} deg), target `{}`, {} trials, seed {}{arm} [3/3 done in {:.1} s]",
        scene.name(),
        pose.name(),
        args.tilt,
        wp.target.name,
        args.trials,
        args.seed,
        start.elapsed().as_secs_f64()
    );
    let table = format_table(&title, &rows);
    let s = TrialSummary::of(&rows);
    awl::io::write_atomic(&args.output.join("table.txt"), table.as_bytes())?;
    write_json(
        &args.output.join("trial.json"),
        &json!({
            "scene": scene.name(), "pose": pose.name(), "tilt_deg": args.tilt, "seed": args.seed,
            "target": wp.target.name, "target_spec": wp.spec.to_string(),
            "hand_eye": {
                "calibrated_poses": calibrated.as_ref().map(|c| c.poses),
                "prior": setup.params.hand_eye.as_ref().map(|h| h.source.clone()),
                "start_error_m": pose_difference(&ee_from_camera, &truth_he).0,
                "start_error_deg": pose_difference(&ee_from_camera, &truth_he).1.to_degrees(),
                "prior_error_m": setup.params.hand_eye.as_ref().map(|h| pose_difference(&h.prior.ee_from_camera, &truth_he).0),
                "prior_error_deg": setup.params.hand_eye.as_ref().map(|h| pose_difference(&h.prior.ee_from_camera, &truth_he).1.to_degrees()),
            },
            "summary": { "trials": s.trials, "mean_m": s.mean_m, "std_m": s.std_m, "max_m": s.max_m,
                         "mean_axis_error_deg": s.mean_axis_error_rad.to_degrees(),
                         "max_axis_error_deg": s.max_axis_error_rad.to_degrees(),
                         "max_locate_rotation_deg": s.max_locate_rotation_rad.to_degrees(),
                         "max_model_normal_error_deg": s.max_model_normal_error_rad.to_degrees(),
                         "mean_axis_error_at_point_deg": s.mean_axis_error_at_point_rad.to_degrees(),
                         "max_axis_error_at_point_deg": s.max_axis_error_at_point_rad.to_degrees(),
                         "mean_tag_only_m": s.mean_tag_only_m, "refined": s.refined,
                         "within_bound": s.within_bound, "axis_within_bound": s.axis_within_bound,
                         "median_bound_m": s.median_bound_m, "median_m": s.median_m,
                         "reach_checked": s.reach_checked, "reachable": s.reachable },
            "robot": setup.robot.as_ref().map(|r| json!({
                "arm": r.arm.name,
                "T_ee_tool": awl::transform::rows_from_isometry(&r.ee_from_tool),
                "base": "the simulated rig's robot base (the shots' world frame)",
            })),
            "rows": rows.iter().map(row_json).collect::<Vec<_>>(),
        }),
    )?;
    print!("{table}");
    Ok(())
}
