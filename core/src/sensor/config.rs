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
    /// Start of the opening along the other axis [m].
    pub lower: R,
    /// End of the opening along the other axis [m].
    pub upper: R,
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
    /// Box size along x and z [m] (origin at 0).
    pub extent: [R; 2],
    /// Boundary kinds of the box (walls, periodic, inflow, outflow = outlet).
    pub bc: Boundaries<2>,
    /// Sensor (velocity frame) points along x and z; each point is the centre of a sensor
    /// cell of the same box, so a sensor grid may be coarser than the estimator grid.
    pub sensor: [u8; 2],
    /// Segregation rate S0 [s^2/m].
    pub s0: R,
    /// eta0 [m] of `T = a eta0/eps0 kappa:kappa`.
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
    /// Height of the bed's free surface at power-up [m]: c below it, 0 above, the cell it
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
    /// Nominal frame / tick period [s]; a held (stale) tick advances this much.
    pub tick_period: R,
    /// Largest accepted frame period, as a multiple of `tick_period` (frames with a longer or
    /// non-positive period are rejected as out of range).
    pub max_period_factor: R,
    /// Work budget: most substeps of one tick.
    pub max_substeps: u16,
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
    /// Openings in wall sides (outlets), at most [`MAX_OPENINGS`].
    pub openings: heapless::Vec<SensorOpening<R>, MAX_OPENINGS>,
    /// Ticks over which the outflow fines fraction is averaged (1 to [`MAX_OUTFLOW_WINDOW`]).
    pub outflow_window: u16,
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
            ("max_substeps", self.max_substeps > 0),
            (
                "reject_speed",
                pos(self.reject_speed) && pos(self.outlier_tol),
            ),
            ("smoothing", pos(self.smoothing) && self.smoothing <= R::ONE),
            (
                "alarms",
                self.psi_alarm.is_finite()
                    && self.fines_band[0].is_finite()
                    && self.fines_band[1].is_finite(),
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

    /// Number of sensor points.
    pub fn sensor_points(&self) -> usize {
        self.sensor[0] as usize * self.sensor[1] as usize
    }
}
