//! A coupled run (flow and segregation, [`super::coupled`]) on a slab of whole rows of a grid
//! cut along its last axis, with the serial bits (docs/parallel.md, "The coupled step on
//! slabs"): what a rank of an MPI run steps.
//!
//! The slab's flow is a flow slab ([`super::slab`], [`super::slab::HALO`] halo rows); its segregation
//! solver lives on the same rows with a wall at the outer face of each halo and the flush
//! off (its halo rows must not flush: the driver flushes the owned cells,
//! [`Coupled::on_slab`]). The step is [`Coupled::step_with_reaching`] with a
//! [`super::slab::Slab`] as its reach.
//!
//! What the whole run's diagnostics take from the slabs: the owned rows of every array, the
//! bound maxima as the largest of the slabs' (exact, but for the sign of a zero), the flush counter and the guard's total
//! from any slab (each holds the running value of all), the discharge through the floor
//! from the first slab and through the lid from the last (the cuts are walls: nothing else
//! crosses a slab's own sides), through the sides along the cut from any slab (their sums
//! run across the slabs, each holds the whole side's), and the books of the segregation's open sides merged
//! exactly ([`Segregation::merge_side_books`]).

use super::coupled::{Coupled, CoupledTotals, CouplingError, Mode};
use super::slab::{load_slab, SlabError, SlabPlan};
use super::{Flow, FlowCounters};
use crate::boundary::Boundary;
use crate::geometry::CutCells;
use crate::real::Real;
use crate::segregation::Segregation;
use crate::sum::FixedSum;

/// Sets `flow` and `seg` up as slab `index` of the coupled run `global` cut into slabs that
/// begin at the rows `starts` ([`load_slab`]): the flow slab, and the segregation solver on
/// the same rows with every state array, its clock, bound maxima and flush counter copied (the
/// books of its open sides go to the first slab); where the whole run has cut cells, their
/// rows and halo rows into `geo` ([`CutCells::load_slab`]). Build the slab's driver with
/// [`Coupled::on_slab`] (with `global.slab_start()` and `geo`).
pub fn load_coupled_slab<R: Real, const D: usize, const M: usize, const N: usize>(
    global: &Coupled<'_, R, D, M>,
    starts: &[usize],
    index: usize,
    flow: &mut Flow<R, D, N>,
    seg: &mut Segregation<R, D, N>,
    geo: Option<&mut CutCells<R, D, N>>,
) -> Result<SlabPlan<D>, SlabError> {
    if global.config().mode != Mode::Coupled {
        return Err(SlabError::NotYet("the prescribed and frozen modes"));
    }
    let whole = &*global.seg;
    let plan = load_slab(global.flow, starts, index, flow)?;
    if let Some(cut) = global.geometry() {
        let local = geo.ok_or(SlabError::GeometryMissing)?;
        let first = plan.rows.start - plan.halo[0];
        local
            .load_slab(cut, first, flow.grid().cells()[D - 1])
            .map_err(SlabError::Geometry)?;
    }
    let mut bc = *whole.boundaries();
    for (side, &h) in plan.halo.iter().enumerate() {
        if h > 0 {
            bc[D - 1][side] = Boundary::Wall;
        }
    }
    let mut cfg = *whole.config();
    cfg.flush_below = R::ZERO;
    seg.setup(*flow.grid(), bc, cfg)
        .map_err(SlabError::Segregation)?;
    seg.set_transport(whole.transport());
    let first = (plan.rows.start - plan.halo[0]) * plan.plane;
    let span = first..first + flow.len();
    whole.for_each_state_array(|name, from| {
        seg.for_each_state_array_mut(|to_name, to| {
            if to_name == name {
                to.copy_from_slice(&from[span.clone()]);
            }
        });
    });
    seg.set_clock(whole.time(), whole.steps());
    seg.set_tracked_excess(whole.tracked_excess());
    seg.set_flushed_tracked(whole.flushed_tracked());
    if index == 0 {
        seg.set_side_books(whole.side_books());
    }
    Ok(plan)
}

