//! The run directory: everything is written into a temporary sibling of DIR and renamed into
//! place at the end ([`Staging::commit`]), so a failed run never leaves a half-written DIR.

pub mod csv;
pub mod plot;
pub mod redraw;
pub mod summary;
pub mod vtk;

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// A temporary directory next to the target that becomes the target on [`Staging::commit`].
/// Dropped without commit, it is deleted.
#[derive(Debug)]
pub struct Staging {
    tmp: tempfile::TempDir,
    target: PathBuf,
}

fn parent_of(target: &Path) -> PathBuf {
    match target.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

fn stem_of(target: &Path) -> String {
    target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "run".into())
}

impl Staging {
    /// Creates the staging directory (and the parent of `target` if needed).
    pub fn new(target: &Path) -> Result<Self> {
        if target.exists() && !target.is_dir() {
            return Err(Error::Input(format!(
                "{}: output path exists and is not a directory",
                target.display()
            )));
        }
        let parent = parent_of(target);
        std::fs::create_dir_all(&parent).map_err(|e| Error::io(&parent, e))?;
        let tmp = tempfile::Builder::new()
            .prefix(&format!(".{}.tmp-", stem_of(target)))
            .tempdir_in(&parent)
            .map_err(|e| Error::io(&parent, e))?;
        Ok(Self {
            tmp,
            target: target.to_path_buf(),
        })
    }

    /// Where to write.
    pub fn path(&self) -> &Path {
        self.tmp.path()
    }

    /// Creates a subdirectory of the staging directory.
    pub fn subdir(&self, name: &str) -> Result<PathBuf> {
        let p = self.path().join(name);
        std::fs::create_dir_all(&p).map_err(|e| Error::io(&p, e))?;
        Ok(p)
    }

    /// Renames the staging directory to the target. An existing target is moved aside first
    /// and deleted only after the rename succeeded (restored if it failed).
    pub fn commit(self) -> Result<PathBuf> {
        let staged = self.tmp.keep();
        let target = self.target;
        let aside = if target.exists() {
            let aside = tempfile::Builder::new()
                .prefix(&format!(".{}.old-", stem_of(&target)))
                .tempdir_in(parent_of(&target))
                .map_err(|e| Error::io(&target, e))?
                .keep();
            let old = aside.join("old");
            std::fs::rename(&target, &old).map_err(|e| Error::io(&target, e))?;
            Some(aside)
        } else {
            None
        };
        if let Err(e) = std::fs::rename(&staged, &target) {
            if let Some(aside) = &aside {
                let _ = std::fs::rename(aside.join("old"), &target);
                let _ = std::fs::remove_dir_all(aside);
            }
            let _ = std::fs::remove_dir_all(&staged);
            return Err(Error::io(&target, e));
        }
        if let Some(aside) = aside {
            std::fs::remove_dir_all(&aside).map_err(|e| Error::io(&aside, e))?;
        }
        Ok(target)
    }
}

/// Writes `bytes` to `path`, naming the path in an error.
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    std::fs::write(path, bytes).map_err(|e| Error::io(path, e))
}

/// Writes one file atomically: a temporary file beside it, renamed into place, so a reader
/// never sees it half-written and a failure leaves any previous file untouched.
pub fn write_file_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    use std::io::Write;
    let parent = parent_of(path);
    std::fs::create_dir_all(&parent).map_err(|e| Error::io(&parent, e))?;
    let mut tmp = tempfile::NamedTempFile::new_in(&parent).map_err(|e| Error::io(&parent, e))?;
    tmp.write_all(bytes).map_err(|e| Error::io(tmp.path(), e))?;
    tmp.persist(path).map_err(|e| Error::io(path, e.error))?;
    Ok(())
}

/// Formats a number for text outputs: plain decimal in a readable range, exponent otherwise,
/// always the shortest form that reads back to the same f64.
pub fn num(x: f64) -> String {
    let a = x.abs();
    if x == 0.0 || (1e-4..1e15).contains(&a) || !x.is_finite() {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}
