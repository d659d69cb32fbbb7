//! `awl pierce WORKPIECE.json --shot SHOT_DIR --target ... -o plan.json`: find the workpiece by its
//! tag in a piercing-time shot and plan approach / pierce / retract tool poses in the robot base frame.

use std::path::{Path, PathBuf};

use anyhow::Context;
use awl::eval::file::read_transform;
use awl::handeye::poses_file::read_ee_from_camera;
use awl::io::outputs::{OutputCheck, write_files_atomic};
use awl::io::scan::read_scan;
use awl::kinematics::Arm;
use awl::kinematics::arm_file::read_arm;
use awl::pierce::plan_file::{PlanSources, plan_json, plan_value_text, programs_json};
use awl::pierce::{
    AxisChoice, HandEyePrior, LocateParams, PierceParams, PiercePlan, ReachParams, ScriptSpeeds, Stroke, Tolerance,
    plan, plan_reach_with, shot_joints, techman_packets, urscript,
};
use awl::workpiece::SurfaceModel;
use awl::workpiece::TargetSpec;
use awl::workpiece::json::{read_targets, read_workpiece};
use nalgebra::Isometry3;

use super::common::NoGo;

/// The piercing direction on the command line.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum AxisArg {
    /// The model's surface normal at the target (right for curved surfaces).
    Normal,
    /// The tag's z axis (the reference system's choice).
    Tag,
}

/// Arguments of `awl pierce`.
#[derive(clap::Args)]
pub struct PierceArgs {
    /// workpiece.json written by `awl fuse` (the model file is read from beside it).
    pub workpiece: PathBuf,
    /// The piercing-time shot: an awl-scan/1 folder with world = robot base, color views that see the tag.
    #[arg(long)]
    pub shot: PathBuf,
    #[command(flatten)]
    pub targets: TargetArgs,
    /// Output plan (JSON): T_base_model, and per target p_base, axis_base and the tool poses.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Also write a URScript program (movel approach -> pierce -> retract per target).
    #[arg(long)]
    pub urscript: Option<PathBuf>,
    /// Also write Techman listen-node packets ($TMSCT, Line("CAP") approach -> pierce -> retract per
    /// target, then ScriptExit()), to send in order to a TMflow Listen node.
    #[arg(long)]
    pub techman: Option<PathBuf>,
    /// Piercing direction.
    #[arg(long, value_enum, default_value = "normal")]
    pub axis: AxisArg,
    /// Approach stand-off before the surface, metres.
    #[arg(long, default_value_t = 0.10)]
    pub approach_m: f64,
    /// Piercing depth past the surface, metres.
    #[arg(long, default_value_t = 0.01)]
    pub depth_m: f64,
    /// Retract stand-off before the surface, metres (default: the approach stand-off).
    #[arg(long)]
    pub retract_m: Option<f64>,
    /// T_ee_camera from this JSON file (e.g. `awl calibrate hand-eye -o`) instead of the shot's scan.json.
    #[arg(long)]
    pub hand_eye: Option<PathBuf>,
    #[command(flatten)]
    pub tolerance: ToleranceArgs,
    /// Use the tag pose only: do not refine it by registering the shot's depth to the model.
    #[arg(long)]
    pub no_refine: bool,
    /// No summary.
    #[arg(long)]
    pub quiet: bool,
    /// Print the plan as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// Replace earlier output files (the same flag in every command).
    #[arg(long)]
    pub force: bool,
    /// Accept a `--depth-m` past 5 cm (up to 2 m, an arm's reach).
    #[arg(long)]
    pub allow_long_moves: bool,
    #[command(flatten)]
    pub robot: RobotArgs,
}

