//! Registration: point-to-plane ICP with a robust kernel, coarse to fine.
//!
//! Frames: `target_from_source` maps source points into the target's frame. Units: metres, radians.

pub mod icp;
pub mod joint;
pub mod kernel;
mod solve;

pub use icp::{
    IcpLevel, IcpParams, IcpResult, LevelStats, MotionKind, PreparedTarget, Unobserved, register, register_levels,
    register_levels_expecting, register_prepared,
};
pub use joint::{JointLevelStats, refine_jointly};
pub use kernel::Kernel;
