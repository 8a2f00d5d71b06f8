//! Configuration of the soft sensor: material, geometry, sensor mapping, budget, input
//! handling and alarms. Serialisable (postcard) so a recording carries the exact configuration
//! the firmware and the host replay run with.

use super::{SensorReal, MAX_REGIONS, MAX_REGION_NAME, MAX_SENSOR_SIDE};
use crate::boundary::{check_periodic_pairs, Boundaries};
use serde::{Deserialize, Serialize};

/// A named rectangle of estimator cells, `lo[a] <= cell[a] < hi[a]` along x (0) and z (1).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Region {
    /// Name (at most [`MAX_REGION_NAME`] bytes), for reports.
    pub name: heapless::String<MAX_REGION_NAME>,
    /// First cell along each axis (inclusive).
    pub lo: [u16; 2],
    /// Last cell along each axis (exclusive).
    pub hi: [u16; 2],
}

impl Region {
    /// A region from a name (truncated to [`MAX_REGION_NAME`] bytes at a char boundary) and
    /// cell bounds.
    pub fn new(name: &str, lo: [u16; 2], hi: [u16; 2]) -> Self {
        let mut s = heapless::String::new();
        for ch in name.chars() {
            if s.push(ch).is_err() {
                break;
            }
        }
        Self { name: s, lo, hi }
    }
}

/// An opening (outlet) in a wall side of the estimator's box: grains leave through the part
/// `lower..upper` of the side (the coordinate along the side, m from the origin), as through
/// the flow's [`crate::boundary::Openings`]; nothing enters through it (issue 9, silo).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SensorOpening<R> {
    /// Axis of the side's normal: 0 (an x side) or 1 (a z side, e.g. a silo floor).
    pub axis: u8,
    /// The high side of that axis (false: the low side, e.g. the floor).
    pub high: bool,
    /// Start of the opening along the other axis \[m\].
    pub lower: R,
    /// End of the opening along the other axis \[m\].
    pub upper: R,
}

/// The tick's time budget and the estimator's cost model, in CPU cycles (issue 9).
///
/// A tick may take as many substeps as the stable step asks for, up to
/// `floor((cycles - fixed) / substep)` ([`Self::substeps`]) with, for an estimator of
/// `cells = nx nz` cells and `faces = 2 (nx + nz)` boundary faces,
///
/// ```text
/// fixed   = per_tick + per_cell cells + per_point points frames
/// substep = per_substep + per_cell_substep cells + per_face_substep faces
/// ```
///
/// (`frames`: the frames the tick decoded, at least 1, so a burst after a stall pays for its
/// decoding out of the substeps). The constant and boundary terms are why a small or
/// elongated estimator costs more per cell than a square one (docs/soft-sensor.md "Cycle
/// budget"). The cap is a model of the cost, not a clock reading, so it is the same on the
/// host and on the firmware and a replay is deterministic. The coefficients are instruction
/// counts measured by `firmware-sim/run.sh` under QEMU `-icount` (one cycle per instruction:
/// the Cortex-M4F issues most integer and FPU instructions in one cycle; flash wait states on
/// a real part make a cycle count larger, which a controller covers by granting the sensor
/// less than the whole period). The firmware checks every tick's measured count against the
/// model, on a shear-cell and on a silo recording.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct CycleBudget {
    /// Cycles the sensor may spend in one tick (clock frequency times the tick period times
    /// the share of the CPU the controller grants the sensor).
    pub cycles: u32,
    /// Fixed part of a tick, whatever the grids (calls, the readout's constant work).
    pub per_tick: u32,
    /// Fixed part of a tick per estimator cell: bilinear map, `prepare_velocity`, estimate.
    pub per_cell: u32,
    /// Fixed part of a tick per sensor point: UART decode (COBS, CRC, postcard), validation,
    /// median / 1-2-1 / EMA filter of one frame.
    pub per_point: u32,
    /// One substep, whatever the grid (stable step, books, sums).
    pub per_substep: u32,
    /// One substep per estimator cell (`step_percolation` compensated + `carry_own_velocity`
    /// with its packing cap).
    pub per_cell_substep: u32,
    /// One substep per boundary face of the estimator (wall, opening and side loops).
    pub per_face_substep: u32,
}

impl CycleBudget {
    /// The cost model of the f32 estimator on the Cortex-M4F, fitted on 2026-12-06 to the
    /// largest tick parts firmware-sim measured over seven recordings (shear cell on 32 x 32,
    /// 8 x 28 and 8 x 8 estimators with an 8 x 8 sensor; a discharging silo on 32 x 32,
    /// 16 x 56, 8 x 28 and 4 x 14 with a 2 x 7 sensor), about 5 % above them:
    /// fixed part 2,250 + 557 per cell (shear cell), feed 1,473 per sensor point and frame,
    /// substep 760 + 545 per cell + 296 per boundary face (the silo, whose packing cap and
    /// openings cost 545 - 454 = 91 more per cell than the shear cell's substep).
    pub const CORTEX_M4F: Self = Self {
        cycles: 0,
        per_tick: 4_000,
        per_cell: 580,
        per_point: 1_520,
        per_substep: 1_000,
        per_cell_substep: 575,
        per_face_substep: 310,
    };

