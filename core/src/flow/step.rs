//! One time step of the flow (the scheme of the module docs of [`super`]).

use super::cg::{self, Preconditioner, Scratch, Stencil, Stop};
use super::reach::{Reach, Whole};
use super::{Flow, FlowSide, OutletPressure, PressureMode, Slip, Stress, VelocityGuess};
use crate::boundary::Boundary;
use crate::closure;
use crate::fork::{Call, Fork, Serial, Share};
use crate::frame::{turn_by, Frame};
use crate::real::Real;
use crate::segregation::flux::transport as upwind;

/// What the viscous flux of one velocity component sees at a non-periodic boundary face.
#[derive(Clone, Copy)]
enum Face<R> {
    /// Dirichlet value at the face (no-slip wall, normal component at a wall, inflow).
    Value(R),
    /// Given stress towards the cell (partial slip below the friction limit).
    Stress(R),
    /// Zero flux (slip wall tangential, outflow).
    Free,
}

/// One worker's share of the velocity solves side by side ([`Flow::viscous`]): its
/// components in order, their systems `(diag, rhs)`, its scratch and, after the fork, the
/// iterations of each.
struct SolveItem<'a, R, const N: usize> {
    x: &'a mut [[R; N]],
    systems: [(&'a [R], &'a [R]); 2],
    scratch: Scratch<'a, R>,
    iterations: [u32; 2],
}

impl<R: Real, const D: usize, const N: usize> Flow<R, D, N> {
    /// One step of length `dt` (at most [`Self::stable_dt`]). Adds `dt` to the clock.
    pub fn step(&mut self, dt: R) {
        self.step_on(dt, &Serial);
    }

    /// [`Self::step`] with the linear solves' fine-grid loops on the threads of `fork`: the
    /// same bits for any number of threads (module [`crate::fork`]).
    pub fn step_on<F: Fork>(&mut self, dt: R, fork: &F) {
        self.step_reaching(dt, fork, &mut Whole);
    }

    /// [`Self::step_on`] on a grid that may be a subdomain: whatever the step needs of cells
    /// it does not own (halo rows, sums, maxima, the implicit solves) it asks of `reach`
    /// (module [`super::reach`]). With [`Whole`] this is the serial step, bit for bit.
    pub fn step_reaching<F: Fork, Re: Reach<R, D, N>>(&mut self, dt: R, fork: &F, reach: &mut Re) {
        debug_assert!(self.prepared, "prepare() must follow set_cell()");
        let n = self.grid.len();
        if !reach.whole() {
            // the halo rows as their owners left them at the end of the last step
            self.for_each_state_array_mut(|_, field| reach.refresh(field));
        }
        for a in 0..D {
            self.u_before[a][..n].copy_from_slice(&self.u_prev[a][..n]);
            self.u_prev[a][..n].copy_from_slice(&self.u[a][..n]);
        }
        self.g_now = self.cfg.frame.gravity(self.cfg.gravity, self.time);
        let implicit = self.cfg.pressure == PressureMode::Implicit;
        if implicit {
            // p^{n+1} = p^n + dp from one SPD solve; the transport's face velocities and the
            // momentum update below both use it (model.md 5.3, implicit pressure).
            self.implicit_pressure(dt, fork, reach);
        }
        // The stages' own loops as hot loops too, at the fork's instruction set (docs/simd.md):
        // what is inlined into them is compiled for it, the rest keeps the crate's features.
        fork.hot(Call(
            #[inline(always)]
            || self.transport(dt, reach),
        ));
        fork.hot(Call(
            #[inline(always)]
            || {
                if implicit {
                    // the linearised pressure at the content the transport delivered
                    self.consistent_pressure();
                } else {
                    self.pressures(); // new c, old T: forward-backward acoustics
                }
                if self.holds() {
                    self.advective_hold(dt);
                }
                self.pressure_and_gravity(dt);
                self.coefficients();
                self.velocity_from_momentum();
            },
        ));
        self.viscous(dt, fork, reach);
        self.temperature_stage(dt, fork, reach);
        self.residual = fork.hot(Call(
            #[inline(always)]
            || {
                self.pressures();
                self.step_residual(dt, reach)
            },
        ));
        self.time += dt;
        self.steps += 1;
    }

    pub(super) fn periodic(&self) -> [bool; D] {
        let mut p = [false; D];
        for a in 0..D {
            p[a] = self.bc[a][0].kind == Boundary::Periodic;
        }
        p
    }

    /// Mass flux through the low boundary face of `first` along `a` (positive = into the cell).
    /// An opening in a wall is an outflow face scaled by its open fraction.
    pub(super) fn low_flux(&self, a: usize, first: usize, side: &FlowSide<R, D>, dt: R) -> R {
        match side.kind {
            Boundary::Inflow => upwind(side.c, self.c[first], side.velocity[a]),
            Boundary::Outflow => upwind(R::ZERO, self.c[first], self.u[a][first].min(R::ZERO)),
            Boundary::Wall if !side.openings.is_empty() => {
                let open = self.open_fraction(a, false, first);
                let v = self.outlet_velocity(a, first, false, side, dt).0;
                open * upwind(R::ZERO, self.c[first], v.min(R::ZERO))
            }
            _ => R::ZERO,
        }
    }

    /// Mass flux through the high boundary face of `last` along `a` (positive = out of the cell).
    pub(super) fn high_flux(
        &self,
        a: usize,
        last: usize,
        first: usize,
        side: &FlowSide<R, D>,
        dt: R,
    ) -> R {
        match side.kind {
            Boundary::Wall if !side.openings.is_empty() => {
                let open = self.open_fraction(a, true, last);
                let v = self.outlet_velocity(a, last, true, side, dt).0;
                open * upwind(self.c[last], R::ZERO, v.max(R::ZERO))
            }
            Boundary::Wall => R::ZERO,
            Boundary::Periodic => upwind(
                self.c[last],
                self.c[first],
                (self.u[a][last] + self.u[a][first]) * R::HALF,
            ),
            Boundary::Inflow => upwind(self.c[last], side.c, side.velocity[a]),
            Boundary::Outflow => upwind(self.c[last], R::ZERO, self.u[a][last].max(R::ZERO)),
        }
    }

