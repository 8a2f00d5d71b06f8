//! What a user reads when the core refuses something: `Display` for every error type of the
//! core (grid, segregation set-up, flow, coupling, soft sensor), in words, through
//! `core::fmt` (no_std, no allocation), plus `core::error::Error`.
//!
//! Why a separate file: the enums stay next to the code that returns them, and the wording
//! (which a host wraps with its file and key, e.g. `scene.toml: grid: ...`) lives in one
//! place. `Debug` stays the terse form for tests and logs. Cell numbers are solver cell
//! indices (x fastest, then y, then z), the order of `final.csv`.

use crate::flow::coupled::CouplingError;
use crate::flow::cycle_slab::PlanError;
use crate::flow::slab::SlabError;
use crate::flow::FlowError;
use crate::grid::GridError;
use crate::segregation::SetupError;
use crate::sensor::frame::{EncodeError, Reject};
use crate::sensor::recording::RecordingError;
use crate::sensor::snapshot::SnapshotError;
use crate::sensor::ConfigError;
use crate::sensor::MAX_SENSOR_SIDE;
use core::fmt;

/// A solver axis, counted from 0 in the scene's order (z in 1D; x, z in 2D; x, y, z in 3D): the
/// core does not know the names, the host adds the key.
struct Axis(usize);

impl fmt::Display for Axis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "axis {}", self.0)
    }
}

/// What a named configuration number must satisfy, for the names the set-up checks return
/// (model.md 2 for the material, 5 for the numerics). `None` for a name without a rule here.
fn rule(name: &str) -> Option<&'static str> {
    Some(match name {
        "s0" => "the segregation rate s0 must be finite and >= 0",
        "diffusion" => "the remixing diffusivity must be finite and >= 0",
        "vacuum" => "the vacuum threshold (below it a cell counts as empty) must be finite and > 0",
        "gravity" => "gravity must be finite",
        "direction" => "a fixed segregation direction must be finite and not the zero vector",
        "temperature" => {
            "the shear-temperature constants must be finite with heating >= 0, eta0 >= 0 and eps0 > 0"
        }
        "eta0" => "the viscosity length eta0 must be finite and > 0",
        "lambda0" => "the conductivity length lambda0 must be finite and > 0",
        "eps0" => "the dissipation rate eps0 must be finite and > 0",
        "heating" => "the heating coefficient a must be finite and > 0",
        "t0" => "the yield temperature scale T0 must be finite and >= 0",
        "packing" => "the packing fractions must satisfy 0 < phi_rlp < phi_rcp < 1",
        "t_min" => "the temperature floor t_min must be finite and > 0",
        "margin" | "margin/cg_max_iterations" => {
            "the packing margin must be in (0, 1) and the CG iteration limit at least 1"
        }
        "surface" => "the free-surface threshold must be finite and > 0",
        "cg_tolerance" => "the CG tolerance must be finite and > 0",
        "wall friction" => "a wall friction coefficient tan(angle) must be finite and >= 0",
        "boundary state" => "a boundary's velocity and c must be finite",
        "inflow state" => {
            "an inflow state needs 0 <= c < (1 - margin) phi_rcp and T >= 0"
        }
        "extent" => "the box must have a finite, positive length along both axes",
        "c" => "the volume fraction c must be in [0, 1]",
        "initial_phihat" => "the initial phihat must be in [0, 1]",
        "inflow_phihat" => "the inflow phihat must be in [0, 1]",
        "tick_period" => "the tick period must be finite and > 0",
        "max_period_factor" => "the largest frame period factor must be finite and > 0",
        "budget" => {
            "the cycle budget must cover the fixed part of a tick and at least one substep"
        }
        "reject_speed" => "the reject speed and the outlier tolerance must be finite and > 0",
        "smoothing" => "the smoothing factor must be in (0, 1]",
        "alarms" => "the alarm thresholds must be finite",
        "segregation" => "the estimator's segregation solver rejected the configuration",
        "initial state" => "the estimator's initial state was rejected (c, phihat out of range)",
        "c field" => "the c field must be finite with 0 <= c <= 1 in every cell",
        _ => return None,
    })
}

