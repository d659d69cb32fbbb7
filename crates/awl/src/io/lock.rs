//! One writer per output: a lock file beside each output path, taken when a command starts
//! ([`crate::io::outputs::OutputCheck::check`]) and confirmed when its outputs are put in place.
//!
//! The lock of `DIR/out` (folder or file) is the file `DIR/.out.awl-lock`, created with
//! `create_new` and holding its owner ([`LockOwner`]: pid, host, start time, the command line and a
//! token unique to the lock). A second run that wants the same output finds the file and is refused,
//! naming the output and the owner. A lock whose owner is dead (same host, no `/proc/<pid>` or a
//! process started at another time: the pid was reused) is stale: it is removed and taken, with a
//! note. So are the staging leftovers of a dead run beside the output (`.out.tmp-PID`, written by
//! [`crate::io::temp_sibling`], and `.out.old-PID`, an earlier output moved aside by
//! [`crate::io::outputs::replace_folder`]; the latter is put back when `out` is missing).
//!
//! Every held lock is also recorded in this process's registry: the writers that put an output in
//! place (`replace_folder`, `write_files_atomic`, `write_atomic`) call [`confirm_write`], which
//! refuses when the lock covering the path is no longer this run's (removed, or taken by another
//! run) and, without `force`, when the output appeared meanwhile. A write no lock covers (a library
//! user without an [`crate::io::outputs::OutputCheck`]) is not checked.
//!
//! Liveness is read from `/proc` (Linux); without it (or for a lock from another host) an owner is
//! taken as alive and its lock is never cleared.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// The suffix of a lock file's name (`.out.awl-lock` beside `out`).
pub const LOCK_SUFFIX: &str = ".awl-lock";

/// The lock file of `target` (a folder or file): `.NAME.awl-lock` beside it; `None` for a path
/// with no name (`/`).
pub fn lock_path(target: &Path) -> Option<PathBuf> {
    let name = target.file_name()?.to_string_lossy().into_owned();
    Some(target.with_file_name(format!(".{name}{LOCK_SUFFIX}")))
}

/// Who holds a lock: what the lock file holds (JSON).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct LockOwner {
    /// Process id.
    pub pid: u32,
    /// Host name (`/proc/sys/kernel/hostname`).
    pub host: String,
    /// When the lock was taken, seconds since 1970-01-01 UTC.
    pub started_unix_s: u64,
    /// The same, readable (`2026-05-01 12:34:56 UTC`).
    pub started: String,
    /// The process's start time in clock ticks after boot (`/proc/<pid>/stat` field 22), to tell a
    /// reused pid from the owner; `None` where `/proc` is missing.
    pub process_start_ticks: Option<u64>,
    /// The owner's command line.
    pub command: String,
    /// Unique to this lock: the commit compares it.
    pub token: String,
}

impl LockOwner {
    /// This process, now.
    fn current() -> Self {
        static COUNTER: AtomicU64 = AtomicU64::new(0);
        let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
        let pid = std::process::id();
        let command = std::env::args().collect::<Vec<_>>().join(" ");
        Self {
            pid,
            host: host_name(),
            started_unix_s: now.as_secs(),
            started: utc_text(now.as_secs()),
            process_start_ticks: process_start_ticks(pid),
            command,
            token: format!("{pid}-{}-{}", now.as_nanos(), COUNTER.fetch_add(1, Ordering::Relaxed)),
        }
    }

    /// `pid 123 on host `h`, started 2026-05-01 12:34:56 UTC (`awl fuse ...`)`.
    pub fn describe(&self) -> String {
        let command = if self.command.is_empty() { String::new() } else { format!(" (`{}`)", self.command) };
        format!("pid {} on host `{}`, started {}{command}", self.pid, self.host, self.started)
    }
}

/// Whether a process still runs, as far as this host can tell.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Liveness {
    /// It runs (or its pid is taken by a process started at the same tick).
    Alive,
    /// No such process here (or a zombie, or a pid reused by a process started later).
    Dead,
    /// Another host, or no `/proc`: taken as alive.
    Unknown,
}

/// The host's name: `/proc/sys/kernel/hostname`, `/etc/hostname`, `$HOSTNAME`, or `unknown`.
pub fn host_name() -> String {
    ["/proc/sys/kernel/hostname", "/etc/hostname"]
        .iter()
        .filter_map(|p| fs::read_to_string(p).ok())
        .map(|s| s.trim().to_string())
        .find(|s| !s.is_empty())
        .or_else(|| std::env::var("HOSTNAME").ok().filter(|s| !s.is_empty()))
        .unwrap_or_else(|| "unknown".to_string())
}

