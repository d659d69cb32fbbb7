//! Hand-eye calibration captures with images (`awl simulate --capture`): a tag36h11 tag printed on a
//! board held fixed in front of the arm base, seen by the flange camera from N diverse arm poses, each
//! view rendered (color and depth, with the scan noise model) by the scan renderer. World = robot base.
//!
//! Geometry: the board (a square of twice the tag's edge, 1 cm thick, front face = the tag plane) on
//! a 4 cm post standing on the floor 0.45 m below the base; the tag where [`crate::sim::calibration`]
//! puts its target (0.55 m in front of the base, tilted 30 degrees toward it) and the cameras drawn by
//! its sampler (up to `spread_deg` from the tag normal, rolled up to `+-spread_deg`), redrawn until the
//! tag's white quiet zone lies 10 px inside the image and the tag is seen well (unoccluded, incidence
//! under 60 degrees). What is recorded: `T_base_ee` with the rig's arm error per view (0.6 mm, 0.06 deg
//! sigma per axis at `realistic`), `T_world_base` identity, and `T_ee_camera` = the true one times the
//! rig's hand-eye error (about 3 mm, 0.3 deg: a user's old calibration). truth.json holds the true
//! `T_ee_camera`, `T_world_tag`, per view the true poses and the tag's true corners (`tag_corners_px`,
//! AprilTag order, pixel centres at integer coordinates), and the board as `cad.ply` (object frame =
//! tag frame), like the other simulator's `sim_reference/calib_seed1`.

use std::path::PathBuf;

use nalgebra::{Isometry3, Point3, UnitQuaternion, Vector3};
use serde_json::{Map, Value, json};

use crate::camera::DepthCamera;
use crate::error::{Error, Result};
use crate::io::truth::{Truth, TruthView};
use crate::mesh::TriMesh;
use crate::random::{Stream, rng};
use crate::scan::{Scan, TagSpec, ViewData, ViewPose, ViewSpec};
use crate::sim::calibration::{CalibrationMotion, ViewSpread, camera_pose, fixed_target, square_in_view};
use crate::sim::layout::{FLOOR, FLOOR_HALF_M};
use crate::sim::noise::DepthNoise;
use crate::sim::render::Renderer;
use crate::sim::rig::{BASE_HEIGHT, hand_eye_error, pose_errors, true_ee_from_camera};
use crate::sim::shapes::cuboid;
use crate::sim::tag36h11::{TAG_BORDER_MODULES, TAG_MODULES, TAG36H11_EMBEDDED, tag36h11_bitmap};
use crate::sim::tagview::{TagObservation, observe_tag};
use crate::sim::world::{Material, TagPrint, Texture, World, WorldBuilder};
use crate::sim::{LABEL_OTHER, LABEL_WORKPIECE, NoiseLevel, SimView, Simulation, simulated_camera};
use crate::transform::rows_from_isometry;

/// The board: label 2 (the "workpiece" of a capture), a beige card where the tag is not printed.
const BOARD: Material = Material { label: LABEL_WORKPIECE, albedo: [200.0, 190.0, 165.0], texture: Texture::Tagged };
/// The post holding the board.
const POST: Material = Material { label: LABEL_OTHER, albedo: [96.0, 96.0, 104.0], texture: Texture::Plain };
/// Board thickness, metres.
const BOARD_THICKNESS_M: f64 = 0.01;
/// Board edge over tag edge.
const BOARD_OVER_TAG: f64 = 2.0;
/// The quiet zone (and the tag) must lie this far inside the image, pixels.
const MARGIN_PX: f64 = 10.0;
/// Camera poses drawn per view before giving up.
const DRAWS: usize = 1000;

/// What to simulate; defaults in [`Default`] (like `sim_reference/calib_seed1`: 20 views, tag id 7, 14 cm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CaptureParams {
    /// Number of views (3 to 1000). Default 20.
    pub views: usize,
    /// Seed of every random choice. Default 1.
    pub seed: u64,
    /// Noise of depth, color, arm poses and the recorded hand-eye. Default realistic.
    pub noise: NoiseLevel,
    /// tag36h11 id printed on the board (0 to 9, the embedded bitmaps). Default 7.
    pub tag_id: u32,
    /// The tag's black-border edge, metres (0.02 to 0.3). Default 0.14.
    pub tag_size_m: f64,
    /// Largest tilt of the view direction from the tag normal and largest roll, degrees (1 to 60).
    /// Default 40.
    pub spread_deg: f64,
    /// Nearest camera-to-tag distance, metres. Default 0.35.
    pub min_distance_m: f64,
    /// Farthest camera-to-tag distance, metres (at most 2). Default 0.7.
    pub max_distance_m: f64,
    /// The true `T_ee_camera`; `None` (default): the rig's ([`crate::sim::rig_ee_from_camera`]), so
    /// the capture calibrates the camera of awl's simulated scans and shots.
    pub ee_from_camera: Option<Isometry3<f64>>,
    /// Seed of the camera (intrinsics, global depth-scale error; see
    /// [`crate::sim::SimParams::camera_seed`]); `None` (default): `seed`.
    pub camera_seed: Option<u64>,
}

