//! The modeling pipeline (`awl fuse`): views with recorded poses -> one model of the object alone.
//!
//! [`fuse::fuse`] runs these stages with the default [`FuseConfig`], in this order:
//! 1. prepare each view, the views in parallel (`prepare`): load (depth -> points, every
//!    `pixel_step`-th row and column), crop to the region of interest around the point the cameras
//!    look at, outliers and normals on the view's pixel grid (with the registration's copy moved
//!    onto local planes), grazing points dropped, voxel down-sampling, the normals of the view's
//!    dominant horizontal plane snapped to it;
//! 2. register the views one by one against the growing model (`multiview`): the anchor (the first
//!    usable view) at its recorded pose, then coarse-to-fine point-to-plane ICP seeded by each
//!    view's recorded pose, the view nearest a merged one next, each judged by the acceptance rule
//!    (a rejected view is left out);
//! 3. the joint refinement (`registration::joint`): the anchor and the accepted views, every
//!    overlapping pair in one system, the anchor fixed; it undoes the sequential pass's drift;
//! 4. the hand-eye refined from the registered base stops (`hand_eye`): into the report, the model
//!    untouched;
//! 5. merge: the views' measured points at their poses, down-sampled on one voxel grid;
//! 6. isolate (`isolate`): the floor plane removed, the object's DBSCAN cluster kept;
//! 7. smooth (MLS).
//!
//! Off by default: rounds of registering each accepted view again against all the others
//! (`registration.refine_rounds`, between 2 and 3). The `fast` preset has no joint refinement and
//! streams its views (`stream`): each one registered as it is prepared, only its measured points
//! kept once it is merged.

mod clean;
pub mod config;
pub mod fuse;
pub mod hand_eye;
mod isolate;
mod multiview;
mod prepare;
pub mod report;
mod stream;

pub use config::{AcceptanceRule, FuseConfig, RejectPolicy, RoiConfig, ViewMemory};
pub use fuse::{FuseOutput, Progress, fuse};
pub use hand_eye::{HandEyeConfig, HandEyeReport};
pub use report::{FuseReport, StageReport, ViewReport, ViewStatus};
