//! The preconditioner of [`super::cg`] (the line solves, and the aggregation V-cycle once a
//! solve switches to it) on a slab of whole rows of a grid cut along its last axis, with the
//! serial bits: the third mechanism the coupled flow under mpirun needs (docs/parallel.md,
//! "The V-cycle on slabs").
//!
//! Why the bits are the serial ones:
//! - the line solves continue along the slabs as pipelines ([`super::line_slab`]), each row
//!   sent in column pieces so that the slabs sweep as a wavefront ([`Plan::with_pieces`]);
//! - a product or a residual of a slab's own rows reads one row beyond them on each cut
//!   side. A slab keeps a halo row there, filled from the neighbour before each product, and
//!   computes its own rows with the serial function on the *view* of its rows and the halo
//!   rows that exist: every own cell sees the serial neighbours, coefficients and order;
//! - a coarse cell aggregates two rows. If every slab begins on a multiple of `2^l` rows,
//!   the aggregates of levels `1..=l` lie inside the slabs, and restriction, prolongation,
//!   the Jacobi smoothing and the Galerkin faces of those levels are local. The Galerkin
//!   diagonal adds each coarse face at both its cells, so a slab's bottom row needs the
//!   faces of the row below it: the halo row again, and the serial cell loop run over the
//!   view adds them in the serial order;
//! - the first level whose aggregates a cut would split (or the coarsest, whose symmetric
//!   Gauss-Seidel sweeps are sequential) is *gathered*: its right-hand side goes to every
//!   slab, and every slab solves that level and all below it with the serial V-cycle, the
//!   same bits everywhere. Its operator is gathered once, at set-up. A driver that cuts on
//!   multiples of a high power of two keeps the gathered levels small (a quarter of the
//!   cells per level in 2D, an eighth in 3D).
//!
//! Cuts must be even (on an odd cut not even the first coarse level is local: [`Plan::new`]
//! refuses it when the preconditioner can coarsen), and a periodic last axis cannot be cut
//! (its wrap faces would join the first and the last slab).
//!
//! Layout: every per-slab array of a level holds the slab's rows with one row more on each
//! side (`(own + 2) s` values for rows of `s` cells): the halo rows, or unused rows where the
//! slab has no neighbour. Everything is in the caller's slices: no allocation.

use super::cg::{
    assemble_diagonal, product_lines, prolong, restrict, strides, Cycle, Levels, Op, OMEGA,
    OMEGA_COARSE,
};
use super::line_slab;
use crate::fork::Serial;
use crate::real::Real;
use core::ops::Range;

/// What a slab exchanges with the others: rows with the slabs beside it, and a level
/// gathered from all of them. The host implements it over MPI ranks, the tests over
/// threads. Every slab makes the same calls in the same order, and the calls to a
/// neighbour are only made where one exists.
pub trait Links<R: Real> {
    /// Sends `row` to the slab above (may wait until it is received: the calls that send up
    /// are the steps of a pipeline whose receiver is waiting for them).
    fn send_up(&mut self, row: &[R]);
    /// Sends `row` to the slab below.
    fn send_down(&mut self, row: &[R]);
    /// Receives the row the slab below sent up.
    fn receive_below(&mut self, row: &mut [R]);
    /// Receives the row the slab above sent down.
    fn receive_above(&mut self, row: &mut [R]);
    /// Swaps boundary rows with both neighbours, those that exist (and must not deadlock):
    /// `bottom` goes to the slab below and `top` to the one above; the slab below's top row
    /// lands in `below`, the slab above's bottom row in `above` (each left as it is where
    /// there is no neighbour).
    fn swap(&mut self, bottom: &[R], top: &[R], below: &mut [R], above: &mut [R]);
    /// Every slab's `own`, in slab order, into `all`, on every slab.
    fn gather(&mut self, own: &[R], all: &mut [R]);
    /// The blocked sum ([`crate::sum::reduce`]) of every slab's `own` terms in slab order,
    /// on every slab: the serial sum's bits (`crate::sum::cut_partials` tells how to get them
    /// without gathering the terms).
    fn sum(&mut self, own: &[R]) -> R;
}

/// Cells of a row per column piece of the line pipelines, by default ([`Plan::with_pieces`]).
const PIECE: usize = 32;
/// Most column pieces by default.
const MAX_PIECES: usize = 8;

