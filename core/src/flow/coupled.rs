//! Coupling of the flow ([`Flow`]) to the segregation equation ([`Segregation`]), model.md
//! sections 2-4, in the three modes a scene chooses from (issue 3).
//!
//! Each coupled step hands `u, c, T` and the current `phi` of every cell to the segregation
//! solver (`set_cell` + `prepare`, which also derives the segregation direction from the
//! velocity gradient if its [`crate::DirectionMode`] is `Flow`), advances both with the same
//! `dt = min(flow limit, percolation Courant limit)` ([`Coupled::stable_dt`]), and, with back-coupling on, replaces the
//! packing constants of the flow by `c_rcp(phihat)`, `c_rlp(phihat)` of model.md 4.
//!
//! **Coupled step** (issue 10): phi rides on the flow's own mass fluxes. One step of length
//! `dt` is
//! 1. the percolation stage: the segregation flux alone ([`Segregation::step_percolation`],
//!    modified Godunov, model.md 5) with the `c`, `T` and direction of the last hand-over, so
//!    the Courant limit that chose `dt` is the one that holds;
//! 2. the flow step, which records its final, limited face mass fluxes
//!    ([`Flow::mass_fluxes`]);
//! 3. the carried transport ([`Segregation::carry_mass_fluxes`]): each face moves
//!    `F phihat_donor` of the small grains and `F (1 - phihat_donor)` of the large ones, so
//!    `0 <= phi <= c` holds exactly by construction (proof in that module) and the small
//!    grains go exactly where the flow's limiters let the grains go;
//! 4. back-coupling of the packing limits, and the hand-over of `T` and `u` (not `c`: the
//!    segregation solver keeps its carried `c = phi + psi`, equal to the flow's `c` up to
//!    round-off, [`Coupled::c_mismatch`]).
//!
//! There is no clipping: the small-grain mass in the box plus what left through the sides
//! ([`Coupled::discharged_small`]) equals the initial mass to round-off. (Before, phi was
//! transported by the segregation solver's own upwind rule and clipped into `[0, c]` where
//! the flow's limiter had cut a face flux: column-collapse lost 0.265 % of its small grains.)
//! Lie splitting (segregation, then transport) is first order in time like each stage.
//!
//! **On slabs of rows** the same step runs with the serial bits ([`Coupled::step_with_reaching`]
//! with a [`super::slab::Slab`]; a slab is set up by [`super::coupled_slab::load_coupled_slab`]
//! and [`Coupled::on_slab`]; docs/parallel.md, "The coupled step on slabs").

use super::reach::{Reach, Whole};
use super::{Flow, FlowError};
use crate::closure::Packing;
use crate::fork::{Fork, Serial};
use crate::geometry::CutCells;
use crate::real::Real;
use crate::segregation::{Discharge, Segregation, SetupError};

/// Most sub-steps of the percolation stage within one coupled step ([`Coupled::step_with`]).
/// The percolation stage costs a few per cent of a flow step (no linear solve), and its limit
/// is held by the hottest dilute cells (`S = S0 sqrt(T) g` with `T ~ 1e-2 m^2/s^2` over the
/// tumbler's free surface: ~1 m/s), often below the flow's; sub-steps keep it from holding
/// the flow. The cap keeps a coupled step from outrunning the segregation by much.
pub const PERCOLATION_SUBSTEPS: usize = 8;

/// How the flow is modelled in a scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Mode {
    /// No flow solve: the segregation solver runs on the fields it was given.
    #[default]
    Prescribed,
    /// The flow is solved until its steady-state residual falls below the tolerance, then
    /// frozen (handed over once) while segregation goes on with its own, larger time step.
    Frozen,
    /// Flow and segregation advance together with a common step.
    Coupled,
}

/// Coupling options.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CouplingConfig<R> {
    /// Modelling mode.
    pub mode: Mode,
    /// Back-coupling of the packing limits (`Packing::Constant` = off).
    pub packing: Packing,
    /// Steady-state tolerance on [`Flow::residual`] (1/s) (frozen mode).
    pub steady_tolerance: R,
    /// Least number of flow steps before the residual test counts (skips the first, quiet
    /// steps of a start from rest).
    pub min_flow_steps: u64,
    /// Flow steps allowed to reach the steady state.
    pub max_flow_steps: u64,
}

