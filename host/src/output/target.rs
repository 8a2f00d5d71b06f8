//! Where sieve may write a directory, and what it never touches (docs/outputs.md, "Where sieve
//! writes and what it never touches").
//!
//! Every directory sieve writes holds a marker, [`MARKER`]: the sieve version, the command,
//! the process id and the list of files sieve wrote into it. Before a command replaces a
//! directory DIR it checks, in this order, and refuses with exit code 2 otherwise:
//! 1. DIR is not the current directory, one of its ancestors or `/` (a rename of those
//!    fails half-way, or would take the user's work with it);
//! 2. DIR does not exist, is empty, or is a directory sieve wrote (marker) holding no file
//!    that sieve did not write (a `notes.txt` the user added later stops the replacement);
//! 3. no other sieve process is writing DIR: an advisory lock on `.DIR.lock` beside DIR, held
//!    until the command ends (the kernel releases it on any exit, even SIGKILL).
//!
//! Holding the lock, it removes what a killed sieve left beside DIR: `.DIR.tmp-*` (a staging
//! directory, marked at creation) and `.DIR.old-*` (a replaced run on its way out), and says so
//! on stderr. Nothing without a marker is removed (an empty directory excepted).

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::collections::BTreeSet;
use std::fs::File;
use std::path::{Path, PathBuf};

/// The marker file sieve writes into every directory it writes.
pub const MARKER: &str = ".sieve-run";

/// The contents of [`MARKER`] (JSON).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct Marker {
    /// Always `"sieve"`.
    pub written_by: String,
    /// The version of sieve.
    pub version: String,
    /// The command line.
    pub command: Vec<String>,
    /// The process that wrote it.
    pub pid: u32,
    /// The files sieve wrote, relative paths with `/` (the marker itself excepted); empty
    /// while the directory is being written.
    pub files: Vec<String>,
}

impl Marker {
    /// A marker of this process with the given files.
    pub fn now(files: Vec<String>) -> Self {
        Self {
            written_by: "sieve".into(),
            version: env!("CARGO_PKG_VERSION").into(),
            command: std::env::args().collect(),
            pid: std::process::id(),
            files,
        }
    }

    /// Reads the marker of `dir` (None if absent or not sieve's).
    pub fn read(dir: &Path) -> Option<Self> {
        let text = std::fs::read_to_string(dir.join(MARKER)).ok()?;
        let m: Marker = serde_json::from_str(&text).ok()?;
        (m.written_by == "sieve").then_some(m)
    }

    /// Writes the marker into `dir`.
    pub fn write(&self, dir: &Path) -> Result<()> {
        let mut text = serde_json::to_string_pretty(self).map_err(Error::failure)?;
        text.push('\n');
        super::write_file(&dir.join(MARKER), text.as_bytes())
    }
}

/// The files under `dir` (relative, `/`-separated, sorted), the markers excepted. Symbolic
/// links count as files (never followed).
pub fn files_under(dir: &Path) -> Result<Vec<String>> {
    let mut out = Vec::new();
    let mut stack = vec![(dir.to_path_buf(), String::new())];
    while let Some((d, prefix)) = stack.pop() {
        for entry in std::fs::read_dir(&d).map_err(|e| Error::io(&d, e))? {
            let entry = entry.map_err(|e| Error::io(&d, e))?;
            let name = entry.file_name().to_string_lossy().into_owned();
            let rel = format!("{prefix}{name}");
            let ty = entry.file_type().map_err(|e| Error::io(&entry.path(), e))?;
            if ty.is_dir() {
                stack.push((entry.path(), format!("{rel}/")));
            } else if name != MARKER {
                out.push(rel);
            }
        }
    }
    out.sort();
    Ok(out)
}

/// The parent directory of `target` (`.` for a bare name).
pub fn parent_of(target: &Path) -> PathBuf {
    match target.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// The last component of `target` (`run` if it has none).
pub fn stem_of(target: &Path) -> String {
    target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "run".into())
}

/// Refuses `.`, `..`, `/`, any directory that holds the current one, and a path below a file.
pub fn refuse_ancestor(target: &Path) -> Result<()> {
    let shown = target.display();
    refuse_file_parent(target)?;
    let lexical = target.file_name().is_none(); // ".", "..", "/", "a/.."
    let Ok(canon) = std::fs::canonicalize(target) else {
        if lexical {
            return Err(Error::Input(format!(
                "{shown}: not a usable output directory; choose a new directory, e.g. --out runs/NAME"
            )));
        }
        return Ok(()); // does not exist yet: cannot hold the current directory
    };
    let cwd = std::env::current_dir()
        .ok()
        .and_then(|d| std::fs::canonicalize(d).ok());
    let holds_cwd = cwd.as_deref().is_some_and(|c| c.starts_with(&canon));
    if holds_cwd || canon.parent().is_none() {
        return Err(Error::Input(format!(
            "{shown}: is the current directory or one of its parents ({}), which sieve never replaces; choose a new directory, e.g. --out runs/NAME",
            canon.display()
        )));
    }
    if lexical {
        // `a/..`: sieve writes beside DIR under DIR's name, which this path does not give
        return Err(Error::Input(format!(
            "{shown}: ends in `..`, not in a directory's name; name the directory itself ({}) or choose a new one, e.g. --out runs/NAME",
            canon.display()
        )));
    }
    Ok(())
}

