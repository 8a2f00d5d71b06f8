//! Bounded reads of the files a user hands sieve back (snapshots, series, run summaries,
//! checkpoints, recordings).
//!
//! Only regular files are read: opening a FIFO blocks until a writer appears (a hang that
//! no signal handler sees, since the open never returns) and a device such as `/dev/zero`
//! never ends. The name is checked before the open, so that a device or FIFO is normally
//! never opened at all; the name can be replaced between that check and the open, so on Unix
//! the open is non-blocking (`O_NONBLOCK`: a FIFO opens at once, a regular file reads as
//! usual) and the open handle is checked again (fstat), which is what counts. The length
//! comes from that handle's metadata and is bounded before anything is allocated, and the
//! buffer is reserved fallibly, so a file larger than memory is one line ("out of memory"),
//! not an abort. The read itself is capped at that length plus one byte,
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
    let (file, meta) = open_file(path)?;
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
    file.take(max.saturating_add(1))
        .read_to_end(&mut out)
        .map_err(|e| Error::io(path, e))?;
    if out.len() as u64 > max {
        return Err(Error::input(format!(
            "{}: grew past {max} bytes while it was read",
            path.display()
        )));
    }
    Ok(out)
}

/// The first bytes of the regular file `path`, at most `n` of them (fewer if the file is
/// shorter): enough to recognise a file's format without reading it all. Errors as
/// [`bytes`].
pub fn head(path: &Path, n: u64) -> Result<Vec<u8>> {
    let (file, _) = open_file(path)?;
    let mut out = Vec::new();
    file.take(n)
        .read_to_end(&mut out)
        .map_err(|e| Error::io(path, e))?;
    Ok(out)
}

/// `path` opened for reading if it is a regular file, checked by name and then on the open
/// handle (module doc), with that handle's metadata.
fn open_file(path: &Path) -> Result<(std::fs::File, std::fs::Metadata)> {
    let not_a_file = || {
        Error::input(format!(
            "{}: not a regular file (a directory, FIFO, socket or device); sieve reads only files it wrote",
            path.display()
        ))
    };
    if !std::fs::metadata(path)
        .map_err(|e| Error::io(path, e))?
        .is_file()
    {
        return Err(not_a_file());
    }
    let file = open(path).map_err(|e| Error::io(path, e))?;
    let meta = file.metadata().map_err(|e| Error::io(path, e))?;
    if !meta.is_file() {
        return Err(not_a_file()); // replaced since the check above
    }
    Ok((file, meta))
}

/// Opens `path` for reading without waiting for a writer: a FIFO put in place of a checked
/// regular file must not block the open (the caller checks the handle).
#[cfg(unix)]
fn open(path: &Path) -> std::io::Result<std::fs::File> {
    use std::os::unix::fs::OpenOptionsExt;
    std::fs::OpenOptions::new()
        .read(true)
        // O_NOCTTY: a terminal swapped in must not become the controlling terminal either.
        .custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY)
        .open(path)
}

/// Opens `path` for reading (no FIFOs that block an open here).
#[cfg(not(unix))]
fn open(path: &Path) -> std::io::Result<std::fs::File> {
    std::fs::File::open(path)
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

    /// Runs `f` on a thread and returns its result, or fails the test if it has not returned
    /// within 5 s (a blocked open must fail the test, not hang CI).
    #[cfg(unix)]
    fn within_5_s<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let _ = tx.send(f());
        });
        rx.recv_timeout(std::time::Duration::from_secs(5))
            .expect("still blocked after 5 s (an open that waits for a FIFO's writer?)")
    }

    /// Makes a FIFO at `p`; false where there is no mkfifo.
    #[cfg(unix)]
    fn mkfifo(p: &Path) -> bool {
        let made = std::process::Command::new("mkfifo").arg(p).status();
        made.is_ok_and(|s| s.success())
    }

    /// A FIFO would block the open until a writer came: refused promptly, exit 2.
    #[cfg(unix)]
    #[test]
    fn a_fifo_is_refused_without_blocking() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("fifo");
        if !mkfifo(&p) {
            return; // no mkfifo on this machine: nothing to check
        }
        let e = within_5_s(move || bytes(&p, MAX_FILE)).unwrap_err();
        assert_eq!(e.exit_code(), 2, "{e}");
        assert!(e.to_string().contains("not a regular file"), "{e}");
    }

    /// A regular file replaced by a FIFO between the check of the name and the open (a
    /// rename race, repeated until it has had every chance to land in that window): each
    /// read returns the file or refuses the FIFO, and none blocks (before the open was
    /// non-blocking and the handle checked, one blocked for ever).
    #[cfg(unix)]
    #[test]
    fn a_fifo_swapped_in_after_the_check_never_blocks_the_read() {
        use std::sync::atomic::{AtomicBool, Ordering};
        use std::sync::Arc;
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().to_path_buf();
        let (file, fifo, target) = (d.join("file"), d.join("fifo"), d.join("target"));
        std::fs::write(&file, b"abc").unwrap();
        if !mkfifo(&fifo) {
            return;
        }
        std::fs::copy(&file, &target).unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let swapper = {
            let (stop, d, target) = (stop.clone(), d.clone(), target.clone());
            std::thread::spawn(move || {
                // ends with the test's directory, should the reader fail first
                while !stop.load(Ordering::Relaxed) {
                    for (src, tmp) in [(&file, "tmp-file"), (&fifo, "tmp-fifo")] {
                        let tmp = d.join(tmp);
                        if std::fs::hard_link(src, &tmp)
                            .and_then(|()| std::fs::rename(&tmp, &target))
                            .is_err()
                        {
                            return;
                        }
                    }
                }
            })
        };
        let (files, fifos) = within_5_s(move || {
            let (mut files, mut fifos) = (0, 0);
            let start = std::time::Instant::now();
            while start.elapsed() < std::time::Duration::from_secs(1) {
                match bytes(&target, MAX_FILE) {
                    Ok(b) => {
                        assert_eq!(b, b"abc");
                        files += 1;
                    }
                    Err(e) => {
                        assert_eq!(e.exit_code(), 2, "{e}");
                        assert!(e.to_string().contains("not a regular file"), "{e}");
                        fifos += 1;
                    }
                }
            }
            (files, fifos)
        });
        stop.store(true, Ordering::Relaxed);
        swapper.join().unwrap();
        assert!(files > 0 && fifos > 0, "files {files}, FIFOs {fifos}");
    }
}
