//! `sieve run --threads N`: the segregation step of box scenes on subdomains, one thread per
//! subdomain, with the same bits as one thread (docs/parallel.md).
//!
//! The global solver stays the state of record: the time loop ([`crate::run`]) calls
//! [`Driver::advance`] in place of `Segregation::advance_to`. Each call copies the tracked
//! fractions of every subdomain's rows from the global solver (it may have been restored or
//! replayed since), steps all subdomains on scoped threads with a halo exchange and one
//! barrier after every step, and copies the owned rows back. Everything between calls
//! (diagnostics, outputs, checkpoints, signals, the replay that resolves the segregation
//! time) sees the global solver exactly as a serial run leaves it.
//!
//! The flushed-mass counter (docs/model.md 5.6) is a running sum in cell order: each worker
//! hands over the values it flushed with their step number, and they are added here in
//! (step, cell) order, the serial order.

use crate::error::{Error, Result};
use crate::scene::Scene;
use sieve_core::decomp::{self, Side, Subdomain};
use sieve_core::geometry::CutCells;
use sieve_core::segregation::{lands_on_target, snap_slack};
use sieve_core::sum::FixedSum;
use sieve_core::{Real, Segregation};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Barrier, Mutex};

/// `--threads` of this process (0: not given). A process-wide setting of the command line,
/// like the signal handlers, rather than a field of `RunOptions`, so that the library's
/// callers that build `RunOptions` need not change.
static REQUESTED: AtomicUsize = AtomicUsize::new(0);

/// Sets `--threads` for the runs of this process (`None`: the default of [`plan`]).
pub fn request_threads(n: Option<usize>) {
    REQUESTED.store(n.unwrap_or(0), Ordering::Relaxed);
}

/// `--threads` as set by [`request_threads`].
pub fn requested_threads() -> Option<usize> {
    match REQUESTED.load(Ordering::Relaxed) {
        0 => None,
        n => Some(n),
    }
}

/// Grids with fewer cells run on one thread unless `--threads` asks otherwise: a barrier per
/// step costs a few microseconds, a step of 65,536 cells about 0.4 ms.
pub const AUTO_MIN_CELLS: usize = 1 << 16;

/// The state array a step exchanges: a face flux reads `q` of both cells; the coefficients
/// are static between prepares and a cell's carried rounding error enters no flux.
const EXCHANGED: &[&str] = &["q"];

/// How many threads a run uses: `requested` (`--threads`; `None` = all cores for grids of
/// at least [`AUTO_MIN_CELLS`] cells), or 1 with the reason when the scene cannot be split.
pub fn plan(scene: &Scene, requested: Option<usize>) -> (usize, Option<String>) {
    let wanted = match requested {
        Some(n) => n,
        None if scene.len() < AUTO_MIN_CELLS => 1,
        None => std::thread::available_parallelism().map_or(1, |n| n.get()),
    };
    if wanted <= 1 || is_coupled(scene) {
        // a coupled scene's segregation rides on the flow: [`coupled_threads`]
        return (1, None);
    }
    let wraps = scene
        .boundaries
        .last()
        .is_some_and(|b| b[0] == sieve_core::Boundary::Periodic);
    if scene.geometry.is_none() || !wraps {
        return (wanted, None);
    }
    // a merge group across the wrap would list its members in another order on a subdomain
    let note = requested.map(|n| {
        format!(
            "note: --threads {n}: cut-cell (geometry) scenes periodic along their last axis run on one thread (docs/parallel.md)"
        )
    });
    (1, note)
}

/// Whether the scene runs the coupled flow.
pub(crate) fn is_coupled(scene: &Scene) -> bool {
    scene
        .flow
        .as_ref()
        .is_some_and(|f| f.equations == crate::scene::Equations::Coupled)
}

