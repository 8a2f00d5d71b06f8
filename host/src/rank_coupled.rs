//! A coupled scene under mpirun (the `mpi` feature; docs/parallel.md, "A coupled scene under
//! mpirun"): every rank steps one slab of rows of the coupled run
//! (`sieve_core::flow::coupled_slab`, its neighbours through [`RankLinks`]) with the serial
//! bits, and rank 0 runs the one coupled run loop ([`crate::flow::coupled_loop_with`]) with
//! [`RankSteps`] as its stepper.
//!
//! Every rank builds the same whole run first (the scene, a resumed checkpoint), then its
//! slab; they agree on the set-up ([`agree`]) before any collective step. Rank 0 then
//! commands, the others serve ([`serve`]):
//!
//! - *coupled step* toward a target: every rank takes the same decision whether the step
//!   may be taken ([`plan_step`]: the stable step is the smallest of the slabs', the same on
//!   every rank), steps its slab, and the ranks take the largest of their "not finite" flags;
//!   while the segregation timer runs, every rank samples its owned cells
//!   ([`crate::step_psi`]: Psi's sums continued from slab to slab, seven values a message);
//! - *gather* (before outputs, checkpoints and the end, and when a step failed or a value
//!   is not finite): the owned rows of every state array and the slab's record
//!   ([`sieve_core::flow::coupled_slab::SlabRecord`]) go to rank 0, which makes its whole run the record of the slabs
//!   ([`store_slab_records`]) and writes every serial file from it, as the serial run does;
//! - *output* `k`: every rank writes the `.vti` piece of its slab's rows, rank 0 the
//!   `.pvti` (`crate::parallel_mpi::write_snapshot`);
//! - *stop* with rank 0's exit code.
//!
//! A rank whose slab's step fails names the cell in the whole grid's numbering (as the serial
//! run does); rank 0 scans its gathered whole run first, so a non-finite value is named as
//! the serial run names it too.

use crate::coupled_steps::{
    plan_step, record_from_words, record_words, slab_starts, too_many_ranks, CoupledSteps,
};
use crate::data::Snapshot;
use crate::error::{Error, Result};
use crate::interrupt::Reason;
use crate::parallel_mpi::{
    agree, broadcast, busy, comm, narrow, receive, stopped, widen, write_piece, Command,
};
use crate::rank_links::RankLinks;
use crate::scene::Scene;
use crate::step_psi::{Sample, StepPsi};
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;
use sieve_core::flow::coupled::{Coupled, CouplingError};
use sieve_core::flow::coupled_slab::{load_coupled_slab, store_slab_records};
use sieve_core::flow::reach::Reach;
use sieve_core::flow::slab::{halo_rows, Slab, SlabPlan};
use sieve_core::flow::Flow;
use sieve_core::fork::Serial;
use sieve_core::geometry::CutCells;
use sieve_core::{Real, Segregation};
use std::ops::Range;
use std::path::Path;

/// Tags of the coupled run's messages (apart from the run's 40-45, the sums' 46-47, the
/// line pipelines' 48-49 and the links' 50-51).
const TAG_RECORD: i32 = 53;
const TAG_ROWS: i32 = 54;
const TAG_ERROR: i32 = 55;

/// This rank's slab before its driver is built: the solvers, the solves' memory, and the
/// slab's cut cells where the scene has a container.
struct Parts<R: Real, const D: usize, const N: usize> {
    flow: Box<Flow<R, D, N>>,
    seg: Box<Segregation<R, D, N>>,
    plan: SlabPlan<D>,
    memory: Vec<R>,
    cut: Option<Box<CutCells<R, D, N>>>,
}

/// The slabs' first rows and the fine cells each rank owns (the parts of the ordered sums).
/// Too many ranks for the halo's depth (deeper with merged cut cells, known only now that
/// the geometry is built) are bad input of the scene `file`, before any step.
fn cut<R: Real, const D: usize, const N: usize>(
    global: &Coupled<'_, R, D, N>,
    ranks: usize,
    file: &str,
) -> Result<(Vec<usize>, Vec<Range<usize>>)> {
    let rows = global.flow.grid().cells()[D - 1];
    let plane = global.flow.len() / rows;
    let depth = halo_rows(global.flow);
    let starts = slab_starts(rows, ranks, depth)
        .ok_or_else(|| too_many_ranks(file, D, rows, ranks, depth))?;
    let parts = (0..ranks)
        .map(|k| starts[k] * plane..starts.get(k + 1).map_or(rows, |&e| e) * plane)
        .collect();
    Ok((starts, parts))
}

