//! The rig simulator behind `awl simulate`: renders a scan folder (`awl-scan/1`) of a workpiece on a
//! floor with clutter and a wall, seen by a RealSense-like camera on a mobile manipulator, with
//! realistic depth noise and pose errors, plus its ground truth (`truth.json`, `cad.ply`, label
//! images). Or, in shot mode, the few views the arm takes at piercing time (world = robot base). Or
//! ([`capture`]) a hand-eye calibration capture: views of a tag on a fixed board, world = robot base.
//!
//! Everything is deterministic per seed: every purpose and every image row draws from its own
//! ChaCha8 stream, so the output is bit-identical whatever the number of threads. Only
//! [`write_simulation`] touches the filesystem.

pub mod calibration;
pub mod capture;
mod layout;
mod noise;
mod record;
mod render;
mod rig;
mod shade;
mod shapes;
mod shot;
mod tag36h11;
mod tagview;
mod workpiece;
mod world;
mod write;

use std::sync::Arc;

use crate::camera::{DepthCamera, Intrinsics};
use crate::error::{Error, Result};
use crate::image::{ColorImage, DepthImage};
use crate::io::truth::Truth;
use crate::mesh::TriMesh;
use crate::random;
use crate::scan::{Scan, ViewData};

pub use noise::axial_sigma_m;
pub use tag36h11::{TAG_BORDER_MODULES, TAG_MODULES, TAG36H11_EMBEDDED, tag36h11_bitmap};
pub use write::write_simulation;

/// Label of pixels without a depth return.
pub const LABEL_NONE: u8 = 0;
/// Label of floor pixels.
pub const LABEL_FLOOR: u8 = 1;
/// Label of workpiece pixels.
pub const LABEL_WORKPIECE: u8 = 2;
/// Label of clutter, wall and support pixels.
pub const LABEL_OTHER: u8 = 3;
/// The tag36h11 id printed on every simulated workpiece.
pub const TAG_ID: u32 = 0;

/// Which workpiece to simulate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SceneKind {
    /// A 48.5 x 48 x 30 cm box, tag (8 cm) centred on its -y face.
    Box,
    /// A 50 x 40 x 35 cm free-form dome shell with a 2 cm groove across its top, tag (9 cm) on its -y side.
    Shell,
    /// A cylinder of radius 15 cm and height 70 cm, tag (8 cm) on its side.
    Cylinder,
    /// A sphere of radius 20 cm resting on the floor, tag (8 cm) on its -y side 15 degrees above the
    /// equator. Alone with the floor it leaves the spin about its vertical axis unconstrained.
    Sphere,
}

impl SceneKind {
    /// The name used on the command line and in truth.json.
    pub fn name(self) -> &'static str {
        match self {
            Self::Box => "box",
            Self::Shell => "shell",
            Self::Cylinder => "cylinder",
            Self::Sphere => "sphere",
        }
    }
}

/// How much sensor and pose noise to simulate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NoiseLevel {
    /// Exact depth (rounded to 1 mm) and exact poses.
    None,
    /// Half the realistic noise.
    Low,
    /// A RealSense D435 on a mobile manipulator with LiDAR SLAM.
    Realistic,
    /// Twice the realistic noise.
    Harsh,
}

impl NoiseLevel {
    /// The factor every noise term is scaled by: 0, 0.5, 1 or 2.
    pub fn scale(self) -> f64 {
        match self {
            Self::None => 0.0,
            Self::Low => 0.5,
            Self::Realistic => 1.0,
            Self::Harsh => 2.0,
        }
    }

    /// The name used on the command line and in truth.json.
    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Low => "low",
            Self::Realistic => "realistic",
            Self::Harsh => "harsh",
        }
    }
}

/// How the workpiece lies at piercing time (shot mode).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShotPose {
    /// Flat on the floor.
    Flat,
    /// Tilted 30 degrees on a support ramp.
    Tilt30,
}

impl ShotPose {
    /// The name used on the command line and in truth.json.
    pub fn name(self) -> &'static str {
        match self {
            Self::Flat => "flat",
            Self::Tilt30 => "tilt30",
        }
    }
}

