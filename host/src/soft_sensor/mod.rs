//! Soft-sensor record and replay on the host (issue 4).
//!
//! * [`record_scene`] records a scene of the host's catalogue (any 2D built-in or TOML scene
//!   whose model is "prescribed" or "frozen-flow", see [`catalogue`]): the scene's own run is
//!   the truth, its velocity (prescribed or the frozen flow) averaged onto the sensor grid
//!   plus noise is what the sensor sends, and the sensor configuration (extent, boundaries,
//!   c, material, gravity, inflow) comes from the scene.
//! * [`record`] / [`record_to_bytes`] record one of the two legacy hand-written scenes
//!   ([`Scene`]: `idealised-shear-cell`, the source of firmware-sim's `shear-cell.rec`, and
//!   `gray-thornton-sensor`).
//! * Both write what a velocity sensor would have sent (noisy frames on a coarser grid, the
//!   exact COBS byte stream the firmware consumes) plus the truth alongside, in the versioned
//!   recording format of `sieve_core::sensor::recording`.
//! * [`replay`] runs the soft sensor (f32, the firmware's type and loop) over a recording,
//!   optionally with the firmware's fault injection, and reports the estimate-against-truth
//!   error over time and the final state hash, which equals firmware-sim's for the same
//!   recording and faults.
//!
//! On the command line (`host/src/cli.rs`): `sieve record SCENE [--sensor-grid NXxNZ]
//! [--noise SIGMA] [--rate HZ] [--frames N] [--seed S] [--estimator-grid NXxNZ]
//! [--truth-grid NXxNZ] [--set KEY=VALUE]... --out FILE` and `sieve replay FILE [--faults]
//! [--every N]`, whose last line `final_state_hash=0x...` is the line firmware-sim prints for
//! the same recording.
//!
//! The legacy functions return plain `String` errors; [`record_scene`] returns the host's
//! [`crate::Error`] (input errors name the scene file and key).

pub mod catalogue;
pub mod check;
mod record;
mod replay;
mod scene;

pub use catalogue::{record_scene, SceneRecordOptions, SceneRecordReport};
pub use record::{record, record_to_bytes, RecordOptions, RecordReport};
pub use replay::{
    print_report, replay, replay_bytes, replay_bytes_with, replay_kinematic, replay_with, OffSpec,
    OutflowAccuracy, ReplayOptions, ReplayReport, ReplayRow,
};
pub use scene::{coarsen, Scene, Truth, TRUTH_CAPACITY};
pub use sieve_core::sensor::feeder::Faults;
use sieve_core::sensor::CycleBudget;

/// Estimator capacity used by the host replay and by firmware-sim (32 x 32 cells).
pub const ESTIMATOR_CAPACITY: usize = 1024;

/// Clock the recorder budgets a tick for by default: a 168 MHz Cortex-M4F (STM32F4 class).
pub const DEFAULT_CPU_HZ: f64 = 168e6;

/// The cycle budget of a tick of `period` \[s\] on a Cortex-M4F at `cpu_hz` granting the sensor
/// the share `cpu_share` of its time, with the cost model firmware-sim measured
/// ([`CycleBudget::CORTEX_M4F`]).
pub fn cpu_budget(cpu_hz: f64, cpu_share: f64, period: f64) -> CycleBudget {
    CycleBudget::CORTEX_M4F.with_clock(cpu_hz, period, cpu_share)
}
