//! The flow on a slab of whole rows of a grid cut along its last axis, with the serial bits
//! (docs/parallel.md, "The flow on slabs"): what a rank of an MPI run steps.
//!
//! A slab is its own [`Flow`] on its rows plus [`halo_rows`] halo rows on each cut side,
//! with a slip wall at the outer face of a halo (its effects stay in the halo, see [`HALO`]). It
//! steps with [`Flow::step_reaching`] and a [`Slab`] as its [`Reach`]:
//! - at the start of a step every state array's halo rows are refreshed from their owners;
//! - sums run in cell order, the running total handed from slab to slab
//!   ([`InOrder::sum_in_order`]), and maxima are exact;
//! - the implicit solves are [`cg_slab::solve`] on the slab's rows, with the serial
//!   iterations and bits, the solution's halo rows refreshed after each.
//!
//! Embedded walls run on slabs: each slab holds the rows of the whole flow's cut-cell
//! geometry (`Walls::load_rows`) and a deeper halo where merge groups span rows
//! ([`halo_rows`]). So do sides along the cut that move mass (inflow, outflow, openings):
//! their discharge is a sum over the owned boundary cells continued from slab to slab
//! (`Flow::discharge_along`), their openings placed on the whole grid (`Flow::open_fraction`).

use super::cg::{Scratch, Solve, Stencil, Stop};
use super::cg_slab;
use super::cycle_slab::{Fine, Links, Plan, PlanError};
use super::reach::Reach;
use super::{Flow, FlowError, FlowSide, Slip};
use crate::fork::Fork;
use crate::geometry::GeometryError;
use crate::real::Real;
use crate::segregation::SetupError;
use crate::sum::InOrder;
use core::ops::Range;

/// Halo rows of a flow slab. Within one step the values of a halo row go wrong from the
/// outside in, since the outermost row sees a wall where the global grid has more cells; a
/// step must end with the owned rows right. The transport reaches furthest: the compact
/// force of the outermost row (4) reads the wall, so the raw flux of face (3, 4) is wrong, so
/// the limiter factor of row 3, so the limited flux of face (2, 3) and the new content of row
/// 2; row 1 is right. Every later explicit stage reads one row across the cut and only
/// pointwise values there (the pressure, the coefficients, `u = m / c`), and the solves
/// refresh what they solve for. So 4 rows, refreshed once per step.
pub const HALO: usize = 4;

/// The halo's depth of the slabs of `flow`: [`HALO`] rows, and 3 more per row a merge group
/// of an embedded wall spans beyond its first (`Walls::rows_spanned`: 0, 1 or 2). Why deeper:
/// a group is one cell for the explicit stages (module `walls`), so each of the
/// transport's group sums (the compact forces, the limiters, the update) hands a value that
/// went wrong in one row of a group to its other rows, up to the group's span further in.
/// Measured on a drum of 32 x 32 cells (groups spanning 1 row, random states, every even
/// cut; tests/tests/flow_slabs.rs): 4 rows failed, 5 held the serial bits; 7 it is.
pub fn halo_rows<R: Real, const D: usize, const N: usize>(flow: &Flow<R, D, N>) -> usize {
    if flow.walls.on {
        HALO + 3 * flow.walls.rows_spanned
    } else {
        HALO
    }
}

/// Why a flow cannot run on the slabs asked for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SlabError {
    /// The cut does not suit the implicit solves ([`Plan::new`]).
    Plan(PlanError),
    /// A slab owns fewer rows than its halo's depth ([`halo_rows`]): its halo rows would
    /// come from two slabs.
    Rows {
        /// the slab
        index: usize,
        /// its rows
        rows: usize,
        /// the halo's depth ([`halo_rows`])
        depth: usize,
    },
    /// The slab's grid needs more cells than its solver holds.
    Capacity {
        /// cells needed
        cells: usize,
        /// capacity
        capacity: usize,
    },
    /// A part of the model that does not run on slabs yet.
    NotYet(&'static str),
    /// The flow to cut was not prepared ([`Flow::prepare`]).
    Unprepared,
    /// The slab's solver refused its set-up.
    Setup(FlowError),
    /// The slab's segregation solver refused its set-up (a coupled run on slabs).
    Segregation(SetupError),
    /// The whole run has cut cells and no geometry was given to hold the slab's.
    GeometryMissing,
    /// The slab's cut cells could not be loaded.
    Geometry(GeometryError),
}

/// Where one slab's rows lie, and its part of the solves' preconditioner.
#[derive(Clone)]
pub struct SlabPlan<const D: usize> {
    /// The owned rows of the global grid.
    pub rows: Range<usize>,
    /// Halo rows below and above (0 where the slab ends at the box).
    pub halo: [usize; 2],
    /// Cells per row.
    pub plane: usize,
    plan: Plan<D>,
}

