//! Online segregation soft sensor (issue 4): estimates the segregation state of a 2D flow from
//! measured velocity frames, inside a fixed time and memory budget.
//!
//! A controller can measure grain velocities (PIV, surface velocimetry, a kinematic model) but
//! not the segregation state. [`SoftSensor`] keeps the small-grain fraction on a static 2D grid
//! and advances it with the core [`Segregation`](crate::segregation::Segregation) solver
//! (model.md 2 last relation: T from the measured shear rate; 3: direction from the measured
//! velocity gradient; 5: modified Godunov step). Nothing here duplicates the numerics.
//!
//! Data flow per tick (see [`SoftSensor`] for the exact rules):
//!
//! ```text
//! UART bytes -> FrameDecoder (COBS, CRC-32, postcard)  -> VelocityFrame
//!            -> SoftSensor::submit (validate, median outlier clean-up, EMA smoothing)
//!            -> SoftSensor::finish_tick (bilinear map onto the estimator grid,
//!               prepare_velocity, budgeted substeps)
//!            -> SoftSensor::estimate -> Estimate (psi, region means, alarms, health)
//! ```
//!
//! Memory is fixed: the estimator capacity is the const generic `N` (cells); sensor frames hold
//! at most [`MAX_SENSOR_POINTS`] points. Nothing allocates, nothing panics on input bytes.

pub mod config;
pub mod entropy;
pub mod estimator;
pub mod feeder;
pub mod frame;
pub mod kinematic;
mod noise;
pub mod recording;
pub mod snapshot;

pub use config::{
    ConfigError, CycleBudget, Region, SensorConfig, SensorOpening, MAX_OPENINGS, MAX_OUTFLOW_WINDOW,
};
pub use estimator::{seq_after, Counters, SoftSensor, TickProfile};
pub use frame::{Estimate, FrameDecoder, Reject, VelocityFrame, WireCounters};

/// Re-exported so users of the wire types (the host CLI) need no direct dependency.
pub use heapless;

use crate::real::Real;
use serde::{de::DeserializeOwned, Serialize};

/// Largest sensor grid side (points per axis of a velocity frame).
pub const MAX_SENSOR_SIDE: usize = 16;
/// Largest number of sensor points in a frame (16 x 16).
pub const MAX_SENSOR_POINTS: usize = MAX_SENSOR_SIDE * MAX_SENSOR_SIDE;
/// Largest number of velocity values in a frame: two components per point.
pub const MAX_FRAME_VALUES: usize = 2 * MAX_SENSOR_POINTS;
/// Largest number of named regions.
pub const MAX_REGIONS: usize = 4;
/// Largest length of a region name in bytes.
pub const MAX_REGION_NAME: usize = 8;

/// Health flags of an [`Estimate`] (bit set in `Estimate::health`), accumulated over one tick.
pub mod health {
    /// The tick needed more substeps than the budget: it advanced less than the frame's time
    /// (stable substeps only, so still bounded and conservative); the shortfall is in `lag`.
    pub const BUDGET_LIMITED: u8 = 1;
    /// No valid frame this tick: the last good velocity was held.
    pub const STALE_INPUT: u8 = 2;
    /// No valid frame for longer than the hold limit: the estimate is frozen (not advanced).
    pub const FROZEN: u8 = 4;
    /// At least one frame was rejected this tick (see the counters for the cause).
    pub const FRAME_REJECTED: u8 = 8;
    /// At least one sensor value was replaced by its neighbourhood median this tick.
    pub const OUTLIERS_REPLACED: u8 = 16;
    /// No valid frame has ever arrived: the estimate is the initial state.
    pub const NO_INPUT: u8 = 32;
    /// phi is outside [0, c] in some cell (round-off, or a measured velocity that is not
    /// divergence-free compressing phi above c). The state is kept as it is, so mass stays
    /// exactly conservative; the readouts clamp phihat into [0, 1]. Cells are counted in
    /// `Counters::phi_excursions`.
    pub const PHI_EXCURSION: u8 = 64;
}

/// Alarm flags of an [`Estimate`] (bit set in `Estimate::alarms`).
pub mod alarm {
    /// The mixing index psi is below the configured threshold (segregated).
    pub const PSI_LOW: u8 = 1;
    /// The outlet region's fines fraction is below the configured band.
    pub const FINES_LOW: u8 = 2;
    /// The outlet region's fines fraction is above the configured band.
    pub const FINES_HIGH: u8 = 4;
}

/// The real types the soft sensor runs in: [`Real`] plus serde, for configurations and
/// snapshots (postcard writes both as fixed-width little-endian IEEE bits), plus direct
/// conversions: `Real::from_usize` goes through f64, which the Cortex-M4F emulates in
/// software (about 60 instructions per conversion, measured in firmware-sim).
pub trait SensorReal: Real + Serialize + DeserializeOwned {
    /// `n` correctly rounded (the same value as `from_f64(n as f64)`).
    fn from_u32(n: u32) -> Self;
    /// `x` correctly rounded (the same value as `from_f64(x as f64)`).
    fn from_f32(x: f32) -> Self;
    /// `self` truncated towards zero to an integer, saturating (`as u32`; NaN gives 0).
    fn trunc_u32(self) -> u32;
    /// For a positive normal `self = 2^e (1 + m)`: `e` and the two leading bits of `m` (a
    /// quarter-octave histogram bin from the bits, no logarithm and no float conversion).
    fn octave_quarter(self) -> (i32, u32);
}
impl SensorReal for f32 {
    #[inline(always)]
    fn from_u32(n: u32) -> Self {
        n as f32
    }
    #[inline(always)]
    fn from_f32(x: f32) -> Self {
        x
    }
    #[inline(always)]
    fn trunc_u32(self) -> u32 {
        self as u32
    }
    #[inline(always)]
    fn octave_quarter(self) -> (i32, u32) {
        let b = self.to_bits();
        (((b >> 23) & 0xff) as i32 - 127, (b >> 21) & 0x3)
    }
}
impl SensorReal for f64 {
    #[inline(always)]
    fn from_u32(n: u32) -> Self {
        n as f64
    }
    #[inline(always)]
    fn from_f32(x: f32) -> Self {
        x as f64
    }
    #[inline(always)]
    fn trunc_u32(self) -> u32 {
        self as u32
    }
    #[inline(always)]
    fn octave_quarter(self) -> (i32, u32) {
        let b = self.to_bits();
        (((b >> 52) & 0x7ff) as i32 - 1023, ((b >> 50) & 0x3) as u32)
    }
}

/// CRC-32 (ISO-HDLC, the zlib/Ethernet polynomial) used by frames, snapshots and recordings.
pub(crate) const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// CRC-32 of `bytes` (the checksum the wire format, snapshots and recordings carry).
pub fn crc32(bytes: &[u8]) -> u32 {
    CRC32.checksum(bytes)
}
