//! MPI ranks as subdomains (the `mpi` feature; docs/parallel.md, "MPI: sieve run under
//! mpirun"): the threads' construction ([`crate::parallel`], [`sieve_core::decomp`]) with one
//! subdomain per rank and the halo rows sent as MPI messages.
//!
//! `mpirun -np K sieve run SCENE ...`: every rank parses the same command line, loads the scene
//! and prepares the global solver (a frozen-flow scene spins its flow up on every rank: the
//! same bits, so nothing is broadcast). Rank 0 runs the ordinary run loop
//! ([`crate::run::time_loop_driven`]) with [`Driver::advance`] as its stepper, in place of the
//! threads' `parallel::Driver::advance`, and writes every serial file from its global solver,
//! the state of record. The other ranks (followers) serve commands from rank 0 until it says
//! stop:
//!
//! - *advance* to `target` with at most `n` steps: every rank steps its subdomain (halo rows
//!   by MPI messages after every step, the flush and the bound maxima over the owned cells:
//!   [`Segregation::end_owned_step`]); the owned rows, the maxima and the flushed values go to
//!   rank 0, which adds the flushed values in (step, rank, cell) order, the serial order;
//! - *load*: rank 0 changed its global state (the replay that resolves the segregation time
//!   restores the start of an interval) and sends every rank its rows;
//! - *output* `k`: every rank writes the `.vti` piece of its owned rows; rank 0 writes the
//!   `.pvti` that names them ([`write_snapshot`]);
//! - *stop* with the exit code of rank 0.
//!
//! Checkpoints (`run.checkpoint_interval`, docs/resume.md) are rank 0's alone: its run loop
//! writes them from its global solver, gathered after every chunk, at the serial chunk
//! boundaries; the wall-clock decision is taken there, once. The followers take no part
//! (they wait for the next command while rank 0 writes), so no rank can decide otherwise and
//! nothing is broadcast for it. `--resume`: every rank reads the checkpoint and restores its
//! global solver before it builds its subdomain (`crate::mpi_jobs::follow`); the kept
//! `.pvti` snapshots and their pieces are rank 0's to check and adopt.
//!
//! Errors end every rank, never a hang: before the run every rank reports to rank 0 whether
//! its setup worked ([`agree`]: the first failure in rank order becomes every rank's result,
//! rank 0 prints it, the others exit with its code silently); after that a follower's failure
//! to write its piece is its reply to the output command; rank 0 ending for any reason sends
//! stop with its exit code; an error in the middle of a message exchange (a panic) aborts the
//! job (`MPI_Abort`).
//!
//! Messages carry f64 (an f32 state widens exactly and narrows back exactly), so the driver
//! is generic over the precision without an MPI datatype per float type. The solver jobs of
//! the followers and of the check without files (`host/examples/mpi_check.rs`) are in
//! `crate::mpi_jobs`: they build solvers through `crate::run`, which calls this module.

use crate::data::Snapshot;
use crate::error::{Error, Result};
use crate::parallel::{halo_of, is_coupled, step_owned, Chunk, Pace};
use crate::scene::validate::{Direction, Temperature};
use crate::scene::Scene;
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;
use sieve_core::decomp::{self, Side, Subdomain};
use sieve_core::geometry::CutCells;
use sieve_core::segregation::snap_slack;
use sieve_core::sum::FixedSum;
use sieve_core::{Real, Segregation};
use std::cell::{Cell, RefCell};
use std::ops::Range;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicUsize, Ordering};
use std::sync::Mutex;

// ---------------------------------------------------------------------------------------
// The launch

/// MPI, once initialised; finalised (dropped) by [`finish`].
static UNIVERSE: Mutex<Option<mpi::environment::Universe>> = Mutex::new(None);
/// This rank and the number of ranks of an MPI run (0 ranks: not an MPI run).
static RANK: AtomicUsize = AtomicUsize::new(0);
static RANKS: AtomicUsize = AtomicUsize::new(0);
/// Where the ranks are: before the agreement, running (agreed), done (stopped, or agreed on
/// a failure).
static PHASE: AtomicU8 = AtomicU8::new(BEFORE);
const BEFORE: u8 = 0;
const RUNNING: u8 = 1;
const DONE: u8 = 2;
/// Rank 0 is inside a command's message exchange (an error there cannot be answered with
/// a stop command: the followers wait for other messages).
static BUSY: AtomicBool = AtomicBool::new(false);
/// This rank's error has been printed (by rank 0): do not print it again.
static SILENT: AtomicBool = AtomicBool::new(false);
/// The agreement found a failure.
static FAILED: AtomicBool = AtomicBool::new(false);

/// Processes of the launch as the launcher's environment says (OpenMPI's mpirun:
/// `OMPI_COMM_WORLD_SIZE`; MPICH's hydra and Slurm's PMI: `PMI_SIZE`).
fn launcher_size() -> Option<usize> {
    ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE"]
        .iter()
        .find_map(|k| std::env::var(k).ok()?.trim().parse().ok())
}

