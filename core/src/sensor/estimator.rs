//! The soft-sensor estimator: input handling, the budgeted tick, and the estimate.

use super::config::{ConfigError, CycleBudget, SensorConfig};
use super::config::{MAX_OPENINGS, MAX_OUTFLOW_WINDOW};
use super::entropy;
use super::frame::{bump, Estimate, Reject, VelocityFrame};
use super::noise::{self, NoiseModel};
use super::{alarm, health, SensorReal, MAX_FRAME_VALUES};
use crate::boundary::{Boundaries, Boundary, Opening, Openings};
use crate::diagnostics::{self, state_hash};
use crate::grid::Grid;
use crate::hash::Fnv64;
use crate::segregation::{
    DirectionMode, Phase, Scheme, Segregation, SegregationConfig, TemperatureMode,
};
use serde::{Deserialize, Serialize};

/// Counters of the estimator (frame-level rejection causes and tick outcomes). Byte-level
/// causes are in [`super::WireCounters`] of the decoder.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Counters {
    /// Frames accepted.
    pub accepted: u32,
    /// [`Reject::Dims`]
    pub dims: u32,
    /// [`Reject::NonFinite`]
    pub non_finite: u32,
    /// [`Reject::Range`]
    pub range: u32,
    /// [`Reject::Seq`]
    pub seq: u32,
    /// Sensor values replaced by their neighbourhood median.
    pub outliers: u32,
    /// Ticks that held the last good velocity.
    pub stale_ticks: u32,
    /// Ticks that froze (hold limit exceeded, or no input yet).
    pub frozen_ticks: u32,
    /// Ticks limited by the substep budget.
    pub budget_limited: u32,
    /// Frame periods that were never simulated (lost while frozen, or a sequence gap).
    pub lost_periods: u32,
    /// Cell-ticks in which phi was outside [0, c] at the end of the tick: by round-off, or by
    /// the compression of a measured velocity that is not divergence-free (c is held fixed,
    /// so such a flow piles phi slightly above c). The state is left as it is (exactly
    /// conservative); only the readouts clamp phihat into [0, 1]. See
    /// [`health::PHI_EXCURSION`].
    pub phi_excursions: u32,
}

/// Serial-number order of sequence numbers (RFC 1982 with 32 bits): `a` comes after `b` if it
/// is ahead by 1 to 2^31 - 1, counting modulo 2^32. A sensor that counts past `u32::MAX`
/// wraps to 0; with plain `>` every later frame would look old and the estimator would freeze
/// for good. A jump of 2^31 or more counts as old (a duplicate or garbage), so a frame cannot
/// claim billions of lost periods. For numbers less than 2^31 apart this is the plain `>`,
/// which is why the golden hashes of recordings are unchanged.
#[inline]
pub fn seq_after(a: u32, b: u32) -> bool {
    (a.wrapping_sub(b) as i32) > 0
}

/// Cells per row segment whose x interpolation weights `map_velocity` keeps on the stack.
const MAP_CHUNK: usize = 64;

/// Instructions (or any clock) spent in the phases of one [`SoftSensor::finish_tick_profiled`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TickProfile {
    /// Bilinear mapping of the sensor field onto the estimator grid.
    pub map: u64,
    /// `Segregation::prepare_velocity`: T, direction, coefficients, stable step.
    pub prepare: u64,
    /// The substeps (`Segregation::step`).
    pub substeps: u64,
    /// The readout (psi, min/max, regions, alarms, excursion count).
    pub estimate: u64,
}

/// The carried c may rise this factor above the bed's configured `c` before the packing cap
/// moves the excess away (docs/soft-sensor.md "A packing cap on the carried c", measured:
/// 1.00 mixes phi through the pool on every substep of a bed at its packing, 1.02 / 1.05 bound
/// the drift as well and leave closed boxes as they were).
pub const PACKING_HEADROOM: f64 = 1.05;

/// Courant number of a substep's carried transport on the cells' speeds
/// ([`Segregation::transport_rate`]): below 1, so upwinding moves a cell's content without
/// the donor limiter except where the measured flow diverges from it, with a margin. The
/// percolation stage keeps the configuration's own `courant` on its own rate. Until
/// 2026-12-07 one limit took `courant` (0.5) on the sum of both rates, which doubled the
/// substeps of a flow-dominated discharge for no accuracy (docs/soft-sensor.md "Substep
/// length").
pub const TRANSPORT_COURANT: f64 = 0.9;