/// Why a cut cannot carry the serial preconditioner.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlanError {
    /// The last axis is periodic and cut.
    PeriodicCut,
    /// A slab starts on an odd row while the preconditioner can coarsen.
    OddCut,
    /// The first rows of the slabs are not increasing from 0 within the grid, or the slab
    /// index is out of range.
    BadCuts,
}

/// One level's rows on this slab.
#[derive(Clone, Copy, Debug)]
struct Layer<const D: usize> {
    /// The slab's own cells (the global ones with the own rows along the last axis).
    cells: [usize; D],
    /// Cells per row.
    s: usize,
    /// Own rows.
    own: usize,
    below: bool,
    above: bool,
}

impl<const D: usize> Layer<D> {
    /// Values of a padded array: the own rows and one row on each side.
    fn padded(&self) -> usize {
        (self.own + 2) * self.s
    }

    /// Own cells in the padded array.
    fn own_range(&self) -> Range<usize> {
        self.s..(self.own + 1) * self.s
    }

    /// Own cells, and the halo rows that exist, in the padded array.
    fn view(&self) -> Range<usize> {
        let lo = usize::from(!self.below) * self.s;
        lo..(self.own + 1 + usize::from(self.above)) * self.s
    }

    /// The view's cells.
    fn view_cells(&self) -> [usize; D] {
        let mut c = self.cells;
        c[D - 1] = self.own + usize::from(self.below) + usize::from(self.above);
        c
    }

    /// The view's first own line along axis 0 (lines before it: the halo row below).
    fn first_line(&self) -> usize {
        usize::from(self.below) * (self.s / self.cells[0].max(1))
    }
}

/// How one slab takes part in the preconditioner: the global grid and hierarchy, the slab's
/// rows and which levels it solves on its rows or whole.
#[derive(Clone)]
pub struct Plan<const D: usize> {
    periodic: [bool; D],
    /// This slab's fine rows.
    rows: Range<usize>,
    below: bool,
    above: bool,
    /// The serial hierarchy (`count == 1`: lines only).
    levels: Levels<D>,
    /// The first level gathered whole on every slab (levels `1..gathered` are on the slabs).
    gathered: usize,
    /// Column pieces of the line pipelines' wavefront (see [`Plan::with_pieces`]).
    pieces: usize,
}

impl<const D: usize> Plan<D> {
    /// The plan of slab `index` of a grid of `cells` cut into slabs beginning at the rows
    /// `starts` (increasing, `starts[0] == 0`), for a solve whose serial
    /// [`super::cg::Scratch::coarse`] holds `room` values (which sets the hierarchy's depth).
    pub fn new(
        cells: [usize; D],
        periodic: [bool; D],
        starts: &[usize],
        index: usize,
        room: usize,
    ) -> Result<Self, PlanError> {
        let total = cells[D - 1];
        let ok = starts.first() == Some(&0)
            && starts.windows(2).all(|w| w[0] < w[1])
            && starts.last().is_some_and(|&s| s < total)
            && index < starts.len();
        if !ok {
            return Err(PlanError::BadCuts);
        }
        if starts.len() > 1 && D < 2 {
            return Err(PlanError::BadCuts); // a 1D grid's rows are its lines
        }
        if starts.len() > 1 && periodic[D - 1] {
            return Err(PlanError::PeriodicCut);
        }
        let horizontal = cells[..D - 1].iter().any(|&c| c > 1);
        let mut levels = Levels::new(cells, if horizontal { room } else { 0 });
        if !horizontal {
            levels.count = 1;
        }
        // the alignment of the cuts: every start is a multiple of 2^align
        let align = starts[1..]
            .iter()
            .map(|&s| s.trailing_zeros() as usize)
            .min()
            .unwrap_or(usize::MAX);
        if levels.count > 1 && align == 0 {
            return Err(PlanError::OddCut);
        }
        let end = starts.get(index + 1).copied().unwrap_or(total);
        Ok(Self {
            periodic,
            rows: starts[index]..end,
            below: index > 0,
            above: index + 1 < starts.len(),
            levels,
            gathered: align.min(levels.count.saturating_sub(1)),
            pieces: if starts.len() > 1 {
                (cells[..D - 1].iter().product::<usize>() / PIECE).clamp(1, MAX_PIECES)
            } else {
                1
            },
        })
    }

