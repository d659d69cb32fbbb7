//! rosbag2 recordings (ROS 2): reading MCAP and sqlite3 (`.db3`) bags without a ROS installation,
//! and importing them as an `awl-scan/1` folder (`awl import rosbag`).
//!
//! - [`Bag`]: a bag folder (its `metadata.yaml` beside `.mcap` / `.db3` files, read in name order)
//!   or a bare file, streamed message by message ([`mcap`]: chunk by chunk; [`db3`]: one query
//!   ordered by timestamp); the bag is never held in memory.
//! - [`cdr`]: the message layouts (`sensor_msgs/Image`, `CompressedImage`, `CameraInfo`,
//!   `tf2_msgs/TFMessage`, `std_msgs/Header`).
//! - [`tf`]: the TF buffer (interpolated lookups through the tree).
//! - [`still`]: still periods and the views taken in them.
//! - [`import`]: the import itself (two passes: TF, camera info and image stamps; then the chosen
//!   images written into the scan folder, atomically).

pub mod cdr;
mod db3;
pub mod import;
mod mcap;
pub mod still;
pub mod tf;

use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

pub use import::{ImportParams, ImportProgress, ImportReport, import_rosbag};

/// One message of a bag, borrowed for the duration of a callback.
#[derive(Debug, Clone, Copy)]
pub struct BagMessage<'a> {
    /// The topic, e.g. `/camera/depth/image_rect_raw`.
    pub topic: &'a str,
    /// The message type as the bag names it, e.g. `sensor_msgs/msg/Image`.
    pub type_name: &'a str,
    /// The time the recorder received it, ns since the epoch.
    pub log_time_ns: u64,
    /// The CDR-serialised message.
    pub data: &'a [u8],
}

/// The storage of one bag file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Storage {
    /// MCAP (rosbag2's default since Iron).
    Mcap,
    /// SQLite 3 (`.db3`, Humble's default).
    Sqlite3,
}

impl Storage {
    /// `mcap` or `sqlite3`, as rosbag2's `storage_identifier`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Mcap => "mcap",
            Self::Sqlite3 => "sqlite3",
        }
    }
}

/// A rosbag2 recording: its files, each with its storage, read in order.
#[derive(Debug, Clone, PartialEq)]
pub struct Bag {
    /// The path given (a bag folder or a file).
    pub path: PathBuf,
    /// The bag's files and their storage, in reading order.
    pub files: Vec<(PathBuf, Storage)>,
}

const MCAP_MAGIC: &[u8] = b"\x89MCAP0\r\n";
const SQLITE_MAGIC: &[u8] = b"SQLite format 3\0";

fn storage_of(path: &Path) -> Result<Storage> {
    use std::io::Read;
    let mut head = [0u8; 16];
    let mut file = crate::io::open_regular(path)?;
    let n = file.read(&mut head).map_err(|e| Error::io(path, e))?;
    let head = &head[..n];
    if head.starts_with(MCAP_MAGIC) {
        Ok(Storage::Mcap)
    } else if head.starts_with(SQLITE_MAGIC) {
        Ok(Storage::Sqlite3)
    } else if head.starts_with(&[0x28, 0xb5, 0x2f, 0xfd]) {
        Err(Error::format(
            path,
            "a zstd-compressed bag file (rosbag2 file compression): decompress it first (`zstd -d`)",
        ))
    } else {
        Err(Error::format(path, "neither an MCAP file nor a rosbag2 sqlite3 (.db3) file (by its first bytes)"))
    }
}

/// A split bag file's name without its trailing number, and the number (`bag_10.mcap` -> ("bag_", 10)).
fn split_index(path: &Path) -> (String, u64, String) {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let digits = stem.len() - stem.trim_end_matches(|c: char| c.is_ascii_digit()).len();
    let (name, number) = stem.split_at(stem.len() - digits);
    (name.to_string(), number.parse().unwrap_or(0), path.to_string_lossy().into_owned())
}

impl Bag {
    /// Opens a bag folder (its `.mcap` and `.db3` files in name order) or a bare `.mcap` / `.db3`
    /// file (told apart by their first bytes).
    ///
    /// # Errors
    /// [`Error::Io`] when the path cannot be read; [`Error::Format`] when a file is neither MCAP
    /// nor SQLite, or a folder holds no bag file.
    pub fn open(path: &Path) -> Result<Self> {
        let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
        let files = if meta.is_dir() {
            let mut names: Vec<PathBuf> = std::fs::read_dir(path)
                .map_err(|e| Error::io(path, e))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| matches!(crate::io::extension(p).as_str(), "mcap" | "db3" | "zstd"))
                .collect();
            // rosbag2 splits a recording into `NAME_0.mcap`, `NAME_1.mcap`, ..., `NAME_10.mcap`
            names.sort_by_key(|p| split_index(p));
            if names.is_empty() {
                return Err(Error::format(path, "a bag folder with no .mcap or .db3 file"));
            }
            names.into_iter().map(|p| storage_of(&p).map(|s| (p, s))).collect::<Result<Vec<_>>>()?
        } else {
            vec![(path.to_path_buf(), storage_of(path)?)]
        };
        Ok(Self { path: path.to_path_buf(), files })
    }

    /// The length of one pass for a progress bar: bytes of MCAP files plus messages of sqlite3 files.
    ///
    /// # Errors
    /// [`Error::Io`] / [`Error::Format`] when a file cannot be read.
    pub fn progress_total(&self) -> Result<u64> {
        let mut total = 0;
        for (path, storage) in &self.files {
            total += match storage {
                Storage::Mcap => std::fs::metadata(path).map_err(|e| Error::io(path, e))?.len(),
                Storage::Sqlite3 => db3::message_count(path)?,
            };
        }
        Ok(total)
    }

    /// Calls `f` on every message whose topic `wanted` accepts, file by file (MCAP in file order,
    /// sqlite3 by timestamp); `progress` gets the pass's position in [`Bag::progress_total`]'s units.
    ///
    /// # Errors
    /// [`Error::Format`] naming the file when it is truncated or damaged, or a topic is not CDR;
    /// `f`'s error.
    pub fn for_each(
        &self,
        wanted: &dyn Fn(&str) -> bool,
        progress: &mut dyn FnMut(u64),
        f: &mut dyn FnMut(&BagMessage<'_>) -> Result<()>,
    ) -> Result<()> {
        let mut before = 0;
        for (path, storage) in &self.files {
            let mut last = 0;
            let mut file_progress = |n: u64| {
                last = n;
                progress(before + n);
            };
            match storage {
                Storage::Mcap => mcap::for_each(path, wanted, &mut file_progress, f)?,
                Storage::Sqlite3 => db3::for_each(path, wanted, &mut file_progress, f)?,
            }
            before += last;
        }
        Ok(())
    }
}
