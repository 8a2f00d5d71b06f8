//! The segregation step on cut cells (issue 8): the same face fluxes as the box step
//! (model.md 5), weighted by the open aperture of each face, and the cell update divided by
//! the open (group) volume through the merging of [`CutCells`].
//!
//! # Design: the geometry is passed in, the solver does not grow
//!
//! `Segregation` keeps no geometry: [`Segregation::prepare_embedded`],
//! [`Segregation::stable_dt_embedded`], [`Segregation::step_embedded`] and
//! [`Segregation::advance_to_embedded`] take a `&CutCells` built on the same grid. So box
//! scenes run exactly the code, the bits and the speed they had, and the firmware's
//! 1024-cell f32 solver is not a byte larger. With [`CutCells::full`] (no walls) the embedded
//! step gives the box step's bits (the face loop adds the same terms in the same order and
//! a full cell is updated by `q + dq / 1`; tested).
//!
//! # What holds, and why
//!
//! - **Fluxes through apertures**: every face flux (transport, segregation, diffusion) is
//!   multiplied by its face's open fraction in one place, `aperture_flux`; the cut wall
//!   itself carries nothing (it is not a face); solid cells have closed faces and are never
//!   updated.
//! - **Mass to round-off**: a face flux leaves one cell with the value it enters the other;
//!   the increments are contents `d(V q)` and each group divides their sum by its volume.
//! - **`0 <= phi <= c` by construction**, for u = 0 or a discretely divergence-free face
//!   velocity: a group is one finite volume with uniform phi and c ([`prepare_embedded`]
//!   averages both over each group), and its update is the box update with face weights
//!   `a_f |face_f| / (V_G |C|)`; the modified flux keeps the bounds when the weighted Courant
//!   sum is at most 1, which [`stable_dt_embedded`] enforces. With a *prescribed* velocity
//!   that is not divergence-free on the cut faces (a solid-body rotation sampled at cell
//!   centres, say) phi/c is not bounded by the scheme, because c does not move with it: the
//!   coupled flow's own face mass fluxes are needed for that.
//! - **Time step**: `dt = C / max_G rate_G` with
//!   `rate_G = sum_{outer faces f of G} A_f [ (|u_a| + |S_a|)/(2 h_a) + D/h_a^2 ]_{cell of f}
//!   / V_G` (faces between members of a group are left out: their fluxes cancel in the
//!   group's sum), which is the box rate for a full cell. Merging bounds `V_G >= small`
//!   (1/2), and a small cell's large apertures face its master, so tiny cut cells do not
//!   shrink the step: in the tested drums (cells down to 9e-7 of a cell) the step is the box
//!   step (measured in tests/tests/segregation_embedded.rs).
//!
//! - Compensated updates ([`super::SegregationConfig::compensated`]) are not used here.
//!
//! [`prepare_embedded`]: Segregation::prepare_embedded
//! [`stable_dt_embedded`]: Segregation::stable_dt_embedded

use super::step::{face, AxisConst, Godunov, Kernel, Modified, Percolation, Side, Slices, Upwind};
use super::{Scheme, Segregation, SetupError};
use crate::boundary::Boundary;
use crate::fork::Call;
use crate::geometry::CutCells;
use crate::hot::{Baseline, Isa};
use crate::real::Real;
use core::ops::Range;

/// A face flux weighted by its open fraction: the one place where the aperture enters the
/// segregation step. A closed face gives `0 * flux = 0` (the flux of a validated state is
/// finite, solid cells included), without a branch, so the face loop vectorises; a full
/// face gives the box flux to the bit (`f * 1 = f`).
#[inline(always)]
fn aperture_flux<R: Real, K: Kernel<R>, const DIFFUSE: bool>(
    aperture: R,
    l: Side<R>,
    r: Side<R>,
    ax: AxisConst<R>,
) -> R {
    face::<R, K, DIFFUSE>(l, r, ax) * aperture
}

/// The interior faces of one block (as the box step's `interior_block`, with apertures):
/// stores each weighted face flux and subtracts it from its left cell. Inlined into a hot
/// loop of the step's `Isa` (one out-of-line function at `Baseline`, as before).
#[inline(always)]
fn interior_block<R: Real, K: Kernel<R>, const DIFFUSE: bool, const FIRST: bool>(
    out: &mut [R],
    rhs: &mut [R],
    ap: &[R],
    left: Slices<'_, R>,
    right: Slices<'_, R>,
    ax: AxisConst<R>,
) {
    let len = out.len();
    let (rhs, ap) = (&mut rhs[..len], &ap[..len]);
    let (left, right) = (left.truncated(len), right.truncated(len));
    for j in 0..len {
        let f = aperture_flux::<R, K, DIFFUSE>(ap[j], left.get(j), right.get(j), ax);
        out[j] = f;
        if FIRST {
            rhs[j] = -f;
        } else {
            rhs[j] -= f;
        }
    }
}