    /// The line pipelines send each row in `pieces` pieces of columns (at least 1), so that
    /// the slab above starts on the first piece while this one sweeps the next: a wavefront.
    /// With `m` pieces on `K` slabs a sweep takes about `(m + K - 1) / m` of a perfectly
    /// shared one, against `K` times for whole rows; each piece is a message. Never changes
    /// the bits. The default: one piece per 32 cells of a row, at most 8.
    pub fn with_pieces(mut self, pieces: usize) -> Self {
        self.pieces = pieces.max(1);
        self
    }

    /// The column pieces of a row of `s` cells.
    fn pieces(&self, s: usize) -> impl Iterator<Item = Range<usize>> {
        let m = self.pieces.clamp(1, s.max(1));
        (0..m).map(move |k| k * s / m..(k + 1) * s / m)
    }

    /// Whether the V-cycle can run ([`coarsen`]); without it the preconditioner is the
    /// lines alone.
    pub fn can_coarsen(&self) -> bool {
        self.levels.count > 1
    }

    /// Level `l`'s rows on this slab (`l <= gathered`: the cuts are aligned there).
    fn layer(&self, l: usize) -> Layer<D> {
        let mut cells = self.levels.cells[l];
        let start = self.rows.start >> l;
        let end = if self.above {
            self.rows.end >> l
        } else {
            cells[D - 1]
        };
        cells[D - 1] = end - start;
        Layer {
            cells,
            s: cells[..D - 1].iter().product(),
            own: end - start,
            below: self.below,
            above: self.above,
        }
    }

    /// Values of every padded per-slab array of the fine level (`r`, `z`, `diag`, `kf`).
    pub fn padded_len(&self) -> usize {
        self.layer(0).padded()
    }

    /// The own cells in a padded fine array.
    pub fn own_range(&self) -> Range<usize> {
        self.layer(0).own_range()
    }

    /// Copies the slab's part of a global fine array (cells in grid order) into the padded
    /// `out`: the own cells, and the row below them too if `row_below` (the faces `kf[D - 1]`
    /// need it, [`Fine`]). The other values of `out` are left as they are.
    pub fn pad_from<R: Copy>(&self, global: &[R], row_below: bool, out: &mut [R]) {
        let lay = self.layer(0);
        let s = lay.s;
        let first = self.rows.start * s;
        let own = lay.own_range();
        out[own.clone()].copy_from_slice(&global[first..first + own.len()]);
        if row_below && self.below {
            out[..s].copy_from_slice(&global[first - s..first]);
        }
    }

    /// The tail: the gathered levels    /// The tail: the gathered levels as a hierarchy of their own (level 1 = `gathered`).
    fn tail(&self) -> Levels<D> {
        self.levels.below(self.gathered)
    }

    /// Workspace of [`factor`], [`coarsen`] and [`apply`] (kept between them).
    pub fn workspace_len(&self) -> usize {
        let mut len = 2 * self.layer(0).s;
        if self.can_coarsen() {
            for l in 1..=self.gathered {
                let lay = self.layer(l);
                len += (D + 3) * lay.padded() + lay.own * lay.s;
            }
            len += self.tail().storage();
        }
        len
    }
}

/// The fine operator on the slab, as padded arrays ([`Plan::padded_len`]): the mass
/// diagonal and the face coefficients of [`super::cg::Stencil`]. The halo row below of
/// `kf[D - 1]` must hold the slab below's top row (the faces between the two slabs).
#[derive(Clone, Copy)]
pub struct Fine<'a, R, const D: usize> {
    /// Mass diagonal.
    pub diag: &'a [R],
    /// Face coefficients.
    pub kf: [&'a [R]; D],
}

/// One slab level's arrays in the workspace.
struct Mem<'a, R> {
    /// Operator: full diagonal, then `D` face arrays, each padded.
    op: &'a mut [R],
    /// Solution, padded.
    x: &'a mut [R],
    /// Right-hand side (the mass diagonal during set-up), padded.
    b: &'a mut [R],
    /// Residual of the own cells.
    t: &'a mut [R],
}

