//! The granular flow equations (model.md section 2) on a static grid: volume fraction `c`,
//! momentum `c u` and `c T`, with the closures of [`crate::closure`].
//!
//! # Scheme (one [`Flow::step`] of length `dt`)
//! Operator splitting, every stage conservative or positivity-preserving:
//! 1. **Transport** (explicit, upwind, the same face rule as the segregation transport:
//!    face velocity = mean of the two cells, upwind donor), plus a Rhie-Chow face-velocity
//!    correction `w tau (F_f - (K_L + K_R)/2) / c_f` (compact face force minus the mean compact
//!    force of its cells, over the face's mass; zero at a discrete rest state, O(h^2) on
//!    smooth flows, `tau` a time scale of the state, model.md 5.3) that damps the
//!    odd-even pressure modes of the collocated grid. Mass flux `F`, momentum flux `F u_donor`,
//!    energy flux `F T_donor`. Two conservative *flux limiters*: each face flux is scaled by the
//!    smaller of its receiver's factor (so that `c <= c_max = (1 - margin) c_rcp`) and its
//!    donor's factor (so that `c >= 0`); every face flux still leaves one cell and enters the
//!    other with the same value, so mass is conserved to round-off and the bounds hold by
//!    construction, not by clipping.
//! 2. **Pressure and gravity** (explicit, forward-backward: `p` from the *new* `c`, so the
//!    acoustic part is a symplectic Euler step): each face carries the compact force
//!    `F_f = w (-(p_R - p_L)/h + g (c_L + c_R)/2)`, shared half and half by its cells. A wall
//!    face has a hydrostatic ghost (`F = 0`), so a resting bed satisfies the compact
//!    lithostatic balance `(p_R - p_L)/h = g (c_L + c_R)/2` exactly. The weight
//!    `w = min(1, min(c_L, c_R)/surface)` is the free-surface condition `p -> 0` next to a nearly
//!    empty cell; the face share `(1 - w)` of gravity acts on the cell directly (dust falls).
//!    With [`FlowConfig::free_surface_push`] the share `(1 - w)` of a face also pushes each
//!    of its cells outwards with its own pressure `p / h` (`p = 0` at a free-surface face, the
//!    finite-volume form), so a vertical free face releases its pressure and a block can
//!    collapse. With [`PressureMode::Implicit`] ([`FlowConfig::pressure`]) the pressure is
//!    instead the end-of-step one of a single linearised SPD solve before the transport, and
//!    the transport's face velocities use it too (module `pressure`, model.md 5.3); no
//!    acoustic time-step limit. Then **wall contact**: a wall cell that cannot carry its weight by pressure
//!    (loose, `c <= c_rlp`, or under a nearly empty neighbour) loses the momentum pointing into
//!    the wall, with Coulomb friction `tan(phi_w)` on that impulse (see `wall_contact`).
//! 3. **Viscosity** (implicit, one SPD system per velocity component, since the asymmetric
//!    stress `eta grad u` decouples them): `c u / dt - div(eta grad u) = (c u)^* / dt`,
//!    `eta` lagged (evaluated at the new `c` and old `T`); walls: normal component 0,
//!    tangential no-slip / slip / partial slip by the wall friction angle (model.md 2, branch
//!    chosen on the velocity at the start of the step), moving walls, inflow Dirichlet, outflow
//!    zero gradient. Conjugate gradients, matrix-free, preconditioned by exact solves along the
//!    vertical grid lines ([`cg`]).
//! 4. **Temperature** (implicit): `(c/dt + eps c) T - a div(lambda grad T) = (c T)^*/dt + a H`
//!    with the discrete viscous heating `H` of the velocity just solved (the dissipation of the
//!    discrete viscous operator, face by face) and lagged `lambda`, `eps`. The matrix is an
//!    M-matrix and the right-hand side is non-negative, so `T >= 0` (the solver's round-off
//!    below 0 is clipped). Since `eta / eps = c eta0 / eps0` exactly, the stiff local balance
//!    (rates up to 1e7 1/s for glass beads) is reached in one step without oscillation.
//!
//! # Stability limits
//! - Courant: `dt <= C / max_i sum_a ((|u_a| + a_s) / h_a + sqrt(|g_a| / h_a))` with
//!   `a_s = sqrt(dp/dc)` ([`crate::closure::sound_speed_squared`]), `C <= 1/2`
//!   ([`FlowConfig::courant`], default 0.4). The acoustic part (explicit pressure, central
//!   differences, forward-backward) is stable for `a_s dt / h < 1`; the `sqrt(|g|/h)` term
//!   keeps the speed a cell gains by free fall within one step below `C h / dt` (without it a
//!   cold, dilute state at rest would allow an infinite step). Positivity of c does not rest on
//!   this limit (the donor limiter guarantees it), but accuracy does. The wave speed grows
//!   like `g(c)` near `c_rcp`; the limiter caps `g <= 1/margin` (1000 by default), so the step
//!   never collapses to zero. For the glass beads at c = 0.6, `a_s = 7.9 m/s`.
//! - With [`PressureMode::Implicit`] the acoustic term `a_s / h_a` drops out of the Courant
//!   sum, and the advective term `|u_a| / h_a` counts only cells with `c >= surface`:
//!   near-empty cells (dust thrown off a free surface) are kept bounded by the donor
//!   limiters at any Courant number. The free-fall term and the dense flowing layer hold
//!   the step. (The Courant condition at the end-of-step free-fall speed,
//!   `sum_a (|u_a| + b_a dt) dt / h_a <= C`, would allow 2.2 times the free-fall step in 2D;
//!   tried on the 64 x 64 tumbler it let a surface cell run away to 4 m/s within 2 s: the
//!   explicit parts of the step at the free surface need the margin of `sqrt(|g_a| / h_a)`.)
//! - Viscosity, conduction and dissipation are implicit: no limit (they diverge as `T -> 0`
//!   and as `c -> c_rcp`, which is why they must be).
//! - Regularisation: transport coefficients use `T_eff = max(T, T_min)`
//!   ([`FlowConfig::t_min`]); this bounds the yield viscosity by `eta0 p_y / sqrt(T_min)` and
//!   sets a creep floor: a resting region under a sub-yield shear stress `tau < mu p_y` flows at
//!   most at the rate `mu sqrt(T_min) / eta0` (`mu = sqrt(eps0 eta0 / a)`), and its temperature
//!   stays below `T_min` (heating cannot outrun dissipation below yield). The same viscosity
//!   carries part of the load while a bed compacts, which then relaxes on the time scale
//!   `eta / (dp/dc)` (~1 s at the default `T_min = 1e-14`, ~5 ms at 1e-10).
//! - Cells with `c < vacuum` (1e-12) carry no velocity and no temperature (their mass stays).

pub mod cg;
pub mod cg_slab;
pub mod coupled;
pub mod coupled_slab;
pub mod cycle_slab;
pub mod line_slab;
mod objective;
mod pressure;
pub mod reach;
pub mod rest;
pub mod slab;
mod step;
mod walls;

pub use objective::Stress;
pub use pressure::PressureMode;
pub use walls::{CutWall, MemberKept, MergedWalls};

