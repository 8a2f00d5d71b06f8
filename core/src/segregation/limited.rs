//! Limited second-order carried transport (issue 8; model.md 5.7): phihat moved on the flow's
//! face mass fluxes with a limited linear face value instead of the donor cell's value.
//!
//! The donor rule of [`Segregation::carry_mass_fluxes`] moves `F phihat_donor` per face: first
//! order, with a numerical diffusion `~ |u| h (1 - nu) / 2` that in a rotating drum is the only
//! remixing (docs/tumbler.md). Here each face `f` leaving donor cell `i` along axis `a` moves
//! `F_f qf` of the tracked phase and `F_f (1 - qf)` of the other one, with the
//! MUSCL-Hancock face value (van Leer 1979; the half-step predictor includes the transverse
//! terms, so a uniform diagonal flow is second order as well)
//!
//! ```text
//! qf = qhat_i + theta_i (clamp(qhat_i + d_f, lo_i, hi_i) - qhat_i),
//! d_f = ( +-sigma_a,i - sum_b nu_b,i sigma_b,i ) / 2,
//! ```
//!
//! clamped once more into `[lo_i, hi_i]` after the scaling: `sigma_b,i` is the van Leer slope
//! of `qhat` along `b` (an undivided difference), `nu_b,i = (F_low + F_high) / (2 c_i)` the
//! cell's Courant number along `b` from its two face amounts (in `[-1, 1]`), `lo_i`, `hi_i`
//! the smallest and largest `qhat` of the cell and its face neighbours, and `theta_i` in
//! `[0, 1]` the cell's bounds limiter below. A slope is 0 next to a box side that is not
//! periodic, next to an empty cell (`c <= vacuum`) and, on cut cells, in every cell that is
//! cut, solid or part of a merge group (those cells take the donor rule, as do faces through
//! the box's sides).
//!
//! **Bounds by construction.** Each receiver gets `F_f qf >= 0` and `F_f (1 - qf) >= 0`
//! (`qf` lies in `[lo_i, hi_i]`, a range of stored `qhat` values in `[0, 1]`, by the final
//! `max`/`min`). A donor `i` with tracked content `q` and untracked `r = c - q` keeps
//! `q - out_q` and `r - out_r`, where `out_q = sum_out F_f qf` and `out_r = sum_out F_f (1 - qf)`
//! are the rounded sums of exactly the products its receivers get. In exact arithmetic, with
//! `K = c - O >= 0` (the flow's donor limiter) and `Dv = sum_out F_f (qf - qhat)`, the kept
//! amounts are `K qhat - theta Dv` and `K (1 - qhat) + theta Dv`, so
//! `theta = min(1, K qhat / Dv)` (`Dv > 0`) or `min(1, K (1 - qhat) / -Dv)` (`Dv < 0`) keeps
//! both non-negative. Floating point is then settled by a check on the computed numbers
//! themselves: the cell takes the limited face values only if `out_q <= q` and `out_r <= r`
//! as floats, and then `fl(q - out_q) >= 0` and `fl(r - out_r) >= 0` exactly (a rounded
//! difference has the sign of the exact one). Otherwise (the limiter's own bound met to the
//! last bit, `K = 0`, an empty or a cut cell) the cell takes the donor rule with its proof
//! ([`super::carried`]): it keeps `q keep`, `r keep`, `keep = (c - O) / c`, and sends `qhat`.
//! No margin and no clipping: every new `q` and `r` is a sum of non-negative floats, and
//! `c' = q + r >= q`. Each phase's mass is conserved to round-off (the donor loses the
//! rounded sum of what its receivers gain).
//!
//! **Scratch, no new memory.** The slopes live in arrays that the carried transport does not
//! otherwise need during the call: axis 0 in the compensated carry (folded into `q` first and
//! zero again at the end), axes 1.. in the face coefficients `k` (the donor rule already uses
//! `k[0]`; call `prepare` after, as for the donor rule), `theta` in `rhs` once the outflow `O`
//! is used. So the solver's size is unchanged (the firmware's soft sensor does not use this
//! path: its own-velocity transport stays the donor rule).