/// Initialises MPI if this process was launched as one of several (decision: only then, so
/// that `sieve run` of an `mpi` build started without a launcher never calls `MPI_Init`,
/// which without a launcher may start a singleton runtime or fail). Returns whether this is
/// an MPI run of more than one rank; a launch of one rank runs serially, unchanged.
pub fn launch() -> Result<bool> {
    if launcher_size().is_none_or(|n| n <= 1) {
        return Ok(false);
    }
    // Serialized: MPI is called from the main thread (this, the agreement on an early
    // failure, the finalisation) and from the solver thread, never at the same time.
    let (universe, _) = mpi::initialize_with_threading(mpi::Threading::Serialized)
        .ok_or_else(|| Error::failure("MPI is already initialised"))?;
    let world = universe.world();
    let (rank, ranks) = (world.rank() as usize, world.size() as usize);
    *UNIVERSE.lock().unwrap_or_else(|e| e.into_inner()) = Some(universe);
    if ranks <= 1 {
        return Ok(false);
    }
    RANK.store(rank, Ordering::Relaxed);
    RANKS.store(ranks, Ordering::Relaxed);
    Ok(true)
}

/// `(rank, ranks)` of an MPI run of more than one rank ([`launch`]).
pub fn world() -> Option<(usize, usize)> {
    match RANKS.load(Ordering::Relaxed) {
        0 => None,
        n => Some((RANK.load(Ordering::Relaxed), n)),
    }
}

/// This process is a follower (rank > 0) of an MPI run.
pub fn is_follower() -> bool {
    world().is_some_and(|(r, _)| r > 0)
}

/// The error of this process was printed by rank 0 (main prints nothing).
pub fn silent() -> bool {
    SILENT.load(Ordering::Relaxed)
}

pub(crate) fn comm() -> SimpleCommunicator {
    SimpleCommunicator::world()
}

/// Ends the MPI run of `sieve run` with the command's result on this rank: agrees on it
/// if the ranks never reached the agreement, sends stop from rank 0, aborts the job if
/// a message exchange was cut off, and finalises MPI. Returns this rank's result (a
/// follower's is silent when rank 0 reported it).
pub fn finish(result: Result<()>) -> Result<()> {
    let out = match world() {
        None => result,
        Some((rank, _)) => match PHASE.load(Ordering::Relaxed) {
            BEFORE => {
                // this rank ended before the agreement (bad input, a setup failure, or a
                // path that does not step): tell the others, take the verdict
                let verdict = agree(result.as_ref().err());
                if rank == 0 && verdict.is_ok() {
                    send_stop(0);
                }
                verdict
            }
            RUNNING if rank == 0 && !BUSY.load(Ordering::Relaxed) => {
                // printed before the stop: mpirun ends the job as soon as a rank exits
                // with a non-zero code, which could cut rank 0 off before its line
                if let Err(e) = &result {
                    report(e);
                }
                send_stop(result.as_ref().err().map_or(0, |e| e.exit_code()));
                result
            }
            RUNNING => abort(result),
            _ => result,
        },
    };
    if FAILED.load(Ordering::Relaxed) {
        // a failed agreement: rank 0 prints the verdict, the others wait for that (see
        // above), then every rank exits with its code
        if let (Some((0, _)), Err(e)) = (world(), &out) {
            report(e);
        }
        comm().barrier();
    }
    let universe = UNIVERSE.lock().unwrap_or_else(|e| e.into_inner()).take();
    drop(universe);
    out
}

/// Rank 0 prints an error as `main` would (one line per problem), before the other ranks
/// may exit; `main` then prints nothing ([`silent`]).
fn report(e: &Error) {
    if SILENT.swap(true, Ordering::Relaxed) {
        return;
    }
    let prefix = match e {
        Error::Interrupted { .. } => "sieve",
        _ => "error",
    };
    for line in e.lines() {
        eprintln!("{prefix}: {line}");
    }
}

/// An error that cannot be delivered through the protocol: printed here, then every rank
/// ends (`MPI_Abort`).
fn abort(result: Result<()>) -> ! {
    let rank = RANK.load(Ordering::Relaxed);
    let e = result
        .err()
        .unwrap_or_else(|| Error::failure("the MPI run ended out of step"));
    for line in e.lines() {
        eprintln!("error: rank {rank}: {line}");
    }
    comm().abort(e.exit_code().max(1))
}

// ---------------------------------------------------------------------------------------
// Agreement and commands

const TAG_AGREE: i32 = 40;
const TAG_HEAD: i32 = 41;
const TAG_VALUES: i32 = 42;
const TAG_FLUSH_STEPS: i32 = 43;
const TAG_FLUSH_VALUES: i32 = 44;
pub(crate) const TAG_STATUS: i32 = 45;

/// An error as bytes: the exit code, then the message.
pub(crate) fn encode(e: &Error) -> Vec<u8> {
    let mut b = vec![e.exit_code().clamp(1, 255) as u8];
    b.extend_from_slice(e.to_string().as_bytes());
    b
}

pub(crate) fn decode(b: &[u8]) -> Error {
    let m = String::from_utf8_lossy(&b[1..]).into_owned();
    match b[0] {
        2 => Error::Input(m),
        3 => Error::Numerical(m),
        c @ (130 | 143) => Error::Interrupted {
            code: c as i32,
            message: m,
        },
        _ => Error::Failure(m),
    }
}