/// The soft sensor: a [`Segregation`] solver on the estimator grid plus the input filter
/// state. `N` is the estimator capacity in cells (1024 for 32 x 32).
///
/// # Tick rules
/// * [`Self::submit`] validates a frame and, if it is good, feeds it to the input filter and
///   books the frame's `period` for this tick. Checks, in order: dimensions ([`Reject::Dims`]), finiteness of the
///   period and every value ([`Reject::NonFinite`]), `0 < period <= max_period_factor *
///   tick_period` and `|u| <= reject_speed` ([`Reject::Range`]), `seq` after the last
///   accepted one in serial-number order ([`seq_after`], so the count may wrap past
///   `u32::MAX`; [`Reject::Seq`]). A rejected frame changes nothing but the counters and
///   the tick's health flags.
/// * Input handling of a good frame: each value is compared with the median of its 3x3
///   sensor neighbourhood (fewer at the edges) and replaced by it if they differ by more
///   than `outlier_tol` (spikes); the result enters an exponential moving average with
///   weight `smoothing` (temporal noise); the averaged sensor field is interpolated
///   bilinearly onto the estimator cell centres (wrapped on periodic axes, linearly
///   extrapolated towards walls so a uniform shear stays uniform).
/// * Time: frame `k` covers period `k`. If periods between the last covered one and `k`
///   were neither received nor held, they are lost: they go to `lag` and
///   `Counters::lost_periods`. A late frame whose period a held tick already covered only
///   updates the velocity.
/// * Budget: the advance of `dt` takes `ceil(dt / stable_dt)` equal substeps
///   ([`Self::stable_dt`]: the percolation stage's and the transport's limits, each on
///   its own rate); if that
///   exceeds what is left of the cap this tick (`floor((budget.cycles - fixed) /
///   substep)` of the cost model, [`super::CycleBudget`]), it takes the remaining budget of
///   full stable substeps (Courant-limited, so bounded and conservative), adds the shortfall
///   to `lag` and sets [`health::BUDGET_LIMITED`].
/// * [`Self::finish_tick`] ends a tick: if frames were accepted, it maps the filtered
///   velocity onto the estimator grid once (`Segregation::prepare_velocity`: no validation
///   of phi, no clamping, so the state stays exactly conservative) and advances by the booked
///   time, so the work of a tick is one mapping plus at most the cap's substeps however
///   many frames arrived. If no frame was accepted during the tick, the last good velocity is held for one `tick_period` ([`health::STALE_INPUT`]) up to `hold_ticks`
///   consecutive ticks, after which the estimate freezes ([`health::FROZEN`]) until a good
///   frame arrives. It returns the [`Estimate`].
#[derive(Clone, Debug)]
pub struct SoftSensor<R: SensorReal, const N: usize> {
    pub(super) seg: Segregation<R, 2, N>,
    pub(super) cfg: SensorConfig<R>,
    /// Smoothed sensor velocities, interleaved (u_x, u_z), x fastest.
    pub(super) vel: [R; MAX_FRAME_VALUES],
    /// Scratch: the cleaned frame being smoothed (not state).
    work: [R; MAX_FRAME_VALUES],
    /// The filter's and the map's noise gain of this configuration (not state: derived
    /// from it).
    noise: NoiseModel<R>,
    /// EMA of the accepted frames' noise variance (`noise.rs`), with the EMA's weights.
    pub(super) noise_variance: R,
    /// The share of one frame's noise variance the EMA of the velocity keeps
    /// (`sum_k w_k^2` of its weights): 1 after the first frame, `a / (2 - a)` in the end.
    pub(super) noise_share: R,
    pub(super) have_velocity: bool,
    pub(super) last_seq: u32,
    /// Last frame period simulated (or held, or given up as lost).
    pub(super) covered: u32,
    /// Consecutive ticks without a good frame.
    pub(super) stale: u32,
    pub(super) lag: R,
    pub(super) tick: u32,
    pub(super) counters: Counters,
    /// Health bits of the current tick.
    flags: u8,
    /// Substeps taken in the current tick.
    substeps: u16,
    /// The longest stable substep for the prepared velocity ([`Self::stable_dt`]; not
    /// state: derived by `prepare_measured`, also on restore).
    substep_dt: R,
    /// Most substeps of the current tick: what the configuration's cycle budget affords
    /// after the fixed part with `frames` frames decoded.
    cap: u16,
    /// Frames decoded this tick (accepted or rejected, byte-level rejects included): each
    /// costs its decoding and filtering in the cost model.
    frames: u32,
    accepted_this_tick: bool,
    /// Time of the frames accepted this tick, advanced by `finish_tick` (0 between ticks).
    pending: R,
    /// Openings of the wall sides `[axis][low, high]` (outlets), from the configuration.
    pub(super) open: [[Openings<R, 2>; 2]; 2],
    /// What left the box this tick: grain volume and small-grain volume (per unit depth).
    pub(super) tick_out: [R; 2],
    /// The same per tick over the last `outflow_window` ticks (ring buffer).
    pub(super) out_ring: [[R; 2]; MAX_OUTFLOW_WINDOW],
    /// Next slot of `out_ring`.
    pub(super) out_head: u16,
    /// What left the box since configuration (grains, small grains).
    pub(super) out_total: [R; 2],
    /// Latched fines alarms ([`alarm::FINES_LOW`] / [`alarm::FINES_HIGH`]).
    pub(super) fines_state: u8,
    /// Consecutive ticks below / above the band / back inside the hysteresis band.
    pub(super) fines_runs: [u16; 3],
    /// (estimator time, outlet fines fraction) of the last ticks that had one (ring), for the
    /// trend of the off-spec prediction.
    pub(super) trend: [[R; 2]; MAX_OUTFLOW_WINDOW],
    /// Samples in `trend` (at most `outflow_window`) and the next slot.
    pub(super) trend_len: u16,
    pub(super) trend_head: u16,
    /// The last off-spec prediction [s] (see [`Estimate::off_spec_in`]); `None`: no exit
    /// predicted.
    pub(super) off_spec_in: Option<R>,
}

impl<R: SensorReal, const N: usize> Default for SoftSensor<R, N> {
    fn default() -> Self {
        Self::new()
    }
}

const fn empty_config<R: SensorReal>() -> SensorConfig<R> {
    let bc: Boundaries<2> = [[Boundary::Wall; 2]; 2];
    SensorConfig {
        cells: [1, 1],
        extent: [R::ONE, R::ONE],
        bc,
        sensor: [1, 1],
        s0: R::ZERO,
        eta0: R::ZERO,
        eps0: R::ONE,
        heating: R::ZERO,
        gravity: [R::ZERO, R::NEG_ONE],
        c: R::ZERO,
        fill_level: R::ONE,
        initial_phihat: R::ZERO,
        inflow_phihat: R::ZERO,
        diffusion: R::ZERO,
        courant: R::HALF,
        tick_period: R::ONE,
        max_period_factor: R::TWO,
        budget: CycleBudget::for_substeps(1, 1),
        hold_ticks: 0,
        reject_speed: R::ONE,
        outlier_tol: R::ONE,
        smoothing: R::ONE,
        spatial_passes: 0,
        track_large: false,
        regions: heapless::Vec::new(),
        outlet: None,
        psi_alarm: R::ZERO,
        fines_band: [R::ZERO, R::ONE],
        fines_hysteresis: R::ZERO,
        alarm_persist: 1,
        openings: heapless::Vec::new(),
        outflow_window: 1,
        noise_term: R::ZERO,
    }
}

