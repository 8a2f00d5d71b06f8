//! Domain decomposition of a box grid into subdomains along the last axis, with the same bits
//! as the undivided grid (docs/parallel.md).
//!
//! A subdomain owns a contiguous range of rows (cells with the same index along the last
//! axis; the rows are the outermost index, so a row range is a contiguous cell range) and
//! is its own [`Segregation`] on the slab of its rows extended by `H` halo rows on each cut
//! side. The outer face of a halo is a wall. After each step the halo rows are overwritten
//! with the owner's rows ([`pack`], [`unpack`]). Why the update is then bit-identical:
//!
//! - every face flux is a pure function of the two cells' `q, c, k, T, u` ([`crate::segregation::flux`]);
//!   a face between an owned row and a halo row sees exactly the global values when the
//!   halo holds them, and its flux is computed by the same function as in the global grid;
//! - every cell adds its face fluxes in the same order (axis by axis, high face then low
//!   face), whether a face is interior, periodic or at a cut (checked in
//!   `segregation/step.rs`: the low periodic face and an interior face below both enter as
//!   `q + ((dq - f_high) + f_low)`);
//! - the derived coefficients (`k`, and T and the direction when they come from the
//!   velocity gradient) of halo row 1 need the velocity of halo row 2: [`halo_width`] is 2
//!   when the gradient is used, else 1. The outermost halo row sees a one-sided gradient,
//!   so its coefficients are wrong; its fluxes only reach halo cells, and the stable rate is
//!   taken over owned cells only ([`Segregation::prepare_owned`]);
//! - the step number, on which the flush of docs/model.md 5.6 depends, is the global one;
//!   the subdomain steps with the flush off and the driver flushes the owned cells
//!   ([`Segregation::end_owned_step`]), handing the flushed values over in cell order;
//! - the bound maxima count the owned cells only: the step's update takes them over the
//!   range given to [`Segregation::prepare_owned`];
//! - the time step is a minimum, and `C / max rate` is the minimum of `C / rate` over
//!   subdomains exactly (correctly rounded division is monotone).
//!
//! On cut cells each subdomain steps on its slab of the global [`CutCells`]
//! ([`load_cut_cells`]) with halos [`GROUP_REACH`] rows wider, so that merge groups across a
//! cut update as in the global grid (docs/parallel.md "Cut cells on subdomains").
//!
//! Diagnostics: the sums of [`crate::diagnostics::diagnose`] run in cell order, so a driver
//! that wants the serial bits gathers the state (what the host does at output times). A
//! driver that cannot gather (many ranks) folds [`RowSums`]: one blocked partial
//! ([`crate::sum::block`]) per grid row, added in row order, the same bits for any split
//! along rows (a row is never cut), within [`crate::sum::error_bound`] of the serial sum.

use crate::boundary::{Boundaries, Boundary};
use crate::diagnostics::mixing_entropy_density;
use crate::geometry::{CutCells, GeometryError};
use crate::grid::Grid;
use crate::real::Real;
use crate::segregation::{DirectionMode, Segregation, SetupError, TemperatureMode};
use core::ops::Range;

/// Low (towards row 0) or high side of a subdomain along the split axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// The side towards row 0.
    Low = 0,
    /// The side towards the last row.
    High = 1,
}

impl Side {
    /// The other side.
    pub fn opposite(self) -> Self {
        match self {
            Side::Low => Side::High,
            Side::High => Side::Low,
        }
    }
}

/// Why a grid cannot be split as asked.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SplitError {
    /// Zero parts, or more parts than the rows allow (each part must own at least as many
    /// rows as the halo is wide, so that a halo comes from one neighbour).
    Parts {
        /// parts asked for
        parts: usize,
        /// the most the grid allows
        max: usize,
    },
    /// The subdomain grid needs more cells than the capacity of its solver.
    Capacity {
        /// cells needed
        cells: usize,
        /// capacity
        capacity: usize,
    },
}

/// Halo rows a subdomain needs for the segregation step: 1 (the flux stencil), or 2 when
/// T or the direction are derived from the velocity gradient (a central difference whose
/// stencil reaches one row further).
pub fn halo_width<R: Real, const D: usize, const N: usize>(s: &Segregation<R, D, N>) -> usize {
    let cfg = s.config();
    let gradient = matches!(cfg.direction, DirectionMode::Flow)
        || matches!(cfg.temperature, TemperatureMode::FromShear { .. });
    if gradient {
        2
    } else {
        1
    }
}