/// Loads this rank's slab of `global`.
fn load<R: Real, const D: usize, const N: usize>(
    global: &Coupled<'_, R, D, N>,
    starts: &[usize],
    rank: usize,
) -> Result<Parts<R, D, N>> {
    let mut flow: Box<Flow<R, D, N>> = Box::new(Flow::zeroed());
    let mut seg: Box<Segregation<R, D, N>> = Box::new(Segregation::zeroed());
    let mut cut = global
        .geometry()
        .map(|_| Box::new(CutCells::<R, D, N>::zeroed()));
    let plan = load_coupled_slab(
        global,
        starts,
        rank,
        &mut flow,
        &mut seg,
        cut.as_deref_mut(),
    )
    .map_err(|e| Error::failure(format!("rank {rank}: the coupled run's slab: {e}")))?;
    let memory = vec![R::ZERO; plan.memory_len()];
    Ok(Parts {
        flow,
        seg,
        plan,
        memory,
        cut,
    })
}

/// This rank's slab of `global` (of the scene `file`) and every rank's owned cells, once
/// every rank has loaded its own ([`agree`]: the first failure in rank order is every
/// rank's).
fn join<R: Real, const D: usize, const N: usize>(
    global: &Coupled<'_, R, D, N>,
    file: &str,
) -> Result<(Parts<R, D, N>, Vec<Range<usize>>)> {
    let (rank, ranks) =
        crate::parallel_mpi::world().ok_or_else(|| Error::failure("not an MPI run"))?;
    let loaded = cut(global, ranks, file)
        .and_then(|(starts, parts)| Ok((load(global, &starts, rank)?, parts)));
    agree(loaded.as_ref().err())?;
    loaded
}

/// What one rank steps: its slab's driver and reach.
struct Stepper<'x, 'c, R: Real, const D: usize, const N: usize> {
    /// The segregation timer's samples of the owned cells, and the last step's.
    psi: StepPsi<R>,
    sampled: Option<Sample>,
    cpl: Coupled<'x, R, D, N>,
    slab: Slab<'x, R, RankLinks<'c, SimpleCommunicator>, D>,
    /// The owned cells in the slab's numbering.
    own: Range<usize>,
    /// The whole grid's number of the slab's first cell (its first halo row's).
    first: usize,
    level: crate::isa::Level,
    /// The last step's failure, in words (none when another slab failed).
    error: Option<String>,
    /// A value of some slab was not finite after the last step.
    not_finite: bool,
}

/// How one rank's step went ([`Stepper::step`]).
enum Stepped {
    Taken,
    /// Not taken: the reason the run stops (the same on every rank).
    Refused(Reason),
    /// The core refused the step on some slab (every slab stops at the same point).
    Failed,
}

impl<R: Real, const D: usize, const N: usize> Stepper<'_, '_, R, D, N> {
    /// One step toward `target`, as every rank takes it: the stable step across the
    /// slabs, the same decision, the step, the largest of the ranks' "not finite", and with
    /// `sample` (the timer's threshold) the sample of a step taken with finite values.
    fn step(&mut self, target: R, first: f64, sample: Option<f64>) -> (R, Stepped) {
        self.sampled = None;
        let Self { cpl, slab, .. } = self;
        let stable = cpl.stable_dt_reaching(slab);
        let dt = match plan_step(stable, target, cpl.seg.time(), first) {
            Ok(dt) => dt,
            Err(r) => return (stable, Stepped::Refused(r)),
        };
        self.error = None;
        let stepped =
            crate::on_level!(self.level, &Serial, |f| cpl.step_with_reaching(dt, f, slab));
        match stepped {
            Err(e) => {
                if e != CouplingError::OtherSlab {
                    self.error = Some(e.offset_cell(self.first).to_string());
                }
                (stable, Stepped::Failed)
            }
            Ok(()) => {
                let mine = crate::interrupt::scan_segregation(cpl.seg)
                    .or_else(|| crate::interrupt::scan_flow(cpl.flow))
                    .is_some();
                let flag = if mine { R::ONE } else { R::ZERO };
                self.not_finite = Reach::<R, D, N>::max(slab, flag) > R::ZERO;
                if let (Some(threshold), false) = (sample, self.not_finite) {
                    self.sampled = Some(self.psi.sample(self.cpl.seg, threshold, &mut self.slab));
                }
                (stable, Stepped::Taken)
            }
        }
    }

