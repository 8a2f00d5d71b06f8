//! Carried transport: phi moved by the flow's own face mass fluxes (issue 10; model.md 3, 5).
//!
//! In a coupled run the flow moves `c` with conservative, limited face mass fluxes. If the
//! segregation solver transported phi with its own upwind rule it would not see the flow's
//! limiter cuts, and `phi <= c` would break wherever a cut was made. Instead each face carries
//! `F phihat_donor` of the small phase and `F (1 - phihat_donor)` of the large one, where `F`
//! is the flow's applied amount of the face in the step (content units: `dt / h` times the
//! face flux, after the limiters; [`MassFluxes`]) and `phihat = phi / c` of the donor cell (an
//! inflow face takes the inflow's phihat).
//!
//! **Bounds by construction.** Let `O_i <= c_i` be the amount leaving cell `i` over all its
//! faces (the flow's donor limiter guarantees `c_i - O_i >= 0`). The cell keeps the share
//! `s_i = (c_i - O_i) / c_i` in `[0, 1]` of both phases and receives non-negative amounts of
//! each from its donors:
//!
//! ```text
//! phi_i' = s_i phi_i + sum_in F_f phihat_d        >= 0
//! psi_i' = s_i psi_i + sum_in F_f (1 - phihat_d)  >= 0      (psi = c - phi)
//! c_i'   = phi_i' + psi_i'                        >= phi_i'
//! ```
//!
//! Every term is a product or sum of non-negative numbers, and rounding is monotone, so both
//! inequalities hold exactly in floating point, not only in exact arithmetic: `phi >= 0` and
//! `psi >= 0` are sums of non-negative terms, and `fl(phi + psi) >= phi` because `psi >= 0`.
//! In exact arithmetic `c_i'` equals the flow's new `c` (same `O_i`, same inflows); in floating
//! point the two differ by round-off (the flow adds the fluxes one by one), so the segregation
//! solver keeps its own `c' = phi' + psi'` (see [`crate::flow::coupled`]). A donor loses
//! `phi_i (1 - s_i) = phihat_i O_i` and its receivers gain `sum F_f phihat_i`: the same amount
//! up to round-off, so each phase's mass is conserved to round-off (plus what leaves the box,
//! which is returned).
//!
//! **No Courant limit of its own.** Nothing above uses the length of the step or the
//! velocity: the only condition is `O_i <= c_i`, which the flow's donor limiter enforces on
//! its final fluxes at any Courant number. So a coupled step is limited by the flow and by
//! the percolation stage alone ([`Segregation::stable_dt_percolation`],
//! `Coupled::stable_dt`), not by the segregation's transport term `|u| / h`.

use super::{Phase, Segregation, Transport};
use crate::boundary::Boundary;
use crate::fork::Call;
use crate::geometry::CutCells;
use crate::hot::{Baseline, Isa};
use crate::real::Real;
use crate::sum::{InOrder, Whole};

/// The face mass fluxes one flow step applied (time-integrated, in content units: the change
/// of `c` they make in a cell), as the flow stores them ([`crate::flow::Flow::mass_fluxes`]).
#[derive(Clone, Copy, Debug)]
pub struct MassFluxes<'a, R, const D: usize, const N: usize> {
    /// Per axis, at the left cell `l` of each face: the amount moved from `l` to its right
    /// neighbour (negative: from the right to `l`). At the last cell of a line: its high
    /// boundary face (positive = out of the box), or, on a periodic axis, the wrap face from
    /// the last cell to the first.
    pub faces: &'a [[R; N]; D],
    /// Per axis, at the first cell of each line: the amount through the low boundary face,
    /// positive = into the box (0 on periodic axes and closed walls).
    pub low: &'a [[R; N]; D],
    /// Per axis `[low, high]`: whether the side's faces may move mass (the flow's inflow,
    /// outflow and wall openings). The amounts through a closed side must be zero. A closed
    /// side of an axis other than the last (a side that a cut into rows crosses) is not
    /// booked (`Segregation::book_sides_along`): the slabs of rows take part in no sum
    /// for it.
    pub open: [[bool; 2]; D],
}

/// What left the box through each side `[axis][low, high]` in one carried transport
/// (volume: content times cell volume; negative if it came in).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Discharge<R, const D: usize> {
    /// Small grains.
    pub small: [[R; 2]; D],
    /// All grains.
    pub total: [[R; 2]; D],
    /// Round-off guard: tracked-phase volume added to lift a cell that the percolation
    /// stage left outside `[0, c]` by round-off back into it before transport (0 if the
    /// percolation kept the bounds exactly, which is what the tests assert).
    pub guarded: R,
}

impl<R: Real, const D: usize> Discharge<R, D> {
    /// Nothing has left (the start of every carried transport's tally).
    pub fn none() -> Self {
        Self {
            small: [[R::ZERO; 2]; D],
            total: [[R::ZERO; 2]; D],
            guarded: R::ZERO,
        }
    }
}

impl<R: Real, const D: usize, const N: usize> Segregation<R, D, N> {
    /// Sets temperature and velocity of cell `i` only (c and phi are carried: see
    /// [`Self::carry_mass_fluxes`]); call [`Self::prepare`] after.
    pub fn set_flow_state(&mut self, i: usize, t: R, u: [R; D]) {
        self.temp[i] = t;
        for (a, ua) in u.iter().enumerate() {
            self.u[a][i] = *ua;
        }
        self.prepared = false;
    }

