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
//! [`StagedFolder`] writes an output folder as a temporary sibling renamed into place at the end, and
//! [`write_files_atomic`] several files that appear together or not at all: a run writes all its
//! outputs or none.

use std::fs;
use std::io::Write;
use std::path::{Component, Path, PathBuf};

use crate::error::{Error, Result};
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

    /// Refuses the run (see the module docs) before anything is written.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the output (its option and path), the input or other output it
    /// collides with, and what to change.
    pub fn check(&self) -> Result<()> {
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
            self.check_existing(o, &name)?;
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
/// [`Error::Io`] naming `dir` when a rename fails, or the old folder when it cannot be removed.
pub fn replace_folder(tmp: &Path, dir: &Path) -> Result<()> {
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
/// [`Error::Io`] naming the file that failed; every temporary file is removed.
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
}
