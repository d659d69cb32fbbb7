//! `awl plan-views WORKPIECE.json --shot DIR --target ... [--candidates FILE] --tolerance-mm T
//! [--tolerance-deg D] [--max-views K] [--robot ARM --tcp FILE [--urscript F] [--techman F]] -o
//! views.json`: the views a shot still needs for its targets' predicted errors to meet the
//! tolerance, chosen among given or sampled flange poses, each checked for the arm when one is given.

use std::path::{Path, PathBuf};

use anyhow::Context;
use awl::io::outputs::{OutputCheck, write_files_atomic};
use awl::io::scan::read_scan;
use awl::pierce::ScriptSpeeds;
use awl::pierce::{LocateParams, PierceParams, plan};
use awl::plan_views::file::{read_candidates, views_json};
use awl::plan_views::program::{ViewsProgram, views_techman, views_urscript};
use awl::plan_views::reach::ViewRobot;
use awl::plan_views::{PlanViewsParams, plan_after_pierce};
use awl::workpiece::SurfaceModel;
use awl::workpiece::json::read_workpiece;

use super::pierce::{RobotArgs, TargetArgs, ToleranceArgs, hand_eye_prior, read_model, robot_setup, targets};

/// Arguments of `awl plan-views`.
#[derive(clap::Args)]
pub struct PlanViewsArgs {
    /// workpiece.json written by `awl fuse` (the model file is read from beside it).
    pub workpiece: PathBuf,
    /// The piercing-time shot so far (an awl-scan/1 folder, world = robot base), as for `awl pierce`.
    #[arg(long)]
    pub shot: PathBuf,
    #[command(flatten)]
    pub targets: TargetArgs,
    /// The flange poses to choose among (JSON: {"candidates": [{"T_base_ee": 4x4, "why": "..."}]}, or a
    /// view bank's bank.json with T_base_ee_commanded): a cell's taught poses. Default: awl's own,
    /// swings of the shot's first view about the targets and close views of each (their reach is not
    /// checked with --robot; without it only 0.3-1.1 m from the base).
    #[arg(long)]
    pub candidates: Option<PathBuf>,
    #[command(flatten)]
    pub tolerance: ToleranceArgs,
    /// At most this many views.
    #[arg(long, default_value_t = 4, allow_hyphen_values = true)]
    pub max_views: i64,
    /// T_ee_camera from this JSON file instead of the workpiece's or the shot's, as for `awl pierce`.
    #[arg(long)]
    pub hand_eye: Option<PathBuf>,
    #[command(flatten)]
    pub robot: RobotArgs,
    /// Also write a URScript program that visits the views (movej to each view's checked joints, then
    /// sleep --dwell-s while the view is taken). Needs --robot and the shot's recorded joints (q).
    #[arg(long)]
    pub urscript: Option<PathBuf>,
    /// Also write Techman listen-node packets that visit the views (one PTP packet per view, then
    /// ScriptExit()). Needs --robot and the shot's recorded joints (q).
    #[arg(long, alias = "tm")]
    pub techman: Option<PathBuf>,
    /// The URScript program's wait at each view, seconds (0-60).
    #[arg(long, default_value_t = 2.0, allow_hyphen_values = true)]
    pub dwell_s: f64,
    /// Output: views.json (awl-views/1).
    #[arg(short, long)]
    pub output: PathBuf,
    /// No summary.
    #[arg(long)]
    pub quiet: bool,
    /// Replace an earlier output file.
    #[arg(long)]
    pub force: bool,
}