impl<R: SensorReal, const N: usize> SoftSensor<R, N> {
    /// An unconfigured sensor; `const` so that it can be placed in a `static` (firmware).
    pub const fn new() -> Self {
        Self {
            seg: Segregation::zeroed(),
            cfg: empty_config(),
            vel: [R::ZERO; MAX_FRAME_VALUES],
            work: [R::ZERO; MAX_FRAME_VALUES],
            noise: NoiseModel::zeroed(),
            noise_variance: R::ZERO,
            noise_share: R::ZERO,
            have_velocity: false,
            last_seq: 0,
            covered: 0,
            stale: 0,
            lag: R::ZERO,
            tick: 0,
            counters: Counters {
                accepted: 0,
                dims: 0,
                non_finite: 0,
                range: 0,
                seq: 0,
                outliers: 0,
                stale_ticks: 0,
                frozen_ticks: 0,
                budget_limited: 0,
                lost_periods: 0,
                phi_excursions: 0,
            },
            flags: 0,
            substeps: 0,
            substep_dt: R::MAX,
            cap: 1,
            frames: 0,
            accepted_this_tick: false,
            pending: R::ZERO,
            open: [[Openings::none(); 2]; 2],
            tick_out: [R::ZERO; 2],
            out_ring: [[R::ZERO; 2]; MAX_OUTFLOW_WINDOW],
            out_head: 0,
            out_total: [R::ZERO; 2],
            fines_state: 0,
            fines_runs: [0; 3],
            trend: [[R::ZERO; 2]; MAX_OUTFLOW_WINDOW],
            trend_len: 0,
            trend_head: 0,
            off_spec_in: None,
        }
    }

    /// Validates and applies a configuration and resets the state: phihat =
    /// `initial_phihat` in every cell, constant c, no velocity yet, clock at zero.
    pub fn configure(&mut self, cfg: &SensorConfig<R>) -> Result<(), ConfigError> {
        cfg.validate(N)?;
        let cells = [cfg.cells[0] as usize, cfg.cells[1] as usize];
        let grid = Grid::new(cells, [R::ZERO; 2], cfg.extent, N).map_err(|_| ConfigError::Cells)?;
        let scfg = SegregationConfig {
            scheme: Scheme::Modified,
            // Either phase: snapshots store the tracked fraction itself (`set_tracked`), so
            // both restore bit-exactly.
            phase: if cfg.track_large {
                Phase::Large
            } else {
                Phase::Small
            },
            s0: cfg.s0,
            gravity: cfg.gravity,
            direction: DirectionMode::Flow,
            temperature: TemperatureMode::FromShear {
                heating: cfg.heating,
                eta0: cfg.eta0,
                eps0: cfg.eps0,
            },
            diffusion: cfg.diffusion,
            courant: cfg.courant,
            vacuum: R::VACUUM,
            // The FPU of the Cortex-M4F computes subnormals in hardware at full speed, and an
            // f32 floor cannot sit far enough above them to matter (docs/model.md 5.6).
            flush_below: R::ZERO,
            // A sensor runs for days in f32: carry the rounding of every cell update so the
            // mass does not drift (see `SegregationConfig::compensated`).
            compensated: true,
        };
        self.seg
            .setup(grid, cfg.bc, scfg)
            .map_err(|_| ConfigError::Parameter("segregation"))?;
        let dz = cfg.extent[1] / R::from_u32(cfg.cells[1] as u32);
        for i in 0..grid.len() {
            // The bed below the fill level; the cell it crosses in proportion.
            let z0 = R::from_u32((i / cells[0]) as u32) * dz;
            let share = if cfg.fill_level >= cfg.extent[1] {
                R::ONE
            } else {
                ((cfg.fill_level - z0) / dz).max(R::ZERO).min(R::ONE)
            };
            let c = cfg.c * share;
            self.seg
                .set_cell(i, c, R::ZERO, [R::ZERO; 2], cfg.initial_phihat * c);
            self.seg.set_inflow(i, cfg.inflow_phihat * c);
        }
        self.cfg = cfg.clone();
        self.noise = NoiseModel::configure(
            [cfg.sensor[0] as usize, cfg.sensor[1] as usize],
            cells,
            [
                cfg.bc[0][0] == Boundary::Periodic,
                cfg.bc[1][0] == Boundary::Periodic,
            ],
            cfg.spatial_passes,
            grid.spacing(),
        );
        self.vel = [R::ZERO; MAX_FRAME_VALUES];
        self.noise_variance = R::ZERO;
        self.noise_share = R::ZERO;
        self.have_velocity = false;
        self.last_seq = 0;
        self.covered = 0;
        self.stale = 0;
        self.lag = R::ZERO;
        self.tick = 0;
        self.counters = Counters::default();
        self.flags = 0;
        self.substeps = 0;
        self.substep_dt = R::MAX;
        self.cap = cfg.substep_cap();
        self.frames = 0;
        self.accepted_this_tick = false;
        self.pending = R::ZERO;
        self.open = [[Openings::none(); 2]; 2];
        for o in &cfg.openings {
            let (a, t) = (o.axis as usize, 1 - o.axis as usize);
            let mut lower = [R::ZERO; 2];
            let mut upper = [R::ZERO; 2];
            lower[t] = o.lower;
            upper[t] = o.upper;
            // At most MAX_OPENINGS (2) in all, so one side never overflows.
            debug_assert!(cfg.openings.len() <= MAX_OPENINGS);
            self.open[a][o.high as usize]
                .push(Opening { lower, upper })
                .map_err(|_| ConfigError::Parameter("openings"))?;
        }
        self.tick_out = [R::ZERO; 2];
        self.out_ring = [[R::ZERO; 2]; MAX_OUTFLOW_WINDOW];
        self.out_head = 0;
        self.out_total = [R::ZERO; 2];
        self.fines_state = 0;
        self.fines_runs = [0; 3];
        self.trend = [[R::ZERO; 2]; MAX_OUTFLOW_WINDOW];
        self.trend_len = 0;
        self.trend_head = 0;
        self.off_spec_in = None;
        self.seg
            .prepare()
            .map_err(|_| ConfigError::Parameter("initial state"))
    }

