//! The segregation equation (model.md section 3) on a static grid, for a given (prescribed or
//! measured) velocity field, volume fraction and granular temperature.
//!
//! Data flow: [`Segregation::setup`] fixes grid, boundaries and configuration; the caller fills
//! the cells ([`Segregation::set_cell`], [`Segregation::set_inflow`]); [`Segregation::prepare`]
//! validates them and derives the static face coefficients (T from shear, segregation
//! direction, `k = S.n / c`, the stable time step); [`Segregation::step`] advances.
//! Memory is fixed by the capacity `N` and the dimension `D`; nothing allocates.

mod carried;
pub mod direction;
mod eigen3;
mod embedded;
pub mod flux;
mod limited;
mod step;

pub use crate::hot::{Baseline, HotLoop, Isa};
pub use carried::{Discharge, MassFluxes};
pub use flux::Scheme;
pub use limited::Transport;

use crate::boundary::{check_periodic_pairs, Boundaries, Boundary};
use crate::fork::{self, Call, Fork, SerialAt};
use crate::grid::Grid;
use crate::real::Real;
use crate::sum::FixedSum;
use direction::LANES_3D;
use serde::{Deserialize, Serialize};

/// Which phase the solver tracks. Its fraction `q` is phi (small) or `psi = c - phi` (large).
/// The small phase has a convex flux, the large phase a concave one. For the modified flux
/// both give the same phi to round-off; for the naive fluxes they differ (model.md 5).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Phase {
    /// Track phi, the small grains.
    #[default]
    Small,
    /// Track psi = c - phi, the large grains.
    Large,
}

/// How the segregation direction `d_s` is chosen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum DirectionMode<R: Real, const D: usize> {
    /// A fixed unit vector (normalised on prepare).
    Fixed([R; D]),
    /// Parallel to gravity.
    Gravity,
    /// From the velocity gradient (model.md 3); parallel to gravity where the shear vanishes.
    Flow,
}

/// Where the granular temperature comes from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TemperatureMode<R: Real> {
    /// The T set per cell is used as is.
    Given,
    /// `T = a eta0 / eps0 * kappa:kappa` from the velocity gradient (steady uniform shear
    /// balance, model.md 2): `a` heating prefactor, `eta0` \[m\], `eps0` [1/m].
    FromShear {
        /// heating prefactor a (3/2 in the source model)
        heating: R,
        /// eta0 \[m\]
        eta0: R,
        /// eps0 [1/m]
        eps0: R,
    },
}

/// Everything about the segregation equation that is not a field.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SegregationConfig<R: Real, const D: usize> {
    /// Numerical segregation flux.
    pub scheme: Scheme,
    /// Tracked phase.
    pub phase: Phase,
    /// Segregation rate S0 [s^2/m]: `S = -S0 sqrt(T) P g`.
    pub s0: R,
    /// Gravity vector [m/s^2].
    pub gravity: [R; D],
    /// Segregation direction.
    pub direction: DirectionMode<R, D>,
    /// Source of T.
    pub temperature: TemperatureMode<R>,
    /// Remixing diffusivity D >= 0 [m^2/s] (Gray & Chugunov 2006), written in phihat.
    pub diffusion: R,
    /// Courant number in (0, 1).
    pub courant: R,
    /// Volume fraction below which a cell counts as empty: no segregation or diffusion flux.
    pub vacuum: R,
    /// Compensated cell updates: each `q += dq` is done as an exact two-sum and its rounding
    /// error is carried into the cell's next update. Without it, a flux much smaller than
    /// `ulp(q)` is rounded differently in the donor and in the receiver, and over many steps
    /// these roundings drift the mass systematically (f32 soft sensor, zero noise: -7.6e-4
    /// relative after 39,000 substeps). With it, `sum(q + carry)` changes only by the
    /// rounding of the increments themselves, and `sum(q)` stays within `n ulp/2` of it. Costs
    /// one array and 5 flops per cell and step; off by default (f64 runs do not need it).
    pub compensated: bool,
    /// Tracked fractions with `|q| <` this are set to zero after each cell update, and
    /// their amount is added to [`Segregation::flushed_small_mass`], so mass is still
    /// accounted for exactly as `sum + flushed`. Without it a phase that leaves a cell decays
    /// geometrically into subnormal numbers, and arithmetic on those is up to 100x slower
    /// (the 700 s shear cell: 2,880 of 6,400 cells subnormal at the end). Deterministic: a
    /// compare and a select, the same on every platform. 0 turns it off
    /// (docs/model.md 5.6). Default [`Real::FLUSH_BELOW`].
    pub flush_below: R,
}

impl<R: Real, const D: usize> SegregationConfig<R, D> {
    /// Defaults: modified flux, small phase, S0 = 1, gravity -1 along the last axis, direction
    /// parallel to gravity, T given, no diffusion, Courant 0.5, vacuum below 1e-6.
    pub const fn new() -> Self {
        let mut gravity = [R::ZERO; D];
        if D > 0 {
            gravity[D - 1] = R::NEG_ONE;
        }
        Self {
            scheme: Scheme::Modified,
            phase: Phase::Small,
            s0: R::ONE,
            gravity,
            direction: DirectionMode::Gravity,
            temperature: TemperatureMode::Given,
            diffusion: R::ZERO,
            courant: R::HALF,
            vacuum: R::VACUUM,
            compensated: false,
            flush_below: R::FLUSH_BELOW,
        }
    }
}

impl<R: Real, const D: usize> Default for SegregationConfig<R, D> {
    fn default() -> Self {
        Self::new()
    }
}

/// Why a configuration or a field cannot be used. Field errors name the first bad cell.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SetupError {
    /// The grid needs more cells than the compiled capacity.
    Capacity {
        /// cells needed
        cells: usize,
        /// compiled capacity
        capacity: usize,
    },
    /// Periodic on one side of an axis only.
    UnpairedPeriodic {
        /// axis
        axis: usize,
    },
    /// Courant number outside (0, 1).
    Courant,
    /// A configuration number is NaN, infinite, or negative where it must not be.
    Parameter(&'static str),
    /// A field value is NaN or infinite.
    NonFinite {
        /// field name
        field: &'static str,
        /// cell index
        cell: usize,
    },
    /// c < 0.
    NegativeVolumeFraction {
        /// cell index
        cell: usize,
    },
    /// T < 0.
    NegativeTemperature {
        /// cell index
        cell: usize,
    },
    /// phi outside [0, c].
    PhiOutOfRange {
        /// cell index
        cell: usize,
    },
    /// Inflow phi outside [0, c] of its boundary cell.
    InflowOutOfRange {
        /// cell index
        cell: usize,
    },
}

impl SetupError {
    /// The same error with its cell counted `offset` cells later: a slab's cell in the whole
    /// grid's numbering, as the serial run names it.
    pub fn offset_cell(self, offset: usize) -> Self {
        use SetupError::*;
        match self {
            NonFinite { field, cell } => NonFinite {
                field,
                cell: cell + offset,
            },
            NegativeVolumeFraction { cell } => NegativeVolumeFraction {
                cell: cell + offset,
            },
            NegativeTemperature { cell } => NegativeTemperature {
                cell: cell + offset,
            },
            PhiOutOfRange { cell } => PhiOutOfRange {
                cell: cell + offset,
            },
            InflowOutOfRange { cell } => InflowOutOfRange {
                cell: cell + offset,
            },
            other => other,
        }
    }
}

