//! Self-contained HTML reports: a generic [`Page`] (tables, PNG renders as data URIs, inline SVG
//! plots, an interactive WebGL point view) and the page of `awl fuse`. The HTML needs no network.

pub mod base64;
pub mod fuse;
pub mod page;
pub mod viewer;

#[cfg(test)]
mod fuse_tests;

pub use fuse::{FusePage, FusePageParams, fuse_page};
pub use page::{Block, KeyValue, Page, Picture, Section, Table};
pub use viewer::{DEFAULT_MAX_POINTS, ViewerCloud};