    /// Pass A of the carried transport (box and cut cells alike): `O_i`, the amount the face
    /// mass fluxes take out of each cell (through its faces and open box sides), into `rhs`.
    fn outflow_into_rhs(&mut self, fx: MassFluxes<'_, R, D, N>) {
        let n = self.grid.len();
        let grid = self.grid;
        self.rhs[..n].fill(R::ZERO);
        for a in 0..D {
            let fb = grid.face_blocks(a);
            let s = fb.stride;
            let periodic = self.bc[a][0] == Boundary::Periodic;
            for b in 0..fb.blocks {
                let l0 = b * fb.block_stride;
                for l in l0..l0 + fb.block_len {
                    let f = fx.faces[a][l];
                    if f > R::ZERO {
                        self.rhs[l] += f;
                    } else if f < R::ZERO {
                        self.rhs[l + s] -= f;
                    }
                }
            }
            let rhs = &mut self.rhs;
            grid.for_each_boundary_cell(a, true, |last, first| {
                let f = fx.faces[a][last];
                if f > R::ZERO {
                    rhs[last] += f;
                } else if f < R::ZERO && periodic {
                    rhs[first] -= f;
                }
            });
            if !periodic {
                grid.for_each_boundary_cell(a, false, |first, _| {
                    let g = fx.low[a][first];
                    if g < R::ZERO {
                        rhs[first] -= g;
                    }
                });
            }
        }
    }

    /// Moves both phases with the flow's face mass fluxes of one step (module docs), sets
    /// `c` to the carried `phi + psi`, and returns what left through each side. Does not
    /// advance the clock (the percolation stage does: [`Self::step_percolation`]). The face
    /// coefficients are used as scratch: call [`Self::prepare`] before the next step.
    pub fn carry_mass_fluxes(&mut self, fx: MassFluxes<'_, R, D, N>) -> Discharge<R, D> {
        self.carry_mass_fluxes_on::<Baseline>(fx)
    }

    /// [`Self::carry_mass_fluxes`] with its passes over the cells run by `I` (the same bits
    /// for every `I`).
    pub fn carry_mass_fluxes_on<I: Isa>(&mut self, fx: MassFluxes<'_, R, D, N>) -> Discharge<R, D> {
        self.carry_mass_fluxes_summing::<I>(fx, &mut Whole)
    }

    /// [`Self::carry_mass_fluxes_on`] with its sums in cell order left to `sums`: the
    /// guard's sum over the counted cells (all of them, or a subdomain's owned ones:
    /// [`Self::prepare_owned_with`]) and the books of the open sides along the last axis
    /// (`Self::book_sides_along`). On the whole grid ([`Whole`]) they are the serial
    /// loops; a slab continues the sums of the slabs below (`crate::flow::slab::Slab`).
    pub fn carry_mass_fluxes_summing<I: Isa>(
        &mut self,
        fx: MassFluxes<'_, R, D, N>,
        sums: &mut impl InOrder<R>,
    ) -> Discharge<R, D> {
        if self.transport == Transport::Limited {
            return self.carry_limited(fx, None, sums);
        }
        let n = self.grid.len();
        let grid = self.grid;
        let vol = grid.cell_volume();
        let mut out = Discharge::none();
        // Pass A: O_i, the amount leaving each cell, into `rhs`.
        self.outflow_into_rhs(fx);
        // Pass B: each cell keeps the share s_i of both phases. Tracked fraction q (phi or
        // psi) stays in `q`, the untracked one `c - q` goes to `k[0]` (scratch), the donor's
        // qhat to `flux`.
        // One branch-free loop (selects; it vectorises), then the guard's sum in cell order.
        let any = I::run(Call(
            #[inline(always)]
            || {
                keep_shares(
                    &mut self.q[..n],
                    &mut self.carry[..n],
                    &self.c[..n],
                    &mut self.rhs[..n],
                    &mut self.flux[..n],
                    &mut self.k[0][..n],
                )
            },
        ));
        let counted = self.tally.0.min(n)..self.tally.1.min(n);
        out.guarded = guard_total(sums, &self.rhs[counted], any) * vol;
        // Pass C: what each cell receives, in the same face order.
        self.receive_faces(fx, &mut out, |i| i);
        self.book_sides_along(fx, &mut out, sums);
        // Pass D: c = tracked + untracked.
        for i in 0..n {
            self.c[i] = self.q[i] + self.k[0][i];
        }
        self.prepared = false;
        out
    }

    /// Pass C of the carried transport: every receiving cell gets, face by face in a fixed
    /// order, `F qhat_donor` and `F (1 - qhat_donor)` (at `to(cell)`: the cell itself in a
    /// box, its merge group's master on cut cells); what crosses the box's open sides across
    /// the last axis is booked into `out` (the sides along it: [`Self::book_sides_along`]).
    fn receive_faces(
        &mut self,
        fx: MassFluxes<'_, R, D, N>,
        out: &mut Discharge<R, D>,
        to: impl Fn(usize) -> usize,
    ) {
        let grid = self.grid;
        let small = self.cfg.phase == Phase::Small;
        let vol = grid.cell_volume();
        for a in 0..D {
            let fb = grid.face_blocks(a);
            let s = fb.stride;
            let periodic = self.bc[a][0] == Boundary::Periodic;
            for b in 0..fb.blocks {
                let l0 = b * fb.block_stride;
                for l in l0..l0 + fb.block_len {
                    let f = fx.faces[a][l];
                    if f > R::ZERO {
                        self.receive(to(l + s), f, self.flux[l]);
                    } else if f < R::ZERO {
                        self.receive(to(l), -f, self.flux[l + s]);
                    }
                }
            }
            let books = a == D - 1;
            grid.for_each_boundary_cell(a, true, |last, first| {
                let f = fx.faces[a][last];
                if periodic {
                    if f > R::ZERO {
                        self.receive(to(first), f, self.flux[last]);
                    } else if f < R::ZERO {
                        self.receive(to(last), -f, self.flux[first]);
                    }
                    return;
                }
                if f < R::ZERO {
                    self.receive(to(last), -f, self.inflow_fraction(last));
                }
                if books {
                    self.book_face(
                        small,
                        last,
                        f,
                        vol,
                        &mut out.small[a][1],
                        &mut out.total[a][1],
                    );
                }
            });
            if !periodic {
                grid.for_each_boundary_cell(a, false, |first, _| {
                    let g = fx.low[a][first];
                    if g > R::ZERO {
                        self.receive(to(first), g, self.inflow_fraction(first));
                    }
                    if books {
                        self.book_face(
                            small,
                            first,
                            -g,
                            vol,
                            &mut out.small[a][0],
                            &mut out.total[a][0],
                        );
                    }
                });
            }
        }
    }

