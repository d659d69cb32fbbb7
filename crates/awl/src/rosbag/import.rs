//! `awl import rosbag`: a rosbag2 recording of the rig -> an `awl-scan/1` folder (or a hand-eye
//! capture folder), in two passes over the bag.
//!
//! 1. Every message: the topics and their types, `/tf` and `/tf_static` into a [`TfBuffer`], the
//!    first `CameraInfo` of each camera-info topic, and each image's header stamp. The depth,
//!    color and camera-info topics are chosen (by type when one candidate, else by the flags), the
//!    rig's pose looked up at each depth stamp, and the still periods found ([`find_views`]).
//! 2. The depth and color topics again: the chosen frames decoded and written into a temporary
//!    folder beside the output, with `scan.json` and the report `import.json`; the folder is then
//!    renamed into place. Nothing is written when anything fails.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use nalgebra::Isometry3;
use serde::Serialize;
use serde_json::{Map, Value};

use crate::camera::{DepthCamera, Intrinsics};
use crate::error::{Error, Result};
use crate::image::{ColorImage, DepthImage};
use crate::io::image::{
    ColorFileKind, color_file_kind, read_color_image, read_depth_png, write_color_png, write_depth_png,
};
use crate::io::scan::write_scan;
use crate::io::{write_atomic, write_folder_atomically};
use crate::rosbag::cdr::{self, CameraInfo};
use crate::rosbag::still::{FramePose, SkipReason, StillParams, find_views};
use crate::rosbag::tf::{LookupError, TfBuffer};
use crate::rosbag::{Bag, BagMessage};
use crate::scan::{Scan, TagSpec, ViewData, ViewPose, ViewSpec};
use crate::transform::pose_difference;

const IMAGE: &str = "sensor_msgs/msg/Image";
const COMPRESSED: &str = "sensor_msgs/msg/CompressedImage";
const CAMERA_INFO: &str = "sensor_msgs/msg/CameraInfo";
const TF_MESSAGE: &str = "tf2_msgs/msg/TFMessage";
/// Depth encodings of `sensor_msgs/Image` read (`mono16` is how some drivers label 16UC1).
const DEPTH_ENCODINGS: [&str; 3] = ["16UC1", "mono16", "32FC1"];
/// Color encodings of `sensor_msgs/Image` read.
const COLOR_ENCODINGS: [&str; 5] = ["rgb8", "bgr8", "rgba8", "bgra8", "mono8"];

/// What to import and how.
#[derive(Debug, Clone, PartialEq)]
pub struct ImportParams {
    /// The depth topic (`--depth-topic`); found by type when `None` and there is one candidate.
    pub depth_topic: Option<String>,
    /// The color topic (`--color-topic`); found by type when `None` (none is fine for a scan).
    pub color_topic: Option<String>,
    /// The camera-info topic (`--camera-info-topic`); found by type, or beside the depth topic.
    pub camera_info_topic: Option<String>,
    /// The SLAM map frame (`--world-frame`, default `map`).
    pub world_frame: String,
    /// The arm's base frame (`--base-frame`, default `base_link`).
    pub base_frame: String,
    /// The flange frame (`--ee-frame`, default `tool0`).
    pub ee_frame: String,
    /// The camera's optical frame (`--camera-frame`); the depth image's `frame_id` when `None`.
    pub camera_frame: Option<String>,
    /// Still-period rules.
    pub still: StillParams,
    /// The tag on the workpiece, written into `scan.json` (`--tag family:id:size`).
    pub tag: Option<TagSpec>,
    /// Depth returns kept, metres (`camera.depth_min` / `depth_max` in `scan.json`).
    pub depth_min_m: f64,
    /// See `depth_min_m`; infinity for no limit.
    pub depth_max_m: f64,
    /// Largest interval between two TF samples of a link that is interpolated, seconds.
    pub tf_max_gap_s: f64,
    /// Write a hand-eye calibration capture (world = robot base, `T_ee_camera` optional) instead of a scan.
    pub capture: bool,
    /// Replace a non-empty output folder.
    pub overwrite: bool,
}

impl Default for ImportParams {
    fn default() -> Self {
        Self {
            depth_topic: None,
            color_topic: None,
            camera_info_topic: None,
            world_frame: "map".into(),
            base_frame: "base_link".into(),
            ee_frame: "tool0".into(),
            camera_frame: None,
            still: StillParams::default(),
            tag: None,
            depth_min_m: 0.1,
            depth_max_m: 10.0,
            tf_max_gap_s: 0.5,
            capture: false,
            overwrite: false,
        }
    }
}