/// Rows by which a merge group of cut cells ([`crate::geometry::CutCells`]) can reach past
/// an owned cell along the split axis: an owned cell merged into a master in the next row,
/// whose group takes in the row after it. A group's update sums its members' increments, so
/// those members' fluxes (and the coefficients of the row beyond) must be the global ones.
pub const GROUP_REACH: usize = 2;

/// Halo rows a subdomain on cut cells needs: [`halo_width`] plus [`GROUP_REACH`].
pub fn halo_width_cut<R: Real, const D: usize, const N: usize>(s: &Segregation<R, D, N>) -> usize {
    halo_width(s) + GROUP_REACH
}

/// The largest number of parts `rows` rows split into with halos `halo` wide.
pub fn max_parts(rows: usize, halo: usize) -> usize {
    (rows / halo.max(1)).max(1)
}

/// The rows `start..end` owned by part `index` of `parts`: `rows * k / parts` boundaries, so
/// the parts differ by at most one row.
pub fn owned_rows(rows: usize, parts: usize, index: usize) -> Range<usize> {
    rows * index / parts..rows * (index + 1) / parts
}

/// One subdomain of a split along the last axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Subdomain {
    /// This part's index, `0..parts`, in row order.
    pub index: usize,
    /// Number of parts.
    pub parts: usize,
    /// Rows of the global grid along the last axis.
    pub global_rows: usize,
    /// Owned global rows.
    pub rows: [usize; 2],
    /// Halo rows on the low and high side (0 where the subdomain ends at a physical boundary).
    pub halo: [usize; 2],
    /// Cells per row.
    pub plane: usize,
    /// The last axis is periodic: the first and last parts are neighbours.
    pub periodic: bool,
}

impl Subdomain {
    /// Part `index` of `parts` of `grid` with boundaries `bc`, halos `halo` rows wide.
    pub fn new<R: Real, const D: usize>(
        grid: &Grid<R, D>,
        bc: &Boundaries<D>,
        parts: usize,
        index: usize,
        halo: usize,
    ) -> Result<Self, SplitError> {
        let cells = grid.cells();
        let global_rows = cells[D - 1];
        let max = max_parts(global_rows, halo);
        if parts == 0 || parts > max || index >= parts {
            return Err(SplitError::Parts { parts, max });
        }
        let periodic = bc[D - 1][0] == Boundary::Periodic && parts > 1;
        let r = owned_rows(global_rows, parts, index);
        let lo = if index > 0 || periodic { halo } else { 0 };
        let hi = if index + 1 < parts || periodic {
            halo
        } else {
            0
        };
        Ok(Self {
            index,
            parts,
            global_rows,
            rows: [r.start, r.end],
            halo: [lo, hi],
            plane: grid.len() / global_rows,
            periodic,
        })
    }