/// The workspace in its parts.
struct Parts<'a, R> {
    /// One fine row: a message.
    row: &'a mut [R],
    /// The multipliers of the slab above's bottom row (kept from [`factor`]).
    l_above: &'a mut [R],
    /// The slab levels `1..=gathered`.
    mems: heapless::Vec<Mem<'a, R>, 32>,
    /// The storage of the gathered levels (their operators, then the V-cycle's work).
    tail: &'a mut [R],
}

/// The workspace cut into its [`Parts`].
fn split<'a, R: Real, const D: usize>(plan: &Plan<D>, work: &'a mut [R]) -> Parts<'a, R> {
    let s = plan.layer(0).s;
    let (row, rest) = work.split_at_mut(s);
    let (l_above, mut rest) = rest.split_at_mut(s);
    let mut mems = heapless::Vec::new();
    if plan.can_coarsen() {
        for l in 1..=plan.gathered {
            let lay = plan.layer(l);
            let p = lay.padded();
            let (op, r) = core::mem::take(&mut rest).split_at_mut((D + 1) * p);
            let (x, r) = r.split_at_mut(p);
            let (b, r) = r.split_at_mut(p);
            let (t, r) = r.split_at_mut(lay.own * lay.s);
            rest = r;
            let _ = mems.push(Mem { op, x, b, t }); // at most MAX_LEVELS levels
        }
    }
    Parts {
        row,
        l_above,
        mems,
        tail: rest,
    }
}

/// Fills the halo rows of the padded `v` from the neighbours.
fn swap_halos<R: Real, L: Links<R>, const D: usize>(links: &mut L, lay: &Layer<D>, v: &mut [R]) {
    let s = lay.s;
    let (below, rest) = v.split_at_mut(s);
    let (own, above) = rest.split_at_mut(lay.own * s);
    links.swap(&own[..s], &own[own.len() - s..], below, &mut above[..s]);
}

/// Fills the halo rows of the padded fine array `v` from the neighbours.
pub(crate) fn swap_fine<R: Real, L: Links<R>, const D: usize>(
    plan: &Plan<D>,
    links: &mut L,
    v: &mut [R],
) {
    swap_halos(links, &plan.layer(0), v);
}

/// The padded operator block of a slab level as the serial [`Op`] on the view.
fn view_op<'a, R: Real, const D: usize>(
    lay: &Layer<D>,
    periodic: [bool; D],
    op: &'a [R],
) -> Op<'a, R, D> {
    let p = lay.padded();
    let v = lay.view();
    let cells = lay.view_cells();
    Op {
        cells,
        strides: strides(cells),
        periodic,
        adiag: &op[v.clone()],
        kf: core::array::from_fn(|a| &op[(1 + a) * p + v.start..(1 + a) * p + v.end]),
    }
}

/// `out = A x` (or `b - A x` if `RES`) on the own cells of the fine level (`b`, `x` padded,
/// `x`'s halo rows filled): the serial product on the view.
pub(crate) fn fine_product<const RES: bool, R: Real, const D: usize>(
    plan: &Plan<D>,
    fine: &Fine<'_, R, D>,
    b: &[R],
    x: &[R],
    out: &mut [R],
) {
    let lay = plan.layer(0);
    let v = lay.view();
    let cells = lay.view_cells();
    product_lines::<RES, R, D>(
        (cells, strides(cells), plan.periodic),
        fine.kf.map(|k| &k[v.clone()]),
        (&fine.diag[v.clone()], &b[v.clone()], &x[v]),
        lay.first_line(),
        out,
    );
}

/// The piece `c` of the row the slab below sent up, received into `row` (`None` on the
/// bottom slab): where a pipeline step continues from.
fn from_below<'r, R: Real, L: Links<R>, const D: usize>(
    plan: &Plan<D>,
    links: &mut L,
    row: &'r mut [R],
    c: &Range<usize>,
) -> Option<&'r [R]> {
    plan.below.then(|| {
        links.receive_below(&mut row[c.clone()]);
        &*row
    })
}

