//! The modeling pipeline (`awl fuse`): views with recorded poses -> one model of the object alone.
//!
//! [`fuse::fuse`] runs these stages with the default [`FuseConfig`], in this order:
//! 1. prepare each view (`prepare`): load (depth -> points, every `pixel_step`-th row and column),
//!    crop to the region of interest around the point the cameras look at, outliers and normals on
//!    the view's pixel grid (with the registration's copy moved onto local planes), grazing points
//!    dropped, voxel down-sampling, the normals of the view's dominant horizontal plane snapped to
//!    it. The views come from a feed (`feed`) that prepares them all first, in parallel, and holds
//!    them, or (`view_memory = "stream"`, the `fast` preset) prepares each as it is registered and
//!    keeps only its measured points once merged;
//! 2. register the views one by one against the growing model (`register`): the anchor (the first
//!    usable view) at its recorded pose, then coarse-to-fine point-to-plane ICP seeded by each
//!    view's recorded pose, the view nearest a merged one next, each judged by the acceptance rule
//!    (a rejected view is left out, or with `on_reject = "keep-seed"` merged at its recorded pose);
//! 3. the joint refinement (`registration::joint`): the anchor and the accepted views, every
//!    overlapping pair in one system, the anchor fixed; it undoes the sequential pass's drift
//!    (held views only: the `fast` preset has none);
//! 4. the hand-eye refined from the registered base stops (`hand_eye`): into the report, the model
//!    untouched; with it the advice on where more views would gain (`advice`);
//! 5. merge: the views' measured points at their poses, down-sampled on one voxel grid;
//! 6. isolate (`isolate`): the floor plane removed, the object's DBSCAN cluster kept;
//! 7. smooth (MLS).

pub mod advice;
mod clean;
pub mod config;
mod feed;
pub mod fuse;
pub mod hand_eye;
mod isolate;
mod prepare;
mod register;
pub mod report;

pub use config::{AcceptanceRule, FuseConfig, RejectPolicy, RoiConfig, ViewMemory};
pub use fuse::{FuseOutput, Progress, fuse};
pub use hand_eye::{HandEyeConfig, HandEyeReport};
pub use report::{FuseReport, StageReport, ViewReport, ViewStatus};