/// Every rank reports whether its setup worked (`mine`); the first failure in rank order
/// is every rank's result. Rank 0 prints it in [`finish`] (a follower's prefixed with its
/// rank) before any rank exits; the followers return it silently. Called exactly once per
/// rank.
pub fn agree(mine: Option<&Error>) -> Result<()> {
    let (rank, ranks) = world().ok_or_else(|| Error::failure("not an MPI run"))?;
    let world = comm();
    let root = world.process_at_rank(0);
    let mut verdict = Vec::new();
    if rank == 0 {
        if let Some(e) = mine {
            verdict = encode(e);
        }
        for r in 1..ranks {
            let (b, _) = world
                .process_at_rank(r as i32)
                .receive_vec_with_tag::<u8>(TAG_AGREE);
            if verdict.is_empty() && !b.is_empty() {
                let e = decode(&b);
                let mut v = vec![b[0]];
                v.extend_from_slice(format!("rank {r}: {e}").as_bytes());
                verdict = v;
            }
        }
    } else {
        let b = mine.map(encode).unwrap_or_default();
        root.send_with_tag(&b[..], TAG_AGREE);
    }
    let mut len = verdict.len() as u64;
    root.broadcast_into(&mut len);
    verdict.resize(len as usize, 0);
    if len > 0 {
        root.broadcast_into(&mut verdict[..]);
        PHASE.store(DONE, Ordering::Relaxed);
        FAILED.store(true, Ordering::Relaxed);
        SILENT.store(rank > 0, Ordering::Relaxed);
        return Err(decode(&verdict));
    }
    PHASE.store(RUNNING, Ordering::Relaxed);
    Ok(())
}

/// A command from rank 0 to every rank.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Command {
    /// End with this exit code.
    Stop(i32),
    /// Step to `target` (f64 bits of the precision's value) with at most `n` steps.
    Advance { target: f64, n: u64 },
    /// Take your rows of the state from rank 0.
    Load,
    /// Write the piece of output `k` into the directory.
    Output { k: u64, dir: String },
    /// One coupled step toward `target` (`first`: the run's first stable step; `sample`:
    /// sample it for the segregation timer): `crate::rank_coupled`.
    CoupledStep {
        target: f64,
        first: f64,
        sample: bool,
    },
    /// Send your slab's rows and record to rank 0 (`crate::rank_coupled`).
    Gather,
}

pub(crate) fn broadcast(cmd: &Command) {
    let world = comm();
    let root = world.process_at_rank(0);
    let mut w: [u64; 4] = match cmd {
        Command::Stop(c) => [0, *c as u64, 0, 0],
        Command::Advance { target, n } => [1, target.to_bits(), *n, 0],
        Command::Load => [2, 0, 0, 0],
        Command::Output { k, dir } => [3, *k, 0, dir.len() as u64],
        Command::CoupledStep {
            target,
            first,
            sample,
        } => [4, target.to_bits(), first.to_bits(), u64::from(*sample)],
        Command::Gather => [5, 0, 0, 0],
    };
    // non-blocking on every rank (a non-blocking collective matches no blocking one): the
    // followers wait for it asleep ([`receive`])
    mpi::request::scope(|sc| {
        root.immediate_broadcast_into(sc, &mut w[..]).wait();
    });
    if let Command::Output { dir, .. } = cmd {
        let mut b = dir.as_bytes().to_vec();
        root.broadcast_into(&mut b[..]);
    }
}

pub(crate) fn receive() -> Command {
    let world = comm();
    let root = world.process_at_rank(0);
    let mut w = [0u64; 4];
    // Polled at full speed for 100 us (a coupled run's next step command follows the last
    // step that closely), then with short sleeps rather than MPI's busy wait: a follower
    // waits for the next command while rank 0 computes diagnostics, writes files and draws
    // the plots, and on a machine with more ranks than free cores a spinning follower takes
    // CPU from rank 0. The sleep delays a chunk of steps by about 0.1 ms.
    mpi::request::scope(|sc| {
        let mut req = root.immediate_broadcast_into(sc, &mut w[..]);
        let start = std::time::Instant::now();
        loop {
            match req.test() {
                Ok(_) => break,
                Err(r) => {
                    req = r;
                    if start.elapsed() > std::time::Duration::from_micros(100) {
                        std::thread::sleep(std::time::Duration::from_micros(50));
                    }
                }
            }
        }
    });
    match w[0] {
        1 => Command::Advance {
            target: f64::from_bits(w[1]),
            n: w[2],
        },
        2 => Command::Load,
        4 => Command::CoupledStep {
            target: f64::from_bits(w[1]),
            first: f64::from_bits(w[2]),
            sample: w[3] != 0,
        },
        5 => Command::Gather,
        3 => {
            let mut b = vec![0u8; w[3] as usize];
            root.broadcast_into(&mut b[..]);
            Command::Output {
                k: w[1],
                dir: String::from_utf8_lossy(&b).into_owned(),
            }
        }
        _ => Command::Stop(w[1] as i32),
    }
}

fn send_stop(code: i32) {
    broadcast(&Command::Stop(code));
    PHASE.store(DONE, Ordering::Relaxed);
}

// ---------------------------------------------------------------------------------------
// Scope

