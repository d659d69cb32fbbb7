//! A scan as data: the camera, the recorded hand-eye, the tag and the views with their recorded
//! poses, each view's measurements either files of a scan folder (`awl-scan/1`, read and written by
//! [`crate::io::scan`]) or images held in memory. Nothing here touches the filesystem.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use crate::camera::DepthCamera;
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::image::{ColorImage, DepthImage};

/// The fiducial stuck on the workpiece.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TagSpec {
    /// Tag family, e.g. `tag36h11`.
    pub family: String,
    /// Tag id within the family.
    pub id: u32,
    /// Black-border edge length, metres.
    #[serde(rename = "size")]
    pub size_m: f64,
}

/// Where a view's measurements are: files relative to the scan folder, or images in memory.
#[derive(Debug, Clone, PartialEq)]
pub enum ViewData {
    /// A 16-bit depth PNG and an optional registered 8-bit color image (PNG or JPEG).
    Depth {
        /// Depth image path.
        depth: PathBuf,
        /// Color image path.
        color: Option<PathBuf>,
    },
    /// A point file (PLY or PCD) in the camera frame, metres.
    Points {
        /// Point file path.
        points: PathBuf,
    },
    /// A depth image and an optional registered color image held in memory (a simulated scan
    /// fused without touching the disk); their sizes must match the scan's camera.
    Images {
        /// The depth image.
        depth: Arc<DepthImage>,
        /// The color image.
        color: Option<Arc<ColorImage>>,
    },
}

impl ViewData {
    /// Whether the view has a color image.
    pub fn has_color(&self) -> bool {
        match self {
            ViewData::Depth { color, .. } => color.is_some(),
            ViewData::Images { color, .. } => color.is_some(),
            ViewData::Points { .. } => false,
        }
    }
}

/// A view's recorded camera pose (the seed that registration refines).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ViewPose {
    /// The camera pose given directly.
    Camera {
        /// `T_world_camera`.
        world_from_camera: Isometry3<f64>,
    },
    /// SLAM base pose and arm forward kinematics; the camera pose also needs `T_ee_camera`.
    Chain {
        /// `T_world_base` (SLAM).
        world_from_base: Isometry3<f64>,
        /// `T_base_ee` (arm forward kinematics).
        base_from_ee: Isometry3<f64>,
    },
}

/// One view of a scan.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewSpec {
    /// The measurements.
    pub data: ViewData,
    /// The recorded pose.
    pub pose: ViewPose,
    /// Keys the spec does not define (kept so a rewrite does not lose a rig's metadata).
    pub extra: Map<String, Value>,
}

/// A scan: its camera, hand-eye, tag and views with their recorded poses. File paths are relative
/// to `dir` (the folder holding `scan.json`; for a scan held in memory, where it would be written).
#[derive(Debug, Clone, PartialEq)]
pub struct Scan {
    /// The folder holding `scan.json`.
    pub dir: PathBuf,
    /// The depth camera; required when any view has a depth image.
    pub camera: Option<DepthCamera>,
    /// `T_ee_camera`, the hand-eye calibration; required when any view gives `T_base_ee`.
    pub ee_from_camera: Option<Isometry3<f64>>,
    /// The tag on the workpiece, if any.
    pub tag: Option<TagSpec>,
    /// The views, in capture order.
    pub views: Vec<ViewSpec>,
    /// What the reader fixed and the user should know (a pose re-orthonormalised, naming its field).
    pub warnings: Vec<String>,
}

/// A view loaded into memory.
#[derive(Debug, Clone)]
pub struct LoadedView {
    /// The recorded camera pose, `T_world_camera`.
    pub world_from_camera: Isometry3<f64>,
    /// Points inside the depth range, camera frame, with colors when the view has them.
    pub cloud_camera: PointCloud,
    /// For a depth view, the pixel (`v * width + u`) each point came from.
    pub pixels: Option<Vec<u32>>,
    /// The color image, when the view has one (loaded with a step: its every `step`-th row and
    /// column).
    pub color: Option<ColorImage>,
    /// What loading the view's files dropped or ignored (a point file's non-finite points, bytes
    /// after its body), each naming the file.
    pub warnings: Vec<String>,
}

impl Scan {
    /// Path of `scan.json` in `dir`.
    pub fn manifest_path(dir: &Path) -> PathBuf {
        dir.join("scan.json")
    }

    /// View `index` of the manifest.
    ///
    /// # Errors
    /// [`Error::Field`] (`views`) when the index is out of range.
    pub fn view(&self, index: usize) -> Result<&ViewSpec> {
        self.views.get(index).ok_or_else(|| {
            Error::field(
                Self::manifest_path(&self.dir),
                "views",
                format!("no view {index} (scan has {})", self.views.len()),
            )
        })
    }

    /// Every file the scan reads: `scan.json` and each view's depth, color or point file (paths as
    /// the manifest names them, joined to `dir`; a view may name a file outside the folder).
    pub fn input_files(&self) -> Vec<PathBuf> {
        let mut files = vec![Self::manifest_path(&self.dir)];
        for v in &self.views {
            match &v.data {
                ViewData::Depth { depth, color } => {
                    files.push(self.dir.join(depth));
                    files.extend(color.iter().map(|c| self.dir.join(c)));
                }
                ViewData::Points { points } => files.push(self.dir.join(points)),
                ViewData::Images { .. } => {}
            }
        }
        files
    }

    /// The depth camera (`camera` in `scan.json`).
    ///
    /// # Errors
    /// [`Error::Field`] (`camera`) when the scan has none.
    pub fn depth_camera(&self) -> Result<&DepthCamera> {
        self.camera.as_ref().ok_or_else(|| Error::field(Self::manifest_path(&self.dir), "camera", "missing"))
    }

    /// The recorded `T_world_camera` of view `index`.
    ///
    /// # Errors
    /// [`Error::Field`] when the view gives `T_base_ee` but the scan has no `T_ee_camera`
    /// (the reader already refuses that, so only hand-built scans reach it), or the index is out of range.
    pub fn world_from_camera(&self, index: usize) -> Result<Isometry3<f64>> {
        let manifest = Self::manifest_path(&self.dir);
        match self.view(index)?.pose {
            ViewPose::Camera { world_from_camera } => Ok(world_from_camera),
            ViewPose::Chain { world_from_base, base_from_ee } => {
                let ee_from_camera = self
                    .ee_from_camera
                    .ok_or_else(|| Error::field(&manifest, "T_ee_camera", "missing, but views give T_base_ee"))?;
                Ok(world_from_base * base_from_ee * ee_from_camera)
            }
        }
    }
}