use crate::boundary::{check_periodic_pairs, Boundary, Openings};
use crate::closure::{self, Material};
use crate::frame::Frame;
use crate::grid::Grid;
use crate::real::Real;
use crate::segregation::MassFluxes;
use core::ops::Range;

/// Tangential condition of a solid wall (model.md 2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Slip<R> {
    /// `u_B = u_W` (Dirichlet on the tangential components).
    NoSlip,
    /// Zero tangential stress.
    Slip,
    /// Partial slip by the wall friction angle, given as `tan(phi_w)`: the wall shear stress is
    /// `min{ p tan(phi_w), eta |u_I - u_W| / h }` towards the wall velocity.
    Friction(R),
}

/// Pressure of the ghost cell behind an opening in a wall ([`FlowSide::openings`]); the rest
/// of the outlet ghost is always zero-gradient (model.md 2, "outflow (silo orifice)").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum OutletPressure {
    /// `p = 0` on the orifice plane (free outflow into air): the ghost mirrors the cell,
    /// `p_ghost = -p_cell`, so the face's mean pressure is 0 and the cell is pushed out by
    /// `p_cell / (h/2)`. A ghost of `p = 0` at the ghost's centre put the plane half a cell
    /// below the orifice: an unresolved pressure layer that slowed coarse grids (model.md 5.3).
    #[default]
    Zero,
    /// `p_ghost = p_cell`: no pressure difference across the face; only gravity pulls the
    /// grains out (the face carries none of the cell's weight).
    ZeroGradient,
}

/// One side of the box for the flow.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlowSide<R, const D: usize> {
    /// Wall, inflow, outflow or periodic.
    pub kind: Boundary,
    /// Openings (outlets) of a wall side: grains leave through them freely. Per boundary face
    /// the open fraction of its area ([`Openings::fraction`]) is outlet, the rest wall.
    /// The outlet ghost state is zero-gradient in `c`, `u` and `T` with inflow blocked (the
    /// face velocity is the cell's outward normal velocity, or 0 if it points inwards), and
    /// the pressure chosen by [`Self::outlet`]: mass, momentum and energy leave with the
    /// donor cell's state, the viscous and conductive fluxes through the open part are 0.
    pub openings: Openings<R, D>,
    /// Ghost pressure of the openings.
    pub outlet: OutletPressure,
    /// Tangential condition if `kind` is a wall.
    pub slip: Slip<R>,
    /// Wall velocity (its normal component is ignored: walls do not move normally), or the
    /// Dirichlet velocity of an inflow.
    pub velocity: [R; D],
    /// Inflow volume fraction.
    pub c: R,
    /// Inflow temperature.
    pub t: R,
}

impl<R: Real, const D: usize> FlowSide<R, D> {
    /// A resting wall with the given tangential condition.
    pub const fn wall(slip: Slip<R>) -> Self {
        Self {
            kind: Boundary::Wall,
            slip,
            velocity: [R::ZERO; D],
            c: R::ZERO,
            t: R::ZERO,
            openings: Openings::none(),
            outlet: OutletPressure::Zero,
        }
    }
    /// A no-slip wall moving tangentially with `velocity`.
    pub const fn moving_wall(velocity: [R; D]) -> Self {
        Self {
            kind: Boundary::Wall,
            slip: Slip::NoSlip,
            velocity,
            c: R::ZERO,
            t: R::ZERO,
            openings: Openings::none(),
            outlet: OutletPressure::Zero,
        }
    }
    /// A periodic side (set on both sides of the axis).
    pub const fn periodic() -> Self {
        Self {
            kind: Boundary::Periodic,
            slip: Slip::Slip,
            velocity: [R::ZERO; D],
            c: R::ZERO,
            t: R::ZERO,
            openings: Openings::none(),
            outlet: OutletPressure::Zero,
        }
    }
    /// Zero-gradient outflow.
    pub const fn outflow() -> Self {
        Self {
            kind: Boundary::Outflow,
            slip: Slip::Slip,
            velocity: [R::ZERO; D],
            c: R::ZERO,
            t: R::ZERO,
            openings: Openings::none(),
            outlet: OutletPressure::Zero,
        }
    }
    /// Dirichlet inflow of the state `(c, u, T)`.
    pub const fn inflow(c: R, velocity: [R; D], t: R) -> Self {
        Self {
            kind: Boundary::Inflow,
            slip: Slip::NoSlip,
            velocity,
            c,
            t,
            openings: Openings::none(),
            outlet: OutletPressure::Zero,
        }
    }
}

/// The flow conditions of the low and high side of every axis.
pub type FlowBoundaries<R, const D: usize> = [[FlowSide<R, D>; 2]; D];

/// Everything about the flow that is not a field.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlowConfig<R, const D: usize> {
    /// Material constants (model.md 2).
    pub material: Material<R>,
    /// Gravity vector (m/s^2).
    pub gravity: [R; D],
    /// Courant number in (0, 1/2] of the transport + acoustic limit (see module docs).
    pub courant: R,
    /// Temperature floor of the transport coefficients (m^2/s^2) (regularisation, > 0).
    pub t_min: R,
    /// `c_max = (1 - margin) c_rcp`: the flux limiter keeps `c <= c_max`, so `g <= 1/margin`.
    pub margin: R,
    /// Below this volume fraction a cell carries no velocity or temperature.
    pub vacuum: R,
    /// Face pressures fade linearly to 0 (free surface) as the thinner side drops below this.
    pub surface: R,
    /// Relative residual of the conjugate-gradient solves of the viscous and temperature
    /// stages (model.md 5.3 stages 2-3).
    pub cg_tolerance: R,
    /// Relative residual of the implicit pressure solve ([`PressureMode::Implicit`]).
    pub cg_tolerance_pressure: R,
    /// Iteration cap of one conjugate-gradient solve.
    pub cg_max_iterations: u32,
    /// Free-surface pressure push (off by default): a faded face (weight `w < 1`, see
    /// [`Self::surface`]) also pushes each of its cells outwards with `(1 - w) p / h`, the
    /// finite-volume force of the free-surface condition `p = 0` at the face. Without it a
    /// faded face carries no pressure force at all, so a free surface acts like a wall for
    /// the pressure: a dense block with a vertical free face stands for ever (its yield
    /// pressure `p_y > 0` is never released). Needed for a column collapse; off by default
    /// because it lets the top layer of an over-compressed bed decompress (a burst of dust
    /// at t = 0, after which the thin surface cells jitter at ~1e-3 m/s), which the resting
    /// pile tests were tuned without.
    pub free_surface_push: bool,
    /// The frame of reference (model.md 2, "rotating container"): the lab (default), or a
    /// frame turning with a drum, with rotating gravity, centrifugal and Coriolis forces
    /// ([`crate::frame`]). `gravity` above is always the lab's.
    pub frame: Frame<R, D>,
    /// How stage 2 advances the pressure (model.md 5.3): explicit forward-backward (default,
    /// acoustic time-step limit) or implicit (one SPD solve per step, no acoustic limit;
    /// [`PressureMode`]).
    pub pressure: PressureMode,
    /// The viscous stress (model.md 2.6): the model's `eta grad u` (default) or the objective
    /// `eta (grad u + grad u^T)`, equal in simple shear and zero in a rigid rotation
    /// ([`Stress`]).
    pub stress: Stress,
    /// Where the velocity solves of stage 3 start (model.md 5.3, "Initial guess"): the
    /// answer is the same to the solver's tolerance, the iterations are not.
    pub guess: VelocityGuess,
    /// Which cell of a merge group takes the wall term of a merged cut cell's wall fragment
    /// in the viscous and temperature stages (model.md 5.4, "The wall term of a merged
    /// cell"; [`MergedWalls`]).
    pub merged_walls: MergedWalls,
    /// The viscous share of the implicit face velocity (on by default; implicit pressure
    /// only; model.md 5.3 and docs/implicit-pressure.md, "The viscous share"): each face adds
    /// `dt` times the smaller of its two cells' accelerations of the last step from the
    /// stress and the transport when they agree in sign (an outlet face its cell's), so that
    /// the face mass flux sees the stress that holds a bed and the inertia of a jet.
    /// Without it a drum's bed creeps downhill by `dt g sin(theta)` per step and its
    /// readouts depend on the step (`tumbler-75` Psi 0.438 at `courant` 0.4 against 0.291
    /// at 0.1; with it 0.255 and 0.243), and a silo's rate grows with the step.
    pub viscous_share: bool,
}