/// The segregation solver: phase fraction, static coefficients and scratch, for up to `N`
/// cells of a `D`-dimensional grid.
#[derive(Clone, Debug)]
pub struct Segregation<R: Real, const D: usize, const N: usize> {
    grid: Grid<R, D>,
    bc: Boundaries<D>,
    cfg: SegregationConfig<R, D>,
    /// Tracked phase fraction (phi or psi).
    q: [R; N],
    /// Total volume fraction c.
    c: [R; N],
    /// Granular temperature T.
    temp: [R; N],
    /// Velocity components.
    u: [[R; N]; D],
    /// `k_a = (S . e_a) / c` per axis, signed for the tracked phase; 0 in empty cells.
    k: [[R; N]; D],
    /// Dirichlet small-phase fraction phi for inflow faces of a boundary cell (converted to the
    /// tracked phase when used, so it may be set before or after the cell's c).
    ghost: [R; N],
    /// Rounding error of q carried to the next update ([`SegregationConfig::compensated`]).
    carry: [R; N],
    /// Scratch: increment of q in the current step.
    rhs: [R; N],
    /// Scratch: face fluxes along the current axis, indexed by the left cell.
    flux: [R; N],
    /// `max_i sum_a (|u_a| + |S_a|)/h_a + 2 D sum_a 1/h_a^2`, so that `dt = C / rate`.
    rate: R,
    /// The same without the transport term `|u_a| / h_a`: the rate of the percolation stage
    /// alone ([`Self::stable_dt_percolation`]).
    percolation_rate: R,
    /// Expected `kappa : kappa` of measurement noise alone (1/s^2), subtracted before T is
    /// derived from the shear ([`TemperatureMode::FromShear`]; see
    /// [`Self::set_shear_noise`]). 0 for a solved velocity.
    shear_noise: R,
    /// Running maxima over cells and steps of `q - c` and `-q` (tracked phase), since setup.
    excess: [R; 2],
    /// The cells `tally.0..tally.1` whose bounds the box step's maxima count: every cell, or
    /// a subdomain's owned ones ([`Self::prepare_owned`]; its halo cells must not count).
    tally: (usize, usize),
    /// Sum of the tracked fractions flushed to zero ([`SegregationConfig::flush_below`]),
    /// weighted by the open volume fraction of their cell (1 on a box grid).
    flushed: R,
    /// Per axis and side (low, high): the small phase that has entered the box through that
    /// side since setup, net (what left counts negative), in cell volumes; kept only for
    /// inflow and outflow sides, and only for the faces of counted cells (`tally`), so a
    /// driver merges its subdomains' books exactly ([`FixedSum`]; [`Self::side_books`]).
    side_books: [[FixedSum; 2]; D],
    prepared: bool,
    /// Per axis: c, T, k and u are the same in every cell (bit for bit) since the last
    /// prepare, so the step reads only q on that axis ([`Self::detect_uniform`]).
    uniform: [bool; D],
    /// Face value of the carried transport ([`Self::set_transport`]).
    transport: Transport,
    time: R,
    steps: u64,
}

impl<R: Real, const D: usize, const N: usize> Default for Segregation<R, D, N> {
    fn default() -> Self {
        Self::zeroed()
    }
}

impl<R: Real, const D: usize, const N: usize> Segregation<R, D, N> {
    /// Capacity in cells.
    pub const CAPACITY: usize = N;

    /// An empty solver on a one-cell grid; `const` so it can live in a `static`.
    pub const fn zeroed() -> Self {
        Self {
            grid: Grid::unit(),
            bc: [[Boundary::Wall; 2]; D],
            cfg: SegregationConfig::new(),
            q: [R::ZERO; N],
            c: [R::ZERO; N],
            temp: [R::ZERO; N],
            u: [[R::ZERO; N]; D],
            k: [[R::ZERO; N]; D],
            ghost: [R::ZERO; N],
            carry: [R::ZERO; N],
            rhs: [R::ZERO; N],
            flux: [R::ZERO; N],
            rate: R::ZERO,
            percolation_rate: R::ZERO,
            shear_noise: R::ZERO,
            excess: [R::ZERO; 2],
            tally: (0, usize::MAX),
            flushed: R::ZERO,
            side_books: [[FixedSum::ZERO; 2]; D],
            prepared: false,
            uniform: [false; D],
            transport: Transport::Donor,
            time: R::ZERO,
            steps: 0,
        }
    }

    /// Fixes grid, boundaries and configuration; clears all fields and the clock.
    pub fn setup(
        &mut self,
        grid: Grid<R, D>,
        bc: Boundaries<D>,
        cfg: SegregationConfig<R, D>,
    ) -> Result<(), SetupError> {
        if grid.len() > N {
            return Err(SetupError::Capacity {
                cells: grid.len(),
                capacity: N,
            });
        }
        check_periodic_pairs(&bc).map_err(|axis| SetupError::UnpairedPeriodic { axis })?;
        if !(cfg.courant > R::ZERO && cfg.courant < R::ONE) {
            return Err(SetupError::Courant);
        }
        let finite_nonneg = |x: R| x.is_finite() && x >= R::ZERO;
        if !finite_nonneg(cfg.s0) {
            return Err(SetupError::Parameter("s0"));
        }
        if !finite_nonneg(cfg.diffusion) {
            return Err(SetupError::Parameter("diffusion"));
        }
        if !finite_nonneg(cfg.vacuum) {
            return Err(SetupError::Parameter("vacuum"));
        }
        if cfg.gravity.iter().any(|g| !g.is_finite()) {
            return Err(SetupError::Parameter("gravity"));
        }
        if let DirectionMode::Fixed(d) = cfg.direction {
            if d.iter().any(|x| !x.is_finite()) || d.iter().all(|&x| x == R::ZERO) {
                return Err(SetupError::Parameter("direction"));
            }
        }
        if let TemperatureMode::FromShear {
            heating,
            eta0,
            eps0,
        } = cfg.temperature
        {
            if !(finite_nonneg(heating)
                && finite_nonneg(eta0)
                && eps0.is_finite()
                && eps0 > R::ZERO)
            {
                return Err(SetupError::Parameter("temperature"));
            }
        }
        self.grid = grid;
        self.bc = bc;
        self.cfg = cfg;
        self.shear_noise = R::ZERO;
        let n = grid.len();
        for a in [
            &mut self.q,
            &mut self.c,
            &mut self.temp,
            &mut self.ghost,
            &mut self.carry,
            &mut self.rhs,
            &mut self.flux,
        ] {
            a[..n].fill(R::ZERO);
        }
        for a in 0..D {
            self.u[a][..n].fill(R::ZERO);
            self.k[a][..n].fill(R::ZERO);
        }
        self.rate = R::ZERO;
        self.percolation_rate = R::ZERO;
        self.excess = [R::ZERO; 2];
        self.tally = (0, usize::MAX);
        self.flushed = R::ZERO;
        self.side_books = [[FixedSum::ZERO; 2]; D];
        self.prepared = false;
        self.uniform = [false; D];
        self.transport = Transport::Donor;
        self.time = R::ZERO;
        self.steps = 0;
        Ok(())
    }

    /// Sets gravity (m/s^2), e.g. the turning gravity of a rotating frame ([`crate::frame`]);
    /// takes effect on the next [`Self::prepare`] (direction and coefficients depend on it).
    pub fn set_gravity(&mut self, g: [R; D]) {
        self.cfg.gravity = g;
        self.prepared = false;
    }

    /// Sets the state of cell `i`: volume fraction `c`, temperature `t` (ignored if derived
    /// from shear), velocity `u`, and small-phase fraction `phi`.
    pub fn set_cell(&mut self, i: usize, c: R, t: R, u: [R; D], phi: R) {
        self.c[i] = c;
        self.temp[i] = t;
        for (a, ua) in u.iter().enumerate() {
            self.u[a][i] = *ua;
        }
        self.q[i] = self.tracked(phi, c);
        self.carry[i] = R::ZERO;
        self.prepared = false;
    }

    /// The expected `kappa : kappa` (1/s^2) that noise alone gives a measured velocity's
    /// gradient: the next [`Self::prepare_velocity`] derives T from `max(kappa:kappa - noise,
    /// 0)` (docs/model.md 2.3, docs/soft-sensor.md "Noise in the measured shear"), so a
    /// creeping bed seen through noisy frames is not heated by the noise. Negative or
    /// non-finite values count as 0.
    pub fn set_shear_noise(&mut self, noise: R) {
        self.shear_noise = if noise.is_finite() && noise > R::ZERO {
            noise
        } else {
            R::ZERO
        };
    }

