//! `awl import rosbag BAG -o SCAN_DIR`: a rosbag2 recording (MCAP or sqlite3) of the rig as an
//! `awl-scan/1` folder (or, with `--capture`, a hand-eye calibration capture). The method is
//! `awl::rosbag::import_rosbag`; this file holds the arguments, the progress bar and the printing.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use awl::rosbag::still::StillParams;
use awl::rosbag::{ImportParams, ImportProgress, import_rosbag};
use awl::scan::TagSpec;

use crate::cmd::common::{lock_outputs, stage_bar};

/// Arguments of `awl import`.
#[derive(clap::Args)]
pub struct ImportArgs {
    /// What to import.
    #[command(subcommand)]
    pub source: ImportSource,
}

/// The importers.
#[derive(clap::Subcommand)]
pub enum ImportSource {
    /// A ROS 2 recording (rosbag2 folder with metadata.yaml, or a bare .mcap / .db3 file): depth
    /// (sensor_msgs/Image 16UC1 mm or 32FC1 m, or compressedDepth PNG), color (rgb8 / bgr8, or
    /// CompressedImage JPEG / PNG), CameraInfo and TF; one view per still period of the base and the
    /// arm, poses T_world_base and T_base_ee from TF at the image stamp, T_ee_camera from TF.
    Rosbag(RosbagArgs),
}