impl Default for CaptureParams {
    fn default() -> Self {
        Self {
            views: 20,
            seed: 1,
            noise: NoiseLevel::Realistic,
            tag_id: 7,
            tag_size_m: 0.14,
            spread_deg: 40.0,
            min_distance_m: 0.35,
            max_distance_m: 0.7,
            ee_from_camera: None,
            camera_seed: None,
        }
    }
}

impl CaptureParams {
    fn camera_seed(&self) -> u64 {
        self.camera_seed.unwrap_or(self.seed)
    }

    fn validate(&self) -> Result<()> {
        if !(3..=1000).contains(&self.views) {
            return Err(Error::invalid("views", format!("a capture needs 3 to 1000 views, got {}", self.views)));
        }
        if self.tag_id >= TAG36H11_EMBEDDED {
            return Err(Error::invalid(
                "tag id",
                format!("the simulator prints tag36h11 ids 0 to {}, got {}", TAG36H11_EMBEDDED - 1, self.tag_id),
            ));
        }
        if !(0.02..=0.3).contains(&self.tag_size_m) {
            return Err(Error::invalid("tag size", format!("must be 0.02 to 0.3 m, got {}", self.tag_size_m)));
        }
        if !(1.0..=60.0).contains(&self.spread_deg) {
            return Err(Error::invalid("spread_deg", format!("must be 1 to 60, got {}", self.spread_deg)));
        }
        if !(self.min_distance_m >= 0.25 && self.max_distance_m >= self.min_distance_m && self.max_distance_m <= 2.0) {
            return Err(Error::invalid(
                "distance",
                format!("need 0.25 <= min <= max <= 2 m, got {} to {}", self.min_distance_m, self.max_distance_m),
            ));
        }
        if let Some(he) = self.ee_from_camera
            && !(he.translation.vector.iter().all(|v| v.is_finite()) && he.translation.vector.norm() <= 0.5)
        {
            return Err(Error::invalid("ee_from_camera", "the translation must be finite and within 0.5 m"));
        }
        Ok(())
    }
}

/// The board in its own frame (= the tag frame: front face z = 0, x right, y up).
fn board_mesh(tag_size_m: f64) -> TriMesh {
    let h = tag_size_m * BOARD_OVER_TAG / 2.0;
    cuboid(Point3::new(-h, -h, -BOARD_THICKNESS_M), Point3::new(h, h, 0.0))
}

/// The scene: floor, post, board with the tag printed on it.
fn capture_world(p: &CaptureParams, world_from_tag: &Isometry3<f64>, board: &TriMesh) -> Result<World> {
    let mut builder = WorldBuilder::default();
    let c = world_from_tag.translation.vector;
    builder.floor((c.x, c.y, -BASE_HEIGHT), FLOOR_HALF_M, FLOOR);
    builder.add(board, world_from_tag, BOARD);
    // A 4 cm post from the floor to just behind the board's centre (the tag leans back, toward +x).
    let back = world_from_tag * Point3::new(0.0, 0.0, -BOARD_THICKNESS_M - 0.02);
    let post = cuboid(
        Point3::new(back.x - 0.02, back.y - 0.02, -BASE_HEIGHT),
        Point3::new(back.x + 0.02, back.y + 0.02, back.z),
    );
    builder.add(&post, &Isometry3::identity(), POST);
    let black = tag36h11_bitmap(p.tag_id)
        .ok_or_else(|| Error::invalid("tag id", format!("tag36h11 id {} is not embedded", p.tag_id)))?;
    let print = TagPrint { tag_from_world: world_from_tag.inverse(), size: p.tag_size_m, black };
    builder.build(Some(print), p.seed)
}