    /// This cost model with the budget of a CPU at `clock_hz` granting the sensor the share
    /// `share` (in (0, 1]) of every `period` \[s\]: `floor(clock_hz period share)` cycles,
    /// saturating at `u32::MAX`.
    pub fn with_clock(self, clock_hz: f64, period: f64, share: f64) -> Self {
        let c = libm::floor(clock_hz * period * share);
        let cycles = if c.is_nan() || c <= 0.0 {
            0
        } else if c >= u32::MAX as f64 {
            u32::MAX
        } else {
            c as u32
        };
        Self { cycles, ..self }
    }

    /// A budget that affords exactly `k` substeps of `cells` cells, whatever the grids
    /// (no fixed part, one cycle per cell and substep): for tests and tools that set the cap
    /// directly.
    pub const fn for_substeps(k: u16, cells: usize) -> Self {
        Self {
            cycles: k as u32 * cells as u32,
            per_tick: 0,
            per_cell: 0,
            per_point: 0,
            per_substep: 0,
            per_cell_substep: 1,
            per_face_substep: 0,
        }
    }

    /// Cycles of the fixed part of a tick with one frame for an estimator of `grid` cells
    /// (x, z) and `points` sensor points.
    pub fn fixed(&self, grid: [usize; 2], points: usize) -> u64 {
        self.fixed_frames(grid, points, 1)
    }

    /// Cycles of the fixed part of a tick that decoded `frames` frames (at least one is
    /// counted).
    pub fn fixed_frames(&self, grid: [usize; 2], points: usize, frames: u32) -> u64 {
        // Saturating: a hostile configuration's coefficients and grids cannot wrap the sum
        // into a small cost (the configuration is range-checked after its cap is computed).
        let cells = (grid[0] as u64).saturating_mul(grid[1] as u64);
        (self.per_tick as u64)
            .saturating_add((self.per_cell as u64).saturating_mul(cells))
            .saturating_add(
                (self.per_point as u64)
                    .saturating_mul(points as u64)
                    .saturating_mul(frames.max(1) as u64),
            )
    }

    /// Cycles of one substep for an estimator of `grid` cells (x, z).
    pub fn substep(&self, grid: [usize; 2]) -> u64 {
        let cells = (grid[0] as u64).saturating_mul(grid[1] as u64);
        let faces = 2u64.saturating_mul((grid[0] as u64).saturating_add(grid[1] as u64));
        (self.per_substep as u64)
            .saturating_add((self.per_cell_substep as u64).saturating_mul(cells))
            .saturating_add((self.per_face_substep as u64).saturating_mul(faces))
    }

    /// Most substeps one tick can afford: `floor((cycles - fixed) / substep)`, 0 if the fixed
    /// part alone exceeds the budget, saturating at `u16::MAX` (a free substep, cost 0, also
    /// gives `u16::MAX`). Integer arithmetic: the same cap on every platform.
    pub fn substeps(&self, grid: [usize; 2], points: usize) -> u16 {
        self.substeps_frames(grid, points, 1)
    }

    /// [`Self::substeps`] of a tick that decoded `frames` frames.
    pub fn substeps_frames(&self, grid: [usize; 2], points: usize, frames: u32) -> u16 {
        let fixed = self.fixed_frames(grid, points, frames);
        let cycles = self.cycles as u64;
        if fixed >= cycles {
            return 0;
        }
        let per = self.substep(grid);
        if per == 0 {
            return u16::MAX;
        }
        ((cycles - fixed) / per).min(u16::MAX as u64) as u16
    }
}

/// Largest number of openings of a sensor configuration.
pub const MAX_OPENINGS: usize = 2;
/// Largest outflow window in ticks ([`SensorConfig::outflow_window`]).
pub const MAX_OUTFLOW_WINDOW: usize = 64;

