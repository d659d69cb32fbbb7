//! What the fuzz targets share: a per-process scratch file for the readers that take a path, and
//! the check that every error names the file it is about.

use std::path::{Path, PathBuf};

/// The scratch folder of this process (`/dev/shm` when there is one: no disk writes).
fn scratch() -> PathBuf {
    let shm = Path::new("/dev/shm");
    let root = if shm.is_dir() { shm.to_path_buf() } else { std::env::temp_dir() };
    let dir = root.join(format!("awl-fuzz-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    dir
}

/// Writes `data` as `name` in this process's scratch folder and returns its path.
pub fn file(name: &str, data: &[u8]) -> PathBuf {
    let path = scratch().join(name);
    std::fs::write(&path, data).expect("the fuzz scratch file");
    path
}

/// A path that only names inputs parsed from memory (it is never read).
pub fn name(name: &str) -> PathBuf {
    Path::new("/fuzz").join(name)
}

/// Panics (a finding for libFuzzer) when `result`'s error does not name `path`'s file.
pub fn names_the_file<T>(path: &Path, result: awl::Result<T>) -> Option<T> {
    match result {
        Ok(v) => Some(v),
        Err(e) => {
            let message = e.to_string();
            let file = path.file_name().and_then(|n| n.to_str()).unwrap_or_default();
            assert!(message.contains(file), "the error does not name {file}: {message}");
            None
        }
    }
}