/// Where an import is: `pass` 1 (reading everything) or 2 (writing the views), `done` of `total`
/// in [`Bag::progress_total`]'s units.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ImportProgress {
    /// 1 or 2.
    pub pass: u8,
    /// Position in the pass.
    pub done: u64,
    /// The pass's length.
    pub total: u64,
}

/// A topic of the bag: its type and message count.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct TopicSummary {
    /// The topic.
    pub topic: String,
    /// Its message type.
    #[serde(rename = "type")]
    pub type_name: String,
    /// Its messages in the bag.
    pub messages: u64,
}

/// One imported view.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ViewReport {
    /// The depth image's stamp, seconds since the epoch.
    pub stamp_s: f64,
    /// The color image's stamp minus the depth image's, milliseconds.
    pub color_offset_ms: Option<f64>,
    /// The base stop.
    pub base_stop: u32,
    /// The still period it was taken in, seconds since the epoch (first and last frame).
    pub still_period_s: [f64; 2],
}

/// What an import did (`import.json` in the output folder).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ImportReport {
    /// The bag as given.
    pub bag: PathBuf,
    /// Its files and their storage.
    pub files: Vec<(PathBuf, &'static str)>,
    /// `scan` or `capture`.
    pub kind: &'static str,
    /// Every topic of the bag.
    pub topics: Vec<TopicSummary>,
    /// The depth topic read.
    pub depth_topic: String,
    /// The color topic read, if any.
    pub color_topic: Option<String>,
    /// The camera-info topic read.
    pub camera_info_topic: String,
    /// The frames: world, base, ee, camera.
    pub frames: [String; 4],
    /// Depth images in the bag.
    pub depth_images: usize,
    /// Color images in the bag.
    pub color_images: usize,
    /// Views written.
    pub views: Vec<ViewReport>,
    /// Depth images not used, by reason.
    pub depth_skipped: BTreeMap<SkipReason, usize>,
    /// Color images not used (all but the views' own).
    pub color_skipped: usize,
    /// Warnings (also worth printing).
    pub warnings: Vec<String>,
}

/// A depth or color image seen in pass 1.
#[derive(Debug, Clone, Copy)]
struct Seen {
    /// Its position among its topic's messages.
    ordinal: usize,
    stamp_ns: i64,
}

#[derive(Default)]
struct TopicSeen {
    type_name: String,
    messages: u64,
    /// Image topics: each message's stamp.
    images: Vec<Seen>,
    /// Image topics: the first message's frame and encoding (or compressed format).
    first: Option<(String, String)>,
    camera_info: Option<CameraInfo>,
}

/// `sensor_msgs/Image` for `sensor_msgs/msg/Image` and `sensor_msgs/msg/Image` alike.
fn normalise_type(t: &str) -> String {
    match t.split('/').collect::<Vec<_>>().as_slice() {
        [package, name] => format!("{package}/msg/{name}"),
        _ => t.to_string(),
    }
}

fn bad_message(bag: &Bag, topic: &str, ordinal: usize, e: &str) -> Error {
    Error::format(&bag.path, format!("topic {topic}: message {ordinal}: {e}"))
}