/// The initial guess of the viscous stage's conjugate-gradient solves (model.md 5.3).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum VelocityGuess {
    /// `2 u^n - u^{n-1}`: the velocity extrapolated from the starts of the last two steps
    /// (default). In a quasi-steady flow, where the yield viscosity undoes most of what the
    /// explicit stages did, it starts next to the answer: the 2D silo needs 5.6x fewer
    /// iterations than from the explicit velocity.
    #[default]
    Extrapolated,
    /// `(c u)* / c`: the velocity after the explicit stages 1-2 (the guess until 2026-12-02;
    /// kept to compare).
    Explicit,
}

impl<R: Real, const D: usize> FlowConfig<R, D> {
    /// Defaults for `material`: gravity -9.81 along the last axis, Courant 0.4,
    /// `T_min = 1e-14`, margin 1e-3, vacuum 1e-12, surface 0.05, CG tolerance 1e-10 (f64) or
    /// 64 machine epsilons (f32), 2000 iterations, no free-surface push, the viscous share of
    /// the implicit face velocity on.
    pub fn new(material: Material<R>) -> Self {
        let mut gravity = [R::ZERO; D];
        gravity[D - 1] = R::from_f64(-9.81);
        Self {
            material,
            gravity,
            courant: R::from_f64(0.4),
            t_min: R::from_f64(1e-14),
            margin: R::from_f64(1e-3),
            vacuum: R::from_f64(1e-12),
            surface: R::from_f64(0.05),
            cg_tolerance: R::from_f64(1e-10).max(R::EPSILON * R::from_f64(64.0)),
            cg_tolerance_pressure: R::from_f64(1e-10).max(R::EPSILON * R::from_f64(64.0)),
            cg_max_iterations: 2000,
            free_surface_push: false,
            frame: Frame::Lab,
            pressure: PressureMode::Explicit,
            stress: Stress::Spec,
            guess: VelocityGuess::Extrapolated,
            merged_walls: MergedWalls::Master,
            viscous_share: true,
        }
    }
}

/// Why the flow cannot be set up or prepared.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FlowError {
    /// The grid needs more cells than the compiled capacity.
    Capacity,
    /// Periodic on one side of an axis only.
    UnpairedPeriodic(usize),
    /// A configuration or material number is out of range.
    Parameter(&'static str),
    /// A field value is NaN or infinite, or c/T out of range, in the named cell.
    Field {
        /// field name
        field: &'static str,
        /// cell index
        cell: usize,
    },
}

impl FlowError {
    /// The same error with its cell counted `offset` cells later: a slab's cell in the whole
    /// grid's numbering, as the serial run names it.
    pub fn offset_cell(self, offset: usize) -> Self {
        match self {
            FlowError::Field { field, cell } => FlowError::Field {
                field,
                cell: cell + offset,
            },
            other => other,
        }
    }
}

/// Diagnostics of the flow (issue 3: max c/c_rcp, min T, kinetic energy, residual).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlowDiagnostics<R> {
    /// Total mass `sum c |C|`.
    pub mass: R,
    /// `max c / c_rcp` over cells.
    pub max_packing: R,
    /// Smallest T over all cells.
    pub t_min: R,
    /// Largest T over cells with `c >= surface` (dust in the air does not count).
    pub t_max: R,
    /// Largest speed |u| over cells that are not nearly empty (`c >= surface`): dust in the
    /// air does not count.
    pub max_speed: R,
    /// Kinetic energy `sum c |u|^2 / 2 |C|` (per unit grain density).
    pub kinetic_energy: R,
    /// Steady-state residual of the last step: `max |u^{n+1} - u^n| / (dt max(|u|, u_ref))`
    /// (1/s) over cells with `c >= surface`, `u_ref` = the largest boundary speed or 1e-3 m/s.
    pub residual: R,
}

/// Names of the momentum arrays in the state visitors.
const MOMENTUM_NAMES: [&str; 4] = ["m0", "m1", "m2", "m3+"];
/// Names of the start-of-step velocity arrays in the state visitors.
const START_NAMES: [&str; 4] = ["u0_start", "u1_start", "u2_start", "u3+_start"];
/// Names of the held-acceleration arrays ([`FlowConfig::viscous_share`]) in the state
/// visitors.
const HOLD_NAMES: [&str; 4] = ["hold0", "hold1", "hold2", "hold3+"];

/// The scalars of a [`Flow`] that a checkpoint keeps besides its arrays
/// ([`Flow::for_each_state_array`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlowCounters<R, const D: usize> {
    /// Simulated time.
    pub time: R,
    /// Steps taken.
    pub steps: u64,
    /// Steady-state residual of the last step.
    pub residual: R,
    /// Conjugate-gradient iterations so far.
    pub cg_iterations: u64,
    /// Iterations of the last step's solves.
    pub last_cg: [u32; 4],
    /// Grain volume out through each side since setup.
    pub discharged: [[R; 2]; D],
    /// Grain volume out through each side in the last step.
    pub discharge_step: [[R; 2]; D],
}