/// Everything the soft sensor needs besides the frames. Axis 0 is x (horizontal / downstream),
/// axis 1 is z (up). Velocities in m/s, lengths in m, times in s.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SensorConfig<R> {
    /// Estimator cells along x and z (their product must fit the capacity `N`).
    pub cells: [u16; 2],
    /// Box size along x and z \[m\] (origin at 0).
    pub extent: [R; 2],
    /// Boundary kinds of the box (walls, periodic, inflow, outflow = outlet).
    pub bc: Boundaries<2>,
    /// Sensor (velocity frame) points along x and z; each point is the centre of a sensor
    /// cell of the same box, so a sensor grid may be coarser than the estimator grid.
    pub sensor: [u8; 2],
    /// Segregation rate S0 [s^2/m].
    pub s0: R,
    /// eta0 \[m\] of `T = a eta0/eps0 kappa:kappa`.
    pub eta0: R,
    /// eps0 [1/m].
    pub eps0: R,
    /// Heating prefactor a (3/2 in the source model).
    pub heating: R,
    /// Gravity [m/s^2].
    pub gravity: [R; 2],
    /// Volume fraction c of the bed at power-up (a field may replace it, see
    /// `SoftSensor::set_c_field`); from then on c is carried with the measured flow.
    pub c: R,
    /// Height of the bed's free surface at power-up \[m\]: c below it, 0 above, the cell it
    /// crosses filled in proportion (a silo's fill level, e.g. from a level sensor); the box
    /// height for a full box.
    pub fill_level: R,
    /// Initial relative small fraction phihat everywhere (the state at power-up).
    pub initial_phihat: R,
    /// phihat entering through inflow boundaries.
    pub inflow_phihat: R,
    /// Remixing diffusivity D >= 0 [m^2/s].
    pub diffusion: R,
    /// Courant number of the substeps, in (0, 1).
    pub courant: R,
    /// Nominal frame / tick period \[s\]; a held (stale) tick advances this much.
    pub tick_period: R,
    /// Largest accepted frame period, as a multiple of `tick_period` (frames with a longer or
    /// non-positive period are rejected as out of range).
    pub max_period_factor: R,
    /// Time budget of a tick and the cost model: the tick takes at most
    /// [`CycleBudget::substeps`] substeps (at least one must fit).
    pub budget: CycleBudget,
    /// Ticks without a valid frame during which the last good velocity is held; after that
    /// the estimate freezes.
    pub hold_ticks: u16,
    /// A frame with any velocity component of magnitude above this [m/s] is rejected as out
    /// of range (physically impossible: sensor garbage).
    pub reject_speed: R,
    /// A value that differs from the median of its 3x3 sensor neighbourhood by more than this
    /// [m/s] is replaced by that median (spike removal).
    pub outlier_tol: R,
    /// Weight of a new frame in the exponential moving average of the velocity, in (0, 1]
    /// (1 = no temporal smoothing).
    pub smoothing: R,
    /// Passes of the separable 1-2-1 filter over the sensor field (0 = off). It leaves linear
    /// profiles unchanged (ends of non-periodic axes are not filtered) and cuts the noise of
    /// the measured gradient, which otherwise inflates T (T grows with its square).
    pub spatial_passes: u8,
    /// Track the large phase (`Phase::Large`, phi = c - q) instead of the small one. The
    /// estimate is the same up to round-off; snapshots restore either bit-exactly.
    pub track_large: bool,
    /// Named regions, reported as mean phihat.
    pub regions: heapless::Vec<Region, MAX_REGIONS>,
    /// Index of the outlet region in `regions` (its mean is the discharge fines fraction).
    pub outlet: Option<u8>,
    /// Alarm when psi falls below this.
    pub psi_alarm: R,
    /// Alarm when the outlet fines fraction leaves `[lo, hi]` (the fines fraction of the
    /// outflow over the window if anything left the box during it, else the outlet region).
    pub fines_band: [R; 2],
    /// Hysteresis of the fines alarms: a raised alarm clears only once the fraction is back
    /// inside `[lo + h, hi - h]` (>= 0, less than half the band).
    pub fines_hysteresis: R,
    /// Persistence of the fines alarms: the fraction must be out of the band (or, to clear,
    /// back inside the hysteresis band) for this many consecutive ticks (>= 1) before the
    /// alarm state changes, so a noisy tick does not chatter.
    pub alarm_persist: u16,
    /// Openings in wall sides (outlets), at most [`MAX_OPENINGS`].
    pub openings: heapless::Vec<SensorOpening<R>, MAX_OPENINGS>,
    /// Ticks over which the outflow fines fraction is averaged (1 to [`MAX_OUTFLOW_WINDOW`]).
    pub outflow_window: u16,
    /// Multiple (0 to 10) of the noise's own `kappa : kappa` subtracted before T is derived
    /// from the measured shear (docs/soft-sensor.md "Noise in the measured shear"): 0 (the
    /// default) leaves T as measured; 1 removes what the noise adds on average.
    pub noise_term: R,
}

/// Why a configuration cannot be used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConfigError {
    /// More estimator cells than the capacity, or an empty axis.
    Cells,
    /// Sensor grid empty or larger than [`MAX_SENSOR_SIDE`] per axis.
    SensorGrid,
    /// Periodic on one side only.
    UnpairedPeriodic,
    /// A number is non-finite or outside its range; names the field.
    Parameter(&'static str),
    /// A region is empty or outside the grid, or the outlet index is invalid.
    Region,
}