    /// Books the amount `f` that leaves the box (negative: enters) through a boundary face of
    /// cell `i` into the running sums of its side: all grains `f`, the small phase at the
    /// donor's fraction (the cell's `qhat`, or the inflow's for an amount that enters). Read
    /// before pass D (`c` and `qhat` still the step's own). A zero amount books nothing.
    #[inline(always)]
    pub(super) fn book_face(&self, small: bool, i: usize, f: R, vol: R, s: &mut R, t: &mut R) {
        if f > R::ZERO {
            *s += small_part(small, f, self.flux[i]) * vol;
            *t += f * vol;
        } else if f < R::ZERO {
            *s -= small_part(small, -f, self.inflow_fraction(i)) * vol;
            *t += f * vol;
        }
    }

    /// The books of the open sides along the last axis (`fx.open`; the sides across it are
    /// booked face by face in pass C): for each, the small phase and all grains through the
    /// faces of the counted cells, in cell order, as sums continued across subdomains
    /// (`sums`, one chain of both numbers per side), so that every slab of rows holds the
    /// serial books of the whole side. Only open sides take part: a closed scene pays
    /// nothing.
    pub(super) fn book_sides_along(
        &self,
        fx: MassFluxes<'_, R, D, N>,
        out: &mut Discharge<R, D>,
        sums: &mut impl InOrder<R>,
    ) {
        let grid = self.grid;
        let n = grid.len();
        let small = self.cfg.phase == Phase::Small;
        let vol = grid.cell_volume();
        let counted = self.tally.0.min(n)..self.tally.1.min(n);
        for a in 0..D - 1 {
            for side in 0..2 {
                if !fx.open[a][side] || self.bc[a][side] == Boundary::Periodic {
                    continue;
                }
                // the amount leaving through cell i's face on this side
                let leaving = |i: usize| {
                    if side == 1 {
                        fx.faces[a][i]
                    } else {
                        -fx.low[a][i]
                    }
                };
                let [s, t] = sums.sums_in_order([R::ZERO; 2], |[mut s, mut t]| {
                    grid.for_each_boundary_cell(a, side == 1, |i, _| {
                        if counted.contains(&i) {
                            self.book_face(small, i, leaving(i), vol, &mut s, &mut t);
                        }
                    });
                    [s, t]
                });
                out.small[a][side] = s;
                out.total[a][side] = t;
            }
        }
    }

    /// Cell `i` receives `f >= 0` of donor fraction `qhat` in `[0, 1]`.
    #[inline(always)]
    fn receive(&mut self, i: usize, f: R, qhat: R) {
        self.q[i] += f * qhat;
        self.k[0][i] += f * (R::ONE - qhat);
    }

    /// Tracked fraction `q / c` of the inflow state at boundary cell `i` (its Dirichlet phi
    /// over the cell's c, as the solver's own inflow faces read it), in `[0, 1]`.
    pub(super) fn inflow_fraction(&self, i: usize) -> R {
        let c = self.c[i];
        if c > R::ZERO {
            (self.inflow_tracked(i) / c).max(R::ZERO).min(R::ONE)
        } else {
            R::ZERO
        }
    }
}

/// The tracked amount `q` of a cell brought into `[0, c]` (round-off of the previous stage)
/// and the amount that moved: `-q`, `c - q`, or 0 where `q` was in range (a guarded cell
/// moves a nonzero amount).
#[inline(always)]
pub(super) fn guard<R: Real>(q: R, c: R) -> (R, R) {
    if q < R::ZERO {
        (R::ZERO, -q)
    } else if q > c {
        (c, c - q)
    } else {
        (q, R::ZERO)
    }
}

/// The guard's sum of one carried transport: the nonzero amounts moved in the counted cells
/// (`moved`), in cell order, from 0. On the whole grid none if `any` is false (no cell
/// moved); a subdomain takes part in the sum across the others whatever it moved.
pub(super) fn guard_total<R: Real>(sums: &mut impl InOrder<R>, moved: &[R], any: bool) -> R {
    if sums.whole() && !any {
        return R::ZERO;
    }
    sums.sum_in_order(R::ZERO, |mut sum| {
        add_nonzero(&mut sum, moved);
        sum
    })
}

/// Adds the nonzero values of `moved` to `sum`, in order: the guard's sum of the carried
/// transport (a zero adds nothing, so a subdomain may continue the sum of others).
fn add_nonzero<R: Real>(sum: &mut R, moved: &[R]) {
    for &m in moved {
        if m != R::ZERO {
            *sum += m;
        }
    }
}