impl<R: Real> CouplingConfig<R> {
    /// `mode`, back-coupling off, tolerance 1e-3 1/s, 50 to 200000 flow steps.
    pub fn new(mode: Mode) -> Self {
        Self {
            mode,
            packing: Packing::Constant,
            steady_tolerance: R::from_f64(1e-3),
            min_flow_steps: 50,
            max_flow_steps: 200_000,
        }
    }
}

/// Why a coupled run stopped.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CouplingError {
    /// The two solvers do not share a grid.
    GridMismatch,
    /// The flow rejected its fields.
    Flow(FlowError),
    /// The segregation solver rejected the handed-over fields.
    Segregation(SetupError),
    /// The flow did not reach the steady-state tolerance within `max_flow_steps`
    /// (carries the last residual).
    NotSteady(R64),
    /// Cut-cell walls need the coupled mode (the flow's face mass fluxes carry phi).
    GeometryNeedsCoupled,
    /// A run on slabs of rows needs the coupled mode.
    SlabsNeedCoupled,
    /// Another slab of a run on slabs stopped (its own error says why).
    OtherSlab,
    /// The flow has cut-cell walls and no geometry was given to the segregation, or the
    /// other way round.
    GeometryMismatch,
}

impl CouplingError {
    /// The same error with the cell it names counted `offset` cells later: a slab's cell in
    /// the whole grid's numbering (`SlabPlan::global_cells` minus `owned_cells`), as the
    /// serial run names it.
    pub fn offset_cell(self, offset: usize) -> Self {
        match self {
            CouplingError::Flow(e) => CouplingError::Flow(e.offset_cell(offset)),
            CouplingError::Segregation(e) => CouplingError::Segregation(e.offset_cell(offset)),
            other => other,
        }
    }
}

/// A residual as f64 (keeps [`CouplingError`] non-generic).
pub type R64 = f64;

/// The running totals of a [`Coupled`] driver ([`Coupled::totals`], [`Coupled::resume`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CoupledTotals<R, const D: usize> {
    /// Small-grain volume out through each side.
    pub out_small: [[R; 2]; D],
    /// Grain volume out through each side, as carried.
    pub out_total: [[R; 2]; D],
    /// Tracked-phase volume added by the round-off guard.
    pub guarded: R,
}

/// What the driver of a slab takes from the whole run's ([`Coupled::slab_start`],
/// [`Coupled::on_slab`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SlabStart<R, const D: usize> {
    /// The coupling.
    pub coupling: CouplingConfig<R>,
    /// The whole run's totals so far.
    pub totals: CoupledTotals<R, D>,
    /// The segregation's flush floor (the slab's own solver steps with the flush off).
    pub floor: R,
}

/// The driver; borrows both (large) solvers.
pub struct Coupled<'a, R: Real, const D: usize, const N: usize> {
    /// The flow.
    pub flow: &'a mut Flow<R, D, N>,
    /// The segregation solver.
    pub seg: &'a mut Segregation<R, D, N>,
    cfg: CouplingConfig<R>,
    frozen: bool,
    flow_steps_to_steady: u64,
    guarded: R,
    out_small: [[R; 2]; D],
    out_total: [[R; 2]; D],
    last: Option<Discharge<R, D>>,
    /// Cut-cell walls (coupled mode only): the flow carries them itself
    /// ([`Flow::set_geometry`]); the segregation runs its embedded step on them.
    geo: Option<&'a CutCells<R, D, N>>,
    /// The percolation stage's limit as of the last [`Self::prepare_segregation`]: the
    /// driver's `stable_dt` and the step both read it, and on cut cells it is a pass over
    /// every cell (once per step, not twice).
    percolation_dt: R,
    /// On a slab ([`Self::on_slab`]): the flush floor of the segregation
    /// (docs/model.md 5.6), applied by this driver to the owned cells, since the slab's
    /// solver steps with the flush off (its halo rows must not flush). 0 on the whole grid.
    slab_floor: R,
}

