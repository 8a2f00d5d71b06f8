//! Soft-sensor record and replay on the host (issue 4).
//!
//! * [`record`] runs a prescribed-flow scene ([`Scene`]) with the core solver as ground truth
//!   and writes what a velocity sensor would have sent (noisy frames on a coarser grid, the
//!   exact COBS byte stream the firmware consumes) plus the truth alongside, in the
//!   versioned recording format of `sieve_core::sensor::recording`.
//! * [`replay`] runs the soft sensor (f32, the firmware's type and loop) over a recording,
//!   optionally with the firmware's fault injection, and reports the estimate-against-truth
//!   error over time and the final state hash, which equals firmware-sim's for the same
//!   recording and faults.
//!
//! Wiring into the CLI (not done here: `host/src/lib.rs` and `main.rs` belong to the CLI):
//! `pub mod soft_sensor;` in `lib.rs`, then
//!
//! * `sieve record SCENE --sensor-grid NXxNZ --noise SIGMA --rate HZ --out FILE` ->
//!   `record(&RecordOptions { sensor: [NX, NZ], noise: SIGMA, period: 1.0 / HZ,
//!   ..RecordOptions::new(Scene::from_name(SCENE)?) }, FILE)` (SCENE: `shear-cell` or
//!   `gray-thornton-shear`; SIGMA relative to the scene's largest speed, e.g. 0.05);
//! * `sieve replay FILE [--faults]` -> `replay(FILE, &ReplayOptions { faults })` with
//!   `faults = Faults::DEMO` (firmware-sim's faulted pass) or `Faults::NONE`, then
//!   `print_report(&report, 10, &mut std::io::stdout())`; its last line
//!   `final_state_hash=0x...` is the line firmware-sim prints for the same recording.
//!
//! Errors are plain `String`s (`Result<_, String>`), ready to wrap in the CLI's error type.

mod record;
mod replay;
mod scene;

pub use record::{record, record_to_bytes, RecordOptions, RecordReport};
pub use replay::{print_report, replay, replay_bytes, ReplayOptions, ReplayReport, ReplayRow};
pub use scene::{coarsen, Scene, Truth, TRUTH_CAPACITY};
pub use sieve_core::sensor::feeder::Faults;

/// Estimator capacity used by the host replay and by firmware-sim (32 x 32 cells).
pub const ESTIMATOR_CAPACITY: usize = 1024;