/// Pass B of [`Segregation::carry_mass_fluxes`] over the cells: the tracked `q + carry`
/// guarded into `[0, c]` ([`guard`]), the donor fraction `qhat` into `flux`, the kept
/// shares of both phases into `q` and `untracked`, carry cleared. What the guard moved goes
/// to `rhs` in the cell's place (the outflow `O_i` is read there first; [`guard`]), so that
/// the caller sums it in cell order ([`add_nonzero`]). Selects only, so the
/// loop vectorises: its two divisions per cell were the cost of the pass. Returns whether any
/// cell was guarded. Inlined into its hot loop (`carry_mass_fluxes_on`).
#[inline(always)]
fn keep_shares<R: Real>(
    q: &mut [R],
    carry: &mut [R],
    c: &[R],
    rhs: &mut [R],
    flux: &mut [R],
    untracked: &mut [R],
) -> bool {
    let n = q.len();
    let (carry, c, rhs) = (&mut carry[..n], &c[..n], &mut rhs[..n]);
    let (flux, untracked) = (&mut flux[..n], &mut untracked[..n]);
    let mut any = false;
    for i in 0..n {
        let ci = c[i];
        let (qi, moved) = guard(q[i] + carry[i], ci);
        any |= moved != R::ZERO;
        carry[i] = R::ZERO;
        let r = ci - qi;
        let (qhat, keep) = if ci > R::ZERO {
            ((qi / ci).min(R::ONE), ((ci - rhs[i]) / ci).max(R::ZERO))
        } else {
            (R::ZERO, R::ONE)
        };
        flux[i] = qhat;
        q[i] = qi * keep;
        untracked[i] = r * keep;
        rhs[i] = moved;
    }
    any
}

/// The small-phase part of an amount `f >= 0` with tracked fraction `qhat` (the tracked phase
/// is the small one if `small`, else the large one).
#[inline(always)]
pub(super) fn small_part<R: Real>(small: bool, f: R, qhat: R) -> R {
    let q = f * qhat;
    if small {
        q
    } else {
        f * (R::ONE - qhat)
    }
}

impl<R: Real, const D: usize, const N: usize> Segregation<R, D, N> {
    /// [`Self::carry_mass_fluxes`] on cut cells. The flow's face amounts are then content per
    /// full cell (aperture-weighted; zero inside a merge group), and a merge group is one
    /// control volume of volume `V_g` ([`CutCells::group_volume`]): the group keeps the share
    /// `(V_g c - outflow_g) / (V_g c)` of both phases (in `[0, 1]` by the flow's donor limiter
    /// on groups) and receives the non-negative amounts `F qhat_donor`, `F (1 - qhat_donor)`,
    /// all in content units at its master; each phase's content is then divided by `V_g` and
    /// copied to the members. Both phases stay non-negative with the same argument as in the
    /// box, so `0 <= phi <= c` holds exactly; with `V_g = 1` and no groups the update is the
    /// box one. Expects group-uniform fields (as [`Self::prepare_embedded`] leaves them).
    pub fn carry_mass_fluxes_embedded(
        &mut self,
        fx: MassFluxes<'_, R, D, N>,
        geo: &CutCells<R, D, N>,
    ) -> Discharge<R, D> {
        self.carry_mass_fluxes_embedded_summing(fx, geo, &mut Whole)
    }

    /// [`Self::carry_mass_fluxes_embedded`] with its sums in cell order left to `sums`, as
    /// [`Self::carry_mass_fluxes_summing`] does it in a box (a slab continues the sums of
    /// the slabs below).
    pub fn carry_mass_fluxes_embedded_summing(
        &mut self,
        fx: MassFluxes<'_, R, D, N>,
        geo: &CutCells<R, D, N>,
        sums: &mut impl InOrder<R>,
    ) -> Discharge<R, D> {
        if self.transport == Transport::Limited {
            return self.carry_limited(fx, Some(geo), sums);
        }
        let n = self.grid.len();
        let grid = self.grid;
        let vol = grid.cell_volume();
        let mut out = Discharge::none();
        // Outflow of every cell (content per full cell), gathered at the masters below.
        self.outflow_into_rhs(fx);
        self.gather_outflow_at_masters(geo);
        // Keep the share of each group, as content at the master; members hold nothing
        // until the end. `flux` holds every cell's tracked fraction (uniform in a group),
        // `rhs` what the guard moved in the cell's place once its outflow is read.
        let mut any = false;
        for i in 0..n {
            let c = self.c[i];
            let (q, moved) = guard(self.q[i], c);
            any |= moved != R::ZERO;
            self.flux[i] = if c > R::ZERO {
                (q / c).min(R::ONE)
            } else {
                R::ZERO
            };
            if geo.master(i) != i || geo.is_solid(i) {
                self.q[i] = R::ZERO;
                self.k[0][i] = R::ZERO;
                self.rhs[i] = moved;
                continue;
            }
            let vg = geo.group_volume(i);
            let content = vg * c;
            let keep = if c > R::ZERO {
                ((content - self.rhs[i]) / content).max(R::ZERO)
            } else {
                R::ONE
            };
            self.q[i] = vg * q * keep;
            self.k[0][i] = vg * (c - q) * keep;
            self.rhs[i] = moved;
        }
        let counted = self.tally.0.min(n)..self.tally.1.min(n);
        out.guarded = guard_total(sums, &self.rhs[counted], any) * vol;
        self.receive_faces(fx, &mut out, |i| geo.master(i));
        self.book_sides_along(fx, &mut out, sums);
        self.spread_group_content(geo);
        for i in 0..n {
            self.c[i] = self.q[i] + self.k[0][i];
        }
        self.prepared = false;
        out
    }

    /// Cut cells: each member's outflow (in `rhs`) added to its merge group's master, which
    /// keeps the group's share. Shared by the donor and the limited rule.
    pub(super) fn gather_outflow_at_masters(&mut self, geo: &CutCells<R, D, N>) {
        for i in 0..self.grid.len() {
            let m = geo.master(i);
            if m != i {
                self.rhs[m] += self.rhs[i];
            }
        }
    }