impl<'a, R: Real, const D: usize, const N: usize> Coupled<'a, R, D, N> {
    /// [`Self::new`] for a container with cut-cell walls (coupled mode): the flow must have
    /// been given the same geometry ([`Flow::set_geometry`]); the segregation solver then runs
    /// its percolation on cut cells and carries phi on the flow's aperture-weighted face
    /// mass fluxes, group by group ([`Segregation::carry_mass_fluxes_embedded`]).
    pub fn new_embedded(
        flow: &'a mut Flow<R, D, N>,
        seg: &'a mut Segregation<R, D, N>,
        cfg: CouplingConfig<R>,
        geo: &'a CutCells<R, D, N>,
    ) -> Result<Self, CouplingError> {
        if cfg.mode != Mode::Coupled {
            return Err(CouplingError::GeometryNeedsCoupled);
        }
        if flow.grid() != seg.grid() {
            return Err(CouplingError::GridMismatch);
        }
        // Solid cells never hold grains, in either solver.
        for i in 0..flow.len() {
            if geo.is_solid(i) {
                flow.set_cell(i, R::ZERO, [R::ZERO; D], R::ZERO);
                seg.set_cell(i, R::ZERO, R::ZERO, [R::ZERO; D], R::ZERO);
            }
        }
        let mut s = Self::unprepared(flow, seg, cfg);
        s.geo = Some(geo);
        s.set_segregation_cells();
        s.apply_packing();
        s.flow.prepare().map_err(CouplingError::Flow)?;
        s.prepare_segregation()
            .map_err(CouplingError::Segregation)?;
        Ok(s)
    }

    fn unprepared(
        flow: &'a mut Flow<R, D, N>,
        seg: &'a mut Segregation<R, D, N>,
        cfg: CouplingConfig<R>,
    ) -> Self {
        Self {
            flow,
            seg,
            cfg,
            frozen: false,
            flow_steps_to_steady: 0,
            guarded: R::ZERO,
            out_small: [[R::ZERO; 2]; D],
            out_total: [[R::ZERO; 2]; D],
            last: None,
            geo: None,
            percolation_dt: R::MAX,
            slab_floor: R::ZERO,
        }
    }

    fn prepare_segregation(&mut self) -> Result<(), SetupError> {
        self.prepare_segregation_with(&Serial)
    }

    /// The segregation's coefficients from the new flow, at `fork`'s instruction set and
    /// with its per-cell velocity gradients cut among the fork's workers (box grids).
    fn prepare_segregation_with<F: Fork>(&mut self, fork: &F) -> Result<(), SetupError> {
        match self.geo {
            Some(g) => self.seg.prepare_embedded(g)?,
            None => self.seg.prepare_with(fork)?,
        }
        self.percolation_dt = match self.geo {
            Some(g) => self.seg.stable_dt_percolation_embedded(g),
            None => self.seg.stable_dt_percolation(),
        };
        Ok(())
    }

    /// Couples two solvers set up on the same grid (the flow with its initial fields, the
    /// segregation solver with its initial `phi`).
    pub fn new(
        flow: &'a mut Flow<R, D, N>,
        seg: &'a mut Segregation<R, D, N>,
        cfg: CouplingConfig<R>,
    ) -> Result<Self, CouplingError> {
        if flow.grid() != seg.grid() {
            return Err(CouplingError::GridMismatch);
        }
        let mut s = Self::unprepared(flow, seg, cfg);
        match cfg.mode {
            Mode::Prescribed => {}
            Mode::Frozen => {
                s.apply_packing();
                s.flow.prepare().map_err(CouplingError::Flow)?;
                s.hand_over()?;
            }
            Mode::Coupled => {
                // c of the flow into the segregation solver first: from here on the packing
                // reads the carried c (equal to the flow's now).
                s.set_segregation_cells();
                s.apply_packing();
                s.flow.prepare().map_err(CouplingError::Flow)?;
                s.prepare_segregation()
                    .map_err(CouplingError::Segregation)?;
            }
        }
        Ok(s)
    }

    fn set_segregation_cells(&mut self) {
        for i in 0..self.flow.len() {
            let phi = self.seg.phi(i);
            self.seg.set_cell(
                i,
                self.flow.c(i),
                self.flow.temperature(i),
                self.flow.velocity(i),
                phi,
            );
        }
    }