/// Runs `awl plan-views`.
pub fn run(args: &PlanViewsArgs) -> anyhow::Result<()> {
    let max_views = usize::try_from(args.max_views)
        .ok()
        .filter(|k| (1..=64).contains(k))
        .ok_or_else(|| anyhow::anyhow!("--max-views must be between 1 and 64, got {}", args.max_views))?;
    let tolerance = args.tolerance.tolerance();
    let params = PlanViewsParams { max_views, tolerance, ..PlanViewsParams::default() };
    params.validate()?;
    let (specs, mut warnings) = targets(&args.targets)?;
    anyhow::ensure!(args.robot.fixed_spin.is_none(), "--fixed-spin is for awl pierce: a view has no tool spin");
    awl::plan_views::program::check_dwell(args.dwell_s)?;
    let robot = robot_setup(&args.robot)?;
    anyhow::ensure!(
        robot.is_some() || (args.urscript.is_none() && args.techman.is_none()),
        "--urscript and --techman need --robot NAME (or --robot-file) and --tcp: a program's joints are checked for the arm"
    );
    let given = args.candidates.as_deref().map(read_candidates).transpose().context("--candidates")?;
    let workpiece = read_workpiece(&args.workpiece)?;
    let model_path = args.workpiece.parent().unwrap_or(Path::new(".")).join(&workpiece.model);
    let mut shot = read_scan(&args.shot)?;
    let mut check = OutputCheck::new(args.force);
    check
        .input_file(&args.workpiece, "WORKPIECE")
        .input_file(&model_path, "the workpiece's model")
        .input_folder(&args.shot, "--shot")
        .input_files(&shot.input_files(), "a file the shot names");
    for (path, what) in [
        (&args.targets.targets_file, "--targets-file"),
        (&args.hand_eye, "--hand-eye"),
        (&args.candidates, "--candidates"),
        (&args.robot.robot_file, "--robot-file"),
        (&args.robot.tcp, "--tcp"),
    ] {
        if let Some(p) = path {
            check.input_file(p, what);
        }
    }
    check.output_file(&args.output, "-o");
    for (path, what) in [(&args.urscript, "--urscript"), (&args.techman, "--techman")] {
        if let Some(p) = path {
            check.output_file(p, what);
        }
    }
    let _outputs = super::common::lock_outputs(&check)?;
    awl::plan_views::check_one_base(&shot)?;
    let world_from_tag = workpiece.require_world_from_tag(&args.workpiece)?;
    let model = read_model(&args.workpiece, &workpiece, &model_path, &mut warnings)?;
    let (_, prior) = hand_eye_prior(&args.workpiece, &workpiece, args.hand_eye.as_deref(), &mut shot)?;
    let pierce_params = PierceParams {
        locate: LocateParams::with_refinement(),
        hand_eye: prior,
        model_disagreement_m: workpiece.model_disagreement_m(),
        ..PierceParams::default()
    };
    let surface = SurfaceModel::new(&model)?.with_floor(workpiece.floor);
    let pierce = plan(&surface, &workpiece.tag, &world_from_tag, &shot, &specs, &pierce_params)?;
    warnings.extend(pierce.warnings.iter().cloned());
    let candidates = match given {
        Some(c) => c,
        None => awl::plan_views::sample::candidates_after_pierce(&pierce, &shot)?,
    };
    let view_robot = robot.map(|(arm, ee_from_tool, reach)| ViewRobot {
        body: reach.body,
        collision: reach.collision,
        floor: workpiece.floor,
        ..ViewRobot::new(arm, ee_from_tool)
    });
    if view_robot.is_none() {
        warnings
            .push("no --robot: the views' reach and collisions are not checked (views.json has no joints)".to_string());
    }
    let views = plan_after_pierce(&pierce, &pierce_params, &shot, &model, view_robot.as_ref(), &candidates, &params)?;
    let names: Vec<String> = pierce.targets.iter().map(|t| t.surface.spec.to_string()).collect();
    let arm_name = view_robot.as_ref().map(|r| r.arm.name.clone());
    let mut json =
        views_json(&views, &candidates, &names, (tolerance.position_m, tolerance.axis_rad), arm_name.as_deref());
    json["warnings"] = serde_json::json!(warnings);
    let text = serde_json::to_string_pretty(&json)? + "\n";
    let mut files: Vec<(&Path, Vec<u8>)> = vec![(args.output.as_path(), text.into_bytes())];
    if args.urscript.is_some() || args.techman.is_some() {
        let program = ViewsProgram::of(&views, arm_name.as_deref().unwrap_or_default(), args.dwell_s)?;
        if let Some(p) = &args.urscript {
            files.push((p.as_path(), views_urscript(&program, &ScriptSpeeds::default())?.into_bytes()));
        }
        if let Some(p) = &args.techman {
            files.push((p.as_path(), views_techman(&program, &ScriptSpeeds::default())?.into_bytes()));
        }
    }
    let refs: Vec<(&Path, &[u8])> = files.iter().map(|(p, b)| (*p, b.as_slice())).collect();
    write_files_atomic(&refs)?;
    if !args.quiet {
        for w in &warnings {
            eprintln!("warning: {w}");
        }
        let worst = |b: &[(f64, f64)]| {
            b.iter().fold((0.0f64, 0.0f64), |(p, a), &(bp, ba)| (p.max(bp * 1e3), a.max(ba.to_degrees())))
        };
        let (p0, a0) = worst(&views.before);
        println!("the shot's views: worst bounds {p0:.2} mm / {a0:.2} deg");
        for (k, c) in views.chosen.iter().enumerate() {
            let (p, a) = worst(&c.bounds);
            let bank = candidates[c.candidate].view.map_or(String::new(), |v| format!(" (bank view {v})"));
            let q = c.reach.map_or(String::new(), |r| {
                let deg: Vec<String> = r.joints.q.iter().map(|v| format!("{:.1}", v.to_degrees())).collect();
                format!("; q [{}] deg", deg.join(", "))
            });
            println!("view {}: candidate {}{bank}: worst bounds {p:.2} mm / {a:.2} deg{q}", k + 1, c.candidate);
        }
        println!("{}: {}", if views.met { "tolerance met" } else { "tolerance NOT met" }, views.stop);
        for (p, _) in &files {
            println!("wrote {}", p.display());
        }
    }
    Ok(())
}