    /// Stage 1: upwind transport of c, c u, c T with conservative limiters.
    ///
    /// The face velocity is the mean of the two cells plus a Rhie-Chow correction
    /// `w tau (F_f - (K_L + K_R)/2) / c_f`: the compact face force minus the mean of its
    /// cells' compact forces, over the face's mass, faded like the face force (model.md 5.3:
    /// the momentum form, so that a nearly empty cell's force is not divided by its tiny
    /// mass). It vanishes at a discrete
    /// rest state and on smooth flows (O(h^2)),
    /// and it drives a mass flux against the odd-even (checkerboard) pressure modes that the
    /// collocated central pressure gradient cannot see, so those are damped, not frozen in.
    #[inline(always)]
    fn transport<Re: Reach<R, D, N>>(&mut self, dt: R, reach: &mut Re) {
        let n = self.grid.len();
        let h = self.grid.spacing();
        let grid = self.grid;
        let vac = self.cfg.vacuum;
        // The Rhie-Chow time scale of each axis: a function of the state, never of the step
        // taken (model.md 5.3); scaled with `dt`, it made the silo's steady discharge rate
        // fall with the Courant number.
        let mut rate = [R::ZERO; D];
        if self.cfg.pressure == PressureMode::Explicit {
            // Compact parts only: the direct gravity of faded faces is not a pressure mode,
            // and counting it would let the correction hold an unsupported surface cell in
            // the air. (The implicit face velocity needs no cell forces.)
            self.cell_forces(false);
            rate = self.rhie_chow_rates(reach);
        }
        let k = R::from_f64(RHIE_CHOW_COURANT) / R::from_usize(D);
        // With an embedded wall every face flux is scaled by its open aperture (0 inside a
        // merge group) and the limiters and the update work in content units (`walls`).
        let emb = self.walls.on;
        // Pass 1: face fluxes (stored at the left cell), inflow and outflow of each cell.
        self.inflow[..n].fill(R::ZERO);
        self.diag[..n].fill(R::ZERO);
        for a in 0..D {
            let lam = dt / h[a];
            // `tau_a = (C_rc / D) / rate_a`; the correction is capped at `C_rc h_a / tau_a`
            let tau = if rate[a] > R::ZERO {
                k / rate[a]
            } else {
                R::ZERO
            };
            let cap = R::from_usize(D) * h[a] * rate[a];
            let fb = grid.face_blocks(a);
            let s = fb.stride;
            for b in 0..fb.blocks {
                let l0 = b * fb.block_stride;
                for l in l0..l0 + fb.block_len {
                    let mut f = self.interior_flux(a, l, l + s, dt, tau, cap, vac);
                    if emb {
                        f *= self.transport_aperture(a, l, l + s);
                    }
                    self.flux[a][l] = f;
                    self.count(l, l + s, lam * f);
                }
            }
            let (lo, hi) = (self.bc[a][0], self.bc[a][1]);
            grid.for_each_boundary_cell(a, true, |last, first| {
                let mut f = if hi.kind == Boundary::Periodic {
                    self.interior_flux(a, last, first, dt, tau, cap, vac)
                } else {
                    self.high_flux(a, last, first, &hi, dt)
                };
                if emb {
                    f *= if hi.kind == Boundary::Periodic {
                        self.transport_aperture(a, last, first)
                    } else {
                        self.walls.ap_hi[a][last]
                    };
                }
                self.flux[a][last] = f;
                if hi.kind == Boundary::Periodic {
                    self.count(last, first, lam * f);
                } else if f < R::ZERO {
                    self.inflow[last] -= lam * f;
                } else {
                    self.diag[last] += lam * f;
                }
            });
            if moves_mass(&lo) {
                grid.for_each_boundary_cell(a, false, |first, _| {
                    let mut f = self.low_flux(a, first, &lo, dt);
                    if emb {
                        f *= self.walls.ap_lo[a][first];
                    }
                    // Kept for pass 2, which changes the cell's c before it reaches this
                    // face: recomputed there, an outlet saw the step's inflow as content
                    // (an O(dt) excess; the limiter factors are for this flux, too).
                    self.flux_low[a][first] = f;
                    if f > R::ZERO {
                        self.inflow[first] += lam * f;
                    } else {
                        self.diag[first] -= lam * f;
                    }
                });
            }
        }
        // Limiters: a cell's inflow is scaled so it cannot pass c_max (outflow only lowers c),
        // its outflow so it cannot drop below 0 (inflow only raises c). Each face flux takes
        // the smaller factor of its donor and receiver, so both bounds hold whatever the
        // neighbours do, and every flux still leaves one cell and enters the other.
        if emb {
            self.embedded_limiters();
            self.embedded_begin_update();
        } else {
            for i in 0..n {
                let room = ((R::ONE - self.cfg.margin) * self.c_rcp[i] - self.c[i]).max(R::ZERO);
                let inflow = self.inflow[i];
                self.inflow[i] = if inflow > room { room / inflow } else { R::ONE };
                let content = spendable(self.c[i]);
                let outflow = self.diag[i];
                self.diag[i] = if outflow > content {
                    content / outflow
                } else {
                    R::ONE
                };
            }
        }
        // Pass 2: apply, and keep each applied amount in `flux` / `flux_low` (the step's
        // face mass fluxes, see `Flow::mass_fluxes`).
        let vol = grid.cell_volume();
        self.discharge_step = [[R::ZERO; 2]; D];
        for a in 0..D {
            let lam = dt / h[a];
            let fb = grid.face_blocks(a);
            let s = fb.stride;
            for b in 0..fb.blocks {
                let l0 = b * fb.block_stride;
                for l in l0..l0 + fb.block_len {
                    self.exchange(a, l, l + s, lam);
                }
            }
            let (lo, hi) = (self.bc[a][0], self.bc[a][1]);
            grid.for_each_boundary_cell(a, true, |last, first| {
                if hi.kind == Boundary::Periodic {
                    return self.exchange(a, last, first, lam);
                }
                // (0 on a closed wall)
                let f = self.flux[a][last];
                let mut df = R::ZERO;
                if f > R::ZERO {
                    // out of the box: the interior state leaves
                    let f = f * self.diag[last];
                    let (u, t) = (self.velocity(last), self.t[last]);
                    df = lam * f;
                    self.add_flux(last, -df, u, t);
                } else if f < R::ZERO {
                    let f = f * self.inflow[last];
                    df = lam * f;
                    self.add_flux(last, -df, hi.velocity, hi.t);
                }
                self.flux[a][last] = df;
                if a == D - 1 {
                    self.discharge_step[a][1] += df * vol;
                }
            });
            if moves_mass(&lo) {
                grid.for_each_boundary_cell(a, false, |first, _| {
                    let f = self.flux_low[a][first];
                    let mut df = R::ZERO;
                    if f > R::ZERO {
                        let f = f * self.inflow[first];
                        df = lam * f;
                        self.add_flux(first, df, lo.velocity, lo.t);
                    } else if f < R::ZERO {
                        let f = f * self.diag[first];
                        let (u, t) = (self.velocity(first), self.t[first]);
                        df = lam * f;
                        self.add_flux(first, df, u, t);
                    }
                    self.flux_low[a][first] = df;
                    if a == D - 1 {
                        self.discharge_step[a][0] -= df * vol;
                    }
                });
            }
        }
        self.discharge_along(reach);
        for a in 0..D {
            for side in 0..2 {
                self.discharged[a][side] += self.discharge_step[a][side];
            }
        }
        if emb {
            self.embedded_end_update();
        }
    }

    /// The step's discharge through the open sides along the last axis (the sides across it
    /// are booked face by face in the transport): the applied amounts of the owned boundary
    /// cells in cell order, as sums continued across subdomains (`reach`), so that every slab
    /// of rows holds the serial discharge of the whole side. A closed side's stays zero and
    /// takes part in no sum: a closed scene pays nothing.
    fn discharge_along<Re: Reach<R, D, N>>(&mut self, reach: &mut Re) {
        let grid = self.grid;
        let vol = grid.cell_volume();
        let own = reach.owned(grid.len());
        for a in 0..D - 1 {
            for side in 0..2 {
                if !moves_mass(&self.bc[a][side]) {
                    continue;
                }
                let high = side == 1;
                let applied = if high {
                    &self.flux[a]
                } else {
                    &self.flux_low[a]
                };
                self.discharge_step[a][side] = reach.sum_in_order(R::ZERO, |mut sum| {
                    grid.for_each_boundary_cell(a, high, |i, _| {
                        if own.contains(&i) {
                            // out of the box is positive on either side
                            if high {
                                sum += applied[i] * vol;
                            } else {
                                sum -= applied[i] * vol;
                            }
                        }
                    });
                    sum
                });
            }
        }
    }

