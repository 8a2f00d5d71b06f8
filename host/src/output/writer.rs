//! Snapshots written beside the stepping: `sieve run` hands each VTK snapshot (an owned copy
//! of the state, [`Snapshot`]) to one writer thread and steps on. Why: a `.vti` of a large
//! grid is megabytes (14.7 MB at 512 x 512), and writing it on the stepping thread kept every
//! other core idle for the length of the write (17 % of a 2-thread run, docs/parallel.md).
//!
//! What stays as it was:
//! - the files: the same bytes under the same names (one writer, in output order);
//! - at most one snapshot waits (in [`Writer::write`]) while one is written, so the run holds
//!   two snapshots at most (one before), and a slow disk slows the run instead of filling
//!   memory;
//! - errors: the first failed write is reported by the next [`Writer::write`], by
//!   [`Pending::wait`] and when the writer is finished; later snapshots are not written;
//! - checkpoints copy the snapshots written before them, so a checkpoint first waits for
//!   every write in flight ([`Pending::wait`], registered with the checkpoint session).

use crate::data::Snapshot;
use crate::error::{Error, Result};
use crate::scene::Scene;
use std::path::PathBuf;
use std::sync::mpsc::{sync_channel, SyncSender};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::{Scope, ScopedJoinHandle};

/// The writes in flight and the first error, shared by the writer, the run loop and the
/// checkpoint session.
#[derive(Debug, Default)]
pub struct Pending {
    state: Mutex<State>,
    idle: Condvar,
}

#[derive(Debug, Default)]
struct State {
    /// Snapshots handed over and not yet written (or skipped).
    queued: usize,
    /// The first write that failed.
    error: Option<Error>,
}

impl Pending {
    fn lock(&self) -> MutexGuard<'_, State> {
        // A poisoned lock only means a thread panicked holding it; the counts stay valid.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Waits until every snapshot handed over is on disk; the first write error, if any.
    pub fn wait(&self) -> Result<()> {
        let mut s = self.lock();
        while s.queued > 0 {
            s = self.idle.wait(s).unwrap_or_else(|e| e.into_inner());
        }
        s.error.clone().map_or(Ok(()), Err)
    }

    /// The first write error so far, without waiting.
    fn check(&self) -> Result<()> {
        self.lock().error.clone().map_or(Ok(()), Err)
    }

    /// One more write in flight (handed over, not yet done).
    pub(crate) fn begin(&self) {
        self.lock().queued += 1;
    }

    /// A write in flight is done, with its result (the first error is kept).
    pub(crate) fn done(&self, r: Result<()>) {
        let mut s = self.lock();
        s.queued -= 1;
        if let (Err(e), None) = (r, &s.error) {
            s.error = Some(e);
        }
        self.idle.notify_all();
    }
}

struct Job {
    path: PathBuf,
    snap: Snapshot,
}

/// The run's side of the writer thread.
pub struct Writer {
    tx: SyncSender<Job>,
    pending: Arc<Pending>,
}

/// The writer thread; [`finish`] joins it.
pub type Handle<'scope> = ScopedJoinHandle<'scope, ()>;

