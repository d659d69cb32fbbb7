//! Planning a simulation (scene + true poses) and writing down what the rig records (noisy poses in
//! the manifest) and what the simulator knows (truth.json).

use std::path::PathBuf;

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use serde_json::{Map, Value, json};

use crate::camera::DepthCamera;
use crate::error::Result;
use crate::io::truth::{Truth, TruthTarget, TruthView};
use crate::scan::{Scan, TagSpec, ViewData, ViewPose, ViewSpec};
use crate::sim::layout::scan_world;
use crate::sim::noise::DepthNoise;
use crate::sim::rig::{RigView, hand_eye_error, plan_scan, pose_errors, stop_count, true_ee_from_camera};
use crate::sim::shot::plan_shot;
use crate::sim::tagview::{TagObservation, observe_tag};
use crate::sim::workpiece::Workpiece;
use crate::sim::world::World;
use crate::sim::{ShotPose, SimParams, TAG_ID};
use crate::transform::rows_from_isometry;

/// A planned simulation: the scene and the true poses.
pub(crate) struct Plan {
    /// The scene.
    pub world: World,
    /// `T_world_object`.
    pub world_from_object: Isometry3<f64>,
    /// True poses per view.
    pub views: Vec<RigView>,
    /// Number of base stops.
    pub stops: usize,
    /// The tag as each view sees it.
    pub observations: Vec<TagObservation>,
    /// Shot metadata for truth.json.
    pub shot: Option<Value>,
}

fn observe_all(
    world: &World,
    wp: &Workpiece,
    camera: &DepthCamera,
    world_from_object: &Isometry3<f64>,
    views: &[RigView],
) -> Vec<TagObservation> {
    let world_from_tag = world_from_object * wp.object_from_tag;
    views.iter().map(|v| observe_tag(world, camera, &world_from_tag, wp.tag_size, &v.world_from_camera)).collect()
}

/// Plans a scan: the seed's scene, then rig plans until enough views see the tag well (4, or a
/// third of the views when fewer than 12); the best of 40 attempts otherwise.
pub(crate) fn scan_plan(wp: &Workpiece, params: &SimParams, camera: &DepthCamera) -> Result<Plan> {
    let (world, layout) = scan_world(wp, params.seed, params.bare)?;
    let need = params.views.div_ceil(3).min(4);
    let mut best: Option<(usize, Vec<RigView>, Vec<TagObservation>)> = None;
    for attempt in 0..40 {
        let views = plan_scan(&layout, wp.centre.z, params.views, params.seed, attempt, params.fixed_base);
        let observations = observe_all(&world, wp, camera, &layout.world_from_object, &views);
        let good = observations.iter().filter(|o| o.good()).count();
        if best.as_ref().is_none_or(|b| good > b.0) {
            best = Some((good, views, observations));
        }
        if good >= need {
            break;
        }
    }
    let (_, views, observations) = best.unwrap_or_default();
    Ok(Plan {
        world,
        world_from_object: layout.world_from_object,
        views,
        stops: if params.fixed_base { 1 } else { stop_count(params.views) },
        observations,
        shot: None,
    })
}

/// Plans a piercing-time shot.
pub(crate) fn shot_plan(wp: &Workpiece, params: &SimParams, pose: ShotPose, camera: &DepthCamera) -> Result<Plan> {
    let plan = plan_shot(wp, pose, params.views, params.seed, camera)?;
    let observations = observe_all(&plan.world, wp, camera, &plan.world_from_object, &plan.views);
    let mut shot = json!({
        "pose": pose.name(),
        "floor_z": -crate::sim::rig::BASE_HEIGHT,
        "note": "world = robot base; the workpiece, tag, camera intrinsics, hand-eye error and depth-scale error are those of the scan with the same scene, seed and noise",
    });
    if let (Some(axis), Some(map)) = (plan.tilt_axis, shot.as_object_mut()) {
        map.insert("tilt_deg".into(), json!(30));
        map.insert("tilt_axis_world".into(), json!([axis.x, axis.y, axis.z]));
    }
    Ok(Plan {
        world: plan.world,
        world_from_object: plan.world_from_object,
        views: plan.views,
        stops: 1,
        observations,
        shot: Some(shot),
    })
}

/// Adds views at the true flange poses `flanges` to a shot's plan (world = the robot base).
pub(crate) fn add_views(plan: &mut Plan, wp: &Workpiece, camera: &DepthCamera, flanges: &[Isometry3<f64>]) {
    let views: Vec<RigView> = flanges
        .iter()
        .map(|f| RigView {
            stop: 0,
            world_from_base: Isometry3::identity(),
            base_from_ee: *f,
            world_from_camera: f * true_ee_from_camera(),
        })
        .collect();
    plan.observations.extend(observe_all(&plan.world, wp, camera, &plan.world_from_object, &views));
    plan.views.extend(views);
}

fn image_path(kind: &str, index: usize) -> PathBuf {
    PathBuf::from(format!("{kind}/{index:06}.png"))
}