use super::carried::{guard, guard_total, Discharge, MassFluxes};
use super::Segregation;
use crate::boundary::Boundary;
use crate::geometry::CutCells;
use crate::real::Real;
use crate::sum::InOrder;
use serde::{Deserialize, Serialize};

/// The face value of phihat in the carried transport of a coupled run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Transport {
    /// The donor cell's phihat (first order; [`Segregation::carry_mass_fluxes`]).
    #[default]
    Donor,
    /// A limited linear (MUSCL-Hancock, van Leer) face value, bounded by construction
    /// (second order where phihat is smooth; module `limited`).
    Limited,
}

impl Transport {
    /// All choices, in the order they are documented.
    pub const ALL: [Transport; 2] = [Transport::Donor, Transport::Limited];
    /// Lower-case name, as in scene files.
    pub fn name(self) -> &'static str {
        match self {
            Transport::Donor => "donor",
            Transport::Limited => "limited",
        }
    }
}

/// The van Leer (harmonic) limited slope of two one-sided differences: 0 at an extremum,
/// at most twice the smaller difference, so `qhat +- sigma / 2` stays between the neighbours.
#[inline(always)]
fn van_leer<R: Real>(dl: R, dr: R) -> R {
    let p = dl * dr;
    if p > R::ZERO {
        (p + p) / (dl + dr)
    } else {
        R::ZERO
    }
}

/// What the face values need besides the solver's arrays: the step's fluxes, the grid's
/// layout and the cut cells (if any).
struct Ctx<'a, R: Real, const D: usize, const N: usize> {
    fx: MassFluxes<'a, R, D, N>,
    geo: Option<&'a CutCells<R, D, N>>,
    cells: [usize; D],
    stride: [usize; D],
    periodic: [bool; D],
    vacuum: R,
}

impl<R: Real, const D: usize, const N: usize> Ctx<'_, R, D, N> {
    /// The neighbour of `i` along `a` on the high or low side (wrapping on periodic axes),
    /// `None` at a box side.
    #[inline(always)]
    fn neighbour(&self, i: usize, a: usize, high: bool) -> Option<usize> {
        let (s, n) = (self.stride[a], self.cells[a]);
        let ca = (i / s) % n;
        if high {
            if ca + 1 < n {
                Some(i + s)
            } else if self.periodic[a] {
                Some(i - (n - 1) * s)
            } else {
                None
            }
        } else if ca > 0 {
            Some(i - s)
        } else if self.periodic[a] {
            Some(i + (n - 1) * s)
        } else {
            None
        }
    }

    /// The signed amount through the low and the high face of `i` along `a` (positive
    /// towards +a), as [`MassFluxes`] stores them.
    #[inline(always)]
    fn face_amounts(&self, i: usize, a: usize) -> (R, R) {
        let (s, n) = (self.stride[a], self.cells[a]);
        let ca = (i / s) % n;
        let low = if ca > 0 {
            self.fx.faces[a][i - s]
        } else if self.periodic[a] {
            self.fx.faces[a][i + (n - 1) * s]
        } else {
            self.fx.low[a][i]
        };
        (low, self.fx.faces[a][i])
    }

    /// A cell whose phihat may serve a slope or a local bound: holds grains, not solid.
    #[inline(always)]
    fn usable(&self, c: &[R; N], j: usize) -> bool {
        c[j] > self.vacuum && self.geo.is_none_or(|g| !g.is_solid(j))
    }

    /// A cell that may take the limited face value: holds grains and, on cut cells, is a
    /// full cell of its own (not cut, not merged, no cells merged into it).
    #[inline(always)]
    fn eligible(&self, c: &[R; N], i: usize) -> bool {
        c[i] > self.vacuum
            && self.geo.is_none_or(|g| {
                !g.is_solid(i) && !g.is_cut(i) && !g.is_merged(i) && !g.has_merged(i)
            })
    }
}