/// How many threads a coupled run's linear solves take ([`flow_pool`]), with a note when
/// `--threads` asked for more than it gets. Only when asked (`--threads`; the default is one
/// thread), and only on grids of at least [`AUTO_MIN_CELLS`] cells: on these 2-core machines
/// the velocity components solved side by side gain 1.2-1.4x above it (column collapse on
/// 640 x 128, the tumbler on 256 x 256 and 512 x 512) and nothing measurable below it
/// (320 x 64 and 160 x 32: 0.97-1.07x); docs/parallel.md "Velocity components side by
/// side".
pub fn coupled_threads(scene: &Scene) -> (usize, Option<String>) {
    let Some(n) = requested_threads().filter(|&n| n > 1) else {
        return (1, None);
    };
    if scene.len() >= AUTO_MIN_CELLS {
        return (n, None);
    }
    let note = format!(
        "note: --threads {n}: a coupled grid of {} cells runs its solves on one thread \
         (below {AUTO_MIN_CELLS} cells a second thread gains nothing; docs/parallel.md)",
        scene.len()
    );
    (1, Some(note))
}

/// Cells per part below which a coupled run's solve runs its own loops (products, sums,
/// updates) on one thread. Measured on these 2-core machines with the velocity components
/// side by side: cutting the other solves' loops at the pool's default 2,048 cells a part cost
/// 6 % on 640 x 128 (27.4 s against 25.9 s) and 10-20 % on the 256 x 256 tumbler, and
/// broke even on 512 x 512 (docs/parallel.md). The bits do not depend on it.
pub const SOLVE_MIN_PER_PART: usize = 1 << 17;

/// The pool whose workers run a coupled run's linear solves ([`sieve_core::fork`]; the same
/// bits for any number), if [`coupled_threads`] gives it more than one thread. (Under
/// mpirun each rank steps its slab on one thread: `crate::rank_coupled`.)
pub fn flow_pool(scene: &Scene) -> Option<crate::pool::Pool> {
    if !is_coupled(scene) {
        return None;
    }
    match coupled_threads(scene) {
        (n, _) if n > 1 => crate::pool::Pool::new(n).map(|p| p.cutting_down_to(SOLVE_MIN_PER_PART)),
        _ => None,
    }
}

/// What one worker (a thread here, a rank in `parallel_mpi`) hands back after a chunk of
/// steps.
pub(crate) struct Chunk<R> {
    pub(crate) taken: u64,
    pub(crate) time: R,
    pub(crate) steps: u64,
    /// The bound maxima over the owned cells ([`Segregation::end_owned_step`]).
    pub(crate) excess: [R; 2],
    /// (step number before the step, value) of every non-zero flushed fraction, in order.
    pub(crate) flushed: Vec<(u64, R)>,
    /// The chunk's books of the open sides, per axis (low, high) ([`Segregation::side_books`]):
    /// merged exactly, so in any order.
    pub(crate) books: Vec<[FixedSum; 2]>,
}

impl<R> Chunk<R> {
    /// The books as the solver keeps them.
    pub(crate) fn side_books<const D: usize>(&self) -> [[FixedSum; 2]; D] {
        core::array::from_fn(|a| self.books[a])
    }
}

/// The halo rows of a subdomain of `s`: the box step's, [`decomp::GROUP_REACH`] wider on
/// cut cells (docs/parallel.md "Cut cells on subdomains"); threads and ranks alike.
pub(crate) fn halo_of<R: Real, const D: usize, const N: usize>(
    s: &Segregation<R, D, N>,
    geo: Option<&CutCells<R, D, N>>,
) -> usize {
    match geo {
        Some(_) => decomp::halo_width_cut(s),
        None => decomp::halo_width(s),
    }
}

/// Subdomains of a prepared solver, stepped on threads: a box grid, or cut cells (each
/// subdomain then steps on its slab of the global [`CutCells`], with halos
/// [`decomp::GROUP_REACH`] rows wider).
pub struct Driver<R: Real, const D: usize, const N: usize> {
    subs: Vec<Subdomain>,
    locals: Mutex<Vec<Box<Segregation<R, D, N>>>>,
    /// The subdomains' cut cells (empty on a box grid).
    geos: Vec<Box<CutCells<R, D, N>>>,
    /// The global solver's stable step (fixed by its prepared state).
    dt: R,
    /// The flush floor of the global configuration (the subdomains step with it off).
    floor: R,
    /// The state arrays copied in and out per chunk.
    fields: &'static [&'static str],
    /// Halo messages, `[subdomain][side][parity of the step]`.
    mail: Vec<[[Mutex<Vec<R>>; 2]; 2]>,
}