/// Writes the rule of `name`, or a generic sentence naming it.
fn parameter(f: &mut fmt::Formatter<'_>, what: &str, name: &str) -> fmt::Result {
    match rule(name) {
        Some(r) => f.write_str(r),
        None => write!(
            f,
            "{what} value `{name}` is out of range (NaN, infinite or outside its allowed interval)"
        ),
    }
}

impl fmt::Display for GridError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            GridError::EmptyAxis(a) => write!(f, "{} has no cells (need at least 1)", Axis(a)),
            GridError::BadExtent(a) => write!(
                f,
                "the box has zero, negative or non-finite length along {} (upper must be > lower)",
                Axis(a)
            ),
            GridError::TooManyCells { cells, capacity } => write!(
                f,
                "{cells} cells exceed the compiled capacity of {capacity} cells"
            ),
        }
    }
}

impl fmt::Display for SetupError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            SetupError::Capacity { cells, capacity } => write!(
                f,
                "{cells} cells exceed the compiled capacity of {capacity} cells"
            ),
            SetupError::UnpairedPeriodic { axis } => write!(
                f,
                "{} is periodic on one side only (periodic boundaries come in pairs)",
                Axis(axis)
            ),
            SetupError::Courant => f.write_str("the Courant number must be in (0, 1)"),
            SetupError::Parameter(name) => parameter(f, "segregation configuration", name),
            SetupError::NonFinite { field, cell } => {
                write!(f, "{field} is NaN or infinite in cell {cell}")
            }
            SetupError::NegativeVolumeFraction { cell } => {
                write!(f, "the volume fraction c is negative in cell {cell}")
            }
            SetupError::NegativeTemperature { cell } => {
                write!(f, "the granular temperature T is negative in cell {cell}")
            }
            SetupError::PhiOutOfRange { cell } => write!(
                f,
                "the small-grain fraction phi is outside [0, c] in cell {cell} (phihat = phi/c must be in [0, 1])"
            ),
            SetupError::InflowOutOfRange { cell } => write!(
                f,
                "the inflow phi is outside [0, c] of its boundary cell {cell} (inflow phihat must be in [0, 1])"
            ),
        }
    }
}

impl fmt::Display for FlowError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            FlowError::Capacity => {
                f.write_str("the grid needs more cells than the flow solver's compiled capacity")
            }
            FlowError::UnpairedPeriodic(a) => write!(
                f,
                "{} is periodic on one side only (periodic boundaries come in pairs)",
                Axis(a)
            ),
            FlowError::Parameter("courant") => {
                f.write_str("the flow's Courant number must be in (0, 1/2]")
            }
            FlowError::Parameter(name) => parameter(f, "flow configuration", name),
            FlowError::Field { field, cell } => match field {
                "c" => write!(
                    f,
                    "the volume fraction c in cell {cell} is NaN, negative or not below (1 - margin) c_rcp"
                ),
                "T" => write!(
                    f,
                    "the granular temperature T in cell {cell} is NaN, infinite or negative"
                ),
                "packing" => write!(
                    f,
                    "the packing limits in cell {cell} do not satisfy 0 < c_rlp < c_rcp"
                ),
                "u" => write!(f, "the velocity in cell {cell} is NaN or infinite"),
                _ => write!(f, "{field} is out of range in cell {cell}"),
            },
        }
    }
}

impl fmt::Display for PlanError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            PlanError::PeriodicCut => "a periodic last axis cannot be cut into slabs yet",
            PlanError::OddCut => {
                "a slab starts on an odd row, which the multigrid's coarse levels cannot cut"
            }
            PlanError::BadCuts => {
                "the slabs' first rows must rise from 0 within the grid, one per slab"
            }
        })
    }
}

impl fmt::Display for SlabError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            SlabError::Plan(e) => e.fmt(f),
            SlabError::Rows { index, rows, depth } => write!(
                f,
                "slab {index} owns {rows} rows; every slab needs at least {depth} (its halo's depth)"
            ),
            SlabError::Capacity { cells, capacity } => write!(
                f,
                "a slab needs {cells} cells, more than the flow solver's compiled capacity {capacity}"
            ),
            SlabError::NotYet(what) => write!(f, "{what} do not run on slabs of rows yet"),
            SlabError::Unprepared => f.write_str("the flow to cut into slabs is not prepared"),
            SlabError::Setup(e) => e.fmt(f),
            SlabError::Segregation(e) => {
                write!(f, "the segregation solver of a slab refused its set-up: {e}")
            }
            SlabError::GeometryMissing => {
                f.write_str("the run has cut-cell walls and its slabs were given no geometry")
            }
            SlabError::Geometry(e) => write!(f, "a slab's cut cells: {e}"),
        }
    }
}