/// Refuses (exit 2) a `target` below an existing file (`file.txt/sub`): creating its parent
/// would fail with a bare "File exists", exit 1.
fn refuse_file_parent(target: &Path) -> Result<()> {
    for up in target.ancestors().skip(1) {
        if up.as_os_str().is_empty() {
            break;
        }
        match std::fs::metadata(up) {
            Ok(m) if m.is_dir() => break,
            Ok(_) => {
                return Err(Error::Input(format!(
                    "{}: its parent {} is a file, not a directory; choose another --out",
                    target.display(),
                    up.display()
                )))
            }
            Err(_) => {}
        }
    }
    Ok(())
}

/// A subdirectory of a marked directory (DIR/plots for `sieve plot DIR`): the parent's list,
/// restricted to it.
fn listed_by_parent(dir: &Path) -> Option<Marker> {
    let name = dir.file_name()?.to_string_lossy().into_owned();
    let parent = Marker::read(&parent_of(dir))?;
    let prefix = format!("{name}/");
    let files = parent
        .files
        .iter()
        .filter_map(|f| f.strip_prefix(&prefix).map(String::from))
        .collect();
    Some(Marker { files, ..parent })
}

/// The names a run, a convergence study or a fit wrote before directories were marked
/// (sieve 0.1.0 up to this change): such a directory without any other file is sieve's.
const LEGACY_NAMES: [&str; 11] = [
    "summary.json",
    "series.csv",
    "final.csv",
    "profiles.csv",
    "discharge.csv",
    "fields",
    "plots",
    "converge.csv",
    "converge.json",
    "converge.png",
    "fit.csv",
];

/// An unmarked directory that holds only what older versions of sieve wrote, with the
/// summary (run), converge.json or fit.json that identifies it.
fn legacy(dir: &Path) -> Option<Marker> {
    let files = files_under(dir).ok()?;
    let identified = ["summary.json", "converge.json", "fit.json"]
        .iter()
        .any(|f| dir.join(f).is_file());
    let known = files.iter().all(|f| {
        let top = f.split('/').next().unwrap_or("");
        top == "fit.json" || LEGACY_NAMES.contains(&top)
    });
    (identified && known).then(|| Marker::now(files))
}

/// Why a directory is not sieve's to replace (None: it may be replaced).
fn foreign(dir: &Path) -> Result<Option<String>> {
    let mut entries = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    if entries.next().is_none() {
        return Ok(None); // empty
    }
    let Some(marker) = Marker::read(dir)
        .or_else(|| listed_by_parent(dir))
        .or_else(|| legacy(dir))
    else {
        return Ok(Some("exists and was not written by sieve".into()));
    };
    let ours: BTreeSet<&str> = marker.files.iter().map(String::as_str).collect();
    // A subdirectory with a marker of its own (plots/ after `sieve plot`) answers for itself.
    let mut stack = vec![(dir.to_path_buf(), String::new())];
    while let Some((d, prefix)) = stack.pop() {
        for entry in std::fs::read_dir(&d).map_err(|e| Error::io(&d, e))? {
            let entry = entry.map_err(|e| Error::io(&d, e))?;
            let name = entry.file_name().to_string_lossy().into_owned();
            let rel = format!("{prefix}{name}");
            let ty = entry.file_type().map_err(|e| Error::io(&entry.path(), e))?;
            if ty.is_dir() {
                if Marker::read(&entry.path()).is_some() {
                    if let Some(why) = foreign(&entry.path())? {
                        return Ok(Some(why));
                    }
                } else {
                    stack.push((entry.path(), format!("{rel}/")));
                }
            } else {
                let own_marker = prefix.is_empty() && name == MARKER;
                if own_marker || ours.contains(rel.as_str()) {
                    continue;
                }
                return Ok(Some(format!(
                    "holds {}, which sieve did not write",
                    d.join(&name).display()
                )));
            }
        }
    }
    Ok(None)
}

/// An advisory lock on `.DIR.lock` beside DIR, released (and the file removed) on drop.
#[derive(Debug)]
pub struct Lock {
    file: File,
    path: PathBuf,
}