/// The true `T_base_camera` of every view and what it sees of the tag.
fn plan_views(
    p: &CaptureParams,
    world: &World,
    camera: &DepthCamera,
    world_from_tag: &Isometry3<f64>,
) -> Result<Vec<(Isometry3<f64>, TagObservation)>> {
    let mut geo = rng(p.seed, Stream::Capture, 1, 0);
    let spread = ViewSpread {
        spread_deg: p.spread_deg,
        min_distance_m: p.min_distance_m,
        max_distance_m: p.max_distance_m,
        motion: CalibrationMotion::Spread,
    };
    let quiet_half = p.tag_size_m * TAG_MODULES as f64 / TAG_BORDER_MODULES as f64 / 2.0;
    (0..p.views)
        .map(|i| {
            (0..DRAWS)
                .map(|_| camera_pose(&mut geo, &spread, world_from_tag))
                .find_map(|pose| {
                    let in_view = square_in_view(&camera.intrinsics, &(pose.inverse() * world_from_tag), quiet_half, MARGIN_PX);
                    let seen = observe_tag(world, camera, world_from_tag, p.tag_size_m, &pose);
                    (in_view && seen.good()).then_some((pose, seen))
                })
                .ok_or_else(|| {
                    Error::invalid(
                        "capture simulation",
                        format!("no camera pose with the whole tag in view found for view {i} in {DRAWS} draws (distances {} to {} m)", p.min_distance_m, p.max_distance_m),
                    )
                })
        })
        .collect()
}

fn image_path(kind: &str, index: usize) -> PathBuf {
    PathBuf::from(format!("{kind}/{index:06}.png"))
}

fn round(v: f64, digits: i32) -> f64 {
    let k = 10f64.powi(digits);
    (v * k).round() / k
}

/// The per-view truth keys of `sim_reference/calib_seed1`.
fn view_extra(
    seen: &TagObservation,
    base_from_camera: &Isometry3<f64>,
    world_from_tag: &Isometry3<f64>,
) -> Map<String, Value> {
    let mut extra = Map::new();
    extra.insert("tag_visible".into(), json!(seen.visible));
    extra.insert("tag_incidence_deg".into(), json!(round(seen.incidence_deg, 3)));
    extra.insert("tag_side_px".into(), json!(round(seen.side_px, 3)));
    extra.insert("tag_corners_px".into(), json!(seen.corners_px.map(|c| c.map(|v| round(v, 4)))));
    let range = (world_from_tag.translation.vector - base_from_camera.translation.vector).norm();
    extra.insert("tag_range_m".into(), json!(round(range, 5)));
    extra
}

/// Simulates a hand-eye calibration capture with images (module docs). Deterministic per seed; write
/// it with [`crate::sim::write_simulation`].
///
/// # Errors
/// [`Error::Invalid`] for bad parameters, or when a view finds no camera pose that sees the whole tag.
pub fn simulate_capture(p: &CaptureParams) -> Result<Simulation> {
    p.validate()?;
    let scale = p.noise.scale();
    let camera = simulated_camera(p.camera_seed());
    let world_from_tag = fixed_target(&mut rng(p.seed, Stream::Capture, 0, 0));
    let cad = board_mesh(p.tag_size_m);
    let world = capture_world(p, &world_from_tag, &cad)?;
    let planned = plan_views(p, &world, &camera, &world_from_tag)?;
    let noise = DepthNoise::new(p.camera_seed(), scale);
    let renderer = Renderer { world: &world, camera: &camera, noise, color_sigma: 2.0 * scale, seed: p.seed };
    let views = planned
        .iter()
        .enumerate()
        .map(|(i, (pose, _))| {
            let images = renderer.render(i, pose);
            SimView { depth: images.depth, color: images.color, labels: images.labels }
        })
        .collect();
    let ee_from_camera = p.ee_from_camera.unwrap_or_else(true_ee_from_camera);
    let recorded_ee_from_camera = ee_from_camera * hand_eye_error(p.seed, scale);
    let arm = pose_errors(p.seed, 1, planned.len(), scale, false).arm;
    let mut spec_views = Vec::with_capacity(planned.len());
    let mut truth_views = Vec::with_capacity(planned.len());
    for (i, (base_from_camera, seen)) in planned.iter().enumerate() {
        let base_from_ee = base_from_camera * ee_from_camera.inverse();
        let error = arm.get(i).copied().unwrap_or_else(Isometry3::identity);
        let mut extra = Map::new();
        extra.insert("base_stop".into(), json!(0));
        spec_views.push(ViewSpec {
            data: ViewData::Depth { depth: image_path("depth", i), color: Some(image_path("color", i)) },
            pose: ViewPose::Chain { world_from_base: Isometry3::identity(), base_from_ee: base_from_ee * error },
            extra,
        });
        truth_views.push(TruthView {
            world_from_camera: *base_from_camera,
            world_from_base: Some(Isometry3::identity()),
            base_from_ee: Some(base_from_ee),
            label: Some(image_path("labels", i)),
            extra: view_extra(seen, base_from_camera, &world_from_tag),
        });
    }
    let tag = TagSpec { family: "tag36h11".into(), id: p.tag_id, size_m: p.tag_size_m };
    let scan = Scan {
        dir: PathBuf::new(),
        camera: Some(camera),
        ee_from_camera: Some(recorded_ee_from_camera),
        tag: Some(tag),
        views: spec_views,
        warnings: Vec::new(),
    };
    let truth = Truth {
        cad: PathBuf::from("cad.ply"),
        world_from_object: world_from_tag,
        world_from_tag: Some(world_from_tag),
        ee_from_camera: Some(ee_from_camera),
        views: truth_views,
        targets: Vec::new(),
        extra: truth_extra(p, &world_from_tag, &ee_from_camera, &recorded_ee_from_camera, noise),
    };
    Ok(Simulation { scan, truth, cad, views })
}

