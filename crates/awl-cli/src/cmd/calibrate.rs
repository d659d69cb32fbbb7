//! `awl calibrate hand-eye`: the eye-in-hand camera's `T_ee_camera` from robot poses and target
//! observations (`awl-handeye/1` poses file, documented in `awl::handeye`), from a capture folder of
//! tag images (`--capture`, `awl::handeye::capture`), or a simulated poses file.

use std::path::{Path, PathBuf};

use anyhow::Context;
use awl::handeye::poses_file::{read_poses, write_poses};
use awl::handeye::{
    CaptureCalibration, CaptureParams, HandEyeMethod, HandEyeParams, HandEyeResult, calibrate, calibrate_capture,
};
use awl::io::capture::read_capture;
use awl::io::outputs::OutputCheck;
use awl::sim::calibration::{CalibrationSimParams, simulate_calibration};
use awl::transform::rows_from_isometry;
use serde_json::json;

use super::common::{lock_outputs, write_json};

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
    #[arg(long, required_unless_present_any = ["write_simulated", "capture"], conflicts_with = "capture")]
    pub poses: Option<PathBuf>,
    /// Capture folder (awl-scan/1): color images (PNG or JPEG; depth optional) of the tag named in its
    /// scan.json, held fixed in the scene, each view with its T_base_ee. The tag is detected and posed per view.
    #[arg(long)]
    pub capture: Option<PathBuf>,
    /// Closed-form solver that starts the refinement.
    #[arg(long, value_enum, default_value = "park")]
    pub method: MethodArg,
    /// Skip the nonlinear refinement (report the closed form; with --capture, no corner bias either).
    #[arg(long)]
    pub no_refine: bool,
    /// With --capture: take the tag detections as they are, without estimating the detector's
    /// corner bias from the views' spread of depths.
    #[arg(long, requires = "capture")]
    pub no_corner_bias: bool,
    /// With --capture: weigh every view alike (rotation by --rotation-weight-m) instead of by its
    /// covariance (the tag pose's from its corners, and the arm's).
    #[arg(long, requires = "capture")]
    pub no_view_weights: bool,
    /// With --capture: the detected tag corners' noise per image axis, pixels (the views' weights and
    /// the predicted bound).
    #[arg(long, requires = "capture", default_value_t = CaptureParams::default().corner_sigma_px)]
    pub corner_sigma_px: f64,
    /// With --capture: the recorded flange pose's translation noise per axis, mm (the arm's repeatability).
    #[arg(long, requires = "capture", default_value_t = CaptureParams::default().arm_sigma_mm)]
    pub arm_sigma_mm: f64,
    /// With --capture: the recorded flange pose's rotation noise per axis, degrees.
    #[arg(long, requires = "capture", default_value_t = CaptureParams::default().arm_sigma_deg)]
    pub arm_sigma_deg: f64,
    /// Output JSON: T_ee_camera, T_base_target, method, per-pose residuals, rejected poses, warnings.
    #[arg(short, long, required_unless_present = "write_simulated")]
    pub output: Option<PathBuf>,
    /// Print the output JSON on stdout instead of a summary.
    #[arg(long)]
    pub json: bool,
    /// Instead of calibrating, write a simulated poses file (noise 0.5 mm / 0.1 deg on the target, 0.1 mm / 0.02 deg on the arm).
    #[arg(long, conflicts_with_all = ["poses", "output", "capture"])]
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
    /// Rejection thresholds and diagnosis limits.
    /// Replace earlier output files (the same flag in every command).
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub tuning: HandEyeTuning,
}