/// Arguments of `awl import rosbag`.
#[derive(clap::Args)]
pub struct RosbagArgs {
    /// The bag: a rosbag2 folder or a .mcap / .db3 file.
    pub bag: PathBuf,
    /// Output scan folder (written atomically; must not exist or be empty, unless --force).
    #[arg(short = 'o', long = "output")]
    pub output: PathBuf,
    /// The depth topic (default: the one depth image topic of the bag).
    #[arg(long)]
    pub depth_topic: Option<String>,
    /// The color topic, registered to the depth image (default: the one color image topic, if any).
    #[arg(long)]
    pub color_topic: Option<String>,
    /// The camera-info topic of the depth image (default: the one CameraInfo topic, or the one beside the depth topic).
    #[arg(long)]
    pub camera_info_topic: Option<String>,
    /// The SLAM map frame.
    #[arg(long, default_value = "map")]
    pub world_frame: String,
    /// The arm's base frame.
    #[arg(long, default_value = "base_link")]
    pub base_frame: String,
    /// The flange frame.
    #[arg(long, default_value = "tool0")]
    pub ee_frame: String,
    /// The camera's optical frame (default: the depth image's frame_id).
    #[arg(long)]
    pub camera_frame: Option<String>,
    /// Shortest still period, seconds: the base and the flange slower than --still-speed-mm-s and
    /// --still-rate-deg-s for at least this long give one view.
    #[arg(long, default_value_t = 0.5)]
    pub still_s: f64,
    /// Largest speed of the base or the flange that counts as still, mm/s.
    #[arg(long, default_value_t = 5.0)]
    pub still_speed_mm_s: f64,
    /// Largest rotation rate of the base or the flange that counts as still, deg/s.
    #[arg(long, default_value_t = 0.5)]
    pub still_rate_deg_s: f64,
    /// Largest time between a view's depth and color images, milliseconds.
    #[arg(long, default_value_t = 25.0)]
    pub sync_ms: f64,
    /// Largest interval between two TF samples that is interpolated, seconds (a longer one is a TF gap).
    #[arg(long, default_value_t = 0.5)]
    pub tf_max_gap_s: f64,
    /// The tag on the workpiece, written into scan.json: family:id:size (size in metres), e.g. tag36h11:0:0.08.
    #[arg(long)]
    pub tag: Option<String>,
    /// Nearest depth return kept, metres (scan.json camera.depth_min).
    #[arg(long, default_value_t = 0.1)]
    pub depth_min: f64,
    /// Farthest depth return kept, metres (scan.json camera.depth_max).
    #[arg(long, default_value_t = 10.0)]
    pub depth_max: f64,
    /// Write a hand-eye calibration capture for `awl calibrate hand-eye --capture` instead of a scan
    /// (color views with T_base_ee, world = robot base; needs --tag and a color topic).
    #[arg(long)]
    pub capture: bool,
    /// Replace a non-empty output folder.
    #[arg(long)]
    pub force: bool,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

/// `family:id:size` as a tag.
fn parse_tag(text: &str) -> anyhow::Result<TagSpec> {
    let parts: Vec<&str> = text.split(':').collect();
    let [family, id, size] = parts.as_slice() else {
        anyhow::bail!("--tag {text}: expected family:id:size, e.g. tag36h11:0:0.08 (size in metres)");
    };
    let id: u32 = id.parse().with_context(|| format!("--tag {text}: the id `{id}` is not a whole number"))?;
    let size_m: f64 = size.parse().with_context(|| format!("--tag {text}: the size `{size}` is not a number"))?;
    anyhow::ensure!(family == &"tag36h11", "--tag {text}: only the tag36h11 family is detected");
    anyhow::ensure!(
        size_m.is_finite() && size_m > 0.0 && size_m < 2.0,
        "--tag {text}: the size must be in metres, between 0 and 2"
    );
    Ok(TagSpec { family: (*family).to_string(), id, size_m })
}

fn positive(flag: &str, value: f64) -> anyhow::Result<f64> {
    anyhow::ensure!(value.is_finite() && value > 0.0, "{flag} {value}: must be a positive number");
    Ok(value)
}

/// Runs `awl import`.
pub fn run(args: &ImportArgs) -> anyhow::Result<()> {
    let ImportSource::Rosbag(args) = &args.source;
    let tag = args.tag.as_deref().map(parse_tag).transpose()?;
    anyhow::ensure!(
        !args.capture || tag.is_some(),
        "--capture needs --tag family:id:size (the tag the capture looks at)"
    );
    anyhow::ensure!(
        args.depth_min >= 0.0 && args.depth_max > args.depth_min,
        "--depth-min {} --depth-max {}: an empty depth range",
        args.depth_min,
        args.depth_max
    );
    let bag_canonical = std::fs::canonicalize(&args.bag).ok();
    if let Some(bag) = &bag_canonical {
        let out = std::fs::canonicalize(&args.output).ok();
        anyhow::ensure!(
            out.as_ref().is_none_or(|o| !bag.starts_with(o)),
            "{}: refusing to write over the bag (the output folder holds it)",
            args.output.display()
        );
    }
    // the output folder locked until it is in place: a second import into it is refused naming this one
    let _outputs = lock_outputs(awl::io::outputs::OutputCheck::new(args.force).locked_folder(&args.output, "-o"))?;
    let params = ImportParams {
        depth_topic: args.depth_topic.clone(),
        color_topic: args.color_topic.clone(),
        camera_info_topic: args.camera_info_topic.clone(),
        world_frame: args.world_frame.clone(),
        base_frame: args.base_frame.clone(),
        ee_frame: args.ee_frame.clone(),
        camera_frame: args.camera_frame.clone(),
        still: StillParams {
            min_still_s: positive("--still-s", args.still_s)?,
            max_speed_m_s: positive("--still-speed-mm-s", args.still_speed_mm_s)? * 1e-3,
            max_rate_rad_s: positive("--still-rate-deg-s", args.still_rate_deg_s)?.to_radians(),
            sync_s: positive("--sync-ms", args.sync_ms)? * 1e-3,
        },
        tag,
        depth_min_m: args.depth_min,
        depth_max_m: args.depth_max,
        tf_max_gap_s: positive("--tf-max-gap-s", args.tf_max_gap_s)?,
        capture: args.capture,
        overwrite: args.force,
    };
    let start = Instant::now();
    let bar = stage_bar(args.quiet);
    let mut progress = |p: ImportProgress| {
        bar.set_length(p.total.max(1));
        bar.set_position(p.done.min(p.total));
        bar.set_message(if p.pass == 1 { "reading the bag (TF, stamps)" } else { "writing the views" });
    };
    let report = import_rosbag(&args.bag, &args.output, &params, &mut progress);
    bar.finish_and_clear();
    let report = report?;
    for warning in &report.warnings {
        eprintln!("warning: {warning}");
    }
    let skipped: Vec<String> = report.depth_skipped.iter().map(|(r, n)| format!("{n} {}", r.describe())).collect();
    let stops = report.views.iter().map(|v| v.base_stop).max().map_or(0, |s| s + 1);
    println!(
        "imported {} {} views ({} base stops) from {} depth images on {}{} -> {} ({:.1} s)",
        report.views.len(),
        report.kind,
        stops,
        report.depth_images,
        report.depth_topic,
        report
            .color_topic
            .as_ref()
            .map(|c| format!(" and {} color images on {c}", report.color_images))
            .unwrap_or_default(),
        args.output.display(),
        start.elapsed().as_secs_f64()
    );
    if !skipped.is_empty() {
        println!("depth images not used: {}", skipped.join("; "));
    }
    println!("report: {}", args.output.join("import.json").display());
    Ok(())
}