    /// Replaces the constant c by a field (one value per estimator cell, x fastest), keeping
    /// the initial phihat. Call right after [`Self::configure`].
    pub fn set_c_field(&mut self, c: &[R]) -> Result<(), ConfigError> {
        let n = self.seg.len();
        if c.len() != n
            || c.iter()
                .any(|&x| !(x.is_finite() && x >= R::ZERO && x <= R::ONE))
        {
            return Err(ConfigError::Parameter("c field"));
        }
        for (i, &ci) in c.iter().enumerate() {
            let u = self.seg.velocity(i);
            self.seg
                .set_cell(i, ci, R::ZERO, u, self.cfg.initial_phihat * ci);
            self.seg.set_inflow(i, self.cfg.inflow_phihat * ci);
        }
        self.seg
            .prepare()
            .map_err(|_| ConfigError::Parameter("c field"))
    }

    /// Sets the relative small fraction of cell `i` (clamped to [0, 1]), e.g. an inversely
    /// graded initial state. Call before the first frame.
    pub fn set_phihat(&mut self, i: usize, phihat: R) {
        let ph = phihat.max(R::ZERO).min(R::ONE);
        self.seg.set_phi(i, ph * self.seg.c(i));
    }

    fn validate(&self, f: &VelocityFrame) -> Result<(), Reject> {
        let cfg = &self.cfg;
        if f.nx != cfg.sensor[0] || f.nz != cfg.sensor[1] || f.u.len() != 2 * cfg.sensor_points() {
            return Err(Reject::Dims);
        }
        if !f.period.is_finite() || f.u.iter().any(|v| !v.is_finite()) {
            return Err(Reject::NonFinite);
        }
        let period = R::from_f32(f.period);
        if !(period > R::ZERO && period <= cfg.tick_period * cfg.max_period_factor) {
            return Err(Reject::Range);
        }
        let limit = cfg.reject_speed;
        if f.u.iter().any(|&v| R::from_f32(v).abs() > limit) {
            return Err(Reject::Range);
        }
        if self.have_velocity && !seq_after(f.seq, self.last_seq) {
            return Err(Reject::Seq);
        }
        Ok(())
    }

    /// Offers one decoded frame. On success it enters the filter and its period (unless a held
    /// tick already covered it) is advanced at the end of the tick; on rejection nothing but
    /// the counters and the tick's health flags changed.
    pub fn submit(&mut self, f: &VelocityFrame) -> Result<(), Reject> {
        self.frames = self.frames.saturating_add(1);
        if let Err(r) = self.validate(f) {
            self.count_reject(r);
            return Err(r);
        }
        bump(&mut self.counters.accepted);
        if self.have_velocity {
            let next = self.covered.wrapping_add(1);
            if seq_after(f.seq, next) {
                let gap = f.seq.wrapping_sub(next);
                self.counters.lost_periods = self.counters.lost_periods.wrapping_add(gap);
                self.lag += self.cfg.tick_period * R::from_f64(gap as f64);
                self.covered = f.seq.wrapping_sub(1);
            }
        } else {
            self.covered = f.seq.wrapping_sub(1);
        }
        self.update_filter(f);
        if seq_after(f.seq, self.covered) || !self.have_velocity {
            self.pending += R::from_f32(f.period);
            self.covered = f.seq;
        }
        self.have_velocity = true;
        self.last_seq = f.seq;
        self.stale = 0;
        self.accepted_this_tick = true;
        Ok(())
    }

    /// Counts a rejection by cause (also used for byte-level causes so the tick's health
    /// flags show them).
    pub fn count_reject(&mut self, r: Reject) {
        self.flags |= health::FRAME_REJECTED;
        let c = &mut self.counters;
        match r {
            Reject::Dims => bump(&mut c.dims),
            Reject::NonFinite => bump(&mut c.non_finite),
            Reject::Range => bump(&mut c.range),
            Reject::Seq => bump(&mut c.seq),
            // Counted by the decoder; only the health flag and the frame's cost here.
            Reject::Overflow | Reject::Framing | Reject::Crc | Reject::Decode => {
                self.frames = self.frames.saturating_add(1);
            }
        }
    }

    /// Median clean-up, spatial and temporal smoothing of a validated frame into `vel`.
    fn update_filter(&mut self, f: &VelocityFrame) {
        let (nx, nz) = (f.nx as usize, f.nz as usize);
        let tol = self.cfg.outlier_tol.to_f64() as f32;
        let mut replaced = 0u32;
        for z in 0..nz {
            for x in 0..nx {
                for comp in 0..2 {
                    let at = 2 * (x + nx * z) + comp;
                    let v = f.u[at];
                    let mut nb = [0.0f32; 9];
                    let mut k = 0;
                    for zz in z.saturating_sub(1)..(z + 2).min(nz) {
                        for xx in x.saturating_sub(1)..(x + 2).min(nx) {
                            nb[k] = f.u[2 * (xx + nx * zz) + comp];
                            k += 1;
                        }
                    }
                    let med = median(&mut nb[..k]);
                    let clean = if (v - med).abs() > tol {
                        replaced += 1;
                        med
                    } else {
                        v
                    };
                    self.work[at] = R::from_f32(clean);
                }
            }
        }
        if replaced > 0 {
            self.flags |= health::OUTLIERS_REPLACED;
            self.counters.outliers = self.counters.outliers.wrapping_add(replaced);
        }
        // The frame's noise, measured before the smoothing correlates it (`noise.rs`); only
        // when the configuration subtracts it (the default does not pay for it).
        let variance = if self.cfg.noise_term > R::ZERO {
            noise::frame_variance(&self.work, [nx, nz])
        } else {
            R::ZERO
        };
        let periodic = [
            self.cfg.bc[0][0] == Boundary::Periodic,
            self.cfg.bc[1][0] == Boundary::Periodic,
        ];
        for _ in 0..self.cfg.spatial_passes {
            smooth_121(&mut self.work, [nx, nz], 0, periodic[0]);
            smooth_121(&mut self.work, [nx, nz], 1, periodic[1]);
        }
        // Running mean of the first frames, then an EMA: the weight of the k-th accepted frame
        // is max(1/k, smoothing), so the start is not left with one frame's full noise.
        let k = self.counters.accepted.max(1);
        let alpha = (R::ONE / R::from_f64(k as f64)).max(self.cfg.smoothing);
        let keep = R::ONE - alpha;
        self.noise_share = keep * keep * self.noise_share + alpha * alpha;
        self.noise_variance += alpha * (variance - self.noise_variance);
        for (p, &w) in self.vel[..2 * nx * nz]
            .iter_mut()
            .zip(self.work[..2 * nx * nz].iter())
        {
            *p += alpha * (w - *p);
        }
    }