    /// Upwind mass flux of an interior (or wrap) face with the Rhie-Chow face velocity of
    /// time scale `tau`; the correction is capped at `cap = 0.4 h / tau`.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn interior_flux(&self, a: usize, l: usize, r: usize, dt: R, tau: R, cap: R, vac: R) -> R {
        let (cl, cr) = (self.c[l], self.c[r]);
        if self.cfg.pressure == PressureMode::Implicit {
            // The end-of-step face velocity `u_f* + dt F_f(p^{n+1}) / c_f` (`p` holds the
            // implicit p^{n+1}): the face velocity the pressure solve predicted.
            let (ff, _) = self.implicit_face_force(a, l, r);
            return upwind(cl, cr, self.implicit_face_velocity(a, l, r, dt, ff, vac));
        }
        let (ff, w) = self.face_force(a, self.face_body(a, l), cl, self.p[l], cr, self.p[r]);
        let cf = (cl + cr) * R::HALF;
        // The face's force minus the mean of its cells' forces, over the face's mass (the
        // momentum form), faded with the face force (`w`, 1 in the bulk) (model.md 5.3).
        // Dividing each cell's force by its own mass made a nearly empty cell over a free
        // surface, pushed by `~ w p / h` with a mass of `~ w surface`, look like an
        // acceleration of `p / (h surface)` that shut the face of a rising surface, which
        // then packed to c_rcp.
        let du = if cf > vac {
            (w * tau * (ff - (self.kf[a][l] + self.kf[a][r]) * R::HALF) / cf)
                .max(-cap)
                .min(cap)
        } else {
            R::ZERO
        };
        upwind(cl, cr, (self.u[a][l] + self.u[a][r]) * R::HALF + du)
    }

    /// Books `df = lam f` of the face (l, r) as inflow and outflow of the two cells.
    #[inline(always)]
    fn count(&mut self, l: usize, r: usize, df: R) {
        if df > R::ZERO {
            self.inflow[r] += df;
            self.diag[l] += df;
        } else {
            self.inflow[l] -= df;
            self.diag[r] -= df;
        }
    }

    /// Moves the stored flux of face (l, r) along `a`, scaled by the smaller limiter factor
    /// of donor (outflow, in `diag`) and receiver (inflow, in `inflow`); stores the amount
    /// moved in its place.
    #[inline(always)]
    fn exchange(&mut self, a: usize, l: usize, r: usize, lam: R) {
        let f = self.flux[a][l];
        let mut df = R::ZERO;
        if f > R::ZERO {
            df = lam * f * self.inflow[r].min(self.diag[l]);
            let (u, t) = (self.velocity(l), self.t[l]);
            self.add_flux(l, -df, u, t);
            self.add_flux(r, df, u, t);
        } else if f < R::ZERO {
            df = lam * f * self.inflow[l].min(self.diag[r]);
            let (u, t) = (self.velocity(r), self.t[r]);
            self.add_flux(l, -df, u, t);
            self.add_flux(r, df, u, t);
        }
        self.flux[a][l] = df;
    }

    #[inline(always)]
    fn add_flux(&mut self, i: usize, dc: R, u: [R; D], t: R) {
        if self.walls.on {
            return self.embedded_add_flux(i, dc, u, t);
        }
        self.c[i] += dc;
        for a in 0..D {
            self.m[a][i] += dc * u[a];
        }
        self.e[i] += dc * t;
    }

    /// Compact face force per volume along `a` between a left and a right state `(c, p)`:
    /// `w (-(p_R - p_L)/h + b_a (c_L + c_R)/2)`, with the body acceleration `b_a` of the face
    /// (gravity, plus the centrifugal part in a rotating frame: [`Self::face_body`]) and the
    /// fade weight `w = min(1, min(c_L, c_R)/surface)` (the free-surface condition `p -> 0`
    /// next to a nearly empty cell, so such a cell is not blown away by a dense neighbour).
    /// Returns `(F, w)`.
    #[inline(always)]
    pub(super) fn face_force(&self, a: usize, b: R, cl: R, pl: R, cr: R, pr: R) -> (R, R) {
        let w = (cl.min(cr) / self.cfg.surface).min(R::ONE);
        let h = self.grid.spacing()[a];
        (w * ((pl - pr) / h + b * (cl + cr) * R::HALF), w)
    }

    /// Body acceleration along `a` at the high face of cell `l` (`l` = the last cell of a line:
    /// its box or wrap face): the frame's gravity, plus in a rotating frame the centrifugal
    /// acceleration at the face (a potential force, so it belongs in the compact face force
    /// and a bed in relative equilibrium is in exact discrete balance).
    #[inline(always)]
    pub(super) fn face_body(&self, a: usize, l: usize) -> R {
        match &self.cfg.frame {
            Frame::Lab => self.g_now[a],
            Frame::Rotating(rot) => {
                // counted from the box's first face, so that a slab's faces lie where the
                // whole grid's do to the bit (`origin + k h`, never `(origin + k0 h) + k h`)
                let mut k = self.grid.coord(l, a) + 1;
                if a == D - 1 {
                    k += self.home_rows;
                }
                let b = &self.home;
                let x = b.origin()[a] + R::from_usize(k) * b.spacing()[a];
                self.g_now[a] + rot.centrifugal(a, x)
            }
        }
    }

    /// Body acceleration along `a` at the low box face of a line (see [`Self::face_body`]).
    #[inline(always)]
    pub(super) fn low_face_body(&self, a: usize) -> R {
        match &self.cfg.frame {
            Frame::Lab => self.g_now[a],
            Frame::Rotating(rot) => self.g_now[a] + rot.centrifugal(a, self.grid.origin()[a]),
        }
    }

    /// Body acceleration at the boundary face of cell `i` on side `high` of axis `a`: the
    /// one choice between [`Self::face_body`] and [`Self::low_face_body`] every boundary
    /// term makes.
    #[inline(always)]
    fn boundary_body(&self, a: usize, i: usize, high: bool) -> R {
        if high {
            self.face_body(a, i)
        } else {
            self.low_face_body(a)
        }
    }

    /// Compact face force `(F, w)` of the outlet ghost `(c_i, p_ghost)` on the boundary face of
    /// cell `i` (side `high` of axis `a`), unscaled by the open fraction. The one place the
    /// ghost pressure is chosen, for the momentum update and the implicit outflow alike.
    pub(super) fn outlet_face_force(
        &self,
        a: usize,
        i: usize,
        high: bool,
        side: &FlowSide<R, D>,
    ) -> (R, R) {
        let (ci, pi) = (self.c[i], self.p[i]);
        let pg = match side.outlet {
            OutletPressure::Zero => -pi,
            OutletPressure::ZeroGradient => pi,
        };
        let b = self.boundary_body(a, i, high);
        if high {
            self.face_force(a, b, ci, pi, ci, pg)
        } else {
            self.face_force(a, b, ci, pg, ci, pi)
        }
    }

    /// Face force of the boundary face of cell `i` (`other`: the other end of its line).
    fn boundary_face_force(
        &self,
        a: usize,
        i: usize,
        other: usize,
        high: bool,
        side: &FlowSide<R, D>,
    ) -> (R, R) {
        let (ci, pi) = (self.c[i], self.p[i]);
        let b = self.boundary_body(a, i, high);
        let (cg, pg) = match side.kind {
            // Hydrostatic ghost (c_i, p_i -+ h c_i g_a): the wall carries its half exactly.
            Boundary::Wall if side.openings.is_empty() => return (R::ZERO, R::ONE),
            // An opening: the outlet ghost (c_i, p_ghost) on the open fraction of the face,
            // the wall's (0, 1) on the rest. `p = 0` on the face: the ghost mirrors the cell.
            Boundary::Wall => {
                let open = self.open_fraction(a, high, i);
                if open == R::ZERO {
                    return (R::ZERO, R::ONE);
                }
                let (f, w) = self.outlet_face_force(a, i, high, side);
                return (open * f, (R::ONE - open) + open * w);
            }
            Boundary::Periodic => (self.c[other], self.p[other]),
            Boundary::Inflow => (
                side.c,
                closure::pressure(
                    &self.cfg.material,
                    side.c,
                    side.t,
                    self.c_rcp[i],
                    self.c_rlp[i],
                ),
            ),
            Boundary::Outflow => (ci, pi),
        };
        if high {
            self.face_force(a, b, ci, pi, cg, pg)
        } else {
            self.face_force(a, b, cg, pg, ci, pi)
        }
    }

    /// Pressure + gravity force per volume of every cell into `kf` (scratch): half the compact
    /// force of each of its faces, plus (if `with_direct_gravity`) direct gravity on the share
    /// `(1 - w)/2` of faded faces (so dust in the air still falls). In the bulk this is the central pressure gradient with
    /// the gravity of the face masses; a rest state is `F_f = 0` on every face, i.e. the compact
    /// lithostatic balance `(p_R - p_L)/h = g (c_L + c_R)/2`.
    ///
    /// With an embedded wall each face term is weighted by the face's open aperture (the open
    /// part of its dual volume), the cut wall fragment is a hydrostatic ghost (no term), and
    /// the sum of a merge group is divided by the group volume (`walls`).
    fn cell_forces(&mut self, with_direct_gravity: bool) {
        let n = self.grid.len();
        let grid = self.grid;
        let emb = self.walls.on;
        // The body force of faded faces acts directly on their cells (only if asked for).
        let direct = |b: R| if with_direct_gravity { b } else { R::ZERO };
        let h = self.grid.spacing();
        for a in 0..D {
            self.kf[a][..n].fill(R::ZERO);
            // Free-surface push per unit (1 - w) (0 for the compact parts only).
            let open = if with_direct_gravity && self.cfg.free_surface_push {
                R::ONE / h[a]
            } else {
                R::ZERO
            };
            let fb = grid.face_blocks(a);
            let s = fb.stride;
            for b in 0..fb.blocks {
                let l0 = b * fb.block_stride;
                for l in l0..l0 + fb.block_len {
                    let r = l + s;
                    let b = self.face_body(a, l);
                    let (f, w) = self.face_force(a, b, self.c[l], self.p[l], self.c[r], self.p[r]);
                    let rest = R::HALF * (R::ONE - w) * direct(b);
                    let push = (R::ONE - w) * open;
                    let wa = if emb { self.walls.ap_hi[a][l] } else { R::ONE };
                    self.kf[a][l] += wa * (R::HALF * f + rest * self.c[l] + push * self.p[l]);
                    self.kf[a][r] += wa * (R::HALF * f + rest * self.c[r] - push * self.p[r]);
                }
            }
            for (high, side) in [(false, self.bc[a][0]), (true, self.bc[a][1])] {
                if side.kind == Boundary::Periodic && !high {
                    continue; // each wrap face once
                }
                grid.for_each_boundary_cell(a, high, |i, other| {
                    let (f, w) = self.boundary_face_force(a, i, other, high, &side);
                    let b = self.boundary_body(a, i, high);
                    let rest = R::HALF * (R::ONE - w) * direct(b);
                    let wa = match (emb, high) {
                        (false, _) => R::ONE,
                        (true, true) => self.walls.ap_hi[a][i],
                        (true, false) => self.walls.ap_lo[a][i],
                    };
                    self.kf[a][i] += wa * (R::HALF * f + rest * self.c[i]);
                    if side.kind == Boundary::Periodic {
                        // the wrap face is an interior face: `i` is its high-side (last) cell
                        let push = (R::ONE - w) * open;
                        self.kf[a][i] += wa * (push * self.p[i]);
                        self.kf[a][other] +=
                            wa * (R::HALF * f + rest * self.c[other] - push * self.p[other]);
                    }
                });
            }
        }
        if emb {
            self.embedded_forces();
        }
    }

    /// Stage 2: `m += dt (-grad p + c g)` with the new c (forward-backward acoustics).
    fn pressure_and_gravity(&mut self, dt: R) {
        let n = self.grid.len();
        self.cell_forces(true);
        for a in 0..D {
            for i in 0..n {
                self.m[a][i] += dt * self.kf[a][i];
            }
        }
        if let Frame::Rotating(rot) = self.cfg.frame {
            // Coriolis `-2 Omega x u`: the exact rotation of the momentum by `-2 omega dt`
            // (length-preserving, so no energy gain and no time-step limit).
            let angle = -(R::TWO * rot.omega * dt);
            let (sn, cs) = (angle.sin(), angle.cos());
            let (p, q) = rot.plane();
            for i in 0..n {
                let mut v = [R::ZERO; D];
                for a in 0..D {
                    v[a] = self.m[a][i];
                }
                let v = turn_by(v, (p, q), sn, cs);
                self.m[p][i] = v[p];
                self.m[q][i] = v[q];
            }
        }
        self.wall_contact();
        if self.walls.on {
            self.embedded_wall_contact();
        }
    }

    /// Unilateral wall contact of loose cells, with Coulomb friction: a wall cell with
    /// `c <= c_rlp` loses the normal momentum `J` that points into the wall (a perfectly
    /// inelastic contact), and its tangential momentum relative to the wall loses up to
    /// `tan(phi_w) J` (all of it at a no-slip wall, none at a slip wall).
    ///
    /// Why: the hydrostatic ghost of a wall face assumes that the cell's own pressure carries
    /// the weight the wall does not. A loose cell (no yield pressure; cold, so `p ~ 0`) with a
    /// free surface above cannot build that pressure, because it cannot compact without
    /// inflow: the unbalanced half weight of its faded upper face would accelerate it into the
    /// wall without bound (no mass moves, the wall flux is 0), and the spurious normal shear
    /// at the wall would heat it forever. Grains that reach a wall stop there; the wall
    /// supplies whatever normal reaction that takes (it can push, never pull). For the same
    /// reason such a cell has no pressure for the friction law of the viscous stage
    /// (`min(p tan(phi_w), W)` with `p ~ 0`, `W ~ eta ~ sqrt(T)`), so a thin loose sheet on a
    /// floor would slide on for ever; the contact reaction is its normal load, and Coulomb
    /// friction on it stops the sheet at the wall friction angle. Dense cells (`c > c_rlp`)
    /// compact and carry their weight by pressure, and their wall friction is unchanged.
    fn wall_contact(&mut self) {
        let grid = self.grid;
        for a in 0..D {
            for (high, side) in [(false, self.bc[a][0]), (true, self.bc[a][1])] {
                if side.kind != Boundary::Wall {
                    continue;
                }
                grid.for_each_boundary_cell(a, high, |i, _| {
                    let m = self.m[a][i];
                    let into = (high && m > R::ZERO) || (!high && m < R::ZERO);
                    // the inner neighbour (none on a one-cell line)
                    let inner = if grid.cells()[a] < 2 {
                        R::ZERO
                    } else if high {
                        self.c[i - grid.stride(a)]
                    } else {
                        self.c[i + grid.stride(a)]
                    };
                    let stuck = self.c[i] <= self.c_rlp[i] || inner < self.cfg.surface;
                    if !(into && stuck) {
                        return;
                    }
                    // only the closed part of the face stops grains (an opening lets them go)
                    let open = self.open_fraction(a, high, i);
                    let impulse = m.abs() * (R::ONE - open);
                    self.m[a][i] = if open > R::ZERO { m * open } else { R::ZERO };
                    for b in 0..D {
                        if b == a {
                            continue;
                        }
                        let rel = self.m[b][i] - self.c[i] * side.velocity[b];
                        let cut = match side.slip {
                            Slip::NoSlip => rel.abs(),
                            Slip::Slip => R::ZERO,
                            Slip::Friction(tan) => (tan * impulse).min(rel.abs()),
                        };
                        if rel > R::ZERO {
                            self.m[b][i] -= cut;
                        } else {
                            self.m[b][i] += cut;
                        }
                    }
                });
            }
        }
    }

    /// Lagged transport coefficients at the new c and old T.
    fn coefficients(&mut self) {
        let n = self.grid.len();
        for i in 0..n {
            let tr = closure::transport(
                &self.cfg.material,
                self.c_eff(i),
                self.t[i],
                self.c_rcp[i],
                self.c_rlp[i],
                self.cfg.t_min,
            );
            self.eta[i] = tr.eta;
            self.lam[i] = tr.lambda;
            self.eps[i] = tr.eps;
        }
    }

    /// With the share (implicit pressure): the transport's acceleration `(m/c - u^n)/dt` of
    /// this step into `hold`, before the pressure and gravity act; `viscous_done` adds the
    /// stress's. So `hold` is the step's acceleration from everything but the pressure and
    /// gravity, and in a steady flow it balances the cell's face forces (model.md 5.3).
    fn advective_hold(&mut self, dt: R) {
        let n = self.grid.len();
        let vac = self.cfg.vacuum;
        for a in 0..D {
            for i in 0..n {
                let c = self.c[i];
                self.hold[a][i] = if c > vac {
                    (self.m[a][i] / c - self.u_prev[a][i]) / dt
                } else {
                    R::ZERO
                };
            }
        }
    }

    fn velocity_from_momentum(&mut self) {
        let n = self.grid.len();
        let vac = self.cfg.vacuum;
        for i in 0..n {
            let c = self.c[i];
            for a in 0..D {
                self.u[a][i] = if c > vac { self.m[a][i] / c } else { R::ZERO };
            }
        }
    }

    /// Face coefficients `scale * mean(coef) / h_a^2` of the interior and wrap faces.
    fn face_coefficients(&mut self, use_lambda: bool, scale: R) {
        let n = self.grid.len();
        let h = self.grid.spacing();
        let grid = self.grid;
        let periodic = self.periodic();
        for a in 0..D {
            let k = scale * R::HALF / (h[a] * h[a]);
            let fb = grid.face_blocks(a);
            let s = fb.stride;
            let coef = if use_lambda { &self.lam } else { &self.eta };
            let kf = &mut self.kf[a];
            for b in 0..fb.blocks {
                let l0 = b * fb.block_stride;
                for l in l0..l0 + fb.block_len {
                    kf[l] = k * (coef[l] + coef[l + s]);
                }
            }
            grid.for_each_boundary_cell(a, true, |last, first| {
                kf[last] = if periodic[a] {
                    k * (coef[last] + coef[first])
                } else {
                    R::ZERO
                };
            });
            if self.walls.on {
                // the open part of each face (0 towards and between solid cells)
                for (k, w) in kf[..n].iter_mut().zip(&self.walls.ap_hi[a][..n]) {
                    *k *= *w;
                }
            }
        }
    }

    /// Boundary condition of velocity component `comp` at the boundary face of cell `i` on
    /// side `side` of axis `axis` (model.md 2), with the friction branch decided on the
    /// velocity at the start of the step (lagged).
    fn wall_face(&self, comp: usize, side: &FlowSide<R, D>, i: usize, axis: usize) -> Face<R> {
        match side.kind {
            Boundary::Inflow => Face::Value(side.velocity[comp]),
            Boundary::Outflow | Boundary::Periodic => Face::Free,
            Boundary::Wall if comp == axis => Face::Value(R::ZERO),
            Boundary::Wall => match side.slip {
                Slip::NoSlip => Face::Value(side.velocity[comp]),
                Slip::Slip => Face::Free,
                Slip::Friction(tan) => {
                    let (ui, uw) = (self.u_prev[comp][i], side.velocity[comp]);
                    let hw = self.grid.spacing()[axis] * R::HALF;
                    let w = self.eta[i] * (ui - uw).abs() / hw;
                    let limit = self.p[i] * tan;
                    if limit >= w {
                        Face::Value(uw)
                    } else if uw > ui {
                        Face::Stress(limit)
                    } else {
                        Face::Stress(-limit)
                    }
                }
            },
        }
    }

    /// Stage 3: one implicit solve per velocity component, then the viscous heating.
    ///
    /// The components' systems share the face coefficients and read the state at the start
    /// of the step only (the lagged wall laws read `u_prev`), so they are independent. On a
    /// fork with workers they solve on two at once, each with its own scratch (the second set
    /// is [`SpareSolve`](super::SpareSolve)): the vertical component on one, the horizontal
    /// ones on the other, one fork per step instead of several per CG iteration
    /// (docs/parallel.md, "Velocity components side by side"). Each solve is the same
    /// arithmetic either way, so the bits do not change. The objective stress doubles the
    /// component's own face coefficients in place, so it solves one component at a time.
    fn viscous<F: Fork, Re: Reach<R, D, N>>(&mut self, dt: R, fork: &F, reach: &mut Re) {
        let n = self.grid.len();
        let vac = self.cfg.vacuum;
        self.face_coefficients(false, R::ONE);
        // Velocity scale of the solver's absolute floor (a bed at rest must not chase
        // round-off): 1e-6 m/s or the fastest box wall, never the field's own speeds
        // (model.md 5.3, "Initial guess"). A fast cell there loosened every cell's tolerance,
        // and the extrapolated guess then repeated an accepted error each step: one cell of
        // the explicit tumbler gained 0.1 m/s per step, whatever dt, until T ran away.
        let u_ref = self.boundary_speed(R::from_f64(1e-6), reach);
        let own = reach.owned(n);
        let mass_norm = reach
            .sum_in_order(R::ZERO, |mut sum| {
                for i in own {
                    let cd = self.mass_factor(i) * self.c[i].max(vac) / dt;
                    sum += cd * cd;
                }
                sum
            })
            .sqrt();
        // Scale of the mass term `c u / dt` alone: the wall terms (yield viscosity up to
        // eta0 p_y / sqrt(T_min)) would make the floor meaninglessly large.
        let stop = Stop {
            relative: self.cfg.cg_tolerance,
            floor: mass_norm * u_ref,
            max_iterations: self.cfg.cg_max_iterations,
            preconditioner: Preconditioner::Auto,
        };
        let objective = self.cfg.stress == Stress::Objective;
        if !objective && D > 1 && fork.parts() > 1 && reach.whole() {
            // the horizontal components' systems into the spare set, the vertical one's
            // into `diag`, `rhs`
            for comp in 0..D - 1 {
                self.viscous_rows(comp, dt, false);
                let (diag, rhs) = if comp == 0 {
                    (&mut self.spare.diag, &mut self.spare.rhs)
                } else {
                    (&mut self.spare.diag2, &mut self.spare.rhs2)
                };
                diag[..n].copy_from_slice(&self.diag[..n]);
                rhs[..n].copy_from_slice(&self.rhs[..n]);
            }
            self.viscous_rows(D - 1, dt, false);
            for comp in 0..D {
                self.initial_guess(comp);
                self.rigid_guess(comp, false);
            }
            let iterations = self.solve_side_by_side(stop, fork);
            for (comp, it) in iterations.into_iter().enumerate() {
                self.rigid_guess(comp, true);
                self.viscous_done(comp, it, dt);
            }
        } else {
            for comp in 0..D {
                self.viscous_rows(comp, dt, objective);
                self.initial_guess(comp);
                self.rigid_guess(comp, false);
                let iterations = self.solve_component(comp, stop, fork, reach);
                self.rigid_guess(comp, true);
                if objective {
                    // back to eta_f ap / h^2 (a power of two: exact)
                    for k in self.kf[comp][..n].iter_mut() {
                        *k *= R::HALF;
                    }
                }
                self.viscous_done(comp, iterations, dt);
            }
        }
        self.heating();
    }

    /// The system of velocity component `comp` into `diag` and `rhs` (model.md 2): the mass
    /// term, the walls' terms and, with the objective stress, its lagged cross force and the
    /// doubled normal coefficient (which the caller halves after the solve).
    fn viscous_rows(&mut self, comp: usize, dt: R, objective: bool) {
        let n = self.grid.len();
        let h = self.grid.spacing();
        let grid = self.grid;
        let vac = self.cfg.vacuum;
        let periodic = self.periodic();
        // With an embedded wall the rows are content balances: mass terms times the open
        // volume (`walls`).
        for i in 0..n {
            let cd = self.mass_factor(i) * self.c[i].max(vac) / dt;
            self.diag[i] = cd;
            self.rhs[i] = cd * self.u[comp][i];
        }
        // Objective stress (model.md 2.6, module `objective`): the normal part of
        // `div(eta grad u^T)` doubles the component's own face coefficient (implicit), the
        // cross parts are a lagged face force.
        if objective {
            self.transposed_force(comp);
            for k in self.kf[comp][..n].iter_mut() {
                *k *= R::TWO;
            }
        }
        for axis in 0..D {
            if periodic[axis] {
                continue;
            }
            let k2 = R::TWO / (h[axis] * h[axis]);
            for (high, side) in [(false, self.bc[axis][0]), (true, self.bc[axis][1])] {
                grid.for_each_boundary_cell(axis, high, |i, _| {
                    // the closed share of the face (the open share is free: zero
                    // gradient), times the box face's aperture (cut-cell walls)
                    let shut = R::ONE - self.open_fraction(axis, high, i);
                    let wa = self.box_aperture(axis, high, i);
                    match self.wall_face(comp, &side, i, axis) {
                        Face::Value(v) => {
                            let mut k = wa * (k2 * self.eta[i] * shut);
                            if objective && comp == axis {
                                k *= R::TWO; // normal stress 2 eta d_n u_n
                            }
                            self.diag[i] += k;
                            self.rhs[i] += k * v;
                        }
                        Face::Stress(tau) => self.rhs[i] += wa * (tau * shut / h[axis]),
                        Face::Free => {}
                    }
                });
            }
        }
        if self.walls.on {
            // the cut wall fragment: towards u_B with the drag of the lagged wall law
            let on_master = self.walls_on_master();
            for i in 0..n {
                let kw = self.walls.wall_k[i];
                if kw > R::ZERO {
                    let (row, kw, ub, e) = self.wall_term(i, on_master);
                    let k = kw * e;
                    self.diag[row] += k;
                    self.rhs[row] += k * ub[comp];
                }
            }
            if self.turning_wall() {
                self.rigid_rhs(comp);
            }
        }
    }

    /// Whether the cut wall turns (a drum in the lab frame): then the velocity solves work on
    /// the flow relative to the wall's rigid motion `u_R` ([`Self::rigid_rhs`]).
    #[inline(always)]
    fn turning_wall(&self) -> bool {
        self.walls.on && self.walls.turns()
    }

    /// Shifts the system of component `comp` to the unknown `v = u - u_R`: `rhs -= A u_R`
    /// (model.md 5.3, "The solves' stopping rule in a turning drum"). Why: the solve stops at
    /// `|r| <= tol |b|`, and in the lab frame `|b|` is the rigid rotation's momentum
    /// `c u_R / dt`, which the solve need not find (the guess holds it); the stop then
    /// admitted errors of `tol` times the drum's speed in the flowing layer, and at the
    /// tumbler's `cg_tolerance` 1e-4 the 68 x 68 lab drum's surface lay 2.3 deg low at Courant
    /// 0.4 (19.45 against 21.48 deg at 0.2; 21.63 with 1e-6). With the shift the stop
    /// measures the flow the wall does not impose, as in the drum's own frame; the residual,
    /// and so the answer, is the same system's. Uses the CG scratch `p` and `ap` (free before
    /// the solve).
    fn rigid_rhs(&mut self, comp: usize) {
        let n = self.grid.len();
        for i in 0..n {
            self.solve.p[i] = self.walls.rigid_velocity(self.home_center(i))[comp];
        }
        let st = Stencil {
            grid: &self.grid,
            periodic: self.periodic(),
            kf: &self.kf,
        };
        st.residual(&self.diag, &self.rhs, &self.solve.p, &mut self.solve.ap);
        self.rhs[..n].copy_from_slice(&self.solve.ap[..n]);
    }

    /// With a turning wall, takes the wall's rigid motion out of the guess of component
    /// `comp` before its solve (`add` false) and puts it back after (`add` true), in the
    /// cells with content ([`Self::rigid_rhs`]).
    fn rigid_guess(&mut self, comp: usize, add: bool) {
        if !self.turning_wall() {
            return;
        }
        let n = self.grid.len();
        let vac = self.cfg.vacuum;
        for i in 0..n {
            if self.c[i] > vac {
                let ur = self.walls.rigid_velocity(self.home_center(i))[comp];
                let u = &mut self.u[comp][i];
                *u = if add { *u + ur } else { *u - ur };
            }
        }
    }

    /// The solve's start for component `comp` in `u` (model.md 5.3, "Initial guess"), once its
    /// right-hand side has read the explicit velocity there: `2 u^n - u^{n-1}`, or that
    /// velocity itself ([`VelocityGuess`]); 0 in empty cells either way.
    fn initial_guess(&mut self, comp: usize) {
        if self.cfg.guess != VelocityGuess::Extrapolated {
            return;
        }
        let n = self.grid.len();
        let vac = self.cfg.vacuum;
        let (now, before) = (&self.u_prev[comp][..n], &self.u_before[comp][..n]);
        for (i, u) in self.u[comp][..n].iter_mut().enumerate() {
            *u = if self.c[i] > vac {
                (now[i] + now[i]) - before[i]
            } else {
                R::ZERO
            };
        }
    }

    /// Solves the system in `diag`, `rhs` for component `comp`, its loops on `fork`.
    fn solve_component<F: Fork, Re: Reach<R, D, N>>(
        &mut self,
        comp: usize,
        stop: Stop<R>,
        fork: &F,
        reach: &mut Re,
    ) -> u32 {
        let st = Stencil {
            grid: &self.grid,
            periodic: self.periodic(),
            kf: &self.kf,
        };
        // `inflow` is dead between the transport and the heating (written after
        // the velocity solves, read into `rhs` before the temperature solve).
        // `flux` is not: it holds the step's applied face mass fluxes, which the
        // coupled driver carries phi with after the step.
        reach
            .solve(
                fork,
                &st,
                &self.diag,
                &self.rhs,
                &mut self.u[comp],
                self.solve.scratch(&mut self.inflow),
                stop,
            )
            .iterations
    }

    /// Solves every velocity component at once on two of `fork`'s items, each with its own
    /// scratch and half the fork's workers (on two threads: one each, its loops on its own
    /// thread): the vertical component (system in `diag`, `rhs`), usually the slowest to
    /// converge under gravity, on one, the horizontal ones (systems in the spare set) one
    /// after the other on the other. Returns the iterations per component.
    fn solve_side_by_side<F: Fork>(&mut self, stop: Stop<R>, fork: &F) -> [u32; D] {
        let st = Stencil {
            grid: &self.grid,
            periodic: self.periodic(),
            kf: &self.kf,
        };
        let (horizontal, vertical) = self.u.split_at_mut(D - 1);
        let spare = &mut self.spare;
        let mut items = [
            SolveItem {
                x: vertical,
                systems: [(&self.diag[..], &self.rhs[..]); 2],
                scratch: self.solve.scratch(&mut self.inflow),
                iterations: [0; 2],
            },
            SolveItem {
                x: horizontal,
                systems: [
                    (&spare.diag[..], &spare.rhs[..]),
                    (&spare.diag2[..], &spare.rhs2[..]),
                ],
                scratch: spare.set.scratch(&mut spare.tmp),
                iterations: [0; 2],
            },
        ];
        let half = Share::new(fork, fork.parts() / 2);
        fork.each(&mut items, |item| {
            for (k, x) in item.x.iter_mut().enumerate() {
                let (diag, rhs) = item.systems[k];
                let scratch = item.scratch.reborrow();
                item.iterations[k] =
                    cg::solve_on(&half, &st, diag, rhs, x, scratch, stop).iterations;
            }
        });
        let mut out = [0; D];
        out[..D - 1].copy_from_slice(&items[1].iterations[..D - 1]);
        out[D - 1] = items[0].iterations[0];
        out
    }

    /// After the solve of component `comp`: its iterations, the momentum `c u` (zero
    /// velocity in empty cells) and, with the viscous share, the step's viscous acceleration
    /// added to the transport's in `hold`.
    fn viscous_done(&mut self, comp: usize, iterations: u32, dt: R) {
        let n = self.grid.len();
        let vac = self.cfg.vacuum;
        let share = self.holds();
        self.last_cg[comp.min(2)] = iterations;
        self.cg_iterations += u64::from(iterations);
        for i in 0..n {
            if self.c[i] > vac {
                if share {
                    // the acceleration the stress gave the cell, added to the transport's
                    // (`advective_hold`), for the next step's face velocities
                    // (`implicit_face_velocity`); `m / c` is still `u*` bit for bit
                    // (`velocity_from_momentum`)
                    let before = self.m[comp][i] / self.c[i];
                    self.hold[comp][i] += (self.u[comp][i] - before) / dt;
                }
                self.m[comp][i] = self.c[i] * self.u[comp][i];
            } else {
                // (`hold` of an empty cell is 0 already: `advective_hold` saw the same c)
                self.u[comp][i] = R::ZERO;
                self.m[comp][i] = R::ZERO;
            }
        }
    }

    /// Discrete viscous heating `H = eta kappa:kappa` per cell into the `inflow` scratch: each
    /// face's dissipation `eta_f |du|^2 / h^2` is shared half and half by its two cells, so the
    /// heating equals the work of the discrete viscous operator. With the objective stress
    /// (model.md 2.6) each face and cut wall adds the work of the transposed part, so `H` is
    /// `2 eta D:D` (clipped at 0 per cell; module `objective`).
    fn heating(&mut self) {
        let n = self.grid.len();
        let h = self.grid.spacing();
        let grid = self.grid;
        let periodic = self.periodic();
        let objective = self.cfg.stress == Stress::Objective;
        self.inflow[..n].fill(R::ZERO);
        for a in 0..D {
            let fb = grid.face_blocks(a);
            let s = fb.stride;
            for b in 0..fb.blocks {
                let l0 = b * fb.block_stride;
                for l in l0..l0 + fb.block_len {
                    let w = R::HALF * self.kf[a][l] * self.jump2(l, l + s);
                    self.inflow[l] += w;
                    self.inflow[l + s] += w;
                }
            }
            if periodic[a] {
                for b in 0..fb.blocks {
                    let l0 = b * fb.block_stride;
                    for first in l0..l0 + s {
                        let last = first + fb.block_len;
                        let w = R::HALF * self.kf[a][last] * self.jump2(last, first);
                        self.inflow[last] += w;
                        self.inflow[first] += w;
                    }
                }
                continue;
            }
            let k4 = R::from_f64(4.0) / (h[a] * h[a]);
            for (high, side) in [(false, self.bc[a][0]), (true, self.bc[a][1])] {
                grid.for_each_boundary_cell(a, high, |i, _| {
                    let shut = R::ONE - self.open_fraction(a, high, i);
                    let wa = self.box_aperture(a, high, i);
                    let mut w = R::ZERO;
                    for comp in 0..D {
                        w += match self.wall_face(comp, &side, i, a) {
                            Face::Value(v) => {
                                let du = v - self.u[comp][i];
                                let w = k4 * self.eta[i] * du * du;
                                if objective && comp == a {
                                    w + w // the doubled normal stress
                                } else {
                                    w
                                }
                            }
                            Face::Stress(tau) => tau * tau / self.eta[i],
                            Face::Free => R::ZERO,
                        };
                    }
                    self.inflow[i] += wa * (R::HALF * w * shut);
                });
            }
        }
        if self.walls.on {
            // the work of the cut wall term `e A / (d |C|) (u_B - u)` (content units)
            let on_master = self.walls_on_master();
            for i in 0..n {
                let kw = self.walls.wall_k[i];
                if kw > R::ZERO {
                    let (row, kw, ub, e) = self.wall_term(i, on_master);
                    let mut du2 = R::ZERO;
                    for (comp, b) in ub.iter().enumerate() {
                        let d = *b - self.u[comp][row];
                        du2 += d * d;
                    }
                    self.inflow[row] += kw * e * du2;
                }
            }
        }
        if objective {
            self.objective_heating();
        }
    }

    /// Open aperture of the box face of cell `i` on side `high` of `axis` (1 without an
    /// embedded wall).
    #[inline(always)]
    fn box_aperture(&self, axis: usize, high: bool, i: usize) -> R {
        match (self.walls.on, high) {
            (false, _) => R::ONE,
            (true, true) => self.walls.ap_hi[axis][i],
            (true, false) => self.walls.ap_lo[axis][i],
        }
    }

    #[inline(always)]
    fn jump2(&self, l: usize, r: usize) -> R {
        let mut s = R::ZERO;
        for comp in 0..D {
            let d = self.u[comp][r] - self.u[comp][l];
            s += d * d;
        }
        s
    }

    /// Stage 4: implicit conduction and dissipation with the heating as source.
    ///
    /// With the implicit pressure the nearly empty cells (`c < surface`, which its time step
    /// does not watch) take no heating (model.md 5.4, "Dust under the implicit pressure"):
    /// their T then stays within what transport and conduction bring (the M-matrix), where
    /// their own heating, unchecked by the acoustic step, ran away (the 3D silo's dust to
    /// T = 3e12 and 1e6 m/s within 0.25 s).
    fn temperature_stage<F: Fork, Re: Reach<R, D, N>>(&mut self, dt: R, fork: &F, reach: &mut Re) {
        let n = self.grid.len();
        let h = self.grid.spacing();
        let grid = self.grid;
        let vac = self.cfg.vacuum;
        let a_heat = self.cfg.material.heating;
        // below this c a cell is not heated (0: every cell is)
        let heated = if self.cfg.pressure == PressureMode::Implicit {
            self.cfg.surface
        } else {
            R::ZERO
        };
        let periodic = self.periodic();
        let emb = self.walls.on;
        if emb {
            // A merge group is one cell: its members' heating heats the group (model.md 5.4,
            // "Heating of a merge group"). Booked in a member, the work of a whole wall
            // fragment went into a strip that may hold 1e-9 of a cell: beside the hopper's
            // orifice channel such strips ran hot, choked the orifice (2.5x too slow) or ran
            // away (docs/silo.md section 7).
            self.walls.gather_to_masters(n, &mut self.inflow);
        }
        for i in 0..n {
            let cd = self.c[i].max(vac);
            self.diag[i] = cd / dt + self.c[i] * self.eps[i];
            self.rhs[i] = self.e[i].max(R::ZERO) / dt;
            if emb {
                // content balance: mass and dissipation times the open volume
                let v = self.walls.mass_volume(i);
                self.diag[i] *= v;
                self.rhs[i] *= v;
            }
            if self.c[i] >= heated {
                self.rhs[i] += a_heat * self.inflow[i];
            }
        }
        self.face_coefficients(true, a_heat);
        for axis in 0..D {
            let k2 = a_heat * R::TWO / (h[axis] * h[axis]);
            for (high, side) in [(false, self.bc[axis][0]), (true, self.bc[axis][1])] {
                if side.kind != Boundary::Inflow {
                    continue; // walls and outflow: d_n T = 0; periodic: wrap faces
                }
                grid.for_each_boundary_cell(axis, high, |i, _| {
                    let k = self.box_aperture(axis, high, i) * (k2 * self.lam[i]);
                    self.diag[i] += k;
                    self.rhs[i] += k * side.t;
                });
            }
        }
        // No absolute floor: T spans many orders of magnitude between cells (and the
        // dissipation term of a resting cell is huge), so only the relative residual is a
        // meaningful target; a zero right-hand side returns T = 0 at once.
        let floor = R::ZERO;
        let st = Stencil {
            grid: &self.grid,
            periodic,
            kf: &self.kf,
        };
        let res = reach.solve(
            fork,
            &st,
            &self.diag,
            &self.rhs,
            &mut self.t,
            self.solve.scratch(&mut self.inflow),
            Stop {
                relative: self.cfg.cg_tolerance,
                floor,
                max_iterations: self.cfg.cg_max_iterations,
                preconditioner: Preconditioner::Auto,
            },
        );
        self.last_cg[3] = res.iterations;
        self.cg_iterations += u64::from(res.iterations);
        for i in 0..n {
            // The exact solution is >= 0 (M-matrix, rhs >= 0); clip the solver's round-off.
            if self.c[i] > vac {
                self.t[i] = self.t[i].max(R::ZERO);
            } else {
                self.t[i] = R::ZERO;
            }
            self.e[i] = self.c[i] * self.t[i];
        }
    }

    /// The fastest speed of a box side (wall or inflow), at least `floor`. From a subdomain,
    /// the largest over every subdomain: each side of the box is some subdomain's own, and
    /// the slip walls at its cuts are at rest.
    fn boundary_speed<Re: Reach<R, D, N>>(&self, floor: R, reach: &mut Re) -> R {
        let mut u_ref = floor;
        for sides in &self.bc {
            for s in sides {
                for v in s.velocity {
                    u_ref = u_ref.max(v.abs());
                }
            }
        }
        reach.max(u_ref)
    }

    fn step_residual<Re: Reach<R, D, N>>(&self, dt: R, reach: &mut Re) -> R {
        let n = self.grid.len();
        let u_ref = self.boundary_speed(R::from_f64(1e-3), reach);
        let mut du = R::ZERO;
        let mut umax = R::ZERO;
        for a in 0..D {
            for i in reach.owned(n) {
                if self.c[i] < self.cfg.surface {
                    continue;
                }
                du = du.max((self.u[a][i] - self.u_prev[a][i]).abs());
                umax = umax.max(self.u[a][i].abs());
            }
        }
        let (du, umax) = (reach.max(du), reach.max(umax));
        du / (dt * umax.max(u_ref))
    }
}