/// The settings of `awl::handeye::HandEyeParams` on the command line (defaults: the library's).
#[derive(clap::Args)]
pub struct HandEyeTuning {
    /// A pose is an outlier above this many times the median residual (and the floors).
    #[arg(long, default_value_t = HandEyeParams::default().outlier_factor)]
    pub outlier_factor: f64,
    /// Translation residuals below this never make an outlier, mm.
    #[arg(long, default_value_t = HandEyeParams::default().outlier_floor_mm)]
    pub outlier_floor_mm: f64,
    /// Rotation residuals below this never make an outlier, degrees.
    #[arg(long, default_value_t = HandEyeParams::default().outlier_floor_deg)]
    pub outlier_floor_deg: f64,
    /// At most this fraction of the poses is rejected (0 to 1).
    #[arg(long, default_value_t = HandEyeParams::default().max_rejected_fraction)]
    pub max_rejected_fraction: f64,
    /// Pairs rotating less than this do not count toward the motion diversity, degrees.
    #[arg(long, default_value_t = HandEyeParams::default().min_pair_angle_deg)]
    pub min_pair_angle_deg: f64,
    /// Warn when the pairs' rotation axes span less than this, degrees.
    #[arg(long, default_value_t = HandEyeParams::default().min_axis_angle_deg)]
    pub min_axis_angle_deg: f64,
    /// Refuse when the pairs' rotation axes span less than this, degrees.
    #[arg(long, default_value_t = HandEyeParams::default().degenerate_axis_angle_deg)]
    pub degenerate_axis_angle_deg: f64,
    /// Weight of rotation residuals in the refinement, metres per radian.
    #[arg(long, default_value_t = HandEyeParams::default().rotation_weight_m)]
    pub rotation_weight_m: f64,
    /// Refinement iteration cap.
    #[arg(long, default_value_t = HandEyeParams::default().max_iterations)]
    pub max_iterations: usize,
    /// The error of T_ee_camera's translation you can accept, mm: warn when its predicted 95 % bound
    /// exceeds this.
    #[arg(long, default_value_t = HandEyeParams::default().tolerance_mm)]
    pub tolerance_mm: f64,
    /// Warn when the 1-sigma of the target scale (tag size) exceeds this, percent.
    #[arg(long, default_value_t = HandEyeParams::default().max_scale_sigma_percent)]
    pub max_scale_sigma_percent: f64,
    /// Warn when the fitted target scale differs from 1 by more than this (and 3 sigma), percent.
    #[arg(long, default_value_t = HandEyeParams::default().scale_mismatch_percent)]
    pub scale_mismatch_percent: f64,
    /// The residual noise the 1-sigmas assume at least, mm.
    #[arg(long, default_value_t = HandEyeParams::default().min_noise_mm)]
    pub min_noise_mm: f64,
    /// Refuse when the poses fit this many times better with T_base_ee or T_camera_target inverted.
    #[arg(long, default_value_t = HandEyeParams::default().inverted_fit_factor)]
    pub inverted_fit_factor: f64,
    /// Accept poses that look inverted (a warning instead of the refusal).
    #[arg(long)]
    pub allow_inverted_fit: bool,
    /// The most poses (views found) a calibration takes (beyond 447 the closed forms use a bounded
    /// set of 100 000 pose pairs: memory and time grow linearly with the count).
    #[arg(long, default_value_t = HandEyeParams::default().max_poses)]
    pub max_poses: usize,
}

impl HandEyeTuning {
    /// The library's parameters with these settings; an error naming the flag out of range.
    fn params(&self, method: HandEyeMethod, refine: bool) -> anyhow::Result<HandEyeParams> {
        let params = HandEyeParams {
            method,
            refine,
            rotation_weight_m: self.rotation_weight_m,
            max_iterations: self.max_iterations,
            outlier_factor: self.outlier_factor,
            outlier_floor_mm: self.outlier_floor_mm,
            outlier_floor_deg: self.outlier_floor_deg,
            max_rejected_fraction: self.max_rejected_fraction,
            min_pair_angle_deg: self.min_pair_angle_deg,
            min_axis_angle_deg: self.min_axis_angle_deg,
            degenerate_axis_angle_deg: self.degenerate_axis_angle_deg,
            tolerance_mm: self.tolerance_mm,
            max_scale_sigma_percent: self.max_scale_sigma_percent,
            scale_mismatch_percent: self.scale_mismatch_percent,
            min_noise_mm: self.min_noise_mm,
            inverted_fit_factor: self.inverted_fit_factor,
            allow_inverted_fit: self.allow_inverted_fit,
            max_poses: self.max_poses,
        };
        match params.validate() {
            Ok(()) => Ok(params),
            Err(awl::Error::Invalid { what, message }) => anyhow::bail!("--{}: {message}", what.replace('_', "-")),
            Err(e) => Err(e.into()),
        }
    }
}

/// Runs `awl calibrate`.
pub fn run(args: &CalibrateArgs) -> anyhow::Result<()> {
    match &args.command {
        CalibrateCommand::HandEye(a) => hand_eye(a),
    }
}

fn write_simulated(args: &HandEyeArgs, path: &Path) -> anyhow::Result<()> {
    let mut check = OutputCheck::new(args.force);
    check.output_file(path, "--write-simulated");
    if let Some(truth) = &args.truth {
        check.output_file(truth, "--truth");
    }
    let _outputs = lock_outputs(&check)?;
    let params = CalibrationSimParams { count: args.count, seed: args.seed, ..CalibrationSimParams::default() };
    let capture = simulate_calibration(&params)?;
    write_poses(path, &capture.poses)?;
    if let Some(truth) = &args.truth {
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
        "T_ee_camera_refined": rows_from_isometry(&result.refined_ee_from_camera),
        "T_base_target": rows_from_isometry(&result.base_from_target),
        "method": result.method.name(),
        "refined": params.refine,
        "poses": result.residuals.len(),
        "rejected": result.rejected,
        "rms_translation_mm": result.rms_translation_mm,
        "rms_rotation_deg": result.rms_rotation_deg,
        "rms_all_translation_mm": result.rms_all_translation_mm,
        "rms_all_rotation_deg": result.rms_all_rotation_deg,
        "uncertainty": result.uncertainty,
        "inversion_fits": result.inversion_fits,
        "residuals": result.residuals,
        "diversity": result.diversity,
        "refinement": result.refinement,
        "refinement_check": result.refinement_check,
        "warnings": result.warnings,
        "params": params,
    })
}

