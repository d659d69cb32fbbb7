//! `awl calibrate hand-eye`: the eye-in-hand camera's `T_ee_camera` from robot poses and target
//! observations (`awl-handeye/1` poses file, documented in `awl::handeye`), or a simulated poses file.

use std::path::{Path, PathBuf};

use anyhow::Context;
use awl::handeye::{HandEyeMethod, HandEyeParams, HandEyeResult, calibrate};
use awl::io::handeye::{read_poses, write_poses};
use awl::sim::calibration::{CalibrationSimParams, simulate_calibration};
use awl::transform::rows_from_isometry;
use serde_json::json;

use super::common::{refuse_overwriting_inputs, write_json};

/// Arguments of `awl calibrate`.
#[derive(clap::Args)]
pub struct CalibrateArgs {
    /// Which calibration.
    #[command(subcommand)]
    pub command: CalibrateCommand,
}

/// The calibrations.
#[derive(clap::Subcommand)]
pub enum CalibrateCommand {
    /// Hand-eye (eye-in-hand): solve AX = XB for T_ee_camera from T_base_ee + T_camera_target pairs.
    HandEye(HandEyeArgs),
}

/// The closed-form solver.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum MethodArg {
    /// Park & Martin (1994).
    Park,
    /// Tsai & Lenz (1989).
    Tsai,
    /// Daniilidis (1999), dual quaternions.
    Daniilidis,
}

/// Arguments of `awl calibrate hand-eye`.
#[derive(clap::Args)]
pub struct HandEyeArgs {
    /// Poses file: {"format":"awl-handeye/1","poses":[{"T_base_ee":4x4,"T_camera_target":4x4},...]}.
    #[arg(long, required_unless_present = "write_simulated")]
    pub poses: Option<PathBuf>,
    /// Closed-form solver that starts the refinement.
    #[arg(long, value_enum, default_value = "park")]
    pub method: MethodArg,
    /// Skip the nonlinear refinement (report the closed form).
    #[arg(long)]
    pub no_refine: bool,
    /// Output JSON: T_ee_camera, T_base_target, method, per-pose residuals, rejected poses, warnings.
    #[arg(short, long, required_unless_present = "write_simulated")]
    pub output: Option<PathBuf>,
    /// Print the output JSON on stdout instead of a summary.
    #[arg(long)]
    pub json: bool,
    /// Instead of calibrating, write a simulated poses file (noise 0.5 mm / 0.1 deg on the target, 0.1 mm / 0.02 deg on the arm).
    #[arg(long, conflicts_with_all = ["poses", "output"])]
    pub write_simulated: Option<PathBuf>,
    /// Simulated poses: how many.
    #[arg(long, default_value_t = 15, requires = "write_simulated")]
    pub count: usize,
    /// Simulated poses: random seed.
    #[arg(long, default_value_t = 1, requires = "write_simulated")]
    pub seed: u64,
    /// Simulated poses: also write the true T_ee_camera and T_base_target here.
    #[arg(long, requires = "write_simulated")]
    pub truth: Option<PathBuf>,
}

/// Runs `awl calibrate`.
pub fn run(args: &CalibrateArgs) -> anyhow::Result<()> {
    match &args.command {
        CalibrateCommand::HandEye(a) => hand_eye(a),
    }
}

fn write_simulated(args: &HandEyeArgs, path: &Path) -> anyhow::Result<()> {
    let params = CalibrationSimParams { count: args.count, seed: args.seed, ..CalibrationSimParams::default() };
    let capture = simulate_calibration(&params)?;
    write_poses(path, &capture.poses)?;
    if let Some(truth) = &args.truth {
        anyhow::ensure!(truth != path, "{}: --truth must differ from --write-simulated", truth.display());
        let value = json!({
            "T_ee_camera": rows_from_isometry(&capture.ee_from_camera),
            "T_base_target": rows_from_isometry(&capture.base_from_target),
            "count": params.count, "seed": params.seed,
            "camera_noise_mm": params.camera_noise_mm, "camera_noise_deg": params.camera_noise_deg,
            "arm_noise_mm": params.arm_noise_mm, "arm_noise_deg": params.arm_noise_deg,
        });
        write_json(truth, &value)?;
    }
    println!("wrote {} simulated poses (seed {}) to {}", params.count, params.seed, path.display());
    Ok(())
}

fn result_json(result: &HandEyeResult, params: &HandEyeParams) -> serde_json::Value {
    json!({
        "format": "awl-handeye-result/1",
        "T_ee_camera": rows_from_isometry(&result.ee_from_camera),
        "T_ee_camera_closed_form": rows_from_isometry(&result.closed_form_ee_from_camera),
        "T_base_target": rows_from_isometry(&result.base_from_target),
        "method": result.method.name(),
        "refined": params.refine,
        "poses": result.residuals.len(),
        "rejected": result.rejected,
        "rms_translation_mm": result.rms_translation_mm,
        "rms_rotation_deg": result.rms_rotation_deg,
        "residuals": result.residuals,
        "diversity": result.diversity,
        "refinement": result.refinement,
        "warnings": result.warnings,
        "params": params,
    })
}

fn hand_eye(args: &HandEyeArgs) -> anyhow::Result<()> {
    if let Some(path) = &args.write_simulated {
        return write_simulated(args, path);
    }
    let (Some(poses_path), Some(output)) = (&args.poses, &args.output) else {
        anyhow::bail!("--poses and --output are required");
    };
    refuse_overwriting_inputs(output, &[poses_path])?;
    let poses = read_poses(poses_path)?;
    let method = match args.method {
        MethodArg::Park => HandEyeMethod::Park,
        MethodArg::Tsai => HandEyeMethod::Tsai,
        MethodArg::Daniilidis => HandEyeMethod::Daniilidis,
    };
    let params = HandEyeParams { method, refine: !args.no_refine, ..HandEyeParams::default() };
    let result =
        calibrate(&poses, &params).with_context(|| format!("{}: hand-eye calibration failed", poses_path.display()))?;
    let value = result_json(&result, &params);
    write_json(output, &value)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&value)?);
        return Ok(());
    }
    let t = result.ee_from_camera.translation.vector * 1e3;
    println!(
        "hand-eye ({}): T_ee_camera t = [{:.2}, {:.2}, {:.2}] mm, rotation {:.3} deg; {} of {} poses used, \
         residual RMS {:.3} mm / {:.4} deg; rejected {:?}; wrote {}",
        method.name(),
        t.x,
        t.y,
        t.z,
        result.ee_from_camera.rotation.angle().to_degrees(),
        poses.len() - result.rejected.len(),
        poses.len(),
        result.rms_translation_mm,
        result.rms_rotation_deg,
        result.rejected,
        output.display()
    );
    for w in &result.warnings {
        eprintln!("warning: {w}");
    }
    Ok(())
}