/// What the donor limiter of the transport may hand out of a cell holding `c` (content
/// units, or `c` itself on a plain grid): all but `SPARE_ULPS` machine epsilons of it.
///
/// Why not all of it: the limited outflows `df_k = fl(fl(lam f_k) * content / O)` (with `O`
/// the rounded sum of the `lam f_k`) and the update `c - df_1 + g_1 - df_2 ...` (inflows in
/// between, merge groups summed first and divided by the group volume) each round, and with
/// the whole content handed out those few half-ulps were enough to leave the cell below 0
/// (the implicit column collapse at `cg_tolerance = 1e-6`: c = 3.55e-12 drained to
/// -2.0e-28). Each of those `k` roundings moves the result by at most half an ulp of the
/// values involved (`<= c + inflows`), and the inflows only add, so a reserve of
/// `SPARE_ULPS eps c` larger than the count of rounded operations on one cell or merge group
/// (at most 7 members, 6 faces each in 3D, plus the sum and the division: well under 64)
/// keeps `c >= 0` exact whatever the face velocities are (model.md 5.3, `0 <= c` by
/// construction). The reserve also sets the threshold: an outflow within it of the content
/// is limited too (its rounded sum may hide the excess). What stays behind is
/// `~1.4e-14 c` (f64) or `~7.6e-6 c` (f32) of a cell that would have emptied.
#[inline(always)]
pub(super) fn spendable<R: Real>(c: R) -> R {
    c.max(R::ZERO) * (R::ONE - R::from_f64(SPARE_ULPS) * R::EPSILON)
}

