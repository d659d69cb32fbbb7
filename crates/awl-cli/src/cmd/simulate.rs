//! `awl simulate`: render a synthetic scan folder (or a piercing-time shot, or a hand-eye
//! calibration capture) with ground truth.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use awl::io::outputs::OutputCheck;
use awl::sim::capture::{CaptureParams, simulate_capture};
use awl::sim::{NoiseLevel, SceneKind, ShotPose, SimParams, write_simulation};
use awl::transform::pose_difference;

/// The workpiece to simulate.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum SceneArg {
    /// 48.5 x 48 x 30 cm box, tag on a side.
    Box,
    /// 50 x 40 x 35 cm free-form dome shell with a groove over the top.
    Shell,
    /// Cylinder, radius 15 cm, height 70 cm.
    Cylinder,
    /// Sphere, radius 20 cm, resting on the floor.
    Sphere,
}

/// Noise level of depth, color and poses.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum NoiseArg {
    /// Exact depth (1 mm steps) and exact poses.
    None,
    /// Half the realistic noise.
    Low,
    /// RealSense D435 on a mobile manipulator with LiDAR SLAM.
    Realistic,
    /// Twice the realistic noise.
    Harsh,
}

/// Piercing-time pose of the workpiece.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum ShotArg {
    /// Flat on the floor.
    Flat,
    /// Tilted 30 degrees on a support.
    Tilt30,
}

/// Arguments of `awl simulate`.
#[derive(clap::Args)]
pub struct SimulateArgs {
    /// Workpiece.
    #[arg(long, value_enum, default_value = "box")]
    pub scene: SceneArg,
    /// Number of views (default 12; 2 in shot mode, at most 3 there; 20 in capture mode).
    #[arg(long)]
    pub views: Option<usize>,
    /// Random seed: the same seed gives the same scan, bit for bit.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Noise level.
    #[arg(long, value_enum, default_value = "realistic")]
    pub noise: NoiseArg,
    /// Simulate a piercing-time shot (world = robot base) instead of a scan.
    #[arg(long, value_enum)]
    pub shot: Option<ShotArg>,
    /// Simulate a hand-eye calibration capture instead of a scan: color and depth views of a tag on a
    /// board held fixed in front of the arm base (world = robot base), each with its noisy T_base_ee;
    /// scan.json's T_ee_camera carries the rig's calibration error, truth.json the true one.
    #[arg(long, conflicts_with_all = ["scene", "shot"])]
    pub capture: bool,
    /// tag36h11 id on the capture's board, 0 to 9 (default 7; capture mode only).
    #[arg(long, requires = "capture")]
    pub tag_id: Option<u32>,
    /// Black-border edge of the capture's tag, metres, 0.02 to 0.3 (default 0.14; capture mode only).
    #[arg(long, requires = "capture")]
    pub tag_size: Option<f64>,
    /// Seed of the camera (intrinsics, global depth-scale error): give a shot the seed of the scan
    /// taken with the same camera. Default: --seed.
    #[arg(long)]
    pub camera_seed: Option<u64>,
    /// The workpiece alone on the floor: no clutter boxes, no wall (scan mode only). With the
    /// cylinder, nothing then constrains the views' spin about its axis.
    #[arg(long, conflicts_with_all = ["shot", "capture"])]
    pub bare: bool,
    /// A fixed arm (scan mode only): every view from one base pose, the camera moved around the
    /// workpiece on the base's side (200 degrees of azimuth, 15 to 60 degrees of elevation).
    #[arg(long, conflicts_with_all = ["shot", "capture"])]
    pub fixed_base: bool,
    /// A shot's extra views: the flange poses of a views.json (`awl plan-views -o`), each taken after the
    /// shot's own views with the arm's noise (shot mode only).
    #[arg(long, requires = "shot")]
    pub extra_views: Option<PathBuf>,
    /// Output scan folder (must not exist or be empty, unless --force).
    #[arg(short = 'o', long = "output")]
    pub output: PathBuf,
    /// Replace an earlier simulation's output folder (the same flag in every command).
    #[arg(long)]
    pub force: bool,
}