    /// Cut cells, after a carried transport: the tracked (`q`) and untracked (`k[0]`)
    /// content each master kept for its merge group becomes fractions (over the group
    /// volume), and the members copy their master's. Shared by the donor and the limited rule.
    pub(super) fn spread_group_content(&mut self, geo: &CutCells<R, D, N>) {
        let n = self.grid.len();
        for i in 0..n {
            if geo.master(i) == i && !geo.is_solid(i) {
                let vg = geo.group_volume(i);
                self.q[i] = self.q[i] / vg;
                self.k[0][i] = self.k[0][i] / vg;
            }
        }
        for i in 0..n {
            let m = geo.master(i);
            if m != i {
                self.q[i] = self.q[m];
                self.k[0][i] = self.k[0][m];
            }
        }
    }
}

/// Which side a boundary face of [`Segregation::carry_own_velocity`] is on, and how open it is.
#[inline(always)]
fn outward<R: Real>(high: bool, u: R) -> R {
    if high {
        u
    } else {
        -u
    }
}

impl<R: Real, const D: usize, const N: usize> Segregation<R, D, N> {
    /// Carried transport on the solver's **own** velocity and its own carried `c` (the soft
    /// sensor: a measured velocity, no flow model; issue 9, model.md 8). Each face moves the
    /// mass amount `F = dt/h |u_face| A_donor` (the face velocity is the mean of the two cells'
    /// normal velocities, as in [`Self::step`]'s transport; `A = c` of the donor, scaled down
    /// by a donor limiter where a cell would lose more than it holds), and with it
    /// `F qhat_donor` of the tracked phase. `c` and the tracked fraction `q` are updated by the
    /// same kept share and the same received amounts in the same order, so
    /// `0 <= q <= c` holds **exactly** in floating point whatever the velocity (a measured,
    /// noisy, not divergence-free one included): `q keep <= c keep` and `F qhat <= F` term by
    /// term, and rounded sums of termwise ordered terms stay ordered. A `q` that the
    /// percolation stage left an ulp outside `[0, c]` is moved back into it with the
    /// difference booked into the cell's compensated carry (so nothing is lost); the carry
    /// itself (below an ulp) is not transported.
    ///
    /// Boundaries: walls move nothing, except their open part `open(axis, high, cell)` in
    /// `[0, 1]` (an outlet, [`crate::boundary::Openings`]), through which grains only leave;
    /// outflow sides take the cell's own state (zero gradient) either way; inflow sides bring
    /// `c` of the cell with the tracked fraction of `inflow_phihat` (the small-phase fraction
    /// of the inflow), and reset the inflow values of their cells to `inflow_phihat c` after
    /// the update; periodic sides wrap. Returns what left through each side.
    ///
    /// The face coefficients `k = S.n / c` are rescaled to the new `c` (S does not depend on
    /// c), so no `prepare` is needed: the next [`Self::step_percolation`] sees the new `c`
    /// with the same segregation velocity and the same stable step. A cell that was empty at
    /// the last `prepare` keeps `k = 0` until the next one. Does not advance the clock.
    ///
    /// **Packing cap** (`cap = Some(c_max)`): after the transport, the part of `c` above
    /// `c_max` is taken out of every cell that has it (each phase by the cell's share, so
    /// `q <= c` stays) and handed first to its face neighbours with room, then, what they
    /// cannot take, to the bed's cells below `c_max`, each filled by the same fraction of its
    /// room at the pooled mix (`Self::pool_packing`), so `c <= c_max` holds exactly and both
    /// phases are conserved to round-off (docs/soft-sensor.md "A packing cap on the carried
    /// c"). `None`: no cap (the transport alone).
    pub fn carry_own_velocity(
        &mut self,
        dt: R,
        inflow_phihat: R,
        cap: Option<R>,
        open: impl Fn(usize, bool, usize) -> R,
    ) -> Discharge<R, D> {
        let n = self.grid.len();
        let grid = self.grid;
        let h = grid.spacing();
        let vol = grid.cell_volume();
        let vacuum = self.cfg.vacuum;
        let small = self.cfg.phase == Phase::Small;
        let inflow_q = if small {
            inflow_phihat
        } else {
            R::ONE - inflow_phihat
        };
        let mut out = Discharge::none();
        // Pass A: the amount each cell would give away with A = c, into `rhs`.
        self.rhs[..n].fill(R::ZERO);
        for a in 0..D {
            let lam = dt / h[a];
            let fb = grid.face_blocks(a);
            let s = fb.stride;
            let u = &self.u[a];
            for b in 0..fb.blocks {
                let l0 = b * fb.block_stride;
                for l in l0..l0 + fb.block_len {
                    let un = (u[l] + u[l + s]) * R::HALF;
                    if un > R::ZERO {
                        self.rhs[l] += lam * un * self.c[l];
                    } else if un < R::ZERO {
                        self.rhs[l + s] += lam * (-un) * self.c[l + s];
                    }
                }
            }
            for high in [false, true] {
                let kind = self.bc[a][high as usize];
                let (rhs, c) = (&mut self.rhs, &self.c);
                grid.for_each_boundary_cell(a, high, |i, j| match kind {
                    Boundary::Periodic => {
                        if high {
                            let un = (u[i] + u[j]) * R::HALF;
                            if un > R::ZERO {
                                rhs[i] += lam * un * c[i];
                            } else if un < R::ZERO {
                                rhs[j] += lam * (-un) * c[j];
                            }
                        }
                    }
                    Boundary::Wall => {
                        let w = open(a, high, i);
                        let uo = outward(high, u[i]);
                        if w > R::ZERO && uo > R::ZERO {
                            rhs[i] += lam * w * uo * c[i];
                        }
                    }
                    Boundary::Inflow | Boundary::Outflow => {
                        let uo = outward(high, u[i]);
                        if uo > R::ZERO {
                            rhs[i] += lam * uo * c[i];
                        }
                    }
                });
            }
        }
        // Pass B: the donor measure A_i (limited so no cell gives more than it holds) into
        // `rhs`, the donor fraction qhat into `flux`; each cell keeps the share `keep` of q
        // and c; k becomes the segregation velocity S = k c for the rescaling in pass D.
        let mut guarded = R::ZERO;
        for i in 0..n {
            let c = self.c[i];
            let mut q = self.q[i];
            // Round-off of the percolation stage: into [0, c], the difference into the carry.
            if q < R::ZERO {
                self.carry[i] += q;
                guarded -= q;
                q = R::ZERO;
            } else if q > c {
                self.carry[i] += q - c;
                guarded += q - c;
                q = c;
            }
            let give = self.rhs[i];
            let (lim, qhat, keep) = if c > R::ZERO {
                let lim = if give > c { c / give } else { R::ONE };
                (
                    lim,
                    (q / c).min(R::ONE),
                    ((c - lim * give) / c).max(R::ZERO),
                )
            } else {
                (R::ONE, R::ZERO, R::ONE)
            };
            self.rhs[i] = lim * c;
            self.flux[i] = qhat;
            self.q[i] = q * keep;
            for a in 0..D {
                self.k[a][i] *= c;
            }
            self.c[i] = c * keep;
        }
        out.guarded = guarded * vol;
        // Pass C: every cell receives, face by face in a fixed order, F of c and F qhat of q.
        for a in 0..D {
            let lam = dt / h[a];
            let fb = grid.face_blocks(a);
            let s = fb.stride;
            for b in 0..fb.blocks {
                let l0 = b * fb.block_stride;
                for l in l0..l0 + fb.block_len {
                    let un = (self.u[a][l] + self.u[a][l + s]) * R::HALF;
                    if un > R::ZERO {
                        let f = lam * un * self.rhs[l];
                        self.receive_own(l + s, f, self.flux[l]);
                    } else if un < R::ZERO {
                        let f = lam * (-un) * self.rhs[l + s];
                        self.receive_own(l, f, self.flux[l + s]);
                    }
                }
            }
            for high in [false, true] {
                let kind = self.bc[a][high as usize];
                let side = high as usize;
                grid.for_each_boundary_cell(a, high, |i, j| {
                    let u = self.u[a][i];
                    match kind {
                        Boundary::Periodic => {
                            if high {
                                let un = (u + self.u[a][j]) * R::HALF;
                                if un > R::ZERO {
                                    let f = lam * un * self.rhs[i];
                                    self.receive_own(j, f, self.flux[i]);
                                } else if un < R::ZERO {
                                    let f = lam * (-un) * self.rhs[j];
                                    self.receive_own(i, f, self.flux[j]);
                                }
                            }
                        }
                        Boundary::Wall => {
                            let w = open(a, high, i);
                            let uo = outward(high, u);
                            if w > R::ZERO && uo > R::ZERO {
                                let f = lam * w * uo * self.rhs[i];
                                out.small[a][side] += small_part(small, f, self.flux[i]) * vol;
                                out.total[a][side] += f * vol;
                            }
                        }
                        Boundary::Inflow | Boundary::Outflow => {
                            let uo = outward(high, u);
                            let f = lam * uo.abs() * self.rhs[i];
                            if uo > R::ZERO {
                                out.small[a][side] += small_part(small, f, self.flux[i]) * vol;
                                out.total[a][side] += f * vol;
                            } else if uo < R::ZERO {
                                let qhat = if kind == Boundary::Inflow {
                                    inflow_q
                                } else {
                                    self.flux[i]
                                };
                                self.receive_own(i, f, qhat);
                                out.small[a][side] -= small_part(small, f, qhat) * vol;
                                out.total[a][side] -= f * vol;
                            }
                        }
                    }
                });
            }
        }
        if let Some(cap) = cap {
            self.vent_at_openings(cap, &open, &mut out);
            self.pool_packing(cap);
        }
        // Pass D: k = S / c for the new c; inflow values follow the new c.
        for i in 0..n {
            let c = self.c[i];
            for a in 0..D {
                self.k[a][i] = if c > vacuum {
                    self.k[a][i] / c
                } else {
                    R::ZERO
                };
            }
        }
        for a in 0..D {
            for high in [false, true] {
                if self.bc[a][high as usize] == Boundary::Inflow {
                    let (ghost, c) = (&mut self.ghost, &self.c);
                    grid.for_each_boundary_cell(a, high, |i, _| ghost[i] = inflow_phihat * c[i]);
                }
            }
        }
        out
    }

