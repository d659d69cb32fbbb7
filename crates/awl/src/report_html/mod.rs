//! Self-contained HTML reports: a generic [`Page`] (tables, PNG renders as data URIs, inline SVG
//! plots, an interactive WebGL point view) and the pages of `awl fuse` and `awl evaluate`. The HTML needs no network.

pub mod base64;
pub mod evaluate;
pub mod fuse;
pub mod page;
pub mod rendered;
pub mod viewer;
pub mod write;

#[cfg(test)]
mod evaluate_tests;
#[cfg(test)]
mod fuse_tests;

pub use evaluate::evaluate_page;
pub use fuse::fuse_page;
pub use page::{Block, KeyValue, Page, Picture, Section, Table};
pub use rendered::{PageParams, RenderedPage};
pub use viewer::{DEFAULT_MAX_POINTS, ViewerCloud};
