//! Every integration test of the crate in one binary: one link and one set of generic
//! instantiations instead of one per file (a clean `cargo test` built and linked ~75
//! binaries). Run one file's tests with `cargo test -p CRATE --test suite FILE::`.

// Helpers shared by the files below.
mod common;

mod cli;
mod converge_readouts;
mod drum_readouts;
mod flow_cli;
mod frame_equivalence;
mod guards;
mod hostile;
mod hostile_input;
mod house;
mod isa;
mod outsafe;
mod pvti;
mod resume;
mod scene_words;
mod sensor_cli;
mod silo_cli;
mod silo_plots;
mod sweep;
mod threads;
mod transport_key;
mod tumbler;
mod tumbler_physics;