impl<R: Real, const D: usize, const N: usize> Driver<R, D, N> {
    /// Splits the prepared `global` into `parts` subdomains along the last axis (fewer if
    /// the rows do not allow as many: [`decomp::max_parts`]). Must run on a thread with room
    /// for one solver on its stack (each subdomain is built there, then boxed).
    pub fn new(
        global: &Segregation<R, D, N>,
        geo: Option<&CutCells<R, D, N>>,
        parts: usize,
    ) -> Result<Self> {
        let halo = halo_of(global, geo);
        let rows = global.grid().cells()[D - 1];
        let parts = parts.min(decomp::max_parts(rows, halo)).max(1);
        let mut subs = Vec::with_capacity(parts);
        let mut locals = Vec::with_capacity(parts);
        let mut geos = Vec::new();
        for k in 0..parts {
            let sub = Subdomain::new(global.grid(), global.boundaries(), parts, k, halo)
                .map_err(|e| Error::failure(format!("cannot split the grid: {e:?}")))?;
            let mut local = Box::new(Segregation::<R, D, N>::zeroed());
            decomp::load_subdomain(global, &sub, &mut local)
                .map_err(|e| Error::failure(format!("subdomain {k}: {e:?}")))?;
            if let Some(g) = geo {
                let mut cut = Box::new(CutCells::<R, D, N>::zeroed());
                decomp::load_cut_cells(g, &sub, &mut cut)
                    .map_err(|e| Error::failure(format!("subdomain {k}: cut cells: {e:?}")))?;
                geos.push(cut);
            }
            subs.push(sub);
            locals.push(local);
        }
        // The global step is the minimum over the subdomains (exact: model.md 5 and
        // core/src/decomp.rs); a difference is a bug, not bad input.
        let stable = |s: &Segregation<R, D, N>, g: Option<&CutCells<R, D, N>>| match g {
            Some(g) => s.stable_dt_embedded(g),
            None => s.stable_dt(),
        };
        let dt = locals
            .iter()
            .enumerate()
            .map(|(k, l)| stable(l, geos.get(k).map(|g| g.as_ref())))
            .fold(R::MAX, |a, b| a.min(b));
        let global_dt = stable(global, geo);
        if dt.to_bits_u64() != global_dt.to_bits_u64() {
            return Err(Error::failure(format!(
                "subdomain time step {:e} differs from the global {:e}",
                dt.to_f64(),
                global_dt.to_f64()
            )));
        }
        let mail = subs
            .iter()
            .map(|s| {
                let m = |side| Mutex::new(vec![R::ZERO; s.message_len(side, EXCHANGED.len())]);
                [[m(Side::Low), m(Side::Low)], [m(Side::High), m(Side::High)]]
            })
            .collect();
        let cfg = global.config();
        Ok(Self {
            subs,
            locals: Mutex::new(locals),
            geos,
            dt: global_dt,
            floor: cfg.flush_below,
            fields: if cfg.compensated {
                &["q", "carry"]
            } else {
                &["q"]
            },
            mail,
        })
    }

    /// Number of subdomains (threads).
    pub fn parts(&self) -> usize {
        self.subs.len()
    }