/// The state letter and start ticks of `/proc/<pid>/stat`; `None` when the file is missing.
fn proc_stat(pid: u32) -> Option<(char, Option<u64>)> {
    let text = fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // `pid (comm) S ...`: comm may hold spaces and parentheses, the fields start after the last `)`
    let rest = &text[text.rfind(')').map_or(0, |i| i + 1)..];
    let mut fields = rest.split_whitespace();
    let state = fields.next().and_then(|s| s.chars().next()).unwrap_or('?');
    // field 22 (starttime) is the 20th after the state (field 3)
    let ticks = fields.nth(18).and_then(|s| s.parse().ok());
    Some((state, ticks))
}

fn process_start_ticks(pid: u32) -> Option<u64> {
    proc_stat(pid).and_then(|(_, t)| t)
}

/// Whether process `pid` runs on this host; `start_ticks` (when known) must match its start time.
pub fn pid_liveness(pid: u32, start_ticks: Option<u64>) -> Liveness {
    if !Path::new("/proc/self/stat").exists() {
        return Liveness::Unknown;
    }
    match proc_stat(pid) {
        None => Liveness::Dead,
        Some(('Z' | 'X', _)) => Liveness::Dead,
        Some((_, ticks)) => match (start_ticks, ticks) {
            (Some(want), Some(got)) if want != got => Liveness::Dead,
            _ => Liveness::Alive,
        },
    }
}

/// Whether `owner` still runs (another host: [`Liveness::Unknown`]).
pub fn owner_liveness(owner: &LockOwner) -> Liveness {
    if owner.host != host_name() {
        return Liveness::Unknown;
    }
    pid_liveness(owner.pid, owner.process_start_ticks)
}

/// `secs` after 1970-01-01 as `YYYY-MM-DD hh:mm:ss UTC`.
pub fn utc_text(secs: u64) -> String {
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    // days to civil date (H. Hinnant's algorithm)
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!("{year:04}-{month:02}-{day:02} {:02}:{:02}:{:02} UTC", rem / 3600, rem % 3600 / 60, rem % 60)
}

/// The owner a lock file names; `None` when it cannot be read or parsed.
pub fn read_owner(lock: &Path) -> Option<LockOwner> {
    let text = fs::read_to_string(lock).ok()?;
    serde_json::from_str(&text).ok()
}

/// One lock file this process holds; removed on drop (when it is still ours), with the folders
/// made to hold it when they are left empty.
#[derive(Debug)]
pub struct LockFile {
    path: PathBuf,
    owner: LockOwner,
    made_dirs: Vec<PathBuf>,
}

impl LockFile {
    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// What it holds.
    pub fn owner(&self) -> &LockOwner {
        &self.owner
    }

    /// Takes the lock of `target` (resolved; `name` names it in messages: `-o `out``): clears a
    /// stale lock and the dead runs' staging leftovers beside `target` (each with a note in
    /// `notes`). `Ok(None)` for a target with no name.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming `name` and the owner when another live run (or one this host
    /// cannot judge) holds it, or when the lock file cannot be read; [`Error::Io`] naming the lock
    /// file or folder that cannot be made.
    pub fn acquire(target: &Path, name: &str, notes: &mut Vec<String>) -> Result<Option<Self>> {
        let Some(path) = lock_path(target) else { return Ok(None) };
        let made_dirs = match path.parent() {
            Some(parent) => make_dirs(parent)?,
            None => Vec::new(),
        };
        let owner = LockOwner::current();
        // the one who made the folders removes them if anything below fails
        let mut lock = Self { path, owner, made_dirs };
        lock.take(name, notes)?;
        clear_leftovers(target, notes);
        Ok(Some(lock))
    }