/// The targets (`--target`, `--targets-file`).
#[derive(clap::Args)]
pub struct TargetArgs {
    /// A target, model frame, metres: `x,y,z` (snapped onto the surface) or `face-centre@x,y,z`
    /// (the centre of the planar face nearest the point). Repeat for several; negative numbers are fine.
    #[arg(long = "target", allow_hyphen_values = true)]
    pub targets: Vec<String>,
    /// A file of targets: one per line (# comments), or JSON (an array of target strings or {"targets": [...]}).
    #[arg(long)]
    pub targets_file: Option<PathBuf>,
}

/// The largest predicted errors allowed (`--tolerance-mm`, `--tolerance-deg`).
#[derive(clap::Args)]
pub struct ToleranceArgs {
    /// The largest predicted 95 % position error allowed, millimetres: `awl pierce` refuses a target
    /// over it (go: false, left out of the programs, exit code 3); `awl plan-views` plans views to reach it.
    #[arg(long, allow_hyphen_values = true)]
    pub tolerance_mm: Option<f64>,
    /// The largest predicted 95 % tool-axis error allowed, degrees (as --tolerance-mm).
    #[arg(long, allow_hyphen_values = true)]
    pub tolerance_deg: Option<f64>,
}

impl ToleranceArgs {
    /// In metres and radians (not yet checked: [`Tolerance::validate`]).
    pub fn tolerance(&self) -> Tolerance {
        Tolerance { position_m: self.tolerance_mm.map(|t| t * 1e-3), axis_rad: self.tolerance_deg.map(f64::to_radians) }
    }
}

/// The arm the plan's reach is checked for (`--robot` / `--robot-file`).
#[derive(clap::Args)]
pub struct RobotArgs {
    /// Check each target's reach for this built-in arm (ur3e, ur5e, ur10e, ur16e, ur20, ur30, tm5-700,
    /// tm5-900, tm12, tm14): joints, margins, collisions; unreachable targets are left out of the programs.
    #[arg(long, conflicts_with = "robot_file")]
    pub robot: Option<String>,
    /// ... or for the arm of this awl-arm/1 file (DH table, limits, T_dh6_flange).
    #[arg(long)]
    pub robot_file: Option<PathBuf>,
    /// T_ee_tool (JSON: a 4x4 matrix, or {"T_ee_tool": 4x4}): the tool centre point on the flange, the
    /// controller's TCP. Needed with --robot / --robot-file.
    #[arg(long)]
    pub tcp: Option<PathBuf>,
    /// Keep this spin about the tool axis, degrees, instead of searching the spin with the most margin.
    #[arg(long, allow_hyphen_values = true)]
    pub fixed_spin: Option<f64>,
    /// The tool's radius for the collision check, metres (at most 0.1).
    #[arg(long, default_value_t = 0.004)]
    pub tool_radius_m: f64,
    /// The tool's length back from its tip, metres (default: the flange-to-TCP distance; at most 1).
    #[arg(long)]
    pub tool_length_m: Option<f64>,
}

/// The targets asked for, each once (the second and later copies of one are dropped, each with a
/// warning), and those warnings.
pub fn targets(args: &TargetArgs) -> anyhow::Result<(Vec<TargetSpec>, Vec<String>)> {
    let mut asked: Vec<TargetSpec> =
        args.targets.iter().map(|t| TargetSpec::parse(t)).collect::<Result<_, _>>().context("--target")?;
    if let Some(path) = &args.targets_file {
        asked.extend(read_targets(path)?);
    }
    anyhow::ensure!(!asked.is_empty(), "no target: give --target x,y,z (or face-centre@x,y,z) or --targets-file");
    awl::workpiece::check_target_count(asked.len()).map_err(|m| anyhow::anyhow!("--target / --targets-file: {m}"))?;
    let (specs, warnings) = awl::workpiece::target_spec::unique_targets(&asked);
    Ok((specs, warnings))
}

