//! Hand-eye calibration captures: N diverse arm poses whose flange camera looks at a tag fixed in
//! the base frame, with the true `ee_from_camera`, exact and noisy measurements. No images.
//!
//! Geometry per seed: the tag (8 cm) lies 0.55 m in front of the base, tilted 30 degrees toward it;
//! each camera sits 0.3-0.6 m from the tag along a direction up to `spread_deg` from the tag normal
//! (uniform azimuth), aims within 2 cm of the tag centre and is rolled up to `+-spread_deg` about its
//! optical axis, so the relative rotations are about every axis; a pose is redrawn until all four tag
//! corners project at least 10 px inside the seed's 640x480 image. The true `ee_from_camera` is drawn
//! per seed: translation within 6 cm sideways and 2-12 cm along the flange, rotation up to 120 degrees
//! about a random axis. Noise (independent normal per axis): `camera_from_target * dT` with `dT` in
//! the target frame (so `camera_noise_mm` is the tag position error and `camera_noise_deg` the
//! orientation error about its centre); `base_from_ee * dT` with `dT` in the flange frame.
//!
//! [`CalibrationMotion::OrbitTarget`] draws the same directions and rolls but keeps every camera at
//! the middle distance, aimed at the tag centre: pure rotations about the target, the capture that
//! cannot tell a wrong tag size from the camera's offset along its optical axis.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand_chacha::ChaCha8Rng;

use crate::camera::Intrinsics;
use crate::error::{Error, Result};
use crate::handeye::HandEyePose;
use crate::random::{Stream, normal_perturbation, rng, uniform, unit_vector};
use crate::sim::simulated_camera;

/// Side of the simulated calibration tag, metres.
pub const CALIBRATION_TAG_SIZE_M: f64 = 0.08;

/// How the simulated arm moves between the poses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CalibrationMotion {
    /// Distances spread over `min_distance_m..max_distance_m`, aims within 2 cm of the tag centre
    /// (module docs). The default.
    #[default]
    Spread,
    /// Every camera at `(min_distance_m + max_distance_m) / 2` from the tag, aimed at its centre:
    /// pure rotations about the target.
    OrbitTarget,
}

/// What to simulate; defaults in [`Default`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalibrationSimParams {
    /// Number of poses (3 to 100 000). Default 15.
    pub count: usize,
    /// Seed of every random choice. Default 1.
    pub seed: u64,
    /// Tag position error per axis (one sigma), millimetres. Default 0.5.
    pub camera_noise_mm: f64,
    /// Tag orientation error per axis (one sigma), degrees. Default 0.1.
    pub camera_noise_deg: f64,
    /// Flange position error per axis (forward kinematics, one sigma), millimetres. Default 0.1.
    pub arm_noise_mm: f64,
    /// Flange orientation error per axis (one sigma), degrees. Default 0.02.
    pub arm_noise_deg: f64,
    /// Largest tilt of the view direction from the tag normal and largest roll, degrees (1 to 60).
    /// Default 40: at 30 the 0.5 mm / 0.1 deg noise leaves up to 2.5 mm error in `T_ee_camera` (seed 8, 18 poses).
    pub spread_deg: f64,
    /// Nearest camera-to-tag distance, metres. Default 0.3.
    pub min_distance_m: f64,
    /// Farthest camera-to-tag distance, metres. Default 0.6.
    pub max_distance_m: f64,
    /// The true `T_ee_camera`; `None` (default): drawn per seed (module docs). Give
    /// [`crate::sim::rig_ee_from_camera`] to calibrate the camera of the simulated scans and shots.
    pub ee_from_camera: Option<Isometry3<f64>>,
    /// How the arm moves between the poses. Default [`CalibrationMotion::Spread`].
    pub motion: CalibrationMotion,
}

impl Default for CalibrationSimParams {
    fn default() -> Self {
        Self {
            count: 15,
            seed: 1,
            camera_noise_mm: 0.5,
            camera_noise_deg: 0.1,
            arm_noise_mm: 0.1,
            arm_noise_deg: 0.02,
            spread_deg: 40.0,
            min_distance_m: 0.3,
            max_distance_m: 0.6,
            ee_from_camera: None,
            motion: CalibrationMotion::Spread,
        }
    }
}