    /// Sets only the velocity of cell `i` (a new measured frame); call [`Self::prepare`] after.
    pub fn set_velocity(&mut self, i: usize, u: [R; D]) {
        for (a, ua) in u.iter().enumerate() {
            self.u[a][i] = *ua;
        }
        self.prepared = false;
    }

    /// Sets the small-phase fraction of cell `i` (for restoring a snapshot).
    pub fn set_phi(&mut self, i: usize, phi: R) {
        self.q[i] = self.tracked(phi, self.c[i]);
        self.carry[i] = R::ZERO;
    }

    /// Sets the tracked phase fraction of cell `i` exactly (bit-exact snapshot restore); clears
    /// its carried rounding error (restore that after, with [`Self::set_carry`]).
    pub fn set_tracked(&mut self, i: usize, q: R) {
        self.q[i] = q;
        self.carry[i] = R::ZERO;
    }

    /// The rounding error of cell `i` carried by compensated updates (0 without them).
    pub fn carry(&self, i: usize) -> R {
        self.carry[i]
    }

    /// Sets the carried rounding error of cell `i` exactly (bit-exact snapshot restore).
    pub fn set_carry(&mut self, i: usize, e: R) {
        self.carry[i] = e;
    }

    /// Sets the inflow (Dirichlet) small-phase fraction seen by inflow faces of boundary cell `i`.
    pub fn set_inflow(&mut self, i: usize, phi: R) {
        self.ghost[i] = phi;
        self.prepared = false;
    }

    /// The inflow value of boundary cell `i` as a tracked-phase fraction.
    #[inline]
    pub(crate) fn inflow_tracked(&self, i: usize) -> R {
        self.tracked(self.ghost[i], self.c[i])
    }

    /// Restores the clock (for snapshots).
    pub fn set_clock(&mut self, time: R, steps: u64) {
        self.time = time;
        self.steps = steps;
    }