impl<const D: usize> SlabPlan<D> {
    /// Owned rows.
    pub fn own_rows(&self) -> usize {
        self.rows.len()
    }

    /// The owned cells in the slab's numbering.
    pub fn owned_cells(&self) -> Range<usize> {
        self.halo[0] * self.plane..(self.halo[0] + self.own_rows()) * self.plane
    }

    /// The owned cells in the global numbering.
    pub fn global_cells(&self) -> Range<usize> {
        self.rows.start * self.plane..self.rows.end * self.plane
    }

    /// Values of the memory a [`Slab`] works in: the padded system of a solve and the
    /// conjugate gradients' scratch ([`cg_slab::Scratch`]).
    pub fn memory_len(&self) -> usize {
        let padded = self.plan.padded_len();
        (6 + D) * padded + 4 * self.plane * self.own_rows() + self.plan.workspace_len()
    }
}

/// Sets `local` up as slab `index` of the prepared flow `global` cut into slabs that begin
/// at the rows `starts` (`starts[0] == 0`, increasing): the global grid's rows of the slab
/// and its halos, the global boundaries with a slip wall at the outer face of each halo,
/// every state array ([`Flow::for_each_state_array`]) and the counters copied. The solves
/// plan for the hierarchy of a serial solver of `local`'s capacity `N` ([`Plan::new`]), so
/// the serial run to compare with must have the same.
pub fn load_slab<R: Real, const D: usize, const M: usize, const N: usize>(
    global: &Flow<R, D, M>,
    starts: &[usize],
    index: usize,
    local: &mut Flow<R, D, N>,
) -> Result<SlabPlan<D>, SlabError> {
    let cfg = *global.config();
    if !global.prepared {
        return Err(SlabError::Unprepared);
    }
    let grid = *global.grid();
    let cells = grid.cells();
    let plan =
        Plan::new(cells, global.periodic(), starts, index, D * N).map_err(SlabError::Plan)?;
    let total = cells[D - 1];
    let depth = halo_rows(global);
    if starts.len() > 1 {
        let ends = starts[1..].iter().copied().chain([total]);
        for (k, (&start, end)) in starts.iter().zip(ends).enumerate() {
            if end - start < depth {
                return Err(SlabError::Rows {
                    index: k,
                    rows: end - start,
                    depth,
                });
            }
        }
    }
    let rows = starts[index]..starts.get(index + 1).copied().unwrap_or(total);
    let halo = [
        if index > 0 { depth } else { 0 },
        if index + 1 < starts.len() { depth } else { 0 },
    ];
    let plane = grid.len() / total;
    let local_rows = rows.len() + halo[0] + halo[1];
    if local_rows * plane > N {
        return Err(SlabError::Capacity {
            cells: local_rows * plane,
            capacity: N,
        });
    }
    let mut bc = *global.boundaries();
    for (side, &h) in halo.iter().enumerate() {
        if h > 0 {
            bc[D - 1][side] = FlowSide::wall(Slip::Slip);
        }
    }
    let first = rows.start - halo[0];
    local
        .setup(grid.slab(first as i64, local_rows), bc, cfg)
        .map_err(SlabError::Setup)?;
    let span = first * plane..(first + local_rows) * plane;
    global.for_each_state_array(|name, from| {
        local.for_each_state_array_mut(|to_name, to| {
            if to_name == name {
                to.copy_from_slice(&from[span.clone()]);
            }
        });
    });
    if global.walls.on {
        local.walls.load_rows(&global.walls, span.clone());
    }
    // a rotating frame's bounds are the box's, not the slab's
    local.home = grid;
    local.home_rows = first;
    local.home_first = first * plane;
    local.restore_counters(global.counters());
    local.prepared = true;
    Ok(SlabPlan {
        rows,
        halo,
        plane,
        plan,
    })
}

/// A slab's [`Reach`]: its neighbours through `links`, the solves on its rows in `memory`
/// ([`SlabPlan::memory_len`] values).
pub struct Slab<'a, R, L, const D: usize> {
    plan: &'a SlabPlan<D>,
    links: &'a mut L,
    memory: &'a mut [R],
}

impl<'a, R: Real, L: Links<R>, const D: usize> Slab<'a, R, L, D> {
    /// The slab of `plan`, talking to its neighbours through `links`. `memory` must hold at
    /// least [`SlabPlan::memory_len`] values.
    pub fn new(plan: &'a SlabPlan<D>, links: &'a mut L, memory: &'a mut [R]) -> Self {
        assert!(memory.len() >= plan.memory_len(), "slab memory too short");
        Self {
            plan,
            links,
            memory,
        }
    }