impl<R: Real, const D: usize, const N: usize> Segregation<R, D, N> {
    /// Chooses the face value of the carried transport of coupled runs (default
    /// [`Transport::Donor`]; reset by [`Self::setup`], so call it after).
    pub fn set_transport(&mut self, t: Transport) {
        self.transport = t;
    }

    /// The face value of the carried transport ([`Self::set_transport`]).
    pub fn transport(&self) -> Transport {
        self.transport
    }

    /// The slope of cell `i` along `a` (scratch during the limited transport).
    #[inline(always)]
    fn slope(&self, a: usize, i: usize) -> R {
        if a == 0 {
            self.carry[i]
        } else {
            self.k[a][i]
        }
    }

    /// The limited face value of donor `i` on its face along `a` (high or low side), with
    /// bounds factor `theta` (module docs). `qhat` of the donor at a box side or if
    /// `theta == 0`.
    #[inline(always)]
    fn face_value(&self, ctx: &Ctx<'_, R, D, N>, i: usize, a: usize, high: bool, theta: R) -> R {
        let qhat = self.flux[i];
        if theta == R::ZERO || ctx.neighbour(i, a, high).is_none() {
            return qhat;
        }
        let c = self.c[i];
        let mut t = R::ZERO;
        let (mut lo, mut hi) = (qhat, qhat);
        for b in 0..D {
            let (fl, fh) = ctx.face_amounts(i, b);
            let nu = ((fl + fh) / (c + c)).max(R::NEG_ONE).min(R::ONE);
            t += nu * self.slope(b, i);
            for side in [false, true] {
                if let Some(j) = ctx.neighbour(i, b, side) {
                    if ctx.usable(&self.c, j) {
                        lo = lo.min(self.flux[j]);
                        hi = hi.max(self.flux[j]);
                    }
                }
            }
        }
        let sa = self.slope(a, i);
        let d = (if high { sa } else { -sa } - t) * R::HALF;
        let full = (qhat + d).max(lo).min(hi) - qhat;
        (qhat + theta * full).max(lo).min(hi)
    }

    /// The amount leaving `i` through its face along `a` on the given side (0 if none).
    #[inline(always)]
    fn outgoing(ctx: &Ctx<'_, R, D, N>, i: usize, a: usize, high: bool) -> R {
        let (fl, fh) = ctx.face_amounts(i, a);
        if high {
            fh.max(R::ZERO)
        } else {
            (-fl).max(R::ZERO)
        }
    }