impl Writer {
    /// Starts the writer thread in `scope`; it ends when the [`Writer`] is dropped and the
    /// queue is empty.
    pub fn start<'scope>(
        scope: &'scope Scope<'scope, '_>,
        scene: &'scope Scene,
    ) -> Result<(Self, Handle<'scope>)> {
        // A rendezvous: `write` hands a snapshot over only when the writer is free, so at most one
        // is being written and one waits (held by the caller in `write`).
        let (tx, rx) = sync_channel::<Job>(0);
        let pending = Arc::new(Pending::default());
        let shared = Arc::clone(&pending);
        let handle = std::thread::Builder::new()
            .name("sieve-writer".into())
            .spawn_scoped(scope, move || {
                for job in rx {
                    let r = match shared.check() {
                        // after a failure nothing more is written: the run is ending
                        Err(e) => Err(e),
                        Ok(()) => std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                            super::vtk::write_vti(&job.path, scene, &job.snap)
                        }))
                        .unwrap_or_else(|_| {
                            Err(Error::failure(format!(
                                "{}: the snapshot writer failed",
                                job.path.display()
                            )))
                        }),
                    };
                    shared.done(r);
                }
            })
            .map_err(|e| Error::failure(format!("cannot start the snapshot writer: {e}")))?;
        Ok((Self { tx, pending }, handle))
    }

    /// Hands `snap` over to be written to `path` as a `.vti`; waits while the previous one is
    /// still being written. An earlier write's error is returned here.
    pub fn write(&self, path: PathBuf, snap: Snapshot) -> Result<()> {
        self.pending.check()?;
        self.pending.begin();
        self.tx.send(Job { path, snap }).map_err(|_| {
            self.pending.lock().queued -= 1;
            Error::failure("the snapshot writer stopped")
        })
    }

    /// What a checkpoint waits for ([`crate::checkpoint::Session::after_writes`]).
    pub fn pending(&self) -> Arc<Pending> {
        Arc::clone(&self.pending)
    }
}

/// Ends the writer: every snapshot handed over is written (or the first error returned).
pub fn finish(writer: Writer, handle: Handle<'_>) -> Result<()> {
    let pending = writer.pending();
    drop(writer);
    handle
        .join()
        .map_err(|_| Error::failure("the snapshot writer panicked"))?;
    pending.wait()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn snapshot(n: usize, t: f64) -> Snapshot {
        Snapshot {
            t,
            c: vec![0.6; n],
            phi: (0..n).map(|i| 0.6 * i as f64 / n as f64).collect(),
            temp: vec![0.0; n],
            u: vec![[0.0; 3]; n],
            p: None,
            volume: None,
        }
    }

    /// The writer's files are byte for byte what the stepping thread wrote, in order.
    #[test]
    fn writes_the_same_bytes_as_a_direct_write() {
        let (scene, _) = crate::scene::load("column-a", &[]).expect("built-in scene");
        let n = scene.len();
        let dir = tempfile::tempdir().expect("tempdir");
        std::thread::scope(|sc| {
            let (w, h) = Writer::start(sc, &scene).expect("writer");
            for k in 0..4 {
                let path = dir.path().join(format!("w_{k}.vti"));
                w.write(path, snapshot(n, k as f64)).expect("queued");
            }
            w.pending().wait().expect("written");
            finish(w, h).expect("finished");
        });
        for k in 0..4 {
            let direct = dir.path().join(format!("d_{k}.vti"));
            super::super::vtk::write_vti(&direct, &scene, &snapshot(n, k as f64)).unwrap();
            let a = std::fs::read(dir.path().join(format!("w_{k}.vti"))).unwrap();
            let b = std::fs::read(&direct).unwrap();
            assert!(!a.is_empty());
            assert_eq!(a, b, "snapshot {k}");
        }
    }

    /// A write that fails is reported by the next write, by wait and by finish, and nothing
    /// after it is written.
    #[test]
    fn a_failed_write_is_reported_and_stops_the_writer() {
        let (scene, _) = crate::scene::load("column-a", &[]).expect("built-in scene");
        let n = scene.len();
        let dir = tempfile::tempdir().expect("tempdir");
        let missing = dir.path().join("no-such-dir").join("a.vti");
        std::thread::scope(|sc| {
            let (w, h) = Writer::start(sc, &scene).expect("writer");
            w.write(missing.clone(), snapshot(n, 0.0)).expect("queued");
            let e = w.pending().wait().expect_err("the write fails");
            assert!(e.to_string().contains("no-such-dir"), "{e}");
            let later = dir.path().join("later.vti");
            assert!(w.write(later.clone(), snapshot(n, 1.0)).is_err());
            assert!(finish(w, h).is_err());
            assert!(!later.exists());
        });
    }
}