/// The workpiece's model, checked against its fingerprint in workpiece.json (a warning when it has none).
pub fn read_model(
    workpiece_path: &Path,
    workpiece: &awl::workpiece::Workpiece,
    model_path: &Path,
    warnings: &mut Vec<String>,
) -> anyhow::Result<awl::cloud::PointCloud> {
    let model = super::common::read_cloud_warned(model_path)
        .with_context(|| format!("the workpiece's model ({})", workpiece_path.display()))?;
    match &workpiece.model_check {
        Some(check) => check.verify(workpiece_path, model_path, &model)?,
        None => warnings.push(format!(
            "{} records no model_check (written by an older awl fuse): nothing shows that {} is the model it was \
             fused with; fuse again to have it checked",
            workpiece_path.display(),
            model_path.display()
        )),
    }
    Ok(model)
}

/// The hand-eye the shot's views start from: a given calibration (`--hand-eye`, which then replaces
/// the shot's), else the workpiece's (refined from the scan) when the shot records the scan's, else
/// the shot's recorded one (`None`); and where it came from.
pub fn hand_eye_prior(
    workpiece_path: &Path,
    workpiece: &awl::workpiece::Workpiece,
    hand_eye: Option<&Path>,
    shot: &mut awl::scan::Scan,
) -> anyhow::Result<(String, Option<HandEyePrior>)> {
    Ok(match hand_eye {
        Some(path) => {
            let x = read_ee_from_camera(path)?;
            shot.ee_from_camera = Some(x);
            (path.display().to_string(), Some(HandEyePrior::calibrated(x, &path.display().to_string())))
        }
        None => match HandEyePrior::of_workpiece(workpiece.hand_eye.as_ref(), shot)? {
            Some(p) => (format!("{} ({})", workpiece_path.display(), p.source), Some(p)),
            None => ("scan.json".to_string(), None),
        },
    })
}

/// The arm, `T_ee_tool` and the reach settings of `--robot` / `--robot-file`, if given.
pub fn robot_setup(args: &RobotArgs) -> anyhow::Result<Option<(Arm, Isometry3<f64>, ReachParams)>> {
    let arm = match (&args.robot, &args.robot_file) {
        (Some(name), _) => Arm::by_name(name).context("--robot")?,
        (None, Some(path)) => read_arm(path).context("--robot-file")?,
        (None, None) => {
            anyhow::ensure!(
                args.tcp.is_none() && args.fixed_spin.is_none(),
                "--tcp and --fixed-spin need --robot NAME or --robot-file arm.json"
            );
            return Ok(None);
        }
    };
    let Some(tcp) = &args.tcp else {
        anyhow::bail!(
            "--robot needs --tcp T_ee_tool.json (the tool centre point on the flange): the reach and the collision \
             checks depend on the tool"
        );
    };
    let ee_from_tool = read_transform(tcp, "T_ee_tool").context("--tcp")?;
    let mut reach = ReachParams::default();
    if let Some(deg) = args.fixed_spin {
        anyhow::ensure!(deg.is_finite() && deg.abs() <= 360.0, "--fixed-spin must be degrees within +-360, got {deg}");
        reach.spin.fixed_rad = Some(deg.to_radians());
    }
    reach.body.tool_radius_m = args.tool_radius_m;
    reach.body.tool_length_m = args.tool_length_m;
    reach.body.validate().context("--tool-radius-m / --tool-length-m")?;
    Ok(Some((arm, ee_from_tool, reach)))
}

