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
//! crosses a slab's own sides), and the books of the segregation's open sides merged
//! exactly ([`Segregation::merge_side_books`]).

use super::coupled::{Coupled, Mode};
use super::slab::{load_slab, SlabError, SlabPlan};
use super::Flow;
use crate::boundary::Boundary;
use crate::real::Real;
use crate::segregation::Segregation;

/// Sets `flow` and `seg` up as slab `index` of the coupled run `global` cut into slabs that
/// begin at the rows `starts` ([`load_slab`]): the flow slab, and the segregation solver on
/// the same rows with every state array, its clock, bound maxima and flush counter copied (the
/// books of its open sides go to the first slab). Build the slab's driver with
/// [`Coupled::on_slab`] (with `global.slab_start()`).
pub fn load_coupled_slab<R: Real, const D: usize, const M: usize, const N: usize>(
    global: &Coupled<'_, R, D, M>,
    starts: &[usize],
    index: usize,
    flow: &mut Flow<R, D, N>,
    seg: &mut Segregation<R, D, N>,
) -> Result<SlabPlan<D>, SlabError> {
    if global.config().mode != Mode::Coupled {
        return Err(SlabError::NotYet("the prescribed and frozen modes"));
    }
    let whole = &*global.seg;
    let plan = load_slab(global.flow, starts, index, flow)?;
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