/// Why a scene cannot run under mpirun, before anything is built (every rank finds the
/// same): cut-cell scenes and coupled scenes periodic along their last axis (decision:
/// refused, exit 2, rather than run on rank 0 while the other ranks wait), and more ranks
/// than the rows allow (cut cells: halos [`decomp::GROUP_REACH`] rows wider; coupled
/// scenes: slabs of [`sieve_core::flow::slab::HALO`] rows at least, starting on even rows;
/// with merged cut cells the halo is deeper, which the ranks check once the geometry is
/// built, before the first step: `crate::rank_coupled`). Checkpoints and `--resume` run (rank 0 writes the checkpoints from its
/// global solver; every rank reads the checkpoint it resumes: `crate::mpi_jobs::follow`).
pub fn check_scope(scene: &Scene) -> Result<()> {
    let Some((_, ranks)) = world() else {
        return Ok(());
    };
    let wraps = scene
        .boundaries
        .last()
        .is_some_and(|b| b[0] == sieve_core::Boundary::Periodic);
    let coupled = is_coupled(scene);
    let why = if scene.geometry.is_some() && wraps {
        Some("cut-cell (geometry) scenes periodic along their last axis")
    } else if coupled && wraps {
        Some("coupled-flow scenes periodic along their last axis")
    } else {
        None
    };
    if let Some(w) = why {
        return Err(Error::at(
            &scene.label,
            "mpirun",
            format!("{w} run on one rank only: run them without mpirun (docs/parallel.md)"),
        ));
    }
    let rows = scene.cells[scene.dim - 1];
    if coupled {
        let halo = sieve_core::flow::slab::HALO;
        if crate::coupled_steps::slab_starts(rows, ranks, halo).is_none() {
            let (label, dim) = (&scene.label, scene.dim);
            return Err(crate::coupled_steps::too_many_ranks(
                label, dim, rows, ranks, halo,
            ));
        }
        return Ok(());
    }
    let gradient = matches!(scene.direction, Direction::Flow)
        || matches!(scene.temperature, Temperature::Shear { .. });
    let halo = if gradient { 2 } else { 1 }
        + if scene.geometry.is_some() {
            decomp::GROUP_REACH
        } else {
            0
        };
    let max = decomp::max_parts(rows, halo);
    if ranks > max {
        let axis = crate::scene::validate::axis_names(scene.dim)[scene.dim - 1];
        return Err(Error::range(
            &scene.label,
            "mpirun -np",
            ranks,
            &format!(
                "1 to {max} ranks for {rows} cells along {axis} (each rank owns at least {halo} row{}, docs/parallel.md)",
                if halo > 1 { "s" } else { "" }
            ),
        ));
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------
// Stepping one subdomain

/// The state arrays of the subdomains rank 0 copies in and out (the carried rounding error
/// of compensated updates too; the halo exchange needs `q` only: docs/parallel.md).
fn copied(global_compensated: bool) -> &'static [&'static str] {
    if global_compensated {
        &["q", "carry"]
    } else {
        &["q"]
    }
}

/// One rank's subdomain and its halo buffers.
struct Local<R: Real, const D: usize, const N: usize> {
    sub: Subdomain,
    s: Box<Segregation<R, D, N>>,
    /// The subdomain's slab of the cut cells (cut-cell scenes).
    geo: Option<Box<CutCells<R, D, N>>>,
    /// The global step (the subdomain's own is larger: model.md 5, decomp.rs).
    dt: R,
    floor: R,
    /// The running bound maxima over the owned cells.
    excess: [R; 2],
    fields: &'static [&'static str],
    send: [Vec<f64>; 2],
    recv: [Vec<f64>; 2],
    buf: Vec<R>,
}

/// Waits for a halo message: polls at full speed for 100 us (a neighbour on its own core is
/// that close behind in a balanced step), then with 20 us sleeps. MPI's own wait polls at
/// full speed however long it takes, which on a machine with more processes than free
/// cores takes the CPU the awaited rank needs (docs/parallel.md, measured there).
pub(crate) fn wait_politely<'a, S: mpi::request::Scope<'a>>(
    mut req: mpi::request::Request<'a, [f64], S>,
) {
    let start = std::time::Instant::now();
    loop {
        match req.test() {
            Ok(_) => return,
            Err(r) => req = r,
        }
        if start.elapsed() < std::time::Duration::from_micros(100) {
            std::hint::spin_loop();
        } else {
            std::thread::sleep(std::time::Duration::from_micros(20));
        }
    }
}

/// A blocking receive of `buf.len()` values from rank `from` with `tag`, waiting as
/// [`wait_politely`] does (the sums and line solves of `rank_sum` and `rank_lines`).
pub(crate) fn receive_politely<C: Communicator>(comm: &C, from: usize, tag: i32, buf: &mut [f64]) {
    mpi::request::scope(|sc| {
        wait_politely(
            comm.process_at_rank(from as i32)
                .immediate_receive_into_with_tag(sc, buf, tag),
        );
    });
}

/// `values` widened to f64, as every message of the solver's MPI drivers travels (an f32
/// value widens and narrows back exactly, so one MPI datatype serves both precisions).
pub(crate) fn widen<R: Real>(values: &[R]) -> Vec<f64> {
    values.iter().map(|v| v.to_f64()).collect()
}

/// A message of [`widen`]ed values back in `R`, into `out`.
pub(crate) fn narrow<R: Real>(message: &[f64], out: &mut [R]) {
    for (o, &v) in out.iter_mut().zip(message) {
        *o = R::from_f64(v);
    }
}