    /// The packing cap of [`Self::carry_own_velocity`] (issue 9; docs/soft-sensor.md "A
    /// packing cap on the carried c"). A dense bed is nearly incompressible, but the measured
    /// velocity is not divergence-free, so the carried `c` rises where it converges. A face
    /// limiter ("the receiver takes what fits, the donor keeps the rest") cannot hold the cap
    /// exactly in a bounded number of local passes without freezing a bed that sits at the
    /// cap (a donor's room depends on what its own receivers accept, and so on along the
    /// flow, around closed streamlines too). So the excess goes first to the face neighbours
    /// ([`Self::push_to_neighbours`], local), and what they cannot take to a pool shared by
    /// the bed (the incompressible bed's answer: its pressure acts at once everywhere):
    ///
    /// 1. Excess `P = sum (c - cap)^+`; room `sum (cap - c)^+` over the bed (`c >= cap/2`),
    ///    or over every cell if the bed's is too small (a thin bed, a silo near empty).
    ///    If `P` exceeds the room by more than round-off (only an inflow side that overfills
    ///    the box can do this) each excess is removed in part: `theta = room / P`.
    /// 2. Each cell above the cap drops to `cap` (`theta = 1`: exactly `cap`); its tracked
    ///    part is scaled by the same share and clipped to the new `c` (round-off only). What
    ///    left, `pool` and `pool_q <= pool`, is summed in cell order.
    /// 3. Each eligible cell below the cap receives `a = rho (cap - c)` of `c` and
    ///    `a phat` of `q`, `rho = min(1, pool / room)`, `phat = pool_q / pool` in `[0, 1]`;
    ///    `c' = min(c + a, cap)` and `q' = min(q + a phat, c')` (both clips bind by round-off
    ///    only, since `a <= cap - c` and `a phat <= a`).
    ///
    /// Bounds: `0 <= q' <= c' <= cap` by the clips and non-negative terms, in floating point.
    /// Mass: the pool leaves the givers and reaches the receivers up to the rounding of the
    /// sums (and the clips), i.e. to round-off. Expects `k` to hold `S` (pass D rescales).
    fn pool_packing(&mut self, cap: R) {
        if !self.push_to_neighbours(cap) {
            return;
        }
        let n = self.grid.len();
        let half = cap * R::HALF;
        let (mut excess, mut room_bed, mut room_all) = (R::ZERO, R::ZERO, R::ZERO);
        for i in 0..n {
            let c = self.c[i];
            if c > cap {
                excess += c - cap;
            } else {
                room_all += cap - c;
                if c >= half {
                    room_bed += cap - c;
                }
            }
        }
        if excess == R::ZERO {
            return;
        }
        let bed_only = excess <= room_bed;
        let room = if bed_only { room_bed } else { room_all };
        // Round-off of the sums above: a box that holds at most `cap` per cell must not
        // leave an excess behind because its room came out an ulp short.
        let slack = R::EPSILON * R::from_usize(4 * n) * cap;
        let theta = if excess <= room + slack {
            R::ONE
        } else {
            room / excess
        };
        let (mut pool, mut pool_q) = (R::ZERO, R::ZERO);
        for i in 0..n {
            let c = self.c[i];
            if c > cap {
                let cn = if theta == R::ONE {
                    cap
                } else {
                    c - theta * (c - cap)
                };
                let q = self.q[i];
                let qn = (q * (cn / c)).min(cn);
                pool += c - cn;
                pool_q += q - qn;
                self.c[i] = cn;
                self.q[i] = qn;
            }
        }
        if room == R::ZERO || pool <= R::ZERO {
            return;
        }
        let phat = (pool_q / pool).max(R::ZERO).min(R::ONE);
        let rho = (pool / room).min(R::ONE);
        for i in 0..n {
            let c = self.c[i];
            if c < cap && (c >= half || !bed_only) {
                let a = rho * (cap - c);
                let cn = (c + a).min(cap);
                self.q[i] = (self.q[i] + a * phat).min(cn);
                self.c[i] = cn;
            }
        }
    }

