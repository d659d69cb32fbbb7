//! A command's outputs checked against its inputs before anything is written, and written whole.
//!
//! [`OutputCheck`] holds every path a command reads (files, and folders whose every file is an
//! input: a scan folder) and every path it writes (files, and folders it owns), all resolved with
//! symlinks followed (a path that does not exist yet is resolved through its nearest existing
//! ancestor). [`OutputCheck::check`] refuses, naming both paths:
//! - an output that is an input (the same path, or the same file by a hard link);
//! - an output inside an input folder, and an output folder that holds an input;
//! - two outputs that name the same file, or one inside the other (`-o x --urscript x`);
//! - an output that exists already, unless `force` (`--force`); with it, an output folder that holds
//!   entries the command does not write (a user's own files) is still refused.
//!
//! [`OutputCheck::check_and_lock`] also locks every output ([`crate::io::lock`]: a `.NAME.awl-lock` file beside it) and returns
//! the locks as an [`OutputGuard`], which the command keeps until its outputs are in place: a second
//! run on the same output is refused at its start, naming the first (pid, host, start time), and the
//! commit refuses when the lock is no longer this run's or (without `force`) the output appeared
//! meanwhile. Dropping the guard (also on error) releases the locks.
//!
//! [`StagedFolder`] writes an output folder as a temporary sibling renamed into place at the end, and
//! [`write_files_atomic`] several files that appear together or not at all: a run writes all its
//! outputs or none.

use std::fs;
use std::io::Write;
use std::path::{Component, Path, PathBuf};

use crate::error::{Error, Result};
use crate::io::lock::{LockFile, confirm_write};
use crate::io::temp_sibling;

/// One path of an [`OutputCheck`].
#[derive(Debug, Clone)]
struct Entry {
    /// The path as the user gave it (for messages).
    given: PathBuf,
    /// Absolute, symlinks resolved.
    resolved: PathBuf,
    /// A folder (every file inside belongs to it).
    folder: bool,
    /// What it is, for messages (`--urscript`, `the workpiece's model`).
    what: String,
    /// For an output folder: the names the command writes there (its other entries are a user's).
    owns: Vec<String>,
}

/// The inputs and outputs of one command run (see the module docs).
#[derive(Debug, Clone, Default)]
pub struct OutputCheck {
    force: bool,
    inputs: Vec<Entry>,
    outputs: Vec<Entry>,
    /// Folders the command writes into without owning them whole (locked only).
    locked: Vec<Entry>,
}

/// The locks of one command run's outputs ([`OutputCheck::check_and_lock`]): keep it until the outputs are
/// written; dropping it releases them.
#[derive(Debug, Default)]
pub struct OutputGuard {
    locks: Vec<LockFile>,
    ids: Vec<u64>,
    notes: Vec<String>,
}

impl OutputGuard {
    /// What taking the locks cleared, one sentence each: stale locks of runs that no longer exist,
    /// their staging leftovers (for the CLI to print).
    pub fn notes(&self) -> &[String] {
        &self.notes
    }

    /// The lock files held.
    pub fn lock_files(&self) -> Vec<&Path> {
        self.locks.iter().map(LockFile::path).collect()
    }
}

impl Drop for OutputGuard {
    fn drop(&mut self) {
        crate::io::lock::release(&self.ids);
        // the locks go after the records: `self.locks` drops next, removing the files
    }
}

/// `path` made absolute with symlinks resolved; a path that does not exist (an output not yet
/// written) is resolved through its nearest existing ancestor, the rest appended (`..` taken off
/// lexically).
pub fn resolve_path(path: &Path) -> PathBuf {
    if let Ok(p) = fs::canonicalize(path) {
        return p;
    }
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut rest: Vec<Component<'_>> = Vec::new();
    let mut base = absolute.as_path();
    loop {
        if let Ok(p) = fs::canonicalize(base) {
            let mut out = p;
            for c in rest.iter().rev() {
                match c {
                    Component::ParentDir => {
                        out.pop();
                    }
                    Component::CurDir => {}
                    other => out.push(other.as_os_str()),
                }
            }
            return out;
        }
        let (Some(parent), Some(last)) = (base.parent(), base.components().next_back()) else {
            return absolute.clone();
        };
        rest.push(last);
        base = parent;
    }
}

/// The same existing file (device and inode), so hard links are caught too.
fn same_file(a: &Path, b: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        match (fs::metadata(a), fs::metadata(b)) {
            (Ok(x), Ok(y)) => x.is_file() && y.is_file() && x.dev() == y.dev() && x.ino() == y.ino(),
            _ => false,
        }
    }
    #[cfg(not(unix))]
    {
        let _ = (a, b);
        false
    }
}