    /// The owned rows of every state array of the flow, then of the segregation, widened.
    fn owned_rows(&self) -> Vec<f64> {
        let mut out = Vec::new();
        let own = self.own.clone();
        self.cpl
            .flow
            .for_each_state_array(|_, a| out.extend(widen(&a[own.clone()])));
        self.cpl
            .seg
            .for_each_state_array(|_, a| out.extend(widen(&a[own.clone()])));
        out
    }
}

/// The timer's samples of this rank's owned cells `part` (the whole grid's numbering) of
/// `global`, stepped on the slab of `plan`.
fn step_psi<R: Real, const D: usize, const N: usize>(
    global: &Coupled<'_, R, D, N>,
    plan: &SlabPlan<D>,
    part: &Range<usize>,
) -> StepPsi<R> {
    let volume = global.geometry().map(|g| &g.volumes()[part.clone()]);
    StepPsi::new(global.seg, plan.owned_cells(), global.seg.len(), volume)
}

/// Writes `values` (as [`Stepper::owned_rows`] sends them) into the cells `cells` of
/// `global`'s arrays; `false` if their number does not fit.
fn put_rows<R: Real, const D: usize, const N: usize>(
    flow: &mut Flow<R, D, N>,
    seg: &mut Segregation<R, D, N>,
    cells: Range<usize>,
    values: &[f64],
) -> bool {
    let mut arrays = 0;
    flow.for_each_state_array(|_, _| arrays += 1);
    seg.for_each_state_array(|_, _| arrays += 1);
    if values.len() != arrays * cells.len() || cells.is_empty() {
        return values.is_empty();
    }
    let mut chunks = values.chunks_exact(cells.len());
    let mut put = |a: &mut [R]| {
        if let Some(c) = chunks.next() {
            narrow(c, &mut a[cells.clone()]);
        }
    };
    flow.for_each_state_array_mut(|_, a| put(a));
    seg.for_each_state_array_mut(|_, a| put(a));
    true
}

/// Rank 0's stepper of a coupled run on the ranks' slabs ([`crate::coupled_steps`]).
pub struct RankSteps<'x, 'c, R: Real, const D: usize, const N: usize> {
    me: Stepper<'x, 'c, R, D, N>,
    /// Every rank's owned cells (global numbering).
    parts: Vec<Range<usize>>,
    /// The whole run is the record of the slabs' current state.
    synced: bool,
    /// The words of the first rank whose step failed, as of the last gather.
    failure: Option<String>,
}

impl<R: Real, const D: usize, const N: usize> CoupledSteps<R, D, N> for RankSteps<'_, '_, R, D, N> {
    fn step_toward(
        &mut self,
        cpl: &mut Coupled<'_, R, D, N>,
        target: R,
        first: f64,
        sample: Option<f64>,
    ) -> (R, std::result::Result<(), Reason>) {
        busy(true);
        broadcast(&Command::CoupledStep {
            target: target.to_f64(),
            first,
            sample: sample.is_some(),
        });
        let (stable, stepped) = self.me.step(target, first, sample);
        self.synced = false;
        busy(false);
        let stepped = match stepped {
            Stepped::Taken => Ok(()),
            Stepped::Refused(r) => Err(r),
            Stepped::Failed => {
                // The whole run's state names a non-finite cell as the serial run does;
                // else the words of the first rank whose step failed.
                let gathered = self.sync(cpl).err().map(|e| Reason::Core(e.to_string()));
                Err(crate::interrupt::scan_segregation(cpl.seg)
                    .or_else(|| crate::interrupt::scan_flow(cpl.flow))
                    .or(gathered)
                    .unwrap_or_else(|| {
                        let words = self.failure.take();
                        Reason::Core(words.unwrap_or_else(|| CouplingError::OtherSlab.to_string()))
                    }))
            }
        };
        (stable, stepped)
    }

