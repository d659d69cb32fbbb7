//! Down-sampling and outlier removal: the first stages after loading a view.
//!
//! - [`voxel`]: one centroid per occupied voxel (sparse keys, output sorted by voxel key).
//! - [`voxel_merge`]: the same down-sampling of a union of clouds added one by one, without
//!   holding the union.
//! - [`outlier`]: statistical and radius outlier removal with Open3D 0.20's exact rules; they
//!   return the kept indices, for [`crate::PointCloud::select`].
//!
//! Every function takes the cloud and a `*Params` struct (serde, documented defaults) and gives the
//! same output with any number of rayon threads.

pub mod outlier;
pub mod voxel;
pub mod voxel_merge;