/// Sends `values` [`widen`]ed to rank `to` with `tag` (a standard, blocking send).
pub(crate) fn send_widened<R: Real, C: Communicator>(comm: &C, to: usize, tag: i32, values: &[R]) {
    comm.process_at_rank(to as i32)
        .send_with_tag(&widen(values)[..], tag);
}

/// A broadcast of `buf` from rank `root`, waiting as [`wait_politely`] does.
pub(crate) fn broadcast_politely<C: Communicator>(comm: &C, root: usize, buf: &mut [f64]) {
    mpi::request::scope(|sc| {
        wait_politely(
            comm.process_at_rank(root as i32)
                .immediate_broadcast_into(sc, buf),
        );
    });
}

impl<R: Real, const D: usize, const N: usize> Local<R, D, N> {
    /// Subdomain `rank` of `ranks` of the prepared `global`, checked against the global
    /// step.
    fn new(
        global: &Segregation<R, D, N>,
        geo: Option<&CutCells<R, D, N>>,
        rank: usize,
        ranks: usize,
    ) -> Result<Self> {
        let halo = halo_of(global, geo);
        let sub = Subdomain::new(global.grid(), global.boundaries(), ranks, rank, halo)
            .map_err(|e| Error::failure(format!("{ranks} ranks cannot split the grid: {e:?}")))?;
        let mut s = Box::new(Segregation::<R, D, N>::zeroed());
        decomp::load_subdomain(global, &sub, &mut s)
            .map_err(|e| Error::failure(format!("rank {rank}: {e:?}")))?;
        let local_geo = match geo {
            Some(g) => {
                let mut cut = Box::new(CutCells::<R, D, N>::zeroed());
                decomp::load_cut_cells(g, &sub, &mut cut)
                    .map_err(|e| Error::failure(format!("rank {rank}: cut cells: {e:?}")))?;
                Some(cut)
            }
            None => None,
        };
        // Every rank steps with the global step, which it computed itself (the same bits on
        // every rank). The subdomain's own step is over a subset of the cells, so it cannot
        // be smaller: a smaller one is a bug, not bad input (docs/parallel.md).
        let (mine, dt) = match (geo, &local_geo) {
            (Some(g), Some(l)) => (s.stable_dt_embedded(l), global.stable_dt_embedded(g)),
            _ => (s.stable_dt(), global.stable_dt()),
        };
        if mine < dt {
            return Err(Error::failure(format!(
                "rank {rank}: subdomain time step {:e} below the global {:e}",
                mine.to_f64(),
                dt.to_f64()
            )));
        }
        let len = |side| sub.message_len(side, 1);
        Ok(Self {
            sub,
            s,
            geo: local_geo,
            dt,
            floor: global.config().flush_below,
            excess: global.tracked_excess(),
            fields: copied(global.config().compensated),
            send: [vec![0.0; len(Side::Low)], vec![0.0; len(Side::High)]],
            recv: [vec![0.0; len(Side::Low)], vec![0.0; len(Side::High)]],
            buf: Vec::new(),
        })
    }

    /// `advance_to(target, max_steps)` on this subdomain, step for step as the serial
    /// control (and the threads' driver), with a halo exchange after every step.
    fn chunk(&mut self, target: R, max_steps: u64) -> Chunk<R> {
        let slack = snap_slack(target);
        let mut flushed = Vec::new();
        let mut taken = 0;
        // the books of this chunk's steps alone: rank 0's global solver holds the earlier ones
        self.s.set_side_books([[FixedSum::ZERO; 2]; D]);
        let pace = Pace {
            target,
            dt: self.dt,
            slack,
            floor: self.floor,
        };
        while self.s.time() < target && taken < max_steps {
            let geo = self.geo.as_deref();
            step_owned(&mut self.s, geo, pace, &mut self.excess, &mut flushed);
            taken += 1;
            self.exchange();
        }
        Chunk {
            taken,
            time: self.s.time(),
            steps: self.s.steps(),
            excess: self.excess,
            flushed,
            books: self.s.side_books().to_vec(),
        }
    }

    /// The owned rows next to each cut to the neighbours (non-blocking sends tagged with the
    /// sending side), the neighbours' rows into the halos (blocking receives).
    fn exchange(&mut self) {
        let sub = self.sub;
        let sides = [Side::Low, Side::High];
        for side in sides {
            if sub.neighbour(side).is_some() {
                let k = side as usize;
                self.buf.resize(sub.message_len(side, 1), R::ZERO);
                decomp::pack(&self.s, &sub, side, &["q"], &mut self.buf);
                for (m, x) in self.send[k].iter_mut().zip(&self.buf) {
                    *m = x.to_f64();
                }
            }
        }
        let world = comm();
        let (send, recv) = (&self.send, &mut self.recv);
        mpi::request::scope(|sc| {
            let mut pending = Vec::new();
            for side in sides {
                if let Some(nb) = sub.neighbour(side) {
                    let p = world.process_at_rank(nb as i32);
                    pending.push(p.immediate_send_with_tag(
                        sc,
                        &send[side as usize][..],
                        side as i32,
                    ));
                }
            }
            for (side, r) in sides.into_iter().zip(recv.iter_mut()) {
                if let Some(nb) = sub.neighbour(side) {
                    let p = world.process_at_rank(nb as i32);
                    pending.push(p.immediate_receive_into_with_tag(
                        sc,
                        &mut r[..],
                        side.opposite() as i32,
                    ));
                }
            }
            for r in pending {
                wait_politely(r);
            }
        });
        for side in sides {
            if sub.neighbour(side).is_some() {
                let k = side as usize;
                self.buf.clear();
                self.buf
                    .extend(self.recv[k].iter().map(|&x| R::from_f64(x)));
                decomp::unpack(&mut self.s, &sub, side, &["q"], &self.buf);
            }
        }
    }