impl<R: Real, const D: usize, const N: usize> Segregation<R, D, N> {
    fn check_geometry(&self, geo: &CutCells<R, D, N>) -> Result<(), SetupError> {
        if geo.grid() != &self.grid {
            return Err(SetupError::Parameter("geometry: built on another grid"));
        }
        for a in 0..D {
            if geo.periodic()[a] != (self.bc[a][0] == Boundary::Periodic) {
                return Err(SetupError::Parameter(
                    "geometry: periodic axes differ from the boundaries",
                ));
            }
        }
        Ok(())
    }

    /// [`Self::prepare`] on cut cells: checks that `geo` was built on this grid with the same
    /// periodic axes, replaces c and phi of every merged group by their volume-weighted means
    /// (content kept to round-off; a group is one finite volume), then validates and derives
    /// the coefficients. Solid cells keep whatever they hold and never change.
    pub fn prepare_embedded(&mut self, geo: &CutCells<R, D, N>) -> Result<(), SetupError> {
        self.check_geometry(geo)?;
        self.merge_group_states(geo);
        self.prepare()
    }

    /// [`Self::prepare_embedded`] for a subdomain that owns the cells `owned`
    /// ([`Self::prepare_owned_with`]): the groups' states, then the coefficients with the
    /// rates and maxima of the owned cells (on cut cells: of the groups whose master it owns).
    pub fn prepare_embedded_owned_with<F: crate::fork::Fork>(
        &mut self,
        geo: &CutCells<R, D, N>,
        fork: &F,
        owned: Range<usize>,
    ) -> Result<(), SetupError> {
        self.check_geometry(geo)?;
        self.merge_group_states(geo);
        self.prepare_owned_with(fork, owned)
    }

    /// Every merge group one state (module docs), the compensated carry cleared.
    fn merge_group_states(&mut self, geo: &CutCells<R, D, N>) {
        let n = self.grid.len();
        for m in 0..n {
            if !geo.has_merged(m) {
                continue;
            }
            let (members, len) = geo.group(m);
            let members = &members[..len];
            // already one state (a repeated prepare): change no bit
            if members
                .iter()
                .all(|&j| self.c[j] == self.c[m] && self.q[j] == self.q[m])
            {
                continue;
            }
            // phi, not the tracked fraction: for the large phase psi = c - phi follows c.
            // The rounded means are monotone, so 0 <= phi <= c per cell gives it per group.
            let (mut content_c, mut content_phi) = (R::ZERO, R::ZERO);
            for &j in members {
                content_c += geo.volume(j) * self.c[j];
                content_phi += geo.volume(j) * self.phi(j);
            }
            let c = content_c / geo.group_volume(m);
            let phi = content_phi / geo.group_volume(m);
            for &j in members {
                self.c[j] = c;
                self.q[j] = self.tracked(phi, c);
            }
        }
        for i in 0..n {
            self.carry[i] = R::ZERO;
        }
    }

    /// The largest stable step on cut cells (`R::MAX` if nothing moves); see the module docs.
    pub fn stable_dt_embedded(&self, geo: &CutCells<R, D, N>) -> R {
        self.embedded_dt(geo, true)
    }

    /// [`Self::stable_dt_percolation`] on cut cells: the limit of
    /// [`Self::step_percolation_embedded_on`] alone (no transport term; the carried transport
    /// [`Self::carry_mass_fluxes_embedded`] keeps the bounds with the flow's donor limiter
    /// on groups, at any Courant number of the flow).
    pub fn stable_dt_percolation_embedded(&self, geo: &CutCells<R, D, N>) -> R {
        self.embedded_dt(geo, false)
    }