/// Pass 1: every topic's summary, image stamps, first camera info, and the TF buffer.
fn survey(
    bag: &Bag,
    params: &ImportParams,
    progress: &mut dyn FnMut(ImportProgress),
) -> Result<(BTreeMap<String, TopicSeen>, TfBuffer, Vec<String>)> {
    let total = bag.progress_total()?;
    let mut topics: BTreeMap<String, TopicSeen> = BTreeMap::new();
    let mut tf = TfBuffer::new(params.tf_max_gap_s);
    let mut warnings = Vec::new();
    let mut report = |done| progress(ImportProgress { pass: 1, done, total });
    bag.for_each(&|_| true, &mut report, &mut |m: &BagMessage<'_>| {
        let seen = topics.entry(m.topic.to_string()).or_default();
        if seen.type_name.is_empty() {
            seen.type_name = normalise_type(m.type_name);
        }
        let ordinal = seen.messages as usize;
        seen.messages += 1;
        match seen.type_name.as_str() {
            IMAGE | COMPRESSED => {
                let (header, format) = if seen.type_name == IMAGE {
                    let image = cdr::decode_image(m.data).map_err(|e| bad_message(bag, m.topic, ordinal, &e))?;
                    (image.header, image.encoding)
                } else {
                    let image =
                        cdr::decode_compressed_image(m.data).map_err(|e| bad_message(bag, m.topic, ordinal, &e))?;
                    (image.header, image.format)
                };
                seen.images.push(Seen { ordinal, stamp_ns: header.stamp_ns });
                if seen.first.is_none() {
                    seen.first = Some((header.frame_id, format));
                }
            }
            CAMERA_INFO if seen.camera_info.is_none() => {
                seen.camera_info =
                    Some(cdr::decode_camera_info(m.data).map_err(|e| bad_message(bag, m.topic, ordinal, &e))?);
            }
            TF_MESSAGE => {
                let fixed = m.topic.ends_with("tf_static");
                for t in cdr::decode_tf_message(m.data).map_err(|e| bad_message(bag, m.topic, ordinal, &e))? {
                    let pose = t.parent_from_child().map_err(|e| bad_message(bag, m.topic, ordinal, &e))?;
                    if let Some(other) = tf.add(&t.header.frame_id, &t.child_frame_id, t.header.stamp_ns, pose, fixed)
                        && warnings.len() < 10
                    {
                        warnings.push(format!(
                            "TF: `{}` has a second parent `{other}` on {} (kept its first, `{}`)",
                            t.child_frame_id, m.topic, t.header.frame_id
                        ));
                    }
                }
            }
            _ => {}
        }
        Ok(())
    })?;
    tf.finish();
    Ok((topics, tf, warnings))
}

fn topic_list(topics: &BTreeMap<String, TopicSeen>) -> String {
    topics.iter().map(|(t, s)| format!("{t} ({}, {} messages)", s.type_name, s.messages)).collect::<Vec<_>>().join(", ")
}

fn is_depth_topic(seen: &TopicSeen) -> bool {
    match (&seen.first, seen.type_name.as_str()) {
        (Some((_, enc)), IMAGE) => DEPTH_ENCODINGS.contains(&enc.as_str()),
        (Some((_, format)), COMPRESSED) => format.contains("compressedDepth"),
        _ => false,
    }
}

fn is_color_topic(seen: &TopicSeen) -> bool {
    matches!(seen.type_name.as_str(), IMAGE | COMPRESSED) && seen.first.is_some() && !is_depth_topic(seen)
}

/// The topic `given`, checked to be in the bag and of one of `types`; or the one candidate.
/// What a topic choice is for: its name in errors, its flag, the types it takes, who qualifies,
/// and whether the bag must have one.
struct TopicRule<'a> {
    what: &'a str,
    flag: &'a str,
    types: &'a str,
    candidate: &'a dyn Fn(&TopicSeen) -> bool,
    required: bool,
}

fn choose_topic(
    bag: &Bag,
    topics: &BTreeMap<String, TopicSeen>,
    given: Option<&str>,
    rule: &TopicRule<'_>,
) -> Result<Option<String>> {
    let TopicRule { what, flag, types, candidate, required } = *rule;
    let bag_name = bag.path.display().to_string();
    if let Some(topic) = given {
        let Some(seen) = topics.get(topic) else {
            return Err(Error::invalid(
                bag_name,
                format!("{flag} {topic}: no such topic in the bag; its topics: {}", topic_list(topics)),
            ));
        };
        if !candidate(seen) {
            return Err(Error::invalid(
                bag_name,
                format!("{flag} {topic}: a {} topic, not a {what} topic ({types})", seen.type_name),
            ));
        }
        return Ok(Some(topic.to_string()));
    }
    let candidates: Vec<&String> = topics.iter().filter(|(_, s)| candidate(s)).map(|(t, _)| t).collect();
    match candidates.as_slice() {
        [one] => Ok(Some((*one).clone())),
        [] if !required => Ok(None),
        [] => Err(Error::invalid(
            bag_name,
            format!("no {what} topic ({types}) in the bag; its topics: {}", topic_list(topics)),
        )),
        many => Err(Error::invalid(
            bag_name,
            format!(
                "{} {what} topics: {}; choose one with {flag}",
                many.len(),
                many.iter().map(|t| t.as_str()).collect::<Vec<_>>().join(", ")
            ),
        )),
    }
}