/// The flow solver for up to `N` cells of a `D`-dimensional grid. Large: keep it in a
/// `static` or on the heap.
#[derive(Clone, Debug)]
pub struct Flow<R: Real, const D: usize, const N: usize> {
    grid: Grid<R, D>,
    /// The whole grid: the grid itself, or on a slab the grid it is cut from
    /// ([`slab::load_slab`]). Positions are taken on it, so that a slab places its faces
    /// where the whole grid does to the bit (`origin + k h`, never `(origin + k0 h) + k h`):
    /// a rotating frame's body force and the bound of its centrifugal acceleration, the
    /// openings of the walls and the cut wall's rigid motion ([`Self::home_center`]).
    home: Grid<R, D>,
    /// Rows of `home` below the grid's first row (0 but on a slab).
    home_rows: usize,
    /// Cells of `home` before the grid's first cell (`home_rows` rows).
    home_first: usize,
    bc: FlowBoundaries<R, D>,
    cfg: FlowConfig<R, D>,
    /// Volume fraction.
    c: [R; N],
    /// Momentum `c u`.
    m: [[R; N]; D],
    /// `c T`.
    e: [R; N],
    /// Velocity (primitive).
    u: [[R; N]; D],
    /// Temperature (primitive).
    t: [R; N],
    /// Pressure.
    p: [R; N],
    /// Cell transport coefficients (lagged within a step).
    eta: [R; N],
    lam: [R; N],
    eps: [R; N],
    /// Packing limits per cell (constants, or back-coupled).
    c_rcp: [R; N],
    c_rlp: [R; N],
    /// Face mass fluxes per axis at the left cell of each face (at the last cell of a line:
    /// its high boundary face, positive = out of the box, or the wrap face): during the
    /// transport stage the raw flux, after it the applied (limited) amount of the step in
    /// content units (`dt / h` times the flux), positive along the axis.
    flux: [[R; N]; D],
    /// The applied amount of each low boundary face (at the first cell of a line; positive
    /// = into the box; 0 on closed walls and periodic axes).
    flux_low: [[R; N]; D],
    /// Grain volume that left through each side `[axis][low, high]`, since setup.
    discharged: [[R; 2]; D],
    /// Grain volume that left through each side in the last step.
    discharge_step: [[R; 2]; D],
    kf: [[R; N]; D],
    /// Velocity at the start of the step, `u^n` (residual, lagged wall friction, the
    /// solves' initial guess). State: after a step it holds the start of the step just taken,
    /// which the next step's guess extrapolates from.
    u_prev: [[R; N]; D],
    /// Velocity at the start of the previous step, `u^{n-1}` (the guess `2 u^n - u^{n-1}`,
    /// [`VelocityGuess`]); copied from `u_prev` when a step starts.
    u_before: [[R; N]; D],
    /// The last step's acceleration from the transport and the stress,
    /// `(u^{n+1} - u^n)/dt` less the pressure and gravity's, per cell and axis
    /// ([`FlowConfig::viscous_share`]; state, zero without it).
    hold: [[R; N]; D],
    /// Scratch of the limiter and the linear solves' systems (`diag`, `rhs`); `inflow` is
    /// also the solves' `tmp` ([`SolveSet::scratch`]).
    inflow: [R; N],
    diag: [R; N],
    rhs: [R; N],
    /// The linear solves' scratch (also the wall and objective updates' between solves).
    solve: SolveSet<R, D, N>,
    /// The second velocity solve's systems and scratch when two solve side by side
    /// (`viscous`).
    spare: SpareSolve<R, D, N>,
    /// Iterations of the last implicit pressure solve (0 in explicit mode).
    last_pressure_cg: u32,
    /// Gravity of the current step as seen in the frame (the lab's in the lab frame).
    g_now: [R; D],
    prepared: bool,
    time: R,
    steps: u64,
    residual: R,
    cg_iterations: u64,
    last_cg: [u32; 4],
    /// Embedded (cut-cell) walls, off unless [`Flow::set_geometry`] loaded them.
    walls: walls::Walls<R, D, N>,
}

/// The arrays one conjugate-gradient solve works in ([`cg::Scratch`] without `tmp`, which
/// the caller lends). Held twice: once as the flow's own solve scratch, once in
/// [`SpareSolve`]. Never state between steps.
#[derive(Clone, Debug)]
struct SolveSet<R, const D: usize, const N: usize> {
    r: [R; N],
    p: [R; N],
    ap: [R; N],
    pre: [R; N],
    line: [R; N],
    /// Coarse levels of the multigrid preconditioner ([`cg`]).
    coarse: [[R; N]; D],
    /// Block partials of the solves' threaded sums ([`cg::Scratch::part`]).
    part: [R; N],
}

impl<R: Real, const D: usize, const N: usize> SolveSet<R, D, N> {
    const fn zeroed() -> Self {
        Self {
            r: [R::ZERO; N],
            p: [R::ZERO; N],
            ap: [R::ZERO; N],
            pre: [R::ZERO; N],
            line: [R::ZERO; N],
            coarse: [[R::ZERO; N]; D],
            part: [R::ZERO; N],
        }
    }

    /// The set as one solve's scratch, with `tmp` lent by the caller.
    fn scratch<'a>(&'a mut self, tmp: &'a mut [R]) -> cg::Scratch<'a, R> {
        cg::Scratch {
            r: &mut self.r,
            p: &mut self.p,
            ap: &mut self.ap,
            pre: &mut self.pre,
            line: &mut self.line,
            tmp,
            coarse: self.coarse.as_flattened_mut(),
            part: &mut self.part,
        }
    }
}

/// A second set of the implicit solves' systems and scratch: with it the velocity components
/// solve on two workers at once, the vertical one on one, the horizontal ones on the other
/// (docs/parallel.md, "Velocity components side by side"). Never state: outside that solve
/// only the implicit pressure keeps `p^n`, `c^n` and `a_s^2` in `diag`, `diag2` and `rhs`
/// for its free-surface cap, between its solve and the momentum update (before the viscous
/// stage; the main set's arrays are the embedded transport's scratch then).
#[derive(Clone, Debug)]
struct SpareSolve<R, const D: usize, const N: usize> {
    /// The first horizontal component's system.
    diag: [R; N],
    rhs: [R; N],
    /// The second one's (3D).
    diag2: [R; N],
    rhs2: [R; N],
    /// The solves' `tmp`.
    tmp: [R; N],
    set: SolveSet<R, D, N>,
}

impl<R: Real, const D: usize, const N: usize> Flow<R, D, N> {
    /// An empty solver on a one-cell grid; `const` so it can live in a `static`.
    pub const fn zeroed() -> Self {
        let side = FlowSide::wall(Slip::NoSlip);
        let z = [R::ZERO; N];
        let zd = [[R::ZERO; N]; D];
        Self {
            grid: Grid::unit(),
            home: Grid::unit(),
            home_rows: 0,
            home_first: 0,
            bc: [[side; 2]; D],
            cfg: FlowConfig {
                material: Material {
                    eta0: R::ONE,
                    lambda0: R::ONE,
                    eps0: R::ONE,
                    t0: R::ONE,
                    phi_rcp: R::ONE,
                    phi_rlp: R::HALF,
                    heating: R::ONE,
                    s0: R::ONE,
                },
                gravity: [R::ZERO; D],
                courant: R::HALF,
                t_min: R::VACUUM,
                margin: R::VACUUM,
                vacuum: R::VACUUM,
                surface: R::VACUUM,
                cg_tolerance: R::VACUUM,
                cg_tolerance_pressure: R::VACUUM,
                cg_max_iterations: 1,
                free_surface_push: false,
                frame: Frame::Lab,
                pressure: PressureMode::Explicit,
                stress: Stress::Spec,
                guess: VelocityGuess::Extrapolated,
                merged_walls: MergedWalls::Master,
                viscous_share: false,
            },
            c: z,
            m: zd,
            e: z,
            u: zd,
            t: z,
            p: z,
            eta: z,
            lam: z,
            eps: z,
            c_rcp: z,
            c_rlp: z,
            flux: zd,
            flux_low: zd,
            discharged: [[R::ZERO; 2]; D],
            discharge_step: [[R::ZERO; 2]; D],
            kf: zd,
            u_prev: zd,
            u_before: zd,
            hold: zd,
            inflow: z,
            diag: z,
            rhs: z,
            solve: SolveSet::zeroed(),
            spare: SpareSolve {
                diag: z,
                rhs: z,
                diag2: z,
                rhs2: z,
                tmp: z,
                set: SolveSet::zeroed(),
            },
            last_pressure_cg: 0,
            g_now: [R::ZERO; D],
            prepared: false,
            time: R::ZERO,
            steps: 0,
            residual: R::ZERO,
            cg_iterations: 0,
            last_cg: [0; 4],
            walls: walls::Walls::zeroed(),
        }
    }

