//! Every integration test of the crate in one binary: one link and one set of generic
//! instantiations instead of one per file (a clean `cargo test` built and linked ~75
//! binaries). Run one file's tests with `cargo test -p CRATE --test suite FILE::`.

// Helpers shared by the files below.
mod common;
mod drum_common;
mod readme;
mod silo_common;

mod bounds;
mod column_a;
mod coupled_step_limit;
mod direction;
mod direction_flow;
mod direction_lanes;
mod flow_boundaries;
mod flow_cg;
mod flow_chute;
mod flow_closure;
mod flow_collapse;
mod flow_coupled;
mod flow_cut_friction;
mod flow_drum;
mod flow_drum_coupled;
mod flow_dust;
mod flow_frame;
mod flow_guess;
mod flow_hopper;
mod flow_implicit;
mod flow_implicit_dilute;
mod flow_objective;
mod flow_pile;
mod flow_settled_fill;
mod flow_settling;
mod flow_shear_cell;
mod flow_silo;
mod flow_silo_3d;
mod flow_surface_release;
mod flow_threads;
mod fuzz_readers;
mod geometry;
mod goldens;
mod gray_thornton;
mod invariants;
mod limited_bounds;
mod limited_transport;
mod limiter_exact;
mod messages;
mod readme_numbers;
mod reproducibility;
mod segregation_embedded;
mod sensor_accuracy;
mod sensor_budget;
mod sensor_carried;
mod sensor_entropy_table;
mod sensor_estimator;
mod sensor_golden;
mod sensor_hysteresis;
mod sensor_kinematic;
mod sensor_noise;
mod sensor_seq_wrap;
mod sensor_silo;
mod sensor_wire;
mod serial_passes;
mod side_books;
mod subnormal;
mod uniform_fast_path;