/// The camera's intrinsics from a `CameraInfo`: `K`, and `D` for `plumb_bob` (any other model with
/// non-zero coefficients is refused by name).
fn intrinsics_from_info(bag: &Bag, topic: &str, info: &CameraInfo) -> Result<Intrinsics> {
    let bad = |m: String| Error::invalid(format!("{}: topic {topic}", bag.path.display()), m);
    let model = info.distortion_model.as_str();
    let mut distortion = [0.0; 5];
    match model {
        "plumb_bob" | "" if info.d.len() <= 5 => distortion[..info.d.len()].copy_from_slice(&info.d),
        _ if info.d.iter().all(|d| *d == 0.0) => {}
        _ => {
            return Err(bad(format!(
                "distortion model `{model}` ({} coefficients) is not supported: awl reads `plumb_bob` (k1, k2, t1, t2, k3); \
                 record the rectified image (e.g. image_rect_raw) or calibrate with plumb_bob",
                info.d.len()
            )));
        }
    }
    let k = info.k;
    let intrinsics =
        Intrinsics { width: info.width, height: info.height, fx: k[0], fy: k[4], cx: k[2], cy: k[5], distortion };
    let finite = k.iter().chain(&distortion).all(|v| v.is_finite());
    if !finite || intrinsics.fx <= 0.0 || intrinsics.fy <= 0.0 || info.width == 0 || info.height == 0 {
        return Err(bad(format!("K {k:?} ({}x{}) is not a pinhole camera (no calibration?)", info.width, info.height)));
    }
    Ok(intrinsics)
}

/// A depth `Image` in millimetres: `16UC1` / `mono16` as given, `32FC1` metres rounded to mm
/// (NaN, infinities, zero or negative and beyond 65.535 m become 0, no return).
fn depth_from_image(image: &cdr::Image<'_>) -> std::result::Result<DepthImage, String> {
    let (w, h) = (image.width as usize, image.height as usize);
    let bytes_per_pixel = if image.encoding == "32FC1" { 4 } else { 2 };
    let step = image.step as usize;
    if step < w * bytes_per_pixel || image.data.len() < step * h.saturating_sub(1) + w * bytes_per_pixel {
        return Err(format!(
            "{}x{} {} image with step {} has only {} bytes",
            w,
            h,
            image.encoding,
            step,
            image.data.len()
        ));
    }
    let mut data = Vec::with_capacity(w * h);
    for row in image.data.chunks(step).take(h) {
        for px in row[..w * bytes_per_pixel].chunks_exact(bytes_per_pixel) {
            let value = if bytes_per_pixel == 2 {
                let b = [px[0], px[1]];
                if image.big_endian { u16::from_be_bytes(b) } else { u16::from_le_bytes(b) }
            } else {
                let b = [px[0], px[1], px[2], px[3]];
                let m = f64::from(if image.big_endian { f32::from_be_bytes(b) } else { f32::from_le_bytes(b) });
                if m.is_finite() && m > 0.0 && m * 1000.0 <= 65535.0 { (m * 1000.0).round() as u16 } else { 0 }
            };
            data.push(value);
        }
    }
    Ok(DepthImage { width: image.width, height: image.height, data })
}

/// A color `Image` as RGB.
fn color_from_image(image: &cdr::Image<'_>) -> std::result::Result<ColorImage, String> {
    let (w, h) = (image.width as usize, image.height as usize);
    let channels = match image.encoding.as_str() {
        "rgb8" | "bgr8" => 3,
        "rgba8" | "bgra8" => 4,
        "mono8" => 1,
        other => return Err(unsupported_color(other)),
    };
    let step = image.step as usize;
    if step < w * channels || image.data.len() < step * h.saturating_sub(1) + w * channels {
        return Err(format!(
            "{}x{} {} image with step {} has only {} bytes",
            w,
            h,
            image.encoding,
            step,
            image.data.len()
        ));
    }
    let bgr = image.encoding.starts_with("bgr");
    let mut data = Vec::with_capacity(w * h);
    for row in image.data.chunks(step).take(h) {
        for px in row[..w * channels].chunks_exact(channels) {
            data.push(match (channels, bgr) {
                (1, _) => [px[0]; 3],
                (_, true) => [px[2], px[1], px[0]],
                _ => [px[0], px[1], px[2]],
            });
        }
    }
    Ok(ColorImage { width: image.width, height: image.height, data })
}