    fn take(&mut self, name: &str, notes: &mut Vec<String>) -> Result<()> {
        let text = serde_json::to_string_pretty(&self.owner).map_err(|e| Error::invalid(name, e.to_string()))?;
        for _ in 0..4 {
            match fs::OpenOptions::new().write(true).create_new(true).open(&self.path) {
                Ok(mut file) => {
                    let written = file.write_all(text.as_bytes()).and_then(|()| file.sync_all());
                    if let Err(e) = written {
                        let _ = fs::remove_file(&self.path);
                        return Err(Error::io(&self.path, e));
                    }
                    return Ok(());
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
                Err(e) => return Err(Error::io(&self.path, e)),
            }
            // the holder may be between creating the file and writing it: read twice
            let mut holder = read_owner(&self.path);
            if holder.is_none() && self.path.exists() {
                std::thread::sleep(std::time::Duration::from_millis(100));
                holder = read_owner(&self.path);
            }
            let Some(holder) = holder else {
                if !self.path.exists() {
                    continue; // released meanwhile
                }
                return Err(Error::invalid(
                    name,
                    format!(
                        "its lock file `{}` exists but cannot be read: another awl run may be writing this output; \
                         if none is, remove the lock file",
                        self.path.display()
                    ),
                ));
            };
            match owner_liveness(&holder) {
                Liveness::Dead => {
                    // another run may have cleared it first: only a file still naming the dead owner goes
                    if read_owner(&self.path).as_ref() == Some(&holder) {
                        fs::remove_file(&self.path).map_err(|e| Error::io(&self.path, e))?;
                        notes.push(format!(
                            "cleared the stale lock `{}` of a run that no longer exists ({})",
                            self.path.display(),
                            holder.describe()
                        ));
                    }
                }
                liveness => {
                    let judged = if liveness == Liveness::Unknown {
                        " (its host's processes cannot be seen from here)"
                    } else {
                        ""
                    };
                    return Err(Error::invalid(
                        name,
                        format!(
                            "another awl run is writing this output: {}{judged}; its lock is `{}`. Wait for it to \
                             finish or choose another output; if that process no longer runs, remove the lock file",
                            holder.describe(),
                            self.path.display()
                        ),
                    ));
                }
            }
        }
        Err(Error::invalid(
            name,
            format!("its lock `{}` kept changing hands: another awl run is starting on it", self.path.display()),
        ))
    }

    /// Whether the lock file still holds this lock.
    pub fn is_ours(&self) -> bool {
        read_owner(&self.path).is_some_and(|o| o.token == self.owner.token)
    }
}

impl Drop for LockFile {
    fn drop(&mut self) {
        if self.is_ours() {
            let _ = fs::remove_file(&self.path);
        }
        for dir in self.made_dirs.iter().rev() {
            // only an empty folder goes: one that received the output stays
            let _ = fs::remove_dir(dir);
        }
    }
}

/// Creates `dir` and its missing parents; returns the ones created, outermost first.
fn make_dirs(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut missing = Vec::new();
    let mut d = Some(dir);
    while let Some(p) = d.filter(|p| !p.as_os_str().is_empty() && fs::symlink_metadata(p).is_err()) {
        missing.push(p.to_path_buf());
        d = p.parent();
    }
    missing.reverse();
    for p in &missing {
        match fs::create_dir(p) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
            Err(e) => {
                for q in missing.iter().rev() {
                    let _ = fs::remove_dir(q);
                }
                return Err(Error::io(p, e));
            }
        }
    }
    Ok(missing)
}

/// The pid of a staging leftover of `name` (`.NAME.tmp-PID` or `.NAME.old-PID`) and whether it is
/// an earlier output moved aside (`old`); `None` for any other entry.
pub fn staging_pid(entry: &str, name: &str) -> Option<(u32, bool)> {
    for (marker, old) in [(".tmp-", false), (".old-", true)] {
        let prefix = format!(".{name}{marker}");
        if let Some(digits) = entry.strip_prefix(&prefix)
            && !digits.is_empty()
            && digits.bytes().all(|b| b.is_ascii_digit())
        {
            return digits.parse().ok().map(|pid| (pid, old));
        }
    }
    None
}

/// Removes the staging leftovers of dead runs beside `target` (see the module docs): only entries
/// named `.NAME.tmp-PID` or `.NAME.old-PID` whose pid is not this process's and no longer runs on
/// this host; an `.old-` folder is put back when `target` is missing. Each removal gives a note;
/// what cannot be removed is left (with a note).
pub fn clear_leftovers(target: &Path, notes: &mut Vec<String>) {
    let (Some(parent), Some(name)) = (target.parent(), target.file_name()) else { return };
    let name = name.to_string_lossy();
    let Ok(entries) = fs::read_dir(parent) else { return };
    let mut found: Vec<(PathBuf, u32, bool)> = entries
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            let entry = e.file_name().to_string_lossy().into_owned();
            staging_pid(&entry, &name).map(|(pid, old)| (e.path(), pid, old))
        })
        .filter(|(_, pid, _)| *pid != std::process::id() && pid_liveness(*pid, None) == Liveness::Dead)
        .collect();
    found.sort();
    for (path, pid, old) in found {
        if old && fs::symlink_metadata(target).is_err() && fs::rename(&path, target).is_ok() {
            notes.push(format!(
                "put back `{}`: the earlier output, moved aside to `{}` by a run that was stopped (pid {pid})",
                target.display(),
                path.display()
            ));
            continue;
        }
        let removed = match fs::symlink_metadata(&path) {
            Ok(m) if m.is_dir() => fs::remove_dir_all(&path),
            Ok(_) => fs::remove_file(&path),
            Err(e) => Err(e),
        };
        match removed {
            Ok(()) => notes.push(format!(
                "removed `{}`, left by a run that was stopped (pid {pid}, no longer running)",
                path.display()
            )),
            Err(e) => notes.push(format!("could not remove `{}`, left by a stopped run: {e}", path.display())),
        }
    }
}