    /// The rate of the faces of every group over its volume, with or without the transport
    /// term `|u_a|`.
    fn embedded_dt(&self, geo: &CutCells<R, D, N>, transport: bool) -> R {
        let n = self.grid.len();
        let h = self.grid.spacing();
        let cells = self.grid.cells();
        let dcoef = self.cfg.diffusion;
        let mut rate = R::ZERO;
        // the rate of one member's faces along a, given its open outer aperture sum
        let face_rate = |a: usize, j: usize, open: R| {
            let s = (self.k[a][j] * self.c[j]).abs();
            let u = if transport {
                self.u[a][j].abs()
            } else {
                R::ZERO
            };
            open * R::HALF * (u + s) / h[a] + open * dcoef / (h[a] * h[a])
        };
        // integer coordinates advanced like an odometer (no division per cell)
        let mut coords = [0usize; D];
        // a subdomain's rate counts the groups whose master it owns
        let owned = self.tally.0..self.tally.1;
        for m in 0..n {
            let here = coords;
            for a in 0..D {
                coords[a] += 1;
                if coords[a] < cells[a] {
                    break;
                }
                coords[a] = 0;
            }
            if geo.is_solid(m) || geo.is_merged(m) || !owned.contains(&m) {
                continue;
            }
            let mut sum = R::ZERO;
            if !geo.has_merged(m) {
                for a in 0..D {
                    let low = if here[a] > 0 {
                        geo.apertures(a)[m - self.grid.stride(a)]
                    } else {
                        geo.aperture_low(a, m)
                    };
                    sum += face_rate(a, m, low + geo.aperture(a, m));
                }
            } else {
                let (members, len) = geo.group(m);
                for &j in &members[..len] {
                    for a in 0..D {
                        // the group's outer faces only: fluxes between its members cancel
                        let mut open = R::ZERO;
                        for high in [false, true] {
                            let inner = geo
                                .neighbour(j, a, high)
                                .is_some_and(|nb| geo.master(nb) == m);
                            if !inner {
                                open += if high {
                                    geo.aperture(a, j)
                                } else {
                                    geo.aperture_low(a, j)
                                };
                            }
                        }
                        sum += face_rate(a, j, open);
                    }
                }
            }
            rate = rate.max(sum / geo.group_volume(m));
        }
        if rate > R::ZERO {
            self.cfg.courant / rate
        } else {
            R::MAX
        }
    }

    /// One explicit step of length `dt` (at most [`Self::stable_dt_embedded`]) on cut cells.
    pub fn step_embedded(&mut self, dt: R, geo: &CutCells<R, D, N>) {
        self.step_embedded_on::<Baseline>(dt, geo);
    }

    /// [`Self::step_embedded`] with its face blocks run by `I` (compiled for its instruction
    /// set; the same bits for every `I`, docs/simd.md).
    pub fn step_embedded_on<I: Isa>(&mut self, dt: R, geo: &CutCells<R, D, N>) {
        debug_assert!(self.prepared, "prepare_embedded() must follow any change");
        debug_assert!(self.check_geometry(geo).is_ok());
        match (self.cfg.scheme, self.cfg.diffusion > R::ZERO) {
            (Scheme::Modified, false) => self.embedded_with::<I, Modified, false>(dt, geo),
            (Scheme::Modified, true) => self.embedded_with::<I, Modified, true>(dt, geo),
            (Scheme::Godunov, false) => self.embedded_with::<I, Godunov, false>(dt, geo),
            (Scheme::Godunov, true) => self.embedded_with::<I, Godunov, true>(dt, geo),
            (Scheme::Upwind, false) => self.embedded_with::<I, Upwind, false>(dt, geo),
            (Scheme::Upwind, true) => self.embedded_with::<I, Upwind, true>(dt, geo),
        }
        self.time += dt;
        self.steps += 1;
    }

    /// [`Self::step_percolation`] on cut cells: the segregation (and diffusion) flux alone,
    /// the transport being carried by the flow's face mass fluxes
    /// ([`Self::carry_mass_fluxes_embedded`]). Its face blocks run by `I` (the same bits for
    /// every `I`).
    pub fn step_percolation_embedded_on<I: Isa>(&mut self, dt: R, geo: &CutCells<R, D, N>) {
        debug_assert!(self.prepared, "prepare_embedded() must follow any change");
        debug_assert!(self.check_geometry(geo).is_ok());
        type P<K> = Percolation<K>;
        match (self.cfg.scheme, self.cfg.diffusion > R::ZERO) {
            (Scheme::Modified, false) => self.embedded_with::<I, P<Modified>, false>(dt, geo),
            (Scheme::Modified, true) => self.embedded_with::<I, P<Modified>, true>(dt, geo),
            (Scheme::Godunov, false) => self.embedded_with::<I, P<Godunov>, false>(dt, geo),
            (Scheme::Godunov, true) => self.embedded_with::<I, P<Godunov>, true>(dt, geo),
            (Scheme::Upwind, false) => self.embedded_with::<I, P<Upwind>, false>(dt, geo),
            (Scheme::Upwind, true) => self.embedded_with::<I, P<Upwind>, true>(dt, geo),
        }
        self.time += dt;
        self.steps += 1;
    }