fn unsupported_color(encoding: &str) -> String {
    format!(
        "unsupported color encoding `{encoding}` (awl reads sensor_msgs/Image in {}, or sensor_msgs/CompressedImage JPEG / PNG)",
        COLOR_ENCODINGS.join(", ")
    )
}

/// The rig's pose at each depth stamp, or why a frame has none (outside the TF recording); a gap or
/// a missing link is an error naming the two frames and the time.
fn frame_poses(
    bag: &Bag,
    tf: &TfBuffer,
    params: &ImportParams,
    depth_topic: &str,
    stamps: &[i64],
) -> Result<Vec<Option<FramePose>>> {
    let lookup = |target: &str, source: &str, t: i64| -> Result<Option<Isometry3<f64>>> {
        match tf.lookup(target, source, t) {
            Ok(pose) => Ok(Some(pose)),
            Err(LookupError::Outside { .. }) => Ok(None),
            Err(e) => Err(Error::invalid(
                format!("{}: TF", bag.path.display()),
                format!(
                    "no transform `{target}` -> `{source}` at {:.3} s (the depth image of {depth_topic} there): {e}",
                    t as f64 * 1e-9
                ),
            )),
        }
    };
    stamps
        .iter()
        .map(|&t| {
            let world_from_base = if params.capture {
                Some(Isometry3::identity())
            } else {
                lookup(&params.world_frame, &params.base_frame, t)?
            };
            let base_from_ee = lookup(&params.base_frame, &params.ee_frame, t)?;
            Ok(world_from_base.zip(base_from_ee).map(|(world_from_base, base_from_ee)| FramePose {
                stamp_ns: t,
                world_from_base,
                base_from_ee,
            }))
        })
        .collect()
}

/// A view chosen in pass 1, to be written in pass 2.
struct Planned {
    depth_ordinal: usize,
    color_ordinal: Option<usize>,
    stamp_ns: i64,
    pose: FramePose,
    report: ViewReport,
}