    /// `global.advance_to(target, max_steps)` on the subdomains: the same steps, the same
    /// bits in the global solver afterwards; returns the number of steps taken.
    pub fn advance(&self, global: &mut Segregation<R, D, N>, target: R, max_steps: u64) -> u64 {
        if !target.is_finite() || max_steps == 0 || global.time() >= target {
            return 0;
        }
        // the prepared state's step (checked against the subdomains' minimum in `new`)
        let dt = self.dt;
        let slack = snap_slack(target);
        let mut locals = self.locals.lock().expect("subdomains");
        let barrier = Barrier::new(self.subs.len());
        let g: &Segregation<R, D, N> = global;
        let chunks: Vec<Chunk<R>> = std::thread::scope(|scope| {
            let mut work = locals.iter_mut().zip(&self.subs);
            let (l0, s0) = work.next().expect("at least one subdomain");
            let barrier = &barrier;
            let handles: Vec<_> = work
                .map(|(l, sub)| {
                    scope.spawn(move || self.work(g, sub, l, target, dt, slack, max_steps, barrier))
                })
                .collect();
            let first = self.work(g, s0, l0, target, dt, slack, max_steps, barrier);
            std::iter::once(first)
                .chain(
                    handles
                        .into_iter()
                        .map(|h| h.join().expect("a subdomain thread panicked")),
                )
                .collect()
        });
        for (l, sub) in locals.iter().zip(&self.subs) {
            decomp::gather_rows(l.as_ref(), sub, global, self.fields);
        }
        let c0 = &chunks[0];
        debug_assert!(chunks
            .iter()
            .all(|c| c.taken == c0.taken && c.steps == c0.steps));
        global.set_clock(c0.time, c0.steps);
        let mut excess = global.tracked_excess();
        for c in &chunks {
            excess = [excess[0].max(c.excess[0]), excess[1].max(c.excess[1])];
        }
        global.set_tracked_excess(excess);
        global.set_flushed_tracked(fold_flushed(global.flushed_tracked(), &chunks));
        for c in &chunks {
            global.merge_side_books(&c.side_books());
        }
        c0.taken
    }

    /// One subdomain's chunk: copy in, step, flush the owned cells, exchange halos.
    #[allow(clippy::too_many_arguments)]
    fn work(
        &self,
        g: &Segregation<R, D, N>,
        sub: &Subdomain,
        l: &mut Segregation<R, D, N>,
        target: R,
        dt: R,
        slack: R,
        max_steps: u64,
        barrier: &Barrier,
    ) -> Chunk<R> {
        decomp::copy_rows(g, sub, l, self.fields);
        l.set_clock(g.time(), g.steps());
        l.set_tracked_excess(g.tracked_excess());
        // the books of this chunk's steps alone: the global solver holds the earlier ones
        l.set_side_books([[FixedSum::ZERO; 2]; D]);
        let mut excess = g.tracked_excess();
        let mut flushed = Vec::new();
        let mut taken = 0;
        let geo = self.geos.get(sub.index).map(|g| g.as_ref());
        let pace = Pace {
            target,
            dt,
            slack,
            floor: self.floor,
        };
        // The control of Segregation::advance_to, step for step.
        while l.time() < target && taken < max_steps {
            step_owned(l, geo, pace, &mut excess, &mut flushed);
            taken += 1;
            self.exchange(sub, l, (taken % 2) as usize, barrier);
        }
        Chunk {
            taken,
            time: l.time(),
            steps: l.steps(),
            excess,
            flushed,
            books: l.side_books().to_vec(),
        }
    }

    /// Sends the owned rows next to each cut, waits for every subdomain, receives the
    /// neighbours' rows into the halos. Messages alternate between two buffers by the parity
    /// of the step, so one barrier per step suffices: a buffer is written again only two
    /// steps later, after its reader has passed the next barrier.
    fn exchange(
        &self,
        sub: &Subdomain,
        l: &mut Segregation<R, D, N>,
        parity: usize,
        barrier: &Barrier,
    ) {
        for side in [Side::Low, Side::High] {
            if sub.neighbour(side).is_some() {
                let mut m = self.mail[sub.index][side as usize][parity]
                    .lock()
                    .expect("halo buffer");
                decomp::pack(l, sub, side, EXCHANGED, &mut m);
            }
        }
        barrier.wait();
        for side in [Side::Low, Side::High] {
            if let Some(nb) = sub.neighbour(side) {
                let m = self.mail[nb][side.opposite() as usize][parity]
                    .lock()
                    .expect("halo buffer");
                decomp::unpack(l, sub, side, EXCHANGED, &m);
            }
        }
    }
}

/// How a subdomain steps towards `target`: the global step `dt`, shortened to land on
/// `target` within `slack` (as `Segregation::advance_to`), and the global flush floor.
#[derive(Clone, Copy)]
pub(crate) struct Pace<R> {
    pub(crate) target: R,
    pub(crate) dt: R,
    pub(crate) slack: R,
    pub(crate) floor: R,
}