    /// Visits the per-cell arrays that carry information from one step to the next, over the
    /// active cells, by name, in a fixed order: the tracked fraction `q`, its carried rounding
    /// error `carry`, `c`, `T`, the inflow values `inflow` and the velocity `u0`, `u1`, `u2`.
    /// With [`Self::time`], [`Self::steps`], [`Self::tracked_excess`] and the gravity of the
    /// configuration this is the whole state a checkpoint must keep (the face coefficients
    /// and the rate are derived from it by `prepare`, the rest is scratch of one step).
    pub fn for_each_state_array(&self, mut f: impl FnMut(&'static str, &[R])) {
        let n = self.grid.len();
        f("q", &self.q[..n]);
        f("carry", &self.carry[..n]);
        f("c", &self.c[..n]);
        f("T", &self.temp[..n]);
        f("inflow", &self.ghost[..n]);
        for a in 0..D {
            f(axis_name(a), &self.u[a][..n]);
        }
    }

    /// The arrays of [`Self::for_each_state_array`] for writing (restoring a checkpoint bit
    /// for bit). Does not re-derive the coefficients: after changing `c`, `T` or `u` call
    /// `prepare` (a run whose `c`, `T` and `u` are fixed may restore `q` and `carry` alone).
    pub fn for_each_state_array_mut(&mut self, mut f: impl FnMut(&'static str, &mut [R])) {
        let n = self.grid.len();
        f("q", &mut self.q[..n]);
        f("carry", &mut self.carry[..n]);
        f("c", &mut self.c[..n]);
        f("T", &mut self.temp[..n]);
        f("inflow", &mut self.ghost[..n]);
        for a in 0..D {
            f(axis_name(a), &mut self.u[a][..n]);
        }
    }

    /// The running maxima of `q - c` and `-q` of the tracked phase since setup, as stored
    /// (see [`Self::bound_violations`] for them in terms of phi).
    pub fn tracked_excess(&self) -> [R; 2] {
        self.excess
    }

    /// Restores the running maxima of [`Self::tracked_excess`] (checkpoints).
    pub fn set_tracked_excess(&mut self, excess: [R; 2]) {
        self.excess = excess;
    }

    /// Whether the side (`0` low, `1` high) of `axis` opens to the world outside the box, so
    /// that what crosses it is booked ([`Self::side_books`]).
    #[inline(always)]
    pub(super) fn books_side(&self, axis: usize, side: usize) -> bool {
        matches!(self.bc[axis][side], Boundary::Inflow | Boundary::Outflow)
    }

    /// Books `into` (small phase into the box through boundary cell `i`'s face on that side,
    /// [`Self::small_across`]) if the cell counts (`tally`: a subdomain's halo cells do not).
    #[inline(always)]
    pub(super) fn book_side(&mut self, axis: usize, side: usize, i: usize, into: R) {
        if self.tally.0 <= i && i < self.tally.1 {
            self.side_books[axis][side].add(into);
        }
    }

    #[inline]
    fn tracked(&self, phi: R, c: R) -> R {
        match self.cfg.phase {
            Phase::Small => phi,
            Phase::Large => c - phi,
        }
    }

    /// Validates the fields and derives T (if from shear), the segregation direction, the face
    /// coefficients `k` and the stable rate. Needed after any change of u, c or T.
    pub fn prepare(&mut self) -> Result<(), SetupError> {
        self.prepare_on::<Baseline>()
    }

    /// [`Self::prepare`] with its passes over the cells run by `I` (compiled for its
    /// instruction set; the same bits for every `I`): a coupled step prepares after every
    /// step, at its fork's width ([`crate::flow::coupled::Coupled::step_with_on`]).
    pub fn prepare_on<I: Isa>(&mut self) -> Result<(), SetupError> {
        self.prepare_with(&SerialAt::<I>::new())
    }

    /// [`Self::prepare_on`] at `fork`'s instruction set, with the per-cell velocity
    /// gradients (pass 1 of the coefficients) cut among its workers: the coupled step's
    /// prepare on a pool. The same bits for any fork.
    pub fn prepare_with<F: Fork>(&mut self, fork: &F) -> Result<(), SetupError> {
        let n = self.grid.len();
        self.prepare_over(fork, 0..n)
    }

    /// [`Self::prepare_with`] for a subdomain (as [`Self::prepare_owned`]): the stable rates
    /// over the cells `owned` only, and from here on the bound maxima and the books count
    /// them only. A coupled step on slabs prepares so after every step
    /// ([`crate::flow::coupled::Coupled::step_with_reaching`]).
    pub fn prepare_owned_with<F: Fork>(
        &mut self,
        fork: &F,
        owned: core::ops::Range<usize>,
    ) -> Result<(), SetupError> {
        self.tally = (owned.start, owned.end);
        self.prepare_over(fork, owned)
    }

    /// The checks of every cell, then the coefficients with the rates over `owned`.
    fn prepare_over<F: Fork>(
        &mut self,
        fork: &F,
        owned: core::ops::Range<usize>,
    ) -> Result<(), SetupError> {
        // The checks of every cell as one branch-free pass (vectorises; a coupled run
        // prepares after every step); the loop below names the first failing cell.
        if !F::Isa::run(Call(
            #[inline(always)]
            || self.fields_valid(),
        )) {
            self.first_invalid_cell()?;
        }
        self.derive_coefficients_cut(fork, owned);
        self.detect_uniform();
        self.prepared = true;
        Ok(())
    }

    /// Whether every cell passes the checks of [`Self::first_invalid_cell`]: the same
    /// comparisons, combined without short circuits so that the loop vectorises.
    #[inline(always)]
    fn fields_valid(&self) -> bool {
        let n = self.grid.len().min(N);
        let (q, carry, c, t, ghost) = (
            &self.q[..n],
            &self.carry[..n],
            &self.c[..n],
            &self.temp[..n],
            &self.ghost[..n],
        );
        let large = matches!(self.cfg.phase, Phase::Large);
        let mut ok = true;
        for i in 0..n {
            // `Self::phi`
            let qc = q[i] + carry[i];
            let phi = if large { c[i] - qc } else { qc };
            let finite = c[i].is_finite() & t[i].is_finite() & phi.is_finite();
            let ranges = (c[i] >= R::ZERO) & (t[i] >= R::ZERO) & (phi >= R::ZERO) & (phi <= c[i]);
            let inflow = ghost[i].is_finite() & (ghost[i] >= R::ZERO) & (ghost[i] <= c[i]);
            ok &= finite & ranges & inflow;
        }
        for a in 0..D {
            ok &= self.u[a][..n].iter().fold(true, |ok, v| ok & v.is_finite());
        }
        ok
    }

    /// The checks of [`Self::prepare`], cell by cell: the first failing one's error.
    fn first_invalid_cell(&self) -> Result<(), SetupError> {
        let n = self.grid.len();
        for i in 0..n {
            let phi = self.phi(i);
            for (field, v) in [("c", self.c[i]), ("T", self.temp[i]), ("phi", phi)] {
                if !v.is_finite() {
                    return Err(SetupError::NonFinite { field, cell: i });
                }
            }
            for a in 0..D {
                if !self.u[a][i].is_finite() {
                    return Err(SetupError::NonFinite {
                        field: "u",
                        cell: i,
                    });
                }
            }
            if self.c[i] < R::ZERO {
                return Err(SetupError::NegativeVolumeFraction { cell: i });
            }
            if self.temp[i] < R::ZERO {
                return Err(SetupError::NegativeTemperature { cell: i });
            }
            if phi < R::ZERO || phi > self.c[i] {
                return Err(SetupError::PhiOutOfRange { cell: i });
            }
            let inflow = self.ghost[i];
            if !inflow.is_finite() {
                return Err(SetupError::NonFinite {
                    field: "inflow phi",
                    cell: i,
                });
            }
            if inflow < R::ZERO || inflow > self.c[i] {
                return Err(SetupError::InflowOutOfRange { cell: i });
            }
        }
        Ok(())
    }

    /// Re-derives the coefficients after only the velocity changed (a new measured frame):
    /// checks that u is finite, then as [`Self::prepare`] without re-validating c, T and phi.
    /// phi may have left [0, c] by round-off or by transport in a measured, not exactly
    /// divergence-free velocity; the step stays conservative either way.
    pub fn prepare_velocity(&mut self) -> Result<(), SetupError> {
        let n = self.grid.len();
        for a in 0..D {
            if let Some(i) = self.u[a][..n].iter().position(|v| !v.is_finite()) {
                return Err(SetupError::NonFinite {
                    field: "u",
                    cell: i,
                });
            }
        }
        self.derive_coefficients::<Baseline>(0..n);
        self.detect_uniform();
        self.prepared = true;
        Ok(())
    }

    /// Model only what the scene needs: on an axis where c, T, k and u hold the same bits in
    /// every cell (the segregation columns of model.md 7.1: no transport, uniform packing and
    /// temperature), the face loop takes them as constants and streams q alone. The face
    /// arithmetic is the general one with the same operands, so the bits do not change; only
    /// the loads do (one array instead of five per side). Runs once per prepare, and stops at
    /// the first cell that differs.
    fn detect_uniform(&mut self) {
        let n = self.grid.len();
        let same = |x: &[R]| {
            let b = x[0].to_bits_u64();
            x[1..n].iter().all(|v| v.to_bits_u64() == b)
        };
        let shared = n > 0 && same(&self.c[..n]) && same(&self.temp[..n]);
        for a in 0..D {
            self.uniform[a] = shared && same(&self.k[a][..n]) && same(&self.u[a][..n]);
        }
    }

    /// Derives T, the direction, `k` and the stable rate; the rate is the maximum over the
    /// cells `owned` only (all cells but for a subdomain, whose outermost halo layer sees a
    /// one-sided velocity gradient: [`Self::prepare_owned`]).
    fn derive_coefficients<I: Isa>(&mut self, owned: core::ops::Range<usize>) {
        // One hot loop: its passes (and the 2D normals') are `#[inline(always)]`.
        I::run(Call(
            #[inline(always)]
            || self.derive_coefficients_inline(owned.clone(), true),
        ))
    }

    /// [`Self::derive_coefficients`] with pass 1 (the velocity gradient of every cell, T from
    /// the shear, the direction from the flow: a 3x3 eigenproblem per cell in 3D, most of a
    /// 3D coupled prepare) cut among `fork`'s workers, cell by cell: each cell's values are
    /// the same arithmetic in any part, so the bits do not change.
    fn derive_coefficients_cut<F: Fork>(&mut self, fork: &F, owned: core::ops::Range<usize>) {
        let n = self.grid.len();
        let cfg = self.cfg;
        let flow_dir = matches!(cfg.direction, DirectionMode::Flow);
        let from_shear = matches!(cfg.temperature, TemperatureMode::FromShear { .. });
        // The 2D direction from the flow alone has its own pass (`flow_normals_2d`).
        let general = from_shear || (flow_dir && D != 2);
        // A cell of pass 1 costs far more than one of a vector update (a 3x3 eigenproblem
        // in 3D), so it is worth cutting on far fewer cells than the fork's loops: at most
        // SHEAR_MIN_PER_PART a part (fewer if the fork says so: tests).
        let min = fork.min_per_part().clamp(1, SHEAR_MIN_PER_PART);
        if !general || fork.parts() < 2 || n < min * fork.parts() {
            return self.derive_coefficients::<F::Isa>(owned);
        }
        {
            let shear = Shear {
                grid: &self.grid,
                bc: &self.bc,
                u: &self.u,
                c: &self.c,
                cfg: &cfg,
                gravity_dir: gravity_direction(&cfg),
                shear_noise: self.shear_noise,
            };
            let cuts = fork::cuts(n, fork.parts(), 1);
            // One item per cut, in order: its start and its chunk of every output array.
            let temp = fork::split(&mut self.temp[..n], &cuts).into_iter();
            let flux = fork::split(&mut self.flux[..n], &cuts).into_iter();
            let mut k = self
                .k
                .each_mut()
                .map(|k| fork::split(&mut k[..n], &cuts).into_iter());
            let mut items: heapless::Vec<ShearItem<'_, R>, { fork::MAX_PARTS }> =
                heapless::Vec::new();
            for (cut, (temp, flux)) in cuts.iter().zip(temp.zip(flux)) {
                let mut ks = heapless::Vec::new();
                for chunk in k.iter_mut().filter_map(Iterator::next) {
                    let _ = ks.push(chunk); // D <= 3
                }
                let _ = items.push(ShearItem {
                    start: cut.start,
                    temp,
                    k: ks,
                    flux,
                }); // as many as cuts
            }
            fork.each(&mut items, |it| {
                fork.hot(Call(
                    #[inline(always)]
                    || shear.pass(it.start, it.temp, &mut it.k, it.flux),
                ))
            });
        }
        F::Isa::run(Call(
            #[inline(always)]
            || self.derive_coefficients_inline(owned.clone(), false),
        ))
    }

    /// The passes of `derive_coefficients`; `pass1` false when the caller has run pass 1.
    #[inline(always)]
    fn derive_coefficients_inline(&mut self, owned: core::ops::Range<usize>, pass1: bool) {
        let n = self.grid.len();
        let cfg = self.cfg;
        let h = self.grid.spacing();
        let g = cfg.gravity;
        let gravity_dir = gravity_direction(&cfg);
        let sign = match cfg.phase {
            Phase::Small => R::ONE,
            Phase::Large => -R::ONE,
        };
        let mut diffusion_rate = R::ZERO;
        for &ha in h.iter() {
            diffusion_rate += R::TWO * cfg.diffusion / (ha * ha);
        }
        // The direction of the Fixed and Gravity modes: the same in every cell, normalised once.
        let const_dir = match cfg.direction {
            DirectionMode::Fixed(d) => {
                let dn = norm(&d);
                let mut out = d;
                out.iter_mut().for_each(|x| *x = *x / dn);
                out
            }
            _ => gravity_dir,
        };
        let shear_noise = self.shear_noise;
        let flow_dir = matches!(cfg.direction, DirectionMode::Flow);
        let from_shear = matches!(cfg.temperature, TemperatureMode::FromShear { .. });
        // Pass 1, cell by cell (branches, so it stays scalar): where the velocity gradient is
        // needed, T from the shear and the direction from the flow, `d` into `k` and `d . d`
        // into the scratch `flux`; then sqrt(T) of every cell into the scratch `rhs` (a
        // straight loop; `Real::sqrt` takes the encoding of the runner: docs/simd.md). Pass 2
        // reads them back in the same cell and overwrites them.
        if flow_dir && !from_shear && D == 2 {
            self.flow_normals_2d(gravity_dir);
        } else if (flow_dir || from_shear) && pass1 {
            let shear = Shear {
                grid: &self.grid,
                bc: &self.bc,
                u: &self.u,
                c: &self.c,
                cfg: &cfg,
                gravity_dir,
                shear_noise,
            };
            let mut k = self.k.each_mut().map(|k| &mut k[..n]);
            shear.pass(0, &mut self.temp[..n], &mut k, &mut self.flux[..n]);
        }
        for (r, t) in self.rhs[..n].iter_mut().zip(&self.temp[..n]) {
            *r = t.sqrt();
        }
        // Pass 2: S, k and the two rates of every cell, one straight loop without branches
        // (selects only) that the compiler vectorises: its divisions were most of the cost
        // of a coupled step's prepare (docs/implicit-pressure.md, "Where the time goes").
        // The same operations in the same order per cell as the one-pass loop before: the
        // same bits.
        // The cell rates go to the scratch `rhs` and `flux`; their maxima are taken in cell
        // order after (pass 3), so even a NaN rate picks what the one-pass loop picked.
        let fixed = Fixed {
            dir: const_dir,
            g,
            s0: cfg.s0,
            sign,
            vacuum: cfg.vacuum,
            diffusion_rate,
            h,
        };
        let cells = Cells {
            n,
            c: &self.c,
            u: &self.u,
        };
        let (k, rates, percolation) = (&mut self.k, &mut self.rhs, &mut self.flux);
        if flow_dir {
            cell_coefficients::<R, D, N, true>(fixed, cells, k, rates, percolation);
        } else {
            cell_coefficients::<R, D, N, false>(fixed, cells, k, rates, percolation);
        }
        let (mut rate, mut percolation_rate) = (R::ZERO, R::ZERO);
        for i in owned.start.min(n)..owned.end.min(n) {
            rate = rate.max(self.rhs[i]);
            percolation_rate = percolation_rate.max(self.flux[i]);
        }
        self.rate = rate;
        self.percolation_rate = percolation_rate;
    }

    /// Pass 1 of `derive_coefficients` for the 2D direction from the flow with T given (every
    /// coupled 2D scene): [`direction::segregation_normal`] of every cell in passes over the
    /// arrays, three of which vectorise; the divisions and branches of the gradient and of
    /// `direction_2d` cost as much as the rest of the prepare together
    /// (docs/implicit-pressure.md, "Where the time goes"). The same operations per cell: the
    /// same bits. Leaves the normal `m` in `k` and `m . m` in the scratch `flux` (pass 2
    /// reads them); `rhs` is scratch too.
    #[inline(always)]
    fn flow_normals_2d(&mut self, fallback: [R; D]) {
        let n = self.grid.len();
        let cells = self.grid.cells();
        let h = self.grid.spacing();
        let [u0, u1] = [&self.u[0][..n], &self.u[1][..n]];
        let (k0, k1) = self.k.split_at_mut(1);
        let (k0, k1) = (&mut k0[0][..n], &mut k1[0][..n]);
        let (rhs, flux) = (&mut self.rhs[..n], &mut self.flux[..n]);
        // A: the gradient g[c][j] = d_j u_c into k0 = g00, k1 = g10, rhs = g01, flux = g11:
        // central differences wherever a cell has both neighbours along j (row ends too,
        // mended below), zero along an axis of one cell ...
        let along = [(cells[0], 1), (cells[1], cells[0])];
        for (j, (out_0, out_1)) in [(&mut *k0, &mut *k1), (&mut *rhs, &mut *flux)]
            .into_iter()
            .enumerate()
        {
            let (len, stride) = along[j];
            if len < 2 {
                out_0.fill(R::ZERO);
                out_1.fill(R::ZERO);
            } else {
                let w = R::TWO * h[j];
                direction::central_difference(out_0, u0, stride, w);
                direction::central_difference(out_1, u1, stride, w);
            }
        }
        // ... then the cells at the ends of a line, one-sided or periodic, as
        // `velocity_gradient_at` has them (the whole gradient of each: corners twice).
        let (nx, nz) = (cells[0], cells[1]);
        if nx == 0 || nz == 0 {
            return;
        }
        let mut mend = |x: usize, z: usize| {
            let i = x + nx * z;
            let mut at = [0usize; D];
            at[0] = x;
            at[1] = z;
            let g = direction::velocity_gradient_at(&self.grid, &self.bc, &self.u, i, at);
            (k0[i], k1[i], rhs[i], flux[i]) = (g[0][0], g[1][0], g[0][1], g[1][1]);
        };
        for x in 0..nx {
            mend(x, 0);
            mend(x, nz - 1);
        }
        for z in 0..nz {
            mend(0, z);
            mend(nx - 1, z);
        }
        // B: the entries a, b, d of the symmetric gradient and r^2 (vectorised), r (libm's
        // sqrt, cell by cell), the normal and m . m (vectorised).
        direction::normal_2d_parts(k0, k1, rhs, flux);
        for r in flux.iter_mut() {
            *r = r.sqrt();
        }
        direction::normal_2d_finish([k0, k1], rhs, flux, [u0, u1], [fallback[0], fallback[1]]);
    }

    /// The largest time step the Courant condition allows (`R::MAX` if nothing moves).
    pub fn stable_dt(&self) -> R {
        if self.rate > R::ZERO {
            self.cfg.courant / self.rate
        } else {
            R::MAX
        }
    }

    /// The largest step of the percolation stage alone ([`Self::step_percolation`]): the
    /// Courant condition of [`Self::stable_dt`] without the transport term `|u_a| / h_a`.
    /// In a coupled run phi is transported by the flow's own limited face mass fluxes
    /// ([`Self::carry_mass_fluxes`]), whose bounds proof needs no Courant limit of its own:
    /// the flow's donor limiter alone keeps each cell's kept share in `[0, 1]` (see
    /// `carried.rs`). So the coupled step's segregation limit is this one, and dust thrown
    /// off a free surface at ~1 m/s (which the flow's limiters handle) does not hold it.
    pub fn stable_dt_percolation(&self) -> R {
        if self.percolation_rate > R::ZERO {
            self.cfg.courant / self.percolation_rate
        } else {
            R::MAX
        }
    }

    /// The largest transport rate `sum_a |u_a| / h_a` over the cells \[1/s\]: the Courant
    /// rate of the transport alone, for a caller that runs transport and percolation as
    /// separate stages, each on its own limit (the soft sensor's substeps:
    /// [`Self::step_percolation`], then [`Self::carry_own_velocity`]). A face moves at the
    /// mean of its two cells' speeds, so a cell can give up to twice this rate, where the
    /// flow leaves it both ways along an axis; the carry's donor limiter keeps the bounds
    /// there.
    pub fn transport_rate(&self) -> R {
        // a product per cell and axis, not a division (14 cycles on a Cortex-M4F)
        let inv_h = self.grid.spacing().map(|h| R::ONE / h);
        let mut rate = R::ZERO;
        for i in 0..self.grid.len() {
            let mut r = R::ZERO;
            for a in 0..D {
                r += self.u[a][i].abs() * inv_h[a];
            }
            rate = rate.max(r);
        }
        rate
    }

    /// The percolation stage of one coupled step of length `dt` as `k` equal sub-steps, the
    /// fewest (at most `max_substeps`) that each keep [`Self::stable_dt_percolation`]
    /// (`stable_dt` is its value). Percolation moves phi only, so `c`, `T`, `u` and with them
    /// the coefficients and the limit stay as [`Self::prepare`] left them through the
    /// sub-steps, and each sub-step keeps `0 <= phi <= c` and the mass like a single one. The
    /// clock advances by exactly `dt` and counts one step. Returns `k`. The hot loops run by
    /// `I` (the same bits for every `I`; the coupled step passes its fork's).
    pub fn step_percolation_substeps_on<I: Isa>(
        &mut self,
        dt: R,
        stable_dt: R,
        max_substeps: usize,
        geo: Option<&crate::geometry::CutCells<R, D, N>>,
    ) -> usize {
        self.step_percolation_substeps_then::<I>(dt, stable_dt, max_substeps, geo, |_, _| {})
    }

    /// [`Self::step_percolation_substeps_on`] calling `after(self, steps_before)` after each
    /// sub-step (`steps_before`: the step counter before it, on which the flush depends): a
    /// slab's driver flushes its owned cells and refreshes its halo rows there
    /// ([`crate::flow::coupled::Coupled::step_with_reaching`]).
    pub fn step_percolation_substeps_then<I: Isa>(
        &mut self,
        dt: R,
        stable_dt: R,
        max_substeps: usize,
        geo: Option<&crate::geometry::CutCells<R, D, N>>,
        mut after: impl FnMut(&mut Self, u64),
    ) -> usize {
        let (time, steps) = (self.time, self.steps);
        let mut k = 1;
        while k < max_substeps && R::from_usize(k) * stable_dt < dt {
            k += 1;
        }
        let sub = dt / R::from_usize(k);
        for j in 0..k {
            match geo {
                Some(g) => self.step_percolation_embedded_on::<I>(sub, g),
                None => self.step_percolation_on::<I>(sub),
            }
            after(self, steps + j as u64);
        }
        self.time = time + dt;
        self.steps = steps + 1;
        k
    }

    /// Advances to time `t_end` with the stable step (the last one shortened to land exactly),
    /// at most `max_steps` steps; returns the number of steps taken.
    ///
    /// A step that would fall short of `t_end` by no more than the round-off of the summed
    /// clock ([`snap_slack`]) is stretched to land on it: adding `dt` forty times leaves the
    /// clock 10-20 ulps below an output time, and a separate step of that length (a zero-length
    /// step in all but name) is pure overhead (610 steps instead of 600 on column a).
    pub fn advance_to(&mut self, t_end: R, max_steps: u64) -> u64 {
        self.advance_to_on::<Baseline>(t_end, max_steps)
    }

    /// Largest `(phi - c, -phi)` seen in any cell after any step since setup (0 if never
    /// positive): the bound violations of model.md 6, over cells *and* time.
    pub fn bound_violations(&self) -> (R, R) {
        let [above, below] = self.excess;
        match self.cfg.phase {
            Phase::Small => (above, below),
            // phi - c = -psi and -phi = psi - c
            Phase::Large => (below, above),
        }
    }

    /// Small-phase mass removed by [`SegregationConfig::flush_below`] since setup (negative
    /// when the tracked phase is the large one: flushing psi adds small grains). The
    /// small-phase mass in the cells plus this equals what it would be without flushing, to
    /// round-off; it is bounded by `floor * (cells * steps)` cell volumes.
    pub fn flushed_small_mass(&self) -> R {
        let m = self.flushed * self.grid.cell_volume();
        match self.cfg.phase {
            Phase::Small => m,
            Phase::Large => -m,
        }
    }

    /// The books of the box's inflow and outflow sides, per axis and side (low, high): the
    /// tracked phase that entered through the side since setup, net, in cell volumes (each
    /// face's flux of every step, booked exactly: [`FixedSum`]). Walls and periodic sides keep
    /// empty books. A subdomain books the faces of its own cells only, so the books of all
    /// subdomains merged ([`Self::merge_side_books`]) are the undivided grid's, bit for bit.
    pub fn side_books(&self) -> [[FixedSum; 2]; D] {
        self.side_books
    }

    /// Replaces the side books (restoring a checkpoint).
    pub fn set_side_books(&mut self, books: [[FixedSum; 2]; D]) {
        self.side_books = books;
    }

    /// Adds the books of a subdomain's steps (a driver, after a chunk of steps).
    pub fn merge_side_books(&mut self, books: &[[FixedSum; 2]; D]) {
        for (mine, theirs) in self.side_books.iter_mut().zip(books) {
            mine[0].merge(theirs[0]);
            mine[1].merge(theirs[1]);
        }
    }

    /// Small-phase mass that has left the box through each inflow or outflow side since setup,
    /// per axis and side (low, high), net (negative where more came in): with the cells and
    /// [`Self::flushed_small_mass`] it closes the small phase's books of a scene whose
    /// prescribed flow crosses its sides (docs/model.md 5.6). Each value is rounded once from
    /// its exact book.
    pub fn small_mass_out_through_sides(&self) -> [[R; 2]; D] {
        let v = self.grid.cell_volume();
        core::array::from_fn(|a| {
            core::array::from_fn(|side| -R::from_f64(self.side_books[a][side].to_f64()) * v)
        })
    }

    /// Sets the flushed amount (restoring a checkpoint), in the units of
    /// [`Self::flushed_tracked`].
    pub fn set_flushed_tracked(&mut self, f: R) {
        self.flushed = f;
    }

    /// The flushed tracked fraction, summed over cells and steps (weighted by open volume
    /// fraction): the raw counter behind [`Self::flushed_small_mass`].
    pub fn flushed_tracked(&self) -> R {
        self.flushed
    }

    /// Per axis, whether the last prepare found c, T, k and u uniform, so that the step streams
    /// q alone on that axis (the same bits as the general loop; see `detect_uniform`).
    pub fn uniform_axes(&self) -> [bool; D] {
        self.uniform
    }

    /// Number of steps taken so far.
    pub fn steps(&self) -> u64 {
        self.steps
    }
    /// Simulated time.
    pub fn time(&self) -> R {
        self.time
    }
    /// The grid.
    pub fn grid(&self) -> &Grid<R, D> {
        &self.grid
    }
    /// The boundaries.
    pub fn boundaries(&self) -> &Boundaries<D> {
        &self.bc
    }
    /// The velocity gradient `g[a][b] = du_a/dx_b` of cell `i`, differenced as the solver does
    /// for the direction and for T from shear ([`direction::velocity_gradient`]).
    pub fn velocity_gradient(&self, i: usize) -> [[R; D]; D] {
        direction::velocity_gradient(&self.grid, &self.bc, &self.u, i)
    }
    /// The configuration.
    pub fn config(&self) -> &SegregationConfig<R, D> {
        &self.cfg
    }
    /// Number of active cells.
    pub fn len(&self) -> usize {
        self.grid.len()
    }
    /// Never empty.
    pub fn is_empty(&self) -> bool {
        false
    }
    /// Small-phase fraction phi of cell `i`.
    #[inline]
    pub fn phi(&self, i: usize) -> R {
        // q + carry: the compensated value (carry is 0 without compensation, and `q + 0`
        // is q; only -0 becomes +0).
        let q = self.q[i] + self.carry[i];
        match self.cfg.phase {
            Phase::Small => q,
            Phase::Large => self.c[i] - q,
        }
    }
    /// Tracked phase fraction of cell `i` (phi or psi).
    #[inline]
    pub fn tracked_fraction(&self, i: usize) -> R {
        self.q[i]
    }
    /// Volume fraction c of cell `i`.
    #[inline]
    pub fn c(&self, i: usize) -> R {
        self.c[i]
    }
    /// The noise term subtracted from `kappa : kappa` ([`Self::set_shear_noise`]).
    #[inline]
    pub fn shear_noise(&self) -> R {
        self.shear_noise
    }
    /// Temperature of cell `i` (derived once prepared, if from shear).
    #[inline]
    pub fn temperature(&self, i: usize) -> R {
        self.temp[i]
    }
    /// Velocity of cell `i`.
    #[inline]
    pub fn velocity(&self, i: usize) -> [R; D] {
        let mut u = [R::ZERO; D];
        for (a, ua) in u.iter_mut().enumerate() {
            *ua = self.u[a][i];
        }
        u
    }
    /// True when every value a state scan reads is finite: [`Self::phi`], `c`, `T`, the
    /// velocity and [`Self::segregation_velocity`] of every cell, computed as those accessors
    /// compute them, so it is false exactly when a cell-by-cell search would find a culprit.
    /// One pass without branches (a run checks the state after every chunk of steps and
    /// searches cell by cell only when this is false).
    pub fn all_finite(&self) -> bool {
        let n = self.grid.len();
        let mut ok = true;
        for i in 0..n {
            let mut cell =
                self.phi(i).is_finite() & self.c[i].is_finite() & self.temp[i].is_finite();
            let s = self.segregation_velocity(i);
            for (a, sa) in s.iter().enumerate() {
                cell &= self.u[a][i].is_finite() & sa.is_finite();
            }
            ok &= cell;
        }
        ok
    }
    /// Segregation velocity `S` of cell `i` for the small phase (model.md 3); zero if empty.
    pub fn segregation_velocity(&self, i: usize) -> [R; D] {
        let sign = match self.cfg.phase {
            Phase::Small => R::ONE,
            Phase::Large => -R::ONE,
        };
        let mut s = [R::ZERO; D];
        for (a, sa) in s.iter_mut().enumerate() {
            *sa = self.k[a][i] * self.c[i] * sign;
        }
        s
    }

    /// [`Self::prepare`] for a subdomain (docs/parallel.md, [`crate::decomp`]): the stable
    /// rate is taken over the cells `owned` only. The outermost halo layer of a subdomain
    /// sees a one-sided velocity gradient (a wall where the global grid goes on), so its
    /// derived T, direction and rate differ from the global ones; its fluxes only ever reach
    /// halo cells, but its rate would reach the time step. The maximum over the owned cells of
    /// all subdomains is the global maximum exactly, so the global dt is the minimum of the
    /// subdomains' dt to the bit. From here on the box step's bound maxima
    /// ([`Self::tracked_excess`]) count the `owned` cells only.
    pub fn prepare_owned(&mut self, owned: core::ops::Range<usize>) -> Result<(), SetupError> {
        self.prepare_owned_with(&SerialAt::<Baseline>::new(), owned)
    }

    /// Whether the step after `steps_before` steps flushes (docs/model.md 5.6) with `floor`:
    /// every step when compensated, else every `step::FLUSH_EVERY` steps; never with a
    /// floor of 0.
    pub fn flush_due(&self, floor: R, steps_before: u64) -> bool {
        floor > R::ZERO && (self.cfg.compensated || steps_before % step::FLUSH_EVERY == 0)
    }

    /// The end of a step of a subdomain (docs/parallel.md, [`crate::decomp`]), on its owned
    /// cells (the range given to [`Self::prepare_owned`]) only: the running bound
    /// maxima `excess` (as [`Self::tracked_excess`]) and the flush of vanishing fractions
    /// (docs/model.md 5.6) with `floor` as [`SegregationConfig::flush_below`], exactly as
    /// [`Self::step`] does them after step number `steps_before` (counted before the step):
    /// the flush every `step::FLUSH_EVERY` steps on `q`, or after every step on `q + carry`
    /// when compensated. A subdomain steps with the flush off: its halo cells must not flush
    /// (the outermost halo row is updated against a wall that is not there). The maxima are
    /// the step's own, which count the owned cells only since [`Self::prepare_owned`] (the
    /// halo rows may overshoot where the global grid does not); `excess` takes them. Every
    /// flushed value is handed to `flushed` in cell order, so that the driver adds them to
    /// the global counter in the serial order.
    pub fn end_owned_step(
        &mut self,
        floor: R,
        steps_before: u64,
        excess: &mut [R; 2],
        mut flushed: impl FnMut(usize, R),
    ) {
        *excess = [excess[0].max(self.excess[0]), excess[1].max(self.excess[1])];
        let n = self.grid.len();
        let (lo, hi) = (self.tally.0.min(n), self.tally.1.min(n));
        if self.cfg.compensated {
            let (q, e) = (&mut self.q[lo..hi], &mut self.carry[lo..hi]);
            for i in 0..hi - lo {
                let v = q[i] + e[i];
                if v.abs() < floor {
                    flushed(lo + i, v);
                    q[i] = R::ZERO;
                    e[i] = R::ZERO;
                }
            }
        } else if floor > R::ZERO && steps_before % step::FLUSH_EVERY == 0 {
            for (i, qi) in self.q[lo..hi].iter_mut().enumerate() {
                if qi.abs() < floor {
                    flushed(lo + i, *qi);
                    *qi = R::ZERO;
                }
            }
        }
    }
}

/// Name of the velocity array of axis `a` in the state visitors (`u0`, `u1`, `u2`).
pub(crate) fn axis_name(a: usize) -> &'static str {
    match a {
        0 => "u0",
        1 => "u1",
        2 => "u2",
        _ => "u3+",
    }
}

fn dot<R: Real, const D: usize>(a: &[R; D], b: &[R; D]) -> R {
    let mut s = R::ZERO;
    for i in 0..D {
        s += a[i] * b[i];
    }
    s
}

fn norm<R: Real, const D: usize>(a: &[R; D]) -> R {
    dot(a, a).sqrt()
}

/// Cells per part below which pass 1 of the coefficients runs on the caller's thread
/// ([`Segregation::prepare_with`]): 512 cells of it take about 0.2 ms in 3D (0.35 us a
/// cell in the 3D silo), several times a sleeping worker's wake-up.
const SHEAR_MIN_PER_PART: usize = 512;

/// The unit vector along gravity, or the last axis without gravity.
fn gravity_direction<R: Real, const D: usize>(cfg: &SegregationConfig<R, D>) -> [R; D] {
    let g = cfg.gravity;
    let gnorm = norm(&g);
    if gnorm > R::ZERO {
        let mut d = g;
        d.iter_mut().for_each(|x| *x = *x / gnorm);
        d
    } else {
        let mut d = [R::ZERO; D];
        d[D - 1] = R::ONE;
        d
    }
}

/// What pass 1 of `derive_coefficients` reads: the grid, the velocity and the settings.
struct Shear<'a, R: Real, const D: usize, const N: usize> {
    grid: &'a Grid<R, D>,
    bc: &'a Boundaries<D>,
    u: &'a [[R; N]; D],
    /// The content: an empty cell (`c <= vacuum`) needs no direction (pass 2 gives it no
    /// segregation velocity, model.md 3.2), so none is solved for it.
    c: &'a [R; N],
    cfg: &'a SegregationConfig<R, D>,
    gravity_dir: [R; D],
    shear_noise: R,
}