/// The line solve on the own rows (`pre` and `line` the factor of the own rows, `l_above`
/// the slab above's bottom-row multipliers): `z = M^-1 r`, or `z = M^-1 z` in place when
/// `r` is `None`. A pipeline up the slabs and back down.
fn lines<R: Real, L: Links<R>, const D: usize>(
    plan: &Plan<D>,
    links: &mut L,
    (pre, line, l_above): (&[R], &[R], &[R]),
    row: &mut [R],
    r: Option<&[R]>,
    z: &mut [R],
) {
    let s = row.len();
    let top = z.len() - s;
    for c in plan.pieces(s) {
        let below = from_below(plan, links, row, &c);
        line_slab::forward(s, c.clone(), line, r, z, below);
        if plan.above {
            links.send_up(&z[top + c.start..top + c.end]);
        }
    }
    for c in plan.pieces(s) {
        if plan.above {
            links.receive_above(&mut row[c.clone()]);
        }
        let above = plan.above.then_some((&*row, l_above));
        line_slab::backward(s, c.clone(), pre, line, z, above);
        if plan.below {
            links.send_down(&z[c]);
        }
    }
}

/// Factors the line preconditioner on the slab's rows (a pipeline up the slabs): writes the
/// inverse pivots `pre` and the multipliers `line` of the own cells, and keeps the slab
/// above's bottom-row multipliers in `work`. The serial [`super::cg::Stencil::line_factor`].
pub fn factor<R: Real, L: Links<R>, const D: usize>(
    plan: &Plan<D>,
    links: &mut L,
    fine: &Fine<'_, R, D>,
    pre: &mut [R],
    line: &mut [R],
    work: &mut [R],
) {
    let lay = plan.layer(0);
    let (s, n) = (lay.s, lay.own * lay.s);
    let (pre, line) = (&mut pre[..n], &mut line[..n]);
    // A's diagonal of the own cells, added as `Stencil::diagonal` adds it: per axis the face
    // below, the face above, the wrap faces
    let v = lay.view();
    let cells = lay.view_cells();
    let st = strides(cells);
    let own = lay.own_range();
    let kf = fine.kf.map(|k| &k[v.clone()]);
    let diag = &fine.diag[v.clone()];
    super::cg::for_each_cell(cells, true, |i, k| {
        let g = i + v.start;
        if !own.contains(&g) {
            return;
        }
        let mut m = diag[i];
        for a in 0..D {
            let c = cells[a];
            if c < 2 {
                continue;
            }
            if k[a] > 0 {
                m += kf[a][i - st[a]];
            }
            if k[a] + 1 < c {
                m += kf[a][i];
            }
            if plan.periodic[a] && k[a] + 1 == c {
                m += kf[a][i];
            }
            if plan.periodic[a] && k[a] == 0 {
                m += kf[a][i + (c - 1) * st[a]];
            }
        }
        pre[g - own.start] = m;
    });
    let Parts { row, l_above, .. } = split(plan, work);
    for c in plan.pieces(s) {
        let below = from_below(plan, links, row, &c);
        // the face below own row i is kf's row i - 1 of the padded array (row 0: the halo)
        line_slab::factor(s, c.clone(), pre, line, &fine.kf[D - 1][..n], below);
        if plan.above {
            links.send_up(&pre[n - s + c.start..n - s + c.end]);
        }
    }
    line_slab::invert_pivots(pre);
    if plan.below {
        links.send_down(&line[..s]);
    }
    if plan.above {
        links.receive_above(l_above);
    }
}