/// A simulated capture and its truth.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationCapture {
    /// The measurements, with noise.
    pub poses: Vec<HandEyePose>,
    /// The same poses without noise.
    pub true_poses: Vec<HandEyePose>,
    /// The true `T_ee_camera`.
    pub ee_from_camera: Isometry3<f64>,
    /// The true `T_base_target`.
    pub base_from_target: Isometry3<f64>,
}

fn validate(p: &CalibrationSimParams) -> Result<()> {
    if !(3..=100_000).contains(&p.count) {
        return Err(Error::invalid("count", format!("must be 3 to 100000, got {}", p.count)));
    }
    let noise = [p.camera_noise_mm, p.camera_noise_deg, p.arm_noise_mm, p.arm_noise_deg];
    if noise.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
        return Err(Error::invalid("noise", format!("must be finite and non-negative, got {noise:?}")));
    }
    if !(1.0..=60.0).contains(&p.spread_deg) {
        return Err(Error::invalid("spread_deg", format!("must be 1 to 60, got {}", p.spread_deg)));
    }
    if !(p.min_distance_m >= 0.1 && p.max_distance_m >= p.min_distance_m && p.max_distance_m <= 3.0) {
        return Err(Error::invalid(
            "distance",
            format!("need 0.1 <= min <= max <= 3 m, got {} to {}", p.min_distance_m, p.max_distance_m),
        ));
    }
    Ok(())
}

/// A frame with z along `z` (unit) and x as close to `x_hint` as possible.
fn frame(z: &Vector3<f64>, x_hint: &Vector3<f64>) -> UnitQuaternion<f64> {
    let x = (x_hint - z * z.dot(x_hint)).try_normalize(1e-9).unwrap_or_else(|| z.cross(&Vector3::z()).normalize());
    let y = z.cross(&x);
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, *z])))
}

fn true_hand_eye(rng: &mut ChaCha8Rng) -> Isometry3<f64> {
    let t = Vector3::new(uniform(rng, -0.06, 0.06), uniform(rng, -0.06, 0.06), uniform(rng, 0.02, 0.12));
    let angle = uniform(rng, 0.0, 120f64.to_radians());
    Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_scaled_axis(unit_vector(rng) * angle))
}

/// True when the square of half-side `half_m` about the origin of the plane z = 0 of `camera_from_target`
/// projects in front of the camera with all four corners at least `margin_px` inside the image.
pub(crate) fn square_in_view(
    intr: &Intrinsics,
    camera_from_target: &Isometry3<f64>,
    half_m: f64,
    margin_px: f64,
) -> bool {
    let h = half_m;
    [(-h, -h), (h, -h), (h, h), (-h, h)].iter().all(|&(x, y)| {
        intr.project(&(camera_from_target * Point3::new(x, y, 0.0))).is_some_and(|px| {
            px.x >= margin_px
                && px.y >= margin_px
                && px.x <= f64::from(intr.width) - margin_px
                && px.y <= f64::from(intr.height) - margin_px
        })
    })
}

/// True when all tag corners project at least 10 px inside the image of a camera at `base_from_camera`.
fn tag_in_view(seed: u64, base_from_camera: &Isometry3<f64>, base_from_target: &Isometry3<f64>) -> bool {
    let intr = simulated_camera(seed).intrinsics;
    square_in_view(&intr, &(base_from_camera.inverse() * base_from_target), CALIBRATION_TAG_SIZE_M / 2.0, 10.0)
}

/// How far and how obliquely the sampled cameras look at the target.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ViewSpread {
    /// Largest tilt from the target normal and largest roll, degrees.
    pub spread_deg: f64,
    /// Nearest camera-to-target distance, metres.
    pub min_distance_m: f64,
    /// Farthest camera-to-target distance, metres.
    pub max_distance_m: f64,
    /// How the camera moves about the target.
    pub motion: CalibrationMotion,
}

