//! The modeling pipeline (`awl fuse`): views with recorded poses -> one model of the object alone.
//!
//! `fuse::fuse` reads like the method: prepare each view (depth -> points, voxel, outliers, normals),
//! register views sequentially against the growing model (coarse-to-fine point-to-plane ICP seeded
//! by the recorded poses, with an explicit acceptance rule), refine every view against all the
//! others, refine the hand-eye from the base stops, merge, remove the floor, keep the object's cluster,
//! smooth (MLS).

mod clean;
pub mod config;
pub mod fuse;
pub mod hand_eye;
mod isolate;
mod multiview;
mod prepare;
pub mod report;
mod stream;

pub use config::{AcceptanceRule, FuseConfig, RejectPolicy, RoiConfig};
pub use fuse::{FuseOutput, Progress, fuse};
pub use hand_eye::{HandEyeConfig, HandEyeReport};
pub use report::{FuseReport, StageReport, ViewReport, ViewStatus};