impl OutputCheck {
    /// An empty check; `force` lets existing outputs be replaced (`--force`).
    pub fn new(force: bool) -> Self {
        Self { force, ..Self::default() }
    }

    fn entry(path: &Path, folder: bool, what: &str, owns: &[&str]) -> Entry {
        Entry {
            given: path.to_path_buf(),
            resolved: resolve_path(path),
            folder,
            what: what.to_string(),
            owns: owns.iter().map(|s| (*s).to_string()).collect(),
        }
    }

    /// An input file (`what` names it in messages, e.g. `the workpiece's model`).
    pub fn input_file(&mut self, path: &Path, what: &str) -> &mut Self {
        self.inputs.push(Self::entry(path, false, what, &[]));
        self
    }

    /// Several input files of one kind.
    pub fn input_files<P: AsRef<Path>>(&mut self, paths: &[P], what: &str) -> &mut Self {
        for p in paths {
            self.input_file(p.as_ref(), what);
        }
        self
    }

    /// An input folder: nothing may be written inside it.
    pub fn input_folder(&mut self, path: &Path, what: &str) -> &mut Self {
        self.inputs.push(Self::entry(path, true, what, &[]));
        self
    }

    /// An output file (`what`: the option that names it, e.g. `--urscript`).
    pub fn output_file(&mut self, path: &Path, what: &str) -> &mut Self {
        self.outputs.push(Self::entry(path, false, what, &[]));
        self
    }

    /// An output folder the command writes whole; `owns` are the entries it writes there (an
    /// existing folder with any other entry is refused, even with `force`).
    pub fn output_folder(&mut self, path: &Path, what: &str, owns: &[&str]) -> &mut Self {
        self.outputs.push(Self::entry(path, true, what, owns));
        self
    }

    /// A folder the command writes into without owning it whole (`awl demo -o DIR` writes DIR/scan,
    /// DIR/fuse, ...): only locked, so no other run writes there meanwhile; the outputs inside it
    /// share its lock.
    pub fn locked_folder(&mut self, path: &Path, what: &str) -> &mut Self {
        self.locked.push(Self::entry(path, true, what, &[]));
        self
    }

    /// Refuses the run (see the module docs) before anything is written; takes no lock (see
    /// [`OutputCheck::check_and_lock`], which every command writing outputs should use).
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the output (its option and path), the input or other output it
    /// collides with, and what to change.
    pub fn check(&self) -> Result<()> {
        self.check_collisions()?;
        self.check_all_existing()
    }

    /// [`OutputCheck::check`], with every output (and [`OutputCheck::locked_folder`]) locked in
    /// between the collision and the existence checks: the guard is kept until the outputs are in
    /// place (the commit confirms the locks), a second run on any of them is refused here.
    ///
    /// # Errors
    /// Those of [`OutputCheck::check`]; [`Error::Invalid`] naming the output and the other run
    /// holding its lock (pid, host, start time); [`Error::Io`] naming a lock file that cannot be
    /// written. The locks taken are released.
    pub fn check_and_lock(&self) -> Result<OutputGuard> {
        self.check_collisions()?;
        let guard = self.take_locks()?;
        self.check_all_existing()?;
        Ok(guard)
    }

    fn check_all_existing(&self) -> Result<()> {
        for o in &self.outputs {
            self.check_existing(o, &format!("{} `{}`", o.what, o.given.display()))?;
        }
        Ok(())
    }

    /// Takes a lock per output and locked folder, except those inside another one (they share its
    /// lock), and records each in the process's registry for the commit.
    fn take_locks(&self) -> Result<OutputGuard> {
        let mut guard = OutputGuard::default();
        let all: Vec<&Entry> = self.locked.iter().chain(&self.outputs).collect();
        let covered =
            |e: &Entry| all.iter().any(|o| o.resolved != e.resolved && o.folder && e.resolved.starts_with(&o.resolved));
        let mut owners: Vec<(PathBuf, usize)> = Vec::new();
        for e in all.iter().filter(|e| !covered(e)) {
            if owners.iter().any(|(p, _)| *p == e.resolved) {
                continue;
            }
            let name = format!("{} `{}`", e.what, e.given.display());
            if let Some(lock) = LockFile::acquire(&e.resolved, &name, &mut guard.notes)? {
                owners.push((e.resolved.clone(), guard.locks.len()));
                guard.locks.push(lock);
            }
        }
        for e in &all {
            let owner =
                owners.iter().filter(|(p, _)| e.resolved.starts_with(p)).max_by_key(|(p, _)| p.components().count());
            if let Some((_, k)) = owner {
                let name = format!("{} `{}`", e.what, e.given.display());
                let folder = e.folder;
                guard.ids.push(crate::io::lock::register(&e.resolved, &guard.locks[*k], self.force, folder, &name));
            }
        }
        Ok(guard)
    }