    /// [`Self::advance_to`] on cut cells.
    pub fn advance_to_embedded(
        &mut self,
        t_end: R,
        max_steps: u64,
        geo: &CutCells<R, D, N>,
    ) -> u64 {
        self.advance_to_embedded_on::<Baseline>(t_end, max_steps, geo)
    }

    /// [`Self::advance_to_embedded`] with every step's face blocks run by `I`.
    pub fn advance_to_embedded_on<I: Isa>(
        &mut self,
        t_end: R,
        max_steps: u64,
        geo: &CutCells<R, D, N>,
    ) -> u64 {
        if !t_end.is_finite() {
            return 0;
        }
        let dt = self.stable_dt_embedded(geo);
        let slack = super::snap_slack(t_end);
        let mut taken = 0;
        while self.time < t_end && taken < max_steps {
            let remaining = t_end - self.time;
            if super::lands_on_target(remaining, dt, slack) {
                self.step_embedded_on::<I>(remaining, geo);
                self.time = t_end;
            } else {
                self.step_embedded_on::<I>(dt, geo);
            }
            taken += 1;
        }
        taken
    }

    fn embedded_with<I: Isa, K: Kernel<R>, const DIFFUSE: bool>(
        &mut self,
        dt: R,
        geo: &CutCells<R, D, N>,
    ) {
        let h = self.grid.spacing();
        let n = self.grid.len();
        for axis in 0..D {
            let ax = AxisConst {
                lambda: dt / h[axis],
                diffusion: self.cfg.diffusion / h[axis],
                vacuum: self.cfg.vacuum,
            };
            self.embedded_axis::<I, K, DIFFUSE>(axis, ax, axis == 0, geo);
        }
        let (q, dq) = (&mut self.q[..n], &self.rhs[..n]);
        geo.apply_increment(q, dq);
        let (mut above, mut below) = (self.excess[0], self.excess[1]);
        // the bounds of a subdomain's owned cells only (its halo rows may overshoot)
        for i in self.tally.0.min(n)..self.tally.1.min(n) {
            if !geo.is_solid(i) {
                above = above.max(self.q[i] - self.c[i]);
                below = below.max(-self.q[i]);
            }
        }
        self.excess = [above, below];
        self.flush_groups(geo);
    }

    /// The flush of [`SegregationConfig::flush_below`](super::SegregationConfig) on cut cells:
    /// per merge group (one control volume), its content counted with the group's open volume.
    fn flush_groups(&mut self, geo: &CutCells<R, D, N>) {
        let floor = self.cfg.flush_below;
        if floor <= R::ZERO || self.steps % super::step::FLUSH_EVERY != 0 {
            return;
        }
        let all = 0..self.grid.len();
        // same additions in the same order as a running `self.flushed += ...`
        let mut total = self.flushed;
        self.flush_groups_in(geo, floor, all.clone(), all, |_, x| total += x);
        self.flushed = total;
    }

    /// Zeroes every group whose master lies in `masters` and whose content is a nonzero
    /// below `floor`, handing `q V_group` of those whose master lies in `counted` to
    /// `flushed` in cell order; then copies masters to their members. One loop for the
    /// serial flush (all cells) and a subdomain's (its owned rows and one row beside).
    fn flush_groups_in(
        &mut self,
        geo: &CutCells<R, D, N>,
        floor: R,
        masters: Range<usize>,
        counted: Range<usize>,
        mut flushed: impl FnMut(usize, R),
    ) {
        let mut any = false;
        for i in masters {
            if geo.is_solid(i) || geo.master(i) != i {
                continue;
            }
            let v = self.q[i];
            if v != R::ZERO && v.abs() < floor {
                if counted.contains(&i) {
                    flushed(i, v * geo.group_volume(i));
                }
                self.q[i] = R::ZERO;
                any = true;
            }
        }
        if any {
            let n = self.grid.len();
            geo.copy_from_masters(&mut self.q[..n]);
        }
    }