impl Lock {
    /// Takes the lock of `target` or refuses (exit 2) if another sieve process holds it.
    pub fn take(target: &Path) -> Result<Self> {
        use std::io::{Read, Seek, Write};
        let parent = parent_of(target);
        let path = parent.join(format!(".{}.lock", stem_of(target)));
        // Another process may remove the file between our open and our lock (it releases
        // by removing first): lock, then check the path still names the file we locked.
        for _ in 0..100 {
            let mut file = std::fs::OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .open(&path)
                .map_err(|e| Error::io(&path, e))?;
            match fs4::FileExt::try_lock(&file) {
                Ok(()) => {}
                Err(fs4::TryLockError::WouldBlock) => {
                    let mut pid = String::new();
                    let _ = file.read_to_string(&mut pid);
                    let pid = pid.trim();
                    let pid = if pid.is_empty() { "?" } else { pid };
                    return Err(Error::Input(format!(
                        "{}: is being written by another sieve run (pid {pid}); wait for it or choose another --out",
                        target.display()
                    )));
                }
                Err(fs4::TryLockError::Error(e)) => return Err(Error::io(&path, e)),
            }
            if !same_file(&file, &path) {
                continue;
            }
            file.set_len(0).map_err(|e| Error::io(&path, e))?;
            file.rewind().map_err(|e| Error::io(&path, e))?;
            writeln!(file, "{}", std::process::id()).map_err(|e| Error::io(&path, e))?;
            return Ok(Self { file, path });
        }
        Err(Error::failure(format!(
            "{}: cannot take the lock {}",
            target.display(),
            path.display()
        )))
    }
}

#[cfg(unix)]
fn same_file(file: &File, path: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (file.metadata(), std::fs::metadata(path)) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    }
}

#[cfg(not(unix))]
fn same_file(_: &File, path: &Path) -> bool {
    path.exists()
}

impl Drop for Lock {
    fn drop(&mut self) {
        // Remove while still holding it, so that nobody locks a file that is gone.
        let _ = std::fs::remove_file(&self.path);
        let _ = fs4::FileExt::unlock(&self.file);
    }
}

/// Removes the staging and set-aside directories a killed sieve left beside `target` (only
/// ones with a sieve marker, or empty); call with the lock held. Returns their names.
fn remove_debris(target: &Path) -> Vec<String> {
    let parent = parent_of(target);
    let stem = stem_of(target);
    let tmp = format!(".{stem}.tmp-");
    let old = format!(".{stem}.old-");
    let Ok(entries) = std::fs::read_dir(&parent) else {
        return Vec::new();
    };
    let mut removed = Vec::new();
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let path = entry.path();
        if !entry.file_type().is_ok_and(|t| t.is_dir()) {
            continue;
        }
        let empty = || std::fs::read_dir(&path).is_ok_and(|mut d| d.next().is_none());
        let ours = if name.starts_with(&tmp) {
            Marker::read(&path).is_some() || empty()
        } else if name.starts_with(&old) {
            // `old/` inside is the replaced run (marked); empty if killed before the move.
            Marker::read(&path.join("old")).is_some() || empty()
        } else {
            false
        };
        if ours && std::fs::remove_dir_all(&path).is_ok() {
            removed.push(name);
        }
    }
    removed.sort();
    removed
}

/// Checks that sieve may write `target`, takes its lock and clears debris of killed runs.
pub fn claim(target: &Path) -> Result<Lock> {
    refuse_ancestor(target)?;
    if target.exists() && !target.is_dir() {
        return Err(Error::Input(format!(
            "{}: exists and is not a directory; choose another --out or move it",
            target.display()
        )));
    }
    let parent = parent_of(target);
    std::fs::create_dir_all(&parent).map_err(|e| Error::io(&parent, e))?;
    let lock = Lock::take(target)?;
    if target.is_dir() {
        if let Some(why) = foreign(target)? {
            return Err(Error::Input(format!(
                "{}: {why}; choose another --out or move its contents",
                target.display()
            )));
        }
    }
    let removed = remove_debris(target);
    if !removed.is_empty() {
        eprintln!(
            "note: removed {} director{} left in {} by an interrupted sieve run: {}",
            removed.len(),
            if removed.len() == 1 { "y" } else { "ies" },
            parent.display(),
            removed.join(", ")
        );
    }
    Ok(lock)
}

/// Checks that sieve may write the single file `path` (`sieve record --out FILE`): never a
/// directory, never an existing file that does not start with `magic` (a file sieve wrote
/// before); exit 2 otherwise. The file itself is then written atomically.
pub fn claim_file(path: &Path, magic: &[u8]) -> Result<()> {
    use std::io::Read;
    refuse_file_parent(path)?;
    if path.is_dir() || path.file_name().is_none() {
        return Err(Error::Input(format!(
            "{}: is a directory; --out takes a file name, e.g. --out runs/NAME.rec",
            path.display()
        )));
    }
    if path.exists() {
        let mut head = vec![0u8; magic.len()];
        let ours = std::fs::File::open(path)
            .and_then(|mut f| f.read_exact(&mut head))
            .is_ok()
            && head == magic;
        if !ours {
            return Err(Error::Input(format!(
                "{}: exists and was not written by sieve; choose another --out or move it",
                path.display()
            )));
        }
    }
    Ok(())
}