    /// With back-coupling on: `c_rcp(phihat)`, `c_rlp(phihat)` of every cell into the flow.
    pub fn apply_packing(&mut self) {
        if self.cfg.packing == Packing::Constant {
            return;
        }
        let m = self.flow.config().material;
        let vac = self.flow.config().vacuum;
        let carried = self.cfg.mode == Mode::Coupled;
        for i in 0..self.flow.len() {
            // the composition of the carried phases (coupled), else of the flow's c
            let c = if carried {
                self.seg.c(i)
            } else {
                self.flow.c(i)
            };
            // An empty cell has no mixture: take the mono-disperse limits of the large grains.
            let phihat = if c > vac {
                self.seg.phi(i) / c
            } else {
                R::ZERO
            };
            let (rcp, rlp) = self.cfg.packing.limits(&m, phihat);
            self.flow.set_packing(i, rcp, rlp);
        }
    }

    /// In a rotating frame the segregation sees the frame's turning gravity (percolation is
    /// driven by gravity alone; [`crate::frame`]). In the lab frame its own gravity stays.
    fn sync_gravity(&mut self) {
        if self.flow.config().frame.rotation().is_some() {
            self.seg.set_gravity(self.flow.frame_gravity());
        }
    }

    /// Hands `c, T, u` of the flow and the current `phi` to the segregation solver and
    /// prepares it (which rejects a `phi` outside `[0, c]`). Coupled mode hands over only `T`
    /// and `u` ([`Self::step_with`]).
    pub fn hand_over(&mut self) -> Result<(), CouplingError> {
        self.sync_gravity();
        self.set_segregation_cells();
        self.prepare_segregation()
            .map_err(CouplingError::Segregation)
    }

    /// Hands the flow over keeping each cell's composition `phihat = phi / c` (new
    /// `phi = phihat c_flow`): the start of the frozen mode, after the flow moved c without
    /// carrying phi. The small-phase mass changes by `sum phihat dc |C|` (reported by
    /// [`Self::freeze`]); the segregation then conserves it.
    pub fn hand_over_keeping_composition(&mut self) -> Result<(), CouplingError> {
        self.sync_gravity();
        let vac = self.flow.config().vacuum;
        for i in 0..self.flow.len() {
            let (c_old, c) = (self.seg.c(i), self.flow.c(i));
            let phihat = if c_old > vac {
                (self.seg.phi(i) / c_old).max(R::ZERO).min(R::ONE)
            } else {
                R::ZERO
            };
            self.seg.set_cell(
                i,
                c,
                self.flow.temperature(i),
                self.flow.velocity(i),
                (phihat * c).min(c),
            );
        }
        self.prepare_segregation()
            .map_err(CouplingError::Segregation)
    }

    /// Frozen mode: settles the flow ([`Self::settle`]), applies the packing switch and hands
    /// the steady flow over keeping the composition; returns the flow steps it took. Called by
    /// the first [`Self::step`] if not called before.
    pub fn freeze(&mut self) -> Result<u64, CouplingError> {
        self.flow_steps_to_steady = self.settle()?;
        self.apply_packing();
        self.hand_over_keeping_composition()?;
        self.frozen = true;
        Ok(self.flow_steps_to_steady)
    }

    /// Runs the flow alone until its residual is below the tolerance; returns the steps.
    pub fn settle(&mut self) -> Result<u64, CouplingError> {
        let mut k = 0;
        loop {
            let dt = self.flow.stable_dt();
            self.flow.step(dt);
            k += 1;
            if k >= self.cfg.min_flow_steps && self.flow.residual() < self.cfg.steady_tolerance {
                return Ok(k);
            }
            if k >= self.cfg.max_flow_steps {
                return Err(CouplingError::NotSteady(self.flow.residual().to_f64()));
            }
        }
    }

    /// One step of the chosen mode; returns the segregation time step taken. In frozen mode
    /// the first call settles the flow first (see [`Self::flow_steps_to_steady`]).
    pub fn step(&mut self) -> Result<R, CouplingError> {
        match self.cfg.mode {
            Mode::Prescribed => {
                let dt = self.seg.stable_dt();
                self.seg.step(dt);
                Ok(dt)
            }
            Mode::Frozen => {
                if !self.frozen {
                    self.freeze()?;
                }
                let dt = self.seg.stable_dt();
                self.seg.step(dt);
                Ok(dt)
            }
            Mode::Coupled => {
                let dt = self.stable_dt();
                self.step_with(dt)?;
                Ok(dt)
            }
        }
    }