    /// [`Self::end_owned_step`] on cut cells: the running bound maxima `excess` and the
    /// flush of vanishing fractions (docs/model.md 5.6) per merge group, exactly as
    /// [`Self::step_embedded`] does them after step number `steps_before`, for a subdomain
    /// that steps with the flush off. Every group with a member among the owned cells is
    /// flushed (its master is at most one row away, and the halo holds it to the bit), so
    /// that an owned cell merged into a master across the cut changes as the global one
    /// does; only the groups whose master is owned hand their content `q V_group` to
    /// `flushed`, in cell order, as the global step adds them to its counter.
    pub fn end_owned_step_embedded(
        &mut self,
        geo: &CutCells<R, D, N>,
        floor: R,
        steps_before: u64,
        excess: &mut [R; 2],
        flushed: impl FnMut(usize, R),
    ) {
        *excess = [excess[0].max(self.excess[0]), excess[1].max(self.excess[1])];
        if floor <= R::ZERO || steps_before % super::step::FLUSH_EVERY != 0 {
            return;
        }
        let n = self.grid.len();
        let plane = n / self.grid.cells()[D - 1].max(1);
        let owned = self.tally.0.min(n)..self.tally.1.min(n);
        let near = owned.start.saturating_sub(plane)..(owned.end + plane).min(n);
        self.flush_groups_in(geo, floor, near, owned, flushed);
    }

    /// The content increments along `axis`, in the box step's order per cell (minus the
    /// high-face flux, then plus the low-face flux), so that full cells reproduce its bits.
    fn embedded_axis<I: Isa, K: Kernel<R>, const DIFFUSE: bool>(
        &mut self,
        axis: usize,
        ax: AxisConst<R>,
        first: bool,
        geo: &CutCells<R, D, N>,
    ) {
        let fb = self.grid.face_blocks(axis);
        let s = fb.stride;
        let ap = geo.apertures(axis);
        for b in 0..fb.blocks {
            let l0 = b * fb.block_stride;
            let len = fb.block_len;
            let slices = |at: usize| {
                Slices::new(
                    &self.q,
                    &self.c,
                    &self.k[axis],
                    &self.temp,
                    &self.u[axis],
                    at,
                    len,
                )
            };
            let (left, right) = (slices(l0), slices(l0 + s));
            let (out, rhs) = (&mut self.flux[l0..l0 + len], &mut self.rhs[l0..l0 + len]);
            let ap = &ap[l0..l0 + len];
            if first {
                I::run(Call(
                    #[inline(always)]
                    || interior_block::<R, K, DIFFUSE, true>(out, rhs, ap, left, right, ax),
                ));
            } else {
                I::run(Call(
                    #[inline(always)]
                    || interior_block::<R, K, DIFFUSE, false>(out, rhs, ap, left, right, ax),
                ));
            }
        }
        let high = self.bc[axis][1];
        let low = self.bc[axis][0];
        let grid = self.grid;
        let (book_low, book_high) = (self.books_side(axis, 0), self.books_side(axis, 1));
        grid.for_each_boundary_cell(axis, true, |last, first_cell| {
            let f = match high {
                Boundary::Wall => R::ZERO,
                Boundary::Periodic => aperture_flux::<R, K, DIFFUSE>(
                    ap[last],
                    self.side(axis, last),
                    self.side(axis, first_cell),
                    ax,
                ),
                kind => aperture_flux::<R, K, DIFFUSE>(
                    ap[last],
                    self.side(axis, last),
                    self.ghost_side(axis, last, kind),
                    ax,
                ),
            };
            self.flux[last] = f;
            if first {
                self.rhs[last] = -f;
            } else {
                self.rhs[last] -= f;
            }
            if book_high {
                let small = self.small_across::<K, DIFFUSE>(axis, last, f, ap[last], ax);
                self.book_side(axis, 1, last, -small);
            }
        });
        if low != Boundary::Wall {
            grid.for_each_boundary_cell(axis, false, |first_cell, last| {
                let f = match low {
                    Boundary::Periodic => self.flux[last],
                    kind => aperture_flux::<R, K, DIFFUSE>(
                        geo.aperture_low(axis, first_cell),
                        self.ghost_side(axis, first_cell, kind),
                        self.side(axis, first_cell),
                        ax,
                    ),
                };
                self.rhs[first_cell] += f;
                if book_low {
                    let ap = geo.aperture_low(axis, first_cell);
                    let small = self.small_across::<K, DIFFUSE>(axis, first_cell, f, ap, ax);
                    self.book_side(axis, 0, first_cell, small);
                }
            });
        }
        for b in 0..fb.blocks {
            let l0 = b * fb.block_stride;
            let len = fb.block_len;
            let (src, dst) = (
                &self.flux[l0..l0 + len],
                &mut self.rhs[l0 + s..l0 + s + len],
            );
            for (dq, f) in dst.iter_mut().zip(src.iter()) {
                *dq += *f;
            }
        }
    }
}