    /// Fixes grid, boundaries and configuration; clears the fields (c = 0 everywhere) and sets
    /// the packing limits to the material constants.
    pub fn setup(
        &mut self,
        grid: Grid<R, D>,
        bc: FlowBoundaries<R, D>,
        cfg: FlowConfig<R, D>,
    ) -> Result<(), FlowError> {
        if grid.len() > N {
            return Err(FlowError::Capacity);
        }
        let mut kinds = [[Boundary::Wall; 2]; D];
        for a in 0..D {
            kinds[a] = [bc[a][0].kind, bc[a][1].kind];
        }
        check_periodic_pairs(&kinds).map_err(FlowError::UnpairedPeriodic)?;
        cfg.material.validate().map_err(FlowError::Parameter)?;
        let pos = |x: R| x.is_finite() && x > R::ZERO;
        if !(pos(cfg.courant) && cfg.courant <= R::HALF) {
            return Err(FlowError::Parameter("courant"));
        }
        for (name, v) in [
            ("t_min", cfg.t_min),
            ("margin", cfg.margin),
            ("vacuum", cfg.vacuum),
            ("surface", cfg.surface),
            ("cg_tolerance", cfg.cg_tolerance),
            ("cg_tolerance_pressure", cfg.cg_tolerance_pressure),
        ] {
            if !pos(v) {
                return Err(FlowError::Parameter(name));
            }
        }
        if cfg.margin >= R::ONE || cfg.cg_max_iterations == 0 {
            return Err(FlowError::Parameter("margin/cg_max_iterations"));
        }
        if cfg.gravity.iter().any(|g| !g.is_finite()) {
            return Err(FlowError::Parameter("gravity"));
        }
        if let Frame::Rotating(rot) = &cfg.frame {
            rot.validate()
                .map_err(|_| FlowError::Parameter("rotating frame"))?;
            // Centrifugal forces are not periodic: the rotation plane must be bounded.
            for a in 0..D {
                if rot.in_plane(a) && bc[a][0].kind == Boundary::Periodic {
                    return Err(FlowError::Parameter(
                        "rotating frame: periodic axis in the rotation plane",
                    ));
                }
            }
        }
        for sides in bc.iter() {
            for s in sides {
                if let Slip::Friction(tan) = s.slip {
                    if !(tan.is_finite() && tan >= R::ZERO) {
                        return Err(FlowError::Parameter("wall friction"));
                    }
                }
                if !s.openings.is_empty() && s.kind != Boundary::Wall {
                    return Err(FlowError::Parameter(
                        "openings on a side that is not a wall",
                    ));
                }
                if s.velocity.iter().any(|v| !v.is_finite()) || !s.c.is_finite() {
                    return Err(FlowError::Parameter("boundary state"));
                }
                if s.kind == Boundary::Inflow
                    && !(s.c >= R::ZERO
                        && s.c < (R::ONE - cfg.margin) * cfg.material.phi_rcp
                        && s.t >= R::ZERO)
                {
                    return Err(FlowError::Parameter("inflow state"));
                }
            }
        }
        self.grid = grid;
        self.home = grid;
        self.home_rows = 0;
        self.home_first = 0;
        self.bc = bc;
        self.cfg = cfg;
        let n = grid.len();
        for arr in [
            &mut self.c,
            &mut self.e,
            &mut self.t,
            &mut self.p,
            &mut self.eta,
            &mut self.lam,
            &mut self.eps,
        ] {
            arr[..n].fill(R::ZERO);
        }
        for a in 0..D {
            self.m[a][..n].fill(R::ZERO);
            self.u[a][..n].fill(R::ZERO);
            self.u_prev[a][..n].fill(R::ZERO);
            self.u_before[a][..n].fill(R::ZERO);
            self.hold[a][..n].fill(R::ZERO);
            self.flux[a][..n].fill(R::ZERO);
            self.flux_low[a][..n].fill(R::ZERO);
        }
        self.discharged = [[R::ZERO; 2]; D];
        self.discharge_step = [[R::ZERO; 2]; D];
        self.c_rcp[..n].fill(cfg.material.phi_rcp);
        self.c_rlp[..n].fill(cfg.material.phi_rlp);
        self.g_now = cfg.frame.gravity(cfg.gravity, R::ZERO);
        self.walls.on = false;
        self.walls.merged = false;
        self.prepared = false;
        self.time = R::ZERO;
        self.steps = 0;
        self.residual = R::ZERO;
        self.cg_iterations = 0;
        Ok(())
    }

    /// Sets the state of cell `i`: volume fraction, velocity, temperature.
    pub fn set_cell(&mut self, i: usize, c: R, u: [R; D], t: R) {
        self.c[i] = c;
        self.t[i] = t;
        self.e[i] = c * t;
        for a in 0..D {
            self.u[a][i] = u[a];
            self.m[a][i] = c * u[a];
        }
        self.prepared = false;
    }

    /// Sets the packing limits of cell `i` (back-coupling, model.md 4). If the current `c`
    /// exceeds the new `c_max`, the pressure is evaluated at `c_max` until the flow relaxes it
    /// (the limiter admits no inflow into such a cell).
    pub fn set_packing(&mut self, i: usize, c_rcp: R, c_rlp: R) {
        self.c_rcp[i] = c_rcp;
        self.c_rlp[i] = c_rlp;
    }

    /// Validates the fields and derives the primitives, pressure and coefficients. With an
    /// embedded wall, solid cells are emptied first and every merge group takes its
    /// content-weighted mean state (conservative).
    pub fn prepare(&mut self) -> Result<(), FlowError> {
        let n = self.grid.len();
        if self.walls.on {
            self.embedded_prepare();
        }
        for i in 0..n {
            let cmax = (R::ONE - self.cfg.margin) * self.c_rcp[i];
            if !(self.c[i].is_finite() && self.c[i] >= R::ZERO && self.c[i] <= cmax) {
                return Err(FlowError::Field {
                    field: "c",
                    cell: i,
                });
            }
            if !(self.t[i].is_finite() && self.t[i] >= R::ZERO) {
                return Err(FlowError::Field {
                    field: "T",
                    cell: i,
                });
            }
            if !(self.c_rlp[i] > R::ZERO && self.c_rlp[i] < self.c_rcp[i]) {
                return Err(FlowError::Field {
                    field: "packing",
                    cell: i,
                });
            }
            for a in 0..D {
                if !self.u[a][i].is_finite() {
                    return Err(FlowError::Field {
                        field: "u",
                        cell: i,
                    });
                }
            }
        }
        self.g_now = self.cfg.frame.gravity(self.cfg.gravity, self.time);
        self.primitives();
        // The first step's guess extrapolates from a start that did not move: `u^0` itself.
        for a in 0..D {
            self.u_prev[a][..n].copy_from_slice(&self.u[a][..n]);
        }
        self.pressures();
        self.prepared = true;
        Ok(())
    }