    /// The owned values of the copied arrays, array after array, as f64.
    fn owned_values(&self) -> Vec<f64> {
        let own = self.sub.owned_cells();
        let mut out = Vec::with_capacity(own.len() * self.fields.len());
        for f in self.fields {
            self.s.for_each_state_array(|name, a| {
                if name == *f {
                    out.extend(a[own.clone()].iter().map(|x| x.to_f64()));
                }
            });
        }
        out
    }

    /// A follower sends its chunk to rank 0.
    fn send_chunk(&self, c: &Chunk<R>) {
        let world = comm();
        let root = world.process_at_rank(0);
        let mut head = vec![
            c.taken,
            c.time.to_f64().to_bits(),
            c.steps,
            c.excess[0].to_f64().to_bits(),
            c.excess[1].to_f64().to_bits(),
        ];
        head.extend(FixedSum::words_of(&c.books));
        root.send_with_tag(&head[..], TAG_HEAD);
        root.send_with_tag(&self.owned_values()[..], TAG_VALUES);
        let steps: Vec<u64> = c.flushed.iter().map(|e| e.0).collect();
        let values: Vec<f64> = c.flushed.iter().map(|e| e.1.to_f64()).collect();
        root.send_with_tag(&steps[..], TAG_FLUSH_STEPS);
        root.send_with_tag(&values[..], TAG_FLUSH_VALUES);
    }

    /// A follower takes its local rows (halos included) and the clock from rank 0.
    fn receive_load(&mut self) {
        let world = comm();
        let root = world.process_at_rank(0);
        let (head, _) = root.receive_vec_with_tag::<u64>(TAG_HEAD);
        let (values, _) = root.receive_vec_with_tag::<f64>(TAG_VALUES);
        let n = self.sub.local_len();
        let fields = self.fields;
        for (j, f) in fields.iter().enumerate() {
            self.s.for_each_state_array_mut(|name, a| {
                if name == *f {
                    for (x, &v) in a[..n].iter_mut().zip(&values[j * n..(j + 1) * n]) {
                        *x = R::from_f64(v);
                    }
                }
            });
        }
        self.s
            .set_clock(R::from_f64(f64::from_bits(head[0])), head[1]);
    }
}

/// Writes the `q` (and `carry`) values of a message into `global`'s cells `cells`.
fn put_values<R: Real, const D: usize, const N: usize>(
    global: &mut Segregation<R, D, N>,
    fields: &[&str],
    cells: Range<usize>,
    values: &[f64],
) {
    let n = cells.len();
    for (j, f) in fields.iter().enumerate() {
        global.for_each_state_array_mut(|name, a| {
            if name == *f {
                for (x, &v) in a[cells.clone()].iter_mut().zip(&values[j * n..(j + 1) * n]) {
                    *x = R::from_f64(v);
                }
            }
        });
    }
}

/// The flushed counter after a chunk: `start` plus every flushed value in (step, rank,
/// cell) order, the serial (step, cell) order. Zeros were skipped: adding a zero to the
/// counter (from +0) changes no bit.
fn fold_flushed<R: Real>(start: R, lists: &[Vec<(u64, R)>]) -> R {
    let mut total = start;
    let mut at = vec![0usize; lists.len()];
    while let Some(step) = lists
        .iter()
        .zip(&at)
        .filter_map(|(l, &k)| l.get(k).map(|e| e.0))
        .min()
    {
        for (l, k) in lists.iter().zip(at.iter_mut()) {
            while let Some(&(s, v)) = l.get(*k) {
                if s != step {
                    break;
                }
                total += v;
                *k += 1;
            }
        }
    }
    total
}

// ---------------------------------------------------------------------------------------
// Rank 0

/// Rank 0's stepper: its own subdomain, the others' by command.
pub struct Driver<R: Real, const D: usize, const N: usize> {
    local: RefCell<Local<R, D, N>>,
    /// Every rank's subdomain (rank order).
    subs: Vec<Subdomain>,
    /// The clock (time bits, steps) of the state the ranks hold: rank 0's global state was
    /// changed between calls when its clock differs (then the ranks load it first).
    held: Cell<(u64, u64)>,
}