/// The manifest (recorded, noisy poses) and the truth of a planned simulation.
pub(crate) fn records(
    wp: &Workpiece,
    params: &SimParams,
    camera: &DepthCamera,
    plan: &Plan,
    noise: DepthNoise,
) -> (Scan, Truth) {
    let scale = params.noise.scale();
    let slam = params.shot.is_none() && !params.fixed_base;
    let errors = pose_errors(params.seed, plan.stops, plan.views.len(), scale, slam);
    let ee_from_camera = true_ee_from_camera();
    let views = plan
        .views
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let slam = errors.slam.get(v.stop).copied().unwrap_or_else(Isometry3::identity);
            let arm = errors.arm.get(i).copied().unwrap_or_else(Isometry3::identity);
            let mut extra = Map::new();
            extra.insert("base_stop".into(), json!(v.stop));
            ViewSpec {
                data: ViewData::Depth { depth: image_path("depth", i), color: Some(image_path("color", i)) },
                pose: ViewPose::Chain { world_from_base: v.world_from_base * slam, base_from_ee: v.base_from_ee * arm },
                extra,
            }
        })
        .collect();
    let scan = Scan {
        dir: PathBuf::new(),
        camera: Some(*camera),
        ee_from_camera: Some(ee_from_camera * hand_eye_error(params.seed, scale)),
        tag: Some(TagSpec { family: "tag36h11".into(), id: TAG_ID, size_m: wp.tag_size }),
        views,
        warnings: Vec::new(),
    };
    (scan, truth(wp, params, plan, noise))
}

fn truth(wp: &Workpiece, params: &SimParams, plan: &Plan, noise: DepthNoise) -> Truth {
    let world_from_tag = plan.world_from_object * wp.object_from_tag;
    let in_shot = params.shot.is_some();
    let targets = wp
        .targets
        .iter()
        .map(|t| TruthTarget {
            name: t.name.clone(),
            p_object: t.p,
            n_object: t.n,
            p_world: in_shot.then(|| plan.world_from_object * t.p),
            n_world: in_shot.then(|| plan.world_from_object.rotation * t.n),
        })
        .collect();
    let views = plan
        .views
        .iter()
        .enumerate()
        .map(|(i, v)| TruthView {
            world_from_camera: v.world_from_base * v.base_from_ee * true_ee_from_camera(),
            world_from_base: Some(v.world_from_base),
            base_from_ee: Some(v.base_from_ee),
            label: Some(image_path("labels", i)),
            extra: Map::new(),
        })
        .collect();
    Truth {
        cad: PathBuf::from("cad.ply"),
        world_from_object: plan.world_from_object,
        world_from_tag: Some(world_from_tag),
        ee_from_camera: Some(true_ee_from_camera()),
        views,
        targets,
        extra: truth_extra(params, plan, &world_from_tag, noise),
    }
}

fn truth_extra(
    params: &SimParams,
    plan: &Plan,
    world_from_tag: &Isometry3<f64>,
    noise: DepthNoise,
) -> Map<String, Value> {
    let flip = Isometry3::from_parts(
        Default::default(),
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI),
    );
    let s = params.noise.scale();
    let mut extra = Map::new();
    extra.insert("generator".into(), json!("awl simulate"));
    extra.insert("scene".into(), json!(params.scene.name()));
    extra.insert("seed".into(), json!(params.seed));
    extra.insert("noise".into(), json!(params.noise.name()));
    if params.bare {
        extra.insert("bare".into(), json!(true));
    }
    extra.insert("T_world_tag_apriltag".into(), json!(rows_from_isometry(&(world_from_tag * flip))));
    extra.insert(
        "tag_frames".into(),
        json!("T_world_tag: x right, y up, z out of the face; T_world_tag_apriltag: AprilTag library frame, x right, y down, z into the face"),
    );
    extra.insert(
        "labels".into(),
        json!("labels/*.png: source of each depth pixel, 0 none, 1 floor, 2 workpiece, 3 clutter, wall or support"),
    );
    extra.insert("depth_scale_error".into(), json!(noise.scale_error));
    extra.insert(
        "noise_params".into(),
        json!({
            "scale": s,
            "axial_sigma": "scale * (1.2 mm + 1.9 mm * (z - 0.4 m)^2) * min(1 / cos(incidence), 3)",
            "lateral_px": 0.5 * s, "grazing_dropout_deg": (90.0 - 12.0 * s).max(45.0),
            "holes": 0.01 * s, "flying": (0.3 * s).min(0.6), "outliers": 0.0002 * s, "stereo_baseline_m": 0.05,
            "slam_xy_m": [0.01 * s, 0.03 * s], "slam_z_sigma_m": 0.003 * s, "slam_yaw_deg": [0.4 * s, 1.2 * s],
            "slam_roll_pitch_sigma_deg": 0.15 * s, "arm_sigma_m": 0.0006 * s, "arm_sigma_deg": 0.06 * s,
            "hand_eye_m": 0.003 * s, "hand_eye_deg": 0.3 * s, "color_sigma": 2.0 * s,
        }),
    );
    let observations: Vec<Value> = plan.observations.iter().enumerate().map(|(i, o)| o.to_json(i)).collect();
    extra.insert(
        "tag_corners_px".into(),
        json!("tag_observations[].corners_px: black-border corners in AprilTag order, pixel centres at integer coordinates"),
    );
    extra.insert("tag_observations".into(), Value::Array(observations));
    if let Some(shot) = &plan.shot {
        extra.insert("shot".into(), shot.clone());
    }
    extra
}