    /// The largest stable step (module docs): `C / max_i sum_a (|u_a| + a_s) / h_a` plus the
    /// free-fall term (explicit), or the Courant condition at the end-of-step free-fall speed
    /// over the cells with `c >= surface` and at the exit speed of the outlet faces
    /// (implicit).
    pub fn stable_dt(&self) -> R {
        self.stable_dt_reaching(&mut reach::Whole)
    }

    /// [`Self::stable_dt`] of the whole grid from a subdomain: the owned cells' rates, their
    /// maximum over every subdomain from `reach` (collective). `C / max rate` is the serial
    /// step to the bit, and so is the smallest of the outlets' steps.
    pub fn stable_dt_reaching<Re: reach::Reach<R, D, N>>(&self, reach: &mut Re) -> R {
        if self.cfg.pressure == PressureMode::Implicit {
            return self.implicit_stable_dt(reach);
        }
        let n = self.grid.len();
        let h = self.grid.spacing();
        let m = &self.cfg.material;
        // Free fall: a velocity gained within the step must not break the Courant limit,
        // |g| dt^2 / h <= C^2, i.e. a rate sqrt(|g_a| / h_a) per axis.
        let body = self.body_bound();
        // The free-fall rate is the same in every cell: one square root per axis, not per cell
        // (added in the same place of the sum, so the same bits).
        let fall: [R; D] = core::array::from_fn(|a| (body[a] / h[a]).sqrt());
        let mut rate = R::ZERO;
        for i in reach.owned(n) {
            let (c, rcp, rlp) = (self.c_eff(i), self.c_rcp[i], self.c_rlp[i]);
            let a_s = closure::sound_speed_squared(m, c, self.t[i], rcp, rlp).sqrt();
            let mut r = R::ZERO;
            for a in 0..D {
                r += (self.u[a][i].abs() + a_s) / h[a] + fall[a];
            }
            rate = rate.max(r);
        }
        let rate = reach.max(rate);
        if rate > R::ZERO {
            self.cfg.courant / rate
        } else {
            R::MAX
        }
    }

    /// Per axis `a`, `max_i (|u_a| + a_s) / h_a + sqrt(|b_a| / h_a)` with the body
    /// acceleration `b` of now: the rates that set the Rhie-Chow time scales (model.md 5.3).
    /// Each axis has its own, so a face's correction reads nothing of the spacing across it
    /// (an x-independent flow on fewer columns keeps its bits), and the frame enters only
    /// through the body force it exerts now (a frame at rest is the lab frame to the bit).
    pub(super) fn rhie_chow_rates<Re: reach::Reach<R, D, N>>(&self, reach: &mut Re) -> [R; D] {
        let h = self.grid.spacing();
        let m = &self.cfg.material;
        let mut rate = [R::ZERO; D];
        for i in reach.owned(self.grid.len()) {
            let (c, rcp, rlp) = (self.c_eff(i), self.c_rcp[i], self.c_rlp[i]);
            let a_s = closure::sound_speed_squared(m, c, self.t[i], rcp, rlp).sqrt();
            for a in 0..D {
                rate[a] = rate[a].max((self.u[a][i].abs() + a_s) / h[a]);
            }
        }
        for a in 0..D {
            rate[a] = reach.max(rate[a]);
            let mut b = self.g_now[a].abs();
            if let Frame::Rotating(rot) = &self.cfg.frame {
                if rot.in_plane(a) {
                    let (lo, cells) = (self.home.origin()[a], self.home.cells()[a]);
                    let hi = lo + h[a] * R::from_usize(cells);
                    b += rot
                        .centrifugal(a, lo)
                        .abs()
                        .max(rot.centrifugal(a, hi).abs());
                }
            }
            rate[a] += (b / h[a]).sqrt();
        }
        rate
    }

    /// [`Self::stable_dt`] with the implicit pressure (model.md 5.4; module docs): no acoustic
    /// term, `C / (max_i sum_a |u_a| / h_a + sum_a sqrt(b_a / h_a))`. Near-empty cells
    /// (`c < surface`: dust thrown off a free surface at ~1 m/s) do not count in `|u_a|`: the
    /// transport's donor limiters act on the final face fluxes, so mass stays exact and
    /// `0 <= c <= c_max` holds at any Courant number of such a cell, and their momentum rides
    /// on those same limited fluxes. Counting them held the 64 x 64 tumbler at 7e-4 s where
    /// its dense bed allows 1.4e-3 s (docs/implicit-pressure.md).
    fn implicit_stable_dt<Re: reach::Reach<R, D, N>>(&self, reach: &mut Re) -> R {
        let h = self.grid.spacing();
        let body = self.body_bound();
        let mut adv = R::ZERO;
        for i in reach.owned(self.grid.len()) {
            if self.c_eff(i) >= self.cfg.surface {
                let mut r = R::ZERO;
                for a in 0..D {
                    r += self.u[a][i].abs() / h[a];
                }
                adv = adv.max(r);
            }
        }
        let mut rate = reach.max(adv);
        for a in 0..D {
            rate += (body[a] / h[a]).sqrt();
        }
        let dt = if rate > R::ZERO {
            self.cfg.courant / rate
        } else {
            R::MAX
        };
        // the smallest outlet step of all (a minimum: the largest negation, exact)
        dt.min(-reach.max(-self.outlet_dt(reach.owned(self.grid.len()))))
    }

    /// The step at which an outlet face's exit speed keeps the Courant limit (model.md 5.4,
    /// "Outlets"): under the implicit pressure a cell of an opening leaves with
    /// `v = u_i + dt a_i`, `a_i = F_open / (2 c_i) + s_i` ([`Self::outlet_velocity`]), so the
    /// exit speed grows with the step, and the condition `(|u_i| + |a_i| dt) dt <= C h` is the
    /// positive root `dt = 2 C h / (|u_i| + sqrt(u_i^2 + 4 |a_i| C h))` (no cancellation).
    /// Why: `|u|` of the cells alone let a packed orifice at rest take the free-fall step,
    /// whose push emptied the orifice cells in one step and left a slow, self-sustaining
    /// branch (a 4-cell orifice at 0.35 of the explicit rate, docs/implicit-pressure.md). Only
    /// sides with openings are visited: other scenes do not pay for it.
    fn outlet_dt(&self, owned: Range<usize>) -> R {
        let h = self.grid.spacing();
        let mut dt = R::MAX;
        self.each_outlet_cell(owned, |a, u, acc| {
            let ch = self.cfg.courant * h[a];
            let root = (u * u + R::from_f64(4.0) * acc * ch).sqrt();
            if u + root > R::ZERO {
                dt = dt.min(R::TWO * ch / (u + root));
            }
        });
        dt
    }