/// Builds the V-cycle's levels (after [`factor`], if [`Plan::can_coarsen`]): the Galerkin
/// operators of the slab levels on the own rows with their halo rows, the gathered levels
/// whole; and damps the line smoother (`pre *= 0.8`), as the serial solve's switch does.
pub fn coarsen<R: Real, L: Links<R>, const D: usize>(
    plan: &Plan<D>,
    links: &mut L,
    fine: &Fine<'_, R, D>,
    pre: &mut [R],
    work: &mut [R],
) {
    if !plan.can_coarsen() {
        return;
    }
    let Parts {
        mut mems,
        tail: tail_mem,
        ..
    } = split(plan, work);
    let periodic = plan.periodic;
    let l0 = plan.layer(0);
    for l in 1..=plan.gathered {
        let (finer, here) = mems.split_at_mut(l - 1);
        let here = &mut here[0];
        let (up, lay) = (plan.layer(l - 1), plan.layer(l));
        let sc = strides(lay.cells);
        let own = lay.own_range();
        // the mass diagonal, restricted from the level above
        let mass = &mut here.b[own.clone()];
        mass.fill(R::ZERO);
        match finer.last() {
            None => restrict(up.cells, &sc, &fine.diag[l0.own_range()], mass),
            Some(m) => restrict(up.cells, &sc, &m.b[up.own_range()], mass),
        }
        // the coarse faces of the own cells, then the halo row below from the slab below
        let p = lay.padded();
        here.op.fill(R::ZERO);
        {
            let (ad, faces) = here.op.split_at_mut(p);
            let mut chunks = faces.chunks_exact_mut(p);
            let mut faces: [&mut [R]; D] = core::array::from_fn(|_| match chunks.next() {
                Some(f) => &mut f[own.clone()],
                None => &mut [],
            });
            let upper = match finer.last() {
                None => Op {
                    cells: up.cells,
                    strides: strides(up.cells),
                    periodic,
                    adiag: &fine.diag[l0.own_range()],
                    kf: fine.kf.map(|k| &k[l0.own_range()]),
                },
                Some(m) => {
                    let pu = up.padded();
                    let ou = up.own_range();
                    Op {
                        cells: up.cells,
                        strides: strides(up.cells),
                        periodic,
                        adiag: &m.op[ou.clone()],
                        kf: core::array::from_fn(|a| {
                            &m.op[(1 + a) * pu + ou.start..(1 + a) * pu + ou.end]
                        }),
                    }
                }
            };
            upper.aggregate_faces(plan.above, lay.cells, &mut faces);
            ad[own.clone()].copy_from_slice(&here.b[own.clone()]);
        }
        swap_halos(links, &lay, &mut here.op[D * p..(D + 1) * p]);
        let v = lay.view();
        let (ad, faces) = here.op.split_at_mut(p);
        let faces: [&[R]; D] = core::array::from_fn(|a| &faces[a * p + v.start..a * p + v.end]);
        assemble_diagonal(lay.view_cells(), periodic, faces, &mut ad[v.clone()]);
    }
    // the gathered levels: level `gathered` whole on every slab, then the serial hierarchy
    let tail = plan.tail();
    let g = plan.gathered;
    let (lay, m) = (plan.layer(g), &mems[g - 1]);
    let (p, own, ng) = (lay.padded(), lay.own_range(), tail.n[1]);
    let (ops, tail_work) = tail_mem.split_at_mut(tail.op_offset(tail.count));
    for k in 0..=D {
        links.gather(
            &m.op[k * p + own.start..k * p + own.end],
            &mut ops[k * ng..(k + 1) * ng],
        );
    }
    links.gather(&m.b[own], &mut tail_work[tail.rhs_slot(1)]);
    tail.coarsen_from_first(periodic, ops, tail_work);
    let omega = R::from_f64(OMEGA);
    for w in pre[..l0.own * l0.s].iter_mut() {
        *w *= omega;
    }
}

/// `z = B r` on the own cells (`r`, `z` padded; `tmp` one value per own cell): the serial
/// preconditioner's `apply`, without its final dot product (a sum across the slabs:
/// [`Links::sum`], as [`super::cg_slab::solve`] takes it). `coarsened`: [`coarsen`] ran on
/// this workspace (the V-cycle), else the lines alone.
#[allow(clippy::too_many_arguments)]
pub fn apply<R: Real, L: Links<R>, const D: usize>(
    plan: &Plan<D>,
    links: &mut L,
    fine: &Fine<'_, R, D>,
    (pre, line): (&[R], &[R]),
    r: &[R],
    z: &mut [R],
    tmp: &mut [R],
    work: &mut [R],
    coarsened: bool,
) {
    let l0 = plan.layer(0);
    let own = l0.own_range();
    let n = own.len();
    let Parts {
        row,
        l_above,
        mut mems,
        tail: tail_mem,
    } = split(plan, work);
    let factor = (&pre[..n], &line[..n], &*l_above);
    lines(
        plan,
        links,
        factor,
        row,
        Some(&r[own.clone()]),
        &mut z[own.clone()],
    );
    if !(coarsened && plan.can_coarsen()) {
        return;
    }
    let tmp = &mut tmp[..n];
    swap_halos(links, &l0, z);
    fine_product::<true, R, D>(plan, fine, r, z, tmp);
    let lay1 = plan.layer(1);
    let sc = strides(lay1.cells);
    {
        let b1 = &mut mems[0].b[lay1.own_range()];
        b1.fill(R::ZERO);
        restrict(l0.cells, &sc, tmp, b1);
    }
    let tail = plan.tail();
    let (ops, tail_work) = tail_mem.split_at_mut(tail.op_offset(tail.count));
    let cycle = Cycle {
        levels: tail,
        periodic: plan.periodic,
        omega_c: R::from_f64(OMEGA_COARSE),
    };
    vcycle(plan, links, 1, &mut mems, (&cycle, ops, tail_work));
    {
        let coarse = own_solution(plan, 1, &mems[0], tail_work);
        prolong(l0.cells, &sc, coarse, &mut z[own.clone()]);
    }
    swap_halos(links, &l0, z);
    fine_product::<true, R, D>(plan, fine, r, z, tmp);
    lines(plan, links, factor, row, None, tmp);
    for (zi, t) in z[own].iter_mut().zip(tmp.iter()) {
        *zi += *t;
    }
}