impl fmt::Display for CouplingError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CouplingError::GridMismatch => {
                f.write_str("the flow and the segregation solver are set up on different grids")
            }
            CouplingError::Flow(e) => write!(f, "the flow solver rejected its fields: {e}"),
            CouplingError::Segregation(e) => {
                write!(f, "the segregation solver rejected the flow's fields: {e}")
            }
            CouplingError::GeometryNeedsCoupled => f.write_str(
                "cut-cell walls need the coupled mode (the flow's face mass fluxes carry the small grains)",
            ),
            CouplingError::SlabsNeedCoupled => f.write_str(
                "a run on slabs of rows needs the coupled mode (the flow's face mass fluxes carry the small grains)",
            ),
            CouplingError::OtherSlab => f.write_str("another slab of the run stopped"),
            CouplingError::GeometryMismatch => f.write_str(
                "the flow's cut-cell walls and the segregation's geometry differ (one has them, the other not)",
            ),
            CouplingError::NotSteady(r) => write!(
                f,
                "the flow did not become steady within the step limit (last residual {r:e} 1/s)"
            ),
        }
    }
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            ConfigError::Cells => f.write_str(
                "the estimator grid has an empty axis or more cells than the compiled capacity",
            ),
            ConfigError::SensorGrid => write!(
                f,
                "the sensor grid must have 1 to {MAX_SENSOR_SIDE} points per axis"
            ),
            ConfigError::UnpairedPeriodic => f.write_str(
                "an axis is periodic on one side only (periodic boundaries come in pairs)",
            ),
            ConfigError::Parameter("courant") => {
                f.write_str("the estimator's Courant number must be in (0, 1)")
            }
            ConfigError::Parameter(name) => parameter(f, "sensor configuration", name),
            ConfigError::Region => f.write_str(
                "a region is empty or outside the estimator grid, or the outlet index is invalid",
            ),
        }
    }
}

impl fmt::Display for SnapshotError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            SnapshotError::BufferTooSmall => "the snapshot buffer is too small",
            SnapshotError::Crc => "the snapshot is truncated or its CRC does not match",
            SnapshotError::Decode => "the snapshot cannot be decoded (or has trailing bytes)",
            SnapshotError::Version => {
                "the snapshot has another format version or float type than this build"
            }
            SnapshotError::Config => "the snapshot was taken with another sensor configuration",
            SnapshotError::Value => {
                "the snapshot holds a non-finite value or a fraction far outside [0, c]"
            }
        })
    }
}

impl fmt::Display for RecordingError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            RecordingError::Magic => "not a sieve recording (wrong magic bytes)",
            RecordingError::Version => "a recording format version this build does not read",
            RecordingError::Truncated => "the recording is truncated or its lengths disagree",
            RecordingError::Crc => "the recording's CRC does not match (corrupted file)",
            RecordingError::Header => "the recording's header cannot be decoded",
        })
    }
}

impl fmt::Display for EncodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("the output buffer is too small for the encoded frame")
    }
}

impl fmt::Display for Reject {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Reject::Overflow => "frame too long before a delimiter (garbage or a lost delimiter)",
            Reject::Framing => "COBS or envelope decoding failed (corrupted framing)",
            Reject::Crc => "frame CRC mismatch",
            Reject::Decode => "frame body is not a valid message (version skew or truncated)",
            Reject::Dims => "frame sensor grid or value count differs from the configuration",
            Reject::NonFinite => "frame holds a NaN or infinite value",
            Reject::Range => "frame value out of range (speed above the reject limit, bad period)",
            Reject::Seq => "frame sequence number does not advance (duplicate or reordered)",
        })
    }
}

impl core::error::Error for GridError {}
impl core::error::Error for SetupError {}
impl core::error::Error for FlowError {}
impl core::error::Error for PlanError {}
impl core::error::Error for SlabError {}
impl core::error::Error for CouplingError {}
impl core::error::Error for ConfigError {}
impl core::error::Error for SnapshotError {}
impl core::error::Error for RecordingError {}
impl core::error::Error for EncodeError {}
impl core::error::Error for Reject {}