/// Runs `awl pierce`.
pub fn run(args: &PierceArgs) -> anyhow::Result<()> {
    let (specs, mut warnings) = targets(&args.targets)?;
    let workpiece = read_workpiece(&args.workpiece)?;
    let model_path = args.workpiece.parent().unwrap_or(Path::new(".")).join(&workpiece.model);
    let mut shot = read_scan(&args.shot)?;
    // the outputs are this run's alone until they are written (another run into them is refused)
    let _outputs = check_outputs(args, &model_path, &shot)?;
    let world_from_tag = workpiece.require_world_from_tag(&args.workpiece)?;
    let model = read_model(&args.workpiece, &workpiece, &model_path, &mut warnings)?;
    let (hand_eye_source, prior) = hand_eye_prior(&args.workpiece, &workpiece, args.hand_eye.as_deref(), &mut shot)?;
    let params = PierceParams {
        axis: match args.axis {
            AxisArg::Normal => AxisChoice::Normal,
            AxisArg::Tag => AxisChoice::Tag,
        },
        stroke: stroke(args)?,
        locate: if args.no_refine { LocateParams::default() } else { LocateParams::with_refinement() },
        hand_eye: prior,
        model_disagreement_m: workpiece.model_disagreement_m(),
        tolerance: args.tolerance.tolerance(),
        ..PierceParams::default()
    };
    params.tolerance.validate()?;
    let surface = SurfaceModel::new(&model)?.with_floor(workpiece.floor);
    let robot = robot_setup(&args.robot)?;
    let mut plan = plan(&surface, &workpiece.tag, &world_from_tag, &shot, &specs, &params)?;
    plan.warnings.extend(warnings);
    if let Some((arm, ee_from_tool, reach)) = &robot {
        let reference = shot_joints(&shot)?;
        let bar = super::common::count_bar(args.quiet || args.json, plan.targets.len(), "targets' reach checked");
        let progress = |done: usize, _total: usize| bar.set_position(done as u64);
        plan_reach_with(&mut plan, arm, ee_from_tool, &model, workpiece.floor, reference, reach, &progress)?;
        bar.finish_and_clear();
    }
    let sources = PlanSources { workpiece: &args.workpiece, shot: &args.shot, hand_eye: &hand_eye_source };
    // everything is computed before the first file is written
    let ur_program = urscript(&plan, &ScriptSpeeds::default(), &args.workpiece.display().to_string())?;
    let tm_packets = techman_packets(&plan, &ScriptSpeeds::default())?;
    let mut json = plan_json(&plan, &sources);
    json["programs"] = programs_json(&ur_program, &tm_packets);
    // (each checked for the robot: finite, within reach) and all written or none
    let mut files = vec![(args.output.as_path(), plan_value_text(&plan, &json)?)];
    if let Some(path) = &args.urscript {
        files.push((path, ur_program.clone()));
    }
    if let Some(path) = &args.techman {
        files.push((path, tm_packets.clone()));
    }
    write_files_atomic(&files.iter().map(|(p, t)| (*p, t.as_bytes())).collect::<Vec<_>>())?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&json)?);
    } else if !args.quiet {
        print_summary(&plan, args);
    }
    let refused = plan.targets.iter().filter(|t| !t.go()).count();
    if refused > 0 {
        return Err(NoGo { refused, targets: plan.targets.len() }.into());
    }
    Ok(())
}

/// The stroke from the options, range-checked (`--depth-m` at most 5 cm unless `--allow-long-moves`,
/// stand-offs within an arm's reach), the error naming the option.
fn stroke(args: &PierceArgs) -> anyhow::Result<Stroke> {
    let stroke = Stroke {
        approach_m: args.approach_m,
        depth_m: args.depth_m,
        retract_m: args.retract_m.unwrap_or(args.approach_m),
        ..Stroke::default()
    };
    let stroke = if args.allow_long_moves { stroke.allowing_long_moves() } else { stroke };
    match stroke.validate() {
        Ok(()) => Ok(stroke),
        Err(awl::Error::Invalid { what, message }) => anyhow::bail!("--{}: {message}", what.replace('_', "-")),
        Err(e) => Err(e.into()),
    }
}