    /// The packing cap's first stage at an opening: a cell on an open wall part or an
    /// outflow side whose measured velocity points out lets its excess above `cap` leave
    /// there (each phase by its share; booked as outflow), as grains pushed into a cell at
    /// the orifice of an incompressible bed leave through it. On a coarse sensor the flow
    /// into the orifice is measured too slow and too wide, and c rose above the orifice to
    /// make up for it; sent back into the bed, that excess held the outflow back.
    fn vent_at_openings(
        &mut self,
        cap: R,
        open: &impl Fn(usize, bool, usize) -> R,
        out: &mut Discharge<R, D>,
    ) {
        let grid = self.grid;
        let vol = grid.cell_volume();
        let small = self.cfg.phase == Phase::Small;
        for a in 0..D {
            for high in [false, true] {
                let kind = self.bc[a][high as usize];
                let side = high as usize;
                if matches!(kind, Boundary::Inflow | Boundary::Periodic) {
                    continue;
                }
                grid.for_each_boundary_cell(a, high, |i, _| {
                    let c = self.c[i];
                    // Cheapest test first: a box without openings rarely has a wall cell above
                    // the cap, so it pays a compare per boundary cell, not the opening lookup.
                    if c > cap
                        && outward(high, self.u[a][i]) > R::ZERO
                        && (kind == Boundary::Outflow || open(a, high, i) > R::ZERO)
                    {
                        let q = self.q[i];
                        let qn = (q * (cap / c)).min(cap);
                        let e = c - cap;
                        let qhat = (q / c).min(R::ONE);
                        out.small[a][side] += small_part(small, e, qhat) * vol;
                        out.total[a][side] += e * vol;
                        self.c[i] = cap;
                        self.q[i] = qn;
                    }
                });
            }
        }
    }

