//! sieve: the desktop command-line front end of `sieve-core`.
//!
//! Data flows one way: [`scene`] (TOML file or built-in, `--set` overrides, validation,
//! analytic fields) -> [`run`] (the core solver on its own thread, the time loop) ->
//! diagnostics -> [`output`] (summary.json, series.csv, final.csv, VTK fields, PNG plots,
//! written atomically). [`converge`] runs a scene on several grids; [`cli`] parses the command
//! line; [`flow`] solves the granular flow of a scene (frozen or coupled) and [`fit`] fits S0 to a
//! segregation time; [`drum`] reads a drum's circulation centre, radial profiles, angle of
//! repose and flowing layer off its snapshots; [`silo`] the discharge through outlets; [`sweep`] runs the product of `--set` values; [`soft_sensor`] records sensor frames and replays the soft sensor; [`error`] maps failures to exit codes (2 for bad input, 3 for a
//! numerical failure, 130/143 for SIGINT/SIGTERM, 1 otherwise); [`interrupt`] stops a run early
//! and keeps what it wrote.

pub mod checkpoint;
pub mod cli;
pub mod converge;
pub mod coupled_steps;
pub mod data;
pub mod drum;
pub mod embedded;
pub mod error;
pub mod estimate;
pub mod fit;
pub mod flow;
pub mod grid_error;
pub mod interrupt;
pub mod isa;
#[cfg(feature = "mpi")]
pub mod mpi_jobs;
pub mod output;
pub mod parallel;
#[cfg(feature = "mpi")]
pub mod parallel_mpi;
pub mod pool;
pub mod power_law;
pub mod progress;
#[cfg(feature = "mpi")]
pub mod rank_coupled;
#[cfg(feature = "mpi")]
pub mod rank_lines;
#[cfg(feature = "mpi")]
pub mod rank_links;
#[cfg(feature = "mpi")]
pub mod rank_sum;
pub mod read;
pub mod run;
pub mod scene;
pub mod silo;
pub mod soft_sensor;
pub mod stdout;
pub mod step_psi;
pub mod sweep;
pub mod text;

pub use error::{Error, Result};