/// Refuses outputs that are an input (the workpiece, its model, a shot file, the targets or hand-eye
/// file), lie in the shot folder, name the same file, exist without `--force`, or are being written
/// by another run; locks them for this one (the guard).
fn check_outputs(
    args: &PierceArgs,
    model: &Path,
    shot: &awl::scan::Scan,
) -> anyhow::Result<awl::io::outputs::OutputGuard> {
    let mut check = OutputCheck::new(args.force);
    check
        .input_file(&args.workpiece, "WORKPIECE")
        .input_file(model, "the workpiece's model")
        .input_folder(&args.shot, "--shot")
        .input_files(&shot.input_files(), "a file the shot names");
    for (path, what) in [
        (&args.targets.targets_file, "--targets-file"),
        (&args.hand_eye, "--hand-eye"),
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
    super::common::lock_outputs(&check)
}

fn print_summary(plan: &PiercePlan, args: &PierceArgs) {
    let l = &plan.located;
    let used = l.detections.iter().filter(|d| d.used).count();
    println!("tag found in {used} of {} shot views checked {:?}", l.views_checked.len(), l.views_checked);
    if let Some(r) = &l.refinement {
        println!(
            "shot depth registered to the model: {} points, fitness {:.2}, rmse {:.2} mm; it moves the tag {:.2} mm / {:.2} deg ({})",
            r.points,
            r.fitness,
            r.rmse_m * 1e3,
            r.correction_m * 1e3,
            r.correction_rad.to_degrees(),
            if r.applied { "applied".to_string() } else { format!("not applied: {}", r.note) }
        );
    }
    for t in &plan.targets {
        let (p, a) = (t.p_base, t.axis_base);
        let angle = t
            .surface
            .angle_to_tag_z_rad
            .map_or(String::new(), |x| format!(", normal vs tag z {:.2} deg", x.to_degrees()));
        let b = &t.prediction;
        println!(
            "target {}: p_base ({:.4}, {:.4}, {:.4}) m, axis ({:.3}, {:.3}, {:.3}){angle}; predicted error <= {:.2} mm, \
             axis <= {:.2} deg (95 %): {}",
            t.surface.spec,
            p.x,
            p.y,
            p.z,
            a.x,
            a.y,
            a.z,
            b.position_bound_m * 1e3,
            b.axis_bound_rad.to_degrees(),
            t.refusal.as_ref().map_or("go".to_string(), |why| format!("NO GO: {why}"))
        );
    }
    print_reach(plan);
    for w in &plan.warnings {
        println!("warning: {w}");
    }
    println!("wrote {}", args.output.display());
    for path in args.urscript.iter().chain(&args.techman) {
        println!("wrote {}", path.display());
    }
}

fn print_reach(plan: &PiercePlan) {
    let Some(setup) = &plan.reach else { return };
    println!(
        "reach for {} ({} model points{}{}):",
        setup.arm,
        setup.model_points,
        if setup.floor { ", floor" } else { "" },
        setup.prefer.map_or(String::new(), |b| format!("; the shot's configuration {b} preferred"))
    );
    for t in &plan.targets {
        let Some(r) = &t.reach else { continue };
        if !r.reachable {
            println!("  target {}: NOT REACHABLE, left out of the programs: {}", t.surface.spec, r.reason);
            continue;
        }
        let m = r.margins.as_ref();
        let clearance = r.clearance.map_or("nothing near".to_string(), |c| {
            format!("{:.1} mm ({} to the {})", c.distance_m * 1e3, c.link.name(), c.against.name())
        });
        println!(
            "  target {}: reachable, {}, spin {:.0} deg; margins: limits {:.1} deg, wrist {:.2}, elbow {:.2}, shoulder {:.0} mm; clearance {clearance}",
            t.surface.spec,
            r.branch.map_or(String::new(), |b| b.to_string()),
            r.spin_rad.to_degrees(),
            m.map_or(f64::NAN, |m| m.limit_rad.to_degrees()),
            m.map_or(f64::NAN, |m| m.wrist),
            m.map_or(f64::NAN, |m| m.elbow),
            m.map_or(f64::NAN, |m| m.shoulder_m * 1e3),
        );
    }
}
