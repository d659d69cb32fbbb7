//! Helpers shared by subcommands: thread count, progress display, JSON output, a non-empty output
//! folder. The outputs' check against the inputs is the library's `awl::io::outputs::OutputCheck`.

use std::io::IsTerminal;
use std::path::Path;

use anyhow::Context;
use awl::io::outputs::{OutputCheck, OutputGuard};
use indicatif::{ProgressBar, ProgressStyle};

/// Sets the number of worker threads once for the whole process (default: all cores).
pub fn set_threads(threads: Option<usize>) -> anyhow::Result<()> {
    if let Some(n) = threads {
        anyhow::ensure!(n > 0, "--threads must be at least 1");
        let cores = std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get);
        let max = (4 * cores).max(16);
        anyhow::ensure!(
            n <= max,
            "--threads {n} is more than {max} (4x the {cores} cores here, at least 16): each thread holds its own \
             buffers; give at most {max}"
        );
        rayon::ThreadPoolBuilder::new().num_threads(n).build_global().context("cannot set up the thread pool")?;
    }
    Ok(())
}

/// A stage progress bar on stderr, hidden when `quiet` or when stderr is not a terminal.
pub fn stage_bar(quiet: bool) -> ProgressBar {
    if quiet || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(1);
    let style = ProgressStyle::with_template("{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} {msg}")
        .unwrap_or_else(|_| ProgressStyle::default_bar());
    bar.set_style(style);
    bar.enable_steady_tick(std::time::Duration::from_millis(120));
    bar
}

/// A progress bar over `total` items on stderr, hidden when `quiet`, when stderr is not a terminal
/// or when there are fewer than 20 items (done before a bar is worth drawing).
pub fn count_bar(quiet: bool, total: usize, what: &str) -> ProgressBar {
    if quiet || total < 20 || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(total as u64);
    let style = ProgressStyle::with_template("{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} {msg} (eta {eta})")
        .unwrap_or_else(|_| ProgressStyle::default_bar());
    bar.set_style(style);
    bar.set_message(what.to_string());
    bar.enable_steady_tick(std::time::Duration::from_millis(120));
    bar
}

/// Reads a point cloud (`.ply` / `.pcd`), printing what the reader dropped or ignored (non-finite
/// points, bytes after the body) as warnings on stderr.
pub fn read_cloud_warned(path: &Path) -> awl::Result<awl::PointCloud> {
    let loaded = awl::io::mesh::read_cloud_checked(path)?;
    loaded.warnings.iter().for_each(|w| eprintln!("warning: {w}"));
    Ok(loaded.value)
}

/// Reads a mesh (`.ply` / `.stl` / `.obj`), printing what the reader ignored as warnings on stderr.
pub fn read_mesh_warned(path: &Path) -> awl::Result<awl::mesh::TriMesh> {
    let loaded = awl::io::mesh::read_mesh_checked(path)?;
    loaded.warnings.iter().for_each(|w| eprintln!("warning: {w}"));
    Ok(loaded.value)
}

/// Checks a command's outputs against its inputs and takes their locks ([`OutputCheck::check_and_lock`]),
/// printing on stderr what taking them cleared (a dead run's lock or staging folder). Keep the guard
/// until the outputs are written: dropping it releases the locks.
pub fn lock_outputs(check: &OutputCheck) -> anyhow::Result<OutputGuard> {
    let guard = check.check_and_lock()?;
    for note in guard.notes() {
        eprintln!("note: {note}");
    }
    Ok(guard)
}

/// Writes pretty JSON atomically.
pub fn write_json(path: &Path, value: &impl serde::Serialize) -> anyhow::Result<()> {
    let text = serde_json::to_string_pretty(value)?;
    awl::io::write_atomic(path, text.as_bytes())?;
    Ok(())
}

/// Refuses a non-empty output `dir` without `force`; with it, removes the command's own `subfolders`
/// there (other files are kept).
pub fn prepare_output(dir: &Path, force: bool, subfolders: &[&str]) -> anyhow::Result<()> {
    let non_empty = match std::fs::read_dir(dir) {
        Ok(mut entries) => entries.next().is_some(),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => false,
        Err(e) => return Err(e).with_context(|| format!("{}: cannot read the output folder", dir.display())),
    };
    if non_empty && !force {
        anyhow::bail!(
            "{}: the output folder exists and is not empty (pass --force to replace its results)",
            dir.display()
        );
    }
    for sub in subfolders {
        let path = dir.join(sub);
        if path.exists() {
            std::fs::remove_dir_all(&path).with_context(|| format!("{}: cannot remove", path.display()))?;
        }
    }
    Ok(())
}

/// `awl pierce` planned, but refused some targets (exit code [`NoGo::EXIT_CODE`]).
#[derive(Debug)]
pub struct NoGo {
    /// Targets refused.
    pub refused: usize,
    /// Targets planned.
    pub targets: usize,
}

impl NoGo {
    /// The process exit code: the plan was written, and these targets are left out of the programs.
    pub const EXIT_CODE: u8 = 3;
}

impl std::fmt::Display for NoGo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} of {} target(s) are no-go (a predicted error over the tolerance, or out of the arm's reach): they are \
             left out of the robot programs; plan.json says why (exit code {})",
            self.refused,
            self.targets,
            Self::EXIT_CODE
        )
    }
}

impl std::error::Error for NoGo {}