/// One output (or a folder written into) under a lock this process holds.
#[derive(Debug)]
struct Held {
    id: u64,
    /// The output, resolved.
    target: PathBuf,
    /// The lock file covering it (its own, or that of a folder holding it).
    lock: PathBuf,
    token: String,
    /// Existing outputs may be replaced (`--force`).
    force: bool,
    /// A folder (its content counts), or a file.
    folder: bool,
    /// For messages (`-o `out``).
    name: String,
}

static HELD: Mutex<Vec<Held>> = Mutex::new(Vec::new());
static NEXT_ID: AtomicU64 = AtomicU64::new(1);

fn held() -> std::sync::MutexGuard<'static, Vec<Held>> {
    HELD.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Records that `target` (resolved) is under the lock `lock`; returns the id [`release`] takes.
pub(crate) fn register(target: &Path, lock: &LockFile, force: bool, folder: bool, name: &str) -> u64 {
    let id = NEXT_ID.fetch_add(1, Ordering::Relaxed);
    held().push(Held {
        id,
        target: target.to_path_buf(),
        lock: lock.path.clone(),
        token: lock.owner.token.clone(),
        force,
        folder,
        name: name.to_string(),
    });
    id
}

/// Forgets the records `ids`.
pub(crate) fn release(ids: &[u64]) {
    held().retain(|h| !ids.contains(&h.id));
}

/// Before `path` is put in place: every lock of this process covering it (its own or a folder's
/// holding it) must still be ours, and, without `force`, an output that is exactly `path` must not
/// have appeared since the start (a file, or a folder with entries). A path no lock covers passes.
///
/// # Errors
/// [`Error::Invalid`] naming the output and the lock, or what appeared.
pub fn confirm_write(path: &Path) -> Result<()> {
    let held = held();
    if held.is_empty() {
        return Ok(());
    }
    let resolved = crate::io::outputs::resolve_path(path);
    for h in held.iter().filter(|h| resolved.starts_with(&h.target)) {
        let holder = read_owner(&h.lock);
        if holder.as_ref().is_none_or(|o| o.token != h.token) {
            let now =
                holder.map_or_else(|| "it is gone".to_string(), |o| format!("it is now held by {}", o.describe()));
            return Err(Error::invalid(
                &h.name,
                format!(
                    "this run's lock `{}` is no longer its own ({now}): another run may be writing the same output; \
                     nothing replaced, run again",
                    h.lock.display()
                ),
            ));
        }
        if resolved == h.target && !h.force {
            let appeared = match fs::symlink_metadata(&resolved) {
                Err(_) => false,
                Ok(m) if h.folder && m.is_dir() => {
                    fs::read_dir(&resolved).map(|mut e| e.next().is_some()).unwrap_or(true)
                }
                Ok(_) => true,
            };
            if appeared {
                return Err(Error::invalid(
                    &h.name,
                    "appeared while this run was working (another run wrote it?); nothing replaced: pass --force to \
                     replace it, or choose another output",
                ));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_text_of_known_instants() {
        assert_eq!(utc_text(0), "1970-01-01 00:00:00 UTC");
        assert_eq!(utc_text(951_782_400), "2000-02-29 00:00:00 UTC");
        assert_eq!(utc_text(1_777_638_896), "2026-05-01 12:34:56 UTC");
    }

    #[test]
    fn staging_names_are_matched_exactly() {
        assert_eq!(staging_pid(".out.tmp-123", "out"), Some((123, false)));
        assert_eq!(staging_pid(".out.old-9", "out"), Some((9, true)));
        for other in [".out.tmp-", ".out.tmp-12x", ".outx.tmp-12", "out.tmp-12", ".out.awl-lock", ".o.tmp-1"] {
            assert_eq!(staging_pid(other, "out"), None, "{other}");
        }
    }

    #[test]
    fn this_process_is_alive_a_reaped_child_is_dead() {
        assert_eq!(pid_liveness(std::process::id(), process_start_ticks(std::process::id())), Liveness::Alive);
        assert_eq!(pid_liveness(std::process::id(), Some(1)), Liveness::Dead, "a reused pid");
        assert_eq!(pid_liveness(dead_pid(), None), Liveness::Dead);
    }

    /// The pid of a child process that has finished and been reaped.
    pub(crate) fn dead_pid() -> u32 {
        let mut child = std::process::Command::new("true").spawn().expect("spawn true");
        let pid = child.id();
        child.wait().expect("wait");
        pid
    }
}