    fn time(&self, _cpl: &Coupled<'_, R, D, N>) -> R {
        self.me.cpl.seg.time()
    }

    fn scan(&mut self, cpl: &mut Coupled<'_, R, D, N>) -> Result<Option<Reason>> {
        if !self.me.not_finite {
            return Ok(None);
        }
        // A gather whose rows hold a non-finite value may fail to prepare the whole run
        // (its rows and counters are stored first): the scan names the value, as serially.
        let gathered = self.sync(cpl).err().map(|e| Reason::Core(e.to_string()));
        Ok(crate::interrupt::scan_segregation(cpl.seg)
            .or_else(|| crate::interrupt::scan_flow(cpl.flow))
            .or(gathered))
    }

    fn sampled(&self) -> Option<Sample> {
        self.me.sampled
    }

    fn sync(&mut self, cpl: &mut Coupled<'_, R, D, N>) -> Result<()> {
        if self.synced {
            return Ok(());
        }
        busy(true);
        broadcast(&Command::Gather);
        let world = comm();
        let mut records = Vec::with_capacity(self.parts.len());
        let mut failure = self.me.error.clone();
        let mut bad = None;
        for (r, part) in self.parts.iter().enumerate() {
            let (record, rows) = if r == 0 {
                (self.me.cpl.slab_record(), self.me.owned_rows())
            } else {
                let p = world.process_at_rank(r as i32);
                let (words, _) = p.receive_vec_with_tag::<u64>(TAG_RECORD);
                let (rows, _) = p.receive_vec_with_tag::<f64>(TAG_ROWS);
                let (error, _) = p.receive_vec_with_tag::<u8>(TAG_ERROR);
                if failure.is_none() && !error.is_empty() {
                    failure = Some(format!("rank {r}: {}", String::from_utf8_lossy(&error)));
                }
                match record_from_words::<R, D>(&words) {
                    Some(rec) => (rec, rows),
                    None => {
                        bad.get_or_insert(format!(
                            "rank {r} sent a record of {} words",
                            words.len()
                        ));
                        continue;
                    }
                }
            };
            if !put_rows(cpl.flow, cpl.seg, part.clone(), &rows) {
                bad.get_or_insert(format!(
                    "rank {r} sent {} values for {} cells",
                    rows.len(),
                    part.len()
                ));
            }
            records.push(record);
        }
        busy(false);
        self.failure = failure;
        if let Some(b) = bad {
            return Err(Error::failure(format!("the coupled run's gather: {b}")));
        }
        // the rows, clocks and counters are stored even when the prepare fails
        self.synced = true;
        store_slab_records(cpl, &records)
            .map_err(|e| Error::failure(format!("the coupled run's gather: {e}")))
    }
}

