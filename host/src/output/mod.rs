//! The run directory: everything is written into a temporary sibling of DIR and renamed into
//! place at the end ([`Staging::commit`]), so a failed run never leaves a half-written DIR.
//! Before anything is created, [`target::claim`] checks that sieve may replace DIR (never a
//! directory sieve did not write, never the current directory or its parents), takes DIR's
//! lock and removes what killed runs left; a run stopped by a signal or a numerical failure
//! commits what it wrote (docs/outputs.md).

pub mod csv;
pub mod plot;
pub mod redraw;
pub mod summary;
pub mod target;
pub mod vtk;
pub mod writer;

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};
use target::{parent_of, stem_of, Marker};

/// A temporary directory next to the target that becomes the target on [`Staging::commit`].
/// Dropped without commit, it is deleted. It holds the target's lock until dropped.
#[derive(Debug)]
pub struct Staging {
    tmp: tempfile::TempDir,
    target: PathBuf,
    // Declared last: dropped after the staging directory is gone.
    _lock: target::Lock,
}

impl Staging {
    /// Checks and locks `target` ([`target::claim`]), then creates the marked staging
    /// directory (and the parent of `target` if needed).
    pub fn new(target: &Path) -> Result<Self> {
        let lock = target::claim(target)?;
        let parent = parent_of(target);
        let tmp = tempfile::Builder::new()
            .prefix(&format!(".{}.tmp-", stem_of(target)))
            .tempdir_in(&parent)
            .map_err(|e| Error::io(&parent, e))?;
        // Marked from the start: if this process is killed, a later run knows it is sieve's.
        Marker::now(Vec::new()).write(tmp.path())?;
        Ok(Self {
            tmp,
            target: target.to_path_buf(),
            _lock: lock,
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

    /// Lists the written files in the marker and renames the staging directory to the
    /// target. An existing target (checked by [`target::claim`]) is moved aside first and
    /// deleted only after the rename succeeded (restored if it failed).
    pub fn commit(self) -> Result<PathBuf> {
        Marker::now(target::files_under(self.path())?).write(self.path())?;
        let Staging { tmp, target, _lock } = self;
        let staged = tmp.keep();
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
        drop(_lock);
        Ok(target)
    }
}

/// Runs `f`, turning a panic into an error (its message, one line) without printing a
/// backtrace: the plotting library panics on some extreme or non-finite data, and a run must
/// not lose its files over a picture.
pub fn without_panic<T>(f: impl FnOnce() -> Result<T>) -> Result<T> {
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
    std::panic::set_hook(hook);
    r.unwrap_or_else(|p| {
        let m = p
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| p.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "a panic".into());
        Err(Error::failure(m))
    })
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
    if x == 0.0 {
        // -0 (e.g. max(0, -phi) of phi = 0) reads as a sign where there is none
        "0".into()
    } else if (1e-4..1e15).contains(&a) || !x.is_finite() {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}