fn noise(arg: NoiseArg) -> NoiseLevel {
    match arg {
        NoiseArg::None => NoiseLevel::None,
        NoiseArg::Low => NoiseLevel::Low,
        NoiseArg::Realistic => NoiseLevel::Realistic,
        NoiseArg::Harsh => NoiseLevel::Harsh,
    }
}

fn params(args: &SimulateArgs) -> SimParams {
    let scene = match args.scene {
        SceneArg::Box => SceneKind::Box,
        SceneArg::Shell => SceneKind::Shell,
        SceneArg::Cylinder => SceneKind::Cylinder,
        SceneArg::Sphere => SceneKind::Sphere,
    };
    let noise = noise(args.noise);
    let shot = args.shot.map(|s| match s {
        ShotArg::Flat => ShotPose::Flat,
        ShotArg::Tilt30 => ShotPose::Tilt30,
    });
    let views = args.views.unwrap_or(if shot.is_some() { 2 } else { 12 });
    SimParams {
        scene,
        views,
        seed: args.seed,
        noise,
        shot,
        camera_seed: args.camera_seed,
        bare: args.bare,
        fixed_base: args.fixed_base,
    }
}

fn capture_params(args: &SimulateArgs) -> CaptureParams {
    let default = CaptureParams::default();
    CaptureParams {
        views: args.views.unwrap_or(default.views),
        seed: args.seed,
        noise: noise(args.noise),
        tag_id: args.tag_id.unwrap_or(default.tag_id),
        tag_size_m: args.tag_size.unwrap_or(default.tag_size_m),
        camera_seed: args.camera_seed,
        ..default
    }
}

fn run_capture(args: &SimulateArgs) -> anyhow::Result<()> {
    let start = Instant::now();
    let params = capture_params(args);
    let sim = simulate_capture(&params).context("capture simulation failed")?;
    write_simulation(&args.output, &sim, args.force)
        .with_context(|| format!("cannot write the capture folder {}", args.output.display()))?;
    let (error_m, error_rad) = match (sim.truth.ee_from_camera, sim.scan.ee_from_camera) {
        (Some(truth), Some(recorded)) => pose_difference(&truth, &recorded),
        _ => (f64::NAN, f64::NAN),
    };
    println!(
        "simulated calibration capture: {} views of tag36h11 id {} ({} m), seed {}, noise {}; scan.json's T_ee_camera is {:.2} mm / {:.3} deg off the true one in truth.json -> {} ({:.1} s)",
        sim.views.len(),
        params.tag_id,
        params.tag_size_m,
        params.seed,
        params.noise.name(),
        error_m * 1e3,
        error_rad.to_degrees(),
        args.output.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

/// The entries `awl simulate` writes in its output folder (`--force` replaces a folder holding only these).
pub const SIMULATE_OUTPUTS: &[&str] = &["scan.json", "truth.json", "cad.ply", "depth", "color", "labels"];

/// Runs `awl simulate`.
pub fn run(args: &SimulateArgs) -> anyhow::Result<()> {
    // held until the folder is in place: no other run writes it meanwhile
    let _outputs =
        super::common::lock_outputs(OutputCheck::new(args.force).output_folder(&args.output, "-o", SIMULATE_OUTPUTS))?;
    if args.capture {
        return run_capture(args);
    }
    let start = Instant::now();
    let params = params(args);
    let extra = match &args.extra_views {
        Some(path) => awl::plan_views::file::read_view_poses(path).context("--extra-views")?,
        None => Vec::new(),
    };
    let sim = awl::sim::simulate_with_views(&params, &extra).context("simulation failed")?;
    write_simulation(&args.output, &sim, args.force)
        .with_context(|| format!("cannot write the scan folder {}", args.output.display()))?;
    let kind = match params.shot {
        Some(pose) => format!("{} shot ({})", params.scene.name(), pose.name()),
        None => format!("{} scan", params.scene.name()),
    };
    println!(
        "simulated {kind}: {} views, {} depth points, seed {}, noise {} -> {} ({:.1} s)",
        sim.views.len(),
        sim.depth_points(),
        params.seed,
        params.noise.name(),
        args.output.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