/// Imports the bag at `bag_path` into the folder `out` (see the module docs): returns the report,
/// also written as `out/import.json`.
///
/// # Errors
/// [`Error::Io`] / [`Error::Format`] naming the file for an unreadable, truncated or damaged bag or
/// message (with the topic); [`Error::Invalid`] naming the bag for a missing or ambiguous topic
/// (the topics listed), an unsupported encoding or distortion model, a TF gap or missing link
/// (the two frames and the time), no still period, or a non-empty `out` without `overwrite`.
/// Nothing is written on error.
pub fn import_rosbag(
    bag_path: &Path,
    out: &Path,
    params: &ImportParams,
    progress: &mut dyn FnMut(ImportProgress),
) -> Result<ImportReport> {
    let bag = Bag::open(bag_path)?;
    if !params.overwrite && crate::io::is_non_empty_dir(out)? {
        return Err(Error::invalid(
            out.display().to_string(),
            "the output folder exists and is not empty (pass --force to replace it)",
        ));
    }
    let bag_name = bag.path.display().to_string();
    let (topics, tf, mut warnings) = survey(&bag, params, progress)?;
    let depth_types = "sensor_msgs/Image 16UC1 or 32FC1, or CompressedImage compressedDepth";
    let depth_topic = choose_topic(
        &bag,
        &topics,
        params.depth_topic.as_deref(),
        &TopicRule {
            what: "depth",
            flag: "--depth-topic",
            types: depth_types,
            candidate: &is_depth_topic,
            required: true,
        },
    )?
    .unwrap_or_default();
    let color_types = "sensor_msgs/Image or CompressedImage";
    let color_topic = choose_topic(
        &bag,
        &topics,
        params.color_topic.as_deref(),
        &TopicRule {
            what: "color",
            flag: "--color-topic",
            types: color_types,
            candidate: &is_color_topic,
            required: params.capture,
        },
    )?;
    let info_given = params.camera_info_topic.clone().or_else(|| {
        // beside the depth topic (`/camera/depth/image_rect_raw` -> `/camera/depth/camera_info`) when there
        let beside = format!("{}/camera_info", depth_topic.rsplit_once('/').map_or("", |(ns, _)| ns));
        (topics.iter().filter(|(_, s)| s.type_name == CAMERA_INFO).count() > 1 && topics.contains_key(&beside))
            .then_some(beside)
    });
    let info_topic = choose_topic(
        &bag,
        &topics,
        info_given.as_deref(),
        &TopicRule {
            what: "camera-info",
            flag: "--camera-info-topic",
            types: "sensor_msgs/CameraInfo",
            candidate: &|s: &TopicSeen| s.type_name == CAMERA_INFO,
            required: true,
        },
    )?
    .unwrap_or_default();
    let depth = &topics[&depth_topic];
    let (depth_frame, depth_format) = depth.first.clone().unwrap_or_default();
    if depth.type_name == COMPRESSED && !depth_format.starts_with("16UC1") && !depth_format.starts_with("mono16") {
        return Err(Error::invalid(
            &bag_name,
            format!(
                "topic {depth_topic}: compressedDepth format `{depth_format}` is not supported (awl reads `16UC1; compressedDepth png`)"
            ),
        ));
    }
    if let Some(color) = &color_topic {
        let seen = &topics[color];
        let format = seen.first.as_ref().map_or("", |f| f.1.as_str());
        if seen.type_name == IMAGE && !COLOR_ENCODINGS.contains(&format) {
            return Err(Error::invalid(&bag_name, format!("topic {color}: {}", unsupported_color(format))));
        }
        if seen.type_name == COMPRESSED
            && !["jpeg", "jpg", "png"].iter().any(|k| format.to_ascii_lowercase().contains(k))
        {
            return Err(Error::invalid(
                &bag_name,
                format!("topic {color}: compressed format `{format}` is not supported (JPEG or PNG)"),
            ));
        }
    }
    let info = topics[&info_topic]
        .camera_info
        .clone()
        .ok_or_else(|| Error::invalid(&bag_name, format!("topic {info_topic}: no message")))?;
    let intrinsics = intrinsics_from_info(&bag, &info_topic, &info)?;
    let camera_frame = params.camera_frame.clone().unwrap_or(depth_frame);

    // the rig's pose at every depth frame, the still periods and their views
    let mut depth_frames = depth.images.clone();
    depth_frames.sort_by_key(|s| (s.stamp_ns, s.ordinal));
    let stamps: Vec<i64> = depth_frames.iter().map(|s| s.stamp_ns).collect();
    let poses = frame_poses(&bag, &tf, params, &depth_topic, &stamps)?;
    let posed: Vec<usize> = (0..poses.len()).filter(|&i| poses[i].is_some()).collect();
    let frames: Vec<FramePose> = posed.iter().filter_map(|&i| poses[i]).collect();
    let mut colors: Vec<Seen> = color_topic.as_ref().map(|c| topics[c].images.clone()).unwrap_or_default();
    colors.sort_by_key(|s| (s.stamp_ns, s.ordinal));
    let color_ns: Vec<i64> = colors.iter().map(|s| s.stamp_ns).collect();
    let (views, reasons) = find_views(&frames, color_topic.as_ref().map(|_| color_ns.as_slice()), &params.still);
    let mut depth_skipped: BTreeMap<SkipReason, usize> = BTreeMap::new();
    for reason in reasons.iter().flatten() {
        *depth_skipped.entry(*reason).or_default() += 1;
    }
    if poses.len() > frames.len() {
        depth_skipped.insert(SkipReason::OutsideTf, poses.len() - frames.len());
    }
    if views.is_empty() {
        let counts: Vec<String> = depth_skipped.iter().map(|(r, n)| format!("{n} {}", r.describe())).collect();
        return Err(Error::invalid(
            &bag_name,
            format!(
                "no still period: the base (`{}` -> `{}`) and the flange (`{}` -> `{}`) were never still (under {} mm/s and {:.2} deg/s) \
                 for --still-s {} s{} ({} depth images on {depth_topic}: {})",
                params.world_frame,
                params.base_frame,
                params.base_frame,
                params.ee_frame,
                params.still.max_speed_m_s * 1e3,
                params.still.max_rate_rad_s.to_degrees(),
                params.still.min_still_s,
                if color_topic.is_some() {
                    format!(" with a color image within --sync-ms {}", params.still.sync_s * 1e3)
                } else {
                    String::new()
                },
                stamps.len(),
                if counts.is_empty() { "none posed".into() } else { counts.join(", ") }
            ),
        ));
    }
    let planned: Vec<Planned> = views
        .iter()
        .map(|v| {
            let frame = depth_frames[posed[v.frame]];
            let color = v.color.map(|c| colors[c]);
            Planned {
                depth_ordinal: frame.ordinal,
                color_ordinal: color.map(|c| c.ordinal),
                stamp_ns: frame.stamp_ns,
                pose: frames[v.frame],
                report: ViewReport {
                    stamp_s: frame.stamp_ns as f64 * 1e-9,
                    color_offset_ms: color.map(|c| (c.stamp_ns - frame.stamp_ns) as f64 * 1e-6),
                    base_stop: v.base_stop,
                    still_period_s: [
                        frames[v.period.0].stamp_ns as f64 * 1e-9,
                        frames[v.period.1].stamp_ns as f64 * 1e-9,
                    ],
                },
            }
        })
        .collect();

    // the hand-eye from TF (static, or at each view: it should not change)
    let ee_from_camera = match tf.lookup(&params.ee_frame, &camera_frame, planned[0].stamp_ns) {
        Ok(pose) => Some(pose),
        Err(_) if params.capture => None,
        Err(e) => {
            return Err(Error::invalid(
                format!("{bag_name}: TF"),
                format!(
                    "no hand-eye transform `{}` -> `{camera_frame}` at {:.3} s (the first view): {e}; record it on /tf_static or give --camera-frame",
                    params.ee_frame,
                    planned[0].stamp_ns as f64 * 1e-9
                ),
            ));
        }
    };
    if let Some(x) = ee_from_camera {
        let worst = planned
            .iter()
            .filter_map(|p| tf.lookup(&params.ee_frame, &camera_frame, p.stamp_ns).ok())
            .map(|y| pose_difference(&x, &y))
            .fold((0.0_f64, 0.0_f64), |a, b| (a.0.max(b.0), a.1.max(b.1)));
        if worst.0 > 1e-6 || worst.1 > 1e-6 {
            warnings.push(format!(
                "the hand-eye `{}` -> `{camera_frame}` changes between views (up to {:.3} mm, {:.4} deg): the first view's is written",
                params.ee_frame,
                worst.0 * 1e3,
                worst.1.to_degrees()
            ));
        }
    }
    let camera = DepthCamera {
        intrinsics,
        depth_scale: 0.001,
        depth_min_m: params.depth_min_m,
        depth_max_m: params.depth_max_m,
    };
    let report = ImportReport {
        bag: bag.path.clone(),
        files: bag.files.iter().map(|(p, s)| (p.clone(), s.name())).collect(),
        kind: if params.capture { "capture" } else { "scan" },
        topics: topics
            .iter()
            .map(|(t, s)| TopicSummary { topic: t.clone(), type_name: s.type_name.clone(), messages: s.messages })
            .collect(),
        depth_topic: depth_topic.clone(),
        color_topic: color_topic.clone(),
        camera_info_topic: info_topic,
        frames: [params.world_frame.clone(), params.base_frame.clone(), params.ee_frame.clone(), camera_frame],
        depth_images: depth.images.len(),
        color_images: colors.len(),
        views: planned.iter().map(|p| p.report.clone()).collect(),
        depth_skipped,
        color_skipped: colors.len() - planned.iter().filter(|p| p.color_ordinal.is_some()).count(),
        warnings,
    };
    let total = bag.progress_total()?;
    write_folder_atomically(out, params.overwrite, |tmp| {
        write_views(&bag, tmp, &planned, &depth_topic, color_topic.as_deref(), &camera, &mut |done| {
            progress(ImportProgress { pass: 2, done, total });
        })
        .and_then(|colors| {
            let views = planned
                .iter()
                .zip(colors)
                .enumerate()
                .map(|(i, (p, color))| {
                    let mut extra = Map::new();
                    extra.insert("base_stop".into(), Value::from(p.report.base_stop));
                    extra.insert("stamp".into(), Value::from(p.report.stamp_s));
                    ViewSpec {
                        data: ViewData::Depth { depth: PathBuf::from(format!("depth/{i:06}.png")), color },
                        pose: ViewPose::Chain {
                            world_from_base: p.pose.world_from_base,
                            base_from_ee: p.pose.base_from_ee,
                        },
                        extra,
                    }
                })
                .collect();
            write_scan(&Scan {
                warnings: Vec::new(),
                dir: tmp.to_path_buf(),
                camera: Some(camera),
                ee_from_camera,
                tag: params.tag.clone(),
                views,
            })?;
            let text =
                serde_json::to_string_pretty(&report).map_err(|e| Error::invalid("import report", e.to_string()))?;
            write_atomic(&tmp.join("import.json"), text.as_bytes())
        })
    })?;
    Ok(report)
}