/// Rank 0's driver of an MPI run ([`world`]); `None` if this is not one. Builds rank 0's
/// subdomain, then agrees with the followers ([`agree`]) and checks the time step.
pub fn driver_for<R: Real, const D: usize, const N: usize>(
    s: &Segregation<R, D, N>,
    geo: Option<&CutCells<R, D, N>>,
) -> Result<Option<Driver<R, D, N>>> {
    let Some((0, ranks)) = world() else {
        return Ok(None);
    };
    let local = Local::new(s, geo, 0, ranks);
    agree(local.as_ref().err())?;
    let local = local?;
    let halo = halo_of(s, geo);
    let subs = (0..ranks)
        .map(|r| Subdomain::new(s.grid(), s.boundaries(), ranks, r, halo))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| Error::failure(format!("{e:?}")))?;
    Ok(Some(Driver {
        local: RefCell::new(local),
        subs,
        held: Cell::new((s.time().to_f64().to_bits(), s.steps())),
    }))
}

impl<R: Real, const D: usize, const N: usize> Driver<R, D, N> {
    /// Number of ranks.
    pub fn ranks(&self) -> usize {
        self.subs.len()
    }

    /// `global.advance_to(target, max_steps)` on the ranks: the same steps, the same bits
    /// in the global solver afterwards; returns the number of steps taken.
    pub fn advance(&self, global: &mut Segregation<R, D, N>, target: R, max_steps: u64) -> u64 {
        if !target.is_finite() || max_steps == 0 || global.time() >= target {
            return 0;
        }
        BUSY.store(true, Ordering::Relaxed);
        let mut local = self.local.borrow_mut();
        let world = comm();
        let fields = local.fields;
        if self.held.get() != (global.time().to_f64().to_bits(), global.steps()) {
            broadcast(&Command::Load);
            let head = [global.time().to_f64().to_bits(), global.steps()];
            for (r, sub) in self.subs.iter().enumerate().skip(1) {
                let p = world.process_at_rank(r as i32);
                let mut values = Vec::with_capacity(sub.local_len() * fields.len());
                for f in fields {
                    global.for_each_state_array(|name, a| {
                        if name == *f {
                            for lr in 0..sub.local_rows() {
                                let g = sub.global_row(lr) * sub.plane;
                                values.extend(a[g..g + sub.plane].iter().map(|x| x.to_f64()));
                            }
                        }
                    });
                }
                p.send_with_tag(&head[..], TAG_HEAD);
                p.send_with_tag(&values[..], TAG_VALUES);
            }
            let sub = local.sub;
            decomp::copy_rows(global, &sub, &mut local.s, fields);
            local.s.set_clock(global.time(), global.steps());
        }
        broadcast(&Command::Advance {
            target: target.to_f64(),
            n: max_steps,
        });
        let mine = local.chunk(target, max_steps);
        let sub = local.sub;
        decomp::gather_rows(&local.s, &sub, global, fields);
        let mut excess = mine.excess;
        global.merge_side_books(&mine.side_books());
        let mut lists = vec![mine.flushed];
        for (r, sub) in self.subs.iter().enumerate().skip(1) {
            let p = world.process_at_rank(r as i32);
            let (head, _) = p.receive_vec_with_tag::<u64>(TAG_HEAD);
            let (values, _) = p.receive_vec_with_tag::<f64>(TAG_VALUES);
            let (steps, _) = p.receive_vec_with_tag::<u64>(TAG_FLUSH_STEPS);
            let (flushed, _) = p.receive_vec_with_tag::<f64>(TAG_FLUSH_VALUES);
            debug_assert_eq!((head[0], head[2]), (mine.taken, mine.steps));
            put_values(global, fields, sub.global_cells(), &values);
            for (e, &h) in excess.iter_mut().zip(&head[3..5]) {
                *e = e.max(R::from_f64(f64::from_bits(h)));
            }
            global.merge_side_books(&FixedSum::sides_from_words(&head[5..]));
            lists.push(
                steps
                    .into_iter()
                    .zip(flushed.into_iter().map(R::from_f64))
                    .collect(),
            );
        }
        let before = global.tracked_excess();
        global.set_clock(mine.time, mine.steps);
        global.set_tracked_excess([before[0].max(excess[0]), before[1].max(excess[1])]);
        global.set_flushed_tracked(fold_flushed(global.flushed_tracked(), &lists));
        self.held
            .set((global.time().to_f64().to_bits(), global.steps()));
        BUSY.store(false, Ordering::Relaxed);
        mine.taken
    }
}

/// The cells of rows `rows` (of the last scene axis) of a snapshot of the whole grid.
fn rows_of(snap: &Snapshot, plane: usize, rows: &Range<usize>) -> Snapshot {
    let cells = rows.start * plane..rows.end * plane;
    Snapshot {
        t: snap.t,
        c: snap.c[cells.clone()].to_vec(),
        phi: snap.phi[cells.clone()].to_vec(),
        temp: snap.temp[cells.clone()].to_vec(),
        u: snap.u[cells.clone()].to_vec(),
        p: snap.p.as_ref().map(|p| p[cells.clone()].to_vec()),
        volume: snap.volume.as_ref().map(|v| v[cells.clone()].to_vec()),
    }
}

/// The rows rank `rank` owns and writes the piece of: its subdomain's, or its slab's in a
/// coupled run ([`crate::coupled_steps::even_starts`]).
fn piece_rows(scene: &Scene, ranks: usize, rank: usize) -> Range<usize> {
    let rows = scene.cells[scene.dim - 1];
    if is_coupled(scene) && rank < ranks {
        let starts = crate::coupled_steps::even_starts(rows, ranks);
        return starts[rank]..starts.get(rank + 1).copied().unwrap_or(rows);
    }
    decomp::owned_rows(rows, ranks, rank)
}