    /// The largest stable step of the chosen mode: the segregation's Courant limit
    /// (prescribed, frozen), or in coupled mode the flow's limit, capped at
    /// [`PERCOLATION_SUBSTEPS`] times the percolation stage's
    /// ([`Segregation::stable_dt_percolation`]). The carried transport moves phi with the
    /// flow's limited face mass fluxes and keeps `0 <= phi <= c` at any Courant number (proof
    /// in `segregation/carried.rs`), so the segregation's transport term `|u| / h` does not
    /// limit a coupled step; the percolation stage takes sub-steps within it
    /// ([`Self::step_with`]).
    pub fn stable_dt(&self) -> R {
        match (self.cfg.mode, self.geo) {
            (Mode::Coupled, _) => self
                .flow
                .stable_dt()
                .min(R::from_usize(PERCOLATION_SUBSTEPS) * self.percolation_dt()),
            (_, Some(g)) => self.seg.stable_dt_embedded(g),
            (_, None) => self.seg.stable_dt(),
        }
    }

    /// The percolation stage's own limit (coupled mode), as prepared.
    fn percolation_dt(&self) -> R {
        self.percolation_dt
    }

    /// One coupled step of length `dt` (at most [`Self::stable_dt`]): percolation (in as
    /// many equal sub-steps as its own Courant limit needs, at most [`PERCOLATION_SUBSTEPS`]),
    /// flow, carried transport, packing, hand-over of `T` and `u` (module docs).
    pub fn step_with(&mut self, dt: R) -> Result<(), CouplingError> {
        self.step_with_on(dt, &Serial)
    }

    /// [`Self::step_with`] with the flow's linear solves on the threads of `fork` (the same
    /// bits for any number of threads: [`Flow::step_on`]).
    pub fn step_with_on<F: Fork>(&mut self, dt: R, fork: &F) -> Result<(), CouplingError> {
        self.step_with_reaching(dt, fork, &mut Whole)
    }

    /// [`Self::step_with_on`] on a subdomain whose view past its own cells is `reach`
    /// ([`Flow::step_reaching`]; docs/parallel.md, "The coupled step on slabs"). With
    /// [`Whole`] it is the serial step. On a slab ([`Self::on_slab`]) the owned cells get the
    /// serial bits because:
    /// - after each percolation sub-step the driver flushes the owned cells (the running
    ///   counter continued from slab to slab in cell order) and refreshes the halo rows of
    ///   `q`, whose outer rows the sub-step updated against the slab's wall;
    /// - the carried transport of an owned cell reads the flow's face mass flux at the cut
    ///   (the serial one: [`super::slab::HALO`]) and the first halo row's `q` and `c`; the
    ///   guard's sum continues the slabs below;
    /// - before the prepare every state array of the segregation is refreshed, so every
    ///   halo row but the outermost (a one-sided gradient) derives the serial coefficients,
    ///   and the rates count the owned cells only, their maximum taken across the slabs.
    ///
    /// Every call is collective on slabs: a slab whose segregation rejects its fields
    /// returns that error, the others [`CouplingError::OtherSlab`].
    pub fn step_with_reaching<F: Fork, Re: Reach<R, D, N>>(
        &mut self,
        dt: R,
        fork: &F,
        reach: &mut Re,
    ) -> Result<(), CouplingError> {
        let limit = self.percolation_dt();
        let (whole, floor, geo) = (reach.whole(), self.slab_floor, self.geo);
        // Every stage's hot loops at the fork's instruction set (docs/simd.md).
        self.seg.step_percolation_substeps_then::<F::Isa>(
            dt,
            limit,
            PERCOLATION_SUBSTEPS,
            geo,
            |seg, before| {
                if !whole {
                    end_slab_substep(seg, geo, floor, before, reach);
                }
            },
        );
        self.flow.step_reaching(dt, fork, reach);
        let fx = self.flow.mass_fluxes();
        let d = match geo {
            Some(g) => self.seg.carry_mass_fluxes_embedded_summing(fx, g, reach),
            None => self.seg.carry_mass_fluxes_summing::<F::Isa>(fx, reach),
        };
        for a in 0..D {
            for side in 0..2 {
                self.out_small[a][side] += d.small[a][side];
                self.out_total[a][side] += d.total[a][side];
            }
        }
        self.guarded += d.guarded;
        self.last = Some(d);
        self.apply_packing();
        self.sync_gravity();
        for i in 0..self.flow.len() {
            self.seg
                .set_flow_state(i, self.flow.temperature(i), self.flow.velocity(i));
        }
        if !whole {
            // the inflow state is set once and never changes
            self.seg.for_each_state_array_mut(|name, a| {
                if name != "inflow" {
                    reach.refresh(a);
                }
            });
        }
        self.prepare_segregation_reaching(fork, reach)
    }