fn hand_eye(args: &HandEyeArgs) -> anyhow::Result<()> {
    if let Some(path) = &args.write_simulated {
        return write_simulated(args, path);
    }
    if let Some(dir) = &args.capture {
        return hand_eye_capture(args, dir);
    }
    let (Some(poses_path), Some(output)) = (&args.poses, &args.output) else {
        anyhow::bail!("--poses and --output are required");
    };
    let params = handeye_params(args)?;
    let method = params.method;
    let _outputs =
        lock_outputs(OutputCheck::new(args.force).input_file(poses_path, "--poses").output_file(output, "-o"))?;
    let poses = read_poses(poses_path)?;
    let result =
        calibrate(&poses, &params).with_context(|| format!("{}: hand-eye calibration failed", poses_path.display()))?;
    let value = result_json(&result, &params);
    write_json(output, &value)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&value)?);
        return Ok(());
    }
    let t = result.ee_from_camera.translation.vector * 1e3;
    let u = &result.uncertainty;
    println!(
        "hand-eye ({}): T_ee_camera t = [{:.2}, {:.2}, {:.2}] mm, rotation {:.3} deg; {} of {} poses used, \
         residual RMS {:.3} mm / {:.4} deg (inliers), {:.3} mm / {:.4} deg (all poses); rejected {:?}; wrote {}",
        method.name(),
        t.x,
        t.y,
        t.z,
        result.ee_from_camera.rotation.angle().to_degrees(),
        poses.len() - result.rejected.len(),
        poses.len(),
        result.rms_translation_mm,
        result.rms_rotation_deg,
        result.rms_all_translation_mm,
        result.rms_all_rotation_deg,
        result.rejected,
        output.display()
    );
    let (s, r) = (u.translation_sigma_mm, u.rotation_sigma_deg);
    println!(
        "1-sigma: translation [{:.2}, {:.2}, {:.2}] mm (flange axes; 95 % bound {:.2} mm), rotation [{:.3}, {:.3}, \
         {:.3}] deg (camera axes), target scale {:.2} % (fitted {:.4})",
        s[0], s[1], s[2], u.translation_bound_95_mm, r[0], r[1], r[2], u.scale_sigma_percent, u.fitted_scale
    );
    if let Some(c) = &result.refinement_check {
        println!(
            "refined vs {} closed form: {:.2} mm / {:.3} deg (limit {:.2} mm / {:.3} deg; closed forms' spread {:.2} \
             mm / {:.3} deg); result: {}",
            method.name(),
            c.shift_mm,
            c.shift_deg,
            c.limit_mm,
            c.limit_deg,
            c.closed_form_spread_mm,
            c.closed_form_spread_deg,
            if c.kept_refined { "refined" } else { "closed form" }
        );
    }
    for w in &result.warnings {
        eprintln!("warning: {w}");
    }
    Ok(())
}

/// The solver's settings from the arguments.
/// The solver settings of the command line (method, refinement, the thresholds), checked.
fn handeye_params(args: &HandEyeArgs) -> anyhow::Result<HandEyeParams> {
    let method = match args.method {
        MethodArg::Park => HandEyeMethod::Park,
        MethodArg::Tsai => HandEyeMethod::Tsai,
        MethodArg::Daniilidis => HandEyeMethod::Daniilidis,
    };
    args.tuning.params(method, !args.no_refine)
}

/// The per-view part of the `--capture` output.
fn capture_json(dir: &Path, capture: &CaptureCalibration, params: &CaptureParams) -> serde_json::Value {
    let views: Vec<serde_json::Value> = capture
        .views
        .iter()
        .map(|v| {
            let mut value = serde_json::to_value(v).unwrap_or_default();
            value["T_camera_tag"] = json!(v.camera_from_tag.as_ref().map(rows_from_isometry));
            value["inlier"] = json!(v.residual.map(|r| r.inlier));
            value
        })
        .collect();
    json!({
        "dir": dir,
        "views": views,
        "views_found": capture.poses.len(),
        "thorough_search": capture.thorough_search,
        "corner_bias_px": capture.corner_bias_px,
        "corner_bias_note": capture.corner_bias_note,
        "bound": capture.bound,
        "view_weights": params.view_weights,
        "detector": params.detector,
        "max_rmse_px": params.max_rmse_px,
        "min_side_px": params.min_side_px,
    })
}