/// One part of pass 1: the cells from `start` on, its chunks of `temp`, `k` (one per axis)
/// and `flux`.
struct ShearItem<'a, R> {
    start: usize,
    temp: &'a mut [R],
    k: heapless::Vec<&'a mut [R], 3>,
    flux: &'a mut [R],
}

impl<R: Real, const D: usize, const N: usize> Shear<'_, R, D, N> {
    /// Pass 1 on the cells `start..start + temp.len()` (branches, so it stays scalar): where
    /// the velocity gradient is needed, T from the shear into `temp` and the direction from
    /// the flow, `d` into `k` and `d . d` into `flux` (pass 2 reads them back in the same cell
    /// and overwrites them). An empty cell
    /// gets no direction: pass 2 gives it no segregation velocity whatever `k` and `flux`
    /// hold there (model.md 3.2), so no eigenproblem is solved for it, which in a draining
    /// silo is most of the cells by the end.
    #[inline(always)]
    fn pass(&self, start: usize, temp: &mut [R], k: &mut [&mut [R]], flux: &mut [R]) {
        let cfg = self.cfg;
        let flow_dir = matches!(cfg.direction, DirectionMode::Flow);
        let from_shear = matches!(cfg.temperature, TemperatureMode::FromShear { .. });
        let cells = self.grid.cells();
        // Integer coordinates advanced like an odometer: no division per cell (cheap on a M4).
        let mut coords = self.grid.coords(start);
        let mut block = Block3::new(self.gravity_dir);
        for j in 0..temp.len() {
            let i = start + j;
            let at = coords;
            for a in 0..D {
                coords[a] += 1;
                if coords[a] < cells[a] {
                    break;
                }
                coords[a] = 0;
            }
            let direction = flow_dir && self.c[i] > cfg.vacuum;
            if !(from_shear || direction) {
                continue;
            }
            let grad = direction::velocity_gradient_at(self.grid, self.bc, self.u, i, at);
            if let TemperatureMode::FromShear {
                heating,
                eta0,
                eps0,
            } = cfg.temperature
            {
                let kk = direction::shear_rate_squared(&grad);
                // A noisy measured velocity adds its noise's kappa:kappa on average; with
                // none (every solved flow) the branch keeps the bits of `kk` itself.
                let kk = if self.shear_noise > R::ZERO {
                    (kk - self.shear_noise).max(R::ZERO)
                } else {
                    kk
                };
                temp[j] = heating * eta0 / eps0 * kk;
            }
            if !direction {
                continue;
            }
            if D == 3 {
                // Gathered into a block whose eigen-solves run side by side (below).
                let l = block.len;
                for (e, x) in block.k.iter_mut().zip(direction::strain_entries(&grad)) {
                    e[l] = x;
                }
                for (ua, u) in block.u.iter_mut().zip(self.u.iter()) {
                    ua[l] = u[i].to_f64();
                }
                block.at[l] = j;
                block.len += 1;
                if block.len == LANES_3D {
                    block.finish(k, flux);
                }
            } else {
                let ui: [R; D] = core::array::from_fn(|a| self.u[a][i]);
                // d is the segregation direction up to length and sign, dd = d . d:
                // exactly 1 except for the unnormalised normals from the flow (see
                // `direction::segregation_normal`), so the division changes no bit
                // elsewhere.
                let (d, dd) = direction::segregation_normal(&grad, &ui, self.gravity_dir);
                for (a, ka) in k.iter_mut().enumerate().take(D) {
                    ka[j] = d[a];
                }
                flux[j] = dd;
            }
        }
        if block.len > 0 {
            block.finish(k, flux);
        }
    }
}

