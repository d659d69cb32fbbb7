//! `awl tags IMAGE...`: the tags in PNG / JPEG images (id, corners, hamming, decision margin) and,
//! given the camera and the tag size, both pose solutions: the first thing to run on a new camera.

use std::path::PathBuf;

use anyhow::Context;
use awl::camera::Intrinsics;
use awl::io::capture::read_camera_file;
use awl::io::image::read_color_image;
use awl::tag::SUPPORTED_FAMILY;
use awl::tag::{AprilTagDetector, DetectorParams, PosedTag, TagPoseSolution, detect_and_pose};
use awl::transform::rows_from_isometry;
use serde_json::json;

/// Arguments of `awl tags`.
#[derive(clap::Args)]
pub struct TagsArgs {
    /// Color images (PNG or JPEG, told apart by their first bytes).
    #[arg(required = true)]
    pub images: Vec<PathBuf>,
    /// Take the camera intrinsics (and, without --size, the tag size) from this scan.json or scan folder.
    #[arg(long, conflicts_with = "intrinsics")]
    pub scan: Option<PathBuf>,
    /// Camera intrinsics file: {"width","height","fx","fy","cx","cy","distortion"?} (pixels; distortion [k1,k2,p1,p2,k3]).
    #[arg(long)]
    pub intrinsics: Option<PathBuf>,
    /// Tag family (only tag36h11 is decoded).
    #[arg(long, default_value = SUPPORTED_FAMILY)]
    pub family: String,
    /// Tag black-border edge length, metres (default with --scan: its tag's size). With intrinsics, poses are printed.
    #[arg(long)]
    pub size: Option<f64>,
    /// Detector: search quads on the image decimated by this factor (1 to 8).
    #[arg(long, default_value_t = DetectorParams::default().quad_decimate)]
    pub decimate: f32,
    /// Detector: Gaussian blur before the quad search, pixels (0 = none).
    #[arg(long, default_value_t = DetectorParams::default().quad_sigma)]
    pub sigma: f32,
    /// Detector: do not snap quad edges to the full-resolution gradients.
    #[arg(long)]
    pub no_refine_edges: bool,
    /// Detector: sharpening of the decoded bit samples (0 to 2).
    #[arg(long, default_value_t = DetectorParams::default().decode_sharpening)]
    pub sharpening: f64,
    /// Detector: most bit errors corrected (0 to 3; 2 and 3 build large decode tables).
    #[arg(long, default_value_t = DetectorParams::default().max_hamming)]
    pub max_hamming: u32,
    /// Detector: worker threads of the C detector (results do not depend on it).
    #[arg(long, default_value_t = DetectorParams::default().threads)]
    pub threads: u8,
    /// Detector: neighbourhoods spanning fewer gray levels are not segmented (the C library's is 5).
    #[arg(long, default_value_t = DetectorParams::default().min_white_black_diff)]
    pub min_contrast: u8,
    /// Print one JSON document instead of text.
    #[arg(long)]
    pub json: bool,
}

fn solution_json(s: &TagPoseSolution) -> serde_json::Value {
    json!({ "T_camera_tag": rows_from_isometry(&s.camera_from_tag), "rmse_px": s.rmse_px })
}

fn tag_json(t: &PosedTag) -> serde_json::Value {
    let d = &t.detection;
    let mut value = json!({
        "id": d.id,
        "hamming": d.hamming,
        "decision_margin": d.decision_margin,
        "corners_px": d.corners_px,
        "centre_px": d.centre_px,
    });
    if let Some(pose) = &t.pose {
        let mut solutions = vec![solution_json(&pose.best)];
        solutions.extend(pose.second.as_ref().map(solution_json));
        value["poses"] = json!(solutions);
        value["ambiguity"] = json!(pose.ambiguity());
    }
    if let Some(e) = &t.pose_error {
        value["pose_error"] = json!(e);
    }
    value
}