    /// The largest Courant number `(|u_i| + |a_i| dt) dt / h` of an outlet face at step `dt`
    /// (model.md 5.4, "Outlets"; `a_i = 0` under the explicit pressure, whose outflow leaves
    /// with the cell's velocity), 0 without openings: under the implicit pressure
    /// [`Self::stable_dt`] keeps it at or below `flow.courant`.
    pub fn outlet_courant(&self, dt: R) -> R {
        let h = self.grid.spacing();
        let mut nu = R::ZERO;
        let all = 0..self.grid.len();
        self.each_outlet_cell(all, |a, u, acc| nu = nu.max((u + acc * dt) * dt / h[a]));
        nu
    }

    /// Calls `f(axis, |u_i|, |a_i|)` for every cell with grains behind an open face: its
    /// velocity along the face normal and, under the implicit pressure, the acceleration its
    /// exit speed gains per unit step (`F_open / (2 c_i) + s_i`; 0 under the explicit one).
    /// Only the cells `owned` (a slab's halo rows are its neighbours' to count).
    fn each_outlet_cell(&self, owned: Range<usize>, mut f: impl FnMut(usize, R, R)) {
        let implicit = self.cfg.pressure == PressureMode::Implicit;
        for a in 0..D {
            for high in [false, true] {
                let side = &self.bc[a][usize::from(high)];
                if side.kind != Boundary::Wall || side.openings.is_empty() {
                    continue;
                }
                self.grid.for_each_boundary_cell(a, high, |i, _| {
                    let ci = self.c[i];
                    if !owned.contains(&i)
                        || ci <= self.cfg.vacuum
                        || self.open_fraction(a, high, i) == R::ZERO
                    {
                        return;
                    }
                    let mut acc = R::ZERO;
                    if implicit {
                        let (push, share, _) = self.outlet_push(a, i, high, side);
                        acc = push;
                        if self.holds() {
                            acc += share;
                        }
                    }
                    f(a, self.u[a][i].abs(), acc.abs());
                });
            }
        }
    }

    /// Bound of the body acceleration along each axis over the box and all times: `|g_a|` in
    /// the lab frame; in a rotating frame `|g|` (gravity turns) plus the largest centrifugal
    /// acceleration `omega^2 |x_a - center_a|` on the box for the axes of the rotation plane.
    fn body_bound(&self) -> [R; D] {
        let g = self.cfg.gravity;
        let mut b = [R::ZERO; D];
        match &self.cfg.frame {
            Frame::Lab => {
                for a in 0..D {
                    b[a] = g[a].abs();
                }
            }
            Frame::Rotating(rot) => {
                let fb = &self.home;
                let (lo, h, cells) = (fb.origin(), fb.spacing(), fb.cells());
                let mut plane_g2 = R::ZERO;
                for a in 0..D {
                    if rot.in_plane(a) {
                        plane_g2 += g[a] * g[a];
                    }
                }
                for a in 0..D {
                    b[a] = if rot.in_plane(a) {
                        let hi = lo[a] + h[a] * R::from_usize(cells[a]);
                        let r = rot
                            .centrifugal(a, lo[a])
                            .abs()
                            .max(rot.centrifugal(a, hi).abs());
                        plane_g2.sqrt() + r
                    } else {
                        g[a].abs()
                    };
                }
            }
        }
        b
    }

    /// Gravity at the flow's current time as seen in its frame (the lab's in the lab frame).
    pub fn frame_gravity(&self) -> [R; D] {
        self.cfg.frame.gravity(self.cfg.gravity, self.time)
    }

    /// `c` clamped to `c_max` of its cell (only differs after a packing change).
    #[inline]
    fn c_eff(&self, i: usize) -> R {
        self.c[i].min((R::ONE - self.cfg.margin) * self.c_rcp[i])
    }

    /// Velocity and temperature from the conserved variables; empty cells at rest and cold.
    fn primitives(&mut self) {
        let n = self.grid.len();
        let vac = self.cfg.vacuum;
        for i in 0..n {
            let c = self.c[i];
            if c > vac {
                self.t[i] = (self.e[i] / c).max(R::ZERO);
                for a in 0..D {
                    self.u[a][i] = self.m[a][i] / c;
                }
            } else {
                self.t[i] = R::ZERO;
                self.e[i] = R::ZERO;
                for a in 0..D {
                    self.u[a][i] = R::ZERO;
                    self.m[a][i] = R::ZERO;
                }
            }
        }
    }

    /// Pressure of every cell from the current c and T.
    fn pressures(&mut self) {
        let n = self.grid.len();
        for i in 0..n {
            let c = self.c_eff(i);
            self.p[i] = closure::pressure(
                &self.cfg.material,
                c,
                self.t[i],
                self.c_rcp[i],
                self.c_rlp[i],
            );
        }
    }

    /// Advances with the stable step until `t_end` (last step shortened), at most `max_steps`
    /// steps; returns the number taken.
    pub fn advance_to(&mut self, t_end: R, max_steps: u64) -> u64 {
        let mut taken = 0;
        while self.time < t_end && taken < max_steps {
            let dt = self.stable_dt().min(t_end - self.time);
            self.step(dt);
            taken += 1;
        }
        taken
    }

    /// Diagnostics of the current state.
    pub fn diagnostics(&self) -> FlowDiagnostics<R> {
        let n = self.grid.len();
        let vol = self.grid.cell_volume();
        let mut d = FlowDiagnostics {
            mass: R::ZERO,
            max_packing: R::ZERO,
            t_min: R::MAX,
            t_max: R::ZERO,
            max_speed: R::ZERO,
            kinetic_energy: R::ZERO,
            residual: self.residual,
        };
        let emb = self.walls.on;
        for i in 0..n {
            // open volume of the cell (exactly `vol` without a geometry)
            let v = if emb { self.walls.vol[i] * vol } else { vol };
            d.mass += self.c[i] * v;
            d.max_packing = d.max_packing.max(self.c[i] / self.c_rcp[i]);
            d.t_min = d.t_min.min(self.t[i]);
            let s2 = self.speed_squared(i);
            if self.c[i] >= self.cfg.surface {
                d.t_max = d.t_max.max(self.t[i]);
                d.max_speed = d.max_speed.max(s2.sqrt());
            }
            d.kinetic_energy += R::HALF * self.c[i] * s2 * v;
        }
        d
    }

    fn speed_squared(&self, i: usize) -> R {
        let mut s2 = R::ZERO;
        for a in 0..D {
            s2 += self.u[a][i] * self.u[a][i];
        }
        s2
    }

