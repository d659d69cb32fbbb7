//! Everything that touches the filesystem: point-cloud and mesh files, images, the scan folder.
//!
//! Every error names the file (and the field, for structured files). Writers are atomic: they
//! write a temporary sibling and rename it into place, so a crash never leaves half a file.

pub mod capture;
pub mod image;
pub mod lock;
pub mod mesh;
pub mod outputs;
pub mod pcd;
mod pcd_header;
pub mod ply;
mod ply_header;
pub mod scan;
pub mod truth;

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// What a reader returns when it can also notice things worth telling the user without refusing
/// the file: the value, and its warnings (each naming the file: non-finite points dropped, bytes
/// after the body the header declares). The library never prints them; the CLI does.
#[derive(Debug, Clone, PartialEq)]
pub struct Loaded<T> {
    /// What was read.
    pub value: T,
    /// What reading it dropped or ignored, one sentence each, naming the file.
    pub warnings: Vec<String>,
}

/// Reads a whole regular file (a symlink to one is followed), naming it in the error.
///
/// # Errors
/// [`Error::Io`] when the file cannot be read; [`Error::Format`] when it is not a regular file
/// ([`open_regular`]).
pub fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    read_bytes_at_most(path, u64::MAX)
}

/// The largest JSON file awl reads, bytes: 64 MiB (a 100 000-view scan.json with chain poses,
/// written with indentation, is about 50 MB; parsing takes a few times the text's size).
pub const MAX_JSON_BYTES: u64 = 64 << 20;

/// Reads a whole regular file of at most `max_bytes`, its size checked before anything is read.
///
/// # Errors
/// [`read_bytes`]'s, and [`Error::Format`] naming the file, its size and the limit when it is larger.
pub fn read_bytes_at_most(path: &Path, max_bytes: u64) -> Result<Vec<u8>> {
    use std::io::Read;
    let file = open_regular(path)?;
    let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let too_big = |len: u64| {
        Error::format(
            path,
            format!(
                "{len} bytes, more than the {max_bytes} bytes awl reads from a file of this kind (is it the right file?)"
            ),
        )
    };
    if len > max_bytes {
        return Err(too_big(len));
    }
    let mut bytes = Vec::with_capacity(usize::try_from(len).unwrap_or(0));
    // (a file growing while it is read stops at the limit too)
    file.take(max_bytes.saturating_add(1)).read_to_end(&mut bytes).map_err(|e| Error::io(path, e))?;
    if bytes.len() as u64 > max_bytes {
        return Err(too_big(bytes.len() as u64));
    }
    Ok(bytes)
}

/// Reads a whole regular text file of at most `max_bytes` ([`read_bytes_at_most`]).
///
/// # Errors
/// [`read_bytes_at_most`]'s, and [`Error::Format`] naming the file when it is not UTF-8 text.
pub fn read_text_at_most(path: &Path, max_bytes: u64) -> Result<String> {
    String::from_utf8(read_bytes_at_most(path, max_bytes)?)
        .map_err(|e| Error::format(path, format!("not UTF-8 text (byte {})", e.utf8_error().valid_up_to())))
}

/// Opens `path` for reading when it is a regular file, a symlink followed: a folder, a FIFO, a
/// socket or a device (`/dev/zero`) is refused before it is opened, so no read can block or run
/// without end.
///
/// # Errors
/// [`Error::Io`] when `path` cannot be examined or opened; [`Error::Format`] naming what it is when
/// it is not a regular file.
pub fn open_regular(path: &Path) -> Result<fs::File> {
    let meta = fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if !meta.is_file() {
        use std::os::unix::fs::FileTypeExt;
        let t = meta.file_type();
        let what = if t.is_dir() {
            "a folder"
        } else if t.is_fifo() {
            "a FIFO (named pipe)"
        } else if t.is_socket() {
            "a socket"
        } else if t.is_char_device() || t.is_block_device() {
            "a device"
        } else {
            "not a regular file"
        };
        return Err(Error::format(
            path,
            format!("{what}, not a regular file: awl reads files saved on disk; save it to one first"),
        ));
    }
    fs::File::open(path).map_err(|e| Error::io(path, e))
}

/// Writes `bytes` to `path` atomically: a temporary file beside it, fsync, then rename.
///
/// # Errors
/// [`Error::Io`] naming `path` when any step fails; [`Error::Invalid`] from
/// [`lock::confirm_write`] when a lock of this run covering `path` is no longer its own, or `path`
/// appeared meanwhile (without `--force`). The temporary file is removed.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = temp_sibling(path);
    let result = (|| {
        let mut file = fs::File::create(&tmp)?;
        file.write_all(bytes)?;
        file.sync_all()
    })()
    .map_err(|e| Error::io(path, e))
    .and_then(|()| lock::confirm_write(path))
    .and_then(|()| fs::rename(&tmp, path).map_err(|e| Error::io(path, e)));
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// A hidden temporary path next to `path`, unique to this process.
pub fn temp_sibling(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}.tmp-{}", std::process::id()))
}

/// Whether `dir` is a folder with something in it (`false` when it does not exist).
///
/// # Errors
/// [`Error::Invalid`] when `dir` is a file; [`Error::Io`] when it cannot be read.
pub fn is_non_empty_dir(dir: &Path) -> Result<bool> {
    match fs::read_dir(dir) {
        Ok(mut entries) => Ok(entries.next().is_some()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(false),
        Err(e) if e.kind() == std::io::ErrorKind::NotADirectory => {
            Err(Error::invalid(dir.display().to_string(), "exists and is not a folder"))
        }
        Err(e) => Err(Error::io(dir, e)),
    }
}

/// Writes the folder `dir` atomically: `fill` writes everything into a hidden temporary sibling
/// folder, which is renamed into place when it succeeds (and removed when it fails), so `dir`
/// appears complete or not at all (an existing `dir` is kept until the new one is in place).
///
/// # Errors
/// [`Error::Invalid`] when `dir` exists, is not empty and `overwrite` is false (or is a file);
/// `fill`'s error, or [`Error::Io`] naming the folder when the move fails.
pub fn write_folder_atomically(dir: &Path, overwrite: bool, fill: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    if is_non_empty_dir(dir)? && !overwrite {
        return Err(Error::invalid(
            dir.display().to_string(),
            "the output folder exists and is not empty (pass --force to replace it)",
        ));
    }
    if let Some(parent) = dir.parent().filter(|p| !p.as_os_str().is_empty()) {
        fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    let tmp = temp_sibling(dir);
    if tmp.exists() {
        fs::remove_dir_all(&tmp).map_err(|e| Error::io(&tmp, e))?;
    }
    let result = fs::create_dir_all(&tmp)
        .map_err(|e| Error::io(&tmp, e))
        .and_then(|()| fill(&tmp))
        .and_then(|()| crate::io::outputs::replace_folder(&tmp, dir));
    if result.is_err() {
        let _ = fs::remove_dir_all(&tmp);
    }
    result
}

/// Lower-case file extension, or "" when there is none.
pub fn extension(path: &Path) -> String {
    path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).unwrap_or_default()
}