    /// Hands running values from the first slab to the last, each continuing them with
    /// `part`, then the last slab's result back down to every slab: one message each way
    /// per neighbour, however many values.
    fn chain<const K: usize>(
        &mut self,
        start: [R; K],
        part: impl FnOnce([R; K]) -> [R; K],
    ) -> [R; K] {
        let [below, above] = self.plan.halo.map(|h| h > 0);
        let mut v = start;
        if below {
            self.links.receive_below(&mut v);
        }
        let mut total = part(v);
        if above {
            self.links.send_up(&total);
            self.links.receive_above(&mut total);
        }
        if below {
            self.links.send_down(&total);
        }
        total
    }

    /// Overwrites the halo rows of a local array with the neighbours' own rows.
    fn swap_halos(&mut self, field: &mut [R]) {
        let s = self.plan.plane;
        let [lo, hi] = self.plan.halo;
        let own = self.plan.own_rows() * s;
        let (below, rest) = field.split_at_mut(lo * s);
        let (mine, rest) = rest.split_at_mut(own);
        // this slab's first rows are the halo above of the slab below, and so on
        let (bottom, top) = (&mine[..lo * s], &mine[own - hi * s..]);
        self.links.swap(bottom, top, below, &mut rest[..hi * s]);
    }

    /// Copies the rows of a local array that the padded layout of the solves holds (the own
    /// rows and one on each side, where the local grid has them) into `padded`.
    fn pad(&self, local: &[R], padded: &mut [R]) {
        let s = self.plan.plane;
        let local_rows = local.len() / s;
        for j in 0..self.plan.own_rows() + 2 {
            // padded row j is local row j + halo below - 1
            let Some(l) = (j + self.plan.halo[0]).checked_sub(1) else {
                continue;
            };
            if l < local_rows {
                padded[j * s..(j + 1) * s].copy_from_slice(&local[l * s..(l + 1) * s]);
            }
        }
    }
}

impl<R: Real, L: Links<R>, const D: usize> InOrder<R> for Slab<'_, R, L, D> {
    fn whole(&self) -> bool {
        false
    }

    fn sums_in_order<const K: usize>(
        &mut self,
        start: [R; K],
        part: impl FnOnce([R; K]) -> [R; K],
    ) -> [R; K] {
        self.chain(start, part)
    }
}

impl<R: Real, L: Links<R>, const D: usize, const N: usize> Reach<R, D, N> for Slab<'_, R, L, D> {
    fn owned(&self, _n: usize) -> Range<usize> {
        self.plan.owned_cells()
    }

    fn refresh(&mut self, field: &mut [R]) {
        self.swap_halos(field);
    }

    fn max(&mut self, x: R) -> R {
        let [m] = self.chain([x], |[m]| [m.max(x)]);
        m
    }

    fn solve<F: Fork>(
        &mut self,
        _fork: &F,
        st: &Stencil<'_, R, D, N>,
        diag: &[R],
        b: &[R],
        x: &mut [R],
        _sc: Scratch<'_, R>,
        stop: Stop<R>,
    ) -> Solve<R> {
        let n = st.grid.len();
        let plan = self.plan;
        let p = plan.plan.padded_len();
        let o = plan.plane * plan.own_rows();
        let memory = core::mem::take(&mut self.memory);
        let (system, rest) = memory.split_at_mut((3 + D) * p);
        let (cg, work) = rest.split_at_mut(3 * p + 4 * o);
        let (diag_p, system) = system.split_at_mut(p);
        let (b_p, system) = system.split_at_mut(p);
        let (x_p, kf_p) = system.split_at_mut(p);
        self.pad(&diag[..n], diag_p);
        self.pad(&b[..n], b_p);
        self.pad(&x[..n], x_p);
        for (a, kf) in kf_p.chunks_exact_mut(p).enumerate() {
            self.pad(&st.kf[a][..n], kf);
        }
        let (r, cg) = cg.split_at_mut(p);
        let (pv, cg) = cg.split_at_mut(p);
        let (ap, cg) = cg.split_at_mut(p);
        let (pre, cg) = cg.split_at_mut(o);
        let (line, cg) = cg.split_at_mut(o);
        let (tmp, terms) = cg.split_at_mut(o);
        let fine = Fine {
            diag: diag_p,
            kf: core::array::from_fn(|a| &kf_p[a * p..(a + 1) * p]),
        };
        let scratch = cg_slab::Scratch {
            r,
            p: pv,
            ap,
            pre,
            line,
            tmp,
            terms,
            work,
        };
        let res = cg_slab::solve(&plan.plan, self.links, &fine, b_p, x_p, scratch, stop);
        x[plan.owned_cells()].copy_from_slice(&x_p[plan.plan.own_range()]);
        self.memory = memory;
        self.swap_halos(&mut x[..n]);
        res
    }
}
