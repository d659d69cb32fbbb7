//! awl: model a large, unknown workpiece from many depth views, then plan piercing poses on it.
//!
//! Frames and units: transforms are `a_from_b` (maps points from frame b to frame a; `T_a_b` in
//! files), metres and radians everywhere unless a name says otherwise. See `ARCHITECTURE.md`.
#![deny(missing_docs)]
#![forbid(unsafe_code)]

pub mod camera;
pub mod cloud;
pub mod cluster;
pub mod error;
#[cfg(feature = "eval")]
pub mod eval;
pub mod filter;
pub mod handeye;
pub mod image;
pub mod io;
pub mod job;
pub mod kinematics;
pub mod mesh;
pub mod normals;
pub mod octahedral;
pub mod off;
pub mod organized;
pub mod pierce;
pub mod pipeline;
pub mod plan_views;
#[cfg(any(test, feature = "sim"))]
pub(crate) mod random;
pub mod registration;
#[cfg(feature = "report")]
pub mod render;
#[cfg(feature = "report")]
pub mod report_html;
pub mod robot;
pub mod rosbag;
pub mod scan;
pub mod segment;
#[cfg(any(test, feature = "sim"))]
pub mod sim;
pub mod smooth;
pub mod spatial;
pub mod tag;
pub mod transform;
#[cfg(feature = "trial")]
pub mod trial;
pub mod workpiece;

pub use cloud::PointCloud;
pub use error::{Error, Result};
