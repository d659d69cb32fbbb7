//! What the report pages share: their parameters and the page together with its renders.

use serde::{Deserialize, Serialize};

use super::page::Page;
use super::viewer::DEFAULT_MAX_POINTS;
use crate::render::{RenderParams, Viewpoint};

/// What goes into a report page (`awl fuse`'s and `awl evaluate`'s).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PageParams {
    /// Size and look of the renders, legend included (default 800 x 600).
    pub render: RenderParams,
    /// Viewpoints rendered (default front, side, top, iso).
    pub views: Vec<Viewpoint>,
    /// Most points embedded in the interactive view (default 200 000).
    pub max_viewer_points: usize,
}

impl Default for PageParams {
    fn default() -> Self {
        Self { render: RenderParams::default(), views: Viewpoint::ALL.to_vec(), max_viewer_points: DEFAULT_MAX_POINTS }
    }
}

/// A page and the renders in it (file name such as `front.png`, PNG bytes) for writing beside it.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderedPage {
    /// The page.
    pub page: Page,
    /// The renders embedded in the page.
    pub renders: Vec<(String, Vec<u8>)>,
}