impl<R: SensorReal> SensorConfig<R> {
    /// Checks ranges; `capacity` is the estimator's compiled cell capacity.
    pub fn validate(&self, capacity: usize) -> Result<(), ConfigError> {
        let n = self.cells[0] as usize * self.cells[1] as usize;
        if n == 0 || n > capacity {
            return Err(ConfigError::Cells);
        }
        for a in 0..2 {
            let s = self.sensor[a] as usize;
            if s == 0 || s > MAX_SENSOR_SIDE {
                return Err(ConfigError::SensorGrid);
            }
        }
        check_periodic_pairs(&self.bc).map_err(|_| ConfigError::UnpairedPeriodic)?;
        let pos = |x: R| x.is_finite() && x > R::ZERO;
        let nonneg = |x: R| x.is_finite() && x >= R::ZERO;
        let unit = |x: R| x.is_finite() && x >= R::ZERO && x <= R::ONE;
        let checks: [(&'static str, bool); 17] = [
            ("extent", pos(self.extent[0]) && pos(self.extent[1])),
            ("s0", nonneg(self.s0)),
            ("eta0", nonneg(self.eta0)),
            ("eps0", pos(self.eps0)),
            ("heating", nonneg(self.heating)),
            (
                "gravity",
                self.gravity[0].is_finite() && self.gravity[1].is_finite(),
            ),
            (
                "c",
                nonneg(self.c)
                    && self.c <= R::ONE
                    && self.fill_level.is_finite()
                    && self.fill_level > R::ZERO,
            ),
            ("initial_phihat", unit(self.initial_phihat)),
            ("inflow_phihat", unit(self.inflow_phihat)),
            ("diffusion", nonneg(self.diffusion)),
            ("courant", pos(self.courant) && self.courant < R::ONE),
            ("tick_period", pos(self.tick_period)),
            ("max_period_factor", pos(self.max_period_factor)),
            ("budget", self.substep_cap() > 0),
            (
                "reject_speed",
                pos(self.reject_speed) && pos(self.outlier_tol),
            ),
            ("smoothing", pos(self.smoothing) && self.smoothing <= R::ONE),
            (
                "alarms",
                self.psi_alarm.is_finite()
                    && self.fines_band[0].is_finite()
                    && self.fines_band[1].is_finite()
                    && self.fines_band[0] <= self.fines_band[1]
                    && nonneg(self.fines_hysteresis)
                    && self.fines_hysteresis + self.fines_hysteresis
                        <= self.fines_band[1] - self.fines_band[0]
                    && self.alarm_persist > 0,
            ),
        ];
        for (name, ok) in checks {
            if !ok {
                return Err(ConfigError::Parameter(name));
            }
        }
        for r in &self.regions {
            for a in 0..2 {
                if r.lo[a] >= r.hi[a] || r.hi[a] > self.cells[a] {
                    return Err(ConfigError::Region);
                }
            }
        }
        for o in &self.openings {
            let a = o.axis as usize;
            if a > 1 || self.bc[a][o.high as usize] != crate::boundary::Boundary::Wall {
                return Err(ConfigError::Parameter("openings"));
            }
            let len = self.extent[1 - a];
            if !(o.lower.is_finite()
                && o.upper.is_finite()
                && o.lower >= R::ZERO
                && o.lower < o.upper
                && o.upper <= len)
            {
                return Err(ConfigError::Parameter("openings"));
            }
        }
        if !(self.noise_term >= R::ZERO && self.noise_term <= R::from_u32(10)) {
            return Err(ConfigError::Parameter("noise_term"));
        }
        if self.outflow_window == 0 || self.outflow_window as usize > MAX_OUTFLOW_WINDOW {
            return Err(ConfigError::Parameter("outflow_window"));
        }
        if let Some(o) = self.outlet {
            if o as usize >= self.regions.len() {
                return Err(ConfigError::Region);
            }
        }
        Ok(())
    }

    /// Number of estimator cells.
    pub fn cell_count(&self) -> usize {
        self.cells[0] as usize * self.cells[1] as usize
    }

    /// Most substeps of one tick: what the cycle budget affords (model, not a clock reading).
    pub fn substep_cap(&self) -> u16 {
        self.budget
            .substeps(self.estimator_grid(), self.sensor_points())
    }

    /// Estimator cells along x and z, as the cost model counts them.
    pub fn estimator_grid(&self) -> [usize; 2] {
        [self.cells[0] as usize, self.cells[1] as usize]
    }

    /// Number of sensor points.
    pub fn sensor_points(&self) -> usize {
        self.sensor[0] as usize * self.sensor[1] as usize
    }
}