    /// Bilinear interpolation of the smoothed sensor field onto the estimator cell centres
    /// (`set_velocity` per cell; the coefficients are derived by [`Self::prepare_velocity`]).
    ///
    /// The weights of one axis depend only on the cell index along it: the x weights are
    /// computed once per row segment of at most [`MAP_CHUNK`] cells and reused for every row.
    pub(super) fn map_velocity(&mut self) {
        let ne = [self.cfg.cells[0] as usize, self.cfg.cells[1] as usize];
        let ns = [self.cfg.sensor[0] as usize, self.cfg.sensor[1] as usize];
        let periodic = [
            self.cfg.bc[0][0] == Boundary::Periodic,
            self.cfg.bc[1][0] == Boundary::Periodic,
        ];
        let mut wx = [(0u8, 0u8, R::ZERO); MAP_CHUNK];
        let mut x_start = 0;
        while x_start < ne[0] {
            let len = (ne[0] - x_start).min(MAP_CHUNK);
            for (k, w) in wx[..len].iter_mut().enumerate() {
                let (x0, x1, t) = axis_weights::<R>(x_start + k, ne[0], ns[0], periodic[0]);
                // Sensor sides are at most MAX_SENSOR_SIDE (16): indices fit a u8.
                *w = (x0 as u8, x1 as u8, t);
            }
            for iz in 0..ne[1] {
                let (z0, z1, wz) = axis_weights::<R>(iz, ne[1], ns[1], periodic[1]);
                let row0 = &self.vel[2 * ns[0] * z0..2 * ns[0] * (z0 + 1)];
                let row1 = &self.vel[2 * ns[0] * z1..2 * ns[0] * (z1 + 1)];
                for (k, &(x0, x1, t)) in wx[..len].iter().enumerate() {
                    let (x0, x1) = (2 * x0 as usize, 2 * x1 as usize);
                    let mut u = [R::ZERO; 2];
                    for (comp, uc) in u.iter_mut().enumerate() {
                        let lo = row0[x0 + comp] + t * (row0[x1 + comp] - row0[x0 + comp]);
                        let hi = row1[x0 + comp] + t * (row1[x1 + comp] - row1[x0 + comp]);
                        *uc = lo + wz * (hi - lo);
                    }
                    self.seg.set_velocity(x_start + k + ne[0] * iz, u);
                }
            }
            x_start += len;
        }
    }

    /// Re-derives T, the segregation direction and the stable step from the mapped velocity.
    /// `prepare_velocity` checks only that u is finite (it is: frames are validated), not
    /// that phi is in [0, c]: the state is never clamped, so the estimator stays exactly
    /// conservative even when a noisy measured velocity is not divergence-free.
    fn prepare_velocity(&mut self) {
        let res = self.prepare_measured();
        debug_assert!(res.is_ok(), "validated input must prepare: {res:?}");
    }

    /// `Segregation::prepare_velocity` with T from the measured shear less what the noise
    /// left in the filtered field gives it (`noise.rs`; its two scalars are in snapshots, so a
    /// restored sensor derives the same coefficients).
    pub(super) fn prepare_measured(&mut self) -> Result<(), crate::segregation::SetupError> {
        let noise = if self.have_velocity && self.cfg.noise_term > R::ZERO {
            self.cfg.noise_term
                * self
                    .noise
                    .shear_noise(self.noise_variance * self.noise_share)
        } else {
            R::ZERO
        };
        self.seg.set_shear_noise(noise);
        self.seg.prepare_velocity()?;
        let rate = self.seg.transport_rate();
        let transport = if rate > R::ZERO {
            R::from_f64(TRANSPORT_COURANT) / rate
        } else {
            R::MAX
        };
        self.substep_dt = self.seg.stable_dt_percolation().min(transport);
        Ok(())
    }

    /// The longest substep for the current velocity: the percolation stage's Courant limit
    /// ([`Segregation::stable_dt_percolation`], the configuration's `courant`) and the
    /// carried transport's ([`TRANSPORT_COURANT`] over [`Segregation::transport_rate`]),
    /// each on its own rate; the two stages of a substep run one after the other.
    pub fn stable_dt(&self) -> R {
        self.substep_dt
    }

    /// Advances by `dt` within what is left of this tick's substep cap (from the cycle
    /// budget, [`SensorConfig::substep_cap`]).
    fn advance(&mut self, dt: R) {
        let left = self.cap.saturating_sub(self.substeps);
        let sdt = self.substep_dt;
        let ratio = dt.to_f64() / sdt.to_f64();
        let need = libm::ceil(ratio).max(1.0);
        if need <= left as f64 {
            let n = need as u16;
            let sub = dt / R::from_usize(n as usize);
            for _ in 0..n {
                self.substep(sub);
            }
            self.substeps += n;
        } else {
            for _ in 0..left {
                self.substep(sdt);
            }
            self.substeps += left;
            self.lag += dt - sdt * R::from_usize(left as usize);
            if self.flags & health::BUDGET_LIMITED == 0 {
                bump(&mut self.counters.budget_limited);
            }
            self.flags |= health::BUDGET_LIMITED;
        }
    }

    /// One substep (model.md 8): the segregation flux alone (modified Godunov, compensated),
    /// then c and phi carried together by the face mass fluxes `c_donor u_face` of the
    /// measured velocity ([`Segregation::carry_own_velocity`]), so `0 <= phi <= c` holds
    /// exactly whatever the noise; what leaves through outlets and open sides is booked.
    fn substep(&mut self, dt: R) {
        self.seg.step_percolation(dt);
        let grid = *self.seg.grid();
        let open = &self.open;
        // The packing cap: 5 % above the bed's c at power-up (docs/soft-sensor.md "A packing
        // cap on the carried c": at the bed's c itself the cap's pool mixes too much).
        let cap = self.cfg.c * R::from_f64(PACKING_HEADROOM);
        let d = self
            .seg
            .carry_own_velocity(dt, self.cfg.inflow_phihat, Some(cap), |a, high, i| {
                open[a][high as usize].fraction(&grid, a, i)
            });
        let (mut total, mut small) = (R::ZERO, R::ZERO);
        for a in 0..2 {
            for side in 0..2 {
                total += d.total[a][side];
                small += d.small[a][side];
            }
        }
        self.tick_out[0] += total;
        self.tick_out[1] += small;
    }