    /// Owned rows.
    pub fn owned_len(&self) -> usize {
        self.rows[1] - self.rows[0]
    }
    /// Rows of the subdomain's own grid (owned plus halos).
    pub fn local_rows(&self) -> usize {
        self.owned_len() + self.halo[0] + self.halo[1]
    }
    /// Cells of the subdomain's own grid.
    pub fn local_len(&self) -> usize {
        self.local_rows() * self.plane
    }
    /// The owned cells in the subdomain's numbering.
    pub fn owned_cells(&self) -> Range<usize> {
        self.halo[0] * self.plane..(self.halo[0] + self.owned_len()) * self.plane
    }
    /// The owned cells in the global numbering.
    pub fn global_cells(&self) -> Range<usize> {
        self.rows[0] * self.plane..self.rows[1] * self.plane
    }
    /// The global row of local row `r` (wrapped on a periodic axis).
    pub fn global_row(&self, r: usize) -> usize {
        let g = self.rows[0] as i64 + r as i64 - self.halo[0] as i64;
        g.rem_euclid(self.global_rows as i64) as usize
    }
    /// The neighbour across `side`, if that side is a cut.
    pub fn neighbour(&self, side: Side) -> Option<usize> {
        if self.halo[side as usize] == 0 {
            return None;
        }
        Some(match side {
            Side::Low => (self.index + self.parts - 1) % self.parts,
            Side::High => (self.index + 1) % self.parts,
        })
    }
    /// The subdomain's grid: the global spacing to the bit.
    pub fn local_grid<R: Real, const D: usize>(&self, global: &Grid<R, D>) -> Grid<R, D> {
        global.slab(self.rows[0] as i64 - self.halo[0] as i64, self.local_rows())
    }
    /// The subdomain's boundaries: the global ones, with a wall at the outer face of a halo.
    pub fn local_boundaries<const D: usize>(&self, global: &Boundaries<D>) -> Boundaries<D> {
        let mut bc = *global;
        for side in [Side::Low, Side::High] {
            if self.halo[side as usize] > 0 {
                bc[D - 1][side as usize] = Boundary::Wall;
            }
        }
        bc
    }
    /// The local rows whose values the neighbour across `side` needs for its halo: the
    /// owned rows next to that cut, as many as the neighbour's halo is wide (this one's).
    pub fn send_rows(&self, side: Side) -> Range<usize> {
        let h = self.halo[side as usize];
        match side {
            Side::Low => self.halo[0]..self.halo[0] + h,
            Side::High => {
                let end = self.halo[0] + self.owned_len();
                end - h..end
            }
        }
    }
    /// The local halo rows on `side`.
    pub fn halo_rows(&self, side: Side) -> Range<usize> {
        match side {
            Side::Low => 0..self.halo[0],
            Side::High => {
                let start = self.halo[0] + self.owned_len();
                start..start + self.halo[1]
            }
        }
    }
    /// Values in a halo message of `fields` state arrays across `side`.
    pub fn message_len(&self, side: Side, fields: usize) -> usize {
        self.halo[side as usize] * self.plane * fields
    }
}

/// Sets up `local` as subdomain `sub` of the prepared solver `global`: its grid and
/// boundaries, every state array of its rows (halos included) copied from `global`, the
/// clock and bound maxima, the flush off (the driver flushes: [`Segregation::end_owned_step`]),
/// then prepared with the stable rate over the owned cells. `global` must be prepared (T
/// from shear is then the derived one; re-deriving it gives the same bits).
pub fn load_subdomain<R: Real, const D: usize, const N: usize, const M: usize>(
    global: &Segregation<R, D, N>,
    sub: &Subdomain,
    local: &mut Segregation<R, D, M>,
) -> Result<(), SetupError> {
    let grid = sub.local_grid(global.grid());
    let bc = sub.local_boundaries(global.boundaries());
    let mut cfg = *global.config();
    cfg.flush_below = R::ZERO;
    local.setup(grid, bc, cfg)?;
    copy_rows(global, sub, local, &[]);
    local.set_clock(global.time(), global.steps());
    local.set_tracked_excess(global.tracked_excess());
    local.prepare_owned(sub.owned_cells())
}

/// The cut cells of subdomain `sub`: its rows, halos included, of the global `geo`
/// ([`CutCells::load_slab`]). A split of a periodic last axis is refused (a merge group
/// across the wrap would list its members in another order).
pub fn load_cut_cells<R: Real, const D: usize, const N: usize, const M: usize>(
    geo: &CutCells<R, D, N>,
    sub: &Subdomain,
    local: &mut CutCells<R, D, M>,
) -> Result<(), GeometryError> {
    if sub.periodic {
        return Err(GeometryError::Dimension);
    }
    local.load_slab(geo, sub.rows[0] - sub.halo[0], sub.local_rows())
}

/// Copies the state arrays named in `only` (all of them if empty) of every local row from
/// the global solver (the start of a chunk of steps: the global state may have been
/// restored or replayed since the last gather).
pub fn copy_rows<R: Real, const D: usize, const N: usize, const M: usize>(
    global: &Segregation<R, D, N>,
    sub: &Subdomain,
    local: &mut Segregation<R, D, M>,
    only: &[&str],
) {
    let p = sub.plane;
    global.for_each_state_array(|name, g| {
        if !only.is_empty() && !only.contains(&name) {
            return;
        }
        local.for_each_state_array_mut(|lname, l| {
            if lname != name {
                return;
            }
            for r in 0..sub.local_rows() {
                let gr = sub.global_row(r);
                l[r * p..(r + 1) * p].copy_from_slice(&g[gr * p..(gr + 1) * p]);
            }
        });
    });
}

