//! Bounded reads of the files a user hands sieve back (snapshots, series, run summaries,
//! checkpoints, recordings).
//!
//! Only regular files are read: opening a FIFO blocks until a writer appears (a hang that
//! no signal handler sees, since the open never returns) and a device such as `/dev/zero`
//! never ends. The length comes from the file's metadata and is bounded before anything is
//! allocated, and the buffer is reserved fallibly, so a file larger than memory is one line
//! ("out of memory"), not an abort. The read itself is capped at that length plus one byte,
//! so a file that grows while it is read cannot grow the buffer without bound.

use crate::error::{Error, Result};
use std::io::Read;
use std::path::Path;

/// Largest file any reader takes (16 GiB): far above any output sieve writes on one machine.
pub const MAX_FILE: u64 = 1 << 34;

/// The bytes of the regular file `path`, at most `max` of them.
///
/// Errors (one line each): no such file or unreadable (exit 1, the system's reason), not a
/// regular file or larger than `max` (exit 2), not enough memory for it (exit 1).
pub fn bytes(path: &Path, max: u64) -> Result<Vec<u8>> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if !meta.is_file() {
        return Err(Error::input(format!(
            "{}: not a regular file (a directory, FIFO, socket or device); sieve reads only files it wrote",
            path.display()
        )));
    }
    let len = meta.len();
    if len > max {
        return Err(Error::input(format!(
            "{}: {len} bytes, at most {max} are read",
            path.display()
        )));
    }
    let mut out = Vec::new();
    out.try_reserve_exact(len as usize).map_err(|_| {
        Error::failure(format!(
            "{}: out of memory for its {len} bytes",
            path.display()
        ))
    })?;
    std::fs::File::open(path)
        .and_then(|f| f.take(max.saturating_add(1)).read_to_end(&mut out))
        .map_err(|e| Error::io(path, e))?;
    if out.len() as u64 > max {
        return Err(Error::input(format!(
            "{}: grew past {max} bytes while it was read",
            path.display()
        )));
    }
    Ok(out)
}

/// [`bytes`] as UTF-8 text.
pub fn text(path: &Path, max: u64) -> Result<String> {
    String::from_utf8(bytes(path, max)?)
        .map_err(|_| Error::input(format!("{}: not UTF-8 text", path.display())))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_files_and_refuses_what_is_not_one() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("a.txt");
        std::fs::write(&f, b"abc").unwrap();
        assert_eq!(bytes(&f, 3).unwrap(), b"abc");
        assert_eq!(text(&f, 10).unwrap(), "abc");
        // Longer than allowed: refused before reading, exit 2.
        let e = bytes(&f, 2).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        assert!(e.to_string().contains("3 bytes, at most 2"), "{e}");
        // A directory and a device: not regular files, exit 2, nothing read.
        let e = bytes(dir.path(), MAX_FILE).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        assert!(e.to_string().contains("not a regular file"), "{e}");
        if Path::new("/dev/zero").exists() {
            let e = bytes(Path::new("/dev/zero"), MAX_FILE).unwrap_err();
            assert!(e.to_string().contains("not a regular file"), "{e}");
        }
        // Missing: the system's reason, exit 1.
        let e = bytes(&dir.path().join("none"), MAX_FILE).unwrap_err();
        assert_eq!(e.exit_code(), 1);
        // Not UTF-8.
        std::fs::write(&f, [0xff, 0xfe]).unwrap();
        assert!(text(&f, 10).unwrap_err().to_string().contains("not UTF-8"));
    }

    /// A FIFO would block the open until a writer came: refused without opening it.
    #[cfg(unix)]
    #[test]
    fn a_fifo_is_refused_without_blocking() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("fifo");
        let made = std::process::Command::new("mkfifo").arg(&p).status();
        if !made.is_ok_and(|s| s.success()) {
            return; // no mkfifo on this machine: nothing to check
        }
        let e = bytes(&p, MAX_FILE).unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
    }
}