    /// Ends the tick: holds or freezes if no frame was accepted during it, then returns the
    /// estimate and clears the tick's health flags.
    pub fn finish_tick(&mut self) -> Estimate {
        self.finish_tick_profiled(&mut || 0).0
    }

    /// [`Self::finish_tick`] that also reads `clock` between its phases (firmware-sim passes
    /// the instruction counter) and returns the differences. With a constant clock the
    /// readings compile away.
    pub fn finish_tick_profiled(
        &mut self,
        clock: &mut impl FnMut() -> u64,
    ) -> (Estimate, TickProfile) {
        let mut prof = TickProfile::default();
        // The cap of this tick: the budget after the fixed part with the frames it decoded.
        self.cap = self.cfg.budget.substeps_frames(
            self.cfg.estimator_grid(),
            self.cfg.sensor_points(),
            self.frames,
        );
        let t0 = clock();
        if self.accepted_this_tick {
            // One velocity update per tick however many frames arrived (a burst after a
            // stall costs one mapping, not one per frame), then their total time.
            self.map_velocity();
            let t1 = clock();
            self.prepare_velocity();
            let t2 = clock();
            prof.map = t1 - t0;
            prof.prepare = t2 - t1;
            let dt = core::mem::replace(&mut self.pending, R::ZERO);
            if dt > R::ZERO {
                self.advance(dt);
            }
        } else {
            self.stale = self.stale.saturating_add(1);
            if self.have_velocity && self.stale <= self.cfg.hold_ticks as u32 {
                self.flags |= health::STALE_INPUT;
                bump(&mut self.counters.stale_ticks);
                self.advance(self.cfg.tick_period);
                self.covered = self.covered.wrapping_add(1);
            } else {
                self.flags |= health::FROZEN;
                bump(&mut self.counters.frozen_ticks);
            }
        }
        // The tick's outflow into the window and the running total.
        let slot = self.out_head as usize % self.cfg.outflow_window as usize;
        self.out_ring[slot] = self.tick_out;
        self.out_head = ((slot + 1) % self.cfg.outflow_window as usize) as u16;
        self.out_total[0] += self.tick_out[0];
        self.out_total[1] += self.tick_out[1];
        let t3 = clock();
        prof.substeps = t3 - t0 - prof.map - prof.prepare;
        let (mut e, excursions) = self.readout();
        if excursions > 0 {
            self.counters.phi_excursions = self.counters.phi_excursions.wrapping_add(excursions);
        }
        self.update_off_spec(&mut e);
        prof.estimate = clock() - t3;
        self.flags = 0;
        self.substeps = 0;
        self.frames = 0;
        self.tick_out = [R::ZERO; 2];
        self.accepted_this_tick = false;
        self.tick = self.tick.wrapping_add(1);
        (e, prof)
    }

    /// One tick with at most one frame (a rejected frame counts as a missing one).
    pub fn tick(&mut self, frame: Option<&VelocityFrame>) -> Estimate {
        if let Some(f) = frame {
            let _ = self.submit(f);
        }
        self.finish_tick()
    }

    /// The estimate of the current state with the current tick's flags.
    pub fn estimate(&self) -> Estimate {
        self.readout().0
    }

    /// The estimate and the number of cells whose phi is outside [0, c] (flagged with
    /// [`health::PHI_EXCURSION`]). One pass over the cells, display-only clamping: phihat is
    /// clamped into [0, 1] for min, max and psi, region means are clamped into [0, 1]; the
    /// state is not touched. psi uses [`entropy::entropy_density`] (a table, about 12
    /// instructions a cell instead of two `ln`), within 4e-4 of `diagnose`'s psi.
    fn readout(&self) -> (Estimate, u32) {
        let g = &self.seg;
        let n = g.len();
        let vacuum = g.config().vacuum;
        let (mut mass_small, mut mass_total, mut ent) = (R::ZERO, R::ZERO, R::ZERO);
        let (mut lo, mut hi) = (R::ONE, R::ZERO);
        let mut excursions = 0u32;
        for i in 0..n {
            let (phi, c) = (g.phi(i), g.c(i));
            mass_small += phi;
            mass_total += c;
            // Beyond round-off only: compensated updates carry sub-ulp increments exactly, so
            // a cell at 0 or at c may sit a denormal or an ulp outside.
            let tol = R::EPSILON * c;
            if phi < -tol || phi > c + tol {
                excursions += 1;
            }
            if c > vacuum {
                let ph = (phi / c).max(R::ZERO).min(R::ONE);
                lo = lo.min(ph);
                hi = hi.max(ph);
                ent += entropy::entropy_density(ph) * c;
            }
        }
        let mixed = if mass_total > R::ZERO {
            diagnostics::mixing_entropy_density(mass_small / mass_total) * mass_total
        } else {
            R::ZERO
        };
        let psi = if mixed > R::ZERO {
            ent / mixed
        } else {
            R::ZERO
        };
        let cfg = &self.cfg;
        let nx = cfg.cells[0] as usize;
        let mut regions = heapless::Vec::new();
        for r in &cfg.regions {
            let (mut sp, mut sc) = (R::ZERO, R::ZERO);
            for iz in r.lo[1] as usize..r.hi[1] as usize {
                for ix in r.lo[0] as usize..r.hi[0] as usize {
                    let i = ix + nx * iz;
                    sp += g.phi(i);
                    sc += g.c(i);
                }
            }
            let mean = if sc > R::ZERO {
                (sp / sc).max(R::ZERO).min(R::ONE)
            } else {
                R::ZERO
            };
            // Cannot overflow: the configuration holds at most as many regions.
            let _ = regions.push(mean.to_f64() as f32);
        }
        let fraction = |o: [R; 2]| {
            if o[0] > R::ZERO {
                (o[1] / o[0]).max(R::ZERO).min(R::ONE)
            } else {
                R::ZERO
            }
        };
        let mut window = [R::ZERO; 2];
        for o in &self.out_ring[..cfg.outflow_window as usize] {
            window[0] += o[0];
            window[1] += o[1];
        }
        let window_fines = fraction(window);
        let mut alarms = 0;
        if psi < cfg.psi_alarm {
            alarms |= alarm::PSI_LOW;
        }
        // The fines fraction of what left over the window where something left, else the
        // outlet region's mean.
        let outlet_fines = if window[0] > R::ZERO {
            Some(window_fines.to_f64() as f32)
        } else {
            cfg.outlet.and_then(|o| regions.get(o as usize)).copied()
        };
        // The fines alarms are latched by `update_off_spec` at the end of each tick
        // (persistence and hysteresis), so a readout between ticks shows the same state.
        let _ = outlet_fines;
        alarms |= self.fines_state;
        let mut h = self.flags;
        if !self.have_velocity {
            h |= health::NO_INPUT;
        }
        if excursions > 0 {
            h |= health::PHI_EXCURSION;
        }
        let f = |x: R| x.to_f64() as f32;
        let e = Estimate {
            seq: self.last_seq,
            tick: self.tick,
            time: f(g.time()),
            psi: f(psi),
            phihat_min: f(lo),
            phihat_max: f(hi),
            regions,
            alarms,
            health: h,
            substeps: self.substeps,
            lag: f(self.lag),
            outflow: f(self.tick_out[0]),
            outflow_fines: f(fraction(self.tick_out)),
            outflow_fines_window: f(window_fines),
            off_spec_in: self.off_spec_in.map_or(f32::INFINITY, f),
        };
        (e, excursions)
    }