    /// [`Self::carry_mass_fluxes`] (`geo = None`) and [`Self::carry_mass_fluxes_embedded`]
    /// with the limited face value (module docs). Same contract and the same passes in the
    /// same fixed order as the donor rule.
    pub(super) fn carry_limited(
        &mut self,
        fx: MassFluxes<'_, R, D, N>,
        geo: Option<&CutCells<R, D, N>>,
        sums: &mut impl InOrder<R>,
    ) -> Discharge<R, D> {
        let n = self.grid.len();
        let grid = self.grid;
        let vol = grid.cell_volume();
        let master = |i: usize| geo.map_or(i, |g| g.master(i));
        let ctx = Ctx {
            fx,
            geo,
            cells: grid.cells(),
            stride: core::array::from_fn(|a| grid.stride(a)),
            periodic: core::array::from_fn(|a| self.bc[a][0] == Boundary::Periodic),
            vacuum: self.cfg.vacuum,
        };
        let mut out = Discharge::none();
        // Pass A: O_i, the amount leaving each cell (gathered at the masters), into `rhs`.
        self.rhs[..n].fill(R::ZERO);
        for i in 0..n {
            let mut o = R::ZERO;
            for a in 0..D {
                o += Self::outgoing(&ctx, i, a, false);
                o += Self::outgoing(&ctx, i, a, true);
            }
            self.rhs[i] = o;
        }
        if let Some(g) = geo {
            self.gather_outflow_at_masters(g);
        }
        // Pass B1: the tracked fraction into [0, c] (round-off guard, as the donor rule), the
        // carry folded in, qhat of every cell into `flux`, what the guard moved into `carry`
        // (summed by `guard_sum` over the counted cells, then overwritten by pass S).
        let mut any = false;
        for i in 0..n {
            let c = self.c[i];
            let (q, moved) = guard(self.q[i] + self.carry[i], c);
            any |= moved != R::ZERO;
            self.carry[i] = moved;
            self.q[i] = q;
            self.flux[i] = if c > R::ZERO {
                (q / c).min(R::ONE)
            } else {
                R::ZERO
            };
        }
        let counted = self.tally.0.min(n)..self.tally.1.min(n);
        out.guarded = guard_total(sums, &self.carry[counted], any) * vol;
        // Pass S: van Leer slopes of qhat, axis 0 into `carry`, axis a into `k[a]`.
        for a in 0..D {
            for i in 0..n {
                let mut sigma = R::ZERO;
                if ctx.eligible(&self.c, i) {
                    if let (Some(l), Some(r)) =
                        (ctx.neighbour(i, a, false), ctx.neighbour(i, a, true))
                    {
                        if ctx.usable(&self.c, l) && ctx.usable(&self.c, r) {
                            let qh = self.flux[i];
                            sigma = van_leer(qh - self.flux[l], self.flux[r] - qh);
                        }
                    }
                }
                if a == 0 {
                    self.carry[i] = sigma;
                } else {
                    self.k[a][i] = sigma;
                }
            }
        }
        // Pass B2: theta of each cell into `rhs` (after reading its O); each master keeps
        // its tracked content in `q` and the untracked one in `k[0]`.
        for i in 0..n {
            let c = self.c[i];
            let q = self.q[i];
            let o = self.rhs[i];
            self.rhs[i] = R::ZERO;
            if let Some(g) = geo {
                if g.master(i) != i || g.is_solid(i) {
                    self.q[i] = R::ZERO;
                    self.k[0][i] = R::ZERO;
                    continue;
                }
            }
            let r = c - q;
            if ctx.eligible(&self.c, i) {
                if let Some((qk, rk, theta)) = self.limited_keep(&ctx, i, q, r, o) {
                    self.q[i] = qk;
                    self.k[0][i] = rk;
                    self.rhs[i] = theta;
                    continue;
                }
            }
            // The donor rule for this cell (group content `V_g c` on cut cells).
            let vg = geo.map_or(R::ONE, |g| g.group_volume(i));
            let content = vg * c;
            let keep = if c > R::ZERO {
                ((content - o) / content).max(R::ZERO)
            } else {
                R::ONE
            };
            self.q[i] = vg * q * keep;
            self.k[0][i] = vg * r * keep;
        }
        // Pass C: what each cell receives, face by face in the donor rule's order.
        let small = self.cfg.phase == super::Phase::Small;
        for a in 0..D {
            let fb = grid.face_blocks(a);
            let s = fb.stride;
            let periodic = ctx.periodic[a];
            for b in 0..fb.blocks {
                let l0 = b * fb.block_stride;
                for l in l0..l0 + fb.block_len {
                    let f = fx.faces[a][l];
                    if f > R::ZERO {
                        let qf = self.face_value(&ctx, l, a, true, self.rhs[l]);
                        self.receive_limited(master(l + s), f, qf);
                    } else if f < R::ZERO {
                        let qf = self.face_value(&ctx, l + s, a, false, self.rhs[l + s]);
                        self.receive_limited(master(l), -f, qf);
                    }
                }
            }
            let books = a == D - 1;
            for (last, first) in boundary_pairs(&grid, a) {
                let f = fx.faces[a][last];
                if periodic {
                    if f > R::ZERO {
                        let qf = self.face_value(&ctx, last, a, true, self.rhs[last]);
                        self.receive_limited(master(first), f, qf);
                    } else if f < R::ZERO {
                        let qf = self.face_value(&ctx, first, a, false, self.rhs[first]);
                        self.receive_limited(master(last), -f, qf);
                    }
                    continue;
                }
                if f < R::ZERO {
                    self.receive_limited(master(last), -f, self.inflow_fraction(last));
                }
                if books {
                    let (s, t) = (&mut out.small[a][1], &mut out.total[a][1]);
                    self.book_face(small, last, f, vol, s, t);
                }
            }
            if !periodic {
                for (_, first) in boundary_pairs(&grid, a) {
                    let g = fx.low[a][first];
                    if g > R::ZERO {
                        self.receive_limited(master(first), g, self.inflow_fraction(first));
                    }
                    if books {
                        let (s, t) = (&mut out.small[a][0], &mut out.total[a][0]);
                        self.book_face(small, first, -g, vol, s, t);
                    }
                }
            }
        }
        self.book_sides_along(fx, &mut out, sums);
        // Pass D: content -> fractions at the masters (cut cells), members copy them;
        // c = tracked + untracked; the slope scratch in `carry` back to zero.
        if let Some(g) = geo {
            self.spread_group_content(g);
        }
        for i in 0..n {
            self.c[i] = self.q[i] + self.k[0][i];
            self.carry[i] = R::ZERO;
        }
        self.prepared = false;
        out
    }