/// What to simulate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SimParams {
    /// The workpiece.
    pub scene: SceneKind,
    /// Number of views (1..=1000 for a scan, 1..=3 for a shot).
    pub views: usize,
    /// Seed of every random choice.
    pub seed: u64,
    /// Noise level.
    pub noise: NoiseLevel,
    /// `Some` for a piercing-time shot instead of a scan.
    pub shot: Option<ShotPose>,
    /// Seed of the camera: its intrinsics and its global depth-scale error, which belong to the
    /// device, so a scan and the shots taken later with the same camera share them (give the scan's
    /// seed). `None`: `seed`.
    pub camera_seed: Option<u64>,
    /// The workpiece alone on the floor: no clutter boxes and no wall (a scan only). A symmetric
    /// workpiece then leaves a motion that no view's surface constrains (the cylinder's spin
    /// about its axis).
    pub bare: bool,
    /// A fixed arm (a scan only): every view from one base pose, the arm moving the camera around
    /// the workpiece on the base's side, no SLAM error (world = the robot base's frame).
    pub fixed_base: bool,
}

impl SimParams {
    /// A realistic 12-view scan of `scene` with seed 1.
    pub fn scan(scene: SceneKind) -> Self {
        Self {
            scene,
            views: 12,
            seed: 1,
            noise: NoiseLevel::Realistic,
            shot: None,
            camera_seed: None,
            bare: false,
            fixed_base: false,
        }
    }

    /// A realistic 2-view shot of `scene` in `pose` with seed 1.
    pub fn shot(scene: SceneKind, pose: ShotPose) -> Self {
        Self {
            scene,
            views: 2,
            seed: 1,
            noise: NoiseLevel::Realistic,
            shot: Some(pose),
            camera_seed: None,
            bare: false,
            fixed_base: false,
        }
    }

    /// The seed of the camera (see `camera_seed`).
    pub fn camera_seed(&self) -> u64 {
        self.camera_seed.unwrap_or(self.seed)
    }

    fn validate(&self) -> Result<()> {
        let max = if self.shot.is_some() { 3 } else { 1000 };
        if self.views == 0 || self.views > max {
            return Err(Error::invalid("views", format!("must be 1 to {max}, got {}", self.views)));
        }
        Ok(())
    }
}

/// An 8-bit label image (see the `LABEL_*` constants), row-major.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LabelImage {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Row-major labels.
    pub data: Vec<u8>,
}

/// The images of one simulated view.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SimView {
    /// Depth in millimetres (`camera.depth_scale` = 0.001), 0 = no return.
    pub depth: DepthImage,
    /// Registered color.
    pub color: ColorImage,
    /// Source of each depth pixel.
    pub labels: LabelImage,
}

/// A simulated scan (or shot, or calibration capture) in memory.
#[derive(Debug, Clone, PartialEq)]
pub struct Simulation {
    /// The manifest, with the recorded (noisy) poses; `dir` is empty and paths are relative.
    pub scan: Scan,
    /// The ground truth; paths are relative.
    pub truth: Truth,
    /// The workpiece's CAD mesh in the object frame.
    pub cad: TriMesh,
    /// The images, one entry per view of `scan`.
    pub views: Vec<SimView>,
}

impl Simulation {
    /// Number of depth pixels with a return, over all views.
    pub fn depth_points(&self) -> usize {
        self.views.iter().map(|v| v.depth.data.iter().filter(|&&d| d > 0).count()).sum()
    }

    /// The scan with each view's images held in memory ([`ViewData::Images`]) instead of the file
    /// names [`write_simulation`] would write them to: fused as it is, without touching the disk.
    pub fn in_memory_scan(&self) -> Scan {
        let mut scan = self.scan.clone();
        for (spec, view) in scan.views.iter_mut().zip(&self.views) {
            let color = spec.data.has_color().then(|| Arc::new(view.color.clone()));
            spec.data = ViewData::Images { depth: Arc::new(view.depth.clone()), color };
        }
        scan
    }
}

/// The true `T_ee_camera` of the simulated rig (every scan and shot; their scan.json carries it
/// with a per-seed calibration error).
pub fn rig_ee_from_camera() -> nalgebra::Isometry3<f64> {
    rig::true_ee_from_camera()
}