fn solution_text(label: &str, s: &TagPoseSolution) -> String {
    let t = s.camera_from_tag.translation.vector;
    let z = s.camera_from_tag.rotation * nalgebra::Vector3::z();
    format!(
        "{label}: t = [{:.4}, {:.4}, {:.4}] m, tag z = [{:.3}, {:.3}, {:.3}], reprojection {:.3} px",
        t.x, t.y, t.z, z.x, z.y, z.z, s.rmse_px
    )
}

/// The camera and the tag size from the arguments, when both are known.
fn camera(args: &TagsArgs) -> anyhow::Result<(Option<Intrinsics>, Option<f64>)> {
    if let Some(size) = args.size {
        anyhow::ensure!(size.is_finite() && size > 0.0, "--size must be a positive length in metres, got {size}");
    }
    if let Some(scan) = &args.scan {
        let (k, tag) = read_camera_file(scan)?;
        return Ok((Some(k), args.size.or(tag.map(|t| t.size_m))));
    }
    if let Some(path) = &args.intrinsics {
        return Ok((Some(read_camera_file(path)?.0), args.size));
    }
    anyhow::ensure!(args.size.is_none(), "--size needs the camera: give --scan scan.json or --intrinsics K.json");
    Ok((None, None))
}

/// Runs `awl tags`.
pub fn run(args: &TagsArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.family == SUPPORTED_FAMILY,
        "--family {}: not supported (only {SUPPORTED_FAMILY} is decoded)",
        args.family
    );
    let params = DetectorParams {
        quad_decimate: args.decimate,
        quad_sigma: args.sigma,
        refine_edges: !args.no_refine_edges,
        decode_sharpening: args.sharpening,
        max_hamming: args.max_hamming,
        threads: args.threads,
        min_white_black_diff: args.min_contrast,
    };
    let mut detector = AprilTagDetector::new(&params).context("detector settings")?;
    let (intrinsics, size) = camera(args)?;
    let pose_camera = intrinsics.as_ref().zip(size);
    let mut images = Vec::new();
    for path in &args.images {
        let image = read_color_image(path)?;
        let tags = detect_and_pose(&mut detector, &image, pose_camera)
            .with_context(|| format!("{}: tag detection failed", path.display()))?;
        if args.json {
            images.push(json!({
                "path": path,
                "width": image.width,
                "height": image.height,
                "tags": tags.iter().map(tag_json).collect::<Vec<_>>(),
            }));
            continue;
        }
        println!("{}: {}x{}, {} tag(s)", path.display(), image.width, image.height, tags.len());
        for t in &tags {
            let d = &t.detection;
            let corners: Vec<String> = d.corners_px.iter().map(|[u, v]| format!("({u:.2}, {v:.2})")).collect();
            println!(
                "  id {}: hamming {}, decision margin {:.1}, corners {} px",
                d.id,
                d.hamming,
                d.decision_margin,
                corners.join(" ")
            );
            if let Some(pose) = &t.pose {
                println!("    {}", solution_text("pose 1", &pose.best));
                match &pose.second {
                    Some(s) => println!(
                        "    {} (ambiguity {:.2})",
                        solution_text("pose 2", s),
                        pose.ambiguity().unwrap_or(1.0)
                    ),
                    None => println!("    (a single solution: not ambiguous)"),
                }
            }
            if let Some(e) = &t.pose_error {
                println!("    no pose: {e}");
            }
        }
    }
    if args.json {
        let doc = json!({
            "format": "awl-tags/1",
            "family": args.family,
            "detector": params,
            "intrinsics": intrinsics,
            "tag_size_m": size,
            "pixel_convention": "integer = pixel centre",
            "pose_frame": "T_camera_tag, awl tag frame: x right, y up, z out of the face",
            "images": images,
        });
        println!("{}", serde_json::to_string_pretty(&doc)?);
    } else if pose_camera.is_none() {
        println!("(no poses: give --scan or --intrinsics, and --size, to pose the tags)");
    }
    Ok(())
}