/// Up to `LANES_3D` cells of a 3D pass 1 waiting for their directions: the strain rate and
/// the velocity of each, and where in the pass each goes (the empty cells between them need
/// none).
struct Block3 {
    len: usize,
    at: [usize; LANES_3D],
    k: [[f64; LANES_3D]; 6],
    u: [[f64; LANES_3D]; 3],
    fallback: [f64; 3],
}

impl Block3 {
    fn new<R: Real, const D: usize>(gravity_dir: [R; D]) -> Self {
        Self {
            len: 0,
            at: [0; LANES_3D],
            k: [[0.0; LANES_3D]; 6],
            u: [[0.0; LANES_3D]; 3],
            fallback: core::array::from_fn(|a| gravity_dir.get(a).map_or(0.0, |x| x.to_f64())),
        }
    }

    /// The directions of the block's `len` cells into `k` and `d . d` into `flux`, the same
    /// bits as [`direction::segregation_normal`] of each cell; empties the block. The lanes
    /// past `len` hold the previous block's cells (or zeros) and are solved and dropped.
    #[inline(always)]
    fn finish<R: Real>(&mut self, k: &mut [&mut [R]], flux: &mut [R]) {
        let mut m = [[0.0; LANES_3D]; 3];
        let mut mm = [0.0; LANES_3D];
        direction::normals_3d(&self.k, &self.u, self.fallback, &mut m, &mut mm);
        for l in 0..self.len.min(LANES_3D) {
            let j = self.at[l];
            for (ka, ma) in k.iter_mut().zip(&m) {
                ka[j] = R::from_f64(ma[l]);
            }
            flux[j] = R::from_f64(mm[l]);
        }
        self.len = 0;
    }
}