/// Pass 2: the planned views' depth (and color) images written into `dir`; each view's color file.
fn write_views(
    bag: &Bag,
    dir: &Path,
    planned: &[Planned],
    depth_topic: &str,
    color_topic: Option<&str>,
    camera: &DepthCamera,
    progress: &mut dyn FnMut(u64),
) -> Result<Vec<Option<PathBuf>>> {
    for sub in ["depth", "color"] {
        std::fs::create_dir_all(dir.join(sub)).map_err(|e| Error::io(dir.join(sub), e))?;
    }
    let depth_view: HashMap<usize, usize> = planned.iter().enumerate().map(|(i, p)| (p.depth_ordinal, i)).collect();
    let color_view: HashMap<usize, usize> =
        planned.iter().enumerate().filter_map(|(i, p)| p.color_ordinal.map(|c| (c, i))).collect();
    let mut colors: Vec<Option<PathBuf>> = vec![None; planned.len()];
    let mut depth_done = vec![false; planned.len()];
    let mut ordinals: HashMap<String, usize> = HashMap::new();
    let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
    let wanted = |t: &str| t == depth_topic || Some(t) == color_topic;
    bag.for_each(&wanted, progress, &mut |m: &BagMessage<'_>| {
        let ordinal = {
            let n = ordinals.entry(m.topic.to_string()).or_default();
            *n += 1;
            *n - 1
        };
        let bad = |e: String| bad_message(bag, m.topic, ordinal, &e);
        let size_check = |what: &str, width: u32, height: u32| {
            if (width, height) == (w, h) {
                Ok(())
            } else {
                Err(bad(format!(
                    "the {what} image is {width}x{height}, the camera info {w}x{h}: awl needs depth and color registered to one camera \
                     (record the depth aligned to the color, e.g. aligned_depth_to_color)"
                )))
            }
        };
        let compressed = normalise_type(m.type_name) == COMPRESSED;
        if m.topic == depth_topic {
            let Some(&view) = depth_view.get(&ordinal) else { return Ok(()) };
            let path = dir.join(format!("depth/{view:06}.png"));
            if compressed {
                let image = cdr::decode_compressed_image(m.data).map_err(bad)?;
                // compressedDepth: a 12-byte header (format, two quantisation floats), then a 16-bit PNG
                let png = image.data.get(12..).filter(|d| d.starts_with(b"\x89PNG")).ok_or_else(|| bad("compressedDepth data without its PNG".into()))?;
                write_atomic(&path, png)?;
                let depth = read_depth_png(&path)?;
                size_check("depth", depth.width, depth.height)?;
            } else {
                let image = cdr::decode_image(m.data).map_err(bad)?;
                if !DEPTH_ENCODINGS.contains(&image.encoding.as_str()) {
                    return Err(bad(format!("unsupported depth encoding `{}` (awl reads 16UC1 millimetres, 32FC1 metres)", image.encoding)));
                }
                let depth = depth_from_image(&image).map_err(bad)?;
                size_check("depth", depth.width, depth.height)?;
                write_depth_png(&path, &depth)?;
            }
            depth_done[view] = true;
        } else if let Some(&view) = color_view.get(&ordinal) {
            let relative = if compressed {
                let image = cdr::decode_compressed_image(m.data).map_err(bad)?;
                let ext = match color_file_kind(image.data) {
                    Some(ColorFileKind::Jpeg) => "jpg",
                    Some(ColorFileKind::Png) => "png",
                    None => return Err(bad(format!("compressed format `{}`: neither JPEG nor PNG data", image.format))),
                };
                let relative = PathBuf::from(format!("color/{view:06}.{ext}"));
                write_atomic(&dir.join(&relative), image.data)?;
                let color = read_color_image(&dir.join(&relative))?;
                size_check("color", color.width, color.height)?;
                relative
            } else {
                let image = cdr::decode_image(m.data).map_err(bad)?;
                let color = color_from_image(&image).map_err(bad)?;
                size_check("color", color.width, color.height)?;
                let relative = PathBuf::from(format!("color/{view:06}.png"));
                write_color_png(&dir.join(&relative), &color)?;
                relative
            };
            colors[view] = Some(relative);
        }
        Ok(())
    })?;
    if let Some(missing) = depth_done.iter().position(|d| !d) {
        return Err(Error::format(
            &bag.path,
            format!("topic {depth_topic}: the depth image of view {missing} was not found again (the bag changed?)"),
        ));
    }
    Ok(colors)
}