    /// The outlet fines fraction the alarms watch: that of what left over the window if
    /// anything left, else the outlet region's mean, else none.
    fn outlet_fines(&self, e: &Estimate) -> Option<R> {
        let window: R = self.out_ring[..self.cfg.outflow_window as usize]
            .iter()
            .fold(R::ZERO, |s, o| s + o[0]);
        if window > R::ZERO {
            Some(R::from_f32(e.outflow_fines_window))
        } else {
            self.cfg
                .outlet
                .and_then(|o| e.regions.get(o as usize))
                .map(|&x| R::from_f32(x))
        }
    }

    /// End of a tick: latches the fines alarms and predicts the time to the next off-spec
    /// event, then writes both into `e`.
    ///
    /// * Alarms: the fraction `f` (see [`Self::outlet_fines`]) raises [`alarm::FINES_LOW`]
    ///   (`f < lo`) or [`alarm::FINES_HIGH`] (`f > hi`) after `alarm_persist` consecutive
    ///   ticks out of the band, and clears only after `alarm_persist` consecutive ticks back
    ///   inside `[lo + h, hi - h]` (`h = fines_hysteresis`): both a persistence count and a
    ///   hysteresis, so neither a noisy tick nor a fraction hovering at a band edge chatters.
    ///   A tick without a fraction (nothing left, no outlet region) changes nothing.
    ///   `alarm_persist = 1`, `h = 0` is the instantaneous comparison.
    /// * Prediction: a least-squares line through the last `outflow_window` (time, f) samples
    ///   (estimator time, so held and burst ticks are placed where they belong), extrapolated
    ///   from its value at the latest sample to the band edge it heads for: `(hi - f)/slope`
    ///   or `(f - lo)/(-slope)`. 0 while out of the band or alarmed; infinity for a flat or
    ///   inward trend or fewer than 3 samples. The windowed fraction lags the discharge by
    ///   about half the window, and a trend sees an event only once it has begun: this warns
    ///   of a drift, not of a front that has not yet reached the outlet (docs/soft-sensor.md).
    fn update_off_spec(&mut self, e: &mut Estimate) {
        let cfg = &self.cfg;
        let (lo, hi, h) = (cfg.fines_band[0], cfg.fines_band[1], cfg.fines_hysteresis);
        let persist = cfg.alarm_persist.max(1);
        if let Some(f) = self.outlet_fines(e) {
            let runs = &mut self.fines_runs;
            let step = |run: &mut u16, on: bool| *run = if on { run.saturating_add(1) } else { 0 };
            step(&mut runs[0], f < lo);
            step(&mut runs[1], f > hi);
            step(&mut runs[2], f >= lo + h && f <= hi - h);
            if runs[0] >= persist {
                self.fines_state = alarm::FINES_LOW;
            } else if runs[1] >= persist {
                self.fines_state = alarm::FINES_HIGH;
            } else if self.fines_state != 0 && runs[2] >= persist {
                self.fines_state = 0;
            }
            let w = cfg.outflow_window as usize;
            self.trend[self.trend_head as usize % w] = [self.seg.time(), f];
            self.trend_head = ((self.trend_head as usize + 1) % w) as u16;
            self.trend_len = (self.trend_len + 1).min(w as u16);
            self.off_spec_in = if self.fines_state != 0 || f < lo || f > hi {
                Some(R::ZERO)
            } else {
                self.trend_exit(lo, hi)
            };
        }
        e.alarms = (e.alarms & !(alarm::FINES_LOW | alarm::FINES_HIGH)) | self.fines_state;
        e.off_spec_in = self
            .off_spec_in
            .map_or(f32::INFINITY, |t| t.to_f64() as f32);
    }