/// One step of a subdomain, on threads and ranks alike: the box or (on its slab of cut
/// cells `geo`) the embedded step, then the flush and bound maxima of its owned cells; each
/// flushed value goes to `flushed` with the step number before the step, the order in which
/// the driver adds them up.
pub(crate) fn step_owned<R: Real, const D: usize, const N: usize>(
    l: &mut Segregation<R, D, N>,
    geo: Option<&CutCells<R, D, N>>,
    pace: Pace<R>,
    excess: &mut [R; 2],
    flushed: &mut Vec<(u64, R)>,
) {
    let step = |l: &mut Segregation<R, D, N>, dt: R| match geo {
        Some(g) => crate::isa::step_embedded(l, dt, g),
        None => crate::isa::step(l, dt),
    };
    let before = l.steps();
    let remaining = pace.target - l.time();
    if lands_on_target(remaining, pace.dt, pace.slack) {
        step(l, remaining);
        l.set_clock(pace.target, l.steps());
    } else {
        step(l, pace.dt);
    }
    let keep = |_, v| {
        if v != R::ZERO {
            flushed.push((before, v));
        }
    };
    match geo {
        Some(g) => l.end_owned_step_embedded(g, pace.floor, before, excess, keep),
        None => l.end_owned_step(pace.floor, before, excess, keep),
    }
}

/// The flushed counter after a chunk: `start` plus every flushed value in (step, cell)
/// order, which is (step, subdomain, cell in the subdomain) order. Zeros are skipped: the
/// counter starts at +0 and adding a zero to it changes no bit.
fn fold_flushed<R: Real>(start: R, chunks: &[Chunk<R>]) -> R {
    let mut total = start;
    let mut at = vec![0usize; chunks.len()];
    loop {
        let next = chunks
            .iter()
            .zip(&at)
            .filter_map(|(c, &k)| c.flushed.get(k).map(|e| e.0))
            .min();
        let Some(step) = next else {
            return total;
        };
        for (c, k) in chunks.iter().zip(at.iter_mut()) {
            while let Some(&(s, v)) = c.flushed.get(*k) {
                if s != step {
                    break;
                }
                total += v;
                *k += 1;
            }
        }
    }
}

/// [`sieve_core::diagnose`] with the per-cell entropy terms (two `libm` logarithms each, most
/// of a diagnosis) evaluated on `pool`'s workers into `terms`; the sums then run in cell order
/// ([`sieve_core::diagnose_with_terms`]), so the result has `diagnose`'s bits. The run loop
/// takes it with a pool of its driver's threads, at outputs and in the step-by-step replay that
/// resolves the segregation time (a Psi after every step of an interval).
pub fn diagnose_on<R: Real, const D: usize, const N: usize>(
    s: &Segregation<R, D, N>,
    pool: Option<&crate::pool::Pool>,
    terms: &mut Vec<R>,
) -> sieve_core::Diagnostics<R> {
    let Some(pool) = pool else {
        return sieve_core::diagnose(s);
    };
    let vacuum = s.config().vacuum;
    terms.clear();
    terms.resize(s.len(), R::ZERO);
    sieve_core::fork::chunks(pool, terms, 1, |start, part| {
        for (j, t) in part.iter_mut().enumerate() {
            *t = sieve_core::entropy_term(s.phi(start + j), s.c(start + j), vacuum);
        }
    });
    sieve_core::diagnose_with_terms(s, |i| terms[i])
}

/// The driver of a run, if it uses more than one thread ([`requested_threads`], [`plan`]);
/// a note goes to stderr when a requested split is not possible.
pub fn driver_for<R: Real, const D: usize, const N: usize>(
    s: &Segregation<R, D, N>,
    geo: Option<&CutCells<R, D, N>>,
    scene: &Scene,
    quiet: bool,
) -> Result<Option<Driver<R, D, N>>> {
    let requested = requested_threads();
    let (threads, note) = plan(scene, requested);
    if let (Some(n), false) = (note, quiet) {
        eprintln!("{n}");
    }
    if threads <= 1 {
        return Ok(None);
    }
    let d = Driver::new(s, geo, threads)?;
    if d.parts() < threads && requested.is_some() && !quiet {
        eprintln!(
            "note: --threads {threads}: {} rows allow {} subdomains",
            s.grid().cells()[D - 1],
            d.parts()
        );
    }
    Ok((d.parts() > 1).then_some(d))
}