    /// [`Self::stable_dt`] (coupled mode) across the subdomains of `reach`: the flow's limit
    /// ([`Flow::stable_dt_reaching`]) capped by the percolation's, which the prepare took
    /// across them already.
    pub fn stable_dt_reaching<Re: Reach<R, D, N>>(&self, reach: &mut Re) -> R {
        self.flow
            .stable_dt_reaching(reach)
            .min(R::from_usize(PERCOLATION_SUBSTEPS) * self.percolation_dt())
    }

    /// The segregation's prepare after a step: on a slab over the owned cells, the
    /// percolation limit the smallest of the slabs' (`C / max rate` is the minimum of `C /
    /// rate` exactly: division rounds monotonically), its negation's maximum.
    fn prepare_segregation_reaching<F: Fork, Re: Reach<R, D, N>>(
        &mut self,
        fork: &F,
        reach: &mut Re,
    ) -> Result<(), CouplingError> {
        if reach.whole() {
            return self
                .prepare_segregation_with(fork)
                .map_err(CouplingError::Segregation);
        }
        let own = reach.owned(self.seg.grid().len());
        let mine = match self.geo {
            Some(g) => self.seg.prepare_embedded_owned_with(g, fork, own),
            None => self.seg.prepare_owned_with(fork, own),
        };
        // a slab that failed sends a positive value: every slab learns of it
        let sent = match (mine, self.geo) {
            (Ok(()), Some(g)) => -self.seg.stable_dt_percolation_embedded(g),
            (Ok(()), None) => -self.seg.stable_dt_percolation(),
            (Err(_), _) => R::ONE,
        };
        let most = reach.max(sent);
        match mine {
            Err(e) => Err(CouplingError::Segregation(e)),
            Ok(()) if most > R::ZERO => Err(CouplingError::OtherSlab),
            Ok(()) => {
                self.percolation_dt = -most;
                Ok(())
            }
        }
    }

    /// Steps until the segregation clock reaches `t_end` (last step may overshoot by less than
    /// one step) or `max_steps`; returns the steps taken.
    pub fn advance_to(&mut self, t_end: R, max_steps: u64) -> Result<u64, CouplingError> {
        let mut k = 0;
        while self.seg.time() < t_end && k < max_steps {
            self.step()?;
            k += 1;
        }
        Ok(k)
    }

    /// Flow steps the frozen mode needed to reach steady state (0 before the first step).
    pub fn flow_steps_to_steady(&self) -> u64 {
        self.flow_steps_to_steady
    }

    /// Small-grain volume that left through each side `[axis][low, high]` so far (coupled).
    pub fn discharged_small(&self) -> [[R; 2]; D] {
        self.out_small
    }

    /// Grain volume (both sizes) that left through each side so far, as the segregation
    /// solver carried it (the flow's own count: [`Flow::discharged`]).
    pub fn discharged_total(&self) -> [[R; 2]; D] {
        self.out_total
    }

    /// What left in the last coupled step (`None` before the first).
    pub fn last_discharge(&self) -> Option<Discharge<R, D>> {
        self.last
    }

    /// Tracked-phase volume the round-off guard of the carried transport added so far
    /// ([`Discharge::guarded`]; 0 when the percolation stage keeps the bounds exactly).
    pub fn guarded_mass(&self) -> R {
        self.guarded
    }

    /// `max_i |c_carried - c_flow|`: how far the segregation solver's carried `c` is from
    /// the flow's (round-off; see the module docs).
    pub fn c_mismatch(&self) -> R {
        let mut m = R::ZERO;
        for i in 0..self.flow.len() {
            m = m.max((self.seg.c(i) - self.flow.c(i)).abs());
        }
        m
    }

