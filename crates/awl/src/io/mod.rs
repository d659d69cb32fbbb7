//! Everything that touches the filesystem: point-cloud and mesh files, images, the scan folder.
//!
//! Every error names the file (and the field, for structured files). Writers are atomic: they
//! write a temporary sibling and rename it into place, so a crash never leaves half a file.

pub mod arm;
pub mod capture;
pub mod evaluation;
pub mod handeye;
pub mod image;
pub mod mesh;
pub mod outputs;
pub mod pcd;
mod pcd_header;
pub mod plan;
pub mod ply;
mod ply_header;
pub mod report;
pub mod scan;
pub mod truth;
pub mod workpiece;

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// Reads a whole file, naming it in the error.
///
/// # Errors
/// [`Error::Io`] when the file cannot be read.
pub fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    fs::read(path).map_err(|e| Error::io(path, e))
}

/// Writes `bytes` to `path` atomically: a temporary file beside it, fsync, then rename.
///
/// # Errors
/// [`Error::Io`] naming `path` when any step fails; the temporary file is removed.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = temp_sibling(path);
    let result = (|| {
        let mut file = fs::File::create(&tmp)?;
        file.write_all(bytes)?;
        file.sync_all()?;
        fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        let _ = fs::remove_file(&tmp);
        return Err(Error::io(path, e));
    }
    Ok(())
}

/// A hidden temporary path next to `path`, unique to this process.
pub fn temp_sibling(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}.tmp-{}", std::process::id()))
}

/// Lower-case file extension, or "" when there is none.
pub fn extension(path: &Path) -> String {
    path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).unwrap_or_default()
}