/// Rank 0 of an MPI run of a coupled scene: builds its slab of the whole run `global`,
/// agrees with the other ranks, and runs `run` (the coupled run loop) with
/// [`RankSteps`]; `global` is then the record of the slabs (after each sync).
pub fn lead<R: Real, const D: usize, const N: usize, T>(
    global: &mut Coupled<'_, R, D, N>,
    scene: &Scene,
    run: impl FnOnce(&mut Coupled<'_, R, D, N>, &mut RankSteps<'_, '_, R, D, N>) -> Result<T>,
) -> Result<T> {
    let (mut mine, parts) = join(global, &scene.label)?;
    let world = comm();
    let mut links = RankLinks::new(&world, parts.clone());
    let Parts {
        flow,
        seg,
        plan,
        memory,
        cut,
    } = &mut mine;
    let mut slab = Slab::new(plan, &mut links, memory);
    // collective: a failure is every slab's (the others say another slab stopped)
    let cpl = Coupled::on_slab(flow, seg, global.slab_start(), cut.as_deref(), &mut slab)
        .map_err(|e| Error::failure(format!("the coupled run's slabs: {e}")))?;
    let me = Stepper {
        psi: step_psi(global, plan, &parts[0]),
        sampled: None,
        cpl,
        slab,
        own: plan.owned_cells(),
        first: plan.global_cells().start - plan.owned_cells().start,
        level: crate::isa::level(),
        error: None,
        not_finite: false,
    };
    let mut steps = RankSteps {
        me,
        parts,
        synced: true,
        failure: None,
    };
    run(global, &mut steps)
}

/// A follower of an MPI run of a coupled scene: builds its slab of the whole run `global`
/// (built as rank 0 builds it), agrees, and serves rank 0's commands until stop, whose exit
/// code it returns as a silent error.
pub fn serve<R: Real, const D: usize, const N: usize>(
    global: &mut Coupled<'_, R, D, N>,
    scene: &Scene,
) -> Result<()> {
    let (rank, ranks) =
        crate::parallel_mpi::world().ok_or_else(|| Error::failure("not an MPI run"))?;
    let (mut mine, parts) = join(global, &scene.label)?;
    let world = comm();
    let root = world.process_at_rank(0);
    let mut links = RankLinks::new(&world, parts.clone());
    let Parts {
        flow,
        seg,
        plan,
        memory,
        cut,
    } = &mut mine;
    let (own, cells) = (plan.owned_cells(), plan.global_cells());
    let first = cells.start - own.start;
    let mut slab = Slab::new(plan, &mut links, memory);
    let start = global.slab_start();
    let Ok(cpl) = Coupled::on_slab(flow, seg, start, cut.as_deref(), &mut slab) else {
        // every slab failed alike: rank 0 reports and stops the run
        loop {
            if let Command::Stop(code) = receive() {
                return stopped(code);
            }
        }
    };
    let mut me = Stepper {
        psi: step_psi(global, plan, &parts[rank]),
        sampled: None,
        cpl,
        slab,
        own,
        first,
        level: crate::isa::level(),
        error: None,
        not_finite: false,
    };
    loop {
        match receive() {
            Command::Stop(code) => return stopped(code),
            Command::CoupledStep {
                target,
                first,
                sample,
            } => {
                // the run's threshold, as rank 0's run loop passes it
                me.step(
                    R::from_f64(target),
                    first,
                    sample.then_some(scene.psi_threshold),
                );
            }
            Command::Gather => {
                let words = record_words(&me.cpl.slab_record());
                root.send_with_tag(&words[..], TAG_RECORD);
                root.send_with_tag(&me.owned_rows()[..], TAG_ROWS);
                let error = me.error.clone().unwrap_or_default();
                root.send_with_tag(error.as_bytes(), TAG_ERROR);
            }
            Command::Output { k, dir } => {
                // this slab's rows of the whole run, then its piece of the snapshot
                let rows_now = me.owned_rows();
                let status = if put_rows(global.flow, global.seg, cells.clone(), &rows_now) {
                    global.seg.set_clock(me.cpl.seg.time(), me.cpl.seg.steps());
                    let mut snap = Snapshot::of(global.seg, scene);
                    snap.p = Some(
                        (0..global.flow.len())
                            .map(|i| global.flow.pressure(i).to_f64())
                            .collect(),
                    );
                    snap.volume = global.geometry().map(crate::embedded::volumes);
                    match write_piece(Path::new(&dir), k, scene, &snap, rank, ranks) {
                        Ok(_) => Vec::new(),
                        Err(e) => crate::parallel_mpi::encode(&e),
                    }
                } else {
                    crate::parallel_mpi::encode(&Error::failure(
                        "the slab's rows do not fit the whole grid",
                    ))
                };
                root.send_with_tag(&status[..], crate::parallel_mpi::TAG_STATUS);
            }
            Command::Advance { .. } | Command::Load => {
                return Err(Error::failure("a segregation command in a coupled run"));
            }
        }
    }
}