/// The seed's RealSense-D435-like camera: 640x480, focal about 615 px and principal point about the
/// image centre (each within 3 px, as a real calibration would give), no distortion, 1 mm depth
/// units, 0.2-3 m range.
pub fn simulated_camera(seed: u64) -> DepthCamera {
    let mut rng = random::rng(seed, random::Stream::Intrinsics, 0, 0);
    let fx = 615.0 + random::uniform(&mut rng, -3.0, 3.0);
    let fy = fx + random::uniform(&mut rng, -1.5, 1.5);
    let cx = 320.0 + random::uniform(&mut rng, -3.0, 3.0);
    let cy = 240.0 + random::uniform(&mut rng, -3.0, 3.0);
    let intrinsics = Intrinsics { width: 640, height: 480, fx, fy, cx, cy, distortion: [0.0; 5] };
    DepthCamera { intrinsics, depth_scale: 0.001, depth_min_m: 0.2, depth_max_m: 3.0 }
}

/// The point of the true surface of `scene`'s workpiece nearest `p_object` and the outward unit
/// normal there, object frame (the dome: its top surface, away from the rim).
pub fn nearest_surface(
    scene: SceneKind,
    p_object: &nalgebra::Point3<f64>,
) -> (nalgebra::Point3<f64>, nalgebra::Vector3<f64>) {
    workpiece::nearest_surface(scene, p_object)
}

/// Simulates a scan or shot.
///
/// # Errors
/// [`Error::Invalid`] for a bad view count, or when a shot finds no camera pose that sees the tag.
pub fn simulate(params: &SimParams) -> Result<Simulation> {
    simulate_with_views(params, &[])
}

/// At most this many extra views in one shot ([`simulate_with_views`]).
pub const MAX_EXTRA_VIEWS: usize = 64;

/// [`simulate`], a shot with `extra_flanges` views after its own: the arm commanded to each flange
/// pose (`T_base_ee`, e.g. `awl plan-views`' proposals), with the arm's noise on what it reports.
/// The shot's own views, scene and noise are those of [`simulate`] with the same parameters.
///
/// # Errors
/// As [`simulate`]; [`Error::Invalid`] for extra views in a scan, more than [`MAX_EXTRA_VIEWS`], or a
/// flange pose that is not finite.
pub fn simulate_with_views(params: &SimParams, extra_flanges: &[nalgebra::Isometry3<f64>]) -> Result<Simulation> {
    params.validate()?;
    if !extra_flanges.is_empty() && params.shot.is_none() {
        return Err(Error::invalid("views", "extra views are taken in a shot only (give a shot pose)"));
    }
    if extra_flanges.len() > MAX_EXTRA_VIEWS {
        return Err(Error::invalid(
            "views",
            format!("{} extra views, more than {MAX_EXTRA_VIEWS}", extra_flanges.len()),
        ));
    }
    if let Some(i) = extra_flanges.iter().position(|f| !f.to_homogeneous().iter().all(|v| v.is_finite())) {
        return Err(Error::invalid(format!("views[{i}].T_base_ee"), "not finite"));
    }
    let wp = workpiece::workpiece(params.scene);
    let camera = simulated_camera(params.camera_seed());
    let mut plan = match params.shot {
        None => record::scan_plan(&wp, params, &camera)?,
        Some(pose) => record::shot_plan(&wp, params, pose, &camera)?,
    };
    record::add_views(&mut plan, &wp, &camera, extra_flanges);
    let scale = params.noise.scale();
    let renderer = render::Renderer {
        world: &plan.world,
        camera: &camera,
        noise: noise::DepthNoise::new(params.camera_seed(), scale),
        color_sigma: 2.0 * scale,
        seed: params.seed,
    };
    let views = plan
        .views
        .iter()
        .enumerate()
        .map(|(i, view)| {
            let images = renderer.render(i, &view.world_from_camera);
            SimView { depth: images.depth, color: images.color, labels: images.labels }
        })
        .collect();
    let (scan, truth) = record::records(&wp, params, &camera, &plan, renderer.noise);
    Ok(Simulation { scan, truth, cad: wp.cad, views })
}
