//! Coupling of the flow ([`Flow`]) to the segregation equation ([`Segregation`]), model.md
//! sections 2-4, in the three modes a scene chooses from (issue 3).
//!
//! Each coupled step hands `u, c, T` and the current `phi` of every cell to the segregation
//! solver (`set_cell` + `prepare`, which also derives the segregation direction from the
//! velocity gradient if its [`crate::DirectionMode`] is `Flow`), advances both with the same
//! `dt = min(flow limit, segregation Courant limit)`, and, with back-coupling on, replaces the
//! packing constants of the flow by `c_rcp(phihat)`, `c_rlp(phihat)` of model.md 4.
//!
//! Both solvers transport with the same upwind face rule and the same velocity, so
//! `0 <= phi <= c` carries over from step to step up to round-off, except where the flow's
//! conservative packing limiter cut a face flux that the segregation transport did not see;
//! there `phi` is clipped into `[0, c]` on hand-over (a small, reported mass defect:
//! [`Coupled::clipped_mass`]). A segregation step that accepted external face mass fluxes
//! would remove it.

use super::{Flow, FlowError};
use crate::closure::Packing;
use crate::real::Real;
use crate::segregation::{Segregation, SetupError};

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
}

/// A residual as f64 (keeps [`CouplingError`] non-generic).
pub type R64 = f64;

/// The driver; borrows both (large) solvers.
pub struct Coupled<'a, R: Real, const D: usize, const N: usize> {
    /// The flow.
    pub flow: &'a mut Flow<R, D, N>,
    /// The segregation solver.
    pub seg: &'a mut Segregation<R, D, N>,
    cfg: CouplingConfig<R>,
    frozen: bool,
    flow_steps_to_steady: u64,
    clipped: R,
}

impl<'a, R: Real, const D: usize, const N: usize> Coupled<'a, R, D, N> {
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
        let mut s = Self {
            flow,
            seg,
            cfg,
            frozen: false,
            flow_steps_to_steady: 0,
            clipped: R::ZERO,
        };
        if cfg.mode != Mode::Prescribed {
            s.apply_packing();
            s.flow.prepare().map_err(CouplingError::Flow)?;
            s.hand_over()?;
        }
        Ok(s)
    }

    /// With back-coupling on: `c_rcp(phihat)`, `c_rlp(phihat)` of every cell into the flow.
    pub fn apply_packing(&mut self) {
        if self.cfg.packing == Packing::Constant {
            return;
        }
        let m = self.flow.config().material;
        let vac = self.flow.config().vacuum;
        for i in 0..self.flow.len() {
            let c = self.flow.c(i);
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

    /// Hands `c, T, u` of the flow and the current `phi` (clipped into `[0, c]`, the clipped
    /// amount counted) to the segregation solver and prepares it.
    pub fn hand_over(&mut self) -> Result<(), CouplingError> {
        self.sync_gravity();
        let vol = self.flow.grid().cell_volume();
        for i in 0..self.flow.len() {
            let c = self.flow.c(i);
            let phi = self.seg.phi(i);
            let clipped = phi.max(R::ZERO).min(c);
            self.clipped += (phi - clipped).abs() * vol;
            self.seg.set_cell(
                i,
                c,
                self.flow.temperature(i),
                self.flow.velocity(i),
                clipped,
            );
        }
        self.seg.prepare().map_err(CouplingError::Segregation)
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
        self.seg.prepare().map_err(CouplingError::Segregation)
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
                let dt = self.flow.stable_dt().min(self.seg.stable_dt());
                self.flow.step(dt);
                self.seg.step(dt);
                self.apply_packing();
                self.hand_over()?;
                Ok(dt)
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

    /// Small-phase mass clipped on hand-over so far (see module docs).
    pub fn clipped_mass(&self) -> R {
        self.clipped
    }

    /// The configuration.
    pub fn config(&self) -> &CouplingConfig<R> {
        &self.cfg
    }
}