/// The per-cell constants of [`cell_coefficients`] (pass 2 of `derive_coefficients`).
#[derive(Clone, Copy)]
struct Fixed<R, const D: usize> {
    /// The segregation direction of the Fixed and Gravity modes (unused with FLOW).
    dir: [R; D],
    g: [R; D],
    s0: R,
    sign: R,
    vacuum: R,
    diffusion_rate: R,
    h: [R; D],
}

/// The fields pass 2 of `derive_coefficients` reads, on the cells `0..n`.
#[derive(Clone, Copy)]
struct Cells<'a, R, const D: usize, const N: usize> {
    n: usize,
    c: &'a [R; N],
    u: &'a [[R; N]; D],
}

/// Pass 2 of `derive_coefficients` on the cells `0..n`: sqrt(T) is read from `rates`, and
/// with `FLOW` the direction `d` from `k` and `d . d` from `percolation` (pass 1 put them
/// there), else they are `f.dir` and 1. Writes `k_a = S_a / c` (0 in empty cells) and each
/// cell's rate and percolation rate; with `FLOW` an empty cell has `S = 0`.
/// `S = -S0 sqrt(T) (g . d) d / (d . d)` (model.md 3), signed for the tracked phase.
/// Every array is cut to `n` first, so the loop has no bounds checks.
/// Inlined into `derive_coefficients`' hot loop (its arrays arrive as separate arguments, so
/// the vectoriser still knows they do not overlap).
#[inline(always)]
fn cell_coefficients<R: Real, const D: usize, const N: usize, const FLOW: bool>(
    f: Fixed<R, D>,
    cells: Cells<'_, R, D, N>,
    k: &mut [[R; N]; D],
    rates: &mut [R; N],
    percolation: &mut [R; N],
) {
    let n = cells.n.min(N);
    let c = &cells.c[..n];
    let u = cells.u.each_ref().map(|x| &x[..n]);
    let k = k.each_mut().map(|x| &mut x[..n]);
    let (rates, percolation) = (&mut rates[..n], &mut percolation[..n]);
    for i in 0..n {
        let (d, dd) = if FLOW {
            (core::array::from_fn(|a| k[a][i]), percolation[i])
        } else {
            (f.dir, R::ONE)
        };
        let g_dot_d = dot(&f.g, &d);
        let s_mag = -(f.s0 * rates[i] * g_dot_d / dd) * f.sign;
        let ci = c[i];
        // With the direction from the flow an empty cell has none (pass 1 leaves whatever
        // `k` and `percolation` held there, even a NaN): no segregation velocity, so its
        // rates count only the flow (model.md 3.2). A select, not a branch: still vectorised.
        let full = ci > f.vacuum;
        let grains = !FLOW || full;
        let (mut cell_rate, mut cell_percolation) = (f.diffusion_rate, f.diffusion_rate);
        for a in 0..D {
            let s_a = if grains { s_mag * d[a] } else { R::ZERO };
            k[a][i] = if full { s_a / ci } else { R::ZERO };
            cell_rate += (u[a][i].abs() + s_a.abs()) / f.h[a];
            cell_percolation += s_a.abs() / f.h[a];
        }
        rates[i] = cell_rate;
        percolation[i] = cell_percolation;
    }
}

/// How far below a target time a step may end and still be stretched to land on it
/// ([`Segregation::advance_to`]): 64 ulps of the target, more than the round-off of the
/// clock summed over an output interval (10-20 ulps seen over 40-step intervals), far less
/// than any step worth taking. A stretched step exceeds the stable step by at most this much
/// (8.5e-12 of dt on column a in f64), far inside the margin of a Courant number below 1.
pub fn snap_slack<R: Real>(t_end: R) -> R {
    R::from_f64(64.0) * R::EPSILON * t_end.abs()
}

/// Whether the step from `remaining` before the target lands on it: the whole remainder
/// when it is at most `dt`, or within `slack` ([`snap_slack`]) above it. The one rule of
/// every stepper that stops on an output time (serial, embedded, a subdomain's).
#[inline]
pub fn lands_on_target<R: Real>(remaining: R, dt: R, slack: R) -> bool {
    remaining <= dt || remaining - dt <= slack
}