    /// The local first stage of the packing cap: every cell above `cap` hands its excess to
    /// its face neighbours (interior and periodic faces; not through walls or open sides),
    /// each of which offers the share `1/(2D)` of its room `cap - c` to each neighbour, so a
    /// cell never receives more than its room whatever its neighbours do. A giver `v` with
    /// offers `O_v` gives `min(c_v - cap, O_v)` (to `cap` exactly if the offers suffice),
    /// each neighbour `n` the part `r_v room_n / (2D)`, `r_v = min(1, (c_v - cap) / O_v)`,
    /// at the giver's tracked fraction. Givers and receivers are disjoint (a giver has no
    /// room), so three passes suffice: ratios and fractions into the scratch `rhs` / `flux`,
    /// the givers, the receivers face by face (reading only receivers' unchanged `c` and the
    /// givers' stored ratios), then the receivers' new `c`. Bounds and mass as in
    /// [`Self::pool_packing`]. What a giver could not hand on (its neighbours full too) is
    /// left for the pool; returns whether any cell is still above the cap.
    fn push_to_neighbours(&mut self, cap: R) -> bool {
        let n = self.grid.len();
        self.rhs[..n].fill(R::ZERO);
        let (mut any, mut left) = (false, false);
        for i in 0..n {
            let c = self.c[i];
            // `flux` of a receiver accumulates what it receives (below)
            self.flux[i] = R::ZERO;
            if c > cap {
                let offers = self.neighbour_offers(i, cap);
                if offers > R::ZERO {
                    self.rhs[i] = ((c - cap) / offers).min(R::ONE);
                    self.flux[i] = (self.q[i] / c).min(R::ONE);
                    any = true;
                } else {
                    left = true;
                }
            }
        }
        if !any {
            return left;
        }
        for i in 0..n {
            let ratio = self.rhs[i];
            if ratio > R::ZERO {
                let c = self.c[i];
                let cn = if ratio < R::ONE {
                    cap
                } else {
                    (c - self.neighbour_offers(i, cap)).max(cap)
                };
                left |= cn > cap;
                self.q[i] = (self.q[i] * (cn / c)).min(cn);
                self.c[i] = cn;
            }
        }
        // Face by face (no index arithmetic per cell): a receiver's `c` stays as it was until
        // the last pass, so every giver sees the same room; its `c` part accumulates in
        // `flux`, its tracked part in `q` directly.
        let share = R::ONE / R::from_usize(2 * D);
        let grid = self.grid;
        for a in 0..D {
            grid.for_each_interior_face(a, |l, r| self.pass_on(l, r, cap, share));
            if self.bc[a][0] == Boundary::Periodic {
                grid.for_each_boundary_cell(a, true, |last, first| {
                    if last != first {
                        self.pass_on(last, first, cap, share);
                    }
                });
            }
        }
        for i in 0..n {
            let a = self.flux[i];
            if self.rhs[i] == R::ZERO && a > R::ZERO {
                let cn = (self.c[i] + a).min(cap);
                self.q[i] = self.q[i].min(cn);
                self.c[i] = cn;
            }
        }
        left
    }

    /// One face of [`Self::push_to_neighbours`]: if one side gives and the other has room,
    /// the receiver gets `ratio room / (2D)` at the giver's tracked fraction.
    #[inline(always)]
    fn pass_on(&mut self, l: usize, r: usize, cap: R, share: R) {
        let (gl, gr) = (self.rhs[l], self.rhs[r]);
        let (giver, to, ratio) = if gl > R::ZERO && gr == R::ZERO {
            (l, r, gl)
        } else if gr > R::ZERO && gl == R::ZERO {
            (r, l, gr)
        } else {
            return;
        };
        let c = self.c[to];
        if c < cap {
            let f = ratio * ((cap - c) * share);
            self.flux[to] += f;
            self.q[to] += f * self.flux[giver];
        }
    }

    /// The room `sum (cap - c_n) / (2D)` the face neighbours of cell `i` offer it (cells
    /// that give in this pass, `rhs > 0`, offer none).
    fn neighbour_offers(&self, i: usize, cap: R) -> R {
        let share = R::ONE / R::from_usize(2 * D);
        let mut offers = R::ZERO;
        self.for_each_neighbour(i, |s, m| {
            let c = s.c[m];
            if s.rhs[m] == R::ZERO && c < cap {
                offers += (cap - c) * share;
            }
        });
        offers
    }

    /// Calls `f` with each face neighbour of cell `i` in a fixed order (low then high side of
    /// each axis), across interior and periodic faces only.
    #[inline(always)]
    fn for_each_neighbour(&self, i: usize, mut f: impl FnMut(&Self, usize)) {
        let cells = self.grid.cells();
        for a in 0..D {
            let (k, m, s) = (self.grid.coord(i, a), cells[a], self.grid.stride(a));
            let periodic = self.bc[a][0] == Boundary::Periodic && m > 1;
            if k > 0 {
                f(self, i - s);
            } else if periodic {
                f(self, i + (m - 1) * s);
            }
            if k + 1 < m {
                f(self, i + s);
            } else if periodic {
                f(self, i - (m - 1) * s);
            }
        }
    }

    /// Cell `i` receives the amount `f >= 0` of `c` with tracked fraction `qhat` in `[0, 1]`.
    #[inline(always)]
    fn receive_own(&mut self, i: usize, f: R, qhat: R) {
        self.q[i] += f * qhat;
        self.c[i] += f;
    }
}

impl<R: Real, const D: usize, const N: usize> Segregation<R, D, N> {
    /// The face coefficient `k_a = S_a / c` of cell `i` (0 in empty cells): derived by
    /// `prepare`, rescaled by [`Self::carry_own_velocity`]. For bit-exact snapshots of a
    /// carried `c`, whose rescaled `k` a fresh `prepare` would round differently.
    pub fn face_coefficient(&self, axis: usize, i: usize) -> R {
        self.k[axis][i]
    }

    /// Restores a face coefficient saved with [`Self::face_coefficient`] (snapshots only;
    /// call after `prepare`/`prepare_velocity`, which would overwrite it).
    pub fn set_face_coefficient(&mut self, axis: usize, i: usize, k: R) {
        self.k[axis][i] = k;
    }

    /// Sets `c` of cell `i` exactly (bit-exact snapshot restore of a carried `c`); call
    /// `prepare_velocity` after.
    pub fn set_volume_fraction(&mut self, i: usize, c: R) {
        self.c[i] = c;
    }
}