    /// The grid.
    pub fn grid(&self) -> &Grid<R, D> {
        &self.grid
    }
    /// The boundaries.
    pub fn boundaries(&self) -> &FlowBoundaries<R, D> {
        &self.bc
    }
    /// The configuration.
    pub fn config(&self) -> &FlowConfig<R, D> {
        &self.cfg
    }
    /// Volume fraction of cell `i`.
    pub fn c(&self, i: usize) -> R {
        self.c[i]
    }
    /// Velocity of cell `i`.
    pub fn velocity(&self, i: usize) -> [R; D] {
        let mut u = [R::ZERO; D];
        for a in 0..D {
            u[a] = self.u[a][i];
        }
        u
    }
    /// Temperature of cell `i`.
    pub fn temperature(&self, i: usize) -> R {
        self.t[i]
    }
    /// Pressure of cell `i` (from the current c and T).
    pub fn pressure(&self, i: usize) -> R {
        self.p[i]
    }
    /// Viscosity of cell `i` as used in the last step.
    pub fn viscosity(&self, i: usize) -> R {
        self.eta[i]
    }
    /// Packing limits `(c_rcp, c_rlp)` of cell `i`.
    pub fn packing(&self, i: usize) -> (R, R) {
        (self.c_rcp[i], self.c_rlp[i])
    }
    /// Simulated time.
    pub fn time(&self) -> R {
        self.time
    }
    /// The face mass fluxes the last step applied (time-integrated, limited, in content
    /// units): what the segregation solver's carried transport moves phi with.
    pub fn mass_fluxes(&self) -> MassFluxes<'_, R, D, N> {
        MassFluxes {
            faces: &self.flux,
            low: &self.flux_low,
            open: core::array::from_fn(|a| {
                core::array::from_fn(|s| step::moves_mass(&self.bc[a][s]))
            }),
        }
    }
    /// Grain volume (volume fraction times cell volume, summed) that left through each side
    /// `[axis][low, high]` since setup (negative if it came in).
    pub fn discharged(&self) -> [[R; 2]; D] {
        self.discharged
    }
    /// Grain volume that left through each side in the last step.
    pub fn last_discharge(&self) -> [[R; 2]; D] {
        self.discharge_step
    }
    /// The centre of cell `i` as the whole grid places it (`home`): what the cut wall's rigid
    /// motion is evaluated at.
    #[inline(always)]
    pub(super) fn home_center(&self, i: usize) -> [R; D] {
        self.home.center(self.home_first + i)
    }
    /// Open fraction of the boundary face of cell `i` on side `high` of axis `a` (0 unless
    /// the side is a wall with openings).
    #[inline]
    pub fn open_fraction(&self, a: usize, high: bool, i: usize) -> R {
        let side = &self.bc[a][usize::from(high)];
        if side.kind != Boundary::Wall || side.openings.is_empty() {
            return R::ZERO;
        }
        side.openings.fraction(&self.home, a, self.home_first + i)
    }
    /// Steps taken.
    pub fn steps(&self) -> u64 {
        self.steps
    }
    /// Steady-state residual of the last step (see [`FlowDiagnostics::residual`]).
    pub fn residual(&self) -> R {
        self.residual
    }
    /// Total conjugate-gradient iterations so far.
    pub fn cg_iterations(&self) -> u64 {
        self.cg_iterations
    }
    /// Iterations of the last step's solves (velocity components..., temperature last).
    pub fn last_cg_iterations(&self) -> [u32; 4] {
        self.last_cg
    }
    /// Iterations of the last step's implicit pressure solve (0 in explicit mode; they are
    /// also counted in [`Self::cg_iterations`]).
    pub fn last_pressure_iterations(&self) -> u32 {
        self.last_pressure_cg
    }

    /// Visits the per-cell arrays that carry information from one step to the next, over the
    /// active cells, by name, in a fixed order: `c`, `e` (= c T), `T`, `p`, the packing
    /// limits `c_rcp`, `c_rlp` (back-coupled), the lagged coefficients `eta`, `lambda`, `eps`,
    /// then momentum `m0..`, velocity `u0..` and the velocity at the start of the last step
    /// `u0_start..` (the next step's initial guess extrapolates from it) per axis, and with
    /// the implicit pressure's viscous share the last step's accelerations from the stress
    /// and the transport `hold0..` (the next step's face velocities add them). Everything
    /// else (face fluxes, CG and multigrid work space) is rebuilt within a step. With
    /// [`Self::counters`] this is the state a checkpoint keeps (the geometry and
    /// configuration come from the scene).
    pub fn for_each_state_array(&self, mut f: impl FnMut(&'static str, &[R])) {
        let n = self.grid.len();
        f("c", &self.c[..n]);
        f("e", &self.e[..n]);
        f("T", &self.t[..n]);
        f("p", &self.p[..n]);
        f("c_rcp", &self.c_rcp[..n]);
        f("c_rlp", &self.c_rlp[..n]);
        f("eta", &self.eta[..n]);
        f("lambda", &self.lam[..n]);
        f("eps", &self.eps[..n]);
        for a in 0..D {
            f(MOMENTUM_NAMES[a.min(3)], &self.m[a][..n]);
            f(crate::segregation::axis_name(a), &self.u[a][..n]);
            f(START_NAMES[a.min(3)], &self.u_prev[a][..n]);
        }
        if self.holds() {
            for a in 0..D {
                f(HOLD_NAMES[a.min(3)], &self.hold[a][..n]);
            }
        }
    }

    /// The arrays of [`Self::for_each_state_array`] for writing (restoring a checkpoint bit for
    /// bit, after `setup` and `prepare` of the same scene).
    pub fn for_each_state_array_mut(&mut self, mut f: impl FnMut(&'static str, &mut [R])) {
        let n = self.grid.len();
        f("c", &mut self.c[..n]);
        f("e", &mut self.e[..n]);
        f("T", &mut self.t[..n]);
        f("p", &mut self.p[..n]);
        f("c_rcp", &mut self.c_rcp[..n]);
        f("c_rlp", &mut self.c_rlp[..n]);
        f("eta", &mut self.eta[..n]);
        f("lambda", &mut self.lam[..n]);
        f("eps", &mut self.eps[..n]);
        for a in 0..D {
            f(MOMENTUM_NAMES[a.min(3)], &mut self.m[a][..n]);
            f(crate::segregation::axis_name(a), &mut self.u[a][..n]);
            f(START_NAMES[a.min(3)], &mut self.u_prev[a][..n]);
        }
        if self.holds() {
            for a in 0..D {
                f(HOLD_NAMES[a.min(3)], &mut self.hold[a][..n]);
            }
        }
    }

    /// Whether the step keeps its acceleration from the stress and the transport for the next
    /// step's face velocities ([`FlowConfig::viscous_share`] with implicit pressure).
    pub(super) fn holds(&self) -> bool {
        self.cfg.viscous_share && self.cfg.pressure == PressureMode::Implicit
    }

    /// Clock, counters and discharge totals (checkpoints; see [`FlowCounters`]).
    pub fn counters(&self) -> FlowCounters<R, D> {
        FlowCounters {
            time: self.time,
            steps: self.steps,
            residual: self.residual,
            cg_iterations: self.cg_iterations,
            last_cg: self.last_cg,
            discharged: self.discharged,
            discharge_step: self.discharge_step,
        }
    }

    /// Restores [`Self::counters`]; the frame's gravity follows the restored clock.
    pub fn restore_counters(&mut self, k: FlowCounters<R, D>) {
        self.time = k.time;
        self.steps = k.steps;
        self.residual = k.residual;
        self.cg_iterations = k.cg_iterations;
        self.last_cg = k.last_cg;
        self.discharged = k.discharged;
        self.discharge_step = k.discharge_step;
        self.g_now = self.cfg.frame.gravity(self.cfg.gravity, self.time);
    }
    /// Number of active cells.
    pub fn len(&self) -> usize {
        self.grid.len()
    }
    /// Never empty.
    pub fn is_empty(&self) -> bool {
        false
    }
}

impl<R: Real, const D: usize, const N: usize> Default for Flow<R, D, N> {
    fn default() -> Self {
        Self::zeroed()
    }
}