    /// The limited keep of an eligible cell `i` (tracked `q`, untracked `r`, outflow `o`):
    /// `Some((q - out_q, r - out_r, theta))` if the floats pass the bounds check of the
    /// module docs, `None` to take the donor rule.
    fn limited_keep(
        &self,
        ctx: &Ctx<'_, R, D, N>,
        i: usize,
        q: R,
        r: R,
        o: R,
    ) -> Option<(R, R, R)> {
        let c = self.c[i];
        let qhat = self.flux[i];
        let k = c - o;
        if k <= R::ZERO {
            return None;
        }
        let mut dv = R::ZERO;
        for a in 0..D {
            for high in [false, true] {
                let f = Self::outgoing(ctx, i, a, high);
                if f > R::ZERO {
                    dv += f * (self.face_value(ctx, i, a, high, R::ONE) - qhat);
                }
            }
        }
        let theta = if dv > R::ZERO {
            (k * qhat / dv).min(R::ONE)
        } else if dv < R::ZERO {
            (k * (R::ONE - qhat) / (-dv)).min(R::ONE)
        } else {
            R::ONE
        };
        if theta <= R::ZERO {
            return None;
        }
        let (mut out_q, mut out_r) = (R::ZERO, R::ZERO);
        for a in 0..D {
            for high in [false, true] {
                let f = Self::outgoing(ctx, i, a, high);
                if f > R::ZERO {
                    let qf = self.face_value(ctx, i, a, high, theta);
                    out_q += f * qf;
                    out_r += f * (R::ONE - qf);
                }
            }
        }
        if out_q <= q && out_r <= r {
            Some((q - out_q, r - out_r, theta))
        } else {
            None
        }
    }

    /// Cell `i` receives `f >= 0` with tracked fraction `qf` in `[0, 1]` (as `receive`).
    #[inline(always)]
    fn receive_limited(&mut self, i: usize, f: R, qf: R) {
        self.q[i] += f * qf;
        self.k[0][i] += f * (R::ONE - qf);
    }
}

/// The `(last, first)` cells of every grid line along `axis`, in the order of
/// [`crate::grid::Grid::for_each_boundary_cell`] (high side).
fn boundary_pairs<R: Real, const D: usize>(
    grid: &crate::grid::Grid<R, D>,
    axis: usize,
) -> impl Iterator<Item = (usize, usize)> {
    let fb = grid.face_blocks(axis);
    let span = fb.block_len;
    (0..fb.blocks).flat_map(move |b| {
        let first = b * fb.block_stride;
        (first..first + fb.stride).map(move |j| (j + span, j))
    })
}