/// The fixed target: 0.55 m in front of the base, 5 cm above it, tilted 30 degrees toward it, turned
/// up to 0.3 rad about its normal.
pub(crate) fn fixed_target(geo: &mut ChaCha8Rng) -> Isometry3<f64> {
    let n = Vector3::new(-30f64.to_radians().sin(), 0.0, 30f64.to_radians().cos());
    let in_plane = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), uniform(geo, -0.3, 0.3));
    Isometry3::from_parts(Translation3::new(0.55, 0.0, 0.05), frame(&n, &Vector3::y()) * in_plane)
}

/// A camera pose looking at the target (module docs), `T_base_camera`.
pub(crate) fn camera_pose(rng: &mut ChaCha8Rng, p: &ViewSpread, base_from_target: &Isometry3<f64>) -> Isometry3<f64> {
    let rot = base_from_target.rotation.to_rotation_matrix();
    let (u, v, n) = (rot * Vector3::x(), rot * Vector3::y(), rot * Vector3::z());
    let spread = p.spread_deg.to_radians();
    let tilt = spread * uniform(rng, 0.0, 1.0).sqrt();
    let azimuth = uniform(rng, 0.0, std::f64::consts::TAU);
    let dir = n * tilt.cos() + (u * azimuth.cos() + v * azimuth.sin()) * tilt.sin();
    let mut distance = uniform(rng, p.min_distance_m, p.max_distance_m);
    let mut offset = u * uniform(rng, -0.02, 0.02) + v * uniform(rng, -0.02, 0.02);
    if p.motion == CalibrationMotion::OrbitTarget {
        distance = 0.5 * (p.min_distance_m + p.max_distance_m);
        offset = Vector3::zeros();
    }
    let eye = base_from_target.translation.vector + dir * distance;
    let aim = base_from_target.translation.vector + offset;
    let z = (aim - eye).normalize();
    // image x along the tag's x (image y down = tag y up), then rolled
    let roll = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), uniform(rng, -spread, spread));
    Isometry3::from_parts(Translation3::from(eye), frame(&z, &u) * roll)
}

/// Simulates a calibration capture.
///
/// # Errors
/// [`Error::Invalid`] for bad parameters, or when no pose with the tag in view is found in 1000 draws.
pub fn simulate_calibration(p: &CalibrationSimParams) -> Result<CalibrationCapture> {
    validate(p)?;
    let mut geo = rng(p.seed, Stream::HandEye, 1, 0);
    let drawn = true_hand_eye(&mut geo);
    let ee_from_camera = p.ee_from_camera.unwrap_or(drawn);
    let base_from_target = fixed_target(&mut geo);
    let spread = ViewSpread {
        spread_deg: p.spread_deg,
        min_distance_m: p.min_distance_m,
        max_distance_m: p.max_distance_m,
        motion: p.motion,
    };
    let mut true_poses = Vec::with_capacity(p.count);
    for i in 0..p.count {
        let base_from_camera = (0..1000)
            .map(|_| camera_pose(&mut geo, &spread, &base_from_target))
            .find(|pose| tag_in_view(p.seed, pose, &base_from_target))
            .ok_or_else(|| {
                Error::invalid("calibration simulation", format!("no view of the tag found for pose {i}"))
            })?;
        true_poses.push(HandEyePose {
            base_from_ee: base_from_camera * ee_from_camera.inverse(),
            camera_from_target: base_from_camera.inverse() * base_from_target,
        });
    }
    let poses = true_poses
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let mut noise = rng(p.seed, Stream::HandEye, 2, i as u64);
            let cam = normal_perturbation(&mut noise, p.camera_noise_mm * 1e-3, p.camera_noise_deg.to_radians());
            let arm = normal_perturbation(&mut noise, p.arm_noise_mm * 1e-3, p.arm_noise_deg.to_radians());
            HandEyePose { base_from_ee: t.base_from_ee * arm, camera_from_target: t.camera_from_target * cam }
        })
        .collect();
    Ok(CalibrationCapture { poses, true_poses, ee_from_camera, base_from_target })
}