/// Copies the state arrays named in `only` of the owned rows back into the global solver
/// (all of them if empty).
pub fn gather_rows<R: Real, const D: usize, const N: usize, const M: usize>(
    local: &Segregation<R, D, M>,
    sub: &Subdomain,
    global: &mut Segregation<R, D, N>,
    only: &[&str],
) {
    let (own, glob) = (sub.owned_cells(), sub.global_cells());
    global.for_each_state_array_mut(|name, g| {
        if !only.is_empty() && !only.contains(&name) {
            return;
        }
        local.for_each_state_array(|lname, l| {
            if lname == name {
                g[glob.clone()].copy_from_slice(&l[own.clone()]);
            }
        });
    });
}

/// Packs the owned rows the neighbour across `side` needs, of the state arrays named in
/// `fields` (in that order), into `buf`; returns the number of values written
/// ([`Subdomain::message_len`]). The segregation step needs `["q"]` only: the coefficients
/// are static between prepares and a cell's carried rounding error never enters a flux.
pub fn pack<R: Real, const D: usize, const M: usize>(
    local: &Segregation<R, D, M>,
    sub: &Subdomain,
    side: Side,
    fields: &[&str],
    buf: &mut [R],
) -> usize {
    let rows = sub.send_rows(side);
    let cells = rows.start * sub.plane..rows.end * sub.plane;
    let len = cells.len();
    let mut at = 0;
    for f in fields {
        local.for_each_state_array(|name, a| {
            if name == *f {
                buf[at..at + len].copy_from_slice(&a[cells.clone()]);
                at += len;
            }
        });
    }
    at
}

/// Writes a neighbour's message ([`pack`] across the opposite side) into the halo rows on
/// `side`.
pub fn unpack<R: Real, const D: usize, const M: usize>(
    local: &mut Segregation<R, D, M>,
    sub: &Subdomain,
    side: Side,
    fields: &[&str],
    buf: &[R],
) {
    let rows = sub.halo_rows(side);
    let cells = rows.start * sub.plane..rows.end * sub.plane;
    let len = cells.len();
    let mut at = 0;
    for f in fields {
        local.for_each_state_array_mut(|name, a| {
            if name == *f {
                a[cells.clone()].copy_from_slice(&buf[at..at + len]);
                at += len;
            }
        });
    }
}

/// Sums of the diagnostics over whole rows ([`crate::diagnostics::diagnose`]'s small-grain
/// mass, total mass and mixing entropy, without the cell volume), one blocked partial
/// per row: the same bits however the rows are split among subdomains.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RowSums<R> {
    /// `sum phi`
    pub small: R,
    /// `sum c`
    pub total: R,
    /// `sum c s(phi/c)` over non-empty cells
    pub entropy: R,
}

impl<R: Real> RowSums<R> {
    /// Zero.
    pub const ZERO: Self = Self {
        small: R::ZERO,
        total: R::ZERO,
        entropy: R::ZERO,
    };

    /// The partial sums of local rows `rows` of `s`, each row summed by
    /// [`crate::sum::reduce`] from its first cell, handed to `out` in row order.
    pub fn of_rows<const D: usize, const M: usize>(
        s: &Segregation<R, D, M>,
        rows: Range<usize>,
        plane: usize,
        mut out: impl FnMut(Self),
    ) {
        let vacuum = s.config().vacuum;
        for r in rows {
            let (a, b) = (r * plane, (r + 1) * plane);
            let small = crate::sum::reduce(b - a, |j| s.phi(a + j));
            let total = crate::sum::reduce(b - a, |j| s.c(a + j));
            let entropy = crate::sum::reduce(b - a, |j| {
                let c = s.c(a + j);
                if c > vacuum {
                    mixing_entropy_density(s.phi(a + j) / c) * c
                } else {
                    R::ZERO
                }
            });
            out(Self {
                small,
                total,
                entropy,
            });
        }
    }

    /// Adds `other` (the next row) to this running total.
    pub fn add(&mut self, other: Self) {
        self.small += other.small;
        self.total += other.total;
        self.entropy += other.entropy;
    }

    /// The mixing index Psi of the folded totals (model.md 6, as
    /// [`crate::diagnostics::diagnose`] forms it from its sums).
    pub fn psi(&self) -> R {
        let mixed = if self.total > R::ZERO {
            mixing_entropy_density(self.small / self.total) * self.total
        } else {
            R::ZERO
        };
        if mixed > R::ZERO {
            self.entropy / mixed
        } else {
            R::ZERO
        }
    }
}