    /// Time until the least-squares line through the trend samples reaches `lo` or `hi`
    /// from its value at the latest sample (`None`: no exit ahead). Sums in ring order
    /// from the oldest sample, so the result is the same on every platform.
    fn trend_exit(&self, lo: R, hi: R) -> Option<R> {
        let n = self.trend_len as usize;
        if n < 3 {
            return None;
        }
        let w = self.cfg.outflow_window as usize;
        let first = (self.trend_head as usize + w - n) % w;
        let at = |k: usize| self.trend[(first + k) % w];
        let inv = R::ONE / R::from_u32(n as u32);
        let t0 = at(0)[0];
        let (mut st, mut sf) = (R::ZERO, R::ZERO);
        for k in 0..n {
            st += at(k)[0] - t0;
            sf += at(k)[1];
        }
        let (tm, fm) = (st * inv, sf * inv);
        let (mut stt, mut stf) = (R::ZERO, R::ZERO);
        for k in 0..n {
            let dt = at(k)[0] - t0 - tm;
            stt += dt * dt;
            stf += dt * (at(k)[1] - fm);
        }
        if stt <= R::ZERO {
            return None;
        }
        let slope = stf / stt;
        let now = at(n - 1)[0] - t0;
        let f = fm + slope * (now - tm);
        let t = if slope > R::ZERO {
            (hi - f) / slope
        } else if slope < R::ZERO {
            (f - lo) / -slope
        } else {
            return None;
        };
        if t.is_finite() {
            Some(t.max(R::ZERO))
        } else {
            None
        }
    }

    /// Hash of the whole estimator state: the core state hash (time, phi, c, T, u) then the
    /// smoothed sensor field, the sequence bookkeeping and the lag.
    pub fn state_hash(&self) -> u64 {
        let mut h = Fnv64::new();
        h.write(&state_hash(&self.seg).to_le_bytes());
        for v in &self.vel[..2 * self.cfg.sensor_points()] {
            v.hash_into(&mut h);
        }
        h.write_u32(self.have_velocity as u32);
        h.write_u32(self.last_seq);
        h.write_u32(self.covered);
        h.write_u32(self.stale);
        self.lag.hash_into(&mut h);
        for v in self.out_total {
            v.hash_into(&mut h);
        }
        h.finish()
    }

    /// The segregation solver (phi, c, T, u on the estimator grid).
    pub fn segregation(&self) -> &Segregation<R, 2, N> {
        &self.seg
    }
    /// The configuration.
    pub fn config(&self) -> &SensorConfig<R> {
        &self.cfg
    }
    /// The counters.
    pub fn counters(&self) -> &Counters {
        &self.counters
    }
    /// Accumulated simulated-time shortfall \[s\].
    pub fn lag(&self) -> R {
        self.lag
    }
    /// What left the box since configuration through outlets and open sides: grain volume
    /// and small-grain volume (per unit depth in 2D).
    pub fn outflow_total(&self) -> [R; 2] {
        self.out_total
    }
    /// phihat of estimator cell `i` (0 in empty cells).
    pub fn phihat(&self, i: usize) -> R {
        let c = self.seg.c(i);
        if c > R::VACUUM {
            self.seg.phi(i) / c
        } else {
            R::ZERO
        }
    }
}

/// One pass of the 1-2-1 filter along `axis` of an interleaved two-component sensor field,
/// in place. Points without two neighbours along the axis (the ends of a non-periodic axis)
/// are left alone, so a linear profile stays exactly linear up to the walls.
pub(super) fn smooth_121<R: SensorReal>(v: &mut [R], n: [usize; 2], axis: usize, periodic: bool) {
    let len = n[axis];
    if len < 3 {
        return;
    }
    let stride = if axis == 0 { 1 } else { n[0] };
    let lines = n[1 - axis];
    let line_stride = if axis == 0 { n[0] } else { 1 };
    let quarter = R::HALF * R::HALF;
    for l in 0..lines {
        for comp in 0..2 {
            let at = |j: usize| 2 * (l * line_stride + j * stride) + comp;
            // Original values of the ends and of the second point (overwritten in the loop).
            let first = v[at(0)];
            let second = v[at(1)];
            let last = v[at(len - 1)];
            let mut prev = first;
            for j in 1..len - 1 {
                let cur = v[at(j)];
                v[at(j)] = (prev + cur + cur + v[at(j + 1)]) * quarter;
                prev = cur;
            }
            if periodic {
                // `prev` is now the original v[len - 2].
                v[at(len - 1)] = (prev + last + last + first) * quarter;
                v[at(0)] = (last + first + first + second) * quarter;
            }
        }
    }
}

/// Median of a short slice (insertion sort in place; the mean of the middle pair for an
/// even count). Comparisons only, so NaN-free input gives a deterministic result.
fn median(a: &mut [f32]) -> f32 {
    for i in 1..a.len() {
        let mut j = i;
        while j > 0 && a[j - 1] > a[j] {
            a.swap(j - 1, j);
            j -= 1;
        }
    }
    let k = a.len();
    if k % 2 == 1 {
        a[k / 2]
    } else {
        (a[k / 2 - 1] + a[k / 2]) * 0.5
    }
}

/// The two sensor points bracketing estimator cell `i` along one axis and the weight of the
/// second: sensor point `j` sits at `(j + 1/2) / ns` of the box, cell `i` at `(i + 1/2) / ne`,
/// so the cell is at sensor coordinate `t = ((2i + 1) ns - ne) / (2 ne)`. Its floor is taken
/// in integers: exact, and no soft-float f64 on the Cortex-M4F.
pub(super) fn axis_weights<R: SensorReal>(
    i: usize,
    ne: usize,
    ns: usize,
    periodic: bool,
) -> (usize, usize, R) {
    if ns == 1 {
        return (0, 0, R::ZERO);
    }
    // i32, not i64: 64-bit division is a library call on the Cortex-M4F. Grid sides are
    // bounded by u16 and 16, so every term fits.
    let num = ((2 * i + 1) * ns) as i32 - ne as i32;
    let den = 2 * ne as i32;
    let fl = num.div_euclid(den);
    let frac = |base: i32| R::from_u32((num - base * den) as u32) / R::from_u32(den as u32);
    if periodic {
        let i0 = fl.rem_euclid(ns as i32) as usize;
        (i0, (i0 + 1) % ns, frac(fl))
    } else {
        // Clamping the segment (not the weight) extrapolates linearly beyond the outermost
        // sensor points, so a linear profile is reproduced up to the walls.
        let i0 = fl.clamp(0, ns as i32 - 2);
        let w = if num >= i0 * den {
            frac(i0)
        } else {
            -(R::from_u32((i0 * den - num) as u32) / R::from_u32(den as u32))
        };
        (i0 as usize, i0 as usize + 1, w)
    }
}
