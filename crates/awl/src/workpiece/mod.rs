//! The workpiece at piercing time: where the AprilTag is on the fused model, and targets on it.
//!
//! - [`tag_pose`]: `T_world_tag` from every color view of a fused scan that sees the declared tag
//!   (detect, pose with the depth-resolved ambiguity, registered view pose, robust SE(3) mean:
//!   [`mean`]), then [`refine`]d on the model's points in the tag square.
//! - [`file`]: the `workpiece.json` record `awl fuse` writes (`awl-workpiece/1`; I/O in
//!   [`crate::workpiece::json`]); [`model_check`]: its model's fingerprint, checked by `awl pierce`.
//! - [`targets`] / [`face`]: a point snapped onto the surface, or the centre of the planar face nearest
//!   a point, with the outward normal and the piercing axis; [`target_spec`] parses target strings.
//!
//! Frames: the model and every pose here are in the scan's world frame (the fused model's frame);
//! the tag frame is awl's (x right, y up, z out of the face).

pub mod face;
pub mod file;
pub mod json;
pub mod mean;
pub mod model_check;
pub mod refine;
pub mod tag_pose;
pub mod target_spec;
pub mod targets;

pub use face::FaceParams;
pub use file::{
    FloorPlane, WORKPIECE_FILE, WORKPIECE_FORMAT, Workpiece, WorkpieceParams, workpiece_from_fuse,
    workpiece_from_search,
};
pub use mean::{MeanParams, PoseMean, robust_mean};
pub use model_check::ModelCheck;
pub use refine::{RefineParams, Refinement, refine_on_model};
pub use tag_pose::{
    Sighting, TagEstimate, TagEstimateParams, TagSearch, TagView, ViewTagDetection, estimate_from_views,
    estimate_world_from_tag, search_tags,
};
pub use target_spec::{MAX_TARGETS, TargetSpec, check_target_count, parse_targets};
pub use targets::{SurfaceModel, SurfaceTarget, TargetParams};