fn truth_extra(
    p: &CaptureParams,
    world_from_tag: &Isometry3<f64>,
    ee_from_camera: &Isometry3<f64>,
    recorded: &Isometry3<f64>,
    noise: DepthNoise,
) -> Map<String, Value> {
    let flip = Isometry3::from_parts(
        Default::default(),
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI),
    );
    let s = p.noise.scale();
    let he = ee_from_camera.inverse() * recorded;
    let mut extra = Map::new();
    extra.insert("generator".into(), json!("awl simulate --capture"));
    extra.insert("mode".into(), json!("calibration"));
    extra.insert("seed".into(), json!(p.seed));
    extra.insert("camera_seed".into(), json!(p.camera_seed()));
    extra.insert("noise".into(), json!(p.noise.name()));
    extra.insert("T_world_tag_apriltag".into(), json!(rows_from_isometry(&(world_from_tag * flip))));
    extra.insert(
        "tag_frames".into(),
        json!("T_world_tag: x right, y up, z out of the face; T_world_tag_apriltag: AprilTag library frame, x right, y down, z into the face"),
    );
    extra.insert(
        "labels".into(),
        json!("labels/*.png: source of each depth pixel, 0 none, 1 floor, 2 tag board, 3 post"),
    );
    extra.insert(
        "tag_corners_px".into(),
        json!("views[].tag_corners_px: the tag's true black-border corners in AprilTag order, pixel centres at integer coordinates"),
    );
    extra.insert("depth_scale_error".into(), json!(noise.scale_error));
    extra.insert(
        "noise_params".into(),
        json!({
            "scale": s,
            "axial_sigma": "scale * (1.2 mm + 1.9 mm * (z - 0.4 m)^2) * min(1 / cos(incidence), 3)",
            "lateral_px": 0.5 * s, "grazing_dropout_deg": (90.0 - 12.0 * s).max(45.0),
            "holes": 0.01 * s, "flying": (0.3 * s).min(0.6), "outliers": 0.0002 * s, "stereo_baseline_m": 0.05,
            "arm_sigma_m": 0.0006 * s, "arm_sigma_deg": 0.06 * s,
            "hand_eye_m": 0.003 * s, "hand_eye_deg": 0.3 * s, "color_sigma": 2.0 * s,
        }),
    );
    extra.insert(
        "calibration".into(),
        json!({
            "views": p.views,
            "tag": {"family": "tag36h11", "id": p.tag_id, "size": p.tag_size_m},
            "board_m": p.tag_size_m * BOARD_OVER_TAG,
            "spread_deg": p.spread_deg,
            "distance_m": [p.min_distance_m, p.max_distance_m],
            "recorded_T_ee_camera_error_mm": round(he.translation.vector.norm() * 1e3, 3),
            "recorded_T_ee_camera_error_deg": round(he.rotation.angle().to_degrees(), 3),
            "note": "world = robot base; the tag board is fixed; T_ee_camera in scan.json is the recorded (erroneous) hand-eye, the true one is here; cad.ply is the board in the tag frame",
        }),
    );
    extra
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_parameters_are_refused_with_their_name() {
        let bad = [
            (CaptureParams { views: 2, ..CaptureParams::default() }, "views"),
            (CaptureParams { tag_id: TAG36H11_EMBEDDED, ..CaptureParams::default() }, "tag id"),
            (CaptureParams { tag_size_m: 0.5, ..CaptureParams::default() }, "tag size"),
            (CaptureParams { tag_size_m: f64::NAN, ..CaptureParams::default() }, "tag size"),
            (CaptureParams { spread_deg: 0.0, ..CaptureParams::default() }, "spread_deg"),
            (CaptureParams { min_distance_m: 0.8, ..CaptureParams::default() }, "distance"),
        ];
        for (p, what) in bad {
            let e = simulate_capture(&p).expect_err("refused").to_string();
            assert!(e.contains(what), "{what}: {e}");
        }
    }
}