/// Level `l`'s own solution: `mem`'s on the slab, or the own rows of the gathered level's
/// (the first vector of the tail's work).
fn own_solution<'a, R: Real, const D: usize>(
    plan: &Plan<D>,
    l: usize,
    mem: &'a Mem<'_, R>,
    tail_work: &'a [R],
) -> &'a [R] {
    let lay = plan.layer(l);
    if l == plan.gathered {
        let start = (plan.rows.start >> l) * lay.s;
        &tail_work[start..start + lay.own * lay.s]
    } else {
        &mem.x[lay.own_range()]
    }
}

/// Level `l >= 1`: `x_l = V b_l` (the serial `Cycle::vcycle`), on the slab while
/// `l < gathered`, else the gathered levels' serial V-cycle on every slab.
fn vcycle<R: Real, L: Links<R>, const D: usize>(
    plan: &Plan<D>,
    links: &mut L,
    l: usize,
    mems: &mut [Mem<'_, R>],
    (cycle, ops, tail_work): (&Cycle<R, D>, &[R], &mut [R]),
) {
    let lay = plan.layer(l);
    if l == plan.gathered {
        let ng = cycle.levels.n[1];
        links.gather(&mems[l - 1].b[lay.own_range()], &mut tail_work[ng..2 * ng]);
        cycle.vcycle(&Serial, ops, 1, tail_work);
        return;
    }
    let (p, own) = (lay.padded(), lay.own_range());
    let w = cycle.omega_c;
    let coarse_lay = plan.layer(l + 1);
    let sc = strides(coarse_lay.cells);
    {
        let here = &mut mems[l - 1];
        let (b, d) = (&here.b[own.clone()], &here.op[own.clone()]);
        for (i, x) in here.x[own.clone()].iter_mut().enumerate() {
            *x = w * b[i] / d[i];
        }
        swap_halos(links, &lay, here.x);
        view_op(&lay, plan.periodic, here.op).residual_lines(
            &here.b[lay.view()],
            &here.x[lay.view()],
            lay.first_line(),
            here.t,
        );
    }
    {
        let (here, deeper) = mems.split_at_mut(l);
        let bc = &mut deeper[0].b[coarse_lay.own_range()];
        bc.fill(R::ZERO);
        restrict(lay.cells, &sc, &here[l - 1].t[..], bc);
    }
    vcycle(plan, links, l + 1, mems, (cycle, ops, &mut *tail_work));
    let (here, deeper) = mems.split_at_mut(l);
    let here = &mut here[l - 1];
    let coarse = own_solution(plan, l + 1, &deeper[0], tail_work);
    prolong(lay.cells, &sc, coarse, &mut here.x[own.clone()]);
    swap_halos(links, &lay, here.x);
    view_op(&lay, plan.periodic, here.op).residual_lines(
        &here.b[lay.view()],
        &here.x[lay.view()],
        lay.first_line(),
        here.t,
    );
    let (t, d) = (&here.t[..], &here.op[..p]);
    for (i, x) in here.x[own.clone()].iter_mut().enumerate() {
        *x += w * t[i] / d[own.start + i];
    }
}