    fn check_collisions(&self) -> Result<()> {
        for (k, o) in self.outputs.iter().enumerate() {
            let name = format!("{} `{}`", o.what, o.given.display());
            for i in &self.inputs {
                let input = format!("{} `{}`", i.what, i.given.display());
                if o.resolved == i.resolved || same_file(&o.resolved, &i.resolved) {
                    return Err(Error::invalid(
                        name,
                        format!("refusing to overwrite an input file: it is {input}; choose another output path"),
                    ));
                }
                if i.folder && o.resolved.starts_with(&i.resolved) {
                    return Err(Error::invalid(
                        name,
                        format!("refusing to write into the input folder {input}; choose a path outside it"),
                    ));
                }
                if o.folder && i.resolved.starts_with(&o.resolved) {
                    return Err(Error::invalid(
                        name,
                        format!(
                            "refusing to overwrite an input file: the output folder holds {input}, which it would \
                             replace; choose another output folder"
                        ),
                    ));
                }
            }
            for p in &self.outputs[k + 1..] {
                let clash = o.resolved == p.resolved
                    || (o.folder && p.resolved.starts_with(&o.resolved))
                    || (p.folder && o.resolved.starts_with(&p.resolved));
                if clash {
                    return Err(Error::invalid(
                        name,
                        format!(
                            "the same file as {} `{}`: one output would replace the other; give each its own path",
                            p.what,
                            p.given.display()
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    fn check_existing(&self, o: &Entry, name: &str) -> Result<()> {
        let Ok(meta) = fs::metadata(&o.resolved) else { return Ok(()) };
        if !o.folder {
            if meta.is_dir() {
                return Err(Error::invalid(name, "is a folder; give a file path"));
            }
            if !self.force {
                return Err(Error::invalid(name, "exists (an earlier output?); pass --force to replace it"));
            }
            return Ok(());
        }
        if !meta.is_dir() {
            return Err(Error::invalid(name, "exists and is not a folder; give a folder path"));
        }
        let entries = fs::read_dir(&o.resolved).map_err(|e| Error::io(&o.given, e))?;
        let mut names = Vec::new();
        for entry in entries {
            let entry = entry.map_err(|e| Error::io(&o.given, e))?;
            names.push(entry.file_name().to_string_lossy().into_owned());
        }
        if names.is_empty() {
            return Ok(());
        }
        if !self.force {
            return Err(Error::invalid(
                name,
                "the output folder exists and is not empty (an earlier output?); pass --force to replace its results",
            ));
        }
        names.sort();
        if let Some(foreign) = names.iter().find(|n| !o.owns.contains(n)) {
            return Err(Error::invalid(
                name,
                format!(
                    "holds `{foreign}`, which this command does not write; --force replaces only an earlier \
                     output folder: move that file or choose another folder"
                ),
            ));
        }
        Ok(())
    }
}

/// Replaces `dir` by the folder `tmp` (both siblings): `dir` moved aside, `tmp` renamed to it, the
/// old one removed (put back when the rename fails).
///
/// # Errors
/// [`Error::Invalid`] from [`confirm_write`] when this run's lock on `dir` is no longer its own or
/// `dir` appeared meanwhile (without `force`); [`Error::Io`] naming `dir` when a rename fails, or the
/// old folder when it cannot be removed.
pub fn replace_folder(tmp: &Path, dir: &Path) -> Result<()> {
    confirm_write(dir)?;
    if fs::symlink_metadata(dir).is_err() {
        return fs::rename(tmp, dir).map_err(|e| Error::io(dir, e));
    }
    let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let old = dir.with_file_name(format!(".{name}.old-{}", std::process::id()));
    fs::rename(dir, &old).map_err(|e| Error::io(dir, e))?;
    if let Err(e) = fs::rename(tmp, dir) {
        let _ = fs::rename(&old, dir);
        return Err(Error::io(dir, e));
    }
    fs::remove_dir_all(&old).map_err(|e| Error::io(&old, e))
}

/// An output folder written as a hidden temporary sibling, renamed into place by
/// [`StagedFolder::commit`]; dropped without it, the temporary folder is removed and `dir` is as
/// it was.
#[derive(Debug)]
pub struct StagedFolder {
    dir: PathBuf,
    tmp: PathBuf,
    committed: bool,
}

impl StagedFolder {
    /// Creates the temporary sibling of `dir` (and `dir`'s parents).
    ///
    /// # Errors
    /// [`Error::Io`] naming the folder that cannot be created.
    pub fn begin(dir: &Path) -> Result<Self> {
        if let Some(parent) = dir.parent().filter(|p| !p.as_os_str().is_empty()) {
            fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
        }
        let tmp = temp_sibling(dir);
        if fs::symlink_metadata(&tmp).is_ok() {
            fs::remove_dir_all(&tmp).map_err(|e| Error::io(&tmp, e))?;
        }
        fs::create_dir(&tmp).map_err(|e| Error::io(&tmp, e))?;
        Ok(Self { dir: dir.to_path_buf(), tmp, committed: false })
    }

    /// Where to write the folder's files until the commit.
    pub fn path(&self) -> &Path {
        &self.tmp
    }

    /// The final folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Renames the temporary folder into place (replacing an earlier `dir`).
    ///
    /// # Errors
    /// [`Error::Io`] from [`replace_folder`] (the temporary folder is removed).
    pub fn commit(mut self) -> Result<()> {
        let result = replace_folder(&self.tmp, &self.dir);
        self.committed = result.is_ok();
        result
    }
}

impl Drop for StagedFolder {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_dir_all(&self.tmp);
        }
    }
}

/// Writes every `(path, bytes)` as a temporary sibling (fsynced), then renames them all into place:
/// when any write fails, none of the files is replaced.
///
/// # Errors
/// [`Error::Io`] naming the file that failed, or [`Error::Invalid`] from [`confirm_write`] (a lock
/// lost, an output that appeared); every temporary file is removed.
pub fn write_files_atomic(files: &[(&Path, &[u8])]) -> Result<()> {
    let temps: Vec<PathBuf> = files.iter().map(|(p, _)| temp_sibling(p)).collect();
    let cleanup = |temps: &[PathBuf]| {
        for t in temps {
            let _ = fs::remove_file(t);
        }
    };
    for ((path, bytes), tmp) in files.iter().zip(&temps) {
        let written = (|| {
            let mut file = fs::File::create(tmp)?;
            file.write_all(bytes)?;
            file.sync_all()
        })();
        if let Err(e) = written {
            cleanup(&temps);
            return Err(Error::io(path, e));
        }
    }
    for (path, _) in files {
        if let Err(e) = confirm_write(path) {
            cleanup(&temps);
            return Err(e);
        }
    }
    for ((path, _), tmp) in files.iter().zip(&temps) {
        if let Err(e) = fs::rename(tmp, path) {
            cleanup(&temps);
            return Err(Error::io(path, e));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn message(check: &OutputCheck) -> String {
        check.check().err().map(|e| e.to_string()).unwrap_or_default()
    }

    #[test]
    fn collisions_are_refused_naming_both_paths() {
        let dir = tempfile::tempdir().expect("tempdir");
        let d = dir.path();
        fs::create_dir(d.join("scan")).expect("mkdir");
        fs::write(d.join("scan/scan.json"), b"{}").expect("write");
        fs::write(d.join("model.ply"), b"ply").expect("write");
        std::os::unix::fs::symlink(d.join("model.ply"), d.join("link.ply")).expect("symlink");
        fs::hard_link(d.join("model.ply"), d.join("hard.ply")).expect("hard link");
        let base = || {
            let mut c = OutputCheck::new(true);
            c.input_folder(&d.join("scan"), "the scan").input_file(&d.join("model.ply"), "the model");
            c
        };
        for (out, want) in [
            (d.join("link.ply"), "refusing to overwrite an input file"),
            (d.join("hard.ply"), "refusing to overwrite an input file"),
            (d.join("scan/../model.ply"), "refusing to overwrite an input file"),
            (d.join("scan/new/x.json"), "refusing to write into the input folder"),
        ] {
            let mut c = base();
            c.output_file(&out, "-o");
            let m = message(&c);
            assert!(m.contains(want) && m.contains(&out.display().to_string()), "{m}");
        }
        let mut c = base();
        c.output_folder(d, "-o", &[]);
        assert!(message(&c).contains("the output folder holds the scan `"), "{}", message(&c));
        let mut c = base();
        c.output_file(&d.join("plan.json"), "-o").output_file(&d.join("./plan.json"), "--urscript");
        assert!(message(&c).contains("the same file as --urscript"), "{}", message(&c));
        let mut c = OutputCheck::new(false);
        c.output_file(&d.join("model.ply"), "-o");
        assert!(message(&c).contains("pass --force"), "{}", message(&c));
        let mut c = OutputCheck::new(true);
        c.output_folder(&d.join("scan"), "-o", &["report.json"]);
        assert!(message(&c).contains("holds `scan.json`"), "{}", message(&c));
        let mut c = OutputCheck::new(true);
        c.output_folder(&d.join("scan"), "-o", &["scan.json"]).output_file(&d.join("new.json"), "-o");
        assert!(c.check().is_ok());
    }

    #[test]
    fn a_staged_folder_appears_whole_or_not_at_all() {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("a/out");
        let staged = StagedFolder::begin(&out).expect("begin");
        fs::write(staged.path().join("x"), b"1").expect("write");
        drop(staged);
        assert!(!out.exists());
        assert_eq!(fs::read_dir(dir.path().join("a")).expect("ls").count(), 0, "temporary folder removed");
        let staged = StagedFolder::begin(&out).expect("begin");
        fs::write(staged.path().join("x"), b"2").expect("write");
        staged.commit().expect("commit");
        assert_eq!(fs::read(out.join("x")).expect("read"), b"2");
        let bad = dir.path().join("no/such/folder/f");
        let good = dir.path().join("g");
        assert!(write_files_atomic(&[(good.as_path(), b"g"), (bad.as_path(), b"b")]).is_err());
        assert!(!good.exists(), "nothing written when one file fails");
    }

    /// The pid of a child process that has finished and been reaped.
    fn dead_pid() -> u32 {
        let mut child = std::process::Command::new("true").spawn().expect("spawn true");
        let pid = child.id();
        child.wait().expect("wait");
        pid
    }

    fn locked(check: &OutputCheck) -> String {
        check.check_and_lock().err().map(|e| e.to_string()).unwrap_or_default()
    }

    fn fuse_like(out: &Path, force: bool) -> OutputCheck {
        let mut c = OutputCheck::new(force);
        c.output_folder(out, "-o", &["model.ply"]);
        c
    }

    #[test]
    fn a_second_lock_on_one_folder_is_refused_naming_it_and_the_holder() {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("deep/out");
        let first = fuse_like(&out, false).check_and_lock().expect("the first run locks");
        let lock = dir.path().join("deep/.out.awl-lock");
        assert_eq!(first.lock_files(), vec![lock.as_path()]);
        let owner = crate::io::lock::read_owner(&lock).expect("the lock names its owner");
        assert_eq!(owner.pid, std::process::id());
        let m = locked(&fuse_like(&out, false));
        let pid = format!("pid {}", std::process::id());
        assert!(m.contains(&out.display().to_string()) && m.contains(&pid), "{m}");
        assert!(m.contains("another awl run is writing this output") && m.contains(&owner.started), "{m}");
        // --force does not take a lock held by a live run either
        assert!(locked(&fuse_like(&out, true)).contains(&pid));
        // an output file inside a locked folder shares its lock: refused too
        let mut c = OutputCheck::new(false);
        c.locked_folder(&dir.path().join("deep"), "-o");
        assert!(c.check_and_lock().is_ok(), "another folder is free");
        drop(first);
        assert!(!lock.exists(), "released on drop");
        assert!(!dir.path().join("deep").exists(), "the folder made for the lock removed with it");
        let again = fuse_like(&out, false).check_and_lock().expect("free again");
        drop(again);
    }

    #[test]
    fn a_stale_lock_and_the_dead_runs_staging_leftovers_are_cleared() {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("out");
        let dead = dead_pid();
        let lock = dir.path().join(".out.awl-lock");
        let stale = serde_json::json!({
            "pid": dead, "host": crate::io::lock::host_name(), "started_unix_s": 0,
            "started": "1970-01-01 00:00:00 UTC", "process_start_ticks": null, "command": "awl fuse", "token": "x"
        });
        fs::write(&lock, stale.to_string()).expect("write");
        let leftover = dir.path().join(format!(".out.tmp-{dead}"));
        fs::create_dir(&leftover).expect("mkdir");
        fs::write(leftover.join("model.ply"), b"half").expect("write");
        let moved_aside = dir.path().join(format!(".out.old-{dead}"));
        fs::create_dir(&moved_aside).expect("mkdir");
        fs::write(moved_aside.join("model.ply"), b"earlier").expect("write");
        // not ours: other names, a live pid (this process's parent is alive), a file of the user
        let keep = [
            dir.path().join(format!(".out.tmp-{}", std::os::unix::process::parent_id())),
            dir.path().join(format!(".outs.tmp-{dead}")),
            dir.path().join(format!(".out.tmp-{dead}x")),
            dir.path().join("notes.txt"),
        ];
        for k in &keep {
            fs::write(k, b"mine").expect("write");
        }
        // (--force: the folder put back is an earlier output, which the check then sees)
        let guard = fuse_like(&out, true).check_and_lock();
        let guard = match guard {
            Ok(g) => g,
            Err(e) => panic!("the stale lock is cleared: {e}"),
        };
        let notes = guard.notes().join("\n");
        assert!(notes.contains("cleared the stale lock") && notes.contains(&format!("pid {dead}")), "{notes}");
        assert!(notes.contains(&format!("removed `{}`", leftover.display())), "{notes}");
        assert!(!leftover.exists(), "{notes}");
        // the earlier output a killed commit had moved aside is put back
        assert!(notes.contains("put back"), "{notes}");
        assert!(!moved_aside.exists());
        drop(guard);
        assert_eq!(fs::read(out.join("model.ply")).expect("restored"), b"earlier");
        for k in &keep {
            assert_eq!(fs::read(k).expect("kept"), b"mine", "{}", k.display());
        }
        assert!(locked(&fuse_like(&out, false)).contains("pass --force"));
    }

    #[test]
    fn the_commit_refuses_a_lost_lock_and_an_output_that_appeared() {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("out");
        let lock = dir.path().join(".out.awl-lock");
        // the lock removed by hand and taken by another run meanwhile
        let guard = fuse_like(&out, false).check_and_lock().expect("lock");
        let staged = StagedFolder::begin(&out).expect("begin");
        fs::write(staged.path().join("model.ply"), b"mine").expect("write");
        fs::remove_file(&lock).expect("rm");
        let other = fuse_like(&out, false).check_and_lock().expect("a second guard (as another run would)");
        let m = staged.commit().err().map(|e| e.to_string()).unwrap_or_default();
        assert!(m.contains("is no longer its own") && m.contains(&out.display().to_string()), "{m}");
        assert!(!out.exists(), "nothing replaced");
        drop(other);
        drop(guard);
        // the output appeared meanwhile (a run without a lock): refused without --force
        let guard = fuse_like(&out, false).check_and_lock().expect("lock");
        let staged = StagedFolder::begin(&out).expect("begin");
        fs::write(staged.path().join("model.ply"), b"late").expect("write");
        fs::create_dir(&out).expect("mkdir");
        fs::write(out.join("model.ply"), b"first").expect("write");
        let m = staged.commit().err().map(|e| e.to_string()).unwrap_or_default();
        assert!(m.contains("appeared while this run was working"), "{m}");
        assert_eq!(fs::read(out.join("model.ply")).expect("read"), b"first", "the other output kept");
        drop(guard);
        // with --force it is replaced; a file output the same
        let guard = fuse_like(&out, true).check_and_lock().expect("lock");
        let staged = StagedFolder::begin(&out).expect("begin");
        fs::write(staged.path().join("model.ply"), b"forced").expect("write");
        staged.commit().expect("commit");
        assert_eq!(fs::read(out.join("model.ply")).expect("read"), b"forced");
        drop(guard);
        let file = dir.path().join("plan.json");
        let mut c = OutputCheck::new(false);
        c.output_file(&file, "-o");
        let guard = c.check_and_lock().expect("lock");
        fs::write(&file, b"other").expect("write");
        let m = write_files_atomic(&[(file.as_path(), b"mine")]).err().map(|e| e.to_string()).unwrap_or_default();
        assert!(m.contains("appeared"), "{m}");
        let m = crate::io::write_atomic(&file, b"mine").err().map(|e| e.to_string()).unwrap_or_default();
        assert!(m.contains("appeared"), "{m}");
        assert_eq!(fs::read(&file).expect("read"), b"other");
        drop(guard);
        assert!(fs::read_dir(dir.path()).expect("ls").all(|e| {
            let n = e.expect("entry").file_name().to_string_lossy().into_owned();
            !n.contains(".tmp-") && !n.ends_with(".awl-lock")
        }));
    }
}