/// The file of rank `rank`'s piece of output `k` (beside the `.pvti`).
fn piece_name(k: u64, rank: usize) -> String {
    crate::checkpoint::piece_name(k as usize, rank)
}

/// Writes this rank's piece of output `k` from a snapshot of the whole grid.
pub(crate) fn write_piece(
    dir: &Path,
    k: u64,
    scene: &Scene,
    snap: &Snapshot,
    rank: usize,
    ranks: usize,
) -> Result<Range<usize>> {
    let rows = piece_rows(scene, ranks, rank);
    let plane = scene.len() / scene.cells[scene.dim - 1];
    let piece = rows_of(snap, plane, &rows);
    crate::output::write_file(
        &dir.join(piece_name(k, rank)),
        &crate::output::vtk::piece_bytes(scene, &piece, rows.clone()),
    )?;
    Ok(rows)
}

/// The VTK snapshot of output `k` of an MPI run (rank 0; `None` if this is not one): every
/// rank writes the `.vti` piece of its owned rows into `dir` (the run's staging `fields/`
/// directory, which must be on a file system every rank sees), rank 0 the
/// `state_KKKK.pvti` that names them; returns its name for the `.pvd`.
pub fn write_snapshot(
    dir: &Path,
    k: usize,
    scene: &Scene,
    snap: &Snapshot,
) -> Result<Option<String>> {
    let Some((0, ranks)) = world() else {
        return Ok(None);
    };
    BUSY.store(true, Ordering::Relaxed);
    let k = k as u64;
    broadcast(&Command::Output {
        k,
        dir: dir.to_string_lossy().into_owned(),
    });
    let mine = write_piece(dir, k, scene, snap, 0, ranks);
    let world = comm();
    let mut failed = mine.as_ref().err().cloned();
    for r in 1..ranks {
        let (b, _) = world
            .process_at_rank(r as i32)
            .receive_vec_with_tag::<u8>(TAG_STATUS);
        if failed.is_none() && !b.is_empty() {
            failed = Some(Error::failure(format!("rank {r}: {}", decode(&b))));
        }
    }
    BUSY.store(false, Ordering::Relaxed);
    if let Some(e) = failed {
        return Err(e);
    }
    let pieces: Vec<(Range<usize>, String)> = (0..ranks)
        .map(|r| (piece_rows(scene, ranks, r), piece_name(k, r)))
        .collect();
    let name = crate::checkpoint::pvti_name(k as usize);
    crate::output::vtk::write_pvti(&dir.join(&name), scene, snap, &pieces)?;
    Ok(Some(name))
}

// ---------------------------------------------------------------------------------------
// Followers

/// A follower's end on rank 0's stop command with exit code `code`: its result, silent
/// (rank 0 reported the error).
pub(crate) fn stopped(code: i32) -> Result<()> {
    PHASE.store(DONE, Ordering::Relaxed);
    if code == 0 {
        return Ok(());
    }
    SILENT.store(true, Ordering::Relaxed);
    Err(decode(&[code.clamp(1, 255) as u8]))
}

/// Marks rank 0 inside (or out of) a command's message exchange: an error there cannot
/// be answered with a stop command ([`finish`]).
pub(crate) fn busy(on: bool) {
    BUSY.store(on, Ordering::Relaxed);
}

/// A follower's part of `sieve run` after its global solver is prepared as rank 0's
/// (`crate::mpi_jobs::follow`): builds its subdomain, agrees, then serves rank 0's commands
/// until stop, whose exit code it returns as a silent error (`p`: the frozen flow's
/// pressure, written into the pieces).
pub fn serve<R: Real, const D: usize, const N: usize>(
    global: &mut Segregation<R, D, N>,
    geo: Option<&CutCells<R, D, N>>,
    scene: &Scene,
    p: Option<Vec<f64>>,
) -> Result<()> {
    let (rank, ranks) = world().ok_or_else(|| Error::failure("not an MPI run"))?;
    let volume = geo.map(crate::embedded::volumes);
    let local = Local::new(global, geo, rank, ranks);
    agree(local.as_ref().err())?;
    let mut local = local?;
    let world = comm();
    let root = world.process_at_rank(0);
    loop {
        match receive() {
            Command::Stop(code) => return stopped(code),
            Command::Load => local.receive_load(),
            Command::Advance { target, n } => {
                let c = local.chunk(R::from_f64(target), n);
                local.send_chunk(&c);
            }
            Command::CoupledStep { .. } | Command::Gather => {
                return Err(Error::failure("a coupled command in a segregation run"))
            }
            Command::Output { k, dir } => {
                let sub = local.sub;
                decomp::gather_rows(&local.s, &sub, global, local.fields);
                global.set_clock(local.s.time(), local.s.steps());
                let mut snap = Snapshot::of(global, scene);
                snap.p = p.clone();
                snap.volume = volume.clone();
                let status = match write_piece(Path::new(&dir), k, scene, &snap, rank, ranks) {
                    Ok(_) => Vec::new(),
                    Err(e) => encode(&e),
                };
                root.send_with_tag(&status[..], TAG_STATUS);
            }
        }
    }
}
