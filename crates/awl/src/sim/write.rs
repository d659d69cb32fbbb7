//! Writing a simulation as a scan folder, atomically: everything goes into a hidden sibling folder
//! that is renamed into place at the end, so a reader never sees half a scan.

use std::fs;
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::io::image::{write_color_png, write_depth_png};
use crate::io::ply::write_ply_mesh;
use crate::io::scan::write_scan;
use crate::io::truth::write_truth;
use crate::io::{write_atomic, write_folder_atomically};
use crate::scan::ViewData;
use crate::sim::{LabelImage, Simulation};

fn label_png(image: &LabelImage) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, image.width, image.height);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.set_compression(png::Compression::Fast);
    let written = encoder.write_header().and_then(|mut w| w.write_image_data(&image.data));
    written.map_err(|e| Error::invalid("label PNG encoder", e.to_string()))?;
    Ok(out)
}

fn write_views(tmp: &Path, sim: &Simulation) -> Result<()> {
    for sub in ["depth", "color", "labels"] {
        fs::create_dir_all(tmp.join(sub)).map_err(|e| Error::io(tmp.join(sub), e))?;
    }
    sim.views.par_iter().enumerate().try_for_each(|(i, view)| {
        let spec = sim
            .scan
            .views
            .get(i)
            .ok_or_else(|| Error::invalid("simulation", format!("no manifest entry for view {i}")))?;
        let ViewData::Depth { depth, color } = &spec.data else {
            return Err(Error::invalid("simulation", format!("view {i} is not a depth view")));
        };
        write_depth_png(&tmp.join(depth), &view.depth)?;
        if let Some(color) = color {
            write_color_png(&tmp.join(color), &view.color)?;
        }
        let label = sim
            .truth
            .views
            .get(i)
            .and_then(|t| t.label.clone())
            .unwrap_or_else(|| PathBuf::from(format!("labels/{i:06}.png")));
        write_atomic(&tmp.join(label), &label_png(&view.labels)?)
    })
}

fn write_all(tmp: &Path, sim: &Simulation) -> Result<()> {
    fs::create_dir_all(tmp).map_err(|e| Error::io(tmp, e))?;
    write_views(tmp, sim)?;
    write_ply_mesh(&tmp.join(&sim.truth.cad), &sim.cad)?;
    write_truth(tmp, &sim.truth)?;
    let mut scan = sim.scan.clone();
    scan.dir = tmp.to_path_buf();
    write_scan(&scan)
}

/// Writes `sim` as the scan folder `dir`: `scan.json`, `truth.json`, `cad.ply`, and `depth/`,
/// `color/`, `labels/` PNGs. The folder appears complete or not at all.
///
/// # Errors
/// [`Error::Invalid`] when `dir` exists, is not empty and `overwrite` is false (or is a file);
/// [`Error::Io`] naming the file when writing fails (the temporary folder is removed).
pub fn write_simulation(dir: &Path, sim: &Simulation, overwrite: bool) -> Result<()> {
    write_folder_atomically(dir, overwrite, |tmp| write_all(tmp, sim))
}