/// Machine epsilons of a cell's content the donor limiter keeps back ([`spendable`]).
const SPARE_ULPS: f64 = 64.0;

/// Courant number of the Rhie-Chow time scales (model.md 5.3): per axis `a`,
/// `tau_a = (0.4 / D) / rate_a` ([`Flow::rhie_chow_rates`]), which in a state of equal
/// spacings and sound speed dominated rates is the stable step at the default
/// `flow.courant` 0.4, the correction's scale when it was the step itself.
const RHIE_CHOW_COURANT: f64 = 0.4;

/// Whether a side has boundary faces that move mass (inflow, outflow, or a wall with
/// openings).
pub(super) fn moves_mass<R: Real, const D: usize>(side: &FlowSide<R, D>) -> bool {
    matches!(side.kind, Boundary::Inflow | Boundary::Outflow)
        || (side.kind == Boundary::Wall && !side.openings.is_empty())
}

#[cfg(test)]
mod tests {
    use super::super::reach::Whole;
    use super::super::{CutWall, Flow, FlowConfig, FlowSide, PressureMode, Slip};
    use crate::closure::{self, Material};
    use crate::fork::Serial;
    use crate::geometry::{CutCells, Region, DEFAULT_SMALL};
    use crate::grid::Grid;

    const N: usize = 256;