fn hand_eye_capture(args: &HandEyeArgs, dir: &Path) -> anyhow::Result<()> {
    let Some(output) = &args.output else { anyhow::bail!("--output is required") };
    let capture = read_capture(dir)?;
    let mut check = OutputCheck::new(args.force);
    // (the result may go beside the images, as a calibration's record: the folder itself is not refused)
    check.input_file(&capture.manifest_path(), "the capture's scan.json");
    for v in &capture.views {
        check.input_file(&capture.dir.join(&v.color), "a color image the capture names");
        if let Some(d) = &v.depth {
            check.input_file(&capture.dir.join(d), "a depth image the capture names");
        }
    }
    let _outputs = lock_outputs(check.output_file(output, "-o"))?;
    let params = CaptureParams {
        handeye: handeye_params(args)?,
        corner_bias: !(args.no_corner_bias || args.no_refine),
        view_weights: !args.no_view_weights,
        corner_sigma_px: args.corner_sigma_px,
        arm_sigma_mm: args.arm_sigma_mm,
        arm_sigma_deg: args.arm_sigma_deg,
        ..CaptureParams::default()
    };
    let calibration = calibrate_capture(&capture, &params)
        .with_context(|| format!("{}: hand-eye calibration from the capture failed", dir.display()))?;
    let result = &calibration.result;
    let mut value = result_json(result, &params.handeye);
    value["capture"] = capture_json(dir, &calibration, &params);
    write_json(output, &value)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&value)?);
        return Ok(());
    }
    for v in &calibration.views {
        match (&v.why_not, v.residual) {
            (Some(why), _) => println!("view {:3}: tag not used: {why}", v.index),
            (None, Some(r)) => println!(
                "view {:3}: solution {} ({}), {:.3} px; residual {:.3} mm / {:.4} deg{}",
                v.index,
                v.solution.unwrap_or(1),
                v.chosen_by.map_or("", |c| match c {
                    awl::handeye::FlipChoice::Unambiguous => "unambiguous",
                    awl::handeye::FlipChoice::Depth => "by depth",
                    awl::handeye::FlipChoice::Consistency => "by consistency",
                }),
                v.rmse_px.unwrap_or(f64::NAN),
                r.translation_mm,
                r.rotation_deg,
                if r.inlier { "" } else { "  REJECTED" }
            ),
            (None, None) => println!("view {:3}: found", v.index),
        }
    }
    match calibration.corner_bias_px {
        Some(b) => println!(
            "the detector's corners lay {:.3} px {} the tag's: its translations corrected for it",
            b.abs(),
            if b >= 0.0 { "inside" } else { "outside" }
        ),
        None => println!("corner bias {}", calibration.corner_bias_note),
    }
    let t = result.ee_from_camera.translation.vector * 1e3;
    println!(
        "hand-eye ({}) from {} of {} views: T_ee_camera t = [{:.2}, {:.2}, {:.2}] mm, rotation {:.3} deg; {} poses \
         used, residual RMS {:.3} mm / {:.4} deg; rejected views {:?}; wrote {}",
        params.handeye.method.name(),
        calibration.poses.len(),
        capture.views.len(),
        t.x,
        t.y,
        t.z,
        result.ee_from_camera.rotation.angle().to_degrees(),
        calibration.poses.len() - result.rejected.len(),
        result.rms_translation_mm,
        result.rms_rotation_deg,
        result
            .rejected
            .iter()
            .filter_map(|&k| calibration.views.iter().find(|v| v.pose == Some(k)).map(|v| v.index))
            .collect::<Vec<_>>(),
        output.display()
    );
    match &calibration.bound {
        Some(b) => println!(
            "predicted error (95 %): {:.2} mm / {:.3} deg (RMS {:.2} mm / {:.3} deg; per axis {:.2}, {:.2}, {:.2} mm \
             and {:.3}, {:.3}, {:.3} deg), from {} views {}, corners {} px, arm {} mm / {} deg a view; residuals \
             {:.2}x the assumed noise{}",
            b.translation_mm,
            b.rotation_deg,
            b.translation_rms_mm,
            b.rotation_rms_deg,
            b.translation_sigma_mm[0],
            b.translation_sigma_mm[1],
            b.translation_sigma_mm[2],
            b.rotation_sigma_deg[0],
            b.rotation_sigma_deg[1],
            b.rotation_sigma_deg[2],
            b.views,
            if b.weighted { "weighted by their covariance" } else { "weighted alike" },
            b.corner_sigma_px,
            b.arm_sigma_mm,
            b.arm_sigma_deg,
            b.normalized_cost.sqrt(),
            if b.noise_scale > 1.0 { " (the bound widened by as much)" } else { "" }
        ),
        None => println!("predicted error: none without the refinement"),
    }
    for w in &result.warnings {
        eprintln!("warning: {w} (poses are the views found, in order)");
    }
    Ok(())
}