    /// The cut cells of the container's walls, if any ([`Self::new_embedded`]).
    pub fn geometry(&self) -> Option<&'a CutCells<R, D, N>> {
        self.geo
    }

    /// The configuration.
    pub fn config(&self) -> &CouplingConfig<R> {
        &self.cfg
    }

    /// What the driver has summed since it was built (checkpoints).
    pub fn totals(&self) -> CoupledTotals<R, D> {
        CoupledTotals {
            out_small: self.out_small,
            out_total: self.out_total,
            guarded: self.guarded,
        }
    }

    /// Continues a coupled run from a checkpoint: the caller has built this driver as for a
    /// fresh run and then restored both solvers' arrays and clocks (coupled mode). Restores
    /// the totals and redoes what the end of [`Self::step_with`] does after the hand-over:
    /// the frame's gravity for the segregation and its `prepare` (face coefficients and rate
    /// are functions of the restored `c`, `T`, `u` and gravity, so they come out bit for bit).
    pub fn resume(&mut self, totals: CoupledTotals<R, D>) -> Result<(), CouplingError> {
        self.out_small = totals.out_small;
        self.out_total = totals.out_total;
        self.guarded = totals.guarded;
        self.last = None;
        self.sync_gravity();
        self.prepare_segregation()
            .map_err(CouplingError::Segregation)
    }

    /// What a slab's driver takes from this run ([`Self::on_slab`]).
    pub fn slab_start(&self) -> SlabStart<R, D> {
        SlabStart {
            coupling: self.cfg,
            totals: self.totals(),
            floor: self.seg.config().flush_below,
        }
    }

    /// The driver of one slab of a coupled run cut into slabs of rows (coupled mode; docs/
    /// parallel.md, "The coupled step on slabs"): `flow` and `seg` as
    /// [`super::coupled_slab::load_coupled_slab`] set them up, `start` from the whole run
    /// ([`Self::slab_start`]), and `geo` the slab's cut cells where the whole run has them
    /// (`load_coupled_slab` loads them). Prepares the segregation over the owned cells with
    /// the percolation limit across the slabs (collective: every slab calls it). Step it
    /// with [`Self::stable_dt_reaching`] and [`Self::step_with_reaching`].
    pub fn on_slab<Re: Reach<R, D, N>>(
        flow: &'a mut Flow<R, D, N>,
        seg: &'a mut Segregation<R, D, N>,
        start: SlabStart<R, D>,
        geo: Option<&'a CutCells<R, D, N>>,
        reach: &mut Re,
    ) -> Result<Self, CouplingError> {
        let SlabStart {
            coupling: cfg,
            totals,
            floor,
        } = start;
        if cfg.mode != Mode::Coupled {
            return Err(CouplingError::SlabsNeedCoupled);
        }
        if flow.grid() != seg.grid() || geo.is_some_and(|g| g.grid() != flow.grid()) {
            return Err(CouplingError::GridMismatch);
        }
        if flow.has_geometry() != geo.is_some() {
            return Err(CouplingError::GeometryMismatch);
        }
        let mut s = Self::unprepared(flow, seg, cfg);
        s.geo = geo;
        s.out_small = totals.out_small;
        s.out_total = totals.out_total;
        s.guarded = totals.guarded;
        s.slab_floor = floor;
        s.sync_gravity();
        s.prepare_segregation_reaching(&Serial, reach)?;
        Ok(s)
    }
}

/// The end of a percolation sub-step on a slab ([`Coupled::step_with_reaching`]): the flush
/// of the owned cells (on cut cells: of the groups with an owned member), when due, into the
/// running counter in cell order across the slabs, then the halo rows of `q` (and of its
/// carry when compensated) from their owners.
fn end_slab_substep<R: Real, const D: usize, const N: usize, Re: Reach<R, D, N>>(
    seg: &mut Segregation<R, D, N>,
    geo: Option<&CutCells<R, D, N>>,
    floor: R,
    before: u64,
    reach: &mut Re,
) {
    if seg.flush_due(floor, before) {
        let counter = seg.flushed_tracked();
        let total = reach.sum_in_order(counter, |mut sum| {
            let mut excess = seg.tracked_excess();
            let add = |_, v| sum += v;
            match geo {
                Some(g) => seg.end_owned_step_embedded(g, floor, before, &mut excess, add),
                None => seg.end_owned_step(floor, before, &mut excess, add),
            }
            sum
        });
        seg.set_flushed_tracked(total);
    }
    let compensated = seg.config().compensated;
    seg.for_each_state_array_mut(|name, a| {
        if name == "q" || (compensated && name == "carry") {
            reach.refresh(a);
        }
    });
}