    /// In a drum on cut cells, whose transport takes the main solve set as its increment
    /// scratch, the free-surface cap of the implicit pressure (`consistent_pressure`) is the
    /// linearised pressure about the start of the step's `p^n`, `c^n` and `a_s^2`,
    /// recomputed here from copies taken before the solve. (The defect fixed on 2026-12-06:
    /// the cap read the embedded transport's increments in their place.)
    #[test]
    fn free_surface_cap_reads_the_start_of_the_step_past_the_embedded_transport() {
        let n = 16;
        let radius = 0.05;
        let h = 2.0 * radius / (n as f64 - 2.0);
        let l = n as f64 * h;
        let grid = Grid::new([n, n], [-0.5 * l; 2], [l; 2], N).unwrap();
        let mut cut = CutCells::<f64, 2, N>::zeroed();
        cut.build(
            &grid,
            &Region::drum([0.0; 2], radius),
            [false; 2],
            DEFAULT_SMALL,
        )
        .unwrap();
        let mut cfg = FlowConfig::new(Material::glass_beads());
        cfg.pressure = PressureMode::Implicit;
        cfg.free_surface_push = true;
        // the cap alone: with the viscous share the thin layer of this set-up lands within
        // the cap, and the test would have nothing to compare
        cfg.viscous_share = false;
        let mut flow = Flow::<f64, 2, N>::zeroed();
        let side = FlowSide::wall(Slip::NoSlip);
        flow.setup(grid, [[side; 2]; 2], cfg).unwrap();
        flow.set_geometry(&cut, CutWall::resting(Slip::Friction(0.2)))
            .unwrap();
        // a bed under a thin falling layer: cells that fade and whose content changes
        for i in 0..grid.len() {
            let y = grid.center(i)[1];
            let c = if flow.open_volume(i) <= 0.0 {
                0.0
            } else if y < 0.0 {
                0.58
            } else if y < 2.0 * h {
                0.02
            } else {
                0.0
            };
            flow.set_cell(i, c, [0.0; 2], 0.0);
        }
        flow.prepare().unwrap();
        for _ in 0..3 {
            let dt = flow.stable_dt();
            flow.step(dt);
        }
        let dt = flow.stable_dt();
        let cells = grid.len();
        // the start of the step, as the solve sees it
        flow.pressures();
        let (p0, c0) = (flow.p, flow.c);
        let floor = flow.sound_floor(dt);
        let mut a2 = [0.0; N];
        for (i, a) in a2.iter_mut().enumerate().take(cells) {
            let s = closure::sound_speed_squared(
                &flow.cfg.material,
                flow.c_eff(i),
                flow.t[i],
                flow.c_rcp[i],
                flow.c_rlp[i],
            );
            *a = s.max(floor);
        }
        flow.implicit_pressure(dt, &Serial, &mut Whole);
        flow.transport(dt, &mut Whole);
        let mut expected = flow.p;
        let mut capped = 0;
        for i in 0..cells {
            let fade = 1.0 - (flow.c[i] / flow.cfg.surface).min(1.0);
            if fade > 0.0 {
                let pc = (p0[i] + a2[i] * (flow.c[i] - c0[i])).max(0.0);
                let excess = (expected[i] - pc).max(0.0);
                if excess > 0.0 && flow.c[i] != c0[i] {
                    capped += 1;
                }
                expected[i] -= fade * excess;
            }
        }
        flow.consistent_pressure();
        assert!(
            capped > 0,
            "no faded cell was capped: the test would not bite"
        );
        for i in 0..cells {
            assert_eq!(flow.p[i], expected[i], "cell {i} of {capped} capped");
        }
    }
}