/// What a slab's driver holds besides the owned rows of its state arrays: the clocks, the
/// counters and the running totals ([`Coupled::slab_record`]). With every slab's record
/// and owned rows, the whole run's record is whole again ([`store_slab_records`]): what an
/// MPI run's rank 0 writes its outputs and checkpoints from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SlabRecord<R, const D: usize> {
    /// The flow's clock and counters (the discharge through the floor is the first slab's,
    /// through the lid the last one's, through the sides along the cut every slab's).
    pub flow: FlowCounters<R, D>,
    /// The segregation's clock.
    pub time: R,
    /// The segregation's steps.
    pub steps: u64,
    /// The bound maxima over the owned cells.
    pub excess: [R; 2],
    /// The flush counter (every slab holds the whole run's).
    pub flushed: R,
    /// The segregation's books of its open sides (the first slab's began with the whole
    /// run's, the others' at zero: they add up exactly).
    pub books: [[FixedSum; 2]; D],
    /// The driver's totals (the discharge through the floor is the first slab's, through
    /// the lid the last slab's; through the sides along the cut and the guard's total
    /// every slab's).
    pub totals: CoupledTotals<R, D>,
}

impl<R: Real, const D: usize, const N: usize> Coupled<'_, R, D, N> {
    /// This slab's record ([`SlabRecord`]).
    pub fn slab_record(&self) -> SlabRecord<R, D> {
        SlabRecord {
            flow: self.flow.counters(),
            time: self.seg.time(),
            steps: self.seg.steps(),
            excess: self.seg.tracked_excess(),
            flushed: self.seg.flushed_tracked(),
            books: self.seg.side_books(),
            totals: self.totals(),
        }
    }
}

/// Makes `global` (the whole run, [`Coupled::new`]) the record of its slabs, whose owned
/// rows of every state array the caller has already copied into `global`'s solvers:
/// `records` are the slabs' ([`Coupled::slab_record`]) from the floor up. Sets the clocks,
/// the counters, the bound maxima (the largest, by value), the flush counter, the merged
/// books and the totals, then prepares the segregation as a resumed run does
/// ([`Coupled::resume`]): the coefficients are functions of the state, so `global` then
/// holds the serial run's bits and steps on with them. An error is the prepare's (a state
/// the segregation refuses); everything else is stored by then.
pub fn store_slab_records<R: Real, const D: usize, const N: usize>(
    global: &mut Coupled<'_, R, D, N>,
    records: &[SlabRecord<R, D>],
) -> Result<(), CouplingError> {
    let (Some(first), Some(last)) = (records.first(), records.last()) else {
        return Ok(());
    };
    // Nothing crosses a cut (a wall on each slab): the floor's books are the first slab's,
    // the lid's the last one's; a side along the cut is summed across the slabs, so its
    // books are the same on every slab.
    let mut flow = first.flow;
    flow.discharged[D - 1][1] = last.flow.discharged[D - 1][1];
    flow.discharge_step[D - 1][1] = last.flow.discharge_step[D - 1][1];
    let mut totals = first.totals;
    totals.out_small[D - 1][1] = last.totals.out_small[D - 1][1];
    totals.out_total[D - 1][1] = last.totals.out_total[D - 1][1];
    let excess = records.iter().fold(first.excess, |m, r| {
        [m[0].max(r.excess[0]), m[1].max(r.excess[1])]
    });
    global.flow.restore_counters(flow);
    global.seg.set_clock(first.time, first.steps);
    global.seg.set_tracked_excess(excess);
    global.seg.set_flushed_tracked(first.flushed);
    global.seg.set_side_books([[FixedSum::ZERO; 2]; D]);
    for r in records {
        global.seg.merge_side_books(&r.books);
    }
    global.resume(totals)
}
